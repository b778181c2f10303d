import numpy as np
import pytest

import mechdsl
from mechdsl.plugins import build_registry
from mechdsl.testing import check_constraint_type
from mechdsl_drives import Angle, Distance, RelAngle, X, Y


def _far_apart(rng, shape):
    """Points far from each other, so that the distance stays away from zero."""
    return rng.uniform(-1, 1, shape) + np.array([3.0, 0.0])


@pytest.mark.parametrize("ctype", [Angle(), X(), Y(), RelAngle()], ids=lambda c: c.name)
def test_drive_types_meet_the_contract(ctype):
    check_constraint_type(ctype, samples=50)


def test_distance_meets_the_contract():
    check_constraint_type(Distance(), samples=50, params={"p2": _far_apart})


def _registry():
    return build_registry(["mechdsl_revolute", "mechdsl_prismatic", "mechdsl_drives"],
                          entry_points=False)


def test_x_y_drives_move_a_point_along_a_given_path():
    # a free body whose origin is driven along (t, t^2) and whose angle is driven: the body
    # point (1, 0) is at r + e(phi), with every derivative in closed form
    mech = mechdsl.loads("""
        body b { guess = (0.1, 0.1, 0.1)  point P = (1, 0) }
        drive dx: x(b.origin) = t
        drive dy: y(b.origin) = t^2
        drive da: angle(b) = sin(t)
        simulate t = 0 .. 3 step 0.01
        output b.P
    """, registry=_registry())
    res = mech.simulate()
    t = res["t"]
    phi, w, al = np.sin(t), np.cos(t), -np.sin(t)
    np.testing.assert_allclose(res["b.P.x"], t + np.cos(phi), atol=1e-13)
    np.testing.assert_allclose(res["b.P.y"], t**2 + np.sin(phi), atol=1e-13)
    np.testing.assert_allclose(res["b.P.vx"], 1 - np.sin(phi) * w, atol=1e-12)
    np.testing.assert_allclose(res["b.P.vy"], 2 * t + np.cos(phi) * w, atol=1e-12)
    np.testing.assert_allclose(res["b.P.ax"], -np.cos(phi) * w**2 - np.sin(phi) * al,
                               atol=1e-11)
    np.testing.assert_allclose(res["b.P.ay"], 2 - np.sin(phi) * w**2 + np.cos(phi) * al,
                               atol=1e-11)


def test_rel_angle_drives_the_second_body_relative_to_the_first():
    mech = mechdsl.loads("""
        body a { guess = (0, 0, 0) }
        body b { guess = (0, 0, 0) }
        joint pa: revolute(ground.origin, a.origin)
        joint pb: revolute(a.origin, b.origin)
        drive da: angle(a) = t
        drive db: rel_angle(a, b) = 2*t^2
        simulate t = 0 .. 1 step 0.05
        output b.phi, b.omega, b.alpha
    """, registry=_registry())
    res = mech.simulate()
    t = res["t"]
    np.testing.assert_allclose(res["b.phi"], t + 2 * t**2, atol=1e-13)
    np.testing.assert_allclose(res["b.omega"], 1 + 4 * t, atol=1e-12)
    np.testing.assert_allclose(res["b.alpha"], 4.0, atol=1e-11)
