"""Reverse-mode differentiable runs: fixed steps, ``lax.scan``, rematerialisation.

:meth:`refmap.model.Model.advance` picks its step size adaptively inside a
``lax.while_loop``, and the smoothing of the extrapolated reference maps stops adaptively
inside another; JAX cannot reverse-differentiate a ``while_loop``.  This module runs the
same step a *fixed, precomputed* number of times with a *fixed* step size, smoothing with a
fixed number of sweeps, so that ``jax.grad`` (and ``jax.vjp``) go through the whole run::

    from refmap import differentiable as rd

    model, state, params = rd.from_case(get_case("circle", 24))
    dt = rd.stable_dt(model, state, params)           # the adaptive choice, held constant

    def loss(G):
        p = rd.replace_law(params, 0, G=G)
        out = rd.rollout(model, state, p, n_steps=20, dt=dt,
                         loss=lambda s: jnp.sum(s.v ** 2))
        return out.loss

    jax.grad(loss)(10.0)

Pieces:

* :func:`rollout` -- ``n_steps`` steps of size ``dt`` in a nested ``lax.scan``; with
  ``checkpoint="sqrt"`` (default) the steps are grouped in ``ceil(sqrt(n))`` chunks, the
  chunks and the steps are rematerialised (``jax.checkpoint``), so the memory of the
  backward pass grows like ``sqrt(n)`` states instead of ``n`` steps' intermediates;
  ``checkpoint="binomial"`` stores at most ``snapshots`` states by Griewank and Walther's
  binomial (revolve) schedule (:func:`binomial_schedule`) in a custom VJP, re-running
  :func:`binomial_cost` steps;
* :func:`differentiable_model` -- a copy of a model whose map smoothing uses fixed sweeps
  (``Numerics.fixed_smooth_sweeps``; :func:`rollout` applies it itself);
* :func:`with_traced` -- a copy of a model in which static parts of the case take traced
  values: solid shapes (e.g. a disc's radius), the contact strength, and the speed of the
  prescribed edge velocities (an inflow); :func:`replace_shape` builds a shape with traced
  parameters;
* :func:`replace_law`, :func:`replace_fluid` -- parameter pytrees with one value replaced
  (traced values welcome);
* :func:`from_case` -- model, initial state and parameters of a :class:`refmap.case.Case`;
  :func:`stable_dt` -- the adaptive step of the initial state, to hold constant.

What is differentiable, what has a zero derivative by design (the discrete choices: ENO
stencils, nearest solid, extrapolation masks, clipping) and the measured costs are in
``docs/differentiable.md``.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from refmap.state import Params, State

__all__ = [
    "CHECKPOINTS",
    "BinomialSchedule",
    "RolloutResult",
    "binomial_cost",
    "binomial_schedule",
    "differentiable_model",
    "from_case",
    "minimize_lbfgs",
    "nested_chunks",
    "replace_fluid",
    "replace_law",
    "replace_shape",
    "rollout",
    "stable_dt",
    "with_traced",
]

#: the rematerialisation strategies of :func:`rollout`
CHECKPOINTS = ("sqrt", "nested", "binomial", "step", None)


class RolloutResult(NamedTuple):
    """What :func:`rollout` returns.

    ``state``: the final state; ``loss``: ``loss(state)`` (or ``loss(state, observations)``
    when ``observe`` was given), None without a loss; ``observations``: the stacked values
    of ``observe(state)`` after every step (leading axis ``n_steps``), None without it."""

    state: State
    loss: Any
    observations: Any


# ----------------------------------------------------------------------------- the model
def differentiable_model(model, sweeps: int | None = None, hand_transposes: bool = True):
    """``model`` with a fixed number of smoothing sweeps (no ``while_loop`` in the step).

    ``sweeps`` defaults to ``Numerics.fixed_smooth_sweeps`` if set, else
    ``Numerics.smooth_max_sweeps`` (the adaptive rule seldom stops before that; see
    :func:`refmap.extrapolation.smooth_extrapolated`).  ``hand_transposes`` (default):
    the step's advection and extra viscosity use their hand-written reverse modes
    (:attr:`refmap.model.Model.hand_transposes`: less memory in reverse mode, same values);
    those have no forward mode, so pass ``False`` for ``jax.jvp`` or ``jax.jacfwd``.
    Returns ``model`` itself when it already has both settings, otherwise a shallow copy
    with replaced numerics (the traced parts set by :func:`with_traced` are kept).
    """
    if not isinstance(hand_transposes, bool):
        raise ValueError(
            f"differentiable_model: hand_transposes must be True or False, got {hand_transposes!r}"
        )
    n = model.numerics
    if sweeps is None:
        sweeps = n.fixed_smooth_sweeps if n.fixed_smooth_sweeps is not None else n.smooth_max_sweeps
    if not isinstance(sweeps, int) or isinstance(sweeps, bool) or sweeps < 0:
        raise ValueError(f"differentiable_model: sweeps must be an integer >= 0, got {sweeps!r}")
    if n.fixed_smooth_sweeps == sweeps and model.hand_transposes == hand_transposes:
        return model
    out = copy.copy(model)
    out.numerics = dataclasses.replace(n, fixed_smooth_sweeps=sweeps)
    out.hand_transposes = hand_transposes
    return out


def _check_differentiable(model):
    """ValueError naming what keeps ``model``'s step from being reverse-differentiable."""
    n = model.numerics
    if n.fixed_smooth_sweeps is None:
        raise ValueError(
            "the model smooths its extrapolated maps with the adaptive stopping rule (a "
            "lax.while_loop, not reverse-differentiable): Numerics.fixed_smooth_sweeps is None; "
            "use refmap.differentiable.differentiable_model(model)"
        )


