"""The checks of a model that need no plugin, and the assembly of the model's statements.

Duplicate names, params used before they are defined, unknown functions and their arity,
time ``t`` where only constants may appear, truth values where numbers are expected: each is
a :class:`~mechdsl.errors.MechError` located at the offending text.
"""

from __future__ import annotations

from ..errors import MechError, Source, Span, cut, suggest
from . import expr as E
from . import motion_functions
from . import statements as S
from .model import (
    BODY_QUANTITIES, ENERGY_QUANTITIES, GROUND, ORIGIN, REDUCTIONS, Body, Drive, Force, Initial, Joint, Model, NamedOutput,
    Optimization, OutputRef, Param, Reduction, ReducedOutput,
    Point, Polygon, Simulate, Sweep, Vector,
)

TIME = "t"
RESERVED = {TIME, "table", *E.CONSTANTS, *E.FUNCTIONS}


def check_expr(e: E.Expr, allowed: set[str], context: str, numeric: bool = True) -> None:
    """Raise a MechError if ``e`` uses an undefined name, a reference, an unknown function, a
    wrong number of arguments, or mixes truth values and numbers.

    ``allowed`` holds the names that may appear (params so far, plus ``t`` in a drive).
    ``numeric`` says whether ``e`` must be a number (True) or a condition (False). The first
    mistake in reading order is reported; the walk keeps its own stack (no recursion limit).
    """
    stack = [(e, numeric)]
    while stack:
        node, num = stack.pop()
        _check_node(node, num, allowed, context)
        stack.extend(reversed(_operands(node)))


def _operands(e: E.Expr) -> list[tuple[E.Expr, bool]]:
    """The sub-expressions of ``e`` that are checked, each with whether it must be a number."""
    if isinstance(e, E.Call):
        return [(a, True) for a in e.args]
    if isinstance(e, E.Cond):
        return [(e.test, False), (e.then, True), (e.orelse, True)]
    if isinstance(e, (E.Compare, E.Binary)):
        return [(e.left, True), (e.right, True)]
    if isinstance(e, E.Logic):
        return [(e.left, False), (e.right, False)]
    if isinstance(e, E.Unary):
        return [(e.operand, e.op == "-")]
    if isinstance(e, E.Table):
        return [(e.arg, True)]
    return []


def _check_node(e: E.Expr, numeric: bool, allowed: set[str], context: str) -> None:
    if numeric and E.is_boolean(e):
        raise MechError("a comparison is not a number; use it as the condition of an 'if'",
                        e.span)
    if not numeric and not E.is_boolean(e):
        raise MechError("the condition of an 'if' must be a comparison (< <= > >=)", e.span)
    if isinstance(e, E.Name):
        if e.id not in allowed:
            if e.id == TIME:
                raise MechError(f"time 't' cannot appear in {context}; only a drive's function "
                                "may depend on time", e.span)
            raise MechError(f"unknown name '{cut(e.id)}' in {context}"
                            + suggest(e.id, allowed - {TIME}), e.span)
    elif isinstance(e, E.Ref):
        raise MechError(f"'{cut('.'.join(e.parts))}' is a reference, not a number; "
                        "references can only be joint or drive arguments", e.span)
    elif isinstance(e, E.Call):
        if e.func not in E.FUNCTIONS:
            raise MechError(f"unknown function '{cut(e.func)}'" + suggest(e.func, E.FUNCTIONS),
                            e.span)
        lo, hi = E.FUNCTIONS[e.func]
        n = len(e.args)
        if n < lo or (hi is not None and n > hi):
            want = f"{lo}" if lo == hi else f"at least {lo}"
            raise MechError(f"{e.func}() takes {want} argument{'s' if lo > 1 else ''}, "
                            f"got {n}", e.span)


def _check_vector(v: Vector, size: int, what: str, allowed: set[str]) -> None:
    if len(v.items) != size:
        raise MechError(f"{what} takes {size} numbers, got {len(v.items)}", v.span)
    for item in v.items:
        check_expr(item, allowed, what)


def _keywords_once(statement: str, args) -> None:
    """Refuse a keyword argument given twice to the joint, drive, initial or force
    ``statement`` (located at the second)."""
    kw = _Names(f"argument of {cut(statement)}")
    for a in args:
        if a.name is not None:
            kw.add(a.name, a.span)


