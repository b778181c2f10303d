"""The basic drive types. Each computes one measure g(q); ``drive NAME: TYPE(...) = f(t)``
adds the constraint g(q) - f(t) = 0 (the core supplies f, f' and f'').

==============================  =====================  ======================================
type                            g(q)                   gamma = -(g_q qd)_q qd
==============================  =====================  ======================================
``angle(body)``                 phi                    0
``x(body.P)``                   x + (A s')_x           (A s')_x phid^2
``y(body.P)``                   y + (A s')_y           (A s')_y phid^2
``rel_angle(body1, body2)``     phi_2 - phi_1          0
``distance(body1.P, body2.Q)``  |d|, d = r^Q - r^P     -(|dd|^2 - (e.dd)^2)/|d| + e.(A_2 s'_2 phid_2^2 - A_1 s'_1 phid_1^2)
==============================  =====================  ======================================

with e = d/|d| and dd = d(d)/dt.
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ConstraintType, hookimpl
from mechdsl.plugins.geometry import block, dot, perp, position, rotate


def _zeros(*arrays, core=1):
    shape = np.broadcast_shapes(*(a.shape[: a.ndim - core] for a in arrays))
    return np.zeros(shape)


class Angle(ConstraintType):
    name = "angle"
    kind = "drive"
    signature = (Arg("body", "body"),)
    n_eq = 1
    doc = "the rotation phi of a body (rad)"
    invariant = False

    def phi(self, q, p):
        return q[0][..., 2:3]

    def jacobian(self, q, p):
        z = _zeros(q[0])
        return (block(np.zeros(z.shape + (1, 2)), (z + 1.0)[..., None]),)

    def gamma(self, q, qd, p):
        return _zeros(q[0], qd[0])[..., None]


class _Coordinate(ConstraintType):
    kind = "drive"
    invariant = False
    signature = (Arg("point", "point"),)
    n_eq = 1
    axis: int

    def phi(self, q, p):
        return position(q[0], p["point"])[..., self.axis : self.axis + 1]

    def jacobian(self, q, p):
        bs = perp(rotate(q[0][..., 2], p["point"]))
        d_r = np.zeros(bs.shape[:-1] + (1, 2))
        d_r[..., 0, self.axis] = 1.0
        return (block(d_r, bs[..., self.axis : self.axis + 1]),)

    def gamma(self, q, qd, p):
        a_s = rotate(q[0][..., 2], p["point"])
        return a_s[..., self.axis : self.axis + 1] * qd[0][..., 2:3] ** 2


class X(_Coordinate):
    name = "x"
    axis = 0
    doc = "the global x coordinate of a point"


class Y(_Coordinate):
    name = "y"
    axis = 1
    doc = "the global y coordinate of a point"


class RelAngle(ConstraintType):
    name = "rel_angle"
    kind = "drive"
    signature = (Arg("body1", "body"), Arg("body2", "body"))
    n_eq = 1
    doc = "the relative rotation phi2 - phi1 (rad)"

    def phi(self, q, p):
        return q[1][..., 2:3] - q[0][..., 2:3]

    def jacobian(self, q, p):
        z = _zeros(q[0], q[1])
        zr = np.zeros(z.shape + (1, 2))
        return block(zr, (z - 1.0)[..., None]), block(zr, (z + 1.0)[..., None])

    def gamma(self, q, qd, p):
        return _zeros(q[0], q[1], qd[0], qd[1])[..., None]


class Distance(ConstraintType):
    name = "distance"
    kind = "drive"
    signature = (Arg("p1", "point"), Arg("p2", "point"))
    n_eq = 1
    doc = "the distance between two points (must stay positive)"

    def _d(self, q, p):
        return position(q[1], p["p2"]) - position(q[0], p["p1"])

    @staticmethod
    def _unit(d):
        """d / |d|; where the points coincide the gradient of |d| is undefined and any unit
        vector is a subgradient: take (1, 0), so that an assembly can pull them apart."""
        length = np.linalg.norm(d, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(length > 0, d / length, np.array([1.0, 0.0])), length[..., 0]

    def phi(self, q, p):
        return np.linalg.norm(self._d(q, p), axis=-1, keepdims=True)

    def jacobian(self, q, p):
        e, _ = self._unit(self._d(q, p))
        bs1 = perp(rotate(q[0][..., 2], p["p1"]))
        bs2 = perp(rotate(q[1][..., 2], p["p2"]))
        return (block(-e[..., None, :], -dot(e, bs1)[..., None]),
                block(e[..., None, :], dot(e, bs2)[..., None]))

    def gamma(self, q, qd, p):
        e, length = self._unit(self._d(q, p))
        as1 = rotate(q[0][..., 2], p["p1"])
        as2 = rotate(q[1][..., 2], p["p2"])
        w1, w2 = qd[0][..., 2:3], qd[1][..., 2:3]
        dd = qd[1][..., :2] + perp(as2) * w2 - qd[0][..., :2] - perp(as1) * w1
        g = (-(dot(dd, dd) - dot(e, dd) ** 2) / length
             + dot(e, as2 * w2**2 - as1 * w1**2))
        return g[..., None]


@hookimpl
def mechdsl_constraint_types():
    return [Angle(), X(), Y(), RelAngle(), Distance()]