class _TracedShape:
    """A shape whose parameters may be traced: evaluates ``shape._sdf`` directly (the
    compiled ``Shape.__call__`` treats its float fields as static keys)."""

    def __init__(self, shape):
        self.shape = shape

    def __call__(self, X, Y):
        X, Y = jnp.broadcast_arrays(jnp.asarray(X, dtype=float), jnp.asarray(Y, dtype=float))
        return self.shape._sdf(X, Y)

    def __repr__(self):
        return f"traced({self.shape!r})"


def replace_shape(shape, **fields):
    """A copy of the (frozen dataclass) ``shape`` with ``fields`` replaced by values that may
    be traced, e.g. ``replace_shape(Disc((0, 0), 0.5), radius=r)``.  The constructor's
    checks are skipped (they need concrete numbers); nested shapes are replaced with nested
    calls.  Use the result through :func:`with_traced`."""
    if not dataclasses.is_dataclass(shape):
        raise TypeError(f"replace_shape: {shape!r} is not a dataclass shape")
    return _with_fields("replace_shape", shape, fields)


def _with_fields(caller: str, obj, fields: Mapping):
    """A shallow copy of the frozen dataclass ``obj`` with ``fields`` set (values may be
    traced, so the constructor and its checks are bypassed); unknown names are refused."""
    names = {f.name for f in dataclasses.fields(obj)}
    unknown = sorted(set(fields) - names)
    if unknown:
        raise ValueError(f"{caller}: {type(obj).__name__} has no field(s) {unknown}; "
                         f"its fields are {sorted(names)}")
    out = copy.copy(obj)
    for name, v in fields.items():
        object.__setattr__(out, name, v)
    return out


