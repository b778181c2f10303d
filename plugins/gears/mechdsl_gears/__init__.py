"""Gear pairs with centres that may move, and rack and pinion (after Nikravesh, Planar
Multibody Dynamics, the gear and rack-and-pinion joints).

Gears: pitch radii R_1, R_2, ratio k = R_1 / R_2, centres C_i = r_i + A_i c'_i, d = C_2 - C_1
and theta the direction of d. Rolling without slip at the pitch point gives
k (phi_1 - theta) + s (phi_2 - theta) = phase, with s = +1 for an external pair
(``gear``) and s = -1 for a pinion inside a ring (``internal_gear``). Written through the
direction the gear angles imply, psi = (k phi_1 + s phi_2 - phase) / (k + s), as

    Phi = perp(e(psi)) . d = |d| sin(theta - psi)                       (1 equation)

it stays smooth when theta turns past +-pi (a planet orbiting its sun). mechdsl derives the
rest from Phi; for reference, with m = perp(e(psi)), e = e(psi), a_1 = k / (k + s),
a_2 = s / (k + s)::

    dPhi/dq_1 = [ -m^T, -m . perp(A_1 c'_1) - a_1 e . d ]
    dPhi/dq_2 = [  m^T,  m . perp(A_2 c'_2) - a_2 e . d ]
    gamma = (m . d) psid^2 + 2 psid e . dd + m . (A_2 c'_2 phid_2^2 - A_1 c'_1 phid_1^2)

with psid = a_1 phid_1 + a_2 phid_2 and dd the time derivative of d. With fixed centres,
omega_2 = -k omega_1 (external) or +k omega_1 (internal).

Rack and pinion: the pinion's centre C (radius R) and a rack line through the rack body's
origin along the unit vector u (in the rack's frame), the pinion on the left of u::

    Phi = u_g . (C - r_rack) + R (phi_pinion - phi_rack) - phase        (1 equation)

with u_g = A_rack u: turning the pinion by +dphi moves it by -R dphi along u.
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ArgError, ConstraintType, hookimpl
from mechdsl.plugins.geometry import Vec

#: The plugin contract this module is written for (mechdsl.plugins.version)
MECHDSL_CONTRACT = 2


class _GearPair(ConstraintType):
    kind = "joint"
    n_eq = 1
    sense: float
    signature = (
        Arg("body1", "body", doc="the first gear"),
        Arg("body2", "body", doc="the second gear"),
        Arg("ratio", "scalar", doc="R1 / R2, the ratio of the pitch radii"),
        Arg("phase", "scalar", 0.0, doc="k (phi1 - theta) + s (phi2 - theta) at mesh (rad)"),
        Arg("center1", "vector", (0.0, 0.0), doc="gear 1's centre in its body's frame"),
        Arg("center2", "vector", (0.0, 0.0), doc="gear 2's centre in its body's frame"),
    )

    def validate(self, p):
        if np.any(p["ratio"] <= 0):
            raise ArgError("ratio", "the ratio of pitch radii must be positive")

    def equations(self, bodies, args):
        b1, b2 = bodies
        k, s = args.ratio, self.sense
        psi = (k * b1.phi + s * b2.phi - args.phase) / (k + s)
        m = Vec(-np.sin(psi), np.cos(psi))  # perp(e(psi))
        return (m.dot(b2.point(args.center2) - b1.point(args.center1)),)


class Gear(_GearPair):
    name = "gear"
    sense = 1.0
    doc = "external gear pair: omega2 = -ratio * omega1 about fixed centres"


class InternalGear(_GearPair):
    name = "internal_gear"
    sense = -1.0
    doc = "pinion (body1) inside a ring gear (body2): omega2 = ratio * omega1 about fixed centres"

    def validate(self, p):
        super().validate(p)
        if np.any(p["ratio"] >= 1):
            raise ArgError("ratio", "the pinion of an internal gear must be smaller than the "
                           "ring: ratio = R_pinion / R_ring < 1")


class RackPinion(ConstraintType):
    name = "rack_pinion"
    kind = "joint"
    n_eq = 1
    signature = (
        Arg("pinion", "body"),
        Arg("rack", "body"),
        Arg("radius", "scalar", doc="the pinion's pitch radius"),
        Arg("axis", "vector", (1.0, 0.0), doc="the rack's direction in its frame; the pinion "
                                              "on its left"),
        Arg("phase", "scalar", 0.0),
        Arg("center", "vector", (0.0, 0.0), doc="the pinion's centre in its body's frame"),
    )
    doc = "rack and pinion: the pinion rolls along a straight rack"

    def validate(self, p):
        if np.any(p["radius"] <= 0):
            raise ArgError("radius", "the pinion's radius must be positive")
        if np.any(np.linalg.norm(p["axis"], axis=-1) == 0):
            raise ArgError("axis", "the rack's axis must not be the zero vector")

    def equations(self, bodies, args):
        pinion, rack = bodies
        u = rack.rotate(args.axis / args.axis.norm())
        return (u.dot(pinion.point(args.center) - rack.r)
                + args.radius * (pinion.phi - rack.phi) - args.phase,)


@hookimpl
def mechdsl_constraint_types():
    return [Gear(), InternalGear(), RackPinion()]
