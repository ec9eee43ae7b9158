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
offending value and where it is.  How the field combines with each
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
    """A bad initial velocity; ``key`` is ``"u"``, ``"v"``, ``"file"`` or ``""``."""

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


def _allowed() -> str:
    return (f"use x, y, numbers, {', '.join(CONSTANTS)}, + - * / ** %, comparisons and "
            f"the functions {', '.join(FUNCTIONS)}")


def _node_text(text: str, node: ast.AST) -> str:
    seg = ast.get_source_segment(text, node)
    return seg if seg is not None else type(node).__name__


def _check(text: str, node: ast.AST, depth: int = 0) -> None:
    """Refuse every node that is not part of the small expression language."""
    if depth > MAX_EXPRESSION_DEPTH:
        raise ValueError(f"nested deeper than {MAX_EXPRESSION_DEPTH} levels")
    d = depth + 1
    if isinstance(node, ast.Expression):
        _check(text, node.body, d)
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
        if node.id not in VARIABLES and node.id not in CONSTANTS:
            what = "a function (call it with arguments)" if node.id in FUNCTIONS else "not allowed"
            raise ValueError(f"name {node.id!r} is {what}")
    elif isinstance(node, ast.BinOp):
        if type(node.op) not in _BINOPS:
            raise ValueError(f"operator {_OPNAMES.get(type(node.op), type(node.op).__name__)!r} "
                             "is not allowed")
        _check(text, node.left, d)
        _check(text, node.right, d)
    elif isinstance(node, ast.UnaryOp):
        if type(node.op) not in _UNARY:
            raise ValueError(f"operator {_OPNAMES.get(type(node.op), type(node.op).__name__)!r} "
                             "is not allowed")
        _check(text, node.operand, d)
    elif isinstance(node, ast.Compare):
        if len(node.ops) != 1 or type(node.ops[0]) not in _COMPARE:
            raise ValueError(f"comparison {_node_text(text, node)!r} is not allowed (one of "
                             "< <= > >= == != between two values)")
        _check(text, node.left, d)
        _check(text, node.comparators[0], d)
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
            _check(text, a, d)
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


def parse_expression(text: Any):
    """A function ``f(x, y) -> array`` of the formula ``text`` (numpy arrays in and out).

    The formula is parsed with :func:`ast.parse` and every node is checked against a small
    language (numbers, ``x``, ``y``, ``pi``, ``e``, ``+ - * / ** %``, one comparison at a
    time, and the calls in :data:`FUNCTIONS`); the function walks that tree with numpy.
    Nothing is passed to ``eval``.  Raises ValueError naming what is not allowed.
    """
    if isinstance(text, bool) or not isinstance(text, (str, int, float)):
        raise ValueError(f"must be a formula in x and y, as a string (got {text!r})")
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
        _check(src.strip(), tree)
    except RecursionError:
        raise ValueError("is nested too deeply") from None
    except ValueError as e:
        raise ValueError(f"{e}; {_allowed()}") from None

    def f(x, y):
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        with np.errstate(all="ignore"):
            out = _evaluate(tree, {"x": x, "y": y})
        return np.broadcast_to(np.asarray(out, dtype=np.float64), np.broadcast(x, y).shape)

    return f


# ----------------------------------------------------------------------------- the four forms


