"""The augmented-Lagrangian equations of motion (mechdsl.solve.motion) against independent
truth: the dense saddle-point solve where Phi_q has full rank, the one-degree-of-freedom
closed forms of a redundant parallelogram and of IFToMM A02's parallelogram branch, the
Gauss principle by an explicit null-space basis at A02's singular position, the
mass-orthogonal projections' closed form, central finite differences of the loads, and
the cost of an evaluation against the number of bodies."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

import mechdsl
from conftest import EXAMPLES
from mechdsl.compiled import equations as eq
from mechdsl.solve.motion import Motion, dense_saddle
from mechdsl.solve.options import SolverOptions

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from a02_motion import a02_state, a02_text, branch_reference, chain_text  # noqa: E402

G = 9.81


def reference(system, t: float, q: np.ndarray, qd: np.ndarray):
    """qdd and lambda from the dense saddle-point matrix, with M, Phi_q, Q and gamma by the
    array kernels (not the one-state paths that Motion takes for small models)."""
    d = system.dynamics
    Q3, Qd3, T2 = q[None, None], qd[None, None], np.full((1, 1), t)
    jac = eq.jacobian(system, Q3)[0, 0]
    gamma = eq.acceleration_rhs(system, Q3, Qd3, T2)[0, 0]
    return dense_saddle(d.mass_matrix(Q3)[0, 0], jac, d.generalised_forces(Q3, Qd3, T2)[0, 0],
                        gamma)


def consistent(motion: Motion, t: float, y: np.ndarray) -> np.ndarray:
    out = motion.project(t, y)
    phi, jac = motion.phi_jac(t, out[:motion.n])
    assert np.abs(phi).max() <= 1e-12
    return out


# -- full rank: the same solution as the dense saddle-point solve --------------------------

DOUBLE_PENDULUM = """
body a { guess = (0.5, 0, 0)  point P = (-0.5, 0)  point Q = (0.5, 0)  mass = 2  inertia = 0.3 }
body b { guess = (1.4, 0, 0)  point P = (-0.4, 0)  mass = 1.5  inertia = 0.1
         centroid = (0.1, 0.05) }
