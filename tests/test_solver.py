"""The solver against closed forms: the seed's slider-crank and its parametric studies, a
four-bar by loop closure, and numerical failures at the instants where they must happen."""

import numpy as np
import pytest

from closed_forms import angle_error, four_bar, slider_crank, start_from_rest
from mechdsl.solve import assemble
from mechdsl.solve import SolverOptions


def rel_err(got, want):
    return np.abs(got - want).max() / np.abs(want).max()


def test_seed_slider_crank_matches_the_closed_form_to_round_off(load_example):
    res = load_example("slider_crank.mech").simulate()
    assert res.ok and len(res["t"]) == 1001
    t = res["t"]
    x, v, a = slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * t, 4 * np.pi, 0.0)
    assert rel_err(res["slider.x"], x) < 1e-13
    assert rel_err(res["slider.vx"], v) < 1e-13
    assert rel_err(res["slider.ax"], a) < 1e-12
    assert res.residual < 1e-13


def test_assembly_from_the_seed_guesses_finds_the_closed_form_configuration(load_example):
    kernels = load_example("slider_crank.mech").compile()
    asm = assemble(kernels, 0.0)
    assert asm.ok.all()
    q = asm.q[0]
    th = np.pi / 4
    B = 2 * np.array([np.cos(th), np.sin(th)])
    x, _, _ = slider_crank(2.0, 3.5, th, 0, 0)
    np.testing.assert_allclose(q[0:3], [np.cos(th), np.sin(th), th], atol=1e-14)
    np.testing.assert_allclose(q[3:5], (B + [x, 0]) / 2, atol=1e-14)
    np.testing.assert_allclose(q[5], np.arctan2(-B[1], x - B[0]), atol=1e-14)
    np.testing.assert_allclose(q[6:9], [x, 0, 0], atol=1e-14)


@pytest.mark.parametrize("t1", [0.5, 1.0, 2.0])
def test_start_from_rest_cases_of_section_VII_A(load_example, t1):
    res = load_example("start_from_rest.mech").simulate(t1=t1)
    t = res["t"]
    assert res.ok and t[-1] == pytest.approx(t1 + 1)
    th, w, al = start_from_rest(t, t1, 4 * np.pi / t1)
    x, v, a = slider_crank(2.0, 3.5, th, w, al)
    assert rel_err(res["slider.x"], x) < 1e-13
    assert rel_err(res["slider.vx"], v) < 1e-13
    assert rel_err(res["slider.ax"], a) < 1e-12


def test_rod_sweep_of_section_VII_B_matches_each_variant(load_example):
    res = load_example("rod_sweep.mech").simulate()
    assert res.ok
    np.testing.assert_array_equal(res["l"], [3.5, 2.5, 2.2, 2.1])
    t = res["t"]
    th, w, al = start_from_rest(t, 1.0, 4 * np.pi)
    for i, l in enumerate(res["l"]):
        x, v, a = slider_crank(2.0, l, th, w, al)
        assert rel_err(res["slider.x"][i], x) < 1e-13
        assert rel_err(res["slider.vx"][i], v) < 1e-12
        assert rel_err(res["slider.ax"][i], a) < 1e-11


def test_four_bar_matches_loop_closure(load_example):
    res = load_example("fourbar.mech").simulate()
    assert res.ok
    t = res["t"]
    th2 = np.pi / 4 + 2 * np.pi * t
    (th3, w3, al3), (th4, w4, al4) = four_bar(1.0, 3.5, 3.0, 4.0, th2, 2 * np.pi, 0.0)
    # the rocker's frame points from B to O4, opposite to the loop's O4 -> B
    assert angle_error(res["rocker.phi"], th4 + np.pi).max() < 1e-13
    assert angle_error(res["coupler.phi"], th3).max() < 1e-13
    assert rel_err(res["rocker.omega"], w4) < 1e-12
    assert rel_err(res["rocker.alpha"], al4) < 1e-11
    A = np.stack((np.cos(th2), np.sin(th2)), -1)
    e3 = np.stack((np.cos(th3), np.sin(th3)), -1)
    n3 = np.stack((-np.sin(th3), np.cos(th3)), -1)
    P = A + 3.5 / 2 * e3 + 1.0 * n3  # coupler point (0, 1) in the coupler frame
    np.testing.assert_allclose(res["coupler.P.x"], P[:, 0], atol=1e-13)
    np.testing.assert_allclose(res["coupler.P.y"], P[:, 1], atol=1e-13)


def test_crank_angle_is_not_wrapped(loads):
    mech = loads("""
        body crank { point A = (-1, 0) }
        joint A: revolute(ground.origin, crank.A)
        drive d: angle(crank) = 3*pi*t
        simulate t = 0 .. 2 step 0.01
        output crank.phi
    """)
    res = mech.simulate()
    np.testing.assert_allclose(res["crank.phi"], 3 * np.pi * res["t"], atol=1e-12)


def test_a_coarse_step_is_bridged_without_losing_the_branch(load_example):
    # 0.1 s steps turn the crank 1.26 rad each: more than a Taylor predictor can bridge
    res = load_example("slider_crank.mech").simulate(step=0.1)
    assert res.ok
    t = res["t"]
    x, v, a = slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * t, 4 * np.pi, 0.0)
    assert rel_err(res["slider.x"], x) < 1e-13


def test_velocities_and_accelerations_are_skipped_when_not_requested(loads, monkeypatch):
    import mechdsl.solve.run as solve

    mech = loads("""
        body crank { point A = (-1, 0) }
        joint A: revolute(ground.origin, crank.A)
        drive d: angle(crank) = t
        simulate t = 0 .. 1 step 0.001
        output crank.x
    """)
    kernels = mech.compile()
    assert kernels.system.order == 0
    calls = []
    real = solve.eq.acceleration_rhs
    monkeypatch.setattr(solve.eq, "acceleration_rhs",
                        lambda s, q, *a: calls.append(q.shape) or real(s, q, *a))
    res = solve.simulate(kernels)
    assert res.ok
    assert np.allclose(res["crank.x"], np.cos(res["t"]), atol=1e-12)
    # gamma is evaluated only where the predictors need it: at the last instant of each
    # block of the plain march, and at the nodes of the parallel-in-time march's levels (the
    # coarse instants, and every level_split-th), never at the instants only recorded
    opts = solve.SolverOptions()
    evaluated = sum(shape[1] for shape in calls)
    assert evaluated <= 1001 // opts.coarse_stride + 1001 // opts.level_split + len(calls)
    assert all(shape[1] <= solve.SolverOptions().max_block for shape in calls)
    calls.clear()
    res = solve.simulate(kernels, solve.SolverOptions(coarse_stride=1))
    assert all(shape[1] == 1 for shape in calls)
    assert len(calls) < 40


def test_unconverging_assembly_is_reported(loads):
    # a link of length 1 pinned at the origin cannot reach x = 3
    mech = loads("""
        body link { point O = (-0.5, 0)  point E = (0.5, 0) }
        joint pin: revolute(ground.origin, link.O)
        drive d: x(link.E) = 3
        simulate t = 0 .. 1 step 0.1
    """)
    res = mech.simulate()
    assert res.status == "failed"
    assert "cannot be assembled" in res.messages[0]
    assert res.n_solved[0] == 0


def test_tighter_newton_tolerance_is_honoured(load_example):
    res = load_example("slider_crank.mech").simulate(options=SolverOptions(newton_tol=1e-14))
    t = res["t"]
    x, _, _ = slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * t, 0, 0)
    assert rel_err(res["slider.x"], x) < 1e-14
