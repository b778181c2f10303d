"""The ``optimize`` / ``minimize`` / ``maximize`` / ``subject to`` statements and
``mechdsl optimize``, checked against designs known independently of the program.

Slider-crank (examples/slider_crank.mech), derived by hand:

    theta = pi/4 + omega t,  x = r cos(theta) + sqrt(l^2 - r^2 sin^2(theta))
    x'' = -r c - r^2 (c^2 - s^2) / D - r^4 s^2 c^2 / D^3,  ax = x'' omega^2

At theta = 0 (x = r + l) the acceleration peaks, |ax| = r omega^2 (1 + r/l); at theta = pi,
x = l - r, so the stroke is 2r. The time grid here, t = 0 .. 1/2 step 1/64, holds theta = pi
(t = 3/16 = 12/64) and theta = 2 pi (t = 7/16 = 28/64) exactly, and the grid does not depend
on the params, so for every (l, r) the sampled max |ax| is >= r omega^2 (1 + r/l) and the
sampled stroke is exactly 2r. Minimising max|ax| subject to stroke >= 4 and l >= 2r over
l in 2.5 .. 6, r in 1 .. 3: feasibility is r >= 2, l >= 2r; r (1 + r/l) grows with r and
falls with l, so the optimum is r = 2, l = 6, objective 2 omega^2 (1 + 1/3), met exactly by
the sampled problem too.

Coupler synthesis (examples/coupler_synthesis.mech): the five targets lie on the coupler curve
of c = 3.1, h = 1.25; checked here with a loop closure written independently of the program.
"""

from __future__ import annotations

import csv
import re
import subprocess
import sys

import numpy as np
import pytest

from conftest import EXAMPLES, ROOT, model_meaning
from mechdsl.compiled.variants import Overrides
from mechdsl.errors import MechError
from mechdsl.grammar import parse
from mechdsl.grammar.format import format_text
from mechdsl.study.optimize import REQUIRE_TOL, Optimum, optimize

OMEGA = 4 * np.pi
STEP = 1 / 64
REV = 0.5  # one crank revolution, 2 pi / omega
SIMULATE = "simulate t = 0 .. 1 step 0.001"
SLIDER = (EXAMPLES / "slider_crank.mech").read_text()
assert SIMULATE in SLIDER
BASE = SLIDER.replace(SIMULATE, "simulate t = 0 .. 0.5 step 1/64")
assert BASE.endswith("output slider.x, slider.vx, slider.ax\n")

OPTIMIZE = """
optimize l in 2.5 .. 6, r in 1 .. 3
minimize max(abs(slider.ax))
subject to range(slider.x) >= 4, l >= 2*r
"""
L_BEST, R_BEST = 6.0, 2.0
#: Relative tolerance on the optimum. The evolution stops at a relative spread of 1e-6 of
#: the population's objectives; SLSQP then refines with ftol 1e-14 and central differences of
#: step 1e-6 of each range (exact here up to rounding: the objective and the slacks are
#: smooth in (l, r) near the optimum, the max being attained at the fixed instant t = 7/16),
#: and it ends on the active bound r = 2 of the stroke requirement to within its feasibility
#: tolerance. 1e-6 relative is the accuracy the search promises; it is far above rounding
#: (1e-13 on the closed forms).
REL = 1e-6


# --- the closed forms (independent truth) -------------------------------------------------

def theta_of(t):
    return np.pi / 4 + OMEGA * np.asarray(t, dtype=float)


def x_of(theta, r, l):
    return r * np.cos(theta) + np.sqrt(l * l - (r * np.sin(theta)) ** 2)


def ax_of(t, r, l):
    theta = theta_of(t)
    s, c = np.sin(theta), np.cos(theta)
    D = np.sqrt(l * l - r * r * s * s)
    return (-r * c - r * r * (c * c - s * s) / D - r**4 * s * s * c * c / D**3) * OMEGA**2


def peak_ax(r, l):
    return r * OMEGA**2 * (1 + r / l)


def times():
    n = round(REV / STEP)
    assert n * STEP == REV
    return np.arange(n + 1) * STEP


def mechdsl(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd or ROOT, timeout=120)


