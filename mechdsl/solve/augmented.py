"""The leading matrix of the augmented Lagrangian, M + Phi_q^T W Phi_q, assembled and
Cholesky-factorised from the compiled model's fixed sparsity pattern.

For a mechanism whose bodies all have mass and inertia, M is symmetric positive definite and
so is A = M + Phi_q^T W Phi_q for any W = diag(w) > 0, whatever the rank of Phi_q: a
Cholesky factorisation exists at redundant constraints and at singular positions alike.
Its pattern is the union of M's (3 x 3 blocks per body) and of Phi_q^T Phi_q's (the
coordinates two equations share): fixed for a model, so the ordering is chosen once.

Two storages, chosen once per model (:func:`plan`):

* **dense**, for few coordinates (below ``SolverOptions.augmented_band_from``): the
  regularised saddle-point matrix R = [[M, J^T], [J, -W^-1]], whose inverse applies the
  augmented Lagrangian's step (A^-1 inside it: :class:`Factor`), by LAPACK's dense LU
  (dgetrf/dgetrs), the fewest numpy calls per evaluation, which is what a small model's
  evaluation costs;
* **band**: the coordinates in reverse Cuthill-McKee order on the symmetric pattern of A
  (scipy.sparse.csgraph), A stored in LAPACK's lower band storage (kd + 1, n) and factorised
  by dpbtrf/dpbtrs: O(n kd^2) and O(n kd) for a band of half-width kd. A chain or a ladder
  of loops keeps kd a few bodies wide whatever its length, so the cost is linear in the
  number of bodies (measured: tests/test_motion.py and benchmarks/a02_motion.py).

Each entry of A is a sum of one entry of M and products w_r J_rk J_rl of two entries of
the same row r of Phi_q: the plan lists, once, where every such term goes in the storage,
so that assembling A at a state is one ``np.bincount`` (no sparse-matrix arithmetic).

BLAS threads: neither storage makes a call that a multithreaded BLAS spreads over threads
(the band factorisation of a half-width of a few is LAPACK's unblocked code; the dense LU
is of at most about 80 rows), so the machine's other work does not slow it: measured on
this shared two-core machine, one evaluation of A02 (N = 40, 243 coordinates) takes 0.24 ms
with one OpenBLAS thread and 0.20 ms with two (noise), where the dense 485 x 485 LU of the
saddle-point matrix takes 23 ms with one thread and 51 ms with two. No thread limit
(threadpoolctl) is therefore needed here.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class Rows:
    """A sparse matrix's fixed pattern in compressed rows, for its products with vectors:
    ``order`` takes the values, in the caller's order of its entries, to the rows' order.
    The product is scipy's compiled ``csr_matvec`` (3 us for 2400 entries, where
    ``np.bincount`` over them takes 8.5: the augmented Lagrangian forms a dozen such
    products per evaluation), or ``np.bincount`` where scipy has no such function."""

    shape: tuple[int, int]
    indptr: np.ndarray
    indices: np.ndarray
    order: np.ndarray
    #: the row of each entry, in the rows' order (the bincount's)
    rows: np.ndarray
    #: the product by scipy's compiled kernel where scipy has it (else the bincount)
    compiled: bool = True

    @classmethod
    def of(cls, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> "Rows":
        order = np.argsort(rows, kind="stable").astype(np.intp)
        counts = np.bincount(rows, minlength=shape[0])
        indptr = np.concatenate(([0], np.cumsum(counts))).astype(np.intc)
        return cls(shape, indptr, np.asarray(cols, dtype=np.intc)[order], order,
                   np.asarray(rows, dtype=np.intp)[order])

    def times(self, data: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The matrix with ``data`` (in the rows' order) times ``x``."""
        matvec = _csr_matvec() if self.compiled else None
        if matvec is None:
            return np.bincount(self.rows, data * x[self.indices], minlength=self.shape[0])
        y = np.zeros(self.shape[0])
        matvec(self.shape[0], self.shape[1], self.indptr, self.indices, data,
               np.ascontiguousarray(x, dtype=float), y)
        return y


