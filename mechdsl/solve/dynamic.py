"""The forward dynamics of a mechanism that is not fully driven: its motion under its loads.

Haug's constrained equations of motion (1989, ch. 6) in the index-1 form: at every state

    [ M(q)   Phi_q^T ] [ qdd    ]   [ Q(q, qd, t) ]
    [ Phi_q  0       ] [ lambda ] = [ gamma       ]

gives the accelerations and the multipliers, and y = (q, qd) is integrated by a stepper of
the registry (:mod:`mechdsl.solve.integrators`, which chooses it: the explicit Runge-Kutta
pairs of :mod:`mechdsl.solve.explicit`, Verner's 9(8), or Dormand and Prince's 5(4) at loose
tolerances, or their 8(5,3), as the options ask) under the driver of
:mod:`mechdsl.solve.driver` (outputs, projections, budget, failures, interrupts). At
every output instant the state is projected back onto both constraint manifolds: q by
Gauss-Newton on Phi(q, t) = 0 with the minimum-norm correction, iterated to newton_tol, then
qd onto Phi_q qd = nu; after every other step, by one such correction of q and qd together
(the drift of one step is within the integrator's tolerance, and one correction leaves its
square). The index-1 form alone lets the constraints drift (|Phi| grows with the run); the
projections keep them at the solver's tolerance whatever the length of the run, at the cost
of one factorisation of (Phi_q D)(Phi_q D)^T per step. This choice over an implicit method
on the index-3 or stabilised index-2 form is argued, with measurements, in docs/dynamics.md.

Drives may move some coordinates (a mixed case): their f(t) enters Phi, nu = f'(t) and
gamma = ... + f''(t) exactly as in the kinematics. The initial state is the assembly at t0
and the velocities of ``v0`` statements (zero otherwise), projected onto Phi_q qd = nu; a
projection that changes a given velocity is reported as a warning with its size.
"""

from __future__ import annotations

import functools
import math
import time
from typing import Callable

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from ..errors import MechError
from .memory import plan
from ..results import Results
from . import extrema, instants
from .assembly import gauss_newton
from .base import Progress, Run
from .diagnose import closed_to_roundoff, constraint_names, jumps_text, variant_label
from .options import SolverOptions, raised_to
from ..symbolic.codegen import first_floats


#: The integrator's tolerances where neither the options nor the simulate statement give them
RTOL, ATOL = 1e-8, 1e-10
#: A relative tolerance above this gets a warning: each step may then be off by a percent
#: and more, which integrators accept (scipy's and SUNDIALS' set no bound) but a run rarely
#: means (a pendulum at rtol 0.5 gained 100 times its energy in 20 s; scipy's default is
#: 1e-3)
LOOSE_RTOL = 1e-2
#: Where the dense equations' steps stall (mechdsl.solve.driver), the constraints' Jacobian
#: whose smallest singular value is below this times its largest is a singular position
#: they cannot pass: the variant goes on by the augmented Lagrangian at once
SINGULAR_STALL = 1e-4
#: The tightest tolerances any integrator is given: scipy's floor of rtol, 100 eps (its
#: solvers raise a smaller one to it), and an atol (relative to the model's size) at double
#: precision's resolution; tighter ones are raised to them, with a warning. Asked for less,
#: a pendulum at rtol 1e-30 reached t = 3e-13 in 2000 steps, the automatic choice read the
#: steps held at round-off as stiffness, and an atol of 1e-200 divided by zero
RTOL_FLOOR, ATOL_FLOOR = 100 * float(np.finfo(float).eps), 1e-16
#: Where radau's step underflows on a model with redundant constraints: its Newton iteration
#: did not pass a position where they turn singular (a driven parallelogram with three
#: cranks at its collinear position, t = 0.19), which the explicit pairs on the augmented
#: Lagrangian passed (4.2e-8 rad over 5 s)
_IMPLICIT_REDUNDANT = ("this model's constraints are redundant, and the implicit method's "
                       "iteration may not pass a position where they turn singular: the "
                       "augmented Lagrangian with an explicit pair (the automatic choice, or "
                       "--method dop853) integrates through singular positions")
#: Where radau's step underflows at a singular position of a model without redundant
#: constraints (Phi_q's smallest singular value below SINGULAR_NEAR of its largest where it
#: stopped): a parallelogram driven through its collinear position by a spring of 1e6
#: N m/rad, at 100 rad/s, stopped at the third passage (t = 0.0139)
SINGULAR_NEAR = 1e-3
_IMPLICIT_SINGULAR = ("the implicit method's iteration did not pass the singular position "
                      "there (the constraints' Jacobian's smallest singular value {ratio:.1e} "
                      "of its largest): where the motion goes on through it (not a lock-up), "
                      "the augmented Lagrangian with an explicit pair (the automatic choice, "
                      "or --method dop853) integrates through singular positions")
#: What a jump of a constraint in time means, by its level (:mod:`mechdsl.solve.jumps`)
_JUMP_POSITION = ("no motion under finite forces follows a jump in a constraint's position; "
                  "write it as a continuous function of t (a ramp, a smoothstep), or run "
                  "again from the state after it")
_JUMP_VELOCITY = ("a jump in a constraint's velocity is an impact (perfectly plastic with "
                  "the constraint); a smooth start (a smoothstep) avoids it")



#: Gauss-Legendre points per step of the dissipated energy's integral
GAUSS_POINTS = 5
#: The output instants of a model of at most this many coordinates and equations are
#: projected and solved together when a variant ends (:mod:`mechdsl.solve.instants`: dense
#: batched solves); a larger model's one by one, as the steps reach them
BATCH_MAX = 120

