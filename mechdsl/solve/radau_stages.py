"""The coupled stage system of Radau IIA with one Jacobian per stage (for mechdsl.solve.radau).

The transformed simplified Newton of :mod:`mechdsl.solve.radau` shares one iteration matrix
among the three stages. Where a stiff force's direction turns with the bodies (a stiff spring
on a swinging link: the spring's Jacobian k d d^T turns by omega h over a step) no common
matrix is close to all three stages' Jacobians, and the iteration contracts only at the rate
~ omega h^2 sqrt(k / M) / gamma: the step size would shrink like k^-1/4. Here each stage j
has its own Jacobian (M_j, dQ/dq_j, dQ/dv_j, Phi_q,j) at the stage's predicted state, and the
positions are eliminated exactly (Q = q0 + h A (v0 + Z_v) is linear in the velocities): with
the stage residuals r = (r_q, r_v, r_lambda) of the module radau,

    sum_k [A^-1_jk M_j / h - h A_jk dQ/dq_j - delta_jk dQ/dv_j] dV_k + Phi_q,j^T dLambda_j
        = -r_v,j - h dQ/dq_j (A r_q)_j,
    sum_k A_jk Phi_q,j dV_k - delta dLambda_j = r_lambda,j / h + Phi_q,j (A r_q)_j,

dZ_q = h A (dV - r_q): one sparse system of 3 (n + m) unknowns, factorised by SuperLU (its
cost still linear in the number of bodies, about three to five times the transformed pair's).
"""

from __future__ import annotations

import numpy as np

from .triplets import Triplets

#: The largest system factorised dense (LAPACK's LU with partial pivoting) rather than by
#: SuperLU: for a few bodies the sparse machinery (a CSC matrix built and checked, COLAMD)
#: costs several times the arithmetic; the stiff pendulum's coupled system has 30 unknowns
DENSE_MAX = 120


class DenseLU:
    """A dense matrix's LU factors (LAPACK's getrf, real or complex), with SuperLU's
    ``solve(b)`` (getrs). LAPACK is called directly: scipy's ``lu_factor`` and ``lu_solve``
    wrap the same calls in checks that cost more than the arithmetic of the stiff
    pendulum's 11 unknowns."""

    __slots__ = ("lu", "piv", "_getrs")

    def __init__(self, a: np.ndarray) -> None:
        from scipy.linalg import lapack  # (lazily: the registry's import stays cheap)
        getrf, self._getrs = (lapack.zgetrf, lapack.zgetrs) if np.iscomplexobj(a) else \
            (lapack.dgetrf, lapack.dgetrs)
        self.lu, self.piv, info = getrf(a)
        if info < 0:  # pragma: no cover - an argument LAPACK refuses
            raise ValueError(f"getrf: argument {-info} is invalid")
        # (info > 0: a zero pivot, as lu_factor, which warns and goes on: the solve then
        # gives inf or NaN, which the caller's tests catch)

    def solve(self, b: np.ndarray) -> np.ndarray:
        x, info = self._getrs(self.lu, self.piv, b)
        return x


def dense(a: object, shape: tuple[int, int]) -> np.ndarray:
    """``a`` (Triplets, a scipy.sparse matrix or an array) as a dense array of ``shape``."""
    return a.reshape(shape) if isinstance(a, np.ndarray) else a.toarray()


def triplets(a: object, r0: int = 0, c0: int = 0, f: float = 1.0, transpose: bool = False
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows + r0, cols + c0, f values) of the nonzeros of a (or of a^T): a sparse
    matrix's stored entries, a dense array's nonzero ones."""
    import scipy.sparse as sp  # (lazily: the registry's import stays cheap)
    if isinstance(a, Triplets):
        r, c, v = a.rows, a.cols, a.data
    elif sp.issparse(a):
        coo = a.tocoo()
        r, c, v = coo.row, coo.col, coo.data
    else:
        r, c = np.nonzero(a)
        v = a[r, c]
    if transpose:
        r, c = c, r
    return r + r0, c + c0, f * v


class CoupledStages:
    """The factorised coupled stage system for step size h and per-stage Jacobians ``jacs``
    (three tuples (M, dQ/dq, dQ/dv, Phi_q), CSR); ``delta`` the lambda block's regularisation
    (as in the transformed system)."""

    def __init__(self, jacs: list[tuple], h: float, A: np.ndarray, Ainv: np.ndarray,
                 n: int, m: int, delta: float) -> None:
        self.jacs, self.h, self.A, self.n, self.m = jacs, h, A, n, m
        if 3 * (n + m) <= DENSE_MAX:
            self._dense(Ainv, delta)
            return
        import scipy.sparse as sp  # (lazily: the registry's import stays cheap)
        from scipy.sparse.linalg import splu
        parts = []
        for j, (M, Kq, Cv, G) in enumerate(jacs):
            for k in range(3):
                parts.append(triplets(M, j * n, k * n, Ainv[j, k] / h))
                parts.append(triplets(Kq, j * n, k * n, -h * A[j, k]))
                if m:
                    parts.append(triplets(G, 3 * n + j * m, k * n, A[j, k]))
            parts.append(triplets(Cv, j * n, j * n, -1.0))
            if m:
                parts.append(triplets(G, j * n, 3 * n + j * m, 1.0, True))
        d = np.arange(3 * n, 3 * (n + m))
        parts.append((d, d, np.full(d.size, -delta)))
        rows, cols, vals = (np.concatenate([p[i] for p in parts]) for i in range(3))
        size = 3 * (n + m)
        K = sp.csc_matrix((vals, (rows, cols)), shape=(size, size))
        self.lu = splu(K, permc_spec="COLAMD")

    def _dense(self, Ainv: np.ndarray, delta: float) -> None:
        """The same matrix dense, block by block, and its LU (:class:`DenseLU`); the stage
        Jacobians kept dense for the products of :meth:`solve`."""
        n, m, h, A = self.n, self.m, self.h, self.A
        jacs = [(dense(M, (n, n)), dense(Kq, (n, n)), dense(Cv, (n, n)), dense(G, (m, n)))
                for M, Kq, Cv, G in self.jacs]
        K = np.zeros((3 * (n + m), 3 * (n + m)))
        for j, (M, Kq, Cv, G) in enumerate(jacs):
            rows = slice(j * n, (j + 1) * n)
            lam = slice(3 * n + j * m, 3 * n + (j + 1) * m)
            for k in range(3):
                cols = slice(k * n, (k + 1) * n)
                K[rows, cols] = (Ainv[j, k] / h) * M - (h * A[j, k]) * Kq
                K[lam, cols] = A[j, k] * G
            K[rows, rows] -= Cv
            K[rows, lam] = G.T
        d = np.arange(3 * n, 3 * (n + m))
        K[d, d] = -delta
        self.jacs, self.lu = jacs, DenseLU(K)

    def solve(self, r: np.ndarray) -> np.ndarray:
        """dZ (3, 2n + m) from the stage residuals r (3, 2n + m)."""
        n, m, h, A = self.n, self.m, self.h, self.A
        rq, rv, rl = r[:, :n], r[:, n:2 * n], r[:, 2 * n:]
        Arq = A @ rq
        top = [-rv[j] - h * (self.jacs[j][1] @ Arq[j]) for j in range(3)]
        bottom = [rl[j] / h + self.jacs[j][3] @ Arq[j] for j in range(3)] if m else []
        x = self.lu.solve(np.concatenate(top + bottom))
        dV = x[:3 * n].reshape(3, n)
        dL = x[3 * n:].reshape(3, m)
        return np.hstack((h * (A @ (dV - rq)), dV, dL))
