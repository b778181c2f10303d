"""Per-variant reductions of a run's histories (``output peak = max(abs(slider.ax))``):
each variant's history y(t_k), k = 0 .. K-1, becomes one number, where it was solved, so that
a study of many variants keeps a row per variant instead of K.

The time averages use the trapezoidal rule on the run's instants:
mean(y) = 1/(t_K-1 - t_0) sum_k (t_k+1 - t_k) (y_k + y_k+1)/2, rms(y) = sqrt(mean(y^2)).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Mapping

import numpy as np

from ..compiled.kernels import Kernels
from ..results import Results
from .extrema import SENSES


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


def reduce_results(results: Results, kernels: Kernels,
                   extremes: Mapping[tuple[str, int], tuple[np.ndarray, np.ndarray]]
                   | None = None) -> Results:
    """``results`` with the system's reductions computed from its histories, which are
    dropped (``Results.reduced`` replaces ``Results.data``). A variant that did not solve every
    instant reduces to NaN: a peak over part of the run is not the peak of the run.

    ``extremes`` maps (column, sense) to each variant's extreme value (times sense: a
    maximum) and its time, found between the samples (:mod:`mechdsl.solve.extrema`):
    ``max``, ``min``, ``argmax``, ``argmin`` and ``range`` read them where given; the
    reductions that did are named in ``Results.refined``."""
    system = kernels.system
    if not system.reductions:
        return results
    extremes = extremes or {}
    t = results.times
    V, K = results.n_variants, len(t)
    complete = results.n_solved == K
    reduced, units, refined = {}, {}, []
    for r in system.reductions:
        env = {name: np.broadcast_to(v, (V, 1))[:, 0] for name, v in system.env.items()}
        used = False
        for name, func, label in r.parts:
            y = results.data[label]
            found = _refined(func, label, extremes)
            if found is not None:
                env[name], used = found, True
            else:
                env[name] = REDUCERS[func](y, t) if K else np.full(V, np.nan)
        with np.errstate(all="ignore"):
            computed = np.asarray(kernels.reductions[r.label](env), dtype=float)
            value = np.array(np.broadcast_to(computed, (V,)))
        value[~complete] = np.nan
        if r.scale != 1.0:  # (the columns are read in radians, the value reported in degrees)
            value *= r.scale
        reduced[r.label] = value
        if used:
            refined.append(r.label)
        if r.unit:
            units[r.label] = r.unit
    return replace(results, data={}, reduced=reduced, units=units, refined=tuple(refined))


def _refined(func: str, label: str, extremes) -> np.ndarray | None:
    """A reduction's value from the refined extremes, where they have it."""
    if func == "range":
        top, bottom = extremes.get((label, 1)), extremes.get((label, -1))
        return None if top is None or bottom is None else top[0] - bottom[0]
    found = extremes.get((label, SENSES[func][0])) if func in SENSES else None
    if found is None:
        return None
    return found[1].copy() if func.startswith("arg") else found[0].copy()
