"""Newton-Raphson for a batch of states, shared by the assembly and the time march."""

from __future__ import annotations

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from ..compiled.system import System
from .linalg import Factor, solve
from .options import SolverOptions
from .rowwise import absmax, allfinite


def use_sparse(system: System, opts: SolverOptions, rows: np.ndarray) -> bool:
    """Whether the equations ``rows`` are solved with the sparse factorisation."""
    return (system.pattern is not None and system.n >= opts.sparse_from
            and len(rows) == system.m == system.n)


def newton(kernels: Kernels, q: np.ndarray, t: np.ndarray, D: np.ndarray, active: np.ndarray,
           opts: SolverOptions, rows: np.ndarray, shift: np.ndarray | None = None,
           reuse: Factor | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Solve the equations ``rows`` of Phi(q, t) + shift = 0 by Newton-Raphson,
    Phi_q dq = -(Phi + shift), from ``q`` (V, b, n) at times ``t`` (V, b), for the ``active``
    variants (V,). ``rows`` are as many independent equations as coordinates.

    Converged where the scaled step max |dq / D| falls to ``opts.newton_tol``, or where the
    error left after it, estimated from the last two steps, is below ``opts.newton_error``;
    abandoned where the step stops contracting (Newton from a good start contracts
    quadratically), so that the caller can shorten its step at once. Returns the iterates, a
    (V, b) mask of the converged ones and the number of iterations used.

    ``reuse`` (sparse systems): the factorised Jacobian of the last solved state, (V, 1), used
    for simplified Newton, Phi_q(q_last) dq = -Phi, while it contracts by ``reuse_ratio`` or
    better; the error left is then estimated from the linear rate theta = |dq_k|/|dq_(k-1)|
    as theta |dq_k| / (1 - theta). A large mechanism saves one sparse LU per iteration.
    """
    system = kernels.system
    sparse = use_sparse(system, opts, rows)
    q = q.copy()
    done = np.zeros(q.shape[:-1], bool) | ~active[:, None]
    failed = np.zeros_like(done)
    prev = np.full(done.shape, np.inf)
    it = 0
    b = q.shape[1]
    # the drives' f(t): the same at every iteration
    f_all = (eq.drive_values(kernels, t, "f", q.shape[:-1]) if kernels.drive_functions
             else None)
    for it in range(1, opts.max_iterations + 1):
        # instants that converged (in every variant) drop out of the next iterations
        cols = np.flatnonzero((~done & ~failed).any(axis=0))
        part = cols.size < b
        qc = q[:, cols] if part else q
        tc = t[:, cols] if part and np.shape(t)[1] == b else t
        fc = f_all[:, cols] if part and f_all is not None else f_all
        stale = reuse is not None and sparse
        with np.errstate(all="ignore"):
            if stale:
                phi = eq.constraint_values(kernels, qc, tc, fc)
            else:
                phi, jac = eq.residual_and_jacobian(kernels, qc, tc, rows, sparse, fc)
            if shift is not None:
                phi = phi + (shift[:, cols] if part and shift.shape[1] == b else shift)
        rhs = -phi if len(rows) == system.m else -phi[..., rows]
        if stale:
            dqc = _solve_stale(reuse, rhs)
            solvedc = allfinite(dqc)
        else:
            dqc, solvedc = solve(jac, rhs)
        if part:
            dq = np.zeros(q.shape)
            dq[:, cols] = dqc
            solved = np.ones(done.shape, bool)
            solved[:, cols] = solvedc
        else:
            dq, solved = dqc, solvedc
        with np.errstate(invalid="ignore"):
            step = absmax(dq / D)
        failed |= ~solved & ~done
        live = ~done & ~failed
        q += np.where(live[..., None], dq, 0.0)  # a live state's step is finite (solved)
        # Newton contracts quadratically, e_{k+1} ~ C e_k^2 with C ~ |dq_k| / |dq_{k-1}|^2:
        # the error left after this step is about |dq_k|^3 / |dq_{k-1}|^2, so the step that
        # would only confirm convergence is saved (Deuflhard 2004, sec. 2.1)
        with np.errstate(all="ignore"):
            left = np.where((step < 0.25 * prev) & (prev < np.inf),
                            step * step * step / (prev * prev), np.inf)
            if stale:
                theta = step / prev
                left = np.where((theta < opts.reuse_ratio) & (prev < np.inf),
                                theta * step / (1 - theta), np.inf)
                if it >= 2 and not (theta[~done & ~failed] < opts.reuse_ratio).all():
                    reuse = None  # too slow: fresh Jacobians from here on
        if stale:
            # a reused Jacobian converges linearly: the error after a small step is about
            # theta |dq|, not |dq|^2, so a step below the tolerance is finished by fresh
            # Jacobians (quadratic again) rather than taken as convergence
            converged = live & (left <= opts.newton_error)
            if (live & ~converged & (step <= opts.newton_tol)).any():
                reuse = None
        else:
            converged = live & ((step <= opts.newton_tol) | (left <= opts.newton_error))
        done |= converged
        if it >= 3 and not stale:
            failed |= live & ~converged & (step > 0.5 * prev)
        prev = np.where(live, step, prev)
        if (done | failed).all():
            break
    return q, done & active[:, None], it


def _solve_stale(fac: Factor, rhs: np.ndarray) -> np.ndarray:
    """Solve with the factorisation (V, 1) of the last state for right-hand sides (V, b, m)."""
    b = rhs.shape[1]
    cols = Factor(None, np.repeat(fac.rcond, b, axis=1), np.repeat(fac.sign, b, axis=1),
                  np.repeat(fac.lus, b, axis=1))
    with np.errstate(all="ignore"):
        return cols.solve(rhs)


def correction_ratio(q: np.ndarray, pred: np.ndarray, base: np.ndarray, D: np.ndarray,
                     floor: float) -> np.ndarray:
    """|q - pred| / max(|q - base|, |pred - base|, floor), scaled by D: Newton's correction
    to a predictor against the motion from the ``base`` state. Of the order of the step
    squared on a smooth path; of order one where the solution jumped to another branch."""
    with np.errstate(invalid="ignore", divide="ignore"):
        moved = np.maximum(absmax((q - base) / D), absmax((pred - base) / D))
        return absmax((q - pred) / D) / np.maximum(moved, floor)
