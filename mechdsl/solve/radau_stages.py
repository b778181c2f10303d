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

import functools

import numpy as np

from .triplets import Triplets

#: The largest system factorised dense (LAPACK's LU with partial pivoting) rather than by
#: SuperLU: for a few bodies the sparse machinery (a CSC matrix built and checked, COLAMD)
#: costs several times the arithmetic; the stiff pendulum's coupled system has 30 unknowns
DENSE_MAX = 120


@functools.cache
def _getrf_getrs(complex_: bool) -> tuple:
    """LAPACK's (z|d)getrf and (z|d)getrs (looked up once: an import statement in the
    constructor cost 5 of its 12 us on the stiff pendulum's 30 unknowns)."""
    from scipy.linalg import lapack  # (lazily: the registry's import stays cheap)
    return (lapack.zgetrf, lapack.zgetrs) if complex_ else (lapack.dgetrf, lapack.dgetrs)


class DenseLU:
    """A dense matrix's LU factors (LAPACK's getrf, real or complex), with SuperLU's
    ``solve(b)`` (getrs). LAPACK is called directly: scipy's ``lu_factor`` and ``lu_solve``
    wrap the same calls in checks that cost more than the arithmetic of the stiff
    pendulum's 11 unknowns."""

    __slots__ = ("lu", "piv", "_getrs")

    def __init__(self, a: np.ndarray) -> None:
        getrf, self._getrs = _getrf_getrs(np.iscomplexobj(a))
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
        #: (M, dQ/dq, dQ/dv, Phi_q) of the three stages stacked dense, for a small system
        self.dense_jacs: tuple | None = None
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
        """The same matrix dense and its LU (:class:`DenseLU`), the nine velocity blocks
        (A^-1_jk / h) M_j - h A_jk dQ/dq_j and the constraint blocks A_jk Phi_q,j each one
        broadcast expression over (j, k) (block by block in Python, the assembly cost more
        than the stiff pendulum's LU); the stage Jacobians kept dense, stacked, for the
        products of :meth:`solve`."""
        n, m, h, A = self.n, self.m, self.h, self.A
        M, Kq, Cv, G = (np.stack([dense(jac[i], shape) for jac in self.jacs])
                        for i, shape in enumerate(((n, n), (n, n), (n, n), (m, n))))
        size = 3 * (n + m)
        K = np.zeros((size, size))
        blocks = (Ainv / h)[:, :, None, None] * M[:, None] \
            - (h * A)[:, :, None, None] * Kq[:, None]  # [j, k]: rows of stage j, cols of k
        stage = np.arange(3)
        blocks[stage, stage] -= Cv
        K[:3 * n, :3 * n] = blocks.transpose(0, 2, 1, 3).reshape(3 * n, 3 * n)
        if m:
            K[3 * n:, :3 * n] = (A[:, :, None, None] * G[:, None]).transpose(
                0, 2, 1, 3).reshape(3 * m, 3 * n)
            for j in range(3):
                K[j * n:(j + 1) * n, 3 * n + j * m:3 * n + (j + 1) * m] = G[j].T
        d = np.arange(3 * n, size)
        K[d, d] = -delta
        self.dense_jacs = (M, Kq, Cv, G)
        self.lu = DenseLU(K)

    def solve(self, r: np.ndarray) -> np.ndarray:
        """dZ (3, 2n + m) from the stage residuals r (3, 2n + m)."""
        n, m, h, A = self.n, self.m, self.h, self.A
        rq, rv, rl = r[:, :n], r[:, n:2 * n], r[:, 2 * n:]
        Arq = A @ rq
        if self.dense_jacs is not None:
            _, Kq, _, G = self.dense_jacs
            Arq3 = Arq[:, :, None]
            top = -rv - h * (Kq @ Arq3)[:, :, 0]
            rhs = np.concatenate((top.ravel(), (rl / h + (G @ Arq3)[:, :, 0]).ravel())) \
                if m else top.ravel()
        else:
            top = [-rv[j] - h * (self.jacs[j][1] @ Arq[j]) for j in range(3)]
            bottom = [rl[j] / h + self.jacs[j][3] @ Arq[j] for j in range(3)] if m else []
            rhs = np.concatenate(top + bottom)
        x = self.lu.solve(rhs)
        dV = x[:3 * n].reshape(3, n)
        dL = x[3 * n:].reshape(3, m)
        return np.hstack((h * (A @ (dV - rq)), dV, dL))
