"""The implicit path's pieces against independent truth: the entries-only sparse matrices
(:mod:`mechdsl.solve.triplets`) against dense algebra, the constraints' curvature
(:mod:`mechdsl.compiled.curvature`) against central differences of Phi_q^T lambda, Hairer's
stiffness detection against the stability boundaries of the pairs, and the automatic switch
to the implicit method on the stiff pendulum against its minimal ODE."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import dynamics_models as dm  # noqa: E402
import mechdsl  # noqa: E402
from mechdsl.solve.explicit import coefficients, stiffness_probe  # noqa: E402
from mechdsl.solve.motion import Motion  # noqa: E402
from mechdsl.solve.options import SolverOptions  # noqa: E402
from mechdsl.solve.triplets import Triplets  # noqa: E402

def _random_triplets(rng, shape=(7, 5), nnz=20):
    rows = rng.integers(0, shape[0], nnz)
    cols = rng.integers(0, shape[1], nnz)  # repeats included: they add
    return Triplets(rng.normal(size=nnz), rows, cols, shape)


def test_triplets_products_are_the_dense_matrix_products():
    rng = np.random.default_rng(1)
    a = _random_triplets(rng)
    dense = np.zeros(a.shape)
    for r, c, v in zip(a.rows, a.cols, a.data):
        dense[r, c] += v
    assert np.array_equal(a.toarray(), dense)
    x = rng.normal(size=5)
    assert np.allclose(a @ x, dense @ x, rtol=1e-14, atol=1e-14)
    z = rng.normal(size=5) + 1j * rng.normal(size=5)
    assert np.allclose(a @ z, dense @ z, rtol=1e-14, atol=1e-14)
    X = rng.normal(size=(5, 3))
    assert np.allclose(a @ X, dense @ X, rtol=1e-14, atol=1e-14)
    y = rng.normal(size=7)
    assert np.allclose(a.T @ y, dense.T @ y, rtol=1e-14, atol=1e-14)
    assert np.allclose(a.tocsc().toarray(), dense) and np.allclose(a.tocsr().toarray(), dense)


def _central_difference(motion, t, q, lam, step=1e-6):
    def force(x):
        return motion.phi_jac(t, x)[1].T @ lam
    cols = []
    for j in range(motion.n):
        e = np.zeros(motion.n)
        e[j] = step
        cols.append((force(q + e) - force(q - e)) / (2 * step))
    return np.column_stack(cols)


@pytest.mark.parametrize("text", [
    dm.a02_text(n=3, t1=1.0),                       # revolutes only (the member layout)
    dm.a02_text(n=40, t1=1.0),                      # 81 bodies: traced member by member here
    dm.stiff_pendulum_text(1e4),                    # a prismatic joint
])
def test_curvature_is_the_derivative_of_the_constraint_forces(text):
    motion = Motion(mechdsl.loads(text).compile())
    rng = np.random.default_rng(2)
    q = motion.system.guess.reshape(-1)[:motion.n] + 0.1 * rng.normal(size=motion.n)
    lam = rng.normal(size=motion.m) * 100.0
    exact = motion.constraint_curvature(0.3, q, lam).toarray()
    fd = _central_difference(motion, 0.3, q, lam)
    scale = np.abs(fd).max()
    assert scale > 1.0  # the constraints are not linear: the test can fail
    assert np.abs(exact - fd).max() <= 1e-7 * scale
    assert np.allclose(exact, exact.T, atol=1e-12 * scale)  # a weighted sum of Hessians


def test_stiffness_thresholds_lie_inside_the_stability_regions():
    """Each pair's threshold of h rho: on both axes up to it, |R(z)| <= 1 + 1e-3 (the
    stability function from the tableau), and the real axis's boundary lies beyond it."""
    for name in ("dopri5", "dop853", "vern9"):
        unit, bound, weights = stiffness_probe(name)
        pair = coefficients(name)
        s = pair.stages
        assert unit is not None and pair.c[unit] == 1.0
        A = np.zeros((s, s))
        for i in range(1, s):
            A[i, :len(pair.a[i])] = pair.a[i]

        def R(z):
            return 1 + z * (pair.b[:s] @ np.linalg.solve(np.eye(s) - z * A, np.ones(s)))
        assert abs(R(-bound)) <= 1 + 1e-3
        # y_new - Y_unit = h sum_j w_j K_j: on y' = 1 (every K_j = 1) it is h (1 - c_unit) = 0
        assert abs(weights.sum() - (1.0 - pair.c[unit])) < 1e-13
        assert abs(R(-2.5 * bound)) > 1  # the threshold is not far inside on the real axis
        assert bound > 1.0  # above the h rho of accurate steps of a smooth motion


