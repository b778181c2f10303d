"""Units: the same mechanism in micrometres, millimetres, metres and kilometres has the same
relative error: every tolerance is relative to the model's own size."""

import numpy as np
import pytest

import mechdsl

SCALED = """
param s = 1
param r = 2*s
param l = 3.5*s
body crank  { guess = (s, 0, 0)  point A = (-r/2, 0)  point B = (r/2, 0) }
body rod    { guess = (3.75*s, 0, 0)  point B = (-l/2, 0)  point C = (l/2, 0) }
body slider { guess = (5.5*s, 0, 0) }
joint A: revolute(ground.origin, crank.A)
joint B: revolute(crank.B, rod.B)
joint C: revolute(rod.C, slider.origin)
joint D: prismatic(ground.origin, slider.origin, axis = (1, 0))
drive crank_angle: angle(crank) = pi/4 + 4*pi*t
simulate t = 0 .. 1 step 0.001
output slider.x, slider.vx, slider.ax
"""


def errors(registry, scale):
    from closed_forms import slider_crank

    res = mechdsl.loads(SCALED, registry=registry).simulate(s=scale)
    assert res.ok
    t = res["t"]
    exact = slider_crank(2.0 * scale, 3.5 * scale, np.pi / 4 + 4 * np.pi * t, 4 * np.pi, 0.0)
    return [np.abs(res[n] - e).max() / np.abs(e).max()
            for n, e in zip(("slider.x", "slider.vx", "slider.ax"), exact)]


@pytest.mark.parametrize("scale", [1e-6, 1e-3, 1e3])
def test_the_relative_error_does_not_depend_on_the_unit(registry, scale):
    reference = errors(registry, 1.0)
    for got, ref in zip(errors(registry, scale), reference):
        assert got < 1e-14
        assert got <= 10 * max(ref, 1e-16)