joint O: revolute(ground.origin, a.P)
joint A: revolute(a.Q, b.P)
drive lift: angle(a) = 0.3*sin(2*t)
force s: rotary_spring(a, b, k = 40, c = 0.7)
gravity = (0, -9.81)
simulate t = 0 .. 1 step 0.01
output b.phi
"""


@pytest.mark.parametrize("case", ["andrews", "a02_regular", "driven"])
def test_full_rank_accelerations_equal_the_dense_saddle_point_solve(case):
    if case == "andrews":
        kernels = mechdsl.load(EXAMPLES / "andrews.mech").compile()
    elif case == "a02_regular":
        kernels = mechdsl.loads(a02_text(4), "a02.mech").compile()
    else:  # a drive and a free coordinate: f, f', f'' enter Phi, nu, gamma
        kernels = mechdsl.loads(DOUBLE_PENDULUM, "dp.mech").compile()
    motion = Motion(kernels)
    rng = np.random.default_rng(3)
    for t in (0.0, 0.37):
        if case == "a02_regular":
            y = a02_state(4, 1.0 + t, -1.3)
        else:
            y = np.concatenate((kernels.system.guess[0] + 1e-3 * rng.normal(size=kernels.system.n),
                                rng.normal(size=kernels.system.n)))
        y = consistent(motion, t, y)
        q, qd = y[:kernels.system.n], y[kernels.system.n:]
        qdd, lam = motion.accelerations(t, q, qd)
        qdd0, lam0 = reference(kernels, t, q, qd)
        assert np.abs(qdd - qdd0).max() <= 1e-12 * np.abs(qdd0).max()
        assert np.abs(lam - lam0).max() <= 1e-11 * np.abs(lam0).max()
        assert np.allclose(motion.rhs(t, y), np.concatenate((qd, qdd)), rtol=0, atol=0)


def test_band_and_dense_storages_agree():
    kernels = mechdsl.loads(chain_text(12), "chain.mech").compile()
    dense = Motion(kernels, SolverOptions(augmented_band_from=10**6))
    band = Motion(kernels, SolverOptions(augmented_band_from=1))
    assert dense.plan.dense and not band.plan.dense and band.plan.kd <= 6
    rng = np.random.default_rng(0)
    y = consistent(dense, 0.0, np.concatenate((kernels.system.guess[0] + 0.01 * rng.normal(
        size=kernels.system.n), rng.normal(size=kernels.system.n))))
    a1, l1 = dense.accelerations(0.0, y[:kernels.system.n], y[kernels.system.n:])
    a2, l2 = band.accelerations(0.0, y[:kernels.system.n], y[kernels.system.n:])
    assert np.abs(a1 - a2).max() <= 1e-12 * np.abs(a1).max()
    assert np.abs(l1 - l2).max() <= 1e-11 * np.abs(l1).max()


# -- redundant constraints: a parallelogram with a redundant crank -------------------------

def parallelogram(cranks: int) -> str:
    """``cranks`` equal cranks (a = 0.5 m, 0.8 kg, centroid mid-length) on pivots 2 m
    apart, their pins joined by one coupler (3 kg): mobility 1, every crank beyond two
    redundant (m = n for three cranks, m > n for four)."""
    d = 2.0
    ground = " ".join(f"point O{k} = ({k * d}, 0)" for k in range(cranks))
    mid = (cranks - 1) * d / 2
    pins = " ".join(f"point A{k} = ({k * d - mid}, 0)" for k in range(cranks))
    lines = [f"ground {{ {ground} }}"]
    for k in range(cranks):
        lines.append(f"body k{k} {{ guess = ({k * d}, 0, 0.8)  point A = (0.5, 0)  mass = 0.8  "
                     f"inertia = 0.02  centroid = (0.25, 0) }}")
    lines.append(f"body coupler {{ guess = ({mid + 0.3}, 0.35, 0)  {pins}  mass = 3  "
                 "inertia = 1.1 }")
    for k in range(cranks):
        lines.append(f"joint O{k}: revolute(ground.O{k}, k{k}.origin)")
        lines.append(f"joint A{k}: revolute(k{k}.A, coupler.A{k})")
    lines += ["gravity = (0, -9.81)", "simulate t = 0 .. 1 step 0.01", "output k0.phi"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("cranks", [3, 4])
def test_a_redundant_parallelogram_moves_as_its_closed_form(cranks):
    kernels = mechdsl.loads(parallelogram(cranks), "par.mech").compile()
    assert kernels.system.m >= kernels.system.n  # a dense saddle-point solve is singular here
    motion = Motion(kernels)
    a, d, mid = 0.5, 2.0, (cranks - 1) * 2.0 / 2
    th, w = 0.7, 1.5
    c, s = np.cos(th), np.sin(th)
    q = [v for k in range(cranks) for v in (k * d, 0.0, th)] + [mid + a * c, a * s, 0.0]
    qd = [v for k in range(cranks) for v in (0.0, 0.0, w)] + [-a * s * w, a * c * w, 0.0]
    q, qd = np.array(q), np.array(qd)
    phi, jac = motion.phi_jac(0.0, q)
    assert np.abs(phi).max() <= 1e-15 and np.abs(jac @ qd).max() <= 1e-15
    qdd, lam = motion.accelerations(0.0, q, qd)
    assert np.isfinite(lam).all()
    gamma = motion.gamma(0.0, q, qd)
    assert np.abs(jac @ qdd - gamma).max() <= 1e-13 * (np.abs(gamma).max() + 1)
    # one degree of freedom: a physical pendulum of the cranks about their pivots and the
    # coupler translating on a circle of radius a
    m_c, i_c, m_b = 0.8, 0.02, 3.0
    inertia = cranks * (i_c + m_c * (a / 2) ** 2) + m_b * a * a
    moment = G * (cranks * m_c * a / 2 + m_b * a)
    thdd = -moment / inertia * c
    expect = [v for k in range(cranks) for v in (0.0, 0.0, thdd)]
    expect += [-a * (c * w * w + s * thdd), a * (-s * w * w + c * thdd), 0.0]
    assert np.abs(qdd - expect).max() <= 1e-12 * abs(thdd)
    # the equations of motion hold with the multipliers found
    residual = motion.mass(q) @ qdd + jac.T @ lam - motion.loads(0.0, q, qd)
    assert np.abs(residual).max() <= 1e-11 * np.abs(lam).max()


# -- IFToMM A02 at and near its singular positions ------------------------------------------

N_A02 = 4
#: theta'' = -(K / I_eff) cos theta on the parallelogram branch
BRANCH = G * ((N_A02 + 1) / 2 + N_A02) / ((N_A02 + 1) / 3 + N_A02)


def a02_accelerations(theta: float, rate: float, thdd: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    out = []
    for _ in range(N_A02 + 1):  # a rocker's frame at its pivot
        out += [0.0, 0.0, thdd]
    for _ in range(N_A02):
        out += [-(c * rate**2 + s * thdd), -s * rate**2 + c * thdd, 0.0]
    return np.array(out)


@pytest.fixture(scope="module")
def a02():
    kernels = mechdsl.loads(a02_text(N_A02), "a02.mech").compile()
    return kernels, Motion(kernels)


@pytest.mark.parametrize("theta", [1.0, 0.4, 0.05, np.pi - 0.05])
def test_a02_regular_positions_follow_the_parallelogram_branch(a02, theta):
    kernels, motion = a02
    rate = -2.0
    y = a02_state(N_A02, theta, rate)
    qdd, _ = motion.accelerations(0.0, y[:kernels.system.n], y[kernels.system.n:])
    expect = a02_accelerations(theta, rate, -BRANCH * np.cos(theta))
    assert np.abs(qdd - expect).max() <= 1e-9 * np.abs(expect).max()


@pytest.mark.parametrize("theta", [0.0, np.pi])
def test_a02_at_its_singular_position_gives_the_gauss_principle(a02, theta):
    """Where every link is collinear, Phi_q loses N of its rank and the accelerations that
    satisfy Phi_q qdd = gamma form an (N + 1)-dimensional set: the equations of motion
    choose the one of least Gauss function 1/2 qdd^T M qdd - Q^T qdd, computed here with
    an explicit basis Z of the null space of Phi_q (qdd = qdd_p + Z (Z^T M Z)^-1 Z^T (Q -
    M qdd_p)). That is finite, and it is NOT the parallelogram branch's acceleration (the
    branch is the limit from the regular positions on either side: the end rockers carry
    less of the couplers' weight than the inner ones, and instantaneously the windows may
    shear), which the test shows too."""
    kernels, motion = a02
    n = kernels.system.n
    rate = -2.0
    y = a02_state(N_A02, theta, rate)
    q, qd = y[:n], y[n:]
    phi, jac = motion.phi_jac(0.0, q)
    jac = jac.toarray()
    assert np.linalg.matrix_rank(jac) == kernels.system.m - N_A02
    qdd, lam = motion.accelerations(0.0, q, qd)
    assert np.isfinite(qdd).all() and np.isfinite(lam).all()
    gamma = motion.gamma(0.0, q, qd)
    assert np.abs(jac @ qdd - gamma).max() <= 1e-13 * (np.abs(gamma).max() + 1)
    mass, load = motion.mass(q).toarray(), motion.loads(0.0, q, qd)
    particular = np.linalg.lstsq(jac, gamma, rcond=None)[0]
    Z = scipy.linalg.null_space(jac)
    gauss = particular + Z @ np.linalg.solve(Z.T @ mass @ Z, Z.T @ (load - mass @ particular))
    assert np.abs(qdd - gauss).max() <= 1e-11 * np.abs(gauss).max()
    branch = a02_accelerations(theta, rate, -BRANCH * np.cos(theta))
    assert np.abs(qdd - branch).max() > 1e-2 * np.abs(branch).max()


@pytest.mark.parametrize("theta, dq", [(1.0, 1e-3), (0.0, 1e-9), (np.pi, 1e-9)])
def test_projections_restore_both_constraint_levels_mass_orthogonally(a02, theta, dq):
    kernels, motion = a02
    n = kernels.system.n
    rng = np.random.default_rng(7)
    y = a02_state(N_A02, theta, -2.0)
    y[:n] += dq * rng.normal(size=n)
    y[n:] += 1e-3 * rng.normal(size=n)
    out = motion.project(0.0, y)
    q, qd = out[:n], out[n:]
    phi, jac = motion.phi_jac(0.0, q)
    assert np.abs(phi).max() <= 1e-13
    if theta == 1.0:
        assert np.abs(jac @ qd).max() <= 1e-13
    else:
        # within dq of the collinear position the rows that lose rank have singular
        # values sigma ~ dq, and sigma^2 times the penalty is far below one: there the
        # projection leaves Phi_q qd at sigma |qd| (the shear velocity of the windows,
        # undetermined at the singular position itself), i.e. of the order of dq
        assert np.abs(jac @ qd).max() <= 10 * dq * np.abs(qd).max()
    if theta == 1.0:
        # the M-orthogonal projection of the given velocity onto Phi_q qd = 0 at q:
        # qd* - M^-1 J^T (J M^-1 J^T)^-1 J qd*
        J, M = jac.toarray(), motion.mass(q).toarray()
        v = y[n:]
        X = np.linalg.solve(M, J.T)
        expect = v - X @ np.linalg.solve(J @ X, J @ v)
        assert np.abs(qd - expect).max() <= 1e-12 * np.abs(v).max()


@pytest.mark.parametrize("penalty", [1e6, 1e10, 1e12])
def test_projection_and_accelerations_are_exact_at_any_penalty(a02, penalty):
    """The penalty sets how fast the iteration contracts, not where it ends: the factor of
    M + Phi_q^T W Phi_q rounds at about the penalty times the unit round-off, and the
    iteration removes that error (it tests both residuals). It did not where the
    constraints' residual met its test at once: a velocity projection kept 2.5e-7 of |qd|
    at a penalty of 1e10. Against the closed forms: the M-orthogonal projection
    qd* - M^-1 J^T (J M^-1 J^T)^-1 J qd* and the dense saddle-point solve."""
    kernels, _ = a02
    motion = Motion(kernels, SolverOptions(augmented_penalty=penalty, augmented_band_from=1))
    n = kernels.system.n
    rng = np.random.default_rng(3)
    y = a02_state(N_A02, 0.8, -2.0)
    y[n:] += 1e-3 * rng.normal(size=n)
    out = motion.project(0.0, y)
    q, qd = out[:n], out[n:]
    J, M = motion.phi_jac(0.0, q)[1].toarray(), motion.mass(q).toarray()
    v = y[n:]
    X = np.linalg.solve(M, J.T)
    expect = v - X @ np.linalg.solve(J @ X, J @ v)
    assert np.abs(qd - expect).max() <= 1e-12 * np.abs(v).max()
    qdd, _ = motion.accelerations(0.0, q, qd)
    ref, _ = reference(kernels, 0.0, q, qd)
    assert np.abs(qdd - ref).max() <= 1e-12 * np.abs(ref).max()


def test_a02_integrates_through_its_singular_positions(a02):
    """DOP853 on Motion.rhs, projected every 0.01 s, over 2 s: two passages through the
    collinear position, B0 on the parallelogram branch (the 1-DOF equation)."""
    from a02_motion import run_a02

    res = run_a02(N=N_A02, t_end=2.0, rtol=1e-10)
    assert res["passages"] == 2
    assert res["B0_error"] <= 1e-6
    assert res["phi_end"] <= 1e-13 and res["velocity_residual_end"] <= 1e-12


# -- exact derivatives of the loads ---------------------------------------------------------

SPRINGS = """
body a { guess = (0.5, 0.1, 0.3)  point P = (-0.5, 0)  point Q = (0.5, 0.1)  mass = 2  inertia = 0.3
         centroid = (0.2, -0.1) }
