"""Per-variant reductions of output histories (``output max(abs(slider.ax)), stroke =
range(slider.x)``, ``simulate(reduce=...)``, ``mechdsl run --reduce``), checked against the
slider-crank's closed form, derived here by hand:

    theta = pi/4 + omega t,  x = r cos(theta) + D,  D = sqrt(l^2 - r^2 sin^2(theta))
    x'  = -r s - r^2 s c / D
    x'' = -r c - r^2 (c^2 - s^2) / D - r^4 s^2 c^2 / D^3      (' = d/dtheta, s, c of theta)
    vx = x' omega, ax = x'' omega^2 (omega constant)

At theta = 0: x = r + l, x'' = -r (1 + r/l), so |ax| = r omega^2 (1 + r/l); at theta = pi:
x = l - r. The time grid, step 1/1024 from t = 0, holds theta = pi (t = 3/16) and theta = 2 pi
(t = 7/16) exactly, and t = 0 .. 1/2 is exactly one crank revolution."""

import csv
import io
import subprocess
import sys

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import ellipe

from conftest import EXAMPLES, ROOT, model_meaning
from mechdsl.errors import MechError
from mechdsl.grammar import parse
from mechdsl.grammar.format import format_text
from mechdsl.outputs.csv import read_csv

SLIDER = (EXAMPLES / "slider_crank.mech").read_text()
OUTPUTS = "output slider.x, slider.vx, slider.ax"
R, L, OMEGA = 2.0, 3.5, 4 * np.pi
STEP = 1 / 1024
REV = 0.5  # one crank revolution, 2 pi / omega
OUTPUT_LINE = 32  # the line of the output statement in slider_crank.mech

trapezoid = getattr(np, "trapezoid", None) or np.trapz


# --- the closed form (independent truth) --------------------------------------------------

def continuous_max(f, t):
    """The maximum of f over [t_0, t_-1], not only at the samples t: a bounded search of
    the closed form between the neighbours of its largest sample (max, min and range are
    found between the samples: mechdsl.solve.extrema)."""
    from scipy.optimize import minimize_scalar

    y = f(t)
    k = int(np.argmax(y))
    best = minimize_scalar(lambda s: -f(np.array([s]))[0], method="bounded",
                           bounds=(t[max(k - 1, 0)], t[min(k + 1, len(t) - 1)]),
                           options={"xatol": 1e-13})
    return max(-best.fun, y[k])


def theta_of(t):
    return np.pi / 4 + OMEGA * np.asarray(t, dtype=float)


def x_of(theta, r=R, l=L):
    return r * np.cos(theta) + np.sqrt(l * l - (r * np.sin(theta)) ** 2)


def x_th(theta, r=R, l=L):
    s, c = np.sin(theta), np.cos(theta)
    D = np.sqrt(l * l - r * r * s * s)
    return -r * s - r * r * s * c / D


def x_thth(theta, r=R, l=L):
    s, c = np.sin(theta), np.cos(theta)
    D = np.sqrt(l * l - r * r * s * s)
    return -r * c - r * r * (c * c - s * s) / D - r**4 * s * s * c * c / D**3


def vx_of(t, r=R, l=L):
    return x_th(theta_of(t), r, l) * OMEGA


def ax_of(t, r=R, l=L):
    return x_thth(theta_of(t), r, l) * OMEGA**2


def peak_ax(r=R, l=L):
    return r * OMEGA**2 * (1 + r / l)


def grid(t0, t1, step=STEP):
    n = round((t1 - t0) / step)
    assert abs(t0 + n * step - t1) < 1e-15
    return t0 + np.arange(n + 1) * step


def with_outputs(line: str, extra: str = "") -> str:
    assert OUTPUTS in SLIDER
    return SLIDER.replace(OUTPUTS, line + extra)


def mechdsl(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd or ROOT, timeout=120)


# --- the truth itself ---------------------------------------------------------------------

