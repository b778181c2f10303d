"""Forward dynamics against published references and closed forms: Andrews' squeezing
mechanism (the Test Set for IVP Solvers), a pendulum released from the horizontal (its
period by the complete elliptic integral, its energy), the constraints held at every output
instant, the initial velocity projected with a warning, a singular mass matrix located."""

import numpy as np
import pytest
from scipy.special import ellipk

import mechdsl
from conftest import EXAMPLES
from mechdsl.solve import SolverOptions

#: Andrews at t = 0.03: the Test Set's reference (PSIDE at 1e-14 on a Cray C90; andsoln in
#: Ex_andrews.f), the seven angles beta, Theta, gamma, Phi, delta, Omega, epsilon
ANDREWS_Q = np.array([0.1581077119629904e+2, -0.1575637105984298e+2, 0.4082224013073101e-1,
                      -0.5347301163226948e+0, 0.5244099658805304e+0, 0.5347301163226948e+0,
                      0.1048080741042263e+1])
ANDREWS_NAMES = ("beta", "Theta", "gamma", "Phi", "delta", "Omega", "epsilon")
#: its energy balance 1/2 qd^T M qd + 1/2 c0 (L - l0)^2 - mom (beta - beta0) at t = 0 (J)
ANDREWS_ENERGY = 1.4357963991616702

G = 9.81


def pendulum(length: float, g: float = G, periods: float = 1.0, per_period: int = 40,
             extra: str = "") -> str:
    """A point mass at the end of a massless rod (a body with its frame at the pivot and all
    its mass at the tip), released at rest from the horizontal."""
    T = float(4 * np.sqrt(length / g) * ellipk(0.5))
    return f"""
param L = {length!r}
body rod {{
    guess = (0, 0, 0)
    point tip = (L, 0)
    mass = 2  inertia = 0  centroid = (L, 0)
    {extra}
}}
joint pivot: revolute(ground.origin, rod.origin)
gravity = (0, -{g!r})
simulate t = 0 .. {periods * T!r} step {T / per_period!r}, rtol = 1e-12, atol = 1e-14
output rod.phi, rod.omega, rod.tip.x, rod.tip.y, rod.tip.vx, rod.tip.vy
"""


def test_andrews_reproduces_the_reference_angles():
    res = mechdsl.load(EXAMPLES / "andrews.mech").simulate()
    assert res.status == "ok", res.messages
    got = np.array([res[name][-1] for name in ANDREWS_NAMES])
    rel = np.abs(got - ANDREWS_Q) / np.abs(ANDREWS_Q)
    assert rel.max() <= 1e-7, dict(zip(ANDREWS_NAMES, rel))
    # every output instant on the constraints
    assert res.residual <= 1e-10


def test_the_pendulum_period_is_the_elliptic_integral():
    length = 1.5
    T = 4 * np.sqrt(length / G) * ellipk(0.5)
    res = mechdsl.loads(pendulum(length, per_period=40), "pendulum.mech").simulate()
    assert res.status == "ok", res.messages
    t, phi, w = res["t"], res["rod.phi"], res["rod.omega"]
    # the bottom (phi = -pi/2) is passed at T/4 and 3T/4: the instants of the grid there,
    # corrected by one Newton step in time, give the crossing times
    for k, when in ((10, T / 4), (30, 3 * T / 4)):
        crossing = t[k] - (phi[k] + np.pi / 2) / w[k]
        assert abs(crossing - when) <= 1e-9 * T
    assert abs(phi[-1]) <= 1e-8  # back at the horizontal after one period


def test_the_pendulum_keeps_its_energy_and_its_length():
    length = 0.8
    res = mechdsl.loads(pendulum(length, periods=100, per_period=4), "p.mech").simulate()
    assert res.status == "ok", res.messages
    x, y, vx, vy = (res[k] for k in ("rod.tip.x", "rod.tip.y", "rod.tip.vx", "rod.tip.vy"))
    energy = 0.5 * (vx**2 + vy**2) + G * y  # per unit mass; 0 at the start
    assert np.abs(energy).max() <= 1e-9 * G * length
    assert np.abs(np.hypot(x, y) - length).max() <= 1e-12 * length


