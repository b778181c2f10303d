"""The revolute joint: a point of one body coincides with a point of another (Haug 3.3.1).

``revolute(P1, P2)``, with P1 = s'_i on body i and P2 = s'_j on body j::

    Phi   = r_i + A_i s'_i - r_j - A_j s'_j                              (2 equations)
    Phi_q = [ I   B_i s'_i  | -I   -B_j s'_j ]
    gamma = A_i s'_i phid_i^2 - A_j s'_j phid_j^2
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ConstraintType, hookimpl
from mechdsl.plugins.geometry import block, perp, position, rotate


class Revolute(ConstraintType):
    name = "revolute"
    kind = "joint"
    signature = (Arg("p1", "point", doc="the pin on the first body"),
                 Arg("p2", "point", doc="the hole on the second body"))
    n_eq = 2
    doc = "pin joint: the two points coincide"

    def phi(self, q, p):
        qi, qj = q
        return position(qi, p["p1"]) - position(qj, p["p2"])

    def jacobian(self, q, p):
        qi, qj = q
        # B s' = perp(A s'); broadcast so both blocks carry the full batch shape
        bsi, bsj = np.broadcast_arrays(perp(rotate(qi[..., 2], p["p1"])),
                                       perp(rotate(qj[..., 2], p["p2"])))
        eye = np.eye(2)
        return block(eye, bsi), block(-eye, -bsj)

    def gamma(self, q, qd, p):
        (qi, qj), (qdi, qdj) = q, qd
        asi = rotate(qi[..., 2], p["p1"])
        asj = rotate(qj[..., 2], p["p2"])
        return asi * qdi[..., 2:3] ** 2 - asj * qdj[..., 2:3] ** 2


@hookimpl
def mechdsl_constraint_types():
    return [Revolute()]