class _Names:
    """Detects a name declared twice and points at both places."""

    def __init__(self, what: str, global_name: bool = False) -> None:
        #: ``global_name``: a name an output's expression can read (a param, a body, a
        #: joint's), which may not be a quantity's
        self.what, self.global_name = what, global_name
        self.seen: dict[str, Span] = {}

    def add(self, name: str, span: Span) -> None:
        if self.global_name and name in ENERGY_QUANTITIES:
            # one name, one meaning: the compiler, the checks and the editor all read an
            # energy's name in an output's expression as the energy
            raise MechError(f"'{cut(name)}' is reserved: it is an output quantity (the "
                            f"mechanism's energy); name the {self.what} otherwise", span)
        if name in self.seen:
            first = self.seen[name]
            raise MechError(f"{self.what} '{cut(name)}' is declared twice", span,
                            notes=[f"first declared at line {first.line}"])
        self.seen[name] = span


def _once(current, item: S.BodyItem, what: str, body: str, refused: str | None):
    """The value of a body item that may be given once, and (``refused`` None) here at all."""
    if refused is not None:
        raise MechError(refused, item.span)
    if current is not None:
        raise MechError(f"body '{cut(body)}' has two {what}", item.span)
    return item.value


def _build_body(name: str, name_span: Span, items: list, span: Span, is_ground: bool,
                params: set[str]) -> Body:
    points: list[Point] = []
    names = _Names(f"point of {cut(name)}")
    guess = shape = density = None
    dyn: dict[str, object] = {}
    for item in items:
        kind = item.kind if isinstance(item, S.BodyItem) else None
        if kind == "shape":
            shape = _once(shape, item, "shapes", name, None)
            if isinstance(shape, Polygon):
                if len(shape.vertices) < 3:
                    raise MechError("a polygon needs at least three vertices", shape.span)
                for v in shape.vertices:
                    _check_vector(v, 2, "a vertex (x, y)", params)
        elif kind == "density":
            density = _once(density, item, "densities", name,
                            "the ground does not move: it takes no density" if is_ground else None)
            check_expr(density, params, f"the density of {cut(name)}")
        elif kind in ("mass", "inertia", "centroid", "v0"):
            what = {"mass": "masses", "inertia": "inertias", "centroid": "centroids",
                    "v0": "initial velocities"}[kind]
            value = _once(dyn.get(kind), item, what, name,
                          f"the ground does not move: it takes no {kind}" if is_ground else None)
            if kind == "centroid":
                _check_vector(value, 2, "a centroid (x, y)", params)
            elif kind == "v0":
                _check_vector(value, 3, "an initial velocity (vx, vy, omega)", params)
            else:
                check_expr(value, params, f"the {kind} of {cut(name)}")
            dyn[kind] = value
        elif kind == "guess":
            guess = _once(guess, item, "guesses", name,
                          "the ground is fixed at (0, 0, 0); it takes no guess" if is_ground
                          else None)
            _check_vector(guess, 3, "a guess (x, y, phi)", params)
        elif isinstance(item, S.Declared):  # a point
            point, pspan = item.node, item.name_span
            if point.name == ORIGIN:
                raise MechError("'origin' is implicit: every body has the point origin = (0, 0)",
                                pspan)
            if point.name in BODY_QUANTITIES:
                raise MechError(f"a point cannot be named '{point.name}': "
                                f"{cut(name)}.{point.name} is an output quantity of the body",
                                pspan)
            names.add(point.name, pspan)
            _check_vector(point.coords, 2, "a point (x, y)", params)
            points.append(point)
    if density is not None and shape is None:
        raise MechError(f"body '{cut(name)}' has a density but no shape: give it "
                        "shape = polygon(...) or shape = \"file.msh\"", span)
    if density is not None and "mass" in dyn:
        raise MechError(f"body '{cut(name)}' has both a mass and a density: give the mass "
                        "(with inertia and centroid), or the shape's density", span)
    for kind in ("inertia", "centroid"):
        if kind in dyn and "mass" not in dyn:
            raise MechError(f"body '{cut(name)}' has an {kind} but no mass: give mass = m",
                            span)
    return Body(name, tuple(points), guess, span, is_ground, shape, density,
                dyn.get("mass"), dyn.get("inertia"), dyn.get("centroid"), dyn.get("v0"))


