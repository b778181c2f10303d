"""lark's LALR(1) parse of a whole text, driven by one loop over lark's own tables.

lark parses a model file token by token through several layers of Python calls per token
(the lexer thread, the contextual lexer's ``next_token``, the parser state's ``feed_token``)
and per reduction (a position callback around each rule's tree builder); on the 300-link
chain (44 KB, 15,000 tokens, 46,000 reductions) that is 180 ms. :class:`FastLALR` runs the
same automaton in one loop:

* **the tokens** are matched by the regular expressions lark compiled for each parser state
  (its contextual lexer's per-state scanners, with their keyword callbacks), so a word is a
  keyword or a name exactly where lark's lexer would say so, with lark's lines and columns;
* **the actions** are read from lark's parse table, and each reduction calls lark's own tree
  builder of the rule (token filtering, ``?rule`` inlining, ``_rule`` expansion), so the tree
  is lark's;
* **the positions** are kept on a stack beside the values: a node's extent is its first
  positioned child's start and its last one's end (a token's own, a tree's container), which
  is the rule of lark's ``propagate_positions`` with the positions at hand instead of
  searched for;
* **the model**, with a ``node`` callback, is made as the parser reduces: each rule's
  children shaped by lark's own wrappers, then handed to the callback with their extent,
  no tree built and no second pass; the nesting depth is kept on a third stack, so that a
  pathological expression is refused where it goes too deep.

The grammar stays defined once, in ``mech.lark``: nothing here knows a rule or a token. On any
input it cannot take (a character no token matches, a token the state does not expect, a
lark configuration of another shape), :meth:`FastLALR.parse` returns None and the caller runs
lark's parser, whose exception says what is wrong and where.
"""

from __future__ import annotations

import functools
from typing import Any, Callable

from lark import Lark, Token, Tree
from lark.grammar import NonTerminal
from lark.parse_tree_builder import ExpandSingleChild, ParseTreeBuilder, PropagatePositions
from lark.parsers.lalr_analysis import Shift

#: a value's extent: (line, column, offset) of its start and of its end, or None
_Extent = tuple[tuple[int, int, int], tuple[int, int, int]] | None


