"""The conformance kit: checks of a constraint type against its contract, for any plugin's
own tests, in one call.

>>> from mechdsl.testing import check_constraint_type
>>> check_constraint_type(MyJoint())          # raises ContractViolation, with the numbers

A type writes its equations once (:meth:`~mechdsl.plugins.ConstraintType.equations`);
mechdsl traces them and derives the Jacobian and gamma exactly, and the type's array methods
``phi``, ``jacobian`` and ``gamma`` evaluate those forms (or the Jacobian and gamma the type
supplies with ``jacobian_terms`` / ``gamma_terms``). On random poses, velocities and
accelerations of the attached bodies and random argument values, it checks

1. the declaration (name, kind, signature, number of equations, an ``equations`` method),
   and that ``validate`` accepts the argument values the test uses;
2. that the equations, and the supplied terms, can be traced: an equation that branches on a
   traced value (``if``, ``bool()``), calls a numpy function that cannot be differentiated,
   returns the wrong number of values, or raises, is a violation with the message;
3. shapes: ``phi`` and ``gamma`` give ``(..., n_eq)`` and ``jacobian`` one ``(..., n_eq, 3)``
   block per attached body, for one, two and three batch axes, with arguments whose batch
   shapes differ and must broadcast;
4. no NaN or infinity on valid input, and each row of a batch computed from its own
   arguments and poses (as if alone);
5. the Jacobian against central differences of Phi in every coordinate;
6. gamma against the second time derivative of Phi along random trajectories
   q(t) = q0 + qd t + qdd t^2 / 2: d2Phi/dt2 = Phi_q qdd - gamma (types are functions of q
   only: Phi_qt and Phi_tt vanish; a drive's f(t) is the core's);
7. where the type supplies ``jacobian_terms`` or ``gamma_terms``: those values against the
   ones derived from its equations, to round-off (a relative error of 1e-9 is caught, which
   differences cannot see);
8. for types that claim ``invariant``: |Phi| unchanged when all attached bodies move by one
   rigid motion.

Checks 5 and 6 hold Phi's derivatives to an independent truth (differences of Phi), so they
also guard mechdsl's derivation; check 7 is what makes a supplied Jacobian or gamma as exact
as a derived one.

``params`` overrides the random values of arguments with a restricted domain: a callable
``f(rng, shape)`` for a point, vector or scalar, expression text (or an
:class:`~mechdsl.functions.ExprFunction`) for a function. ``poses`` likewise replaces the
random poses: ``f(rng, shape) -> tuple of (*shape, 3) arrays``, one per attached body.
"""

from __future__ import annotations

import traceback
from typing import Callable, Mapping

import numpy as np

from .functions import ExprFunction
from .plugins.contract import REQUIRED, ConstraintType, contract_problems
from .plugins.derived import EquationError
from .symbolic import GraphError

#: The methods a type writes that mechdsl runs on traced values.
_TRACED_METHODS = ("equations", "jacobian_terms", "gamma_terms")

#: The function a ``function`` argument gets unless the test gives one: smooth, positive.
DEFAULT_FUNCTION = "1.5 + 0.3*sin({v}) + 0.1*cos(2*{v})"


class ContractViolation(AssertionError):
    """A constraint type does not meet its contract; the message has the numbers."""


def random_params(ctype: ConstraintType, rng: np.random.Generator, batch: tuple[int, ...],
                  overrides: Mapping[str, object] | None = None) -> dict[str, object]:
    """Random argument values of shape ``batch + (...)``: points and vectors uniform in
    [-1, 1]^2, scalars at their default +- 0.3 or uniform in [0.5, 1.5], functions
    :data:`DEFAULT_FUNCTION` of their variable."""
    overrides = overrides or {}
    p: dict[str, object] = {}
    for arg in ctype.signature:
        if arg.kind == "body":
            continue
        given = overrides.get(arg.name)
        if arg.kind == "function":
            if isinstance(given, ExprFunction):
                p[arg.name] = given
            else:
                text = given if isinstance(given, str) else DEFAULT_FUNCTION.format(v=arg.var)
                p[arg.name] = ExprFunction.of(text, arg.var)
            continue
        shape = batch + ((2,) if arg.kind in ("point", "vector") else ())
        if given is not None:
            p[arg.name] = np.broadcast_to(np.asarray(given(rng, shape), dtype=float), shape)
        elif arg.kind == "scalar" and arg.default is not REQUIRED:
            p[arg.name] = np.full(shape, float(arg.default)) + rng.uniform(-0.3, 0.3, shape)
        elif arg.kind == "scalar":
            p[arg.name] = rng.uniform(0.5, 1.5, shape)
        else:
            p[arg.name] = rng.uniform(-1, 1, shape)
    return p


