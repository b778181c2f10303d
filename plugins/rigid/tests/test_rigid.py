import numpy as np

import mechdsl
from mechdsl.plugins import build_registry
from mechdsl.testing import check_constraint_type
from mechdsl_rigid import Rigid


def test_rigid_meets_the_contract():
    check_constraint_type(Rigid(), samples=50)


def test_a_welded_arm_turns_with_its_hub():
    # an arm welded to a driven hub at (0.3, 0.1), turned by 0.5 rad: its tip (0.4, 0) is at
    # R(phi) ((0.3, 0.1) + R(0.5)(0.4, 0)) for a hub turning as phi = t^2
    registry = build_registry(["mechdsl_revolute", "mechdsl_drives", "mechdsl_rigid"],
                              entry_points=False)
    mech = mechdsl.loads("""
        body hub { }
        body arm { guess = (0.3, 0.1, 0.5)  point tip = (0.4, 0) }
        joint axle: revolute(ground.origin, hub.origin)
        joint weld: rigid(hub, arm, at = (0.3, 0.1), angle = 0.5)
        drive d: angle(hub) = t^2
        simulate t = 0 .. 1.5 step 0.01
        output arm.tip, arm.phi
    """, registry=registry)
    res = mech.simulate()
    t = res["t"]
    phi, w, al = t**2, 2 * t, 2.0
    local = np.array([0.3, 0.1]) + 0.4 * np.array([np.cos(0.5), np.sin(0.5)])
    c, s = np.cos(phi), np.sin(phi)
    x, y = c * local[0] - s * local[1], s * local[0] + c * local[1]
    np.testing.assert_allclose(res["arm.phi"], phi + 0.5, atol=1e-14)
    np.testing.assert_allclose(res["arm.tip.x"], x, atol=1e-14)
    np.testing.assert_allclose(res["arm.tip.y"], y, atol=1e-14)
    np.testing.assert_allclose(res["arm.tip.vx"], -y * w, atol=1e-13)
    np.testing.assert_allclose(res["arm.tip.vy"], x * w, atol=1e-13)
    np.testing.assert_allclose(res["arm.tip.ax"], -y * al - x * w**2, atol=1e-12)
    np.testing.assert_allclose(res["arm.tip.ay"], x * al - y * w**2, atol=1e-12)
