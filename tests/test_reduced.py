"""The relative coordinates that joints fix, eliminated (mechdsl.solve.reduced): which rows go
(the stiff pendulum's all four; a pin away from the frame's origin none on the frames'
origins, though one of its rows has a single gradient entry at the start, and both at its
own point; a drive at rest none), the equations left against Lagrange's equations written
by hand, and the runs in them against the minimal ODE."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import mechdsl
from mechdsl.solve.motion import Motion
from mechdsl.solve.options import SolverOptions
from mechdsl.solve.reduced import reduce
from mechdsl.solve.relative import Relative, forest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import dynamics_models as dm  # noqa: E402

P = dm.PENDULUM


def _relative(text: str):
    kernels = mechdsl.loads(text, "pendulum.mech").compile()
    motion = Motion(kernels, SolverOptions())
    parent = forest(kernels.system, tuple(f.bodies for f in kernels.dynamics.forces))
    rel = Relative(motion, parent)
    y0 = np.concatenate((kernels.system.guess[0], np.zeros(motion.n)))
    return kernels, rel, rel.relative(y0)[:motion.n]


def test_the_pendulums_joints_leave_its_two_joint_coordinates():
    """The pin at both frames' origins fixes the rod's s (two rows), the slider through
    the origins along the rod's axis the bob's offset across it and its angle (two rows):
    left are the rod's angle and the bob's travel along the rod, and no equation."""
    kernels, rel, z = _relative(dm.stiff_pendulum_text(1e8))
    names = kernels.system.body_names
    rod, bob = 3 * names.index("rod"), 3 * names.index("bob")
    red = reduce(rel, 0.0, z, 2.0)
    assert red is not None
    assert sorted(red.free.tolist()) == sorted([rod + 2, bob])
    assert red.m == 0 and red.n == 2


def test_a_pin_away_from_the_frames_origin_is_eliminated_at_its_point():
    """The pin at P = (-l/2, 0) of a rod along x, in relative coordinates on the frames'
    origins: its x row's gradient has one entry at the start (d/dphi of -l/2 cos(phi) is
    zero at phi = 0), but the probes see it move: both pin rows are kept, the slider's two
    go. With the pin's point found from the rows' gradient (exactly P) as the rod's
    reference point, the pin fixes it and goes too."""
    from mechdsl.solve.reduced import pin_points

    kernels, rel, z = _relative(dm.stiff_pendulum_off_centre_text(1e8))
    _, jac = rel.phi_jac(0.0, z)
    singles = [r for r in range(rel.m)
               if np.count_nonzero(np.abs(jac[r]) > 1e-12 * np.abs(jac[r]).max()) == 1]
    pin = [int(r) for r in kernels.system.joint_rows[:2]]
    assert set(pin) & set(singles), "the start has a pin row with a single entry"
    red = reduce(rel, 0.0, z, 2.0)
    assert red is not None
    assert sorted(red.keep.tolist()) == sorted(pin)
    assert red.n == 4 and red.m == 2
    points = pin_points(rel, 0.0, z)
    rod = kernels.system.body_names.index("rod")
    assert np.abs(points[rod] - (-P["l"] / 2, 0.0)).max() < 1e-12
    at_pin = Relative(rel.base, rel.parent, points)
    y0 = np.concatenate((kernels.system.guess[0], np.zeros(rel.n)))
    red = reduce(at_pin, 0.0, at_pin.relative(y0)[:rel.n], 2.0)
    assert red.n == 2 and red.m == 0


@pytest.mark.parametrize("k", [1e2, 1e8])
def test_the_equations_left_are_lagranges(k):
    """At random states (theta, s, theta', s'): the reduced equations' accelerations are
    those of the minimal ODE written by hand (dynamics_models.stiff_pendulum_rhs, Lagrange's
    equations), and their loads' derivative along s holds the spring's -k exactly."""
    kernels, rel, z = _relative(dm.stiff_pendulum_text(k))
    names = kernels.system.body_names
    red = reduce(rel, 0.0, z, 2.0)
    theta_at = int(np.flatnonzero(red.free == 3 * names.index("rod") + 2)[0])
    s_at = 1 - theta_at
    rng = np.random.default_rng(7)
    for _ in range(5):
        y = np.array([rng.uniform(-3, 3), P["l0"] + rng.uniform(-0.2, 0.2),
                      rng.normal(scale=3), rng.normal(scale=0.5)])
        w, wd = np.empty(2), np.empty(2)
        w[[theta_at, s_at]], wd[[theta_at, s_at]] = y[:2], y[2:]
        wdd = red.rhs(0.3, np.concatenate((w, wd)))[2:]
        want = dm.stiff_pendulum_rhs(0.3, y, k)[2:]
        assert np.abs(wdd[[theta_at, s_at]] - want).max() < 1e-9 * (1 + np.abs(want).max())
        dq, dqd = red.load_derivatives(0.3, w, wd)
        # f_s = mb s theta'^2 - k (s - L0) - mb g sin(theta): d/ds = mb theta'^2 - k
        assert dq[s_at, s_at] == pytest.approx(P["mb"] * y[2] ** 2 - k, rel=1e-12)
        # every entry against central differences of the loads f_w
        step = 1e-6
        for j in range(4):
            e = np.zeros(4)
            e[j] = step
            up = red.loads(0.3, w + e[:2], wd + e[2:])
            down = red.loads(0.3, w - e[:2], wd - e[2:])
            column = (up - down) / (2 * step)
            got = (dq if j < 2 else dqd)[:, j % 2]
            # (the differences' round-off: eps |f| / step, |f| up to k (s - L0))
            size = 1 + np.abs(column).max() + np.abs(up).max()
            assert np.abs(got - column).max() < 1e-6 * size


@pytest.mark.parametrize("model", ["stiff_pendulum_text", "stiff_pendulum_off_centre_text"])
def test_the_stiff_pendulum_runs_in_its_joint_coordinates(model):
    """k = 1e8, radau named: in the joints' two coordinates from the start, within 1e-7
    of the minimal ODE at t = 2 (measured 7.7e-9 rad; 1.1e-7 in absolute coordinates), in
    fewer than 100 attempts, which absolute coordinates exhaust. The same with the rod's
    frame at its centre of mass (Haug's), pinned at its end: the pin's point is the rod's
    reference point (3.6e-7 rad in relative coordinates with the pin kept)."""
    k = 1e8
    text = getattr(dm, model)(k)
    res = mechdsl.loads(text).simulate(options=SolverOptions(method="radau", max_steps=100))
    assert res.ok, res.messages
    assert "radau in the joints' own coordinates (2 of 6 left" in res.method, res.method
    ref = dm.stiff_pendulum_oracle(k)
    assert abs(res["theta"][-1] - ref[0]) < 1e-7
    assert abs(res["s"][-1] - ref[1]) < 1e-7
    absolute = mechdsl.loads(text).simulate(
        options=SolverOptions(method="radau", max_steps=100, relative_max=0))
    assert not absolute.ok and "budget" in " ".join(absolute.messages)


def test_the_automatic_choice_goes_on_in_joint_coordinates():
    """k = 1e6 with no method named: vern9 finds it stiff, radau goes on in the joints'
    coordinates; theta and s within 1e-7 of the minimal ODE at the end (2e-7 before, in
    relative coordinates with every joint's equations), and at every output instant, most
    inside steps (read off the steps' dense outputs all at once and mapped to the bodies'
    coordinates together), theta within 1e-6 rad and its rate within 1e-5 rad/s (2.5e-7
    and 2.1e-6 measured)."""
    k = 1e6
    res = mechdsl.loads(dm.stiff_pendulum_text(k)).simulate()
    assert res.ok, res.messages
    assert "radau in the joints' own coordinates (2 of 6 left" in res.method, res.method
    ref = dm.stiff_pendulum_oracle(k)
    assert abs(res["theta"][-1] - ref[0]) < 1e-7
    assert abs(res["s"][-1] - ref[1]) < 1e-7
    t = np.asarray(res["t"], dtype=float)
    tight = dm.stiff_pendulum_rtol(k)
    every = dm.stiff_pendulum_solve(k, 2.0, "Radau", tight, tight / 100, t_eval=t).y
    assert np.abs(np.asarray(res["theta"]) - every[0]).max() < 1e-6
    assert np.abs(np.asarray(res["s"]) - every[1]).max() < 1e-6
    assert np.abs(np.asarray(res["theta.vel"]) - every[2]).max() < 1e-5


def test_a_skewed_slider_stays_an_equation_and_goes_through_the_trial():
    """The slider's axis at 53 degrees in the rod's frame: its offset across the axis reads
    in two of the bob's relative coordinates and stays an equation, so radau starts in
    absolute coordinates, finds its stages need their own Jacobians, tries relative ones
    with the pin and the slider's angle eliminated (3 of 6 left) and keeps them (about 8
    times less work per simulated second); theta and s within 1e-6 of the minimal ODE (the
    same motion as the stiff pendulum's)."""
    k = 1e8
    res = mechdsl.loads(dm.stiff_pendulum_skew_text(k), "skew.mech").simulate(
        options=SolverOptions(method="radau"))
    assert res.ok, res.messages
    assert "radau in relative coordinates (3 of 6 left" in res.method, res.method
    assert "times less work per simulated second)" in res.method
    ref = dm.stiff_pendulum_oracle(k)
    assert abs(res["theta"][-1] - ref[0]) < 1e-6
    assert abs(res["s"][-1] - ref[1]) < 1e-6


def test_a_drive_at_rest_is_never_eliminated():
    """A drive at rest until t = 1.3 (the rod, then 2 (t - 1.3)^3) is constant at t0 and at
    every probe that falls before 1.3, but not after: its row stays an equation, and the
    bob slides along the turning rod as s'' = s theta'^2 - g sin theta - k (s - 1) / mb
    (solved apart at rtol 1e-12) says. Eliminated, the rod never turned in the stepper's
    coordinates and s(2) was 0.2 m off."""
    from scipy.integrate import solve_ivp

    text = dm.stiff_pendulum_text(100.0, rtol=1e-8, atol=1e-10).replace(
        "force spring", "drive turn: angle(rod) = if t < 1.3 then 0 else 2*(t - 1.3)^3\n"
                        "force spring")
    res = mechdsl.loads(text, "dwell.mech").simulate(options=SolverOptions(method="radau"))
    assert res.ok, res.messages

    def theta(t, order=0):
        if t < 1.3:
            return 0.0
        return (2 * (t - 1.3) ** 3, 6 * (t - 1.3) ** 2)[order]

    def f(t, y):
        return [y[1], y[0] * theta(t, 1) ** 2 - 9.81 * np.sin(theta(t))
                - 100.0 * (y[0] - P["l0"]) / P["mb"]]
    ref = solve_ivp(f, (0, 2), [P["l0"], 0.0], method="DOP853", rtol=1e-12, atol=1e-14,
                    max_step=0.01, t_eval=res.times)
    assert np.abs(res["s"] - ref.y[0]).max() < 1e-6


#: a double pendulum (two rods of 1 m and 1 kg) on a rotary spring of 1e4 N m/rad: frames at
#: the pins; frames at the centres of mass (Haug's) with the second pin doubled by a pin in a
#: slot (a redundant joint: its row vanishes where the pin holds)
DOUBLE = {
    "frames at the pins": """body a { guess = (0, 0, 0)  mass = 1  inertia = 1/12  centroid = (0.5, 0)  point E = (1, 0) }
body b { guess = (1, 0, 0)  mass = 1  inertia = 1/12  centroid = (0.5, 0) }
joint p1: revolute(ground.origin, a.origin)
joint p2: revolute(a.E, b.origin)
""",
    "Haug's, a redundant pin": """body a { guess = (0.5, 0, 0)  point P = (-0.5, 0)  point Q = (0.5, 0)  mass = 1  inertia = 1/12 }
body b { guess = (1.5, 0, 0)  point P = (-0.5, 0)  mass = 1  inertia = 1/12 }
joint p1: revolute(ground.origin, a.P)
joint p2: revolute(a.Q, b.P)
joint ps: pin_slot(a.Q, b.P, axis = (1, 0))
"""}


def _double_pendulum_text(bodies: str = "frames at the pins", k: float = 1e4) -> str:
    """The double pendulum of :data:`DOUBLE` on a rotary spring of stiffness k."""
    return ("gravity = (0, -9.81)\nground { }\n" + DOUBLE[bodies]
            + f"force s2: rotary_spring(a, b, k = {k!r})\n"
            "simulate t = 0 .. 0.5 step 0.01, rtol = 1e-8, atol = 1e-10\n"
            "output th1 = a.phi, th2 = b.phi\n")


@pytest.mark.parametrize("bodies", list(DOUBLE), ids=list(DOUBLE))
def test_a_pin_between_two_moving_bodies_is_eliminated_too(bodies):
    """The double pendulum's second pin: its rows are in world axes and turn with the first
    rod, yet vanish wherever the second rod's reference point is the pin's: radau runs in
    the two joint angles, within 2e-7 rad of Lagrange's equations written by hand (solved
    apart at rtol 1e-11). With the pin doubled (a pin in a slot at the same point) the
    second joint's row goes too: on the joint angles it is a row of zeros (radau's step
    underflowed at t = 0.098 with it kept)."""
    import math

    from scipy.integrate import solve_ivp

    k = 1e4
    text = _double_pendulum_text(bodies, k)
    res = mechdsl.loads(text, "double.mech").simulate(options=SolverOptions(method="radau"))
    assert res.ok, res.messages
    assert "radau in the joints' own coordinates (2 of 6 left" in res.method, res.method
    J, g = 1 / 12, 9.81

    def f(t, y):
        t1, t2, w1, w2 = y
        c, s = math.cos(t1 - t2), math.sin(t1 - t2)
        M = np.array([[J + 0.25 + 1.0, 0.5 * c], [0.5 * c, J + 0.25]])
        rhs = np.array([-0.5 * s * w2 * w2 - 1.5 * g * math.cos(t1) + k * (t2 - t1),
                        0.5 * s * w1 * w1 - 0.5 * g * math.cos(t2) - k * (t2 - t1)])
        return [w1, w2, *np.linalg.solve(M, rhs)]
    ref = solve_ivp(f, (0, 0.5), [0, 0, 0, 0], method="DOP853", rtol=1e-11, atol=1e-13,
                    t_eval=res.times)
    assert np.abs(res["th1"] - ref.y[0]).max() < 2e-7
    assert np.abs(res["th2"] - ref.y[1]).max() < 2e-7


def test_a_run_that_ends_during_the_trial_says_so():
    """The skewed slider's run switches to relative coordinates at t = 0.0957 and ends at
    0.0975, before the trial's steps rated them: its note says so (a division by zero
    before, exit 3)."""
    text = dm.stiff_pendulum_skew_text(1e8).replace("t = 0 .. 2 step 0.01",
                                                    "t = 0 .. 0.0975 step 0.01")
    res = mechdsl.loads(text, "skew.mech").simulate(options=SolverOptions(method="radau"))
    assert res.ok, res.messages
    assert "the run ended before the trial's 8 steps rated them" in res.method, res.method


@pytest.mark.parametrize("model", ["stiff_pendulum_text", "stiff_pendulum_off_centre_text",
                                   "double"])
def test_the_generated_terms_equal_the_map(model):
    """The reduced equations traced and generated (mechdsl.solve.reduced_terms) against
    the same terms through the relative map and the absolute kernels, at random states:
    M_w and f_w, the three stages' residuals M_w a - f_w in one call (rows or flat), the
    absolute state (q, qd) and G = dq/dw (its columns against central differences of q); on the
    pendulum with its frames at the pins, at the rod's centre (pin points) and on a double
    pendulum on a rotary spring (a pin between two moving bodies)."""
    from mechdsl.solve.reduced import pin_points

    text = _double_pendulum_text() if model == "double" else getattr(dm, model)(1e6)
    kernels, rel, z = _relative(text)
    points = pin_points(rel, 0.0, z)
    if points is not None:
        rel = Relative(rel.base, rel.parent, points)
        y0 = np.concatenate((kernels.system.guess[0], np.zeros(rel.n)))
        z = rel.relative(y0)[:rel.n]
    red = reduce(rel, 0.0, z, 2.0)
    assert red is not None and red.m == 0
    traced = red.traced
    assert traced is not None
    rng = np.random.default_rng(11)
    n = red.n
    for _ in range(4):
        w = z[red.free] + rng.uniform(-0.3, 0.3, n)
        wd = rng.normal(size=n)
        t = float(rng.uniform(0, 2))
        M1, f1 = red.rel.mass_loads(t, red._z(w), red._zd(wd))
        M2, f2 = traced.terms(t, w, wd)
        assert np.abs(M2 - M1[red._ww]).max() < 1e-12 * np.abs(M1).max()
        assert np.abs(f2 - f1[red.free]).max() < 1e-10 * (1 + np.abs(f1).max())
        W, Wd, A = (rng.normal(size=(3, n)) for _ in range(3))
        W += w
        ts = [t, t + 0.1, t + 0.2]
        want = np.array([traced.terms(ts[j], W[j], Wd[j])[0] @ A[j]
                         - traced.terms(ts[j], W[j], Wd[j])[1] for j in range(3)])
        got = np.reshape(red.stage_residuals(ts, np.hstack((W, Wd)), A), (3, n))
        assert np.abs(got - want).max() < 1e-10 * (1 + np.abs(want).max())
        # the same with Y and A flat (radau's Newton iteration)
        flat = np.reshape(red.stage_residuals(ts, np.hstack((W, Wd)).ravel(), A.ravel()),
                          (3, n))
        assert np.abs(flat - want).max() < 1e-10 * (1 + np.abs(want).max())
        state, G = traced.absolute(w, wd)
        assert np.abs(state - red.rel.absolute(red._full(np.concatenate((w, wd))))).max() \
            < 1e-12
        for a in range(n):
            e = np.zeros(n)
            e[a] = 1e-6
            fd = (traced.state(w + e, wd)[:red.N] - traced.state(w - e, wd)[:red.N]) / 2e-6
            assert np.abs(G[:, a] - fd).max() < 1e-8


def test_a_run_in_the_joints_own_coordinates_is_on_the_constraints_unprojected():
    """In the joints' own coordinates with no equation left, every state satisfies the
    constraints identically: the outputs are reported as integrated (rule 6's
    exact_outputs), and the largest constraint residual over the run, measured at every
    output, is round-off."""
    res = mechdsl.loads(dm.stiff_pendulum_text(1e8)).simulate()
    assert res.ok and "joints' own coordinates" in res.method
    assert res.residual < 1e-12


def test_the_condition_of_a_joints_block_in_closed_form():
    """The 2 x 2 blocks' condition number in closed form equals numpy's SVD's; a singular
    block's is infinite."""
    from mechdsl.solve.reduced import _cond

    rng = np.random.default_rng(5)
    for _ in range(20):
        a = rng.normal(size=(2, 2)) * 10.0 ** rng.uniform(-3, 3)
        assert _cond(a) == pytest.approx(np.linalg.cond(a), rel=1e-10)
    assert _cond(np.array([[1.0, 2.0], [2.0, 4.0]])) == np.inf
    assert _cond(np.array([[0.0]])) == np.inf and _cond(np.array([[-3.0]])) == 1.0


def test_the_generated_terms_are_made_once_per_structure():
    """The joints' equations are generated for the reduction's structure, the eliminated
    coordinates' values and the points read as inputs: runs from states that differ (in
    round-off too: every trial starts elsewhere) reuse the code, so the model's graph and
    its kept code do not grow run after run (they grew by 19 MB a run on a chain of ten
    links whose trials said no), and the state-dependent choices keep one entry each."""
    mech = mechdsl.loads(dm.stiff_pendulum_text(1e8), "pendulum.mech")
    first = mech.simulate()
    d = mech.compile().dynamics
    nodes, kept = len(d.graph.nodes), len(d._floats)
    ref = dm.stiff_pendulum_oracle(1e8)
    for rtol, method in ((1e-7, "auto"), (3e-6, "auto"), (1e-6, "radau"), (2e-7, "radau")):
        res = mech.simulate(options=SolverOptions(rtol=rtol, method=method))
        assert res.ok and "joints' own coordinates" in res.method
        assert abs(res["theta"][-1] - ref[0]) < 1e-6
    assert len(d.graph.nodes) == nodes and len(d._floats) == kept
    assert sum(1 for key in d._floats if key[0] == "reduced") == 1
    assert first.ok


def test_a_sweeps_variants_share_the_generated_code_with_their_own_values():
    """A sweep over the spring's stiffness: each variant runs in the joints' coordinates
    within 1e-7 rad of its own minimal ODE (its own k among the generated code's inputs,
    run after run), and a variant's dynamics keeps its code in the model's (made once for
    the sweep, not once per variant and run)."""
    ks = [1e6, 1e8]
    mech = mechdsl.loads(dm.stiff_pendulum_text(1e6), "pendulum.mech")
    for order in (ks, ks[::-1]):
        theta = np.asarray(mech.simulate(sweep={"k": order})["theta"])
        for v, k in enumerate(order):
            assert abs(theta[v, -1] - dm.stiff_pendulum_oracle(k)[0]) < 1e-7
    d = mech.compile().dynamics
    assert d.variant(0)._floats is d._floats


def test_joints_that_lock_every_coordinate_leave_radau_in_absolute_ones():
    """Two bodies each held by a pin and a slider at one point (no degree of freedom), a
    rotary spring between them: the joints' own coordinates would be none at all, where
    radau raised a ValueError (a traceback; found in review). It stays in absolute
    coordinates, and the bodies stay where they are assembled."""
    text = """gravity = (0, -9.81)
ground { }
body a { guess = (0, 0, 0)  mass = 1  inertia = 0.1  point E = (1, 0) }
body b { guess = (1, 0, 0)  mass = 1  inertia = 0.1 }
joint p: revolute(ground.origin, a.origin)
joint l: prismatic(ground.origin, a.origin, axis = (1, 0))
joint q: revolute(a.E, b.origin)
joint r: prismatic(a.E, b.origin, axis = (1, 0))
force s: rotary_spring(a, b, k = 100.0)
simulate t = 0 .. 0.1 step 0.01
output b.x, b.phi
"""
    res = mechdsl.loads(text, "locked.mech").simulate(options=SolverOptions(method="radau"))
    assert res.ok, res.messages
    assert "joints' own coordinates" not in res.method
    assert np.abs(np.asarray(res["b.x"]) - 1.0).max() < 1e-12
    assert np.abs(np.asarray(res["b.phi"])).max() < 1e-12