def test_the_closed_form_derivatives_are_those_of_x():
    theta = np.linspace(0, 2 * np.pi, 97)
    for l in (2.5, 3.0, 3.5, 4.0):
        h = 1e-5
        d1 = (x_of(theta + h, l=l) - x_of(theta - h, l=l)) / (2 * h)
        np.testing.assert_allclose(x_th(theta, l=l), d1, atol=1e-8)
        h = 1e-4
        d2 = (x_of(theta + h, l=l) - 2 * x_of(theta, l=l) + x_of(theta - h, l=l)) / h**2
        np.testing.assert_allclose(x_thth(theta, l=l), d2, atol=1e-6)
        # at theta = 0 and pi: the extremes of x and the peak of x''
        assert x_of(0.0, l=l) == pytest.approx(R + l, rel=1e-15)
        assert x_of(np.pi, l=l) == pytest.approx(l - R, rel=1e-15)
        assert x_thth(0.0, l=l) == pytest.approx(-R * (1 + R / l), rel=1e-15)


@pytest.mark.parametrize("l", [2.5, 3.0, 3.5, 4.0])
def test_the_peak_acceleration_is_at_theta_zero(l):
    theta = np.linspace(-np.pi, np.pi, 2_000_001)  # theta = 0 at the middle
    a = np.abs(x_thth(theta, l=l)) * OMEGA**2
    assert np.argmax(a) == len(theta) // 2
    assert a.max() == pytest.approx(peak_ax(l=l), rel=1e-14)


def test_the_grid_holds_the_dead_centres():
    t = grid(0, REV)
    assert len(t) == 513
    assert 3 / 16 in t and 7 / 16 in t
    assert np.isclose(theta_of(3 / 16), np.pi, rtol=0, atol=1e-15)
    assert np.isclose(theta_of(7 / 16), 2 * np.pi, rtol=0, atol=1e-15)


# --- the reductions' values ---------------------------------------------------------------

@pytest.fixture
def one_rev(load_example):
    """The reductions over one crank revolution, t = 0 .. 1/2 step 1/1024."""
    mech = load_example("slider_crank.mech")
    res = mech.simulate(span=(0, REV), step=STEP, reduce=(
        "max(slider.x), min(slider.x), stroke = range(slider.x), max(abs(slider.ax)), "
        "mean(slider.x), rms(slider.vx), initial(slider.x), final(slider.x), "
        "ta = argmax(slider.x), argmin(slider.x), q = range(slider.x) / r, "
        "p = max(slider.x) - min(slider.x) + r"))
    return res


def test_reduced_results_replace_the_histories(one_rev):
    assert one_rev.data == {} or len(one_rev.data) == 0
    assert list(one_rev.reduced) == [
        "max(slider.x)", "min(slider.x)", "stroke", "max(abs(slider.ax))", "mean(slider.x)",
        "rms(slider.vx)", "initial(slider.x)", "final(slider.x)", "ta", "argmin(slider.x)",
        "q", "p"]
    for v in one_rev.reduced.values():
        assert np.shape(v) == (1,)
    np.testing.assert_array_equal(one_rev.times, grid(0, REV))
    assert list(one_rev.n_solved) == [513]


def test_extremes_and_stroke_are_the_dead_centres(one_rev):
    red = one_rev.reduced
    assert red["max(slider.x)"][0] == pytest.approx(R + L, rel=1e-12)
    assert red["min(slider.x)"][0] == pytest.approx(L - R, rel=1e-12)
    assert red["stroke"][0] == pytest.approx(2 * R, rel=1e-12)


def test_peak_acceleration_is_the_closed_form(one_rev):
    assert one_rev.reduced["max(abs(slider.ax))"][0] == pytest.approx(peak_ax(), rel=1e-10)


def test_mean_over_a_revolution_is_the_trapezoid_rule_and_the_exact_average(one_rev):
    t = grid(0, REV)
    trap = trapezoid(x_of(theta_of(t)), t) / REV
    got = one_rev.reduced["mean(slider.x)"][0]
    assert got == pytest.approx(trap, rel=1e-13)
    # the exact average over the revolution: by quadrature, and as the elliptic integral
    # (mean of r cos is 0; mean of sqrt(l^2 - r^2 sin^2) is (2/pi) l E(r^2/l^2))
    exact = quad(lambda th: x_of(th), np.pi / 4, np.pi / 4 + 2 * np.pi, epsabs=1e-13,
                 epsrel=1e-13, limit=200)[0] / (2 * np.pi)
    assert exact == pytest.approx(2 / np.pi * L * ellipe(R * R / (L * L)), rel=1e-13)
    # the trapezoid rule over a whole period of a smooth periodic function: spectrally exact
    assert abs(trap - exact) < 1e-12
    assert abs(got - exact) <= abs(trap - exact) + 1e-12


