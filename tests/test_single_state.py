"""The one-state code on Python floats (mechdsl/compiled/scalar.py, mechdsl/solve/single.py):
its kernels against the batched ones and finite differences, its LU against LAPACK, its
condition number against the exact one, and the solves that use it (the coarse march, the
assembly's continuation) against the closed form and the batched solver."""

from __future__ import annotations

import numpy as np
import pytest

from closed_forms import slider_crank
from mechdsl.compiled.lu import THRESHOLD
from mechdsl.compiled.variants import Overrides
from mechdsl.solve import SolverOptions, simulate
from mechdsl.solve.assembly import assemble
from mechdsl.solve.diagnose import col_scale
from mechdsl.solve.single import UNDECIDED, OneState, coarse_march_one


@pytest.fixture
def crank(load_example):
    return load_example("slider_crank.mech").compile(Overrides())


def _states(kernels, count: int, seed: int = 5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return kernels.system.guess[0] + 0.05 * rng.normal(size=(count, kernels.system.n))


def test_float_kernels_agree_with_the_batched_ones(crank):
    one = crank.one_state
    q = _states(crank, 7)
    qd = np.random.default_rng(1).normal(size=q.shape)
    phi, jac = crank.fused.evaluate_phi_jac(q[None])
    gamma = crank.fused.evaluate_gamma(q[None], qd[None])
    for k in range(len(q)):
        out = one.phi_jac(q[k].tolist(), (), 0.0, one.params, one.functions)
        np.testing.assert_allclose(out[: one.m], phi[0, k], rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(out[one.m :], jac[0, k], rtol=1e-14, atol=1e-14)
        g = one.gamma(q[k].tolist(), qd[k].tolist(), 0.0, one.params, one.functions)
        np.testing.assert_allclose(g, gamma[0, k], rtol=1e-13, atol=1e-13)


def test_float_jacobian_is_the_derivative_of_phi(crank):
    one = crank.one_state
    q = _states(crank, 1)[0]
    out = one.phi_jac(q.tolist(), (), 0.0, one.params, one.functions)
    dense = crank.fused.dense(np.array(out[one.m :]))
    h = 1e-6
    for j in range(crank.system.n):
        e = np.zeros(crank.system.n)
        e[j] = h
        plus = one.phi_jac((q + e).tolist(), (), 0.0, one.params, one.functions)[: one.m]
        minus = one.phi_jac((q - e).tolist(), (), 0.0, one.params, one.functions)[: one.m]
        np.testing.assert_allclose((np.array(plus) - minus) / (2 * h), dense[:, j], atol=1e-8)


def test_float_lu_solves_and_signs_as_lapack(crank):
    one = crank.one_state
    rng = np.random.default_rng(2)
    for q in _states(crank, 20):
        vals = one.phi_jac(q.tolist(), (), 0.0, one.params, one.functions)[one.m :]
        A = crank.fused.dense(np.array(vals))
        fac = one.factor(vals, THRESHOLD)
        assert fac is not None
        b = rng.normal(size=crank.system.n)
        np.testing.assert_allclose(A @ one.solve(fac, b.tolist()), b, atol=1e-12)
        np.testing.assert_allclose(A.T @ one.solve_t(fac, b.tolist()), b, atol=1e-12)
        solver = OneState(crank, one, col_scale(crank.system)[0, 0], SolverOptions())
        assert solver.sign(fac) == np.sign(np.linalg.det(A))


def test_condition_number_is_the_exact_one_and_the_estimate_bounds_it(crank):
    one = crank.one_state
    D = col_scale(crank.system)[0, 0]
    solver = OneState(crank, one, D, SolverOptions())
    for q in _states(crank, 10, seed=9):
        jac = crank.fused.dense(crank.fused.evaluate_jac(q[None, None]))[0, 0]
        a = jac * D
        a = a / np.linalg.norm(a, axis=1, keepdims=True)
        exact = 1 / (np.linalg.norm(a, 1) * np.linalg.norm(np.linalg.inv(a), 1))
        got = solver.factor(q.tolist())
        assert got.rcond == pytest.approx(exact, rel=1e-12)
        np.testing.assert_allclose(got.batched().inverse[0, 0], np.linalg.inv(jac),
                                   rtol=1e-12, atol=1e-12)
        # Hager's estimate of ||A^-1||_1 is a lower bound: rcond from above, and close
        est = solver.factor(q.tolist(), exact=False).rcond
        assert exact * (1 - 1e-12) <= est <= 3 * exact


def test_a_pivot_that_vanished_falls_back_to_lapack(crank):
    one = crank.one_state
    q = _states(crank, 1)[0]
    vals = one.phi_jac(q.tolist(), (), 0.0, one.params, one.functions)[one.m :]
    # a pivot with entries below it, made small against them
    step = next(s for s in crank.lu.steps if s[2])
    vals[step[4]] = 1e-3 * max(abs(vals[slot]) for _, slot in step[2])
    A = crank.fused.dense(np.array(vals))
    assert abs(np.linalg.det(A)) > 1e-6  # still regular, only the fixed order fails
    assert one.factor(vals, THRESHOLD) is None
    solver = OneState(crank, one, col_scale(crank.system)[0, 0], SolverOptions())
    b = np.arange(1.0, crank.system.n + 1)
    np.testing.assert_allclose(A @ solver._solve_values(vals, b.tolist()), b, atol=1e-12)


def test_the_coarse_march_on_floats_lands_on_the_closed_form(crank):
    opts = SolverOptions()
    asm = assemble(crank, 0.0, opts)
    solver = OneState(crank, crank.one_state, col_scale(crank.system)[0, 0], opts)
    fac = solver.factor(asm.q[0].tolist())
    qd, qdd = solver.rates(fac, asm.q[0].tolist(), [4 * np.pi], [0.0])
    out = coarse_march_one(solver, (0.0, asm.q[0], qd, qdd), fac.sign, crank.system.times,
                           opts.coarse_stride, opts, opts.level_split)
    assert out is not None and out is not UNDECIDED
    idx, (q, qd, qdd) = out
    assert idx[-1] == len(crank.system.times) - 1 and (np.diff(idx) > 0).all()
    th = np.pi / 4 + 4 * np.pi * crank.system.times[idx]
    k = crank.system.body_names.index("slider")
    for got, want in zip((q, qd, qdd), slider_crank(2.0, 3.5, th, 4 * np.pi, 0.0)):
        np.testing.assert_allclose(got[0, :, 3 * k], want, rtol=1e-13, atol=1e-13)


def test_float_and_batched_assembly_agree(crank, load_example):
    batched = load_example("slider_crank.mech").compile(Overrides())
    batched.__dict__["one_state"] = None  # (a cached property: the batched path)
    opts = SolverOptions()
    a, b = assemble(crank, 0.0, opts), assemble(batched, 0.0, opts)
    assert a.ok.all() and b.ok.all()
    np.testing.assert_allclose(a.q, b.q, atol=1e-13)
    k = crank.system.body_names.index("slider")
    assert a.q[0, 3 * k] == pytest.approx(slider_crank(2.0, 3.5, np.pi / 4, 0, 0)[0], abs=1e-13)


def test_a_sweep_has_no_float_code_and_gives_the_same_answers(load_example):
    mech = load_example("slider_crank.mech")
    sweep = mech.compile(Overrides(sweeps={"l": [3.0, 3.5]}))
    assert sweep.one_state is None
    alone = mech.compile(Overrides())
    r_sweep, r_alone = simulate(sweep), simulate(alone)
    np.testing.assert_allclose(r_sweep["slider.ax"][1], r_alone["slider.ax"], rtol=1e-13,
                               atol=1e-12)


def test_a_jacobian_without_a_usable_pivot_is_no_factorisation(load_example):
    """A pivot of the fixed order exactly zero with zeros below it passes the threshold test
    (0 >= 0) and divides by zero on floats (the four-bar's plan meets one on a Jacobian of
    zeros): the factorisation is refused, not raised."""
    from dataclasses import replace

    kernels = load_example("fourbar.mech").compile(Overrides())
    one = kernels.one_state
    with pytest.raises(ZeroDivisionError):
        one.factor([0.0] * one.nnz, THRESHOLD)
    zeros = replace(one, phi_jac=lambda q, qd, t, p, F: [0.0] * (one.m + one.nnz))
    solver = OneState(kernels, zeros, col_scale(kernels.system)[0, 0], SolverOptions())
    assert solver.factor(kernels.system.guess[0].tolist()) is None
    assert solver.factor(kernels.system.guess[0].tolist(), exact=False) is None


def test_the_cholesky_step_is_the_svd_step_and_gives_way_to_it_on_redundant_rows():
    """The Levenberg-Marquardt step through a a^T + lam I, of one state and of a batch,
    equals the SVD's (the identity (a^T a + lam I)^-1 a^T = a^T (a a^T + lam I)^-1); with a
    repeated row it is the SVD's own (the Cholesky factor's diagonal then spans far more
    than 1e5)."""
    from mechdsl.solve.assembly import _lm_step, _lm_step_one, _lm_step_svd

    rng = np.random.default_rng(3)
    for k, n in ((4, 6), (6, 6), (20, 21)):
        a, r = rng.normal(size=(k, n)), 1e-3 * rng.normal(size=k)
        want = _lm_step_svd(a[None], r[None])[0]
        np.testing.assert_allclose(_lm_step_one(a, r), want, rtol=1e-10, atol=1e-16)
        batch = rng.normal(size=(7, 1, k, n))
        rb = 1e-3 * rng.normal(size=(7, 1, k))
        np.testing.assert_allclose(_lm_step(batch, rb), _lm_step_svd(batch, rb), rtol=1e-9,
                                   atol=1e-16)
    a = rng.normal(size=(5, 7))
    a[4] = a[1]
    r = np.zeros(5)
    r[[1, 4]] = 1e-9
    want = _lm_step_svd(a[None], r[None])[0]
    np.testing.assert_allclose(_lm_step_one(a, r), want, rtol=1e-12, atol=1e-20)
    batch = np.stack([rng.normal(size=(5, 7)), a])[:, None]
    rb = np.stack([1e-3 * rng.normal(size=5), r])[:, None]
    np.testing.assert_allclose(_lm_step(batch, rb), _lm_step_svd(batch, rb), rtol=1e-12,
                               atol=1e-20)


def test_float_and_batched_assembly_agree_from_guesses_off_the_closure(load_example):
    """Guesses that leave the joints open: the float Gauss-Newton and drive continuation
    reach the batched path's configuration, and the slider's position is the closed form's."""
    from conftest import EXAMPLES
    from mechdsl import loads

    text = (EXAMPLES / "slider_crank.mech").read_text().replace(
        "guess = (3.75, 0, 0)", "guess = (3.6, 0.3, 0.1)")
    assert "(3.6, 0.3, 0.1)" in text
    crank, batched = (loads(text, "slider_crank.mech").compile(Overrides()) for _ in range(2))
    batched.__dict__["one_state"] = None  # (a cached property: the batched path)
    opts = SolverOptions()
    a, b = assemble(crank, 0.0, opts), assemble(batched, 0.0, opts)
    assert a.ok.all() and b.ok.all() and a.start is not None and b.start is None
    np.testing.assert_allclose(a.q, b.q, atol=1e-12)
    k = crank.system.body_names.index("slider")
    assert a.q[0, 3 * k] == pytest.approx(slider_crank(2.0, 3.5, np.pi / 4, 0, 0)[0], abs=1e-12)
    # the factorisation handed to the first instant is the one at the configuration reached
    fresh = OneState(crank, crank.one_state, col_scale(crank.system)[0, 0], opts).factor(
        a.q[0].tolist())
    assert a.start.fac.sign == fresh.sign and a.start.fac.rcond == pytest.approx(fresh.rcond)
    res = simulate(crank)
    x, vx, ax = slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * res["t"], 4 * np.pi, 0)
    np.testing.assert_allclose(res["slider.vx"][:1], vx[:1], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(res["slider.ax"][:1], ax[:1], rtol=1e-13, atol=1e-12)


def test_the_float_finiteness_check_is_isfinite_of_every_term():
    from mechdsl.solve.single import _all_finite

    inf, nan = float("inf"), float("nan")
    for values in ([], [1.0, -2.0], [1e308, 1e308], [1.0, inf], [inf, -inf], [nan, 1.0],
                   [-1e308, -1e308, 1.0], [0.0, -inf]):
        assert _all_finite(values) == all(np.isfinite(values)), values
