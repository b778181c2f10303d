"""Tabulated functions: ``table("motion.csv", t)``, ``table([(0, 0), (1, 2)], t)`` and the
periodic ``table("cam.csv", psi, 2*pi)``, read into :class:`~mechdsl.expr.Table` nodes.

A file holds two numbers per line (x, then y), separated by a comma, a semicolon, a tab or
spaces; blank lines, lines starting with ``#`` and one header line are skipped. The x values
must increase strictly. Relative paths are taken from the folder of the ``.mech`` file.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

from . import expr as E
from .errors import MechError, Span
from .model import Vector

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
    if isinstance(data, str):
        xs, ys = _read(os.path.join(base_dir, data), data, data_span)
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
    return E.Table(tuple(xs), tuple(ys), arg, p, 0, label, span)


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
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except OSError as err:
        raise MechError(f"cannot read the table {shown}: {err.strerror}", span) from None
    except UnicodeDecodeError:
        raise MechError(f"the table {shown} is not UTF-8 text", span) from None
    xs, ys = [], []
    for number, line in enumerate(lines, 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = [f for f in _SEP.split(text) if f]
        try:
            x, y = float(fields[0]), float(fields[1])
        except (ValueError, IndexError):
            if not xs and not any(c.isdigit() for c in fields[0][:1]):
                continue  # a header line
            raise MechError(f"{shown}:{number}: expected two numbers (x, y), got {text!r}",
                            span) from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise MechError(f"{shown}:{number}: the numbers must be finite", span)
        xs.append(x)
        ys.append(y)
    return xs, ys


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
