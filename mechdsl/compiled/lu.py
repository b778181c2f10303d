"""A sparse LU of the Jacobian's own pattern, with the pivot order fixed at compile time,
generated as straight-line numpy code over a batch of matrices.

Phi_q of a small mechanism has a few non-zeros per row (the seed's slider-crank: 21 of 81).
Gaussian elimination in a fixed order touches only them (and the fill they create), so it
is a fixed sequence of scalar operations: generated once as Python source, each operation
runs on whole batch arrays (every instant and variant at once). The order is chosen by
Markowitz's criterion with threshold pivoting (a pivot at least ``THRESHOLD`` times the
largest entry of its column among the remaining rows), on a sample Jacobian of the model
(:func:`plan`). At run time a pivot that has become small (below ``THRESHOLD`` times its
column's largest entry, relative) marks the state: the caller falls back to a pivoted dense
factorisation there, so the fixed order never costs accuracy.

The factorisation P A Q = L U also gives the determinant's sign for free: the parities of
the row and column permutations times the signs of U's diagonal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

#: Threshold pivoting: a pivot is at least this fraction of its column's largest entry.
THRESHOLD = 0.1
#: Up to this many coordinates a model gets a generated LU (its pivot search grows like n^2
#: and its code with the fill; a larger mechanism is solved by the band or sparse LU).
MAX_N = 300


def _parity(perm: list[int]) -> float:
    seen = [False] * len(perm)
    sign = 1.0
    for i in range(len(perm)):
        if seen[i]:
            continue
        j, length = i, 0
        while not seen[j]:
            seen[j] = True
            j = perm[j]
            length += 1
        if length % 2 == 0:
            sign = -sign
    return sign


@dataclass(frozen=True)
class LUPlan:
    """A generated LU of an n x n pattern (see the module documentation).

    ``factor(values)`` takes the entries (..., nnz) in the pattern's order and returns the
    factors (..., slots) and a (...,) mask of states whose pivots stayed acceptable;
    ``solve(factors, b)`` solves A x = b for b of shape (..., n);
    ``sign(factors)`` is the sign of det A."""

    n: int
    nnz: int
    slots: int
    pivots: np.ndarray
    parity: float
    factor_fn: Callable
    solve_fn: Callable
    solve_t_fn: Callable
    source: str
    fill: int
    #: the elimination, for other code generators (the compiled backend): per step, (pivot
    #: row, pivot column, [(row below, its multiplier's slot)], {row below: [(slot of U's
    #: entry, slot updated)]}, pivot slot)
    steps: tuple = ()
    #: the back substitution: per step, (pivot row, pivot column, [(U's slot, column)],
    #: pivot slot)
    back: tuple = ()
    #: factor, solve and solve_t for Phi_q's own entries (not scaled), with what the
    #: constant entries determine folded in (:func:`_source`); the functions above where
    #: no entry is constant. Their factors are the same, for either kind of solve.
    raw_factor_fn: Callable | None = None
    raw_solve_fn: Callable | None = None
    raw_solve_t_fn: Callable | None = None

    def factor(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The factors of the matrices with entries ``values`` (..., nnz), entry-major with
        the batch axes reversed ((slots,) + batch[::-1]: ``values.T``'s layout), and the
        mask (batch[::-1]) of those whose pivots stayed acceptable."""
        with np.errstate(all="ignore"):
            # values.T: entry-major (and contiguous, as the model's kernels write them)
            return self.factor_fn(values.T)

    def solve(self, factors: np.ndarray, b: np.ndarray) -> np.ndarray:
        """x with A x = b for b of shape (..., n)."""
        with np.errstate(all="ignore"):
            y = np.array(b.T, dtype=float)  # a contiguous copy: solved in place
            return self.solve_fn(factors, y).T

    def sign(self, factors: np.ndarray) -> np.ndarray:
        """The sign of det A: the permutations' parity times the signs of U's diagonal."""
        return (self.parity * np.prod(np.sign(factors[self.pivots]), axis=0)).T

    def solve_transposed(self, factors: np.ndarray, c: np.ndarray) -> np.ndarray:
        """z with A^T z = c for c of shape (..., n)."""
        with np.errstate(all="ignore"):
            y = np.array(c.T, dtype=float)
            return self.solve_t_fn(factors, y).T

    def inverse_norm1(self, factors: np.ndarray) -> np.ndarray:
        """An estimate (a lower bound, exact in most cases) of ||A^-1||_1 per matrix: one
        step of Hager's method from x = (1/n, ..., 1/n), with Higham's alternating vector
        b_i = (-1)^i (1 + i/(n-1)) as a safeguard (Higham 1988; LAPACK's xLACN2): four
        solves instead of the n of an inverse."""
        n, batch = self.n, factors.shape[1:]
        i = np.arange(n)
        y = np.empty((n, 2) + batch)
        y[:, 0] = 1.0 / n
        y[:, 1] = ((-1.0) ** i * (1 + i / max(n - 1, 1))).reshape((n,) + (1,) * len(batch))
        with np.errstate(all="ignore"):
            x = self.solve_fn(factors[:, None], y)
            est = np.maximum(np.abs(x[:, 0]).sum(axis=0),
                             2 * np.abs(x[:, 1]).sum(axis=0) / (3 * n))
            z = self.solve_t_fn(factors, np.where(x[:, 0] >= 0, 1.0, -1.0))
            az = np.abs(z)
            j = np.argmax(az, axis=0)
            better = az.max(axis=0) > z.sum(axis=0) / n  # Hager's test: e_j may give more
            if better.any():
                e = np.zeros((n,) + batch)
                np.put_along_axis(e, j[None], 1.0, axis=0)
                est = np.where(better, np.maximum(est, np.abs(self.solve_fn(factors, e))
                                                  .sum(axis=0)), est)
        return est.T

    def inverse(self, factors: np.ndarray) -> np.ndarray:
        """A^-1 (..., n, n), from n right-hand sides solved at once."""
        batch = factors.shape[1:]
        y = np.empty((self.n, self.n) + batch)
        y[...] = np.eye(self.n).reshape((self.n, self.n) + (1,) * len(batch))
        with np.errstate(all="ignore"):
            x = self.solve_fn(factors[:, None], y)  # x[j, k] = (A^-1)[j, k], batch reversed
        return x.T.swapaxes(-1, -2)


