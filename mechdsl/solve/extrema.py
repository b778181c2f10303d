"""Extremes found between the samples: the reductions ``max``, ``min``, ``argmax``,
``argmin`` and ``range`` of a kinematic run, refined to the solver's accuracy (a forward
dynamics run refines them on its dense output with the same candidates and steps:
:meth:`mechdsl.solve.dynamic.DynamicRun._refine_extremes`).

A reduction over the run's instants sees only the samples y_k = E(t_k): the peak of a
slider's acceleration, or a stroke, falls between them, and the sampled value is short of it
by about E'' h^2 / 8. The kinematics solves any instant exactly, so each extremum is found
where it is: for every variant, the sampled local maxima of E (of -E for a minimum; the
``CANDIDATES`` highest, the run's ends included) are each bracketed by the samples on either
side, [t_k-1, t_k+1], and refined by successive parabolic interpolation through three
points (a, m, b) with E(m) >= E(a), E(b):

    u = m - 1/2 [(m - a)^2 (E_m - E_b) - (m - b)^2 (E_m - E_a)]
              / [(m - a)(E_m - E_b) - (m - b)(E_m - E_a)],

safeguarded by a golden-section step into the larger half where u is not inside the bracket
(Brent's rule, vectorised over variants and candidates). Each E(u) is a kinematic solve at
u from the Taylor prediction of the sample's state, q_k + tau qd_k + tau^2/2 qdd_k (the
march's own predictor, on its own branch: the determinant's sign is checked as the march
checks it), then the column's value from q, qd, qdd. It stops when the vertex moves by less
than ``XTOL`` times the run's span, or after ``MAX_ITERATIONS``. The extreme reported is the
largest of the samples and the refined points, so refining never lowers a maximum.

The value at an extremum is insensitive to its time (E' = 0): it is found to the solve's
accuracy (round-off, for a mechanism exact to round-off); ``argmax``/``argmin`` are found
to about ``XTOL`` of the run's span, or to sqrt(machine epsilon) relative to the curvature's
time scale where that is coarser (there E values no longer tell neighbouring times apart).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..compiled import equations as eq

if TYPE_CHECKING:  # pragma: no cover
    from .run import KinematicRun

#: the reductions refined, and the sense of the extremum each needs (+1 max, -1 min)
SENSES = {"max": (1,), "argmax": (1,), "min": (-1,), "argmin": (-1,), "range": (1, -1)}
#: sampled local extrema refined per variant and column (the highest ones)
CANDIDATES = 3
#: the refinement stops when the vertex moves by less than this, relative to the run's span
#: (about where values stop telling times apart: the value is then exact to round-off)
XTOL = 1e-10
#: ... or when the value changes by less than this relative to the column's largest
FLAT = 1e-15
MAX_ITERATIONS = 30
#: extremes within this (relative to the column's largest) of the best are equal: the
#: first in time is the argmax/argmin, as of the samples
TIE = 1e-12
#: ... and, of an integrated motion, within this many times its rtol: its equal peaks (a
#: periodic motion's) differ by the integration's error, far above TIE (a mass on a spring
#: at rtol 1e-8: argmax(vx) gave its third peak, not its first)
TIE_RTOL = 100
_GOLD = (3 - math.sqrt(5)) / 2


class Abandoned(Exception):
    """A refinement's solve failed a check: the sampled extremes stand."""


def wanted(system) -> set[tuple[str, int]]:
    """The (column label, sense) pairs the system's reductions need refined."""
    return {(label, sense) for r in system.reductions for _, func, label in r.parts
            for sense in SENSES.get(func, ())}


