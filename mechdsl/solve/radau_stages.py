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
        import scipy.sparse as sp  # (lazily: the registry's import stays cheap)
        from scipy.sparse.linalg import splu
        self.jacs, self.h, self.A, self.n, self.m = jacs, h, A, n, m
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
