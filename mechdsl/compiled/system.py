"""The compiled system: what the solver needs, as frozen dataclasses of index arrays.

Shapes: V sweep variants (1 without a sweep), J constraints of a group, n = 3 * (number of
moving bodies) coordinates, m equations. Per-variant values are stored with a singleton axis
after V -- params ``(V, 1)``, group values ``(V, 1, J, ...)`` -- so that they broadcast against
solver arrays of shape ``(V, b, ...)`` for a block of b instants.
"""

from __future__ import annotations

import bisect
import functools
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from ..errors import Source, Span
from ..grammar import expr as E
from ..plugins.contract import ConstraintType
from .fused import Fused
from .lu import MAX_N, LUPlan, plan
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
class DriveFunction:
    """f(t), f'(t), f''(t) of one drive, compiled, with the trees they came from."""

    f: Callable
    fd: Callable
    fdd: Callable
    exprs: tuple[E.Expr, E.Expr, E.Expr]


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
    time derivatives): ``function`` evaluated on the params, ``t`` and the output quantities
    ``inputs`` ((name in the expression, its column spec)). ``order`` is the highest time
    derivative of q the inputs need."""

    label: str
    function: Callable
    inputs: tuple[tuple[str, OutputSpec], ...]
    order: int
    expr: E.Expr
    unit: str = ""
    scale: float = 1.0
    #: its dimension (:data:`mechdsl.compiled.units.Dim`; None where it is not known)
    dim: tuple | None = None


@dataclass(frozen=True)
class ReductionOutput:
    """One value per variant (``output peak = max(abs(slider.ax))``): ``function`` evaluated
    on the params and on ``parts``, ``(name in the expression, reduction, output column)``:
    each a reduction (:data:`mechdsl.grammar.model.REDUCTIONS`) of a column of the run's
    ``outputs`` over its instants."""

    label: str
    function: Callable
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
    """A compiled mechanism. Arrays are read-only; nothing here changes during a solve."""

    source: Source
    body_names: tuple[str, ...]
    n: int
    m: int
    constraints: tuple[Constraint, ...]
    groups: tuple[Group, ...]
    drive_rows: np.ndarray
    drive_functions: tuple[DriveFunction, ...]
    env: Mapping[str, np.ndarray]
    sweep: Mapping[str, np.ndarray]
    n_variants: int
    guess: np.ndarray
    scale: np.ndarray
    times: np.ndarray | None
    outputs: tuple[OutputSpec | ExprOutput, ...]
    order: int = field(default=0)
    #: the non-zero entries of Phi_q (the order of ``fused.jac``'s values)
    pattern: Pattern | None = None
    #: the compiled evaluation of Phi, Phi_q, gamma (:mod:`mechdsl.compiled.fused`)
    fused: Fused | None = None
    #: the geometry that drawings and exports show
    sketch: Sketch | None = None
    #: per moving body, the mass properties of its shape (shapes.MassProperties) or None
    mass: tuple = ()
    #: the unit of time, from the model's ``units`` statement ("" where none is given)
    time_unit: str = ""
    #: masses and loads (:mod:`mechdsl.compiled.dynamics`), where the model has any
    dynamics: object | None = None
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
    #: the model whose traced code this one runs with other values (compile_model's
    #: ``reuse``): its plans (the LU, the code on floats) serve this one too
    template: "System | None" = field(default=None, repr=False, compare=False)

    @functools.cached_property
    def lu(self) -> LUPlan | None:
        """The generated sparse LU of Phi_q (square systems), its pivot order chosen on the
        Jacobian at the first variant's guess (:mod:`mechdsl.compiled.lu`); None where that
        Jacobian is singular in its pattern. A model with a ``template`` takes the
        template's (the same pattern and code: a pivot that becomes small for these values
        falls back to partial pivoting, as one does over a run)."""
        if self.template is not None:
            return self.template.lu
        if self.fused is None or self.m != self.n or not 0 < self.n <= MAX_N:
            return None
        f = self.fused
        sample = f.evaluate_jac(self.guess[:, None, :])[0, 0]
        # the member layout's entries are one node each: those that are constants fold
        constants = ({k: float(d.value) for k, d in enumerate(f.jac_nodes)
                      if d.op == "const" and np.isfinite(float(d.value))}
                     if f.layout == "member" else None)
        return plan(f.rows, f.cols, self.n, sample, constants)

    @functools.cached_property
    def native(self):
        """The compiled module of this model (:mod:`mechdsl.compiled.native`: numba
        imported, the march compiled or loaded from the disk cache), or None where the
        backend does not apply or numba is missing. Loaded on first use only."""
        from . import native

        return native.load(self)

    @functools.cached_property
    def one_state(self):
        """A single mechanism's model as code on Python floats, for the steps of a solve that
        see one state at a time (:mod:`mechdsl.compiled.scalar`); None for a sweep, or where
        it does not apply."""
        if self.n_variants != 1:
            return None
        from .scalar import with_values

        if self.template is not None:
            one = self.template.state_code
            return None if one is None else with_values(one, self.fused)
        return self.state_code

    @functools.cached_property
    def state_code(self):
        """:attr:`one_state` of the first variant whatever the number of variants: the code
        a model compiled as a template (compile_model's ``reuse``) lends to the models that
        run it with other values."""
        from .scalar import one_state

        return one_state(self, 0)

    @functools.cached_property
    def scalar_kernels(self):
        """The forward dynamics' one-state kernels on floats
        (:func:`mechdsl.symbolic.codegen.scalar_kernel`): ``(phi_jac, motion, fixed)``.
        ``phi_jac`` gives Phi and Phi_q's entries. ``motion`` gives the entries of the
        augmented matrix [M Phi_q^T; Phi_q 0] in the order they are stored (Phi_q's entries,
        Phi_q^T's, M's) except the constant ones, then its right-hand side [Q; gamma];
        ``fixed`` holds, over that order, the value of each constant entry and NaN where
        ``motion`` gives it (a constant is stored once, not at every evaluation). None
        where the model is traced type by type (the group layout) or has no masses."""
        from ..symbolic.codegen import joint_scalar_kernel, scalar_kernel

        f, d = self.fused, self.dynamics
        if self.template is not None and d is not None and self.template.dynamics is not None \
                and d.graph is self.template.dynamics.graph:
            return self.template.scalar_kernels
        if f is None or d is None or f.layout != "member" or d.graph is None:
            return None
        nodes = [*f.jac_nodes, *f.gamma_nodes, *d.mass_nodes, *d.load_nodes]
        nnz, m, n_mass = len(f.jac_nodes), len(f.gamma_nodes), len(d.mass_nodes)
        jac, mass = range(nnz), range(nnz + m, nnz + m + n_mass)
        matrix = [*jac, *jac, *mass]
        fixed = np.array([float(nodes[k].value) if nodes[k].op == "const" else np.nan
                          for k in matrix], dtype=float)
        rhs = [*range(nnz + m + n_mass, len(nodes)), *range(nnz, nnz + m)]
        order = [k for k, c in zip(matrix, fixed) if np.isnan(c)] + rhs
        return (scalar_kernel(f.graph, [*f.phi_nodes, *f.jac_nodes], "phi_jac"),
                joint_scalar_kernel([(f.graph, [*f.jac_nodes, *f.gamma_nodes]),
                                     (d.graph, [*d.mass_nodes, *d.load_nodes])], "motion",
                                    order=order), fixed)

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

