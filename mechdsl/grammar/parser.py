"""Text -> :class:`~mechdsl.grammar.model.Model`.

The lark grammar (``mech.lark``, beside this module) is parsed by lark's tables run in one
loop (:mod:`.lalr`), which makes the model's dataclasses as it reduces each rule
(:meth:`_ToModel.node`); where that loop finds a syntax error, lark's own parser runs to say
it. :mod:`.checks` then checks what can be checked without plugins. A table or mesh file is
named, never read here (:mod:`.tables`). lark's exceptions are translated here and nowhere
else: every error leaves this module as a :class:`~mechdsl.errors.MechError` with a span.

Nothing here recurses over the input: the LALR parser is iterative, the model is made
bottom-up as it reduces (or from lark's tree by a loop, :meth:`_ToModel.transform`), and
the passes over expressions in :mod:`.expr`, :mod:`.derive` and :mod:`.checks` keep their
own stacks. The nesting depth is bounded all the same (:data:`MAX_DEPTH`), checked while
the parser reduces, so that a pathological expression is refused as soon as it goes too
deep rather than after filling the memory.
"""

from __future__ import annotations

import functools
import os
from typing import Iterable

from lark import Lark, Token, Tree
from lark.parse_tree_builder import PropagatePositions
from lark import __version__ as lark_version
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken
from lark.grammar import Rule
from lark.lexer import TerminalDef
from lark.tree import SlottedTree

from ..errors import MechError, Source, Span, cut
from ..memory import collection_paused
from . import expr as E
from . import statements as S
from .cache import cached_tables
from .checks import TIME, build_model, check_expr
from .lalr import FastLALR, set_positions
from .model import ANGLE_UNITS, SIMULATE_OPTIONS, TRACE_FUNCTIONS, UNIT_NAMES
from .model import (
    Arg, CentrodeTrace, Drive, Force, Initial, Joint, MeshFile, Model, NamedOutput, OutputRef, Param, Point, Polygon,
    ReducedOutput, Simulate, Sweep, Vector,
)
from .tables import PointList, make_table

__all__ = ["parse", "parse_tree", "lex", "parse_expr", "parse_expr_list", "parse_reductions",
           "parse_traces", "check_expr", "TIME", "MAX_DEPTH"]

#: Memory that parsing can take per byte of a model file, at worst (a file of nothing but
#: tiny expressions: about 480 MB per MB measured; ordinary models take 130).
PARSE_BYTES_PER_BYTE = 500

#: The options of an ``initial`` statement after its value
INITIAL_OPTIONS = ("rate",)

#: The deepest nesting of an expression (a level per operation: a sum of n terms nests n
#: deep, as does ``sin(sin(...))`` n times). A 2,000-term Fourier series is well within it;
#: an expression beyond it is an error located where it goes too deep.
MAX_DEPTH = 10_000

_OPTIONS = dict(parser="lalr", start=["start", "expr_only", "expr_list", "output_list",
                                      "trace_list"],
                propagate_positions=True, maybe_placeholders=False)


class _Tree(SlottedTree):
    """lark's parse tree node, knowing its depth; the parser builds each node after its
    children, so the depth limit is checked as the tree grows."""

    __slots__ = ("depth",)

    def __init__(self, data, children, meta=None) -> None:
        super().__init__(data, children, meta)
        if data[0] == "_":
            # lark's repetitions (``__start_star_0``) are rebuilt at each item and expanded
            # into their parent: the parent counts their items, once (counting them here
            # would make a file of n statements cost n^2)
            self.depth = 0
            return
        depth = 0
        for c in children:
            if type(c) is _Tree and c.depth > depth:
                depth = c.depth
        self.depth = depth + 1
        if depth >= MAX_DEPTH:
            raise _nested_too_deeply(depth + 1, _first_span(children))


