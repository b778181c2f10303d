import numpy as np
import pytest

import mechdsl
from mechdsl.errors import MechError
from mechdsl.plugins import build_registry
from mechdsl.plugins.geometry import Vec
from mechdsl.testing import ContractViolation, check_constraint_type
from mechdsl_prismatic import Prismatic


def test_prismatic_meets_the_contract():
    check_constraint_type(Prismatic(), samples=50)


def test_phi_is_the_normal_offset_and_the_relative_angle():
    # slide line through the origin along (1, 1) on an unturned ground; the point at (2, 0)
    # is sqrt(2) off the line; the slider is turned by 0.5 rad, the joint asks for 0.2
    q = (np.zeros(3), np.array([2.0, 0.0, 0.5]))
    p = {"p1": np.zeros(2), "p2": np.zeros(2), "axis": np.array([1.0, 1.0]),
         "angle": np.array(0.2)}
    np.testing.assert_allclose(Prismatic().phi(q, p), [-np.sqrt(2), 0.3], atol=1e-15)


def test_a_gamma_without_its_coriolis_term_is_caught():
    class Broken(Prismatic):
        def gamma_terms(self, bodies, rates, args):
            # the module docstring's gamma, with a spurious phid_1 xd_2 term
            (b1, b2), (v1, v2) = bodies, rates
            n = b1.rotate(args.axis.perp() / args.axis.norm())
            a1, a2 = b1.rotate(args.p1), b2.rotate(args.p2)
            d = b2.point(args.p2) - b1.point(args.p1)
            dd = Vec(v2.x, v2.y) + a2.perp() * v2.phi - Vec(v1.x, v1.y) - a1.perp() * v1.phi
            g = (n.dot(d) * v1.phi**2 - 2 * v1.phi * n.perp().dot(dd)
                 + n.dot(a2 * v2.phi**2 - a1 * v1.phi**2))
            return g + v1.phi * v2.x, 0.0

    with pytest.raises(ContractViolation, match="gamma"):
        check_constraint_type(Broken())


REG = None


def _registry():
    return build_registry(["mechdsl_revolute", "mechdsl_prismatic", "mechdsl_drives"],
                          entry_points=False)


def test_slider_on_an_inclined_turning_guide():
    # a guide turning about the origin at phi(t) = 0.4 t; a slider driven along it so that
    # its distance from the pivot is s(t) = 1 + t^2: position s e(phi) in closed form
    mech = mechdsl.loads("""
        body guide  { guess = (0, 0, 0) }
        body slider { guess = (1, 0.1, 0) }
        joint pivot: revolute(ground.origin, guide.origin)
        joint slide: prismatic(guide.origin, slider.origin, axis = (2, 0))
        drive turn: angle(guide) = 0.4*t
        drive push: distance(guide.origin, slider.origin) = 1 + t^2
        simulate t = 0 .. 1.5 step 0.01
        output slider.x, slider.y, slider.vx, slider.vy, slider.ax, slider.ay, slider.phi
    """, registry=_registry())
    res = mech.simulate()
    t = res["t"]
    phi, w = 0.4 * t, 0.4
    s, sd, sdd = 1 + t**2, 2 * t, 2.0
    c, si = np.cos(phi), np.sin(phi)
    np.testing.assert_allclose(res["slider.x"], s * c, atol=1e-13)
    np.testing.assert_allclose(res["slider.y"], s * si, atol=1e-13)
    np.testing.assert_allclose(res["slider.phi"], phi, atol=1e-13)
    np.testing.assert_allclose(res["slider.vx"], sd * c - s * w * si, atol=1e-12)
    np.testing.assert_allclose(res["slider.vy"], sd * si + s * w * c, atol=1e-12)
    np.testing.assert_allclose(res["slider.ax"], sdd * c - 2 * sd * w * si - s * w**2 * c,
                               atol=1e-11)
    np.testing.assert_allclose(res["slider.ay"], sdd * si + 2 * sd * w * c - s * w**2 * si,
                               atol=1e-11)


def test_a_zero_axis_is_reported_at_the_argument():
    mech = mechdsl.loads("""body s { }
joint j: prismatic(ground.origin, s.origin, axis = (0, 0))
drive d: x(s.origin) = t
simulate t = 0 .. 1 step 0.1
""", "z.mech", registry=_registry())
    with pytest.raises(MechError, match="zero vector") as info:
        mech.simulate()
    assert (info.value.span.line, info.value.span.column) == (2, 45)


def test_pin_slot_meets_the_contract():
    from mechdsl_prismatic import PinSlot

    check_constraint_type(PinSlot(), samples=50)


def test_scotch_yoke_by_pin_slot():
    mech = mechdsl.loads("""
        body crank { guess = (0, 0, 0.2)  point P = (0.5, 0) }
        body yoke  { guess = (0.4, 0, 0) }
        joint axle:  revolute(ground.origin, crank.origin)
        joint guide: prismatic(ground.origin, yoke.origin, axis = (1, 0))
        joint pin:   pin_slot(yoke.origin, crank.P, axis = (0, 1))
        drive motor: angle(crank) = 2*t
        simulate t = 0 .. 2 step 0.01
        output yoke.x, yoke.vx, yoke.ax
    """, registry=_registry())
    res = mech.simulate()
    t = res["t"]
    np.testing.assert_allclose(res["yoke.x"], 0.5 * np.cos(2 * t), atol=1e-14)
    np.testing.assert_allclose(res["yoke.vx"], -1.0 * np.sin(2 * t), atol=1e-13)
    np.testing.assert_allclose(res["yoke.ax"], -2.0 * np.cos(2 * t), atol=1e-12)
