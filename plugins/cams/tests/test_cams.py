import numpy as np

import mechdsl
from mechdsl.plugins import build_registry
from mechdsl.testing import check_constraint_type
from mechdsl_cams import CamFlat, CamRoller


def _registry():
    return build_registry(["mechdsl_revolute", "mechdsl_prismatic", "mechdsl_drives",
                           "mechdsl_cams"], entry_points=False)


def _away(rng, shape):
    """Roller centres away from the cam centre, so that the polar angle is defined."""
    return rng.uniform(-1, 1, shape) + np.array([2.5, 0.0])


def test_flat_faced_cam_meets_the_contract():
    check_constraint_type(CamFlat(), samples=50)


def test_roller_cam_meets_the_contract():
    check_constraint_type(CamRoller(), samples=50, params={"roller": _away})


def test_roller_on_a_harmonic_pitch_curve():
    # pitch curve rho = 1 + 0.2 cos(2 psi), roller straight above the axle: y = rho(pi/2 - phi)
    mech = mechdsl.loads("""
        body cam { }
        body follower { guess = (0, 0.9, 0) }
        joint axle: revolute(ground.origin, cam.origin)
        joint guide: prismatic(ground.origin, follower.origin, axis = (0, 1))
        joint contact: cam_roller(cam.origin, follower.origin, pitch = 1 + 0.2*cos(2*psi))
        drive d: angle(cam) = 1.5*t
        simulate t = 0 .. 4 step 0.01
        output follower.y, follower.vy, follower.ay
    """, registry=_registry())
    res = mech.simulate()
    t = res["t"]
    psi = np.pi / 2 - 1.5 * t
    np.testing.assert_allclose(res["follower.y"], 1 + 0.2 * np.cos(2 * psi), atol=1e-14)
    np.testing.assert_allclose(res["follower.vy"], 0.2 * 2 * 1.5 * np.sin(2 * psi), atol=1e-13)
    np.testing.assert_allclose(res["follower.ay"], -0.2 * 4 * 2.25 * np.cos(2 * psi), atol=1e-12)


def test_flat_face_on_an_offset_follower_reads_the_support_function():
    # a face whose normal points straight down onto a cam below it: theta = -pi/2 - phi
    mech = mechdsl.loads("""
        body cam { }
        body follower { guess = (0.3, -1.2, 0) }
        joint axle: revolute(ground.origin, cam.origin)
        joint guide: prismatic(ground.origin, follower.origin, axis = (0, 1))
        joint contact: cam_flat(cam.origin, follower.origin, support = 1 + 0.1*sin(theta),
                                normal = (0, -1))
        drive d: angle(cam) = 2*t
        simulate t = 0 .. 3 step 0.01
        output follower.y
    """, registry=_registry())
    res = mech.simulate()
    theta = -np.pi / 2 - 2 * res["t"]
    np.testing.assert_allclose(res["follower.y"], -(1 + 0.1 * np.sin(theta)), atol=1e-14)
