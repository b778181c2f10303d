"""Extremes found between the samples (issue 30): max, min, argmax, argmin and range of a
kinematic run equal the closed forms, not the samples' (mechdsl.solve.extrema)."""

import math

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar

from closed_forms import slider_crank
from conftest import EXAMPLES
from mechdsl.solve.options import SolverOptions

R, L, OMEGA = 2.0, 3.5, 4 * np.pi
PEAKS = "peak = max(abs(slider.ax)), stroke = range(slider.x), " \
        "tx = argmax(slider.x), tn = argmin(slider.x)"


def peak_ax(r: float, l: float) -> float:
    """max |x''| omega^2 over a revolution, by a bounded search on each of many brackets
    (to 1e-14 in the angle): independent of the program."""
    def f(th):
        return -abs(slider_crank(r, l, th, OMEGA, 0.0)[2])
    edges = np.linspace(0, 2 * np.pi, 65)
    return max(-minimize_scalar(f, bounds=(a, b), method="bounded",
                                options={"xatol": 1e-14}).fun for a, b in zip(edges, edges[1:]))


@pytest.mark.parametrize("step", [0.001, 0.05])
def test_the_seeds_extremes_equal_the_closed_forms_between_samples(load_example, step):
    """At 1001 instants the samples miss the peak of |ax| by 3.4e-5 relative and the stroke by
    2e-5; at 21 by 2e-2: refined, both equal the closed forms to 1e-12, and the instants of
    the slider's dead centres (theta = 2 pi and 3 pi) are found to 1e-9 s."""
    mech = load_example("slider_crank.mech")
    res = mech.simulate(step=step, reduce=PEAKS)
    assert res.refined == ("peak", "stroke", "tx", "tn")
    assert res.reduced["peak"][0] == pytest.approx(peak_ax(R, L), rel=1e-12)
    assert res.reduced["stroke"][0] == pytest.approx(2 * R, rel=1e-12)
    # x is largest at theta = 2 pi (t = 7/16), smallest at theta = pi and 3 pi (the first)
    assert res.reduced["tx"][0] == pytest.approx(7 / 16, abs=1e-9)
    assert res.reduced["tn"][0] == pytest.approx(3 / 16, abs=1e-9)
    sampled = mech.simulate(step=step, reduce=PEAKS,
                            options=SolverOptions(refine_extrema=False))
    assert sampled.refined == ()
    assert sampled.reduced["peak"][0] < peak_ax(R, L) * (1 - 1e-5)
    assert sampled.reduced["stroke"][0] < 2 * R * (1 - 1e-5)


def test_every_variant_of_a_sweep_has_its_own_extremes(load_example):
    ls = [2.5, 3.0, 4.0]
    res = load_example("slider_crank.mech").simulate(step=0.01, sweep={"l": ls},
                                                     reduce="peak = max(abs(slider.ax))")
    for l, peak in zip(res.sweep["l"], res.reduced["peak"]):
        assert peak == pytest.approx(peak_ax(R, l), rel=1e-12)


def test_min_of_angles_reported_in_degrees(loads):
    """The rod's angle swings between -asin(r/l) and asin(r/l): refined in radians, reported
    in degrees."""
    text = (EXAMPLES / "slider_crank.mech").read_text().replace(
        'units length = "m", time = "s"', 'units length = "m", time = "s", angle = "deg"')
    res = loads(text).simulate(step=0.05, reduce="lo = min(rod.phi), hi = max(rod.phi)")
    swing = math.degrees(math.asin(R / L))
    assert res.reduced["lo"][0] == pytest.approx(-swing, rel=1e-12)
    assert res.reduced["hi"][0] == pytest.approx(swing, rel=1e-12)


def test_the_stroke_optimisation_reaches_the_closed_form_optimum(load_example):
    """examples/offset_stroke.mech: the smallest guide offset e with a stroke of 2.1 solves
    sqrt((l + r)^2 - e^2) - sqrt((l - r)^2 - e^2) = 2.1. Of the samples (51 instants), the
    optimiser finds 7.5e-3 too large an offset."""
    def stroke(e):
        return math.sqrt(16 - e * e) - math.sqrt(4 - e * e)
    exact = brentq(lambda e: stroke(e) - 2.1, 0, 1.5, xtol=1e-15)
    best = load_example("offset_stroke.mech").optimize()
    assert best.params["e"] == pytest.approx(exact, abs=1e-9)
    sampled = load_example("offset_stroke.mech").optimize(
        options=SolverOptions(refine_extrema=False))
    assert abs(sampled.params["e"] - exact) > 1e-3


def test_the_summary_says_which_extremes_were_refined(load_example):
    from mechdsl.results import summary

    res = load_example("slider_crank.mech").simulate(
        step=0.01, reduce="peak = max(abs(slider.ax)), mean(slider.x)")
    text = summary(res)
    assert "extremes found between the samples: peak" in text
    assert "of the samples: mean(slider.x)" in text


def test_a_forward_dynamics_extremes_between_samples_equal_the_damped_oscillators():
    """On the integrator's dense output (integrated again around each candidate): the damped
    oscillator's first minimum x(pi / omega_d) and the largest velocity, within the run's
    tolerance of the closed form, at 31 output instants that miss both by 1e-2."""
    import mechdsl
    from test_dissipation import DAMPED, C, K, M, oscillator

    text = DAMPED.replace("step 0.01", "step 0.1").replace(
        "output block.x, kinetic_energy, potential_energy, dissipated_power, dissipated_energy",
        "output lo = min(block.x), tmin = argmin(block.x), hi = max(block.vx), "
        "thi = argmax(block.vx)")
    mech = mechdsl.loads(text)
    res = mech.simulate()
    assert res.refined == ("lo", "tmin", "hi", "thi")
    w0, z = np.sqrt(K / M), C / (2 * np.sqrt(K * M))
    t_min = np.pi / (w0 * np.sqrt(1 - z * z))
    assert res.reduced["lo"][0] == pytest.approx(oscillator(np.array([t_min]))[0][0], abs=1e-9)
    assert res.reduced["tmin"][0] == pytest.approx(t_min, abs=1e-8)
    best = minimize_scalar(lambda t: -oscillator(np.array([t]))[1][0], bounds=(0.5, 1.5),
                           method="bounded", options={"xatol": 1e-13})
    assert res.reduced["hi"][0] == pytest.approx(-best.fun, abs=1e-9)
    assert res.reduced["thi"][0] == pytest.approx(best.x, abs=1e-8)
    sampled = mech.simulate(options=SolverOptions(refine_extrema=False))
    assert abs(sampled.reduced["lo"][0] - res.reduced["lo"][0]) > 1e-3
