"""Grid3D and located fields in 3D (issue 12); the 2D Grid keeps its fields."""

import dataclasses

import jax
import numpy as np
import pytest

import refmap  # noqa: F401
from refmap.fields import Field, divergence, gradient, locate, to_nodes
from refmap.grid import Grid, Grid3D


def test_2d_grid_fields_unchanged():
    assert [f.name for f in dataclasses.fields(Grid)] == ["nx", "ny", "ax", "bx", "ay", "by"]
    g = Grid(10, 8, 0.0, 1.0, 0.0, 2.0)
    assert g.ndim == 2 and g.spacing == (g.dx, g.dy) == (0.1, 0.25)


def test_grid3d_geometry():
    g = Grid3D(8, 10, 12, 0.0, 1.0, -1.0, 1.0, 0.0, 3.0)
    assert g.ndim == 3 and g.spacing == (0.125, 0.2, 0.25) and g.h == 0.125
    assert g.shape("node") == (8, 10, 12) and g.shape("corner") == (9, 11, 13)
    x, y, z = g.axes("node")
    assert x[0] == pytest.approx(0.0625) and y[-1] == pytest.approx(0.9) and len(z) == 12
    X, Y, Z = g.mesh("corner")
    assert X.shape == (9, 11, 13) and Z[0, 0, -1] == pytest.approx(3.0)
    assert g.cell_volume == pytest.approx(0.125 * 0.2 * 0.25)
    assert g.contains(0.5, 0.0, 1.0) and not g.contains(0.5, 0.0, 3.5)
    with pytest.raises(ValueError, match="nz must be an integer >= 8"):
        Grid3D(8, 8, 4)
    with pytest.raises(ValueError, match="bz > az"):
        Grid3D(8, 8, 8, az=1.0, bz=0.0)
    with pytest.raises(ValueError, match="unknown grid location"):
        g.axes("edge")
    assert hash(g) == hash(Grid3D(8, 10, 12, 0.0, 1.0, -1.0, 1.0, 0.0, 3.0))


def test_located_fields_in_3d():
    g = Grid3D(8, 9, 10, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0)
    xs = [
        np.concatenate([[a[0] - h], a, [a[-1] + h]])
        for a, h in zip(g.axes(), g.spacing, strict=True)
    ]
    Xp, Yp, Zp = np.meshgrid(*xs, indexing="ij")
    lin = 2.0 * Xp - 3.0 * Yp + 0.5 * Zp  # padded with exact ghost values
    f = Field(lin[1:-1, 1:-1, 1:-1], "node", g)
    grads = gradient(f, lin)
    assert len(grads) == 3 and all(c.loc == "corner" for c in grads)
    for c, v in zip(grads, (2.0, -3.0, 0.5), strict=True):
        np.testing.assert_allclose(c.data, v, atol=1e-12)  # exact on linear fields
    zero = Field(np.zeros(g.shape("corner")), "corner", g)
    d = jax.jit(divergence)(grads[0], zero, zero, grads[1], zero, grads[2])
    assert d.loc == "node" and d.data.shape == (3, 8, 9, 10)
    np.testing.assert_allclose(d.data, 0.0, atol=1e-10)  # divergence of a constant tensor
    assert to_nodes(grads[0]).data.shape == (8, 9, 10)
    assert locate(g, np.zeros((2, 9, 10, 11))).loc == "corner"
    with pytest.raises(ValueError, match="needs the 6 components"):
        divergence(grads[0], grads[1], grads[2])
    with pytest.raises(ValueError, match="on a 8x9x10 grid must end in shape"):
        Field(np.zeros((8, 9, 11)), "node", g)
