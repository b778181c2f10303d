"""The plugin API: everything a joint, drive or force plugin imports from mechdsl.

>>> from mechdsl.plugins import ConstraintType, Arg, hookimpl, geometry

See ``docs/plugins.md`` for the contract and a worked example.
"""

from . import geometry
from .contract import REQUIRED, Arg, ArgError, ConstraintType
from .force import ForceType
from .hookspecs import hookimpl
from .manager import ENTRY_POINT_GROUP, build_registry
from .registry import BrokenPlugin, Provider, Registry
from .version import CONTRACT_VERSION

__all__ = [
    "REQUIRED", "Arg", "ArgError", "ConstraintType", "ForceType", "hookimpl", "geometry",
    "ENTRY_POINT_GROUP", "build_registry", "BrokenPlugin", "Provider", "Registry",
    "CONTRACT_VERSION",
]