def with_traced(model, shapes: Mapping[int, Any] | None = None, contact_strength=None,
                edge_velocity_scale=None):
    """A shallow copy of ``model`` in which static parts of the case take traced values.

    * ``shapes``: ``{k: shape}`` replaces solid k's reference shape (its phi0, used for the
      initial level set and for the pinning of every step), e.g. a disc of traced radius
      from :func:`replace_shape`.  The solid's initial map, its anchor and the gluing to
      the walls (decided on the concrete shape at t = 0) stay as they are;
    * ``contact_strength``: the strength of every :class:`refmap.contact.Contact` body force;
    * ``edge_velocity_scale``: a factor multiplying every prescribed edge velocity (the
      ``velocity`` segments and moving walls of :mod:`refmap.boundary`): an inflow of speed
      ``scale * U``.  ``d/d scale`` at 1 is ``U`` times the derivative with respect to U.

    Start from this model's :meth:`Model.initial_state` to differentiate through the
    initial state too (the level set of a traced shape).
    """
    out = copy.copy(model)
    if shapes:
        solids = list(out.solids)
        for k, shape in dict(shapes).items():
            if not (isinstance(k, int) and 0 <= k < len(solids)):
                raise ValueError(f"with_traced: shapes key {k!r} is not a solid index "
                                 f"(the model has {len(solids)} solids)")
            s = copy.copy(solids[k])
            object.__setattr__(s, "shape", _TracedShape(shape))
            solids[k] = s
        out.solids = tuple(solids)
    if contact_strength is not None:
        from refmap.contact import Contact

        forces = []
        found = False
        for f in out.body_forces:
            if isinstance(f, Contact):
                f = copy.copy(f)
                object.__setattr__(f, "strength", contact_strength)
                found = True
            forces.append(f)
        if not found:
            raise ValueError("with_traced: contact_strength given but the model has no Contact body force")
        out.body_forces = tuple(forces)
    if edge_velocity_scale is not None:
        bc = copy.copy(out.bc)
        rules = {}
        found = False
        for key, rule in bc._rules.items():
            rule = copy.copy(rule)
            dirichlet = []
            for seg, m, val, how in rule.dirichlet:
                if how == "odd":  # a prescribed velocity (not the density at an inflow)
                    val = val * edge_velocity_scale
                    found = True
                dirichlet.append((seg, m, val, how))
            rule.dirichlet = dirichlet
            rules[key] = rule
        if not found:
            raise ValueError("with_traced: edge_velocity_scale given but no edge of the model "
                             "prescribes a nonzero velocity")
        bc._rules = rules
        out.bc = bc
    return out


# ----------------------------------------------------------------------------- parameters
def replace_law(params: Params, k: int, **values) -> Params:
    """``params`` with solid k's law fields replaced (e.g. ``G=``, ``kappa=``, ``rho0=``);
    the values may be traced.  Law constructors' checks are skipped for traced values."""
    laws = list(params.laws)
    if not (0 <= k < len(laws)):
        raise ValueError(f"replace_law: no solid {k} (params has {len(laws)} laws)")
    laws[k] = _with_fields("replace_law", laws[k], values)
    return dataclasses.replace(params, laws=tuple(laws))


def replace_fluid(params: Params, **values) -> Params:
    """``params`` with fluid fields replaced (``eta``, ``lambda_f``, ``rho0``, ...)."""
    return dataclasses.replace(params, fluid=_with_fields("replace_fluid", params.fluid, values))


# ----------------------------------------------------------------------------- set-up
def from_case(case, sweeps: int | None = None, n: int = 64):
    """``(model, state, params)`` of a :class:`refmap.case.Case` (validated) or of a
    scenario named by ``case`` at grid size ``n``, the model with fixed smoothing sweeps
    (:func:`differentiable_model`)."""
    if isinstance(case, str):
        from refmap.scenarios import get_case

        case = get_case(case, n)
    model, params = case.build()
    model = differentiable_model(model, sweeps)
    state = jax.jit(model.initial_state)(params)
    return model, state, params


def stable_dt(model, state: State, params: Params) -> float:
    """The adaptive step (``Model.time_step``) of ``state``, as a Python float.  A
    differentiable run holds it constant: the step size then does not depend on the
    parameters, so its (piecewise) derivative is not part of the gradient."""
    dt, _ = jax.jit(model.time_step)(state, params)
    return float(dt)


# ----------------------------------------------------------------------------- the run
def _chunks(n_steps: int, checkpoint):
    """(chunk length, number of full chunks, remainder) of the outer scan."""
    if checkpoint != "sqrt":
        return n_steps, 1, 0
    c = max(1, math.isqrt(n_steps - 1) + 1) if n_steps > 1 else 1  # ceil(sqrt(n))
    return c, n_steps // c, n_steps % c


def _iroot_ceil(n: int, k: int) -> int:
    """The smallest integer c >= 1 with c**k >= n (exact: no float rounding)."""
    c = max(1, int(round(n ** (1.0 / k))))
    while c**k < n:
        c += 1
    while c > 1 and (c - 1) ** k >= n:
        c -= 1
    return c


