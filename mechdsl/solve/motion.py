"""The equations of motion of one mechanism by the augmented Lagrangian: sparse, and tolerant
of redundant constraints and singular positions.

Haug's constrained equations of motion (1989, ch. 6) in the index-1 form,

    M qdd + Phi_q^T lambda = Q(q, qd, t),    Phi_q qdd = gamma(q, qd, t),

are a saddle-point (KKT) system [[M, Phi_q^T], [Phi_q, 0]] [qdd; lambda] = [Q; gamma].
The dense LU of that matrix (what :mod:`mechdsl.solve.dynamic` solves today) needs Phi_q of
full row rank, and costs O((n + m)^3). Following Bayo, Garcia de Jalon and Serna (1988) and
Bayo and Ledesma (1996), this module solves it instead with the **augmented Lagrangian**
iteration on the symmetric matrix

    A = M + Phi_q^T W Phi_q,   W = diag(w_1 .. w_m) > 0 (the penalty),

which is positive definite whenever M is (every body has mass and inertia), whatever the
rank of Phi_q; it is factorised ONCE per evaluation, by LAPACK's band Cholesky in a
reverse Cuthill-McKee order chosen once per model (time linear in the bodies of a chain),
or, for few coordinates, the equivalent regularised saddle-point matrix by a dense LU
(:mod:`mechdsl.solve.augmented`).

**The iteration** (:meth:`Motion.saddle`), for [[M, J^T], [J, 0]] [x; lambda] = [b; c]
with J = Phi_q: from lambda_0 = 0, x_0 = 0, with the residuals r_i = b - M x_i - J^T
lambda_i and s_i = c - J x_i,

    A d_i = r_i + J^T W s_i,
    x_{i+1} = x_i + d_i,
    lambda_{i+1} = lambda_i + W (J d_i - s_i)   (= lambda_i + W (J x_{i+1} - c)).

It is Bayo's iteration A x_{i+1} = b - J^T lambda_i + J^T W c, lambda_{i+1} = lambda_i +
W (J x_{i+1} - c), written in correction form (the same iterates in exact arithmetic; in
floating point the residuals are formed afresh at each iteration, so that the ill
conditioning of A, about the penalty's 1e8, does not reach the converged x and lambda:
that is iterative refinement on the saddle-point system). After each iteration the first
residual vanishes in exact arithmetic (M x_{i+1} + J^T lambda_{i+1} - b = A d_i - r_i -
J^T W s_i = 0), in floating point to about the penalty times the unit round-off, which
the next iteration removes; the second contracts, in the multipliers' error e_i =
lambda_i - lambda*, as

    e_{i+1} = (I + W^(1/2) J M^-1 J^T W^(1/2))^-1 e_i   (in W-weighted form; by Woodbury),

a factor 1 / (1 + w sigma) per iteration on each direction with eigenvalue sigma of J M^-1
J^T: with w sigma about ``augmented_penalty`` = 1e8 on a well-conditioned mechanism, two
to four iterations reach round-off (Andrews: 3; A02: 2; a chain of 400 links: 4). On the
null space of J^T (redundant equations) e_i does not change, but there J^T e_i = 0 does
not change x either: qdd is the unique minimiser of the Gauss function 1/2 qdd^T M qdd -
Q^T qdd on {J qdd = gamma}, and lambda is the limit of the iteration (its component in
null(J^T) is zero, from lambda_0 = 0: the least-squares multipliers in the W^-1 metric).
The iteration stops when |J x - c|_2 is at most ``augmented_tol`` (1e-14) times the scale
|c|_2 + | |J| |x| |_2 (what forming that residual rounds: the sizes of the terms it sums)
and, in the band storage, |b - M x - J^T lambda|_2 at most ``augmented_tol`` times |b|_2 +
| |J|^T |lambda| |_2, or after ``augmented_max_iterations`` (12). Near a singular
position (directions with w sigma below one) it contracts slowly and ends there, at the
same iterate for every state nearby: a bounded blend of the penalty solution, whose
constraint error the projections correct, and a smooth function of the state (it used to
stop where an iteration no longer halved the residual, an iteration that changed from one
state to the next: the accelerations jumped with it and A02 took a fifth more
evaluations). (Conjugate gradients on the multipliers,
``augmented_krylov_iterations``, can take over where it stops halving; off by default, see
:class:`~mechdsl.solve.options.SolverOptions`.)

**At a singular position** (IFToMM A02 with every link collinear, tests/test_motion.py) the
accelerations with Phi_q qdd = gamma form a larger set, and the result is the unique
minimiser of the Gauss function on it: finite, but not the limit of the accelerations of
the regular positions on either side (the motion's branch), which differ from it by
O(1). Within about kappa^(-1/2) of such a position the iteration stalls and blends the two
smoothly; an integrator on :meth:`Motion.rhs` steps through that window with an error of
its width (benchmarks/a02_motion.py measures it).

**The penalty** w_r = kappa * mbar / |(J D)_r|^2 per equation r, with mbar the mean of the
diagonal of D M D (the mass of a scaled coordinate) and kappa = ``augmented_penalty``
(1e8): each equation's term in A is then kappa times the mass it constrains, in any units,
and a drive's row weighs as a joint's. Larger kappa contracts faster and reaches further
toward singular positions (w sigma > 1 for sigma > 1/w), smaller keeps A better
conditioned: cond(A) ~ kappa cond(M); 1e8 leaves about 1e8 of the 1e16 of double
precision to the factor, which the correction form needs only to contract, not to be
accurate (Bayo and Ledesma use 1e7 to 1e9 for the same reasons).

**Projections** (Bayo and Ledesma 1996: mass-orthogonal) with the same factorisation:
positions by Gauss-Newton in the metric of M, each step dq the minimum M-norm correction
with Phi_q dq = -Phi (the saddle-point system with b = 0, c = -Phi, whose first AL
iterate is Bayo's A dq = -Phi_q^T W Phi), iterated to ``newton_tol`` (scaled by D);
velocities by the saddle-point system with b = M qd*, c = nu, whose solution is the
M-orthogonal projection of qd* onto Phi_q qd = nu (first AL iterate: A qd = M qd* + Phi_q^T
W nu). Both tolerate redundant and singular Phi_q where the constraints are consistent.

Small models (the constraint-by-constraint layout) are evaluated by the one-state scalar
kernels (:attr:`mechdsl.compiled.kernels.Kernels.scalar_kernels`), as :mod:`dynamic` does; the
others by the array kernels, one state at a time.
"""

