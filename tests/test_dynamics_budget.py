"""Forward dynamics that announces its work and has a step budget: a runaway integration (a
span far beyond what its steps can reach) stops at ``max_steps`` with exit 2 and the instants
integrated before it written, right (a pendulum's energy and length); the budget is a named
option on the command line and in the API; a run on a terminal shows the simulated time, the
steps and an estimate of the time left, extrapolated from its rate, and nothing with -q or
off a terminal."""

import io
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest

import mechdsl
from mechdsl.commands import ProgressBar
from mechdsl.solve import SolverOptions, simulate
from test_dynamics import G, pendulum

LENGTH = 1.0


@pytest.fixture
def pendulum_file(tmp_path):
    """The pendulum of tests/test_dynamics.py (rtol 1e-12: about 45 steps a period)."""
    path = tmp_path / "p.mech"
    path.write_text(pendulum(LENGTH))
    return path


def _mechdsl(*args, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)],
                          capture_output=True, text=True, **kwargs)


def _pendulum_truth(t, x, y, vx, vy):
    """The released pendulum's invariants at its instants: energy per unit mass 0 (it starts
    at rest at the pivot's height), the tip at the rod's length."""
    energy = 0.5 * (vx**2 + vy**2) + G * y
    assert np.abs(energy).max() <= 1e-9 * G * LENGTH
    assert np.abs(np.hypot(x, y) - LENGTH).max() <= 1e-12 * LENGTH
    assert np.ptp(y) > 0.9 * LENGTH  # it did swing: the check is not of a body at rest


def test_a_runaway_integration_ends_at_the_budget_with_the_instants_so_far(pendulum_file,
                                                                           tmp_path):
    # 1e4 s of a pendulum at rtol 1e-12 is about 160,000 steps (over a minute); a budget of
    # 3,000 stops it after some 190 s of simulated time
    out = tmp_path / "out.csv"
    begin = time.monotonic()
    run = _mechdsl("run", pendulum_file, "--t1", "1e4", "--step", "0.1", "--max-steps",
                   3000, "-o", out)
    wall = time.monotonic() - begin
    assert run.returncode == 2, run.stderr
    assert wall < 30, wall
    assert "Traceback" not in run.stderr
    err = run.stderr
    assert "budget of 3,000 steps" in err and "--max-steps" in err
    reached = float(re.search(r"budget of 3,000 steps at t = ([0-9.e+-]+) of 0 \.\. 10000 "
                              r"\(([0-9,]+) steps accepted, ([0-9,]+) rejected\)", err)[1])
    counts = re.search(r"\(([0-9,]+) steps accepted, ([0-9,]+) rejected\)", err)
    assert sum(int(c.replace(",", "")) for c in counts.groups()) == 3000
    written = int(re.search(r"the (\d+) instants solved before the failure are in", err)[1])
    assert re.search(rf"the {written} output instants integrated before it, to t = "
                     r"[0-9.]+, are kept", err)
    header = out.read_text().splitlines()[0].split(",")
    data = np.loadtxt(out, delimiter=",", comments="#", skiprows=1)
    col = {name: data[:, header.index(name)] for name in header}
    # the rows are the instants of the grid up to the time the steps reached, and no more
    assert len(data) == written > 100
    np.testing.assert_allclose(col["t"], 0.1 * np.arange(written), rtol=0, atol=1e-9)
    assert col["t"][-1] <= reached < col["t"][-1] + 0.1
    _pendulum_truth(col["t"], col["rod.tip.x"], col["rod.tip.y"], col["rod.tip.vx"],
                    col["rod.tip.vy"])


@pytest.mark.parametrize("bad", ["0", "-5"])
def test_a_budget_below_one_step_is_a_named_option_error(pendulum_file, bad):
    run = _mechdsl("run", pendulum_file, "--max-steps", bad, "-o", "-")
    assert run.returncode == 1
    assert f"--max-steps: max_steps must be a whole number of steps, at least 1, not {bad}" \
        in run.stderr
    assert "Traceback" not in run.stderr


