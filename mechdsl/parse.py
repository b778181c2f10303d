"""Text -> :class:`~mechdsl.model.Model`.

The lark grammar (``grammar/mech.lark``) gives a parse tree; a Transformer turns it into the
model's dataclasses, and :func:`parse` then checks what can be checked without plugins:
duplicate names, params used before they are defined, unknown functions and their arity,
time ``t`` where only constants may appear. lark's exceptions are translated here and nowhere
else: every error leaves this module as a :class:`~mechdsl.errors.MechError` with a span.
"""

from __future__ import annotations

import functools
from importlib import resources
from typing import Iterable

from lark import Lark, Token, Transformer, v_args
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

from . import expr as E
from .errors import MechError, Source, Span, suggest
from .model import (
    BODY_QUANTITIES, GROUND, ORIGIN, Arg, Body, Drive, Joint, Model, OutputRef, Param, Point,
    Simulate, Sweep, Vector,
)

TIME = "t"
RESERVED = {TIME, *E.CONSTANTS, *E.FUNCTIONS}


@functools.cache
def _parser() -> Lark:
    grammar = resources.files("mechdsl").joinpath("grammar/mech.lark").read_text("utf-8")
    return Lark(
        grammar,
        parser="lalr",
        start=["start", "expr_only", "expr_list"],
        propagate_positions=True,
        maybe_placeholders=False,
        cache=True,
    )


def _span(meta) -> Span:
    return Span(meta.line, meta.column, meta.end_line, meta.end_column)


def _tspan(tok: Token) -> Span:
    return Span(tok.line, tok.column, tok.end_line, tok.end_column)


def _join(a: Span, b: Span) -> Span:
    return Span(a.line, a.column, b.end_line, b.end_column)


@v_args(meta=True)
class _ToModel(Transformer):
    """Parse tree -> model nodes (statements are returned as a flat list)."""

    def start(self, meta, items):
        return [i for i in items if not isinstance(i, Token)]

    # -- expressions ---------------------------------------------------------------------------
    def number(self, meta, items):
        (tok,) = items
        return E.Num(float(tok), _tspan(tok))

    def name(self, meta, items):
        (tok,) = items
        if str(tok) in E.CONSTANTS:
            return E.Num(E.CONSTANTS[str(tok)], _tspan(tok))
        return E.Name(str(tok), _tspan(tok))

    def ref(self, meta, items):
        return E.Ref(tuple(str(t) for t in items), _span(meta))

    def call(self, meta, items):
        func, *args = items
        return E.Call(str(func), tuple(args), _span(meta))

    def _binary(op):  # noqa: N805 - a factory used in the class body
        def method(self, meta, items):
            left, right = items
            return E.Binary(op, left, right, _span(meta))

        return method

    add = _binary("+")
    sub = _binary("-")
    mul = _binary("*")
    div = _binary("/")
    pow = _binary("^")

    def neg(self, meta, items):
        (operand,) = items
        if isinstance(operand, E.Num):
            return E.Num(-operand.value, _span(meta))
        return E.Unary("-", operand, _span(meta))

    def compare(self, meta, items):
        left, op, right = items
        return E.Compare(str(op), left, right, _span(meta))

    def and_(self, meta, items):
        return E.Logic("and", items[0], items[1], _span(meta))

    def or_(self, meta, items):
        return E.Logic("or", items[0], items[1], _span(meta))

    def not_(self, meta, items):
        return E.Unary("not", items[0], _span(meta))

    def ifelse(self, meta, items):
        test, then, orelse = items
        return E.Cond(test, then, orelse, _span(meta))

    def vector(self, meta, items):
        return Vector(tuple(items), _span(meta))

    def expr_only(self, meta, items):
        return items[0]

    def expr_list(self, meta, items):
        return list(items)

    # -- statements ----------------------------------------------------------------------------
    def param(self, meta, items):
        name, value = items
        return Param(str(name), value, _span(meta)), _tspan(name)

    def point(self, meta, items):
        name, coords = items
        return Point(str(name), coords, _span(meta)), _tspan(name)

    def guess(self, meta, items):
        return ("guess", items[0], _span(meta))

    def ground(self, meta, items):
        return ("ground", items, _span(meta))

    def body(self, meta, items):
        name, *rest = items
        return ("body", (str(name), _tspan(name)), rest, _span(meta))

    def arg(self, meta, items):
        return Arg(None, items[0], _span(meta))

    def kwarg(self, meta, items):
        name, value = items
        return Arg(str(name), value, _span(meta))

    def joint(self, meta, items):
        name, type_name, *args = items
        return (Joint(str(name), str(type_name), tuple(args), _span(meta), _tspan(type_name)),
                _tspan(name))

    def drive(self, meta, items):
        name, type_name, *args, function = items
        return (Drive(str(name), str(type_name), tuple(args), function, _span(meta),
                      _tspan(type_name)), _tspan(name))

    def simulate(self, meta, items):
        var, t0, t1, step = items
        if str(var) != TIME:
            raise MechError(f"the simulated variable is time 't', not '{var}'", _tspan(var))
        return Simulate(t0, t1, step, _span(meta))

    def ref_or_name(self, meta, items):
        return OutputRef(tuple(str(t) for t in items), _span(meta))

    def output(self, meta, items):
        return ("output", tuple(items))

    def sweep_list(self, meta, items):
        return ("list", tuple(items))

    def sweep_range(self, meta, items):
        start, stop, kind, value = items
        return ("range", start, stop, str(kind), value)

    def sweep(self, meta, items):
        name, spec = items
        if spec[0] == "list":
            return Sweep(str(name), spec[1], None, None, None, None, _span(meta)), _tspan(name)
        _, start, stop, kind, value = spec
        step, count = (value, None) if kind == "step" else (None, value)
        return Sweep(str(name), None, start, stop, step, count, _span(meta)), _tspan(name)


