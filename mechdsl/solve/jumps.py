"""Where a constraint jumps in time: a drive written with a step (``if t < 1 then 0 else
0.1``), or one whose velocity jumps (a ramp that starts at t = 1).

No motion under finite forces follows such a drive: at the jump the constraint asks for an
infinite velocity (a position jump) or acceleration (a velocity jump). An explicit pair
steps over it and its projection moves the state onto the new constraint, silently unless
this module is asked; an implicit method, which satisfies the constraints at its stages,
halves its step until it underflows. Both are told here which constraint jumped, when and by
how much.

The test is by bisection in time, at a fixed position q: for a row i of Phi(q, t) (the
position level) or of nu(t) = -Phi_t (the velocity level) that changes across [a, b],
[a, b] is halved towards the half that changes more, down to a few units of round-off in t.
A row that is continuous there changes by nothing over so short an interval (a drive
moving at 1e3 m/s by 1e-12 m); one that jumps keeps its whole change in it. A row counts as
jumping where the final interval holds more than half of its change over [a, b] and that
change exceeds the caller's floor (its tolerance).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

#: Halvings of the interval at most (from a step of 1 s to 1e-18 s: past round-off in t)
BISECTIONS = 60
#: Rows examined per level at most (those changing most across the interval)
MAX_ROWS = 8


@dataclass(frozen=True)
class Jump:
    """Equation ``row`` jumps at ``t`` by ``size`` at the ``level`` "position" (Phi) or
    "velocity" (nu)."""

    row: int
    t: float
    size: float
    level: str
    #: the last instant found before the jump (``t`` the first after it, a few units of
    #: round-off later)
    t_before: float = float("nan")


def time_jumps(phi: Callable[[float], np.ndarray], nu: Callable[[float], np.ndarray] | None,
               a: float, b: float, floor: float) -> list[Jump]:
    """The jumps in [a, b] of ``phi(t)`` (Phi(q, t) at a fixed q, shape (m,)) and ``nu(t)``
    (module docstring), each at most once per row, the position level first; ``floor``
    the smallest change that counts."""
    out: list[Jump] = []
    if not b > a:
        return out
    for level, f in (("position", phi), ("velocity", nu)):
        if f is None:
            continue
        fa, fb = np.asarray(f(a), dtype=float), np.asarray(f(b), dtype=float)
        change = np.abs(fb - fa)
        change[~np.isfinite(change)] = 0.0
        rows = [int(r) for r in np.argsort(-change)[:MAX_ROWS] if change[r] > floor]
        for r in rows:
            jump = _bisect(lambda t, r=r: float(np.asarray(f(t))[r]), a, b,
                           float(fa[r]), float(fb[r]))
            if jump is not None and abs(jump[2]) > max(floor, 0.5 * change[r]):
                out.append(Jump(r, jump[1], abs(jump[2]), level, jump[0]))
    return out


def _bisect(g: Callable[[float], float], a: float, b: float, ga: float, gb: float
            ) -> tuple[float, float, float] | None:
    """(t-, t+, g(t+) - g(t-)): the interval of [a, b] whose halves are taken towards the
    one that changes more, down to round-off; None where g is not finite on the way."""
    for _ in range(BISECTIONS):
        mid = 0.5 * (a + b)
        if not a < mid < b:
            break
        gm = g(mid)
        if not np.isfinite(gm):
            return None
        if abs(gm - ga) >= abs(gb - gm):
            b, gb = mid, gm
        else:
            a, ga = mid, gm
    return a, b, gb - ga
