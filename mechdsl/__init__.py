"""mechdsl: kinematics of planar mechanisms described in ``.mech`` files.

The pipeline, one module per stage: :mod:`~mechdsl.parse` (text -> model),
:mod:`~mechdsl.compile` (model + plugins -> system), :mod:`~mechdsl.solve` (system -> results),
:mod:`~mechdsl.results` (CSV), :mod:`~mechdsl.plot` (figures).
"""

from .api import Mechanism, load, loads
from .errors import MechError, NumericalError

__version__ = "0.1.0"
__all__ = ["Mechanism", "MechError", "NumericalError", "load", "loads", "__version__"]
