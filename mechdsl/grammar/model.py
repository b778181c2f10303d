"""The model: what the user wrote, as frozen dataclasses, resolved to names, nothing solved.

Every node keeps the :class:`~mechdsl.errors.Span` it came from so that any later stage can
point at the source. Numbers stay expressions here (a point may be ``(-r/2, 0)``); they become
numbers per sweep variant when the model is compiled.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import Source, Span
from .expr import Expr

GROUND = "ground"
ORIGIN = "origin"

#: Output quantities of a body ``B.q`` and of a point ``B.P.q``; angles in radians.
BODY_QUANTITIES = ("x", "y", "phi", "vx", "vy", "omega", "ax", "ay", "alpha")
POINT_QUANTITIES = ("x", "y", "vx", "vy", "ax", "ay")
#: Output quantities of a joint ``J.q`` (its reaction on its last attached body) and of a
#: drive ``D.q`` (the actuator's effort, a torque or a force, and its power)
JOINT_QUANTITIES = ("fx", "fy", "torque")
DRIVE_QUANTITIES = ("torque", "force", "power")
#: The mechanism's energies, output quantities of their own: the power its force elements
#: dissipate (dampers), and its time integral over a forward-dynamics run
ENERGY_QUANTITIES = ("kinetic_energy", "potential_energy", "dissipated_power",
                     "dissipated_energy")
#: The options of the simulate statement: the forward dynamics' tolerances
SIMULATE_OPTIONS = ("rtol", "atol")
#: What a ``units`` statement names (the units of the others follow from these:
#: :mod:`mechdsl.compiled.units`), and the units angles may be reported in (they are written
#: and computed in radians)
UNIT_NAMES = ("length", "time", "mass", "angle", "force")
ANGLE_UNITS = ("rad", "deg")


@dataclass(frozen=True)
class Vector:
    """A parenthesised tuple of expressions, ``(x, y)`` or ``(x, y, phi)``."""

    items: tuple[Expr, ...]
    span: Span


@dataclass(frozen=True)
class Param:
    """``param NAME = value [in lo .. hi]``: the range, where given, is where a slider of
    ``mechdsl view`` moves (numbers, or expressions of numbers and earlier params)."""

    name: str
    value: Expr
    span: Span
    range: tuple[Expr, Expr] | None = None


@dataclass(frozen=True)
class Point:
    """A point fixed in its body, at ``coords`` in body coordinates."""

    name: str
    coords: Vector
    span: Span


@dataclass(frozen=True)
class Polygon:
    """``polygon((x1, y1), (x2, y2), ...)``: a shape's vertices in the body frame."""

    vertices: tuple[Vector, ...]
    span: Span


@dataclass(frozen=True)
class MeshFile:
    """``shape = "plate.msh"``: a mesh file as the model names it (``name``, relative to
    ``folder``, the folder of the ``.mech`` file); read when the model is compiled
    (:func:`mechdsl.compiled.files.read_files`), its errors located at ``span``."""

    name: str
    folder: str
    span: Span


@dataclass(frozen=True)
class Body:
    """A rigid body with q = (x, y, phi) of its frame; the ground is a body with ``is_ground``.
    ``shape`` is a Polygon, a MeshFile, or, once read, the mesh of that file
    (:class:`mechdsl.compiled.shapes.MeshShape`); ``density`` its mass per unit area."""

    name: str
    points: tuple[Point, ...]
    guess: Vector | None
    span: Span
    is_ground: bool = False
    shape: object | None = None
    density: Expr | None = None
    #: ``mass = m``, ``inertia = J`` (about the centre of mass), ``centroid = (x, y)``
    mass: Expr | None = None
    inertia: Expr | None = None
    centroid: Vector | None = None
    #: ``v0 = (vx, vy, omega)``: the initial velocity the forward dynamics starts nearest
    v0: Vector | None = None


