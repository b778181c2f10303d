"""The compiled backend (numba, the ``fast`` extra): the same answers as the numpy path, by
closed form; its stops handed to the numpy march, which reports them as it always does;
never imported for a small run; compiled once per model, cached on disk as data checked
byte for byte."""

import os
import subprocess
import sys

import numpy as np
import pytest

import mechdsl
from closed_forms import slider_crank
from conftest import EXAMPLES, ROOT
from mechdsl.compiled import native
from mechdsl.solve import SolverOptions
from mechdsl.solve import simulate

COMPILED = SolverOptions(backend="compiled")
NUMPY = SolverOptions(backend="numpy")
OMEGA = 4 * np.pi


@pytest.mark.parametrize("settled", [0.0, 1e-15, 1e-13])
def test_the_compiled_march_is_exact_on_the_seed(settled):
    # settled_step 0: the Jacobian is always factorised once more at the converged position;
    # otherwise a round-off step keeps the factorisation it was computed with
    kernels = mechdsl.load(EXAMPLES / "slider_crank.mech").compile()
    assert native.load(kernels) is not None
    res = simulate(kernels, SolverOptions(backend="compiled", settled_step=settled))
    assert res.ok
    x, v, a = slider_crank(2.0, 3.5, np.pi / 4 + OMEGA * res["t"], OMEGA, 0.0)
    np.testing.assert_allclose(res["slider.x"], x, rtol=0, atol=1e-12 * np.abs(x).max())
    np.testing.assert_allclose(res["slider.vx"], v, rtol=0, atol=1e-12 * np.abs(v).max())
    np.testing.assert_allclose(res["slider.ax"], a, rtol=0, atol=1e-12 * np.abs(a).max())
    assert res.residual < 1e-12


def test_a_sweep_with_a_locking_variant_ends_as_on_the_numpy_path():
    # l = 1.6: the rod is too short to follow the crank past 53 degrees: a lock-up midway,
    # found by the compiled march, reported by the numpy one from there
    mech = mechdsl.load(EXAMPLES / "slider_crank.mech")
    kernels = mech.compile(mechdsl.api.Overrides(sweeps={"l": [3.5, 1.6, 3.0]}))
    fast, slow = simulate(kernels, COMPILED), simulate(kernels, NUMPY)
    assert fast.status == slow.status == "failed"
    assert list(fast.n_solved) == list(slow.n_solved) and fast.n_solved[1] < 1001
    assert fast.messages == slow.messages
    for v, length in ((0, 3.5), (2, 3.0)):
        x, vx, ax = slider_crank(2.0, length, np.pi / 4 + OMEGA * fast["t"], OMEGA, 0.0)
        np.testing.assert_allclose(fast["slider.x"][v], x, atol=1e-12 * np.abs(x).max())
        np.testing.assert_allclose(fast["slider.ax"][v], ax, atol=1e-11 * np.abs(ax).max())
    k = fast.n_solved[1]
    np.testing.assert_allclose(fast["slider.x"][1, :k], slow["slider.x"][1, :k], atol=1e-12)


def test_a_model_the_backend_cannot_compile_runs_on_numpy():
    # a cam's profile is a function argument: evaluated by numpy, not compiled
    kernels = mechdsl.load(EXAMPLES / "cam_flat.mech").compile()
    assert native.source(kernels) is None
    fast, slow = simulate(kernels, COMPILED), simulate(kernels, NUMPY)
    assert fast.ok and slow.ok
    for label in fast.data:
        np.testing.assert_array_equal(fast[label], slow[label])


def run(*args, env=None):
    return subprocess.run([sys.executable, "-c", *args], capture_output=True, text=True,
                          cwd=ROOT, env={**os.environ, **(env or {})}, timeout=300)


SMALL_RUN = """
import sys, mechdsl
res = mechdsl.load("examples/slider_crank.mech").simulate()
assert res.ok
print("numba" in sys.modules)
"""


def test_a_small_run_never_imports_numba():
    r = run(SMALL_RUN)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"


