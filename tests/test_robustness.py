"""Regressions from review: singular instants, drive kinks, odd drives, odd sweeps, and the
command line's handling of bad targets. Each asserts against a closed form or a message."""

import re
import subprocess
import sys

import numpy as np
import pytest

import mechdsl.solve.run as solve
from closed_forms import slider_crank
from conftest import EXAMPLES, ROOT
from mechdsl.errors import MechError

SLIDER = (EXAMPLES / "slider_crank.mech").read_text()


def run_cli(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=120)


def test_an_instant_exactly_at_the_dead_point_is_not_written(load_example):
    # l = r with step 0.0125: the fifth instant, t = 0.0625, is exactly the dead point
    res = load_example("slider_crank.mech").simulate(l=2.0, step=0.0125)
    assert res.status == "failed" and res.n_solved[0] == 5
    assert "singular position at t = 0.0625 (instant 6 of 81)" in res.messages[0]
    assert np.isfinite(res["slider.ax"]).all()


@pytest.mark.parametrize("drive, theta, omega", [
    # the crank reverses at t = 0.5: its speed jumps from -omega to +omega
    ("pi/4 + omega*abs(t - 0.5)", lambda t: np.pi / 4 + 4 * np.pi * np.abs(t - 0.5),
     lambda t: np.where(t >= 0.5, 4 * np.pi, -4 * np.pi)),
    # a motor switching on between two instants, at full speed at once
    ("if t < 0.5053 then pi/4 else pi/4 + 10*omega*(t - 0.5053)",
     lambda t: np.where(t < 0.5053, np.pi / 4, np.pi / 4 + 40 * np.pi * (t - 0.5053)),
     lambda t: np.where(t < 0.5053, 0.0, 40 * np.pi)),
])
def test_a_jump_in_a_drives_speed_is_not_a_branch_jump(loads, drive, theta, omega):
    mech = loads(SLIDER.replace("pi/4 + omega*t", drive))
    res = mech.simulate(step=0.01)
    assert res.ok, res.messages
    t = res["t"]
    x, v, _ = slider_crank(2.0, 3.5, theta(t), omega(t), 0.0)
    np.testing.assert_allclose(res["slider.x"], x, atol=1e-12)
    np.testing.assert_allclose(res["slider.vx"], v, atol=1e-10)


def test_an_infinite_initial_acceleration_stops_the_run_unless_kept(loads):
    mech = loads(SLIDER.replace("pi/4 + omega*t", "pi/4 + 3*t^1.5"))
    res = mech.simulate()
    # f'' = 2.25 t^-0.5 is infinite at t = 0: said, not written silently
    assert res.status == "failed" and res.n_solved[0] == 0
    assert res.messages[0].startswith("slider.ax is ")
    assert "at t = 0 (instant 1 of 1001)" in res.messages[0]
    assert "drive crank_angle (angle, line 28)" in res.messages[0]
    res = mech.simulate(options=solve.SolverOptions(nonfinite="keep"))
    assert res.ok, res.messages
    assert np.isinf(res["slider.ax"][0])
    t = res["t"][1:]
    th, w, al = np.pi / 4 + 3 * t**1.5, 4.5 * t**0.5, 2.25 * t**-0.5
    x, v, a = slider_crank(2.0, 3.5, th, w, al)
    np.testing.assert_allclose(res["slider.x"][1:], x, atol=1e-12)
    np.testing.assert_allclose(res["slider.ax"][1:], a, rtol=1e-9)


def test_a_distance_drive_assembles_from_coinciding_points(loads):
    res = loads("""body slider { }
        joint slide: prismatic(ground.origin, slider.origin, axis = (1, 0))
        drive push: distance(ground.origin, slider.origin) = 1 + t
        simulate t = 0 .. 1 step 0.1""").simulate()
    assert res.ok
    np.testing.assert_allclose(res["slider.x"], 1 + res["t"], atol=1e-14)


def test_a_variant_that_never_assembles_does_not_slow_the_others(load_example, monkeypatch):
    calls = []
    real = solve.newton
    monkeypatch.setattr(solve, "newton", lambda *a, **k: calls.append(1) or real(*a, **k))
    alone = load_example("slider_crank.mech").simulate()
    n_alone = len(calls)
    calls.clear()
    res = load_example("slider_crank.mech").simulate(sweep={"l": [3.5, 1.0]})
    assert len(calls) == n_alone
    assert res.status == "failed" and list(res.n_solved) == [1001, 0]
    np.testing.assert_allclose(res["slider.x"][0], alone["slider.x"], rtol=1e-15)


def test_abs_differentiates_branch_by_branch(loads):
    # 0.5 abs(t - 0.5)^2 is smooth with second derivative 1 everywhere, t = 0.5 included
    res = loads("""body crank { point A = (-1, 0) }
        joint A: revolute(ground.origin, crank.A)
        drive d: angle(crank) = 0.5*abs(t - 0.5)^2
        simulate t = 0 .. 1 step 0.25
        output crank.alpha""").simulate()
    np.testing.assert_allclose(res["crank.alpha"], 1.0, atol=1e-12)


def test_keyword_arguments_may_be_named_body_and_point(loads):
    res = loads("""body b { point P = (1, 0) }
        joint pin: revolute(ground.origin, b.origin)
        drive d: angle(body = b) = t
        simulate t = 0 .. 1 step 0.5
        output b.P.x""").simulate()
    np.testing.assert_allclose(res["b.P.x"], np.cos([0, 0.5, 1]), atol=1e-14)
    mech = loads("""body s { }
        joint j: prismatic(ground.origin, s.origin)
        drive d: x(point = s.origin) = 2*t
        simulate t = 0 .. 1 step 0.5
        output s.x""")
    np.testing.assert_allclose(mech.simulate()["s.x"], [0, 1, 2], atol=1e-14)