def write(tmp_path, text: str, name: str = "opt.mech"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_grid_holds_the_dead_centres():
    t = times()
    assert len(t) == 33
    assert 3 / 16 in t and 7 / 16 in t
    assert np.isclose(theta_of(3 / 16), np.pi, rtol=0, atol=1e-15)
    assert np.isclose(theta_of(7 / 16), 2 * np.pi, rtol=0, atol=1e-15)
    # the sampled peak and stroke are the closed forms, at any (r, l) of the ranges
    for r, l in ((1.0, 2.5), (2.0, 6.0), (3.0, 6.0), (2.5, 5.0)):
        assert np.max(np.abs(ax_of(t, r, l))) == pytest.approx(peak_ax(r, l), rel=1e-13)
        x = x_of(theta_of(t), r, l)
        assert x.max() - x.min() == pytest.approx(2 * r, rel=1e-13)


# --- 1. minimize, subject to: the slider-crank --------------------------------------------

@pytest.fixture(scope="module")
def slider_best(registry):
    import mechdsl

    mech = mechdsl.loads(BASE + OPTIMIZE, "slider.mech", registry=registry)
    return mech, optimize(mech)


def test_the_optimum_is_the_closed_form(slider_best):
    _, best = slider_best
    assert isinstance(best, Optimum)
    assert set(best.params) == {"l", "r"}
    assert best.params["l"] == pytest.approx(L_BEST, rel=REL)
    assert best.params["r"] == pytest.approx(R_BEST, rel=REL)
    assert best.objective == pytest.approx(peak_ax(R_BEST, L_BEST), rel=REL)
    assert best.objective == pytest.approx(2 * OMEGA**2 * 4 / 3, rel=REL)
    # and the objective reported is the closed form at the params reported
    assert best.objective == pytest.approx(peak_ax(best.params["r"], best.params["l"]),
                                           rel=1e-10)


def test_both_requirements_hold_at_the_optimum(slider_best):
    _, best = slider_best
    assert best.feasible
    assert list(best.requirements) == ["range(slider.x) >= 4", "l >= 2*r"]
    r, l = best.params["r"], best.params["l"]
    stroke, spare = best.requirements.values()
    assert stroke >= -REQUIRE_TOL and spare >= -REQUIRE_TOL  # round-off at the bound holds
    # the slacks are the requirements' own sides: 2r - 4 (active) and l - 2r
    assert stroke == pytest.approx(2 * r - 4, abs=1e-10)
    assert stroke < 1e-5  # the stroke requirement is what stops r
    assert spare == pytest.approx(l - 2 * r, abs=1e-12)
    assert spare == pytest.approx(L_BEST - 2 * R_BEST, rel=REL)


def test_the_search_counts_its_sweeps(slider_best):
    _, best = slider_best
    assert best.sweeps >= 2 and best.variants >= best.sweeps
    assert best.seconds > 0
    assert best.message.startswith("differential evolution")


def test_the_run_at_the_optimum_has_the_files_outputs(slider_best):
    _, best = slider_best
    res = best.run
    assert res is not None
    assert list(res.data) == ["slider.x", "slider.vx", "slider.ax"]
    np.testing.assert_allclose(res.times, times(), rtol=0, atol=1e-15)
    r, l = best.params["r"], best.params["l"]
    np.testing.assert_allclose(np.ravel(res.data["slider.x"]), x_of(theta_of(times()), r, l),
                               rtol=1e-10)
    np.testing.assert_allclose(np.ravel(res.data["slider.ax"]), ax_of(times(), r, l),
                               rtol=1e-8, atol=1e-8 * OMEGA**2)


@pytest.fixture(scope="module")
def slider_again(slider_best):
    """The same search once more, its progress recorded: (the best so far, variants, sweep)
    after every sweep. A progress callback only watches: the search is the same one."""
    mech, _ = slider_best
    seen = []
    again = optimize(mech, run=False, progress=lambda b, v, s: seen.append((b, v, s)))
    return again, seen


def test_same_seed_same_params(slider_best, slider_again):
    _, best = slider_best
    again, _ = slider_again
    assert again.params == best.params
    assert again.objective == best.objective
    assert again.requirements == best.requirements


def test_overrides_of_the_time_grid_and_params_are_used(registry):
    """The search runs with the overrides: omega = 2 pi (the file's is 4 pi), t = 0 .. 1 (one
    revolution at that speed) step 1/128, which holds theta = 2 pi (t = 7/8) and theta = pi
    (t = 3/8); the optimum stays r = 2, l = 6, its peak 2 omega^2 (1 + 1/3) with the new
    omega."""
    import mechdsl

    mech = mechdsl.loads(BASE + OPTIMIZE, "slider.mech", registry=registry)
    omega = 2 * np.pi
    best = optimize(mech, Overrides(params={"omega": omega}, t1=1.0, step=1 / 128),
                    popsize=8, run=True)
    assert best.params["r"] == pytest.approx(R_BEST, rel=REL)
    assert best.params["l"] == pytest.approx(L_BEST, rel=REL)
    assert best.objective == pytest.approx(2 * omega**2 * 4 / 3, rel=REL)
    assert best.feasible
    # the run at the optimum is on the same grid, with the same omega
    assert len(best.run.times) == 129 and best.run.times[-1] == 1.0
    ax = np.ravel(best.run.data["slider.ax"])
    assert np.abs(ax).max() == pytest.approx(2 * omega**2 * 4 / 3, rel=REL)


def test_a_narrow_feasible_region(registry):
    """l in 2.5 .. 5: the feasible designs (r >= 2, 2r <= l <= 5) are 5 % of the box, so a
    generation of the evolution may have no feasible member; the optimum is the closed
    form's, l = 5, r = 2, objective 2 omega^2 (1 + 2/5)."""
    import mechdsl

    text = BASE + OPTIMIZE.replace("l in 2.5 .. 6", "l in 2.5 .. 5")
    mech = mechdsl.loads(text, "slider.mech", registry=registry)
    best = optimize(mech, run=False)
    assert best.feasible
    assert best.params["r"] == pytest.approx(R_BEST, rel=REL)
    assert best.params["l"] == pytest.approx(5.0, rel=REL)
    assert best.objective == pytest.approx(peak_ax(R_BEST, 5.0), rel=REL)
    assert best.requirements["l >= 2*r"] == pytest.approx(1.0, rel=REL)


# --- 2. maximize --------------------------------------------------------------------------

def test_maximize_ends_on_the_upper_bound(registry):
    import mechdsl

    text = BASE + "optimize r in 1 .. 2\nmaximize range(slider.x)\n"
    mech = mechdsl.loads(text, "max.mech", registry=registry)
    best = optimize(mech, popsize=8, run=False)
    assert best.params["r"] == pytest.approx(2.0, rel=REL)  # stroke 2r grows with r
    assert best.objective == pytest.approx(4.0, rel=REL)  # positive: the maximum, not -max
    assert best.objective <= 4.0 + 1e-12
    assert best.requirements == {} and best.feasible


# --- 3. coupler synthesis: the known design, and brute force -------------------------------

def coupler_point(t, a=1.0, b=3.5, c=3.1, d=4.0, h=1.25, omega=2 * np.pi):
    """The coupler point P of the crank-rocker of coupler_synthesis.mech, by loop closure:
    A on the crank circle, B the intersection of the circles about A (radius b) and O4
    (radius c) on the side of the file's guess (above A-O4), P = mid(A, B) + h n, n the
    left normal of A -> B."""
    th = np.pi / 4 + omega * np.asarray(t, dtype=float)
    A = np.stack([a * np.cos(th), a * np.sin(th)], axis=-1)
    O4 = np.array([d, 0.0])
    v = O4 - A
    e = np.linalg.norm(v, axis=-1, keepdims=True)
    u = v / e
    along = (b * b - c * c + e * e) / (2 * e)
    across = np.sqrt(b * b - along**2)
    left = np.stack([-u[:, 1], u[:, 0]], axis=-1)
    B = A + along * u + across * left
    w = (B - A) / b
    n = np.stack([-w[:, 1], w[:, 0]], axis=-1)
    return (A + B) / 2 + h * n


TARGETS = np.array([(1.189430161, 2.802903565), (0.380173099, 2.873220209),
                    (-0.441698757, 1.923684612), (-0.328569292, 1.155992979),
                    (0.548170523, 1.669088273)])


def coupler_objective(c, h):
    """The sum over the targets of the least squared distance to the coupler curve over the
    run, each least distance found between the samples (as mechdsl's min is: a bounded
    search of the closed form between the neighbours of the nearest sample)."""
    from scipy.optimize import minimize_scalar

    t = np.arange(1001) * 0.001
    P = coupler_point(t, c=c, h=h)
    total = 0.0
    for target in TARGETS:
        d2 = ((P - target) ** 2).sum(-1)
        k = int(np.argmin(d2))
        best = minimize_scalar(
            lambda s: float(((coupler_point(np.array([s]), c=c, h=h)[0] - target) ** 2).sum()),
            method="bounded", bounds=(t[max(k - 1, 0)], t[min(k + 1, 1000)]),
            options={"xatol": 1e-13})
        total += min(best.fun, d2[k])
    return total


def test_the_targets_are_on_the_curve_of_the_known_design():
    assert "(1.189430161, 2.802903565)" in (EXAMPLES / "coupler_synthesis.mech").read_text()
    assert coupler_objective(3.1, 1.25) < 1e-15
    assert coupler_objective(3.0, 1.0) > 1e-3  # the file's own values are not the design


@pytest.fixture(scope="module")
def coupler(registry):
    import mechdsl

    mech = mechdsl.load(EXAMPLES / "coupler_synthesis.mech", registry=registry)
    return mech, optimize(mech, run=False)


def test_the_optimiser_recovers_the_design(coupler):
    _, best = coupler
    assert best.params["c"] == pytest.approx(3.1, abs=1e-6)
    assert best.params["h"] == pytest.approx(1.25, abs=1e-6)
    assert 0 <= best.objective < 1e-12
    assert best.requirements == {} and best.feasible
    # the objective reported is the independent one at the params found
    assert abs(best.objective - coupler_objective(best.params["c"], best.params["h"])) < 1e-11


def test_brute_force_finds_nothing_better(coupler):
    mech, best = coupler
    n = 21
    brute = optimize(mech, run=False, grid=n)
    assert brute.sweeps == 1 and brute.variants == n * n
    assert brute.objective >= best.objective
    for name, (lo, hi) in {"c": (2.5, 3.5), "h": (0.2, 1.8)}.items():
        axis = np.linspace(lo, hi, n)
        spacing = axis[1] - axis[0]
        assert np.min(np.abs(axis - brute.params[name])) < 1e-12  # a point of the grid
        assert abs(brute.params[name] - best.params[name]) <= spacing + 1e-12
    # the grid's best is the independent objective's best over the same grid
    cs, hs = np.linspace(2.5, 3.5, n), np.linspace(0.2, 1.8, n)
    values = np.array([[coupler_objective(c, h) for h in hs] for c in cs])
    i, j = np.unravel_index(np.argmin(values), values.shape)
    assert (brute.params["c"], brute.params["h"]) == pytest.approx((cs[i], hs[j]), abs=1e-12)
    assert brute.objective == pytest.approx(values[i, j], rel=1e-6)


# --- 4. the command -----------------------------------------------------------------------

OUTPUT_RE = re.compile(
    r"^(?P<file>\S+): minimum found at\n"
    r"  l = (?P<l>\S+)\n"
    r"  r = (?P<r>\S+)\n"
    r"objective: (?P<objective>\S+)\n"
    r"requirement range\(slider\.x\) >= 4: holds \(slack (?P<s1>\S+)\)\n"
    r"requirement l >= 2\*r: holds \(slack (?P<s2>\S+)\)\n"
    r"(?P<variants>\d+) variants solved in (?P<sweeps>\d+) sweeps, [0-9.]+ s "
    r"\(differential evolution: .*; refined by SLSQP\)"
    # designs of the evolution where l < r lock up: they give no objective, and are counted
    r"(; (?P<nonfinite>\d+) of (?P=variants) designs gave no finite objective "
    r"\((?P=nonfinite) could not be solved\))?\n")


def test_the_command_prints_the_optimum_and_writes_the_run_there(tmp_path):
    path = write(tmp_path, BASE + OPTIMIZE)
    r = mechdsl("optimize", path, "-o", tmp_path / "best.csv", "--popsize", 10)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    m = OUTPUT_RE.match(r.stdout)
    assert m, r.stdout
    assert m["file"] == str(path)
    l, rr = float(m["l"]), float(m["r"])
    assert l == pytest.approx(L_BEST, rel=REL) and rr == pytest.approx(R_BEST, rel=REL)
    assert float(m["objective"]) == pytest.approx(peak_ax(R_BEST, L_BEST), rel=REL)
    assert float(m["s1"]) >= -REQUIRE_TOL and float(m["s2"]) == pytest.approx(2, rel=1e-5)
    assert int(m["variants"]) >= int(m["sweeps"]) >= 2
    # the run at the optimum: the file's outputs, at the printed params
    rows = [row for row in csv.reader((tmp_path / "best.csv").read_text().splitlines())
            if row and not row[0].startswith("#")]
    assert rows[0] == ["t", "slider.x", "slider.vx", "slider.ax"]
    data = np.array(rows[1:], dtype=float)
    np.testing.assert_allclose(data[:, 0], times(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(data[:, 1], x_of(theta_of(times()), rr, l), rtol=1e-10)
    np.testing.assert_allclose(data[:, 3], ax_of(times(), rr, l), rtol=1e-8,
                               atol=1e-8 * OMEGA**2)
    k = np.flatnonzero(data[:, 0] == 7 / 16)[0]  # theta = 2 pi: the dead centre
    assert data[k, 1] == pytest.approx(rr + l, rel=1e-12)
    assert abs(data[k, 3]) == pytest.approx(peak_ax(rr, l), rel=1e-10)


def test_the_command_maximize_says_maximum(tmp_path):
    path = write(tmp_path, BASE + "optimize r in 1 .. 2\nmaximize range(slider.x)\n")
    r = mechdsl("optimize", path, "--popsize", 5, "--no-refine")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == f"{path}: maximum found at"
    assert re.fullmatch(r"  r = \S+", lines[1])
    assert float(lines[1].split("=")[1]) == pytest.approx(2.0, rel=1e-4)
    assert float(lines[2].removeprefix("objective: ")) == pytest.approx(4.0, rel=1e-4)
    assert "refined by SLSQP" not in r.stdout


INFEASIBLE = OPTIMIZE.replace("range(slider.x) >= 4", "range(slider.x) >= 100")


@pytest.mark.parametrize("search", [[], ["--grid", "5"]], ids=["evolution", "grid"])
def test_an_infeasible_requirement_exits_2(tmp_path, search):
    # the stroke is 2r <= 6 over the ranges: no design has a stroke of 100
    path = write(tmp_path, BASE + INFEASIBLE)
    r = mechdsl("optimize", path, "-o", tmp_path / "best.csv", "--popsize", 5,
                "--maxiter", 5, *search)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert "requirement range(slider.x) >= 100: VIOLATED" in r.stdout
    assert "no design in the ranges satisfies every requirement" in r.stderr
    assert not (tmp_path / "best.csv").exists()


ERRORS = [  # (the statements after the slider-crank, the text located, message)
    ("minimize max(abs(slider.ax))\n", "minimize max", "without an 'optimize' statement"),
    ("optimize l in 2.5 .. 6\n", "optimize l", "'optimize' without an objective"),
    ("optimize lx in 2.5 .. 6\nminimize max(abs(slider.ax))\n", "lx in",
     "'lx' is not a param; only params can be optimised; did you mean 'l'?"),
    ("optimize l in 2.5 .. 6, r in 1 .. 3, l in 3 .. 4\nminimize max(abs(slider.ax))\n",
     "l in 3", "'l' is varied twice"),
    ("optimize l in 2.5 .. 6\nminimize max(abs(slider.ax))\nsubject to range(slider.x)\n",
     "range(slider.x)\n", "a requirement is a comparison"),
    ("optimize l in 2.5 .. 6\nminimize slider.x\n", "slider.x\n",
     "minimize takes one value per variant"),
    ("optimize l in 6 .. 2.5\nminimize max(abs(slider.ax))\n", "l in 6",
     "the range of 'l' is 6 .. 2.5"),
    ("optimize l in 3 .. 3\nminimize max(abs(slider.ax))\n", "l in 3",
     "the range of 'l' is 3 .. 3"),
    ("optimize l in 2.5 .. 6\nminimize max(abs(slider.ax))\nmaximize max(slider.x)\n",
     "maximize", "a second 'minimize/maximize' statement"),
    ("optimize l in 2.5 .. 6\nminimize max(abs(slider.ax))\nsubject to slider.x >= 1\n",
     "slider.x >= 1", "'slider.x' is outside a reduction"),
]


def location(text: str, marker: str) -> str:
    """LINE:COL of the one occurrence of ``marker`` in the optimize statements of ``text``."""
    start = len(BASE)
    i = text.index(marker, start)
    assert text.find(marker, i + 1) == -1
    line = text.count("\n", 0, i) + 1
    return f"{line}:{i - text.rfind(chr(10), 0, i)}"


@pytest.mark.parametrize("statements, marker, message", ERRORS,
                         ids=["no-optimize", "no-objective", "not-a-param", "varied-twice",
                              "not-a-comparison", "not-a-reduction", "bounds-reversed",
                              "bounds-empty", "second-objective", "quantity-outside"])
def test_mistakes_exit_1_located(tmp_path, statements, marker, message):
    text = BASE + statements
    path = write(tmp_path, text)
    r = mechdsl("optimize", path, "--popsize", 4, "--maxiter", 2)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert r.stderr.startswith(f"{path}:{location(text, marker)}: error: "), r.stderr
    assert message in r.stderr
    assert r.stdout == ""


@pytest.mark.parametrize("statements, marker, message",
                         [e for e in ERRORS if "the range of" not in e[2]])
def test_mistakes_in_the_statements_are_refused_on_loading(loads, statements, marker,
                                                           message):
    text = BASE + statements
    with pytest.raises(MechError) as err:
        loads(text)
    assert message in err.value.message
    line, col = map(int, location(text, marker).split(":"))
    assert (err.value.span.line, err.value.span.column) == (line, col)


def test_reversed_bounds_are_refused_by_the_api(loads):
    mech = loads(BASE + "optimize l in 6 .. 2.5\nminimize max(abs(slider.ax))\n")
    with pytest.raises(MechError, match=r"the range of 'l' is 6 \.\. 2\.5"):
        optimize(mech, run=False)


def test_a_file_without_optimize_is_refused(tmp_path, loads):
    path = write(tmp_path, BASE)
    r = mechdsl("optimize", path)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert "has no 'optimize' statement" in r.stderr and str(path) in r.stderr
    assert r.stdout == ""
    with pytest.raises(MechError, match="no 'optimize' statement"):
        optimize(loads(BASE), run=False)


# --- 6. fmt -------------------------------------------------------------------------------



@pytest.mark.parametrize("statements", [
    OPTIMIZE,
    "\noptimize   l in 2.5..6 ,r in 1 ..  3\nminimize max( abs(slider.ax) )\n"
    "subject to range(slider.x)>=4,l>=2*r  # the stroke\n",
    "\noptimize l in 2.5 .. 6, r in 1 .. 3\nminimize max(abs(slider.ax))\n"
    "   + 0.5*min( slider.x )\n      +range(slider.x)/100  # a sum\n"
    "subject to l >= 2*r, range(slider.x) > 4, max(slider.x) <= 9, 1 < min(slider.x)\n",
    "\noptimize r in 1 .. 2\nmaximize range(slider.x)\n",
], ids=["canonical", "respaced", "continued", "maximize"])
def test_fmt_keeps_the_optimize_block_and_is_idempotent(statements):
    text = BASE + statements
    once = format_text(text, "r.mech")
    assert format_text(once, "r.mech") == once
    before, after = parse(text, "t.mech"), parse(once, "o.mech")
    assert after.optimization is not None
    assert model_meaning(after) == model_meaning(before)


def test_fmt_keeps_a_continued_objective_on_its_lines():
    text = (BASE + "\noptimize l in 2.5 .. 6, r in 1 .. 3\nminimize max(abs(slider.ax))\n"
            "   + 0.5*min( slider.x )\n      +range(slider.x)/100  # a sum\n")
    once = format_text(text, "r.mech")
    assert once.endswith("minimize max(abs(slider.ax))\n    + 0.5*min(slider.x)\n"
                         "    + range(slider.x)/100  # a sum\n")
    objective = parse(once, "o.mech").optimization.objective
    before = parse(text, "t.mech").optimization.objective
    assert model_meaning(objective) == model_meaning(before)


def test_the_example_is_in_the_canonical_layout():
    text = (EXAMPLES / "coupler_synthesis.mech").read_text()
    assert format_text(text, "coupler_synthesis.mech") == text


def test_the_api_method_is_the_command(slider_best):
    # Mechanism.optimize takes simulate's overrides and gives the same search as optimize()
    mech, best = slider_best
    again = mech.optimize()
    assert again.params == best.params and again.objective == best.objective
    # an override reaches the search: a slower crank (omega = 2 pi) quarters the peak
    slow = mech.optimize(omega=2 * np.pi, span=(0, 1), step=1 / 64)
    assert slow.params["r"] == pytest.approx(R_BEST, rel=REL)
    assert slow.objective == pytest.approx(peak_ax(R_BEST, L_BEST) / 4, rel=REL)
    assert slow.run is not None and len(slow.run["t"]) == 65


def test_the_search_reports_its_progress_after_every_sweep(slider_best, slider_again):
    _, best = slider_best
    again, seen = slider_again
    assert again.params == best.params
    assert [s for _, _, s in seen] == list(range(1, again.sweeps + 1))
    assert seen[-1][1] == again.variants
    bests = [b for b, _, _ in seen if np.isfinite(b)]
    assert bests == sorted(bests, reverse=True)  # the best so far only improves
    assert bests[-1] == pytest.approx(again.objective, rel=1e-12)