def nested_chunks(n_steps: int, levels: int) -> tuple[int, ...]:
    """The scan lengths ``(c_1, ..., c_k)`` (innermost first) of ``checkpoint="nested"``.

    Their product is at least ``n_steps``: the ``prod - n_steps`` steps past the end are
    computed on the final state and discarded.  The backward pass keeps about ``sum(c_i)``
    states.  Chosen among the lengths from ``c - 3`` to ``c + 2`` (``c = ceil(n^(1/k))``):
    those that discard at most 5 % of ``n_steps`` if there are any, of these the smallest
    sum (fewest states), then the fewest discarded steps."""
    if isinstance(levels, bool) or not isinstance(levels, int) or levels < 1:
        raise ValueError(f"rollout: levels must be an integer >= 1, got {levels!r}")
    c = _iroot_ceil(n_steps, levels)
    best, key = (c,) * levels, None
    for t in itertools.combinations_with_replacement(range(max(1, c - 3), c + 3), levels):
        waste = math.prod(t) - n_steps
        if waste >= 0:
            k = (waste > 0.05 * n_steps, sum(t), waste)
            if key is None or k < key:
                best, key = t, k
    return best


def _nested(one, observe, state, n_steps, cs):
    """``n_steps`` of ``one`` in ``len(cs)`` nested, rematerialised scans of lengths ``cs``
    (innermost first).  The carry holds the step count; the ``prod(cs) - n_steps`` steps
    past the end are computed on the final state and discarded (``jnp.where``).  One copy
    of the step in the program, whatever ``n_steps``.

    Not ``lax.cond``: a cond that skips the step (inside or outside its checkpoint) put the
    step's backward pass in a conditional, and XLA's buffers there cost about 14 fields
    more at the peak (10 MiB at 128^2, 0.45 MiB at 32^2); the discarded steps cost time
    instead (a few percent: see :func:`nested_chunks`)."""
    padded = math.prod(cs) > n_steps
    cs = tuple(c for c in cs if c > 1) or (1,)  # a scan of length 1 would only add a re-run
    one = jax.checkpoint(one)

    def level(carry):
        s, i = carry
        if padded:
            new = one(s)
            s = jax.tree_util.tree_map(lambda a, b: jnp.where(i < n_steps, a, b), new, s)
        else:
            s = one(s)
        return (s, i + 1), (observe(s) if observe is not None else None)

    for j, c in enumerate(cs):

        def level(carry, body=level, c=c):
            return lax.scan(lambda x, _: body(x), carry, None, length=c)

        if j < len(cs) - 1:  # the outermost scan is not rematerialised (as in "sqrt")
            level = jax.checkpoint(level)
    (s, _), obs = level((state, jnp.zeros((), jnp.int32)))
    if observe is not None:
        total = math.prod(cs)
        k = len(cs)
        obs = jax.tree_util.tree_map(lambda a: a.reshape((total,) + a.shape[k:])[:n_steps], obs)
    return s, obs


