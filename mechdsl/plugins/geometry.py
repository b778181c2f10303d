"""Planar kinematics helpers for plugin authors, all broadcasting over leading batch axes.

Haug's notation: a body's pose is q = (x, y, phi), its rotation matrix A(phi) = [[c, -s],
[s, c]], and B(phi) = dA/dphi = [[-s, -c], [c, -s]] = R A with R the rotation by +90 degrees,
so that B s = perp(A s) and dA/dt s = perp(A s) phid.
"""

from __future__ import annotations

import numpy as np

_PERP_SIGNS = np.array([-1.0, 1.0])
_PERP_SIGNS.flags.writeable = False


def rotate(phi: np.ndarray, s: np.ndarray) -> np.ndarray:
    """A(phi) s = cos(phi) s + sin(phi) perp(s) for angles ``(...)`` and vectors ``(..., 2)``;
    returns ``(..., 2)``."""
    phi = np.asarray(phi)[..., None]
    # written with whole-vector products (no stacking): the solver calls this on tiny
    # batches where per-call overhead, not arithmetic, is the cost
    return np.cos(phi) * s + np.sin(phi) * perp(s)


def perp(v: np.ndarray) -> np.ndarray:
    """R v = (-v_y, v_x): ``v`` turned by +90 degrees."""
    return np.asarray(v)[..., ::-1] * _PERP_SIGNS


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a . b over the last axis."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def position(q: np.ndarray, s: np.ndarray) -> np.ndarray:
    """r^P = r + A(phi) s': the global position of the body point ``s`` (Haug eq. 2.6.4)."""
    return q[..., :2] + rotate(q[..., 2], s)


def block(d_r: np.ndarray, d_phi: np.ndarray) -> np.ndarray:
    """A Jacobian block ``(..., n_eq, 3)`` from dPhi/dr ``(..., n_eq, 2)`` and dPhi/dphi
    ``(..., n_eq)``."""
    d_r, d_phi = np.asarray(d_r), np.asarray(d_phi)
    out = np.empty(np.broadcast(d_r[..., 0], d_phi).shape + (3,))
    out[..., :2] = d_r
    out[..., 2] = d_phi
    return out


def batch_shape(*arrays: np.ndarray, core: tuple[int, ...] = ()) -> tuple[int, ...]:
    """The broadcast batch shape of ``arrays``, each with its ``core`` trailing dims stripped.

    ``core`` gives the number of trailing axes that are not batch axes, per array.
    """
    shapes = [np.shape(a)[: np.ndim(a) - k] for a, k in zip(arrays, core)]
    return np.broadcast_shapes(*shapes)
