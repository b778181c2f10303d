"""Line joints: a point of one body on a line fixed in another (Haug 3.3.2 and 3.4).

With P1 = s'_1 on body 1, P2 = s'_2 on body 2, the unit normal u = perp(v / |v|) of the line
direction v (in body 1's frame), n = A_1 u and d = r_2 + A_2 s'_2 - r_1 - A_1 s'_1:

``pin_slot(P1, P2, axis = v)`` -- revolute-translational composite, 1 equation::

    Phi   = n . d
    dPhi/dq_1 = [ -n^T,  perp(n) . d - n . perp(A_1 s'_1) ]
    dPhi/dq_2 = [  n^T,  n . perp(A_2 s'_2) ]
    gamma = (n . d) phid_1^2 - 2 phid_1 perp(n) . dd + n . (A_2 s'_2 phid_2^2 - A_1 s'_1 phid_1^2)

with dd = rd_2 + perp(A_2 s'_2) phid_2 - rd_1 - perp(A_1 s'_1) phid_1.

``prismatic(P1, P2, axis = v, angle = a)`` -- translational joint, 2 equations: the same, and
phi_2 - phi_1 - a = 0 (Jacobian [0, 0, -1 | 0, 0, 1], gamma 0).
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ArgError, ConstraintType, hookimpl
from mechdsl.plugins.geometry import block, dot, perp, rotate


def _check_axis(p) -> None:
    if np.any(np.linalg.norm(p["axis"], axis=-1) == 0):
        raise ArgError("axis", "the axis must not be the zero vector")


def _frame(q, p):
    """A_1 s'_1, A_2 s'_2, the line's normal n = A_1 u and d = r^P2 - r^P1."""
    q1, q2 = q
    axis = p["axis"]
    as1 = rotate(q1[..., 2], p["p1"])
    as2 = rotate(q2[..., 2], p["p2"])
    n = rotate(q1[..., 2], perp(axis) / np.sqrt(dot(axis, axis))[..., None])
    d = q2[..., :2] + as2 - q1[..., :2] - as1
    return as1, as2, n, d


def _phi(q, p):
    _, _, n, d = _frame(q, p)
    return dot(n, d)


def _jacobian(q, p):
    as1, as2, n, d = _frame(q, p)
    # dn/dphi_1 = perp(n), d(A_1 s'_1)/dphi_1 = perp(A_1 s'_1)
    return (block(-n[..., None, :], (dot(perp(n), d) - dot(n, perp(as1)))[..., None]),
            block(n[..., None, :], dot(n, perp(as2))[..., None]))


def _gamma(q, qd, p):
    as1, as2, n, d = _frame(q, p)
    qd1, qd2 = qd
    w1, w2 = qd1[..., 2:3], qd2[..., 2:3]
    dd = qd2[..., :2] + perp(as2) * w2 - qd1[..., :2] - perp(as1) * w1
    w1 = w1[..., 0]
    return (dot(n, d) * w1**2 - 2 * w1 * dot(perp(n), dd)
            + dot(n, as2 * w2**2 - as1 * (w1**2)[..., None]))


class PinSlot(ConstraintType):
    name = "pin_slot"
    kind = "joint"
    signature = (
        Arg("p1", "point", doc="a point on the slot's centre line, on the first body"),
        Arg("p2", "point", doc="the pin, on the second body"),
        Arg("axis", "vector", (1.0, 0.0), doc="the slot's direction, in the first body's frame"),
    )
    n_eq = 1
    doc = "pin in a straight slot: P2 stays on the line through P1 along axis"

    def validate(self, p):
        _check_axis(p)

    def phi(self, q, p):
        return _phi(q, p)[..., None]

    def jacobian(self, q, p):
        return _jacobian(q, p)

    def gamma(self, q, qd, p):
        return _gamma(q, qd, p)[..., None]


class Prismatic(ConstraintType):
    name = "prismatic"
    kind = "joint"
    signature = (
        Arg("p1", "point", doc="a point on the slide line, on the first body"),
        Arg("p2", "point", doc="the point of the second body that slides along the line"),
        Arg("axis", "vector", (1.0, 0.0), doc="direction of the line, in the first body's frame"),
        Arg("angle", "scalar", 0.0, doc="the fixed relative rotation phi2 - phi1 (rad)"),
    )
    n_eq = 2
    doc = "slider: P2 moves along a line through P1 without relative rotation"

    def validate(self, p):
        _check_axis(p)

    def phi(self, q, p):
        on_line = _phi(q, p)
        rel = q[1][..., 2] - q[0][..., 2] - p["angle"]
        out = np.empty(np.broadcast_shapes(on_line.shape, rel.shape) + (2,))
        out[..., 0], out[..., 1] = on_line, rel
        return out

    def jacobian(self, q, p):
        b1, b2 = _jacobian(q, p)
        j1 = np.zeros(np.broadcast_shapes(b1.shape[:-2], b2.shape[:-2]) + (2, 3))
        j2 = np.zeros_like(j1)
        j1[..., :1, :], j2[..., :1, :] = b1, b2
        j1[..., 1, 2], j2[..., 1, 2] = -1.0, 1.0  # d(phi_2 - phi_1)
        return j1, j2

    def gamma(self, q, qd, p):
        g = _gamma(q, qd, p)
        out = np.zeros(g.shape + (2,))
        out[..., 0] = g
        return out


@hookimpl
def mechdsl_constraint_types():
    return [Prismatic(), PinSlot()]
