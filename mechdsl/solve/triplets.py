"""A sparse matrix as its stored entries, for the one-state evaluations of the dynamics.

The implicit steppers ask the equations of motion for M(q), Phi_q(q) and dQ/dq, dQ/dqd at
every Newton iteration, one state at a time, and use them in two ways only: products with a
vector (the residuals) and their entries (the assembly of an iteration matrix on a pattern
fixed per model). A ``scipy.sparse`` matrix costs 50-100 microseconds to build and check,
more than the generated code that computes its entries (A02, 81 bodies: 3.7 ms of sparse
bookkeeping per Radau iteration against 0.4 ms of arithmetic); :class:`Triplets` costs a
tuple. Products are sums over the entries,

    (A x)_i = sum_{k : rows_k = i} data_k x_{cols_k},

by ``numpy.bincount`` (entries repeated in the pattern add, as in the COO format).
"""

from __future__ import annotations

import numpy as np


class Triplets:
    """The matrix of ``shape`` whose entry (rows[k], cols[k]) is data[k] (repeats add)."""

    __slots__ = ("data", "rows", "cols", "shape")

    def __init__(self, data: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                 shape: tuple[int, int]) -> None:
        self.data, self.rows, self.cols, self.shape = data, rows, cols, shape

    @property
    def T(self) -> "Triplets":  # noqa: N802 - numpy's and scipy's name
        """The transpose (the same entries, rows and columns exchanged)."""
        return Triplets(self.data, self.cols, self.rows, (self.shape[1], self.shape[0]))

    @property
    def nnz(self) -> int:
        """The number of stored entries."""
        return int(self.data.size)

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x)
        if x.ndim == 1:
            if np.iscomplexobj(x):
                return self @ x.real + 1j * (self @ x.imag)
            return np.bincount(self.rows, self.data * x[self.cols], minlength=self.shape[0])
        out = np.zeros((self.shape[0],) + x.shape[1:], dtype=np.result_type(self.data, x))
        np.add.at(out, self.rows, self.data.reshape((-1,) + (1,) * (x.ndim - 1)) * x[self.cols])
        return out

    def toarray(self) -> np.ndarray:
        """The dense matrix (repeated entries add)."""
        rows, cols = self.shape
        flat = np.bincount(self.rows * cols + self.cols, weights=self.data,
                           minlength=rows * cols)
        return flat.reshape(self.shape)

    def tocoo(self):
        """The scipy COO matrix (for the code that factorises)."""
        from scipy.sparse import coo_matrix

        return coo_matrix((self.data, (self.rows, self.cols)), shape=self.shape)

    def tocsr(self):
        """The scipy CSR matrix."""
        return self.tocoo().tocsr()

    def tocsc(self):
        """The scipy CSC matrix."""
        return self.tocoo().tocsc()