def test_an_inconsistent_initial_velocity_is_projected_with_a_warning():
    text = pendulum(1.0, extra="v0 = (0.5, 0, 2)")  # vx = 0.5 would stretch the rod
    res = mechdsl.loads(text, "p.mech").simulate()
    assert res.status == "ok"
    assert any("projected" in w and "rod.vx" in w and "0.5" in w for w in res.warnings)
    # omega = 2 is kept: the tip starts at (L, 0) moving up at 2 m/s
    assert res["rod.omega"][0] == pytest.approx(2.0, abs=1e-12)
    assert res["rod.tip.vy"][0] == pytest.approx(2.0, abs=1e-12)


def test_a_free_body_without_mass_is_a_located_failure():
    text = pendulum(1.0).replace("mass = 2  inertia = 0  centroid = (L, 0)", "")
    text = text.replace("gravity", "body other { mass = 1 }\ngravity")
    res = mechdsl.loads(text, "p.mech").simulate()
    assert res.status == "failed"
    assert "singular" in res.messages[0] and "rod" in res.messages[0]


def test_the_compiled_backend_integrates_the_same_motion():
    from mechdsl.compiled import native
    from mechdsl.solve import SolverOptions

    mech = mechdsl.load(EXAMPLES / "andrews.mech")
    kernels = mech.compile()
    assert native.load_dynamics(kernels) is not None
    fast = mech.simulate(options=SolverOptions(backend="compiled"))
    slow = mech.simulate(options=SolverOptions(backend="numpy"))
    assert fast.status == slow.status == "ok" and not fast.warnings
    got = np.array([fast[name][-1] for name in ANDREWS_NAMES])
    assert (np.abs(got - ANDREWS_Q) / np.abs(ANDREWS_Q)).max() <= 1e-7
    # the same method, the same tolerance: the same motion at every output instant, to the
    # accuracy asked for (the evaluations differ by round-off, which moves the steps a little)
    for name in ANDREWS_NAMES:
        np.testing.assert_allclose(fast[name], slow[name], rtol=1e-6,
                                   atol=1e-6 * np.abs(slow[name]).max())
    assert fast.residual <= 1e-10


def test_a_pendulum_on_a_cart_driven_at_constant_speed_swings_as_on_a_fixed_pivot():
    # a mixed case: the cart's x is driven (x = v t), the pendulum is free; in the cart's
    # frame, moving uniformly, it swings exactly as the fixed pendulum (Galilean invariance)
    length = 1.2
    T = float(4 * np.sqrt(length / G) * ellipk(0.5))
    text = f"""
    body cart {{ mass = 3  inertia = 0.1 }}
    body rod {{ guess = (0, 0, 0)  point tip = ({length}, 0)
               mass = 2  inertia = 0  centroid = ({length}, 0) }}
    joint slide: prismatic(ground.origin, cart.origin, axis = (1, 0))
    joint pivot: revolute(cart.origin, rod.origin)
    drive move: x(cart.origin) = 0.7*t
    gravity = (0, -{G})
    simulate t = 0 .. {T} step {T / 40}, rtol = 1e-12, atol = 1e-14
    output rod.phi, rod.omega, rod.alpha, move.force, cart.vx
    """
    res = mechdsl.loads(text, "cart.mech").simulate()
    assert res.status == "ok", res.messages
    t, phi, w = res["t"], res["rod.phi"], res["rod.omega"]
    for k, when in ((10, T / 4), (30, 3 * T / 4)):
        assert abs(t[k] - (phi[k] + np.pi / 2) / w[k] - when) <= 1e-9 * T
    np.testing.assert_allclose(res["cart.vx"], 0.7, rtol=0, atol=1e-12)
    # the cart does not accelerate: the drive's force balances the pendulum's pull on it,
    # which is the rod's mass times its centre's horizontal acceleration (its weight is
    # vertical), -L (sin(phi) alpha + cos(phi) omega^2)
    ax = -length * (np.sin(phi) * res["rod.alpha"] + np.cos(phi) * w**2)
    np.testing.assert_allclose(res["move.force"], 2 * ax, rtol=0,
                               atol=1e-9 * np.abs(2 * ax).max())


