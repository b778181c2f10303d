"""Many instants settled at once (mechdsl/solve/batch.py) against the step-by-step path
(Newton, the factorisation, the rate solves) and the slider-crank's closed form."""

from __future__ import annotations

import numpy as np
import pytest

from closed_forms import slider_crank
from mechdsl.compiled import equations as eq
from mechdsl.compiled.variants import Overrides
from mechdsl.solve import SolverOptions, batch
from mechdsl.solve.diagnose import col_scale
from mechdsl.solve.linalg import factor
from mechdsl.solve.newton import newton

OPTS = SolverOptions()


def _crank_states(kernels, lengths, t, noise=1e-6, seed=3):
    """The closed-form states of slider-cranks with rods ``lengths`` at ``t``, perturbed."""
    th = np.pi / 4 + 4 * np.pi * t
    V, b = len(lengths), len(t)
    q = np.zeros((V, b, kernels.system.n))
    names = kernels.system.body_names
    for v, l in enumerate(lengths):
        x, _, _ = slider_crank(2.0, l, th, 4 * np.pi, 0.0)
        c, s = np.cos(th), np.sin(th)
        B = np.stack((2.0 * c, 2.0 * s))
        k = names.index("crank")
        q[v, :, 3 * k : 3 * k + 3] = np.stack((c, s, th), axis=-1)
        k = names.index("rod")
        q[v, :, 3 * k : 3 * k + 3] = np.stack(((B[0] + x) / 2, B[1] / 2,
                                               np.arctan2(-B[1], x - B[0])), axis=-1)
        k = names.index("slider")
        q[v, :, 3 * k] = x
    rng = np.random.default_rng(seed)
    return q + noise * rng.normal(size=q.shape), th


@pytest.fixture
def sweep(load_example):
    lengths = [3.0, 3.5, 4.5]
    return load_example("slider_crank.mech").compile(Overrides(sweeps={"l": lengths})), lengths