# ---------------------------------------------------------------------------------------------
# Syntax errors

_TERMINAL_WORDS = {
    "NAME": "a name", "NUMBER": "a number", "COMPARE": "a comparison", "$END": "end of file",
    "STEP": "'step'", "COUNT": "'count'",
}


def _describe_expected(expected: Iterable[str]) -> str:
    lit = {t.name: t.pattern.value for t in _parser().terminals}
    words = sorted({_TERMINAL_WORDS.get(e) or f"'{lit.get(e, e)}'" for e in expected})
    if len(words) > 8:
        return ""
    if len(words) == 1:
        return f"; expected {words[0]}"
    return "; expected " + ", ".join(words[:-1]) + " or " + words[-1]


def _syntax_error(err: UnexpectedInput, source: Source) -> MechError:
    if isinstance(err, UnexpectedToken) and err.token.type == "$END":
        line = source.text.count("\n") + 1
        col = len(source.text) - source.text.rfind("\n")
        span = Span(line, col, line, col + 1)
        return MechError("unexpected end of file" + _describe_expected(err.expected), span, source)
    if isinstance(err, UnexpectedToken):
        tok = err.token
        what = f"'{tok}'" if tok.type != "NUMBER" else f"number {tok}"
        if tok.type == "NAME":
            what = f"name '{tok}'"
        msg = f"unexpected {what}" + _describe_expected(err.accepts or err.expected)
        return MechError(msg, _tspan(tok), source)
    if isinstance(err, UnexpectedCharacters):
        ch = source.text[err.pos_in_stream] if err.pos_in_stream < len(source.text) else "?"
        span = Span(err.line, err.column, err.line, err.column + 1)
        return MechError(f"unexpected character {ch!r}", span, source)
    if isinstance(err, UnexpectedEOF):
        return MechError("unexpected end of file", None, source)
    return MechError(str(err), None, source)  # pragma: no cover - lark has no other kinds


def _lark_parse(text: str, source: Source, start: str):
    try:
        tree = _parser().parse(text, start=start)
        return _ToModel().transform(tree)
    except UnexpectedInput as err:
        raise _syntax_error(err, source) from None
    except MechError as err:
        raise err.with_source(source) from None
    except Exception as err:  # a transformer error wrapped by lark
        inner = getattr(err, "orig_exc", None)
        if isinstance(inner, MechError):
            raise inner.with_source(source) from None
        raise


# ---------------------------------------------------------------------------------------------
# Semantic checks that need no plugin