def _index(flat: int, shape: tuple[int, ...]) -> tuple[int, ...]:
    return tuple(int(i) for i in np.unravel_index(flat, shape))


def _fail(ctype: ConstraintType, what: str, got, want, where: str = "") -> None:
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    err = np.abs(got - want)
    i = _index(int(np.nanargmax(err)), err.shape) if err.size else ()
    raise ContractViolation(
        f"{ctype.kind} type '{ctype.name}': {what} is wrong{where}: at index {i} got "
        f"{float(got[i])!r}, expected {float(want[i])!r} (error {float(err[i]):.3g})")


def _call(ctype: ConstraintType, method: str, *args, where: str = ""):
    """Call a method of the type; an exception it raises is a violation too."""
    try:
        with np.errstate(all="ignore"):
            return getattr(ctype, method)(*args)
    except Exception as err:  # noqa: BLE001 - the plugin's failure is the finding
        raise ContractViolation(f"{ctype.kind} type '{ctype.name}': {method}() raised "
                                f"{type(err).__name__}: {err}{where}") from err


def _shape(ctype: ConstraintType, what: str, got, want: tuple[int, ...]) -> None:
    if np.shape(got) != want:
        raise ContractViolation(f"{ctype.kind} type '{ctype.name}': {what} has shape "
                                f"{np.shape(got)}, expected {want}")


def _finite(ctype: ConstraintType, what: str, a) -> None:
    a = np.asarray(a, dtype=float)
    if not np.isfinite(a).all():
        i = _index(int(np.argmin(np.isfinite(a))), a.shape)
        raise ContractViolation(f"{ctype.kind} type '{ctype.name}': {what} is "
                                f"{float(a[i])!r} at index {i} for valid input")


def _traced(ctype: ConstraintType) -> None:
    """Trace the type's equations (and supplied terms) as mechdsl does; what cannot be traced
    is a violation with the message."""
    prefix = f"{ctype.kind} type '{ctype.name}'"
    try:
        with np.errstate(all="ignore"):
            ctype.derived
    except (EquationError, GraphError) as err:
        text = str(err)
        own = f"the {prefix}: "
        text = text[len(own):] if text.startswith(own) else text
        supplied = next((m for m in _SUPPLIED if f"{m}()" in text), None)
        raise ContractViolation(f"{prefix}: {_what_failed(supplied)}: {text}") from err
    except Exception as err:  # noqa: BLE001 - the plugin's failure is the finding
        frames = [fr.name for fr in traceback.extract_tb(err.__traceback__)]
        method = next((m for m in reversed(frames) if m in _TRACED_METHODS), "equations")
        raise ContractViolation(f"{prefix}: {_what_failed(method if method in _SUPPLIED else None)}"
                                f": {method}() raised {type(err).__name__}: {err}") from err


#: The terms a type may supply instead of having them derived
_SUPPLIED = ("jacobian_terms", "gamma_terms")


def _what_failed(supplied: str | None) -> str:
    """What a tracing failure is of: the supplied terms named, or the equations."""
    return (f"its supplied {supplied}() does not fit the contract" if supplied
            else "its equations cannot be traced")


def _supplied(ctype: ConstraintType, q, qd, p, blocks, gamma) -> None:
    """A supplied Jacobian or gamma equals the one derived from the equations, to round-off:
    atol = 1e-12 (1 + max |derived|)."""
    def close(got, want) -> bool:
        return np.allclose(got, want, rtol=0, atol=1e-12 * (1.0 + np.abs(want).max()))

    if ctype.supplies("jacobian_terms"):
        with np.errstate(all="ignore"):
            derived = ctype.derived.derived_jacobian(q, p)
        for k, (blk, want) in enumerate(zip(blocks, derived)):
            if not close(blk, want):
                _fail(ctype, f"Jacobian block {k} (attached body {k}) supplied by "
                      "jacobian_terms()", blk, want, " (against the Jacobian derived from its "
                      "equations)")
    if ctype.supplies("gamma_terms"):
        with np.errstate(all="ignore"):
            want = ctype.derived.derived_gamma(q, qd, p)
        if not close(gamma, want):
            _fail(ctype, "gamma supplied by gamma_terms()", gamma, want, " (against the gamma "
                  "derived from its equations)")


