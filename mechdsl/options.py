"""The solver's tolerances and limits, each a named field with its default."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SolverOptions:
    """Tolerances and limits of the solver. Lengths are relative to the model's length scale
    L (its largest point coordinate or guessed position); angles are in radians."""

    #: Newton-Raphson stops when its step is at most this (|dx|/L, |dy|/L, |dphi|). The
    #: position error after that step is of the order of its square.
    newton_tol: float = 1e-10
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
    #: accelerations solved with a (nearly) singular matrix.
    singular_rcond: float = 1e-8
    #: A solved state whose reciprocal condition number falls below this is near a singular
    #: position: the run goes on, with a warning naming the instant.
    warn_rcond: float = 1e-5
    #: At a singular position (dead point, change point): "stop" with an error, or "continue"
    #: on the branch the motion was on (the smooth continuation of the path so far). At an
    #: instant exactly on the singular position, velocities and accelerations are then
    #: completed along the Jacobian's null space from their predicted values, to O(step).
    at_singular: str = "stop"
    #: Largest accepted ratio of Newton's correction to the predictor over the motion since
    #: the last solved state. Above it the interval is bisected; if the position is still
    #: discontinuous at the finest bisection, the solution has jumped branch.
    branch_ratio: float = 0.5
    #: Instants solved together at most, and at the start.
    max_block: int = 256
    initial_block: int = 8
    #: Cap on V * b * m * n, the size of a batched Jacobian (memory bound).
    max_batch_elements: int = 2**22
    #: Halvings of the substep before a failing instant before the failure is reported.
    max_bisections: int = 12
    #: Substeps allowed to cross one output interval; past them the step is too coarse for
    #: the motion, an error.
    max_substeps: int = 400

    def __post_init__(self) -> None:
        if not 0 < self.newton_tol <= 1e-4:
            raise ValueError(f"newton_tol must be in (0, 1e-4], not {self.newton_tol!r}")
        if self.at_singular not in ("stop", "continue"):
            raise ValueError(f"at_singular must be 'stop' or 'continue', not {self.at_singular!r}")
        if not 0 < self.singular_rcond < 1:
            raise ValueError(f"singular_rcond must be in (0, 1), not {self.singular_rcond!r}")
        for name in ("max_iterations", "assembly_max_iterations", "max_block", "initial_block",
                     "max_batch_elements"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1")