def plan(rows: np.ndarray, cols: np.ndarray, n: int, sample: np.ndarray,
         constants: dict[int, float] | None = None) -> LUPlan | None:
    """Choose the pivot order on ``sample`` (nnz,) and generate the code; None where the
    sample is singular in the pattern (no acceptable pivot is left). ``constants`` maps the
    entries that are the same in every matrix (a revolute joint's -1 and 1) to their
    values: the code folds what they determine (see :func:`_source`)."""
    rows = [int(r) for r in rows]
    cols = [int(c) for c in cols]
    nnz = len(rows)
    # the working matrix: (row, col) -> slot; each slot is one array of the generated code
    slot: dict[tuple[int, int], int] = {(r, c): k for k, (r, c) in enumerate(zip(rows, cols))}
    val: dict[tuple[int, int], float] = {(r, c): float(v) for r, c, v in
                                         zip(rows, cols, np.asarray(sample, dtype=float))}
    by_row: dict[int, set[int]] = {i: set() for i in range(n)}
    by_col: dict[int, set[int]] = {j: set() for j in range(n)}
    for r, c in slot:
        by_row[r].add(c)
        by_col[c].add(r)
    free_rows, free_cols = set(range(n)), set(range(n))
    order_rows: list[int] = []
    order_cols: list[int] = []
    steps: list[tuple] = []  # (pivot row, pivot column, below, right, pivot slot)
    next_slot = nnz
    pivot_slots: list[int] = []
    for _ in range(n):
        best = None
        for j in free_cols:
            col_rows = [i for i in by_col[j] if i in free_rows]
            if not col_rows:
                continue
            big = max(abs(val[(i, j)]) for i in col_rows)
            if big == 0.0:
                continue
            cj = len(col_rows) - 1
            for i in col_rows:
                a = abs(val[(i, j)])
                if a < THRESHOLD * big:
                    continue
                ri = sum(1 for c in by_row[i] if c in free_cols) - 1
                key = (ri * cj, -a / big, i, j)
                if best is None or key < best[0]:
                    best = (key, i, j)
        if best is None:
            return None
        _, pr, pc = best
        free_rows.discard(pr)
        free_cols.discard(pc)
        order_rows.append(pr)
        order_cols.append(pc)
        p_slot = slot[(pr, pc)]
        pivot_slots.append(p_slot)
        below = sorted(i for i in by_col[pc] if i in free_rows)
        right = sorted(c for c in by_row[pr] if c in free_cols)
        for i in below:
            l_slot = slot[(i, pc)]
            l_val = val[(i, pc)] / val[(pr, pc)] if val[(pr, pc)] != 0 else 0.0
            val[(i, pc)] = l_val
            for c in right:
                if (i, c) in slot:
                    val[(i, c)] -= l_val * val[(pr, c)]
                else:  # fill
                    slot[(i, c)] = next_slot
                    next_slot += 1
                    by_row[i].add(c)
                    by_col[c].add(i)
                    val[(i, c)] = -l_val * val[(pr, c)]
        steps.append((pr, pc, [(i, slot[(i, pc)]) for i in below],
                      {i: [(slot[(pr, c)], slot[(i, c)]) for c in right] for i in below},
                      p_slot))
    slots = next_slot
    source = _source(steps, n, nnz, slots, order_cols, by_row, slot, {})
    ns = _compiled(source, "lu")
    # (a constant that is not a number stays in the arrays: the code reads it there)
    fixed = {int(k): float(v) for k, v in (constants or {}).items() if np.isfinite(v)}
    raw = ns
    if fixed:
        raw = _compiled(_source(steps, n, nnz, slots, order_cols, by_row, slot, fixed),
                        "lu of the entries")
    back = []
    for k, (pr, pc, below, right, p_slot) in enumerate(steps):
        later = set(order_cols[k + 1 :])
        back.append((pr, pc, [(slot[(pr, c)], c) for c in sorted(by_row[pr] & later)], p_slot))
    parity = _parity(order_rows) * _parity(order_cols)
    return LUPlan(n, nnz, slots, np.array(pivot_slots, dtype=np.intp), parity, ns["factor"],
                  ns["solve"], ns["solve_t"], source, slots - nnz, tuple(steps), tuple(back),
                  raw["factor"], raw["solve"], raw["solve_t"])


