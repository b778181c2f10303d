"""Options fail as options, and a drive that jumps is named.

A bad ``--step``, ``--t0``, ``--t1`` or count is the option's error (``mechdsl: error:
--step: ...``, exit 1), not the file's ``simulate`` line's; counts take 1e3 as the API takes
1e3; a loose ``rtol`` is said; with ``-o`` a dynamics run still says its integrator. A drive
whose position or velocity jumps is located by bisection in time (checked against step
functions whose jump is known) and named: in a warning where an explicit pair projected over
it, in the failure where radau's step underflowed at it."""

import math
import subprocess
import sys

import numpy as np
import pytest

import mechdsl
from mechdsl.errors import OptionError
from mechdsl.solve import SolverOptions
from mechdsl.solve.jumps import time_jumps

PENDULUM = """gravity = (0, -9.81)
ground { }
body bar { guess = (0, 0, 0)  mass = 1  inertia = 1/12  centroid = (0.5, 0) }
joint pin: revolute(ground.origin, bar.origin)
simulate t = 0 .. 1 step 0.01
output theta = bar.phi
"""

# a pendulum hanging from a cart whose drive is DRIVE
CART = """gravity = (0, -9.81)
ground { }
body cart { guess = (0, 0, 0)  mass = 1  inertia = 0.1 }
body bar { guess = (0, 0, -1.5708)  mass = 1  inertia = 1/12  centroid = (0.5, 0) }
joint rail: prismatic(ground.origin, cart.origin, axis = (1, 0))
joint pin: revolute(cart.origin, bar.origin)
drive push: x(cart.origin) = DRIVE
simulate t = 0 .. 2 step 0.01
output theta = bar.phi, x = cart.x
"""


def _run(path, *args):
    return subprocess.run([sys.executable, "-m", "mechdsl", "run", str(path), *map(str, args)],
                          capture_output=True, text=True, timeout=120)


@pytest.fixture
def pendulum_file(tmp_path):
    path = tmp_path / "p.mech"
    path.write_text(PENDULUM)
    return path


@pytest.mark.parametrize("args, message", [
    (("--step", "0"), "mechdsl: error: --step: the simulated time step must be positive, "
                      "not 0"),
    (("--t1", "-1"), "mechdsl: error: --t1: the simulated time range ends (-1) before it "
                     "starts (0)"),
    (("--t0", "5"), "mechdsl: error: --t0: the simulated time range ends (1) before it "
                    "starts (5)"),
    (("--step", "nan"), "mechdsl: error: --step: the step is nan"),
    (("--max-steps", "1.5"), "mechdsl: error: --max-steps: a whole number, not '1.5'"),
    (("--frames", "x"), "mechdsl: error: --frames: a whole number, not 'x'"),
    (("--max-steps", "0"), "mechdsl: error: --max-steps: max_steps must be a whole number"),
])
def test_bad_option_values_are_the_options_errors(pendulum_file, tmp_path, args, message):
    r = _run(pendulum_file, "-o", tmp_path / "o.csv", *args)
    assert r.returncode == 1
    assert r.stderr.startswith(message), r.stderr
    assert "p.mech" not in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o.csv").exists()


def test_the_api_fails_the_same_way_and_takes_counts_as_the_command_line():
    mech = mechdsl.loads(PENDULUM, "p.mech")
    with pytest.raises(OptionError, match=r"^step: the simulated time step must be positive"):
        mech.simulate(step=0)
    with pytest.raises(OptionError, match=r"^span: the simulated time range ends \(-1\)"):
        mech.simulate(span=(0, -1))
    assert SolverOptions(max_steps=1e3).max_steps == 1000
    assert type(SolverOptions(max_steps=1e3).max_steps) is int
    for bad in (2.5, math.nan, math.inf):
        with pytest.raises(ValueError, match="max_steps must be"):
            SolverOptions(max_steps=bad)


def test_a_count_written_1e3_runs_and_a_loose_rtol_is_said(pendulum_file, tmp_path):
    out = tmp_path / "o.csv"
    r = _run(pendulum_file, "-o", out, "--max-steps", "1e3", "--rtol", "0.5")
    assert r.returncode == 0, r.stderr
    assert "rtol = 0.5 is loose" in r.stderr
    # -o: the rows written, and the integrator that wrote them
    assert f"{out}: 101 rows" in r.stderr and "integrator: " in r.stderr
    r = _run(pendulum_file, "-o", out, "--rtol", "1e-3")
    assert r.returncode == 0 and "loose" not in r.stderr