def test_settled_states_are_the_closed_form(sweep):
    kernels, lengths = sweep
    t = np.linspace(0.0, 0.5, 40)
    pred, th = _crank_states(kernels, lengths, t)
    T = np.broadcast_to(t, (len(lengths), len(t)))
    out = batch.settle(kernels, pred, T, col_scale(kernels.system), np.ones(3, bool), OPTS,
                       rates=True)
    assert out is not None and out.converged.all()
    k = kernels.system.body_names.index("slider")
    for v, l in enumerate(lengths):
        x, vx, ax = slider_crank(2.0, l, th, 4 * np.pi, 0.0)
        np.testing.assert_allclose(out.q[v, :, 3 * k], x, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(out.qd[v, :, 3 * k], vx, rtol=1e-13, atol=1e-12)
        np.testing.assert_allclose(out.qdd[v, :, 3 * k], ax, rtol=1e-12, atol=1e-10)


def test_settle_agrees_with_the_step_by_step_path(sweep):
    kernels, lengths = sweep
    t = np.linspace(0.1, 0.4, 30)
    pred, _ = _crank_states(kernels, lengths, t, seed=8)
    T = np.broadcast_to(t, (len(lengths), len(t)))
    D, active = col_scale(kernels.system), np.ones(3, bool)
    out = batch.settle(kernels, pred, T, D, active, OPTS, rates=True)
    q, ok, _ = newton(kernels, pred, T, D, active, OPTS, np.arange(kernels.system.m))
    fac = factor(eq.solver_jacobian(kernels, q, np.arange(kernels.system.m), False), D)
    assert ok.all()
    np.testing.assert_allclose(out.q, q, atol=1e-14)
    np.testing.assert_allclose(out.fac.rcond, fac.rcond, rtol=1e-9)
    np.testing.assert_array_equal(out.fac.sign, fac.sign)
    # the factorisation it hands back solves as the general one does
    rhs = np.random.default_rng(2).normal(size=q.shape)
    np.testing.assert_allclose(out.fac.solve(rhs), fac.solve(rhs), rtol=1e-10, atol=1e-12)


def test_without_rates_only_the_factorisation_comes_back(sweep):
    kernels, lengths = sweep
    t = np.linspace(0.0, 0.3, 30)
    pred, _ = _crank_states(kernels, lengths, t)
    T = np.broadcast_to(t, (3, len(t)))
    out = batch.settle(kernels, pred, T, col_scale(kernels.system), np.ones(3, bool), OPTS,
                       rates=False)
    assert out.qd is None and out.qdd is None and out.converged.all()


def test_an_inactive_variant_is_left_as_it_is(sweep):
    kernels, lengths = sweep
    t = np.linspace(0.0, 0.3, 30)
    pred, _ = _crank_states(kernels, lengths, t)
    T = np.broadcast_to(t, (3, len(t)))
    active = np.array([True, False, True])
    out = batch.settle(kernels, pred, T, col_scale(kernels.system), active, OPTS, rates=True)
    np.testing.assert_array_equal(out.q[1], pred[1])
    assert out.converged.all()


def test_a_small_batch_or_a_lost_pivot_goes_to_the_general_path(sweep):
    kernels, lengths = sweep
    t = np.linspace(0.0, 0.3, 10)  # 3 x 10 states: below the generated LU's batch
    pred, _ = _crank_states(kernels, lengths, t)
    T = np.broadcast_to(t, (3, len(t)))
    assert batch.settle(kernels, pred, T, col_scale(kernels.system), np.ones(3, bool), OPTS,
                        rates=True) is None
    t = np.linspace(0.0, 0.3, 40)
    pred, _ = _crank_states(kernels, lengths, t)
    pred[0, 5] = np.nan  # a state the fixed pivot order cannot take
    T = np.broadcast_to(t, (3, len(t)))
    assert batch.settle(kernels, pred, T, col_scale(kernels.system), np.ones(3, bool), OPTS,
                        rates=True) is None


def test_the_residual_and_correction_ratio_are_measured_where_the_run_measures_them(sweep):
    # the settle's own |Phi| at its final positions and Newton's correction against the
    # motion from each state's predecessor are what the step-by-step path measures
    from mechdsl.solve.newton import correction_ratio

    kernels, lengths = sweep
    t = np.linspace(0.1, 0.3, 30)
    pred, _ = _crank_states(kernels, lengths, t, noise=1e-5)
    before, _ = _crank_states(kernels, lengths, np.array([0.09]), noise=0.0)
    T = np.broadcast_to(t, (len(lengths), len(t)))
    D = col_scale(kernels.system)
    out = batch.settle(kernels, pred, T, D, np.ones(3, bool), OPTS, rates=False,
                       before=before[:, 0], floor=1e-5)
    assert out is not None and out.converged.all()
    phi = np.abs(eq.constraint_values(kernels, out.q, T)).max(axis=-1)
    np.testing.assert_allclose(out.residual, phi, rtol=0, atol=1e-16)
    assert out.residual.max() <= 1e-14
    previous = np.concatenate((before, out.q[:, :-1]), axis=1)
    expected = correction_ratio(out.q, pred, previous, D, 1e-5)
    np.testing.assert_allclose(out.ratio, expected, rtol=1e-12)
    # the correction of a 1e-5 perturbation against 0.0067 s of motion: small, not zero
    assert 1e-5 < out.ratio.max() < 0.1


def test_rowwise_reductions_are_numpys_in_either_layout():
    """max |x| and all-finite over the coordinates: the same answers on a states-major array
    and on the entry-major views the batched Newton hands out (NaN and inf included)."""
    from mechdsl.solve.rowwise import absmax, allfinite

    rng = np.random.default_rng(7)
    base = rng.normal(size=(9, 3, 50, 4))  # (n, right-hand sides, b, V)
    base[2, 1, 7, 3] = np.nan
    base[5, 1, 9, 0] = np.inf
    base[0, 1, 11, 2] = -np.inf
    for x in (base[:, 1].T, np.ascontiguousarray(base[:, 1].T), base[:, 1, :, 0].T[None]):
        np.testing.assert_array_equal(allfinite(x), np.isfinite(x).all(axis=-1))
        np.testing.assert_array_equal(absmax(x), np.abs(x).max(axis=-1))