def test_an_interrupt_keeps_the_instants_integrated_before_it():
    kernels = mechdsl.loads(pendulum(1.0), "p.mech").compile()
    from mechdsl.solve import simulate

    def progress(done, total):
        if done == 12:
            raise KeyboardInterrupt

    res = simulate(kernels, progress=progress)
    assert res.status == "interrupted"
    k = int(res.n_solved[0])
    assert k == 12
    phi = res["rod.phi"]
    assert np.isfinite(phi[:k]).all() and np.isnan(phi[k:]).all()
    # what was kept is the motion: the pendulum's energy per unit mass is still zero
    vx, vy, y = res["rod.tip.vx"][:k], res["rod.tip.vy"][:k], res["rod.tip.y"][:k]
    assert np.abs(0.5 * (vx**2 + vy**2) + G * y).max() <= 1e-9 * G


def test_check_reports_the_freedom_left_to_the_dynamics_and_a_singular_start():
    report = mechdsl.load(EXAMPLES / "andrews.mech").check()
    assert report.error is None and report.mobility == 1
    assert any("1 degree of freedom left to the forward dynamics" in ln for ln in report.lines)
    assert any(ln.strip().startswith("force spring") for ln in report.lines)
    text = pendulum(1.0).replace("mass = 2  inertia = 0  centroid = (L, 0)", "")
    text = text.replace("gravity", "body other { mass = 1 }\ngravity")
    bad = mechdsl.loads(text, "p.mech").check()
    assert bad.error is not None and "singular" in str(bad.error)


def test_the_command_line_tolerance_overrides_the_file(tmp_path):
    import subprocess
    import sys

    errors = {}
    for extra in ([], ["--rtol", "1e-4", "--atol", "1e-6"]):
        out = tmp_path / f"a{len(extra)}.csv"
        subprocess.run([sys.executable, "-m", "mechdsl", "run", str(EXAMPLES / "andrews.mech"),
                        "-o", str(out), "-q", *extra], check=True)
        header = out.read_text().splitlines()[0].split(",")
        last = np.loadtxt(out, delimiter=",", comments="#", skiprows=1)[-1]
        got = np.array([last[header.index(name)] for name in ANDREWS_NAMES])
        errors[len(extra)] = (np.abs(got - ANDREWS_Q) / np.abs(ANDREWS_Q)).max()
    assert errors[0] <= 1e-7 < 1e-5 < errors[4]


def test_andrews_keeps_its_energy_balance():
    # E = T + V_spring - mom (beta - beta0) is constant (the torque's work leaves through
    # the last term); its published value at t = 0, and within 1e-8 at rtol = 1e-8
    from mechdsl.solve import SolverOptions

    text = (EXAMPLES / "andrews.mech").read_text().replace(
        "output beta", "output kinetic_energy, potential_energy, beta")
    res = mechdsl.loads(text, "andrews.mech").simulate(
        options=SolverOptions(rtol=1e-8, atol=1e-10))
    assert res.status == "ok"
    energy = res["kinetic_energy"] + res["potential_energy"] - 0.033 * (res["beta"]
                                                                        - res["beta"][0])
    assert energy[0] == pytest.approx(ANDREWS_ENERGY, rel=1e-14)
    assert np.abs(energy / ANDREWS_ENERGY - 1).max() <= 1e-8
    assert np.ptp(res["kinetic_energy"]) > 1.0  # the energy does change form


