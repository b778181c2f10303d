"""The rigid joint: two bodies welded together (Haug's 'rigid' and Nikravesh's 'weld').

``rigid(body1, body2, at = (x, y), angle = a)``: body 2's frame sits at ``at`` in body 1's
frame, turned by ``a``. With a = A_1 at::

    Phi   = [ r_2 - r_1 - A_1 at ;  phi_2 - phi_1 - a ]               (3 equations)
    dPhi/dq_1 = [ -I, -perp(A_1 at) ; 0, 0, -1 ]
    dPhi/dq_2 = [  I,  0            ; 0, 0,  1 ]
    gamma = [ -A_1 at phid_1^2 ; 0 ]
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ConstraintType, hookimpl
from mechdsl.plugins.geometry import perp, rotate


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

    def phi(self, q, p):
        q1, q2 = q
        r = q2[..., :2] - q1[..., :2] - rotate(q1[..., 2], p["at"])
        turn = q2[..., 2] - q1[..., 2] - p["angle"]
        shape = np.broadcast_shapes(r.shape[:-1], turn.shape)
        return np.concatenate((np.broadcast_to(r, shape + (2,)),
                               np.broadcast_to(turn, shape)[..., None]), axis=-1)

    def jacobian(self, q, p):
        q1, q2 = q
        ba = perp(rotate(q1[..., 2], p["at"]))
        shape = np.broadcast_shapes(ba.shape[:-1], q2.shape[:-1], np.shape(p["angle"]))
        j1 = np.zeros(shape + (3, 3))
        j1[..., 0, 0] = j1[..., 1, 1] = j1[..., 2, 2] = -1.0
        j1[..., :2, 2] = -ba
        j2 = np.zeros(shape + (3, 3))
        j2[..., 0, 0] = j2[..., 1, 1] = j2[..., 2, 2] = 1.0
        return j1, j2

    def gamma(self, q, qd, p):
        q1, q2 = q
        w1 = qd[0][..., 2]
        g = -rotate(q1[..., 2], p["at"]) * (w1**2)[..., None]
        shape = np.broadcast_shapes(g.shape[:-1], q2.shape[:-1], qd[1].shape[:-1],
                                    np.shape(p["angle"]))
        out = np.zeros(shape + (3,))
        out[..., :2] = g
        return out


@hookimpl
def mechdsl_constraint_types():
    return [Rigid()]