def test_rms_over_a_revolution_is_the_trapezoid_rule_and_the_exact_rms(one_rev):
    t = grid(0, REV)
    v = vx_of(t)
    trap = np.sqrt(trapezoid(v * v, t) / REV)
    got = one_rev.reduced["rms(slider.vx)"][0]
    assert got == pytest.approx(trap, rel=1e-12)
    exact = np.sqrt(quad(lambda th: (x_th(th) * OMEGA) ** 2, np.pi / 4, np.pi / 4 + 2 * np.pi,
                         epsabs=1e-11, epsrel=1e-13, limit=200)[0] / (2 * np.pi))
    assert abs(trap - exact) < 1e-10 * exact
    assert got == pytest.approx(exact, rel=1e-10)


def test_initial_and_final_over_a_revolution(one_rev):
    x0 = x_of(np.pi / 4)
    assert one_rev.reduced["initial(slider.x)"][0] == pytest.approx(x0, rel=1e-13)
    assert one_rev.reduced["final(slider.x)"][0] == pytest.approx(x0, rel=1e-13)


def test_argmax_and_argmin_are_the_dead_centre_instants(one_rev):
    # the first theta = 2 pi k (max x) is at t = 7/16, theta = pi (min x) at t = 3/16
    assert one_rev.reduced["ta"][0] == 7 / 16
    assert one_rev.reduced["argmin(slider.x)"][0] == 3 / 16


def test_reductions_combined_with_params(one_rev):
    assert one_rev.reduced["q"][0] == pytest.approx(2.0, rel=1e-12)
    assert one_rev.reduced["p"][0] == pytest.approx(3 * R, rel=1e-12)


def test_units_of_reductions(one_rev):
    units = one_rev.units
    assert units["stroke"] == "m" and units["max(slider.x)"] == "m"
    assert units["mean(slider.x)"] == "m" and units["rms(slider.vx)"] == "m/s"
    assert units["ta"] == "s" and units["argmin(slider.x)"] == "s"
    # a reduction combined with a param is not a plain quantity's
    assert "q" not in units or not units["q"]


def test_mean_initial_final_on_a_part_of_the_run(load_example):
    # t = 1/8 .. 7/16: not a period, and not from 0: the mean divides the trapezoid rule by
    # t1 - t0, which differs here from the plain average of the samples
    t0, t1 = 0.125, 7 / 16
    res = load_example("slider_crank.mech").simulate(
        span=(t0, t1), step=STEP,
        reduce="mean(slider.x), initial(slider.x), final(slider.x), rms(slider.ax)")
    t = grid(t0, t1)
    np.testing.assert_array_equal(res.times, t)
    x = x_of(theta_of(t))
    trap = trapezoid(x, t) / (t1 - t0)
    got = res.reduced["mean(slider.x)"][0]
    assert got == pytest.approx(trap, rel=1e-13)
    assert abs(np.mean(x) - trap) > 1e-4  # the test tells the two apart
    assert abs(trapezoid(x, t) / t1 - trap) > 1e-1
    # and close to the exact average, within the trapezoid rule's error (h^2/12 max|x_tt|)
    exact = quad(lambda s: x_of(theta_of(s)), t0, t1, epsabs=1e-14, epsrel=1e-14)[0] / (t1 - t0)
    bound = STEP**2 / 12 * np.abs(ax_of(np.linspace(t0, t1, 10001))).max()
    assert abs(got - exact) <= bound
    assert res.reduced["initial(slider.x)"][0] == pytest.approx(x_of(theta_of(t0)), rel=1e-13)
    assert res.reduced["final(slider.x)"][0] == pytest.approx(R + L, rel=1e-13)
    a = ax_of(t)
    assert res.reduced["rms(slider.ax)"][0] == pytest.approx(
        np.sqrt(trapezoid(a * a, t) / (t1 - t0)), rel=1e-10)