def test_a_spring_is_drawn_between_its_points():
    from mechdsl.outputs.draw import zigzag

    kernels = mechdsl.load(EXAMPLES / "andrews.mech").compile()
    ((b1, xy1, b2, xy2),) = kernels.system.sketch.links
    assert kernels.system.body_names[b1] == "triangle"
    assert b2 == kernels.system.n_bodies  # to the ground
    np.testing.assert_allclose(xy1[0], [0.02, -0.018])
    np.testing.assert_allclose(xy2[0], [0.014, 0.072])
    p, q = np.array([1.0, 2.0]), np.array([4.0, 6.0])
    z = zigzag(p, q)
    np.testing.assert_allclose(z[[0, -1]], [p, q])
    # every vertex lies within a twentieth of the length from the line p-q
    u = (q - p) / 5.0
    offsets = (z - p) @ np.array([-u[1], u[0]])
    assert np.abs(offsets).max() == pytest.approx(0.05 * 5.0)


def test_a_sweep_integrates_every_variant_with_its_own_values():
    lengths = [0.5, 1.0, 2.0]
    text = pendulum(1.0).replace("param L = 1.0", "param L = 1.0\nsweep L = [0.5, 1.0, 2.0]")
    res = mechdsl.loads(text, "p.mech").simulate()
    assert res.status == "ok"
    for v, length in enumerate(lengths):
        x, y, vx, vy = (res[k][v] for k in ("rod.tip.x", "rod.tip.y", "rod.tip.vx",
                                             "rod.tip.vy"))
        assert np.abs(np.hypot(x, y) - length).max() <= 1e-12 * length
        assert np.abs(0.5 * (vx**2 + vy**2) + G * y).max() <= 1e-9 * G * length
    # a longer pendulum swings slower: at the same instant it has fallen less far
    k = len(res["t"]) // 8
    assert res["rod.phi"][0, k] < res["rod.phi"][1, k] < res["rod.phi"][2, k] < 0


def _andrews_run(rtol: float = 1e-8):
    from mechdsl.solve.dynamic import DynamicRun, _Evaluator
    from mechdsl.solve.options import SolverOptions

    kernels = mechdsl.load(EXAMPLES / "andrews.mech").compile()
    run = DynamicRun(kernels, SolverOptions(rtol=rtol, atol=rtol * 1e-2))
    q0 = run._initial_positions()[0]
    run.ev = _Evaluator(kernels, run.D[0, 0])
    return run, q0


def test_the_step_correction_agrees_with_the_full_projection_to_its_square():
    # a state moved off both manifolds by the drift of a step (1e-9 and 1e-7 of the
    # coordinates' scales): one Gauss-Newton correction each for q and qd lands where the
    # projection iterated to newton_tol does, to the square of the drift
    run, q0 = _andrews_run()
    n = run.ev.n
    rng = np.random.default_rng(7)
    qd = rng.normal(size=n)
    y = np.concatenate((q0, qd))
    exact = run._project(0.0, y)
    for drift in (1e-9, 1e-7):
        moved = exact + drift * rng.normal(size=2 * n) * np.concatenate((run.ev.D, run.ev.D))
        settled, projected = run._settle(0.0, moved), run._project(0.0, moved)
        phi, jac = run.ev.phi_jac(0.0, settled[:n])
        assert np.abs(phi).max() <= 1e-6 * drift  # on the position manifold, to its square
        assert np.abs(jac @ settled[n:]).max() <= 1e-5 * drift * np.abs(qd).max()
        assert np.abs(settled - projected).max() <= 1e-5 * drift * np.abs(y).max()
        assert np.abs(settled - moved).max() >= 0.1 * drift * np.abs(run.ev.D).min()
        assert not np.array_equal(settled, projected)  # one correction, not the iteration


def test_a_drift_beyond_the_tolerance_gets_the_full_projection():
    # |dz|^2 above atol / 1000: one correction would not do, the iteration runs as at an
    # output instant (the same state, to the last bit)
    run, q0 = _andrews_run()
    n = run.ev.n
    y = np.concatenate((q0 + 1e-4 * run.ev.D, np.zeros(n)))
    assert np.array_equal(run._settle(0.0, y), run._project(0.0, y))
    phi, _ = run.ev.phi_jac(0.0, run._settle(0.0, y)[:n])
    assert np.abs(phi).max() <= 1e-12


