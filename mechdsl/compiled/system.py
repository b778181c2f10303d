"""The compiled system: what the solver needs, as frozen dataclasses of index arrays.

Shapes: V sweep variants (1 without a sweep), J constraints of a group, n = 3 * (number of
moving bodies) coordinates, m equations. Per-variant values are stored with a singleton axis
after V -- params ``(V, 1)``, group values ``(V, 1, J, ...)`` -- so that they broadcast against
solver arrays of shape ``(V, b, ...)`` for a block of b instants.
"""

from __future__ import annotations

import bisect
import functools
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from ..errors import Source, Span
from ..grammar import expr as E
from ..plugins.contract import ConstraintType
from .shapes import MassProperties
from .sparse import Pattern


@dataclass(frozen=True)
class Constraint:
    """One joint or drive: what the user called it, where, and which rows of Phi it owns."""

    name: str
    kind: str
    type_name: str
    span: Span
    rows: tuple[int, int]
    bodies: tuple[str, ...]


@dataclass(frozen=True)
class Group:
    """All constraints of one type, packed: the solver evaluates them with one call."""

    ctype: ConstraintType
    members: tuple[int, ...]
    slots: np.ndarray
    params: Mapping[str, np.ndarray]
    rows: np.ndarray


@dataclass(frozen=True)
class OutputSpec:
    """One output column: quantity ``quantity`` of ``body`` or of a point fixed in it."""

    label: str
    body: int
    point: np.ndarray | None
    quantity: str
    order: int
    #: its unit, from the model's ``units`` statement ("" where none is given)
    unit: str = ""
    #: the factor from the computed value to the reported one (180/pi for an angle reported
    #: in degrees; 1 for a column only read by others)
    scale: float = 1.0


@dataclass(frozen=True)
class ExprOutput:
    """One output column computed by an expression (``output slide = ...``, or its exact
    time derivatives): ``expr`` evaluated on the params, ``t`` and the output quantities
    ``inputs`` ((name in the expression, its column spec)), by the function compiled for it
    (:attr:`mechdsl.compiled.kernels.Kernels.expressions`). ``order`` is the highest time
    derivative of q the inputs need."""

    label: str
    inputs: tuple[tuple[str, OutputSpec], ...]
    order: int
    expr: E.Expr
    unit: str = ""
    scale: float = 1.0
    #: its dimension (:data:`mechdsl.compiled.units.Dim`; None where it is not known)
    dim: tuple | None = None


@dataclass(frozen=True)
class ReductionOutput:
    """One value per variant (``output peak = max(abs(slider.ax))``): ``expr`` evaluated
    on the params and on ``parts``, ``(name in the expression, reduction, output column)``:
    each a reduction (:data:`mechdsl.grammar.model.REDUCTIONS`) of a column of the run's
    ``outputs`` over its instants, by the function compiled for it
    (:attr:`mechdsl.compiled.kernels.Kernels.reductions`)."""

    label: str
    parts: tuple[tuple[str, str, str], ...]
    expr: E.Expr
    unit: str = ""
    scale: float = 1.0


@dataclass(frozen=True)
class ReactionOutput:
    """A load of constraint ``constraint`` from its Lagrange multipliers: a joint's reaction
    (``fx``, ``fy``, ``torque``) on moving body ``body`` (the torque about ``point`` (V, 1,
    2) of that body, or its origin when None); a drive's effort (``torque`` or ``force``,
    -lambda) or its ``power``."""

    label: str
    constraint: int
    quantity: str
    body: int
    point: np.ndarray | None = None
    order: int = 2
    unit: str = ""
    scale: float = 1.0


@dataclass(frozen=True)
class EnergyOutput:
    """The mechanism's kinetic energy 1/2 qd^T M qd (``order`` 1), the potential energy of
    gravity and of the force elements that write one (``order`` 0), the power its force
    elements dissipate or the energy they dissipated since t0 (``order`` 1; label says
    which)."""

    label: str
    order: int
    unit: str = ""
    scale: float = 1.0


@dataclass(frozen=True)
class Sketch:
    """What a drawing of the mechanism needs, in body frames; body index ``n_bodies`` is the
    ground. ``outlines[i]`` (V, P, 2): the points of body i in declaration order (its origin
    if it declares none), drawn as the polygon or polyline through them; ``pins``: (body,
    (V, J, 2)) the points that joints and drives attach, drawn as small circles; ``traces``:
    (label, body, (V, 2)) the points whose paths are drawn."""

    outlines: tuple[np.ndarray, ...]
    pins: tuple[tuple[int, np.ndarray], ...]
    traces: tuple[tuple[str, int, np.ndarray], ...]
    #: per body (the ground last), the edges (V, E, 2, 2) of its shape's outline, or None
    shapes: tuple[np.ndarray | None, ...] = ()
    #: force elements between two points (springs), drawn as zigzags: (body, (V, 2), body,
    #: (V, 2))
    links: tuple = ()
    #: lines that a point slides on (a type's ``guide``: a slider's rail, a slot), drawn over
    #: the point's travel: (body of the line, a point of it (V, 2), its direction (V, 2),
    #: body of the sliding point, that point (V, 2)), in the bodies' frames
    guides: tuple = ()
    #: the moving bodies' names, in order, and the name of each pin's joint (labels)
    names: tuple[str, ...] = ()
    pin_names: tuple[str, ...] = ()
    #: the unit of length (axes), "" where the model names none
    length_unit: str = ""
    #: ``trace ic(A, B)``: (label, body A, body B), the ground as ``n_bodies``
    centrodes: tuple[tuple[str, int, int], ...] = ()