@dataclass(frozen=True)
class Arg:
    """One argument of a joint or drive: positional (``name`` None) or ``name = value``."""

    name: str | None
    value: Expr | Vector
    span: Span


@dataclass(frozen=True)
class Element:
    """What joints, drives, initial statements and forces have in common: ``KIND NAME:
    TYPE(args)``, a plugin's type applied to arguments. ``span`` is the statement's,
    ``type_span`` its type name's."""

    name: str
    type_name: str
    args: tuple[Arg, ...]
    span: Span
    type_span: Span


@dataclass(frozen=True)
class Joint(Element):
    """``joint NAME: TYPE(args)``: the equations TYPE writes hold at every instant."""


@dataclass(frozen=True)
class Drive(Element):
    """``drive NAME: TYPE(args) = f(t)``: the measure that TYPE computes from q equals f(t)."""

    function: Expr


@dataclass(frozen=True)
class Initial(Element):
    """``initial NAME: TYPE(args) = value[, rate = r]``: the measure that the drive type TYPE
    computes from q equals ``value`` at t0, and its rate equals ``r`` where given: where a
    forward-dynamics run starts (:mod:`mechdsl.solve.initial`). Used for the assembly at t0
    only; after t0 the statement plays no role."""

    value: Expr
    rate: Expr | None


@dataclass(frozen=True)
class Force(Element):
    """``force NAME: TYPE(args)``: a force element (spring, damper, applied load)."""


@dataclass(frozen=True)
class Simulate:
    """``simulate t = t0 .. t1 step h``: the instants t0 + k h, both ends included;
    ``options``: the integrator's tolerances (``rtol = 1e-8, atol = 1e-10``) as (name,
    expression, span)."""

    t0: Expr
    t1: Expr
    step: Expr
    span: Span
    options: tuple[tuple[str, Expr, Span], ...] = ()


@dataclass(frozen=True)
class OutputRef:
    """A quantity or a group of quantities: ``B.x``, ``B.P.vy``, ``B`` (nine) or ``B.P`` (six)."""

    parts: tuple[str, ...]
    span: Span


#: The functions a ``trace`` statement may call, by name: what each draws.
TRACE_FUNCTIONS: dict[str, str] = {
    "ic": "the centrodes of body A relative to body B: the paths of their instant centre in "
          "B's frame (fixed centrode) and in A's (moving centrode)",
}


@dataclass(frozen=True)
class CentrodeTrace:
    """``trace ic(A, B)``: the centrodes of body A relative to body B (either may be the
    ground), drawn as traces. The instant centre I_AB is the point whose velocity is the
    same as a point of A and as a point of B,
    v_A + omega_A perp(r^I - r_A) = v_B + omega_B perp(r^I - r_B), perp(x, y) = (-y, x);
    its path in B's frame is the fixed centrode, in A's the moving centrode, which rolls
    without slipping on the fixed one. Where omega_A = omega_B it is at infinity."""

    a: str
    b: str
    span: Span
    #: where the names of A and B are written (None: where the span says)
    a_span: Span | None = None
    b_span: Span | None = None

    @property
    def label(self) -> str:
        return f"ic({self.a}, {self.b})"


@dataclass(frozen=True)
class NamedOutput:
    """``output NAME = EXPR``: a quantity of the user's, an expression of params, ``t`` and
    output quantities (``rod.phi``, ``lever.O.x``; written here as names such as
    ``Name("rod.phi")``), whose velocity and acceleration are derived exactly."""

    name: str
    expr: Expr
    span: Span
    name_span: Span


#: The reductions over the instants of a run, by name: what each gives per variant. A call
#: of one with one argument in an output makes it a per-variant value (``max(abs(slider.ax))``)
#: instead of a history; ``min``/``max`` with two or more arguments stay elementwise.
REDUCTIONS: dict[str, str] = {
    "max": "the largest value over the run",
    "min": "the smallest value over the run",
    "mean": "the time average over the run (trapezoidal rule)",
    "rms": "the root mean square over the run (trapezoidal rule)",
    "range": "the largest value minus the smallest",
    "initial": "the value at the first instant",
    "final": "the value at the last instant",
    "argmax": "the first instant at which the largest value is reached",
    "argmin": "the first instant at which the smallest value is reached",
}


