"""mechdsl: kinematics of planar mechanisms described in ``.mech`` files.

The pipeline, one package per stage, each importing only the stages before it:
:mod:`~mechdsl.grammar` (text -> model), :mod:`~mechdsl.compiled` (model + plugins ->
system), :mod:`~mechdsl.solve` (system -> :mod:`~mechdsl.results`), :mod:`~mechdsl.outputs`
(CSV, plots, drawings, exports). :mod:`~mechdsl.api` joins them; :mod:`~mechdsl.cli` is the
command line.
"""

from .api import CheckReport, Mechanism, load, loads
from .errors import MechError, NumericalError
from .outputs.store import open_store

__version__ = "0.1.0"
__all__ = ["CheckReport", "Mechanism", "MechError", "NumericalError", "load", "loads",
           "open_store", "__version__"]
