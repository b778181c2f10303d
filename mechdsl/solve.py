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
from dataclasses import dataclass, field

import numpy as np

from . import equations as eq
from .assembly import assemble, check_mobility
from .system import System
from .diagnose import col_scale, failure, variant_label
from .errors import MechError
from .linalg import Factor, factor
from .newton import correction_ratio, newton
from .options import SolverOptions
from .results import Results

__all__ = ["SolverOptions", "simulate", "assemble", "check_mobility"]


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
    failures: list[str] = field(default_factory=list)
    residual: float = 0.0


def _predict(st: _State, T: np.ndarray) -> np.ndarray:
    """q + tau qd + tau^2/2 qdd, falling back to lower orders where that is not finite (an
    infinite acceleration at t0, as for f = t^1.5)."""
    tau = (T - st.t[:, None])[..., None]
    q, qd, qdd = st.q[:, None], st.qd[:, None], st.qdd[:, None]
    with np.errstate(all="ignore"):
        first = q + tau * qd
        second = first + 0.5 * tau**2 * qdd
    first = np.where(np.isfinite(first), first, q)
    return np.where(np.isfinite(second), second, first)


def simulate(system: System, options: SolverOptions | None = None) -> Results:
    """Solve positions (and, where outputs need them, velocities and accelerations) at every
    instant of ``system.times``, for every variant.

    Raises MechError if the model is not fully driven. Numerical failures do not raise: the
    failing variant stops, the instants solved before are kept, and ``Results.status`` is
    ``"failed"`` with the reasons in ``Results.messages``.
    """
    opts = options or SolverOptions()
    check_mobility(system)
    times = system.times
    if times is None:
        raise MechError("the system was compiled without a time grid")
    V, n, K = system.n_variants, system.n, len(times)
    data = {o.label: np.full((V, K), np.nan) for o in system.outputs}
    start = time.perf_counter()
    asm = assemble(system, float(times[0]), opts)
    st = _State(t=np.full(V, times[0]), q=asm.q.copy(), qd=np.zeros((V, n)),
                qdd=np.zeros((V, n)), sign=np.ones(V), active=asm.ok.copy(),
                n_solved=np.zeros(V, int), failures=list(asm.messages))
    status = "ok"
    try:
        if st.active.any():
            q0, t0 = asm.q[:, None], np.full((V, 1), times[0])
            fac = factor(eq.jacobian(system, q0), col_scale(system))
            singular = st.active & ~(fac.rcond[:, 0] >= opts.singular_rcond)
            for v in np.flatnonzero(singular):
                st.failures.append(failure(system, st.q[v], float(times[0]), int(v),
                                           float(times[0]), 0, "singular"))
            st.active &= ~singular
            st.sign = fac.sign[:, 0]
            _accept(system, st, q0, t0, np.array([0]), fac, st.active.copy(), data)
            _march(system, st, opts, data)
    except KeyboardInterrupt:
        status = "interrupted"
    elapsed = time.perf_counter() - start
    if status == "ok" and st.failures:
        status = "failed"
    return Results(
        times=times, data=data, sweep=dict(system.sweep), n_solved=st.n_solved,
        status=status, messages=tuple(st.failures), solve_time=elapsed,
        residual=st.residual, source_name=system.source.name,
    )


def _accept(system: System, st: _State, q: np.ndarray, t: np.ndarray, rec: np.ndarray,
            fac: Factor, mask: np.ndarray, data: dict) -> None:
    """Take the solved positions ``q`` (V, c, n) at ``t`` (V, c), with their factorised
    Jacobians, as the new state of the variants in ``mask``; solve velocities and
    accelerations (at every column when an output needs them, else at the last column only,
    for the predictor); record the columns whose ``rec`` index is not negative."""
    order = system.order
    c = q.shape[1]
    cols = slice(None) if order >= 1 else slice(c - 1, c)
    qs, ts = q[:, cols], t[:, cols]
    inv = Factor(fac.inverse[:, cols], fac.rcond[:, cols], fac.sign[:, cols])
    with np.errstate(all="ignore"):
        qd = inv.solve(eq.velocity_rhs(system, ts, qs.shape[:-1]))
        qdd = inv.solve(eq.acceleration_rhs(system, qs, qd, ts))
        res = np.abs(eq.constraint_values(system, q, t)[mask]).max(initial=0.0)
    st.residual = max(st.residual, float(res))
    st.q[mask], st.t[mask] = q[mask, -1], t[mask, -1]
    st.qd[mask], st.qdd[mask] = qd[mask, -1], qdd[mask, -1]
    st.sign[mask] = fac.sign[mask, -1]
    keep = rec >= 0
    if not keep.any():
        return
    k = rec[keep]
    full_qd = qd if order >= 1 else None
    full_qdd = qdd if order >= 2 else None
    for spec in system.outputs:
        values = eq.output_values(system, spec, q, full_qd, full_qdd)
        data[spec.label][np.ix_(mask, k)] = values[mask][:, keep]
    st.n_solved[mask] = k[-1] + 1