def _digest(a: np.ndarray) -> str:
    h = hashlib.sha1(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(repr(a.shape).encode())
    return h.hexdigest()


def _check_values(a: np.ndarray, grid, what: str) -> np.ndarray:
    """``a`` as a finite float64 (2, nx, ny) array, else InitialVelocityError."""
    want = (2,) + grid.shape()
    if a.dtype.kind not in "iuf":
        raise InitialVelocityError(f"{what} must hold real numbers, got dtype {a.dtype}", "")
    if a.shape != want:
        raise InitialVelocityError(
            f"{what} has shape {a.shape}; the grid needs (2, nx, ny) = {want} (node values, "
            "components first, indexed [i, j] with i along x)", "")
    a = np.asarray(a, dtype=np.float64)
    for c, key in enumerate("uv"):
        bad = ~np.isfinite(a[c])
        if bad.any():
            i, j = (int(k[0]) for k in np.nonzero(bad))
            X, Y = grid.mesh("node")
            raise InitialVelocityError(
                f"{what}: {key} is not finite at {int(bad.sum())} node(s), the first at "
                f"(x, y) = ({X[i, j]:.4g}, {Y[i, j]:.4g}) (node [{i}, {j}]): {float(a[c, i, j])!r}", key)
    return a


class _Field:
    """Common interface: ``sample(grid) -> (2, nx, ny)`` float64, ``to_dict()``."""

    def sample(self, grid) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def to_dict(self) -> dict:  # pragma: no cover - overridden
        raise NotImplementedError


class VelocityFunction(_Field):
    """A Python callable ``fn(x, y) -> (u, v)`` (or an array ``(2, nx, ny)``)."""

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
        X, Y = grid.mesh("node")
        shape = grid.shape()
        what = f"the callable {self.name}"
        try:
            with np.errstate(all="ignore"):
                r = self.fn(X, Y)
        except Exception as e:  # noqa: BLE001 - any failure is the user's value
            raise InitialVelocityError(
                f"{what} raised {type(e).__name__}: {e} when called as f(x, y) on the node "
                f"coordinate arrays (numpy, shape {shape})") from None
        if isinstance(r, (tuple, list)):
            if len(r) != 2:
                raise InitialVelocityError(
                    f"{what} must return (u, v), got a {type(r).__name__} of {len(r)} items")
            comps = []
            for key, c in zip("uv", r, strict=True):
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
                raise InitialVelocityError(f"{what} returned {type(r).__name__}, not (u, v) "
                                           f"({e})") from None
            if a.ndim != 3:
                raise InitialVelocityError(
                    f"{what} must return (u, v) or an array of shape (2, nx, ny) = "
                    f"{(2,) + shape}, got {type(r).__name__} of shape {a.shape}")
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
    """Node values ``(2, nx, ny)``; compared and hashed by content."""

    def __init__(self, values):
        try:
            a = np.array(values)  # a copy: later edits of the user's array do not leak in
        except Exception as e:  # noqa: BLE001
            raise InitialVelocityError(f"cannot be read as an array ({type(e).__name__}: {e})") \
                from None
        if a.dtype.kind not in "iuf":
            raise InitialVelocityError(f"must hold real numbers, got dtype {a.dtype}")
        if a.ndim != 3 or a.shape[0] != 2:
            raise InitialVelocityError(
                f"an array must have shape (2, nx, ny) (node values, components first), got "
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
    """Formulas in x and y for the two components (see :func:`parse_expression`)."""

    def __init__(self, u: Any = "0", v: Any = "0"):
        self._f = {}
        for key, text in (("u", u), ("v", v)):
            try:
                self._f[key] = parse_expression(text)
            except ValueError as e:
                raise InitialVelocityError(f"{e} (got {text!r})", key) from None
        self.u = str(u).strip()
        self.v = str(v).strip()

    def __call__(self, x, y):
        return self._f["u"](x, y), self._f["v"](x, y)

    def sample(self, grid) -> np.ndarray:
        X, Y = grid.mesh("node")
        a = np.stack([self._f["u"](X, Y), self._f["v"](X, Y)])
        try:
            return _check_values(a, grid, "the formula")
        except InitialVelocityError as e:
            text = getattr(self, e.key, "")
            raise InitialVelocityError(f"{e.msg} (got {text!r})", e.key) from None

    def to_dict(self) -> dict:
        return {"u": self.u, "v": self.v}

    def __reduce__(self):  # pickled as its formulas (the parsed functions are closures)
        return (VelocityExpression, (self.u, self.v))

    def __eq__(self, other):
        return isinstance(other, VelocityExpression) and (other.u, other.v) == (self.u, self.v)

    def __hash__(self):
        return hash((self.u, self.v))

    def __repr__(self):
        return f"VelocityExpression(u={self.u!r}, v={self.v!r})"


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
    """Node values ``(2, nx, ny)`` read from a ``.npy`` file or a dataset of an ``.h5``
    file (``dataset`` may be left out when the file holds exactly one)."""

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


def as_initial_velocity(obj):
    """None, or ``obj`` as one of the field classes of this module.

    Accepts those classes, a callable ``f(x, y)``, an array-like ``(2, nx, ny)`` (numpy or
    jax), or a dict ``{"u": ..., "v": ...}`` / ``{"file": ..., "dataset": ...}`` (the forms of
    a case file).  Raises :class:`InitialVelocityError` for anything else.
    """
    if obj is None or isinstance(obj, _Field):
        return obj
    if isinstance(obj, dict):
        keys = set(obj)
        if keys and keys <= {"u", "v"}:
            return VelocityExpression(obj.get("u", "0"), obj.get("v", "0"))
        if "file" in keys and keys <= {"file", "dataset"}:
            return VelocityFile(obj["file"], obj.get("dataset"))
        raise InitialVelocityError(
            f"a dict must be {{'u': FORMULA, 'v': FORMULA}} or {{'file': PATH}}, got keys "
            f"{sorted(map(str, keys))}")
    if callable(obj):
        return VelocityFunction(obj)
    if isinstance(obj, (str, bytes, bool, int, float)):
        raise InitialVelocityError(
            f"must be a callable f(x, y) -> (u, v), an array of shape (2, nx, ny) or None, got "
            f"{obj!r}")
    if hasattr(obj, "shape") or isinstance(obj, (list, tuple)):
        return VelocityArray(obj)
    raise InitialVelocityError(
        f"must be a callable f(x, y) -> (u, v), an array of shape (2, nx, ny) or None, got "
        f"{type(obj).__name__}: {obj!r}")
