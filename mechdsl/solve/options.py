"""The solver's tolerances and limits, each a named field with its default."""

from __future__ import annotations

from dataclasses import dataclass
from numbers import Integral

from ..memory import DEFAULT_MAX_MEMORY


@dataclass(frozen=True)
class SolverOptions:
    """Tolerances and limits of the solver. Lengths are relative to the model's length scale
    L (its largest point coordinate or guessed position); angles are in radians."""

    #: Newton-Raphson stops when its step is at most this (|dx|/L, |dy|/L, |dphi|). The
    #: position error after that step is of the order of its square.
    newton_tol: float = 1e-10
    #: Newton-Raphson also stops when the error left after its step, estimated from the
    #: quadratic contraction of its last two steps as |dq_k|^3 / |dq_(k-1)|^2 (scaled as
    #: newton_tol), is at most this: the step that would only confirm convergence is saved.
    newton_error: float = 1e-18
    #: A Newton step at most this (scaled as newton_tol) shows that the position it starts
    #: from is solved to round-off: the step is taken and the factorisation it was computed
    #: with is kept as the final one (the rates solved with it are exact to round-off)
    #: instead of evaluating and factorising the Jacobian once more. The compiled march's
    #: predictor usually lands within it, so that most instants take one evaluation;
    #: measured on the seed, 5e-16 leaves the rates within 6e-16 of the closed form where
    #: 1e-15 left them within 1.2e-15 (two evaluations at every instant: 4.9e-16).
    settled_step: float = 5e-16
    #: A large mechanism's simplified Newton (:mod:`mechdsl.solve.large`) may stall at the
    #: noise of its equations, above settled_step (steps below newton_tol that stop
    #: contracting); its position then counts as solved if the Newton step of the Jacobian
    #: factorised there is noise too: at most this multiple of the larger of the last two
    #: steps (noise steps of one instant scatter within a factor of 3 on a row of 1001
    #: bodies). Else the careful march solves the instant.
    noise_scatter: float = 4.0
    #: ... and counts as stalled at noise only where those last two steps are at most this
    #: and newton_tol (scaled as newton_tol): a larger stall is a slow or diverging
    #: iteration, for the careful march. (A row of 1001 bodies stalls between 1e-14 and
    #: 3e-13.)
    noise_floor: float = 1e-12
    #: The reductions max, min, argmax, argmin and range of a kinematic run refine each
    #: extremum between the samples, by kinematic solves at the instants it needs
    #: (:mod:`mechdsl.solve.extrema`); False: the extremes of the samples.
    refine_extrema: bool = True
    #: Forward dynamics: the integrator's relative and absolute error tolerances per step (the
    #: absolute one scaled as newton_tol: lengths by L, velocities by L per unit time). None:
    #: the ``simulate`` statement's ``rtol = ..., atol = ...``, else 1e-8 and 1e-10; a value
    #: given here (``--rtol``, ``--atol``) overrides the file's.
    rtol: float | None = None
    atol: float | None = None
    #: Forward dynamics: the integrator, a name in :data:`mechdsl.solve.integrators.INTEGRATORS`
    #: ("vern9", Verner's 9(8) pair; "dop853", Dormand and Prince's 8(5,3); "dopri5", their
    #: 5(4); ...) or "auto" (:func:`mechdsl.solve.integrators.choose`): dopri5 where rtol is
    #: at least ``dopri5_from``, vern9 below (the lower-order pair takes the fewest
    #: evaluations for a loose tolerance, the highest-order one for a tight one).
    method: str = "auto"
    #: The rtol from which "auto" integrates with dopri5.
    dopri5_from: float = 1e-4
    #: Forward dynamics: the integrator's step budget per variant, accepted and rejected
    #: steps together; a variant that uses it up stops there (a numerical failure, the
    #: output instants integrated before it kept). Real runs stay far below it: the
    #: examples take tens to a few thousand steps (Andrews' mechanism as written 58, at
    #: rtol 1e-12 170; a pendulum over 100 periods at rtol 1e-12, tests/test_dynamics.py,
    #: 3,832), so the default leaves a margin of 250 over the longest, room for 26,000
    #: pendulum periods or 6,000 times Andrews' span at rtol 1e-12, and stops a runaway
    #: (a span of 1e12 s, a tolerance nothing can meet) after 7 to 22 minutes (0.4 to 1.3
    #: ms a step on numpy) instead of never.
    max_steps: int = 1_000_000
    #: Forward dynamics by radau: a model of at most this many coordinates is integrated in
    #: relative coordinates (each body's frame in its parent's, :mod:`mechdsl.solve.relative`),
    #: where a stiff force between jointed bodies keeps its direction and one Jacobian serves
    #: many steps (the stiff pendulum at k = 1e8: 44 steps instead of 134); a larger one in
    #: the absolute coordinates, whose matrices stay sparse. 0: always absolute.
    relative_max: int = 30
    #: Forward dynamics: the BLAS threads while it integrates a model of at least
    #: ``augmented_band_from`` coordinates (:mod:`mechdsl.solve.threads`: its many small
    #: factorisations lose by more threads, most on a busy machine; a smaller model's are
    #: below the sizes at which BLAS starts threads); 0 leaves the BLAS library's setting.
    blas_threads: int = 1
    #: Forward dynamics by the augmented Lagrangian (:mod:`mechdsl.solve.motion`): the penalty
    #: kappa, each equation's term in M + Phi_q^T W Phi_q relative to the mass it constrains.
    #: Larger contracts the iteration faster (a factor 1 / (1 + kappa sigma) per iteration,
    #: sigma the mechanism's conditioning) and nearer singular positions; smaller keeps that
    #: matrix better conditioned (about kappa times M's). Bayo and Ledesma use 1e7 to 1e9.
    #: Measured on IFToMM A02 (DOP853 at rtol 1e-10 on the index-1 form, projected every
    #: 0.01 s, 20 s; benchmarks/a02_motion.py), B0's error at t = 20 for N = 40: 1e7 fails
    #: (a projection at a collinear passage does not close), 1e8 1.3e-4 m, 1e9 2.8e-3,
    #: 1e10 3.5e-2; for N = 4: 1e6 fails, 1e8 4.4e-7, 1e10 2.7e-8.
    augmented_penalty: float = 1e8
    #: ... its iteration stops when |Phi_q qdd - gamma|_2 is at most this times the scale
    #: |gamma|_2 + | |Phi_q| |qdd| |_2 (the sizes of the terms the residual sums: forming
    #: it rounds a few 1e-16 of that; in the band storage the force balance too), or after
    #: ``augmented_max_iterations`` (Andrews: qdd within 1.2e-13 of the dense solve after
    #: two iterations, 1.5e-15 after three, which this asks for).
    augmented_tol: float = 1e-14
    #: ... and at most this many iterations: near a singular position, where it contracts
    #: slowly, the accelerations are this iterate, a smooth blend of the two branches (at
    #: 20 the blend is narrower and steeper, and A02 stops at a passage at rtol 1e-8)
    augmented_max_iterations: int = 12
    #: ... and where it stops contracting (near a singular position), conjugate gradients on
    #: the multipliers may take over for at most this many iterations (about one per
    #: direction of small singular value: A02's N windows). Off (0) by default: they solve
    #: the saddle-point system exactly to within 1e-9 rad of A02's collinear position
    #: (5e-8 relative there), but that exact index-1 right-hand side amplifies the drift of
    #: an integrated state near the bifurcation without bound, and DOP853 then stops at
    #: the first passage (step size underflow); the stalled penalty iteration keeps the
    #: accelerations bounded there, and passes all twenty.
    augmented_krylov_iterations: int = 0
    #: ... from this many coordinates on, M + Phi_q^T W Phi_q is factorised in LAPACK's band
    #: storage in reverse Cuthill-McKee order (cost linear in the bodies of a chain), below
    #: with the dense LU of the regularised saddle-point matrix (cheaper for small n: on
    #: chains of links, measured by thread CPU time per evaluation, dense 68 / band 80 us
    #: at n = 30, 104 / 97 at 45, 131 / 99 at 60, 271 / 119 at 90).
    augmented_band_from: int = 40
    #: Newton iterations allowed per attempt at an instant.
    max_iterations: int = 12
    #: Assembly stops when its step is at most this (scaled as newton_tol).
    assembly_tol: float = 1e-10
    #: Largest scaled residual (each equation divided by the norm of its Jacobian row) that
    #: counts as assembled.
    assembly_residual: float = 1e-8
    #: Gauss-Newton iterations allowed for the assembly.
    assembly_max_iterations: int = 200
    #: Largest assembly step (scaled as newton_tol: a fraction of L, or radians), so that the
    #: assembly moves from the guesses to the nearest closure rather than leap to another.
    assembly_max_step: float = 0.2
    #: A solved state whose scaled Jacobian has a reciprocal condition number (1-norm) below
    #: this is a singular position: the run stops there rather than write velocities and
    #: accelerations solved with a (nearly) singular matrix. For more than 10 bodies, this
    #: and warn_rcond are divided by (bodies / 10)^2 (see :meth:`for_size`).
    singular_rcond: float = 1e-8
    #: A solved state whose reciprocal condition number falls below this is near a singular
    #: position: the run goes on, with a warning naming the instant.
    warn_rcond: float = 1e-5
    #: At a singular position (dead point, change point): "stop" with an error, or "continue"
    #: on the branch the motion was on (the smooth continuation of the path so far). At an
    #: instant exactly on the singular position, velocities and accelerations are then
    #: completed along the Jacobian's null space from their predicted values, to O(step).
    at_singular: str = "stop"
    #: A position, velocity or acceleration that is not a finite number (a drive whose
    #: derivative is unbounded, such as sqrt(t) at t = 0; a plugin returning NaN): "stop" the
    #: variant there with a numerical failure naming the quantity and the instant, or "keep"
    #: it in the results and go on.
    nonfinite: str = "stop"
    #: Largest accepted ratio of Newton's correction to the predictor over the motion since
    #: the last solved state. Above it the interval is bisected; if the position is still
    #: discontinuous at the finest bisection, the solution has jumped branch.
    branch_ratio: float = 0.5
    #: Order of the Taylor predictor that starts Newton at each instant from the last state:
    #: 1 (q + tau qd) or 2 (+ tau^2/2 qdd). (Order 0 is not offered: the branch check
    #: measures Newton's correction against the predicted motion.)
    predictor_order: int = 2
    #: Instants solved together at most, and at the start.
    max_block: int = 256
    initial_block: int = 8
    #: Parallel-in-time march: every this-many-th instant is solved first (a coarse march),
    #: then levels that split every gap by ``level_split``, each solved all at once from the
    #: quintic Hermite interpolation of the states before; 1 turns it off. The levers
    #: section of benchmarks/bench.py measures its effect.
    coarse_stride: int = 128
    #: Parallel-in-time march: each level splits the gaps between solved instants into this
    #: many parts.
    level_split: int = 16
    #: Newton's tolerance (scaled as newton_tol) in the coarse march of the parallel-in-time
    #: march of a sweep; its states are only starting points, corrected to newton_tol all at
    #: once. (A single mechanism's coarse march runs on floats and solves each of its few
    #: states to newton_tol at once: :mod:`mechdsl.solve.single`.)
    coarse_newton_tol: float = 1e-2
    #: Instants handled per window of the parallel-in-time march (the granularity at which a run
    #: that is interrupted keeps its results).
    window: int = 4096
    #: Which code solves a fully driven mechanism: "numpy" (the default path, no compiler
    #: needed), "compiled" (the model's generated code compiled by numba, the ``fast``
    #: extra; where it does not apply, numpy) or "auto": compiled for runs of at least
    #: ``compiled_from`` states (variants times instants) when numba is installed, so that
    #: a small run never pays for importing or compiling it.
    backend: str = "auto"
    #: The size of run from which "auto" chooses the compiled backend.
    compiled_from: int = 100_000
    #: Cap on V * b * m * n, the size of a batched Jacobian (lowered to fit max_memory).
    max_batch_elements: int = 2**22
    #: Peak resident memory of the whole process, in bytes: a run estimated to need more
    #: is refused before it starts (:mod:`mechdsl.memory`).
    max_memory: int = DEFAULT_MAX_MEMORY
    #: From this many coordinates (3 per moving body) on, a mechanism without redundant
    #: constraints is solved with sparse LU (SuperLU), one state at a time, instead of dense
    #: batched linear algebra; the scaling section of benchmarks/bench.py measures the cross-over.
    sparse_from: int = 90
    #: Sparse systems: simplified Newton reuses the last state's factorised Jacobian while
    #: each step is at most this fraction of the one before; beyond, it refactorises.
    reuse_ratio: float = 0.2
    #: Halvings of the substep before a failing instant before the failure is reported.
    max_bisections: int = 12
    #: Substeps allowed to cross one output interval; past them the step is too coarse for
    #: the motion, an error.
    max_substeps: int = 400

    def for_size(self, n_bodies: int) -> "SolverOptions":
        """The options for a mechanism of ``n_bodies``: the condition limits divided by
        (n_bodies / 10)^2 above 10 bodies. The condition number of a healthy mechanism grows
        with its size (as N^2 for a chain of N loops, like a discretised bar), so a fixed limit
        would call a long regular chain singular; a dead point still drives it to infinity."""
        factor = max(1.0, (n_bodies / 10.0) ** 2)
        if factor == 1.0:
            return self
        from dataclasses import replace
        return replace(self, singular_rcond=self.singular_rcond / factor,
                       warn_rcond=self.warn_rcond / factor)

    def derived(self, **changes) -> "SolverOptions":
        """A copy with ``changes`` that the solver derived from valid options (a batch cap,
        the backend it chose), without checking every option again as ``replace`` does."""
        new = object.__new__(SolverOptions)
        new.__dict__.update(self.__dict__, **changes)
        return new

    def __post_init__(self) -> None:
        if not 0 < self.newton_tol <= 1e-4:
            raise ValueError(f"newton_tol must be in (0, 1e-4], not {self.newton_tol!r}")
        for name in ("rtol", "atol"):
            if getattr(self, name) is not None and not 0 < getattr(self, name) < 1:
                raise ValueError(f"{name} must be in (0, 1), not {getattr(self, name)!r}")
        if not 0 <= self.settled_step <= 1e-13:
            raise ValueError(f"settled_step must be in [0, 1e-13], not {self.settled_step!r}")
        if not 1 <= self.noise_scatter <= 100:
            raise ValueError(f"noise_scatter must be in [1, 100], not {self.noise_scatter!r}")
        if not 0 <= self.noise_floor <= 1e-6:
            raise ValueError(f"noise_floor must be in [0, 1e-6], not {self.noise_floor!r}")
        if not 0 < self.coarse_newton_tol <= 1e-1:
            raise ValueError("coarse_newton_tol must be in (0, 0.1], not "
                             f"{self.coarse_newton_tol!r}")
        if self.predictor_order not in (1, 2):
            raise ValueError(f"predictor_order must be 1 or 2, not {self.predictor_order!r}")
        if self.at_singular not in ("stop", "continue"):
            raise ValueError(f"at_singular must be 'stop' or 'continue', not {self.at_singular!r}")
        if self.method != "auto":
            from .integrators import validate  # the registry: the steppers' names

            validate(self.method)
        if not (isinstance(self.relative_max, int) and self.relative_max >= 0):
            raise ValueError(f"relative_max must be an integer >= 0, not {self.relative_max!r}")
        if not 0 < self.dopri5_from <= 1:
            raise ValueError(f"dopri5_from must be in (0, 1], not {self.dopri5_from!r}")
        if self.backend not in ("auto", "numpy", "compiled"):
            raise ValueError(f"backend must be 'auto', 'numpy' or 'compiled', not "
                             f"{self.backend!r}")
        if self.nonfinite not in ("stop", "keep"):
            raise ValueError(f"nonfinite must be 'stop' or 'keep', not {self.nonfinite!r}")
        if not 0 < self.singular_rcond < 1:
            raise ValueError(f"singular_rcond must be in (0, 1), not {self.singular_rcond!r}")
        if not 0 < self.max_memory < 2**63:
            raise ValueError(f"max_memory must be a positive number of bytes, not "
                             f"{self.max_memory!r}")
        for name in ("max_iterations", "assembly_max_iterations", "max_block", "initial_block",
                     "max_batch_elements", "coarse_stride", "window", "compiled_from"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1")
        for name in ("max_steps", "blas_threads"):  # 1e6 as the command line takes it
            value = getattr(self, name)
            if isinstance(value, float) and value.is_integer():
                object.__setattr__(self, name, int(value))
        # a count of steps: a float (nan above all) would let a run go on without end
        if (isinstance(self.max_steps, bool) or not isinstance(self.max_steps, Integral)
                or self.max_steps < 1):
            raise ValueError(f"max_steps must be a whole number of steps, at least 1, not "
                             f"{self.max_steps!r}")
        if (isinstance(self.blas_threads, bool) or not isinstance(self.blas_threads, Integral)
                or self.blas_threads < 0):
            raise ValueError(f"blas_threads must be a whole number, at least 0, not "
                             f"{self.blas_threads!r}")
        if not 1 <= self.augmented_penalty <= 1e12:
            raise ValueError(f"augmented_penalty must be in [1, 1e12], not "
                             f"{self.augmented_penalty!r}")
        if not 0 < self.augmented_tol < 1e-4:
            raise ValueError(f"augmented_tol must be in (0, 1e-4), not {self.augmented_tol!r}")
        if self.augmented_max_iterations < 1 or self.augmented_krylov_iterations < 0:
            raise ValueError("augmented_max_iterations must be at least 1 and "
                             "augmented_krylov_iterations not negative")
        if self.level_split < 2:
            raise ValueError("level_split must be at least 2")


def raised_to(rtol: float, atol: float, rtol_min: float, atol_min: float
              ) -> tuple[float, float, list[str]]:
    """(rtol, atol) raised to ``rtol_min``, ``atol_min`` where below them, and the values
    asked for that were raised ("rtol 1e-12", ...), for the line that says so."""
    asked = [f"{name} {value:g}" for name, value, low in
             (("rtol", rtol, rtol_min), ("atol", atol, atol_min)) if value < low]
    return max(rtol, rtol_min), max(atol, atol_min), asked