def rollout(
    model,
    state: State,
    params: Params,
    n_steps: int,
    dt,
    loss: Callable | None = None,
    observe: Callable | None = None,
    checkpoint: str | None = "sqrt",
    sweeps: int | None = None,
    levels: int = 3,
    snapshots: int = 13,
    hand_transposes: bool = True,
) -> RolloutResult:
    """``n_steps`` steps of ``model`` of fixed size ``dt``, reverse-differentiable.

    Args:
        model: a :class:`refmap.model.Model` (or one from :func:`with_traced`); it is run
            with fixed smoothing sweeps (:func:`differentiable_model`: ``sweeps``, else
            ``fixed_smooth_sweeps``, else ``smooth_max_sweeps``).
        state, params: the initial state and the parameters (the things to differentiate
            with respect to: ``params`` leaves, ``state.v``, ...).
        n_steps: number of steps (a Python int >= 1: static).
        dt: the step size (held constant, not chosen adaptively: see :func:`stable_dt`;
            it may be traced).
        loss: optional ``loss(final_state)`` -> scalar, or ``loss(final_state,
            observations)`` when ``observe`` is given.
        observe: optional ``observe(state)`` -> pytree of arrays, recorded after every
            step (stacked along a new leading axis of length ``n_steps``).
        checkpoint: ``"sqrt"`` (default): an outer scan over ``~sqrt(n)`` chunks of
            ``~sqrt(n)`` steps, each chunk and each step rematerialised in the backward pass,
            which then keeps ``~2 sqrt(n)`` states and one step's intermediates;
            ``"nested"``: ``levels`` nested scans of ``~n^(1/levels)`` iterations each
            (:func:`nested_chunks`), every level rematerialised: ``~levels n^(1/levels)``
            states kept, the forward run recomputed ``levels`` times; ``"step"``: one scan,
            each step rematerialised (``n`` states kept); ``None``: no rematerialisation
            (every step's intermediates kept: fastest, most memory).
        levels: the number of nested scans of ``checkpoint="nested"`` (an int >= 1;
            ignored by the other strategies).  ``levels=2`` is ``"sqrt"`` with the
            remainder padded instead of run separately; ``levels=1`` is ``"step"``.
        snapshots: the number of stored states of ``checkpoint="binomial"`` (an int >= 1;
            ignored by the other strategies): binomial checkpointing (Griewank and
            Walther's revolve, :func:`binomial_schedule`) in a custom VJP; the backward pass
            holds ``snapshots + 1`` states and one step's backward, and re-runs
            :func:`binomial_cost` steps (e.g. 10 000 steps, 13 snapshots: 4.8 runs).
        hand_transposes: the step's advection and extra viscosity with hand-written
            reverse modes (default: less memory in ``jax.grad``; see
            :func:`differentiable_model`).  Pass ``False`` for forward mode (``jax.jvp``,
            ``jax.jacfwd``), with any ``checkpoint`` but ``"binomial"`` (a custom VJP too).

    Returns:
        :class:`RolloutResult` ``(state, loss, observations)``.
    """
    if isinstance(n_steps, bool) or not isinstance(n_steps, int) or n_steps < 1:
        raise ValueError(f"rollout: n_steps must be an integer >= 1, got {n_steps!r}")
    if checkpoint not in CHECKPOINTS:
        raise ValueError(f"rollout: checkpoint must be one of {CHECKPOINTS}, got {checkpoint!r}")
    if isinstance(dt, (int, float)) and not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"rollout: dt must be a finite number > 0, got {dt!r}")
    if loss is not None and not callable(loss):
        raise ValueError(f"rollout: loss must be callable, got {loss!r}")
    if observe is not None and not callable(observe):
        raise ValueError(f"rollout: observe must be callable, got {observe!r}")
    cs = nested_chunks(n_steps, levels) if checkpoint == "nested" else None
    if checkpoint == "binomial" and (isinstance(snapshots, bool) or not isinstance(snapshots, int)
                                     or snapshots < 1):
        raise ValueError(f"rollout: snapshots must be an integer >= 1, got {snapshots!r}")
    model = differentiable_model(model, sweeps, hand_transposes)
    _check_differentiable(model)
    dt = jnp.asarray(dt, dtype=jnp.float64)

    def one(s):
        return model.step(s, params, dt)

    if checkpoint == "nested":
        s, obs = _nested(one, observe, state, n_steps, cs)
    elif checkpoint == "binomial":
        s, obs = _binomial(one, observe, state, n_steps, snapshots)
    else:
        if checkpoint is not None:
            one = jax.checkpoint(one)

        def body(s, _):
            s = one(s)
            return s, (observe(s) if observe is not None else None)

        def run(s, length):
            return lax.scan(body, s, None, length=length)

        chunk, n_full, rem = _chunks(n_steps, checkpoint)
        if checkpoint == "sqrt":
            inner = jax.checkpoint(lambda s: run(s, chunk))

            def outer(s, _):
                return inner(s)

            s, obs = lax.scan(outer, state, None, length=n_full)
            if observe is not None:
                obs = jax.tree_util.tree_map(
                    lambda a: a.reshape((n_full * chunk,) + a.shape[2:]), obs
                )
            if rem:
                s, obs_r = jax.checkpoint(lambda s: run(s, rem))(s)
                if observe is not None:
                    obs = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), obs, obs_r)
        else:
            s, obs = run(state, n_steps)
    value = None
    if loss is not None:
        value = loss(s, obs) if observe is not None else loss(s)
    return RolloutResult(s, value, obs)