def refine(run: "KinematicRun", pairs: set[tuple[str, int]]
           ) -> dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]:
    """For each (label, sense), per variant: the extreme value of the column (times sense:
    its maximum) and its time, between the samples (module docstring); NaN where the
    variant did not solve every instant. Every pair is refined in the same solves (one
    batch of the variants' candidates); where a solve fails a check, none is."""
    system, t = run.system, run.times
    V, K = system.n_variants, len(t)
    pairs = sorted(pairs)
    if K < 2 or not pairs:
        return {}
    specs = {o.label: o for o in system.outputs}
    ys = [sense * run.data[label] for label, sense in pairs]
    complete = (run.n_solved == K) & run.active
    for y in ys:
        complete &= np.isfinite(y).all(axis=1)
    if not complete.any():
        return {}
    ys = [np.where(complete[:, None], y, 0.0) for y in ys]
    found = [_candidates(y, t) for y in ys]
    ks = [kk for kk, _ in found]
    k = np.concatenate(ks, axis=1)                              # (V, P C)
    finished = np.concatenate([d for _, d in found], axis=1) | ~complete[:, None]
    C = ks[0].shape[1]
    rows = np.arange(V)[:, None]
    q0 = run.poses[rows, k]                                     # (V, P C, n)
    qd0, qdd0 = run.pose_rates[rows, k, 0], run.pose_rates[rows, k, 1]
    tk = t[k]
    a, b = t[np.maximum(k - 1, 0)], t[np.minimum(k + 1, K - 1)]
    sampled = np.concatenate([y[rows, kk] for y, kk in zip(ys, ks)], axis=1)
    fa = np.concatenate([y[rows, np.maximum(kk - 1, 0)] for y, kk in zip(ys, ks)], axis=1)
    fb = np.concatenate([y[rows, np.minimum(kk + 1, K - 1)] for y, kk in zip(ys, ks)],
                        axis=1)

    def at(T: np.ndarray) -> np.ndarray:
        tau = (T - tk)[..., None]
        solved = run.level(q0 + tau * qd0 + 0.5 * tau * tau * qdd0, T)
        if solved is None:
            raise Abandoned
        _, q, qd, qdd = solved
        f = np.empty_like(T)
        with np.errstate(all="ignore"):
            for j, (label, sense) in enumerate(pairs):
                cut = slice(j * C, (j + 1) * C)
                f[:, cut] = sense * eq.output_values(run.kernels, specs[label], q[:, cut],
                                                     qd[:, cut], qdd[:, cut], T[:, cut], {})
        if not np.isfinite(f[complete]).all():
            raise Abandoned
        return np.where(complete[:, None], f, 0.0)

    active = run.active.copy()
    run.active &= complete  # (the solves' masks: a variant that stopped is not refined)
    try:
        # the middle point: the sample itself inside, the bracket's middle at the run's ends
        m = np.where((k > 0) & (k < K - 1), tk, 0.5 * (a + b))
        scale = np.concatenate([np.repeat(np.abs(y).max(axis=1, keepdims=True), C, axis=1)
                                for y in ys], axis=1)
        best_t, best_f = search(at, a, m, b, fa, at(m), fb, finished, scale,
                                XTOL * max(abs(t[-1] - t[0]), 1e-300))
    except Abandoned:
        return {}
    finally:
        run.active = active
    # never below the samples: the best of the sampled extremum and the refined ones
    refined = best_f >= sampled
    f = np.where(refined, best_f, sampled)
    tt = np.where(refined, best_t, tk)
    out = {}
    for j, pair in enumerate(pairs):
        cut = slice(j * C, (j + 1) * C)
        fj, tj = f[:, cut], tt[:, cut]
        pick = first_best(fj, tj, scale[:, cut])
        value, when = np.full(V, np.nan), np.full(V, np.nan)
        value[complete] = pair[1] * fj[np.arange(V), pick][complete]
        when[complete] = tj[np.arange(V), pick][complete]
        out[pair] = (value, when)
    return out


def search(at, a, m, b, fa, fm, fb, finished, scale, xtol: float):
    """The best point (times, values) of the safeguarded parabolic search (module
    docstring) from brackets a < m < b with values fa, fm, fb (arrays of one shape; ``at``
    gives the values at new points), each stopping where ``finished``, where its vertex
    moves by at most ``xtol``, or where its values change by at most FLAT times ``scale``
    (a flat extremum: the value is exact, its time at round-off)."""
    best_t, best_f = np.array(m, dtype=float), np.array(fm, dtype=float)
    for _ in range(MAX_ITERATIONS):
        u = _vertex(a, m, b, fa, fm, fb)
        fu = at(u)
        better = fu > best_f
        best_t, best_f = np.where(better, u, best_t), np.where(better, fu, best_f)
        finished = finished | (np.abs(u - m) <= xtol) | (np.abs(fu - fm) <= FLAT * scale)
        a, m, b, fa, fm, fb = _narrow(a, m, b, fa, fm, fb, u, fu)
        if np.all(finished | (b - a <= xtol)):
            break
    return best_t, best_f


