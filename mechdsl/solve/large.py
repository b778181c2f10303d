"""The march of a single large mechanism: one instant after another, with no more than each
instant needs.

A mechanism of thousands of coordinates is solved one instant at a time with LAPACK's band
LU (:mod:`mechdsl.compiled.band`); what costs there is the number of factorisations and
solves per instant, and the Python around them. The careful march
(:meth:`mechdsl.solve.run.KinematicRun.march`) is general (blocks, sweeps, substeps,
bisection, passing singular positions) and spends about two factorisations, eight solves and
a millisecond of bookkeeping per instant on a row of 1001 bodies. :func:`march_large` takes
each instant as the compiled backend's march does (:mod:`mechdsl.compiled.native`):

1. predict by the quintic through the last two states (q, qd, qdd at both: error O(h^6));
2. correct by simplified Newton, Phi_q(q_prev) dq = -Phi, with the last instant's
   factorisation, down to round-off: a step at most ``settled_step``, or an error left after
   it, theta |dq| / (1 - theta) with theta the contraction, at most ``newton_error`` or one
   ulp of the largest scaled coordinate; or down to the noise of the mechanism's own
   equations, where steps below ``noise_floor`` stop contracting (then the step the final
   Jacobian gives must be noise too, within ``noise_scatter``);
3. factorise Phi_q once, at that converged position: the final Jacobian, which gives the
   condition number (Hager and Higham's estimate), the sign of det(Phi_q), the velocities and
   the accelerations exactly (Phi_q qd = nu, Phi_q qdd = gamma), and the next instant's
   Newton matrix;
4. check as the careful march checks: converged, regular (``singular_rcond``), det(Phi_q) of
   the same sign (no singular position crossed), Newton's correction small against the
   motion (``branch_ratio``), finite rates.

An instant that fails a check, or whose simplified Newton does not contract by
``reuse_ratio``, is handed to the careful march, which solves it or reports exactly what
happened there; the instants before it are recorded in blocks, and on an interrupt the
block in hand is recorded first.
"""

from __future__ import annotations

import math

import numpy as np

from ..compiled import equations as eq
from ..compiled.band import BandLU
from ..compiled.sparse import band_of
from . import hermite
from .linalg import Factor
from .newton import use_sparse
from .rowwise import allfinite

#: Instants recorded together (outputs are computed for a block at once).
BLOCK = 32
#: the unit round-off of doubles: the smallest error a position can be solved to, relative
EPS = float(np.finfo(float).eps)


def _extrapolate(a: tuple, b: tuple, t: float) -> np.ndarray:
    """q at ``t`` from the quintic through the states a and b = (t, q, qd, qdd), the last two
    solved: the Hermite basis of :mod:`mechdsl.solve.hermite` beyond its interval, error
    O(h^6) against the cubic Taylor polynomial's O(h^4)."""
    h = b[0] - a[0]
    h0, h1, h2, h3, h4, h5 = hermite.basis((t - a[0]) / h)
    return (h0 * a[1] + h3 * b[1] + h * (h1 * a[2] + h4 * b[2])
            + h * h * (h2 * a[3] + h5 * b[3]))


def _solve(lu: BandLU, b: np.ndarray, trans: int = 0) -> np.ndarray:
    """A' y = b (or A'^T y = b) for the band matrix A' of the plan's order, by LAPACK's dgbtrs
    on ``lu``'s factors: no permutation (the caller's vectors are in that order already)."""
    from scipy.linalg.lapack import dgbtrs  # (the band LU is scipy's: imported with it)

    p = lu.plan
    y, _ = dgbtrs(lu.lu, p.kl, p.ku, b, lu.ipiv, trans=trans, overwrite_b=1)
    return y


def applies(run) -> bool:
    """Whether :func:`march_large` takes the run's instants: a single mechanism solved with the
    band LU (a square system, large enough for the sparse path, narrow-banded)."""
    system = run.system
    return (system.n_variants == 1 and use_sparse(system, run.opts, run.rows)
            and band_of(system.pattern) is not None)