CACHED_RUN = """
import mechdsl
from mechdsl.solve import SolverOptions
res = mechdsl.load("examples/slider_crank.mech").simulate(
    options=SolverOptions(backend="compiled"))
print(res.status, float(res["slider.x"][-1]))
"""


def test_the_compiled_model_is_cached_on_disk_and_checked_before_use(tmp_path):
    env = {"XDG_CACHE_HOME": str(tmp_path)}
    first = run(CACHED_RUN, env=env)
    assert first.returncode == 0, first.stderr
    folder = tmp_path / "mechdsl" / "native"
    (module,) = folder.glob("mechdsl_native_*.py")
    assert oct(folder.stat().st_mode & 0o777) == "0o700"
    text = module.read_text()
    # a file changed behind mechdsl's back is not run: it is written again
    module.write_text("raise SystemExit('tampered')\n")
    second = run(CACHED_RUN, env=env)
    assert second.returncode == 0, second.stderr
    assert second.stdout == first.stdout
    assert module.read_text() == text


def test_the_settled_step_is_checked():
    for bad in (-1e-16, 1e-12, float("nan")):
        with pytest.raises(ValueError, match="settled_step"):
            SolverOptions(settled_step=bad)


@pytest.mark.parametrize("value", ["gpu", ""])
def test_the_backend_option_is_checked(value):
    with pytest.raises(ValueError, match="backend must be 'auto', 'numpy' or 'compiled'"):
        SolverOptions(backend=value)


def test_the_command_line_takes_the_backend_as_the_api_does(tmp_path):
    from mechdsl.cli import main

    out = tmp_path / "out.csv"
    assert main(["run", str(EXAMPLES / "slider_crank.mech"), "-q", "-o", str(out),
                 "--backend", "compiled"]) == 0
    data = np.loadtxt(out.read_text().splitlines()[2:], delimiter=",")
    x, v, a = slider_crank(2.0, 3.5, np.pi / 4 + OMEGA * data[:, 0], OMEGA, 0.0)
    np.testing.assert_allclose(data[:, 1], x, atol=1e-12 * np.abs(x).max())
    np.testing.assert_allclose(data[:, 3], a, atol=1e-12 * np.abs(a).max())
    r = subprocess.run([sys.executable, "-m", "mechdsl", "run", str(EXAMPLES / "slider_crank.mech"),
                        "-o", str(out), "--backend", "gpu"], capture_output=True, text=True,
                       cwd=tmp_path, timeout=120)
    assert r.returncode == 1
    assert "--backend: backend must be 'auto', 'numpy' or 'compiled', not 'gpu'" in r.stderr


def test_asking_for_the_compiled_backend_where_it_does_not_apply_says_so():
    res = mechdsl.load(EXAMPLES / "cam_flat.mech").simulate(options=COMPILED)
    assert res.ok
    assert any("backend 'compiled' asked for" in w and "solved on numpy" in w
               for w in res.warnings)


@pytest.mark.parametrize("drive", ["pi/4 + 1e-3*sqrt(t)", "pi/4 + omega*t + 1e-3*t*sqrt(t)"])
def test_a_failure_at_instant_0_is_reported_as_on_the_numpy_path(drive):
    # f' (first) or f'' (second) infinite at t = 0: the compiled march, which would solve
    # instant 0 too, hands it to the numpy solver, which reports it
    text = (EXAMPLES / "slider_crank.mech").read_text().replace("pi/4 + omega*t", drive)
    kernels = mechdsl.loads(text, "s.mech").compile()
    fast, slow = simulate(kernels, COMPILED), simulate(kernels, NUMPY)
    assert fast.status == slow.status == "failed"
    assert list(fast.n_solved) == list(slow.n_solved) == [0]
    assert fast.messages == slow.messages
    assert "at t = 0 (instant 1 of 1001)" in fast.messages[0]