def first_best(f: np.ndarray, t: np.ndarray, scale, tie: float = TIE) -> np.ndarray:
    """Per row of ``f`` (V, C), the index of its largest value, the first in time (``t``) of
    those within ``tie`` times ``scale`` of it (equal extremes: argmax is the first)."""
    tied = f >= f.max(axis=1, keepdims=True) - tie * scale
    return np.argmin(np.where(tied, t, np.inf), axis=1)


def _candidates(y: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(V, C) each: the indices of each row's highest local maxima (the run's ends
    included), the best first, the best repeated where a row has fewer; and which need no
    refining. Only a peak that could reach the best is refined: its sample plus twice the
    larger difference to its neighbours (what a smooth curve can rise between samples) is
    at least the best sample. An end whose samples' parabola is highest outside the last
    interval is the extremum itself."""
    V, K = y.shape
    left = np.concatenate((np.full((V, 1), -np.inf), y[:, :-1]), axis=1)
    right = np.concatenate((y[:, 1:], np.full((V, 1), -np.inf)), axis=1)
    with np.errstate(invalid="ignore"):
        rise = 2 * np.fmax(np.abs(y - left), np.abs(right - y))
    reach = np.where(np.isfinite(rise), y + rise, y)
    score = np.where((y >= left) & (y >= right)
                     & (reach >= y.max(axis=1, keepdims=True)), y, -np.inf)
    order = np.argsort(-score, axis=1, kind="stable")[:, :CANDIDATES]
    best = np.take_along_axis(score, order, axis=1)
    k = np.where(np.isfinite(best), order, order[:, :1])
    done = ~np.isfinite(best)
    if K >= 3:  # the ends: the three samples' parabola peaks beyond the end interval
        rows = np.arange(V)[:, None]
        for end, (i0, i1, i2) in ((0, (0, 1, 2)), (K - 1, (K - 1, K - 2, K - 3))):
            u = _vertex(t[i0], t[i1], t[i2], y[rows, i0], y[rows, i1], y[rows, i2],
                        guarded=False)
            outside = ~((np.minimum(t[i0], t[i1]) < u) & (u < np.maximum(t[i0], t[i1])))
            done |= (k == end) & outside
    return k, done


def _vertex(a, m, b, fa, fm, fb, guarded: bool = True) -> np.ndarray:
    """The parabola's vertex through the three points; ``guarded``, a golden-section point
    into the larger half where the vertex is not strictly inside the bracket (a, b)."""
    with np.errstate(all="ignore"):
        p = (m - a) ** 2 * (fm - fb) - (m - b) ** 2 * (fm - fa)
        q = (m - a) * (fm - fb) - (m - b) * (fm - fa)
        u = m - 0.5 * p / q
    if not guarded:
        return u
    golden = np.where(b - m > m - a, m + _GOLD * (b - m), m - _GOLD * (m - a))
    tiny = 1e-3 * (b - a)
    ok = np.isfinite(u) & (u > a + tiny) & (u < b - tiny) & (np.abs(u - m) > 0)
    return np.where(ok, u, golden)


def _narrow(a, m, b, fa, fm, fb, u, fu):
    """The bracket after E(u): the best point in the middle, the others the ends."""
    up = fu >= fm
    left = u < m
    na = np.where(up, np.where(left, a, m), np.where(left, u, a))
    nb = np.where(up, np.where(left, m, b), np.where(left, b, u))
    nfa = np.where(up, np.where(left, fa, fm), np.where(left, fu, fa))
    nfb = np.where(up, np.where(left, fm, fb), np.where(left, fb, fu))
    nm = np.where(up, u, m)
    nfm = np.where(up, fu, fm)
    return na, nm, nb, nfa, nfm, nfb
