"""Per-variant reductions of a run's histories (``output peak = max(abs(slider.ax))``):
each variant's history y(t_k), k = 0 .. K-1, becomes one number, where it was solved, so that
a study of many variants keeps a row per variant instead of K.

The time averages use the trapezoidal rule on the run's instants:
mean(y) = 1/(t_K-1 - t_0) sum_k (t_k+1 - t_k) (y_k + y_k+1)/2, rms(y) = sqrt(mean(y^2)).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from ..compiled.system import System
from ..results import Results


def _mean(y: np.ndarray, t: np.ndarray) -> np.ndarray:
    if len(t) < 2:
        return y[:, 0].copy()
    trapezoid = getattr(np, "trapezoid", None) or np.trapz  # numpy < 2 names it trapz
    return trapezoid(y, t, axis=-1) / (t[-1] - t[0])


#: reduction name -> f(histories (V, K), times (K,)) -> (V,)
REDUCERS: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "max": lambda y, t: np.max(y, axis=-1),
    "min": lambda y, t: np.min(y, axis=-1),
    "mean": _mean,
    "rms": lambda y, t: np.sqrt(_mean(y * y, t)),
    "range": lambda y, t: np.max(y, axis=-1) - np.min(y, axis=-1),
    "initial": lambda y, t: y[:, 0].copy(),
    "final": lambda y, t: y[:, -1].copy(),
    "argmax": lambda y, t: t[np.argmax(y, axis=-1)],
    "argmin": lambda y, t: t[np.argmin(y, axis=-1)],
}


def reduce_results(results: Results, system: System) -> Results:
    """``results`` with the system's reductions computed from its histories, which are
    dropped (``Results.reduced`` replaces ``Results.data``). A variant that did not solve every
    instant reduces to NaN: a peak over part of the run is not the peak of the run."""
    if not system.reductions:
        return results
    t = results.times
    V, K = results.n_variants, len(t)
    complete = results.n_solved == K
    reduced, units = {}, {}
    for r in system.reductions:
        env = {name: np.broadcast_to(v, (V, 1))[:, 0] for name, v in system.env.items()}
        for name, func, label in r.parts:
            y = results.data[label]
            env[name] = REDUCERS[func](y, t) if K else np.full(V, np.nan)
        with np.errstate(all="ignore"):
            value = np.array(np.broadcast_to(np.asarray(r.function(env), dtype=float), (V,)))
        value[~complete] = np.nan
        reduced[r.label] = value
        if r.unit:
            units[r.label] = r.unit
    return replace(results, data={}, reduced=reduced, units=units)