@functools.cache
def _csr_matvec():
    """scipy's compiled kernel behind csr_matrix @ x, without its checks, looked up at the
    first product (a run that forms none, the stiff pendulum's in its joint coordinates,
    never imports scipy.sparse: 25 ms of the process); None where scipy has none."""
    try:
        from scipy.sparse._sparsetools import csr_matvec
    except ImportError:  # pragma: no cover - a scipy without it: the bincount
        return None
    return csr_matvec


@dataclass(frozen=True)
class Plan:
    """Where each term of A = M + Phi_q^T W Phi_q goes, for one model.

    ``mass_at``: the entries of M (of ``Dynamics.rows/cols``) that lie in the stored lower
    triangle; ``k1``, ``k2``, ``pair_row``: the pairs of Phi_q entries (indices into its
    values) of one row whose product lands in the stored triangle. ``perm`` orders the
    coordinates (new i is old perm[i]); ``kd`` is the half-bandwidth, or -1 for the dense
    storage; ``size`` the length of the flat storage."""

    n: int
    m: int
    kd: int
    perm: np.ndarray
    mass_at: np.ndarray
    k1: np.ndarray
    k2: np.ndarray
    pair_row: np.ndarray
    #: the flat index in the storage of each term (M's entries, then the pairs')
    where: np.ndarray
    size: int
    #: the number of Phi_q's entries
    nnz: int
    #: the flat index in the (n + m) x (n + m) saddle-point matrix K = [[M, J^T], [J, 0]]
    #: of each value of [J's entries, J^T's, M's] (the dense storage's K), and of the
    #: multipliers' diagonal (where R = K - [[0, 0], [0, W^-1]] differs from it)
    kkt_at: np.ndarray
    w_diag: np.ndarray
    #: J, J^T and K in compressed rows (the band storage's products); K's ``order`` takes
    #: the entries [J's, J's again, M's] straight to its rows' order
    j_rows: Rows
    jt_rows: Rows
    k_rows_csr: Rows

    @property
    def dense(self) -> bool:
        return self.kd < 0