@dataclass(frozen=True)
class Start:
    """What a forward-dynamics run needs to state where it starts
    (:mod:`mechdsl.solve.initial`). ``guessed`` (n,): the coordinates of the bodies that give
    a ``guess`` (the assembly warns where it moves them). Where the model has ``initial``
    statements, ``system`` is the model with each of them added as a drive after the others
    (their rows ``rows``, kind "initial" in ``system.constraints``, f(t) = value + rate (t -
    t0)), and ``rated`` (k,) says which give a rate (only those rows enter the projection
    of the initial velocities)."""

    guessed: np.ndarray
    system: "System | None" = None
    rows: np.ndarray | None = None
    rated: np.ndarray | None = None


@dataclass(frozen=True)
class System:
    """A compiled mechanism as plain data. Arrays are read-only; nothing here changes during
    a solve, and nothing here is code: the code generated for it is held by its
    :class:`~mechdsl.compiled.kernels.Kernels`."""

    source: Source
    body_names: tuple[str, ...]
    n: int
    m: int
    constraints: tuple[Constraint, ...]
    groups: tuple[Group, ...]
    drive_rows: np.ndarray
    env: Mapping[str, np.ndarray]
    sweep: Mapping[str, np.ndarray]
    n_variants: int
    guess: np.ndarray
    scale: np.ndarray
    times: np.ndarray | None
    outputs: tuple[OutputSpec | ExprOutput, ...]
    order: int = field(default=0)
    #: the non-zero entries of Phi_q (the order of the kernels' Jacobian values)
    pattern: Pattern | None = None
    #: the geometry that drawings and exports show
    sketch: Sketch | None = None
    #: per moving body, the mass properties of its shape, or None where it has none
    mass: tuple[MassProperties | None, ...] = ()
    #: the unit of time, from the model's ``units`` statement ("" where none is given)
    time_unit: str = ""
    #: the simulate statement's options (rtol, atol)
    tolerances: Mapping[str, float] = field(default_factory=dict)
    #: per-variant reductions of the ``outputs`` (which are then their inputs only)
    reductions: tuple[ReductionOutput, ...] = ()
    #: where a forward-dynamics run starts: guesses given, ``initial`` statements (None
    #: for a model without masses)
    start: Start | None = None
    #: warnings about the model's text (a unit mismatch in an output), located
    #: (:class:`mechdsl.errors.MechWarning`)
    warnings: tuple[str, ...] = ()

    def variant(self, v: int) -> "System":
        """The system restricted to sweep variant ``v``."""
        groups = tuple(replace(g, params={k: a.variant(v) if hasattr(a, "variant")
                                          else a[v : v + 1] for k, a in g.params.items()})
                       for g in self.groups)
        return replace(self, groups=groups, env={k: a[v : v + 1] for k, a in self.env.items()},
                       outputs=tuple(_output_variant(o, v) for o in self.outputs),
                       n_variants=1, scale=self.scale[v : v + 1], guess=self.guess[v : v + 1])

    def reads(self, label: str) -> bool:
        """Whether an output column is ``label`` (``dissipated_energy``) or an expression
        column reads it."""
        return any(o.label == label or any(s.label == label
                                           for _, s in getattr(o, "inputs", ()))
                   for o in self.outputs)

    @property
    def n_bodies(self) -> int:
        return len(self.body_names)

    @functools.cached_property
    def joint_rows(self) -> np.ndarray:
        """The equations that are not drives, in order (read-only)."""
        # a mask, not np.setdiff1d: that imports numpy.ma (10 ms of every start-up)
        mask = np.ones(self.m, bool)
        mask[self.drive_rows] = False
        rows = np.flatnonzero(mask)
        rows.flags.writeable = False
        return rows

    def row_owner(self, row: int) -> Constraint:
        """The joint or drive that owns equation ``row`` (by bisection: messages about large
        mechanisms ask for many rows)."""
        k = bisect.bisect_right(self._row_starts, row) - 1
        if k < 0 or row >= self.constraints[k].rows[1]:
            raise IndexError(row)
        return self.constraints[k]

    @functools.cached_property
    def _row_starts(self) -> list[int]:
        return [c.rows[0] for c in self.constraints]



def _output_variant(spec, v: int):
    """An output column's spec for variant ``v`` alone (its point's coordinates)."""
    if getattr(spec, "point", None) is not None:
        return replace(spec, point=spec.point[v : v + 1])
    if getattr(spec, "inputs", None):
        return replace(spec, inputs=tuple((name, _output_variant(s, v))
                                          for name, s in spec.inputs))
    return spec
