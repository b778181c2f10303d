"""The solver: a compiled system -> :class:`~mechdsl.results.Results`.

:func:`simulate` builds a run of a solver method and calls it. A method is a run object
(:mod:`.base`: the contract; :mod:`.run`: the registry of methods and the kinematic march of a
fully driven mechanism), the only mutable state of a solve. It is built from the assembly at
t0 (:mod:`.assembly`, with the mobility count of :mod:`.mobility`), Newton-Raphson on batches
of states (:mod:`.newton`), the factorisations of the Jacobian (:mod:`.linalg`), the levels of
the parallel-in-time march (:mod:`.levels`, :mod:`.hermite`), the passage of singular
positions (:mod:`.singular`) and the messages that name what failed (:mod:`.diagnose`), under
the tolerances and limits of :mod:`.options`.
"""

from .assembly import assemble
from .base import Run
from .options import SolverOptions
from .run import METHODS, KinematicRun, simulate

__all__ = ["METHODS", "KinematicRun", "Run", "SolverOptions", "assemble", "simulate"]
