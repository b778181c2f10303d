"""Near lock-up, lock-up and change points: right answers, or a clear stop at the right
instant; never a silently wrong result."""

import numpy as np
import pytest

from closed_forms import slider_crank

EPS = np.finfo(float).eps
RODS = [2.1, 2.01, 2.001, 2.0001]


def rel_err(got, want):
    return np.abs(got - want).max() / np.abs(want).max()


@pytest.mark.parametrize("l", RODS)
def test_near_lock_up_degrades_gracefully(load_example, l):
    """The error against the closed form stays within 100 eps times the condition number."""
    res = load_example("slider_crank.mech").simulate(l=l)
    assert res.ok
    cond = res.condition[0]
    t = res["t"]
    x, v, a = slider_crank(2.0, l, np.pi / 4 + 4 * np.pi * t, 4 * np.pi, 0.0)
    for name, exact in (("slider.x", x), ("slider.vx", v), ("slider.ax", a)):
        assert rel_err(res[name], exact) <= 100 * cond * EPS, name


def test_the_condition_number_grows_as_the_rod_nears_the_crank(load_example):
    mech = load_example("slider_crank.mech")
    conds = [mech.simulate(l=l).condition[0] for l in RODS]
    assert all(a < b for a, b in zip(conds, conds[1:])), conds
    assert conds[0] > 10


def test_rod_as_long_as_the_crank_stops_at_the_dead_point(load_example):
    # at theta = pi/2 (t = 1/16) the slider meets the crank pivot: two ways to go on
    res = load_example("slider_crank.mech").simulate(l=2.0)
    assert res.status == "failed" and res.n_solved[0] == 63
    assert "t = 0.063 (instant 64 of 1001)" in res.messages[0]
    assert "singular position" in res.messages[0]


def test_rod_shorter_than_the_crank_stops_where_the_loop_opens(load_example):
    res = load_example("slider_crank.mech").simulate(l=1.5)
    t_star = (np.arcsin(1.5 / 2) - np.pi / 4) / (4 * np.pi)
    k = int(np.ceil(t_star / 0.001))
    assert res.status == "failed" and res.n_solved[0] == k
    message = res.messages[0]
    assert f"t = {k * 0.001:g} (instant {k + 1} of 1001)" in message
    assert "condition number" in message and "joint B (revolute, line 24: " in message
    t = res["t"]  # the instants before the lock-up are right
    x, _, _ = slider_crank(2.0, 1.5, np.pi / 4 + 4 * np.pi * t, 0, 0)
    np.testing.assert_allclose(res["slider.x"], x, atol=1e-12)


def test_a_parallelogram_stops_at_its_change_point_by_default(load_example):
    # b = d and c = a: at theta = pi (t = 0.375) all four links are collinear
    res = load_example("fourbar.mech").simulate(b=4.0, c=1.0)
    assert res.status == "failed" and res.n_solved[0] == 375
    assert "singular position at t = 0.375" in res.messages[0]
    th = np.pi / 4 + 2 * np.pi * res["t"]  # up to there the rocker turns with the crank
    np.testing.assert_allclose(np.cos(res["rocker.phi"]), np.cos(th + np.pi), atol=1e-9)


def test_a_parallelogram_continues_as_a_parallelogram_if_asked(load_example):
    from mechdsl.solve import SolverOptions

    res = load_example("fourbar.mech").simulate(
        b=4.0, c=1.0, options=SolverOptions(at_singular="continue"))
    assert res.ok
    t = res["t"]
    th = np.pi / 4 + 2 * np.pi * t
    # every bar stays parallel to its opposite: the rocker turns with the crank and the
    # coupler keeps its angle, through theta = pi (t = 0.375) and 2 pi (t = 0.875)
    np.testing.assert_allclose(np.cos(res["rocker.phi"] - th - np.pi), 1.0, atol=1e-12)
    np.testing.assert_allclose(res["coupler.phi"], 0.0, atol=1e-7)
    regular = np.abs(np.sin(th)) > 0.01
    np.testing.assert_allclose(res["rocker.omega"][regular], 2 * np.pi, atol=1e-9)
    np.testing.assert_allclose(res["rocker.omega"], 2 * np.pi, atol=1e-4)
    np.testing.assert_allclose(res["rocker.alpha"][regular], 0.0, atol=1e-6)
    assert any("passes singular positions near t = 0.375, 0.875" in w for w in res.warnings)


def test_three_crank_coupling_rods_have_mobility_one(load_example):
    """Redundant bar: Grubler counts 0 degrees of freedom, the rank says 1."""
    from mechdsl.solve import assemble
    from mechdsl.solve.diagnose import col_scale
    from mechdsl.solve.mobility import report

    mech = load_example("parallelogram.mech")
    kernels = mech.compile()
    asm = assemble(kernels, 0.0)
    mobility, rank, redundant = report(kernels.variant(0), asm.q[0],
                                       col_scale(kernels.system)[0, 0])
    assert (mobility, rank) == (1, 11)
    assert redundant == "joint A3 (1 of 2 equations, line 20)"


def test_three_crank_coupling_rods_follow_the_closed_form(load_example):
    from mechdsl.solve import SolverOptions

    res = load_example("parallelogram.mech").simulate(options=SolverOptions(at_singular="continue"))
    assert res.ok
    assert any("redundant constraints" in w for w in res.warnings)
    t = res["t"]
    th = np.pi / 4 + 2 * np.pi * t
    # exactly on a singular position the residual is quadratic in the error along the null
    # direction: positions are fixed there only to about sqrt(eps) of the size
    regular = np.abs(np.sin(th)) > 0.01
    np.testing.assert_allclose(res["coupler.x"], 2 + 0.5 * np.cos(th), atol=1e-12)
    np.testing.assert_allclose(res["coupler.y"][regular], 0.5 * np.sin(th[regular]), atol=1e-12)
    np.testing.assert_allclose(res["coupler.y"], 0.5 * np.sin(th), atol=3 * np.sqrt(np.finfo(float).eps))
    np.testing.assert_allclose(res["crank3.phi"][regular], th[regular], atol=1e-11)
    np.testing.assert_allclose(res["coupler.vx"], -np.pi * np.sin(th), atol=1e-6)
    np.testing.assert_allclose(res["coupler.ay"], -0.5 * (2 * np.pi) ** 2 * np.sin(th),
                               atol=1e-3)
