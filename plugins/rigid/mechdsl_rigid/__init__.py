"""The rigid joint: two bodies welded together (Haug's 'rigid' and Nikravesh's 'weld').

``rigid(body1, body2, at = (x, y), angle = a)``: body 2's frame sits at ``at`` in body 1's
frame, turned by ``a``::

    Phi   = [ r_2 - r_1 - A_1 at ;  phi_2 - phi_1 - a ]               (3 equations)

mechdsl derives the rest from Phi; for reference, it is::

    dPhi/dq_1 = [ -I, -perp(A_1 at) ; 0, 0, -1 ]
    dPhi/dq_2 = [  I,  0            ; 0, 0,  1 ]
    gamma = [ -A_1 at phid_1^2 ; 0 ]
"""

from __future__ import annotations

from mechdsl.plugins import Arg, ConstraintType, hookimpl

#: The plugin contract this module is written for (mechdsl.plugins.version)
MECHDSL_CONTRACT = 2


class Rigid(ConstraintType):
    name = "rigid"
    kind = "joint"
    signature = (
        Arg("body1", "body"),
        Arg("body2", "body"),
        Arg("at", "vector", (0.0, 0.0), doc="body 2's origin in body 1's frame"),
        Arg("angle", "scalar", 0.0, doc="body 2's rotation relative to body 1 (rad)"),
    )
    n_eq = 3
    doc = "weld: body 2 keeps a fixed pose in body 1's frame"

    def equations(self, bodies, args):
        b1, b2 = bodies
        r = b2.r - b1.r - b1.rotate(args.at)
        return r.x, r.y, b2.phi - b1.phi - args.angle


@hookimpl
def mechdsl_constraint_types():
    return [Rigid()]