def test_argmax_and_argmin_take_the_first_of_equal_values(load_example):
    # cos(omega t) over t = 0 .. 1 is exactly 1 at t = 0, 1/2, 1 and exactly -1 at t = 1/4,
    # 3/4 (checked here on the grid): the first instant of each
    t = grid(0, 1)
    c = np.cos(OMEGA * t)
    assert list(np.flatnonzero(c == c.max())) == [0, 512, 1024]
    assert list(np.flatnonzero(c == c.min())) == [256, 768]
    res = load_example("slider_crank.mech").simulate(
        span=(0, 1), step=STEP, reduce="argmax(cos(omega*t)), argmin(cos(omega*t))")
    assert res.reduced["argmax(cos(omega*t))"][0] == 0.0
    assert res.reduced["argmin(cos(omega*t))"][0] == 0.25


def test_max_with_two_arguments_stays_elementwise_inside_a_reduction(load_example):
    res = load_example("slider_crank.mech").simulate(
        span=(0, REV), step=STEP, reduce="m = max(max(slider.x, slider.vx)), "
                                         "n = min(min(slider.x, slider.vx))")
    t = grid(0, REV)
    assert res.reduced["m"][0] == pytest.approx(
        continuous_max(lambda s: np.maximum(x_of(theta_of(s)), vx_of(s)), t), rel=1e-12)
    assert res.reduced["n"][0] == pytest.approx(
        -continuous_max(lambda s: -np.minimum(x_of(theta_of(s)), vx_of(s)), t), rel=1e-12)


def test_a_two_argument_max_in_a_file_is_a_history(loads):
    res = loads(with_outputs("output m = max(slider.x, slider.vx)")).simulate(
        span=(0, REV), step=1 / 64)
    assert not res.reduced and "m" in res.data
    t = grid(0, REV, 1 / 64)
    np.testing.assert_allclose(res["m"], np.maximum(x_of(theta_of(t)), vx_of(t)), rtol=1e-12)


def test_reductions_written_in_the_file(loads):
    text = with_outputs("output max(abs(slider.ax)), stroke = range(slider.x), "
                        "ta = argmax(slider.x)")
    res = loads(text).simulate(span=(0, REV), step=STEP)
    assert list(res.reduced) == ["max(abs(slider.ax))", "stroke", "ta"]
    assert res.reduced["max(abs(slider.ax))"][0] == pytest.approx(peak_ax(), rel=1e-10)
    assert res.reduced["stroke"][0] == pytest.approx(2 * R, rel=1e-12)
    assert res.reduced["ta"][0] == 7 / 16


# --- sweeps -------------------------------------------------------------------------------

LS = [2.5, 3.0, 3.5, 4.0]


def check_sweep_row(l, peak, stroke, ta, mean):
    t = grid(0, REV)
    assert peak == pytest.approx(peak_ax(l=l), rel=1e-10)
    assert stroke == pytest.approx(2 * R, rel=1e-12)
    assert ta == 7 / 16
    assert mean == pytest.approx(trapezoid(x_of(theta_of(t), l=l), t) / REV, rel=1e-13)
    assert mean == pytest.approx(2 / np.pi * l * ellipe(R * R / (l * l)), rel=1e-12)


def test_a_sweep_reduces_each_variant(load_example):
    res = load_example("slider_crank.mech").simulate(
        span=(0, REV), step=STEP, sweep={"l": LS},
        reduce="max(abs(slider.ax)), stroke = range(slider.x), ta = argmax(slider.x), "
               "mean(slider.x), k = range(slider.x) / l")
    np.testing.assert_array_equal(res.sweep["l"], LS)
    for v in res.reduced.values():
        assert np.shape(v) == (4,)
    for k, l in enumerate(LS):
        check_sweep_row(l, res.reduced["max(abs(slider.ax))"][k], res.reduced["stroke"][k],
                        res.reduced["ta"][k], res.reduced["mean(slider.x)"][k])
        assert res.reduced["k"][k] == pytest.approx(2 * R / l, rel=1e-12)


