"""The symbol table of a ``.mech`` text, kept for editors: every name, what it names, where it
is declared and where it is used, read from the tokens so that a file being typed (one that
does not parse) still has one.

Every statement begins with a keyword, and what a name is follows from where it stands:
``param NAME``, ``body NAME``, ``point NAME`` (inside a body's braces), ``joint NAME:``
(drive, force) and ``output NAME =`` declare; ``TYPE(`` after ``joint NAME:`` is a type of the
plugin registry; ``NAME =`` inside a type's parentheses is an argument name; ``NAME(`` a
function; in a reference ``A.B.C`` the head is a body (or a joint, drive or force: ``J.fx``),
``B`` a point of that body (``origin`` is every body's) or a quantity, ``C`` a quantity of the
point. A bare name is a param, a body, the time or a constant.

Nothing is evaluated and nothing is imported: this is what :mod:`mechdsl.lsp` answers go to
definition, references, rename, hover, completion and semantic tokens from.
"""

from __future__ import annotations

from dataclasses import dataclass

from . import expr as E
from .model import ENERGY_QUANTITIES, REDUCTIONS, TRACE_FUNCTIONS
from .motion_functions import SIGNATURES

#: Keywords that start a statement and name nothing else: a statement starts here
RESERVED_STARTS = {"param", "body", "joint", "drive", "simulate", "output", "sweep", "plugin"}
#: Keywords that start a statement unless a name or a value is expected where they stand
SOFT_STARTS = {"force", "gravity", "trace", "units", "ground", "optimize", "minimize",
               "maximize", "subject", "initial"}
#: After these, a word is a name or a value, not the start of a statement
EXPECTS_VALUE = {"param", "body", "joint", "drive", "initial", "force", "sweep", "point", "trace", ":",
                 ".", "=", ",", "(", "[", "+", "-", "*", "/", "^", "..", "<", "<=", ">",
                 ">=", "if", "then", "else", "and", "or", "not", "step", "count", "in", "to",
                 "optimize", "minimize", "maximize"}
#: Words that are keywords inside one kind of statement only: ``optimize c in 1 .. 2``,
#: ``subject to ...``
INNER_KEYWORDS = {"optimize": "in", "param": "in", "subject": "to"}

#: The statements of the form ``KEYWORD NAME: TYPE(args)``; an ``initial`` statement takes
#: the drive types, and its name and type are a drive's (:data:`_AS`)
_TYPED = ("joint", "drive", "force", "initial")
_AS = {"initial": "drive"}

#: The kinds of names that are declared in a file, and so can be renamed
DECLARED_KINDS = ("param", "body", "point", "joint", "drive", "force", "output")
#: The body every file has, whether or not it writes ``ground { }``, and every body's point
GROUND, ORIGIN = "ground", "origin"
TIME = "t"
#: Functions of the output expressions beside those of every expression: the functions of
#: points and bodies (distance, instant centres, ...) and the reductions over the run
OUTPUT_FUNCTIONS = (*SIGNATURES, *REDUCTIONS)


@dataclass(frozen=True)
class Token:
    """A token of the text: its type (lark's terminal name), text and place (1-based line and
    column, end column exclusive, as :class:`mechdsl.errors.Span`)."""

    type: str
    text: str
    line: int
    column: int
    end_column: int
    offset: int


@dataclass(frozen=True)
class Symbol:
    """One occurrence of a name. ``kind``: param, body, point, joint, drive, force, output,
    type, argument, variable (of a function argument: ``cos(theta)`` in a cam's profile),
    function, constant, time, quantity, option or unknown. ``owner``: the
    body of a point, the statement (joint, drive, force) of a type, the body or point or
    constraint of a quantity; None otherwise."""

    kind: str
    name: str
    owner: str | None
    line: int
    column: int
    end_column: int
    declaration: bool = False

    @property
    def key(self) -> tuple[str, str | None, str]:
        """What the occurrence names: equal keys are the same thing."""
        return (self.kind, self.owner, self.name)

    def covers(self, line: int, column: int) -> bool:
        """Whether the 1-based (line, column) is on this name (or just after it, where an
        editor's cursor stands after typing it)."""
        return self.line == line and self.column <= column <= self.end_column


