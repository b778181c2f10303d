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


#: c3, c4, c5 of the expansion below from (D, A, B, E, F)
_HIGH = np.array([[10.0, -6.0, -4.0, -1.5, 0.5], [-15.0, 8.0, 7.0, 1.5, -1.0],
                  [6.0, -3.0, -3.0, -0.5, 0.5]])
_HIGH.flags.writeable = False


def quintic_hermite(tn: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                    t: np.ndarray) -> np.ndarray:
    """Interpolate the states ``q, qd, qdd`` (V, N, n) at increasing node times ``tn`` (N,)
    to the increasing times ``t`` (b,) in [tn[0], tn[-1]]: returns (V, b, n).

    Each gap's quintic is expanded in powers of s once, p = c0 + c1 s + ... + c5 s^5 with
    (D = q_b - q_a, A = h qd_a, B = h qd_b, E = h^2 qdd_a, F = h^2 qdd_b)

        c0 = q_a,  c1 = A,  c2 = E / 2,
        c3 = 10 D - 6 A - 4 B - 3/2 E + F / 2,
        c4 = -15 D + 8 A + 7 B + 3/2 E - F,
        c5 = 6 D - 3 A - 3 B - E / 2 + F / 2

    (the basis above collected by powers), and the instants take their gap's coefficients in
    one matrix product per gap: [1, s, .., s^5] of its instants times its coefficients,
    written in the layout the batched Newton works in (:func:`mechdsl.solve.batch.settle`):
    coordinates, instants, variants. The result is a (V, b, n) view of that (n, b, V)
    array."""
    V, n = q.shape[0], q.shape[2]
    if len(t) == 0:
        return np.empty((n, 0, V)).T
    i = np.clip(np.searchsorted(tn, t, side="right") - 1, 0, len(tn) - 2)
    if len(i) > 1 and (np.diff(i) < 0).any():
        raise ValueError("quintic_hermite: the times must increase")
    # only the gaps the instants fall in (a batch of a long run spans a few of many)
    lo, hi = int(i[0]), int(i[-1]) + 2
    tn, i = tn[lo:hi], i - lo
    h = np.diff(tn)[:, None, None]  # (gaps, 1, 1)

    def ends(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nodes' values at the start and at the end of each gap: (gaps, n, V) each."""
        return a[:, lo : hi - 1].transpose(1, 2, 0), a[:, lo + 1 : hi].transpose(1, 2, 0)

    (qa, qb), (va, vb), (aa, ab) = ends(q), ends(qd), ends(qdd)
    gaps = qa.shape[0]
    # [c0 .. c5] = [q_a, A, E / 2, HIGH (D, A, B, E, F)]: the last three by one product
    data = np.stack((qb - qa, h * va, h * vb, h * h * aa, h * h * ab)).reshape(5, -1)
    coef = np.empty((6, gaps * n * V))
    coef[0] = qa.reshape(-1)
    coef[1] = data[1]
    np.multiply(data[3], 0.5, out=coef[2])
    np.matmul(_HIGH, data, out=coef[3:])
    coef = coef.reshape(6, gaps, n * V).transpose(1, 0, 2)
    s = (t - tn[i]) / (tn[i + 1] - tn[i])
    powers = s[:, None] ** np.arange(6)  # (b, 6)
    out = np.empty((n, len(t), V))
    # the instants of each gap: i does not decrease along t
    cuts = [0, *(np.flatnonzero(np.diff(i)) + 1).tolist(), len(t)]
    for j0, j1 in zip(cuts[:-1], cuts[1:]):
        values = powers[j0:j1] @ coef[int(i[j0])]  # (instants, n V)
        out[:, j0:j1] = values.reshape(j1 - j0, n, V).transpose(1, 0, 2)
    return out.T