class DynamicRun(Run):
    """Forward dynamics of every variant over ``system.times`` (see the module)."""

    name = "dynamic"

    def __init__(self, kernels: Kernels, options: SolverOptions | None = None, *,
                 poses: bool = False, rates: bool = False, progress: Progress | None = None,
                 extra_memory: int = 0) -> None:
        system = kernels.system
        super().__init__(kernels, options, progress=progress)
        if kernels.dynamics is None:
            raise MechError(
                f"the mechanism is not fully driven ({system.n} coordinates, {system.m} "
                "equations) and has no masses: give its bodies mass and inertia to simulate "
                "its motion, or add drives", source=system.source)
        self.keep_poses, self.keep_rates = poses or rates, rates
        #: the reductions' extremes refined between the samples on the integrator's dense
        #: output (:meth:`_refine_extremes`), per (column, sense): values and times (V,)
        self.to_refine = {pair for pair in extrema.wanted(system)
                          if pair[0] != "dissipated_energy"} \
            if self.opts.refine_extrema else set()
        self.extrema: dict = {}
        # refused before anything the size of the run is allocated, as the kinematics is; a
        # large model's equations of motion are the augmented Lagrangian's band factor and
        # sparse terms (:mod:`.motion`), not a dense n x n matrix (a chain of 3000 links
        # was refused at 4.1 GiB)
        banded = system.n >= self.opts.augmented_band_from or system.m > system.n
        plan(system, self.opts.max_memory, self.opts.max_batch_elements, sparse=banded,
             poses=poses or rates, rates=rates, extra=extra_memory,
             compiled=self.opts.backend == "compiled")
        tol = system.tolerances  # the file's; options given explicitly override them
        self.rtol = self.opts.rtol or tol.get("rtol", RTOL)
        self.atol = self.opts.atol or tol.get("atol", ATOL)
        self.rtol, self.atol, asked = raised_to(self.rtol, self.atol, RTOL_FLOOR, ATOL_FLOOR)
        if asked:
            self.warnings.append(
                f"{' and '.join(asked)} {'are' if len(asked) > 1 else 'is'} below what "
                f"double precision resolves: integrated at rtol {self.rtol:.3g}, atol "
                f"{self.atol:g}")
        if self.rtol > LOOSE_RTOL:
            self.warnings.append(
                f"rtol = {self.rtol:g} is loose: each step may be off by {self.rtol:.0%} of "
                f"the state, and the motion wrong in kind (energy gained, a swing lost); "
                f"1e-3 to 1e-10 are usual, {RTOL:g} the default")
        from .integrators import choose

        #: the integrator's name (in :data:`mechdsl.solve.integrators.INTEGRATORS`) and why
        #: it was chosen
        #: the equations by the augmented Lagrangian (:class:`~mechdsl.solve.motion.Motion`,
        #: sparse, tolerant of redundant constraints and singular positions) for a large
        #: model or one with more equations than coordinates; a small one keeps the dense
        #: index-1 solve, twice as fast there (Andrews: 27 against 55 us an evaluation).
        #: Redundancy that appears only at the assembly (rank of Phi_q below m) switches
        #: too, variant by variant (:meth:`_equations_of`)
        self.large = system.n >= self.opts.augmented_band_from
        self.redundant = system.m > system.n
        self.method, self.method_reason = choose(self.opts.method, self.rtol,
                                                 dopri5_from=self.opts.dopri5_from,
                                                 large=self.large, redundant=self.redundant)
        #: where the automatic choice went on with the implicit method (stiffness found)
        self.switches: list[str] = []
        self.singular_met = False  # (per variant: :meth:`_variant`)
        #: a Ctrl-C came while a variant's output instants were completed (:meth:`_write`)
        self.interrupted = False

    # -- the equations of one variant --------------------------------------------------------
    def _project(self, t: float, y: np.ndarray) -> np.ndarray:
        """(q, qd) moved onto Phi(q, t) = 0 and Phi_q qd = nu: Gauss-Newton with the
        minimum-norm correction in coordinates scaled by D, dz = -(J D)^+ Phi, then
        qd -= D (J D)^+ (J qd - nu); positions whose steps do not fall to newton_tol are
        closed where Phi holds to round-off (a singular position:
        diagnose.closed_to_roundoff), else LinAlgError."""
        ev = self.ev
        n, m = ev.n, ev.m
        if m == 0:
            return y
        D = ev.D
        q, qd = y[:n].copy(), y[n:].copy()
        # as the kinematics: a step of at most newton_tol leaves an error of its square
        for _ in range(self.opts.max_iterations):
            phi, jac = ev.phi_jac(t, q)
            dz = _min_norm(ev.dgesv, jac * D, phi)
            q -= D * dz
            if not np.abs(dz).max() > self.opts.newton_tol:
                break
        else:  # (a singular position, where the steps are noise: closed to round-off)
            if not closed_to_roundoff(ev.phi_jac(t, q)[0], q, D):
                # the integrator reports it, with the instant
                raise np.linalg.LinAlgError("the position constraints cannot be closed "
                                            "there (a lock-up, or a singular position)")
        _, jac = ev.phi_jac(t, q)
        qd -= D * _min_norm(ev.dgesv, jac * D, jac @ qd - ev.nu(t))
        return np.concatenate((q, qd))

    def _impulse(self, t: float, y: np.ndarray) -> np.ndarray:
        """The state just after the constraints' velocity terms jumped at t (a drive that
        starts abruptly): the positions projected as at an output (they are continuous), the
        velocities by the impulsive motion of ideal constraints (a perfectly plastic impact
        with them), M (qd+ - qd-) = Phi_q^T Lambda with Phi_q qd+ = nu(t+), that is

            [M  Phi_q^T] [qd+   ]   [M qd-]
            [Phi_q   0 ] [Lambda] = [nu   ],

        the M-orthogonal projection of qd- onto Phi_q qd = nu (Haug's impulse-momentum
        equations with the constraints as the impact's conditions)."""
        n, m = self.ev.n, self.ev.m
        q = self._project(t, y)[:n]
        if m == 0:
            return np.concatenate((q, y[n:]))
        _, jac = self.ev.phi_jac(t, q)
        mass = self.one.dynamics.mass_matrix(q[None, None])[0, 0]
        a = np.zeros((n + m, n + m))
        a[:n, :n], a[:n, n:], a[n:, :n] = mass, jac.T, jac
        rhs = np.concatenate((mass @ y[n:], self.ev.nu(t)))
        qd = np.linalg.lstsq(a, rhs, rcond=None)[0][:n]  # (redundant rows: least squares)
        return np.concatenate((q, qd))

    def _settle(self, t: float, y: np.ndarray) -> np.ndarray:
        """(q, qd) after a step, moved onto both manifolds by one Gauss-Newton correction
        each: dz = (J D)^+ Phi at q, then dv = (J D)^+ (J' qd - nu) with J' = Phi_q at the
        corrected q, both on one Cholesky factorisation of S = (J D)(J D)^T (at the
        corrected q, J' D (J D)^T = S + O(|dz|): the velocity's residual is left at the
        product of the two drifts). A step's drift is within the integrator's tolerance,
        and one correction of size |dz| leaves an error of order |dz|^2; where that is not
        far inside the absolute tolerance (|dz|^2 > atol / 1000, scaled coordinates), the
        full projection (:meth:`_project`) iterates as at an output instant."""
        ev = self.ev
        n = ev.n
        if ev.m == 0:
            return y
        D = ev.D
        q, qd = y[:n], y[n:]
        phi, jac = ev.phi_jac(t, q)
        a = jac * D
        # S = (J D)(J D)^T is symmetric positive definite where J has full rank: Cholesky,
        # once for both corrections
        c, info = ev.dpotrf(a @ a.T, lower=1)
        if info != 0:
            return self._project(t, y)
        dz = a.T @ ev.dpotrs(c, phi, lower=1)[0]
        if not np.abs(dz).max() ** 2 <= 1e-3 * self.atol:
            return self._project(t, y)
        q = q - D * dz
        _, jac = ev.phi_jac(t, q)
        dv = a.T @ ev.dpotrs(c, jac @ qd - ev.nu(t), lower=1)[0]
        if not (math.isfinite(dz @ dz) and math.isfinite(dv @ dv)):
            return self._project(t, y)
        return np.concatenate((q, qd - D * dv))

    # -- the run -------------------------------------------------------------------------------
    def run(self) -> Results:
        """Integrate every variant in turn (:meth:`Run.run`'s contract). Each has a budget
        of ``max_steps`` steps, accepted and rejected: one that uses it up stops there, a
        numerical failure whose message says the budget, the time reached and how to raise
        it, with the output instants before it kept. ``progress(done, total)`` is called at
        every output instant, unless it has a method ``motion(t, steps, t0, t1, variant,
        variants, max_steps)`` (:class:`mechdsl.commands.ProgressBar`): that is called
        after every accepted step instead, with the time reached in t0 .. t1 and the steps
        taken so far by ``variant`` (from 0) of ``variants``."""
        sysm, times = self.system, self.times
        V, K, n = sysm.n_variants, len(times), sysm.n
        start = time.perf_counter()
        self.data = {o.label: np.full((V, K), np.nan) for o in sysm.outputs}
        self.poses = np.full((V, K, n), np.nan) if self.keep_poses else None
        self.pose_rates = np.full((V, K, 2, n), np.nan) if self.keep_rates else None
        self.residual = 0.0
        status = "ok"
        from .threads import blas_threads

        try:
            # (a small model's LAPACK calls are below the sizes at which BLAS starts
            # threads; finding the libraries to limit costs 2 ms, 4 % of Andrews' run)
            with blas_threads(self.opts.blas_threads if self.large else 0):
                q0 = self._initial_positions()
                for v in range(V):
                    if q0[v] is None:
                        continue
                    if self._variant(v, q0[v]) == "interrupted" or self.interrupted:
                        status = "interrupted"
                        break
        except KeyboardInterrupt:
            status = "interrupted"
        if status == "ok" and self.failures:
            status = "failed"
        poses = None if self.poses is None else self.poses.reshape(V, K, -1, 3)
        rates = None if self.pose_rates is None else self.pose_rates.reshape(V, K, 2, -1, 3)
        method = self.method_reason
        if self.switches:
            method += "; " + "; ".join(self.switches)
        return self.results(status, time.perf_counter() - start, residual=self.residual,
                            poses=poses, rates=rates, method=method)

    def initial_state(self) -> tuple[np.ndarray | None, str | None]:
        """The first variant's configuration at t0 (the assembly this run starts from) and,
        where there is none or the equations of motion are singular there, the message
        that the run would stop with (what ``mechdsl check`` reports)."""
        q0 = self._initial_positions()[0]
        if q0 is None:
            return None, self.failures[0]
        self.one, self.variant = _one(self.kernels, 0), 0
        self.ev = self._equations_of(0, q0)
        try:
            self.ev.accelerations(float(self.times[0]), q0, np.zeros(self.system.n))
        except np.linalg.LinAlgError:
            return q0, self._singular_message(0, float(self.times[0]))
        return q0, None

    def _equations_of(self, v: int, q0: np.ndarray):
        """The evaluator of variant ``v`` (whose assembly is ``q0``): the augmented
        Lagrangian's :class:`~mechdsl.solve.motion.Motion` where the model is large, has
        more equations than coordinates, or Phi_q has rank below m at the assembly
        (redundant constraints); else the dense index-1 evaluator."""
        from .integrators import INTEGRATORS, choose

        redundant = self.redundant
        if INTEGRATORS[self.method].implicit:  # it needs the index-3 form's terms
            return _augmented()(self.one, self.opts)
        if not (redundant or self.large) and self.system.m:
            probe = _Evaluator(self.one, self.D[v, 0])
            # the rank at the assembly, with a tolerance scaled to the matrix (numpy's)
            ratio = _singular_ratio(probe, float(self.times[0]), q0, self.D[v, 0])
            redundant = ratio <= max(probe.m, probe.n) * np.finfo(float).eps
            if not redundant:
                return _Evaluator(self.one, self.D[v, 0], self._compiled())
        if redundant and not self.redundant:
            self.warnings.append(
                f"the constraints are redundant at the assembly{variant_label(self.one.system, v)} "
                "(Phi_q has rank below its number of equations): integrated by the "
                "augmented Lagrangian, which determines the motion but not how redundant "
                "joints share their reactions")
            self.redundant = True
            if self.opts.method == "auto":
                # the choice for redundant constraints, which the count of equations did
                # not show (a parallelogram's third crank: vern9 ended 1.6e-4 rad off the
                # one-degree-of-freedom equation at rtol 1e-6 over 20 s, dop853 2.7e-5)
                self.method, why = choose("auto", self.rtol, dopri5_from=self.opts.dopri5_from,
                                          large=self.large, redundant=True)
                self.method_reason = f"{why} (the constraints proved redundant at the assembly)"
        return _augmented()(self.one, self.opts)

    def _projector(self) -> Callable[[float, np.ndarray], np.ndarray]:
        """The projection onto both constraint manifolds that the run's evaluator uses."""
        return self.ev.project if isinstance(self.ev, _augmented()) else self._project

    def _compiled(self):
        """The compiled equations of motion where the options ask for the compiled backend
        ("compiled": a small forward dynamics never pays numba's start-up unasked), numba
        is installed and the model compiles (no function arguments, no drives); else None,
        with a warning where it was asked for."""
        if self.opts.backend != "compiled":
            return None
        if getattr(self, "_accel", None) is None:
            from ..compiled import native

            self._accel = native.load_dynamics(self.kernels) or False
            if not self._accel:
                why = ("numba is not installed (pip install mechdsl[fast])"
                       if not native.available() else "the compiled backend does not "
                       "compile this model (a function argument, a drive, or more than a "
                       "small mechanism's constraints)")
                self.warnings.append(f"backend 'compiled' asked for, but {why}: solved on "
                                     "numpy")
        return self._accel or None

    def _initial_positions(self) -> list[np.ndarray | None]:
        """The assembly at t0: the joints from the guesses, then every equation (drives
        included), each by damped Gauss-Newton with minimum-norm steps (the configuration
        nearest the guesses)."""
        sysm, opts = self.system, self.opts
        V = sysm.n_variants
        t = np.full((V, 1), self.times[0])
        guess = sysm.guess.reshape(V, 1, sysm.n)
        one = None
        k = self.kernels
        if V == 1 and k.scalar_kernels is not None:
            # a single mechanism on floats, by the kernels its integration uses
            ev, t0 = _Evaluator(k, self.D[0, 0]), float(self.times[0])

            def one(x: list) -> tuple[np.ndarray, np.ndarray]:
                return ev.phi_jac(t0, np.array(x))

        q1, ok1, _ = gauss_newton(k, guess, t, self.D, sysm.joint_rows, opts, one)
        if sysm.drive_rows.size:
            q2, ok2, _ = gauss_newton(k, q1, t, self.D, np.arange(sysm.m), opts, one)
        else:  # the joints are every equation
            q2, ok2 = q1, ok1
        # the initial statements closed too, and the guesses it moved reported
        from .initial import positions
        q2, notes = positions(k, q2, ok1 & ok2, t, self.D, opts)
        self.warnings.extend(notes)
        out: list[np.ndarray | None] = []
        for v in range(V):
            if ok1[v] and ok2[v]:
                out.append(q2[v, 0])
                continue
            phi = np.abs(eq.constraint_values(k, q2[v : v + 1], t[v : v + 1])[0, 0])
            worst = np.argsort(-np.nan_to_num(phi, nan=np.inf))[:3]
            self.failures.append(
                f"the mechanism cannot be assembled at t = {self.times[0]:g}"
                f"{variant_label(sysm, v)}: the equations of "
                f"{constraint_names(sysm, worst)} stay unsatisfied near the guesses; check "
                "the dimensions, or give guesses nearer the intended configuration")
            out.append(None)
        return out

    def _variant(self, v: int, q0: np.ndarray) -> str:
        from .driver import integrate
        from .integrators import INTEGRATORS, choose, stiff_method

        #: the system as variant v sees it: its params, its functions
        self.one, self.variant = _one(self.kernels, v), v
        self.ev = self._equations_of(v, q0)
        times, d = self.times, self.one.dynamics
        sysm = self.one.system
        n = sysm.n
        t0 = float(times[0])
        from .initial import velocities
        try:
            # v0 and the initial statements' rates onto the constraints, with the warnings
            qd0, notes = velocities(self.kernels, v, t0, q0, self.D[v, 0], self.opts)
            y0 = None
            y0 = self._projector()(t0, np.concatenate((q0, qd0)))
            self.ev.accelerations(t0, y0[:n], y0[n:])  # singular at the start?
        except np.linalg.LinAlgError:
            self.failures.append(self._singular_message(v, t0, y0))
            return "failed"
        self.warnings.extend(notes)

        V = self.system.n_variants
        t1, budget = float(times[-1]), self.opts.max_steps
        # a display that can show the steps is fed by them (see :meth:`run`); one output
        # interval can take millions of steps, during which the instants stand still
        motion = getattr(self.progress, "motion", None)
        on_step = None
        if motion is not None:
            def on_step(t: float, steps: int) -> None:
                # positional: a third of the cost of binding keywords, at every step
                motion(t, steps, t0, t1, v, V, budget)

        def record(k: int, t: float, y: np.ndarray, raw: bool = False) -> None:
            self._record(k, t, y, raw)
            if self.progress is not None and motion is None:  # the variants in turn
                self.progress((v * len(times) + k + 1) // V, len(times))

        def record_all(k: int, ts: np.ndarray, ys: np.ndarray, raw: bool) -> None:
            """The outputs k .. k + len(ts) - 1 at once (as :func:`record` each)."""
            end = k + len(ts)
            self.states["y"][k:end] = ys
            self.raw[k:end] = raw
            self.n_solved[v] = end
            if self.progress is not None and motion is None:  # (at every instant, as above)
                for j in range(k, end):
                    self.progress((v * len(times) + j + 1) // V, len(times))

        K = len(times)
        #: the states at the output instants, written as outputs when the variant ends
        #: ("q" and "qd" views of "y", the integrated states (q, qd): one row an instant)
        y_out = np.full((K, 2 * n), np.nan)
        self.states = {"y": y_out, "q": y_out[:, :n], "qd": y_out[:, n:],
                       "qdd": np.full((K, n), np.nan), "lambda": np.full((K, sysm.m), np.nan),
                       "W": np.full(K, np.nan)}
        #: the instants kept as the dense output gave them, projected when the variant ends
        self.raw = np.zeros(K, dtype=bool)
        #: the dense equations stopped at a singular position met on the way: the variant's
        #: instants are then completed one by one, by the augmented Lagrangian
        self.singular_met = False
        scale = np.concatenate((self.D[v, 0], self.D[v, 0]))
        try:
            equations = (self.ev if isinstance(self.ev, _augmented())
                         else _Equations(self.ev, self._project, self._settle, self._impulse))
            stiff = None
            if self.opts.method == "auto" and not INTEGRATORS[self.method].implicit:
                implicit = stiff_method()
                if implicit is not None:
                    stiff = (implicit, lambda: _augmented()(self.one, self.opts))
            on_interval = self._dissipation_integral()
            # the drives' jumps in rate, found before the run: each step over one is
            # integrated again up to it and the run goes on from the impulsive motion
            # there (radau, which keeps the constraints, passed them by steps that shrank
            # to them: a pendulum on a crank whose speed jumps, 1.9e-4 rad off at rtol 1e-6)
            ahead = tuple(self._rate_jumps(equations, self.atol * float(np.max(scale))))
            sol = integrate(INTEGRATORS[self.method], equations, y0, times,
                            rtol=self.rtol, atol=self.atol, scale=scale, on_output=record,
                            on_step=on_step, max_steps=budget, stiff=stiff,
                            on_interval=on_interval, raw_outputs=self._batched(),
                            jumps_ahead=ahead, on_outputs=record_all)
            if sol.switched is not None:
                name, at, why = sol.switched
                self.switches.append(
                    f"{name} from t = {at:.6g}{variant_label(sysm, v)}, where the model "
                    f"proved stiff ({why})")
            if sol.note:
                self.switches.append(f"{sol.note}{variant_label(sysm, v)}")
            if sol.status == "failed" and sol.reason not in ("budget", "jump") and \
                    equations is not self.ev:
                # the dense index-1 solve needs Phi_q of full rank: a singular position
                # met on the way (a parallelogram's collinear one) stops it. The variant
                # goes on by the augmented Lagrangian, which passes it, from the last
                # output instant reached (from t0 it did the same work twice: a
                # Scott-Russell mechanism whose first stall came at t = 117 s of 200)
                at = float(sol.t_reached)
                self.ev = _augmented()(self.one, self.opts)
                self.singular_met = True
                method = self.method
                if self.opts.method == "auto":
                    # the pair the automatic choice takes on the augmented Lagrangian
                    # through singular positions, as for redundant constraints (a
                    # parallelogram driven through its collinear position 540 times in
                    # 3 s by a spring of 1e6 N m/rad, rtol 1e-8: dop853 20.8 s, its energy
                    # kept to 5.9e-7; vern9 31.1 s, 8.5e-7)
                    method = choose("auto", self.rtol, dopri5_from=self.opts.dopri5_from,
                                    large=self.large, redundant=True)[0]
                stopped = sol.message
                sol, t_from = self._go_on(v, sol, method, scale, record, on_step, budget,
                                          ahead)
                self.warnings.append(
                    f"the dense equations of motion stopped near t = {at:.6g}"
                    f"{variant_label(sysm, v)} ({stopped}); the variant went on from t = "
                    f"{t_from:.6g} by the augmented Lagrangian"
                    + (f" with {method}" if method != self.method else "")
                    + ", which passes singular positions")
                if method != self.method:
                    self.switches.append(
                        f"{method} on the augmented Lagrangian{variant_label(sysm, v)}, where "
                        f"a singular position stopped the dense equations at t = {at:.6g}")
                equations = self.ev
        finally:  # an interrupt too: the instants solved are written, complete
            self._write(v)
        if sol.rough:
            listed = ", ".join(f"{r:.6g}" for r in sol.rough[:3]) + (
                f" and {len(sol.rough) - 3} more" if len(sol.rough) > 3 else "")
            self.warnings.append(
                f"the output instant{'s' if len(sol.rough) > 1 else ''} t = {listed}"
                f"{variant_label(sysm, v)} lie{'' if len(sol.rough) > 1 else 's'} inside a "
                "step over a singular position, where its interpolant is far off the "
                "constraints, and no step could end there to integrate it again: reported "
                "as the interpolant gave it, projected (the velocities may be off by more "
                "than the tolerance; move the output instant or tighten --rtol)")
        jumps = self._jumps(sol, equations, scale, ahead)
        if jumps and sol.status != "failed":
            self.warnings.append(
                f"{jumps_text(sysm, jumps)}{variant_label(sysm, v)}; the motion went on from "
                "the constraints' impulsive motion there (the velocities' mass-orthogonal "
                f"projection): {_JUMP_VELOCITY}")
        if sol.status == "ok" and self.to_refine:
            self._refine_extremes(v, equations, scale)
        # the instants kept: those integrated, less any that could not be projected (_write)
        k = min(len(sol.t), int(self.n_solved[v]))
        if sol.status == "failed" and sol.reason == "budget":
            self.failures.append(
                f"the forward dynamics{variant_label(sysm, v)} used up its budget of "
                f"{budget:,} steps at t = {sol.t_reached:.10g} of {t0:g} .. {t1:g} "
                f"({sol.steps:,} steps accepted, {sol.rejected:,} rejected); the "
                f"{f'{k} output instants' if k != 1 else 'output instant'} integrated before "
                f"it, to t = {self.times[k - 1] if k else t0:.10g}, "
                f"{'are' if k != 1 else 'is'} kept in the results. Raise the budget with "
                f"--max-steps N (SolverOptions(max_steps=N)), or shorten the span or loosen "
                f"--rtol")
        elif sol.status == "failed":
            t_fail = float(self.times[k - 1]) if k else t0
            self.failures.append(
                f"the forward dynamics stopped after t = {t_fail:.10g}"
                f"{variant_label(sysm, v)}: {sol.message}"
                + (f"; {jumps_text(sysm, jumps)}: {_JUMP_POSITION}"
                   if any(j.level == "position" for j in jumps) else
                   f"; {jumps_text(sysm, jumps)}: {_JUMP_VELOCITY}" if jumps else
                   self._implicit_note(sol, equations, v)))
        return sol.status

    def _implicit_note(self, sol, equations, v: int) -> str:
        """What to do where the implicit method's step underflowed (``sol``: the driver's
        Solution, of variant ``v``): at redundant constraints or a singular position, the explicit pairs on
        the augmented Lagrangian (the automatic choice); "" elsewhere."""
        from .integrators import INTEGRATORS

        sysm = self.kernels.system
        if not (INTEGRATORS[self.method].implicit and "underflow" in sol.message):
            return ""
        if self.redundant or sysm.m >= sysm.n:
            return f"; {_IMPLICIT_REDUNDANT}"
        ratio = _singular_ratio(equations, sol.t_reached, sol.y_reached, self.D[v, 0])
        return f"; {_IMPLICIT_SINGULAR.format(ratio=ratio)}" if ratio < SINGULAR_NEAR else ""

    def _rate_jumps(self, equations, floor: float) -> list:
        """The jumps of the drives' rates f'(t) between the output instants
        (:mod:`mechdsl.solve.jumps`): where a sampled change departs from both its
        neighbours' by more than the tolerance ``floor`` and a thousand times the drive's
        median departure (a smooth rate's departures are its curvature times the step
        squared), located to round-off; the few intervals found are examined, not the run.
        The implicit stepper, which keeps the constraints at its stages, passes such a jump
        by steps that shrink to it, and no projection shows it."""
        from .jumps import MAX_ROWS, departures, time_jumps

        nu = getattr(equations, "nu", None)
        T = self.times
        if nu is None or not self.one.system.drive_rows.size or len(T) < 4:
            return []
        with np.errstate(all="ignore"):
            rates = eq.drive_values(self.one, T[None, :], "fd", (1, len(T)))[0]
        departs = np.nan_to_num(departures(np.diff(rates, axis=0)))
        found: dict[int, object] = {}
        for column in departs.T:
            limit = max(floor, 1e3 * float(np.median(column)))
            for k in np.flatnonzero(column > limit)[:MAX_ROWS]:
                for j in time_jumps(None, nu, float(T[k]), float(T[k + 1]), floor):
                    found.setdefault((j.row, j.t), j)
        # every jump of every row (a ramp that starts and stops has two: the run meets
        # both, jumps_ahead); the report names each row once (_jumps)
        return sorted(found.values(), key=lambda j: j.t)

    def _jumps(self, sol, equations, scale: np.ndarray, ahead: tuple = ()) -> list:
        """The constraints that jump in time (:mod:`mechdsl.solve.jumps`): those the driver
        met (``sol.jumps``), and where the integration failed (not for its budget) those
        around the instant it reached (radau's step underflows at a drive's step), and in a
        run that ended well the drives' jumps in rate, found before it (``ahead``,
        :meth:`_rate_jumps`); one per row."""
        from .jumps import constraint_jumps

        floor = self.atol * float(np.max(scale))
        found = list(sol.jumps)
        if sol.status == "failed" and sol.reason != "budget" and len(sol.y) and \
                self.system.m:
            t, span = float(sol.t_reached), float(self.times[-1] - self.times[0])
            width = max(1e-3 * span, 1e-9)
            found += constraint_jumps(equations, sol.y[-1][:self.system.n],
                                      max(t - width, float(self.times[0])),
                                      min(t + width, float(self.times[-1])), floor)
        elif sol.status == "ok":
            found += ahead
        rows: dict[int, object] = {}
        for j in found:
            rows.setdefault(j.row, j)
        return sorted(rows.values(), key=lambda j: j.t)

    def _go_on(self, v: int, sol, method: str, scale: np.ndarray, record: Callable,
               on_step: Callable | None, budget: int, ahead: tuple = ()):
        """Variant v integrated on by the augmented Lagrangian (``self.ev``) with
        ``method``, from the last output instant the dense attempt ``sol`` reached (its
        state projected onto the constraints anew), to the end, over the jumps known
        ``ahead``: (the two attempts' solution as one, that instant)."""
        from dataclasses import replace

        from .driver import integrate
        from .integrators import INTEGRATORS

        times, n = self.times, self.one.system.n
        k = max(len(sol.t), 1) - 1  # the output instant the run goes on from
        t_k = float(times[k])
        try:
            y_k = self._projector()(t_k, np.asarray(sol.y[k], dtype=float))
        except np.linalg.LinAlgError:  # (that state not closed: from t0, as assembled)
            k, t_k = 0, float(times[0])
            y_k = np.concatenate((self.states["q"][0], self.states["qd"][0]))
        self.n_solved[v] = k

        def shifted(j: int, t: float, y: np.ndarray, raw: bool = False) -> None:
            record(k + j, t, y, raw)

        spent = sol.steps + sol.rejected
        again = integrate(INTEGRATORS[method], self.ev, y_k, times[k:], rtol=self.rtol,
                          atol=self.atol, scale=scale, on_output=shifted, on_step=on_step,
                          max_steps=max(budget - spent, 1),
                          on_interval=self._dissipation_integral(start=k),
                          jumps_ahead=ahead)
        y_before = np.asarray(sol.y[:k]).reshape(k, 2 * n)
        return replace(
            again, t=np.concatenate((np.asarray(sol.t[:k]), again.t)),
            y=np.concatenate((y_before, again.y.reshape(len(again.t), 2 * n))),
            steps=sol.steps + again.steps, rejected=sol.rejected + again.rejected,
            evaluations=sol.evaluations + again.evaluations, njev=sol.njev + again.njev,
            nlu=sol.nlu + again.nlu,
            jumps=tuple(j for j in sol.jumps if j.t <= t_k) + again.jumps,
            rough=tuple(r for r in sol.rough if r < t_k) + again.rough), t_k

    def _dissipation_integral(self, start: int = 0):
        """Where an output asks for ``dissipated_energy``: the callback of each accepted step
        (t_a, t_b, dense) that integrates the dissipated power P(q, qd, t) over it by
        Gauss-Legendre's 5 points on the step's dense output (exact for polynomials of degree
        9, beyond the order of every method's interpolant), adding W(t_b) = W(t_a) +
        int P, and W at each output instant inside the step; W(t0) = 0, or from output
        ``start`` on, W there as integrated before. None otherwise."""
        if not self.system.reads("dissipated_energy"):
            return None
        times, n, d = self.times, self.one.system.n, self.one.dynamics
        W = self.states["W"]
        W[start + 1:] = np.nan  # (``start``: an integration going on from output start)
        if start == 0:
            W[0] = 0.0
        nodes, weights = np.polynomial.legendre.leggauss(GAUSS_POINTS)
        state = {"total": float(W[start]), "next": start + 1}

        def integral(a: float, b: float, dense) -> float:
            if b <= a:
                return 0.0
            ts = 0.5 * (a + b) + 0.5 * (b - a) * nodes
            y = np.array([dense(float(s)) for s in ts])  # (points, 2n)
            p = d.dissipated_power(y[None, :, :n], y[None, :, n:], ts[None])[0]
            return 0.5 * (b - a) * float(weights @ p)

        def on_interval(a: float, b: float, dense) -> None:
            k = state["next"]
            while k < len(times) and times[k] <= b:
                W[k] = state["total"] + integral(a, float(times[k]), dense)
                k += 1
            state["next"] = k
            state["total"] += integral(a, b, dense)
        return on_interval

    def _refine_extremes(self, v: int, equations, scale: np.ndarray) -> None:
        """Variant v's extremes of the reduced columns between the samples
        (:mod:`mechdsl.solve.extrema`'s candidates and parabolic refinement), each trial
        instant read from the dense output of an integration again from the output state
        before the candidate to the one after it, at the run's tolerances: the extreme to
        the integrator's accuracy. A variant's pairs not refined keep the samples'."""
        times = self.times
        K, V = len(times), self.system.n_variants
        specs = {o.label: o for o in self.one.system.outputs}
        brackets: dict = {}  # (lo, hi) -> the dense output between (each integrated once)
        for label, sense in sorted(self.to_refine):
            y = sense * self.data[label][v]
            out = self.extrema.setdefault((label, sense), (np.full(V, np.nan),
                                                           np.full(V, np.nan)))
            if K < 2 or not np.isfinite(y).all():
                continue
            ks, done = extrema._candidates(y[None], times)
            best_f, best_t = [], []
            for k, finished in zip(ks[0], done[0]):
                f, t = float(y[k]), float(times[k])
                if not finished:
                    try:
                        f, t = self._refine_one(k, y, sense, specs[label], equations, scale,
                                                brackets)
                    except (np.linalg.LinAlgError, ArithmeticError, ValueError):
                        pass  # the sample stands
                best_f.append(f)
                best_t.append(t)
            best_f, best_t = np.array(best_f), np.array(best_t)
            j = int(extrema.first_best(best_f[None], best_t[None], np.abs(y).max(),
                                       max(extrema.TIE, extrema.TIE_RTOL * self.rtol))[0])
            out[0][v], out[1][v] = sense * best_f[j], best_t[j]

    def _refine_one(self, k: int, y: np.ndarray, sense: int, spec, equations,
                    scale: np.ndarray, brackets: dict) -> tuple[float, float]:
        """The extreme of sense * the column ``spec`` near output instant k and its time."""
        from .driver import integrate
        from .integrators import INTEGRATORS

        times, n, st = self.times, self.one.system.n, self.states
        K = len(times)
        lo, hi = max(k - 1, 0), min(k + 1, K - 1)
        segments = brackets.get((lo, hi))
        if segments is None:  # (each bracket integrated once, for every column's extremes)
            segments = []
            start = np.concatenate((st["q"][lo], st["qd"][lo]))
            sol = integrate(INTEGRATORS[self.method], equations, start, times[lo:hi + 1],
                            rtol=self.rtol, atol=self.atol, scale=scale,
                            max_steps=self.opts.max_steps,
                            on_interval=lambda a, b, dense: segments.append((a, b, dense)))
            if sol.status != "ok":
                segments = []
            brackets[(lo, hi)] = segments
        if not segments:
            return float(y[k]), float(times[k])

        def at(t) -> float:
            t = float(t)
            dense = next((d for a, b, d in segments if a <= t <= b), segments[-1][2])
            state = np.asarray(dense(t), dtype=float)
            q, qd = state[:n], state[n:2 * n]
            qdd, lam = self.ev.accelerations(t, q, qd)
            value = eq.output_values(self.one, spec, q[None, None], qd[None, None],
                                     qdd[None, None], np.array([[t]]),
                                     {"lambda": lam[None, None]})
            return sense * float(value[0, 0])

        a, b = float(times[lo]), float(times[hi])
        m = float(times[k]) if 0 < k < K - 1 else 0.5 * (a + b)
        # (the dense output is a smooth polynomial in each step: its extremum is found as
        # the kinematics' is, the value then within the integrator's tolerance)
        best_t, best_f = extrema.search(at, a, m, b, float(y[lo]), at(m), float(y[hi]),
                                        False, float(np.abs(y).max()),
                                        extrema.XTOL * max(abs(times[-1] - times[0]), 1e-300))
        # never below the sample
        return max((float(best_f), float(best_t)), (float(y[k]), float(times[k])))

    def _batched(self) -> bool:
        """Whether the output instants are settled together when the variant ends
        (:mod:`mechdsl.solve.instants`: dense matrices, Phi_q of full rank): a model of few
        equations without redundant constraints, whose variant met no singular position
        (there the saddle-point matrices are ill conditioned: the augmented Lagrangian's
        one-state solves take those instants), integrated on the dense index-1 equations.
        Not on the augmented Lagrangian (radau, large or redundant models): it passes
        singular positions without failing, and there a saddle-point matrix nearly singular
        passes the batched solve too (A02 under radau: a reaction of 3.8e8 N at a collinear
        passage where the one-state solve gives -35 N)."""
        sysm = self.one.system
        return (sysm.n + sysm.m <= BATCH_MAX and not self.redundant
                and not self.singular_met and not isinstance(self.ev, _augmented()))

    def _record(self, k: int, t: float, y: np.ndarray, raw: bool = False) -> None:
        """Keep the state at output instant k (``raw``: as the dense output gave it, for
        :meth:`_complete` to project)."""
        self.states["y"][k] = y
        self.raw[k] = raw
        self.n_solved[self.variant] = k + 1

    def _complete(self, v: int) -> None:
        """The instants variant ``v`` has solved, completed: those kept raw projected (all at
        once where :meth:`_batched`, else one by one; an instant that cannot be projected
        ends the variant there), their accelerations and multipliers where an output (order
        2: an acceleration, a load) or the kept rates need them, and the largest constraint
        residual of the run."""
        k = int(self.n_solved[v])
        st, n, opts = self.states, self.one.system.n, self.opts
        T = self.times[:k]
        raw = np.flatnonzero(self.raw[:k])
        batched = self._batched()
        if raw.size:
            y = np.concatenate((st["q"][raw], st["qd"][raw]), axis=1)
            out = instants.project(self.one, self.D[v, 0], T[raw], y, opts.newton_tol,
                                   opts.max_iterations) if batched else None
            if out is None:
                out, project = np.empty_like(y), self._projector()
                for i, kk in enumerate(raw):
                    try:
                        out[i] = project(float(T[kk]), y[i])
                    except np.linalg.LinAlgError as err:
                        end = (f"end at t = {T[kk - 1]:.10g}" if kk else
                               "have no instant")
                        self.failures.append(
                            f"the forward dynamics' results"
                            f"{variant_label(self.one.system, v)} {end}: the state the "
                            f"integrator gave at t = {T[kk]:.10g} cannot be moved onto the "
                            f"constraints ({err})")
                        k, out, raw = int(kk), out[:i], raw[:i]
                        self.n_solved[v] = k
                        break
            st["q"][raw], st["qd"][raw] = out[:, :n], out[:, n:]
            self.raw[raw] = False
        if k == 0:
            return
        T, q, qd = T[:k], st["q"][:k], st["qd"][:k]
        if self.one.system.order >= 2 or self.keep_rates:
            solved = instants.accelerations(self.one, T, q, qd) if batched else None
            if solved is not None:
                st["qdd"][:k], st["lambda"][:k] = solved
            else:
                for i in range(k):
                    try:
                        st["qdd"][i], st["lambda"][i] = self.ev.accelerations(
                            float(T[i]), q[i], qd[i])
                    except np.linalg.LinAlgError:  # (NaN, not an earlier attempt's values)
                        st["qdd"][i], st["lambda"][i] = np.nan, np.nan
        if self.one.system.m:
            phi = eq.constraint_values(self.one, q[None], T[None])[0]
            self.residual = max(self.residual, float(np.abs(phi).max()))

    def _write(self, v: int) -> None:
        """The outputs of variant ``v`` at the instants it has solved, all at once (first
        completed: :meth:`_complete`; a Ctrl-C there leaves what it did not finish NaN or
        unprojected, says so, and still writes the instants)."""
        try:
            self._complete(v)
        except KeyboardInterrupt:
            self.interrupted = True
            self.warnings.append(
                f"interrupted while the output instants{variant_label(self.one.system, v)} "
                "were completed: their accelerations and loads after the interrupt are "
                "missing (NaN), and some positions may be off the constraints by the "
                "integrator's tolerance")
        k = int(self.n_solved[v])
        if k == 0:
            return
        st = self.states
        q, qd, qdd = (st[name][None, :k] for name in ("q", "qd", "qdd"))
        T = self.times[None, :k]
        cache = {"lambda": st["lambda"][None, :k], "dissipated_energy": st["W"][None, :k]}
        for spec in self.one.system.outputs:
            self.data[spec.label][v, :k] = eq.output_values(self.one, spec, q, qd, qdd, T,
                                                            cache)[0]
        if self.poses is not None:
            self.poses[v, :k] = q[0]
        if self.pose_rates is not None:
            self.pose_rates[v, :k, 0], self.pose_rates[v, :k, 1] = qd[0], qdd[0]

    def _singular_message(self, v: int, t: float, y: np.ndarray | None = None) -> str:
        """Why the equations of motion of variant ``v`` cannot be solved at t (at the
        state y where known): loads that are not numbers there (the force elements on the
        bodies concerned named), else bodies without mass or inertia, else the constraints."""
        sysm, d = self.one.system, self.one.dynamics
        if y is not None:
            n = sysm.n
            with np.errstate(all="ignore"):
                load = d.generalised_forces(y[None, None, :n], y[None, None, n:],
                                            np.full((1, 1), t))[0, 0]
            bad = {sysm.body_names[k // 3] for k in np.flatnonzero(~np.isfinite(load))}
            if bad:
                forces = [f.name for f in d.forces if bad & set(f.bodies)]
                named = ", ".join(f"'{f}'" for f in forces[:5]) or "none of the forces"
                return (f"the loads on {', '.join(sorted(bad)[:5])} are not finite numbers at "
                        f"t = {t:g}{variant_label(sysm, v)}, from force "
                        f"{named}: the force element is undefined in this state (a division "
                        "by zero, a root of a negative number)")
        massless = [b + (" (no mass)" if d.mass[0, i] == 0 else " (no inertia)")
                    for i, b in enumerate(sysm.body_names)
                    if d.mass[0, i] == 0 or d.inertia[0, i] == 0]
        what = (f"bodies without mass or inertia ({', '.join(massless[:5])}) whose motion the "
                "constraints may not fix" if massless else "the constraints lock the "
                "mechanism or are redundant")
        return (f"the equations of motion are singular at t = {t:g}{variant_label(sysm, v)}: "
                f"{what}; give every free body a mass and an inertia")


class _Equations:
    """The equations of one variant as a stepper sees them
    (:class:`mechdsl.solve.stepper.Equations`): the evaluator's right-hand side and terms,
    the run's projections. (Bound methods held as attributes: the steppers call them at
    every stage.) Any object with ``rhs`` and ``project`` (``settle`` and ``carry``
    optional) can take its place in :meth:`DynamicRun._variant`."""

    def __init__(self, ev: "_Evaluator", project: Callable, settle: Callable,
                 impulse: Callable) -> None:
        self.n, self.m = ev.n, ev.m
        self.rhs = ev.derivative
        self.project, self.settle = project, settle
        self.phi_jac, self.nu, self.accelerations = ev.phi_jac, ev.nu, ev.accelerations
        self.impulse = impulse
        self.scale = ev.D  # the coordinates' scale (the model's lengths, radians)

    def carry(self, y: np.ndarray, f: np.ndarray) -> np.ndarray:
        """y' = (qd, qdd): after a correction of y, its first half is the corrected qd
        exactly; qdd is kept from before it."""
        n = self.n
        out = f.copy()
        out[:n] = y[n:]
        return out

    def stalled(self, t: float, y: np.ndarray) -> str | None:
        """Why the steps stall at (t, y) (mechdsl.solve.driver, "stalls"), where the reason
        is a singular position: Phi_q's smallest singular value below
        :data:`SINGULAR_STALL` times its largest, which these equations, needing Phi_q of
        full rank, cannot pass; None otherwise."""
        ratio = _singular_ratio(self, t, y, self.scale)
        if not ratio < SINGULAR_STALL:
            return None
        return (f"the steps stalled at t = {t:.10g} at a singular position: the constraints' "
                f"Jacobian's smallest singular value is {ratio:.1e} of its largest")


def _singular_ratio(equations, t: float, y: np.ndarray | None, scale: np.ndarray) -> float:
    """sigma_min / sigma_max of Phi_q D at the positions of y (1 without constraints or
    state), D the coordinates' ``scale`` (as the rank at the assembly is judged: a model
    in millimetres is not near-singular for its units): how near (t, y) is to a singular
    position."""
    if y is None or not equations.m:
        return 1.0
    G = equations.phi_jac(t, y[:equations.n])[1]
    G = G.toarray() if hasattr(G, "toarray") else np.atleast_2d(np.asarray(G, float))
    sigma = np.linalg.svd(G * scale, compute_uv=False)
    return float(sigma[-1] / sigma[0]) if sigma[0] > 0 else 0.0


def _augmented() -> type:
    """:class:`mechdsl.solve.motion.Motion`, imported where a run needs it."""
    from .motion import Motion

    return Motion


def _one(kernels: Kernels, v: int) -> Kernels:
    """The kernels as variant ``v`` alone sees them (its params), for the outputs."""
    if kernels.system.n_variants == 1:
        return kernels
    one = kernels.variant(v)
    # the one-state kernels read the params as arguments: every variant runs the code
    # generated once for the sweep (Andrews, 30 variants: 10 ms a variant less)
    one.__dict__["scalar_kernels"] = kernels.scalar_kernels
    return one


def _solve(dgesv: Callable, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x = b by LAPACK's ``dgesv`` (scipy's, passed in: 9 us on Andrews' 41 x 41 system,
    against np.linalg.solve's 20, whose checks cost more than the arithmetic; importing it at
    every call would cost as much again); LinAlgError where a is singular."""
    _, _, x, info = dgesv(a, b)
    # x @ x: one call where np.isfinite(x).all() takes two (a solution beyond 1e154, which
    # overflows it and is reported as singular, is no more use than an infinite one)
    if info != 0 or not math.isfinite(x.ravel() @ x.ravel()):
        raise np.linalg.LinAlgError("singular matrix")
    return x


def _min_norm(dgesv: Callable, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The minimum-norm solution of a x = b for a of full row rank: a^T (a a^T)^-1 b (the
    least-squares one where a a^T is singular)."""
    try:
        return a.T @ _solve(dgesv, a @ a.T, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(a, b, rcond=None)[0]


class _Evaluator:
    """Phi, Phi_q, nu, gamma, M and Q of one variant at one state. Where the model is
    traced constraint by constraint (the member layout), by the scalar kernels of its graphs
    (:func:`mechdsl.symbolic.codegen.scalar_kernel`: Python floats, a few microseconds for a
    small mechanism, against a microsecond per numpy operation on arrays of one state);
    otherwise, or where a scalar kernel meets a value outside a function's domain, by the
    array kernels."""

    def __init__(self, kernels: Kernels, D: np.ndarray, compiled=None) -> None:
        # scipy.linalg is imported by the forward dynamics only (0.1 s of start-up)
        from scipy.linalg.lapack import dgesv, dpotrf, dpotrs

        from ..symbolic.codegen import scalar_functions

        system = kernels.system
        self.dgesv, self.dpotrf, self.dpotrs = dgesv, dpotrf, dpotrs
        self.system, self.kernels, self.D = system, kernels, D
        #: the compiled accel of the backend (mechdsl.compiled.native), or None
        self.compiled = compiled
        f, d = kernels.fused, kernels.dynamics
        self.n, self.m = n, m = system.n, system.m
        scalar = kernels.scalar_kernels
        self.scalar = scalar is not None
        if self.scalar:
            self.k_phi_jac, self.k_motion, fixed = scalar
            self.p = first_floats(f.params)
            self.F = scalar_functions(f.functions)
            self.pd = first_floats(d.params)
            self.Fd = scalar_functions(d.functions)
            self.p_arr, self.pd_arr = np.array(self.p), np.array(self.pd)
            rows, cols = f.rows, f.cols
            self.jac_flat = rows * n + cols
            big = n + m
            #: where the entries of Phi_q, Phi_q^T and M go in the augmented matrix
            aug = np.concatenate(((rows + n) * big + cols, cols * big + rows + n,
                                  d.rows * big + d.cols))
            given = np.isnan(fixed)
            #: where the motion kernel's entries go, in its order; [Q; gamma] follows
            self.aug = aug[given]
            self.n_out = len(self.aug) + big
            self.a = np.zeros((big, big))
            self.a.flat[aug[~given]] = fixed[~given]
            self.motion = functools.partial(self.k_motion.fn, t=None, p=(self.p, self.pd),
                                            F=(self.F, self.Fd))
        self.drive_rows = system.drive_rows

    def _drives(self, t: float, which: str) -> np.ndarray:
        T = np.full((1, 1), t)
        return eq.drive_values(self.kernels, T, which, (1, 1))[0, 0]

    def phi_jac(self, t: float, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Phi(q, t) (m,) and Phi_q (m, n)."""
        n, m = self.n, self.m
        if self.scalar:
            try:
                out = self.k_phi_jac(q.tolist(), (), t, self.p, self.F)
                phi = np.array(out[:m])
                jac = np.zeros(m * n)
                jac[self.jac_flat] = out[m:]
                jac = jac.reshape(m, n)
                if self.drive_rows.size:
                    phi[self.drive_rows] -= self._drives(t, "f")
                return phi, jac
            except (ValueError, ZeroDivisionError, OverflowError):
                pass
        Q3, T2 = q[None, None], np.full((1, 1), t)
        with np.errstate(all="ignore"):
            return (eq.constraint_values(self.kernels, Q3, T2)[0, 0],
                    eq.jacobian(self.kernels, Q3)[0, 0])

    def nu(self, t: float) -> np.ndarray:
        out = np.zeros(self.m)
        if self.drive_rows.size:
            out[self.drive_rows] = self._drives(t, "fd")
        return out

    def _scalar_solve(self, t: float, q: list, qd: list) -> np.ndarray:
        """[qdd; lambda] by the motion kernel on floats and LAPACK."""
        # fromiter with its dtype: np.array would inspect each float first (1 us more)
        vals = np.fromiter(self.motion(q, qd, t=t), float, self.n_out)
        k = len(self.aug)
        # the same positions every time: the other entries stay zero
        self.a.flat[self.aug] = vals[:k]
        rhs = vals[k:]
        if self.drive_rows.size:
            rhs[self.n + self.drive_rows] += self._drives(t, "fdd")
        return _solve(self.dgesv, self.a, rhs)

    def derivative(self, t: float, y: np.ndarray) -> np.ndarray:
        """y' = (qd, qdd) at y = (q, qd): the integrator's right-hand side."""
        n = self.n
        if self.scalar and self.compiled is None:
            try:
                listed = y.tolist()
                out = np.empty(2 * n)
                out[:n] = y[n:]
                out[n:] = self._scalar_solve(t, listed[:n], listed[n:])[:n]
                return out
            except (ValueError, ZeroDivisionError, OverflowError):
                pass
        qdd, _ = self.accelerations(t, y[:n], y[n:])
        return np.concatenate((y[n:], qdd))

    def accelerations(self, t: float, q: np.ndarray, qd: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """qdd (n,) and lambda (m,) from [M Phi_q^T; Phi_q 0][qdd; lambda] = [Q; gamma]."""
        n, m = self.n, self.m
        big = n + m
        if self.compiled is not None:
            qdd, lam = np.empty(n), np.empty(m)
            if not self.compiled(t, q, qd, self.p_arr, self.pd_arr, qdd, lam):
                raise np.linalg.LinAlgError("singular matrix")
            return qdd, lam
        if self.scalar:
            try:
                sol = self._scalar_solve(t, q.tolist(), qd.tolist())
                return sol[:n], sol[n:]
            except (ValueError, ZeroDivisionError, OverflowError):
                pass
        k, d = self.kernels, self.kernels.dynamics
        Q3, Qd3, T2 = q[None, None], qd[None, None], np.full((1, 1), t)
        with np.errstate(all="ignore"):
            jac = eq.jacobian(k, Q3)[0, 0]
            gamma = eq.acceleration_rhs(k, Q3, Qd3, T2)[0, 0]
            mass = d.mass_matrix(Q3)[0, 0]
            load = d.generalised_forces(Q3, Qd3, T2)[0, 0]
        a = np.zeros((big, big))
        a[:n, :n] = mass
        a[:n, n:] = jac.T
        a[n:, :n] = jac
        sol = np.linalg.solve(a, np.concatenate((load, gamma)))
        return sol[:n], sol[n:]
