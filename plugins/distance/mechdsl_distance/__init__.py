"""The distance joint: two points at a fixed distance, a massless coupler with a pin at each
end (Haug's revolute-revolute composite joint, 3.4.1).

``distance(P1, P2, length = L)`` with d = r_2 + A_2 s'_2 - r_1 - A_1 s'_1::

    Phi   = (d . d - L^2) / 2                                           (1 equation)

mechdsl derives the rest from Phi; for reference, it is::

    dPhi/dq_1 = [ -d^T, -d . perp(A_1 s'_1) ]
    dPhi/dq_2 = [  d^T,  d . perp(A_2 s'_2) ]
    gamma = -dd . dd + d . (A_2 s'_2 phid_2^2 - A_1 s'_1 phid_1^2)

with dd = rd_2 + perp(A_2 s'_2) phid_2 - rd_1 - perp(A_1 s'_1) phid_1.
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ArgError, ConstraintType, hookimpl

#: The plugin contract this module is written for (mechdsl.plugins.version)
MECHDSL_CONTRACT = 2


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

    def equations(self, bodies, args):
        b1, b2 = bodies
        d = b2.point(args.p2) - b1.point(args.p1)
        return (0.5 * (d.dot(d) - args.length**2),)


@hookimpl
def mechdsl_constraint_types():
    return [Distance()]
