"""The steps of a solve that see one state at a time, on Python floats.

The coarse march of the parallel-in-time solver (:func:`mechdsl.solve.levels.coarse_march`)
steps through a few instants one after the other, and the assembly carries a single
mechanism's drives to their values at t0 in a few Newton solves: each is one state, and as
batched numpy calls it costs a microsecond per operation, some hundred per Newton step.
:class:`OneState` runs the same steps on the model's float code
(:mod:`mechdsl.compiled.scalar`): Newton-Raphson, Phi_q dq = -Phi, with the convergence
rules of the batched solver, the factorisation in the generated LU's fixed pivot order
(LAPACK's partial pivoting where a pivot of that order became small), the determinant's sign
from the pivots, and the rates Phi_q qd = nu, Phi_q qdd = gamma. A step the float code
cannot take (a square root of a negative number, an overflow) is not converged: the caller
then does what the batched solver does with a state that failed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from operator import add, neg, sub, truediv

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from ..compiled.lu import THRESHOLD
from ..compiled.scalar import OneState as Code
from .linalg import Factor
from .options import SolverOptions

#: what the float code cannot evaluate (numpy's nan and inf)
FLOAT_ERRORS = (ArithmeticError, ValueError)


def _all_finite(values: list) -> bool:
    """Whether every float of ``values`` is a finite number: fsum is inf or nan where a term
    is (one C call where a generator of isfinite costs ten times more); where it raises
    (a sum that overflows, inf - inf) the terms are checked one by one."""
    try:
        return math.isfinite(math.fsum(values))
    except (OverflowError, ValueError):
        return all(math.isfinite(v) for v in values)


class OneState:
    """Newton, factorisation and rates for the single variant of ``system`` (see the module
    documentation); ``D`` its column scale (n,) (L for lengths, 1 for angles)."""

    def __init__(self, kernels: Kernels, code: Code, D: np.ndarray, opts: SolverOptions) -> None:
        system = kernels.system
        self.system, self.kernels, self.code, self.opts = system, kernels, code, opts
        self.D = [float(d) for d in D]
        self.m, self.n = code.m, code.n
        self.drive_rows = [int(r) for r in system.drive_rows]

    def drives(self, times: np.ndarray, which: tuple[str, ...] = ("f", "fd", "fdd")
               ) -> tuple[list, ...]:
        """f, f', f'' (``which``) of every drive at ``times``: a list per derivative asked
        for, of the drives' lists of values, one per instant."""
        t = np.asarray(times, dtype=float)[None, :]
        if not self.kernels.drive_functions:
            return tuple([] for _ in which)
        # one list per drive (a list per instant costs fifty times more to build)
        return tuple([col.tolist() for col in
                      np.array(eq.drive_values(self.kernels, t, w, t.shape)[0]).T]
                     for w in which)

    def residual(self, x: list, f: list) -> tuple[list, list]:
        """Phi(x, t) (the drives' f(t) given) and Phi_q's entries."""
        c = self.code
        out = c.phi_jac(x, (), 0.0, c.params, c.functions)
        phi = out[: self.m]
        for row, value in zip(self.drive_rows, f):
            phi[row] -= value
        return phi, out[self.m :]

    def _solve_values(self, vals: list, b: list) -> list | None:
        """x with Phi_q x = b, Phi_q from its entries: the fixed-order LU, or LAPACK."""
        fac = self.code.factor(vals, THRESHOLD)
        if fac is not None:
            return self.code.solve(fac, b)
        dense = self.kernels.fused.dense(np.array(vals))
        with np.errstate(all="ignore"):
            try:
                x = np.linalg.solve(dense, np.array(b))
            except np.linalg.LinAlgError:
                return None
        return x.tolist() if np.isfinite(x).all() else None

    def newton(self, x: list, f: list, tol: float) -> tuple[list, bool, int]:
        """Newton-Raphson from ``x`` to the scaled step ``tol`` (or the error left, from the
        quadratic contraction |dq_k|^3 / |dq_(k-1)|^2, below ``newton_error``), abandoned
        where the step stops contracting: :func:`mechdsl.solve.levels.polish` on one state.
        Returns the iterate, whether it converged and the iterations taken."""
        opts, D = self.opts, self.D
        x = list(x)
        prev = math.inf
        it = 0
        try:
            for it in range(1, opts.max_iterations + 1):
                phi, vals = self.residual(x, f)
                dq = self._solve_values(vals, list(map(neg, phi)))
                if dq is None:
                    return x, False, it
                if not math.isfinite(math.fsum(dq)):
                    return x, False, it
                # (map over the builtins: a third of the loop's cost on nine floats)
                step = max(map(abs, map(truediv, dq, D)), default=0.0)
                x = list(map(add, x, dq))
                left = (step**3 / prev**2 if step < 0.25 * prev and prev < math.inf
                        else math.inf)
                if step <= tol or left <= opts.newton_error:
                    return x, True, it
                if it >= 3 and not step <= 0.5 * prev:
                    return x, False, it
                prev = step
        except FLOAT_ERRORS:
            return x, False, it
        return x, False, it

    def sign(self, fac: tuple) -> float:
        """The sign of det Phi_q: the permutations' parity times the pivots' signs."""
        s = self.code.parity
        for k in self.code.pivots:
            p = fac[k]
            s = s if p > 0 else -s if p < 0 else 0.0
        return s

    def rates(self, fac: "OneFactor", x: list, fd: list, fdd: list
              ) -> tuple[list, list] | None:
        """qd and qdd at the solved position ``x``: Phi_q qd = nu, Phi_q qdd = gamma."""
        nu = [0.0] * self.m
        for row, value in zip(self.drive_rows, fd):
            nu[row] = value
        try:
            qd = fac.solve(nu)
            g = self.code.gamma(x, qd, 0.0, self.code.params, self.code.functions)
            for row, value in zip(self.drive_rows, fdd):
                g[row] += value
            qdd = fac.solve(g)
        except FLOAT_ERRORS:
            return None
        if not (_all_finite(qd) and _all_finite(qdd)):
            return None
        return qd, qdd

    def correction_ratio(self, x: list, pred: list, base: list, floor: float) -> float:
        """Newton's correction against the motion from ``base``, scaled by D
        (:func:`mechdsl.solve.newton.correction_ratio` on one state)."""
        # (Python's max() passes over a NaN that is not first: the states must be numbers)
        if not (_all_finite(x) and _all_finite(pred)):
            return math.inf
        D = self.D
        moved = max(max(map(truediv, map(abs, map(sub, x, base)), D), default=0.0),
                    max(map(truediv, map(abs, map(sub, pred, base)), D), default=0.0))
        corr = max(map(truediv, map(abs, map(sub, x, pred)), D), default=0.0)
        return corr / max(moved, floor)

    def factor(self, x: list, exact: bool | None = True) -> "OneFactor | None":
        """Phi_q at ``x`` factorised as :func:`mechdsl.solve.linalg.factor` factorises one
        dense state: A = R Phi_q D (R the reciprocal row norms of Phi_q D) in the fixed-order
        LU, the exact reciprocal 1-norm condition number 1 / (||A||_1 ||A^-1||_1) (A^-1
        from n solves; with ``exact`` False, ||A^-1||_1 estimated from four, as the batched
        generated LU estimates it; with None, not measured: rcond is NaN) and the sign of
        det Phi_q from the pivots. None where the fixed order does not apply or an entry is
        not a number (the caller factorises with LAPACK)."""
        code, D, n = self.code, self.D, self.n
        try:
            out = code.phi_jac(x, (), 0.0, code.params, code.functions)
        except FLOAT_ERRORS:
            return None
        a = [v * D[c] for v, c in zip(out[self.m :], code.cols)]
        r = [0.0] * self.m
        for v, row in zip(a, code.rows):
            r[row] += v * v
        if not _all_finite(r):
            return None
        r = [1.0 / math.sqrt(v) if v > 0 else 1.0 for v in r]
        a = [v * r[row] for v, row in zip(a, code.rows)]
        try:
            fac = code.factor(a, THRESHOLD)
            if fac is None:
                return None
            if exact is None:
                return OneFactor(code, fac, r, D, None, math.nan, self.sign(fac))
        except FLOAT_ERRORS:  # a pivot exactly zero, its column zero below it: no LU
            return None
        col = [0.0] * n  # ||A||_1 from the column sums of |A|
        for v, c in zip(a, code.cols):
            col[c] += abs(v)
        try:
            if exact:
                inverse = []  # the columns of A^-1
                for j in range(n):
                    e = [0.0] * n
                    e[j] = 1.0
                    inverse.append(code.solve(fac, e))
                sums = [math.fsum(abs(v) for v in column) for column in inverse]
                # (Python's max() passes over a NaN that is not first)
                norm_inv = max(sums) if all(math.isfinite(v) for v in sums) else math.nan
            else:
                inverse, norm_inv = None, _inverse_norm1(code, fac, n)
        except FLOAT_ERRORS:  # a pivot exactly zero, its column zero below it: no LU
            return None
        rcond = 1.0 / (max(col) * norm_inv) if norm_inv > 0 else 0.0
        if not (math.isfinite(rcond) and all(math.isfinite(v) for v in col)):
            rcond = 0.0
        return OneFactor(code, fac, r, D, inverse, rcond, self.sign(fac) if rcond > 0 else 0.0)