def minimize_lbfgs(fun, x0, iters: int, tol: float):
    """Minimise ``fun`` from ``x0`` with optax's L-BFGS, the whole loop in one jitted
    ``lax.while_loop``: at most ``iters`` iterations, stopping once ``fun < tol``.  Returns
    ``(iterations done, x, values, iterates)``, the last two padded with NaN to ``iters``.
    Needs optax (``pip install -e ".[inverse]"``); used by the inverse-problem examples."""
    import optax

    opt = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(fun)

    def cond(c):
        k, _, _, val, _, _ = c
        return (k < iters) & (val >= tol)

    def body(c):
        k, x, st, _, vals, xs = c
        val, g = value_and_grad(x, state=st)
        upd, st = opt.update(g, st, x, value=val, grad=g, value_fn=fun)
        vals, xs = vals.at[k].set(val), xs.at[k].set(x)
        return k + 1, optax.apply_updates(x, upd), st, val, vals, xs

    @jax.jit
    def run(x0):
        init = (0, x0, opt.init(x0), jnp.inf, jnp.full(iters, jnp.nan),
                jnp.full((iters,) + x0.shape, jnp.nan))
        k, x, _, _, vals, xs = lax.while_loop(cond, body, init)
        return k, x, vals, xs

    k, x, vals, xs = run(x0)
    return int(k), x, vals, xs


# ----------------------------------------------------------------------------- binomial
def _beta(c: int, t: int) -> int:
    """``C(c + t, c)``: the most steps that ``c`` snapshots reverse with each step run
    forward at most ``t`` times beyond its first run (Griewank's beta; 0 for t < 0)."""
    return math.comb(c + t, c) if t >= 0 else 0


def _reps(n_steps: int, c: int) -> int:
    """The repetition number: the smallest t with ``_beta(c, t) >= n_steps``."""
    t = 0
    while _beta(c, t) < n_steps:
        t += 1
    return t


def binomial_cost(n_steps: int, snapshots: int) -> int:
    """Griewank and Walther's minimal number of forward steps re-run to reverse
    ``n_steps`` steps holding at most ``snapshots`` states (the initial one among them):
    ``t n - beta(s + 1, t - 1)``, t the repetition number (:func:`_reps`).  The steps
    whose backward pass is taken are run once more inside it (not counted)."""
    if n_steps <= 1:
        return 0
    t = _reps(n_steps, snapshots)
    return t * n_steps - _beta(snapshots + 1, t - 1)


class BinomialSchedule(NamedTuple):
    """The static schedule of ``checkpoint="binomial"`` (:func:`binomial_schedule`).

    Slots ``0 .. snapshots - 1`` hold the schedule's snapshots (slot 0 the initial state);
    slot ``snapshots`` holds the state before the last step (the first reversal's).
    ``forward_store[p]``: the slot that the forward pass stores the state at step p in
    (before taking step p), -1 for none.  Reversal k (k = 0 .. n - 1) reverses step
    ``n - 1 - k``: it restores ``restore[k]``, takes ``advances[k]`` steps, storing the
    state before advance op j (``offset[k] <= j < offset[k] + advances[k]``) in
    ``store[j]`` (-1: none), then stores the current state in ``end_store[k]`` (-1: none)
    and takes the backward pass of one step from it."""

    n_steps: int
    snapshots: int
    forward_store: Any
    restore: Any
    advances: Any
    offset: Any
    store: Any
    end_store: Any
    recomputed: int


