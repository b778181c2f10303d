"""Source spans, the errors that carry them, and the one formatter that shows them.

Two kinds of failure reach a user, and the command line gives each its own exit status:

* :class:`MechError` -- the input is wrong (syntax, an unknown name, a bad value). Exit 1.
* :class:`NumericalError` -- the input is well formed but the mechanism cannot be solved
  (no assembly, a singular Jacobian, Newton-Raphson does not converge). Exit 2.

Both carry an optional :class:`Span` and :class:`Source` so that :func:`format_error` can print
``FILE:LINE:COL: error: MESSAGE`` followed by the source line and a caret under the spot.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Iterable

#: Bounds on what an error shows, whatever the input: the longest message and note (cut with
#: '...'), the notes shown, the characters of a source line shown around the spot, a token
#: of the input echoed in a message (:func:`cut`), names in a list (:func:`listing`) and the
#: longest name that gets a suggestion.
MAX_MESSAGE_CHARS = 2000
MAX_NOTE_CHARS = 1000
MAX_NOTES = 20
SOURCE_WINDOW = 100
MAX_TOKEN_CHARS = 40
MAX_LISTED = 5
MAX_SUGGESTED = 100


@dataclass(frozen=True)
class Span:
    """A region of source text; lines and columns count from 1, ``end_column`` is exclusive."""

    line: int
    column: int
    end_line: int
    end_column: int


@dataclass(frozen=True)
class Source:
    """The text of a ``.mech`` file (or of a command-line value) and the name it is shown under."""

    name: str
    text: str

    def line(self, number: int) -> str:
        """The text of line ``number`` (1-based), without its newline; '' if out of range.

        Lines end at '\n' only, as the parser counts them (not at form feeds or U+2028)."""
        lines = self.text.split("\n")
        return lines[number - 1].rstrip("\r") if 1 <= number <= len(lines) else ""


class MechError(Exception):
    """A user error: the input is wrong. ``notes`` are extra lines printed after the caret."""

    def __init__(
        self,
        message: str,
        span: Span | None = None,
        source: Source | None = None,
        notes: Iterable[str] = (),
    ) -> None:
        super().__init__(message)
        self.message = message
        self.span = span
        self.source = source
        self.notes = tuple(notes)

    @property
    def file(self) -> str | None:
        """The name of the file (or command-line value) the error is in, if known."""
        return self.source.name if self.source is not None else None

    @property
    def line(self) -> int | None:
        """The line (from 1) where the error is, if it is located."""
        return self.span.line if self.span is not None else None

    @property
    def column(self) -> int | None:
        """The column (from 1) where the error is, if it is located."""
        return self.span.column if self.span is not None else None

    def with_source(self, source: Source) -> "MechError":
        """Attach ``source`` unless one is already attached; returns ``self``."""
        if self.source is None:
            self.source = source
        return self


class OptionError(MechError):
    """A bad value of an option or argument (``--step 0``, ``simulate(step=0)``): the
    message starts with the option's name, and no file is attached to it, since the value is
    not in one (the command line prints it as ``mechdsl: error: --step: ...``)."""

    def with_source(self, source: Source) -> "MechError":
        return self


class MechWarning(str):
    """A warning located in the model's text: the text "line L, column C: MESSAGE" (how it
    reads in the API, stores and pages) that also keeps its ``message``, ``span`` and
    ``source``, so that the command line shows it as it shows an error
    (:func:`format_warning`)."""

    span: Span | None
    source: Source | None
    message: str

    def __new__(cls, message: str, span: Span | None = None,
                source: Source | None = None) -> "MechWarning":
        where = f"line {span.line}, column {span.column}: " if span is not None else ""
        self = super().__new__(cls, where + message)
        self.message, self.span, self.source = message, span, source
        return self

    def __reduce__(self):  # pickled (a Dask worker's results) as what it was built from
        return MechWarning, (self.message, self.span, self.source)


def format_warning(warning: str, name: str) -> str:
    """``FILE:LINE:COL: warning: MESSAGE`` with the source line and a caret for a
    :class:`MechWarning`, ``NAME: warning: TEXT`` for another warning of file ``name``."""
    if isinstance(warning, MechWarning) and warning.source is not None:
        return format_error(MechError(warning.message, warning.span, warning.source),
                            "warning")
    return f"{name}: warning: {_printable(cut(str(warning), MAX_MESSAGE_CHARS))}"


class NumericalError(MechError):
    """The mechanism is well described but cannot be solved (assembly, singularity, divergence)."""


def suggest(name: str, candidates: Iterable[str], what: str = "") -> str:
    """A '; did you mean ...?' suffix naming the closest candidates (each prefixed with
    ``what``), or '' if none is close."""
    if len(name) > MAX_SUGGESTED:  # no misspelling is that long; difflib would be slow
        return ""
    lower = name.lower()
    candidates = [c for c in candidates if len(c) <= MAX_SUGGESTED]
    by_lower: dict[str, str] = {}
    for c in candidates:
        by_lower.setdefault(c.lower(), c)
    # case differences (L for l) count as close; then spelling
    close = [c for c in candidates if c != name and c.lower() == lower]
    close += [by_lower[c] for c in difflib.get_close_matches(lower, list(by_lower),
                                                              n=3, cutoff=0.6)
              if by_lower[c] not in close and by_lower[c] != name]
    close = close[:3]
    if not close:
        return ""
    quoted = " or ".join(f"'{what}{cut(c)}'" for c in close)
    return f"; did you mean {quoted}?"


def cut(text: str, width: int = MAX_TOKEN_CHARS) -> str:
    """``text`` if it has at most ``width`` characters, else its first ``width`` and '...':
    for echoing a token of the input in a message without echoing a whole line or file."""
    text = str(text)
    return text if len(text) <= width else text[:width] + "..."


def listing(items: Iterable[str], first: int = MAX_LISTED, total: int | None = None) -> str:
    """'a, b, c' or, for a longer list, 'a, b, c, d, e and 12 more': a bounded list of
    names for a message. ``total``: how many there are, where ``items`` holds only the
    first of them."""
    items = list(items)
    total = len(items) if total is None else total
    if total <= first + 1:
        return ", ".join(items[:total])
    return ", ".join(items[:first]) + f" and {total - first} more"


def format_error(error: MechError, kind: str = "error") -> str:
    """Render ``error`` as ``FILE:LINE:COL: error: MESSAGE``, the source line and a caret.

    Without a span the location is the file name alone; without a source, the message alone.
    The output is bounded whatever the input: the source line is shown as a window of
    :data:`SOURCE_WINDOW` characters around the spot, the message and each note are cut, at
    most :data:`MAX_NOTES` notes are shown, and control characters (a terminal's escape
    sequences written in the file) are shown as '?'.
    """
    head = f"{kind}: {_printable(cut(error.message, MAX_MESSAGE_CHARS))}"
    src, span = error.source, error.span
    if src is None:
        lines = [head]
    elif span is None:
        lines = [f"{src.name}: {head}"]
    else:
        lines = [f"{src.name}:{span.line}:{span.column}: {head}"]
        text = src.line(span.line).expandtabs(1)
        if text:
            if span.end_line == span.line:
                width = max(1, span.end_column - span.column)
            else:
                width = max(1, len(text) - span.column + 1)
            shown, offset, width = _window(text, span.column - 1, width)
            gutter = f"{span.line:>5} | "
            lines.append(gutter + _printable(shown))
            lines.append(" " * (len(gutter) - 2) + "| " + " " * offset + "^" * width)
    notes = error.notes
    lines.extend(f"  note: {_printable(cut(n, MAX_NOTE_CHARS))}" for n in notes[:MAX_NOTES])
    if len(notes) > MAX_NOTES:
        lines.append(f"  note: and {len(notes) - MAX_NOTES} more notes")
    return "\n".join(lines)


def _window(text: str, start: int, width: int) -> tuple[str, int, int]:
    """The part of ``text`` shown around ``start`` (0-based): (shown text with '...' where it
    is cut, the caret's offset in it, the caret's width within it)."""
    if len(text) <= SOURCE_WINDOW:
        return text, start, width
    # some context before the spot, most of the window after it
    begin = max(0, min(start - SOURCE_WINDOW // 4, len(text) - SOURCE_WINDOW))
    end = min(len(text), begin + SOURCE_WINDOW)
    before = "..." if begin > 0 else ""
    after = "..." if end < len(text) else ""
    width = max(1, min(width, end - start))
    return before + text[begin:end] + after, len(before) + start - begin, width


_CONTROL = dict.fromkeys([*range(0x20), 0x7F, *range(0x80, 0xA0)], "?")
_CONTROL.pop(ord("\n"))


def _printable(text: str) -> str:
    return text.translate(_CONTROL)
