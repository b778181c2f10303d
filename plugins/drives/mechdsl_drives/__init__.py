"""The basic drive types. Each computes one measure g(q); ``drive NAME: TYPE(...) = f(t)``
adds the constraint g(q) - f(t) = 0 (the core supplies f, f' and f'').

mechdsl derives the Jacobian and gamma from g (``distance`` also supplies its Jacobian, to
have one where its points coincide); for reference:

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
from mechdsl.plugins.geometry import Vec

#: The plugin contract this module is written for (mechdsl.plugins.version)
MECHDSL_CONTRACT = 2


class Angle(ConstraintType):
    name = "angle"
    kind = "drive"
    signature = (Arg("body", "body"),)
    n_eq = 1
    doc = "the rotation phi of a body (rad)"
    invariant = False

    def equations(self, bodies, args):
        return (bodies[0].phi,)


class _Coordinate(ConstraintType):
    kind = "drive"
    invariant = False
    signature = (Arg("point", "point"),)
    n_eq = 1
    axis: int

    def equations(self, bodies, args):
        return (tuple(bodies[0].point(args.point))[self.axis],)


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

    def equations(self, bodies, args):
        return (bodies[1].phi - bodies[0].phi,)


class Distance(ConstraintType):
    name = "distance"
    kind = "drive"
    signature = (Arg("p1", "point"), Arg("p2", "point"))
    n_eq = 1
    doc = "the distance between two points (must stay positive)"

    def equations(self, bodies, args):
        b1, b2 = bodies
        return ((b2.point(args.p2) - b1.point(args.p1)).norm(),)

    def jacobian_terms(self, bodies, args):
        """The derived gradient of |d|, e = d / |d|, except where the points coincide: there
        it is undefined and any unit vector is a subgradient; take (1, 0), so that an
        assembly can pull them apart (``at`` is 1 there, else 0: no branch)."""
        b1, b2 = bodies
        d = b2.point(args.p2) - b1.point(args.p1)
        length = d.norm()
        at = 1 - np.sign(length)
        e = Vec(d.x + at, d.y) / (length + at)
        return (([-e.x, -e.y, -e.dot(b1.rotate(args.p1).perp())],),
                ([e.x, e.y, e.dot(b2.rotate(args.p2).perp())],))


@hookimpl
def mechdsl_constraint_types():
    return [Angle(), X(), Y(), RelAngle(), Distance()]