def build_model(source: Source, statements: list, files: tuple[str, ...] = ()) -> Model:
    """The :class:`Model` of the statements the parser gives, checked; ``files`` are the
    real paths of the files the model names."""
    params: list[Param] = []
    param_names = _Names("param", global_name=True)
    bodies: list[Body] = []
    body_names = _Names("body", global_name=True)
    body_names.add(GROUND, Span(1, 1, 1, 1))
    constraint_names = _Names("joint, drive or force", global_name=True)
    joints: list[Joint] = []
    drives: list[Drive] = []
    outputs: list[OutputRef] = []
    traces: list[OutputRef] = []
    units: dict[str, str] = {}
    sweeps: list[Sweep] = []
    sweep_names = _Names("sweep of")
    ground: Body | None = None
    simulate: Simulate | None = None
    defined: set[str] = set()
    pending_sweeps: list[tuple[Sweep, Span]] = []
    plugins: list[tuple[str, Span]] = []
    forces: list[Force] = []
    initials: list[Initial] = []
    gravity: Vector | None = None
    optimizing: dict[type, object] = {}

    for st in statements:
        match st:
            case S.Declared(Param() as p, nspan):
                if p.name in RESERVED:
                    raise MechError(f"'{cut(p.name)}' is reserved and cannot name a param",
                                    nspan)
                param_names.add(p.name, nspan)
                check_expr(p.value, defined, f"param '{cut(p.name)}'")
                if p.range is not None:
                    for bound in p.range:
                        check_expr(bound, defined, f"the range of param '{cut(p.name)}'")
                defined.add(p.name)
                params.append(p)
            case S.GroundDecl(items, span):
                if ground is not None:
                    raise MechError("the ground is declared twice", span,
                                    notes=[f"first declared at line {ground.span.line}"])
                ground = _build_body(GROUND, span, items, span, True, defined)
            case S.BodyDecl(name, nspan, items, span):
                if name == GROUND:
                    raise MechError("the ground is declared with 'ground { ... }'", nspan)
                body_names.add(name, nspan)
                bodies.append(_build_body(name, nspan, items, span, False, defined))
            case S.Declared(Joint() | Drive() as c, nspan):
                constraint_names.add(c.name, nspan)
                _keywords_once(c.name, c.args)
                if isinstance(c, Drive):
                    # t joins the params for this check only (a copy per drive would be
                    # quadratic in a model of many params and drives); t is never a param
                    defined.add(TIME)
                    try:
                        check_expr(c.function, defined,
                                   f"the function of drive '{cut(c.name)}'")
                    finally:
                        defined.discard(TIME)
                    drives.append(c)
                else:
                    joints.append(c)
            case S.Declared(Initial() as c, nspan):
                # one namespace with the joints and drives: messages name the statement
                constraint_names.add(c.name, nspan)
                _keywords_once(c.name, c.args)
                # a value at t0: params only (time 't' is refused, located, by check_expr)
                check_expr(c.value, defined, f"the value of initial '{cut(c.name)}'")
                if c.rate is not None:
                    check_expr(c.rate, defined, f"the rate of initial '{cut(c.name)}'")
                initials.append(c)
            case S.Declared(Force() as f, nspan):
                constraint_names.add(f.name, nspan)
                _keywords_once(f.name, f.args)
                forces.append(f)
            case S.GravityDecl(vec, span):
                if gravity is not None:
                    raise MechError("gravity is given twice", span,
                                    notes=[f"first given at line {gravity.span.line}"])
                _check_vector(vec, 2, "gravity (gx, gy)", defined)
                gravity = vec
            case Simulate():
                if simulate is not None:
                    raise MechError("a second 'simulate' statement", st.span,
                                    notes=[f"the first is at line {simulate.span.line}"])
                for e in (st.t0, st.t1, st.step):
                    check_expr(e, defined, "the simulated span")
                for name, e, _ in st.options:
                    check_expr(e, defined, f"the option {name} of simulate")
                simulate = st
            case S.PluginLine(module, span):
                if not all(part.isidentifier() for part in module.split(".")):
                    raise MechError(f"'{cut(module)}' is not a module name", span)
                plugins.append((module, span))
            case S.OutputList(items):
                for item in items:
                    if isinstance(item, NamedOutput):
                        item = named_output(item, defined)
                    outputs.append(item)
            case S.TraceList(items):
                traces.extend(items)
            case S.OptimizeDecl() | S.ObjectiveDecl() | S.RequirementDecl():
                first = optimizing.get(type(st))
                if first is not None:
                    raise MechError(f"a second '{st.word}' statement; give all in one",
                                    st.span, notes=[f"the first is at line {first.span.line}"])
                optimizing[type(st)] = st
            case S.UnitsDecl(given, _):
                for dim, text, span in given:
                    if dim in units:
                        raise MechError(f"the unit of {dim} is given twice", span)
                    units[dim] = text
            case S.Declared(Sweep() as sw, nspan):
                sweep_names.add(sw.name, nspan)
                pending_sweeps.append((sw, nspan))
                for e in _sweep_exprs(sw):
                    check_expr(e, defined, f"the sweep of '{cut(sw.name)}'")
                sweeps.append(sw)
            case _:  # pragma: no cover - the transformer returns only the kinds above
                raise TypeError(f"unexpected statement {st!r}")

    for sw, nspan in pending_sweeps:
        if sw.name not in param_names.seen:
            raise MechError(f"'{cut(sw.name)}' is not a param; only params can be swept"
                            + suggest(sw.name, param_names.seen), nspan)
    if ground is None:
        ground = Body(GROUND, (), None, Span(1, 1, 1, 1), True)
    optimization = _optimization(optimizing, defined) if optimizing else None
    return Model(source, tuple(params), ground, tuple(bodies), tuple(joints), tuple(drives),
                 simulate, tuple(outputs), tuple(sweeps), tuple(plugins), tuple(traces),
                 tuple(units.items()), tuple(files), tuple(forces), gravity, optimization,
                 tuple(initials))


