"""Tabulated functions: ``table("motion.csv", t)``, ``table([(0, 0), (1, 2)], t)`` and the
periodic ``table("cam.csv", psi, 2*pi)``, as :class:`~mechdsl.grammar.expr.Table` nodes.

Points written in the model are checked here. A file is only named here: the table node
holds its real path (relative paths are taken from the folder of the ``.mech`` file) and no
points, which are read when the model is compiled (:mod:`mechdsl.compiled.files`). Either way
the x values must increase strictly, and a periodic table must close over its period.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from ..errors import MechError, Span
from . import expr as E
from .model import Vector


@dataclass(frozen=True)
class PointList:
    """Inline table data as written: ``[(x, y), ...]``."""

    points: tuple[Vector, ...]
    span: Span


def make_table(data: str | PointList, data_span: Span, arg: E.Expr, period: E.Expr | None,
               base_dir: str, span: Span) -> E.Table:
    """The table node for ``table(data, arg[, period])``; ``data`` is a file name (the node
    names the file and is read later) or inline points."""
    if isinstance(data, str):
        path = os.path.realpath(os.path.join(base_dir, data))
        return E.Table((), (), arg, _period(period), 0, f'"{data}"', span, path, data_span)
    xs, ys = _inline(data.points, data_span)
    label = "[" + ", ".join(f"({x!r}, {y!r})" for x, y in zip(xs, ys)) + "]"
    check_points(xs, ys, data_span)
    p = _period(period)
    if p is not None:
        xs, ys = one_period(xs, ys, p, data_span)
    return E.Table(tuple(xs), tuple(ys), arg, p, 0, label, span, None, data_span)


def check_points(xs: list[float], ys: list[float], span: Span) -> None:
    """At least two points, with x values that increase strictly."""
    if len(xs) < 2:
        raise MechError("a table needs at least two points", span)
    for i in range(1, len(xs)):
        if not xs[i] > xs[i - 1]:
            raise MechError(f"the x values of a table must increase: {xs[i]!r} follows "
                            f"{xs[i - 1]!r}", span)


def _period(period: E.Expr | None) -> float | None:
    if period is None:
        return None
    p = _constant(period, "the period of a table")
    if not p > 0:
        raise MechError(f"the period of a table must be positive, not {p:g}", period.span)
    return p


def _constant(e: E.Expr, what: str) -> float:
    names = E.free_names(e)
    if names:
        raise MechError(f"{what} must be a constant number, not depend on '{sorted(names)[0]}'",
                        e.span)
    if any(isinstance(n, E.Table) and n.unread for n in E.walk(e)):
        raise MechError(f"{what} must be a number written in the model, not read from a file",
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


def one_period(xs: list[float], ys: list[float], period: float, span: Span
               ) -> tuple[list[float], list[float]]:
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