def test_a_stiff_spring_switches_to_the_implicit_method_and_stays_accurate():
    k = 1e8
    res = mechdsl.loads(dm.stiff_pendulum_text(k)).simulate()
    assert res.ok, res.messages
    assert "radau from t = " in res.method and "proved stiff" in res.method
    ref = dm.stiff_pendulum_oracle(k)
    assert abs(res["theta"][-1] - ref[0]) < 1e-5
    assert abs(res["s"][-1] - ref[1]) < 1e-5


def test_the_outputs_of_the_implicit_trial_are_kept_and_accurate():
    """The run goes on with the trial's own radau steps (their outputs from their dense
    outputs, projected): every output before and after the switch, at the instants asked,
    within 1e-5 of the minimal ODE, and the run no slower than a named radau run's steps."""
    k = 1e8
    res = mechdsl.loads(dm.stiff_pendulum_text(k, t1=0.2)).simulate()
    assert res.ok and "radau from t = " in res.method, res.method
    t = np.asarray(res["t"])
    assert np.allclose(t, np.linspace(0.0, 0.2, 21), rtol=0, atol=1e-12)
    ref = dm.stiff_pendulum_solve(k, 0.2, "Radau", rtol=1e-8, t_eval=t)
    assert ref.success
    assert np.abs(np.asarray(res["theta"]) - ref.y[0]).max() < 1e-5
    assert np.abs(np.asarray(res["s"]) - ref.y[1]).max() < 1e-5


def _spring_fourbar(k: float) -> str:
    """Two links pinned to the ground at (0, 0) and (2, 0), their ends joined by a spring
    of stiffness k, relaxed at the start (a four-bar whose coupler is a spring)."""
    return f"""
gravity = (0, -9.81)
ground {{ point O2 = (2, 0) }}
body crank {{ guess = (0, 0, 1.2) mass = 1 inertia = 0.1 point B = (1, 0) centroid = (0.5, 0) }}
body rocker {{ guess = (2, 0, 1.9) mass = 1 inertia = 0.2 point B = (1.5, 0)
               centroid = (0.75, 0) }}
joint O1: revolute(ground.origin, crank.origin)
joint O2: revolute(ground.O2, rocker.origin)
force link: spring(crank.B, rocker.B, k = {k!r}, length = {_FOURBAR_LENGTH!r})
simulate t = 0 .. 2 step 0.01, rtol = 1e-6, atol = 1e-8
output crank.phi, rocker.phi
"""


#: the spring's length at the start: |B_rocker - B_crank| at phi = 1.2 and 1.9
_FOURBAR_LENGTH = float(np.hypot(2 + 1.5 * np.cos(1.9) - np.cos(1.2),
                                 1.5 * np.sin(1.9) - np.sin(1.2)))


def _spring_fourbar_minimal(k: float, t1: float) -> np.ndarray:
    """(phi_crank, phi_rocker) at t1 from the two links' own equations, each turning about
    its pin (I = I_c + m d^2) under gravity and the spring's force, by DOP853 at 1e-12."""
    from scipy.integrate import solve_ivp

    g, i1, i2 = 9.81, 0.1 + 0.5 ** 2, 0.2 + 0.75 ** 2

    def rhs(t, y):
        a, b, wa, wb = y
        bc = np.array([np.cos(a), np.sin(a)])
        rb = 1.5 * np.array([np.cos(b), np.sin(b)])
        d = np.array([2.0, 0.0]) + rb - bc
        length = np.hypot(*d)
        f = k * (length - _FOURBAR_LENGTH) * d / length  # on the crank's end, toward the rocker
        torque_a = -g * 0.5 * np.cos(a) + (bc[0] * f[1] - bc[1] * f[0])
        torque_b = -g * 0.75 * np.cos(b) - (rb[0] * f[1] - rb[1] * f[0])
        return [wa, wb, torque_a / i1, torque_b / i2]

    sol = solve_ivp(rhs, (0.0, t1), [1.2, 1.9, 0.0, 0.0], method="DOP853", rtol=1e-12,
                    atol=1e-14)
    assert sol.success
    return sol.y[:2, -1]


