"""Line joints: a point of one body on a line fixed in another (Haug 3.3.2 and 3.4).

With P1 = s'_1 on body 1, P2 = s'_2 on body 2, the unit normal u = perp(v / |v|) of the line
direction v (in body 1's frame), n = A_1 u and d = r_2 + A_2 s'_2 - r_1 - A_1 s'_1:

``pin_slot(P1, P2, axis = v)`` -- revolute-translational composite, 1 equation::

    Phi   = n . d

``prismatic(P1, P2, axis = v, angle = a)`` -- translational joint, 2 equations: the same, and
phi_2 - phi_1 - a = 0.

mechdsl derives the rest from Phi; for reference, the line equation's is::

    dPhi/dq_1 = [ -n^T,  perp(n) . d - n . perp(A_1 s'_1) ]
    dPhi/dq_2 = [  n^T,  n . perp(A_2 s'_2) ]
    gamma = (n . d) phid_1^2 - 2 phid_1 perp(n) . dd + n . (A_2 s'_2 phid_2^2 - A_1 s'_1 phid_1^2)

with dd = rd_2 + perp(A_2 s'_2) phid_2 - rd_1 - perp(A_1 s'_1) phid_1 (and for the angle
equation Phi_q = [0, 0, -1 | 0, 0, 1], gamma = 0).
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ArgError, ConstraintType, hookimpl

#: The plugin contract this module is written for (mechdsl.plugins.version)
MECHDSL_CONTRACT = 2


def _check_axis(p) -> None:
    if np.any(np.linalg.norm(p["axis"], axis=-1) == 0):
        raise ArgError("axis", "the axis must not be the zero vector")


def _off_line(b1, b2, args):
    """n . d: how far P2 is off the line through P1 along the axis."""
    n = b1.rotate(args.axis.perp() / args.axis.norm())
    return n.dot(b2.point(args.p2) - b1.point(args.p1))


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
    guide = ("p1", "p2", "axis")

    def validate(self, p):
        _check_axis(p)

    def equations(self, bodies, args):
        return (_off_line(*bodies, args),)


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
    guide = ("p1", "p2", "axis")

    def validate(self, p):
        _check_axis(p)

    def equations(self, bodies, args):
        b1, b2 = bodies
        return _off_line(b1, b2, args), b2.phi - b1.phi - args.angle


@hookimpl
def mechdsl_constraint_types():
    return [Prismatic(), PinSlot()]
