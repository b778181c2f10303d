"""The parallel-in-time march: its interpolating predictor, and that it changes neither the
answers nor where and how a run fails."""

import numpy as np
import pytest

from closed_forms import slider_crank
from mechdsl.solve.hermite import quintic_hermite
from mechdsl.solve import SolverOptions

PLAIN = SolverOptions(coarse_stride=1)


def rel_err(got, want):
    return np.abs(got - want).max() / np.abs(want).max()


def test_hermite_reproduces_a_quintic_exactly():
    rng = np.random.default_rng(3)
    coef = rng.normal(size=(6, 2))  # two coordinates, each a quintic in t
    tn = np.array([0.0, 0.3, 1.1, 1.5])  # uneven intervals

    def states(t):
        cols = [np.polyval(np.polyder(coef[:, j], d) if d else coef[:, j], t)
                for d in range(3) for j in range(2)]
        return [np.stack(cols[2 * d : 2 * d + 2], axis=-1)[None] for d in range(3)]

    t = np.linspace(0.0, 1.5, 61)
    got = quintic_hermite(tn, *states(tn), t)
    np.testing.assert_allclose(got, states(t)[0], atol=1e-13)


def test_hermite_error_falls_as_the_sixth_power_of_the_interval():
    def err(h):
        tn = np.arange(0.0, 1.0 + h / 2, h)
        s = [(np.sin(tn), np.cos(tn), -np.sin(tn))[d][None, :, None] for d in range(3)]
        t = np.linspace(0.0, tn[-1], 1001)
        return np.abs(quintic_hermite(tn, *s, t)[0, :, 0] - np.sin(t)).max()

    ratio = err(0.25) / err(0.125)
    assert 50 < ratio < 80  # 2^6 = 64


@pytest.mark.parametrize("stride, window", [(1, 4096), (3, 4096), (16, 100), (64, 4096),
                                            (500, 4096)])
def test_every_stride_gives_the_closed_form(load_example, stride, window):
    res = load_example("slider_crank.mech").simulate(
        options=SolverOptions(coarse_stride=stride, window=window))
    assert res.ok
    th = np.pi / 4 + 4 * np.pi * res["t"]
    for name, exact in zip(("slider.x", "slider.vx", "slider.ax"),
                           slider_crank(2.0, 3.5, th, 4 * np.pi, 0.0)):
        assert rel_err(res[name], exact) < 1e-13, name


@pytest.mark.parametrize("options", [PLAIN, SolverOptions(), SolverOptions(window=50)])
def test_a_lock_up_is_reported_at_the_same_instant(load_example, options):
    res = load_example("slider_crank.mech").simulate(l=1.5, options=options)
    t_star = (np.arcsin(1.5 / 2) - np.pi / 4) / (4 * np.pi)
    k = int(np.ceil(t_star / 0.001))
    assert res.status == "failed" and res.n_solved[0] == k
    assert f"t = {k * 0.001:g} (instant {k + 1} of 1001)" in res.messages[0]
    x, _, _ = slider_crank(2.0, 1.5, np.pi / 4 + 4 * np.pi * res["t"], 0, 0)
    np.testing.assert_allclose(res["slider.x"], x, atol=1e-12)


@pytest.mark.parametrize("options", [PLAIN, SolverOptions(window=50)])
def test_a_change_point_inside_a_window_still_stops_the_run(load_example, options):
    res = load_example("fourbar.mech").simulate(b=4.0, c=1.0, options=options)
    assert res.status == "failed" and res.n_solved[0] == 375
    assert "singular position at t = 0.375" in res.messages[0]


def test_a_sweep_with_one_failing_variant_keeps_the_others(load_example):
    res = load_example("slider_crank.mech").simulate(sweep={"l": [3.5, 1.5, 2.5]})
    t_star = (np.arcsin(1.5 / 2) - np.pi / 4) / (4 * np.pi)
    k = int(np.ceil(t_star / 0.001))
    assert list(res.n_solved) == [1001, k, 1001]
    th = np.pi / 4 + 4 * np.pi * res["t"]
    for v, l in ((0, 3.5), (2, 2.5)):
        x, vx, ax = slider_crank(2.0, l, th, 4 * np.pi, 0.0)
        assert rel_err(res["slider.x"][v], x) < 1e-13
        assert rel_err(res["slider.ax"][v], ax) < 1e-12


@pytest.mark.parametrize("value", [0.0, -1e-6, 0.5, float("nan")])
def test_the_coarse_tolerance_is_checked_where_it_is_set(value):
    with pytest.raises(ValueError, match="coarse_newton_tol"):
        SolverOptions(coarse_newton_tol=value)


def test_a_jacobian_with_a_nan_entry_is_singular():
    from mechdsl.solve.linalg import factor

    fac = factor(np.array([[np.nan, 1.0], [1.0, 1.0]])[None, None], np.ones((1, 1, 2)))
    assert fac.rcond[0, 0] == 0.0 and fac.sign[0, 0] == 0.0


def test_a_single_mechanism_is_predicted_from_its_coarse_states_without_levels(
        load_example, monkeypatch):
    """The coarse states of a single mechanism are solved exactly on floats: every instant is
    predicted from them directly, no level is solved, and the answers are the closed form."""
    from mechdsl.solve import run as run_module

    calls = {"level": 0}
    real = run_module.KinematicRun.level

    def counted(self, *args, **kwargs):
        calls["level"] += 1
        return real(self, *args, **kwargs)

    monkeypatch.setattr(run_module.KinematicRun, "level", counted)
    res = load_example("slider_crank.mech").simulate(options=SolverOptions(backend="numpy"))
    assert res.ok and calls["level"] == 0
    th = np.pi / 4 + 4 * np.pi * res["t"]
    for name, exact in zip(("slider.x", "slider.vx", "slider.ax"),
                           slider_crank(2.0, 3.5, th, 4 * np.pi, 0.0)):
        assert rel_err(res[name], exact) < 1e-13, name


def test_hermite_of_no_instant_is_empty_and_of_unordered_instants_is_refused():
    tn = np.linspace(0.0, 1.0, 5)
    q, qd, qdd = (np.ones((2, 5, 3)) for _ in range(3))
    assert quintic_hermite(tn, q, qd, qdd, np.zeros(0)).shape == (2, 0, 3)
    with pytest.raises(ValueError, match="increase"):
        quintic_hermite(tn, q, qd, qdd, np.array([0.9, 0.1, 0.95]))
