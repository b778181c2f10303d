"""The generated sparse LU (mechdsl/compiled/lu.py) against numpy's dense LAPACK: solves,
transposed solves, the determinant's sign, the inverse and Hager's estimate of ||A^-1||_1,
on random sparse patterns and batches; fill-in; the run-time pivot check; singular samples.

Layout (see LUPlan.factor): values are (..., nnz) with batch axes first; the factors and the
ok mask come back entry-major with the batch axes reversed; solve, sign, inverse and
inverse_norm1 hand results back with the batch axes first again."""

from __future__ import annotations

import numpy as np
import pytest

from mechdsl.compiled.lu import THRESHOLD, plan


def _random_pattern(rng, n: int, per_row: int = 3):
    """A diagonal plus ``per_row`` random entries per row (some may fall on it), rows shuffled
    (so that the pivot order is not the identity and the permutations' parity matters);
    (rows, cols) sorted by (row, col)."""
    mask = np.eye(n, dtype=bool)
    for i in range(n):
        mask[i, rng.choice(n, size=min(per_row, n), replace=False)] = True
    mask = mask[rng.permutation(n)]
    return np.nonzero(mask)


def _dense(rows, cols, n, values):
    A = np.zeros(values.shape[:-1] + (n, n))
    A[..., rows, cols] = values
    return A


def _values(rng, rows, batch):
    """Entries (batch + (nnz,)): each matrix a small perturbation of one random sample (so
    that the pivot order chosen on the sample stays acceptable for all); the sample is the
    first matrix of the batch."""
    base = rng.normal(size=len(rows))
    values = base * (1 + 0.02 * rng.uniform(-1, 1, size=batch + (len(rows),)))
    values.reshape(-1, len(rows))[0] = base
    return base, values


CASES = [(n, batch, seed) for seed, (n, batch) in enumerate(
    [(5, (7,)), (8, (3, 4)), (12, (1, 1)), (20, (7,)), (30, (3, 4)), (17, (2, 3, 2))])]