def _rotate(angle, v):
    c, s = np.cos(angle), np.sin(angle)
    return np.stack((c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]), axis=-1)


def check_constraint_type(ctype: ConstraintType, *, samples: int = 24, seed: int = 0,
                          params: Mapping[str, object] | None = None,
                          poses: Callable | None = None, rtol: float = 1e-6) -> None:
    """Raise :class:`ContractViolation` if ``ctype`` breaks its contract (see the module
    documentation for the checks); return None if it meets it."""
    problems = contract_problems(ctype)
    if problems:
        raise ContractViolation(f"type {getattr(ctype, 'name', ctype)!r} is declared wrongly: "
                                + "; ".join(problems))
    _traced(ctype)
    rng = np.random.default_rng(seed)
    S, m = len(ctype.slots), ctype.n_eq
    batch = (samples,)
    p = random_params(ctype, rng, batch, params)
    # validate() sees arrays with a leading variant axis; the test's values must pass it
    try:
        with np.errstate(all="ignore"):
            ctype.validate(p)
    except Exception as err:  # noqa: BLE001
        raise ContractViolation(
            f"{ctype.kind} type '{ctype.name}': validate() rejects the test's values "
            f"({type(err).__name__}: {err}); give valid ones with params=") from err
    if poses is not None:
        q = tuple(np.asarray(x, dtype=float) for x in poses(rng, batch))
    else:
        q = tuple(rng.uniform(-1, 1, batch + (3,)) * [1, 1, np.pi] for _ in range(S))
    qd = tuple(rng.uniform(-1, 1, batch + (3,)) for _ in range(S))
    qdd = tuple(rng.uniform(-1, 1, batch + (3,)) for _ in range(S))

    # shapes and finiteness, one batch axis
    phi = np.asarray(_call(ctype, "phi", q, p))
    _shape(ctype, "phi", phi, batch + (m,))
    _finite(ctype, "phi", phi)
    blocks = tuple(_call(ctype, "jacobian", q, p))
    if len(blocks) != S:
        raise ContractViolation(f"{ctype.kind} type '{ctype.name}': jacobian returned "
                                f"{len(blocks)} blocks for {S} attached bodies")
    for k, blk in enumerate(blocks):
        _shape(ctype, f"Jacobian block {k}", blk, batch + (m, 3))
        _finite(ctype, f"Jacobian block {k}", blk)
    gamma = np.asarray(_call(ctype, "gamma", q, qd, p))
    _shape(ctype, "gamma", gamma, batch + (m,))
    _finite(ctype, "gamma", gamma)

    # the Jacobian against central differences
    h = 1e-6
    for k, blk in enumerate(blocks):
        fd = np.empty(batch + (m, 3))
        for c in range(3):
            dq = np.zeros(3)
            dq[c] = h
            plus = tuple(x + dq if i == k else x for i, x in enumerate(q))
            minus = tuple(x - dq if i == k else x for i, x in enumerate(q))
            fd[..., c] = (ctype.phi(plus, p) - ctype.phi(minus, p)) / (2 * h)
        if not np.allclose(blk, fd, rtol=0, atol=rtol * (1.0 + np.abs(fd).max())):
            _fail(ctype, f"Jacobian block {k} (attached body {k})", blk, fd,
                  " (against central differences of phi)")

    # gamma against d2Phi/dt2 along q(t) = q + qd t + qdd t^2/2 (Richardson-extrapolated)
    def second(step: float) -> np.ndarray:
        at = lambda s: tuple(x + v * s + a * s * s / 2 for x, v, a in zip(q, qd, qdd))  # noqa
        return (ctype.phi(at(step), p) - 2 * phi + ctype.phi(at(-step), p)) / step**2

    d2 = (4 * second(5e-4) - second(1e-3)) / 3
    want = sum(np.einsum("...ij,...j->...i", b, a) for b, a in zip(blocks, qdd)) - d2
    if not np.allclose(gamma, want, rtol=0, atol=1e-5 * (1.0 + np.abs(want).max())):
        _fail(ctype, "gamma", gamma, want, " (against d2Phi/dt2 = Phi_q qdd - gamma along "
              "random trajectories)")

    # a supplied Jacobian or gamma against the derived one, to round-off
    _supplied(ctype, q, qd, p, blocks, gamma)

    # each constraint of a batch computes with its own arguments and poses
    _batch_members(ctype, q, qd, p, phi, blocks, gamma)

    # broadcasting: poses batched along one axis, arguments along another, velocities a third
    _broadcasting(ctype, q, qd, p, samples)

    # invariance of |Phi| under one rigid motion of every attached body
    if ctype.invariant:
        angle = rng.uniform(-np.pi, np.pi, batch)
        shift = rng.uniform(-2, 2, batch + (2,))
        moved = tuple(np.concatenate((_rotate(angle, x[..., :2]) + shift,
                                      (x[..., 2] + angle)[..., None]), axis=-1) for x in q)
        got = np.linalg.norm(np.asarray(ctype.phi(moved, p)), axis=-1)
        if not np.allclose(got, np.linalg.norm(phi, axis=-1), rtol=0,
                           atol=1e-9 * (1.0 + np.abs(phi).max())):
            _fail(ctype, "|phi| after a rigid motion of the whole mechanism (the type claims "
                  "invariant = True)", got, np.linalg.norm(phi, axis=-1))


