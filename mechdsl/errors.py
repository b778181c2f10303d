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

    def with_source(self, source: Source) -> "MechError":
        """Attach ``source`` unless one is already attached; returns ``self``."""
        if self.source is None:
            self.source = source
        return self


class NumericalError(MechError):
    """The mechanism is well described but cannot be solved (assembly, singularity, divergence)."""


def suggest(name: str, candidates: Iterable[str], what: str = "") -> str:
    """A '; did you mean ...?' suffix naming the closest candidates (each prefixed with
    ``what``), or '' if none is close."""
    candidates = list(candidates)
    by_lower: dict[str, str] = {}
    for c in candidates:
        by_lower.setdefault(c.lower(), c)
    # case differences (L for l) count as close; then spelling
    close = [c for c in candidates if c.lower() == name.lower() and c != name]
    close += [by_lower[c] for c in difflib.get_close_matches(name.lower(), list(by_lower),
                                                              n=3, cutoff=0.6)
              if by_lower[c] not in close and by_lower[c] != name]
    close = close[:3]
    if not close:
        return ""
    quoted = " or ".join(f"'{what}{c}'" for c in close)
    return f"; did you mean {quoted}?"


def format_error(error: MechError, kind: str = "error") -> str:
    """Render ``error`` as ``FILE:LINE:COL: error: MESSAGE``, the source line and a caret.

    Without a span the location is the file name alone; without a source, the message alone.
    """
    head = f"{kind}: {error.message}"
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
            gutter = f"{span.line:>5} | "
            lines.append(gutter + text)
            lines.append(" " * (len(gutter) - 2) + "| " + " " * (span.column - 1) + "^" * width)
    lines.extend(f"  note: {n}" for n in error.notes)
    return "\n".join(lines)