def test_the_integrator_is_chosen_by_the_tolerance_unless_named():
    from mechdsl.solve.dynamic import DynamicRun

    kernels = mechdsl.loads(pendulum(1.0), "p.mech").compile()
    assert DynamicRun(kernels).method == "vern9"  # the file's rtol, 1e-12
    for rtol, method, chosen in ((1e-3, "auto", "dopri5"), (1e-4, "auto", "dopri5"),
                                 (9e-5, "auto", "vern9"), (1e-3, "dop853", "dop853"),
                                 (1e-9, "dopri5", "dopri5"), (1e-2, "vern9", "vern9")):
        run = DynamicRun(kernels, SolverOptions(rtol=rtol, method=method))
        assert run.method == chosen, (rtol, method)
        # the reason, for the run's summary: the tolerance against the threshold, or named
        assert (f"rtol {rtol:g}" if method == "auto" else "as the options name it") \
            in run.method_reason
    with pytest.raises(ValueError, match="method must be"):
        SolverOptions(method="rk4")


@pytest.mark.parametrize("method", ["dopri5", "dop853"])
def test_the_pendulum_period_by_the_other_pairs(method):
    """The pairs that are not the default at this tolerance reach the elliptic integral's
    period too, at their own cost."""
    length = 1.5
    T = 4 * np.sqrt(length / G) * ellipk(0.5)
    res = mechdsl.loads(pendulum(length, per_period=40), "pendulum.mech").simulate(
        options=SolverOptions(method=method, rtol=1e-11, atol=1e-13))
    assert res.status == "ok", res.messages
    t, phi, w = res["t"], res["rod.phi"], res["rod.omega"]
    for k, when in ((10, T / 4), (30, 3 * T / 4)):
        crossing = t[k] - (phi[k] + np.pi / 2) / w[k]
        assert abs(crossing - when) <= 1e-9 * T
    assert res.residual <= 1e-12 * length


def test_the_command_line_names_the_integrator(tmp_path):
    import subprocess
    import sys

    runs = {}
    for method in ("dop853", "dopri5", "vern9"):
        out = tmp_path / f"{method}.csv"
        subprocess.run([sys.executable, "-m", "mechdsl", "run", str(EXAMPLES / "andrews.mech"),
                        "-o", str(out), "-q", "--rtol", "1e-4", "--atol", "1e-6", "--method",
                        method], check=True)
        runs[method] = np.loadtxt(out, delimiter=",", comments="#", skiprows=1)[-1]
    # the same tolerance, two methods: two different approximations, each near the reference
    assert np.abs(runs["dop853"] - runs["dopri5"]).max() > 1e-9
    assert np.abs(runs["vern9"] - runs["dop853"]).max() > 1e-9
    bad = subprocess.run([sys.executable, "-m", "mechdsl", "run", str(EXAMPLES / "andrews.mech"),
                          "-o", "-", "-q", "--method", "rk4"], capture_output=True, text=True)
    assert bad.returncode == 1 and "--method: method must be" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_accelerations_are_solved_where_an_output_or_the_rates_need_them():
    """The point-mass pendulum's angular acceleration is -g cos(phi) / L (phi from the
    horizontal): an output of order 2 (rod.alpha) gets it at every output instant, and so do
    the kept rates of a run whose outputs need none (simulate(rates=True)); a run that needs
    neither keeps no rates."""
    length = 1.0
    with_alpha = pendulum(length).replace("output rod.phi,", "output rod.alpha, rod.phi,")
    res = mechdsl.loads(with_alpha, "pendulum.mech").simulate()
    assert res.status == "ok", res.messages
    np.testing.assert_allclose(res["rod.alpha"], -G * np.cos(res["rod.phi"]) / length,
                               rtol=0, atol=1e-8)
    mech = mechdsl.loads(pendulum(length), "pendulum.mech")
    kept = mech.simulate(rates=True)
    assert kept.status == "ok", kept.messages
    np.testing.assert_allclose(kept.rates[0, :len(kept["t"]), 1, 0, 2],
                               -G * np.cos(kept["rod.phi"]) / length, rtol=0, atol=1e-8)
    assert mech.simulate().rates is None
