"""Where a constraint jumps in time: a drive written with a step (``if t < 1 then 0 else
0.1``), or one whose velocity jumps (a ramp that starts at t = 1).

No motion under finite forces follows such a drive: at the jump the constraint asks for an
infinite velocity (a position jump) or acceleration (a velocity jump). An explicit pair
steps over it and its projection moves the state onto the new constraint, silently unless
this module is asked; an implicit method, which satisfies the constraints at its stages,
halves its step until it underflows. Both are told here which constraint jumped, when and by
how much.

The test is by subdivision in time, at a fixed position q: for a row i of Phi(q, t) (the
position level) or of nu(t) = -Phi_t (the velocity level) that changes across [a, b],
[a, b] is cut into eight parts and the one whose change departs most from both its
neighbours' is kept, down to a few units of round-off in t. A smooth change is about the
same in neighbouring parts (a kink departs by at most half its change of rate times the
parts' width, which shrinks); a jump departs by its size in every part it is in (and a
part beside it from one neighbour only), however much the row
changes smoothly besides (a step of 0.1 m on a ramp of 0.4 m/s over a step of 2 s: halving
towards the half that changes more would follow the ramp). A row jumps where its change
over the last part, a few units of round-off wide, exceeds the caller's floor (its
tolerance) and a millionth of its change across [a, b]: a continuous row changes there by
its rate times 1e-16 s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

#: Subdivisions of the interval at most (eight parts each: from a step of 100 s to 1e-16 s
#: takes 20)
LEVELS = 24
#: Parts per subdivision
PARTS = 8
#: ... and a change over the last part below this fraction of the row's change across
#: [a, b] is not a jump (a drive like sqrt(|t - t1|), whose rate is unbounded at t1, changes
#: by 1e-8 over 1e-16 s there)
RELATIVE = 1e-6
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


def time_jumps(phi: Callable[[float], np.ndarray] | None,
               nu: Callable[[float], np.ndarray] | None,
               a: float, b: float, floor: float) -> list[Jump]:
    """The jumps in [a, b] of ``phi(t)`` (Phi(q, t) at a fixed q, shape (m,)) and ``nu(t)``
    (module docstring; either may be None), each at most once per row, the position level
    first; ``floor`` the smallest change that counts."""
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
            jump = _locate(lambda t, r=r: float(np.asarray(f(t))[r]), a, b)
            if jump is not None and abs(jump[2]) > max(floor, RELATIVE * change[r]):
                out.append(Jump(r, jump[1], abs(jump[2]), level, jump[0]))
    return out


def _locate(g: Callable[[float], float], a: float, b: float
            ) -> tuple[float, float, float] | None:
    """(t-, t+, g(t+) - g(t-)): the part of [a, b] that departs most from the others'
    change, subdivided down to round-off (module docstring); None where g is not finite
    on the way."""
    for _ in range(LEVELS):
        ts = np.linspace(a, b, PARTS + 1)
        if not np.all(np.diff(ts) > 0):
            break
        vals = np.array([g(float(x)) for x in ts])
        if not np.isfinite(vals).all():
            return None
        i = int(np.argmax(departures(np.diff(vals))))
        a, b = float(ts[i]), float(ts[i + 1])
    return a, b, g(b) - g(a)


def departures(d: np.ndarray) -> np.ndarray:
    """How far each change d[i] of successive parts (axis 0, at least three) departs from
    both its neighbours' (an end part's: from the next two parts'): a jump's part departs
    by the jump from both, a part beside it from one only, a smooth change's by its
    curvature times the parts' width squared."""
    before = np.concatenate((d[2:3], d[:-1]))
    after = np.concatenate((d[1:], d[-3:-2]))
    return np.minimum(np.abs(d - before), np.abs(d - after))


def constraint_jumps(equations, q: np.ndarray, a: float, b: float, floor: float
                     ) -> list[Jump]:
    """:func:`time_jumps` of the equations' constraints (``phi_jac``, ``nu`` of
    :class:`mechdsl.solve.stepper.Equations`) at the positions q; none where the equations
    have no ``phi_jac``."""
    phi_jac = getattr(equations, "phi_jac", None)
    if phi_jac is None:
        return []
    return time_jumps(lambda t: phi_jac(t, q)[0], getattr(equations, "nu", None), a, b, floor)
