"""Initial velocity fields: ``Case.initial_velocity`` and the case files' ``[initial_velocity]``.

A case may start from a given flow ``v(x, 0) = v0(x)`` on the nodes, for the fluid and the
solids alike.  :func:`as_initial_velocity` turns what the user gives into one of

* :class:`VelocityFunction`: a Python callable ``f(x, y) -> (u, v)`` on node coordinate
  arrays (numpy in, numpy or jax out; a scalar component is broadcast, so
  ``lambda x, y: (1.0, 0.0)`` is a uniform flow), or ``f(x, y) -> array (2, nx, ny)``;
* :class:`VelocityArray`: the node values themselves, an array of shape ``(2, nx, ny)``
  indexed ``[component, i, j]`` with i along x (like the state's ``v``);
* :class:`VelocityExpression`: two formulas in x and y (``u = "-y"``, ``v = "x"``), read by
  a small evaluator of its own (:func:`parse_expression`): numbers, ``x``, ``y``, ``pi``,
  ``e``, ``+ - * / ** %``, comparisons, and the functions in :data:`FUNCTIONS`, nothing
  else (no attribute access, no other names, no ``eval``);
* :class:`VelocityFile`: a ``.npy`` file, or a dataset of an ``.h5`` file, holding the
  ``(2, nx, ny)`` node values.

:meth:`sample` gives the ``(2, nx, ny)`` node values on a grid and checks them (shape,
finiteness) with :class:`InitialVelocityError` naming the key (``u``, ``v``, ``file``), the
offending value and where it is.

Three dimensions.  On a :class:`refmap.grid.Grid3D` every form has a third component and
coordinate: a callable ``f(x, y, z) -> (u, v, w)`` (or an array ``(3, nx, ny, nz)``), node
values ``(3, nx, ny, nz)`` indexed ``[component, i, j, k]``, formulas ``u, v, w`` in x, y
and z (``VelocityExpression(u, v, w)``, or ``dim=3`` with a left-out ``w``), and files
holding ``(3, nx, ny, nz)``.  ``z`` in a formula and a ``w`` formula are refused on a 2D
grid, naming them; shape errors name the shape the grid's dimension needs.  How the field combines with each
:attr:`refmap.model.Solid.velocity` is described in :meth:`refmap.model.Model.initial_state`.
"""

from __future__ import annotations

import ast
import hashlib
import math
import operator
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "FUNCTIONS",
    "InitialVelocityError",
    "VelocityArray",
    "VelocityExpression",
    "VelocityFile",
    "VelocityFunction",
    "as_initial_velocity",
    "parse_expression",
]

#: longest accepted expression (characters) and deepest accepted expression tree
MAX_EXPRESSION_LENGTH = 2000
MAX_EXPRESSION_DEPTH = 60


class InitialVelocityError(ValueError):
    """A bad initial velocity; ``key`` is ``"u"``, ``"v"``, ``"w"``, ``"file"``,
    ``"dataset"`` or ``""``."""

    def __init__(self, msg: str, key: str = ""):
        super().__init__(msg)
        self.key = key
        self.msg = msg


# ----------------------------------------------------------------------------- expressions

#: the functions an expression may call: name -> (numpy function, number of arguments)
FUNCTIONS: dict[str, tuple[Any, int]] = {
    "sin": (np.sin, 1),
    "cos": (np.cos, 1),
    "tan": (np.tan, 1),
    "arcsin": (np.arcsin, 1),
    "arccos": (np.arccos, 1),
    "arctan": (np.arctan, 1),
    "arctan2": (np.arctan2, 2),
    "atan2": (np.arctan2, 2),
    "sinh": (np.sinh, 1),
    "cosh": (np.cosh, 1),
    "tanh": (np.tanh, 1),
    "exp": (np.exp, 1),
    "log": (np.log, 1),
    "log10": (np.log10, 1),
    "sqrt": (np.sqrt, 1),
    "abs": (np.abs, 1),
    "sign": (np.sign, 1),
    "floor": (np.floor, 1),
    "ceil": (np.ceil, 1),
    "hypot": (np.hypot, 2),
    "min": (np.minimum, 2),
    "max": (np.maximum, 2),
    "where": (np.where, 3),
}
#: the names an expression may use besides the functions
CONSTANTS = {"pi": math.pi, "e": math.e}
VARIABLES = ("x", "y")
#: the variables of a formula on a 3D grid
VARIABLES_3D = ("x", "y", "z")