def _nested_too_deeply(levels: int, span: Span | None) -> MechError:
    """The error of a node nested ``levels`` deep, more than :data:`MAX_DEPTH`, at ``span``
    (the tree's check, :class:`_Tree`, and the one-loop parser's, :func:`_too_deep`)."""
    return MechError(f"the expression is nested too deeply: {levels:,} levels here, more "
                     f"than the limit of {MAX_DEPTH:,} (a sum of n terms counts n levels; "
                     "split it with params)", span)


def _too_deep(depth: int, extent) -> None:
    """The one-loop parser's depth check (:mod:`.lalr`): the error of a node nested
    ``depth`` levels deep, located at the start of ``extent``."""
    span = None if extent is None else Span(extent[0][0], extent[0][1], extent[0][0],
                                             extent[0][1] + 1)
    raise _nested_too_deeply(depth, span)


def _first_span(children) -> Span | None:
    for c in children:
        if isinstance(c, Token):
            return Span(c.line, c.column, c.line, c.column + 1)
        if isinstance(c, _Tree) and not c.meta.empty:
            return Span(c.meta.line, c.meta.column, c.meta.line, c.meta.column + 1)
    return None  # pragma: no cover - an expression node has a positioned child


class _Positions:
    """lark's ``propagate_positions`` for one rule, as lark computes them (a node starts at
    its first positioned child's container and ends at its last's; containers take in the
    tokens the tree filters out, such as a statement's keyword and the parentheses around an
    expression), but a rule that hands its single child on (``?expr`` down to ``?atom``:
    nine such rules under every number and name of an expression) costs one comparison: such
    a child's container is already its own. On the 300-link chain's 15,000 tokens the tree
    is built about 25 % faster."""

    __slots__ = ("build",)

    def __init__(self, build) -> None:
        self.build = build

    def __call__(self, children):
        res = self.build(children)
        if len(children) == 1 and res is children[0]:
            return res
        if not isinstance(res, Tree):
            return res
        first = _edge(children, True)
        if first is None:
            return res
        set_positions(res.meta, first, _edge(reversed(children), False))
        return res


def _edge(children, start: bool) -> tuple[int, int, int] | None:
    """(line, column, offset) where the first positioned of ``children`` starts (its
    container's start for a tree), or with ``start`` False where it ends; None if none is."""
    for c in children:
        if isinstance(c, Token):
            return (c.line, c.column, c.start_pos) if start else \
                (c.end_line, c.end_column, c.end_pos)
        if isinstance(c, Tree) and not c.meta.empty:
            m = c.meta
            return (m.container_line, m.container_column, m.container_start_pos) if start \
                else (m.container_end_line, m.container_end_column, m.container_end_pos)
    return None


def _fast_positions(parser: Lark) -> Lark:
    """``parser`` with lark's position callbacks replaced by :class:`_Positions` (where
    lark's parser has the shape this version of lark gives it; else unchanged, and lark's
    own callbacks compute the same positions more slowly)."""
    callbacks = getattr(getattr(getattr(getattr(parser, "parser", None), "parser", None),
                                "parser", None), "callbacks", None)
    if isinstance(callbacks, dict):
        for rule, callback in callbacks.items():
            if type(callback) is PropagatePositions and callback.node_filter is None:
                callbacks[rule] = _Positions(callback.node_builder)
    return parser


def _grammar() -> str:
    # read beside this module (importlib.resources would add 13 ms to every start-up)
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "mech.lark")
    with open(path, encoding="utf-8") as f:
        return f.read()


def _tables(grammar: str) -> dict:
    """The LALR tables of ``grammar``, built (about 50 ms) and serialised as plain data."""
    data, memo = Lark(grammar, **_OPTIONS).memo_serialize([TerminalDef, Rule])
    return {"data": data, "memo": memo}


