"""Cams, with the profile given as a function of an angle in the cam's frame, so that the
follower's motion is explicit and its derivatives exact (no contact point to solve for).

``cam_flat(cam.O, follower.F, support = p(theta), normal = (0, 1))`` -- a flat-faced
follower. F is a point of the face, n = A_f n' its unit normal (pointing away from the cam).
For a convex profile the face touches it where n . (F - O) equals the profile's support
function p in the direction of n, whose angle in the cam's frame is
theta = phi_f + angle(n') - phi_c. With d = F - O::

    Phi   = n . d - p(theta)

``cam_roller(cam.O, follower.C, pitch = rho(psi))`` -- a roller follower: its centre C stays
on the pitch curve, the profile offset by the roller's radius, given in polar form about O
in the cam's frame. With d = C - O, L = |d| and psi = angle(d) - phi_c::

    Phi   = L - rho(psi)

Both functions are evaluated at their angle wrapped into [0, 2 pi): write one turn of the
profile, closing on itself.

mechdsl derives the rest from Phi, with the functions' exact derivatives; for reference, it
is, for ``cam_flat``::

    dPhi/dq_c = [ -n^T, -n . perp(A_c s'_O) + p'(theta) ]
    dPhi/dq_f = [  n^T,  perp(n) . d + n . perp(A_f s'_F) - p'(theta) ]
    gamma = (n . d) phid_f^2 - 2 phid_f perp(n) . dd + n . (A_f s'_F phid_f^2 - A_c s'_O phid_c^2)
            + p''(theta) (phid_f - phid_c)^2

and for ``cam_roller``, with e = d / L, g = perp(d) / L^2 and w = e - rho'(psi) g::

    dPhi/dq_c = [ -w^T, -w . perp(A_c s'_O) + rho'(psi) ]
    dPhi/dq_f = [  w^T,  w . perp(A_f s'_C) ]
    gamma = w . (A_f s'_C phid_f^2 - A_c s'_O phid_c^2) - (|dd|^2 - (e . dd)^2) / L
            + rho''(psi) psid^2 - 2 rho'(psi) (perp(d) . dd)(d . dd) / L^4

with psid = g . dd - phid_c.
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ArgError, ConstraintType, hookimpl

#: The plugin contract this module is written for (mechdsl.plugins.version)
MECHDSL_CONTRACT = 2

TURN = 2 * np.pi


class CamFlat(ConstraintType):
    name = "cam_flat"
    kind = "joint"
    n_eq = 1
    signature = (
        Arg("cam", "point", doc="the centre of the profile's polar coordinates, on the cam"),
        Arg("face", "point", doc="a point of the follower's flat face"),
        Arg("support", "function", var="theta",
            doc="the profile's support function: distance from the centre to a tangent "
                "whose outward normal makes angle theta with the cam's x axis"),
        Arg("normal", "vector", (0.0, 1.0), doc="the face's normal in the follower's frame, "
                                                "pointing away from the cam"),
    )
    doc = "flat-faced follower on a convex cam profile given by its support function"

    def validate(self, p):
        if np.any(np.linalg.norm(p["normal"], axis=-1) == 0):
            raise ArgError("normal", "the face normal must not be the zero vector")

    def equations(self, bodies, args):
        cam, follower = bodies
        nl = args.normal / args.normal.norm()
        theta = np.remainder(follower.phi + np.arctan2(nl.y, nl.x) - cam.phi, TURN)
        d = follower.point(args.face) - cam.point(args.cam)
        return (follower.rotate(nl).dot(d) - args.support(theta),)


class CamRoller(ConstraintType):
    name = "cam_roller"
    kind = "joint"
    n_eq = 1
    signature = (
        Arg("cam", "point", doc="the centre of the pitch curve's polar coordinates, on the cam"),
        Arg("roller", "point", doc="the roller's centre, on the follower"),
        Arg("pitch", "function", var="psi",
            doc="the pitch curve: distance from the centre to the roller's centre at polar "
                "angle psi in the cam's frame"),
    )
    doc = "roller follower whose centre stays on a pitch curve given in polar form"

    def equations(self, bodies, args):
        cam, follower = bodies
        d = follower.point(args.roller) - cam.point(args.cam)
        psi = np.remainder(np.arctan2(d.y, d.x) - cam.phi, TURN)
        return (d.norm() - args.pitch(psi),)


@hookimpl
def mechdsl_constraint_types():
    return [CamFlat(), CamRoller()]
