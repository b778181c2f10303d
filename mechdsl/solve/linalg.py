"""Batched dense linear algebra for the solver: many small systems at once.

The Jacobian of a solved state is factorised once (as the inverse of its scaled form) and
that factorisation serves the velocity solve, the acceleration solve, the condition estimate
and, with the determinant's sign, the detection of singular positions between states.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..compiled.lu import LUPlan
from ..compiled.sparse import LUJac, SparseJac, lu_one, sparse_lu
from .rowwise import absmax, allfinite

def solve(a: np.ndarray | SparseJac, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched a x = b; ``ok`` is False (and x NaN) where a is singular or x not finite.

    With more equations than unknowns (redundant constraints) x is the least-squares
    solution, by QR: exact where the equations are consistent. A sparse ``a`` is solved
    state by state with SuperLU."""
    if isinstance(a, SparseJac):
        return _solve_sparse(a, b)
    if isinstance(a, LUJac):
        return _solve_lu(a, b)
    if a.shape[-2] > a.shape[-1]:
        with np.errstate(all="ignore"):
            qm, r = np.linalg.qr(np.nan_to_num(a))
            a, b = r, np.einsum("...ji,...j->...i", qm, b)
    with np.errstate(all="ignore"):
        try:
            x = np.linalg.solve(a, b[..., None])[..., 0]
        except np.linalg.LinAlgError:  # one singular matrix fails the whole batch
            x = _each(lambda i: np.linalg.solve(a[i], b[i]), b.shape, core=1)
    return x, allfinite(x)


