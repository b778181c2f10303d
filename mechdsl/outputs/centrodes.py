"""Centrodes: the paths of the instant centre of one body relative to another, drawn as traces
(``trace ic(coupler, ground)``).

The instant centre I_AB of body A relative to body B is the point where a point of A and a
point of B have the same velocity (Haug eq. 2.6.5, v^P = v + omega perp(r^P - r) with
perp(x, y) = (-y, x)):

    v_A + omega_A perp(r^I - r_A) = v_B + omega_B perp(r^I - r_B)

so that (omega_A - omega_B) perp(r^I) = c with c = v_B - v_A + omega_A perp(r_A) -
omega_B perp(r_B), and r^I = (c_y, -c_x) / (omega_A - omega_B): the formula of the
``ic_x``/``ic_y`` outputs. Its path in B's frame, s'_B = A(phi_B)^T (r^I - r_B), is the
fixed centrode; in A's frame the moving centrode, which rolls without slipping on the fixed
one and touches it at I_AB. Where omega_A = omega_B the centre is at infinity (A translates
relative to B); where omega_A - omega_B changes sign between two instants it has passed
through infinity, and the curve is broken there (a NaN row) instead of drawn across.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Centrode:
    """The centrodes of body ``a`` relative to body ``b`` over a run (the ground is the body
    index past the last): ``fixed`` (V, M, 2) in b's frame, ``moving`` (V, M, 2) in a's, each
    NaN where the curve breaks (M >= K: a break adds a row); ``centre`` (V, K, 2) the instant
    centre in world coordinates at every instant; ``pose_a``, ``pose_b`` (V, K, 3) the two
    frames' (x, y, phi), zero for the ground."""

    label: str
    a: int
    b: int
    fixed: np.ndarray
    moving: np.ndarray
    centre: np.ndarray
    pose_a: np.ndarray
    pose_b: np.ndarray

    def at(self, v: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Both centrodes of variant v in world coordinates at instant k (M, 2) each: the
        fixed one carried by b's pose, the moving one by a's."""
        return _to_world(self.pose_b[v, k], self.fixed[v]), _to_world(self.pose_a[v, k],
                                                                       self.moving[v])


def _to_world(pose: np.ndarray, local: np.ndarray) -> np.ndarray:
    """r + A(phi) s' for points ``local`` (M, 2) of a frame with pose (x, y, phi)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return pose[:2] + local @ np.array([[c, s], [-s, c]])


def _body(arr: np.ndarray, i: int) -> np.ndarray:
    """Body i's columns of poses (V, K, bodies, 3) or rates; zeros for the ground (i past
    the last body)."""
    if i >= arr.shape[2]:
        return np.zeros(arr.shape[:2] + (3,))
    return arr[:, :, i]


def instant_centre(poses: np.ndarray, rates: np.ndarray, a: int, b: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The instant centre r^I of body a relative to body b at every instant (V, K, 2) (NaN
    where omega_a = omega_b), and omega_a - omega_b (V, K), from poses (V, K, bodies, 3) and
    rates (V, K, 2, bodies, 3) (velocities first)."""
    qa, qb = _body(poses, a), _body(poses, b)
    va, vb = _body(rates[:, :, 0], a), _body(rates[:, :, 0], b)
    dw = va[..., 2] - vb[..., 2]
    cx = vb[..., 0] - va[..., 0] - va[..., 2] * qa[..., 1] + vb[..., 2] * qb[..., 1]
    cy = vb[..., 1] - va[..., 1] + va[..., 2] * qa[..., 0] - vb[..., 2] * qb[..., 0]
    # a relative rotation below round-off of the run's rates is none (a body that only
    # translates: its omega is 1e-14, not 0): the centre is at infinity there, not 1e17 away
    with np.errstate(invalid="ignore"):
        w = np.nanmax(np.abs(np.stack((va[..., 2], vb[..., 2]))), axis=(0, 2), initial=0.0)
        v = np.nanmax(np.abs(np.concatenate((va[..., :2], vb[..., :2]), axis=-1)),
                      axis=(1, 2), initial=0.0)
        xy = poses[..., :2]
        size = np.nanmax(np.nanmax(xy, axis=(1, 2)) - np.nanmin(xy, axis=(1, 2)), axis=-1,
                         initial=0.0) if np.isfinite(xy).any() else np.zeros(len(w))
    tol = 1e-9 * np.maximum(w, v / np.where(size > 0, size, 1.0))
    dw = np.where(np.abs(dw) > tol[:, None], dw, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.stack((cy / dw, -cx / dw), axis=-1)
    r[~np.isfinite(r).all(axis=-1)] = np.nan
    return r, dw


def _local(r: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """A(phi)^T (r - r_F): points r (V, K, 2) in the frame of poses (V, K, 3)."""
    d = r - pose[..., :2]
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    return np.stack((c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]), axis=-1)


def _broken(curve: np.ndarray, cuts: np.ndarray) -> np.ndarray:
    """``curve`` (V, K, 2) with a NaN row after each instant k where ``cuts[v, k]`` (the
    curve passes through infinity between k and k + 1), padded with NaN to one length."""
    rows = []
    for v in range(curve.shape[0]):
        at = np.flatnonzero(cuts[v]) + 1
        rows.append(np.insert(curve[v], at, np.nan, axis=0))
    m = max(len(r) for r in rows)
    out = np.full((curve.shape[0], m, 2), np.nan)
    for v, r in enumerate(rows):
        out[v, : len(r)] = r
    return out


def pieces(curve: np.ndarray) -> list[np.ndarray]:
    """The runs of finite points of a curve (M, 2), of two points or more: its pieces between
    the breaks (NaN rows)."""
    good = np.isfinite(curve).all(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], good.astype(int), [0]))))
    return [curve[i:j] for i, j in zip(edges[::2], edges[1::2]) if j - i >= 2]


def within_reach(lo: np.ndarray, hi: np.ndarray, centres: list[np.ndarray]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The box (lo, hi) of a drawing grown to take in the instant centres ``centres`` (any
    shape ending in 2) that lie within the box's size of it: a centre far away (at infinity
    while a body translates) would leave the mechanism a dot."""
    if not centres:
        return lo, hi
    reach = max(float((hi - lo).max()), 1e-9)
    ic = np.concatenate([c.reshape(-1, 2) for c in centres])
    ic = ic[(np.isfinite(ic) & (ic >= lo - reach) & (ic <= hi + reach)).all(axis=1)]
    return (np.minimum(lo, ic.min(axis=0, initial=np.inf)),
            np.maximum(hi, ic.max(axis=0, initial=-np.inf)))


def centrodes(poses: np.ndarray, rates: np.ndarray, sketch_centrodes) -> list[Centrode]:
    """Every ``trace ic(A, B)`` of a sketch ((label, a, b) each) over a run with poses
    (V, K, bodies, 3) and rates (V, K, 2, bodies, 3)."""
    out = []
    for label, a, b in sketch_centrodes:
        r, dw = instant_centre(poses, rates, a, b)
        with np.errstate(invalid="ignore"):
            cuts = np.zeros(dw.shape, dtype=bool)
            cuts[:, :-1] = dw[:, :-1] * dw[:, 1:] < 0
        pa, pb = _body(poses, a), _body(poses, b)
        out.append(Centrode(label, a, b, _broken(_local(r, pb), cuts),
                            _broken(_local(r, pa), cuts), r, pa, pb))
    return out
