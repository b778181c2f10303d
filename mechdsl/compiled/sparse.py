"""Sparse Jacobians for large mechanisms: a fixed pattern, values per state, SuperLU.

A joint couples at most a few bodies, so Phi_q of a mechanism of N bodies has O(N) non-zero
entries. Above a size (``SolverOptions.sparse_from`` coordinates) the solver keeps only these
entries, in the pattern fixed at compile time, and factorises each state with SuperLU
(scipy.sparse.linalg.splu, COLAMD column order): memory and time grow about linearly with N
instead of as N^2 and N^3.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .lu import LUPlan


@dataclass(frozen=True)
class Pattern:
    """The non-zero entries of Phi_q: ``rows[k], cols[k]`` of entry k. ``by_row`` sorts them
    row by row, giving Phi_q^T in compressed-column form (``indptr``, ``indices``): SuperLU
    factorises the transpose, whose transposed solve is the faster one in scipy."""

    rows: np.ndarray
    cols: np.ndarray
    shape: tuple[int, int]
    by_row: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    #: memo of the run, filled on first use (both depend only on the pattern): the parity of
    #: SuperLU's permutations already met, permutation bytes -> +1 or -1; and the column
    #: order chosen for SuperLU, under the key "ordering"
    parities: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def from_entries(cls, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]
                     ) -> "Pattern":
        by_row = np.lexsort((cols, rows))
        indptr = np.searchsorted(rows[by_row], np.arange(shape[0] + 1)).astype(np.int32)
        return cls(rows, cols, shape, by_row, indptr, cols[by_row].astype(np.int32))

    def transposed(self, values: np.ndarray):
        """Phi_q^T of one state's ``values`` (nnz,) as a scipy CSC matrix."""
        from scipy.sparse import csc_matrix
        return csc_matrix((values[self.by_row], self.indices, self.indptr),
                          shape=self.shape[::-1])

    @functools.cached_property
    def row_indicator(self) -> np.ndarray:
        """(nnz, m): 1 where entry k lies in row k (row sums of the entries by one matmul)."""
        return _indicator(self.rows, self.shape[0])

    @functools.cached_property
    def col_indicator(self) -> np.ndarray:
        """(nnz, n): 1 where entry k lies in column k."""
        return _indicator(self.cols, self.shape[1])

    def parity(self, perm: np.ndarray) -> float:
        key = perm.tobytes()
        if key not in self.parities:
            self.parities[key] = permutation_sign(perm)
        return self.parities[key]


class TransposedLU:
    """Solves with Phi_q from a SuperLU factorisation of Phi_q^T (``trans='T'``)."""

    def __init__(self, values: np.ndarray, pattern: Pattern) -> None:
        from scipy.sparse.linalg import splu

        a = pattern.transposed(values)
        spec = pattern.parities.get("ordering")
        # rows and columns are already scaled by the caller: no equilibration
        self.lu = splu(a, permc_spec=spec or "COLAMD", options={"Equil": False})
        if spec is None:
            # the file's own order (bodies and joints as declared: mostly along the loops) often
            # fills in less than COLAMD and saves the cost of ordering at every state; kept
            # when its factors are at most 25 % larger
            natural = splu(a, permc_spec="NATURAL", options={"Equil": False})
            size = lambda lu: lu.L.nnz + lu.U.nnz  # noqa: E731
            spec = "NATURAL" if size(natural) <= 1.25 * size(self.lu) else "COLAMD"
            pattern.parities["ordering"] = spec
            if spec == "NATURAL":
                self.lu = natural

    @property
    def n(self) -> int:
        return self.lu.shape[0]

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self.lu.solve(b, trans="T")

    def solve_transposed(self, b: np.ndarray) -> np.ndarray:
        return self.lu.solve(b)


@dataclass(frozen=True)
class SparseJac:
    """Phi_q of a batch of states: ``values`` (..., nnz) in ``pattern``."""

    values: np.ndarray
    pattern: Pattern

    @property
    def shape(self) -> tuple[int, ...]:
        return self.values.shape[:-1] + self.pattern.shape

    def row_norms(self, col_scale: np.ndarray) -> np.ndarray:
        """(..., m): the 2-norm of each row of Phi_q D."""
        p = self.pattern
        sq = (self.values * np.broadcast_to(col_scale, self.values.shape[:-1] + (p.shape[1],))
              [..., p.cols]) ** 2
        out = np.zeros(self.values.shape[:-1] + (p.shape[0],))
        for i in np.ndindex(*self.values.shape[:-1]):
            out[i] = np.bincount(p.rows, sq[i], minlength=p.shape[0])
        return np.sqrt(out)


#: From this many states at once, a square Jacobian is factorised by the model's generated
#: sparse LU (:mod:`mechdsl.compiled.lu`); below, numpy's batched LAPACK calls cost less
#: (each generated operation has a fixed overhead that only a large batch amortises).
LU_BATCH = 64
#: States factorised together at most by the generated LU: its operations pass over one
#: array per entry, and batches of this size keep those arrays in the processor's cache
#: (the sweep of 1000 slider-cranks: 1.8 s at 2^13 states a batch, 2.0 s at 2^12 and at
#: 2^14, 2.8 s at 2^16).
LU_BATCH_STATES = 2**13