def march_large(run, k: int, end: int) -> int:
    """Solve the instants k .. end-1 of ``run`` (see the module documentation); return the
    first instant not solved (``end`` when all are)."""
    fac = run.fac
    if fac is None or fac.lus is None or fac.lus[0, 0] is None or not run.active[0]:
        return k
    system, opts, times = run.system, run.opts, run.times
    fused, pattern = run.kernels.fused, system.pattern
    n, m = system.n, system.m
    D = run.D[0, 0]
    drive_rows = system.drive_rows
    T = times[k:end]
    shape = (1, len(T))
    if run.kernels.drive_functions:
        f, fd, fdd = (np.array(eq.drive_values(run.kernels, T[None, :], w, shape)[0])
                      for w in ("f", "fd", "fdd"))
        defined = allfinite(f) & allfinite(fd) & allfinite(fdd)
    else:
        f = fd = fdd = np.zeros((len(T), 0))
        defined = np.ones(len(T), bool)
    lu, r, d = fac.lus[0, 0]
    plan = band_of(pattern)
    prow, pcol = pattern.rows, pattern.cols
    dcols = D[pcol]
    i = np.arange(n)
    alt = (-1.0) ** i * (1 + i / max(n - 1, 1))  # Higham's safeguard vector
    invD = 1.0 / D
    band_rows, band_cols = plan.prow, plan.pcol
    q, qd, qdd = run.q[0].copy(), run.qd[0].copy(), run.qdd[0].copy()
    t, sign = float(run.t[0]), float(run.sign[0])
    before = None  # the state before the last, for the predictor
    block: list[tuple] = []
    residual = 0.0

    def record() -> None:
        if not block:
            return
        j0 = block[0][0]
        c = len(block)
        lus = np.empty((1, c), dtype=object)
        lus[0, -1] = block[-1][6]
        states = [np.array([[b[i] for b in block]]) for i in (1, 2, 3)]
        rec = np.arange(k + j0, k + j0 + c)
        run.residual = max(run.residual, residual)
        run.accept(states[0], T[None, j0 : j0 + c], rec,
                   Factor(None, np.array([[b[4] for b in block]]),
                          np.array([[b[5] for b in block]]), lus),
                   run.active.copy(), (states[1], states[2]), checked=True)
        block.clear()
        if run.progress is not None:
            run.progress(int(rec[-1]) + 1, len(times))

    j = 0
    try:
        for j in range(len(T)):
            if not defined[j]:
                break
            tau = float(T[j]) - t
            if before is None:
                pred = q + tau * (qd + tau / 2 * qdd)
            else:
                pred = _extrapolate(before, (t, q, qd, qdd), float(T[j]))
            x = pred.copy()
            converged, prev, noise = False, math.inf, 0.0
            ulp = EPS * max(1.0, float(np.abs(pred / D).max()))
            with np.errstate(all="ignore"):
                for _ in range(opts.max_iterations):
                    phi = fused.evaluate_phi(x[None, None])[0, 0]
                    phi[drive_rows] -= f[j]
                    dx = d * lu.solve(-(r * phi))
                    step = float(np.abs(dx * invD).max())
                    if not math.isfinite(step):
                        break
                    x += dx
                    if step <= opts.settled_step:
                        converged = True
                        break
                    if prev < math.inf:
                        theta = step / prev
                        if theta >= opts.reuse_ratio:
                            # no longer contracting: round-off, if the steps are tiny (their
                            # size is then the noise of this mechanism's equations); else
                            # too slow or diverging, for the careful march
                            noise = max(step, prev)
                            converged = noise <= min(opts.noise_floor, opts.newton_tol)
                            break
                        # the error left, below newton_error or below what floating point
                        # resolves in the largest coordinate (one ulp of it, scaled)
                        if theta * step / (1 - theta) <= max(opts.newton_error, ulp):
                            converged = True
                            break
                    prev = step
                if not converged:
                    break
                # the final Jacobian, at the converged position
                out = fused.evaluate_phi_jac(x[None, None])
                phi, vals = out[0][0, 0].copy(), out[1][0, 0]
                phi[drive_rows] -= f[j]
                res = float(np.abs(phi).max())
                a = vals * dcols
                norms = np.sqrt(np.bincount(prow, a * a, minlength=m))
                if not (math.isfinite(float(norms.sum())) and math.isfinite(res)):
                    break
                r_new = 1.0 / np.where(norms > 0, norms, 1.0)  # (an empty row: 1)
                a *= r_new[prow]  # A = R Phi_q D
                lu_new = BandLU(plan, a)
                if lu_new.info != 0:
                    break
                sgn = lu_new.sign()  # (NaN where a factor is not a number: stops here)
                if sgn != sign:
                    break
                # one solve for three right-hand sides: Hager's and Higham's vectors of the
                # condition estimate (as sparse.inverse_norm1), R nu; and, where the equations
                # converged to their noise, -R Phi (the check that this Jacobian is final).
                # The solves work in the band plan's order (A' = A[prow][:, pcol]): the
                # estimate's vectors need no permuting (the norms of A^-1 and of A'^-1 are
                # the same, and Higham's vector in A''s order is as good a safeguard)
                check = noise > opts.settled_step
                B = np.empty((n, 4 if check else 3), order="F")
                B[:, 0] = 1.0 / n
                B[:, 1] = alt
                rnu = np.zeros(m)  # R nu: f'(t) in the drive rows
                rnu[drive_rows] = r_new[drive_rows] * fd[j]
                B[:, 2] = rnu[band_rows]
                if check:
                    B[:, 3] = -(r_new * phi)[band_rows]
                y = _solve(lu_new, B)
                if check:
                    # converged to the noise of the equations, above settled_step: the
                    # position is solved if the Newton step of the Jacobian factorised there
                    # is noise too (within the scatter of the last steps, ``noise_scatter``);
                    # it is not taken, so that the rates are solved at the position recorded
                    if not float(np.abs(y[:, 3]).max()) <= opts.noise_scatter * noise:
                        break
                went, meant = (x - q) * invD, (pred - q) * invD
                moved = max(float(np.abs(went).max()), float(np.abs(meant).max()))
                ratio = float(np.abs(went - meant).max()) / max(moved, run.floor)
                if not ratio <= opts.branch_ratio:
                    break
                qd_new = np.empty(n)
                qd_new[band_cols] = y[:, 2]
                qd_new *= D
                gamma = fused.evaluate_gamma(x[None, None], qd_new[None, None])[0, 0]
                gamma[drive_rows] += fdd[j]
                inv_norm = max(float(np.abs(y[:, 0]).sum()), 2 * float(np.abs(y[:, 1]).sum()) / (3 * n))
                z = _solve(lu_new, np.where(y[:, 0] >= 0, 1.0, -1.0), trans=1)
                big = int(np.argmax(np.abs(z)))
                hager = abs(z[big]) > z.sum() / n  # Hager's test: e_j may give a larger column
                B = np.zeros((n, 2 if hager else 1), order="F")
                B[:, 0] = (r_new * gamma)[band_rows]
                if hager:
                    B[big, 1] = 1.0
                y = _solve(lu_new, B)
                if hager:
                    inv_norm = max(inv_norm, float(np.abs(y[:, 1]).sum()))
                norm_a = float(np.bincount(pcol, np.abs(a), minlength=n).max())
                rcond = 1.0 / (norm_a * inv_norm)
                if not rcond >= opts.singular_rcond:
                    break
                qdd_new = np.empty(n)
                qdd_new[band_cols] = y[:, 0]
                qdd_new *= D
                if not (np.isfinite(qd_new).all() and np.isfinite(qdd_new).all()):
                    break
            residual = max(residual, res)
            before = (t, q, qd, qdd)
            q, qd, qdd, t = x, qd_new, qdd_new, float(T[j])
            lu, r, d = lu_new, r_new, D
            block.append((j, x, qd_new, qdd_new, rcond, sgn, (lu_new, r_new, D)))
            if len(block) == BLOCK:
                record()
        else:
            j = len(T)
    except KeyboardInterrupt:
        record()
        raise
    record()
    return k + j