@pytest.mark.parametrize("n,batch,seed", CASES)
def test_solves_sign_inverse_against_numpy(n, batch, seed):
    rng = np.random.default_rng(100 + seed)
    rows, cols = _random_pattern(rng, n)
    base, values = _values(rng, rows, batch)
    lu = plan(rows, cols, n, base)
    assert lu is not None and lu.n == n and lu.nnz == len(rows)
    A = _dense(rows, cols, n, values)
    factors, ok = lu.factor(values)
    assert factors.shape == (lu.slots,) + batch[::-1]
    assert ok.shape == batch[::-1]
    assert ok.all()
    b = rng.normal(size=batch + (n,))
    x = lu.solve(factors, b)
    assert x.shape == batch + (n,)
    want = np.linalg.solve(A, b[..., None])[..., 0]
    np.testing.assert_allclose(x, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
    # the residual is at round-off
    assert np.abs(np.einsum("...ij,...j->...i", A, x) - b).max() < 1e-10
    z = lu.solve_transposed(factors, b)
    want_t = np.linalg.solve(np.swapaxes(A, -1, -2), b[..., None])[..., 0]
    np.testing.assert_allclose(z, want_t, rtol=1e-9, atol=1e-9 * np.abs(want_t).max())
    sign = lu.sign(factors)
    assert sign.shape == batch
    np.testing.assert_array_equal(sign, np.linalg.slogdet(A)[0])
    inv = lu.inverse(factors)
    assert inv.shape == batch + (n, n)
    want_inv = np.linalg.inv(A)
    np.testing.assert_allclose(inv, want_inv, rtol=1e-9, atol=1e-9 * np.abs(want_inv).max())
    est = lu.inverse_norm1(factors)
    assert est.shape == batch
    exact = np.abs(want_inv).sum(axis=-2).max(axis=-1)
    assert (est <= exact * (1 + 1e-10)).all()  # a lower bound
    assert (est >= exact / n).all()


def test_condition_estimate_on_independent_matrices():
    """Hager's estimate: never above ||A^-1||_1, never below it by more than n, and exact for
    most matrices (its documentation: "exact in most cases"); the determinant's sign."""
    rng = np.random.default_rng(12)
    exact_count = 0
    signs = set()
    trials = 40
    for _ in range(trials):
        n = int(rng.integers(5, 31))
        rows, cols = _random_pattern(rng, n)
        sample = rng.normal(size=len(rows))
        lu = plan(rows, cols, n, sample)
        factors, ok = lu.factor(sample[None])
        assert ok.all()
        A = _dense(rows, cols, n, sample)
        exact = np.abs(np.linalg.inv(A)).sum(axis=0).max()
        est = lu.inverse_norm1(factors)[0]
        signs.add(lu.sign(factors)[0])
        assert lu.sign(factors)[0] == np.linalg.slogdet(A)[0]
        assert exact / n <= est <= exact * (1 + 1e-10)
        exact_count += bool(np.isclose(est, exact, rtol=1e-10))
    assert exact_count >= trials // 2
    assert signs == {-1.0, 1.0}


def test_repeated_solves_leave_factors_and_right_hand_sides_unchanged():
    rng = np.random.default_rng(7)
    n = 9
    rows, cols = _random_pattern(rng, n)
    base, values = _values(rng, rows, (4,))
    lu = plan(rows, cols, n, base)
    factors, ok = lu.factor(values)
    assert ok.all()
    A = _dense(rows, cols, n, values)
    for _ in range(3):
        b = rng.normal(size=(4, n))
        np.testing.assert_allclose(lu.solve(factors, b), np.linalg.solve(A, b[..., None])[..., 0],
                                   rtol=1e-10, atol=1e-12)
    # solving does not overwrite the factors or b
    b = rng.normal(size=(4, n))
    b0, f0 = b.copy(), factors.copy()
    lu.solve(factors, b)
    lu.solve_transposed(factors, b)
    lu.inverse_norm1(factors)
    np.testing.assert_array_equal(b, b0)
    np.testing.assert_array_equal(factors, f0)


def test_sign_of_a_single_permutation_matrix():
    """Pure permutations: det = the permutation's sign, U's diagonal all ones."""
    rng = np.random.default_rng(8)
    for n in (2, 3, 6, 11):
        perm = rng.permutation(n)
        rows, cols = np.arange(n), perm
        order = np.argsort(rows * n + cols)
        rows, cols = rows[order], cols[order]
        vals = np.ones(n)
        lu = plan(rows, cols, n, vals)
        factors, ok = lu.factor(vals[None])
        assert ok.all()
        A = _dense(rows, cols, n, vals)
        assert lu.sign(factors)[0] == np.linalg.slogdet(A)[0]


def _arrow(n: int, diag: float):
    """An arrow matrix: full first row and column, a diagonal of ``diag``."""
    mask = np.eye(n, dtype=bool)
    mask[0, :] = mask[:, 0] = True
    rows, cols = np.nonzero(mask)
    vals = np.where(rows == cols, diag, 1.0)
    vals[(rows == 0) & (cols == 0)] = 1.0
    return rows, cols, vals


def _ring(n: int):
    """Periodic tridiagonal: any diagonal pivot creates fill."""
    mask = np.eye(n, dtype=bool) | np.roll(np.eye(n, dtype=bool), 1, axis=1) | np.roll(
        np.eye(n, dtype=bool), -1, axis=1)
    return np.nonzero(mask)


@pytest.mark.parametrize("kind", ["arrow", "ring"])
def test_fill_in_is_exact(kind):
    rng = np.random.default_rng(9)
    n = 10
    if kind == "arrow":
        # diagonal pivots below the threshold: the pivots come from the first row, and
        # eliminating them fills the rows they update
        rows, cols, base = _arrow(n, diag=0.2 * THRESHOLD)
    else:
        rows, cols = _ring(n)
        base = np.where(rows == cols, 4.0, 1.0) + 0.3 * rng.normal(size=len(rows))
    lu = plan(rows, cols, n, base)
    assert lu is not None
    assert lu.fill > 0 and lu.slots == lu.nnz + lu.fill
    values = base * (1 + 0.01 * rng.uniform(-1, 1, size=(5, len(rows))))
    factors, ok = lu.factor(values)
    assert ok.all()
    A = _dense(rows, cols, n, values)
    b = rng.normal(size=(5, n))
    np.testing.assert_allclose(lu.solve(factors, b), np.linalg.solve(A, b[..., None])[..., 0],
                               rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(lu.solve_transposed(factors, b),
                               np.linalg.solve(np.swapaxes(A, -1, -2), b[..., None])[..., 0],
                               rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(lu.sign(factors), np.linalg.slogdet(A)[0])
    np.testing.assert_allclose(lu.inverse(factors), np.linalg.inv(A), rtol=1e-10, atol=1e-12)


def test_arrow_with_an_acceptable_diagonal_needs_no_fill():
    """Markowitz's order takes the diagonal of the arrow's rows first: no fill at all, even
    where each diagonal entry is not its column's largest, only above THRESHOLD times it."""
    n = 10
    rows, cols, base = _arrow(n, diag=5 * THRESHOLD)
    base[(rows == 0) & (cols == 0)] = 20.0
    lu = plan(rows, cols, n, base)
    assert lu.fill == 0
    A = _dense(rows, cols, n, base)
    factors, ok = lu.factor(base[None])
    assert ok.all()
    b = np.arange(1.0, n + 1)[None]
    np.testing.assert_allclose(lu.solve(factors, b)[0], np.linalg.solve(A, b[0]), rtol=1e-12)


def test_a_pivot_that_became_small_is_reported_for_that_matrix_only():
    """Full 3 x 3 pattern; in matrix 2 of the batch, the second pivot is ~1e-9 after the first
    elimination step (the matrix is still regular): only that matrix is not ok."""
    rng = np.random.default_rng(10)
    n = 3
    rows, cols = np.nonzero(np.ones((n, n), dtype=bool))
    sample = rng.uniform(1, 2, size=9) * rng.choice([-1, 1], size=9)
    lu = plan(rows, cols, n, sample)
    (r0, c0, *_), (r1, c1, *_) = lu.steps[0], lu.steps[1]
    values = np.tile(sample, (3, 4, 1)) * (1 + 0.01 * rng.uniform(-1, 1, size=(3, 4, 9)))
    bad = (2, 1)
    A = values[bad].reshape(n, n).copy()
    A[r1, c1] = A[r1, c0] * A[r0, c1] / A[r0, c0] + 1e-9
    values[bad] = A.ravel()
    assert abs(np.linalg.det(A)) > 1e-12  # regular, just badly ordered
    factors, ok = lu.factor(values)
    assert ok.shape == (4, 3)
    expected = np.ones((3, 4), bool)
    expected[bad] = False
    np.testing.assert_array_equal(ok.T, expected)
    # the other matrices are solved exactly
    b = rng.normal(size=(3, 4, n))
    x = lu.solve(factors, b)
    want = np.linalg.solve(_dense(rows, cols, n, values), b[..., None])[..., 0]
    good = expected
    np.testing.assert_allclose(x[good], want[good], rtol=1e-10, atol=1e-12)


def test_an_exactly_zero_pivot_is_reported():
    """A pivot with nothing below it is only checked for zero."""
    n = 4
    rows, cols = np.arange(n), np.arange(n)
    sample = np.array([1.0, 2.0, 3.0, 4.0])
    lu = plan(rows, cols, n, sample)
    values = np.tile(sample, (5, 1))
    values[3, 2] = 0.0
    factors, ok = lu.factor(values)
    np.testing.assert_array_equal(ok, [True, True, True, False, True])
    b = np.ones((5, n))
    with np.errstate(divide="ignore"):
        want = b / values
    np.testing.assert_allclose(lu.solve(factors, b)[ok], want[ok], rtol=1e-15)


def test_singular_samples_give_no_plan():
    rng = np.random.default_rng(11)
    n = 6
    # two equal rows: structurally regular, numerically singular
    mask = np.eye(n, dtype=bool)
    mask[0, [1, 3, 4]] = True
    mask[4] = mask[0]
    rows, cols = np.nonzero(mask)
    sample = rng.normal(size=len(rows))
    sample[rows == 4] = sample[rows == 0]
    A = _dense(rows, cols, n, sample)
    assert np.array_equal(A[0], A[4]) and np.linalg.matrix_rank(A) == n - 1
    assert plan(rows, cols, n, sample) is None
    # the same pattern with a regular sample has a plan
    assert plan(rows, cols, n, sample + np.where(rows == 4, 1.0, 0.0)) is not None
    # a column whose entries are all zero in the sample
    rows, cols = _random_pattern(rng, n)
    sample = rng.normal(size=len(rows))
    assert plan(rows, cols, n, sample) is not None
    zeroed = np.where(cols == 2, 0.0, sample)
    assert plan(rows, cols, n, zeroed) is None
    # a column the pattern does not have at all
    keep = cols != 5
    assert plan(rows[keep], cols[keep], n, sample[keep]) is None


@pytest.mark.parametrize("seed", range(4))
def test_constant_entries_fold_to_the_same_factors_and_solutions(seed):
    # a third of the entries the same in every matrix (units, as a revolute joint's, and
    # other values), the rest varying: the code for the entries with the constants folded
    # solves as LAPACK does, and its factors are the general code's, slot by slot
    rng = np.random.default_rng(300 + seed)
    n = 14
    rows, cols = _random_pattern(rng, n)
    base, values = _values(rng, rows, (2, 5))
    pick = rng.choice(len(rows), size=len(rows) // 3, replace=False)
    const = {int(k): float(rng.choice([1.0, -1.0, 2.5, -0.75])) for k in pick}
    for k, v in const.items():
        base[k] = v
        values[..., k] = v
    lu = plan(rows, cols, n, base, const)
    assert lu is not None and lu.raw_factor_fn is not lu.factor_fn
    entry_major = np.ascontiguousarray(values.T)
    general, ok = lu.factor_fn(entry_major)
    folded, ok_folded = lu.raw_factor_fn(entry_major)
    assert ok.all() and ok_folded.all()
    np.testing.assert_allclose(folded, general, rtol=1e-13, atol=1e-15)
    # fewer operations: the folded factorisation is shorter
    assert lu.raw_factor_fn.__code__.co_code != lu.factor_fn.__code__.co_code
    A = _dense(rows, cols, n, values)
    b = rng.normal(size=(2, 5, n))
    x = lu.raw_solve_fn(folded, np.ascontiguousarray(b.T)).T
    np.testing.assert_allclose(x, np.linalg.solve(A, b[..., None])[..., 0], rtol=1e-10,
                               atol=1e-12)
    z = lu.raw_solve_t_fn(folded, np.ascontiguousarray(b.T)).T
    np.testing.assert_allclose(z, np.linalg.solve(np.swapaxes(A, -1, -2), b[..., None])[..., 0],
                               rtol=1e-10, atol=1e-12)
    # the general solves on the folded factors: the same solutions
    np.testing.assert_allclose(lu.solve_fn(folded, np.ascontiguousarray(b.T)).T, x,
                               rtol=1e-12, atol=1e-13)
