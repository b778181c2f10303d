"""Forward dynamics through redundant constraints and singular positions, through the public
API: what main refused (a mechanism with more equations than coordinates) or stopped at (the
first collinear position of IFToMM A02) is integrated, against independent truth."""

import importlib.util
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import mechdsl
from mechdsl.solve.options import SolverOptions
from conftest import ROOT


def _models():
    spec = importlib.util.spec_from_file_location(
        "dynamics_models", ROOT / "benchmarks" / "dynamics_models.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a02_passes_its_first_singular_position_on_the_parallelogram_branch():
    # 4 windows (9 bodies): the dense index-1 solve stops at the collinear position; the
    # run goes on by the augmented Lagrangian and stays on the branch whose motion is the
    # one-degree-of-freedom pendulum theta'' = -(K / I_eff) cos theta
    dm = _models()
    first = dm.a02_first_horizontal(4)
    t1 = round(first + 0.5, 2)
    res = mechdsl.loads(dm.a02_text(n=4, t1=t1, step=0.01, rtol=1e-8), "a02.mech").simulate()
    assert res.ok, res.messages
    assert res.n_solved[0] == len(res.times)
    ref = dm.a02_oracle(res.times, n=4)
    err = np.hypot(res.data["b0x"][0] - ref[:, 0], res.data["b0y"][0] - ref[:, 1])
    assert err.max() < 1e-4, err.max()
    # the collinear position is inside the span, and was passed (B0 below the ground line)
    assert first < t1 and res.data["b0y"][0][-1] < 0


def test_a_parallelogram_with_a_redundant_crank_falls_as_one_pendulum():
    # three equal cranks joined by one coupler: 12 equations for 12 coordinates, mobility 1.
    # Falling from rest under gravity, every crank turns as one physical pendulum:
    # (3 J_c + 3 m_c (a/2)^2 + m a^2) theta'' = -(3 m_c a/2 + m a) g cos theta
    a, d, mc, jc, m = 0.5, 2.0, 1.0, 0.1, 2.0
    text = f"""
param a = {a}
param d = {d}
gravity = (0, -9.81)
ground {{ point O1 = (0, 0)  point O2 = (d, 0)  point O3 = (2*d, 0) }}
body crank1 {{ guess = (0, 0, 0.8)  point O = (0, 0)  point A = (a, 0)  mass = {mc}  inertia = {jc}  centroid = (a/2, 0) }}
body crank2 {{ guess = (2, 0, 0.8)  point O = (0, 0)  point A = (a, 0)  mass = {mc}  inertia = {jc}  centroid = (a/2, 0) }}
body crank3 {{ guess = (4, 0, 0.8)  point O = (0, 0)  point A = (a, 0)  mass = {mc}  inertia = {jc}  centroid = (a/2, 0) }}
body coupler {{ guess = (2.35, 0.36, 0)  point A1 = (-d, 0)  point A2 = (0, 0)  point A3 = (d, 0)  mass = {m}  inertia = 1 }}
joint O1: revolute(ground.O1, crank1.O)
joint O2: revolute(ground.O2, crank2.O)
joint O3: revolute(ground.O3, crank3.O)
joint A1: revolute(crank1.A, coupler.A1)
joint A2: revolute(crank2.A, coupler.A2)
joint A3: revolute(crank3.A, coupler.A3)
initial start: angle(crank1) = 0.8, rate = 0
simulate t = 0 .. 1 step 0.05, rtol = 1e-10, atol = 1e-12
output crank1.phi, crank3.phi, coupler.phi
"""
    mech = mechdsl.loads(text, "par.mech")
    res = mech.simulate()
    assert res.ok, res.messages
    assert any("redundant" in w for w in res.warnings)
    # the redundancy shows only at the assembly (12 equations, 12 coordinates): the automatic
    # choice is the one for redundant constraints on the augmented Lagrangian, dop853 (it
    # kept vern9, whose error estimate is not reliable on its accelerations)
    assert res.method.startswith("dop853") and "redundant at the assembly" in res.method
    from scipy.integrate import solve_ivp

    inertia = 3 * (jc + mc * (a / 2) ** 2) + m * a * a
    moment = (3 * mc * a / 2 + m * a) * 9.81
    sol = solve_ivp(lambda _, y: (y[1], -moment / inertia * math.cos(y[0])), (0, 1),
                    [0.8, 0.0], method="DOP853", rtol=1e-12, atol=1e-14, t_eval=res.times)
    np.testing.assert_allclose(res.data["crank1.phi"][0], sol.y[0], atol=1e-7)
    np.testing.assert_allclose(res.data["crank3.phi"][0], sol.y[0], atol=1e-7)
    np.testing.assert_allclose(res.data["coupler.phi"][0], 0.0, atol=1e-9)
    # over 20 s at rtol 1e-8: dop853 within 3e-7 rad of the pendulum (1.8e-7; vern9 5.5e-7)
    res = mech.simulate(span=(0, 20), step=0.1,
                        options=SolverOptions(rtol=1e-8, atol=1e-10))
    sol = solve_ivp(lambda _, y: (y[1], -moment / inertia * math.cos(y[0])), (0, 20),
                    [0.8, 0.0], method="DOP853", rtol=1e-12, atol=1e-14, t_eval=res.times)
    assert np.abs(res.data["crank1.phi"][0] - sol.y[0]).max() < 3e-7


# a parallelogram with four cranks (two of them redundant), the first driven at 3 rad/s, and
# a pendulum hung from the coupler: 18 equations for 18 coordinates, but of rank 16 with
# the drive, so one degree of freedom is left (the pendulum's)
FOUR_CRANKS_PENDULUM = """param r = 0.3
param a = 0.5
param th0 = 1.0
ground { point O1 = (0, 0)  point O2 = (a, 0)  point O3 = (2*a, 0)  point O4 = (1.5*a, 0) }
body k1 { guess = (r/2*sin(th0), -r/2*cos(th0), th0)  point A = (0, r/2)  point B = (0, -r/2)  mass = 0.4  inertia = 0.003 }
body k2 { guess = (a + r/2*sin(th0), -r/2*cos(th0), th0)  point A = (0, r/2)  point B = (0, -r/2)  mass = 0.4  inertia = 0.003 }
body k3 { guess = (2*a + r/2*sin(th0), -r/2*cos(th0), th0)  point A = (0, r/2)  point B = (0, -r/2)  mass = 0.4  inertia = 0.003 }
body k4 { guess = (1.5*a + r/2*sin(th0), -r/2*cos(th0), th0)  point A = (0, r/2)  point B = (0, -r/2)  mass = 0.4  inertia = 0.003 }
body cp { guess = (a + r*sin(th0), -r*cos(th0), 0)  point P4 = (a/2, 0)  point P1 = (-a, 0)  point P2 = (0, 0)  point P3 = (a, 0)  mass = 2  inertia = 0.2 }
body pend { guess = (a + r*sin(th0) + 0.2*sin(0.3), -r*cos(th0) - 0.2*cos(0.3), 0.3)  point T = (0, 0.2)  mass = 0.5  inertia = 0.5*0.4^2/12 }
joint g1: revolute(ground.O1, k1.A)
joint g2: revolute(ground.O2, k2.A)
joint g3: revolute(ground.O3, k3.A)
joint g4: revolute(ground.O4, k4.A)
joint c1: revolute(k1.B, cp.P1)
joint c2: revolute(k2.B, cp.P2)
joint c3: revolute(k3.B, cp.P3)
joint c4: revolute(k4.B, cp.P4)
joint hang: revolute(cp.P2, pend.T)
drive spin: angle(k1) = th0 + 3*t
gravity = (0, -9.81)
simulate t = 0 .. 2 step 0.01
output pend.phi, pend.omega
"""


@pytest.mark.parametrize("cranks", [3, 4])
def test_a_driven_model_whose_redundant_joints_hide_a_free_degree_of_freedom_moves(cranks):
    # the count says fully driven (3 cranks: 15 equations for 15 coordinates; 4: 18 for
    # 18); the rank at the assembly leaves the pendulum free: the run is forward dynamics
    # (3 cranks: it stopped "at a singular position at t = 0"; 4: "not fully driven")
    text = FOUR_CRANKS_PENDULUM if cranks == 4 else "\n".join(
        line for line in FOUR_CRANKS_PENDULUM.splitlines() if "k4" not in line)
    res = mechdsl.loads(text, "p.mech").simulate()
    assert mechdsl.loads(text, "p.mech").check().free == 1
    assert res.ok, res.messages
    assert res.method  # forward dynamics (the kinematics has no integrator)
    # the coupler translates on a circle: its point P2 at (a + r sin th, -r cos th), th =
    # th0 + 3 t; the pendulum (mass 0.5, length 0.4, pinned 0.2 above its centre) about
    # that moving pivot: I_O phi'' = -m l ((g + a_y) sin phi + a_x cos phi)
    ref = _about_circling_pivot(res["t"], res["pend.omega"][0])
    assert np.abs(res["pend.phi"] - ref[0]).max() < 1e-6


def _about_circling_pivot(t: np.ndarray, omega0: float) -> np.ndarray:
    """(phi, phi') of the pendulum whose pivot P2 circles at 3 rad/s (the models above)."""
    r, W, g, m, l = 0.3, 3.0, 9.81, 0.5, 0.2
    inertia = m * 0.4 ** 2 / 12 + m * l * l

    def f(t, y):
        th = 1.0 + W * t
        ax, ay = -r * W * W * math.sin(th), r * W * W * math.cos(th)
        return [y[1], -m * l * ((g + ay) * math.sin(y[0]) + ax * math.cos(y[0])) / inertia]
    return solve_ivp(f, (t[0], t[-1]), [0.3, omega0], method="DOP853", rtol=1e-12,
                     atol=1e-13, t_eval=t).y


def test_radau_on_a_driven_redundant_model_passes_or_says_what_does():
    # radau's iteration did not pass the cranks' collinear position (t = 0.19) of the
    # driven three-crank parallelogram; where it stops, it says which way passes
    text = "\n".join(line for line in FOUR_CRANKS_PENDULUM.splitlines() if "k4" not in line)
    res = mechdsl.loads(text, "p.mech").simulate(options=SolverOptions(method="radau"))
    if res.ok:  # (then right: the pendulum about its circling pivot, as above)
        ref = _about_circling_pivot(res["t"], res["pend.omega"][0])
        assert np.abs(res["pend.phi"] - ref[0]).max() < 1e-6
    else:
        message = res.messages[0]
        assert "the step size underflowed at t = 0.190" in message
        assert "the augmented Lagrangian with an explicit pair (the automatic choice, or " \
               "--method dop853) integrates through singular positions" in message


def test_outputs_inside_a_step_over_a_singular_position_are_integrated_again():
    # the four-crank model over 5 s at rtol 1e-8: a dop853 step of 0.077 s spans the
    # cranks' collinear position at t = 3.332, its ends within 1e-8 of the oracle, its
    # interpolant 0.16 rad/s off the pendulum's angular velocity inside (the augmented
    # Lagrangian's accelerations turn within a small interval there); the projection left
    # 3.9e-3 rad/s. Those outputs are now integrated again from the step's start.
    text = FOUR_CRANKS_PENDULUM.replace("simulate t = 0 .. 2 step 0.01",
                                        "simulate t = 0 .. 5 step 0.01, rtol = 1e-8")
    res = mechdsl.loads(text, "p.mech").simulate()
    assert res.ok, res.messages
    ref = _about_circling_pivot(res["t"], res["pend.omega"][0])
    assert np.abs(res["pend.phi"] - ref[0]).max() < 2e-7
    assert np.abs(res["pend.omega"] - ref[1]).max() < 1e-6


#: A parallelogram four-bar (crank and rocker 1 m and 1 kg, coupler 2 m and 2 kg, all
#: uniform; pivots 2 m apart) under gravity, the crank at 0.5 rad turning at -2 rad/s: it
#: reaches its collinear position (theta = 0) at t = 0.1730954
PARALLELOGRAM = """gravity = (0, -9.81)
ground { point A = (0, 0)  point D = (2, 0) }
body crank { guess = (0.4388, 0.2397, 0.5)  point A = (-0.5, 0)  point B = (0.5, 0)  mass = 1  inertia = 1/12 }
body coupler { guess = (1.8776, 0.4794, 0)  point B = (-1, 0)  point C = (1, 0)  mass = 2  inertia = 2*4/12 }
body rocker { guess = (2.4388, 0.2397, 0.5)  point D = (-0.5, 0)  point C = (0.5, 0)  mass = 1  inertia = 1/12 }
joint A: revolute(ground.A, crank.A)
joint B: revolute(crank.B, coupler.B)
joint C: revolute(coupler.C, rocker.C)
joint D: revolute(rocker.D, ground.D)
initial a: angle(crank) = 0.5, rate = -2
simulate t = 0 .. 0.5 step 0.01
output th = crank.phi, ph = coupler.phi
"""


def test_the_dense_solve_hands_a_collinear_position_to_the_augmented_lagrangian_at_once():
    """The dense index-1 solve cannot pass the parallelogram's collinear position. It used
    to take 14,689 ever shorter steps around it until a projection failed 7 ms past it
    (6.5 s of a 6.8 s run); the stall is now recognised where it starts (mechdsl.solve.driver, "stalls": Phi_q singular there), and the augmented
    Lagrangian integrates the variant, on the parallelogram branch: the one-degree-of-
    freedom pendulum (8/3) theta'' = -3 g cos theta (T = (1/3 + 1/3 + 2) theta'^2 / 2, V =
    (0.5 + 0.5 + 2) g sin theta), the coupler parallel to the ground."""
    import re

    res = mechdsl.loads(PARALLELOGRAM, "parallelogram.mech").simulate()
    assert res.ok, res.messages
    stall = [w for w in res.warnings if "stalled" in w]
    assert stall and "singular position" in stall[0], res.warnings
    # on from the last output instant reached, not again from t0
    assert "the variant went on from t = 0.17 by the augmented Lagrangian" in stall[0]
    crossing = solve_ivp(lambda t, y: [y[1], -9 / 8 * 9.81 * math.cos(y[0])], (0, 0.5),
                         [0.5, -2.0], rtol=1e-12, atol=1e-14,
                         events=lambda t, y: y[0]).t_events[0][0]
    at = float(re.search(r"stalled at t = ([0-9.e+-]+)", stall[0])[1])
    assert abs(at - crossing) < 1e-4, (at, crossing)
    # the automatic choice's pair for the augmented Lagrangian through singular positions
    assert "dop853 on the augmented Lagrangian, where a singular position" in res.method
    ref = solve_ivp(lambda t, y: [y[1], -9 / 8 * 9.81 * math.cos(y[0])], (0, 0.5),
                    [0.5, -2.0], rtol=1e-12, atol=1e-14, t_eval=res.times).y[0]
    assert np.max(np.abs(res["th"] - ref)) < 1e-7
    assert np.max(np.abs(res["ph"])) < 1e-9
    assert res["th"][-1] < -1.7  # (well past the collinear position)


def test_a_stall_is_a_run_of_steps_far_shorter_than_those_before():
    """mechdsl.solve.driver._Stall: STALL_STEPS accepted steps in a row, each below
    STALL_RATIO times the fading longest step before them; a run whose steps shrink
    gradually (by 1 % a step, as a step-size control may over a long approach) is none."""
    from mechdsl.solve.driver import STALL_RATIO, STALL_STEPS, _Stall

    stall = _Stall()
    assert not any(stall.after(1e-3) for _ in range(20))
    tiny = 0.1 * STALL_RATIO * 1e-3
    assert not any(stall.after(tiny) for _ in range(STALL_STEPS - 1))
    assert stall.after(tiny)
    stall = _Stall()
    assert not any(stall.after(1e-3 * 0.99 ** k) for k in range(5000))
    stall = _Stall()  # one longer step in between starts the count afresh
    stall.after(1e-3)
    assert not any(stall.after(tiny) for _ in range(STALL_STEPS - 1))
    stall.after(1e-3)
    assert not any(stall.after(tiny) for _ in range(STALL_STEPS - 1))


def test_an_implicit_run_stopped_at_a_singular_position_says_what_passes_it():
    """Where radau's step underflows, the failure says whether the state it stopped at is a
    singular position (Phi_q D's smallest singular value below SINGULAR_NEAR of its
    largest), and what integrates through one. Checked on the parallelogram's own
    configurations: at its collinear position (every link on the ground line) Phi_q has
    rank 7 of 8, a ratio at round-off; at theta = 0.5 it is far from singular, and no
    advice is given."""
    from mechdsl.solve.driver import Solution
    from mechdsl.solve.dynamic import DynamicRun, _singular_ratio
    from mechdsl.solve.motion import Motion

    mech = mechdsl.loads(PARALLELOGRAM)
    kernels = mech.compile()
    run = DynamicRun(kernels, SolverOptions(method="radau"))
    motion = Motion(kernels, run.opts)
    D = run.D[0, 0]
    collinear = np.array([0.5, 0, 0, 2, 0, 0, 2.5, 0, 0] + [0.0] * 9)
    c, s = math.cos(0.5), math.sin(0.5)
    regular = np.array([0.5 * c, 0.5 * s, 0.5, 1 + c, s, 0, 2 + 0.5 * c, 0.5 * s, 0.5]
                       + [0.0] * 9)
    assert np.abs(motion.phi_jac(0.0, collinear[:9])[0]).max() < 1e-12  # (on the constraints)
    assert np.abs(motion.phi_jac(0.0, regular[:9])[0]).max() < 1e-12
    assert _singular_ratio(motion, 0.0, collinear, D) < 1e-12
    assert _singular_ratio(motion, 0.0, regular, D) > 1e-2

    def note(y):
        failed = Solution(np.zeros(1), np.zeros((1, 18)), "failed",
                          "the step size underflowed at t = 0.17", 10, 5, 100, 0.17,
                          y_reached=y)
        return run._implicit_note(failed, motion, 0)

    assert "did not pass the singular position there" in note(collinear)
    assert "--method dop853" in note(collinear)
    assert note(regular) == ""


def _driven_parallelogram(t1: float) -> str:
    """A parallelogram (cranks 0.6 m, their pivots 1.5 m apart) driven at 2 rad/s from 0.2
    rad through its collinear positions (theta = pi at t = 1.4708, 2 pi at 3.0416), a bead
    of 0.2 kg sliding along the coupler on a spring of 1e4 N/m and a damper of 2 N s/m
    (trial 49's model m10)."""
    return f"""param a = 0.6
param d = 1.5
gravity = (0, -9.81)
ground {{ point O1 = (0, 0)  point O2 = (d, 0) }}
body crank1 {{ guess = (0, 0, 0.2)  point A = (a, 0)  mass = 1  inertia = a^2/12  centroid = (a/2, 0) }}
body crank2 {{ guess = (d, 0, 0.2)  point A = (a, 0)  mass = 1.5  inertia = 1.5*a^2/12  centroid = (a/2, 0) }}
body coupler {{ guess = (a*cos(0.2), a*sin(0.2), 0)  point A1 = (0, 0)  point A2 = (d, 0)  mass = 3  inertia = 3*d^2/12  centroid = (d/2, 0.2) }}
body bead {{ guess = (a*cos(0.2) + 0.75, a*sin(0.2), 0)  mass = 0.2  inertia = 1e-4 }}
joint O1: revolute(ground.O1, crank1.origin)
joint O2: revolute(ground.O2, crank2.origin)
joint A1: revolute(crank1.A, coupler.A1)
joint A2: revolute(crank2.A, coupler.A2)
joint S: prismatic(coupler.origin, bead.origin, axis = (1, 0))
drive motor: angle(crank1) = 0.2 + 2*t
force sp: spring(coupler.origin, bead.origin, k = 1e4, length = 0.75, c = 2)
initial b: distance(coupler.origin, bead.origin) = 0.75, rate = 0
simulate t = 0 .. {t1} step 0.01, rtol = 1e-6
output crank2.phi, coupler.phi, s = distance(coupler.origin, bead.origin)
"""


def test_a_driven_parallelogram_passes_its_collinear_positions():
    """At a collinear position the projections' Gauss-Newton steps are the residual's
    rounding over Phi_q's smallest singular value: they stopped shrinking (2.3e-10 scaled,
    1.5 % less an iteration, against newton_tol 1e-10) with |Phi| at 3e-14 m, and the run
    stopped there, "the position constraints cannot be closed (a lock-up)", at the first
    passage or the second as the steps happened to fall. The state is now taken as closed
    where Phi holds to round-off (diagnose.closed_to_roundoff), and the run passes both, on
    the parallelogram branch: the coupler translates (its angle 0), crank2 turns with
    crank1, and the bead follows s'' = -(k/m)(s - L0) - (c/m) s' + a w^2 cos(theta) (the
    coupler's acceleration along the slide, -a w^2 cos theta, felt as an inertial force)."""
    t1 = 3.5
    res = mechdsl.loads(_driven_parallelogram(t1), "parallelogram.mech").simulate()
    assert res.ok, res.messages
    assert res.times[-1] == pytest.approx(t1)
    theta = 0.2 + 2 * res.times
    assert np.max(np.abs(res["coupler.phi"])) < 1e-9
    assert np.max(np.abs(np.angle(np.exp(1j * (res["crank2.phi"] - theta))))) < 1e-9

    def bead(t, y):
        return [y[1], -(1e4 * (y[0] - 0.75) + 2 * y[1]) / 0.2 + 0.6 * 4 * math.cos(0.2 + 2 * t)]

    ref = solve_ivp(bead, (0, t1), [0.75, 0.0], method="DOP853", rtol=1e-12, atol=1e-14,
                    t_eval=res.times).y[0]
    assert np.max(np.abs(res["s"] - ref)) < 2e-5


def test_the_augmented_lagrangian_goes_on_with_the_dissipated_energy_so_far():
    """The parallelogram above carrying a bead on a damped spring along its coupler: the
    dense solve stalls at the collinear position (t = 0.1738), the augmented Lagrangian goes
    on from the output at t = 0.17 (mechdsl.solve.dynamic, _go_on), and the dissipated
    energy's integral goes on from its value there: kinetic + potential + dissipated energy
    stays what it was at t0 (the model is otherwise conservative) to 1e-7 of it, and the
    dissipated energy never decreases."""
    text = PARALLELOGRAM.replace(
        "joint D: revolute(rocker.D, ground.D)",
        "joint D: revolute(rocker.D, ground.D)\n"
        "body bead { guess = (1.8776, 0.4794, 0)  mass = 0.3  inertia = 1e-3 }\n"
        "joint S: prismatic(coupler.origin, bead.origin, axis = (1, 0))\n"
        "force sp: spring(coupler.origin, bead.origin, k = 100, length = 0, c = 1)\n"
        "initial b: distance(coupler.origin, bead.origin) = 0, rate = 0").replace(
        "output th = crank.phi, ph = coupler.phi",
        "output E = kinetic_energy + potential_energy + dissipated_energy, "
        "W = dissipated_energy")
    res = mechdsl.loads(text, "parallelogram.mech").simulate()
    assert res.ok, res.messages
    assert any("went on from t = 0.17 by the augmented Lagrangian" in w
               for w in res.warnings), res.warnings
    E, W = res["E"], res["W"]
    assert np.max(np.abs(E - E[0])) < 1e-7 * abs(E[0])
    assert np.all(np.diff(W) >= 0) and W[-1] > 0.1