body b { guess = (1.6, 0.7, -0.4)  point P = (-0.4, 0.05)  mass = 1.5  inertia = 0.1
         centroid = (0.1, 0.05) }
joint O: revolute(ground.origin, a.P)
force s1: spring(a.Q, b.P, k = 300, length = 0.4, c = 2.5)
force s2: rotary_spring(a, b, k = 40, angle = 0.2, c = 0.7)
force s3: spring(ground.origin, b.origin, k = 50, length = 1, c = 1.2)
force m: torque(a, value = 0.5*sin(3*t))
gravity = (0, -9.81)
simulate t = 0 .. 1 step 0.01
output b.phi
"""


def test_load_derivatives_equal_central_differences():
    kernels = mechdsl.loads(SPRINGS, "springs.mech").compile()
    motion = Motion(kernels)
    rng = np.random.default_rng(11)
    n, t = kernels.system.n, 0.3
    q = kernels.system.guess[0] + 0.05 * rng.normal(size=n)
    qd = rng.normal(size=n)
    dq, dqd = motion.load_derivatives(t, q, qd)
    dq, dqd = dq.toarray(), dqd.toarray()
    h = 1e-6
    fd_q, fd_qd = np.empty((n, n)), np.empty((n, n))
    for k in range(n):
        e = np.zeros(n)
        e[k] = h
        fd_q[:, k] = (motion.loads(t, q + e, qd) - motion.loads(t, q - e, qd)) / (2 * h)
        fd_qd[:, k] = (motion.loads(t, q, qd + e) - motion.loads(t, q, qd - e)) / (2 * h)
    scale = np.abs(fd_q).max()
    assert np.abs(dq - fd_q).max() <= 1e-7 * scale
    assert np.abs(dqd - fd_qd).max() <= 1e-7 * np.abs(fd_qd).max()
    # the damping and the quadratic velocity term make dQ/dqd non-zero; gravity alone
    # (constant) has no entry
    assert np.abs(dqd).max() > 0.5


# -- cost against size ---------------------------------------------------------------------

def test_an_evaluation_costs_time_linear_in_the_number_of_bodies():
    """Chains of 40 and 320 links (band storage, half-width 5): eight times the bodies,
    at most 16 times the thread CPU time of an evaluation (linear, with the fixed costs of
    the calls; a dense factorisation would take about 500 times, a dense multiplication
    64 times). The measured numbers are in benchmarks/a02_motion.py's output."""
    from a02_motion import cpu_time_per_call

    cost = {}
    for N in (40, 320):
        kernels = mechdsl.loads(chain_text(N), "chain.mech").compile()
        motion = Motion(kernels)
        assert not motion.plan.dense and motion.plan.kd <= 6
        rng = np.random.default_rng(0)
        y = consistent(motion, 0.0, np.concatenate((kernels.system.guess[0] + 1e-3 * rng.normal(
            size=kernels.system.n), rng.normal(size=kernels.system.n))))
        cost[N] = cpu_time_per_call(lambda: motion.rhs(0.0, y), reps=10)
    assert cost[320] <= 16 * cost[40], cost