def binomial_schedule(n_steps: int, snapshots: int) -> BinomialSchedule:
    """The binomial (revolve) schedule of ``n_steps`` steps with ``snapshots`` stored
    states, as static arrays (see :class:`BinomialSchedule`).

    Recursively: to reverse the l steps after a snapshot with c snapshots in all, advance
    j steps, store that state, reverse the last l - j steps with c - 1 snapshots, then the
    first j with c; j minimises ``j + cost(l - j, c - 1) + cost(j, c)`` with the closed
    form :func:`binomial_cost`, so the total is Griewank's optimum (checked).  With one
    snapshot the l steps are reversed by re-running from it (l (l - 1) / 2 steps).  The
    schedule is replayed symbolically before it is returned (every reversal finds its
    step's state, no slot is overwritten while needed)."""
    import numpy as np

    n, c0 = n_steps, snapshots
    if isinstance(c0, bool) or not isinstance(c0, int) or c0 < 1:
        raise ValueError(f"rollout: snapshots must be an integer >= 1, got {snapshots!r}")
    cost = binomial_cost
    last = c0  # the slot of the state before the last step
    # the action list: ("R", slot) restore, ("A",) advance one step, ("S", slot) store,
    # ("B", pos) backward pass of step pos
    acts: list = [("S", 0)]

    def rev(a, l, slot, free):
        if l == 1:
            acts.append(("R", slot))
            acts.append(("B", a))
            return
        if not free:
            for i in range(a + l - 1, a - 1, -1):
                acts.append(("R", slot))
                acts.extend([("A",)] * (i - a))
                acts.append(("B", i))
            return
        c = len(free) + 1
        j = min(range(1, l), key=lambda j: (j + cost(l - j, c - 1) + cost(j, c), -j))
        acts.append(("R", slot))
        acts.extend([("A",)] * j)
        acts.append(("S", free[0]))
        rev(a + j, l - j, free[0], free[1:])
        rev(a, j, slot, free)

    rev(0, n, 0, list(range(1, c0)))
    # the forward pass: the actions before the first backward pass (no restore needed:
    # they run from the initial state), then the last step; the first reversal's state is
    # stored in slot `last`
    first = next(i for i, x in enumerate(acts) if x[0] == "B")
    fwd_store = np.full(n, -1, np.int32)
    pos = 0
    for x in acts[:first]:
        if x[0] == "S":
            fwd_store[pos] = x[1]
        elif x[0] == "A":
            pos += 1
    assert pos == n - 1, (pos, n)
    if fwd_store[n - 1] < 0:
        fwd_store[n - 1] = last
        first_slot = last
    else:
        first_slot = int(fwd_store[n - 1])
    # the reversals: each from its restore (the first from the stored last state)
    restore, advances, offset, store, end_store = [], [], [], [], []
    pending = None  # a store before the next advance (or at the end)
    k_acts = [("R", first_slot), ("B", n - 1)] + acts[first + 1:]
    cur_adv, cur_store = 0, []
    started = False
    for x in k_acts:
        if x[0] == "R":
            if not started:
                restore.append(x[1])
                offset.append(len(store))
                cur_adv, cur_store, pending, started = 0, [], None, True
            # a later restore inside a segment reloads the state just stored: a no-op
        elif x[0] == "A":
            cur_store.append(-1 if pending is None else pending)
            pending = None
            cur_adv += 1
        elif x[0] == "S":
            pending = x[1]
        else:
            advances.append(cur_adv)
            store.extend(cur_store)
            end_store.append(-1 if pending is None else pending)
            started = False
    sched = BinomialSchedule(
        n, c0, fwd_store, np.asarray(restore, np.int32), np.asarray(advances, np.int32),
        np.asarray(offset, np.int32), np.asarray(store if store else [-1], np.int32),
        np.asarray(end_store, np.int32), int(sum(advances)) + n - 1,
    )
    _replay(sched)
    return sched


def _replay(s: BinomialSchedule) -> None:
    """Run the schedule on step indices: AssertionError unless every backward pass of step
    i finds the state at i, and the forward pass ends at n - 1."""
    n = s.n_steps
    slots = [None] * (s.snapshots + 1)
    for p in range(n):
        if s.forward_store[p] >= 0:
            slots[s.forward_store[p]] = p
    for k in range(n):
        cur = slots[s.restore[k]]
        assert cur is not None, (k, s.restore[k])
        for j in range(s.offset[k], s.offset[k] + s.advances[k]):
            if s.store[j] >= 0:
                slots[s.store[j]] = cur
            cur += 1
        if s.end_store[k] >= 0:
            slots[s.end_store[k]] = cur
        assert cur == n - 1 - k, (k, cur)


