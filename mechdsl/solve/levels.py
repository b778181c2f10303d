"""The levels of the parallel-in-time march: many instants solved as one batched problem.

Positions at different instants are independent root-finding problems, Phi(q_j, t_j) = 0;
only the starting guesses and the branch checks need the neighbours. The march
(:meth:`mechdsl.solve.run.KinematicRun.parallel`) solves a coarse grid first, then levels
that split every gap, each level's instants started from the quintic Hermite interpolation
of the states already solved (q, qd, qdd at both ends of a gap: error O(gap^6)) and
corrected all at once.

:func:`polish` is the batched Newton of a level, lean on purpose: one evaluation of Phi and
the Jacobian's entries per iteration (:mod:`mechdsl.compiled.fused`), the model's generated
LU (:mod:`mechdsl.compiled.lu`) for a large batch, and one convergence test over the whole
batch, so that a Newton step costs a few dozen numpy calls whatever the number of instants.
"""

from __future__ import annotations

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from .linalg import solve
from .options import SolverOptions
from .rowwise import absmax
from .single import UNDECIDED, OneState, coarse_march_one


def polish(kernels: Kernels, q: np.ndarray, t: np.ndarray, D: np.ndarray,
           opts: SolverOptions, rows: np.ndarray, active: np.ndarray | None = None,
           tol: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Newton-Raphson on Phi(q, t) = 0 for a batch of states ``q`` (V, b, n) at ``t``
    (V, b), all iterated together until every state's scaled step max|dq / D| is at most
    ``tol`` (``opts.newton_tol`` by default) or its error left, estimated from the quadratic
    contraction |dq_k|^3 / |dq_(k-1)|^2, at most ``opts.newton_error``. Returns the states and a (V, b)
    mask of the converged ones (a state whose step stopped contracting is not). Variants
    not ``active`` (V,) are left as they are, and count as converged."""
    system = kernels.system
    q = np.array(q, dtype=float)
    tol = opts.newton_tol if tol is None else tol
    f = (eq.drive_values(kernels, t, "f", q.shape[:-1]) if kernels.drive_functions else None)
    prev = np.full(q.shape[:-1], np.inf)
    done = np.zeros(q.shape[:-1], bool)
    if active is not None:
        done |= ~active[:, None]
    with np.errstate(all="ignore"):  # once for the loop: each entry costs a few us
        for it in range(1, opts.max_iterations + 1):
            phi, vals = kernels.fused.evaluate_phi_jac(q)
            if f is not None:
                phi = phi.copy()
                phi[..., system.drive_rows] -= f
            jac = eq.jacobian_for(kernels, vals, rows)
            dq, solved = solve(jac, -phi if len(rows) == system.m else -phi[..., rows])
            step = absmax(dq / D)
            left = np.where((step < 0.25 * prev) & (prev < np.inf),
                            step * step * step / (prev * prev), np.inf)
            live = ~done & solved
            # a live state's step is finite (solved); where() keeps the others' NaN out
            q += np.where(live[..., None], dq, 0.0)
            done |= live & ((step <= tol) | (left <= opts.newton_error))
            if done.all():
                break
            if it >= 3 and not (step[~done] <= 0.5 * prev[~done]).all():
                break  # not contracting somewhere: the caller falls back to the careful march
            prev = np.where(live, step, prev)
    return q, done


def coarse_march(kernels: Kernels, start: tuple[np.ndarray, ...], sign: np.ndarray,
                 times: np.ndarray, gap: int, D: np.ndarray, opts: SolverOptions,
                 rows: np.ndarray, min_gap: int, active: np.ndarray
                 ) -> tuple[np.ndarray, tuple[np.ndarray, ...], bool] | None:
    """March from the state ``start`` = (t (V,), q, qd, qdd (V, n)) at ``times[0]`` to
    ``times[-1]`` over every ``gap``-th instant, adapting the gap to the motion: each step
    is predicted by the Taylor polynomial q + tau qd + tau^2/2 qdd + tau^3/6 qddd (qddd from
    the last two accelerations) and corrected by :func:`polish` to
    ``opts.coarse_newton_tol``. A step whose correction is large against the motion (over
    ``branch_ratio``) or whose det(Phi_q) changed sign is halved, down to ``min_gap``
    instants (past that the march gives up and returns None: the careful march then takes
    over and reports what happened); a step whose correction is small (under a tenth of
    ``branch_ratio``) doubles the next gap. Returns the indices into ``times`` reached,
    the states there (q, qd, qdd (V, c, n)) and whether they are settled (solved to the
    full tolerance and checked as a level checks its states: a single mechanism, marched
    on floats by :func:`mechdsl.solve.single.coarse_march_one`); the variants not
    ``active`` stay where they are."""
    from .newton import correction_ratio

    system = kernels.system
    if kernels.one_state is not None and active[0]:
        # a single mechanism: one state per step, on floats (numpy's per-call overhead
        # would be nearly all of its cost)
        one = OneState(kernels, kernels.one_state, D[0, 0], opts)
        out = coarse_march_one(one, (start[0][0], *(a[0] for a in start[1:])), sign[0],
                               times, gap, opts, min_gap)
        if out is not UNDECIDED:
            return None if out is None else (*out, True)
    loose = max(opts.newton_tol, opts.coarse_newton_tol)
    t, q, qd, qdd = (np.array(a, dtype=float) for a in start)
    V = len(q)
    live = np.flatnonzero(active)[0]
    still = ~active[:, None]
    floor = np.sqrt(opts.newton_tol)
    out: list[tuple[np.ndarray, ...]] = []
    reached: list[int] = []
    jerk = np.zeros_like(q)  # d3q/dt3, estimated from the last two nodes' accelerations
    at, last = 0, len(times) - 1
    while at < last:
        j = min(at + gap, last)
        target = times[j]
        tau = target - t[live]
        T = np.where(still, t[:, None], target)
        with np.errstate(all="ignore"):
            taylor = q + tau * (qd + tau / 2 * (qdd + tau / 3 * jerk))
            pred = np.where(still[..., None], q[:, None], taylor[:, None])
        qn, ok = polish(kernels, pred, T, D, opts, rows, active, tol=loose)
        # no condition estimate here (every instant gets one when it is settled): the sign of
        # det(Phi_q) and the rates, by LAPACK on the small dense Jacobian
        jac = eq.jacobian(kernels, qn)
        if len(rows) != system.m:
            jac = jac[..., rows, :]
        with np.errstate(all="ignore"):
            det_sign = np.linalg.slogdet(np.nan_to_num(jac))[0]
        ratio = correction_ratio(qn, pred, q[:, None], D, floor)
        good = (ok & (det_sign == sign[:, None]) & (ratio <= opts.branch_ratio)) | still
        if not good.all():
            if (j - at) // 2 < min_gap:
                return None
            gap = (j - at) // 2
            continue
        qd_new, _ = solve(jac, eq.velocity_rhs(kernels, T, (V, 1))[..., rows])
        qdd_new, _ = solve(jac, eq.acceleration_rhs(kernels, qn, qd_new, T)[..., rows])
        if not (np.isfinite(qd_new[active]).all() and np.isfinite(qdd_new[active]).all()):
            return None
        with np.errstate(all="ignore"):
            jerk = (qdd_new[:, 0] - qdd) / tau
            jerk = np.where(np.isfinite(jerk), jerk, 0.0)
        q, qd, qdd = qn[:, 0], qd_new[:, 0], qdd_new[:, 0]
        t = np.where(active, target, t)
        out.append((qn, qd_new, qdd_new))
        reached.append(j)
        at = j
        if (ratio[active] < 0.1 * opts.branch_ratio).all():
            gap *= 2
    if not out:
        return None
    return (np.array(reached, np.intp),
            tuple(np.concatenate([o[i] for o in out], axis=1) for i in range(3)), False)