@dataclass(frozen=True)
class Reduction:
    """``FUNC(EXPR)``: one of :data:`REDUCTIONS` of an expression of params, ``t`` and output
    quantities (names such as ``Name("slider.ax")``), over the instants of the run."""

    func: str
    expr: Expr
    span: Span


@dataclass(frozen=True)
class ReducedOutput:
    """An output with one value per variant: ``output NAME = EXPR`` or ``output
    max(abs(slider.ax))`` (named by its text), where ``expr`` is an expression of params and
    of the reductions, written there as ``Name("@0")``, ``Name("@1")``, ... for
    ``reductions[0]``, ``reductions[1]``, ..."""

    name: str
    expr: Expr
    reductions: tuple[Reduction, ...]
    span: Span
    name_span: Span


@dataclass(frozen=True)
class Optimization:
    """``optimize NAME in A .. B, ...``, ``minimize EXPR`` (or ``maximize``) and ``subject to
    EXPR >= EXPR, ...``: the params varied within their bounds (expressions of the params
    that are not varied), the objective and each requirement's slack as reductions
    (:class:`ReducedOutput`; a requirement ``g >= h`` holds where its slack g - h >= 0,
    ``g <= h`` where h - g >= 0)."""

    ranges: tuple[tuple[str, Expr, Expr, Span], ...]
    sense: str
    objective: "ReducedOutput | None"
    requirements: tuple["ReducedOutput", ...]
    span: Span


@dataclass(frozen=True)
class Sweep:
    """``sweep NAME = [v1, v2, ...]`` or ``sweep NAME = a .. b step h | count n``."""

    name: str
    values: tuple[Expr, ...] | None
    start: Expr | None
    stop: Expr | None
    step: Expr | None
    count: Expr | None
    span: Span


@dataclass(frozen=True)
class Model:
    """A whole ``.mech`` file. ``ground`` is always present (implicit when not declared)."""

    source: Source
    params: tuple[Param, ...]
    ground: Body
    bodies: tuple[Body, ...]
    joints: tuple[Joint, ...]
    drives: tuple[Drive, ...]
    simulate: Simulate | None
    #: the outputs in the order written: references (``B.x``, ``B``, ``B.P``) and named
    #: expressions
    outputs: tuple[OutputRef | NamedOutput | ReducedOutput, ...]
    sweeps: tuple[Sweep, ...]
    #: ``plugin "module"`` statements: modules to load as plugins, with where they are named.
    plugins: tuple[tuple[str, Span], ...] = ()
    #: ``trace body.P`` statements: points whose paths snapshots and animations draw, and
    #: ``trace ic(A, B)``: centrodes.
    traces: tuple[OutputRef | CentrodeTrace, ...] = ()
    #: ``units length = "m", time = "s", mass = "kg"``: the names of the units (labels, and
    #: the angle outputs' unit), as (dimension, name) pairs.
    units: tuple[tuple[str, str], ...] = ()
    #: The files the model reads (tables, meshes), as ``os.path.realpath`` gives them, each
    #: once, in the order of the text: outputs must never overwrite them.
    files: tuple[str, ...] = ()
    #: ``force NAME: TYPE(args)`` statements, in order
    forces: tuple[Force, ...] = ()
    #: ``gravity = (gx, gy)``
    gravity: Vector | None = None
    #: ``optimize``, ``minimize``/``maximize`` and ``subject to`` statements, if any
    optimization: Optimization | None = None
    #: ``initial NAME: TYPE(args) = value, rate = r`` statements, in order
    initials: tuple[Initial, ...] = ()