def test_a_grid_of_two_swept_params_reduces_each_combination(load_example):
    res = load_example("slider_crank.mech").simulate(
        span=(0, REV), step=STEP, sweep={"l": [3.0, 4.0], "r": [1.0, 2.0]},
        reduce="peak = max(abs(slider.ax)), p = max(slider.x) - l")
    ls, rs = np.asarray(res.sweep["l"]), np.asarray(res.sweep["r"])
    assert sorted(zip(ls, rs)) == [(3.0, 1.0), (3.0, 2.0), (4.0, 1.0), (4.0, 2.0)]
    for k, (l, r) in enumerate(zip(ls, rs)):
        assert res.reduced["peak"][k] == pytest.approx(peak_ax(r, l), rel=1e-10)
        assert res.reduced["p"][k] == pytest.approx(r, rel=1e-12)


PER_VARIANT = "# one row per variant; swept params: "


def read_reduced_csv(text):
    """Header, units line (or None), rows of a CSV of reductions, read by the csv module; the
    header comes first (numpy's names=True reads it), and a comment before the rows says
    they are variants and names the swept params, which lead the header."""
    lines = list(csv.reader(io.StringIO(text)))
    header = lines[0]
    comments = [ln for ln in text.splitlines() if ln.startswith("#")]
    first = next(c for c in comments if c.startswith(PER_VARIANT))
    swept = [s for s in first[len(PER_VARIANT):].split(", ") if s]
    assert header[:len(swept)] == swept
    units = [c for c in comments if c.startswith("# units")]
    rows = [r for r in lines[1:] if not r[0].startswith("#")]
    return header, units, np.array(rows, dtype=float)


def test_the_cli_writes_one_row_per_variant(tmp_path):
    mech = tmp_path / "sweep.mech"
    mech.write_text(with_outputs(
        "output max(abs(slider.ax)), stroke = range(slider.x), ta = argmax(slider.x)",
        "\nsweep l = [2.5, 3, 3.5, 4]\n").replace(
        "simulate t = 0 .. 1 step 0.001", "simulate t = 0 .. 0.5 step 1/1024"))
    out = tmp_path / "out.csv"
    r = mechdsl("run", mech, "-o", out, "-q")
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    assert len(text.splitlines()) == 7  # header, units, per-variant line, 4 rows
    header, units, rows = read_reduced_csv(text)
    assert header == ["l", "max(abs(slider.ax))", "stroke", "ta"]
    assert units == ["# units: l, max(abs(slider.ax)) [m/s^2], stroke [m], ta [s]"]
    assert text.splitlines()[1] == units[0]
    assert text.splitlines()[2] == PER_VARIANT + "l"
    # the README's recipes read it as written
    np.testing.assert_array_equal(np.loadtxt(out, delimiter=",", skiprows=1), rows)
    table = np.genfromtxt(out, delimiter=",", names=True)
    assert table.dtype.names == ("l", "maxabssliderax", "stroke", "ta")
    np.testing.assert_array_equal(table["stroke"], rows[:, 2])
    # and it reads back as a table of reductions (mechdsl plot draws it)
    back = read_csv(str(out))
    np.testing.assert_array_equal(back.sweep["l"], rows[:, 0])
    np.testing.assert_array_equal(back.reduced["stroke"], rows[:, 2])
    assert back.units == {"max(abs(slider.ax))": "m/s^2", "stroke": "m", "ta": "s"}
    assert rows.shape == (4, 4)
    np.testing.assert_array_equal(rows[:, 0], LS)
    for l, peak, stroke, ta in rows:
        assert peak == pytest.approx(peak_ax(l=l), rel=1e-10)
        assert stroke == pytest.approx(2 * R, rel=1e-12)
        assert ta == 7 / 16


def test_the_cli_reduce_option_replaces_the_outputs():
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--t1", "0.5", "--step", repr(STEP),
                "--sweep", "l=2.5,3,3.5,4", "-o", "-",
                "--reduce", "max(abs(slider.ax)), stroke = range(slider.x)",
                "--reduce", "ta = argmax(slider.x), mean(slider.x)")
    assert r.returncode == 0, r.stderr
    header, units, rows = read_reduced_csv(r.stdout)
    assert header == ["l", "max(abs(slider.ax))", "stroke", "ta", "mean(slider.x)"]
    assert units == ["# units: l, max(abs(slider.ax)) [m/s^2], stroke [m], ta [s], "
                     "mean(slider.x) [m]"]
    assert rows.shape == (4, 5)
    for l, peak, stroke, ta, mean in rows:
        check_sweep_row(l, peak, stroke, ta, mean)