from __future__ import annotations

import functools

import math
import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from ..errors import MechError
from .augmented import Factor, Plan, plan
from .body_terms import BodyTerms
from .diagnose import closed_to_roundoff, col_scale
from ..symbolic.codegen import first_floats
from .options import SolverOptions
from .triplets import Triplets

#: A projection's last Newton step at most this fraction of ``newton_tol`` is round-off: the
#: velocities are projected with the factorisation of the step's start (Phi_q moved by
#: round-off), not a new one
ROUNDOFF_STEP = 1e-3


class Motion:
    """The equations of motion of one variant of a mechanism (the
    :class:`mechdsl.solve.stepper.Equations` protocol), by the augmented Lagrangian (see
    the module). Sparse matrices are returned as :class:`~mechdsl.solve.triplets.Triplets`."""

    #: every evaluation of :meth:`rhs` factorises M + Phi_q^T W Phi_q (the driver's trial
    #: of the implicit stepper reads it: :data:`mechdsl.solve.driver.TRIAL_RATIO_FACTORISED`)
    factorises = True

    def __init__(self, kernels: Kernels, options: SolverOptions | None = None,
                 variant: int = 0) -> None:
        from scipy.linalg.lapack import dgetrf, dgetrs, dpbtrf, dpbtrs

        system = kernels.system
        if kernels.dynamics is None:
            raise MechError("the mechanism has no masses: give its bodies mass and inertia "
                            "to simulate its motion", source=system.source)
        if system.n_variants > 1:
            kernels = kernels.variant(variant)
            system = kernels.system
        self.system, self.kernels = system, kernels
        self.opts = opts = options or SolverOptions()
        f, d = kernels.fused, kernels.dynamics
        self.n, self.m = n, m = system.n, system.m
        self.D = col_scale(system)[0, 0]
        self._lapack = (dgetrf, dgetrs, dpbtrf, dpbtrs)
        self.jac_rows, self.jac_cols = f.rows, f.cols
        self.mass_rows, self.mass_cols = d.rows, d.cols
        self.drive_rows = system.drive_rows
        # the scalar kernels of the one-state fast path (small models), shared with the
        # explicit integrators' evaluator (compiled once per model)
        scalar = kernels.scalar_kernels
        self.scalar = scalar is not None
        if self.scalar:
            from ..symbolic.codegen import scalar_functions

            self.k_phi_jac, k_motion, fixed = scalar
            self.p = first_floats(f.params)
            self.F = scalar_functions(f.functions)
            self.pd = first_floats(d.params)
            self.Fd = scalar_functions(d.functions)
            self._motion = k_motion.fn
            given = np.isnan(fixed)
            self._given = np.flatnonzero(given)
            self._n_given = len(self._given)
            self._fixed = fixed
            self._n_out = self._n_given + n + m
        # the array path: every model's where the scalar kernels do not apply, and a small
        # model's at a state outside a function's domain (the scalar kernels raise there)
        self._array_kernel(d)
        self._penalty(system.guess[0])

    # -- set-up -----------------------------------------------------------------------------
    @functools.cached_property
    def plan(self) -> Plan:
        """The factorisation's plan of M + Phi_q^T W Phi_q (:func:`.augmented.plan`), made
        at the first factorisation (a run that goes on in the joints' own coordinates
        never factorises it)."""
        d, f = self.kernels.dynamics, self.kernels.fused
        return plan(self.n, self.m, d.rows, d.cols, f.rows, f.cols,
                    self.opts.augmented_band_from)

    def _array_kernel(self, d) -> None:
        """One array kernel for the entries of M and Q that vary with the state, the
        constant ones stored once: a body's M is constant where its frame is at its centre
        of mass, gravity's load always, and the generated code of the member layout writes
        each output by one numpy operation (A02's 81 constant mass blocks cost more than
        its constraints' Jacobian). Where the bodies' part is traced apart from the force
        elements' (:class:`~mechdsl.solve.body_terms.BodyTerms`), the kernel is of the
        force elements' loads only and the bodies' terms are array arithmetic on all of
        them at once."""
        self._bodies = BodyTerms(d) if BodyTerms.applies(d) else None
        nodes = [*d.force_load_nodes] if self._bodies is not None else \
            [*d.mass_nodes, *d.load_nodes]
        const = np.array([nd.op == "const" for nd in nodes], dtype=bool)
        values = np.array([float(d.graph.constant_value(nd)) if c else 0.0
                           for nd, c in zip(nodes, const)])
        varying = np.flatnonzero(~const)
        #: the constant entries of [M's entries, Q] (or Q's force part), and where the
        #: kernel's go
        self._mq_fixed, self._mq_varying = values, varying
        self._mq_nodes = [nodes[k] for k in varying]
        self._n_mass = 0 if self._bodies is not None else len(d.mass_nodes)
        # the same on Python floats: one state at a time, the array kernel's numpy call per
        # operation costs a microsecond where a float operation costs a few dozen
        # nanoseconds (a chain of 300 links: 8.5 ms an evaluation against about 1 ms)
        from ..symbolic.codegen import scalar_functions

        self._mq_scalar = None
        self._mq_p = first_floats(d.params)
        self._mq_F = scalar_functions(d.functions)
        if len(varying):
            self._mq_scalar = d.floats([nodes[k] for k in varying], "motion_terms")

    @functools.cached_property
    def _mq_kernel(self):
        """The array kernel of the varying entries of M and Q, compiled where a state first
        needs it (outside a function's domain, where the floats' kernel raises)."""
        from ..symbolic import kernel

        d = self.kernels.dynamics
        return kernel(d.graph, self._mq_nodes, "motion_terms") if self._mq_nodes else None

    def _mass_loads(self, q: np.ndarray, qd: np.ndarray, t: float
                    ) -> tuple[np.ndarray, np.ndarray]:
        """M's entries and Q at one state, by the array path."""
        out = self._mq_fixed.copy()
        done = False
        if self._mq_scalar is not None:
            try:
                out[self._mq_varying] = self._mq_scalar(q.tolist(), qd.tolist(), t,
                                                        self._mq_p, self._mq_F)
                done = True
            except (ValueError, ZeroDivisionError, OverflowError):
                pass  # outside a function's domain: the array kernel says nan or inf
        if not done and self._mq_kernel is not None:
            d = self.kernels.dynamics
            with np.errstate(all="ignore"):
                out[self._mq_varying] = self._mq_kernel(
                    q[None, None], qd[None, None], np.full((1, 1), t), d.params,
                    d.functions)[0, 0]
        mass, loads = out[:self._n_mass], out[self._n_mass:]
        if self._bodies is not None:
            mass = self._bodies.evaluate(q, qd, loads)
        return mass, loads

    def _penalty(self, q: np.ndarray) -> None:
        """w_r = kappa mbar / |(J D)_r|^2 (the module's argument), from the state q (the
        guesses: the rows' norms of a joint change little with the configuration, and a
        penalty fixed for the model keeps the evaluations a smooth function of the state)."""
        n, m, D = self.n, self.m, self.D
        mv = self.mass_values(q)
        diag = np.zeros(n)
        on = self.mass_rows == self.mass_cols
        diag[self.mass_rows[on]] = mv[on]
        scaled = diag * D * D
        positive = scaled[scaled > 0]
        mbar = float(positive.mean()) if positive.size else 1.0
        _, jv = self._phi_jac_values(0.0, q)
        jd = jv * D[self.jac_cols]
        norm2 = np.bincount(self.jac_rows, jd * jd, minlength=m)
        typical = float(np.median(norm2)) if m else 1.0
        norm2 = np.maximum(norm2, 1e-6 * (typical if typical > 0 else 1.0))
        #: the penalty per equation
        self.w = self.opts.augmented_penalty * mbar / norm2
        self._minus_inverse = -1.0 / self.w

    # -- the model's terms, as values in their fixed patterns ---------------------------------
    def _drives(self, t: float, which: str) -> np.ndarray:
        return eq.drive_values(self.kernels, np.full((1, 1), t), which, (1, 1))[0, 0]

    def _phi_jac_values(self, t: float, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Phi (m,) and the entries of Phi_q (nnz,)."""
        m = self.m
        phi = None
        if self.scalar:
            try:
                out = self.k_phi_jac(q.tolist(), (), t, self.p, self.F)
                phi, jv = np.array(out[:m]), np.array(out[m:])
            except (ValueError, ZeroDivisionError, OverflowError):
                pass
        if phi is None:
            with np.errstate(all="ignore"):
                phi, jv = self.kernels.fused.evaluate_phi_jac(q[None, None])
            phi, jv = phi[0, 0].copy(), jv[0, 0]
        if self.drive_rows.size:
            phi[self.drive_rows] -= self._drives(t, "f")
        return phi, jv

    def mass_values(self, q: np.ndarray) -> np.ndarray:
        """The entries of M in ``Dynamics.rows/cols``' order."""
        return self._mass_loads(q, np.zeros(self.n), 0.0)[0]

    def _entries(self, q: np.ndarray, jv: np.ndarray) -> np.ndarray:
        """[Phi_q's entries, again, M's entries] at q (what :meth:`factor` takes)."""
        return np.concatenate((jv, jv, self.mass_values(q)))

    def _terms(self, t: float, q: np.ndarray, qd: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """[Phi_q's entries, again, M's entries] (:meth:`factor`), Q and gamma at one
        state."""
        n = self.n
        if self.scalar:
            try:
                vals = np.fromiter(self._motion(q.tolist(), qd.tolist(), t, (self.p, self.pd),
                                                (self.F, self.Fd)), float, self._n_out)
                k = self._n_given
                entries = self._fixed.copy()  # the constant entries stored once
                entries[self._given] = vals[:k]
                gamma = vals[k + n:]
                if self.drive_rows.size:
                    gamma[self.drive_rows] += self._drives(t, "fdd")
                return entries, vals[k:k + n], gamma
            except (ValueError, ZeroDivisionError, OverflowError):
                pass
        code = self.kernels
        Q3, Qd3, T2 = q[None, None], qd[None, None], np.full((1, 1), t)
        with np.errstate(all="ignore"):
            jv = code.fused.evaluate_jac(Q3)[0, 0]
            gamma = eq.acceleration_rhs(code, Q3, Qd3, T2)[0, 0]
        mv, load = self._mass_loads(q, qd, t)
        return np.concatenate((jv, jv, mv)), load, gamma

    def factor(self, entries: np.ndarray) -> Factor:
        """A = M + Phi_q^T W Phi_q factorised (band Cholesky; for few coordinates the dense
        LU of the equivalent regularised saddle-point matrix) from ``entries``, the values
        of [Phi_q's entries, Phi_q's entries, M's entries] (:class:`Factor`), with the
        saddle-point products at that state; LinAlgError where A is not positive
        definite (band) or the LU meets a zero pivot (dense)."""
        return Factor(self.plan, entries, self.w, self._lapack, self._minus_inverse)

    def saddle(self, fac: Factor, b: np.ndarray, c: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, int]:
        """x and lambda of [[M, J^T], [J, 0]] [x; lambda] = [b; c] (J = Phi_q, M as
        factorised in ``fac``) by the augmented Lagrangian iteration of the module, and the
        iterations taken (solves with the factor)."""
        o, n = self.opts, self.n
        bc = np.concatenate((b, c))
        z = fac.step(bc)  # from x = 0, lambda = 0: the first iterate
        # the stopping test in 2-norms, squared, on both residuals, each against what
        # forming it rounds, the sizes of the terms it sums (x and lambda change little
        # after the first iterate): |J x - c| against |c| + | |J| |x| |, and, in the band
        # storage, |b - M x - J^T lambda| against |b| + | |J|^T |lambda| | (a chain's
        # tensions cancel in J^T lambda, not in its rounding). The second vanishes
        # in exact arithmetic after every iteration, but the Cholesky factor of A, whose
        # entries are the penalty's size, rounds it at about the penalty times the unit
        # round-off: where the constraints' residual met its test at once (a velocity
        # projection), x kept that error (on A02 a projection kept 2.5e-7 of |qd| at a
        # penalty of 1e10, and at the default 1e8 B0 drifted by 4.9e-9 m over the first
        # 0.6 s at rtol 1e-10; 7e-11 with this test). The dense storage's LU of R, whose
        # entries are M's and J's, is backward stable: its first residual is at round-off
        terms = fac.j_abs(z[:n])
        limit = o.augmented_tol * (math.sqrt(c @ c) + math.sqrt(terms @ terms))
        limit = max(limit * limit, 1e-300)
        limit_r = math.inf
        if not fac.plan.dense:
            forces = fac.jt_abs(z[n:])
            limit_r = o.augmented_tol * (math.sqrt(b @ b) + math.sqrt(forces @ forces))
            limit_r = max(limit_r * limit_r, 1e-300)
        its, prev, krylov = 1, math.inf, False
        while True:
            rho = bc - fac.kkt(z)  # the residuals formed afresh: iterative refinement
            s, r = rho[n:], rho[:n]
            res, res_r = (s @ s) / limit, (r @ r) / limit_r
            if not res_r <= res:  # (a NaN in either stops the iteration below)
                res = res_r
            if not (res > 1 and its < o.augmented_max_iterations):
                break
            if res <= 0.25 * prev or krylov or not o.augmented_krylov_iterations:
                # (where it no longer contracts by half, near a singular position, it goes
                # on all the same, to augmented_max_iterations: had it stopped there, the
                # iteration it stopped at would change from one state to the next and the
                # accelerations jump with it; A02 at rtol 1e-8 took 8750 evaluations with
                # that stop, 6900 without, 1.82 s -> 1.6 s)
                z += fac.step(rho)
            else:
                # the iteration no longer halves the residual: directions of small sigma
                # (near a singular position), where the dual iteration is accelerated
                krylov = True
                z += self._krylov(fac, rho, limit)
            its += 1
            prev = res
        return z[:n], z[n:], its

    def _krylov(self, fac: Factor, rho: np.ndarray, limit: float) -> np.ndarray:
        """The correction dz with K dz = rho, by conjugate gradients on the multipliers.

        With dx0 = A^-1 (r + J^T W s) (the iteration's own step), the corrections are
        dx(mu) = dx0 - A^-1 J^T mu, and the constraint residual s - J dx(mu) = g0 + S mu,
        g0 = s - J dx0, S = J A^-1 J^T: symmetric, positive semi-definite, positive
        definite on the range of J. Preconditioned by W (W S = I - (I + W^(1/2) J M^-1 J^T
        W^(1/2))^-1 in the weighted form: 1 on the well-constrained directions, w sigma /
        (1 + w sigma) on those of small sigma), conjugate gradients solve S mu = -g0 in
        about as many iterations as there are directions of small sigma (one per window
        of A02 at its collinear position), where the augmented Lagrangian's own iteration
        would take 1 / (w sigma) of them. The multipliers' correction is then mu + W (J dx -
        s) (M dx + J^T (mu + W (J dx - s)) = r). Stops at ``limit`` (squared 2-norm of the
        constraint residual), after ``augmented_krylov_iterations``, or where the
        curvature p^T S p is not positive (an inconsistent residual, on the null space)."""
        n, w = self.n, self.w
        s = rho[n:]
        first = fac.step(rho)
        dx = first[:n]
        res = fac.j(dx) - s  # = -(g0 + S mu) at mu = 0
        mu = np.zeros(self.m)
        zc = w * res
        p, rz = zc, res @ zc
        zeros = np.zeros(self.m)
        for _ in range(self.opts.augmented_krylov_iterations):
            y = fac.step(np.concatenate((fac.jt(p), zeros)))[:n]  # A^-1 J^T p
            sp = fac.j(y)
            curvature = p @ sp
            if not curvature > 0:
                break
            alpha = rz / curvature
            mu += alpha * p
            dx -= alpha * y
            res -= alpha * sp
            if not res @ res > limit:
                break
            zc = w * res
            rz, rz_old = res @ zc, rz
            p = zc + (rz / rz_old) * p
        return np.concatenate((dx, mu + w * (fac.j(dx) - s)))

    # -- the Equations protocol -------------------------------------------------------------
    def accelerations(self, t: float, q: np.ndarray, qd: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """qdd (n,) and lambda (m,) of M qdd + Phi_q^T lambda = Q, Phi_q qdd = gamma, by the
        augmented Lagrangian (the module); with redundant constraints, lambda is the
        iteration's limit (no component in the null space of Phi_q^T). LinAlgError where
        A = M + Phi_q^T W Phi_q is not positive definite or the result is not finite."""
        qdd, lam = self._accelerations(t, q, qd)
        if not np.isfinite(qdd).all():
            raise np.linalg.LinAlgError("the accelerations are not finite")
        return qdd, lam

    def _accelerations(self, t: float, q: np.ndarray, qd: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`accelerations`, whose result may not be finite (an overflow is no
        warning: the callers test the result)."""
        entries, load, gamma = self._terms(t, q, qd)
        with np.errstate(over="ignore", invalid="ignore"):
            qdd, lam, _ = self.saddle(self.factor(entries), load, gamma)
        return qdd, lam

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        """y' = (qd, qdd) at y = (q, qd). Where qdd is not finite it is returned so: the
        state is a stage of a step far too long (a stiff spring's, whose force overflows
        there), which the explicit pairs reject and shorten (an error said that the
        equations were singular at t0: a chain of 60 links on rotary springs of 1e8 N m/rad
        stopped there)."""
        n = self.n
        out = np.empty(2 * n)
        out[:n] = y[n:]
        out[n:] = self._accelerations(t, y[:n], y[n:])[0]
        return out

    def project(self, t: float, y: np.ndarray) -> np.ndarray:
        """y = (q, qd) moved onto Phi(q, t) = 0 and Phi_q qd = nu mass-orthogonally (the
        module): q by Gauss-Newton steps dq of least M-norm with Phi_q dq = -Phi until
        max|dq / D| <= newton_tol; qd to the M-orthogonal projection of the given qd onto
        Phi_q qd = nu at the final q. Where the steps do not fall to newton_tol in
        ``max_iterations`` but Phi holds to round-off (a singular position, where they are
        its rounding over Phi_q's smallest singular value: diagnose.closed_to_roundoff), the
        positions are closed; elsewhere LinAlgError (a lock-up, inconsistent
        constraints)."""
        n, m, o = self.n, self.m, self.opts
        if m == 0:
            return np.array(y, dtype=float)
        q, qd = np.array(y[:n], dtype=float), np.array(y[n:], dtype=float)
        zero = np.zeros(n)
        converged = False
        for _ in range(o.max_iterations):
            phi, jv = self._phi_jac_values(t, q)
            fac = self.factor(self._entries(q, jv))
            dq, _, _ = self.saddle(fac, zero, -phi)
            q += dq
            step = float(np.abs(dq / self.D).max())
            if not math.isfinite(step):
                break
            if step <= o.newton_tol:
                converged = True
                break
        if not converged:
            # (a singular position: the steps are the residual's rounding over Phi_q's
            # smallest singular value and never fall to newton_tol, while Phi holds to
            # round-off; a step that is not a number leaves Phi not one either)
            phi, jv = self._phi_jac_values(t, q)
            if not closed_to_roundoff(phi, q, self.D):
                raise np.linalg.LinAlgError("the position constraints cannot be closed "
                                            "there (a lock-up, inconsistent constraints, "
                                            "or a singular position)")
            fac = self.factor(self._entries(q, jv))
        elif step > ROUNDOFF_STEP * o.newton_tol:
            # Phi_q at the corrected q (a step of newton_tol leaves Phi of its square); a
            # last step at round-off moved Phi_q by round-off only
            _, jv = self._phi_jac_values(t, q)
            fac = self.factor(self._entries(q, jv))
        qd, _, _ = self.saddle(fac, fac.m_times(qd), self.nu(t))
        return np.concatenate((q, qd))

    def phi_jac(self, t: float, q: np.ndarray) -> tuple[np.ndarray, object]:
        """Phi(q, t) (m,) and Phi_q (m, n)."""
        phi, jv = self._phi_jac_values(t, q)
        return phi, Triplets(jv, self.jac_rows, self.jac_cols, (self.m, self.n))

    def nu(self, t: float) -> np.ndarray:
        """nu = -Phi_t (m,): the drives' f'(t) in their rows, zero elsewhere."""
        out = np.zeros(self.m)
        if self.drive_rows.size:
            out[self.drive_rows] = self._drives(t, "fd")
        return out

    def gamma(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """gamma = -(Phi_q qd)_q qd + f''(t) in the drive rows (m,)."""
        with np.errstate(all="ignore"):
            return eq.acceleration_rhs(self.kernels, q[None, None], qd[None, None],
                                       np.full((1, 1), t))[0, 0]

    def mass(self, q: np.ndarray) -> object:
        """M(q) (n, n)."""
        return Triplets(self.mass_values(q), self.mass_rows, self.mass_cols, (self.n, self.n))

    def loads(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Q(q, qd, t) (n,)."""
        return self._mass_loads(q, qd, t)[1]

    def mass_loads(self, t: float, q: np.ndarray, qd: np.ndarray) -> tuple[object, np.ndarray]:
        """M(q) (n, n) and Q(q, qd, t) (n,), from one evaluation of the kernels."""
        mv, load = self._mass_loads(q, qd, t)
        return Triplets(mv, self.mass_rows, self.mass_cols, (self.n, self.n)), load

    @functools.cached_property
    def _load_jacobian(self) -> tuple:
        """The load derivatives' kernel of floats (None without varying entries) and the
        positions of dQ/dq's and dQ/dqd's entries in its output."""
        d = self.kernels.dynamics
        lj = d.load_jacobian
        fn = d.floats(lj.nodes, "load_jacobian") if lj.kernel is not None else None
        return fn, np.flatnonzero(lj.wrt == 0), np.flatnonzero(lj.wrt == 1)

    def load_derivatives(self, t: float, q: np.ndarray, qd: np.ndarray
                         ) -> tuple[Triplets, Triplets]:
        """dQ/dq and dQ/dqd (n, n): exact, from the traced loads
        (:attr:`mechdsl.compiled.dynamics.Dynamics.load_jacobian`)."""
        d = self.kernels.dynamics
        lj = d.load_jacobian
        fn, on_q, on_qd = self._load_jacobian
        vals = None
        if fn is not None:
            try:
                vals = np.fromiter(fn(q.tolist(), qd.tolist(), t, self._mq_p, self._mq_F),
                                   float, lj.rows.size)
            except (ValueError, ZeroDivisionError, OverflowError):
                pass  # outside a function's domain: the array kernel says nan or inf
        if vals is None:
            vals = d.load_derivative_values(q[None, None], qd[None, None],
                                            np.full((1, 1), t))[0, 0]
        shape = (self.n, self.n)
        return (Triplets(vals[on_q], lj.rows[on_q], lj.cols[on_q], shape),
                Triplets(vals[on_qd], lj.rows[on_qd], lj.cols[on_qd], shape))


    @property
    def _curvature(self):
        return self.kernels.curvature

    def constraint_curvature(self, t: float, q: np.ndarray, lam: np.ndarray) -> Triplets:
        """d/dq (Phi_q^T lambda) = sum_i lambda_i Phi_i,qq (n, n), exact
        (:mod:`mechdsl.compiled.curvature`); empty where the constraints are linear."""
        c = self._curvature
        if c is None:
            return Triplets(np.zeros(0), np.zeros(0, np.intp), np.zeros(0, np.intp),
                            (self.n, self.n))
        return Triplets(c.matrix_entries(q, np.asarray(lam, dtype=float), t), c.rows, c.cols,
                        (self.n, self.n))


def dense_saddle(mass: np.ndarray, jac: np.ndarray, b: np.ndarray, c: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The reference: [[M, J^T], [J, 0]] [x; lambda] = [b; c] by one dense LU (what
    :mod:`mechdsl.solve.dynamic` solves today; J of full row rank)."""
    n, m = mass.shape[0], jac.shape[0]
    a = np.zeros((n + m, n + m))
    a[:n, :n], a[:n, n:], a[n:, :n] = mass, jac.T, jac
    sol = np.linalg.solve(a, np.concatenate((b, c)))
    return sol[:n], sol[n:]