def _compiled(source: str, name: str) -> dict:
    """The generated ``source`` run in a namespace of the numpy functions it calls."""
    ns = {"empty": np.empty, "ones": np.ones, "maximum": np.maximum, "absolute": np.absolute,
          "divide": np.divide, "multiply": np.multiply, "subtract": np.subtract, "add": np.add,
          "negative": np.negative, "copyto": np.copyto}
    exec(compile(source, f"<mechdsl generated {name}>", "exec"), ns)  # noqa: S102 - generated
    return ns


class _Folding:
    """The values of the factor slots known when the code is generated: the constant
    entries, and what elimination computes from constants alone. ``val(k)`` is slot k as
    the generated code reads it (its value written out, or ``F[k]``)."""

    def __init__(self, fixed: dict[int, float], nnz: int, slots: int) -> None:
        self.known = dict(fixed)
        self.known.update({k: 0.0 for k in range(nnz, slots)})  # fill starts at zero
        #: known slots whose value differs from what the array holds (folded updates)
        self.stale: set[int] = set()

    def val(self, k: int) -> str:
        return repr(self.known[k]) if k in self.known else f"F[{k}]"

    def forget(self, k: int, out: list[str]) -> None:
        """Slot k is about to be computed at run time: the array must hold its value."""
        if k in self.known:
            if k in self.stale:
                out.append(f"    F[{k}] = {self.known[k]!r}")
            del self.known[k]
            self.stale.discard(k)

    def set(self, k: int, value: float) -> None:
        self.known[k] = value
        self.stale.add(k)


def _times(row: str, factor: str, target: str, out: list[str]) -> None:
    """``target -= factor * row`` with ``factor`` a value written out or an array: one
    operation for a unit factor, none for zero, else two."""
    try:
        f = float(factor)
    except ValueError:
        f = None
    if f == 0.0:
        return
    if f is not None and abs(f) == 1.0:
        op = "subtract" if f > 0 else "add"
        out.append(f"    {op}({target}, {row}, out={target})")
        return
    out.append(f"    multiply({factor}, {row}, out=tmp)")
    out.append(f"    subtract({target}, tmp, out={target})")


