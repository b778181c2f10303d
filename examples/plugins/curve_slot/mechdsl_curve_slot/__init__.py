"""A pin in a curved slot: point P2 of body 2 stays on the curve y = f(x) drawn in body 1's
frame, with its origin at point P1 of body 1.

With d = r_2 + A_2 s'_2 - r_1 - A_1 s'_1 and u = A_1^T d the pin's coordinates in the slot's
frame::

    Phi = u_y - f(u_x)

mechdsl derives the Jacobian and gamma from it, with f's exact derivatives.
"""

from mechdsl.plugins import Arg, ConstraintType, hookimpl

#: The plugin contract this module is written for (mechdsl.plugins.version)
MECHDSL_CONTRACT = 2


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

    def equations(self, bodies, args):
        b1, b2 = bodies
        u = b1.unrotate(b2.point(args.p2) - b1.point(args.p1))  # A_1^T d
        return (u.y - args.shape(u.x),)


@hookimpl
def mechdsl_constraint_types():
    return [CurveSlot()]
