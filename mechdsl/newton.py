"""Newton-Raphson for a batch of states, shared by the assembly and the time march."""

from __future__ import annotations

import numpy as np

from . import equations as eq
from .system import System
from .linalg import solve
from .options import SolverOptions


def newton(system: System, q: np.ndarray, t: np.ndarray, D: np.ndarray, active: np.ndarray,
           opts: SolverOptions, rows: np.ndarray, shift: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray, int]:
    """Solve the equations ``rows`` of Phi(q, t) + shift = 0 by Newton-Raphson,
    Phi_q dq = -(Phi + shift), from ``q`` (V, b, n) at times ``t`` (V, b), for the ``active``
    variants (V,). ``rows`` are as many independent equations as coordinates.

    Converged where the scaled step max |dq / D| falls to ``opts.newton_tol``; abandoned
    where the step stops contracting (Newton from a good start contracts quadratically), so
    that the caller can shorten its step at once. Returns the iterates, a (V, b) mask of the
    converged ones and the number of iterations used.
    """
    q = q.copy()
    done = np.zeros(q.shape[:-1], bool) | ~active[:, None]
    failed = np.zeros_like(done)
    prev = np.full(done.shape, np.inf)
    it = 0
    for it in range(1, opts.max_iterations + 1):
        with np.errstate(all="ignore"):
            phi = eq.constraint_values(system, q, t)
            if shift is not None:
                phi = phi + shift
        dq, solved = solve(eq.jacobian(system, q)[..., rows, :], -phi[..., rows])
        with np.errstate(invalid="ignore"):
            step = np.abs(dq / D).max(axis=-1)
        failed |= ~solved & ~done
        live = ~done & ~failed
        q += np.where(live[..., None], np.nan_to_num(dq), 0.0)
        converged = live & (step <= opts.newton_tol)
        done |= converged
        if it >= 3:
            failed |= live & ~converged & (step > 0.5 * prev)
        prev = np.where(live, step, prev)
        if (done | failed).all():
            break
    return q, done & active[:, None], it


def correction_ratio(q: np.ndarray, pred: np.ndarray, base: np.ndarray, D: np.ndarray,
                     floor: float) -> np.ndarray:
    """|q - pred| / max(|q - base|, |pred - base|, floor), scaled by D: Newton's correction
    to a predictor against the motion from the ``base`` state. Of the order of the step
    squared on a smooth path; of order one where the solution jumped to another branch."""
    with np.errstate(invalid="ignore", divide="ignore"):
        moved = np.maximum(np.abs((q - base) / D).max(axis=-1),
                           np.abs((pred - base) / D).max(axis=-1))
        return np.abs((q - pred) / D).max(axis=-1) / np.maximum(moved, floor)