class FastLALR:
    """The LALR(1) automaton and contextual lexer of ``parser`` (a lark parser built with
    ``parser="lalr"``, ``lexer="contextual"`` and ``propagate_positions``), run in one loop
    (module docstring). ``builders`` maps each rule to its tree builder without position
    callbacks (:func:`mechdsl.grammar.parser._fast_positions` unwraps them)."""

    def __init__(self, parser: Lark, builders: dict) -> None:
        frontend = parser.parser
        table = frontend.parser.parser.parse_table
        self.states = table.states
        self.start_states = table.start_states
        self.end_states = table.end_states
        # a ``?rule`` of one rule symbol (``?sum: product``) hands its child on unchanged:
        # its reduction only changes the state (on the chain, 31,000 of 46,000 reductions)
        # (keyed by identity: a Rule's hash is a Python method, called per reduction)
        self.rules = {id(rule): (len(rule.expansion), rule.origin.name,
                             None if _hands_on(rule, build) else build)
                      for rule, build in builders.items()}
        if any(kind is not Shift and id(arg) not in self.rules
               for actions in self.states.values() for kind, arg in actions.values()):
            raise TypeError("a rule of the table has no builder")
        self.token_callbacks = {k: v for k, v in frontend.parser.parser.callbacks.items()
                                if isinstance(k, str)}
        # each rule's shaping of its children (token filtering, ``_rule`` splicing, ``?rule``
        # hand-on), without positions: what :meth:`parse` wraps around a ``node`` callback
        self.shapers = [(rule, tuple(w for w in chain if w is not PropagatePositions))
                        for rule, chain in ParseTreeBuilder(
                            parser.rules, Tree, False, False, False).rule_builders]
        if {id(rule) for rule, _ in self.shapers} != set(self.rules):
            raise TypeError("the rules of the tree builder are not the table's")
        self._state_lexers = frontend.lexer.lexers
        #: each parser state's (regular expressions, keyword callbacks, ignored and
        #: multi-line token types), made where the state is first met: compiling every
        #: state's expressions at once would cost 20 ms of every process's first parse
        self.lexers: dict[Any, tuple] = {}

    def _lexer(self, state: Any) -> tuple:
        """:attr:`lexers`' entry of ``state``, made now (the state's scanner is lark's)."""
        lexer = self._state_lexers[state]
        scanner = lexer.scanner  # (built on first use: compiles the state's expressions)
        made = self.lexers[state] = (tuple(scanner._mres), dict(lexer.callback),
                                     frozenset(lexer.ignore_types),
                                     frozenset(lexer.newline_types))
        return made

    def _hand_on(self, below: Any, origin: str, type_: str) -> Any:
        """The state on top of ``below`` after reducing to ``origin`` and every further
        hand-on reduction the lookahead ``type_`` makes there."""
        states, rules = self.states, self.rules
        top = states[below][origin][1]
        while True:
            action = states[top].get(type_)
            if action is None or action[0] is Shift:
                return top
            build = rules[id(action[1])][2]
            if build is not None:
                return top
            top = states[below][rules[id(action[1])][1]][1]

    def _transforming(self, node: Callable, cell: list) -> dict:
        """:attr:`rules` with each builder's tree replaced by ``node(name, cell[0],
        children)`` (the extent in ``cell``, set before the call)."""
        rules = {}
        for rule, chain in self.shapers:
            n, origin, build = self.rules[id(rule)]
            if build is not None:
                name = rule.alias or rule.options.template_source or origin
                if name.startswith("_"):  # (spliced into its parent: a bare tree)
                    build = functools.partial(Tree, name)
                else:
                    def build(children: list, name: str = name) -> Any:
                        cell[1] = True  # (a node made: a level, whatever it returns)
                        return node(name, cell[0], children)
                for wrap in chain:
                    build = wrap(build)
            rules[id(rule)] = (n, origin, build)
        return rules

    def parse(self, text: str, start: str, node: Callable | None = None,
              max_depth: int = 0, too_deep: Callable | None = None) -> Any:
        """The tree of ``text`` from the rule ``start`` (lark's, with its positions), or None
        where lark's own parser must say what is wrong.

        With ``node``, no tree: each node is ``node(name, extent, children)`` as it is
        reduced, children first (a transformer run during the parse; extent is
        ((line, column, offset) of the start, of the end) of lark's container, or None), and
        nodes nested deeper than ``max_depth`` (counted as lark's trees would be: a level
        per rule, ``_rule`` splices none) call ``too_deep(depth, extent)``, which raises."""
        states, lexers = self.states, self.lexers
        cell: list = [None, False]  # the extent of the node being made; whether it was
        rules = self.rules if node is None else self._transforming(node, cell)
        depths: list[int] = []  # (with ``node``: each value's nesting depth)
        token_callbacks = self.token_callbacks
        # lark's constructor behind its keyword handling (the public one where it has none)
        new_token = getattr(Token, "_future_new", Token)
        end_state = self.end_states[start]
        state_stack: list = [self.start_states[start]]
        values: list = []
        extents: list[_Extent] = []
        pos, line, line_start, size = 0, 1, 0, len(text)
        last = None
        # (state below, state, token) -> the state after the ?rule hand-ons this token
        # makes there: an expression's number or name is handed on through nine levels
        chains: dict[tuple, Any] = {}
        while True:
            if pos < size:  # the next token, lexed in the current state (lark's contextual)
                lexer = lexers.get(state_stack[-1])
                mres, callbacks, ignore, newline = lexer if lexer is not None else \
                    self._lexer(state_stack[-1])
                for mre in mres:
                    m = mre.match(text, pos)
                    if m is not None:
                        break
                else:
                    return None
                value, type_ = m.group(0), m.lastgroup
                end = pos + len(value)
                end_line, end_start = line, line_start
                if type_ in newline:
                    k = value.count("\n")
                    if k:
                        end_line += k
                        end_start = pos + value.rindex("\n") + 1
                if type_ in ignore:
                    if type_ in callbacks:
                        return None  # (a callback on ignored text: lark's path)
                    pos, line, line_start = end, end_line, end_start
                    continue
                token = new_token(type_, value, pos, line, pos - line_start + 1, end_line,
                                  end - end_start + 1, end)
                if type_ in callbacks:
                    token = callbacks[type_](token)
                pos, line, line_start = end, end_line, end_start
                last = token
                at_end = False
            else:
                token = Token.new_borrow_pos("$END", "", last) if last is not None else \
                    Token("$END", "", 0, 1, 1)
                at_end = True
            type_ = token.type
            while True:  # feed it: reduce as the table says, then shift it
                action = states[state_stack[-1]].get(type_)
                if action is None:
                    return None
                kind, arg = action
                if kind is Shift:
                    if at_end:
                        return None
                    state_stack.append(arg)
                    values.append(token if type_ not in token_callbacks
                                  else token_callbacks[type_](token))
                    if node is not None:
                        depths.append(0)
                    extents.append(((token.line, token.column, token.start_pos),
                                    (token.end_line, token.end_column, token.end_pos)))
                    break
                n, origin, build = rules[id(arg)]
                if build is None:  # a chain of hand-ons: where it ends, looked up once
                    below = state_stack[-2]
                    key = (below, state_stack[-1], type_)
                    top = chains.get(key)
                    if top is None:
                        top = chains[key] = self._hand_on(below, origin, type_)
                    state_stack[-1] = top
                    continue
                if n:
                    children = values[-n:]
                    spans = extents[-n:]
                    del state_stack[-n:], values[-n:], extents[-n:]
                else:
                    children, spans = [], []
                if node is None:
                    res = build(children)
                    extents.append(_place(res, children, spans))
                else:
                    if n:
                        levels = depths[-n:]
                        del depths[-n:]
                    else:
                        levels = []
                    res, extent, depth = _transformed(build, children, spans, levels, origin,
                                                      cell)
                    if depth > max_depth and too_deep is not None:
                        too_deep(depth, extent)
                    extents.append(extent)
                    depths.append(depth)
                values.append(res)
                kind, goto = states[state_stack[-1]][origin]
                state_stack.append(goto)
                if at_end and goto == end_state:
                    return values[-1]


