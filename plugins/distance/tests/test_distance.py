import numpy as np
import pytest

import mechdsl
from mechdsl.errors import MechError
from mechdsl.plugins import build_registry
from mechdsl.testing import check_constraint_type
from mechdsl_distance import Distance


def _registry():
    return build_registry(["mechdsl_revolute", "mechdsl_prismatic", "mechdsl_drives",
                           "mechdsl_distance"], entry_points=False)


def test_distance_meets_the_contract():
    check_constraint_type(Distance(), samples=50)


def test_slider_crank_with_a_massless_rod():
    # crank r = 1 and a rod of length 2.5 as a distance joint between the crank pin and the
    # slider: x = r cos(th) + sqrt(l^2 - r^2 sin^2(th))
    mech = mechdsl.loads("""
        body crank  { guess = (0, 0, 0.3)  point B = (1, 0) }
        body slider { guess = (3.4, 0, 0) }
        joint axle:  revolute(ground.origin, crank.origin)
        joint slide: prismatic(ground.origin, slider.origin)
        joint rod:   distance(crank.B, slider.origin, length = 2.5)
        drive d: angle(crank) = 0.3 + 3*t
        simulate t = 0 .. 2 step 0.01
        output slider.x
    """, registry=_registry())
    res = mech.simulate()
    th = 0.3 + 3 * res["t"]
    np.testing.assert_allclose(res["slider.x"], np.cos(th) + np.sqrt(6.25 - np.sin(th) ** 2),
                               atol=1e-13)


def test_the_length_must_be_positive():
    mech = mechdsl.loads("body b { }\njoint j: distance(ground.origin, b.origin, length = -1)\n",
                         "neg.mech", registry=_registry())
    with pytest.raises(MechError, match="must be positive") as info:
        mech.compile(need_times=False)
    assert (info.value.span.line, info.value.span.column) == (2, 44)
