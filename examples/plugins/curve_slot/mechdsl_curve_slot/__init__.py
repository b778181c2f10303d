"""A pin in a curved slot: point P2 of body 2 stays on the curve y = f(x) drawn in body 1's
frame, with its origin at point P1 of body 1.

With d = r_2 + A_2 s'_2 - r_1 - A_1 s'_1 and u = A_1^T d the pin's coordinates in the slot's
frame, Phi = u_y - f(u_x). With G = A_1 (-f'(u_x), 1), v = dd - perp(d) phid_1 and
ud = A_1^T v::

    dPhi/dq_1 = [ -G^T, -G . perp(d + A_1 s'_1) ]
    dPhi/dq_2 = [  G^T,  G . perp(A_2 s'_2) ]
    gamma = G . (perp(v + dd) phid_1 - A_1 s'_1 phid_1^2 + A_2 s'_2 phid_2^2)
            + f''(u_x) ud_x^2
"""

import numpy as np

from mechdsl.plugins import Arg, ConstraintType, hookimpl
from mechdsl.plugins.geometry import block, dot, perp, rotate


class CurveSlot(ConstraintType):
    name = "curve_slot"
    kind = "joint"
    signature = (
        Arg("p1", "point", doc="the origin of the slot's frame, on the first body"),
        Arg("p2", "point", doc="the pin, on the second body"),
        Arg("shape", "function", var="x", doc="the slot's curve y = f(x)"),
    )
    n_eq = 1
    doc = "pin in a curved slot y = f(x) fixed in the first body"

    def _parts(self, q, p):
        q1, q2 = q
        as1 = rotate(q1[..., 2], p["p1"])
        as2 = rotate(q2[..., 2], p["p2"])
        d = q2[..., :2] + as2 - q1[..., :2] - as1
        u = rotate(-q1[..., 2], d)                      # A_1^T d
        x = u[..., 0]
        slope = p["shape"].d1(x)
        G = rotate(q1[..., 2], np.stack((-slope, np.ones_like(slope)), axis=-1))
        return as1, as2, d, u, G

    def phi(self, q, p):
        _, _, _, u, _ = self._parts(q, p)
        return (u[..., 1] - p["shape"](u[..., 0]))[..., None]

    def jacobian(self, q, p):
        as1, as2, d, _, G = self._parts(q, p)
        return (block(-G[..., None, :], -dot(G, perp(d + as1))[..., None]),
                block(G[..., None, :], dot(G, perp(as2))[..., None]))

    def gamma(self, q, qd, p):
        as1, as2, d, u, G = self._parts(q, p)
        w1, w2 = qd[0][..., 2:3], qd[1][..., 2:3]
        dd = qd[1][..., :2] + perp(as2) * w2 - qd[0][..., :2] - perp(as1) * w1
        v = dd - perp(d) * w1
        ud = rotate(-q[0][..., 2], v)
        g = (dot(G, perp(v + dd) * w1 - as1 * w1**2 + as2 * w2**2)
             + p["shape"].d2(u[..., 0]) * ud[..., 0] ** 2)
        return g[..., None]


@hookimpl
def mechdsl_constraint_types():
    return [CurveSlot()]