def test_an_unnamed_reduction_with_a_comma_must_be_named():
    # an unnamed reduction is labelled by its text, the name of its CSV column: a comma in
    # it (a two-argument max inside) would split the column, so it is refused, located
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--t1", "0.5", "--step", repr(STEP),
                "--sweep", "l=3,3.5", "-o", "-",
                "--reduce", "max(max(slider.x, slider.vx)), stroke = range(slider.x)")
    assert r.returncode == 1
    assert r.stderr.startswith("--reduce:1:1: error: max(max(slider.x, slider.vx)): name "
                               "this output (output NAME = ...)")
    named = mechdsl("run", EXAMPLES / "slider_crank.mech", "--t1", "0.5", "--step", repr(STEP),
                    "--sweep", "l=3,3.5", "-o", "-",
                    "--reduce", "top = max(max(slider.x, slider.vx)), stroke = range(slider.x)")
    assert named.returncode == 0, named.stderr
    header, _, rows = read_reduced_csv(named.stdout)
    assert header == ["l", "top", "stroke"]
    t = grid(0, 0.5)
    for l, top, stroke in rows:
        expected = continuous_max(lambda s: np.maximum(x_of(theta_of(s), l=l), vx_of(s, l=l)),
                                  t)
        assert top == pytest.approx(expected, rel=1e-12)
        assert stroke == pytest.approx(2 * R, rel=1e-12)


def test_the_cli_plots_reductions_against_the_swept_param(tmp_path):
    png = tmp_path / "red.png"
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--t1", "0.5", "--step", "0.01",
                "--sweep", "l=2.5,3,3.5,4", "--reduce", "stroke = range(slider.x)",
                "--plot", png, "-q")
    assert r.returncode == 0, r.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# --- variants that fail -------------------------------------------------------------------

def test_a_variant_that_fails_reduces_to_nan(load_example):
    # l = 1: cannot assemble at t = 0 (r sin(pi/4) > l); l = 1.5: locks up when
    # r sin(theta) reaches l, early in the run; l = 3.5 runs through
    res = load_example("slider_crank.mech").simulate(
        span=(0, REV), step=STEP, sweep={"l": [1.0, 1.5, 3.5]},
        reduce="max(abs(slider.ax)), stroke = range(slider.x), ta = argmax(slider.x), "
               "initial(slider.x), q = range(slider.x) / r")
    assert list(res.n_solved[:2]) != [513, 513] and res.n_solved[2] == 513
    assert 0 < res.n_solved[1] < 513  # the lock-up is mid-run: a partial history
    for label, v in res.reduced.items():
        assert np.isnan(v[0]) and np.isnan(v[1]), label
        assert np.isfinite(v[2]), label
    assert res.reduced["max(abs(slider.ax))"][2] == pytest.approx(peak_ax(), rel=1e-10)
    assert res.reduced["stroke"][2] == pytest.approx(2 * R, rel=1e-12)
    assert res.reduced["ta"][2] == 7 / 16
    assert res.reduced["initial(slider.x)"][2] == pytest.approx(x_of(np.pi / 4), rel=1e-13)
    assert res.reduced["q"][2] == pytest.approx(2.0, rel=1e-12)


def test_the_cli_writes_nan_for_a_failed_variant():
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--t1", "0.5", "--step", repr(STEP),
                "--sweep", "l=1.5,3.5", "-o", "-", "--reduce", "stroke = range(slider.x)")
    assert r.returncode == 2  # a numerical failure
    _, _, rows = read_reduced_csv(r.stdout)
    assert rows.shape == (2, 2)
    assert np.isnan(rows[0, 1]) and rows[1, 1] == pytest.approx(2 * R, rel=1e-12)


# --- mistakes -----------------------------------------------------------------------------

