"""Text -> :class:`~mechdsl.model.Model`.

The lark grammar (``grammar/mech.lark``) gives a parse tree; a Transformer turns it into the
model's dataclasses, and :mod:`.checks` checks what can be checked without plugins. lark's
exceptions are translated here and nowhere else: every error leaves this module as a
:class:`~mechdsl.errors.MechError` with a span.
"""

from __future__ import annotations

import functools
import os
from typing import Iterable

from lark import Lark, Token, Transformer, v_args
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

from . import expr as E
from .checks import TIME, build_model, check_expr
from .errors import MechError, Source, Span
from .model import (
    Arg, Drive, Joint, Model, OutputRef, Param, Point, Polygon, Simulate, Sweep, Vector,
)
from .shapes import read_mesh
from .tables import PointList, make_table

__all__ = ["parse", "parse_expr", "parse_expr_list", "check_expr", "TIME"]


@functools.cache
def _parser() -> Lark:
    # read beside this module (importlib.resources would add 13 ms to every start-up)
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "grammar", "mech.lark")
    with open(path, encoding="utf-8") as f:
        grammar = f.read()
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

    def __init__(self, base_dir: str) -> None:
        super().__init__()
        self.base_dir = base_dir

    def call(self, meta, items):
        func, *args = items
        name = str(func)
        if name == "table":
            return self._table(args, _span(meta))
        for a in args:
            if isinstance(a, (Token, PointList)):
                raise MechError(f"only table() takes a file name or a list of points, not "
                                f"{name}()", _tspan(a) if isinstance(a, Token) else a.span)
        return E.Call(name, tuple(args), _span(meta))

    def _table(self, args, span):
        usage = ('table() takes the data (a file name such as "motion.csv" or points such '
                 'as [(0, 0), (1, 2)]), the abscissa, and optionally the period')
        if not 2 <= len(args) <= 3:
            raise MechError(usage, span)
        data = args[0]
        if isinstance(data, Token) and data.type == "STRING":
            data, data_span = str(data)[1:-1], _tspan(data)
        elif isinstance(data, PointList):
            data_span = data.span
        else:
            raise MechError(usage, getattr(data, "span", span))
        for a in args[1:]:
            if isinstance(a, (Token, PointList)):
                raise MechError(usage, _tspan(a) if isinstance(a, Token) else a.span)
        period = args[2] if len(args) == 3 else None
        return make_table(data, data_span, args[1], period, self.base_dir, span)

    def point_list(self, meta, items):
        return PointList(tuple(items), _span(meta))

    def plugin(self, meta, items):
        (tok,) = items
        return ("plugin", str(tok)[1:-1], _tspan(tok))

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

    def shape(self, meta, items):
        (value,) = items
        if isinstance(value, Token):  # a mesh file, read now: its errors point at the file name
            return ("shape", read_mesh(str(value)[1:-1], self.base_dir, _tspan(value)),
                    _span(meta))
        return ("shape", value, _span(meta))

    def polygon(self, meta, items):
        return Polygon(tuple(items), _span(meta))

    def density(self, meta, items):
        return ("density", items[0], _span(meta))

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

    def trace(self, meta, items):
        return ("trace", tuple(items))

    def unit(self, meta, items):
        name, text = items
        if str(name) not in ("length", "time"):
            raise MechError(f"units are given for 'length' and 'time', not '{name}' (angles "
                            "are in radians)", _tspan(name))
        return str(name), str(text)[1:-1], _tspan(name)

    def units(self, meta, items):
        return ("units", tuple(items), _span(meta))

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
    "STEP": "'step'", "COUNT": "'count'", "STRING": "a quoted name",
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
        # point just after the last thing written, not at the empty line that may follow
        text = source.text.rstrip()
        line = text.count("\n") + 1
        col = len(text) - text.rfind("\n")
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
    # tables are read relative to the .mech file (the working folder for text without a file)
    base_dir = os.getcwd() if source.name.startswith("<") else os.path.dirname(
        os.path.abspath(source.name))
    try:
        tree = _parser().parse(text, start=start)
        return _ToModel(base_dir).transform(tree)
    except UnexpectedInput as err:
        raise _syntax_error(err, source) from None
    except MechError as err:
        raise err.with_source(source) from None
    except Exception as err:  # a transformer error wrapped by lark
        inner = getattr(err, "orig_exc", None)
        if isinstance(inner, MechError):
            raise inner.with_source(source) from None
        raise


def parse(text: str, name: str = "<string>") -> Model:
    """Parse the text of a ``.mech`` file into a :class:`Model`.

    Raises :class:`MechError` (with span and source) for syntax errors and for every mistake
    that can be found without the plugin registry.
    """
    source = Source(name, text)
    statements = _lark_parse(text, source, "start")
    try:
        return build_model(source, statements)
    except MechError as err:
        raise err.with_source(source) from None


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


