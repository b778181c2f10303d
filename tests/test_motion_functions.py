"""The textbook quantities as outputs (issue 30), each against a closed form derived by hand:
instant centres (ic_x, ic_y), the transmission angle (transmission), the velocity ratio
(mechanical advantage), the velocity and acceleration of a point relative to a moving body
(rel_vx, rel_vy, rel_ax, rel_ay). mechdsl.grammar.motion_functions has the formulas."""

import numpy as np
import pytest

from closed_forms import slider_crank
from conftest import EXAMPLES
from mechdsl.errors import MechError

SLIDER = (EXAMPLES / "slider_crank.mech").read_text()
FOURBAR = (EXAMPLES / "fourbar.mech").read_text()
R, L, OMEGA = 2.0, 3.5, 4 * np.pi
A, B, C, D, W2 = 1.0, 3.5, 3.0, 4.0, 2 * np.pi  # fourbar.mech: crank, coupler, rocker, ground


def with_outputs(text: str, outputs: str) -> str:
    lines = [outputs if line.startswith("output ") else line for line in text.splitlines()]
    return "\n".join(lines) + "\n"


def test_instant_centres_of_the_slider_cranks_rod(loads):
    """Relative to the ground, the rod's instant centre is where the crank's line meets the
    normal to the slider's guide through C: (x_C, x_C tan theta); relative to the crank it
    is their common pin B."""
    text = with_outputs(SLIDER, "output slider.x, ix = ic_x(rod, ground), iy = ic_y(rod, ground),"
                                " jx = ic_x(rod, crank), jy = ic_y(rod, crank), crank.B.x,"
                                " crank.B.y")
    res = loads(text).simulate(step=0.01)
    theta = np.pi / 4 + OMEGA * res["t"]
    x, _, _ = slider_crank(R, L, theta, OMEGA, 0.0)
    away = np.abs(np.cos(theta)) > 0.2  # tan theta finite
    np.testing.assert_allclose(res["ix"], x, rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(res["iy"][away], (x * np.tan(theta))[away], rtol=1e-10)
    np.testing.assert_allclose(res["jx"], R * np.cos(theta), atol=1e-11)
    np.testing.assert_allclose(res["jy"], R * np.sin(theta), atol=1e-11)
    assert res.units["ix"] == "m" and res.units["ix.vel"] == "m/s"


def fourbar_angles(t):
    """theta2, theta3, theta4 of fourbar.mech by loop closure: B where the circles about A
    (radius b) and O4 (radius c) meet, on the side of the file's guess."""
    th2 = np.pi / 4 + W2 * np.asarray(t)
    pa = np.stack([A * np.cos(th2), A * np.sin(th2)], axis=-1)
    v = np.array([D, 0.0]) - pa
    e = np.linalg.norm(v, axis=-1, keepdims=True)
    u = v / e
    along = (B * B - C * C + e * e) / (2 * e)
    across = np.sqrt(B * B - along**2)
    pb = pa + along * u + across * np.stack([-u[:, 1], u[:, 0]], axis=-1)
    th3 = np.arctan2(*(pb - pa).T[::-1])
    th4 = np.arctan2(*(pb - np.array([D, 0.0])).T[::-1])
    return th2, th3, th4


def test_the_four_bars_transmission_angle_and_velocity_ratio_over_a_revolution(loads):
    """mu: cos mu = (b^2 + c^2 - a^2 - d^2 + 2 a d cos theta2) / (2 b c) (law of cosines on
    the diagonal A-O4); the velocity ratio omega4 / omega2 = a sin(theta2 - theta3) /
    (c sin(theta4 - theta3)) (the loop closure differentiated)."""
    text = with_outputs(FOURBAR, "output mu = transmission(coupler.A, coupler.B, rocker.O),"
                                 " ratio = rocker.omega / crank.omega")
    res = loads(text).simulate(step=0.01)
    th2, th3, th4 = fourbar_angles(res["t"])
    mu = np.arccos((B**2 + C**2 - A**2 - D**2 + 2 * A * D * np.cos(th2)) / (2 * B * C))
    np.testing.assert_allclose(res["mu"], mu, atol=1e-11)
    np.testing.assert_allclose(res["ratio"], A * np.sin(th2 - th3) / (C * np.sin(th4 - th3)),
                               atol=1e-11)
    assert res.units["mu"] == "rad" and "ratio" not in res.units  # a pure number


def test_the_sliders_motion_relative_to_the_turning_crank(loads):
    """Relative to the crank (turning at omega about the origin), the slider at (x, 0) moves
    at v_rel = (x', -omega x) and accelerates at a_rel = (x'' - omega^2 x, -2 omega x')
    (the coincident point's acceleration -omega^2 (x, 0), Coriolis' 2 omega perp(v_rel))."""
    text = with_outputs(SLIDER, "output vx = rel_vx(slider.origin, crank), "
                                "vy = rel_vy(slider.origin, crank), "
                                "ax = rel_ax(slider.origin, crank), "
                                "ay = rel_ay(slider.origin, crank), "
                                "g = rel_vx(slider.origin, ground)")
    res = loads(text).simulate(step=0.01)
    x, xd, xdd = slider_crank(R, L, np.pi / 4 + OMEGA * res["t"], OMEGA, 0.0)
    for name, exact in (("vx", xd), ("vy", -OMEGA * x), ("ax", xdd - OMEGA**2 * x),
                        ("ay", -2 * OMEGA * xd), ("g", xd)):
        np.testing.assert_allclose(res[name], exact, rtol=1e-11, atol=1e-9, err_msg=name)
    assert (res.units["vx"], res.units["ax"]) == ("m/s", "m/s^2")


@pytest.mark.parametrize("call, message", [
    ("ic_x(rod.B, ground)", "ic_x() takes two bodies, such as ic_x(rod, ground)"),
    ("transmission(crank.B, rod.C)", "transmission() takes three points"),
    ("rel_vx(slider, crank)", "rel_vx() takes a point and a body"),
    ("ic_x(rod, nobody)", "nobody"),
])
def test_bad_arguments_are_located_errors(loads, call, message):
    with pytest.raises(MechError) as err:
        loads(with_outputs(SLIDER, f"output q = {call}")).simulate(step=0.1)
    assert message in str(err.value) and err.value.span is not None
