import jax
import numpy as np
import pytest

import refmap  # noqa: F401
from refmap.fields import Field, divergence, gradient, locate, to_nodes
from refmap.grid import Grid


def test_location_checks_and_inference():
    g = Grid(10, 8)
    n = locate(g, np.zeros((10, 8)))
    c = locate(g, np.zeros((3, 11, 9)))
    assert n.loc == "node" and c.loc == "corner"
    with pytest.raises(ValueError, match="neither"):
        locate(g, np.zeros((9, 8)))
    with pytest.raises(ValueError, match="corner field"):
        Field(np.zeros((10, 8)), "corner", g)
    with pytest.raises(ValueError, match="needs a node field"):
        gradient(c, np.zeros((12, 10)))
    with pytest.raises(ValueError, match="needs a corner field"):
        divergence(n, n, n)


def test_gradient_divergence_locations_and_jit():
    g = Grid(10, 8, 0.0, 1.0, 0.0, 1.0)
    X, Y = g.mesh("node")
    f = Field(X**2 + Y, "node", g)
    fp = np.pad(np.asarray(f.data), 1, mode="reflect")
    gx, gy = gradient(f, fp)
    assert gx.loc == gy.loc == "corner"
    d = jax.jit(divergence)(gx, gy, gy)
    assert d.loc == "node" and d.data.shape == (2, 10, 8)
    assert to_nodes(gx).loc == "node"
