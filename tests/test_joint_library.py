"""Every joint family's example mechanism against its closed form."""

import numpy as np
import pytest

from closed_forms import angle_error, four_bar
from conftest import EXAMPLES


def rel_err(got, want):
    return np.abs(got - want).max() / np.abs(want).max()


def test_scotch_yoke_moves_in_simple_harmonic_motion(load_example):
    res = load_example("scotch_yoke.mech").simulate()
    assert res.ok
    w, r, t = 2 * np.pi, 0.5, res["t"]
    assert rel_err(res["yoke.x"], r * np.cos(w * t)) < 1e-13
    assert rel_err(res["yoke.vx"], -r * w * np.sin(w * t)) < 1e-13
    assert rel_err(res["yoke.ax"], -r * w * w * np.cos(w * t)) < 1e-12


def test_planetary_train_turns_the_carrier_at_the_train_ratio(load_example):
    res = load_example("planetary.mech").simulate()
    assert res.ok
    t = res["t"]
    Rs, Rp, Rr, ws = 1.0, 0.5, 2.0, 2 * np.pi
    wc = ws * Rs / (Rs + Rr)
    wp = wc - Rs / Rp * (ws - wc)
    np.testing.assert_allclose(res["carrier.omega"], wc, rtol=1e-13)
    np.testing.assert_allclose(res["planet.omega"], wp, rtol=1e-13)
    np.testing.assert_allclose(res["carrier.phi"], wc * t, atol=1e-12)
    np.testing.assert_allclose(res["planet.x"], (Rs + Rp) * np.cos(wc * t), atol=1e-12)
    np.testing.assert_allclose(res["planet.y"], (Rs + Rp) * np.sin(wc * t), atol=1e-12)


def test_the_train_ratio_holds_for_other_gears(load_example):
    res = load_example("planetary.mech").simulate(Rs=0.7, Rp=0.45, span=(0, 1), step=0.01)
    ws, Rs, Rr = 2 * np.pi, 0.7, 0.7 + 0.9
    np.testing.assert_allclose(res["carrier.omega"], ws * Rs / (Rs + Rr), rtol=1e-13)


def test_rack_travels_the_pinions_arc(load_example):
    res = load_example("rack_pinion.mech").simulate()
    assert res.ok
    t, R, al = res["t"], 0.2, 0.5 * np.pi
    np.testing.assert_allclose(res["rack.x"], R * al * t**2 / 2, atol=1e-14)
    np.testing.assert_allclose(res["rack.vx"], R * al * t, atol=1e-13)
    np.testing.assert_allclose(res["rack.ax"], R * al, atol=1e-12)


def test_flat_follower_on_an_eccentric_cam_is_harmonic(load_example):
    res = load_example("cam_flat.mech").simulate()
    assert res.ok
    t, R, e, w = res["t"], 0.04, 0.01, 10 * np.pi
    assert rel_err(res["follower.y"], R + e * np.sin(w * t)) < 1e-13
    assert rel_err(res["follower.vy"], e * w * np.cos(w * t)) < 1e-12
    assert rel_err(res["follower.ay"], -e * w * w * np.sin(w * t)) < 1e-11


def test_a_swept_param_inside_a_cam_profile_moves_each_variant_its_own_way(load_example):
    # the eccentricity e is read by the profile function R + e cos(theta): per variant
    res = load_example("cam_flat.mech").simulate(sweep={"e": [0.005, 0.01, 0.02]})
    assert res.ok
    t, R, w = res["t"], 0.04, 10 * np.pi
    for v, e in enumerate((0.005, 0.01, 0.02)):
        assert rel_err(res["follower.y"][v], R + e * np.sin(w * t)) < 1e-13
        assert rel_err(res["follower.ay"][v], -e * w * w * np.sin(w * t)) < 1e-11


def test_roller_follower_lift_is_the_tabulated_profile(load_example):
    from scipy.interpolate import CubicSpline

    res = load_example("cam_roller.mech").simulate()
    assert res.ok
    data = np.loadtxt(EXAMPLES / "data" / "cam_pitch.csv", delimiter=",", skiprows=3)
    psi = np.append(data[:, 0], 2 * np.pi)
    rho = np.append(data[:, 1], data[0, 1])
    spline = CubicSpline(psi, rho, bc_type="periodic")
    # the roller sits straight above the cam's axle: polar angle pi/2 - phi_cam = pi/2 + w t
    t, w = res["t"], 2 * np.pi
    angle = np.mod(np.pi / 2 + w * t, 2 * np.pi)
    np.testing.assert_allclose(res["follower.y"], spline(angle), atol=1e-15)
    np.testing.assert_allclose(res["follower.vy"], spline(angle, 1) * w, atol=1e-13)
    np.testing.assert_allclose(res["follower.ay"], spline(angle, 2) * w * w, atol=1e-10)
    # and the spline is the cycloidal program it samples, to interpolation accuracy
    rise = np.clip(np.degrees(angle) / 120, 0, 1)
    program = 0.04 + 0.015 * (rise - np.sin(2 * np.pi * rise) / (2 * np.pi))
    during_rise = np.degrees(angle) < 120
    np.testing.assert_allclose(res["follower.y"][during_rise], program[during_rise], atol=1e-7)


def test_massless_coupler_and_weld_keep_the_four_bar_closed_form(load_example):
    res = load_example("fourbar_coupler.mech").simulate()
    assert res.ok
    t = res["t"]
    th2 = np.pi / 4 + 2 * np.pi * t
    _, (th4, w4, al4) = four_bar(1.0, 3.5, 3.0, 4.0, th2, 2 * np.pi, 0.0)
    assert angle_error(res["rocker.phi"], th4 + np.pi).max() < 1e-13
    assert rel_err(res["rocker.omega"], w4) < 1e-12
    assert rel_err(res["rocker.alpha"], al4) < 1e-11
    np.testing.assert_allclose(res["plate.phi"], res["rocker.phi"], atol=1e-14)
    # the plate's point T = (0, 0.5) rides with the rocker, whose centre is O4 + (c/2) e(th4)
    centre = np.stack((4 + 1.5 * np.cos(th4), 1.5 * np.sin(th4)), -1)
    phi = res["rocker.phi"]
    T = centre + 0.5 * np.stack((-np.sin(phi), np.cos(phi)), -1)
    np.testing.assert_allclose(res["plate.T.x"], T[:, 0], atol=1e-13)
    np.testing.assert_allclose(res["plate.T.y"], T[:, 1], atol=1e-13)


@pytest.mark.parametrize("name", ["scotch_yoke.mech", "planetary.mech", "rack_pinion.mech",
                                  "cam_flat.mech", "cam_roller.mech", "fourbar_coupler.mech"])
def test_library_examples_pass_check(name, registry):
    import mechdsl
    from mechdsl.solve import assemble

    kernels = mechdsl.load(EXAMPLES / name, registry=registry).compile()
    asm = assemble(kernels, kernels.system.times[0])
    assert asm.ok.all() and asm.mobility.rows.size == kernels.system.n