_SLACK = {">=": lambda a, b: E.sub(a, b), ">": lambda a, b: E.sub(a, b),
          "<=": lambda a, b: E.sub(b, a), "<": lambda a, b: E.sub(b, a)}


def _optimization(found: dict[type, object], params: set[str]) -> Optimization:
    """The ``optimize``, ``minimize``/``maximize`` and ``subject to`` statements, checked:
    the varied names are params, each once, with bounds of the params; the objective and each
    requirement's slack are reductions."""
    if S.OptimizeDecl not in found:
        st = found.get(S.ObjectiveDecl) or found[S.RequirementDecl]
        raise MechError(f"'{st.word}' without an 'optimize' statement naming the "
                        "params to vary (optimize l in 2.5 .. 4)", st.span)
    ranges, span = found[S.OptimizeDecl].ranges, found[S.OptimizeDecl].span
    if S.ObjectiveDecl not in found:
        raise MechError("'optimize' without an objective: add 'minimize EXPR' (or "
                        "'maximize'), EXPR a reduction such as max(abs(slider.ax))", span)
    seen: set[str] = set()
    varied = {name for name, *_ in ranges}
    for name, lo, hi, nspan in ranges:
        if name not in params:
            raise MechError(f"'{cut(name)}' is not a param; only params can be optimised"
                            + suggest(name, params), nspan)
        if name in seen:
            raise MechError(f"'{cut(name)}' is varied twice", nspan)
        seen.add(name)
        for e in (lo, hi):  # fixed while the params vary
            check_expr(e, params - varied, f"the bounds of '{cut(name)}'")
    wanted = found[S.ObjectiveDecl]
    sense, expr, ospan = wanted.sense, wanted.expr, wanted.span
    objective = named_output(NamedOutput("objective", expr, ospan, ospan), params)
    if not isinstance(objective, ReducedOutput):
        read = _quantities(objective.expr)
        if any(isinstance(n, E.Name) and (n.id in read or n.id == TIME)
               for n in E.walk(objective.expr)):
            raise MechError(f"{sense} takes one value per variant: a reduction of the motion "
                            "such as max(abs(slider.ax)) or mean(rod.omega^2), or params",
                            expr.span or ospan)
        # of the params alone (minimize e subject to range(slider.x) >= 2.1): the size of
        # a design, its performance in the requirements
        objective = ReducedOutput(objective.name, objective.expr, (), ospan, ospan)
    requirements = []
    if S.RequirementDecl in found:
        given = found[S.RequirementDecl]
        for k, e in enumerate(given.exprs, start=1):
            if not isinstance(e, E.Compare) or e.op not in _SLACK:
                raise MechError("a requirement is a comparison with >=, >, <= or <, such as "
                                "range(slider.x) >= 4", e.span or given.span)
            slack = _SLACK[e.op](e.left, e.right)
            out = named_output(NamedOutput(f"requirement_{k}", slack, e.span, e.span), params)
            if not isinstance(out, ReducedOutput):  # of the params alone
                read = _quantities(out.expr)
                quantity = next((n for n in E.walk(out.expr) if isinstance(n, E.Name)
                                 and (n.id in read or n.id == TIME)), None)
                if quantity is not None:
                    raise MechError(f"'{cut(quantity.id)}' is outside a reduction: a "
                                    "requirement holds for the whole run; reduce it (max, min, "
                                    "range, ...)", quantity.span or e.span)
                out = ReducedOutput(out.name, out.expr, (), e.span, e.span)
            requirements.append(out)
    return Optimization(tuple(ranges), "max" if sense == "maximize" else "min", objective,
                        tuple(requirements), span)


