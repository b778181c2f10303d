"""Planar kinematics helpers for plugin authors, all broadcasting over leading batch axes.

Haug's notation: a body's pose is q = (x, y, phi), its rotation matrix A(phi) = [[c, -s],
[s, c]], and B(phi) = dA/dphi = [[-s, -c], [c, -s]] = R A with R the rotation by +90 degrees,
so that B s = perp(A s) and dA/dt s = perp(A s) phid.
"""

from __future__ import annotations

import numpy as np


def rotate(phi: np.ndarray, s: np.ndarray) -> np.ndarray:
    """A(phi) s for angles ``(...)`` and vectors ``(..., 2)``; returns ``(..., 2)``."""
    c, sn = np.cos(phi), np.sin(phi)
    sx, sy = s[..., 0], s[..., 1]
    return np.stack(np.broadcast_arrays(c * sx - sn * sy, sn * sx + c * sy), axis=-1)


def perp(v: np.ndarray) -> np.ndarray:
    """R v = (-v_y, v_x): ``v`` turned by +90 degrees."""
    return np.stack((-v[..., 1], v[..., 0]), axis=-1)


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a . b over the last axis."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def position(q: np.ndarray, s: np.ndarray) -> np.ndarray:
    """r^P = r + A(phi) s': the global position of the body point ``s`` (Haug eq. 2.6.4)."""
    return q[..., :2] + rotate(q[..., 2], s)


def block(d_r: np.ndarray, d_phi: np.ndarray) -> np.ndarray:
    """A Jacobian block ``(..., n_eq, 3)`` from dPhi/dr ``(..., n_eq, 2)`` and dPhi/dphi
    ``(..., n_eq)``."""
    d_r, d_phi = np.broadcast_arrays(d_r, d_phi[..., None])
    return np.concatenate((d_r, d_phi[..., :1]), axis=-1)


def batch_shape(*arrays: np.ndarray, core: tuple[int, ...] = ()) -> tuple[int, ...]:
    """The broadcast batch shape of ``arrays``, each with its ``core`` trailing dims stripped.

    ``core`` gives the number of trailing axes that are not batch axes, per array.
    """
    shapes = [np.shape(a)[: np.ndim(a) - k] for a, k in zip(arrays, core)]
    return np.broadcast_shapes(*shapes)
