"""The hook specifications of mechdsl: the whole interface between the core and a plugin.

A plugin is a module (or object) with functions marked ``@hookimpl``, registered through an
entry point in the ``mechdsl`` group (see :mod:`mechdsl.plugins.manager`). The built-in joints
are plugins of exactly this kind, in their own distributions.
"""

from __future__ import annotations

from typing import Sequence

import pluggy

from .contract import ConstraintType
from .force import ForceType

PROJECT = "mechdsl"
hookspec = pluggy.HookspecMarker(PROJECT)
#: Mark a plugin's hook functions with ``@hookimpl``.
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def mechdsl_constraint_types() -> Sequence[ConstraintType]:
    """Return the joint and drive types this plugin provides (instances of
    :class:`~mechdsl.plugins.contract.ConstraintType` subclasses).

    Called once, when the registry is built, never during a solve. A type's name must be
    unique among the types of its kind (``joint`` or ``drive``) across all plugins.
    """


@hookspec
def mechdsl_force_types() -> Sequence[ForceType]:
    """Return the force types this plugin provides (instances of
    :class:`~mechdsl.plugins.force.ForceType` subclasses): springs, dampers, applied forces
    and torques, used as ``force NAME: TYPE(args)``. Called once, like
    :func:`mechdsl_constraint_types`; a force type's name must be unique among force types.
    """