def check_expr(e: E.Expr, allowed: set[str], context: str, numeric: bool = True) -> None:
    """Raise a MechError if ``e`` uses an undefined name, a reference, an unknown function, a
    wrong number of arguments, or mixes truth values and numbers.

    ``allowed`` holds the names that may appear (params so far, plus ``t`` in a drive).
    ``numeric`` says whether ``e`` must be a number (True) or a condition (False).
    """
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
            raise MechError(f"unknown name '{e.id}' in {context}"
                            + suggest(e.id, allowed - {TIME}), e.span)
    elif isinstance(e, E.Ref):
        raise MechError(f"'{'.'.join(e.parts)}' is a reference, not a number; "
                        "references can only be joint or drive arguments", e.span)
    elif isinstance(e, E.Call):
        if e.func not in E.FUNCTIONS:
            raise MechError(f"unknown function '{e.func}'" + suggest(e.func, E.FUNCTIONS), e.span)
        lo, hi = E.FUNCTIONS[e.func]
        n = len(e.args)
        if n < lo or (hi is not None and n > hi):
            want = f"{lo}" if lo == hi else f"at least {lo}"
            raise MechError(f"{e.func}() takes {want} argument{'s' if lo > 1 else ''}, "
                            f"got {n}", e.span)
        for a in e.args:
            check_expr(a, allowed, context)
    elif isinstance(e, E.Cond):
        check_expr(e.test, allowed, context, numeric=False)
        check_expr(e.then, allowed, context)
        check_expr(e.orelse, allowed, context)
    elif isinstance(e, E.Compare):
        check_expr(e.left, allowed, context)
        check_expr(e.right, allowed, context)
    elif isinstance(e, E.Logic):
        check_expr(e.left, allowed, context, numeric=False)
        check_expr(e.right, allowed, context, numeric=False)
    elif isinstance(e, E.Unary):
        check_expr(e.operand, allowed, context, numeric=(e.op == "-"))
    elif isinstance(e, E.Binary):
        check_expr(e.left, allowed, context)
        check_expr(e.right, allowed, context)


def _check_vector(v: Vector, size: int, what: str, allowed: set[str]) -> None:
    if len(v.items) != size:
        raise MechError(f"{what} takes {size} numbers, got {len(v.items)}", v.span)
    for item in v.items:
        check_expr(item, allowed, what)


class _Names:
    """Detects a name declared twice and points at both places."""

    def __init__(self, what: str) -> None:
        self.what = what
        self.seen: dict[str, Span] = {}

    def add(self, name: str, span: Span) -> None:
        if name in self.seen:
            first = self.seen[name]
            raise MechError(f"{self.what} '{name}' is declared twice", span,
                            notes=[f"first declared at line {first.line}"])
        self.seen[name] = span


def _build_body(name: str, name_span: Span, items: list, span: Span, is_ground: bool,
                params: set[str]) -> Body:
    points: list[Point] = []
    names = _Names(f"point of {name}")
    guess = None
    for item in items:
        if isinstance(item, tuple) and item and item[0] == "guess":
            if is_ground:
                raise MechError("the ground is fixed at (0, 0, 0); it takes no guess", item[2])
            if guess is not None:
                raise MechError(f"body '{name}' has two guesses", item[2])
            guess = item[1]
            _check_vector(guess, 3, "a guess (x, y, phi)", params)
        elif isinstance(item, tuple):
            point, pspan = item
            if point.name == ORIGIN:
                raise MechError("'origin' is implicit: every body has the point origin = (0, 0)",
                                pspan)
            if point.name in BODY_QUANTITIES:
                raise MechError(f"a point cannot be named '{point.name}': {name}.{point.name} is "
                                "an output quantity of the body", pspan)
            names.add(point.name, pspan)
            _check_vector(point.coords, 2, "a point (x, y)", params)
            points.append(point)
    return Body(name, tuple(points), guess, span, is_ground)


def parse(text: str, name: str = "<string>") -> Model:
    """Parse the text of a ``.mech`` file into a :class:`Model`.

    Raises :class:`MechError` (with span and source) for syntax errors and for every mistake
    that can be found without the plugin registry.
    """
    source = Source(name, text)
    statements = _lark_parse(text, source, "start")
    try:
        return _build_model(source, statements)
    except MechError as err:
        raise err.with_source(source) from None