def test_a_resolved_oscillation_at_the_stability_boundary_keeps_its_pair():
    """The spring's oscillation (about 30 rad/s... 170 rad/s at 1e4 N/m) is followed to the
    tolerance by vern9 at h rho near its stability boundary, which Hairer's test reads as
    stiffness; radau's steps there are no longer (it must follow the oscillation too), so
    the trial says no and the pair goes on: 4e-7 rad from the links' own equations. (Switched
    without a trial, radau took 2.3 times vern9's time and ended 1.9e-4 rad off.)"""
    k = 1e4
    res = mechdsl.loads(_spring_fourbar(k)).simulate()
    assert res.ok, res.messages
    assert res.method.startswith("vern9") and "radau" not in res.method, res.method
    ref = _spring_fourbar_minimal(k, 2.0)
    assert abs(res["crank.phi"][-1] - ref[0]) < 1e-5
    assert abs(res["rocker.phi"][-1] - ref[1]) < 1e-5


def test_a_stiffness_the_pair_resolves_is_found_by_a_trial_of_the_implicit_method():
    """k = 1e7: vern9's steps follow the spring's oscillation to the tolerance (h rho about
    0.7, far below its stability boundary 2.6, so Hairer's test never fires) and their
    number grows like sqrt(k): 3168 steps where radau takes about a hundred. The trial of
    radau (module mechdsl.solve.driver) finds steps 10 times longer and the run goes on
    with it, as accurate as the Done-when of issue 28 asks (1e-5 against the minimal ODE)."""
    from mechdsl.solve.driver import TRIAL_RATIO

    k = 1e7
    res = mechdsl.loads(dm.stiff_pendulum_text(k)).simulate()
    assert res.ok, res.messages
    assert "radau from t = " in res.method and "over a trial of" in res.method, res.method
    ratio = float(res.method.split("radau's steps ")[1].split(" times")[0])
    assert ratio >= TRIAL_RATIO
    ref = dm.stiff_pendulum_oracle(k)
    assert abs(res["theta"][-1] - ref[0]) < 1e-5
    assert abs(res["s"][-1] - ref[1]) < 1e-5


def test_a_moderate_spring_keeps_its_pair_until_a_trial_says_yes(monkeypatch):
    """Where the rest of the run takes fewer than TRIAL_MIN_STEPS explicit steps (k = 1e5:
    about 400) nothing is tried and the pair goes on. The pendulum whose slider's axis is
    skewed in the rod's frame at k = 1e6 (radau keeps that row as an equation and starts
    in absolute coordinates: test_reduced.py): the first trial finds radau's steps under
    TRIAL_RATIO times the pair's and declines; the trial is asked again after pauses that double, and
    a later one, against the pair's mean step over the run, finds them long enough: the
    run goes on with radau, within 1e-5 rad of the minimal ODE. (The stiff pendulum itself
    at k = 1e6 now says yes at the first trial, radau's steps in its joint coordinates
    15 times vern9's.)"""
    import mechdsl.solve.driver as driver

    tried = []
    original = driver._trial

    def watch(*args):
        tried.append(original(*args))
        return tried[-1]

    monkeypatch.setattr(driver, "_trial", watch)
    res = mechdsl.loads(dm.stiff_pendulum_text(1e5)).simulate()
    assert res.ok and "radau" not in res.method, res.method
    assert tried and all(why is None and not spent.any() for why, spent, _ in tried)
    tried.clear()
    k = 1e6
    res = mechdsl.loads(dm.stiff_pendulum_skew_text(k)).simulate()
    assert res.ok and "radau from t = " in res.method, res.method
    assert tried[0][0] is None and tried[0][1][0] > 0  # ran, and declined
    assert tried[-1][0] is not None  # the one that said yes
    assert abs(res["theta"][-1] - dm.stiff_pendulum_oracle(k)[0]) < 1e-5


def test_a_soft_spring_keeps_the_explicit_pair():
    res = mechdsl.loads(dm.stiff_pendulum_text(1e2)).simulate()
    assert res.ok, res.messages
    assert res.method.startswith("vern9") and "radau" not in res.method


def test_a_named_method_is_never_switched():
    res = mechdsl.loads(dm.stiff_pendulum_text(1e8, t1=0.05)).simulate(
        options=SolverOptions(method="dopri5"))
    assert res.ok, res.messages
    assert res.method.startswith("dopri5") and "radau" not in res.method


