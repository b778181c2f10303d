"""The contract of a solver method: a run object, built for one compiled system and called once.

A method is a subclass of :class:`Run`, listed by name in :data:`mechdsl.solve.run.METHODS`
(the kinematic march of a fully driven mechanism is the only one today; integrators of the
dynamics will sit beside it, sharing the equations of :mod:`mechdsl.compiled.equations` and
the factorisations of :mod:`mechdsl.solve.linalg`). To add one:

1. Subclass :class:`Run` and give it a ``name``; add it to ``METHODS``.
2. ``__init__(system, options, *, poses, rates, progress, extra_memory)`` takes the compiled
   system and the :class:`~mechdsl.solve.options.SolverOptions`, calls ``super().__init__``
   (options for the model's size, the time grid, the column scale D), checks that the method
   applies to the system (a MechError that names what is missing, as
   :func:`mechdsl.solve.mobility.count_check` does) and refuses a run whose memory would
   exceed ``options.max_memory`` (:func:`mechdsl.solve.memory.plan`), before anything the size of
   the run is allocated. Nothing is solved yet.
3. ``run()`` solves every instant of ``system.times`` for every variant and returns
   :meth:`results`. It raises nothing for what can happen while solving: a numerical failure
   stops its variant (a message in :attr:`failures`, status "failed"), an interrupt
   (KeyboardInterrupt) the run (status "interrupted"); the instants solved before are kept
   in every case. (No plugin code runs while solving: a type's equations are traced when
   the model is compiled.)
4. The run is the only mutable state of a solve: the last solved state of each variant, the
   output arrays :attr:`data` (V, K) it fills, the instants each variant has solved
   (:attr:`n_solved`), and what the user should be told (:attr:`failures`,
   :attr:`warnings`). The system is never modified.
5. ``progress(done, total)``, if given, is called with the instants solved so far as the run
   goes on.

Shapes follow :mod:`mechdsl.compiled.equations`: V variants, b instants of a block, n
coordinates, m equations; states are (V, b, n), times (V, b).
"""

from __future__ import annotations

from typing import Callable, ClassVar

import numpy as np

from ..compiled.kernels import Kernels
from ..errors import MechError
from ..results import Results
from .diagnose import col_scale
from .options import SolverOptions

#: The progress callback: progress(instants_done, instants).
Progress = Callable[[int, int], None]


class Run:
    """One run of a solver method over a compiled system (see the module's contract)."""

    #: The method's name in :data:`mechdsl.solve.run.METHODS`.
    name: ClassVar[str] = ""

    def __init__(self, kernels: Kernels, options: SolverOptions | None = None, *,
                 progress: Progress | None = None) -> None:
        system = kernels.system
        if system.times is None:
            raise MechError("the system was compiled without a time grid")
        self.system, self.kernels = system, kernels
        #: The options, with the condition limits for the model's size
        #: (:meth:`~mechdsl.solve.options.SolverOptions.for_size`).
        self.opts = (options or SolverOptions()).for_size(system.n_bodies)
        self.times: np.ndarray = system.times
        self.progress = progress
        #: (V, 1, n): the column scale of every scaled quantity (L for x and y, 1 for phi).
        self.D = col_scale(system)
        self.data: dict[str, np.ndarray] = {}
        self.n_solved = np.zeros(system.n_variants, int)
        self.failures: list[str] = []
        self.warnings: list[str] = []

    def run(self) -> Results:  # pragma: no cover - the contract
        raise NotImplementedError

    def results(self, status: str, solve_time: float, *, residual: float = 0.0,
                condition: np.ndarray | None = None, poses: np.ndarray | None = None,
                rates: np.ndarray | None = None, method: str = "") -> Results:
        """What the run solved, as :class:`~mechdsl.results.Results`: the output arrays, how
        the run ended and what the user should know."""
        system = self.system
        return Results(
            times=self.times, data=self.data, sweep=dict(system.sweep), n_solved=self.n_solved,
            status=status, messages=tuple(self.failures), solve_time=solve_time,
            residual=residual, source_name=system.source.name,
            warnings=(*system.warnings, *self.warnings), condition=condition, poses=poses,
            rates=rates,
            units={o.label: o.unit for o in system.outputs if o.unit},
            time_unit=system.time_unit, method=method)