def test_the_angles_cosines_are_carried_across_a_step_to_round_off():
    # trig_step: cos and sin at q from their values at qo by the angle-addition formulas,
    # against numpy's cos and sin at q, for steps from round-off to beyond the series' range
    kernels = mechdsl.load(EXAMPLES / "slider_crank.mech").compile()
    module = native._module(native.source(kernels))
    rng = np.random.default_rng(7)
    angles = [2, 5]  # the crank's and the rod's phi (the slider's enters no cosine)
    worst = 0.0
    for h in (1e-16, 1e-12, 1e-8, 1e-5, 9e-4, 1.1e-3, 0.3):
        qo = rng.uniform(-10, 10, kernels.system.n)
        q = qo + h * rng.choice([-1.0, 1.0], kernels.system.n)
        cs = np.empty(2 * len(angles))
        module.trig(qo, cs)
        module.trig_step(q, qo, cs)
        exact = np.ravel([(np.cos(q[k]), np.sin(q[k])) for k in angles])
        worst = max(worst, float(np.abs(cs - exact).max()))
    assert worst <= 4e-16


def _carried(kernels, options):
    from mechdsl.solve import assembly
    from mechdsl.solve.diagnose import col_scale
    from mechdsl.solve.single import OneState

    D, t0 = col_scale(kernels.system), float(kernels.system.times[0])
    q1, ok, _ = assembly.gauss_newton(kernels, kernels.system.guess.reshape(1, 1, kernels.system.n),
                                      np.full((1, 1), t0), D, kernels.system.joint_rows, options)
    assert ok.all()
    fast = assembly._continue_compiled(kernels, q1[0, 0], t0, D[0, 0], options)
    slow = assembly._continue_one(OneState(kernels, kernels.one_state, D[0, 0], options),
                                  q1[0, 0], t0, options)
    return fast, slow


@pytest.mark.parametrize("name", ["slider_crank", "fourbar", "fourbar_coupler", "planetary",
                                  "rack_pinion", "scotch_yoke", "start_from_rest"])
def test_the_compiled_assembly_carries_the_drives_as_the_float_code(name):
    # the same Newton steps, bisections and checks: the same configuration, to round-off
    fast, slow = _carried(mechdsl.load(EXAMPLES / f"{name}.mech").compile(), COMPILED)
    assert fast[1:3] == slow[1:3] and fast[1]
    np.testing.assert_allclose(fast[0], slow[0], rtol=0, atol=1e-13)


def test_the_compiled_assembly_refuses_a_dead_point_as_the_float_code():
    # a rod of 1.6 locks the crank at 53 degrees: the drive cannot be carried to 90
    text = (EXAMPLES / "slider_crank.mech").read_text().replace(
        "param l = 3.5", "param l = 1.6").replace("pi/4 + omega*t", "pi/2 + omega*t")
    kernels = mechdsl.loads(text, "s.mech").compile()
    fast, slow = _carried(kernels, COMPILED)
    assert fast[1] is slow[1] is False and fast[2] == slow[2]
    np.testing.assert_allclose(fast[0], slow[0], rtol=0, atol=1e-13)
    for options in (COMPILED, NUMPY):
        res = simulate(kernels, options)
        assert res.status == "failed" and res.n_solved[0] == 0
        assert "the drives cannot reach their values at t0" in res.messages[0]


@pytest.mark.parametrize("m", [1, 2, 5, 8, 10])
def test_the_predictors_weights_integrate_polynomials_exactly(m):
    # q(t + tau) = q + tau qd + tau^2 sum_j beta_j qdd(t - j tau) holds exactly for every
    # polynomial q of degree up to m + 1 (its acceleration of degree m - 1 is extrapolated
    # exactly): checked in rational arithmetic on q = s^p, tau = 1, t = 0
    from fractions import Fraction

    beta = native.stormer(m)
    for p in range(m + 2):
        q1 = Fraction(1) ** p  # q(1)
        q0 = Fraction(1 if p == 0 else 0)
        qd0 = Fraction(1 if p == 1 else 0)
        acc = [Fraction(p * (p - 1)) * Fraction(-j) ** (p - 2) if p >= 2 else Fraction(0)
               for j in range(m)]
        assert q0 + qd0 + sum(b * a for b, a in zip(beta, acc)) == q1
    # and not for degree m + 2: the formula is of order m + 1, no more
    p = m + 2
    acc = [Fraction(p * (p - 1)) * Fraction(-j) ** (p - 2) for j in range(m)]
    assert sum(b * a for b, a in zip(beta, acc)) != 1


