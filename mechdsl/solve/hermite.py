"""Quintic Hermite interpolation of solved states: the predictor of the parallel-in-time march.

Between two states at t_a and t_b = t_a + h, each with q, qd and qdd, the quintic
p(t_a + s h) = q_a H0 + h qd_a H1 + h^2 qdd_a H2 + q_b H3 + h qd_b H4 + h^2 qdd_b H5
matches all six values; its error is h^6 max|q^(6)| / 46080 (at s = 1/2), so that on a smooth
motion a state interpolated between states a few steps apart is already converged to
Newton's tolerance, or nearly.
"""

from __future__ import annotations

import numpy as np


def basis(s):
    """The quintic Hermite basis (H0 .. H5) at s = (t - t_a) / h, in Horner form:
    H3 = s^3 (10 - 15 s + 6 s^2), H0 = 1 - H3, and so on. Valid beyond [0, 1] too (an
    extrapolation from the last two states)."""
    s2 = s * s
    s3 = s2 * s
    h3 = s3 * (10.0 + s * (-15.0 + 6.0 * s))
    return (1.0 - h3, s + s3 * (-6.0 + s * (8.0 - 3.0 * s)),
            0.5 * (s2 + s3 * (-3.0 + s * (3.0 - s))), h3,
            s3 * (-4.0 + s * (7.0 - 3.0 * s)), 0.5 * s3 * (1.0 + s * (-2.0 + s)))


def quintic_hermite(tn: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                    t: np.ndarray) -> np.ndarray:
    """Interpolate the states ``q, qd, qdd`` (V, N, n) at increasing node times ``tn`` (N,)
    to the times ``t`` (b,) in [tn[0], tn[-1]]: returns (V, b, n)."""
    i = np.clip(np.searchsorted(tn, t, side="right") - 1, 0, len(tn) - 2)
    h = tn[i + 1] - tn[i]
    h0, h1, h2, h3, h4, h5 = basis(((t - tn[i]) / h)[None, :, None])
    h = h[None, :, None]
    return (q[:, i] * h0 + q[:, i + 1] * h3
            + h * (qd[:, i] * h1 + qd[:, i + 1] * h4)
            + h * h * (qdd[:, i] * h2 + qdd[:, i + 1] * h5))