def _build_parser(fast: bool = True) -> Lark:
    """The parser, from the per-user cache of its tables (see :mod:`.cache`; never
    lark's own cache, a pickle in the shared temporary folder) or built in memory; with
    ``fast``, its positions computed by :class:`_Positions`."""
    grammar = _grammar()
    key = "\n".join([lark_version, repr(sorted(_OPTIONS.items())), grammar])
    tables = cached_tables(key, lambda: _tables(grammar))
    try:
        parser = Lark._load_from_dict(tables["data"], tables["memo"], tree_class=_Tree)
    except Exception:  # noqa: BLE001 - tables lark cannot use (or a lark without this
        # loader): the public constructor, which builds them
        parser = Lark(grammar, **_OPTIONS, tree_class=_Tree)
    return _fast_positions(parser) if fast else parser


@functools.cache
def _parser() -> Lark:
    return _build_parser()


@functools.cache
def _fast() -> FastLALR | None:
    """The one-loop driver of :func:`_parser`'s tables (:mod:`.lalr`), or None where a
    rule's callback is not the position wrapper around a tree builder that this version of
    lark gives (then lark parses alone)."""
    parser = _parser()
    callbacks = getattr(getattr(getattr(getattr(parser, "parser", None), "parser", None),
                                "parser", None), "callbacks", None)
    if not isinstance(callbacks, dict):
        return None
    builders = {}
    for rule, callback in callbacks.items():
        if isinstance(rule, str):
            continue  # (a terminal's callback: applied as lark applies it)
        if type(callback) is not _Positions:
            return None
        builders[rule] = callback.build
    try:
        fast = FastLALR(parser, builders)
        # the loop reads lark's internals: on this version of lark it must give lark's own
        # trees and positions, or it is not used (checked once, on a text of every kind of
        # statement and expression: about 3 ms)
        for text, start in _SELF_CHECK:
            if _positions(fast.parse(text, start)) != _positions(parser.parse(text, start=start)):
                return None
        return fast
    except Exception:  # noqa: BLE001 - lark's internals of another shape: lark parses alone
        return None


#: what :func:`_fast` parses both ways before the loop is used
_SELF_CHECK = (
    ("param l = 2.5 in 1 .. 4  # a comment\nparam r = if l > 2 and not l >= 3 then (l) else "
     "-l^2 * sin(atan2(1, l)) / 2\ngravity = (0, -9.81)\nground { point O = (0, 0) }\n"
     "body crank { guess = (0, 0, 0.5)  point A = (r, 0)  mass = 1  inertia = 0.1 }\n"
     "joint j: revolute(ground.O, crank.origin)\ndrive d: angle(crank) = 2*t\n"
     "sweep l = [1, 2]\nsimulate t = 0 .. 1 step 0.1, rtol = 1e-6\n"
     "output x = max(crank.A.x, 0), crank.A\n", "start"),
    ("-(2 * (l + 1))^2", "expr_only"),
)


def _positions(tree) -> list:
    """Every node of ``tree`` with its positions (what the self-check compares)."""
    return [(t.data, t.children if not t.children or not isinstance(t.children[0], Tree)
             else len(t.children), *(getattr(t.meta, a, None) for a in (
                 "line", "column", "start_pos", "end_line", "end_column", "end_pos",
                 "container_line", "container_column", "container_end_line",
                 "container_end_column")))
            for t in tree.iter_subtrees()]


def _tree(text: str, start: str):
    """The parse tree of ``text`` from ``start``: by the one-loop driver (:mod:`.lalr`), or
    by lark's parser where the driver cannot go on (a syntax error: lark's exception says
    what and where)."""
    fast = _fast()
    tree = fast.parse(text, start) if fast is not None else None
    return tree if tree is not None else _parser().parse(text, start=start)


def lex(text: str, dont_ignore: bool = False) -> Iterable[Token]:
    """The grammar's tokens of ``text`` (lark's), in order; with ``dont_ignore``, the
    comments and white space too. Lexing stops with lark's UnexpectedCharacters at a
    character no token takes."""
    return _parser().lex(text, dont_ignore=dont_ignore)


def parse_tree(text: str):
    """The parse tree of a whole file (lark's, with positions): for tools that keep the
    text's own layout, such as the formatter; :func:`parse` gives the model."""
    return _tree(text, "start")