BASE = """param k = 1
param m = 2*k
body c { point A = (-1, 0) }
joint j: revolute(ground.origin, c.A)
drive d: angle(c) = t
simulate t = 0 .. 1 step 0.5
"""


@pytest.mark.parametrize("extra, kwargs, message", [
    ("sweep k = [1, 5]\nparam l = 1\nsweep l = [m, 10]", {}, "cannot depend on 'm'"),
    ("param l = 1\nsweep l = 3 .. 4 count 1e300", {}, "more than the limit"),
    ("param l = 1\nsweep l = 3 .. 4 count 1", {}, "at least 2 when the ends differ"),
    ("", {"k": 2.0, "sweep": {"k": [1, 2]}}, "given both a value and a sweep"),
    ("", {"sweep": {"k": []}}, "the sweep of 'k' has no values"),
])
def test_sweep_mistakes_are_errors(loads, extra, kwargs, message):
    with pytest.raises(MechError, match=message):
        loads(BASE + extra).simulate(**kwargs)


def test_set_replaces_the_files_sweep_and_its_dependents_may_be_swept(loads):
    res = loads(BASE + "sweep k = [1, 5]\nparam l = 1\nsweep l = [m, 10]").simulate(k=3.0)
    np.testing.assert_array_equal(res["l"], [6, 10])


@pytest.mark.parametrize("span, step, times", [
    ("0 .. 1", "1e300", [0, 1]), ("2 .. 2", "0.1", [2]), ("0 .. 0.3", "0.1", [0, 0.1, 0.2, 0.3]),
])
def test_the_grid_always_ends_at_t1(loads, span, step, times):
    res = loads(BASE.replace("0 .. 1 step 0.5", f"{span} step {step}")).simulate()
    np.testing.assert_allclose(res["t"], times, rtol=1e-15)
    assert res["t"][-1] == times[-1]


def test_bad_output_targets_are_refused_before_solving(tmp_path):
    r = run_cli("run", EXAMPLES / "slider_crank.mech", "-o", tmp_path / "no" / "x.csv")
    assert r.returncode == 1 and "does not exist" in r.stderr and "Traceback" not in r.stderr
    out = tmp_path / "x.csv"
    r = run_cli("run", EXAMPLES / "slider_crank.mech", "-o", out, "--plot", tmp_path / "x.foo")
    assert r.returncode == 1 and "unknown image format 'foo'" in r.stderr
    assert not out.exists()


def test_quiet_prints_nothing_on_success():
    r = run_cli("run", EXAMPLES / "slider_crank.mech", "-q")
    assert r.returncode == 0 and r.stdout == "" and r.stderr == ""


def test_an_out_of_range_newton_tolerance_is_refused():
    r = run_cli("run", EXAMPLES / "slider_crank.mech", "--newton-tol", "1")
    assert r.returncode == 1 and "newton_tol must be in (0, 1e-4]" in r.stderr


def test_a_requested_plugin_that_fails_to_load_is_an_error(tmp_path):
    (tmp_path / "brokenplug.py").write_text("raise ImportError('no gears today')\n")
    f = tmp_path / "g.mech"
    f.write_text("body b { }\njoint g: gear(ground, b)\n")
    r = subprocess.run([sys.executable, "-m", "mechdsl", "run", str(f), "--plugin", "brokenplug"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=60,
                       env={**__import__("os").environ, "PYTHONPATH": str(tmp_path)})
    assert r.returncode == 1
    assert "cannot load the plugin 'brokenplug': ImportError: no gears today" in r.stderr


def test_lines_are_counted_as_the_parser_counts_them(tmp_path):
    f = tmp_path / "ff.mech"
    f.write_text("param a = 1\n\fparam c = 3\nparam b = 2\nparam d = e\n")
    r = run_cli("run", f)
    assert f"{f}:4:11: error: unknown name 'e'" in r.stderr
    assert "    4 | param d = e" in r.stderr


def test_output_to_a_pipe_is_written_into_it_not_over_it(tmp_path, load_example):
    import os
    import stat
    import threading

    from mechdsl.outputs.csv import write_csv

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    received = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_text()))
    reader.start()
    write_csv(load_example("slider_crank.mech").simulate(step=0.1), fifo)
    reader.join(timeout=30)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert received[0].splitlines()[0] == "t,slider.x,slider.vx,slider.ax"
    assert len(received[0].splitlines()) == 13  # the header, the units line, 11 rows


def test_a_lock_up_names_the_loop_that_cannot_close_ranked(loads):
    # two loops: the slider-crank, whose rod (1.5 m on a 2 m crank) cannot close it, and a
    # second crank turning on its own; only the first loop's joints carry the dependency
    text = SLIDER.replace("param l = 3.5", "param l = 1.5") + """
        body other { point P = (1, 0) }
        joint E: revolute(ground.origin, other.origin)
        drive spin: angle(other) = t"""
    res = loads(text).simulate()
    assert res.status == "failed" and res.n_solved[0] == 5
    message = res.messages[0]
    assert "(instant 6 of 1001)" in message
    loop = message.split("the loop that can no longer close: ")[1]
    named = re.findall(r"(joint|drive) (\w+) \(\w+, line \d+: ([\d.]+) %\)", loop)
    assert {name for _, name, _ in named} <= {"A", "B", "C", "D"} and len(named) >= 2
    shares = [float(s) for _, _, s in named]
    assert shares == sorted(shares, reverse=True)
    assert "spin" not in loop and "joint E" not in loop
