"""Cams, with the profile given as a function of an angle in the cam's frame, so that the
follower's motion is explicit and its derivatives exact (no contact point to solve for).

``cam_flat(cam.O, follower.F, support = p(theta), normal = (0, 1))`` -- a flat-faced
follower. F is a point of the face, n = A_f n' its unit normal (pointing away from the cam).
For a convex profile the face touches it where n . (F - O) equals the profile's support
function p in the direction of n, whose angle in the cam's frame is
theta = phi_f + angle(n') - phi_c. With d = F - O::

    Phi   = n . d - p(theta)
    dPhi/dq_c = [ -n^T, -n . perp(A_c s'_O) + p'(theta) ]
    dPhi/dq_f = [  n^T,  perp(n) . d + n . perp(A_f s'_F) - p'(theta) ]
    gamma = (n . d) phid_f^2 - 2 phid_f perp(n) . dd + n . (A_f s'_F phid_f^2 - A_c s'_O phid_c^2)
            + p''(theta) (phid_f - phid_c)^2

``cam_roller(cam.O, follower.C, pitch = rho(psi))`` -- a roller follower: its centre C stays
on the pitch curve, the profile offset by the roller's radius, given in polar form about O
in the cam's frame. With d = C - O, L = |d|, e = d / L, g = perp(d) / L^2 and
psi = angle(d) - phi_c::

    Phi   = L - rho(psi)
    w     = e - rho'(psi) g
    dPhi/dq_c = [ -w^T, -w . perp(A_c s'_O) + rho'(psi) ]
    dPhi/dq_f = [  w^T,  w . perp(A_f s'_C) ]
    gamma = w . (A_f s'_C phid_f^2 - A_c s'_O phid_c^2) - (|dd|^2 - (e . dd)^2) / L
            + rho''(psi) psid^2 - 2 rho'(psi) (perp(d) . dd)(d . dd) / L^4

with psid = g . dd - phid_c. Both functions are evaluated at their angle wrapped into
[0, 2 pi): write one turn of the profile, closing on itself.
"""

from __future__ import annotations

import numpy as np

from mechdsl.plugins import Arg, ArgError, ConstraintType, hookimpl
from mechdsl.plugins.geometry import block, dot, perp, rotate

TURN = 2 * np.pi


def _turn(angle):
    return np.mod(angle, TURN)


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

    def _parts(self, q, p):
        qc, qf = q
        nl = p["normal"] / np.linalg.norm(p["normal"], axis=-1, keepdims=True)
        n = rotate(qf[..., 2], nl)
        aso = rotate(qc[..., 2], p["cam"])
        asf = rotate(qf[..., 2], p["face"])
        d = qf[..., :2] + asf - qc[..., :2] - aso
        theta = qf[..., 2] + np.arctan2(nl[..., 1], nl[..., 0]) - qc[..., 2]
        n, aso, asf, d = np.broadcast_arrays(n, aso, asf, d)
        return n, aso, asf, d, _turn(np.broadcast_to(theta, d.shape[:-1]))

    def phi(self, q, p):
        n, _, _, d, theta = self._parts(q, p)
        return (dot(n, d) - p["support"](theta))[..., None]

    def jacobian(self, q, p):
        n, aso, asf, d, theta = self._parts(q, p)
        dp = p["support"].d1(theta)
        return (block(-n[..., None, :], (-dot(n, perp(aso)) + dp)[..., None]),
                block(n[..., None, :], (dot(perp(n), d) + dot(n, perp(asf)) - dp)[..., None]))

    def gamma(self, q, qd, p):
        n, aso, asf, d, theta = self._parts(q, p)
        wc, wf = qd[0][..., 2], qd[1][..., 2]
        dd = (qd[1][..., :2] + perp(asf) * wf[..., None]
              - qd[0][..., :2] - perp(aso) * wc[..., None])
        g = (dot(n, d) * wf**2 - 2 * wf * dot(perp(n), dd)
             + dot(n, asf * (wf**2)[..., None] - aso * (wc**2)[..., None])
             + p["support"].d2(theta) * (wf - wc) ** 2)
        return g[..., None]


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

    def _parts(self, q, p):
        qc, qf = q
        aso = rotate(qc[..., 2], p["cam"])
        asc = rotate(qf[..., 2], p["roller"])
        d = qf[..., :2] + asc - qc[..., :2] - aso
        aso, asc, d = np.broadcast_arrays(aso, asc, d)
        length = np.linalg.norm(d, axis=-1)
        psi = _turn(np.arctan2(d[..., 1], d[..., 0]) - qc[..., 2])
        return aso, asc, d, length, np.broadcast_to(psi, length.shape)

    def phi(self, q, p):
        _, _, _, length, psi = self._parts(q, p)
        return (length - p["pitch"](psi))[..., None]

    def jacobian(self, q, p):
        aso, asc, d, length, psi = self._parts(q, p)
        dr = p["pitch"].d1(psi)
        w = d / length[..., None] - dr[..., None] * perp(d) / (length**2)[..., None]
        return (block(-w[..., None, :], (-dot(w, perp(aso)) + dr)[..., None]),
                block(w[..., None, :], dot(w, perp(asc))[..., None]))

    def gamma(self, q, qd, p):
        aso, asc, d, length, psi = self._parts(q, p)
        wc, wf = qd[0][..., 2], qd[1][..., 2]
        dr, ddr = p["pitch"].d1(psi), p["pitch"].d2(psi)
        e = d / length[..., None]
        g = perp(d) / (length**2)[..., None]
        w = e - dr[..., None] * g
        dd = (qd[1][..., :2] + perp(asc) * wf[..., None]
              - qd[0][..., :2] - perp(aso) * wc[..., None])
        psid = dot(g, dd) - wc
        out = (dot(w, asc * (wf**2)[..., None] - aso * (wc**2)[..., None])
               - (dot(dd, dd) - dot(e, dd) ** 2) / length
               + ddr * psid**2
               - 2 * dr * dot(perp(d), dd) * dot(d, dd) / length**4)
        return out[..., None]


@hookimpl
def mechdsl_constraint_types():
    return [CamFlat(), CamRoller()]