@pytest.mark.parametrize("t1", [0.5, 1.0])
def test_a_drive_with_a_kink_is_exact_on_the_compiled_march(t1):
    # the crank's acceleration jumps at t1: the predictor's history spans the kink there,
    # and the march must still land on the closed form at every instant
    from closed_forms import start_from_rest

    kernels = mechdsl.load(EXAMPLES / "start_from_rest.mech").compile(
        mechdsl.api.Overrides(params={"t1": t1}))
    res = simulate(kernels, COMPILED)
    assert res.ok and not res.warnings
    th, w, al = start_from_rest(res["t"], t1, 4 * np.pi / t1)
    x, v, a = slider_crank(2.0, 3.5, th, w, al)
    np.testing.assert_allclose(res["slider.x"], x, rtol=0, atol=1e-13 * np.abs(x).max())
    np.testing.assert_allclose(res["slider.vx"], v, rtol=0, atol=1e-13 * np.abs(v).max())
    np.testing.assert_allclose(res["slider.ax"], a, rtol=0, atol=1e-12 * np.abs(a).max())


def test_the_compiled_march_evaluates_most_instants_once():
    # the predictor lands within settled_step of the solution: one evaluation of Phi and
    # Phi_q for most instants, counted by an instrumented copy of the generated march (each
    # evaluation adds 1 to the residual it keeps, whose own value is below 1e-14)
    from mechdsl.solve.assembly import assemble
    from mechdsl.solve.diagnose import col_scale
    from mechdsl.solve.run import _drive_values

    kernels = mechdsl.load(EXAMPLES / "slider_crank.mech").compile()
    counted = native.source(kernels).replace("norm_a = evaluate(x, cs",
                                            "RES[v] += 1.0; norm_a = evaluate(x, cs")
    assert counted.count("RES[v] += 1.0") == 4  # (march and march_one)
    module = native._module(counted)
    K, n, opts = len(kernels.system.times), kernels.system.n, COMPILED
    fd = np.stack(_drive_values(kernels, kernels.system.times[None, :]), axis=2)
    asm = assemble(kernels, float(kernels.system.times[0]), opts)
    Q, QD, QDD = (np.empty((1, K, n)) for _ in range(3))
    RC, SG = np.empty((1, K)), np.empty((1, K))
    status, counter = np.zeros(1, np.int64), np.zeros(1)
    module.march(asm.q, np.zeros((1, n)), np.zeros((1, n)), np.ones(1), kernels.system.times.copy(),
                 fd, np.zeros((0, 1)), np.ascontiguousarray(col_scale(kernels.system)[:, 0]),
                 opts.newton_tol, opts.newton_error, opts.settled_step, opts.max_iterations,
                 0.1, opts.branch_ratio, opts.singular_rcond, 1, Q, QD, QDD, RC, SG, status,
                 counter)
    assert status[0] == K
    assert K <= int(counter[0]) <= 1.35 * K
    x, v, a = slider_crank(2.0, 3.5, np.pi / 4 + OMEGA * kernels.system.times, OMEGA, 0.0)
    np.testing.assert_allclose(Q[0, :, 6], x, rtol=0, atol=1e-15 * np.abs(x).max())
    np.testing.assert_allclose(QD[0, :, 6], v, rtol=0, atol=1e-15 * np.abs(v).max())
    np.testing.assert_allclose(QDD[0, :, 6], a, rtol=0, atol=1e-15 * np.abs(a).max())