# -- jumps --------------------------------------------------------------------------------

def test_bisection_locates_a_step_and_ignores_a_fast_smooth_change():
    jump_at, size = 0.3141, 0.1

    def phi(t):  # row 0 smooth and fast (1000 rad/s), row 1 a step, row 2 a kink
        return np.array([0.05 * math.sin(1000 * t), 0.2 + (size if t >= jump_at else 0.0),
                         max(t - jump_at, 0.0)])

    def nu(t):  # minus the time derivative of phi
        return -np.array([50 * math.cos(1000 * t), 0.0, 1.0 if t >= jump_at else 0.0])

    found = time_jumps(phi, nu, 0.3, 0.33, floor=1e-10)
    assert [(j.row, j.level) for j in found] == [(1, "position"), (2, "velocity")]
    for j, expected in zip(found, (size, 1.0)):
        assert abs(j.t - jump_at) <= 4 * np.spacing(jump_at)
        assert j.size == pytest.approx(expected, rel=1e-12)
    # no step inside the interval: nothing, however fast the rows change
    assert time_jumps(phi, nu, 0.32, 0.33, floor=1e-10) == []
    # a change below the floor does not count
    assert time_jumps(phi, nu, 0.3, 0.33, floor=10.0) == []


def test_a_step_on_a_ramp_is_found_over_a_long_step():
    # a position step of 0.1 where a ramp of 0.4 starts, in a step of 2.12 s whose ramp part
    # changes the row by 0.45 (halving towards the larger change followed the ramp)
    def phi(t):
        return np.array([0.0 if t < 1 else 0.1 + 0.4 * (t - 1), math.sqrt(abs(t - 1.5))])

    found = time_jumps(phi, None, 0.0, 2.12, floor=1e-10)
    assert [(j.row, j.level) for j in found] == [(0, "position")]  # (sqrt: unbounded rate)
    assert abs(found[0].t - 1.0) <= 4 * np.spacing(1.0)
    assert found[0].size == pytest.approx(0.1, rel=1e-12)
    assert found[0].t_before < 1.0 <= found[0].t


@pytest.mark.parametrize("method", ["auto", "radau"])
@pytest.mark.parametrize("drive", ["if t < 1 then 0 else 0.1",
                                   "if t < 1 then 0 else 0.1 + 0.4*(t - 1)"])
def test_a_drive_that_jumps_in_position_ends_the_run_there_named(tmp_path, method, drive):
    path = tmp_path / "cart.mech"
    path.write_text(CART.replace("DRIVE", drive))
    out = tmp_path / "o.csv"
    r = _run(path, "-o", out, "--method", method)
    assert r.returncode == 2, r.stderr
    assert "the forward dynamics stopped after t = 0.99" in r.stderr
    assert "drive push (x, line 7) jumps at t = 1 (its position by 0.1)" in r.stderr
    assert "augmented Lagrangian" not in r.stderr  # (not taken for a singular position)
    data = np.loadtxt(out, delimiter=",", comments="#", skiprows=1)
    assert len(data) == 100 and data[-1, 0] == pytest.approx(0.99)


def _hanging_bar(theta0: float, omega0: float, t: np.ndarray) -> np.ndarray:
    """The bar (1 m, 1 kg, uniform) on a pin that moves at constant velocity: about the pin,
    I theta'' = -m g (L/2) cos theta, I = m L^2 / 3, so theta'' = -(3 g / 2) cos theta."""
    from scipy.integrate import solve_ivp

    sol = solve_ivp(lambda _, y: [y[1], -1.5 * 9.81 * math.cos(y[0])], (t[0], t[-1]),
                    [theta0, omega0], rtol=1e-12, atol=1e-13, t_eval=t)
    return sol.y


