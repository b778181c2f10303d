"""The revolute joint: a point of one body coincides with a point of another (Haug 3.3.1).

``revolute(P1, P2)``, with P1 = s'_i on body i and P2 = s'_j on body j::

    Phi   = r_i + A_i s'_i - r_j - A_j s'_j                              (2 equations)

mechdsl derives the rest from Phi; for reference, it is
Phi_q = [ I   B_i s'_i  | -I   -B_j s'_j ] and gamma = A_i s'_i phid_i^2 - A_j s'_j phid_j^2.
"""

from __future__ import annotations

from mechdsl.plugins import Arg, ConstraintType, hookimpl

#: The plugin contract this module is written for (mechdsl.plugins.version)
MECHDSL_CONTRACT = 2


class Revolute(ConstraintType):
    name = "revolute"
    kind = "joint"
    signature = (Arg("p1", "point", doc="the pin on the first body"),
                 Arg("p2", "point", doc="the hole on the second body"))
    n_eq = 2
    doc = "pin joint: the two points coincide"

    def equations(self, bodies, args):
        i, j = bodies
        gap = i.point(args.p1) - j.point(args.p2)
        return gap.x, gap.y


@hookimpl
def mechdsl_constraint_types():
    return [Revolute()]
