"""The prismatic (translational) joint (Haug 3.3.2, with the axis given as a vector).

``prismatic(P1, P2, axis = v, angle = a)``: point P2 (s'_2 on body 2) stays on the line through
P1 (s'_1 on body 1) along v, fixed in body 1; the relative rotation phi_2 - phi_1 stays a.
With u = perp(v / |v|) the unit normal in body 1, n = A_1 u and
d = r_2 + A_2 s'_2 - r_1 - A_1 s'_1::

    Phi_1 = n . d
    Phi_2 = phi_2 - phi_1 - a
    dPhi_1/dq_1 = [ -n^T,  perp(n) . d - n . perp(A_1 s'_1) ]
    dPhi_1/dq_2 = [  n^T,  n . perp(A_2 s'_2) ]
    gamma_1 = (n . d) phid_1^2 - 2 phid_1 perp(n) . dd + n . (A_2 s'_2 phid_2^2 - A_1 s'_1 phid_1^2)
    gamma_2 = 0
with dd = rd_2 + perp(A_2 s'_2) phid_2 - rd_1 - perp(A_1 s'_1) phid_1.
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ArgError, ConstraintType, hookimpl
from mechdsl.plugins.geometry import block, dot, perp, rotate


def _normal(v: np.ndarray) -> np.ndarray:
    return perp(v / np.linalg.norm(v, axis=-1, keepdims=True))


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
        if np.any(np.linalg.norm(p["axis"], axis=-1) == 0):
            raise ArgError("axis", "the axis of a prismatic joint must not be the zero vector")

    def _parts(self, q, p):
        q1, q2 = q
        as1 = rotate(q1[..., 2], p["p1"])
        as2 = rotate(q2[..., 2], p["p2"])
        n = rotate(q1[..., 2], _normal(p["axis"]))
        d = q2[..., :2] + as2 - q1[..., :2] - as1
        return as1, as2, n, d

    def phi(self, q, p):
        q1, q2 = q
        _, _, n, d = self._parts(q, p)
        rel = q2[..., 2] - q1[..., 2] - p["angle"]
        return np.stack(np.broadcast_arrays(dot(n, d), rel), axis=-1)

    def jacobian(self, q, p):
        as1, as2, n, d = np.broadcast_arrays(*self._parts(q, p))
        zeros = np.zeros_like(n)
        one = np.ones(n.shape[:-1])
        dr1 = np.stack((-n, zeros), axis=-2)
        dr2 = np.stack((n, zeros), axis=-2)
        dphi1 = np.stack((dot(perp(n), d) - dot(n, perp(as1)), -one), axis=-1)
        dphi2 = np.stack((dot(n, perp(as2)), one), axis=-1)
        return block(dr1, dphi1), block(dr2, dphi2)

    def gamma(self, q, qd, p):
        as1, as2, n, d = self._parts(q, p)
        qd1, qd2 = qd
        w1, w2 = qd1[..., 2], qd2[..., 2]
        dd = qd2[..., :2] + perp(as2) * w2[..., None] - qd1[..., :2] - perp(as1) * w1[..., None]
        g1 = (dot(n, d) * w1**2 - 2 * w1 * dot(perp(n), dd)
              + dot(n, as2 * (w2**2)[..., None] - as1 * (w1**2)[..., None]))
        return np.stack((g1, np.zeros_like(g1)), axis=-1)


@hookimpl
def mechdsl_constraint_types():
    return [Prismatic()]