def named_output(out: NamedOutput, params: set[str]) -> NamedOutput | ReducedOutput:
    """``output NAME = EXPR`` with its references to output quantities (``rod.phi``,
    ``lever.O.x``) as names (``Name("rod.phi")``) that the compiler resolves, and the
    functions of points and bodies (``distance(P, Q)``, ``ic_x(A, B)``, ...) written out as
    expressions of them (:mod:`mechdsl.grammar.motion_functions`); checked as any
    expression of the params, ``t`` and those names."""
    if out.name in RESERVED or out.name == TIME:
        raise MechError(f"'{cut(out.name)}' is reserved and cannot name an output",
                        out.name_span)
    if out.name in ENERGY_QUANTITIES:
        raise MechError(f"'{cut(out.name)}' is reserved: it is an output quantity (the "
                        "mechanism's energy); name the output otherwise", out.name_span)
    if out.name in params:  # a swept param is a column of the CSV too
        raise MechError(f"'{cut(out.name)}' is a param; give the output another name",
                        out.name_span)

    def rule(e: E.Expr) -> E.Expr:
        if isinstance(e, E.Ref):
            return E.Name(".".join(e.parts), e.span)
        if isinstance(e, E.Call) and e.func in motion_functions.SIGNATURES:
            return motion_functions.expand(e)
        return e

    expr = E.rewrite(out.expr, rule)
    if not out.name.isidentifier() and not _is_reduction(expr):  # output FUNC(EXPR)
        raise MechError(f"{cut(out.name)}: only a reduction ({', '.join(REDUCTIONS)}) of one "
                        "expression may stand unnamed in an output; name it: output NAME = "
                        "...", out.span)
    if not out.name.isidentifier() and "," in out.name:  # a column name of the CSV
        raise MechError(f"{cut(out.name)}: name this output (output NAME = ...); its text "
                        "has a comma, which a CSV column name cannot", out.span)
    if any(_is_reduction(n) for n in E.walk(expr)):
        return _reduced_output(out.name, expr, params, out)
    check_expr(expr, params | _quantities(expr) | {TIME}, f"output '{cut(out.name)}'")
    return NamedOutput(out.name, expr, out.span, out.name_span)


def _quantities(e: E.Expr) -> set[str]:
    """The quantities an output's expression reads: ``body.x``, ``joint.fx``, ... and the
    energies (``kinetic_energy``, ...: reserved names, :class:`_Names`)."""
    return {n.id for n in E.walk(e) if isinstance(n, E.Name) and (
        "." in n.id or n.id in ENERGY_QUANTITIES)}


def _is_reduction(e: E.Expr) -> bool:
    """A call of one of :data:`REDUCTIONS` with one argument (``max(a, b)`` is elementwise)."""
    return isinstance(e, E.Call) and e.func in REDUCTIONS and (
        len(e.args) == 1 or e.func not in E.FUNCTIONS)


def _reduced_output(name: str, expr: E.Expr, params: set[str],
                    out: NamedOutput) -> ReducedOutput:
    """An output with reductions: each reduction's argument checked as an expression of the
    params, ``t`` and quantities; the expression around them as one of the params and the
    reductions alone (a quantity outside every reduction has no single value)."""
    context = f"output '{cut(name)}'"
    found: list[Reduction] = []

    def rule(e: E.Expr) -> E.Expr:
        if not _is_reduction(e):
            return e
        if len(e.args) != 1:
            raise MechError(f"{e.func}() takes one expression (the value to reduce over the "
                            f"run), not {len(e.args)}", e.span)
        (arg,) = e.args
        inner = next((n for n in E.walk(arg) if isinstance(n, E.Name) and n.id.startswith("@")),
                     None)
        if inner is not None:
            raise MechError(f"a reduction inside {e.func}(): reduce a history once", e.span)
        check_expr(arg, params | _quantities(arg) | {TIME}, context)
        found.append(Reduction(e.func, arg, e.span or out.span))
        return E.Name(f"@{len(found) - 1}", e.span)

    outer = E.rewrite(expr, rule)
    read = _quantities(outer)
    for n in E.walk(outer):
        if isinstance(n, E.Name) and (n.id in read or n.id == TIME):
            raise MechError(f"'{cut(n.id)}' is outside a reduction: an output with "
                            f"{found[0].func}() has one value per variant; reduce "
                            f"'{cut(n.id)}' too (max, min, mean, final, ...)",
                            n.span or out.span)
    check_expr(outer, params | {f"@{k}" for k in range(len(found))}, context)
    return ReducedOutput(name, outer, tuple(found), out.span, out.name_span)


def _sweep_exprs(sw: Sweep) -> list[E.Expr]:
    if sw.values is not None:
        return list(sw.values)
    return [e for e in (sw.start, sw.stop, sw.step, sw.count) if e is not None]


