"""Reductions over the last (coordinate) axis of a batch of states, fast for short axes.

numpy reduces a short inner axis (the nine coordinates of a slider-crank, over a million
states of a sweep) element by element, several times slower than it combines whole
columns: these functions loop over the columns instead, each step one elementwise
operation on (V, b) arrays. Results are numpy's: NaN propagates through the maxima.
"""

from __future__ import annotations

import numpy as np

#: Up to this many entries in the last axis, the columns are combined one by one.
SHORT = 32


def _entry_major(x: np.ndarray) -> bool:
    """Whether the last axis is the slowest in memory (a view of an array whose coordinates
    come first, as the batched Newton keeps them)."""
    return x.ndim > 1 and x.size > 0 and x.strides[-1] == max(map(abs, x.strides))


def absmax(x: np.ndarray) -> np.ndarray:
    """max |x| over the last axis (NaN where a value is NaN)."""
    if x.shape[-1] > SHORT or x.shape[-1] == 0:
        return np.abs(x).max(axis=-1)
    if _entry_major(x):
        # entry-major underneath (the batched Newton's arrays): whole rows, one reduction
        return np.abs(x.T).max(axis=0).T
    out = np.abs(x[..., 0])
    for i in range(1, x.shape[-1]):
        np.maximum(out, np.abs(x[..., i]), out=out)
    return out


def allfinite(x: np.ndarray) -> np.ndarray:
    """Whether every value along the last axis is a finite number."""
    if x.shape[-1] > SHORT or x.shape[-1] == 0:
        return np.isfinite(x).all(axis=-1)
    if _entry_major(x):
        return np.isfinite(x.T).all(axis=0).T
    out = np.isfinite(x[..., 0])
    for i in range(1, x.shape[-1]):
        out &= np.isfinite(x[..., i])
    return out