def _container(spans: list) -> _Extent:
    """The extent of a node whose children have the extents ``spans``: the first
    positioned one's start to the last one's end (lark's container), None if none is."""
    if not spans:
        return None
    first, last = spans[0], spans[-1]
    if first is None:
        first = next((s for s in spans if s is not None), None)
        if first is None:
            return None
    if last is None:
        last = next(s for s in reversed(spans) if s is not None)
    return (first[0], last[1])


def _transformed(build: Callable, children: list, spans: list, depths: list, origin: str,
                 cell: list) -> tuple[Any, _Extent, int]:
    """A reduction of :meth:`FastLALR.parse` with ``node``: the value, its extent as its
    parent sees it and its depth, as lark's tree of the same text would have them (a child
    handed on keeps its depth; a ``_rule``, spliced into its parent, adds no level)."""
    extent = cell[0] = _container(spans)
    cell[1] = False
    res = build(children)
    depth = max(depths) if depths else 0
    if cell[1]:  # the node function made it (lark's tree would have a node here)
        return res, extent, depth + 1
    for k, c in enumerate(children):  # lark's wrappers handed a child on
        if res is c:
            return res, (spans[0] if len(children) == 1 else extent), depths[k]
    if isinstance(res, Token):
        return res, ((res.line, res.column, res.start_pos),
                     (res.end_line, res.end_column, res.end_pos)), 0
    return res, extent, depth if origin[0] == "_" else depth + 1


def _hands_on(rule, build) -> bool:
    """Whether reducing by ``rule`` gives its one child unchanged: an inlined ``?rule``
    without alias whose expansion is one rule that is itself kept (``_rule`` children are
    spliced into their parent, so their count is not known)."""
    return (len(rule.expansion) == 1 and rule.options.expand1 and not rule.alias
            and type(build) is ExpandSingleChild and isinstance(rule.expansion[0], NonTerminal)
            and not rule.expansion[0].name.startswith("_"))


def _place(res: Any, children: list, spans: list) -> _Extent:
    """Set the positions of the node ``res`` built from ``children`` (with extents
    ``spans``) as lark's ``propagate_positions`` does, and return its extent as its parent
    sees it: a tree's container, a token's own, a passed-on child's unchanged."""
    if len(children) == 1 and res is children[0]:
        return spans[0]
    if not isinstance(res, Tree):
        if isinstance(res, Token):
            return ((res.line, res.column, res.start_pos),
                    (res.end_line, res.end_column, res.end_pos))
        return None
    extent = _container(spans)
    meta = res.meta
    if extent is None:
        if meta.empty:
            return None
        return ((meta.container_line, meta.container_column, meta.container_start_pos),
                (meta.container_end_line, meta.container_end_column, meta.container_end_pos))
    set_positions(meta, *extent)
    return extent


def set_positions(meta, first: tuple[int, int, int], last: tuple[int, int, int]) -> None:
    """lark's ``propagate_positions`` on one node's ``meta``: its container from ``first``
    (line, column, offset) to ``last``, and its own start and end where it has none yet (a
    child handed on keeps its own, its container takes in the parent's filtered tokens)."""
    if not hasattr(meta, "line"):
        meta.line, meta.column, meta.start_pos = first
    if not hasattr(meta, "end_line"):
        meta.end_line, meta.end_column, meta.end_pos = last
    meta.empty = False
    meta.container_line, meta.container_column, meta.container_start_pos = first
    meta.container_end_line, meta.container_end_column, meta.container_end_pos = last