def test_the_api_takes_the_budget_as_an_option_and_fails_the_same_way():
    mech = mechdsl.loads(pendulum(LENGTH), "p.mech")
    res = mech.simulate(span=(0.0, 1e4), step=0.1, options=SolverOptions(max_steps=400))
    assert res.status == "failed" and len(res.messages) == 1
    message = res.messages[0]
    assert "budget of 400 steps" in message and "SolverOptions(max_steps=N)" in message
    k = int(res.n_solved[0])
    assert 10 < k < 1000  # of the 100,001 instants asked for
    t = res["t"]
    assert np.isfinite(res["rod.phi"][:k]).all() and np.isnan(res["rod.phi"][k:]).all()
    _pendulum_truth(t[:k], *(res[name][:k] for name in ("rod.tip.x", "rod.tip.y",
                                                        "rod.tip.vx", "rod.tip.vy")))
    # the same instants as a run with budget to spare: the budget cuts the motion short,
    # it does not change it
    full = mech.simulate(span=(0.0, float(t[k - 1])), step=0.1)
    assert full.status == "ok"
    # (the same steps, bit for bit, but the last, which the shorter span cuts at its end)
    np.testing.assert_array_equal(full["rod.phi"][:-1], res["rod.phi"][: k - 1])
    assert full["rod.phi"][-1] == pytest.approx(res["rod.phi"][k - 1], abs=1e-10)
    assert SolverOptions().max_steps == 1_000_000
    for bad in (0, 2.5, float("nan"), True):
        with pytest.raises(ValueError, match="max_steps must be"):
            SolverOptions(max_steps=bad)


def test_the_budget_holds_across_the_switch_to_the_implicit_method():
    """A stiff spring (the stiff pendulum at k = 1e6: vern9 for 0.09 s, then radau, about
    70 steps in all) with a budget of 60: the steps attempted, the implicit trial's
    included, are at most 60 (the trial was given 32 attempts whatever the budget had left,
    61 accepted and 1 rejected, found in review); with 400 the run is whole."""
    import importlib.util

    from conftest import ROOT

    spec = importlib.util.spec_from_file_location(
        "dynamics_models", ROOT / "benchmarks" / "dynamics_models.py")
    dm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(dm)
    mech = mechdsl.loads(dm.stiff_pendulum_text(1e6), "stiff.mech")
    res = mech.simulate(options=SolverOptions(max_steps=60))
    assert res.status == "failed" and "budget of 60 steps" in res.messages[0]
    accepted, rejected = (int(x.replace(",", "")) for x in re.search(
        r"\(([0-9,]+) steps accepted, ([0-9,]+) rejected\)", res.messages[0]).groups())
    assert accepted + rejected <= 60
    assert mech.simulate(options=SolverOptions(max_steps=400)).status == "ok"


class _Display:
    """A progress that can show the steps: records what the dynamics feeds it."""

    def __init__(self):
        self.steps, self.instants = [], []

    def __call__(self, done, total):
        self.instants.append(done)

    def motion(self, t, steps, t0, t1, variant, variants, max_steps):
        self.steps.append((t, steps, t0, t1, variant, variants, max_steps))


def test_the_display_is_fed_by_the_steps_not_only_by_the_outputs():
    # two output instants, a period apart: the outputs alone would say nothing in between
    text = pendulum(LENGTH, per_period=1)
    T = float(text.split("simulate t = 0 .. ")[1].split(" ")[0])
    shown = _Display()
    res = simulate(mechdsl.loads(text, "p.mech").compile(), SolverOptions(max_steps=5000),
                   progress=shown)
    assert res.status == "ok" and len(res["t"]) == 2
    assert len(shown.steps) > 30 and not shown.instants
    t, steps = np.array([s[0] for s in shown.steps]), np.array([s[1] for s in shown.steps])
    assert (np.diff(t) > 0).all() and (np.diff(steps) > 0).all()
    assert t[-1] == pytest.approx(T, rel=1e-12)
    for _, _, t0, t1, variant, variants, budget in shown.steps:
        assert (t0, variant, variants, budget) == (0.0, 0, 1, 5000)
        assert t1 == pytest.approx(T, rel=1e-12)


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def _lines(stream: io.StringIO) -> list[str]:
    return [line.strip() for line in stream.getvalue().split("\r") if line.strip()]


