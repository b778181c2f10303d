"""The distance joint: two points at a fixed distance, a massless coupler with a pin at each
end (Haug's revolute-revolute composite joint, 3.4.1).

``distance(P1, P2, length = L)`` with d = r_2 + A_2 s'_2 - r_1 - A_1 s'_1::

    Phi   = (d . d - L^2) / 2                                           (1 equation)
    dPhi/dq_1 = [ -d^T, -d . perp(A_1 s'_1) ]
    dPhi/dq_2 = [  d^T,  d . perp(A_2 s'_2) ]
    gamma = -dd . dd + d . (A_2 s'_2 phid_2^2 - A_1 s'_1 phid_1^2)
with dd = rd_2 + perp(A_2 s'_2) phid_2 - rd_1 - perp(A_1 s'_1) phid_1.
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ArgError, ConstraintType, hookimpl
from mechdsl.plugins.geometry import block, dot, perp, rotate


class Distance(ConstraintType):
    name = "distance"
    kind = "joint"
    signature = (
        Arg("p1", "point"),
        Arg("p2", "point"),
        Arg("length", "scalar", doc="the distance between the two points"),
    )
    n_eq = 1
    doc = "massless coupler: the two points stay at the given distance"

    def validate(self, p):
        if np.any(p["length"] <= 0):
            raise ArgError("length", "the length of a distance joint must be positive")

    def _parts(self, q, p):
        as1 = rotate(q[0][..., 2], p["p1"])
        as2 = rotate(q[1][..., 2], p["p2"])
        d = q[1][..., :2] + as2 - q[0][..., :2] - as1
        return np.broadcast_arrays(as1, as2, d)

    def phi(self, q, p):
        d = self._parts(q, p)[2]
        return (0.5 * (dot(d, d) - p["length"] ** 2))[..., None]

    def jacobian(self, q, p):
        as1, as2, d = self._parts(q, p)
        return (block(-d[..., None, :], -dot(d, perp(as1))[..., None]),
                block(d[..., None, :], dot(d, perp(as2))[..., None]))

    def gamma(self, q, qd, p):
        as1, as2, d = self._parts(q, p)
        w1, w2 = qd[0][..., 2:3], qd[1][..., 2:3]
        dd = qd[1][..., :2] + perp(as2) * w2 - qd[0][..., :2] - perp(as1) * w1
        return (-dot(dd, dd) + dot(d, as2 * w2**2 - as1 * w1**2))[..., None]


@hookimpl
def mechdsl_constraint_types():
    return [Distance()]
