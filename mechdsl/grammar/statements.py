"""The statements of a ``.mech`` file as the parser hands them to the checks
(:mod:`mechdsl.grammar.checks`): one small frozen class each, matched by class. The model's
own nodes (:class:`~mechdsl.grammar.model.Param`, ``Joint``, ``Simulate``, ...) come
wrapped where the checks also need where their name is written (:class:`Declared`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ..errors import Span


@dataclass(frozen=True)
class Declared:
    """A param, joint, drive, initial, force, sweep or a body's point (``node``) and its
    name's span."""

    node: object
    name_span: Span


@dataclass(frozen=True)
class BodyItem:
    """Any other item of a body: ``kind`` one of guess, shape, density, mass, inertia,
    centroid, v0; its value and span."""

    kind: str
    value: object
    span: Span


@dataclass(frozen=True)
class GroundDecl:
    """``ground { ... }``."""

    items: tuple
    span: Span


@dataclass(frozen=True)
class BodyDecl:
    """``body NAME { ... }``."""

    name: str
    name_span: Span
    items: tuple
    span: Span


@dataclass(frozen=True)
class GravityDecl:
    """``gravity = (gx, gy)``."""

    vector: object
    span: Span


@dataclass(frozen=True)
class PluginLine:
    """``plugin "module"``."""

    module: str
    span: Span


@dataclass(frozen=True)
class OutputList:
    """``output ...``: its items."""

    items: tuple


@dataclass(frozen=True)
class TraceList:
    """``trace ...``: its items."""

    items: tuple


@dataclass(frozen=True)
class UnitsDecl:
    """``units length = "m", ...``: (dimension, unit, span) each."""

    units: tuple
    span: Span


@dataclass(frozen=True)
class OptimizeDecl:
    """``optimize l in 2.5 .. 4, ...``: (name, low, high, name span) each."""

    word: ClassVar[str] = "optimize"
    ranges: tuple
    span: Span


@dataclass(frozen=True)
class ObjectiveDecl:
    """``minimize EXPR`` or ``maximize EXPR`` (``sense``)."""

    word: ClassVar[str] = "minimize/maximize"
    sense: str
    expr: object
    span: Span


@dataclass(frozen=True)
class RequirementDecl:
    """``subject to EXPR, ...``."""

    word: ClassVar[str] = "subject to"
    exprs: tuple
    span: Span