_BINOPS = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
    ast.Mod: np.mod,
}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg}
_COMPARE = {
    ast.Lt: np.less,
    ast.LtE: np.less_equal,
    ast.Gt: np.greater,
    ast.GtE: np.greater_equal,
    ast.Eq: np.equal,
    ast.NotEq: np.not_equal,
}
_OPNAMES = {ast.MatMult: "@", ast.FloorDiv: "//", ast.LShift: "<<", ast.RShift: ">>",
            ast.BitOr: "|", ast.BitXor: "^", ast.BitAnd: "&", ast.Invert: "~", ast.Not: "not"}


def _allowed(variables=VARIABLES) -> str:
    return (f"use {', '.join(variables)}, numbers, {', '.join(CONSTANTS)}, + - * / ** %, "
            f"comparisons and the functions {', '.join(FUNCTIONS)}")


def _check_dim(dim) -> int:
    if isinstance(dim, bool) or dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    return int(dim)


def _in_vars(dim: int) -> str:
    return "x and y" if dim == 2 else "x, y and z"


def _node_text(text: str, node: ast.AST) -> str:
    seg = ast.get_source_segment(text, node)
    return seg if seg is not None else type(node).__name__


def _check(text: str, node: ast.AST, depth: int = 0, variables=VARIABLES) -> None:
    """Refuse every node that is not part of the small expression language."""
    if depth > MAX_EXPRESSION_DEPTH:
        raise ValueError(f"nested deeper than {MAX_EXPRESSION_DEPTH} levels")
    d = depth + 1

    def sub(child):
        _check(text, child, d, variables)

    if isinstance(node, ast.Expression):
        sub(node.body)
    elif isinstance(node, ast.Constant):
        v = node.value
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{_node_text(text, node)} is not a number")
        try:
            f = float(v)
        except OverflowError:
            f = math.inf
        if not math.isfinite(f):
            raise ValueError(f"the number {_node_text(text, node)} is too large")
    elif isinstance(node, ast.Name):
        if node.id not in variables and node.id not in CONSTANTS:
            what = "a function (call it with arguments)" if node.id in FUNCTIONS else "not allowed"
            if node.id in VARIABLES_3D:  # z in a 2D formula
                what += f" on a 2D grid ({node.id} is the third coordinate of a 3D grid)"
            raise ValueError(f"name {node.id!r} is {what}")
    elif isinstance(node, ast.BinOp):
        if type(node.op) not in _BINOPS:
            raise ValueError(f"operator {_OPNAMES.get(type(node.op), type(node.op).__name__)!r} "
                             "is not allowed")
        sub(node.left)
        sub(node.right)
    elif isinstance(node, ast.UnaryOp):
        if type(node.op) not in _UNARY:
            raise ValueError(f"operator {_OPNAMES.get(type(node.op), type(node.op).__name__)!r} "
                             "is not allowed")
        sub(node.operand)
    elif isinstance(node, ast.Compare):
        if len(node.ops) != 1 or type(node.ops[0]) not in _COMPARE:
            raise ValueError(f"comparison {_node_text(text, node)!r} is not allowed (one of "
                             "< <= > >= == != between two values)")
        sub(node.left)
        sub(node.comparators[0])
    elif isinstance(node, ast.Call):
        f = node.func
        if not isinstance(f, ast.Name):
            raise ValueError(f"call of {_node_text(text, f)!r} is not allowed")
        if f.id not in FUNCTIONS:
            raise ValueError(f"function {f.id!r} is not allowed")
        if node.keywords or any(isinstance(a, ast.Starred) for a in node.args):
            raise ValueError(f"{f.id}() takes plain positional arguments")
        n = FUNCTIONS[f.id][1]
        if len(node.args) != n:
            raise ValueError(f"{f.id}() takes {n} argument{'s' * (n != 1)}, got {len(node.args)}")
        for a in node.args:
            sub(a)
    else:
        kinds = {ast.Attribute: "attribute access", ast.Subscript: "indexing",
                 ast.Lambda: "lambda", ast.IfExp: "if-else (use where(cond, a, b))",
                 ast.BoolOp: "and/or", ast.JoinedStr: "an f-string", ast.List: "a list",
                 ast.Tuple: "a tuple", ast.Dict: "a dict", ast.NamedExpr: ":="}
        what = kinds.get(type(node), type(node).__name__)
        raise ValueError(f"{what} is not allowed ({_node_text(text, node)!r})")


