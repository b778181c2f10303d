"""The canonical layout of a ``.mech`` file (``mechdsl fmt``).

One statement per line (a ``;`` between statements goes), a body's items on their own lines
indented by four spaces (a body written on one line stays on one, its items two spaces
apart), one blank line at most between statements, and the spacing of
every token by one rule: a space around ``=``, ``..``, ``+``, ``-``, comparisons and words,
after ``,`` and ``:``, none around ``*``, ``/``, ``^`` and ``.``, inside brackets, or after a
unary sign. Comments are all kept: a comment on a line of its own stays on a line of its
own, a comment after code stays after it, and the trailing comments of consecutive lines
are aligned two spaces after the longest of those lines. A statement the author broke over
several lines after commas, or before the + or - of a sum, keeps those breaks (the
continuation indented by four spaces).

Only whitespace changes and ``;`` separators go: the tokens, and so the model, are those of
the input, and that is checked on every call (:func:`format_text` refuses to return text
whose tokens differ). Formatting its own output changes nothing.
"""

from __future__ import annotations

from lark import Token, Tree

from ..errors import MechError, Source
from .parser import lex, normalise, parse, parse_tree

#: The statement keywords whose item lists sit in braces
_BLOCKS = ("body", "ground")
_TIGHT = {"*", "/", "^", "."}
_NO_SPACE_BEFORE = {")", "]", ",", ":", ".", ";"}
_NO_SPACE_AFTER = {"(", "[", "."}
_OPERATORS = {"+", "-", "*", "/", "^", "=", "..", "<", "<=", ">", ">=", ",", "(", "[", ":",
              "if", "then", "else", "and", "or", "not", "step", "count"}
_INDENT = "    "


def _significant(tokens: list[Token]) -> list[tuple[str, str]]:
    return [(t.type, str(t)) for t in tokens if t.type not in ("WS", "COMMENT", "SEMICOLON")
            and str(t) != ";"]


def _words(a: str, b: str) -> bool:
    return (a[-1:].isalnum() or a[-1:] == "_") and (b[:1].isalnum() or b[:1] == "_")


def _join(tokens: list[Token], first_unary: bool = True) -> str:
    """The tokens of one line of code, spaced by the rule of the module."""
    out: list[str] = []
    prev: str | None = None
    prev_unary = False
    for tok in tokens:
        text = str(tok)
        unary = text in ("-", "+") and (prev is None or prev in _OPERATORS
                                        or prev in ("param", "sweep") or prev == "{")
        if prev is not None:
            if _words(prev, text):
                space = True
            elif prev_unary or prev in _NO_SPACE_AFTER or text in _NO_SPACE_BEFORE:
                space = False
            elif text in _TIGHT or prev in _TIGHT:
                space = False
            elif text in ("(", "[") and (prev[-1:].isalnum() or prev[-1:] == "_"):
                space = False  # a call, table(...), polygon(...), revolute(...)
            else:
                space = True
            if space:
                out.append(" ")
        out.append(text)
        prev, prev_unary = text, unary
    return "".join(out)