def _inverse_norm1(code: Code, fac: tuple, n: int) -> float:
    """||A^-1||_1 estimated by one step of Hager's method with Higham's safeguard
    (:meth:`mechdsl.compiled.lu.LUPlan.inverse_norm1` on one matrix); NaN where a solve is
    not finite."""
    x = code.solve(fac, [1.0 / n] * n)
    est = math.fsum(abs(v) for v in x)
    z = code.solve_t(fac, [1.0 if v >= 0 else -1.0 for v in x])
    az = [abs(v) for v in z]
    if not (math.isfinite(est) and all(math.isfinite(v) for v in az)):
        return math.nan
    big = max(az)
    if big > math.fsum(z) / n:  # Hager's test: e_j may give more
        e = [0.0] * n
        e[az.index(big)] = 1.0
        est = max(est, math.fsum(abs(v) for v in code.solve(fac, e)))
    alt = [(1.0 if i % 2 == 0 else -1.0) * (1 + i / max(n - 1, 1)) for i in range(n)]
    last = 2 * math.fsum(abs(v) for v in code.solve(fac, alt)) / (3 * n)
    return max(est, last) if math.isfinite(est) and math.isfinite(last) else math.nan


class OneFactor:
    """Phi_q of one state factorised (:meth:`OneState.factor`): the fixed-order LU of
    A = R Phi_q D, the columns of A^-1, ``rcond`` and ``sign``."""

    def __init__(self, code: Code, fac: tuple, r: list, D: list, inverse: list,
                 rcond: float, sign: float) -> None:
        self.code, self.fac, self.r, self.D = code, fac, r, D
        self.inverse, self.rcond, self.sign = inverse, rcond, sign

    def solve(self, b: list) -> list:
        """Phi_q^-1 b = D A^-1 (R b)."""
        x = self.code.solve(self.fac, [bi * ri for bi, ri in zip(b, self.r)])
        return [xi * di for xi, di in zip(x, self.D)]

    def batched(self) -> Factor:
        """As the batched solver's factorisation of a (1, 1) batch: Phi_q^-1 = D A^-1 R
        (of an exact factorisation)."""
        n, D, r, inv = len(self.D), self.D, self.r, self.inverse
        if inv is None:
            raise ValueError("batched() needs the exact factorisation (factor(x, exact=True))")
        phi_q_inv = np.array([[D[i] * inv[j][i] * r[j] for j in range(n)] for i in range(n)])
        return Factor(phi_q_inv[None, None], np.array([[self.rcond]]),
                      np.array([[self.sign]]))