def test_the_estimate_is_the_time_left_at_the_rate_so_far():
    # simulated time advances 20 per wall second over 0 .. 1000, 200 steps a second:
    # after t the truth is (1000 - t) / 20 s left
    def feed(max_steps: int) -> list[str]:
        stream, now = _Terminal(), [100.0]
        bar = ProgressBar(stream, delay=1.0, rate=10.0, estimate_after=1.5)
        bar.clock, bar.start = (lambda: now[0]), 100.0
        for i in range(33):  # every 1/16 s for 2 s: more often than the rate draws
            now[0] = 100.0 + i / 16
            bar.motion(5.0 + 1.25 * i, int(12.5 * i), t0=0.0, t1=1000.0, max_steps=max_steps)
        return _lines(stream)

    lines = feed(100_000)
    # nothing in the first second, then at most one line per tenth of a second (every
    # other call: at 1, 1.125, ..., 2 s)
    assert len(lines) == 9
    assert all(line.endswith("estimating") for line in lines[:4])  # before 1.5 s
    assert not any("estimating" in line for line in lines[4:])
    assert lines[-1] == "t = 45/1000 (4.5 %), 400/100,000 steps, 48 s left"  # 47.75 s
    # a budget that runs out before the end is said, with when: (5000 - 400) / 200 s
    assert feed(5000)[-1] == "t = 45/1000 (4.5 %), 400/5,000 steps, 48 s left, budget: 23 s"
    assert ProgressBar.duration(1e9) == "31.7 years"
    # off a terminal: nothing, ever
    quiet = io.StringIO()
    bar = ProgressBar(quiet, delay=0.0)
    for i in range(100):
        bar.motion(float(i), i, t0=0.0, t1=1000.0)
    bar.close()
    assert quiet.getvalue() == ""


def _on_a_terminal(*args) -> tuple[int, str]:
    """``mechdsl ARGS`` with its standard error on a pseudo-terminal: its exit status and
    what it drew there."""
    master, slave = os.openpty()
    try:
        proc = subprocess.Popen([sys.executable, "-m", "mechdsl", *map(str, args)],
                                stdout=subprocess.DEVNULL, stderr=slave)
    finally:
        os.close(slave)
    drawn = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:  # the other end closed (EIO): the process is gone
            break
        if not chunk:
            break
        drawn += chunk
    os.close(master)
    return proc.wait(timeout=120), drawn.decode(errors="replace")


def test_a_run_on_a_terminal_shows_its_time_steps_and_estimate_and_nothing_else(
        pendulum_file, tmp_path):
    # 600 s of pendulum: some 11,000 steps, several seconds
    out = tmp_path / "out.csv"
    status, drawn = _on_a_terminal("run", pendulum_file, "--t1", "600", "--step", "1",
                                   "-o", out)
    assert status == 0, drawn
    lines = [ln.strip() for ln in drawn.split("\r") if ln.strip()]
    shape = re.compile(r"t = ([0-9.e+]+)/600 \(([0-9.]+) %\), ([0-9,]+)/1,000,000 steps, "
                       r"(estimating|(\d+) (s|min) left)$")
    shown = [shape.match(ln) for ln in lines if ln.startswith("t = ")]
    assert len(shown) >= 5 and all(shown), lines
    t = [float(m[1]) for m in shown]
    steps = [int(m[3].replace(",", "")) for m in shown]
    assert t == sorted(t) and steps == sorted(steps) and 0 < t[0] and t[-1] <= 600
    for m in shown:  # the percentage is of the span
        assert float(m[2]) == pytest.approx(100 * float(m[1]) / 600, abs=0.06)
    assert shown[0][4] == "estimating"
    assert any(m[5] is not None for m in shown)
    # the line is cleared at the end, and the run's own lines follow
    assert f"{out}: 601 rows" in drawn
    assert len(np.loadtxt(out, delimiter=",", comments="#", skiprows=1)) == 601
    # the same run with -q, or with standard error not a terminal: no display
    status, drawn = _on_a_terminal("run", pendulum_file, "--t1", "300", "--step", "1", "-q",
                                   "-o", tmp_path / "q.csv")
    assert status == 0 and drawn == ""
    piped = _mechdsl("run", pendulum_file, "--t1", "300", "--step", "1", "-o",
                     tmp_path / "p.csv")
    assert piped.returncode == 0
    assert "steps" not in piped.stderr and "\r" not in piped.stderr
