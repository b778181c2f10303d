"""Many instants settled at once: Newton, the final factorisation, the condition estimate and
the rates of a batch of states in one pass over entry-major arrays.

The levels and the last batch of the parallel-in-time march (:meth:`mechdsl.solve.run.
KinematicRun.parallel`) correct states predicted by interpolation, factorise Phi_q at the
converged positions, estimate their condition and solve their rates. Done step by step
(:func:`mechdsl.solve.newton.newton`, :func:`mechdsl.solve.linalg.factor`, the run's
``accept``) each step converts between the states' layout (variants, instants, coordinates)
and the generated code's entry-major one (coordinates, instants, variants), and each solve
passes over the factors on its own. :func:`settle` keeps everything entry-major and:

* iterates Newton with Phi_q's own factors (the generated LU), whose last ones are the final
  ones wherever the last step was at round-off (``settled_step``) or the state did not move;
  where some state's last step was larger, the batch is factorised once more at the
  converged positions;
* takes the condition number of the scaled A = R Phi_q D (R the reciprocal row norms of
  Phi_q D, D the column scale) without forming A: its solves are Phi_q's, with the scalings
  applied to the right-hand sides and the solutions;
* solves Hager's and Higham's vectors of the condition estimate (as
  :meth:`mechdsl.compiled.lu.LUPlan.inverse_norm1`) and nu together, then e_j and gamma
  together: two multi-right-hand-side passes over the factors where separate solves took
  five.

It applies to the member layout with a generated LU (a small mechanism, square) and a batch
large enough for the generated LU; elsewhere, or where a pivot of the fixed order became
small, it returns None and the caller takes the step-by-step path, which handles every case.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from ..compiled.sparse import LU_BATCH
from .linalg import Factor, GeneratedLU
from .options import SolverOptions


@dataclass(frozen=True)
class Settled:
    """States of a (V, b) batch: positions ``q`` (V, b, n), whether each ``converged``, the
    factorisation ``fac`` of Phi_q there (rcond, sign, and the generated LU for solves),
    and, where asked for, the rates ``qd``, ``qdd`` and the correction ratio."""

    q: np.ndarray
    converged: np.ndarray
    fac: Factor
    qd: np.ndarray | None
    qdd: np.ndarray | None
    #: max |Phi| of each state at its final position (V, b)
    residual: np.ndarray
    #: Newton's correction against the motion (:func:`mechdsl.solve.newton.
    #: correction_ratio`), (V, b), where ``before`` was given
    ratio: np.ndarray | None = None


def applies(kernels: Kernels, states: int) -> bool:
    """Whether :func:`settle` takes a batch of ``states`` states of ``kernels``."""
    system = kernels.system
    f = kernels.fused
    return (kernels.lu is not None and f is not None and f.layout == "member"
            and system.m == system.n and states >= LU_BATCH)


def _sums(values: np.ndarray, index: np.ndarray, size: int,
          weights: np.ndarray | None = None, by: np.ndarray | None = None) -> np.ndarray:
    """(size, ...): the sum of the entries ``values`` (nnz, ...) of each row (or column)
    ``index`` (nnz,), each entry k times ``weights[by[k]]`` where given: one operation of
    whole batch arrays per entry (a matrix product over a batch of this shape costs more on
    a few hundred entries)."""
    out = np.zeros((size,) + values.shape[1:])
    if weights is None:
        for k, i in enumerate(index.tolist()):
            out[i] += values[k]
    else:
        for k, (i, w) in enumerate(zip(index.tolist(), by.tolist())):
            out[i] += values[k] * weights[w]
    return out


def _absmax0(x: np.ndarray) -> np.ndarray:
    """max |x| over the first (coordinate) axis of an entry-major array: contiguous rows."""
    return np.maximum.reduce(np.abs(x), axis=0)


def settle(kernels: Kernels, pred: np.ndarray, T: np.ndarray, D: np.ndarray,
           active: np.ndarray, opts: SolverOptions, rates: bool,
           before: np.ndarray | None = None, floor: float | None = None,
           drive_values: tuple[np.ndarray, ...] | None = None) -> Settled | None:
    """Solve Phi(q, T) = 0 from ``pred`` (V, b, n) at times ``T`` (V, b) for the ``active``
    variants (V,), factorise Phi_q at the solutions, estimate the condition, and (with
    ``rates``) solve Phi_q qd = nu and Phi_q qdd = gamma; see the module documentation.
    Convergence as :func:`mechdsl.solve.newton.newton` (the scaled step max |dq / D| at most
    ``newton_tol``, or the error left, |dq_k|^3 / |dq_(k-1)|^2, at most ``newton_error``;
    abandoned where the step stops contracting). With ``before`` (V, n), the state before
    the batch's first instant, each state's correction ratio against the motion from the
    state before it (:func:`mechdsl.solve.newton.correction_ratio` with ``floor``) is
    measured too, on the entry-major arrays (``floor`` required with it: a state that did
    not move would make 0 / 0). ``drive_values``: the drives' f, f', f'' at ``T``
    (V, b, drives each) where the caller has them. None where it does not apply."""
    system = kernels.system
    V, b, n = pred.shape
    if before is not None and not (floor or 0) > 0:
        raise ValueError("settle: the correction ratio needs a positive floor")
    if not applies(kernels, V * b):
        return None
    plan, fused, p = kernels.lu, kernels.fused, system.pattern
    m = system.m
    P, Fn = fused.params, fused.functions
    X = np.array(pred.T, dtype=float)  # (n, b, V), contiguous
    X0 = X.copy() if before is not None else None
    Dt = np.ascontiguousarray(np.broadcast_to(D, (V, 1, n)).T)  # (n, 1, V)
    dcols = Dt[p.cols]
    inv_d = 1.0 / Dt
    drive_rows = system.drive_rows
    which = ("f", "fd", "fdd") if rates else ("f",)
    if not kernels.drive_functions:
        drives = None
    elif drive_values is not None:
        drives = [v.T for v in drive_values[: len(which)]]
    else:
        drives = [np.asarray(eq.drive_values(kernels, T, w, (V, b))).T for w in which]
    done = np.zeros((b, V), bool)
    done |= ~active[None, :]
    failed = np.zeros((b, V), bool)
    prev = np.full((b, V), np.inf)
    moved = np.zeros((b, V), bool)
    step = np.zeros((b, V))
    with np.errstate(all="ignore"):
        for it in range(1, opts.max_iterations + 1):
            # (the last iteration's arrays let go before this one's are made: every page the
            # process touches anew costs a fault, a quarter of a microsecond each)
            E = F = dq = None
            E = fused.phi_jac(X.T, None, None, P, Fn).T  # (m + nnz, b, V)
            if drives is not None:
                for i, row in enumerate(drive_rows):
                    E[row] -= drives[0][i]
            F, fixed = plan.raw_factor_fn(E[m:])
            if not fixed.all():
                return None  # a pivot of the fixed order became small: the general path
            dq = plan.raw_solve_fn(F, -E[:m])  # Phi_q dq = -Phi
            step = _absmax0(dq * inv_d)  # max |dq / D|
            solved = np.isfinite(step)
            left = np.where((step < 0.25 * prev) & (prev < np.inf),
                            step * step * step / (prev * prev), np.inf)
            failed |= ~solved & ~done
            live = ~done & ~failed
            moved = live
            if live.all():
                X += dq
            else:
                np.copyto(X, X + dq, where=live[None])
            converged = live & ((step <= opts.newton_tol) | (left <= opts.newton_error))
            done |= converged
            if it >= 3:
                failed |= live & ~converged & (step > 0.5 * prev)
            prev = np.where(live, step, prev)
            if (done | failed).all():
                break
        ok = done & ~failed
        # the last factors were taken at the positions before the last step: the final ones
        # where that step was at round-off (and where a state did not move); else once more
        # at the converged positions (every state: one pass of the kernels)
        vals = E[m:]
        if not (step[moved & ok] <= opts.settled_step).all():
            E = F = vals = dq = None
            E = fused.phi_jac(X.T, None, None, P, Fn).T
            F, fixed = plan.raw_factor_fn(E[m:])
            if not fixed.all():
                return None
            vals = E[m:]
            phi = E[:m]
        else:
            phi = np.asarray(fused.phi(X.T, None, None, P, Fn)).T
        # the residual |Phi| at the final positions, as the run records it
        if drives is not None:
            phi = phi.copy()
            for i, row in enumerate(drive_rows):
                phi[row] -= drives[0][i]
        residual = _absmax0(phi)
        # the condition number is that of the scaled A = R Phi_q D (R the reciprocal row
        # norms of Phi_q D), never formed: A^-1 y = D^-1 Phi_q^-1 R^-1 y and
        # A^-T c = R^-1 Phi_q^-T D^-1 c, with Phi_q's own factors
        a = vals * dcols
        np.abs(a, out=a)
        E = vals = phi = dq = None  # (the peak of the memory a batch takes: see above)
        norms = np.sqrt(_sums(a * a, p.rows, m))
        finite = np.isfinite(norms).all(axis=0)
        inv_r = np.where(norms > 0, norms, 1.0)  # R^-1 (an empty row: 1)
        norm_a = np.maximum.reduce(_sums(a, p.cols, n, 1.0 / inv_r, p.rows), axis=0)
        a = None
        # Hager's and Higham's vectors of the estimate (as LUPlan.inverse_norm1) and nu, one
        # pass over the factors
        cols = 3 if rates else 2
        Y = np.empty((n, cols, b, V))
        Y[:, 0] = inv_r / n
        i = np.arange(n)
        Y[:, 1] = ((-1.0) ** i * (1 + i / max(n - 1, 1)))[:, None, None] * inv_r
        if rates:
            Y[:, 2] = 0.0
            if drives is not None:
                Y[drive_rows, 2] = drives[1]
        S = plan.raw_solve_fn(F[:, None], Y)
        Y = None
        x0 = S[:, 0] / Dt
        est = np.maximum(np.abs(x0).sum(axis=0), 2 * np.abs(S[:, 1] / Dt).sum(axis=0) / (3 * n))
        qd = S[:, 2].copy() if rates else None
        S = None
        rhs = []
        if rates:
            gamma = np.asarray(fused.gamma(X.T, qd.T, None, P, Fn)).T  # fresh: added to in place
            if drives is not None:
                for k, row in enumerate(drive_rows):
                    gamma[row] += drives[2][k]
            rhs.append(gamma)
        z = plan.raw_solve_t_fn(F, np.where(x0 >= 0, 1.0, -1.0) / Dt) * inv_r
        az = np.abs(z)
        top = np.maximum.reduce(az, axis=0)
        better = top > z.sum(axis=0) / n  # Hager's test: e_j may give more
        if better.any():
            # e_j at the largest |z_j| (a tie shares the unit among the tied entries: still a
            # vector of 1-norm one, so the estimate stays a lower bound)
            e = (az == top).astype(float)
            e /= e.sum(axis=0)
            e *= inv_r
            rhs.append(e)
        z = az = e = gamma = x0 = None
        qdd = None
        if rhs:
            S2 = plan.raw_solve_fn(F[:, None], np.stack(rhs, axis=1))
            rhs = None
            if rates:
                qdd = S2[:, 0].copy()
            if better.any():
                est = np.where(better, np.maximum(est, np.abs(S2[:, -1] / Dt).sum(axis=0)), est)
            S2 = None
        rcond = 1.0 / (norm_a * est)
        rcond = np.where(np.isfinite(rcond) & finite, rcond, 0.0)
        sign = np.where(rcond > 0, plan.parity * np.prod(np.sign(F[plan.pivots]), axis=0), 0.0)
        ratio = None
        if X0 is not None:
            # as correction_ratio: |q - pred| / max(|q - base|, |pred - base|, floor), scaled
            # by D, the base of each instant the state before it
            B = np.empty_like(X)
            B[:, 0] = before.T
            B[:, 1:] = X[:, :-1]
            # (``moved`` rebound on purpose: a new name here measured 0.3 ms slower on the
            # seed's 1000 states, 3.4 against 3.0 ms, in alternating runs)
            moved = np.maximum(_absmax0((X - B) * inv_d), _absmax0((X0 - B) * inv_d))
            ratio = (_absmax0((X - X0) * inv_d) / np.maximum(moved, floor)).T
    one = np.ones(1)
    fac = Factor(None, rcond.T, sign.T, gen=GeneratedLU(plan, F, np.broadcast_to(one, (V, b, m)),
                                                         np.broadcast_to(one, (V, b, n))))
    return Settled(X.T, ok.T, fac, None if qd is None else qd.T, None if qdd is None else qdd.T,
                   residual.T, ratio)