class _Watch:
    """A progress display that records the BLAS threads at every accepted step."""

    def __init__(self) -> None:
        self.threads: set[int] = set()

    def __call__(self, done: int, total: int) -> None:  # the instants' display (unused)
        pass

    def motion(self, t, steps, t0, t1, variant, variants, budget) -> None:
        from threadpoolctl import threadpool_info

        self.threads.update(d["num_threads"] for d in threadpool_info()
                            if d["user_api"] == "blas")


@pytest.mark.parametrize("limit", [1, 2])
def test_the_dynamics_runs_with_the_blas_threads_it_is_given(limit):
    from threadpoolctl import threadpool_info, threadpool_limits

    from mechdsl.solve.dynamic import DynamicRun

    kernels = mechdsl.loads(dm.chain_text(15, t1=0.05)).compile()  # 45 coordinates: large
    watch = _Watch()
    with threadpool_limits(limits=4, user_api="blas"):  # the process's own setting
        before = {d["filepath"]: d["num_threads"] for d in threadpool_info()}
        res = DynamicRun(kernels, SolverOptions(blas_threads=limit), progress=watch).run()
        after = {d["filepath"]: d["num_threads"] for d in threadpool_info()}
    assert res.ok, res.messages
    assert watch.threads == {limit}
    # restored, for every library loaded before (the run may load scipy's own)
    assert {k: after[k] for k in before} == before


def test_blas_threads_is_a_named_option_error(capsys):
    from mechdsl.cli import main

    model = Path(__file__).resolve().parents[1] / "examples" / "andrews.mech"
    assert main(["run", str(model), "--blas-threads", "-1", "-q"]) == 1
    assert "--blas-threads: blas_threads must be a whole number" in capsys.readouterr().err
    with pytest.raises(ValueError, match="blas_threads"):
        SolverOptions(blas_threads=-1)


def test_radau_passes_a02s_first_collinear_position_at_a_tight_tolerance():
    """IFToMM A02 (N = 40): every rocker horizontal at t = 0.7216 (Phi_q loses 40 of its
    rank there); radau at rtol 1e-8 used to stop just before it (the step size underflowed).
    B0 against the parallelogram branch's one-degree-of-freedom equation, after the
    passage."""
    t1 = 1.0
    assert dm.a02_first_horizontal() < t1
    res = mechdsl.loads(dm.a02_text(t1=t1, step=0.05, rtol=1e-8, atol=1e-10)).simulate(
        options=SolverOptions(method="radau"))
    assert res.ok, res.messages
    ref = dm.a02_oracle(res.times)
    err = np.hypot(res["b0x"] - ref[:, 0], res["b0y"] - ref[:, 1])
    assert err.max() < 1e-7


def test_radau_passes_a02s_next_collinear_positions_at_a_tight_tolerance():
    """A02 to t = 7.3, past eight of its collinear positions, with radau at rtol 1e-8. It
    stopped at two of them (the step size underflowed):

    * at t = 1.244, by its step-size controller: after steps halved by Newton failures,
      Gustafsson's prediction (h / h_prev) (err_prev / err)^1/4 read the halving as a
      trend and shrank every following step tenfold;
    * at t = 7.141, by Newton's rate: at a singular position it converges linearly, at
      rates of 0.6 to 0.9 there, which the iteration gave up at 0.6.

    B0 against the parallelogram branch's one-degree-of-freedom equation at every output;
    the error grows with the phase over the run (1.7e-6 m by t = 7)."""
    t1 = 7.3
    res = mechdsl.loads(dm.a02_text(t1=t1, step=0.05, rtol=1e-8, atol=1e-10)).simulate(
        options=SolverOptions(method="radau"))
    assert res.ok, res.messages
    ref = dm.a02_oracle(res.times)
    assert np.sum(np.diff(np.sign(ref[:, 1])) != 0) >= 8  # the passages it went through
    err = np.hypot(res["b0x"] - ref[:, 0], res["b0y"] - ref[:, 1])
    assert err.max() < 5e-6