def _solve_lu(a: LUJac, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    f, ok = a.lu.factor(a.values)
    x = a.lu.solve(f, b)
    redo = ~ok.T
    if redo.any():  # a pivot of the fixed order became small: LAPACK's pivoting there
        x[redo] = solve(a.dense()[redo], b[redo])[0]
    return x, allfinite(x)


def _solve_sparse(a: SparseJac, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.full(b.shape[:-1] + (a.pattern.shape[1],), np.nan)
    for i in np.ndindex(*b.shape[:-1]):
        try:
            with np.errstate(all="ignore"):
                x[i] = sparse_lu(a.values[i], a.pattern).solve(b[i])
        except (RuntimeError, ValueError):  # singular, or not finite
            pass
    return x, allfinite(x)


def inverse(a: np.ndarray) -> np.ndarray:
    """Batched inverse; NaN where a matrix is singular."""
    with np.errstate(all="ignore"):
        try:
            return np.linalg.inv(a)
        except np.linalg.LinAlgError:
            return _each(lambda i: np.linalg.inv(a[i]), a.shape, core=2)


def _each(fn, shape: tuple[int, ...], core: int) -> np.ndarray:
    """Call ``fn(index)`` for every batch index of ``shape`` (whose last ``core`` axes belong
    to one result); NaN where it raises LinAlgError."""
    out = np.full(shape, np.nan)
    for i in np.ndindex(*shape[: len(shape) - core]):
        try:
            out[i] = fn(i)
        except np.linalg.LinAlgError:
            pass
    return out


@dataclass(frozen=True)
class GeneratedLU:
    """Factors of the scaled Jacobians A = R Phi_q D of a (V, b) batch by the generated LU:
    ``factors`` (slots, b, V) (:meth:`mechdsl.compiled.lu.LUPlan.factor`'s layout), ``r``
    (V, b, m), ``d`` broadcastable to (V, b, n)."""

    plan: LUPlan
    factors: np.ndarray
    r: np.ndarray
    d: np.ndarray

    def columns(self, cols) -> "GeneratedLU":
        # factors are (slots, b, V): the batch axes reversed
        return GeneratedLU(self.plan, self.factors[:, cols], self.r[:, cols],
                           self.d[:, cols] if self.d.ndim == 3 else self.d)


@dataclass(frozen=True)
class Factor:
    """The factorised Jacobian of a batch of states.

    With column scale D (L for lengths, 1 for angles) and row scale R (1 / norm of each row
    of Phi_q D), A = R Phi_q D is the scaled Jacobian; ``inverse`` is Phi_q^-1 = D A^-1 R,
    ``rcond`` the reciprocal 1-norm condition number of A and ``sign`` the sign of det Phi_q
    (0 where singular). A sparse factorisation keeps, instead of the inverse, one SuperLU
    object per state (``lus``, with R and D), and an estimated condition number.
    """

    inverse: np.ndarray | None
    rcond: np.ndarray
    sign: np.ndarray
    lus: np.ndarray | None = None
    gen: "GeneratedLU | None" = None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """Phi_q^-1 rhs for right-hand sides ``(..., m)``."""
        if self.gen is not None:
            g = self.gen
            return g.d * g.plan.solve(g.factors, g.r * rhs)
        if self.lus is None:
            return np.einsum("...ij,...j->...i", self.inverse, rhs)
        out = np.full(rhs.shape, np.nan)
        for i in np.ndindex(*self.lus.shape):
            item = self.lus[i]
            if item is not None:
                lu, r, d = item
                out[i] = d * lu.solve(r * rhs[i])
        return out

    def columns(self, cols) -> "Factor":
        """The factorisations of the states ``[:, cols]``."""
        return Factor(None if self.inverse is None else self.inverse[:, cols],
                      self.rcond[:, cols], self.sign[:, cols],
                      None if self.lus is None else self.lus[:, cols],
                      None if self.gen is None else self.gen.columns(cols))


def factor(jac: np.ndarray | SparseJac, col_scale: np.ndarray) -> Factor:
    """Factorise ``jac`` (..., m, n) with ``col_scale`` broadcastable to (..., n).

    Square: the inverse, its 1-norm condition and the determinant's sign. With m > n
    (redundant constraints): the pseudo-inverse by SVD, the 2-norm condition (smallest over
    largest singular value), and sign 1 (no determinant). Sparse: SuperLU per state."""
    if isinstance(jac, SparseJac):
        return _factor_sparse(jac, col_scale)
    if isinstance(jac, LUJac):
        return _factor_lu(jac, col_scale)
    # in place where possible: for a sweep these arrays hold millions of entries, and each
    # pass over them costs more than the arithmetic
    with np.errstate(all="ignore"):
        a = jac * col_scale[..., None, :]
        norms = np.sqrt(np.einsum("...ij,...ij->...i", a, a))
        r = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
        a *= r[..., :, None]
    if a.shape[-2] > a.shape[-1]:
        return _factor_redundant(np.nan_to_num(a), r, col_scale)
    with np.errstate(all="ignore"):
        # a NaN or infinite entry makes its row's norm so: no pass over every entry
        if not np.isfinite(norms).all():
            a = np.nan_to_num(a)
        sign = np.linalg.slogdet(a)[0]
        ainv = inverse(a)
        norm_a = np.abs(a, out=a).sum(axis=-2).max(axis=-1)  # a is not needed after this
        norm_inv = np.abs(ainv).sum(axis=-2).max(axis=-1)
        rcond = 1.0 / (norm_a * norm_inv)
    # a Jacobian that is not a number somewhere is singular, whatever its cleaned copy is
    rcond = np.where(np.isfinite(rcond) & np.isfinite(norms).all(axis=-1), rcond, 0.0)
    ainv *= r[..., None, :]
    ainv *= col_scale[..., :, None]
    return Factor(ainv, rcond, np.where(rcond > 0, sign, 0.0))


def _factor_lu(jac: LUJac, col_scale: np.ndarray) -> Factor:
    """:func:`factor` by the generated LU: the scaled entries A = R Phi_q D factorised in the
    fixed order, kept for the solves; ||A^-1||_1 estimated (Hager, Higham) rather than
    formed; the sign from the pivots. A batch where a pivot of the fixed order became small
    is factorised by LAPACK instead."""
    p, lu = jac.pattern, jac.lu
    batch = jac.values.shape[:-1]
    m, n = p.shape
    with np.errstate(all="ignore"):
        d = np.broadcast_to(col_scale, batch + (n,))
        # (the column scale gathered before it is broadcast: a gather over every state of a
        # large batch costs more than the product)
        a = jac.values * np.asarray(col_scale)[..., p.cols]
        norms = np.sqrt((a * a) @ p.row_indicator)  # BLAS, not einsum's loop
        r = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
        a *= r[..., p.rows]
        f, ok = lu.factor(a)
    if not ok.all() or not np.isfinite(a).all():
        return factor(jac.dense(), col_scale)
    with np.errstate(all="ignore"):
        norm_a = absmax(np.abs(a) @ p.col_indicator)
        rcond = _clean(1.0 / (norm_a * lu.inverse_norm1(f)), norms)
    sign = np.where(rcond > 0, lu.sign(f), 0.0)
    return Factor(None, rcond, sign, gen=GeneratedLU(lu, f, r, d))


def _clean(rcond: np.ndarray, norms: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(rcond) & allfinite(norms), rcond, 0.0)


def _factor_sparse(jac: SparseJac, col_scale: np.ndarray) -> Factor:
    batch = jac.values.shape[:-1]
    with np.errstate(all="ignore"):
        norms = jac.row_norms(col_scale)
    r = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
    d = np.broadcast_to(col_scale, batch + (jac.pattern.shape[1],))
    lus = np.empty(batch, dtype=object)
    rcond, sign = np.zeros(batch), np.zeros(batch)
    for i in np.ndindex(*batch):
        lu, rcond[i], sign[i] = lu_one(jac.values[i], jac.pattern, r[i], d[i])
        lus[i] = None if lu is None else (lu, r[i], d[i])
    return Factor(None, rcond, sign, lus)


def _factor_redundant(a: np.ndarray, r: np.ndarray, col_scale: np.ndarray) -> Factor:
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    rcond = s[..., -1] / np.where(s[..., 0] > 0, s[..., 0], 1.0)
    inv_s = np.where(s > 0, 1.0 / np.where(s > 0, s, 1.0), 0.0)
    ainv = np.einsum("...ki,...k,...jk->...ij", vt, inv_s, u)  # V S^-1 U^T
    phi_q_pinv = col_scale[..., :, None] * ainv * r[..., None, :]
    return Factor(phi_q_pinv, rcond, np.ones(rcond.shape))