def _span(meta) -> Span:
    return Span(meta.line, meta.column, meta.end_line, meta.end_column)


def _tspan(tok: Token) -> Span:
    return Span(tok.line, tok.column, tok.end_line, tok.end_column)


def _keep_tree(data: str, meta, children: list) -> Tree:
    """A node the model has no method for, kept as a tree of its transformed children."""
    return Tree(data, children, meta if not isinstance(meta, _Meta) else meta.lark())


class _Meta:
    """The positions a model node is made with during the parse (lark's ``meta``: the
    line and column of its start and of its end)."""

    __slots__ = ("line", "column", "start_pos", "end_line", "end_column", "end_pos", "empty")

    def __init__(self, extent) -> None:
        self.empty = extent is None
        if extent is not None:
            (self.line, self.column, self.start_pos), \
                (self.end_line, self.end_column, self.end_pos) = extent

    def lark(self):
        """The same as lark's Meta."""
        from lark.tree import Meta

        meta = Meta()
        for name in self.__slots__:
            if hasattr(self, name):
                setattr(meta, name, getattr(self, name))
        return meta


class _ToModel:
    """Parse tree -> model nodes (statements are returned as a flat list). ``files`` collects
    the real paths of the tables and meshes named, in the order of the text; they are read
    when the model is compiled (:mod:`mechdsl.compiled.files`).

    A node named ``x`` becomes ``self.x(meta, items)``, its children transformed first (a
    node without such a method stays a Tree of its transformed children): lark's
    non-recursive Transformer with ``v_args(meta=True)``, without its per-node wrappers
    (on the 300-link chain, 58 ms of a 180 ms parse)."""

    def transform(self, tree: Tree):
        """The model nodes of ``tree``, bottom-up; no recursion (:data:`MAX_DEPTH`)."""
        order, stack = [], [tree]
        while stack:  # pre-order; reversed, every node comes after its descendants
            node = stack.pop()
            order.append(node)
            stack.extend(c for c in node.children if isinstance(c, Tree))
        done: dict[int, object] = {}
        for node in reversed(order):
            children = [done.pop(id(c)) if isinstance(c, Tree) else c for c in node.children]
            done[id(node)] = self._node(node.data, node.meta, children)
        return done[id(tree)]

    def node(self, name: str, extent, children: list):
        """The model node ``name`` of ``children`` (transformed) at ``extent`` ((line,
        column, offset) of its start and of its end, or None): what :meth:`transform` makes
        of a tree's node, made while the parser reduces it (:mod:`.lalr`)."""
        return self._node(name, _Meta(extent), children)

    def _node(self, name: str, meta, children: list):
        f = self._methods.get(name)
        if f is None:
            f = getattr(self, name, None) if not name.startswith("_") and name not in (
                "transform", "node") else None
            self._methods[name] = f = f or functools.partial(_keep_tree, name)
        return f(meta, children)

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
        self.base_dir = base_dir
        self._methods: dict[str, object] = {}
        self.files: list[str] = []

    def _name_file(self, name: str, span: Span) -> None:
        if "\0" in name:  # no file can have it; os would raise ValueError
            raise MechError(f"cannot read {cut(name)!r}: a file name has no NUL character",
                            span)
        path = os.path.realpath(os.path.join(self.base_dir, name))
        if path not in self.files:
            self.files.append(path)

    def call(self, meta, items):
        func, *args = items
        name = str(func)
        if name == "table":
            return self._table(args, _span(meta))
        for a in args:
            if isinstance(a, (Token, PointList)):
                raise MechError(f"only table() takes a file name or a list of points, not "
                                f"{cut(name)}()", _tspan(a) if isinstance(a, Token) else a.span)
        return E.Call(name, tuple(args), _span(meta))

    def _table(self, args, span):
        usage = ('table() takes the data (a file name such as "motion.csv" or points such '
                 'as [(0, 0), (1, 2)]), the abscissa, and optionally the period')
        if not 2 <= len(args) <= 3:
            raise MechError(usage, span)
        data = args[0]
        if isinstance(data, Token) and data.type == "STRING":
            data, data_span = str(data)[1:-1], _tspan(data)
            self._name_file(data, data_span)
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
        return S.PluginLine(str(tok)[1:-1], _tspan(tok))

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

    def output_list(self, meta, items):
        return list(items)

    def trace_list(self, meta, items):
        return tuple(items)

    # -- statements ----------------------------------------------------------------------------
    def param(self, meta, items):
        name, value, *bounds = items
        return S.Declared(Param(str(name), value, _span(meta), tuple(bounds) or None),
                          _tspan(name))

    def point(self, meta, items):
        name, coords = items
        return S.Declared(Point(str(name), coords, _span(meta)), _tspan(name))

    def guess(self, meta, items):
        return S.BodyItem("guess", items[0], _span(meta))

    def shape(self, meta, items):
        (value,) = items
        if isinstance(value, Token):  # a mesh file: its errors will point at the file name
            self._name_file(str(value)[1:-1], _tspan(value))
            return S.BodyItem("shape", MeshFile(str(value)[1:-1], self.base_dir,
                                                _tspan(value)), _span(meta))
        return S.BodyItem("shape", value, _span(meta))

    def polygon(self, meta, items):
        return Polygon(tuple(items), _span(meta))

    def density(self, meta, items):
        return S.BodyItem("density", items[0], _span(meta))

    def mass(self, meta, items):
        return S.BodyItem("mass", items[0], _span(meta))

    def inertia(self, meta, items):
        return S.BodyItem("inertia", items[0], _span(meta))

    def centroid(self, meta, items):
        return S.BodyItem("centroid", items[0], _span(meta))

    def v0(self, meta, items):
        return S.BodyItem("v0", items[0], _span(meta))

    def gravity(self, meta, items):
        return S.GravityDecl(items[0], _span(meta))

    def ground(self, meta, items):
        return S.GroundDecl(tuple(i for i in items if not isinstance(i, Token)), _span(meta))

    def body(self, meta, items):
        name, *rest = items
        return S.BodyDecl(str(name), _tspan(name),
                          tuple(i for i in rest if not isinstance(i, Token)), _span(meta))

    def arg(self, meta, items):
        return Arg(None, items[0], _span(meta))

    def kwarg(self, meta, items):
        name, value = items
        return Arg(str(name), value, _span(meta))

    def joint(self, meta, items):
        name, type_name, *args = items
        return S.Declared(Joint(str(name), str(type_name), tuple(args), _span(meta),
                                _tspan(type_name)), _tspan(name))

    def drive(self, meta, items):
        name, type_name, *args, function = items
        return S.Declared(Drive(str(name), str(type_name), tuple(args), _span(meta),
                                _tspan(type_name), function), _tspan(name))

    def initial_option(self, meta, items):
        name, value = items
        if str(name) not in INITIAL_OPTIONS:
            raise MechError(f"initial takes the option {', '.join(INITIAL_OPTIONS)} (the "
                            f"measure's rate at t0), not '{cut(name)}'", _tspan(name))
        return str(name), value, _tspan(name)

    def initial(self, meta, items):
        name, type_name, *rest = items
        options = [o for o in rest if isinstance(o, tuple)]
        args = [a for a in rest if isinstance(a, Arg)]
        (value,) = [e for e in rest if not isinstance(e, (tuple, Arg))]
        rate = None
        for opt, e, span in options:
            if rate is not None:
                raise MechError(f"option '{opt}' is given twice", span)
            rate = e
        return S.Declared(Initial(str(name), str(type_name), tuple(args), _span(meta),
                                  _tspan(type_name), value, rate), _tspan(name))

    def force(self, meta, items):
        name, type_name, *args = items
        return S.Declared(Force(str(name), str(type_name), tuple(args), _span(meta),
                                _tspan(type_name)), _tspan(name))

    def sim_option(self, meta, items):
        name, value = items
        if str(name) not in SIMULATE_OPTIONS:
            raise MechError(f"simulate takes the options {', '.join(SIMULATE_OPTIONS)}, not "
                            f"'{cut(name)}'", _tspan(name))
        return str(name), value, _tspan(name)

    def simulate(self, meta, items):
        var, t0, t1, step, *options = items
        if str(var) != TIME:
            raise MechError(f"the simulated variable is time 't', not '{cut(var)}'",
                            _tspan(var))
        seen = set()
        for name, _, span in options:
            if name in seen:
                raise MechError(f"option '{name}' is given twice", span)
            seen.add(name)
        return Simulate(t0, t1, step, _span(meta), tuple(options))

    def ref_or_name(self, meta, items):
        return OutputRef(tuple(str(t) for t in items), _span(meta))

    def named_output(self, meta, items):
        name, expr = items
        return NamedOutput(str(name), expr, _span(meta), _tspan(name))

    def reduced_output(self, meta, items):
        func, expr = items
        call = E.Call(str(func), (expr,), _span(meta))
        return NamedOutput(E.to_text(call), call, _span(meta), _span(meta))

    def output(self, meta, items):
        return S.OutputList(tuple(items))

    def trace(self, meta, items):
        return S.TraceList(tuple(items))

    def trace_call(self, meta, items):
        func, a, b = items
        if str(func) not in TRACE_FUNCTIONS:
            raise MechError(f"'{cut(func)}' cannot be traced; trace body.P (a point's path) or "
                            f"{' or '.join(f'{n}(A, B)' for n in TRACE_FUNCTIONS)}",
                            _tspan(func))
        if str(a) == str(b):
            raise MechError(f"the centrodes of '{cut(a)}' relative to itself: name two bodies",
                            _span(meta))
        return CentrodeTrace(str(a), str(b), _span(meta), _tspan(a), _tspan(b))

    def unit(self, meta, items):
        name, text = items
        if str(name) not in UNIT_NAMES:
            raise MechError(f"units are given for {', '.join(map(repr, UNIT_NAMES))}, not "
                            f"'{cut(name)}' (the others follow from them)", _tspan(name))
        value = str(text)[1:-1]
        if str(name) == "angle" and value not in ANGLE_UNITS:
            raise MechError(f"angles are reported in 'rad' or 'deg', not '{cut(value)}' (and "
                            "written in radians)", _tspan(text))
        return str(name), value, _tspan(name)

    def opt_range(self, meta, items):
        name, lo, hi = items
        return str(name), lo, hi, _tspan(name)

    def optimize(self, meta, items):
        return S.OptimizeDecl(tuple(items), _span(meta))

    def minimize(self, meta, items):
        return S.ObjectiveDecl("minimize", items[0], _span(meta))

    def maximize(self, meta, items):
        return S.ObjectiveDecl("maximize", items[0], _span(meta))

    def requirement(self, meta, items):
        return S.RequirementDecl(tuple(items), _span(meta))

    def units(self, meta, items):
        return S.UnitsDecl(tuple(items), _span(meta))

    def sweep_list(self, meta, items):
        return ("list", tuple(items))

    def sweep_range(self, meta, items):
        start, stop, kind, value = items
        return ("range", start, stop, str(kind), value)

    def sweep(self, meta, items):
        name, spec = items
        if spec[0] == "list":
            return S.Declared(Sweep(str(name), spec[1], None, None, None, None, _span(meta)),
                              _tspan(name))
        _, start, stop, kind, value = spec
        step, count = (value, None) if kind == "step" else (None, value)
        return S.Declared(Sweep(str(name), None, start, stop, step, count, _span(meta)),
                          _tspan(name))


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
        what = f"'{cut(tok)}'" if tok.type != "NUMBER" else f"number {cut(tok)}"
        if tok.type == "NAME":
            what = f"name '{cut(tok)}'"
        msg = f"unexpected {what}" + _describe_expected(err.accepts or err.expected)
        return MechError(msg, _tspan(tok), source)
    if isinstance(err, UnexpectedCharacters):
        ch = source.text[err.pos_in_stream] if err.pos_in_stream < len(source.text) else "?"
        span = Span(err.line, err.column, err.line, err.column + 1)
        return MechError(f"unexpected character {ch!r}", span, source)
    if isinstance(err, UnexpectedEOF):
        return MechError("unexpected end of file", None, source)
    return MechError(str(err), None, source)  # pragma: no cover - lark has no other kinds