class _Layout:
    """The output lines, each code and an optional trailing comment, aligned at the end."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str | None]] = []

    def add(self, code: str, comment: str | None = None) -> None:
        self.lines.append((code, comment))

    def blank(self) -> None:
        if self.lines and self.lines[-1] != ("", None):
            self.lines.append(("", None))

    def text(self) -> str:
        out: list[str] = []
        i = 0
        while i < len(self.lines):
            j = i
            # a run of consecutive lines with code and a trailing comment: one column
            while j < len(self.lines) and self.lines[j][0].strip() and self.lines[j][1]:
                j += 1
            if j > i:
                width = max(len(code) for code, _ in self.lines[i:j])
                out += [f"{code.ljust(width)}  {comment}" for code, comment in self.lines[i:j]]
                i = j
                continue
            code, comment = self.lines[i]
            out.append(comment if not code.strip() and comment else code)
            i += 1
        while out and out[-1] == "":
            out.pop()
        return "\n".join(out) + "\n"


def _comment_after(tokens: list[Token], end: int) -> Token | None:
    """The comment on the same line right after offset ``end`` (spaces between), or None."""
    after = (t for t in tokens if t.start_pos >= end)
    first = next(after, None)
    if first is not None and first.type == "WS" and "\n" not in first:
        first = next(after, None)
    return first if first is not None and first.type == "COMMENT" else None


def _statements(tree: Tree) -> list[Tree]:
    return [c for c in tree.children if isinstance(c, Tree)]


def format_text(text: str, name: str = "<string>") -> str:
    """``text`` in the canonical layout (see the module). A syntax error raises the located
    MechError that parsing it gives."""
    text = normalise(text)
    parse(text, name)  # a file that does not parse is reported as the command line does
    tree = parse_tree(text)
    tokens = list(lex(text, dont_ignore=True))
    layout = _Layout()
    stmts = _statements(tree)
    pos = 0
    for stmt in stmts:
        start, end = stmt.meta.start_pos, stmt.meta.end_pos
        _gap(layout, [t for t in tokens if pos <= t.start_pos < start], bool(layout.lines))
        body = [t for t in tokens if start <= t.start_pos < end]
        # the comment that ends the statement's last line belongs to it
        trailing = _comment_after(tokens, end)
        if stmt.data in _BLOCKS:
            _block(layout, stmt, body, trailing)
        else:
            _statement(layout, body, trailing)
        pos = (trailing.end_pos if trailing is not None else end)
    _gap(layout, [t for t in tokens if t.start_pos >= pos], bool(layout.lines))
    out = layout.text()
    _same_tokens(text, out, name)
    return out


def _gap(layout: _Layout, tokens: list[Token], started: bool) -> None:
    """The comments and blank lines between two statements: each comment on its line, one
    blank line where the input has one or more."""
    newlines = 0
    for t in tokens:
        if t.type == "WS":
            newlines += str(t).count("\n")
            continue
        if t.type == "COMMENT":
            if newlines >= 2 and started:
                layout.blank()
            layout.add("", str(t).rstrip())
            newlines = 0
            started = True
    if newlines >= 2 and started:
        layout.blank()


def _lines_of(tokens: list[Token]) -> list[tuple[list[Token], Token | None]]:
    """Code tokens split where the input breaks a line after a comma (or at a comment),
    each piece with the comment that ends it."""
    pieces: list[tuple[list[Token], Token | None]] = []
    current: list[Token] = []
    for i, t in enumerate(tokens):
        if t.type == "COMMENT":
            pieces.append((current, t))
            current = []
        elif t.type == "WS":
            if "\n" in t and current and (str(current[-1]) == ","
                                          or _before_binary(current[-1], tokens, i)):
                pieces.append((current, None))
                current = []
        elif str(t) != ";":
            current.append(t)
    if current or not pieces:
        pieces.append((current, None))
    return [(code, c) for code, c in pieces if code or c is not None]


def _before_binary(last: Token, tokens: list[Token], i: int) -> bool:
    """Whether the break at ``tokens[i]`` comes before a binary ``+`` or ``-`` (the line before
    ends an operand): a long sum may be written a term per line."""
    after = next((u for u in tokens[i + 1:] if u.type != "WS"), None)
    return (after is not None and str(after) in ("+", "-")
            and (str(last) in (")", "]") or last.type in ("NAME", "NUMBER")))


def _statement(layout: _Layout, tokens: list[Token], trailing: Token | None,
               indent: str = "") -> None:
    pieces = _lines_of(tokens)
    for k, (code, comment) in enumerate(pieces):
        if k == len(pieces) - 1 and comment is None and trailing is not None:
            comment = trailing
        text = _join(code)
        before = pieces[k - 1][0] if k else []
        if k and code and str(code[0]) in ("+", "-") and before and str(before[-1]) != ",":
            text = f"{code[0]} {_join(code[1:])}"  # a binary sign that opens the line
        line = (indent if k == 0 else indent + _INDENT) + text
        layout.add(line if code else "", None if comment is None else str(comment).rstrip())


def _block(layout: _Layout, stmt: Tree, tokens: list[Token], trailing: Token | None) -> None:
    """``body NAME {`` and its items, each on its line, then ``}``."""
    brace = next(i for i, t in enumerate(tokens) if str(t) == "{")
    close = max(i for i, t in enumerate(tokens) if str(t) == "}")
    head = [t for t in tokens[:brace + 1] if t.type not in ("WS", "COMMENT")]
    inner = tokens[brace + 1 : close]
    items = [c for c in stmt.children if isinstance(c, Tree)]
    head_comment = next((t for t in inner if t.type == "COMMENT"
                         and all("\n" not in u for u in inner[: inner.index(t)]
                                 if u.type == "WS")), None)
    if not items and all(t.type == "WS" for t in inner):
        layout.add(_join(head) + " }", None if trailing is None else str(trailing).rstrip())
        return
    if all(t.type != "COMMENT" and (t.type != "WS" or "\n" not in t) for t in inner):
        # written on one line: it stays on one, its items two spaces apart
        parts = [_join([t for t in inner if item.meta.start_pos <= t.start_pos
                        < item.meta.end_pos and t.type != "WS"]) for item in items]
        layout.add(f"{_join(head)} {'  '.join(parts)} }}",
                   None if trailing is None else str(trailing).rstrip())
        return
    layout.add(_join(head), None if head_comment is None else str(head_comment).rstrip())
    pos = head_comment.end_pos if head_comment is not None else tokens[brace].end_pos
    for item in items:
        start, end = item.meta.start_pos, item.meta.end_pos
        for t in inner:  # comments on lines of their own before the item
            if pos <= t.start_pos < start and t.type == "COMMENT":
                layout.add("", _INDENT + str(t).rstrip())
        code = [t for t in inner if start <= t.start_pos < end]
        comment = _comment_after(inner, end)
        _statement(layout, code, comment, _INDENT)
        pos = comment.end_pos if comment is not None else end
    for t in inner:
        if t.start_pos >= pos and t.type == "COMMENT":
            layout.add("", _INDENT + str(t).rstrip())
    layout.add("}", None if trailing is None else str(trailing).rstrip())


def _same_tokens(before: str, after: str, name: str) -> None:
    """The formatted text must have the input's tokens and comments, in order."""
    a = list(lex(before, dont_ignore=True))
    b = list(lex(after, dont_ignore=True))
    comments = ([str(t).rstrip() for t in a if t.type == "COMMENT"],
                [str(t).rstrip() for t in b if t.type == "COMMENT"])
    if _significant(a) != _significant(b) or comments[0] != comments[1]:
        raise MechError("mechdsl fmt would change this file's meaning (a defect of the "
                        "formatter: please report it); the file is left as it is",
                        source=Source(name, before))
