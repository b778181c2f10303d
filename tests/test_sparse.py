"""The sparse path for large mechanisms: the same equations, factorisations and answers as the
dense path, checked against the dense Jacobian and against the closed form of a row of
parallelograms (benchmarks/models.py)."""

from __future__ import annotations

import itertools
import sys

import numpy as np
import pytest

from conftest import ROOT
from mechdsl.compiled import equations as eq
from mechdsl.solve.linalg import factor, solve
from mechdsl.solve import SolverOptions
from mechdsl.solve import simulate
from mechdsl.compiled.sparse import permutation_sign
from mechdsl.compiled.variants import Overrides

sys.path.insert(0, str(ROOT / "benchmarks"))
import models  # noqa: E402

SPARSE = SolverOptions(sparse_from=0)
DENSE = SolverOptions(sparse_from=10**9)


def _dense(sj) -> np.ndarray:
    out = np.zeros(sj.shape)
    out[..., sj.pattern.rows, sj.pattern.cols] = sj.values
    return out


@pytest.mark.parametrize("example", ["slider_crank.mech", "planetary.mech", "cam_roller.mech"])
def test_pattern_values_are_the_dense_jacobian(load_example, example):
    kernels = load_example(example).compile()
    rng = np.random.default_rng(1)
    q = rng.normal(size=(kernels.system.n_variants, 4, kernels.system.n))
    np.testing.assert_array_equal(_dense(eq.jacobian_values(kernels, q)), eq.jacobian(kernels, q))


def test_permutation_sign_is_the_parity():
    rng = np.random.default_rng(2)
    for n in (1, 2, 3, 7, 64):
        for _ in range(5):
            perm = rng.permutation(n)
            # parity by counting inversions
            inversions = sum(perm[i] > perm[j] for i, j in itertools.combinations(range(n), 2))
            assert permutation_sign(perm) == (-1.0) ** inversions


def test_sparse_factor_agrees_with_dense(loads):
    kernels = loads(models.chain_text(6)).compile()
    rng = np.random.default_rng(3)
    q = rng.normal(size=(1, 5, kernels.system.n))
    D = np.full((1, 1, kernels.system.n), 1.0)
    dense = factor(eq.jacobian(kernels, q), D)
    sparse = factor(eq.jacobian_values(kernels, q), D)
    np.testing.assert_array_equal(sparse.sign, dense.sign)
    # Higham's estimate of ||A^-1||_1 is a lower bound, exact in most cases
    assert np.all(sparse.rcond >= dense.rcond * (1 - 1e-9))
    assert np.all(sparse.rcond <= 3 * dense.rcond)
    rhs = rng.normal(size=(1, 5, kernels.system.m))
    np.testing.assert_allclose(sparse.solve(rhs), dense.solve(rhs), rtol=1e-9, atol=1e-12)
    x, ok = solve(eq.jacobian_values(kernels, q), rhs)
    assert ok.all()
    np.testing.assert_allclose(np.einsum("...ij,...j->...i", eq.jacobian(kernels, q), x), rhs,
                               atol=1e-10)


@pytest.mark.parametrize("opts", [SPARSE, DENSE], ids=["sparse", "dense"])
def test_row_of_parallelograms_matches_closed_form(loads, opts):
    n_loops = 8
    res = simulate(loads(models.chain_text(n_loops, t1=0.5, step=0.01)).compile(), opts)
    assert res.ok, res.messages
    ex = models.chain_exact(res["t"])
    last = f"coupler{n_loops - 1}"
    assert np.abs(res[f"{last}.x"] - (n_loops - 1) - ex["x"]).max() < 1e-13
    assert np.abs(res[f"{last}.vx"] - ex["vx"]).max() < 1e-12
    assert np.abs(res[f"{last}.ax"] - ex["ax"]).max() < 1e-11
    assert np.abs(res[f"crank{n_loops}.alpha"] - ex["alpha"]).max() < 1e-10