def normalise(text: str) -> str:
    """The text as the parser reads it: without a UTF-8 byte-order mark (Windows editors
    write one), with '\\r\\n' and a lone '\\r' as line ends ('\\n'), so that lines and columns
    count as an editor shows them."""
    if text.startswith("\ufeff"):
        text = text[1:]
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text


def _lark_parse(source: Source, start: str):
    """Parse ``source.text`` from the rule ``start`` and transform it; returns the result and
    the real paths of the files it names."""
    # files are named relative to the .mech file (the working folder for text without a file)
    base_dir = os.getcwd() if source.name.startswith("<") else os.path.dirname(
        os.path.abspath(source.name))
    to_model = _ToModel(base_dir)
    try:
        fast = _fast()
        if fast is not None:  # the model made while parsing (lalr.py); None: a syntax error
            model = fast.parse(source.text, start, node=to_model.node, max_depth=MAX_DEPTH,
                               too_deep=_too_deep)
            if model is not None:
                return model, tuple(to_model.files)
            to_model = _ToModel(base_dir)
        tree = _parser().parse(source.text, start=start)
        return to_model.transform(tree), tuple(to_model.files)
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
    source = Source(name, normalise(text))
    with collection_paused():
        statements, files = _lark_parse(source, "start")
        try:
            return build_model(source, statements, files)
        except MechError as err:
            raise err.with_source(source) from None