def tokens(text: str) -> list[Token]:
    """The tokens of ``text``; a character that no token takes is skipped (a file being typed
    may hold one), comments and white space are not tokens."""
    from lark.exceptions import UnexpectedCharacters

    from .parser import lex

    out: list[Token] = []
    # a character no token takes is read as a space, and lexing resumes at the token before
    # it (whose end may depend on what follows: "body @ ="): lexing the whole text again for
    # each such character took minutes on a file of junk
    work, start, line, column = text, 0, 1, 1  # what is left to lex, and where it begins
    for _ in range(1002):
        try:
            for t in lex(work):
                first = t.line == 1  # tokens are on one line: only the first one shifts
                out.append(Token(t.type, str(t), line + t.line - 1,
                                 t.column + (column - 1 if first else 0),
                                 t.end_column + (column - 1 if first else 0),
                                 start + t.start_pos))
            return out
        except UnexpectedCharacters as err:
            bad = err.pos_in_stream
            work = work[:bad] + " " + work[bad + 1:]
            if out and out[-1].offset >= start:
                last = out.pop()
                work = work[last.offset - start:]
                start, line, column = last.offset, last.line, last.column
    return out


def _is_word(tok: Token) -> bool:
    """Whether the token can be a name (``ground`` is a keyword that names the ground)."""
    return tok.type in ("NAME", "KEYWORD_NAME", "GROUND")


def statement_starts(toks: list[Token]) -> list[int]:
    """The indices of the tokens that start a statement."""
    starts, prev = [], None
    for i, tok in enumerate(toks):
        word = tok.text
        if tok.type not in ("NAME", "STRING") and (
                word in RESERVED_STARTS or (word in SOFT_STARTS and prev not in EXPECTS_VALUE)):
            # initial(...) is the reduction, `initial NAME:` the statement
            if word == "initial" and i + 1 < len(toks) and toks[i + 1].text == "(":
                continue
            starts.append(i)
        prev = word
    return starts


@dataclass(frozen=True)
class SymbolIndex:
    """Every occurrence of a name in a text, in the text's order, and its tokens."""

    symbols: tuple[Symbol, ...]
    tokens: tuple[Token, ...]

    def at(self, line: int, column: int) -> Symbol | None:
        """The occurrence under the 1-based (line, column), or None."""
        return next((s for s in self.symbols if s.covers(line, column)), None)

    def declaration(self, symbol: Symbol) -> Symbol | None:
        """Where the thing ``symbol`` names is declared (None for ``origin``, the time, a
        type, a function, a quantity)."""
        return next((s for s in self.symbols if s.declaration and s.key == symbol.key), None)

    def uses(self, symbol: Symbol) -> list[Symbol]:
        """Every occurrence of what ``symbol`` names, its declaration included."""
        return [s for s in self.symbols if s.key == symbol.key]

    def declared(self, kind: str, owner: str | None = None) -> list[str]:
        """The names declared of one kind (the points of ``owner`` for ``point``), in order,
        each once."""
        names = [s.name for s in self.symbols
                 if s.declaration and s.kind == kind and (owner is None or s.owner == owner)]
        return list(dict.fromkeys(names))