def _pairs(jac_rows: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ordered pair (k1, k2) of Phi_q entries in the same row (k1 == k2 included), row
    by row, k1 then k2 in the order of the entries (array arithmetic: a Python loop over
    the rows took 48 ms on a chain of 300 links)."""
    order = np.argsort(jac_rows, kind="stable")
    starts = np.searchsorted(jac_rows[order], np.arange(m + 1))
    count = np.diff(starts)[jac_rows[order]]  # the length of each entry's row
    if not count.size:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    k1 = np.repeat(order, count)
    block = np.repeat(np.cumsum(count) - count, count)  # where each entry's pairs begin
    row_start = np.repeat(starts[:-1][jac_rows[order]], count)
    k2 = order[row_start + np.arange(k1.size) - block]
    return k1.astype(np.intp), k2.astype(np.intp)


def plan(n: int, m: int, mass_rows: np.ndarray, mass_cols: np.ndarray,
         jac_rows: np.ndarray, jac_cols: np.ndarray, band_from: int) -> Plan:
    """The storage and ordering of A for a model of n coordinates and m equations: dense
    below ``band_from`` coordinates or where the band would not be narrow (half-width
    above n / 4: a band that wide does no less work than the dense factorisation), else
    the band of the reverse Cuthill-McKee order."""
    k1, k2 = _pairs(jac_rows, m)
    pr, pc = jac_cols[k1], jac_cols[k2]
    rows = np.concatenate((mass_rows, pr, np.arange(n)))
    cols = np.concatenate((mass_cols, pc, np.arange(n)))
    perm = np.arange(n)
    kd = -1
    if n >= band_from:
        # (imported here: a small model's run never needs scipy.sparse, 35 ms of a process)
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import reverse_cuthill_mckee

        pattern = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()
        order = np.asarray(reverse_cuthill_mckee(pattern, symmetric_mode=True), np.intp)
        rank = np.empty(n, np.intp)
        rank[order] = np.arange(n)
        width = int(np.abs(rank[rows] - rank[cols]).max(initial=0))
        if width <= n // 4:
            perm, kd = order, width
    rank = np.empty(n, np.intp)
    rank[perm] = np.arange(n)

    def where(r: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i, j = rank[r], rank[c]
        keep = i >= j  # the lower triangle (what dpotrf and dpbtrf read with lower=1)
        i, j = i[keep], j[keep]
        # both Fortran-ordered: column j holds rows i (dense) or i - j (band)
        flat = j * n + i if kd < 0 else j * (kd + 1) + (i - j)
        return np.flatnonzero(keep), flat.astype(np.intp)

    mass_at, mass_where = where(mass_rows, mass_cols)
    at, pair_where = where(pr, pc)
    size = n * n if kd < 0 else (kd + 1) * n
    big, nnz = n + m, len(jac_rows)
    # K's entries (M's, J^T's, J's) and where each is in [J's, J's again, M's]
    k_csr = Rows.of(np.concatenate((mass_rows, jac_cols, n + jac_rows)),
                    np.concatenate((mass_cols, n + jac_rows, jac_cols)), (big, big))
    kkt_order = np.concatenate((2 * nnz + np.arange(len(mass_rows)), nnz + np.arange(nnz),
                                np.arange(nnz)))
    k_csr = replace(k_csr, order=kkt_order[k_csr.order])
    return Plan(n, m, kd, perm, mass_at, k1[at], k2[at], jac_rows[k1[at]],
                np.concatenate((mass_where, pair_where)), size, nnz,
                np.concatenate(((n + jac_rows) * big + jac_cols, jac_cols * big + n + jac_rows,
                                mass_rows * big + mass_cols)),
                (n + np.arange(m)) * big + n + np.arange(m),
                Rows.of(jac_rows, jac_cols, (m, n)), Rows.of(jac_cols, jac_rows, (n, m)), k_csr)


class Factor:
    """A = M + Phi_q^T W Phi_q at one state, Cholesky-factorised (see the module), with the
    two products the augmented Lagrangian iteration
    (:meth:`mechdsl.solve.motion.Motion.saddle`) needs, on z = [x; lambda] (J = Phi_q):

    * :meth:`kkt`: K z = [M x + J^T lambda; J x], K the saddle-point matrix [[M, J^T],
      [J, 0]];
    * :meth:`step`: the iteration's correction of z for the residual rho = [r; s]:
      dx = A^-1 (r + J^T W s), dlambda = W (J dx - s). (That is R^-1 rho for the
      regularised saddle-point matrix R = [[M, J^T], [J, -W^-1]], whose inverse is
      [[A^-1, A^-1 J^T W], [W J A^-1, W J A^-1 J^T W - W]]: the augmented Lagrangian
      iteration is iterative refinement of K z = [b; c] preconditioned by R^-1.)

    ``entries`` are the values of [Phi_q's entries, Phi_q's entries again, M's entries]
    (the order in which the one-state kernels give them: the entries of K).

    Dense below the plan's band size: there R itself is factorised, by LAPACK's LU
    (dgetrf: R is quasi-definite, hence non-singular wherever A is positive definite), so
    that a correction is one dgetrs and K z one matrix-vector product: for a small model
    the numpy calls' overhead, not their arithmetic, is the cost, and this takes the
    fewest (measured on Andrews' 21 coordinates: the LU of R and one dgetrs per iteration,
    13 us + 2 us, against 25 us + 1.5 us for A's Cholesky and R^-1 formed from it). R's
    factor is only a preconditioner: its rounding (about the penalty times the unit
    round-off, R's condition) slows the contraction a little and does not reach the fixed
    point, which the residuals formed afresh from K decide. Else A is factorised in the
    band storage (dpbtrf) and the products are formed in the fixed patterns
    (:class:`Rows`, O(nnz))."""

    __slots__ = ("plan", "c", "n", "m", "w", "_k", "_piv", "_jd", "_jtd", "_vals", "_solve",
                 "_jabs", "_jtabs")

    def __init__(self, plan: Plan, entries: np.ndarray, w: np.ndarray, lapack: tuple,
                 minus_inverse: np.ndarray) -> None:
        """``minus_inverse``: -1 / w, R's diagonal block (computed once per model)."""
        dgetrf, dgetrs, dpbtrf, dpbtrs = lapack
        self.plan = p = plan
        self.n, self.m, self.w = n, m, w = p.n, p.m, w
        if p.dense:
            big = n + m
            k = np.zeros(big * big)
            k[p.kkt_at] = entries
            r = k.copy()
            r[p.w_diag] = minus_inverse
            self._k = k.reshape(big, big)
            # R is symmetric: its transpose is the Fortran-ordered array LAPACK wants
            c, self._piv, info = dgetrf(r.reshape(big, big).T, overwrite_a=1)
            # (U's diagonal: R is non-singular; a zero pivot is a NaN or an A that is not
            # positive definite)
            self._solve = dgetrs
        else:
            nnz = p.nnz
            jv, mv = entries[:nnz], entries[2 * nnz:]
            vals = np.concatenate((mv[p.mass_at], w[p.pair_row] * jv[p.k1] * jv[p.k2]))
            flat = np.bincount(p.where, vals, minlength=p.size)
            c, info = dpbtrf(flat.reshape((p.kd + 1, n), order="F"), lower=1,
                             overwrite_ab=1)
            self._vals = entries[p.k_rows_csr.order]
            self._jd, self._jtd = jv[p.j_rows.order], jv[p.jt_rows.order]
            self._k = None
            self._solve = dpbtrs
        self._jabs = self._jtabs = None  # |J|, made where a stopping test first needs it
        if info != 0:
            # A is not positive definite: a body without mass or inertia whose motion the
            # constraints do not fix (or a NaN in the state)
            raise np.linalg.LinAlgError("the augmented mass matrix is not positive definite")
        self.c = c

    def kkt(self, z: np.ndarray) -> np.ndarray:
        """K z = [M x + J^T lambda; J x] for z = [x; lambda]."""
        p = self.plan
        if p.dense:
            return self._k @ z
        return p.k_rows_csr.times(self._vals, z)

    def step(self, rho: np.ndarray) -> np.ndarray:
        """The correction [dx; dlambda] = R^-1 rho (the class docstring)."""
        p = self.plan
        if p.dense:
            return self._solve(self.c, self._piv, rho)[0]
        n, w = self.n, self.w
        ws = w * rho[n:]
        b = rho[:n] + p.jt_rows.times(self._jtd, ws)
        dx = np.empty(n)
        dx[p.perm] = self._solve(self.c, b[p.perm], lower=1)[0]
        jd = p.j_rows.times(self._jd, dx)
        return np.concatenate((dx, w * jd - ws))

    def j(self, x: np.ndarray) -> np.ndarray:
        """J x."""
        p = self.plan
        if p.dense:
            return self._k[self.n:, :self.n] @ x
        return p.j_rows.times(self._jd, x)

    def j_abs(self, x: np.ndarray) -> np.ndarray:
        """|J| |x| (entrywise absolute values): the size of the terms that J x sums."""
        p = self.plan
        if self._jabs is None:
            self._jabs = np.abs(self._k[self.n:, :self.n]) if p.dense else np.abs(self._jd)
        if p.dense:
            return self._jabs @ np.abs(x)
        return p.j_rows.times(self._jabs, np.abs(x))

    def jt_abs(self, y: np.ndarray) -> np.ndarray:
        """|J|^T |y| (entrywise absolute values): the size of the terms that J^T y sums."""
        p = self.plan
        if self._jtabs is None:
            self._jtabs = np.abs(self._k[:self.n, self.n:]) if p.dense else np.abs(self._jtd)
        if p.dense:
            return self._jtabs @ np.abs(y)
        return p.jt_rows.times(self._jtabs, np.abs(y))

    def jt(self, y: np.ndarray) -> np.ndarray:
        """J^T y."""
        p = self.plan
        if p.dense:
            return self._k[:self.n, self.n:] @ y
        return p.jt_rows.times(self._jtd, y)

    def m_times(self, x: np.ndarray) -> np.ndarray:
        """M x."""
        return self.kkt(np.concatenate((x, np.zeros(self.m))))[:self.n]