def _batch_members(ctype: ConstraintType, q, qd, p, phi, blocks, gamma) -> None:
    """Row i of a batched call equals a call with sample i alone (a type that used, say, the
    first constraint's length for all would pass every other check)."""
    kinds = {a.name: a.kind for a in ctype.signature}
    n = phi.shape[0]
    for i in sorted({0, n // 2, n - 1}):
        one = slice(i, i + 1)
        qi = tuple(x[one] for x in q)
        qdi = tuple(x[one] for x in qd)
        pi = {k: (v if kinds[k] == "function" else v[one]) for k, v in p.items()}
        for what, got, want in (
                ("phi", _call(ctype, "phi", qi, pi), phi[one]),
                ("gamma", _call(ctype, "gamma", qi, qdi, pi), gamma[one]),
                *((f"Jacobian block {k}", b, blocks[k][one])
                  for k, b in enumerate(_call(ctype, "jacobian", qi, pi)))):
            if np.shape(got) != np.shape(want) or not np.allclose(got, want, rtol=1e-12,
                                                                  atol=1e-12):
                _fail(ctype, f"{what} of sample {i} computed alone (each constraint must use "
                      "its own arguments and poses)", np.broadcast_to(got, np.shape(want)),
                      want)


def _broadcasting(ctype: ConstraintType, q, qd, p, n: int) -> None:
    """Outputs carry the broadcast batch shape for two and three batch axes."""
    m = ctype.n_eq
    kinds = {a.name: a.kind for a in ctype.signature}

    def lift(x, axis: int, axes: int, core: int):
        """Put the sample axis of ``x`` at ``axis`` of ``axes`` batch axes."""
        shape = [1] * axes
        shape[axis] = n
        return np.reshape(x, tuple(shape) + np.shape(x)[np.ndim(x) - core:])

    for axes, (q_ax, p_ax, v_ax) in ((2, (1, 0, 1)), (3, (2, 0, 1))):
        q2 = tuple(lift(x, q_ax, axes, 1) for x in q)
        qd2 = tuple(lift(x, v_ax, axes, 1) for x in qd)
        p2 = {k: (v if kinds[k] == "function" else
                  lift(v, p_ax, axes, 1 if kinds[k] in ("point", "vector") else 0))
              for k, v in p.items()}
        shapes = [x.shape[:-1] for x in q2]
        shapes += [v.shape[: v.ndim - (1 if kinds[k] in ("point", "vector") else 0)]
                   for k, v in p2.items() if kinds[k] != "function"]
        want = np.broadcast_shapes(*shapes)
        with_v = np.broadcast_shapes(want, *(x.shape[:-1] for x in qd2))
        where = f" with {axes} batch axes"
        _shape(ctype, "phi" + where, _call(ctype, "phi", q2, p2, where=where), want + (m,))
        for k, blk in enumerate(_call(ctype, "jacobian", q2, p2, where=where)):
            _shape(ctype, f"Jacobian block {k}" + where, blk, want + (m, 3))
        _shape(ctype, "gamma" + where, _call(ctype, "gamma", q2, qd2, p2, where=where),
               with_v + (m,))


# -- force types ------------------------------------------------------------------------------

def _force_args(ftype, p: Mapping[str, object]):
    """The arguments as a force type's loads() receives them on arrays."""
    from .plugins.contract import Args
    from .plugins.geometry import Vec

    args = {}
    for arg in ftype.signature:
        if arg.kind == "body":
            continue
        value = p[arg.name]
        if arg.kind in ("point", "vector"):
            value = np.asarray(value)
            args[arg.name] = Vec(value[..., 0], value[..., 1])
        else:
            args[arg.name] = value
    return Args(args)


def force_loads(ftype, q: tuple[np.ndarray, ...], qd: tuple[np.ndarray, ...],
                p: Mapping[str, object], t) -> np.ndarray:
    """A force type's loads on arrays: poses and velocities ``(..., 3)`` per attached body,
    arguments as :func:`random_params` gives them, time ``t`` (broadcasting): shape
    ``(..., bodies, 3)``."""
    from .plugins.geometry import Body, Rate

    bodies = tuple(Body.of(x) for x in q)
    rates = tuple(Rate.of(x) for x in qd)
    batch = np.broadcast_shapes(*(np.shape(x)[:-1] for x in (*q, *qd)), np.shape(t))
    with np.errstate(all="ignore"):
        loads = ftype.loads(bodies, rates, _force_args(ftype, p), np.asarray(t, dtype=float))
        return np.stack([np.stack([np.broadcast_to(np.asarray(c, dtype=float), batch)
                                   for c in load], axis=-1) for load in loads], axis=-2)


def force_energy(ftype, q: tuple[np.ndarray, ...], p: Mapping[str, object]) -> np.ndarray:
    """A force type's potential energy on arrays (types that write ``energy``)."""
    from .plugins.geometry import Body

    with np.errstate(all="ignore"):
        return np.asarray(ftype.energy(tuple(Body.of(x) for x in q), _force_args(ftype, p)),
                          dtype=float)


def _force_traced(ftype) -> None:
    """Trace loads() (and energy()) as mechdsl does; what cannot be traced is a violation."""
    from .plugins.contract import Args
    from .plugins.derived import _TracedFunction, body_of
    from .plugins.geometry import Rate, Vec
    from .symbolic import Graph

    g = Graph()
    S = len(ftype.slots)
    bodies = tuple(body_of(g, 3 * k) for k in range(S))
    rates = tuple(Rate(*(g.var("qd", 3 * k + c) for c in range(3))) for k in range(S))
    args, j = {}, 0
    for a in ftype.signature:
        if a.kind == "body":
            continue
        if a.kind == "function":
            args[a.name] = _TracedFunction(g, g.function(None, None, None))
        elif a.kind in ("point", "vector"):
            args[a.name] = Vec(g.var("p", j), g.var("p", j + 1))
            j += 2
        else:
            args[a.name] = g.var("p", j)
            j += 1
    methods = [("loads", lambda: ftype.loads(bodies, rates, Args(args), g.var("t")))]
    if ftype.supplies("energy"):
        methods.append(("energy", lambda: [ftype.energy(bodies, Args(args))]))
    for name, call in methods:
        try:
            out = call()
            for item in out:
                for c in (item if name == "loads" else [item]):
                    g.lift(c)
        except (GraphError, EquationError) as err:
            raise ContractViolation(f"force type '{ftype.name}': {name}() cannot be traced: "
                                    f"{err}") from None
        except Exception as err:  # noqa: BLE001 - the plugin's failure is the finding
            raise ContractViolation(
                f"force type '{ftype.name}': {name}() raised {type(err).__name__} on traced "
                f"values: {err} (a type may not branch on, compare or convert them)") from err


def check_force_type(ftype, *, samples: int = 24, seed: int = 0,
                     params: Mapping[str, object] | None = None) -> None:
    """Check a force type (:class:`~mechdsl.plugins.force.ForceType`) against its contract
    on random poses, velocities, times and argument values; raise ContractViolation with
    the numbers where it fails:

    1. the declaration, and ``validate`` accepting the values used;
    2. loads() and energy() can be traced (no branching on values);
    3. one (F_x, F_y, n) triple per attached body, of the batch's shape, finite;
    4. each member of a batch computed from its own values (as if alone);
    5. where the type writes ``energy``: at rest (its damping gives nothing), the loads are
       -dV/dq by central differences of V in every coordinate of every attached body.

    ``params`` restricts argument values as for :func:`check_constraint_type` (a point or
    scalar as ``f(rng, shape)``, a function as expression text of its variable)."""
    from .plugins.force import ForceType, force_problems

    problems = force_problems(ftype)
    if problems:
        raise ContractViolation(f"force type '{getattr(ftype, 'name', ftype)}': "
                                + "; ".join(problems))
    assert isinstance(ftype, ForceType)
    rng = np.random.default_rng(seed)
    S = len(ftype.slots)
    p = random_params(ftype, rng, (samples,), params)
    try:
        ftype.validate(p)
    except Exception as err:  # noqa: BLE001
        raise ContractViolation(f"force type '{ftype.name}': validate() rejects the test's "
                                f"values: {err}") from err
    _force_traced(ftype)
    q = tuple(np.column_stack((rng.uniform(-1, 1, (samples, 2)), rng.uniform(-3, 3, samples)))
              for _ in range(S))
    qd = tuple(rng.uniform(-1, 1, (samples, 3)) for _ in range(S))
    t = rng.uniform(0, 2, samples)
    try:
        loads = force_loads(ftype, q, qd, p, t)
    except Exception as err:  # noqa: BLE001
        raise ContractViolation(f"force type '{ftype.name}': loads() failed on arrays: "
                                f"{type(err).__name__}: {err}") from err
    if loads.shape != (samples, S, 3):
        raise ContractViolation(f"force type '{ftype.name}': loads() gave shape "
                                f"{loads.shape[1:]} per sample, expected ({S}, 3): one "
                                "(F_x, F_y, n) triple per attached body")
    if not np.isfinite(loads).all():
        i = _index(int(np.argmin(np.isfinite(loads))), loads.shape)
        raise ContractViolation(f"force type '{ftype.name}': loads() is "
                                f"{float(loads[i])!r} at index {i} for valid input")
    for j in range(min(samples, 4)):
        one = {k: (v if isinstance(v, ExprFunction) else np.asarray(v)[j : j + 1])
               for k, v in p.items()}
        alone = force_loads(ftype, tuple(x[j : j + 1] for x in q),
                            tuple(x[j : j + 1] for x in qd), one, t[j : j + 1])
        if not np.allclose(alone[0], loads[j], rtol=1e-13, atol=1e-13):
            raise ContractViolation(f"force type '{ftype.name}': member {j} of a batch differs "
                                    "from the same values alone: loads() mixes the batch")
    if ftype.supplies("energy"):
        rest = tuple(np.zeros_like(x) for x in qd)
        at_rest = force_loads(ftype, q, rest, p, t)
        scale = max(1.0, float(np.abs(at_rest).max()))
        for k in range(S):
            for c in range(3):
                h = 1e-6
                plus = tuple(x + (h if (i == k) else 0.0) * np.eye(3)[c] for i, x in enumerate(q))
                minus = tuple(x - (h if (i == k) else 0.0) * np.eye(3)[c] for i, x in enumerate(q))
                dV = (force_energy(ftype, plus, p) - force_energy(ftype, minus, p)) / (2 * h)
                got, want = at_rest[:, k, c], -dV
                if not np.allclose(got, want, rtol=1e-6, atol=1e-6 * scale):
                    i = int(np.argmax(np.abs(got - want)))
                    raise ContractViolation(
                        f"force type '{ftype.name}': the load on body {k}, component "
                        f"{('F_x', 'F_y', 'n')[c]}, is not -dV/dq of its energy(): got "
                        f"{got[i]!r}, -dV/dq by differences {want[i]!r}")