@dataclass(frozen=True)
class OneStart:
    """A single mechanism as the assembly left it on floats: its drives' f, f', f'' at t0
    (a value per drive) and Phi_q factorised exactly at the assembled configuration."""

    f: list
    fd: list
    fdd: list
    fac: OneFactor


#: coarse_march_one's answer where the float code cannot decide: the batched march decides
UNDECIDED = object()


def coarse_march_one(solver: OneState, start: tuple, sign: float, times: np.ndarray,
                     gap: int, opts: SolverOptions, min_gap: int):
    """:func:`mechdsl.solve.levels.coarse_march` for one variant on floats: the same
    predictor, checks and gap control, the indices reached and the states there as
    (1, c, n) arrays (None where the march gives up), or :data:`UNDECIDED` where a pivot of
    the fixed order became small. Each state is solved to the full tolerance at once (a
    Newton step on floats costs a few microseconds: the loose tolerance and the batched
    polish after it would cost more than they save), and checked for the sign of det Phi_q
    and the correction ratio. Its condition is not estimated here: every instant of the
    window, these included, is settled after, with its condition measured and checked
    (:func:`mechdsl.solve.batch.settle`); a node near a singular position only spoils the
    predictions around it, which those checks then refuse."""
    t = float(start[0])
    q, qd, qdd = (np.asarray(a, dtype=float).tolist() for a in start[1:])
    n = solver.n
    floor = math.sqrt(opts.newton_tol)
    f, fd, fdd = solver.drives(times)
    jerk = [0.0] * n
    reached: list[int] = []
    states: list[tuple[list, list, list]] = []
    at, last = 0, len(times) - 1
    while at < last:
        j = min(at + gap, last)
        tau = float(times[j]) - t
        pred = [q[i] + tau * (qd[i] + tau / 2 * (qdd[i] + tau / 3 * jerk[i])) for i in range(n)]
        x, ok, _ = solver.newton(pred, [c[j] for c in f], opts.newton_tol)
        fac = solver.factor(x, exact=None)
        if fac is None:
            return UNDECIDED
        try:
            ratio = solver.correction_ratio(x, pred, q, floor)
        except FLOAT_ERRORS:
            ratio = math.inf
        if not (ok and fac.sign == sign and ratio <= opts.branch_ratio):
            if (j - at) // 2 < min_gap:
                return None
            gap = (j - at) // 2
            continue
        rates = solver.rates(fac, x, [c[j] for c in fd], [c[j] for c in fdd])
        if rates is None:
            return None
        qd_new, qdd_new = rates
        jerk = [(a - b) / tau for a, b in zip(qdd_new, qdd)]
        jerk = [v if math.isfinite(v) else 0.0 for v in jerk]
        q, qd, qdd, t = x, qd_new, qdd_new, float(times[j])
        states.append((x, qd_new, qdd_new))
        reached.append(j)
        at = j
        if ratio < 0.1 * opts.branch_ratio:
            gap *= 2
    if not states:
        return None
    return (np.array(reached, np.intp),
            tuple(np.array([[s[i] for s in states]]) for i in range(3)))
