"""The kinematic solver: assembly at t0, then Newton-Raphson at every instant, with velocities
and accelerations from the same factorised Jacobian (Haug 1989, ch. 4).

Position: Newton-Raphson on Phi(q, t) = 0, Phi_q dq = -Phi, started from the Taylor predictor
q + tau qd + tau^2/2 qdd of the last solved instant. Velocity: Phi_q qd = nu. Acceleration:
Phi_q qdd = gamma. The Jacobian used for qd and qdd is the one at the converged q.

Speed comes from batching: several instants (a *block*) and every sweep variant are solved as
one batched array problem. The block grows while Newton converges in few iterations and
shrinks when it does not. When even one instant fails, the interval before it is bisected
(intermediate states are solved but not recorded) before the failure is declared, so a coarse
output step does not cause a failure on its own.

No silent branch switching. A solved state is refused when

* its Jacobian is singular (reciprocal condition below ``singular_rcond``): a dead point,
  change point or lock-up, where velocities are undetermined;
* det(Phi_q) has changed sign since the previous state: the path crossed a singular position;
* Newton's correction to the predictor is large against the motion since the last state
  (ratio above ``branch_ratio``) and, once the interval is bisected to its finest, the
  position is still discontinuous: a jump to another assembly branch. (A drive whose
  velocity jumps passes this test: its positions stay continuous.)

Refused states are bisected towards, then reported with the instant and the joints involved.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from . import equations as eq
from .assembly import assemble
from .system import ExprOutput, System
from .diagnose import (
    col_scale, constraint_names, failure, instant_text, jacobian_defects, nonfinite_message,
    variant_label,
)
from .mobility import count_check, redundancy_warning
from .errors import MechError
from .linalg import Factor, factor
from .memory import plan
from .newton import correction_ratio, newton, use_sparse
from .singular import singular_step
from .hermite import quintic_hermite
from .levels import coarse_march, polish
from .compiled import native
from .compiled.lu import THRESHOLD
from .options import SolverOptions
from .results import Results

__all__ = ["SolverOptions", "simulate", "assemble"]


@dataclass
class _State:
    """The last solved state of each variant (the solver's only mutable data)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    sign: np.ndarray
    active: np.ndarray
    n_solved: np.ndarray
    rows: np.ndarray
    watched: np.ndarray
    watch_weights: np.ndarray
    min_rcond: np.ndarray
    min_rcond_t: np.ndarray
    failures: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    passages: list[float] = field(default_factory=list)
    residual: float = 0.0
    #: The last state whose Jacobian was well conditioned (rcond >= warn_rcond): time,
    #: velocity, acceleration; near a singular position, predictions start from it.
    good: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    #: Sparse systems: the factorised Jacobian of the last state, for simplified Newton.
    fac: Factor | None = None
    #: (V, K, n): every recorded instant's coordinates, when drawings or exports need them;
    #: (V, K, 2, n) their velocities and accelerations, when exports need them.
    poses: np.ndarray | None = None
    rates: np.ndarray | None = None
    #: Instants per block of the march, grown while Newton converges fast.
    block: int = 8
    #: Named outputs already warned about for values that are not finite.
    undefined_outputs: set[str] = field(default_factory=set)


def _predict(st: _State, T: np.ndarray, order: int = 2) -> np.ndarray:
    """q + tau qd + tau^2/2 qdd (to ``order``), falling back to lower orders where that is
    not finite (an infinite acceleration at t0, as for f = t^1.5)."""
    tau = (T - st.t[:, None])[..., None]
    q, qd, qdd = st.q[:, None], st.qd[:, None], st.qdd[:, None]
    with np.errstate(all="ignore"):
        first = q + tau * qd
        second = first + 0.5 * tau**2 * qdd if order >= 2 else first
    first = np.where(np.isfinite(first), first, q)
    return np.where(np.isfinite(second), second, first)


def simulate(system: System, options: SolverOptions | None = None, *,
             poses: bool = False, rates: bool = False,
             progress: Callable[[int, int], None] | None = None,
             extra_memory: int = 0) -> Results:
    """Solve positions (and, where outputs need them, velocities and accelerations) at every
    instant of ``system.times``, for every variant; with ``poses``, also keep every body's
    (x, y, phi) at every instant (``Results.poses``), for drawings and exports, and with
    ``rates`` their first and second time derivatives too (``Results.rates``). ``progress``
    is called as progress(instants_done, instants) as the run goes on. A run whose memory,
    with ``extra_memory`` bytes that the caller will add for its outputs, would exceed
    ``options.max_memory`` is refused before it starts (:func:`mechdsl.memory.plan`).

    Raises MechError if the model is not fully driven. Numerical failures do not raise: the
    failing variant stops, the instants solved before are kept, and ``Results.status`` is
    ``"failed"`` with the reasons in ``Results.messages``. Neither does a plugin that raises
    (status ``"error"``, ``Results.error`` the located error) nor an interrupt (status
    ``"interrupted"``): the instants solved before are kept.
    """
    opts = (options or SolverOptions()).for_size(system.n_bodies)
    times = system.times
    if times is None:
        raise MechError("the system was compiled without a time grid")
    V, n, K = system.n_variants, system.n, len(times)
    count_check(system)  # before anything the size of the model is allocated
    sparse = use_sparse(system, opts, np.arange(system.m))
    compiled = _wants_native(system, opts)
    try:
        budget = plan(system, opts.max_memory, opts.max_batch_elements, sparse=sparse,
                      poses=poses or rates, rates=rates, extra=extra_memory, compiled=compiled)
    except MechError:
        if not compiled or opts.backend != "auto":
            raise
        compiled = False  # "auto": the numpy path fits where numba would not
        budget = plan(system, opts.max_memory, opts.max_batch_elements, sparse=sparse,
                      poses=poses or rates, rates=rates, extra=extra_memory)
    if not compiled:
        opts = replace(opts, backend="numpy")
    opts = replace(opts, max_batch_elements=budget.batch_elements)
    start = time.perf_counter()
    data = {o.label: np.full((V, K), np.nan) for o in system.outputs}
    try:
        asm = assemble(system, float(times[0]), opts)
    except (KeyboardInterrupt, eq.PluginError) as err:
        return _nothing_solved(system, data, err, time.perf_counter() - start)
    mob = asm.mobility
    rows = mob.rows if mob is not None else np.arange(system.m)
    redundant = mob is not None and mob.dropped.size > 0
    watched = rows if redundant else np.zeros(0, np.intp)
    weights = mob.dropped_weights if redundant else np.zeros(0)
    st = _State(t=np.full(V, times[0]), q=asm.q.copy(), qd=np.zeros((V, n)),
                qdd=np.zeros((V, n)), sign=np.ones(V), active=asm.ok.copy(),
                n_solved=np.zeros(V, int), rows=rows, watched=watched,
                watch_weights=weights, min_rcond=np.ones(V),
                min_rcond_t=np.full(V, times[0]), failures=list(asm.messages),
                block=opts.initial_block,
                poses=np.full((V, K, n), np.nan) if poses or rates else None,
                rates=np.full((V, K, 2, n), np.nan) if rates else None)
    if asm.mobility is not None:
        note = redundancy_warning(system, asm.mobility)
        if note:
            st.warnings.append(note)
    status, error = "ok", None
    try:
        if st.active.any():
            q0, t0 = asm.q[:, None], np.full((V, 1), times[0])
            fac = factor(eq.solver_jacobian(system, q0, rows, use_sparse(system, opts, rows)),
                         col_scale(system))
            singular = st.active & ~(fac.rcond[:, 0] >= opts.singular_rcond)
            for v in np.flatnonzero(singular):
                st.failures.append(failure(system, st.q[v], float(times[0]), int(v),
                                           float(times[0]), 0, "singular"))
            st.active &= ~singular
            st.sign = fac.sign[:, 0]
            _accept(system, st, q0, t0, np.array([0]), fac, st.active.copy(), data, opts)
            _run(system, st, opts, data, progress)
    except KeyboardInterrupt:
        status = "interrupted"
    except eq.PluginError as err:  # a defect of a plugin: keep what was solved before it
        status, error = "error", err
        st.failures.insert(0, err.message)
    elapsed = time.perf_counter() - start
    if status == "ok" and st.failures:
        status = "failed"
    if st.passages:
        st.warnings.append(_passages(st.passages, times))
    for v in np.flatnonzero(st.min_rcond < opts.warn_rcond):
        st.warnings.append(
            f"near a singular position{variant_label(system, int(v))}: the Jacobian's "
            f"condition number reaches {1 / st.min_rcond[v]:.3g} at t = {st.min_rcond_t[v]:.10g}"
            "; results there are sensitive to the data")
    return Results(
        times=times, data=data, sweep=dict(system.sweep), n_solved=st.n_solved,
        status=status, messages=tuple(st.failures), solve_time=elapsed,
        residual=st.residual, source_name=system.source.name,
        warnings=tuple(st.warnings), condition=1.0 / st.min_rcond,
        poses=None if st.poses is None else st.poses.reshape(V, K, -1, 3),
        rates=None if st.rates is None else st.rates.reshape(V, K, 2, -1, 3),
        units={o.label: o.unit for o in system.outputs if o.unit}, time_unit=system.time_unit,
        error=error,
    )


def _nothing_solved(system: System, data: dict, err: BaseException, elapsed: float
                    ) -> Results:
    """The results of a run stopped before its first instant: by an interrupt or a plugin."""
    error = err if isinstance(err, eq.PluginError) else None
    return Results(
        times=system.times, data=data, sweep=dict(system.sweep),
        n_solved=np.zeros(system.n_variants, int),
        status="interrupted" if error is None else "error",
        messages=(error.message,) if error else (), solve_time=elapsed, residual=0.0,
        source_name=system.source.name, error=error,
        units={o.label: o.unit for o in system.outputs if o.unit}, time_unit=system.time_unit)


def _accept(system: System, st: _State, q: np.ndarray, t: np.ndarray, rec: np.ndarray,
            fac: Factor, mask: np.ndarray, data: dict, opts: SolverOptions,
            rates: tuple[np.ndarray, np.ndarray] | None = None,
            residual_known: bool = False) -> None:
    """Take the solved positions ``q`` (V, c, n) at ``t`` (V, c), with their factorised
    Jacobians, as the new state of the variants in ``mask``; solve velocities and
    accelerations (at every column when an output needs them, else at the last column only,
    for the predictor), unless ``rates`` gives them; record the columns whose ``rec`` index is
    not negative. Redundant equations left out of the solve must still hold."""
    order = 2 if st.rates is not None else system.order
    rows = st.rows
    c = q.shape[1]
    if rates is not None:
        qd, qdd = rates
    else:
        cols = slice(None) if order >= 1 else slice(c - 1, c)
        qs, ts = q[:, cols], t[:, cols]
        inv = fac.columns(cols)
        with np.errstate(all="ignore"):
            qd = inv.solve(eq.velocity_rhs(system, ts, qs.shape[:-1])[..., rows])
            qdd = inv.solve(eq.acceleration_rhs(system, qs, qd, ts)[..., rows])
    if opts.nonfinite == "stop":
        need = 2 if st.rates is not None else system.order
        bad = _nonfinite(q, qd, qdd, need) & mask[:, None]
        if bad.any():
            _split_at_nonfinite(system, st, q, t, rec, fac, mask, data, opts, (qd, qdd), bad)
            return
    if not residual_known:  # (the compiled march measures it as it goes)
        with np.errstate(all="ignore"):
            phi = eq.constraint_values(system, q, t)
        st.residual = max(st.residual, float(np.abs(phi[mask]).max(initial=0.0)))
        _watch_redundant(system, st, phi, t, mask, opts)
    worst = np.argmin(fac.rcond, axis=1)
    lowest = fac.rcond[np.arange(len(worst)), worst]
    lower = mask & (lowest < st.min_rcond)
    st.min_rcond[lower] = lowest[lower]
    st.min_rcond_t[lower] = t[lower, worst[lower]]
    st.q[mask], st.t[mask] = q[mask, -1], t[mask, -1]
    st.qd[mask], st.qdd[mask] = qd[mask, -1], qdd[mask, -1]
    st.sign[mask] = fac.sign[mask, -1]
    # per variant: the variants that stopped are skipped by Newton, whatever their entry
    if fac.lus is not None and mask.any() and (fac.rcond[mask, -1] > 0).all():
        st.fac = fac.columns(slice(c - 1, c))
    regular = mask & (fac.rcond[:, -1] >= opts.warn_rcond) & (qd.shape[1] == c)
    if st.good is None:
        st.good = (st.t.copy(), st.qd.copy(), st.qdd.copy())
    gt, gqd, gqdd = st.good
    gt[regular], gqd[regular], gqdd[regular] = t[regular, -1], qd[regular, -1], qdd[regular, -1]
    keep = rec >= 0
    if not keep.any():
        return
    k = rec[keep]
    if st.poses is not None:
        st.poses[np.ix_(mask, k)] = q[mask][:, keep]
    if st.rates is not None:
        st.rates[np.ix_(mask, k, [0])] = qd[mask][:, keep][:, :, None]
        st.rates[np.ix_(mask, k, [1])] = qdd[mask][:, keep][:, :, None]
    full_qd = qd if order >= 1 else None
    full_qdd = qdd if order >= 2 else None
    for spec in system.outputs:
        values = eq.output_values(system, spec, q, full_qd, full_qdd, t)
        data[spec.label][np.ix_(mask, k)] = values[mask][:, keep]
        if isinstance(spec, ExprOutput) and spec.label not in st.undefined_outputs:
            _watch_named(system, st, spec.label, values[:, keep], t[:, keep], mask)
    st.n_solved[mask] = k[-1] + 1


def _watch_named(system: System, st: _State, label: str, values: np.ndarray,
                 t: np.ndarray, mask: np.ndarray) -> None:
    """Warn, once per named output, where its expression is not a finite number (the rate
    of a distance between coinciding points, log of a negative number): a result the
    user defined, written as it is, but never silently."""
    bad = ~np.isfinite(values) & mask[:, None]
    if bad.any():
        v, j = np.argwhere(bad)[0]
        st.undefined_outputs.add(label)
        st.warnings.append(f"output {label} is {float(values[v, j])!r} from t = "
                           f"{t[v, j]:.10g}{variant_label(system, int(v))} on: its expression "
                           "is not defined there (such as the rate of the distance between "
                           "two points that coincide); those values are written as they are")


def _nonfinite(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, need: int) -> np.ndarray:
    """(V, c): the columns of a block whose position, or the rates the outputs need (``need``
    is their highest time derivative), are not all finite. Rates solved at the last column
    only (for the predictor) are not results and are not checked."""
    c = q.shape[1]
    bad = ~np.isfinite(q).all(axis=-1)
    for order, a in ((1, qd), (2, qdd)):
        if need >= order and a.shape[1] == c:
            bad |= ~np.isfinite(a).all(axis=-1)
    return bad


def _split_at_nonfinite(system: System, st: _State, q: np.ndarray, t: np.ndarray,
                        rec: np.ndarray, fac: Factor, mask: np.ndarray, data: dict,
                        opts: SolverOptions, rates: tuple[np.ndarray, np.ndarray],
                        bad: np.ndarray) -> None:
    """Accept the columns before the first one with a non-finite result, stop the variants
    that have one there (a numerical failure naming the quantity and the instant), and go on
    with the others from that column."""
    c = q.shape[1]
    j = int(np.argmax(bad.any(axis=0)))
    full = rates[0].shape[1] == c

    def part(cols: slice) -> tuple[np.ndarray, np.ndarray] | None:
        return (rates[0][:, cols], rates[1][:, cols]) if full else None

    if j:
        _accept(system, st, q[:, :j], t[:, :j], rec[:j], fac.columns(slice(0, j)), mask, data,
                opts, part(slice(0, j)))
    qd, qdd = rates if full else (np.full(q.shape, np.nan), np.full(q.shape, np.nan))
    for v in np.flatnonzero(bad[:, j] & mask):
        st.failures.append(nonfinite_message(system, int(v), q[v, j], qd[v, j], qdd[v, j],
                                             float(t[v, j]), int(rec[j])))
        st.active[v] = False
        mask[v] = False
    if mask.any():
        _accept(system, st, q[:, j:], t[:, j:], rec[j:], fac.columns(slice(j, c)), mask, data,
                opts, part(slice(j, c)))


def _watch_redundant(system: System, st: _State, phi: np.ndarray, t: np.ndarray,
                     mask: np.ndarray, opts: SolverOptions) -> None:
    """Stop the variants of a redundant model whose equations no longer all hold: least
    squares converges to a compromise where redundant constraints are inconsistent."""
    if not st.watched.size:
        return
    resid = np.abs(phi[..., st.watched]) * st.watch_weights
    bad = mask & ~(resid <= opts.assembly_residual).all(axis=(1, 2))
    for v in np.flatnonzero(bad):
        col = int(np.argmax((resid[v] > opts.assembly_residual).any(axis=-1)))
        worst = st.watched[np.argsort(-resid[v, col])[:3]]
        st.failures.append(
            f"the redundant constraints no longer hold together at t = {t[v, col]:.10g}"
            f"{variant_label(system, int(v))}: equations of {constraint_names(system, worst)} "
            f"are violated (scaled residual {resid[v, col].max():.3g}); the constraints are "
            "inconsistent, over-constraining the mechanism as it moves")
        st.active[v] = False
        mask[v] = False


def _run(system: System, st: _State, opts: SolverOptions, data: dict,
         progress: Callable[[int, int], None] | None) -> None:
    """March from the state at instant 0 to the last instant, window by window.

    Each window is first tried parallel in time (:func:`_parallel`); what that does not settle
    is marched instant by instant (:func:`_march`), which reports any failure exactly."""
    K = len(system.times)
    stride = opts.coarse_stride
    parallel = stride > 1 and not use_sparse(system, opts, st.rows)
    k = 1
    march = _native(system, st, opts)
    if march is not None:
        k = _compiled(system, st, opts, data, march, progress)
    while k < K and st.active.any():
        end = min(K, k + max(opts.window, 2 * stride))
        if parallel and end - k >= 2 * stride:
            try:
                k = _parallel(system, st, opts, data, k, end)
            except eq.PluginError:  # the march below finds the instant it fails at
                k = max(k, int(st.n_solved.max()))
            if progress is not None:
                progress(k, K)
        if k < end and st.active.any():
            _march(system, st, opts, data, progress, np.arange(k, end))
        k = end


def _parallel(system: System, st: _State, opts: SolverOptions, data: dict, k: int,
               end: int) -> int:
    """Solve the instants k .. end-1 in levels, parallel in time; return the first instant
    not solved.

    1. Coarse: march every ``coarse_stride``-th instant (and end-1) from a copy of the state
       with a loose Newton tolerance; then correct those states all at once to the full
       tolerance (:func:`mechdsl.levels.polish`) and solve their velocities and
       accelerations: the first nodes.
    2. Levels: split every gap between nodes by ``level_split``; the new instants, predicted
       by the quintic Hermite interpolation of the nodes (:mod:`mechdsl.hermite`), are
       corrected all at once and become nodes, until the gaps are at most
       ``level_split`` instants.
    3. Settle: every instant of the window, predicted from the nodes, is solved by batched
       Newton, factorised, checked against its predecessor and recorded.

    At every level each state is checked as the march checks it: converged, regular
    (condition above ``singular_rcond``), det(Phi_q) of the same sign as at the start of the
    window (no singular position crossed), and Newton's correction small against the motion
    from the node before (``branch_ratio``: no jump to another branch). Any failure stops
    here, and the ordinary march takes the window over: it finds and reports the failure at
    its exact instant. The number of sequential batched steps grows like log(instants).
    """
    times = system.times
    act = st.active[:, None]
    first = int(np.flatnonzero(st.active)[0])
    D, rows = col_scale(system), st.rows
    if len(rows) != system.n:
        return k  # not as many independent equations as coordinates: the careful march
    floor = np.sqrt(opts.newton_tol)
    split = opts.level_split
    coarse = coarse_march(system, (st.t, st.q, st.qd, st.qdd), st.sign, times[k - 1 : end],
                          opts.coarse_stride, D, opts, rows, min_gap=split, active=st.active)
    if coarse is None:
        return k
    # the coarse states, corrected to the full tolerance: the first nodes
    idx, (qc, _, _) = coarse[0] + k - 1, coarse[1]
    Tc = np.where(act, times[idx][None, :], st.t[:, None])
    start = (st.t[:, None], st.q[:, None], st.qd[:, None], st.qdd[:, None])
    level = _level(system, st, opts, qc, Tc, qc, D, rows, floor, None)
    if level is None:
        return k
    node = np.concatenate(([k - 1], idx))
    tn, qn, qdn, qddn = (np.concatenate((a, b), axis=1) for a, b in zip(start, level))
    while (np.diff(node) > split).any():
        # split every gap longer than level_split into level_split parts, or into as few
        # as leave none longer (sets, not np.unique: that imports numpy.ma, 10 ms of every
        # start-up)
        have = set(node.tolist())
        pairs = zip(node[:-1].tolist(), node[1:].tolist())
        new = np.array(sorted({a + (i * (b - a)) // parts for a, b in pairs if b - a > split
                               for parts in (min(split, -(-(b - a) // split)),)
                               for i in range(1, parts)} - have), np.intp)
        T = np.where(act, times[new][None, :], st.t[:, None])
        with np.errstate(all="ignore"):
            pred = quintic_hermite(tn[first], qn, qdn, qddn, times[new])
        left = np.searchsorted(node, new) - 1
        level = _level(system, st, opts, pred, T, qn[:, left], D, rows, floor, "left")
        if level is None:
            return k
        order = np.argsort(np.concatenate((node, new)), kind="stable")
        node = np.concatenate((node, new))[order]
        tn, qn, qdn, qddn = (np.concatenate((a, b), axis=1)[:, order]
                             for a, b in zip((tn, qn, qdn, qddn), level))
    tn = tn[first]
    cap = _batch_cap(system, opts)
    for j0 in range(k, end, cap):
        idx = np.arange(j0, min(j0 + cap, end))
        T = np.where(act, times[idx][None, :], st.t[:, None])
        if (_undefined_drives(system, T) & act).any():
            return j0
        with np.errstate(all="ignore"):
            pred = quintic_hermite(tn, qn, qdn, qddn, times[idx])
        q, ok, _ = newton(system, pred, T, D, st.active, opts, rows)
        fac = factor(eq.solver_jacobian(system, q, rows, False), D)
        previous = np.concatenate((st.q[:, None], q[:, :-1]), axis=1)
        ratio = correction_ratio(q, pred, previous, D, floor)
        good = (ok & (fac.rcond >= opts.singular_rcond) & (fac.sign == _signs_before(st, fac))
                & (ratio <= opts.branch_ratio)) | ~act
        nacc = _good_prefix(good)
        if nacc:
            _accept(system, st, q[:, :nacc], T[:, :nacc], idx[:nacc],
                    fac.columns(slice(0, nacc)), st.active.copy(), data, opts)
        if nacc < len(idx) or not st.active.any():
            return j0 + nacc
    return end


def _wants_native(system: System, opts: SolverOptions) -> bool:
    """Whether the options ask for the compiled backend for this run: "compiled", or "auto"
    for a run of at least ``compiled_from`` states with numba installed (a square system;
    whether the model compiles is known only when it is loaded)."""
    if opts.backend == "numpy" or system.m != system.n or system.times is None:
        return False
    return opts.backend == "compiled" or (
        system.n_variants * len(system.times) >= opts.compiled_from and native.available())


def _native(system: System, st: _State, opts: SolverOptions):
    """The compiled march of the model, where the options ask for it and it applies (a
    square system without redundant equations, the member layout, no function arguments,
    numba installed); else None."""
    if not _wants_native(system, opts) or len(st.rows) != system.n:
        return None
    return system.native


def _compiled(system: System, st: _State, opts: SolverOptions, data: dict, march,
              progress: Callable[[int, int], None] | None) -> int:
    """The instants by the compiled march (:mod:`mechdsl.compiled.native`), a chunk of
    ``native.chunk_instants`` at a time from the last state (so that progress is shown and
    an interrupt is taken between chunks); each chunk's instants up to the first where some
    variant stops are accepted (with their rates, condition numbers and signs), and the
    numpy march goes on from there. Returns the first instant not solved."""
    times = system.times
    K, V, n = len(times), system.n_variants, system.n
    live = np.flatnonzero(st.active)
    params = system.fused.params
    P = (np.stack([np.broadcast_to(p, (V, 1))[:, 0] for p in params]) if params
         else np.zeros((0, V)))
    c = np.ascontiguousarray
    P, D = c(P[:, live]), c(col_scale(system)[live, 0])
    step = native.chunk_instants(len(live))
    k = 1
    while k < K:
        end = min(K, k + step)
        T = np.broadcast_to(times[k - 1 : end], (V, end - k + 1))
        if (_undefined_drives(system, T) & st.active[:, None]).any():
            return k
        fd = np.zeros((len(live), end - k + 1, 3, len(system.drive_rows)))
        for i, which in enumerate(("f", "fd", "fdd")):
            if system.drive_functions:
                fd[:, :, i] = eq.drive_values(system, T, which, T.shape)[live]
        L, C = len(live), end - k + 1
        out = ([np.full((L, C, n), np.nan) for _ in range(3)]
               + [np.ones((L, C)), np.zeros((L, C))])
        status, residual = np.zeros(L, np.int64), np.zeros(L)
        march(c(st.q[live]), c(st.qd[live]), c(st.qdd[live]), c(st.sign[live], dtype=float),
              c(times[k - 1 : end]), fd, P, D, opts.newton_tol, opts.newton_error,
              opts.max_iterations, THRESHOLD, opts.branch_ratio, opts.singular_rcond, *out,
              status, residual)
        if L == V:  # the usual case: no copies of the results
            Q, QD, QDD, RC, SG = out
        else:
            Q, QD, QDD = (np.full((V, C, n), np.nan) for _ in range(3))
            RC, SG = np.ones((V, C)), np.zeros((V, C))
            for full, part in zip((Q, QD, QDD, RC, SG), out):
                full[live] = part
        reached = int(status.min())  # the first column of the chunk not solved
        if reached > 1:
            cols = slice(1, reached)
            st.residual = max(st.residual, float(residual.max(initial=0.0)))
            _accept(system, st, Q[:, cols], T[:, cols], np.arange(k, k + reached - 1),
                    Factor(None, RC[:, cols], SG[:, cols]), st.active.copy(), data, opts,
                    (QD[:, cols], QDD[:, cols]), residual_known=True)
        k += reached - 1
        if progress is not None:
            progress(k, K)
        if reached < C:
            break
    return k


def _level(system: System, st: _State, opts: SolverOptions, pred: np.ndarray, T: np.ndarray,
           base: np.ndarray, D: np.ndarray, rows: np.ndarray, floor: float,
           measure: str | None) -> tuple[np.ndarray, ...] | None:
    """Correct the predicted states ``pred`` (V, c, n) at ``T`` (V, c) all at once and
    solve their rates: the new nodes (t, q, qd, qdd), or None if a state fails a check.
    With ``measure`` = "left", Newton's correction is measured against the motion from
    ``base``, the node before each state; without, ``base`` is the loosely solved state of
    the coarse march itself, already checked."""
    act = st.active[:, None]
    if (_undefined_drives(system, T) & act).any():
        return None
    q, ok = polish(system, pred, T, D, opts, rows, st.active)
    fac = factor(eq.solver_jacobian(system, q, rows, False), D)
    ratio = (correction_ratio(q, pred, base, D, floor) if measure == "left"
             else np.zeros(q.shape[:-1]))
    good = (ok & (fac.rcond >= opts.singular_rcond) & (fac.sign == st.sign[:, None])
            & (ratio <= opts.branch_ratio)) | ~act
    if not good.all():
        return None
    with np.errstate(all="ignore"):
        qd = fac.solve(eq.velocity_rhs(system, T, q.shape[:-1])[..., rows])
        qdd = fac.solve(eq.acceleration_rhs(system, q, qd, T)[..., rows])
    return T, q, qd, qdd


def _batch_cap(system: System, opts: SolverOptions) -> int:
    """Instants solved together at most: V * b * m * n within ``max_batch_elements``."""
    per_instant = system.n_variants * system.m * system.n
    return max(1, opts.max_batch_elements // max(1, per_instant))


def _signs_before(st: _State, fac: Factor) -> np.ndarray:
    """(V, b): the sign of det Phi_q at the state before each column of a block."""
    return np.concatenate((st.sign[:, None], fac.sign[:, :-1]), axis=1)


def _good_prefix(good: np.ndarray) -> int:
    """How many leading columns of a block (V, b) are good in every variant."""
    col_ok = good.all(axis=0)
    return len(col_ok) if col_ok.all() else int(np.argmin(col_ok))


def _recorded(instant: np.ndarray, rec: np.ndarray) -> np.ndarray:
    """The instants (indices into system.times) that the march's positions ``rec`` record;
    -1 for substeps."""
    return np.where(rec >= 0, instant[np.maximum(rec, 0)], -1)


def _march(system: System, st: _State, opts: SolverOptions, data: dict,
           progress: Callable[[int, int], None] | None, grid: np.ndarray) -> None:
    """Solve the instants ``grid`` (indices into ``system.times``, increasing, after the
    state's time) one block after another, each block predicted from the last state, and
    record them."""
    # position 0 is the state's own time; position j >= 1 is instant grid[j - 1]
    times = np.concatenate(([float(st.t[st.active][0])], system.times[grid]))
    instant = np.concatenate(([-1], np.asarray(grid)))
    K, K_all = len(times), len(system.times)
    D = col_scale(system)
    rows = st.rows
    stop_at_singular = opts.at_singular == "stop"
    sparse = use_sparse(system, opts, rows)
    cap = _batch_cap(system, opts)
    b = max(1, min(st.block, cap))
    k = 1  # the next position of ``times`` to solve
    # between output instants that cannot be reached in one step the interval is crossed in
    # substeps of adaptive size hsub (halved on failure, doubled on success)
    hsub: float | None = None
    attempts = 0
    floor = np.sqrt(opts.newton_tol)
    while k < K and st.active.any():
        if progress is not None:
            progress(int(instant[k]), K_all)
        t_now = float(st.t[st.active][0])  # the active variants move in lockstep
        h_out = times[k] - times[k - 1]
        if hsub is None:
            bb = min(b, K - k, cap)
            targets, rec = times[k : k + bb], np.arange(k, k + bb)
        elif t_now + hsub < times[k] - 1e-9 * h_out:
            targets, rec = np.array([t_now + hsub]), np.array([-1])
        else:
            targets, rec = times[k : k + 1], np.array([k])
        bb = len(targets)
        act = st.active[:, None]
        T = np.where(act, targets[None, :], st.t[:, None])
        undefined = _undefined_drives(system, T) & act
        pred = _predict(st, T, opts.predictor_order)
        try:
            qn, ok, iters = newton(system, pred, T, D, st.active, opts, rows,
                                   reuse=st.fac if sparse else None)
            fac = factor(eq.solver_jacobian(system, qn, rows, sparse), D)
        except eq.PluginError:
            if bb == 1:
                raise
            b = 1  # a plugin failing in a block: find the instant it fails at, one by one
            continue
        ratio = correction_ratio(qn, pred, st.q[:, None], D, floor)
        singular = ok & ~(fac.rcond >= opts.singular_rcond)
        crossing = ok & ~singular & (fac.sign != _signs_before(st, fac)) & stop_at_singular
        jump = ok & ~singular & ~crossing & ~(ratio <= opts.branch_ratio)
        good = (ok & ~singular & ~crossing & ~jump & ~undefined) | ~act
        nacc = _good_prefix(good)
        if hsub is not None:
            attempts += 1
        if nacc:
            try:
                _accept(system, st, qn[:, :nacc], T[:, :nacc],
                        _recorded(instant, rec[:nacc]), fac.columns(slice(0, nacc)),
                        st.active.copy(), data, opts)
            except eq.PluginError:
                if nacc == 1:
                    raise
                b = 1
                continue
            if hsub is None:
                k += nacc
            elif rec[0] >= 0:
                hsub, attempts, k = None, 0, k + 1
            else:
                hsub = 2 * hsub
        if nacc == bb:
            if hsub is None:  # the block grows while Newton converges fast
                if iters <= 3:
                    b = min(2 * b, opts.max_block, cap)
                elif iters >= 6:
                    b = max(1, b // 2)
                st.block = b
            continue
        if bb > 1:
            b = max(1, min(nacc, bb // 2))
            continue
        # a single step fails: shorten it, then decide
        target = float(targets[0])
        gap = target - t_now
        if attempts > opts.max_substeps:
            for v in np.flatnonzero(st.active):
                defects = (jacobian_defects(system, pred[v, 0], target, int(v))
                           or jacobian_defects(system, st.q[v], float(st.t[v]), int(v)))
                st.failures.append(
                    f"Newton-Raphson does not converge after t = {t_now:.10g}: {defects}"
                    if defects else _too_coarse(system, int(v), t_now, int(instant[k]),
                                                opts.max_substeps))
            st.active[:] = False
            break
        if gap > h_out / 2**opts.max_bisections and not undefined.any():
            hsub = gap / 2
            b = 1
            continue
        # at the finest interval a large correction with a continuous position is a kink in
        # a drive's velocity, not a branch jump
        jump &= ~_continuous(system, st, qn[:, 0], T[:, 0], fac, D, gap, floor, rows)
        good = (ok & ~singular & ~crossing & ~jump & ~undefined) | ~act
        rates = None
        if not stop_at_singular and (st.active & ~good[:, 0]).any():
            qn, rates, passed = _through(system, st, pred, T, D, rows, opts)
            good |= passed[:, None] & ~undefined
        bad = st.active & ~good[:, 0]
        for v in np.flatnonzero(bad):
            if undefined[v, 0]:
                st.failures.append(_undefined_message(system, int(v), target, int(instant[k])))
                continue
            why = ("singular" if singular[v, 0] else "crossing" if crossing[v, 0]
                   else "jump" if jump[v, 0] else "diverged")
            st.failures.append(failure(system, st.q[v], float(st.t[v]), int(v), target,
                                       int(instant[k]), why, pred[v, 0]))
        st.active &= ~bad
        if st.active.any():
            fac = factor(eq.solver_jacobian(system, qn, rows, sparse), D)
            _accept(system, st, qn, T, _recorded(instant, rec), fac, st.active.copy(),
                    data, opts, rates)
            if rec[0] >= 0:
                hsub, attempts, k = None, 0, k + 1
            else:
                hsub = gap


def _too_coarse(system: System, v: int, t_now: float, k: int, budget: int) -> str:
    return (f"the time step is too coarse for the motion: going on from t = {t_now:.10g} to "
            f"the next instant t = {system.times[k]:.10g} ({instant_text(system, k)})"
            f"{variant_label(system, v)} took more than {budget} "
            "substeps (the mechanism moves far, or to and fro, between instants); take a "
            "smaller step")


def _through(system: System, st: _State, pred: np.ndarray, T: np.ndarray, D: np.ndarray,
             rows: np.ndarray, opts: SolverOptions):
    """One instant on a singular position, for the option at_singular = "continue"."""
    gt, gqd, gqdd = st.good
    tau = (T[:, 0] - gt)[:, None]
    q, qd, qdd, ok = singular_step(system, pred, T, gqd + tau * gqdd, gqdd, D, rows, opts)
    ratio = correction_ratio(q, pred, st.q[:, None], D, np.sqrt(opts.newton_tol))[:, 0]
    passed = ok & (ratio <= opts.branch_ratio) & st.active
    if passed.any():
        st.passages.append(float(T[passed][0, 0]))
    return q, (qd, qdd), passed


def _passages(times_passed: list[float], grid: np.ndarray) -> str:
    """One warning for the singular positions passed, one time per output step."""
    h = float(np.min(np.diff(grid))) if len(grid) > 1 else 1.0
    marks: list[float] = []
    for t in sorted(times_passed):
        # name the output instant the passage belongs to, not an internal substep
        t = float(grid[min(np.searchsorted(grid, t), len(grid) - 1)])
        if not marks or t - marks[-1] > h / 2:
            marks.append(t)
    shown = ", ".join(f"{t:.6g}" for t in marks)
    return (f"the mechanism passes singular positions near t = {shown} and continues on the "
            "branch it was moving on; velocities and accelerations exactly there are completed "
            "from their predicted values (accurate to about one step)")


def _undefined_drives(system: System, T: np.ndarray) -> np.ndarray:
    """(V, b): where some drive's function, or its derivatives, is not a finite number."""
    if not system.drive_functions:
        return np.zeros(T.shape, bool)
    ok = np.ones(T.shape, bool)
    for which in ("f", "fd", "fdd"):
        ok &= np.isfinite(eq.drive_values(system, T, which, T.shape)).all(axis=-1)
    return ~ok


def _undefined_message(system: System, v: int, target: float, k: int) -> str:
    values = eq.drive_values(system, np.full((system.n_variants, 1), target), "f",
                             (system.n_variants, 1))[v, 0]
    drives = [c for c in system.constraints if c.kind == "drive"]
    bad = [drives[i] for i in np.flatnonzero(~np.isfinite(values))] or drives
    names = ", ".join(f"drive {c.name} (line {c.span.line})" for c in bad)
    return (f"the function of {names} is not defined at t = {target:.10g} "
            f"({instant_text(system, k)}){variant_label(system, v)}: outside its table's range, "
            "or a domain error such as sqrt of a negative number")


def _continuous(system: System, st: _State, q: np.ndarray, t: np.ndarray, fac: Factor,
                D: np.ndarray, gap: float, floor: float, rows: np.ndarray) -> np.ndarray:
    """(V, 1): whether the step from the state to ``q`` (V, n) over ``gap`` is no larger than
    the velocities at both ends allow (twice their mean times the gap)."""
    with np.errstate(all="ignore"):
        qd = fac.solve(eq.velocity_rhs(system, t[:, None], (len(q), 1))[..., rows])[:, 0]
        speed = (np.abs(st.qd / D[:, 0]) + np.abs(qd / D[:, 0])).max(axis=-1)
        moved = np.abs((q - st.q) / D[:, 0]).max(axis=-1)
    return (moved <= speed * gap + floor * 1e-3)[:, None]