def test_a_large_model_is_planned_with_its_banded_solver_not_a_dense_one():
    """The memory plan of a forward dynamics of many bodies counts the augmented
    Lagrangian's sparse terms, not a dense n x n matrix: a chain of 3000 links (12 s, a
    258 MiB peak) was refused as needing 4.1 GiB. Here a chain of 400 links, under a limit
    that the dense estimate exceeds, is accepted."""
    from mechdsl.errors import MechError
    from mechdsl.memory import resident_bytes
    from mechdsl.solve.memory import plan
    from mechdsl.solve.dynamic import DynamicRun

    kernels = mechdsl.loads(dm.chain_text(400, t1=0.01)).compile()
    limit = resident_bytes() + 40 * 2**20
    with pytest.raises(MechError, match="needs about"):
        plan(kernels.system, limit, SolverOptions().max_batch_elements, sparse=False)
    DynamicRun(kernels, SolverOptions(max_memory=limit))  # accepted


def _spring_chain(n: int, k: float, t1: float) -> str:
    """n links of 1 m and 1 kg hinged end to end from the ground's origin, horizontal at
    rest, a rotary spring of stiffness k at every pin between two links; outputs the free
    end (tipx, tipy)."""
    return dm.chain_text(n, t1=t1, springs=k)


def _spring_chain_minimal(n: int, k: float, t1: float) -> np.ndarray:
    """The free end at t1 from Lagrange's equations in the links' angles phi:
    with a_ij = 1 for j < i, 1/2 for j = i (link i's centre moves by a_ij (-sin, cos)
    phi_j' of link j's), mu_jk = sum_i a_ij a_ik,

        sum_k mu_jk (cos(phi_j - phi_k) phi_k'' + sin(phi_j - phi_k) phi_k'^2)
            + phi_j'' / 12 = -g cos(phi_j) sum_i a_ij - dV/dphi_j,

    V = k/2 sum_j (phi_j - phi_(j-1))^2; by scipy's DOP853 at rtol 1e-10 (its Radau agrees to
    1e-13 m)."""
    from scipy.integrate import solve_ivp

    a = np.tril(np.ones((n, n)), -1) + 0.5 * np.eye(n)
    mu = a.T @ a
    weight = 9.81 * a.sum(axis=0)

    def rhs(t, y):
        phi, w = y[:n], y[n:]
        d = phi[:, None] - phi[None, :]
        mass = mu * np.cos(d) + np.eye(n) / 12
        twist = np.diff(phi)
        dv = np.zeros(n)
        dv[1:] += k * twist
        dv[:-1] -= k * twist
        force = -weight * np.cos(phi) - dv - (mu * np.sin(d)) @ (w * w)
        return np.concatenate((w, np.linalg.solve(mass, force)))

    sol = solve_ivp(rhs, (0.0, t1), np.zeros(2 * n), method="DOP853", rtol=1e-10,
                    atol=1e-12)
    assert sol.success
    phi = sol.y[:n, -1]
    return np.array([np.cos(phi).sum(), np.sin(phi).sum()])


def test_a_large_stiff_model_switches_where_implicit_steps_cost_less():
    """A chain of 20 links on rotary springs of 1e6 N m/rad, integrated on the augmented
    Lagrangian, whose every evaluation factorises: there a radau step costs less than a
    DOP853 step (0.7 against 1.5 ms), and radau's steps longer than DOP853's by
    TRIAL_RATIO_FACTORISED make the trial say yes (against TRIAL_RATIO, ten, the run kept
    DOP853 and took 5.7 times radau's time). The free end within 1e-5 m of the chain's own
    equations."""
    from mechdsl.solve.driver import TRIAL_RATIO, TRIAL_RATIO_FACTORISED

    n, k, t1 = 20, 1e6, 0.5
    res = mechdsl.loads(_spring_chain(n, k, t1)).simulate()
    assert res.ok, res.messages
    assert "radau from t = " in res.method and "over a trial of" in res.method, res.method
    ratio = float(res.method.split("radau's steps ")[1].split(" times")[0])
    assert TRIAL_RATIO_FACTORISED <= ratio < TRIAL_RATIO
    ref = _spring_chain_minimal(n, k, t1)
    assert abs(res["tipx"][-1] - ref[0]) < 1e-5
    assert abs(res["tipy"][-1] - ref[1]) < 1e-5