def test_branch_reference_reproduces_the_published_table():
    """The 1-DOF oracle used above against the reference file's B0 table (N = 40)."""
    got = branch_reference(40, 10.0)
    assert np.abs(got - [0.180512226681, 0.983572740583]).max() <= 1e-9


def test_the_bodies_terms_are_haugs_closed_form():
    """M(q) and Q(q, qd) of the array path (the bodies' terms by array arithmetic,
    solve/body_terms.py, plus the traced force elements') against Haug's closed form for
    bodies whose centres of mass are off their frames (sec. 6.2: M = [[m, 0, -m a_y], [0, m,
    m a_x], [-m a_y, m a_x, J + m |s'|^2]], Q = m g + m a phid^2, n = a x m g) plus a
    spring's force written out by hand, at random states; and the traced scalar code, which
    a model of fewer bodies takes, agrees."""
    from mechdsl.solve.body_terms import FROM_BODIES
    from mechdsl.symbolic.codegen import scalar_kernel

    nb = FROM_BODIES + 1
    props = [(1.0 + 0.1 * i, 0.2 + 0.01 * i, (0.4 - 0.03 * i, -0.1 + 0.02 * i))
             for i in range(nb)]
    lines = ["gravity = (0.5, -9.81)", "ground { }"]
    for i, (m, J, (sx, sy)) in enumerate(props):
        lines.append(f"body b{i} {{ guess = ({i}, 0, 0)  mass = {m!r}  inertia = {J!r}  "
                     f"centroid = ({sx!r}, {sy!r}) }}")
    lines += [f"force s: spring(ground.origin, b{nb - 1}.origin, k = 50, length = 0.5)",
              "simulate t = 0 .. 1 step 0.1"]
    kernels = mechdsl.loads("\n".join(lines), "bodies.mech").compile()
    motion = Motion(kernels)
    assert motion._bodies is not None
    d = kernels.dynamics
    n = 3 * nb
    rng = np.random.default_rng(7)
    g = np.array([0.5, -9.81])
    for _ in range(5):
        q, qd = rng.normal(size=n), rng.normal(size=n)
        mass, loads = motion._mass_loads(q, qd, 0.0)
        M = np.zeros((n, n))
        M[d.rows, d.cols] = mass
        Q = np.zeros(n)
        expected_M = np.zeros((n, n))
        for i, (m, J, (sx, sy)) in enumerate(props):
            phi, w = q[3 * i + 2], qd[3 * i + 2]
            ax = np.cos(phi) * sx - np.sin(phi) * sy
            ay = np.sin(phi) * sx + np.cos(phi) * sy
            k = 3 * i
            expected_M[k:k + 3, k:k + 3] = [[m, 0, -m * ay], [0, m, m * ax],
                                            [-m * ay, m * ax, J + m * (sx * sx + sy * sy)]]
            Q[k:k + 3] = (m * g[0] + m * ax * w * w, m * g[1] + m * ay * w * w,
                          ax * m * g[1] - ay * m * g[0])
        r = q[n - 3:n - 1]  # the spring from the ground's origin to the last body's origin
        length = np.linalg.norm(r)
        Q[n - 3:n - 1] -= 50 * (length - 0.5) * r / length
        assert np.allclose(M, expected_M, rtol=1e-14, atol=1e-14)
        assert np.allclose(loads, Q, rtol=1e-13, atol=1e-12)
        # the traced scalar code of every term (the path of fewer bodies) agrees
        fn = scalar_kernel(d.graph, [*d.mass_nodes, *d.load_nodes], "all").fn
        traced = np.array(fn(q.tolist(), qd.tolist(), 0.0, motion._mq_p, motion._mq_F))
        assert np.allclose(traced[:len(mass)], mass, rtol=1e-14, atol=1e-14)
        assert np.allclose(traced[len(mass):], loads, rtol=1e-13, atol=1e-12)


def test_the_compressed_rows_products_equal_the_dense_ones():
    """solve/augmented.py's Rows: the product with scipy's compiled kernel and with the
    bincount it falls back to equal the dense matrix's, with repeated entries (summed)
    and empty rows, for values given in the caller's order."""
    from dataclasses import replace

    from mechdsl.solve.augmented import Rows, _csr_matvec

    rng = np.random.default_rng(3)
    rows = np.array([4, 0, 0, 2, 4, 4, 0, 2])  # rows 1 and 3 empty, (0, 1) twice
    cols = np.array([0, 1, 1, 3, 2, 0, 4, 4])
    values, x = rng.normal(size=rows.size), rng.normal(size=5)
    dense = np.zeros((5, 5))
    np.add.at(dense, (rows, cols), values)
    plan = Rows.of(rows, cols, (5, 5))
    assert _csr_matvec() is not None
    for p in (plan, replace(plan, compiled=False)):
        assert np.allclose(p.times(values[p.order], x), dense @ x, rtol=1e-14, atol=1e-15)