def _march(system: System, st: _State, opts: SolverOptions, data: dict) -> None:
    times = system.times
    V, n, K = system.n_variants, system.n, len(times)
    D = col_scale(system)
    cap = max(1, opts.max_batch_elements // max(1, V * system.m * n))
    b = max(1, min(opts.initial_block, cap))
    k = 1  # the next instant to record
    sub: list[float] = []  # pending intermediate times before times[k], ascending
    floor = np.sqrt(opts.newton_tol)
    while k < K and st.active.any():
        if sub:
            targets, rec = np.array(sub[:1]), np.array([-1])
        else:
            bb = min(b, K - k, cap)
            targets, rec = times[k : k + bb], np.arange(k, k + bb)
        bb = len(targets)
        act = st.active[:, None]
        T = np.where(act, targets[None, :], st.t[:, None])
        undefined = _undefined_drives(system, T) & act
        pred = _predict(st, T)
        qn, ok, iters = newton(system, pred, T, D, st.active, opts)
        fac = factor(eq.jacobian(system, qn), D)
        ratio = correction_ratio(qn, pred, st.q[:, None], D, floor)
        singular = ok & ~(fac.rcond >= opts.singular_rcond)
        before = np.concatenate((st.sign[:, None], fac.sign[:, :-1]), axis=1)
        crossing = ok & ~singular & (fac.sign != before)
        jump = ok & ~singular & ~crossing & ~(ratio <= opts.branch_ratio)
        good = (ok & ~singular & ~crossing & ~jump & ~undefined) | ~act
        col_ok = good.all(axis=0)
        nacc = bb if col_ok.all() else int(np.argmin(col_ok))
        if nacc:
            _accept(system, st, qn[:, :nacc], T[:, :nacc], rec[:nacc], _cols(fac, nacc),
                    st.active.copy(), data)
            if sub:
                sub.pop(0)
            else:
                k += nacc
        if nacc == bb:
            if iters <= 3 and not sub:
                b = min(2 * b, opts.max_block, cap)
            elif iters >= 6:
                b = max(1, b // 2)
            continue
        if bb > 1:
            b = max(1, min(nacc, bb // 2))
            continue
        # a single step fails: bisect the interval, then decide
        t_act = float(st.t[st.active][0])
        target = float(targets[0])
        gap = target - t_act
        if gap > (times[k] - times[k - 1]) / 2**opts.max_bisections and not undefined.any():
            sub.insert(0, t_act + 0.5 * gap)
            b = 1
            continue
        # at the finest interval a large correction with a continuous position is a kink in
        # a drive's velocity, not a branch jump
        jump &= ~_continuous(system, st, qn[:, 0], T[:, 0], fac, D, gap, floor)
        good = (ok & ~singular & ~crossing & ~jump & ~undefined) | ~act
        bad = st.active & ~good[:, 0]
        for v in np.flatnonzero(bad):
            if undefined[v, 0]:
                st.failures.append(_undefined_message(system, int(v), target, k))
                continue
            why = ("singular" if singular[v, 0] else "crossing" if crossing[v, 0]
                   else "jump" if jump[v, 0] else "diverged")
            st.failures.append(failure(system, st.q[v], float(st.t[v]), int(v), target, k, why))
        st.active &= ~bad
        if st.active.any():
            _accept(system, st, qn, T, rec, fac, st.active.copy(), data)
            if sub:
                sub.pop(0)
            else:
                k += 1


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
    return (f"the function of {names} is not defined at t = {target:.10g} (instant {k} of "
            f"{len(system.times) - 1}){variant_label(system, v)}: outside its table's range, "
            "or a domain error such as sqrt of a negative number")


def _cols(fac: Factor, c: int) -> Factor:
    return Factor(fac.inverse[:, :c], fac.rcond[:, :c], fac.sign[:, :c])


def _continuous(system: System, st: _State, q: np.ndarray, t: np.ndarray, fac: Factor,
                D: np.ndarray, gap: float, floor: float) -> np.ndarray:
    """(V, 1): whether the step from the state to ``q`` (V, n) over ``gap`` is no larger than
    the velocities at both ends allow (twice their mean times the gap)."""
    with np.errstate(all="ignore"):
        qd = fac.solve(eq.velocity_rhs(system, t[:, None], (len(q), 1)))[:, 0]
        speed = (np.abs(st.qd / D[:, 0]) + np.abs(qd / D[:, 0])).max(axis=-1)
        moved = np.abs((q - st.q) / D[:, 0]).max(axis=-1)
    return (moved <= speed * gap + floor * 1e-3)[:, None]
