"""Named outputs, ``output NAME = EXPR``: their values and exact time derivatives against the
closed form of the slider-crank, and their mistakes as located errors."""

import numpy as np
import pytest

from closed_forms import slider_crank
from conftest import EXAMPLES
from mechdsl.errors import MechError

SLIDER = (EXAMPLES / "slider_crank.mech").read_text()
R, L, OMEGA = 2.0, 3.5, 4 * np.pi


def with_outputs(line: str) -> str:
    return SLIDER.replace("output slider.x, slider.vx, slider.ax", line)


def test_a_distance_and_its_rates_are_the_closed_form(loads):
    # the crank's pivot A is at the ground's origin, the slider runs on the x axis: the
    # distance from A to the slider is the slider's x
    res = loads(with_outputs("output slide = distance(crank.A, slider.origin)")).simulate()
    assert list(res.data) == ["slide", "slide.vel", "slide.acc"]
    t = res["t"]
    x, v, a = slider_crank(R, L, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
    np.testing.assert_allclose(res["slide"], x, atol=1e-13 * np.abs(x).max())
    np.testing.assert_allclose(res["slide.vel"], v, atol=1e-12 * np.abs(v).max())
    np.testing.assert_allclose(res["slide.acc"], a, atol=1e-11 * np.abs(a).max())


def test_a_relative_angle_and_its_rates_are_the_closed_form(loads):
    res = loads(with_outputs("output rel = rod.phi - crank.phi")).simulate()
    t = res["t"]
    theta = np.pi / 4 + OMEGA * t
    # the rod from the crank pin (r sin theta high) down to the slider on the x axis
    beta = -np.arcsin(R * np.sin(theta) / L)
    beta_d = -R * np.cos(theta) * OMEGA / (L * np.cos(beta))
    beta_dd = (R * np.sin(theta) * OMEGA**2 + L * np.sin(beta) * beta_d**2) / (L * np.cos(beta))
    wrap = np.round((res["rel"] - (beta - theta)) / (2 * np.pi)) * 2 * np.pi
    np.testing.assert_allclose(res["rel"] - wrap, beta - theta, atol=1e-13)
    np.testing.assert_allclose(res["rel.vel"], beta_d - OMEGA, atol=1e-12 * OMEGA)
    np.testing.assert_allclose(res["rel.acc"], beta_dd, atol=1e-11 * np.abs(beta_dd).max())


def test_an_expression_of_rates_has_the_derivatives_that_exist(loads):
    # e = vx^2 / 2: e' = vx ax; e'' would need the jerk, which is not computed
    res = loads(with_outputs("output slider.x, e = 0.5*slider.vx^2 + 0*t")).simulate()
    assert list(res.data) == ["slider.x", "e", "e.vel"]
    t = res["t"]
    _, v, a = slider_crank(R, L, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
    np.testing.assert_allclose(res["e"], v * v / 2, rtol=1e-12, atol=1e-12 * (v * v).max())
    np.testing.assert_allclose(res["e.vel"], v * a, atol=1e-11 * np.abs(v * a).max())


def test_params_and_time_in_a_named_output(loads):
    res = loads(with_outputs("output lag = crank.phi - omega*t")).simulate(step=0.1)
    np.testing.assert_allclose(res["lag"], np.pi / 4, atol=1e-14)
    np.testing.assert_allclose(res["lag.vel"], 0.0, atol=1e-12)
    np.testing.assert_allclose(res["lag.acc"], 0.0, atol=1e-10)


def test_a_named_output_in_a_sweep_follows_each_variant(loads):
    res = loads(with_outputs("output slide = distance(crank.A, slider.origin)")).simulate(
        sweep={"l": [3.5, 5.0]}, step=0.01)
    t = res["t"]
    for v, l in enumerate((3.5, 5.0)):
        x, _, _ = slider_crank(R, l, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
        np.testing.assert_allclose(res["slide"][v], x, atol=1e-12)


@pytest.mark.parametrize("line, column, message", [
    ("output s = distance(crank, slider.origin)", 12, "distance() takes two points"),
    ("output s = crank.q", 12, "'crank.q' in output 's' is not a quantity"),
    ("output s = nosuch.x", 12, "unknown body 'nosuch'"),
    ("output s = crank.Z.x", 12, "body 'crank' has no point 'Z'"),
    ("output s = crank.x + w", 22, "unknown name 'w' in output 's'"),
    ("output slider.x, slider.x = 1", 27, "unexpected '='"),
    ("output s = crank.x, s = crank.y", 21, "output 's' is requested twice"),
])
def test_mistakes_in_named_outputs_are_located(loads, line, column, message):
    with pytest.raises(MechError) as err:
        loads(with_outputs(line)).simulate(step=0.5)
    assert err.value.line == 32 and err.value.column == column, err.value.message
    assert err.value.message.startswith(message)


def test_a_named_output_that_is_not_defined_somewhere_is_said(loads):
    # the rate of the distance between two points that coincide (the crank's pivot and the
    # ground's origin) is 0/0: written as it is, with a warning, never silently
    res = loads(with_outputs("output h = distance(crank.A, ground.origin)")).simulate(step=0.1)
    assert res.ok
    np.testing.assert_array_equal(res["h"], 0.0)
    assert np.isnan(res["h.vel"]).all()
    assert [w for w in res.warnings if w.startswith("output h.vel is nan from t = 0 on")]


def test_a_named_output_cannot_take_a_params_name(loads):
    with pytest.raises(MechError) as err:
        loads(with_outputs("output l = crank.phi"))
    assert err.value.message == "'l' is a param; give the output another name"
    assert (err.value.line, err.value.column) == (32, 8)
