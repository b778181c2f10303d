import numpy as np

import mechdsl
from mechdsl.testing import check_constraint_type
from mechdsl_curve_slot import CurveSlot


def test_curve_slot_meets_the_contract():
    check_constraint_type(CurveSlot())


def test_a_pin_driven_along_x_follows_the_parabola():
    mech = mechdsl.loads("""
        body pin { guess = (0.1, 0.1, 0) }
        joint slot: curve_slot(ground.origin, pin.origin, shape = 0.5*x^2)
        drive along: x(pin.origin) = sin(t)
        drive upright: angle(pin) = 0
        simulate t = 0 .. 3 step 0.01
        output pin.y, pin.vy, pin.ay
    """)
    res = mech.simulate()
    t = res["t"]
    x, v, a = np.sin(t), np.cos(t), -np.sin(t)
    np.testing.assert_allclose(res["pin.y"], 0.5 * x**2, atol=1e-14)
    np.testing.assert_allclose(res["pin.vy"], x * v, atol=1e-13)
    np.testing.assert_allclose(res["pin.ay"], v**2 + x * a, atol=1e-12)
