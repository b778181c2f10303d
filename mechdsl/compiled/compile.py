"""Model + registry -> :class:`~mechdsl.compiled.system.System`: names resolved, numbers
evaluated.

Compiling resolves names (bodies, points, types, arguments, outputs) against the model and
the plugin registry, evaluates every number for every sweep variant (:mod:`.variants`), and
packs the constraints by type, so that the solver evaluates each type with one call for all
of its constraints, all instants of a block and all variants.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import MechError, MechWarning, Span, cut, suggest
from ..functions import ExprFunction
from ..grammar import expr as E
from ..grammar.checks import TIME, check_expr
from ..grammar.derive import derivative, total_derivative
from ..grammar.model import (
    BODY_QUANTITIES, DRIVE_QUANTITIES, ENERGY_QUANTITIES, GROUND, JOINT_QUANTITIES, ORIGIN, POINT_QUANTITIES, Body,
    CentrodeTrace, Drive, Force, Joint, Model, NamedOutput, ReducedOutput, Vector,
)
from ..memory import BYTES, collection_paused, resident_bytes, within
from ..plugins.contract import REQUIRED, ArgError, ConstraintType
from ..plugins.derived import EquationError
from ..plugins.manager import PLUGIN_FAILURES
from ..plugins.registry import Registry
from .files import read_files, read_tables
from .fused import Fused, TraceFailure, fuse, rebind
from .shapes import mass_properties, shape_edges
from .sparse import Pattern
from . import dynamics as dyn
from .kernels import DriveFunction, Kernels
from .system import (
    Constraint, EnergyOutput, ExprOutput, Group, OutputSpec, ReactionOutput, ReductionOutput,
    Sketch, Start, System,
)
from .units import QUANTITY_DIMS, Units, expr_dim
from .units import TIME as TIME_DIM
from .units import div as dim_div
from .units import power as dim_power
from .variants import Overrides, evaluate, remembered, time_grid

__all__ = ["compile_model", "Kernels", "Overrides", "System"]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


def compile_model(model: Model, registry: Registry, overrides: Overrides | None = None,
                  *, need_times: bool = True, fold: bool = True,
                  reuse: Kernels | None = None, memo: dict | None = None) -> Kernels:
    """Resolve ``model`` against ``registry`` for every sweep variant: the compiled model's
    data (``.system``, a :class:`~mechdsl.compiled.system.System`) and the code generated
    for it (the :class:`~mechdsl.compiled.kernels.Kernels` returned).

    ``fold``: values the same in every variant are constants of the generated code (the
    fastest code for these values); without it every value is a param of the code, which
    then serves other values too. ``reuse``: kernels compiled from the same model (by
    :meth:`mechdsl.api.Mechanism.compile`: for two variants, each param moved a little,
    so that its code holds as constants only what no param changes); where the structure is
    the same (the same joints, drives and forces between the same bodies, only values
    differ) and the values fit its code, its traced and generated code is taken with the
    new values instead of tracing again (:func:`mechdsl.compiled.fused.rebind`), and so are
    its plans (``Kernels.template``): the LU's pivot order (a pivot that becomes small falls
    back to partial pivoting, as over a run) and the code on floats. ``memo``: a dict the
    caller keeps for this model, in which each expression's compiled form is kept from one
    compilation to the next.

    Raises :class:`MechError` (with the model's source attached) for every unknown name, bad
    argument, non-finite value or inconsistent time grid.
    """
    model = read_files(model)  # (already read by mechdsl.load: then the model itself)
    overrides = read_tables(overrides or Overrides(), model.source)
    compiler = _Compiler(model, registry, overrides, fold, reuse, memo)
    try:
        with collection_paused():
            kernels = compiler.run(need_times)
    except MechError as err:
        raise err.with_source(model.source) from None
    if compiler.reuse is not None:  # its code was taken (not traced anew): and its plans
        kernels = replace(kernels, template=reuse.template or reuse)
    return kernels


def check_structure(model: Model, registry: Registry, memo: dict | None = None) -> None:
    """Resolve every name of ``model`` against itself and ``registry`` without evaluating a
    number: joint and drive types, their arguments (names, kinds, the bodies and points they
    refer to), outputs and traces. Raises the MechError that :func:`compile_model` would
    raise for the same mistake; a value that is out of range is left to compile_model, since
    overrides may still change it. ``memo``: compile_model's, where what both derive (the
    named outputs' time derivatives) is kept for the compilation that follows."""
    compiler = _Compiler(model, registry, Overrides(), memo=memo)
    try:
        compiler.structure()
    except MechError as err:
        raise err.with_source(model.source) from None


class _Unevaluated:
    """Stands for :class:`~mechdsl.compiled.variants.Variants` when only names are resolved: one
    variant, every value zero, nothing evaluated."""

    count = 1
    sweep: dict = {}

    def __init__(self, params: list[str]) -> None:
        self.env = {p: np.zeros(1) for p in params}

    def values(self, e, what: str, span) -> np.ndarray:
        return np.zeros(1)

    def vector(self, v: Vector, what: str) -> np.ndarray:
        return np.zeros((1, len(v.items)))


def _same_structure(groups, others) -> bool:
    """Whether two lists of groups bind the same types to the same bodies in the same rows,
    with arguments of the same shapes (their values may differ)."""
    if others is None or len(groups) != len(others):
        return False
    for g, h in zip(groups, others):
        if g.ctype is not h.ctype or len(g.members) != len(h.members) or \
                not np.array_equal(g.slots, h.slots) or not np.array_equal(g.rows, h.rows) or \
                g.params.keys() != h.params.keys():
            return False
        for k, a in g.params.items():
            b = h.params[k]
            if isinstance(a, np.ndarray) != isinstance(b, np.ndarray) or (
                    isinstance(a, np.ndarray) and a.shape[1:] != b.shape[1:]):
                return False
    return True


def _fused(groups: list[Group], constraints: list[Constraint], n_bodies: int, source,
           fold: bool = True) -> Fused:
    """The whole mechanism's equations traced, differentiated and compiled; a type whose
    equations cannot be traced is a located error at the constraint where it failed."""
    m = constraints[-1].rows[1] if constraints else 0
    try:
        return fuse(groups, n_bodies, m, fold=fold)
    except TraceFailure as fail:
        ctype, err = fail.group.ctype, fail.error
        c = constraints[fail.group.members[fail.member]]
        what = (str(err).split(": ", 1)[-1] if isinstance(err, EquationError)
                else f"{type(err).__name__}: {str(err)[:200]}")
        raise MechError(
            f"the {ctype.kind} type '{ctype.name}' failed in equations() for {c.kind} "
            f"'{c.name}': {what}", c.span, source,
            notes=[f"the type comes from the plugin {type(ctype).__module__}; this is a "
                   "defect of the plugin, not of the .mech file"]) from None


@dataclass(frozen=True)
class _BindPlan:
    """What the arguments of one joint, drive or force name (:meth:`_Compiler._bind_plan`):
    (kind, argument, what) in the signature's order, and each given argument's span."""

    args: tuple[tuple[str, str, object], ...]
    spans: dict


class _Compiler:
    def __init__(self, model: Model, registry: Registry, ov: Overrides, fold: bool = True,
                 reuse: Kernels | None = None, memo: dict | None = None) -> None:
        self.model, self.registry, self.ov = model, registry, ov
        self.fold, self.reuse, self.memo = fold, reuse, memo
        self.evaluated = True  # False while only names are resolved (structure())
        self.units = Units.of(model.units)
        self.unit_warnings: dict[tuple, MechWarning] = {}  # each mismatch once
        self.param_names = [p.name for p in model.params]

    def structure(self) -> None:
        """What :func:`check_structure` checks: the names, through the same code as run()."""
        self.var, self.V, self.evaluated = _Unevaluated(self.param_names), 1, False
        self._bodies()
        self.constraints, groups, _, _ = self._constraints()
        if self.model.initials:
            self._constraints(self._initial_drives(0.0))
        self._forces()
        self._outputs()
        self._sketch(groups)

    def run(self, need_times: bool) -> Kernels:
        self.var = evaluate(self.model, self.ov, self.memo)
        self.V = self.var.count
        if self.V > 1:
            model = self.model
            values = (2 * sum(len(b.points) + 1 for b in (*model.bodies, model.ground))
                      + 2 * sum(len(c.args) for c in (*model.joints, *model.drives, *model.forces))
                      + 6 * len(model.bodies) + len(model.params))
            check_compile(self.V, values, self.ov.max_memory)
        self._bodies()
        constraints, groups, drive_rows, drive_fns = self._constraints()
        self.constraints, self.groups = constraints, groups
        force_groups, elements = self._forces()
        if self.reuse is not None and not (_same_structure(groups, self.reuse.system.groups)
                                           and _same_structure(force_groups,
                                                               self._reused_forces())):
            self.reuse = None  # another structure: traced anew
        fused = self.reuse and self.reuse.fused and rebind(self.reuse.fused, groups)
        if not fused:
            fused = _fused(groups, constraints, len(self.bodies), self.model.source, self.fold)
            self.reuse = None
        pattern = (self.reuse.system.pattern if self.reuse is not None else
                   Pattern.from_entries(fused.rows, fused.cols, (fused.m, fused.n)))
        outputs = self._outputs()
        times = (time_grid(self.model, self.ov, self.var, len(outputs)) if need_times
                 else None)
        order = max((o.order for o in outputs), default=0)
        env = {k: _readonly(v[:, None]) for k, v in self.var.env.items()}
        guess = self._guess()
        dynamics = self._dynamics(force_groups, elements, outputs)
        system = System(
            source=self.model.source,
            body_names=tuple(b.name for b in self.bodies),
            n=3 * len(self.bodies),
            m=constraints[-1].rows[1] if constraints else 0,
            constraints=tuple(constraints),
            groups=tuple(groups),
            drive_rows=_readonly(np.asarray(drive_rows, dtype=np.intp)),
            env=env,
            sweep={k: _readonly(v) for k, v in self.var.sweep.items()},
            n_variants=self.V,
            guess=_readonly(guess),
            scale=_readonly(self._scale(guess)),
            times=None if times is None else _readonly(times),
            outputs=tuple(outputs),
            order=order,
            pattern=pattern,
            sketch=self._sketch(groups),
            mass=tuple(mass_properties(b, self.var) for b in self.bodies),
            time_unit=self.units.time,
            tolerances=self._tolerances(),
            reductions=tuple(self.reductions),
            warnings=tuple(self.unit_warnings.values()),
        )
        kernels = Kernels(system, fused, dynamics, tuple(drive_fns), self._expressions(outputs),
                          {r.label: self._compiled_expr(r.expr) for r in self.reductions})
        return self._with_start(kernels)

    def _compiled_expr(self, e: E.Expr):
        """``e`` as a function of an environment, kept in the memo from one compilation of
        the model to the next."""
        return remembered(self.memo, "expr", e, lambda: E.compile_expr(e))

    def _expressions(self, outputs) -> dict:
        """The functions of the expression outputs, by label."""
        return {o.label: self._compiled_expr(o.expr) for o in outputs
                if isinstance(o, ExprOutput)}

    # -- the start of a forward-dynamics run ---------------------------------------------------
    def _with_start(self, kernels: Kernels) -> Kernels:
        """``kernels`` with their system's :class:`~mechdsl.compiled.system.Start`: which
        coordinates are guessed, and the model with its ``initial`` statements added as
        drives (f(t) = value + rate (t - t0), so that f(t0) is the value and f'(t0) the
        rate), its code in ``kernels.start``. An initial
        statement in a model that has no forward dynamics is a located error: the run is
        the kinematics (the joints and drives fix every coordinate), or the model has no
        masses."""
        initials = self.model.initials
        system = kernels.system
        if initials and kernels.dynamics is None:
            raise MechError(f"initial '{cut(initials[0].name)}' is for forward dynamics, and "
                            "the model has no masses: give its bodies mass and inertia, or "
                            "remove the statement", initials[0].span)
        # the run is the kinematics where the drives fix every coordinate (the rule of
        # mechdsl.solve.run.method_for: a model with masses and no drive is dynamics)
        if initials and system.m >= system.n and system.drive_rows.size:
            raise MechError(
                f"initial '{cut(initials[0].name)}' is for forward dynamics: the drives fix "
                f"every coordinate ({system.n} coordinates, {system.m} equations of joints "
                "and drives), and the run is the kinematics; remove it, or drive the "
                "mechanism from where it should start", initials[0].span)
        if kernels.dynamics is None:
            return kernels
        guessed = np.zeros(system.n, bool)
        for i, b in enumerate(self.bodies):
            if b.guess is not None:
                guessed[3 * i : 3 * i + 3] = True
        if not initials:
            return kernels.with_system(replace(system, start=Start(_readonly(guessed))))
        t0 = float(system.times.reshape(-1)[0]) if system.times is not None else 0.0
        constraints, groups, drive_rows, drive_fns = self._constraints(
            self._initial_drives(t0))
        m = constraints[-1].rows[1]
        fused = _fused(groups, constraints, len(self.bodies), self.model.source)
        pattern = Pattern.from_entries(fused.rows, fused.cols, (fused.m, fused.n))
        # the equations only: no masses, outputs or reductions (it is assembled, never run)
        augmented = replace(system, m=m, constraints=tuple(constraints), groups=tuple(groups),
                            drive_rows=_readonly(np.asarray(drive_rows, dtype=np.intp)),
                            pattern=pattern, outputs=(), reductions=(), start=None)
        rows = np.arange(system.m, m, dtype=np.intp)
        rated = np.array([c.rate is not None for c in initials], dtype=bool)
        start = Start(_readonly(guessed), augmented, _readonly(rows), _readonly(rated))
        return replace(kernels, system=replace(system, start=start),
                       start=Kernels(augmented, fused, None, tuple(drive_fns)))

    def _initial_drives(self, t0: float) -> list[Drive]:
        """The ``initial`` statements as drives of f(t) = value + rate (t - t0) (rate 0 where
        none is given: that row then stays out of the velocities, see
        :class:`~mechdsl.compiled.system.Start`)."""
        out = []
        for c in self.model.initials:
            # a value or rate that is not a number is its own error, not an unreachable one
            for what, e in (("value", c.value), ("rate", c.rate)):
                if e is not None:
                    self.var.values(e, f"the {what} of initial '{c.name}'",
                                    getattr(e, "span", None) or c.span)
            f = c.value
            if c.rate is not None:
                f = E.add(c.value, E.mul(c.rate, E.sub(E.Name(TIME, c.span), E.Num(t0, c.span))))
            out.append(Drive(c.name, c.type_name, c.args, c.span, c.type_span, f))
        return out

    # -- dynamics ------------------------------------------------------------------------------
    def _forces(self):
        """The force elements, packed by type like the constraints (rows unused)."""
        packed: dict[str, list] = {}
        elements = []
        #: (body, (V, 2), body, (V, 2)): the force elements drawn between two points
        self.links = []
        for f in self.model.forces:
            ftype = self._type("force", f.type_name, f.type_span)
            slots, params = self._bind(f, ftype)
            elements.append(dyn.ForceElement(f.name, f.type_name, f.span,
                                             tuple(self._name_of(s) for s in slots)))
            points = [a.name for a in ftype.signature if a.kind == "point"]
            if len(points) >= 2:  # drawn as a spring between its first two points
                refs = [a for a in ftype.signature if a.is_reference]
                k1, k2 = (refs.index(next(a for a in refs if a.name == n)) for n in points[:2])
                self.links.append((slots[k1], _readonly(params[points[0]]), slots[k2],
                                   _readonly(params[points[1]])))
            packed.setdefault(f.type_name, [ftype, []])[1].append(
                (len(elements) - 1, slots, params, (0, 0)))
        return [self._group(ftype, members) for ftype, members in packed.values()], elements

    def _reused_forces(self) -> list:
        """The force groups of the kernels reused (none where they have no dynamics)."""
        d = self.reuse.dynamics if self.reuse is not None else None
        return list(d.force_groups) if d is not None else []

    def _dynamics(self, force_groups, elements, outputs) -> "dyn.Dynamics | None":
        """The masses and loads, where the model has any (or an output asks for reactions)."""
        model = self.model
        wanted = (model.forces or model.gravity is not None
                  or any(b.mass is not None or b.density is not None or b.v0 is not None
                         for b in self.bodies)
                  or any(isinstance(o, (ReactionOutput, EnergyOutput))
                         or any(isinstance(i, (ReactionOutput, EnergyOutput))
                                for _, i in getattr(o, "inputs", ()))  # a named output
                         for o in outputs))
        if not wanted:
            return None
        V, nb = self.V, len(self.bodies)
        mass, inertia = np.zeros((V, nb)), np.zeros((V, nb))
        centroid = np.zeros((V, nb, 2))
        v0, given = np.zeros((V, 3 * nb)), np.zeros(3 * nb, bool)
        for i, b in enumerate(self.bodies):
            if b.mass is not None:
                mass[:, i] = self.var.values(b.mass, f"the mass of {b.name}", b.mass.span)
                if b.inertia is not None:
                    inertia[:, i] = self.var.values(b.inertia, f"the inertia of {b.name}",
                                                    b.inertia.span)
                if b.centroid is not None:
                    centroid[:, i] = self.var.vector(b.centroid, f"the centroid of {b.name}")
                for what, value, span in (("mass", mass[:, i], b.mass.span),
                                          ("inertia", inertia[:, i],
                                           b.inertia.span if b.inertia else b.span)):
                    if not np.all(value >= 0):
                        raise MechError(f"the {what} of {b.name} must not be negative", span)
            elif b.density is not None:
                props = mass_properties(b, self.var)
                mass[:, i], inertia[:, i], centroid[:, i] = (props.mass, props.inertia,
                                                             props.centroid)
            if b.v0 is not None:
                v0[:, 3 * i : 3 * i + 3] = self.var.vector(b.v0, f"the v0 of {b.name}")
                given[3 * i : 3 * i + 3] = True
        gravity = (self.var.vector(model.gravity, "gravity") if model.gravity is not None
                   else np.zeros((V, 2)))
        template = self.reuse.dynamics if self.reuse is not None else None
        if template is not None:
            again = dyn.rebind(template, nb, mass, inertia, centroid, gravity, force_groups,
                               tuple(elements), _readonly(v0), _readonly(given))
            if again is not None:
                return again
        try:
            return dyn.build(nb, mass, inertia, centroid, gravity, force_groups,
                             tuple(elements), _readonly(v0), _readonly(given), self.fold)
        except dyn.ForceError as err:
            raise MechError(str(err), self.model.forces[0].span if self.model.forces
                            else None) from None

    def _tolerances(self) -> dict[str, float]:
        """The simulate statement's options (rtol, atol), evaluated (one value for all
        variants)."""
        sim = self.model.simulate
        out: dict[str, float] = {}
        for name, e, span in (sim.options if sim is not None else ()):
            values = self.var.values(e, f"option {name}", span)
            if not (np.all(values == values[0]) and 0 < values[0] < 1):
                raise MechError(f"{name} must be one number in (0, 1)", span)
            out[name] = float(values[0])
        return out

    # -- params and sweeps ---------------------------------------------------------------------
    # -- bodies --------------------------------------------------------------------------------
    def _bodies(self) -> None:
        self.bodies: list[Body] = list(self.model.bodies)
        self.body_index = {b.name: i for i, b in enumerate(self.bodies)}
        self.body_index[GROUND] = len(self.bodies)
        self.points: dict[str, dict[str, np.ndarray]] = {}
        for b in [*self.bodies, self.model.ground]:
            pts = {ORIGIN: np.zeros((self.V, 2))}
            for pt in b.points:
                pts[pt.name] = self.var.vector(pt.coords, f"point {b.name}.{pt.name}")
            self.points[b.name] = pts

    def _guess(self) -> np.ndarray:
        g = np.zeros((self.V, 3 * len(self.bodies)))
        for i, b in enumerate(self.bodies):
            if b.guess is not None:
                g[:, 3 * i : 3 * i + 3] = self.var.vector(b.guess, f"the guess of {b.name}")
        return g

    def _scale(self, guess: np.ndarray) -> np.ndarray:
        """A length characteristic of the model, per variant: the largest point coordinate or
        guessed position (1 if all are zero). Convergence tests on lengths are relative to it."""
        xys = [xy for pts in self.points.values() for xy in pts.values()]  # each (V, 2)
        s = np.abs(np.concatenate(xys, axis=1)).max(axis=1)
        g = guess.reshape(self.V, -1, 3)[..., :2]
        if g.size:
            s = np.maximum(s, np.abs(g).max(axis=(-1, -2)))
        return np.where(s > 0, s, 1.0)

    def _body_ref(self, name: str, span: Span | None) -> int:
        if name not in self.body_index:
            raise MechError(f"unknown body '{name}'" + suggest(name, self.body_index), span)
        return self.body_index[name]

    def _point_ref(self, parts: tuple[str, ...], span: Span | None) -> tuple[int, np.ndarray]:
        if len(parts) != 2:
            raise MechError(f"'{'.'.join(parts)}' is not a point; write body.point", span)
        body, point = parts
        i = self._body_ref(body, span)
        pts = self.points[body]
        if point not in pts:
            raise MechError(f"body '{body}' has no point '{point}'"
                            + suggest(point, pts, f"{body}."), span)
        return i, pts[point]

    # -- constraints ---------------------------------------------------------------------------
    def _constraints(self, initials: list[Drive] = ()):
        """The joints, the drives and (for the start of a forward dynamics) ``initials``,
        the ``initial`` statements as drives (:meth:`_initial_drives`), in that order:
        their constraints, groups, drive rows and drive functions."""
        constraints = []
        packed: dict[tuple[str, str], list] = {}
        drive_rows, drive_fns = [], []
        row = 0
        items: list[Joint | Drive] = [*self.model.joints, *self.model.drives, *initials]
        first_initial = len(items) - len(initials)
        for k, c in enumerate(items):
            kind = "drive" if isinstance(c, Drive) else "joint"
            # an initial statement takes the drive types (the drives plugin's, or any other)
            ctype = self._type(kind, c.type_name, c.type_span)
            if k >= first_initial:
                kind = "initial"
            slots, params = self._bind(c, ctype)
            if all(s == self.body_index[GROUND] for s in slots):
                what = {"drive": "a drive on the ground", "initial": "an initial statement "
                        "on the ground", "joint": "a joint of the ground with itself"}[kind]
                raise MechError(f"{what} constrains nothing", c.span)
            if kind == "joint" and len(slots) > 1 and len(set(slots)) == 1:
                raise MechError(f"joint '{c.name}' connects body "
                                f"'{self.bodies[slots[0]].name}' to itself", c.span)
            rows = (row, row + ctype.n_eq)
            row += ctype.n_eq
            names = tuple(self._name_of(s) for s in slots)
            constraints.append(Constraint(c.name, kind, c.type_name, c.span, rows, names))
            packed.setdefault((kind, c.type_name), [ctype, []])[1].append(
                (len(constraints) - 1, slots, params, rows))
            if kind in ("drive", "initial"):
                drive_rows.append(rows[0])
                drive_fns.append(self._drive_function(c))
        groups = [self._group(ctype, members) for ctype, members in packed.values()]
        return constraints, groups, drive_rows, drive_fns

    def _name_of(self, index: int) -> str:
        return GROUND if index == len(self.bodies) else self.bodies[index].name

    def _type(self, kind: str, name: str, span: Span) -> ConstraintType:
        key = (kind, name)
        if key in self.registry.conflicts:
            raise MechError(self.registry.conflicts[key], span)
        ctype = self.registry.get(kind, name)
        if ctype is None:
            old = self.registry.broken_for(name)
            if old is not None:  # its plugin was written for another contract
                raise MechError(f"the {kind} type '{name}' comes from the plugin "
                                f"{old.provider.plugin} ({old.provider}), which cannot be "
                                f"loaded: {old.reason}", span)
            other = {"drive": "joint", "joint": "drive", "force": "joint"}[kind]
            if self.registry.get(other, name) is not None:
                raise MechError(f"'{name}' is a {other} type, not a {kind} type", span)
            names = self.registry.names(kind)
            notes = [f"{kind} types: " + ", ".join(names) if names else
                     f"no {kind} types are installed (see 'mechdsl plugins')"]
            notes += [f"the plugin {b.provider.plugin} ({b.provider}) failed to load: "
                      f"{b.reason}" for b in self.registry.broken]
            raise MechError(f"unknown {kind} type '{name}'" + suggest(name, names), span,
                            notes=notes)
        return ctype

    def _bind(self, c: Joint | Drive | Force, ctype):
        """The bodies (slots) and argument values of ``c`` (an instance of ``ctype``), for
        every variant, checked by the type's ``validate``."""
        # what the arguments name is the same for every value of the params: resolved once
        # per model (the memo), only the values evaluated again
        plan = remembered(self.memo, ("bind", id(ctype), self.evaluated), c,
                          lambda: self._bind_plan(c, ctype))
        slots: list[int] = []
        params: dict[str, np.ndarray] = {}
        for kind, name, what in plan.args:
            if kind == "point":
                slots.append(what[0])
                params[name] = self.points[what[1]][what[2]]
            elif kind == "body":
                slots.append(what)
            elif kind == "vector":
                params[name] = self.var.vector(what, f"argument '{name}'")
            elif kind == "number":
                params[name] = self.var.values(what, f"argument '{name}'", what.span)
            elif kind == "function":
                params[name] = what
            else:  # the default
                params[name] = np.broadcast_to(what, (self.V,) + what.shape).copy()
        spans = plan.spans
        values = {k: self._function(ctype, k, [v]) if isinstance(v, E.NODES) else v
                  for k, v in params.items()}
        try:
            with np.errstate(all="ignore"):
                if self.evaluated:  # placeholder zeros are no values to judge
                    ctype.validate(values)
        except ArgError as err:
            raise MechError(f"{ctype.name}: {err.message}{self._bad_variant(ctype, values)}",
                            spans.get(err.arg, c.span)) from None
        except PLUGIN_FAILURES as err:
            provider = self.registry.provider(ctype.kind, ctype.name)
            raise MechError(
                f"the {ctype.kind} type '{ctype.name}' failed in validate() for {c.name}: "
                f"{type(err).__name__}: {str(err)[:200]}", c.span,
                notes=[f"the type comes from the plugin {provider.plugin if provider else '?'}"
                       "; this is a defect of the plugin, not of the .mech file"]) from None
        return slots, params

    def _bind_plan(self, c: Joint | Drive | Force, ctype) -> "_BindPlan":
        """What each argument of ``c`` names, in ``ctype``'s signature order: a point (body,
        body name, point), a body, an expression or vector to evaluate, a function, or the
        default; every mistake of names, kinds and order a located error."""
        sig = ctype.signature
        by_name = {a.name: a for a in sig}
        given: dict[str, object] = {}
        for i, a in enumerate(c.args):
            if a.name is None:
                if given and any(x.name is not None for x in c.args[:i]):
                    raise MechError("a positional argument cannot follow a keyword argument",
                                    a.span)
                if i >= len(sig):
                    raise MechError(f"{ctype.name}() takes {len(sig)} argument"
                                    f"{'s' if len(sig) != 1 else ''}: {ctype.describe()}", a.span)
                target = sig[i]
            else:
                if a.name not in by_name:
                    raise MechError(f"{ctype.name}() has no argument '{a.name}'"
                                    + suggest(a.name, by_name), a.span,
                                    notes=[f"signature: {ctype.describe()}"])
                target = by_name[a.name]
            if target.name in given:
                raise MechError(f"argument '{target.name}' is given twice", a.span)
            given[target.name] = a
        args: list[tuple[str, str, object]] = []
        spans: dict[str, Span] = {}
        for arg in sig:
            a = given.get(arg.name)
            if a is None:
                if arg.default is REQUIRED:
                    raise MechError(f"{ctype.name}() needs argument '{arg.name}' ({arg.kind})",
                                    c.span, notes=[f"signature: {ctype.describe()}"])
                default = np.broadcast_to(np.asarray(arg.default, dtype=float),
                                          (2,) if arg.kind == "vector" else ())
                args.append(("default", arg.name, default))
                continue
            spans[arg.name] = a.span
            v = a.value
            if arg.kind == "point":
                if isinstance(v, E.Ref):
                    body, _ = self._point_ref(v.parts, v.span)
                    args.append(("point", arg.name, (body, *v.parts)))
                elif isinstance(v, E.Name) and v.id in self.body_index:
                    raise MechError(f"argument '{arg.name}' is a point: write {v.id}.origin or "
                                    f"{v.id}.POINT", a.span)
                else:
                    raise MechError(f"argument '{arg.name}' must be a point such as body.P",
                                    a.span)
            elif arg.kind == "body":
                if isinstance(v, E.Name):
                    args.append(("body", arg.name, self._body_ref(v.id, v.span)))
                else:
                    raise MechError(f"argument '{arg.name}' must be a body name", a.span)
            elif arg.kind == "vector":
                if not isinstance(v, Vector) or len(v.items) != 2:
                    raise MechError(f"argument '{arg.name}' must be a vector (x, y)", a.span)
                for item in v.items:
                    check_expr(item, set(self.param_names), f"argument '{arg.name}'")
                args.append(("vector", arg.name, v))
            elif arg.kind == "function":
                if isinstance(v, (Vector, E.Ref)):
                    raise MechError(f"argument '{arg.name}' must be an expression of "
                                    f"'{arg.var}'", a.span)
                check_expr(v, {*self.param_names, arg.var},
                           f"argument '{arg.name}' (a function of '{arg.var}')")
                args.append(("function", arg.name, v))
            else:
                if isinstance(v, Vector):
                    raise MechError(f"argument '{arg.name}' must be a number", a.span)
                if isinstance(v, E.Ref):
                    raise MechError(f"argument '{arg.name}' must be a number, not a reference",
                                    a.span)
                check_expr(v, set(self.param_names), f"argument '{arg.name}'")
                args.append(("number", arg.name, v))
        return _BindPlan(tuple(args), spans)

    def _bad_variant(self, ctype: ConstraintType, values: dict) -> str:
        """' (for l = -1)': the first sweep variant whose values the type rejects."""
        if self.V == 1:
            return ""
        for v in range(self.V):
            one = {k: (a.variant(v) if isinstance(a, ExprFunction) else a[v : v + 1])
                   for k, a in values.items()}
            try:
                with np.errstate(all="ignore"):
                    ctype.validate(one)
            except PLUGIN_FAILURES:
                return " (for " + ", ".join(f"{k} = {a[v]:g}" for k, a in
                                            self.var.sweep.items()) + ")"
        return ""

    def _group(self, ctype: ConstraintType, members: list) -> Group:
        idx = tuple(m[0] for m in members)
        slots = np.array([m[1] for m in members], dtype=np.intp).reshape(len(members), -1)
        rows = np.array([np.arange(*m[3]) for m in members], dtype=np.intp)
        params = {}
        for name, first in members[0][2].items():
            if isinstance(first, E.NODES):
                params[name] = self._function(ctype, name, [m[2][name] for m in members])
                continue
            if len(members) == 1:  # (V, ...) -> (V, 1, 1, ...): a view, no copy
                params[name] = _readonly(first.reshape(first.shape[:1] + (1, 1) + first.shape[1:]))
                continue
            stacked = np.stack([m[2][name] for m in members], axis=1)  # (V, J, ...)
            params[name] = _readonly(stacked[:, None])
        return Group(ctype, idx, _readonly(slots), params, _readonly(rows))

    def _function(self, ctype: ConstraintType, name: str, exprs: list) -> ExprFunction:
        """The function argument ``name`` of a group: member j's expression on x[..., j];
        params (V, 1) broadcast against x[..., j] of shape (V, b)."""
        var = next(a.var for a in ctype.signature if a.name == name)
        env = {k: v[:, None] for k, v in self.var.env.items()}
        return ExprFunction(exprs, var, env)

    def _drive_function(self, d: Drive) -> DriveFunction:
        def make() -> DriveFunction:
            f = d.function
            fd = derivative(f, TIME)
            fdd = derivative(fd, TIME)
            return DriveFunction(E.compile_expr(f), E.compile_expr(fd), E.compile_expr(fdd),
                                 (f, fd, fdd))
        return remembered(self.memo, "drive", d.function, make)

    # -- outputs -------------------------------------------------------------------------------
    def _sketch(self, groups: list[Group]) -> Sketch:
        outlines = []
        for b in [*self.bodies, self.model.ground]:
            pts = [xy for name, xy in self.points[b.name].items() if name != ORIGIN]
            pts = pts or [self.points[b.name][ORIGIN]]
            outlines.append(_readonly(np.stack(pts, axis=1)))
        pins, pin_names, guides = [], [], []
        for g in groups:
            guide = getattr(g.ctype, "guide", None)
            k = 0
            for arg in g.ctype.signature:
                if arg.kind == "point" and not (guide and arg.name == guide[0]):
                    for j in range(g.slots.shape[0]):
                        pins.append((int(g.slots[j, k]), _readonly(g.params[arg.name][:, 0, j])))
                        pin_names.append(self.constraints[g.members[j]].name)
                if arg.kind in ("point", "body"):
                    k += 1
            if guide:  # the line a point slides on: a rail, not a pivot
                p1, p2, axis = guide
                for j in range(g.slots.shape[0]):
                    guides.append((int(g.slots[j, 0]), _readonly(g.params[p1][:, 0, j]),
                                   _readonly(g.params[axis][:, 0, j]), int(g.slots[j, 1]),
                                   _readonly(g.params[p2][:, 0, j])))
        traces, centrodes = [], []
        for r in self.model.traces:
            if isinstance(r, CentrodeTrace):
                centrodes.append((r.label, self._body_ref(r.a, r.a_span or r.span),
                                   self._body_ref(r.b, r.b_span or r.span)))
                continue
            body = r.parts[0]
            i = self._body_ref(body, r.span)
            if len(r.parts) > 2:
                raise MechError(f"'{'.'.join(r.parts)}' is not a point; trace body.P or body",
                                r.span)
            point = r.parts[1] if len(r.parts) == 2 else ORIGIN
            if point not in self.points[body]:
                raise MechError(f"body '{body}' has no point '{point}'"
                                + suggest(point, self.points[body], f"{body}."), r.span)
            traces.append(('.'.join(r.parts), i, _readonly(self.points[body][point])))
        shapes = tuple(shape_edges(b, self.var) for b in [*self.bodies, self.model.ground])
        return Sketch(tuple(outlines), tuple(pins), tuple(traces), shapes,
                      tuple(getattr(self, "links", ())), tuple(guides),
                      tuple(b.name for b in self.bodies), tuple(pin_names),
                      self.units.length, tuple(centrodes))

    def _outputs(self) -> list[OutputSpec | ExprOutput]:
        refs = self.model.outputs
        out: list[OutputSpec | ExprOutput] = []
        self.reductions: list[ReductionOutput] = []
        reduced = [r for r in refs if isinstance(r, ReducedOutput)]
        if reduced:
            return self._reduced(refs, reduced)
        if not refs:
            for b in self.bodies:
                out.extend(self._body_quantities(b.name, BODY_QUANTITIES))
            return out
        seen: set[str] = set()
        for r in refs:
            specs = (self._named(r) if isinstance(r, NamedOutput)
                     else self._output(r.parts, r.span))
            for s in specs:
                if s.label in seen:
                    raise MechError(f"output '{s.label}' is requested twice", r.span)
                seen.add(s.label)
            out.extend(specs)
        return [self._reported(s) for s in out]

    def _reported(self, spec):
        """``spec`` as a reported column: scaled to the unit it is reported in (degrees);
        the columns other outputs read keep the computed value (radians)."""
        factor = self.units.scale(self._dim(spec))
        return spec if factor == 1.0 else replace(spec, scale=factor)

    def _dim(self, spec):
        """The dimension of an output column (:mod:`mechdsl.compiled.units`)."""
        if isinstance(spec, ExprOutput):
            return spec.dim
        return QUANTITY_DIMS[spec.label if isinstance(spec, EnergyOutput) else spec.quantity]

    def _dim_of(self, e: E.Expr, dims, owner: str):
        """The dimension of expression ``e`` of output ``owner``, its names' dimensions from
        ``dims``; each unit mismatch a located warning."""
        def warn(message: str, span: Span | None) -> None:
            if (message, span) not in self.unit_warnings:
                self.unit_warnings[message, span] = MechWarning(
                    f"output '{cut(owner)}': {message}", span, self.model.source)
        return expr_dim(e, dims, warn, self.units)

    def _reduced(self, refs, reduced: list[ReducedOutput]) -> list[OutputSpec | ExprOutput]:
        """The columns the reductions read (a quantity, or an expression named by its text
        in brackets), each once; the reductions themselves in ``self.reductions``."""
        other = next((r for r in refs if not isinstance(r, ReducedOutput)), None)
        if other is not None:
            raise MechError(
                f"output '{cut(getattr(other, 'name', '.'.join(getattr(other, 'parts', ()))))}'"
                " is a history, and this run's other outputs have one value per variant "
                f"('{cut(reduced[0].name)}'); a run gives one or the other: reduce it (max, "
                "min, mean, final, ...) or write the histories in a run of their own",
                other.span)
        columns: dict[str, OutputSpec | ExprOutput] = {}
        seen: set[str] = set()
        for r in reduced:
            if r.name in seen:
                raise MechError(f"output '{cut(r.name)}' is requested twice", r.span)
            seen.add(r.name)
            parts = []
            for k, red in enumerate(r.reductions):
                e = red.expr
                if isinstance(e, E.Name) and self._reads(e.id):
                    spec = self._quantity(e.id, e.span or red.span, r.name)
                else:
                    text = f"[{E.to_text(e)}]"
                    spec = columns.get(text) or self._expr_column(text, e, red.span, r.name)
                columns.setdefault(spec.label, spec)
                parts.append((f"@{k}", red.func, spec.label))
            part_dims = {name: TIME_DIM if func.startswith("arg") else self._dim(columns[label])
                         for name, func, label in parts}
            d = self._dim_of(r.expr, part_dims.get, r.name)
            self.reductions.append(ReductionOutput(r.name, tuple(parts),
                                                   r.expr, self.units.label(d),
                                                   self.units.scale(d)))
        return list(columns.values())

    def _expr_column(self, label: str, e: E.Expr, span: Span, owner: str,
                     rate_of: tuple | None = None) -> ExprOutput:
        """A column computed by the expression ``e`` of params, ``t`` and quantities; its
        dimension that of ``e``, or for the k-th time derivative of a column of dimension
        d (``rate_of`` = (d, k)) d / time^k."""
        names = {n.id: n.span for n in E.walk(e) if isinstance(n, E.Name) and self._reads(n.id)}
        # resolved in reading order: the first wrong quantity is the one reported
        specs = {n: self._quantity(n, at or span, owner) for n, at in names.items()}
        inputs = tuple((n, specs[n]) for n in sorted(specs))
        if rate_of is None:
            d = self._dim_of(e, lambda n: self._dim(specs[n]) if n in specs else None, owner)
        else:
            d = dim_div(rate_of[0], dim_power(TIME_DIM, rate_of[1]))
        return ExprOutput(label, inputs,
                          max((s.order for _, s in inputs), default=0), e,
                          self.units.label(d), dim=d)

    def _named(self, out: NamedOutput) -> list[ExprOutput]:
        """The columns of ``output NAME = EXPR``: NAME, and its exact time derivatives
        NAME.vel and NAME.acc (by the chain rule through the quantities it reads: x -> vx ->
        ax, phi -> omega -> alpha), as far as the quantities read have derivatives."""
        columns = []
        e = out.expr
        suffixes = ("", ".vel", ".acc")
        for k, suffix in enumerate(suffixes):
            column = self._expr_column(out.name + suffix, e, out.span, out.name,
                                       (columns[0].dim, k) if columns else None)
            columns.append(column)
            if k == len(suffixes) - 1:
                break  # (the jerk: no column reads it)
            specs = dict(column.inputs)
            rates = {n: n[: n.rfind(".") + 1] + RATE[s.quantity] for n, s in specs.items()
                     if isinstance(s, OutputSpec) and s.quantity in RATE}
            # (kept in the memo: check_structure derives the same before every compilation,
            # 1.9 ms of the stiff pendulum's 34 for its two outputs)
            e = remembered(self.memo, "rate", e,
                           lambda e=e: total_derivative(e, set(specs), rates))
            if e is None:
                break
        return columns

    def _reads(self, name: str) -> bool:
        """Whether ``name`` in an output's expression is a quantity (``rod.phi``, an
        energy: their names are reserved), not a param or ``t``."""
        return "." in name or name in ENERGY_QUANTITIES

    def _quantity(self, name: str, span: Span, output: str) -> OutputSpec:
        """The column spec of one quantity read by a named output (``rod.phi``,
        ``kinetic_energy``)."""
        parts = tuple(name.split("."))
        if parts[-1] not in ENERGY_QUANTITIES and parts[-1] not in (*BODY_QUANTITIES, *POINT_QUANTITIES, *JOINT_QUANTITIES,
                             *DRIVE_QUANTITIES):
            raise MechError(f"'{cut(name)}' in output '{cut(output)}' is not a quantity: write "
                            "body.x, body.phi, body.P.x, joint.fx, drive.torque, ... (or "
                            "distance(P, Q) for points)", span)
        found = self._output(parts, span)
        if len(found) != 1:  # pragma: no cover - a quantity name gives one column
            raise MechError(f"'{cut(name)}' is not one quantity", span)
        return found[0]

    def _unit(self, quantity: str) -> str:
        return self.units.quantity(quantity)

    def _body_quantities(self, body: str, quantities) -> list[OutputSpec]:
        i = self.body_index[body]
        return [OutputSpec(f"{body}.{q}", i, None, q, _order(q), self._unit(q))
                for q in quantities]

    def _point_quantities(self, body: str, point: str, quantities) -> list[OutputSpec]:
        i = self.body_index[body]
        xy = _readonly(self.points[body][point][:, None])
        return [OutputSpec(f"{body}.{point}.{q}", i, xy, q, _order(q), self._unit(q))
                for q in quantities]

    def _output(self, parts: tuple[str, ...], span: Span) -> list[OutputSpec]:
        body = parts[0]
        if body not in self.body_index and parts in ((q,) for q in ENERGY_QUANTITIES):
            return [EnergyOutput(body, 0 if body == "potential_energy" else 1,
                                 self._unit(body))]
        if body not in self.body_index:
            for k, c in enumerate(self.constraints):
                if c.name == body:
                    return self._reaction(k, c, parts, span)
        self._body_ref(body, span)
        pts = self.points[body]
        if len(parts) == 1:
            return self._body_quantities(body, BODY_QUANTITIES)
        second = parts[1]
        if len(parts) == 2:
            if second in BODY_QUANTITIES:
                return self._body_quantities(body, (second,))
            if second in pts:
                return self._point_quantities(body, second, POINT_QUANTITIES)
            raise MechError(f"'{second}' is neither a quantity of body '{body}' nor one of its "
                            "points" + suggest(second, [*BODY_QUANTITIES, *pts]), span,
                            notes=["body quantities: " + " ".join(BODY_QUANTITIES)])
        if len(parts) == 3:
            if second not in pts:
                raise MechError(f"body '{body}' has no point '{second}'"
                                + suggest(second, pts), span)
            q = parts[2]
            if q not in POINT_QUANTITIES:
                raise MechError(f"'{q}' is not a point quantity" + suggest(q, POINT_QUANTITIES),
                                span, notes=["point quantities: " + " ".join(POINT_QUANTITIES)])
            return self._point_quantities(body, second, (q,))
        raise MechError(f"'{'.'.join(parts)}' is not an output: write body.quantity or "
                        "body.point.quantity", span)

    def _reaction(self, k: int, c: Constraint, parts: tuple[str, ...], span: Span
                  ) -> list[ReactionOutput]:
        """``J.fx``, ``J.fy``, ``J.torque`` of a joint: the load it exerts on its last attached
        moving body (torque about that body's point of the joint, or its origin); ``D.torque``,
        ``D.force``, ``D.power`` of a drive: the actuator's effort and its power."""
        names = JOINT_QUANTITIES if c.kind == "joint" else DRIVE_QUANTITIES
        quantities = names if len(parts) == 1 else parts[1:]
        if len(quantities) != len(names) and (len(parts) != 2 or parts[1] not in names):
            raise MechError(f"'{'.'.join(parts)}' is not an output of {c.kind} '{c.name}'"
                            + (suggest(parts[1], names) if len(parts) == 2 else ""), span,
                            notes=[f"{c.kind} quantities: " + " ".join(names)])
        moving = [i for i, b in enumerate(c.bodies) if b != GROUND]
        slot = moving[-1]
        body = self.body_index[c.bodies[slot]]
        point = None
        group = next(g for g in self.groups if k in g.members) if self.evaluated else None
        if group is not None:
            refs = [a for a in group.ctype.signature if a.is_reference]
            if refs[slot].kind == "point":
                j = group.members.index(k)
                point = _readonly(group.params[refs[slot].name][:, 0, j][:, None])
        return [ReactionOutput(f"{c.name}.{q}", k, q, body, point, unit=self._unit(q))
                for q in quantities]

    # -- time ----------------------------------------------------------------------------------

#: The time derivative of each output quantity (an acceleration has none computed).
RATE = {"x": "vx", "y": "vy", "phi": "omega", "vx": "ax", "vy": "ay", "omega": "alpha"}


def _order(quantity: str) -> int:
    if quantity in ("x", "y", "phi"):
        return 0
    if quantity in ("vx", "vy", "omega"):
        return 1
    return 2


def check_compile(variants: int, values_per_variant: int, limit: int) -> None:
    """Before a model is compiled for ``variants`` sweep variants: its arrays hold about
    ``values_per_variant`` numbers per variant (points, arguments, guesses, params), built
    through one temporary copy each."""
    within({"the process so far": resident_bytes(),
            "the compiled model": 2 * BYTES * variants * values_per_variant}, limit)
