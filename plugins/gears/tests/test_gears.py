import numpy as np
import pytest

import mechdsl
from mechdsl.errors import MechError
from mechdsl.plugins import build_registry
from mechdsl.testing import check_constraint_type
from mechdsl_gears import Gear, InternalGear, RackPinion


def _registry():
    return build_registry(["mechdsl_revolute", "mechdsl_prismatic", "mechdsl_drives",
                           "mechdsl_gears"], entry_points=False)


def _small(rng, shape):
    return rng.uniform(0.2, 0.8, shape)


@pytest.mark.parametrize("ctype, params", [(Gear(), {}), (InternalGear(), {"ratio": _small}),
                                           (RackPinion(), {})], ids=lambda x: getattr(x, "name", ""))
def test_gear_types_meet_the_contract(ctype, params):
    check_constraint_type(ctype, samples=50, params=params)


def test_fixed_centre_gears_turn_at_the_ratio():
    mech = mechdsl.loads("""
        param R1 = 0.3  param R2 = 0.75
        ground { point C2 = (R1 + R2, 0)  point P = (3, 0)  point Q = (3.75, 0) }
        body g1 { }
        body g2 { guess = (R1 + R2, 0, 0) }
        body ring { guess = (3, 0, 0) }
        body pin { guess = (3.75, 0, 0) }
        joint a1: revolute(ground.origin, g1.origin)
        joint a2: revolute(ground.C2, g2.origin)
        joint mesh: gear(g1, g2, ratio = R1/R2)
        joint a3: revolute(ground.P, ring.origin)
        joint a4: revolute(ground.Q, pin.origin)
        joint inner: internal_gear(pin, ring, ratio = 0.25)
        drive d: angle(g1) = sin(t)
        drive e: angle(pin) = t^2
        simulate t = 0 .. 2 step 0.01
        output g2.omega, g2.alpha, ring.omega
    """, registry=_registry())
    res = mech.simulate()
    t = res["t"]
    np.testing.assert_allclose(res["g2.omega"], -0.4 * np.cos(t), atol=1e-13)
    np.testing.assert_allclose(res["g2.alpha"], 0.4 * np.sin(t), atol=1e-12)
    np.testing.assert_allclose(res["ring.omega"], 0.25 * 2 * t, atol=1e-13)


def test_an_internal_gear_needs_a_smaller_pinion():
    mech = mechdsl.loads("body a { }\nbody b { }\njoint j: internal_gear(a, b, ratio = 2)\n",
                         "big.mech", registry=_registry())
    with pytest.raises(MechError, match="smaller than the ring"):
        mech.compile(need_times=False)


def test_rack_and_pinion_travel():
    mech = mechdsl.loads("""
        ground { point O = (0, 0.1) }
        body pinion { guess = (0, 0.1, 0) }
        body rack { }
        joint axle: revolute(ground.O, pinion.origin)
        joint slide: prismatic(ground.origin, rack.origin)
        joint mesh: rack_pinion(pinion, rack, radius = 0.1)
        drive d: angle(pinion) = 3*t
        simulate t = 0 .. 1 step 0.1
        output rack.x
    """, registry=_registry())
    np.testing.assert_allclose(mech.simulate()["rack.x"], 0.3 * np.linspace(0, 1, 11), atol=1e-14)