def test_a_pair_counts_stiff_steps_afresh_once_its_detection_is_on_again():
    """After a trial that said no the driver turns the detection off for a while; turned
    on again, STIFF needs STIFF_STEPS steps in a row at the boundary anew, not the next one
    (the count kept from before the pause made every step after it a new trial). On the
    stiff pendulum h rho stays at the boundary for a few steps after the first report."""
    from mechdsl.solve.explicit import STIFF_STEPS, Vern9
    from mechdsl.solve.stepper import STIFF

    motion = Motion(mechdsl.loads(dm.stiff_pendulum_text(1e8)).compile())
    y0 = np.concatenate((motion.system.guess.reshape(-1)[:motion.n], np.zeros(motion.n)))
    y0 = motion.project(0.0, y0)
    s = Vern9(motion, 0.0, y0, 2.0, rtol=1e-6, atol=1e-8, scale=np.ones(2 * motion.n))
    s.detect_stiffness = True
    steps = 0
    while s.step() != STIFF:
        steps += 1
        assert steps < 10 * STIFF_STEPS
    # (at k = 1e8 the first step's h rho is far past the boundary: reported at once)
    assert s.stiff_steps >= STIFF_STEPS or (s.naccepted == 1 and s.stiff_steps == 1)
    s.detect_stiffness = False
    assert s.step() is None
    s.detect_stiffness = True
    reports = [s.step() for _ in range(STIFF_STEPS - 1)]
    assert reports == [None] * (STIFF_STEPS - 1)  # (before: STIFF at the first)


def test_a_chain_stiff_enough_to_be_rigid_falls_as_one_bar():
    """Five links on rotary springs of 1e10 N m/rad: the first explicit steps are far too
    long for the springs, and their stages' accelerations overflow. Such a stage is a
    rejected step, not a singular model (the run stopped at t0 with "the equations of
    motion are singular", numpy's overflow warnings printed); the pair shortens its steps,
    the trial hands the run to radau, and the chain falls as the rigid bar it nearly is:
    phi'' = -(3 g / (2 n)) cos(phi) (I = n^3 / 3 about the pivot, its weight n at n / 2),
    the free end at n (cos phi, sin phi), within 1e-6 m (the springs bend it by about
    g n^2 / k, 2.5e-8 rad)."""
    import warnings

    from scipy.integrate import solve_ivp

    n, k, t1 = 5, 1e10, 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warning reaches the user
        res = mechdsl.loads(_spring_chain(n, k, t1)).simulate()
    assert res.ok, res.messages
    assert "radau from t = " in res.method, res.method
    bar = solve_ivp(lambda t, y: [y[1], -1.5 * 9.81 / n * np.cos(y[0])], (0.0, t1),
                    [0.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-14)
    phi = bar.y[0, -1]
    assert abs(res["tipx"][-1] - n * np.cos(phi)) < 1e-6
    assert abs(res["tipy"][-1] - n * np.sin(phi)) < 1e-6


@pytest.mark.parametrize("k, early", [(1e7, True), (1e8, True), (1e10, True), (1e4, False)])
def test_a_first_step_far_past_the_boundary_reports_stiffness_at_once(k, early):
    """Hairer's first step is chosen for accuracy; where stability allows far less (h rho
    above EARLY_STIFF times the boundary: the stiff pendulum at k = 1e8, h rho about 22
    against vern9's 2.64; at 1e10 about 17, for the step first tried, though rejections cut
    it to the boundary; at 1e7 4.3) the pair reports STIFF after that step, not after STIFF_STEPS
    more; at k = 1e4 (h rho 5e-4 at the first step) it does not. The run then goes on
    with radau, its summary saying so, within 1e-7 rad of the minimal ODE."""
    from mechdsl.solve.explicit import EARLY_STIFF, Vern9, stiffness_probe
    from mechdsl.solve.stepper import STIFF

    motion = Motion(mechdsl.loads(dm.stiff_pendulum_text(k)).compile())
    y0 = np.concatenate((motion.system.guess.reshape(-1)[:motion.n], np.zeros(motion.n)))
    y0 = motion.project(0.0, y0)
    s = Vern9(motion, 0.0, y0, 2.0, rtol=1e-6, atol=1e-8, scale=np.ones(2 * motion.n))
    s.detect_stiffness = True
    report = s.step()
    bound = stiffness_probe("vern9")[1]
    assert (report == STIFF) == early
    assert (s.h_rho > EARLY_STIFF * bound) == early  # (h rho of the step first tried)
    if early:
        res = mechdsl.loads(dm.stiff_pendulum_text(k)).simulate()
        assert "h rho = " in res.method and "for the first step it tried" in res.method, \
            res.method
        assert abs(res["theta"][-1] - dm.stiff_pendulum_oracle(k)[0]) < 1e-7