@pytest.mark.parametrize("line, column, message", [
    ("output q = max(slider.x) - slider.x", 28, "'slider.x' is outside a reduction"),
    ("output q = max(slider.x) + t", 28, "'t' is outside a reduction"),
    ("output q = max(max(slider.x))", 12, "a reduction inside max()"),
    ("output q = mean(abs(min(slider.x)))", 12, "a reduction inside mean()"),
    ("output sin(slider.x)", 8, "sin(slider.x): only a reduction"),
    ("output slider.x, max(slider.x)", 8, "output 'slider.x' is a history"),
    ("output max(slider.x), slider.x", 23, "output 'slider.x' is a history"),
    ("output q = max(slider.x), v = slider.vx", 27, "output 'v' is a history"),
    ("output q = mean(slider.x, slider.vx)", 12, "mean() takes one expression"),
    ("output q = max(slider.x), q = min(slider.x)", 27, "output 'q' is requested twice"),
    ("output q = max(slidr.x)", 16, "unknown body 'slidr'"),
])
def test_mistakes_in_reductions_are_located(loads, line, column, message):
    with pytest.raises(MechError) as err:
        loads(with_outputs(line)).simulate(step=0.25)
    assert (err.value.line, err.value.column) == (OUTPUT_LINE, column), err.value.message
    assert err.value.message.startswith(message), err.value.message


def test_a_mistake_in_a_file_exits_1_located(tmp_path):
    bad = tmp_path / "bad.mech"
    bad.write_text(with_outputs("output q = max(max(slider.x))"))
    r = mechdsl("run", bad)
    assert r.returncode == 1
    assert r.stderr.splitlines()[0].startswith(
        f"{bad}:{OUTPUT_LINE}:12: error: a reduction inside max()")
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("reduce, location, message", [
    ("slider.x", "--reduce:1:1", "'slider.x' is not a reduction"),
    ("max(slidr.x)", "--reduce:1:5", "unknown body 'slidr'"),
    ("stroke = range(slider.x), max(slidr.x)", "--reduce:1:31", "unknown body 'slidr'"),
    ("q = max(slider.x) - slider.x", "--reduce:1:21", "'slider.x' is outside a reduction"),
])
def test_mistakes_in_the_reduce_option_are_located_in_it(reduce, location, message):
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--reduce", reduce)
    assert r.returncode == 1
    assert r.stderr.startswith(f"{location}: error: {message}"), r.stderr
    assert "Traceback" not in r.stderr


def test_mistakes_in_the_reduce_argument_are_located_in_it(load_example):
    mech = load_example("slider_crank.mech")
    with pytest.raises(MechError) as err:
        mech.simulate(step=0.25, reduce="max(slidr.x)")
    assert (err.value.line, err.value.column) == (1, 5)
    assert err.value.message.startswith("unknown body 'slidr'")
    assert "--reduce:1:5" in str(err.value) or err.value.source.name == "--reduce"
    with pytest.raises(MechError, match="'slider.x' is not a reduction"):
        mech.simulate(step=0.25, reduce="slider.x")


@pytest.mark.parametrize("option, message", [
    (["--snapshot", "s.png"], "--snapshot draws the motion"),
    (["--animate", "a.gif"], "--animate draws the motion"),
    (["--export", "e.vtu"], "--export draws the motion"),
    (["--plot", "p.png"], "--plot: the outputs are reductions"),
])
def test_options_that_need_histories_are_refused(tmp_path, option, message):
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--reduce", "max(slider.x)", *option,
                cwd=tmp_path)
    assert r.returncode == 1
    assert message in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / option[1]).exists()


# --- fmt ----------------------------------------------------------------------------------



@pytest.mark.parametrize("line", [
    "output max(abs(slider.ax)), stroke = range(slider.x)",
    "output   max( abs(slider.ax) ) ,stroke=range( slider.x )",
    "output q = max(slider.x)-min(slider.x)+r,argmax(slider.x)",
    "output max(abs(slider.ax)),\n  stroke = range(slider.x) # the stroke",
])
def test_fmt_keeps_reductions_and_is_idempotent(line):
    text = with_outputs(line)
    once = format_text(text, "r.mech")
    assert format_text(once, "r.mech") == once
    assert model_meaning(parse(once, "o.mech")) == model_meaning(parse(text, "t.mech"))
    # the reductions are there, unchanged
    outputs = parse(once, "o.mech").outputs
    assert all(type(o).__name__ == "ReducedOutput" for o in outputs)


def test_fmt_writes_reductions_canonically():
    once = format_text(with_outputs("output   max( abs(slider.ax) ) ,stroke=range( slider.x )"))
    assert "\noutput max(abs(slider.ax)), stroke = range(slider.x)\n" in once