def parse_expr(text: str, name: str, params: Iterable[str]) -> E.Expr:
    """Parse one expression given on the command line (``--set l=2*r``) against ``params``."""
    source = Source(name, normalise(text))
    e, _ = _lark_parse(source, "expr_only")
    try:
        check_expr(e, set(params), name)
    except MechError as err:
        raise err.with_source(source) from None
    return e


def parse_expr_list(text: str, name: str, params: Iterable[str]) -> list[E.Expr]:
    """Parse a comma-separated list of expressions (``--sweep l=3.5,2.5``)."""
    source = Source(name, normalise(text))
    items, _ = _lark_parse(source, "expr_list")
    try:
        for e in items:
            check_expr(e, set(params), name)
    except MechError as err:
        raise err.with_source(source) from None
    return items


def parse_traces(text: str, name: str) -> tuple:
    """Parse what the command line asks to trace (``--trace "coupler.P, ic(coupler,
    ground)"``), as the ``trace`` statement reads it: points (OutputRef) and centrodes
    (CentrodeTrace), located in ``text``; their bodies and points are checked against the
    model where it is compiled."""
    source = Source(name, normalise(text))
    items, _ = _lark_parse(source, "trace_list")
    return items


def parse_reductions(text: str, name: str, params: Iterable[str]) -> tuple[ReducedOutput, ...]:
    """Parse the outputs given on the command line (``--reduce "max(abs(slider.ax)), stroke =
    range(slider.x)"``) against ``params``: every item must be a reduction."""
    from .checks import named_output

    source = Source(name, normalise(text))
    items, _ = _lark_parse(source, "output_list")
    out = []
    try:
        for item in items:
            checked = named_output(item, set(params)) if isinstance(item, NamedOutput) else item
            if not isinstance(checked, ReducedOutput):
                what = getattr(checked, "name", None) or ".".join(checked.parts)
                raise MechError(f"'{cut(what)}' is not a reduction: {name} takes outputs with "
                                "one value per variant, such as max(abs(slider.ax)) or stroke "
                                "= range(slider.x)", checked.span)
            out.append(checked)
    except MechError as err:
        raise err.with_source(source) from None
    return tuple(out)