def _split_state(state):
    leaves, tree = jax.tree_util.tree_flatten(state)
    isf = [jnp.issubdtype(jnp.result_type(x), jnp.inexact) for x in leaves]
    return leaves, tree, isf


def _binomial(one, observe, state, n_steps, snapshots):
    """``n_steps`` of ``one`` reversed by the binomial schedule (custom VJP)."""
    import numpy as np

    sched = binomial_schedule(n_steps, snapshots)

    def f(s):
        s1 = one(s)
        return s1, (observe(s1) if observe is not None else None)

    conv, consts = jax.closure_convert(f, state)
    consts = tuple(consts)
    leaves, tree, isf = _split_state(state)

    def merge(fl, other):
        fi, oi = iter(fl), iter(other)
        return jax.tree_util.tree_unflatten(tree, [next(fi) if b else next(oi) for b in isf])

    def split(s):
        ls = jax.tree_util.tree_leaves(s)
        return (tuple(x for x, b in zip(ls, isf, strict=True) if b),
                tuple(x for x, b in zip(ls, isf, strict=True) if not b))

    fstore = jnp.asarray(sched.forward_store)
    restore, advances = jnp.asarray(sched.restore), jnp.asarray(sched.advances)
    offset, store, end_store = (jnp.asarray(sched.offset), jnp.asarray(sched.store),
                                jnp.asarray(sched.end_store))
    n_slots = snapshots + 1

    def put(snaps, slot, s):
        i = jnp.maximum(slot, 0)
        return jax.tree_util.tree_map(
            lambda b, x: b.at[i].set(jnp.where(slot >= 0, x, b[i])), snaps, s)

    def take(snaps, slot):
        return jax.tree_util.tree_map(lambda b: b[slot], snaps)

    def forward(s, cs):
        snaps = jax.tree_util.tree_map(lambda x: jnp.zeros((n_slots,) + jnp.shape(x), jnp.result_type(x)), s)

        def body(carry, slot):
            s, snaps = carry
            snaps = put(snaps, slot, s)
            s, o = conv(s, *cs)
            return (s, snaps), o

        (s, snaps), obs = lax.scan(body, (s, snaps), fstore)
        return s, obs, snaps

    @jax.custom_vjp
    def run(s, cs):
        s, obs, _ = forward(s, cs)
        return s, obs

    def run_fwd(s, cs):
        s1, obs, snaps = forward(s, cs)
        return (s1, obs), (snaps, cs)

    def run_bwd(res, g):
        snaps, cs = res
        g_s, g_obs = g
        ct = split(g_s)[0]
        ct_c = jax.tree_util.tree_map(jnp.zeros_like, cs)

        def body(k, carry):
            snaps, ct, ct_c = carry
            cur = take(snaps, restore[k])

            def adv(j, c):
                cur, snaps = c
                snaps = put(snaps, store[j], cur)
                cur, _ = conv(cur, *cs)
                return cur, snaps

            cur, snaps = lax.fori_loop(offset[k], offset[k] + advances[k], adv, (cur, snaps))
            snaps = put(snaps, end_store[k], cur)
            fl, other = split(cur)
            i = n_steps - 1 - k

            def g1(fl, cs):
                s1, o = conv(merge(fl, other), *cs)
                return split(s1)[0], o

            _, vjp = jax.vjp(g1, fl, cs)
            o_ct = None if g_obs is None else jax.tree_util.tree_map(lambda a: a[i], g_obs)
            d_fl, d_cs = vjp((ct, o_ct))
            ct_c = jax.tree_util.tree_map(jnp.add, ct_c, d_cs)
            return snaps, d_fl, ct_c

        _, ct, ct_c = lax.fori_loop(0, n_steps, body, (snaps, ct, ct_c))
        other = split(take(snaps, 0))[1]
        d_other = tuple(np.zeros(jnp.shape(x), jax.dtypes.float0) for x in other)
        return merge(ct, d_other), ct_c

    run.defvjp(run_fwd, run_bwd)
    return run(state, consts)