def _divide(num: str, pivot: str, target: str, out: list[str]) -> None:
    """``target = num / pivot``: a copy or a negation for a unit pivot written out."""
    if pivot in ("1.0", "-1.0"):
        if pivot == "1.0":
            if num != target:
                out.append(f"    copyto({target}, {num})")
        else:
            out.append(f"    negative({num}, out={target})")
        return
    out.append(f"    divide({num}, {pivot}, out={target})")


def _source(steps: list, n: int, nnz: int, slots: int, order_cols: list[int],
            by_row: dict, slot: dict, fixed: dict[int, float]) -> str:
    """The generated factor, solve and solve_t. They work on entry-major arrays (one
    contiguous row of the batch per entry) and in place: each operation is one ufunc call
    writing into existing memory. Where entries are constant (``fixed``), what elimination
    computes from them alone is computed here, a pivot test on constants is passed (the plan
    chose that pivot on the same values), and a product with a unit factor is an addition:
    the slider-crank's factorisation makes 7 calls instead of 20. The factors hold every
    slot's value all the same, so that the general solves work on them too."""
    fold = _Folding(fixed, nnz, slots)
    src = ["def factor(At):",
           f"    F = empty(({slots},) + At.shape[1:])",
           f"    F[:{nnz}] = At"]
    if slots > nnz:
        src.append(f"    F[{nnz}:] = 0.0")
    src += ["    tmp = empty(At.shape[1:])", "    ok = ones(At.shape[1:], bool)"]
    for pr, pc, below, right, p_slot in steps:
        if all(k in fold.known for k in [p_slot] + [l for _, l in below]):
            pass  # the test on constants: the plan chose this pivot on these values
        elif below:
            terms = [f"absolute(F[{l}])" for _, l in below if l not in fold.known]
            big = (f"maximum.reduce(({', '.join(terms)},))" if len(terms) > 1
                   else terms[0] if terms else "")
            known = [abs(fold.known[l]) for _, l in below if l in fold.known]
            if known:  # the largest constant below, written out
                big = f"maximum({big}, {max(known)!r})" if big else repr(max(known))
            pivot = (repr(abs(fold.known[p_slot])) if p_slot in fold.known
                     else f"absolute(F[{p_slot}])")
            src.append(f"    ok &= {pivot} >= {THRESHOLD!r} * {big}")
        else:
            src.append(f"    ok &= {fold.val(p_slot)} != 0")
        for i, l in below:
            if l in fold.known and p_slot in fold.known:
                fold.set(l, fold.known[l] / fold.known[p_slot])
            else:
                fold.forget(l, src)
                _divide(f"F[{l}]", fold.val(p_slot), f"F[{l}]", src)
            for u, t in right[i]:
                if l in fold.known and u in fold.known:
                    product = fold.known[l] * fold.known[u]
                    if t in fold.known:
                        fold.set(t, fold.known[t] - product)
                    elif product != 0.0:
                        src.append(f"    subtract(F[{t}], {product!r}, out=F[{t}])")
                    continue
                fold.forget(t, src)
                if l in fold.known:
                    _times(f"F[{u}]", fold.val(l), f"F[{t}]", src)
                elif u in fold.known:
                    _times(f"F[{l}]", fold.val(u), f"F[{t}]", src)
                else:
                    src.append(f"    multiply(F[{l}], F[{u}], out=tmp)")
                    src.append(f"    subtract(F[{t}], tmp, out=F[{t}])")
    for k in sorted(fold.stale):  # the factors hold every slot's value (the sign reads
        src.append(f"    F[{k}] = {fold.known[k]!r}")  # the pivots, other solves the rest)
    src.append("    return F, ok")
    solve = ["def solve(F, Y):",
             "    tmp = empty(Y.shape[1:])",
             "    X = empty(Y.shape)"]
    for pr, pc, below, right, p_slot in steps:
        for i, l in below:
            _times(f"Y[{pr}]", fold.val(l), f"Y[{i}]", solve)
    for k in reversed(range(n)):
        pr, pc, below, right, p_slot = steps[k]
        later = set(order_cols[k + 1 :])
        for c in sorted(by_row[pr] & later):
            _times(f"X[{c}]", fold.val(slot[(pr, c)]), f"Y[{pr}]", solve)
        _divide(f"Y[{pr}]", fold.val(p_slot), f"X[{pc}]", solve)
    solve.append("    return X")
    # the transposed solve A^T z = c (for the condition estimate): A = E^-1 U with E the
    # elimination's row operations, so U^T w = c forward in pivot order, then z = E^T w
    tsolve = ["def solve_t(F, C):", "    tmp = empty(C.shape[1:])", "    W = empty(C.shape)"]
    for k, (pr, pc, below, right, p_slot) in enumerate(steps):
        _divide(f"C[{pc}]", fold.val(p_slot), f"W[{pr}]", tsolve)
        later = set(order_cols[k + 1 :])
        for c in sorted(by_row[pr] & later):
            _times(f"W[{pr}]", fold.val(slot[(pr, c)]), f"C[{c}]", tsolve)
    for pr, pc, below, right, p_slot in reversed(steps):
        for i, l in below:
            _times(f"W[{i}]", fold.val(l), f"W[{pr}]", tsolve)
    tsolve.append("    return W")
    return "\n\n".join("\n".join(x) for x in (src, solve, tsolve)) + "\n"