def _build_model(source: Source, statements: list) -> Model:
    params: list[Param] = []
    param_names = _Names("param")
    bodies: list[Body] = []
    body_names = _Names("body")
    body_names.add(GROUND, Span(1, 1, 1, 1))
    constraint_names = _Names("joint or drive")
    joints: list[Joint] = []
    drives: list[Drive] = []
    outputs: list[OutputRef] = []
    sweeps: list[Sweep] = []
    sweep_names = _Names("sweep of")
    ground: Body | None = None
    simulate: Simulate | None = None
    defined: set[str] = set()
    pending_sweeps: list[tuple[Sweep, Span]] = []

    for st in statements:
        if isinstance(st, tuple) and isinstance(st[0], Param):
            p, nspan = st
            if p.name in RESERVED:
                raise MechError(f"'{p.name}' is reserved and cannot name a param", nspan)
            param_names.add(p.name, nspan)
            check_expr(p.value, defined, f"param '{p.name}'")
            defined.add(p.name)
            params.append(p)
        elif isinstance(st, tuple) and st[0] == "ground":
            _, items, span = st
            if ground is not None:
                raise MechError("the ground is declared twice", span,
                                notes=[f"first declared at line {ground.span.line}"])
            ground = _build_body(GROUND, span, items, span, True, defined)
        elif isinstance(st, tuple) and st[0] == "body":
            _, (name, nspan), items, span = st
            if name == GROUND:
                raise MechError("the ground is declared with 'ground { ... }'", nspan)
            body_names.add(name, nspan)
            bodies.append(_build_body(name, nspan, items, span, False, defined))
        elif isinstance(st, tuple) and isinstance(st[0], (Joint, Drive)):
            c, nspan = st
            constraint_names.add(c.name, nspan)
            kw = _Names(f"argument of {c.name}")
            for a in c.args:
                if a.name is not None:
                    kw.add(a.name, a.span)
                _check_arg(a, defined)
            if isinstance(c, Drive):
                check_expr(c.function, defined | {TIME}, f"the function of drive '{c.name}'")
                drives.append(c)
            else:
                joints.append(c)
        elif isinstance(st, Simulate):
            if simulate is not None:
                raise MechError("a second 'simulate' statement", st.span,
                                notes=[f"the first is at line {simulate.span.line}"])
            for e in (st.t0, st.t1, st.step):
                check_expr(e, defined, "the simulated span")
            simulate = st
        elif isinstance(st, tuple) and st[0] == "output":
            outputs.extend(st[1])
        elif isinstance(st, tuple) and isinstance(st[0], Sweep):
            sw, nspan = st
            sweep_names.add(sw.name, nspan)
            pending_sweeps.append((sw, nspan))
            for e in _sweep_exprs(sw):
                check_expr(e, defined, f"the sweep of '{sw.name}'")
            sweeps.append(sw)
        else:  # pragma: no cover - the transformer returns only the kinds above
            raise TypeError(f"unexpected statement {st!r}")

    for sw, nspan in pending_sweeps:
        if sw.name not in param_names.seen:
            raise MechError(f"'{sw.name}' is not a param; only params can be swept"
                            + suggest(sw.name, param_names.seen), nspan)
    if ground is None:
        ground = Body(GROUND, (), None, Span(1, 1, 1, 1), True)
    return Model(source, tuple(params), ground, tuple(bodies), tuple(joints), tuple(drives),
                 simulate, tuple(outputs), tuple(sweeps))


def _sweep_exprs(sw: Sweep) -> list[E.Expr]:
    if sw.values is not None:
        return list(sw.values)
    return [e for e in (sw.start, sw.stop, sw.step, sw.count) if e is not None]


def _check_arg(a: Arg, params: set[str]) -> None:
    """Arguments may be references (checked at compile time, against the type's signature)."""
    v = a.value
    if isinstance(v, (E.Ref, E.Name)):
        return
    if isinstance(v, Vector):
        for item in v.items:
            check_expr(item, params, "an argument")
    else:
        check_expr(v, params, "an argument")


def parse_expr(text: str, name: str, params: Iterable[str]) -> E.Expr:
    """Parse one expression given on the command line (``--set l=2*r``) against ``params``."""
    source = Source(name, text)
    e = _lark_parse(text, source, "expr_only")
    try:
        check_expr(e, set(params), name)
    except MechError as err:
        raise err.with_source(source) from None
    return e


def parse_expr_list(text: str, name: str, params: Iterable[str]) -> list[E.Expr]:
    """Parse a comma-separated list of expressions (``--sweep l=3.5,2.5``)."""
    source = Source(name, text)
    items = _lark_parse(text, source, "expr_list")
    try:
        for e in items:
            check_expr(e, set(params), name)
    except MechError as err:
        raise err.with_source(source) from None
    return items