def index(text: str) -> SymbolIndex:
    """The symbol table of ``text`` (see the module)."""
    toks = tokens(text)
    n = len(toks)
    starts = set(statement_starts(toks))
    words = [t.text for t in toks]

    def nxt(i: int) -> str | None:
        return words[i + 1] if i + 1 < n else None

    def sym(kind: str, i: int, owner: str | None = None, declaration: bool = False) -> Symbol:
        t = toks[i]
        return Symbol(kind, t.text, owner, t.line, t.column, t.end_column, declaration)

    # first pass: the declarations, and what each token is by its place in its statement
    role: dict[int, Symbol] = {}
    in_args: set[int] = set()  # the tokens inside a type's parentheses
    statement = None  # the keyword of the statement a token is in
    body = None  # the body whose braces a token is in
    depth = 0  # parentheses and brackets
    for i, tok in enumerate(toks):
        w = tok.text
        if i in starts:
            statement, depth = w, 0
            if w != "ground":
                body = None
        if w in "([":
            depth += 1
        elif w in ")]":
            depth = max(depth - 1, 0)
        elif w == "{" and statement == "ground":
            body = GROUND
        elif w == "{" and statement == "body" and i >= 1 and toks[i - 1].type == "NAME":
            body = toks[i - 1].text
        elif w == "}":
            body = None
        if depth > 0 and statement in _TYPED:
            in_args.add(i)
        if w == "ground" and i in starts and nxt(i) == "{":
            role[i] = sym("body", i, declaration=True)
        if statement == "trace" and depth == 0 and nxt(i) == "(" and w in TRACE_FUNCTIONS:
            role[i] = sym("function", i)  # trace ic(A, B): a function of traces alone
        if not _is_word(tok) or i in starts or INNER_KEYWORDS.get(statement) == w:
            continue
        prev = words[i - 1] if i else None
        if statement in ("param", "body", *_TYPED) and prev == statement:
            # an initial statement is a drive frozen at t0: its name is declared as a drive's
            role[i] = sym(_AS.get(statement, statement), i, declaration=True)
        elif prev == "point" and body is not None and tok.type == "NAME":
            role[i] = sym("point", i, owner=body, declaration=True)
        elif statement in _TYPED and prev == ":" and depth == 0:
            role[i] = sym("type", i, owner=_AS.get(statement, statement))
        elif nxt(i) == "=" and depth > 0 and statement in _TYPED:
            role[i] = sym("argument", i)
        elif nxt(i) == "=" and depth == 0 and statement == "initial" and prev == ",":
            role[i] = sym("option", i)
        elif nxt(i) == "=" and depth == 0 and statement == "output" and prev in ("output", ","):
            role[i] = sym("output", i, declaration=True)
        elif nxt(i) == "=" and depth == 0 and statement in ("units", "simulate") and \
                prev in ("units", "simulate", ","):
            role[i] = sym("time" if prev == "simulate" else "option", i)
    declared: dict[str, set[str]] = {}
    points: dict[str, set[str]] = {}
    for s in role.values():
        if s.declaration and s.kind == "point":
            points.setdefault(s.owner, set()).add(s.name)
        elif s.declaration:
            declared.setdefault(s.kind, set()).add(s.name)
    bodies = declared.get("body", set()) | {GROUND}
    constraints = {name: kind for kind in ("joint", "drive", "force", "output")
                   for name in declared.get(kind, ())}

    # second pass: the references
    out: list[Symbol] = []
    i = 0
    while i < n:
        tok = toks[i]
        if i in role:
            out.append(role[i])
            i += 1
            continue
        if tok.text in INNER_KEYWORDS.values() and i > 1 and _inner_keyword(toks, starts, i):
            i += 1
            continue
        if not _is_word(tok) or (i in starts and not (tok.text == "ground" and nxt(i) == ".")):
            i += 1
            continue
        if i > 0 and words[i - 1] == "." and i > 1 and _is_word(toks[i - 2]):
            i += 1  # reached only after a broken chain: the chain's walk handles the rest
            continue
        w = tok.text
        if nxt(i) == "." and i + 2 < n and _is_word(toks[i + 2]):
            chain = [i]
            while len(chain) < 3 and nxt(chain[-1]) == "." and chain[-1] + 2 < n and \
                    _is_word(toks[chain[-1] + 2]):
                chain.append(chain[-1] + 2)
            out.extend(_chain(chain, toks, bodies, points, constraints, sym))
            i = chain[-1] + 1
            continue
        if nxt(i) == "(":
            known = w in E.FUNCTIONS or w == "table" or w in OUTPUT_FUNCTIONS
            out.append(sym("function" if known else "unknown", i))
        elif w in declared.get("param", ()):
            out.append(sym("param", i))
        elif w in bodies:
            out.append(sym("body", i))
        elif w == TIME:
            out.append(sym("time", i))
        elif w in E.CONSTANTS:
            out.append(sym("constant", i))
        elif w in constraints:
            out.append(sym(constraints[w], i))
        elif w in ENERGY_QUANTITIES:
            out.append(sym("quantity", i))
        elif i in in_args:  # the variable of a function argument: its type names it
            out.append(sym("variable", i))
        else:
            out.append(sym("unknown", i))
        i += 1
    return SymbolIndex(tuple(out), tuple(toks))


def _inner_keyword(toks: list[Token], starts: set[int], i: int) -> bool:
    """Whether ``toks[i]`` (``in``, ``to``) is the keyword of the statement it stands in."""
    start = max((s for s in starts if s < i), default=None)
    return start is not None and INNER_KEYWORDS.get(toks[start].text) == toks[i].text


def _chain(chain: list[int], toks: list[Token], bodies: set[str],
           points: dict[str, set[str]], constraints: dict[str, str], sym) -> list[Symbol]:
    """The occurrences of a reference ``A.B`` or ``A.B.C`` (token indices ``chain``)."""
    head = toks[chain[0]].text
    if head in bodies:
        out = [sym("body", chain[0])]
        if len(chain) > 1:
            second = toks[chain[1]].text
            if second == ORIGIN or second in points.get(head, ()) or len(chain) > 2:
                out.append(sym("point", chain[1], owner=head))
                if len(chain) > 2:
                    out.append(sym("quantity", chain[2], owner=f"{head}.{second}"))
            else:
                out.append(sym("quantity", chain[1], owner=head))
        return out
    if head in constraints:
        return [sym(constraints[head], chain[0])] + [sym("quantity", j, owner=head)
                                                     for j in chain[1:]]
    return [sym("unknown", j) for j in chain]
