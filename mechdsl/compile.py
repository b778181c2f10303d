"""Model + registry -> :class:`System`: everything the solver needs, as index maps and arrays.

Compiling resolves names (bodies, points, types, arguments, outputs) and evaluates every
number for every sweep variant. Constraints are grouped by type, so that the solver evaluates
each type with one call for all of its constraints, all instants of a block and all variants.

Shapes: V sweep variants (1 without a sweep), J constraints of a group, n = 3 * (number of
moving bodies) coordinates, m equations. Per-variant values are stored with a singleton axis
after V -- params ``(V, 1)``, group values ``(V, 1, J, ...)`` -- so that they broadcast against
solver arrays of shape ``(V, b, ...)`` for a block of b instants.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from . import expr as E
from .errors import MechError, Source, Span, suggest
from .model import (
    BODY_QUANTITIES, GROUND, ORIGIN, POINT_QUANTITIES, Body, Drive, Joint, Model, Vector,
)
from .parse import TIME, check_expr
from .plugins.contract import REQUIRED, ArgError, ConstraintType
from .plugins.registry import Registry

#: Largest number of instants a run may have unless the caller raises it.
MAX_INSTANTS = 50_000_000
#: Relative slack when deciding whether (t1 - t0) / step is a whole number of steps.
GRID_SLACK = 1e-9


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
    cols: tuple[np.ndarray, ...]


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
    outputs: tuple[OutputSpec, ...]
    order: int = field(default=0)

    @property
    def n_bodies(self) -> int:
        return len(self.body_names)

    def row_owner(self, row: int) -> Constraint:
        """The joint or drive that owns equation ``row``."""
        for c in self.constraints:
            if c.rows[0] <= row < c.rows[1]:
                return c
        raise IndexError(row)


@dataclass
class Overrides:
    """Values that replace what the file says: params, sweeps, and the simulated span.

    Values are expressions or plain numbers; ``params`` entries remove a sweep of that name.
    """

    params: dict[str, E.Expr | float] = field(default_factory=dict)
    sweeps: dict[str, Sequence[E.Expr | float]] = field(default_factory=dict)
    t0: E.Expr | float | None = None
    t1: E.Expr | float | None = None
    step: E.Expr | float | None = None
    max_instants: int = MAX_INSTANTS


def _as_expr(v: E.Expr | float) -> E.Expr:
    return E.Num(float(v)) if isinstance(v, (int, float, np.number)) else v


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


# ---------------------------------------------------------------------------------------------


def compile_model(model: Model, registry: Registry, overrides: Overrides | None = None,
                  *, need_times: bool = True) -> System:
    """Resolve ``model`` against ``registry`` for every sweep variant.

    Raises :class:`MechError` (with the model's source attached) for every unknown name, bad
    argument, non-finite value or inconsistent time grid.
    """
    try:
        return _Compiler(model, registry, overrides or Overrides()).run(need_times)
    except MechError as err:
        raise err.with_source(model.source) from None


class _Compiler:
    def __init__(self, model: Model, registry: Registry, ov: Overrides) -> None:
        self.model, self.registry, self.ov = model, registry, ov
        self.param_names = [p.name for p in model.params]

    def run(self, need_times: bool) -> System:
        sweep = self._sweep_table()
        self.V = len(next(iter(sweep.values()))) if sweep else 1
        self.env = self._params(sweep)
        self._bodies()
        constraints, groups, drive_rows, drive_fns = self._constraints()
        outputs = self._outputs()
        times = self._times() if need_times else None
        order = max((o.order for o in outputs), default=0)
        env = {k: _readonly(v[:, None]) for k, v in self.env.items()}
        return System(
            source=self.model.source,
            body_names=tuple(b.name for b in self.bodies),
            n=3 * len(self.bodies),
            m=constraints[-1].rows[1] if constraints else 0,
            constraints=tuple(constraints),
            groups=tuple(groups),
            drive_rows=_readonly(np.asarray(drive_rows, dtype=np.intp)),
            drive_functions=tuple(drive_fns),
            env=env,
            sweep={k: _readonly(v) for k, v in sweep.items()},
            n_variants=self.V,
            guess=_readonly(self._guess()),
            scale=_readonly(self._scale()),
            times=None if times is None else _readonly(times),
            outputs=tuple(outputs),
            order=order,
        )

    # -- params and sweeps ---------------------------------------------------------------------
    def _check_override_name(self, name: str, what: str) -> None:
        if name not in self.param_names:
            raise MechError(f"{what} '{name}': there is no param of that name"
                            + suggest(name, self.param_names))

    def _sweep_table(self) -> dict[str, np.ndarray]:
        ov = self.ov
        for name in ov.params:
            self._check_override_name(name, "cannot set")
        for name in ov.sweeps:
            self._check_override_name(name, "cannot sweep")
        base = self._params({}, keep_sweeps=False)
        lists: dict[str, tuple[np.ndarray, Span | None]] = {}
        for sw in self.model.sweeps:
            if sw.name in ov.params or sw.name in ov.sweeps:
                continue
            lists[sw.name] = (self._sweep_values(sw, base), sw.span)
        for name, values in ov.sweeps.items():
            vals = [self._scalar(_as_expr(v), base, f"--sweep {name}", None) for v in values]
            lists[name] = (np.array(vals, dtype=float), None)
        if not lists:
            return {}
        combos = list(itertools.product(*(v for v, _ in lists.values())))
        table = np.array(combos, dtype=float).reshape(len(combos), len(lists))
        return {name: table[:, i].copy() for i, name in enumerate(lists)}

    def _sweep_values(self, sw, base: dict[str, np.ndarray]) -> np.ndarray:
        swept = {s.name for s in self.model.sweeps} | set(self.ov.sweeps)
        exprs = [e for e in (sw.values or (sw.start, sw.stop, sw.step, sw.count)) if e is not None]
        for e in exprs:
            dep = E.free_names(e) & swept
            if dep:
                raise MechError(f"sweep values cannot depend on the swept param '{dep.pop()}'",
                                e.span)
        if sw.values is not None:
            return np.array([self._scalar(e, base, "a sweep value", e.span) for e in sw.values])
        a = self._scalar(sw.start, base, "a sweep bound", sw.start.span)
        b = self._scalar(sw.stop, base, "a sweep bound", sw.stop.span)
        if sw.count is not None:
            c = self._scalar(sw.count, base, "a sweep count", sw.count.span)
            if c != int(c) or c < 1:
                raise MechError(f"a sweep count must be a whole number >= 1, not {c:g}",
                                sw.count.span)
            return np.linspace(a, b, int(c))
        h = self._scalar(sw.step, base, "a sweep step", sw.step.span)
        return _grid(a, b, h, sw.span, "sweep", self.ov.max_instants)

    def _scalar(self, e: E.Expr, env, what: str, span: Span | None) -> float:
        v = np.asarray(E.evaluate(e, {k: x[0] for k, x in env.items()}), dtype=float)
        if v.ndim or not math.isfinite(float(v)):
            raise MechError(f"{what} must be a finite number, not {float(v)!r}", span)
        return float(v)

    def _params(self, sweep: dict[str, np.ndarray], keep_sweeps: bool = True) -> dict:
        V = len(next(iter(sweep.values()))) if sweep else 1
        env: dict[str, np.ndarray] = {}
        for p in self.model.params:
            if p.name in sweep:
                value = sweep[p.name]
            elif p.name in self.ov.params:
                e = _as_expr(self.ov.params[p.name])
                where = f"--set {p.name}"
                late = E.free_names(e) - env.keys()
                if late:
                    raise MechError(f"{where}: '{sorted(late)[0]}' is not a param defined "
                                    f"before '{p.name}'")
                value = E.evaluate(e, env)
                if not np.all(np.isfinite(value)):
                    raise MechError(f"{where} gives {_first_bad(value)}")
            else:
                value = E.evaluate(p.value, env)
            value = np.broadcast_to(np.asarray(value, dtype=float), (V,)).copy()
            if not np.all(np.isfinite(value)):
                raise MechError(f"param '{p.name}' is {_first_bad(value)}"
                                + self._variant_note(sweep, value), p.span)
            env[p.name] = value
        return env

    @staticmethod
    def _variant_note(sweep, value) -> str:
        if not sweep:
            return ""
        i = int(np.flatnonzero(~np.isfinite(value))[0])
        return " for " + ", ".join(f"{k} = {v[i]:g}" for k, v in sweep.items())

    def _values(self, e: E.Expr, what: str, span: Span | None) -> np.ndarray:
        """An expression of params, evaluated for every variant: shape (V,)."""
        value = np.broadcast_to(np.asarray(E.evaluate(e, self.env), dtype=float), (self.V,))
        if not np.all(np.isfinite(value)):
            raise MechError(f"{what} is {_first_bad(value)}", span)
        return value

    def _vector(self, v: Vector, what: str) -> np.ndarray:
        """A vector of expressions: shape (V, len)."""
        return np.stack([self._values(e, what, e.span) for e in v.items], axis=-1)

    # -- bodies --------------------------------------------------------------------------------
    def _bodies(self) -> None:
        self.bodies: list[Body] = list(self.model.bodies)
        self.body_index = {b.name: i for i, b in enumerate(self.bodies)}
        self.body_index[GROUND] = len(self.bodies)
        self.points: dict[str, dict[str, np.ndarray]] = {}
        for b in [*self.bodies, self.model.ground]:
            pts = {ORIGIN: np.zeros((self.V, 2))}
            for pt in b.points:
                pts[pt.name] = self._vector(pt.coords, f"point {b.name}.{pt.name}")
            self.points[b.name] = pts

    def _guess(self) -> np.ndarray:
        g = np.zeros((self.V, 3 * len(self.bodies)))
        for i, b in enumerate(self.bodies):
            if b.guess is not None:
                g[:, 3 * i : 3 * i + 3] = self._vector(b.guess, f"the guess of {b.name}")
        return g

    def _scale(self) -> np.ndarray:
        """A length characteristic of the model, per variant: the largest point coordinate or
        guessed position (1 if all are zero). Convergence tests on lengths are relative to it."""
        s = np.zeros(self.V)
        for pts in self.points.values():
            for xy in pts.values():
                s = np.maximum(s, np.abs(xy).max(axis=-1))
        g = self._guess().reshape(self.V, -1, 3)[..., :2]
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
    def _constraints(self):
        constraints = []
        packed: dict[tuple[str, str], list] = {}
        drive_rows, drive_fns = [], []
        row = 0
        items: list[Joint | Drive] = [*self.model.joints, *self.model.drives]
        for c in items:
            kind = "drive" if isinstance(c, Drive) else "joint"
            ctype = self._type(kind, c.type_name, c.type_span)
            slots, params = self._bind(c, ctype)
            if all(s == self.body_index[GROUND] for s in slots):
                what = "a drive on the ground" if kind == "drive" else "a joint of the ground with itself"
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
            if kind == "drive":
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
            other = "joint" if kind == "drive" else "drive"
            if self.registry.get(other, name) is not None:
                raise MechError(f"'{name}' is a {other} type, not a {kind} type", span)
            raise MechError(f"unknown {kind} type '{name}'"
                            + suggest(name, self.registry.names(kind)), span,
                            notes=[f"{kind} types: " + ", ".join(self.registry.names(kind))
                                   if self.registry.names(kind) else
                                   f"no {kind} types are installed (see 'mechdsl plugins')"])
        return ctype

    def _bind(self, c: Joint | Drive, ctype: ConstraintType):
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
        slots: list[int] = []
        params: dict[str, np.ndarray] = {}
        spans: dict[str, Span] = {}
        for arg in sig:
            a = given.get(arg.name)
            if a is None:
                if arg.default is REQUIRED:
                    raise MechError(f"{ctype.name}() needs argument '{arg.name}' ({arg.kind})",
                                    c.span, notes=[f"signature: {ctype.describe()}"])
                params[arg.name] = np.broadcast_to(
                    np.asarray(arg.default, dtype=float),
                    (self.V,) + ((2,) if arg.kind == "vector" else ())).copy()
                continue
            spans[arg.name] = a.span
            v = a.value
            if arg.kind == "point":
                if isinstance(v, E.Ref):
                    body, xy = self._point_ref(v.parts, v.span)
                elif isinstance(v, E.Name) and v.id in self.body_index:
                    raise MechError(f"argument '{arg.name}' is a point: write {v.id}.origin or "
                                    f"{v.id}.POINT", a.span)
                else:
                    raise MechError(f"argument '{arg.name}' must be a point such as body.P",
                                    a.span)
                slots.append(body)
                params[arg.name] = xy
            elif arg.kind == "body":
                if isinstance(v, E.Name):
                    slots.append(self._body_ref(v.id, v.span))
                else:
                    raise MechError(f"argument '{arg.name}' must be a body name", a.span)
            elif arg.kind == "vector":
                if not isinstance(v, Vector) or len(v.items) != 2:
                    raise MechError(f"argument '{arg.name}' must be a vector (x, y)", a.span)
                params[arg.name] = self._vector(v, f"argument '{arg.name}'")
            else:
                if isinstance(v, Vector):
                    raise MechError(f"argument '{arg.name}' must be a number", a.span)
                if isinstance(v, E.Ref):
                    raise MechError(f"argument '{arg.name}' must be a number, not a reference",
                                    a.span)
                check_expr(v, set(self.param_names), f"argument '{arg.name}'")
                params[arg.name] = self._values(v, f"argument '{arg.name}'", a.span)
        try:
            with np.errstate(all="ignore"):
                ctype.validate(params)
        except ArgError as err:
            raise MechError(f"{ctype.name}: {err.message}", spans.get(err.arg, c.span)) from None
        return slots, params

    def _group(self, ctype: ConstraintType, members: list) -> Group:
        idx = tuple(m[0] for m in members)
        slots = np.array([m[1] for m in members], dtype=np.intp).reshape(len(members), -1)
        rows = np.array([np.arange(*m[3]) for m in members], dtype=np.intp)
        params = {}
        for name in members[0][2]:
            stacked = np.stack([m[2][name] for m in members], axis=1)  # (V, J, ...)
            params[name] = _readonly(stacked[:, None])
        # Jacobian columns in the extended matrix whose last 3 columns belong to the ground
        cols = tuple(_readonly((3 * slots[:, k])[:, None, None] + np.arange(3)[None, None, :])
                     for k in range(slots.shape[1]))
        return Group(ctype, idx, _readonly(slots), params, _readonly(rows), cols)

    def _drive_function(self, d: Drive) -> DriveFunction:
        f = d.function
        fd = E.derivative(f, TIME)
        fdd = E.derivative(fd, TIME)
        return DriveFunction(E.compile_expr(f), E.compile_expr(fd), E.compile_expr(fdd),
                             (f, fd, fdd))

    # -- outputs -------------------------------------------------------------------------------
    def _outputs(self) -> list[OutputSpec]:
        refs = self.model.outputs
        out: list[OutputSpec] = []
        if not refs:
            for b in self.bodies:
                out.extend(self._body_quantities(b.name, BODY_QUANTITIES))
            return out
        seen: set[str] = set()
        for r in refs:
            specs = self._output(r.parts, r.span)
            for s in specs:
                if s.label in seen:
                    raise MechError(f"output '{s.label}' is requested twice", r.span)
                seen.add(s.label)
            out.extend(specs)
        return out

    def _body_quantities(self, body: str, quantities) -> list[OutputSpec]:
        i = self.body_index[body]
        return [OutputSpec(f"{body}.{q}", i, None, q, _order(q)) for q in quantities]

    def _point_quantities(self, body: str, point: str, quantities) -> list[OutputSpec]:
        i = self.body_index[body]
        xy = _readonly(self.points[body][point][:, None])
        return [OutputSpec(f"{body}.{point}.{q}", i, xy, q, _order(q)) for q in quantities]

    def _output(self, parts: tuple[str, ...], span: Span) -> list[OutputSpec]:
        body = parts[0]
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

    # -- time ----------------------------------------------------------------------------------
    def _times(self) -> np.ndarray:
        sim = self.model.simulate
        ov = self.ov
        if sim is None and (ov.t1 is None or ov.step is None):
            raise MechError("nothing to simulate: add a line such as "
                            "'simulate t = 0 .. 1 step 0.001'")
        def pick(o, e, what):
            if o is not None:
                return self._values(_as_expr(o), what, None)
            return self._values(e, what, e.span)
        t0 = pick(ov.t0, sim.t0 if sim else E.Num(0.0), "the start time")
        t1 = pick(ov.t1, sim.t1 if sim else None, "the end time")
        h = pick(ov.step, sim.step if sim else None, "the step")
        span = sim.span if sim else None
        for v, what in ((t0, "start time"), (t1, "end time"), (h, "step")):
            if np.ptp(v) != 0:
                raise MechError(f"the {what} differs between sweep variants; the time grid "
                                "cannot depend on a swept param", span)
        return _grid(float(t0[0]), float(t1[0]), float(h[0]), span, "simulate",
                     ov.max_instants)


def _order(quantity: str) -> int:
    if quantity in ("x", "y", "phi"):
        return 0
    if quantity in ("vx", "vy", "omega"):
        return 1
    return 2


def _first_bad(value) -> str:
    v = np.asarray(value, dtype=float).ravel()
    bad = v[~np.isfinite(v)]
    return repr(float(bad[0])) if bad.size else "not finite"


def _grid(a: float, b: float, h: float, span: Span | None, what: str, limit: int) -> np.ndarray:
    """a + k h for k = 0, 1, ... up to b, and b itself: both ends included."""
    if not h > 0:
        raise MechError(f"the {what} step must be positive, not {h:g}", span)
    if b < a:
        raise MechError(f"the {what} range ends ({b:g}) before it starts ({a:g})", span)
    steps = (b - a) / h
    n = math.floor(steps + GRID_SLACK)
    if n + 2 > limit:
        raise MechError(f"the {what} has {n + 1:,} instants, more than the limit of {limit:,}",
                        span, notes=["raise the limit with --max-instants if this is intended"])
    grid = a + h * np.arange(n + 1, dtype=float)
    if steps - n > GRID_SLACK:
        grid = np.append(grid, b)
    else:
        grid[-1] = b if n > 0 else a
    return grid