@pytest.mark.parametrize("method", ["vern9", "dop853", "dopri5", "radau"])
def test_a_drive_whose_velocity_jumps_goes_on_from_the_impulsive_motion(method):
    # the cart starts at 0.5 m/s at t = 1. The impulse P on the bar at the pin gives its
    # centre m dv = P and its rotation (1/12) dw = -P / 2 (the pin 1/2 above the centre);
    # the pin's velocity dv - dw / 2 = 4 P = 0.5: dw = -6 P = -0.75 rad/s exactly
    text = CART.replace("DRIVE", "if t < 1 then 0 else 0.5*(t - 1)").replace(
        "output theta = bar.phi, x = cart.x", "output theta = bar.phi, w = bar.omega")
    res = mechdsl.loads(text, "cart.mech").simulate(
        options=SolverOptions(method=method, rtol=1e-10, atol=1e-12))
    assert res.ok, res.messages
    t = res["t"]
    before, after = t < 1 - 1e-12, t > 1 + 1e-12
    theta0 = res["theta"][0]  # the guess: free, kept by the assembly
    ref = _hanging_bar(theta0, 0.0, np.append(t[before], 1.0))
    assert np.abs(res["theta"][before] - ref[0, :-1]).max() < 1e-7
    post = _hanging_bar(ref[0, -1], ref[1, -1] - 0.75, np.append(1.0, t[after]))
    err = np.abs(res["theta"][after] - post[0, 1:]).max()
    assert err < 1e-7, err  # (measured 4.5e-9 for the explicit pairs, 2.4e-8 for radau)
    assert np.abs(res["w"][after] - post[1, 1:]).max() < 1e-6
    # said by every method (radau's by the scan of the drives' rates), once
    said = [w for w in res.warnings if "drive push (x, line 7) jumps at t = 1 (its velocity "
            "by 0.5)" in w and "impulsive motion" in w]
    assert len(said) == 1, res.warnings


@pytest.mark.parametrize("method", ["auto", "radau"])
def test_a_smooth_fast_drive_is_not_called_a_jump(tmp_path, method):
    path = tmp_path / "cart.mech"
    path.write_text(CART.replace("DRIVE", "0.1*sin(50*t)"))
    r = _run(path, "-o", tmp_path / "o.csv", "--method", method)
    assert r.returncode == 0, r.stderr
    assert "jumps" not in r.stderr


@pytest.mark.parametrize("rtol, atol, said", [
    (None, 1e-300, "atol 1e-300 is below what double precision resolves: integrated at "
                   "rtol 1e-08, atol 1e-16"),
    (1e-30, 1e-30, "rtol 1e-30 and atol 1e-30 are below what double precision resolves: "
                   "integrated at rtol 2.22e-14, atol 1e-16"),
])
def test_tolerances_beyond_double_precision_are_raised_and_said(rtol, atol, said):
    # (an atol of 1e-200 divided by zero in the first step's estimate, exit 3; at rtol 1e-30
    # a pendulum reached t = 3e-13 in 2000 steps and the automatic choice called it stiff)
    text = PENDULUM.replace("output theta = bar.phi", "output theta = bar.phi, w = bar.omega")
    res = mechdsl.loads(text, "p.mech").simulate(options=SolverOptions(rtol=rtol, atol=atol))
    assert res.ok, res.messages
    assert said in res.warnings
    assert res.method.startswith("vern9") and "radau" not in res.method
    # the released bar keeps its energy: (1/2) (1/3) w^2 + g (1/2) sin(theta) = 0
    theta, w = res["theta"], res["w"]
    assert np.ptp(theta) > 1.0  # it swung
    energy = w ** 2 / 6 + 9.81 / 2 * np.sin(theta)
    assert np.abs(energy).max() < 1e-9


def test_argmin_of_a_periodic_motion_is_its_first_of_equal_extremes():
    # the bar released horizontal swings to the other horizontal, phi = -pi, at every odd
    # half period, T / 2 = 2 sqrt(I / (m g a)) K(1/2) (I = 1/3 about the pin, a = 1/2):
    # those minima are equal to the integration's error, far above 1e-12 of |phi|; of equal
    # extremes the first is the argmin (a later one was given)
    from scipy.special import ellipk

    half = 2 * math.sqrt((1 / 3) / (9.81 * 0.5)) * ellipk(0.5)
    text = PENDULUM.replace("simulate t = 0 .. 1 step 0.01", "simulate t = 0 .. 5 step 0.01")
    res = mechdsl.loads(text, "p.mech").simulate(reduce="first = argmin(bar.phi)")
    assert 5 > 5 * half  # (three minima in the run: the first is asked for)
    assert float(res["first"]) == pytest.approx(half, abs=1e-6)