def test_sparse_assembly_from_rough_guesses(loads):
    """Sparse Levenberg-Marquardt closes the loops from guesses 20 % of a crank off."""
    text = models.chain_text(5, t1=0.0, step=0.01)
    rng = np.random.default_rng(4)
    lines = []
    for line in text.splitlines():
        if "guess = (" in line:
            head, rest = line.split("guess = (")
            vals, tail = rest.split(")", 1)
            x, y, phi = (float(v) for v in vals.split(","))
            x, y = x + rng.uniform(-0.1, 0.1), y + rng.uniform(-0.1, 0.1)
            phi += rng.uniform(-0.2, 0.2)
            line = f"{head}guess = ({x}, {y}, {phi}){tail}"
        lines.append(line)
    res = simulate(loads("\n".join(lines)).compile(), SPARSE)
    assert res.ok, res.messages
    ex = models.chain_exact(res["t"])
    assert abs(res["coupler4.x"][0] - 4 - ex["x"][0]) < 1e-12
    assert abs(res["crank5.phi"][0] - ex["phi"][0]) < 1e-12


def test_sparse_lock_up_stops_where_dense_does(load_example):
    """The slider-crank with a rod shorter than its crank locks up: the sparse path reports
    the same instant, the same reason and keeps the same instants as the dense one."""
    kernels = load_example("slider_crank.mech").compile(Overrides(params={"l": 1.5}))
    dense, sparse = simulate(kernels, DENSE), simulate(kernels, SPARSE)
    assert not dense.ok and not sparse.ok
    assert dense.n_solved[0] == sparse.n_solved[0]
    # the same reason; the instant bisected to may differ in its last digits
    assert dense.messages[0].split(" t = ")[0] == sparse.messages[0].split(" t = ")[0]
    k = dense.n_solved[0]
    np.testing.assert_allclose(sparse["slider.x"][:k], dense["slider.x"][:k], atol=1e-12)


@pytest.mark.parametrize("order", [1, 2])
def test_every_predictor_order_reaches_the_closed_form(load_example, order):
    res = simulate(load_example("slider_crank.mech").compile(Overrides(t1=0.2)),
                   SolverOptions(predictor_order=order))
    assert res.ok
    x, vx, ax = models.slider_crank_exact(res["t"])
    assert np.abs(res["slider.x"] - x).max() / np.abs(x).max() < 1e-13
    assert np.abs(res["slider.ax"] - ax).max() / np.abs(ax).max() < 1e-11


def test_large_chain_at_its_change_point_is_reported_without_a_dense_analysis(loads):
    """A row of 120 parallelograms (723 coordinates, above the dense analysis limit) driven
    to theta = 0, where every crank lines up with its couplers: the run stops at the change
    point, with the joints involved named from the sparse factorisation."""
    text = models.chain_text(120, t1=0.5, step=0.01).replace(
        "pi/2 + pi/4*sin(2*pi*t)", "pi/2 - 2*pi*t")
    res = simulate(loads(text).compile(), SPARSE)
    assert res.status == "failed"
    assert 22 <= res.n_solved[0] <= 25  # theta reaches 0 at t = 0.25
    assert "singular position" in res.messages[0]
    assert "joint" in res.messages[0].split("can no longer close:")[1]


def test_condition_limits_grow_with_size():
    opts = SolverOptions()
    assert opts.for_size(3) is opts
    big = opts.for_size(1001)
    assert big.singular_rcond == pytest.approx(opts.singular_rcond / 100.1**2)
    assert big.warn_rcond == pytest.approx(opts.warn_rcond / 100.1**2)


def test_simplified_newton_converges_to_round_off(load_example):
    """Reusing a factorisation converges linearly; it must still end at round-off, as the
    dense path does (the slider-crank solved on the sparse path against its closed form)."""
    res = load_example("slider_crank.mech").simulate(options=SPARSE)
    assert res.ok
    x, vx, ax = models.slider_crank_exact(res["t"])
    assert np.abs(res["slider.x"] - x).max() / np.abs(x).max() < 1e-15
    assert np.abs(res["slider.vx"] - vx).max() / np.abs(vx).max() < 1e-14
    assert np.abs(res["slider.ax"] - ax).max() / np.abs(ax).max() < 1e-14
    assert res.residual < 1e-14


def test_a_variant_that_stops_leaves_the_others_exact_on_the_sparse_path(load_example):
    # rod 1.9 < crank 2: that variant locks up early; the other goes on reusing its own
    # factorisations, not the ones from before the lock-up
    res = load_example("slider_crank.mech").simulate(sweep={"l": [3.5, 1.9]}, options=SPARSE)
    assert res.n_solved[0] == 1001 and res.n_solved[1] < 100
    x, vx, ax = models.slider_crank_exact(res["t"])
    assert np.abs(res["slider.x"][0] - x).max() / np.abs(x).max() < 1e-15
    assert np.abs(res["slider.ax"][0] - ax).max() / np.abs(ax).max() < 1e-14
