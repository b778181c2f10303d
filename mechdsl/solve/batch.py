"""Many instants settled at once: Newton, the final factorisation, the condition estimate and
the rates of a batch of states in one pass over entry-major arrays.

The levels and the last batch of the parallel-in-time march (:meth:`mechdsl.solve.run.
KinematicRun.parallel`) correct states predicted by interpolation, factorise Phi_q at the
converged positions, estimate their condition and solve their rates. Done step by step
(:func:`mechdsl.solve.newton.newton`, :func:`mechdsl.solve.linalg.factor`, the run's
``accept``) each step converts between the states' layout (variants, instants, coordinates)
and the generated code's entry-major one (coordinates, instants, variants), and each solve
passes over the factors on its own. :func:`settle` keeps everything entry-major and:

* iterates Newton with the plain factorisation of Phi_q while the steps are large, then with
  the *scaled* one A = R Phi_q D (R the reciprocal row norms of Phi_q D, D the column
  scale), so that the factors of the last iteration are the final ones wherever its step
  was at round-off (``settled_step``) or the state did not move;
  where some state's last step was larger, the batch is factorised once more at the
  converged positions;
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
from ..compiled.sparse import LU_BATCH
from ..compiled.system import System
from .linalg import Factor, GeneratedLU
from .options import SolverOptions


@dataclass(frozen=True)
class Settled:
    """States of a (V, b) batch: positions ``q`` (V, b, n), whether each ``converged``, the
    factorisation ``fac`` of Phi_q there (rcond, sign, and the generated LU for solves), and,
    where asked for, the rates ``qd``, ``qdd``."""

    q: np.ndarray
    converged: np.ndarray
    fac: Factor
    qd: np.ndarray | None
    qdd: np.ndarray | None
    #: Newton iterations taken
    iterations: int = 0


def applies(system: System, states: int) -> bool:
    """Whether :func:`settle` takes a batch of ``states`` states of ``system``."""
    f = system.fused
    return (system.lu is not None and f is not None and f.layout == "member"
            and system.m == system.n and states >= LU_BATCH)


#: A Newton step (scaled as newton_tol) at most this makes the next one, quadratically smaller,
#: likely the last: from there the iterations factorise the scaled matrix, whose factors are
#: then the final ones; before, the plain one (cheaper: no scaling pass).
NEAR = 1e-6


def _sums(values: np.ndarray, index: np.ndarray, size: int) -> np.ndarray:
    """(size, ...): the sum of the entries ``values`` (nnz, ...) of each row (or column)
    ``index`` (nnz,), one addition of whole batch arrays per entry (a matrix product over a
    batch of this shape costs more on a few hundred entries)."""
    out = np.zeros((size,) + values.shape[1:])
    for k, i in enumerate(index.tolist()):
        out[i] += values[k]
    return out


class _Scaled:
    """Phi_q at the states X (n, b, V) scaled and factorised, entry-major."""

    def __init__(self, system: System, E: np.ndarray, dcols: np.ndarray) -> None:
        p, plan = system.pattern, system.lu
        m = system.m
        vals = E[m:]
        a = vals * dcols
        norms = np.sqrt(_sums(a * a, p.rows, m))
        self.r = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
        self.finite = np.isfinite(norms).all(axis=0)
        a *= self.r[p.rows]
        self.a = a
        self.F, self.ok = plan.factor_fn(a)


def settle(system: System, pred: np.ndarray, T: np.ndarray, D: np.ndarray,
           active: np.ndarray, opts: SolverOptions, rates: bool, near: bool = False
           ) -> Settled | None:
    """Solve Phi(q, T) = 0 from ``pred`` (V, b, n) at times ``T`` (V, b) for the ``active``
    variants (V,), factorise Phi_q at the solutions, estimate the condition, and (with
    ``rates``) solve Phi_q qd = nu and Phi_q qdd = gamma; see the module documentation.
    ``near``: the predictions are likely converged already (the last batch took one
    iteration), so that the first iteration factorises the scaled matrix.
    Convergence as :func:`mechdsl.solve.newton.newton` (the scaled step max |dq / D| at most
    ``newton_tol``, or the error left, |dq_k|^3 / |dq_(k-1)|^2, at most ``newton_error``;
    abandoned where the step stops contracting). None where it does not apply."""
    V, b, n = pred.shape
    if not applies(system, V * b):
        return None
    plan, fused, p = system.lu, system.fused, system.pattern
    m = system.m
    P, Fn = fused.params, fused.functions
    X = np.array(pred.T, dtype=float)  # (n, b, V), contiguous
    Dt = np.ascontiguousarray(np.broadcast_to(D, (V, 1, n)).T)  # (n, 1, V)
    dcols = Dt[p.cols]
    drive_rows = system.drive_rows
    which = ("f", "fd", "fdd") if rates else ("f",)
    drives = ([np.asarray(eq.drive_values(system, T, w, (V, b))).T for w in which]
              if system.drive_functions else None)
    done = np.zeros((b, V), bool)
    done |= ~active[None, :]
    failed = np.zeros((b, V), bool)
    prev = np.full((b, V), np.inf)
    moved = np.zeros((b, V), bool)
    step = np.zeros((b, V))
    scaled = None
    with np.errstate(all="ignore"):
        for it in range(1, opts.max_iterations + 1):
            E = fused.phi_jac(X.T, None, None, P, Fn).T  # (m + nnz, b, V)
            if drives is not None:
                for i, row in enumerate(drive_rows):
                    E[row] -= drives[0][i]
            if near:
                # the steps are small: this iteration's factors may be the final ones, so
                # they are the scaled factorisation the condition estimate needs
                scaled = _Scaled(system, E, dcols)
                if not scaled.ok.all():
                    return None  # a pivot of the fixed order became small: the general path
                Z = plan.solve_fn(scaled.F, -(scaled.r * E[:m]))  # A (dq / D) = -R Phi
            else:
                scaled = None
                F_it, ok_it = plan.factor_fn(E[m:])
                if not ok_it.all():
                    return None
                Z = plan.solve_fn(F_it, -E[:m]) / Dt  # Phi_q dq = -Phi, as dq / D
            step = np.maximum.reduce(np.abs(Z), axis=0)
            solved = np.isfinite(step)
            left = np.where((step < 0.25 * prev) & (prev < np.inf), step**3 / prev**2, np.inf)
            failed |= ~solved & ~done
            live = ~done & ~failed
            moved = live
            np.copyto(X, X + Dt * Z, where=live[None])
            converged = live & ((step <= opts.newton_tol) | (left <= opts.newton_error))
            done |= converged
            if it >= 3:
                failed |= live & ~converged & (step > 0.5 * prev)
            prev = np.where(live, step, prev)
            if (done | failed).all():
                break
            near = bool((step[live & ~converged] <= NEAR).all())
        ok = done & ~failed
        # the last factors were taken at the positions before the last step: the final ones
        # where that step was at round-off (and where a state did not move); else once more
        # at the converged positions (every state: one pass of the kernels)
        if scaled is None or not (step[moved & ok] <= opts.settled_step).all():
            E = fused.phi_jac(X.T, None, None, P, Fn).T
            scaled = _Scaled(system, E, dcols)
            if not scaled.ok.all():
                return None
        F, r, a = scaled.F, scaled.r, scaled.a
        # the condition estimate (Hager, Higham) and nu, one pass over the factors
        cols = 3 if rates else 2
        Y = np.empty((n, cols, b, V))
        Y[:, 0] = 1.0 / n
        i = np.arange(n)
        Y[:, 1] = ((-1.0) ** i * (1 + i / max(n - 1, 1)))[:, None, None]
        if rates:
            nu = np.zeros((m, b, V))
            if drives is not None:
                nu[drive_rows] = drives[1]
            Y[:, 2] = r * nu
        S = plan.solve_fn(F[:, None], Y)
        est = np.maximum(np.abs(S[:, 0]).sum(axis=0), 2 * np.abs(S[:, 1]).sum(axis=0) / (3 * n))
        qd = None
        rhs = []
        if rates:
            qd = Dt * S[:, 2]
            gamma = np.array(fused.gamma(X.T, qd.T, None, P, Fn).T)
            if drives is not None:
                for k, row in enumerate(drive_rows):
                    gamma[row] += drives[2][k]
            rhs.append(r * gamma)
        z = plan.solve_t_fn(F, np.where(S[:, 0] >= 0, 1.0, -1.0))
        az = np.abs(z)
        top = np.maximum.reduce(az, axis=0)
        better = top > z.sum(axis=0) / n  # Hager's test: e_j may give more
        if better.any():
            # e_j at the largest |z_j| (a tie shares the unit among the tied entries: still a
            # vector of 1-norm one, so the estimate stays a lower bound)
            e = (az == top).astype(float)
            e /= e.sum(axis=0)
            rhs.append(e)
        qdd = None
        if rhs:
            S2 = plan.solve_fn(F[:, None], np.stack(rhs, axis=1))
            if rates:
                qdd = Dt * S2[:, 0]
            if better.any():
                est = np.where(better, np.maximum(est, np.abs(S2[:, -1]).sum(axis=0)), est)
        norm_a = np.maximum.reduce(_sums(np.abs(a), p.cols, n), axis=0)
        rcond = 1.0 / (norm_a * est)
        rcond = np.where(np.isfinite(rcond) & scaled.finite, rcond, 0.0)
        sign = np.where(rcond > 0, plan.parity * np.prod(np.sign(F[plan.pivots]), axis=0), 0.0)
    fac = Factor(None, rcond.T, sign.T, gen=GeneratedLU(plan, F, r.T, np.broadcast_to(D, (V, b, n))))
    return Settled(X.T, ok.T, fac, None if qd is None else qd.T, None if qdd is None else qdd.T,
                   it)