@dataclass(frozen=True)
class LUJac:
    """Phi_q of a batch of states as its entries ``values`` (..., nnz) in ``pattern``, to be
    factorised by the generated LU ``lu``."""

    values: np.ndarray
    pattern: Pattern
    lu: "LUPlan"

    @property
    def shape(self) -> tuple[int, ...]:
        return self.values.shape[:-1] + self.pattern.shape

    def dense(self) -> np.ndarray:
        p = self.pattern
        out = np.zeros(self.values.shape[:-1] + (p.shape[0] * p.shape[1],))
        out[..., p.rows * p.shape[1] + p.cols] = self.values
        return out.reshape(self.shape)


def _indicator(index: np.ndarray, size: int) -> np.ndarray:
    out = np.zeros((len(index), size))
    out[np.arange(len(index)), index] = 1.0
    return out


def permutation_sign(perm: np.ndarray) -> float:
    """+1 or -1: the parity of ``perm`` from its number of cycles, found by pointer doubling
    (each index learns the smallest index of its cycle in log2(n) vectorised rounds)."""
    n = len(perm)
    low = np.arange(n)
    hop = np.asarray(perm)
    for _ in range(max(1, int(np.ceil(np.log2(max(n, 2)))) + 1)):
        low = np.minimum(low, low[hop])
        hop = hop[hop]
    cycles = int(np.count_nonzero(low == np.arange(n)))
    return -1.0 if (n - cycles) % 2 else 1.0


def inverse_norm1(lu) -> float:
    """An estimate (a lower bound, exact in most cases) of ||A^-1||_1 from three solves: one
    step of Hager's method from x = (1/n, ..., 1/n), with Higham's alternating vector
    b_i = (-1)^i (1 + i/(n-1)) as a safeguard (Higham 1988, the method of LAPACK's xLACN2)."""
    n = lu.n
    i = np.arange(n)
    alt = (-1.0) ** i * (1 + i / max(n - 1, 1))
    y = lu.solve(np.stack((np.full(n, 1.0 / n), alt), axis=1))
    est = max(float(np.abs(y[:, 0]).sum()), 2 * float(np.abs(y[:, 1]).sum()) / (3 * n))
    z = lu.solve_transposed(np.where(y[:, 0] >= 0, 1.0, -1.0))
    j = int(np.argmax(np.abs(z)))
    if abs(z[j]) > z.sum() / n:  # Hager's test: e_j may give a larger column of A^-1
        e = np.zeros(n)
        e[j] = 1.0
        est = max(est, float(np.abs(lu.solve(e)).sum()))
    return est


def band_of(pattern: Pattern):
    """The band plan of the pattern (:mod:`mechdsl.compiled.band`), found once; None where
    the matrix is not narrow-banded in any order found (SuperLU then)."""
    if "band" not in pattern.parities:
        from .band import band_plan

        m, n = pattern.shape
        pattern.parities["band"] = (band_plan(pattern.rows, pattern.cols, n) if m == n
                                    else None)
    return pattern.parities["band"]


def sparse_lu(values: np.ndarray, pattern: Pattern):
    """The LU of one state: LAPACK's band LU in the compile-time order where the pattern is
    narrow-banded, else SuperLU. Raises RuntimeError where singular."""
    band = band_of(pattern)
    if band is None:
        return TransposedLU(values, pattern)
    from .band import BandLU

    lu = BandLU(band, values)
    if not lu.ok:
        raise RuntimeError("singular")
    return lu


def lu_one(values: np.ndarray, pattern: Pattern, row_scale: np.ndarray,
           col_scale: np.ndarray):
    """Sparse LU of the scaled matrix A = R Phi_q D of one state, with its reciprocal 1-norm
    condition estimate (Higham's estimator of ||A^-1||_1, scipy's onenormest) and the sign of
    det Phi_q. Returns (TransposedLU or None, rcond, sign)."""
    scaled = values * row_scale[pattern.rows] * col_scale[pattern.cols]
    if not np.isfinite(scaled).all():
        return None, 0.0, 0.0
    try:
        lu = sparse_lu(scaled, pattern)
    except RuntimeError:  # exactly singular
        return None, 0.0, 0.0
    n = pattern.shape[0]
    if not isinstance(lu, TransposedLU):  # band
        norm_a = float(np.bincount(pattern.cols, np.abs(scaled), minlength=n).max())
        with np.errstate(all="ignore"):
            rcond = 1.0 / (norm_a * inverse_norm1(lu))
        return (lu, rcond, lu.sign()) if rcond > 0 and np.isfinite(rcond) else (None, 0.0, 0.0)
    diag = lu.lu.U.diagonal()
    if not (np.isfinite(diag).all() and (diag != 0).all()):
        return None, 0.0, 0.0
    # ||A||_1: the largest column sum of |A|
    norm_a = float(np.bincount(pattern.cols, np.abs(scaled), minlength=n).max())
    with np.errstate(all="ignore"):
        rcond = 1.0 / (norm_a * inverse_norm1(lu))
    if not np.isfinite(rcond):
        return None, 0.0, 0.0
    # det(Phi_q) = det(A) / (prod R prod D) with R, D > 0; det(A) = det(A^T) = det(Pr^T L U
    # Pc^T) = sign(Pr) sign(Pc) prod diag U
    sign = (pattern.parity(lu.lu.perm_r) * pattern.parity(lu.lu.perm_c)
            * float(np.prod(np.sign(diag))))
    return lu, rcond, sign