def scalar_lines(lu: LUPlan, a, y, x, c, w, fail: str, recip=None) -> tuple[list, list, list]:
    """The plan's factorisation and solves as scalar statements (for code on one state: the
    float code of :mod:`mechdsl.compiled.scalar`, the compiled backend's march), with the
    names each caller gives: ``a(k)`` the factor in slot k, ``y(i)``, ``x(i)`` the right-hand
    side and the solution of A x = y, ``c(i)``, ``w(i)`` those of A^T w = c (the right-hand
    sides are overwritten); ``fail`` the statement where a pivot of the fixed order became
    small; ``recip(k)``, where given, the place where the factorisation keeps 1 / pivot of
    the pivot in slot k, so that the solves multiply by it (a division costs three to four
    multiplications' time on the solves' chains of dependent operations; the result differs
    by one rounding at most). Returns the bodies (one statement per line, unindented) of
    factor, solve and solve_t."""

    def over(value: str, slot: int) -> str:
        return f"{value} * {recip(slot)}" if recip else f"{value} / {a(slot)}"

    factor = []
    for pr, pc, below, right, p_slot in lu.steps:
        if below:
            terms = [f"abs({a(l)})" for _, l in below]
            big = f"max({', '.join(terms)})" if len(terms) > 1 else terms[0]
            factor.append(f"if not abs({a(p_slot)}) >= threshold * {big}:")
        else:
            factor.append(f"if not {a(p_slot)} != 0.0:")
        factor.append(f"    {fail}")
        if recip:
            factor.append(f"{recip(p_slot)} = 1.0 / {a(p_slot)}")
        for i, l in below:
            factor.append(f"{a(l)} = {over(a(l), p_slot)}")
            for u, t in right[i]:
                factor.append(f"{a(t)} = {a(t)} - {a(l)} * {a(u)}")
    solve = []
    for pr, pc, below, right, p_slot in lu.steps:
        for i, l in below:
            solve.append(f"{y(i)} = {y(i)} - {a(l)} * {y(pr)}")
    for pr, pc, terms, p_slot in reversed(lu.back):
        rest = "".join(f" - {a(u)} * {x(col)}" for u, col in terms)
        solve.append(f"{x(pc)} = {over(f'({y(pr)}{rest})', p_slot)}")
    solve_t = []
    for pr, pc, terms, p_slot in lu.back:
        solve_t.append(f"{w(pr)} = {over(c(pc), p_slot)}")
        for u, col in terms:
            solve_t.append(f"{c(col)} = {c(col)} - {a(u)} * {w(pr)}")
    for pr, pc, below, right, p_slot in reversed(lu.steps):
        for i, l in below:
            solve_t.append(f"{w(pr)} = {w(pr)} - {a(l)} * {w(i)}")
    return factor, solve, solve_t