def _evaluate(node: ast.AST, env: dict):
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, env)
    if isinstance(node, ast.Constant):
        return np.float64(node.value)
    if isinstance(node, ast.Name):
        return env[node.id] if node.id in env else np.float64(CONSTANTS[node.id])
    if isinstance(node, ast.BinOp):
        return _BINOPS[type(node.op)](_evaluate(node.left, env), _evaluate(node.right, env))
    if isinstance(node, ast.UnaryOp):
        return _UNARY[type(node.op)](_evaluate(node.operand, env))
    if isinstance(node, ast.Compare):
        return _COMPARE[type(node.ops[0])](_evaluate(node.left, env),
                                           _evaluate(node.comparators[0], env)).astype(np.float64)
    if isinstance(node, ast.Call):
        args = [_evaluate(a, env) for a in node.args]
        if node.func.id == "where":
            args[0] = np.asarray(args[0]) != 0
        return FUNCTIONS[node.func.id][0](*args)
    raise AssertionError(type(node))  # _check refused everything else


def parse_expression(text: Any, dim: int = 2):
    """A function ``f(x, y) -> array`` of the formula ``text`` (numpy arrays in and out);
    with ``dim=3`` a function ``f(x, y, z)`` of a formula that may use ``z`` too.

    The formula is parsed with :func:`ast.parse` and every node is checked against a small
    language (numbers, ``x``, ``y`` (and ``z`` in 3D), ``pi``, ``e``, ``+ - * / ** %``, one
    comparison at a time, and the calls in :data:`FUNCTIONS`); the function walks that
    tree with numpy.  Nothing is passed to ``eval``.  Raises ValueError naming what is not
    allowed (``z`` in a 2D formula among it).
    """
    dim = _check_dim(dim)
    variables = VARIABLES if dim == 2 else VARIABLES_3D
    if isinstance(text, bool) or not isinstance(text, (str, int, float)):
        raise ValueError(f"must be a formula in {_in_vars(dim)}, as a string (got {text!r})")
    src = str(text)
    if len(src) > MAX_EXPRESSION_LENGTH:
        raise ValueError(f"is longer than {MAX_EXPRESSION_LENGTH} characters")
    if not src.strip():
        raise ValueError("is empty (write 0 for a zero component)")
    try:
        tree = ast.parse(src.strip(), mode="eval")
    except SyntaxError as e:
        raise ValueError(f"is not a formula: {e.msg} (at column {e.offset})") from None
    except (RecursionError, MemoryError, ValueError):
        raise ValueError("is nested too deeply") from None
    try:
        _check(src.strip(), tree, 0, variables)
    except RecursionError:
        raise ValueError("is nested too deeply") from None
    except ValueError as e:
        raise ValueError(f"{e}; {_allowed(variables)}") from None

    if dim == 2:
        def f(x, y):
            x = np.asarray(x, dtype=np.float64)
            y = np.asarray(y, dtype=np.float64)
            with np.errstate(all="ignore"):
                out = _evaluate(tree, {"x": x, "y": y})
            return np.broadcast_to(np.asarray(out, dtype=np.float64), np.broadcast(x, y).shape)

        return f

    def f3(x, y, z):
        env = {k: np.asarray(a, dtype=np.float64) for k, a in zip("xyz", (x, y, z), strict=True)}
        with np.errstate(all="ignore"):
            out = _evaluate(tree, env)
        return np.broadcast_to(np.asarray(out, dtype=np.float64), np.broadcast(*env.values()).shape)

    return f3


