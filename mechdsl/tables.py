"""Tabulated functions: ``table("motion.csv", t)``, ``table([(0, 0), (1, 2)], t)`` and the
periodic ``table("cam.csv", psi, 2*pi)``, read into :class:`~mechdsl.expr.Table` nodes.

A file holds two numbers per line (x, then y), separated by a comma, a semicolon, a tab or
spaces; blank lines, lines starting with ``#`` and one header line are skipped. The x values
must increase strictly. Relative paths are taken from the folder of the ``.mech`` file. The
file is read as data (:mod:`.reading`): a regular file of at most
:data:`~mechdsl.reading.MAX_DATA_BYTES`, quoted in messages by a few characters at most.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

from . import expr as E
from .errors import MechError, Span, cut
from .model import Vector
from .reading import excerpt, read_data

_SEP = re.compile(r"[,;\s]+")


@dataclass(frozen=True)
class PointList:
    """Inline table data as written: ``[(x, y), ...]``."""

    points: tuple[Vector, ...]
    span: Span


def make_table(data: str | PointList, data_span: Span, arg: E.Expr, period: E.Expr | None,
               base_dir: str, span: Span) -> E.Table:
    """Build the table node for ``table(data, arg[, period])``; ``data`` is a file name or
    inline points."""
    path = None
    if isinstance(data, str):
        path = os.path.realpath(os.path.join(base_dir, data))
        xs, ys = _read(path, cut(data), data_span)
        label = f'"{data}"'
    else:
        xs, ys = _inline(data.points, data_span)
        label = "[" + ", ".join(f"({x!r}, {y!r})" for x, y in zip(xs, ys)) + "]"
    if len(xs) < 2:
        raise MechError("a table needs at least two points", data_span)
    for i in range(1, len(xs)):
        if not xs[i] > xs[i - 1]:
            raise MechError(f"the x values of a table must increase: {xs[i]!r} follows "
                            f"{xs[i - 1]!r}", data_span)
    p = None
    if period is not None:
        p = _constant(period, "the period of a table")
        if not p > 0:
            raise MechError(f"the period of a table must be positive, not {p:g}", period.span)
        xs, ys = _one_period(xs, ys, p, data_span)
    return E.Table(tuple(xs), tuple(ys), arg, p, 0, label, span, path)


def _constant(e: E.Expr, what: str) -> float:
    names = E.free_names(e)
    if names:
        raise MechError(f"{what} must be a constant number, not depend on '{sorted(names)[0]}'",
                        e.span)
    value = float(E.evaluate(e, {}))
    if not math.isfinite(value):
        raise MechError(f"{what} must be finite", e.span)
    return value


def _inline(points: list[Vector], span: Span) -> tuple[list[float], list[float]]:
    xs, ys = [], []
    for v in points:
        if len(v.items) != 2:
            raise MechError(f"a table point is (x, y), not {len(v.items)} numbers", v.span)
        xs.append(_constant(v.items[0], "a table point"))
        ys.append(_constant(v.items[1], "a table point"))
    return xs, ys


def _read(path: str, shown: str, span: Span) -> tuple[list[float], list[float]]:
    # read as data (a regular file, size-checked); messages show a few characters of the
    # offending field at most, never a line of the file (which may be anybody's file)
    raw = read_data(path, "the table ", "MAX_DATA_BYTES", span, shown=shown)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        before = raw[: err.start].replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        line = before.count(b"\n") + 1
        raise MechError(f"the table {shown} is not UTF-8 text (line {line})", span) from None
    if text.startswith("\ufeff"):  # the byte-order mark spreadsheets write
        text = text[1:]
    xs, ys = [], []
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    for number, line in enumerate(lines, 1):
        row = line.strip()
        if not row or row.startswith("#"):
            continue
        fields = [f for f in _SEP.split(row) if f]
        try:
            x, y = float(fields[0]), float(fields[1])
        except (ValueError, IndexError):
            if not xs and fields and not fields[0][:1].isdigit():
                continue  # a header line
            raise MechError(f"{shown}:{number}: expected two numbers (x, y), "
                            + _bad_fields(fields), span) from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise MechError(f"{shown}:{number}: the numbers must be finite", span)
        xs.append(x)
        ys.append(y)
    return xs, ys


def _bad_fields(fields: list[str]) -> str:
    """What is wrong with the fields of a line, showing the bad one cut short."""
    if len(fields) < 2:
        return "found one" if fields else "found none"
    bad = next(f for f in fields[:2] if not _is_number(f))
    return f"but {excerpt(bad)} is not a number"


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _one_period(xs, ys, period: float, span: Span):
    """Data over one period, closed: the last point repeats the first, one period on."""
    width = xs[-1] - xs[0]
    if width > period * (1 + 1e-12):
        raise MechError(f"a periodic table spans {width:g}, more than its period {period:g}",
                        span)
    if abs(width - period) <= 1e-12 * period:
        if abs(ys[-1] - ys[0]) > 1e-9 * max(1.0, abs(ys[0])):
            raise MechError("a periodic table must end where it starts: the last y "
                            f"({ys[-1]!r}) differs from the first ({ys[0]!r})", span)
        return xs[:-1] + [xs[0] + period], ys[:-1] + [ys[0]]
    return xs + [xs[0] + period], ys + [ys[0]]