# ----------------------------------------------------------------------------- the four forms


def _digest(a: np.ndarray) -> str:
    h = hashlib.sha1(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(repr(a.shape).encode())
    return h.hexdigest()


def _ndim(grid) -> int:
    return int(getattr(grid, "ndim", 2))


#: per dimension: the components, the shape of the node values, their index
_KEYS = {2: "uv", 3: "uvw"}
_SHAPE = {2: "(2, nx, ny)", 3: "(3, nx, ny, nz)"}
_RETURNS = {2: "(u, v)", 3: "(u, v, w)"}
_CALL = {2: "f(x, y)", 3: "f(x, y, z)"}


def _check_values(a: np.ndarray, grid, what: str) -> np.ndarray:
    """``a`` as a finite float64 (d, nx, ny[, nz]) array, else InitialVelocityError."""
    nd = _ndim(grid)
    want = (nd,) + grid.shape()
    if a.dtype.kind not in "iuf":
        raise InitialVelocityError(f"{what} must hold real numbers, got dtype {a.dtype}", "")
    if a.shape != want:
        index = "[i, j]" if nd == 2 else "[i, j, k]"
        raise InitialVelocityError(
            f"{what} has shape {a.shape}; the grid needs {_SHAPE[nd]} = {want} (node values, "
            f"components first, indexed {index} with i along x)", "")
    a = np.asarray(a, dtype=np.float64)
    for c, key in enumerate(_KEYS[nd]):
        bad = ~np.isfinite(a[c])
        if bad.any():
            idx = tuple(int(k[0]) for k in np.nonzero(bad))
            mesh = grid.mesh("node")
            names = ", ".join("xyz"[:nd])
            at = ", ".join(f"{m[idx]:.4g}" for m in mesh)
            node = ", ".join(map(str, idx))
            raise InitialVelocityError(
                f"{what}: {key} is not finite at {int(bad.sum())} node(s), the first at "
                f"({names}) = ({at}) (node [{node}]): {float(a[(c,) + idx])!r}", key)
    return a


class _Field:
    """Common interface: ``sample(grid) -> (d, nx, ny[, nz])`` float64, ``to_dict()``."""

    def sample(self, grid) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def to_dict(self) -> dict:  # pragma: no cover - overridden
        raise NotImplementedError


class VelocityFunction(_Field):
    """A Python callable ``fn(x, y) -> (u, v)`` (or an array ``(2, nx, ny)``); on a 3D grid
    ``fn(x, y, z) -> (u, v, w)`` (or an array ``(3, nx, ny, nz)``)."""

    def __init__(self, fn):
        if not callable(fn):
            raise InitialVelocityError(f"must be callable, got {fn!r}")
        self.fn = fn

    @property
    def name(self) -> str:
        mod = getattr(self.fn, "__module__", None) or ""
        qn = getattr(self.fn, "__qualname__", None) or type(self.fn).__name__
        return f"{mod}.{qn}" if mod else qn

    def sample(self, grid) -> np.ndarray:
        nd = _ndim(grid)
        mesh = grid.mesh("node")
        shape = grid.shape()
        what = f"the callable {self.name}"
        try:
            with np.errstate(all="ignore"):
                r = self.fn(*mesh)
        except Exception as e:  # noqa: BLE001 - any failure is the user's value
            raise InitialVelocityError(
                f"{what} raised {type(e).__name__}: {e} when called as {_CALL[nd]} on the node "
                f"coordinate arrays (numpy, shape {shape})") from None
        if isinstance(r, (tuple, list)):
            if len(r) != nd:
                raise InitialVelocityError(
                    f"{what} must return {_RETURNS[nd]}, got a {type(r).__name__} of {len(r)} "
                    "items")
            comps = []
            for key, c in zip(_KEYS[nd], r, strict=True):
                try:
                    c = np.asarray(c)
                except Exception as e:  # noqa: BLE001
                    raise InitialVelocityError(f"{what} returned a {key} that is not an array "
                                               f"({type(e).__name__}: {e})", key) from None
                if c.dtype.kind not in "biuf":
                    raise InitialVelocityError(
                        f"{what} returned {key} of dtype {c.dtype}; it must be real numbers", key)
                try:
                    c = np.broadcast_to(c.astype(np.float64), shape)
                except ValueError:
                    raise InitialVelocityError(
                        f"{what} returned {key} with shape {c.shape}, which does not fit the node "
                        f"grid {shape}", key) from None
                comps.append(c)
            a = np.stack(comps)
        else:
            try:
                a = np.asarray(r)
            except Exception as e:  # noqa: BLE001
                raise InitialVelocityError(f"{what} returned {type(r).__name__}, not "
                                           f"{_RETURNS[nd]} ({e})") from None
            if a.ndim != nd + 1:
                raise InitialVelocityError(
                    f"{what} must return {_RETURNS[nd]} or an array of shape {_SHAPE[nd]} = "
                    f"{(nd,) + shape}, got {type(r).__name__} of shape {a.shape}")
        return _check_values(a, grid, f"the values of {what}")

    def to_dict(self) -> dict:
        return {"callable": self.name}

    def __eq__(self, other):
        return isinstance(other, VelocityFunction) and other.fn is self.fn

    def __hash__(self):
        return hash(id(self.fn))

    def __repr__(self):
        return f"VelocityFunction({self.name})"


class VelocityArray(_Field):
    """Node values ``(2, nx, ny)``, or ``(3, nx, ny, nz)`` for a 3D grid; compared and
    hashed by content.  ``dim`` (2 or 3) accepts only that dimension's form (and names it
    in the error); None accepts either."""

    def __init__(self, values, dim: int | None = None):
        if dim is not None:
            dim = _check_dim(dim)
        try:
            a = np.array(values)  # a copy: later edits of the user's array do not leak in
        except Exception as e:  # noqa: BLE001
            raise InitialVelocityError(f"cannot be read as an array ({type(e).__name__}: {e})") \
                from None
        if a.dtype.kind not in "iuf":
            raise InitialVelocityError(f"must hold real numbers, got dtype {a.dtype}")
        dims = (2, 3) if dim is None else (dim,)
        if not any(a.ndim == d + 1 and a.shape[0] == d for d in dims):
            want = " or ".join(_SHAPE[d] for d in dims)
            on = "" if dim in (None, 2) else " on a 3D grid"
            raise InitialVelocityError(
                f"an array must have shape {want} (node values, components first){on}, got "
                f"shape {a.shape}")
        a = a.astype(np.float64)
        a.setflags(write=False)
        self.values = a
        self.digest = _digest(a)

    def sample(self, grid) -> np.ndarray:
        return _check_values(self.values, grid, "the array")

    def to_dict(self) -> dict:
        return {"array": list(self.values.shape), "sha1": self.digest}

    def __eq__(self, other):
        return isinstance(other, VelocityArray) and other.digest == self.digest

    def __hash__(self):
        return hash(self.digest)

    def __repr__(self):
        return f"VelocityArray(shape={self.values.shape}, sha1={self.digest[:8]})"


class VelocityExpression(_Field):
    """Formulas for the components (see :func:`parse_expression`): ``u``, ``v`` in x and y
    on a 2D grid; ``u``, ``v``, ``w`` in x, y and z on a 3D grid.

    ``dim`` is 2 or 3; left out, it is 3 when ``w`` is given and 2 otherwise.  In 3D a
    left-out ``w`` is ``"0"``; in 2D a ``w`` (and ``z`` in a formula) is an error naming
    it.  A field is sampled on grids of its own dimension only."""

    def __init__(self, u: Any = "0", v: Any = "0", w: Any = None, dim: int | None = None):
        if dim is None:
            dim = 2 if w is None else 3
        try:
            dim = _check_dim(dim)
        except ValueError as e:
            raise InitialVelocityError(str(e)) from None
        if dim == 2 and w is not None:
            raise InitialVelocityError(
                f"a w formula is for a 3D grid; a 2D grid takes u and v in x and y (got "
                f"{w!r})", "w")
        if dim == 3 and w is None:
            w = "0"
        self.dim = dim
        self._f = {}
        comps = (("u", u), ("v", v)) + ((("w", w),) if dim == 3 else ())
        for key, text in comps:
            try:
                self._f[key] = parse_expression(text, dim)
            except ValueError as e:
                raise InitialVelocityError(f"{e} (got {text!r})", key) from None
        self.u = str(u).strip()
        self.v = str(v).strip()
        self.w = None if dim == 2 else str(w).strip()

    def _keys(self) -> str:
        return _KEYS[self.dim]

    def __call__(self, *coords):
        if len(coords) != self.dim:
            raise TypeError(f"{self!r} takes {self.dim} coordinate arrays "
                            f"({', '.join('xyz'[:self.dim])}), got {len(coords)}")
        return tuple(self._f[k](*coords) for k in self._keys())

    def sample(self, grid) -> np.ndarray:
        nd = _ndim(grid)
        if nd != self.dim:
            given = ", ".join(self._keys())
            raise InitialVelocityError(
                f"the formulas ({given}) are for a {self.dim}D grid but the grid is {nd}D; "
                + ("give w too (VelocityExpression(u, v, w), or dim=3)" if nd == 3
                   else "give u and v in x and y only"))
        mesh = grid.mesh("node")
        a = np.stack([self._f[k](*mesh) for k in self._keys()])
        try:
            return _check_values(a, grid, "the formula")
        except InitialVelocityError as e:
            text = getattr(self, e.key, "")
            raise InitialVelocityError(f"{e.msg} (got {text!r})", e.key) from None

    def to_dict(self) -> dict:
        if self.dim == 2:
            return {"u": self.u, "v": self.v}
        return {"u": self.u, "v": self.v, "w": self.w}

    def _key(self) -> tuple:
        return (self.u, self.v) if self.dim == 2 else (self.u, self.v, self.w)

    def __reduce__(self):  # pickled as its formulas (the parsed functions are closures)
        if self.dim == 2:
            return (VelocityExpression, (self.u, self.v))
        return (VelocityExpression, (self.u, self.v, self.w, 3))

    def __eq__(self, other):
        return isinstance(other, VelocityExpression) and other._key() == self._key()

    def __hash__(self):
        return hash(self._key())

    def __repr__(self):
        w = "" if self.dim == 2 else f", w={self.w!r}"
        return f"VelocityExpression(u={self.u!r}, v={self.v!r}{w})"


def _read_velocity_file(path: Path, dataset: str | None) -> np.ndarray:
    suffix = path.suffix.lower()
    if not path.is_file():
        raise InitialVelocityError(f"names no readable file: {path}", "file")
    if suffix == ".npy":
        if dataset is not None:
            raise InitialVelocityError(f"a .npy file has no datasets; leave 'dataset' out "
                                       f"(got {dataset!r})", "dataset")
        try:
            return np.load(path, allow_pickle=False)
        except Exception as e:  # noqa: BLE001 - any unreadable file is a bad value
            raise InitialVelocityError(f"could not be read ({type(e).__name__}: {e}): {path}",
                                       "file") from None
    if suffix in (".h5", ".hdf5"):
        import h5py

        try:
            with h5py.File(path, "r") as f:
                names = []
                f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
                if dataset is None:
                    if len(names) != 1:
                        raise InitialVelocityError(
                            f"holds {len(names)} datasets ({', '.join(names[:8]) or 'none'}); "
                            f"name the one to read with 'dataset': {path}", "dataset")
                    dataset = names[0]
                if dataset not in names:
                    raise InitialVelocityError(
                        f"no dataset {dataset!r} in {path} (it holds: "
                        f"{', '.join(names[:8]) or 'none'})", "dataset")
                return np.asarray(f[dataset][()])
        except InitialVelocityError:
            raise
        except Exception as e:  # noqa: BLE001
            raise InitialVelocityError(f"could not be read ({type(e).__name__}: {e}): {path}",
                                       "file") from None
    raise InitialVelocityError(f"must be a .npy or .h5 file, got {path}", "file")


class VelocityFile(_Field):
    """Node values ``(2, nx, ny)`` (3D: ``(3, nx, ny, nz)``) read from a ``.npy`` file or a
    dataset of an ``.h5`` file (``dataset`` may be left out when the file holds exactly
    one).  The array is checked against the grid when sampled."""

    def __init__(self, file, dataset: str | None = None):
        if not isinstance(file, (str, Path)):
            raise InitialVelocityError(f"must be a file path, got {file!r}", "file")
        if dataset is not None and not isinstance(dataset, str):
            raise InitialVelocityError(f"must be a string, got {dataset!r}", "dataset")
        self.file = str(Path(file).expanduser().resolve())
        self.dataset = dataset
        a = _read_velocity_file(Path(self.file), dataset)
        try:
            arr = VelocityArray(a)
        except InitialVelocityError as e:
            raise InitialVelocityError(f"{self.file}: {e.msg}", "file") from None
        self.values = arr.values
        self.digest = arr.digest

    def sample(self, grid) -> np.ndarray:
        try:
            return _check_values(self.values, grid, f"the array in {self.file}")
        except InitialVelocityError as e:
            raise InitialVelocityError(e.msg, "file") from None

    def to_dict(self) -> dict:
        d = {"file": self.file}
        if self.dataset is not None:
            d["dataset"] = self.dataset
        d["sha1"] = self.digest
        return d

    def __eq__(self, other):
        return isinstance(other, VelocityFile) and (other.file, other.dataset, other.digest) == (
            self.file, self.dataset, self.digest)

    def __hash__(self):
        return hash((self.file, self.dataset, self.digest))

    def __repr__(self):
        ds = "" if self.dataset is None else f", dataset={self.dataset!r}"
        return f"VelocityFile({self.file!r}{ds})"


def as_initial_velocity(obj, dim: int | None = None):
    """None, or ``obj`` as one of the field classes of this module.

    Accepts those classes, a callable ``f(x, y)`` (3D: ``f(x, y, z)``), an array-like
    ``(2, nx, ny)`` (3D: ``(3, nx, ny, nz)``; numpy or jax), or a dict
    ``{"u": ..., "v": ...}`` (3D: ``"w"`` too) / ``{"file": ..., "dataset": ...}`` (the forms
    of a case file).  ``dim`` is the grid's dimension when known (a :class:`~refmap.case.Case`
    passes it): it decides the dimension of formulas and arrays and the wording of the
    errors.  Raises :class:`InitialVelocityError` for anything else.
    """
    if dim is not None:
        try:
            dim = _check_dim(dim)
        except ValueError as e:
            raise InitialVelocityError(str(e)) from None
    nd = 2 if dim is None else dim
    if obj is None or isinstance(obj, _Field):
        return obj
    if isinstance(obj, dict):
        keys = set(obj)
        if keys and keys <= {"u", "v", "w"}:
            return VelocityExpression(obj.get("u", "0"), obj.get("v", "0"), obj.get("w"), dim)
        if "file" in keys and keys <= {"file", "dataset"}:
            return VelocityFile(obj["file"], obj.get("dataset"))
        formulas = ("{'u': FORMULA, 'v': FORMULA}" if nd == 2
                    else "{'u': FORMULA, 'v': FORMULA, 'w': FORMULA}")
        raise InitialVelocityError(
            f"a dict must be {formulas} or {{'file': PATH}}, got keys "
            f"{sorted(map(str, keys))}")
    if callable(obj):
        return VelocityFunction(obj)
    forms = (f"must be a callable {_CALL[nd]} -> {_RETURNS[nd]}, an array of shape "
             f"{_SHAPE[nd]} or None")
    if isinstance(obj, (str, bytes, bool, int, float)):
        raise InitialVelocityError(f"{forms}, got {obj!r}")
    if hasattr(obj, "shape") or isinstance(obj, (list, tuple)):
        return VelocityArray(obj, dim)
    raise InitialVelocityError(f"{forms}, got {type(obj).__name__}: {obj!r}")
