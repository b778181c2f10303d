"""Before the run: the assembly at t0, in the assembly mode nearest the guesses."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from ..compiled.lu import THRESHOLD
from ..compiled.sparse import SparseJac
from ..compiled.system import System
from .diagnose import (
    DENSE_ANALYSIS_MAX, col_scale, constraint_names, jacobian_defects, variant_label,
)
from .linalg import factor
from .mobility import Mobility, analyse, count_check, hidden_freedom, square
from .newton import correction_ratio, newton, use_sparse
from .options import SolverOptions
from .single import FLOAT_ERRORS, OneStart, OneState


@dataclass(frozen=True)
class Assembly:
    """The configuration at t0 of every variant (``ok[v]`` False where it was not found, with
    the reasons in ``messages``) and the mobility analysis that says which equations to use
    (None if no variant's joints could be closed). ``start``: for a single mechanism
    assembled on floats, the drives at t0 and Phi_q factorised at ``q`` (the first instant
    takes them over); else None."""

    q: np.ndarray
    ok: np.ndarray
    messages: tuple[str, ...]
    iterations: int
    mobility: Mobility | None
    start: OneStart | None = None


def _lm_step(a: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The Levenberg-Marquardt step dz = -(a^T a + lam I)^-1 a^T r with lam = |r|^2
    (Yamashita and Fukushima). As r -> 0 it becomes the Gauss-Newton step, and it
    converges quadratically even where the solutions are not isolated (redundant joints,
    a mechanism with free coordinates), where a plain minimum-norm step would divide noise
    by a vanishing singular value and creep along the solution set. By
    :func:`_cholesky_step` where every state's system looks well conditioned, else every
    state by SVD."""
    a = np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)
    if a.ndim > 2 and np.isfinite(r).all():
        step = _cholesky_step(a, r)
        if step is not None:
            return step
    return _lm_step_svd(a, r)


def _cholesky_step(a: np.ndarray, r: np.ndarray) -> np.ndarray | None:
    """:func:`_lm_step` of one state (``a`` (k, n), ``r`` (k,)) or of a batch (``a``
    (..., k, n)) through the identity (a^T a + lam I)^-1 a^T = a^T (a a^T + lam I)^-1: the
    Cholesky factorisation of the k x k matrix G = a a^T + lam I, six times cheaper than
    the SVD. None for more rows than columns, and where some G does not look well
    conditioned (its factor's diagonal spans more than 1e5, so cond(G) >= 1e10: rows
    redundant or nearly so, a singular position; a heuristic, as a factor's diagonal can
    look tame on a worse matrix, where the step is only less accurate and the line search
    and the next iterations correct it): the SVD decides there."""
    if a.shape[-2] > a.shape[-1]:
        return None
    g = a @ np.swapaxes(a, -1, -2)
    np.einsum("...ii->...i", g)[...] += np.sum(r * r, axis=-1, keepdims=True)  # + lam I
    try:
        d = np.einsum("...ii->...i", np.linalg.cholesky(g))
    except np.linalg.LinAlgError:  # some G is not positive definite
        return None
    if not (d.min(axis=-1) > 1e-5 * d.max(axis=-1)).all():
        return None
    return -(np.swapaxes(a, -1, -2) @ np.linalg.solve(g, r[..., None]))[..., 0]


def _lm_step_svd(a: np.ndarray, r: np.ndarray) -> np.ndarray:
    """:func:`_lm_step` by SVD (``a`` without NaN)."""
    lam = np.sum(r * r, axis=-1, keepdims=True)
    try:
        u, s, vt = np.linalg.svd(a, full_matrices=False)
    except np.linalg.LinAlgError:  # rare: fall back to one variant at a time
        out = np.zeros(a.shape[:-2] + a.shape[-1:])
        for i in np.ndindex(*a.shape[:-2]):
            try:
                out[i] = -np.linalg.lstsq(a[i], r[i], rcond=1e-12)[0]
            except np.linalg.LinAlgError:
                pass
        return out
    keep = s > s[..., :1] * 1e-14
    gain = np.where(keep, s / np.where(keep, s * s + lam, 1.0), 0.0)
    return -np.einsum("...ji,...j,...j->...i", vt, gain, np.einsum("...ji,...j->...i", u, r))


def _lm_step_one(a: np.ndarray, r: np.ndarray) -> np.ndarray:
    """:func:`_lm_step` for one state (``a`` (k, n), ``r`` (k,)), without a batch's
    overhead: :func:`_cholesky_step` where its entries are numbers and it applies, else
    the SVD."""
    if np.isfinite(a).all() and np.isfinite(r).all():
        step = _cholesky_step(a, r)
        if step is not None:
            return step
    return _lm_step_svd(np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)[None], r[None])[0]


def assemble(kernels: Kernels, t0: float, options: SolverOptions | None = None,
             compiled: bool = False) -> Assembly:
    """Find q with Phi(q, t0) = 0 in the assembly mode nearest the guesses.

    1. The joints alone, by damped Gauss-Newton from the guesses (see :func:`_gauss_newton`):
       with the drives left out the system is under-determined, and minimum-norm steps keep
       the configuration nearest the guess.
    2. The drives, by continuation from the values g(q1) they have there to f(t0): Newton on
       Phi(q, t0) + (1 - s)(f(t0) - g(q1)) = 0 for s from 0 to 1, each step started from the
       tangent Phi_q dq/ds = f(t0) - g(q1), shortened when Newton struggles, refused where the
       Jacobian turns singular or changes sign (the path would cross a dead point and could
       come out in another assembly mode).
    3. Where that fails, Gauss-Newton on all equations at once, as a last resort.

    ``compiled``: the run marches on the compiled backend, which then carries a single
    mechanism's drives too (where the model compiles).
    """
    system = kernels.system
    opts = options or SolverOptions()
    count_check(system)
    V, n = system.n_variants, system.n
    D = col_scale(system)
    t = np.full((V, 1), float(t0))
    joint_rows = system.joint_rows
    guess = system.guess.reshape(V, 1, n)
    q1, ok1, it1 = gauss_newton(kernels, guess, t, D, joint_rows, opts)
    mob, start = None, None
    q, ok, it2 = q1, ok1 & False, 0
    if ok1.any():
        first = int(np.flatnonzero(ok1)[0])
        if system.m > n:
            # more equations than coordinates: find the redundant ones before going on
            mob = analyse(kernels.variant(first), q1[first, 0], D[first, 0])
        else:
            if kernels.dynamics is not None and system.m == n and n <= DENSE_ANALYSIS_MAX:
                hidden_freedom(kernels.variant(first), q1[first, 0], D[first, 0])
            mob = square(system)
        q, ok, it2, start = _continue_drives(kernels, q1, t, D, ok1, opts, mob.rows, compiled)
        retry = ok1 & ~ok
        if retry.any():
            q2, ok2, it3 = gauss_newton(kernels, q1, t, D, mob.rows, opts)
            q = np.where((retry & ok2)[:, None, None], q2, q)
            ok = ok | (retry & ok2)
            it2 += it3
    messages = []
    reported: set[int] = set()
    if ok.all() and (mob is None or not mob.dropped.size):
        # nothing to check or to report
        return Assembly(q[:, 0], ok, (), it1 + it2, mob, start)
    with np.errstate(all="ignore"):
        phi = eq.constraint_values(kernels, np.where(ok1[:, None, None], q, q1), t)[:, 0]
        weights = _row_weights(kernels, q, D, opts)[:, 0]
    if mob is not None and mob.dropped.size:
        # least squares settles for a compromise where redundant equations are inconsistent:
        # every equation must hold
        resid = np.abs(weights * phi)
        for v in np.flatnonzero(ok & ~(resid <= opts.assembly_residual).all(axis=1)):
            ok[v] = False
            reported.add(int(v))
            worst = np.argsort(-resid[v])[:3]
            messages.append(
                f"the mechanism is over-constrained{variant_label(system, v)}: its redundant "
                f"constraints ({constraint_names(system, mob.dropped)}) cannot hold together "
                f"with the others; equations of {constraint_names(system, worst)} are violated "
                f"(scaled residual {resid[v].max():.3g}); remove them or make the dimensions "
                "consistent")
    for v in np.flatnonzero(~ok):
        if v in reported:
            continue
        rows = joint_rows if not ok1[v] else np.arange(system.m)
        resid = np.nan_to_num(np.abs(weights[v, rows] * phi[v, rows]), nan=np.inf)
        worst = rows[np.argsort(-resid)[:3]]
        over = system.m > n and not ok1[v]
        what = ("the joints cannot be closed near the guesses" if not ok1[v] else
                "the drives cannot reach their values at t0 from the guessed configuration")
        if over:
            what += (f" ({len(joint_rows)} joint equations for {n} coordinates: they may "
                     "over-constrain the mechanism)")
        closest = np.where(ok1[v], q[v, 0], q1[v, 0])
        defects = jacobian_defects(kernels, closest, float(t0), int(v))
        if defects:
            messages.append(f"the mechanism cannot be assembled at t = {t0:g}"
                            f"{variant_label(system, v)}: {defects}")
            continue
        messages.append(
            f"the mechanism cannot be assembled at t = {t0:g}{variant_label(system, v)}: "
            f"{what}; the closest configuration found leaves equations of "
            f"{constraint_names(system, worst)} unsatisfied (scaled residual "
            f"{resid.max():.3g}); check the dimensions, or give guesses nearer the intended "
            "configuration")
    return Assembly(q[:, 0], ok, tuple(messages), it1 + it2, mob)


def _large(system: System, opts: SolverOptions) -> bool:
    """Whether the assembly works on sparse Jacobians (see SolverOptions.sparse_from)."""
    return system.pattern is not None and system.n >= opts.sparse_from


def _lm_step_sparse(jac: SparseJac, rows: np.ndarray, D: np.ndarray, W: np.ndarray,
                    r: np.ndarray) -> np.ndarray:
    """The step of :func:`_lm_step` for a large sparse Jacobian, through the identity
    (A^T A + lam I)^-1 A^T = A^T (A A^T + lam I)^-1 with A = W Phi_q D: one sparse LU of the
    m x m matrix A A^T + lam I (lam floored at 1e-14 of its diagonal, for redundant rows)."""
    from scipy.sparse import csr_matrix, identity
    from scipy.sparse.linalg import splu

    p = jac.pattern
    where = np.full(p.shape[0], -1)
    where[rows] = np.arange(len(rows))
    sel = where[p.rows] >= 0
    ri, ci = where[p.rows[sel]], p.cols[sel]
    D = np.broadcast_to(D, r.shape[:-1] + (p.shape[1],))
    out = np.zeros(r.shape[:-1] + (p.shape[1],))
    for i in np.ndindex(*r.shape[:-1]):
        vals = np.nan_to_num(jac.values[i][sel] * W[i][ri] * D[i][ci])
        a = csr_matrix((vals, (ri, ci)), shape=(len(rows), p.shape[1]))
        m = (a @ a.T).tocsc()
        lam = float(r[i] @ r[i]) + 1e-14 * max(float(m.diagonal().max(initial=0.0)), 1.0)
        try:
            out[i] = -(a.T @ splu(m + lam * identity(len(rows), format="csc")).solve(r[i]))
        except RuntimeError:
            pass
    return out


def _row_weights(kernels: Kernels, q: np.ndarray, D: np.ndarray,
                 opts: SolverOptions) -> np.ndarray:
    """1 / norm of each row of Phi_q D (1 for an empty row): makes equations comparable."""
    system = kernels.system
    with np.errstate(all="ignore"):
        if _large(system, opts):
            norms = np.nan_to_num(eq.jacobian_values(kernels, q).row_norms(D))
        else:
            norms = np.linalg.norm(np.nan_to_num(eq.jacobian(kernels, q) * D[..., None, :]),
                                   axis=-1)
    return np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)


#: Phi(q, t) (m,) and Phi_q (m, n) of one state at a fixed t, from q as a list of floats
OneEquations = Callable[[list], tuple[np.ndarray, np.ndarray]]


def gauss_newton(kernels: Kernels, q: np.ndarray, t: np.ndarray, D: np.ndarray,
                 rows: np.ndarray, opts: SolverOptions, one: OneEquations | None = None
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """Damped Gauss-Newton on the equations ``rows`` from ``q`` (V, 1, n).

    With W the row weights at the start, each step solves min || W (Phi + Phi_q D dz) || in
    the least-squares, minimum-norm sense (SVD) and is halved until || W Phi || decreases;
    this goes through configurations where the Jacobian is singular. Returns q, a (V,) mask
    of the converged variants (step and scaled residual small) and the iterations used.
    A single mechanism is solved on floats: by ``one`` where the caller has its equations
    as float code at ``t``, else by the kernels' own (``kernels.one_state``).
    """
    system = kernels.system
    V = q.shape[0]
    if rows.size == 0:
        return q.copy(), np.ones(V, bool), 0
    if one is None and kernels.one_state is not None:
        solver = OneState(kernels, kernels.one_state, D[0, 0], opts)
        if V == 1 and _closed_exactly(solver, q[0, 0], rows):
            return q.copy(), np.ones(1, bool), 1
        one = _one_equations(solver, float(t[0, 0]), rows)
    if one is not None and V == 1:
        out = _gauss_newton_one(one, q[0, 0], D[0, 0], rows, opts)
        if out is not None:
            qn, ok, it = out
            return np.array(qn).reshape(q.shape), np.array([ok]), it
    large = _large(system, opts)
    W = _row_weights(kernels, q, D, opts)[..., rows]
    with np.errstate(all="ignore"):
        phi = eq.constraint_values(kernels, q, t)[..., rows]
    merit = 0.5 * np.sum((W * phi) ** 2, axis=-1)
    merit = np.where(np.isfinite(merit), merit, np.inf)
    done = np.zeros((V, 1), bool)
    stuck = np.zeros((V, 1), bool)
    it = 0
    for it in range(1, opts.assembly_max_iterations + 1):
        with np.errstate(all="ignore"):
            if large:
                dz = _lm_step_sparse(eq.jacobian_values(kernels, q), rows, D, W,
                                     np.nan_to_num(W * phi))
            else:
                A = eq.jacobian(kernels, q)[..., rows, :] * D[..., None, :] * W[..., None]
                dz = _lm_step(A, np.nan_to_num(W * phi))
        # a trust region: long Gauss-Newton steps can leap to another assembly mode; short
        # ones follow the residual down from the guess to the closure nearest it
        size = np.abs(dz).max(axis=-1, keepdims=True)
        dz = dz * np.minimum(1.0, opts.assembly_max_step / np.maximum(size, 1e-300))
        alpha = np.ones((V, 1))
        # already closed: the residual is nil and Gauss-Newton asks for no step (no line
        # search, which would halve a zero step to no decrease)
        done |= ((np.abs(W * phi).max(axis=-1) <= opts.assembly_residual)
                 & (size[..., 0] <= opts.assembly_tol))
        todo = ~(done | stuck)
        if not todo.any():
            break
        accepted = np.zeros((V, 1), bool)
        for _ in range(30):
            q_try = q + (alpha * todo)[..., None] * D * dz
            with np.errstate(all="ignore"):
                phi_try = eq.constraint_values(kernels, q_try, t)[..., rows]
                merit_try = 0.5 * np.sum((W * phi_try) ** 2, axis=-1)
            better = todo & ~accepted & (merit_try < merit) & np.isfinite(merit_try)
            q = np.where(better[..., None], q_try, q)
            phi = np.where(better[..., None], phi_try, phi)
            merit = np.where(better, merit_try, merit)
            step = np.abs(alpha[..., None] * dz).max(axis=-1)
            small_r = np.abs(W * phi).max(axis=-1) <= opts.assembly_residual
            done |= better & (step <= opts.assembly_tol) & small_r
            accepted |= better
            alpha = np.where(accepted, alpha, alpha * 0.5)
            if (accepted | ~todo).all():
                break
        # no decrease along the Gauss-Newton direction: converged if the residual is nil
        small_r = np.abs(W * phi).max(axis=-1) <= opts.assembly_residual
        done |= todo & ~accepted & small_r
        stuck |= todo & ~accepted & ~small_r
        if (done | stuck).all():
            break
    return q, done[:, 0], it


def _continue_drives(kernels: Kernels, q: np.ndarray, t: np.ndarray, D: np.ndarray,
                     active: np.ndarray, opts: SolverOptions, rows: np.ndarray,
                     compiled: bool = False
                     ) -> tuple[np.ndarray, np.ndarray, int, OneStart | None]:
    """Carry the drives from their values at ``q`` to f(t0) (step 2 of :func:`assemble`;
    ``compiled``: by the compiled backend where it applies); the last item is the float
    code's :class:`OneStart` where it carried them."""
    system = kernels.system
    ok = active.copy()
    if system.drive_rows.size == 0 or not ok.any():
        return q, ok, 0, None
    if kernels.one_state is not None and len(rows) == system.n:
        done = (_continue_compiled(kernels, q[0, 0], float(t[0, 0]), D[0, 0], opts)
                if compiled else None)
        if done is None:
            done = _continue_one(OneState(kernels, kernels.one_state, D[0, 0], opts), q[0, 0],
                                 float(t[0, 0]), opts)
        if done is not None:
            qn, good, it, start = done
            return np.array(qn).reshape(q.shape), np.array([good]), it, start
    with np.errstate(all="ignore"):
        delta = np.zeros(q.shape[:-1] + (system.m,))
        delta[..., system.drive_rows] = -eq.constraint_values(kernels, q, t)[..., system.drive_rows]
    delta = np.where(ok[:, None, None], np.nan_to_num(delta), 0.0)
    sparse = use_sparse(system, opts, rows)
    fac = factor(eq.solver_jacobian(kernels, q, rows, sparse), D)
    floor = np.sqrt(opts.newton_tol)
    s, ds, iterations = 0.0, 1.0, 0
    while s < 1.0 and ok.any():
        s_new = min(1.0, s + ds)
        with np.errstate(all="ignore"):
            pred = q + (s_new - s) * fac.solve(delta[..., rows])
        pred = np.where(np.isfinite(pred), pred, q)
        qn, conv, it = newton(kernels, pred, t, D, ok, opts, rows, shift=(1.0 - s_new) * delta)
        iterations += it
        fn = factor(eq.solver_jacobian(kernels, qn, rows, sparse), D)
        good = (conv & (fn.rcond >= opts.singular_rcond) & (fn.sign == fac.sign)
                & (correction_ratio(qn, pred, q, D, floor) <= opts.branch_ratio))
        good |= ~ok[:, None]
        if not good.all():
            if ds > 2.0 ** -opts.max_bisections:
                ds /= 2
                continue
            ok &= good[:, 0]
        q = np.where(ok[:, None, None], qn, q)
        fac = fn
        s = s_new
        if it <= 3:
            ds = min(1.0, 2 * ds)
    return q, ok, iterations, None


def _continue_one(one, q: np.ndarray, t0: float, opts: SolverOptions
                  ) -> tuple[list, bool, int, OneStart | None] | None:
    """:func:`_continue_drives` for a single mechanism, on floats
    (:mod:`mechdsl.solve.single`): the same steps and checks, and where they succeed the
    drives at t0 with the exact factorisation at the configuration reached; None where the
    fixed-order LU does not apply (the batched continuation decides)."""
    x = q.tolist()
    f, fd, fdd = ([c[0] for c in d] for d in one.drives(np.array([t0])))
    try:
        phi, _ = one.residual(x, [0.0] * len(f))
    except FLOAT_ERRORS:
        return None
    # Phi(q, t0) + (1 - s) delta = 0 on the drive rows: a drive's target moves from g(q1)
    # at s = 0 to f(t0) at s = 1
    g = [phi[r] for r in one.drive_rows]
    fac = one.factor(x, exact=None)  # its sign and its solves: the condition is not asked
    if fac is None:
        return None
    delta = [0.0] * one.m
    for r, gi, fi in zip(one.drive_rows, g, f):
        delta[r] = fi - gi if math.isfinite(fi - gi) else 0.0
    floor = math.sqrt(opts.newton_tol)
    s, ds, iterations = 0.0, 1.0, 0
    while s < 1.0:
        s_new = min(1.0, s + ds)
        try:
            tangent = fac.solve(delta)  # Phi_q dq/ds = delta
        except FLOAT_ERRORS:
            return None
        pred = [xi + (s_new - s) * ti if math.isfinite(ti) else xi
                for xi, ti in zip(x, tangent)]
        target = [gi - (gi - fi) * s_new for gi, fi in zip(g, f)]
        xn, conv, it = one.newton(pred, target, opts.newton_tol)
        iterations += it
        fn = one.factor(xn)
        if fn is None:
            return None
        good = (conv and fn.rcond >= opts.singular_rcond and fn.sign == fac.sign
                and one.correction_ratio(xn, pred, x, floor) <= opts.branch_ratio)
        if not good:
            if ds > 2.0 ** -opts.max_bisections:
                ds /= 2
                continue
            return x, False, iterations, None
        x, fac, s = xn, fn, s_new
        if it <= 3:
            ds = min(1.0, 2 * ds)
    return x, True, iterations, OneStart(f, fd, fdd, fac)


def _continue_compiled(kernels: Kernels, q: np.ndarray, t0: float, D: np.ndarray,
                       opts: SolverOptions) -> tuple[list, bool, int, None] | None:
    """:func:`_continue_one` by the compiled backend (``carry`` of
    :mod:`mechdsl.compiled.native`), for a run on that backend: the same steps and checks
    in machine code; None where the model does not compile or a pivot of the fixed order
    became small (the float code decides)."""
    system = kernels.system
    module = kernels.native
    if module is None:
        return None
    f = np.ascontiguousarray(
        eq.drive_values(kernels, np.array([[t0]]), "f", (1, 1))[0, 0], dtype=float)
    params = kernels.fused.params
    p = np.array([float(np.ravel(v)[0]) for v in params]) if params else np.zeros(0)
    x, info = np.empty(system.n), np.zeros(2, np.int64)
    module.carry(np.ascontiguousarray(q, dtype=float), f, p, np.ascontiguousarray(D),
                 opts.newton_tol, opts.newton_error, opts.max_iterations, THRESHOLD,
                 opts.branch_ratio, opts.singular_rcond, opts.max_bisections, x, info)
    if info[0] < 0:
        return None
    return x.tolist(), bool(info[0]), int(info[1]), None


def _closed_exactly(one: OneState, q: np.ndarray, rows: np.ndarray) -> bool:
    """Whether the joint equations ``rows`` (no drive among them: else False) hold exactly
    at ``q``, guesses written from the drawing: Gauss-Newton's step would be zero."""
    if not set(one.drive_rows).isdisjoint(rows.tolist()):
        return False
    try:
        phi, _ = one.residual(q.tolist(), [0.0] * len(one.drive_rows))
    except FLOAT_ERRORS:
        return False
    return not any(phi[r] for r in rows.tolist())


def _one_equations(one: OneState, t: float, rows: np.ndarray) -> OneEquations:
    """Phi and Phi_q of a single mechanism at ``t`` by its float code (the drives' values
    at t only where their rows are solved: the joints alone need none)."""
    f = ([c[0] for c in one.drives(np.array([t]), ("f",))[0]]
         if not set(one.drive_rows).isdisjoint(rows.tolist()) else [0.0] * len(one.drive_rows))
    dense = one.kernels.fused.dense

    def evaluate(x: list) -> tuple[np.ndarray, np.ndarray]:
        phi, vals = one.residual(x, f)
        return np.array(phi), dense(np.array(vals))

    return evaluate


def _gauss_newton_one(equations: OneEquations, q: np.ndarray, D: np.ndarray, rows: np.ndarray,
                      opts: SolverOptions) -> tuple[list, bool, int] | None:
    """:func:`gauss_newton` for a single mechanism, Phi and Phi_q from ``equations`` (float
    code): the same weights, steps, trust region and line search; None where the float
    code meets what numpy would make a NaN (the batched Gauss-Newton then decides)."""

    def evaluate(x: list) -> tuple[np.ndarray, np.ndarray]:
        phi, jac = equations(x)
        return phi[rows], jac[rows]

    try:
        x = q.tolist()
        phi, jac = evaluate(x)
        if not phi.any():
            # closed exactly (guesses written from the drawing): the step would be zero
            return x, True, 1
        with np.errstate(all="ignore"):
            norms = np.sqrt(np.einsum("ij,ij->i", jac * D, jac * D))
        W = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
        merit = 0.5 * float(np.sum((W * phi) ** 2))
        if not math.isfinite(merit):
            return None
        done, it = False, 0
        for it in range(1, opts.assembly_max_iterations + 1):
            if not phi.any():  # closed exactly after a step
                return x, True, it
            dz = _lm_step_one(jac * D * W[:, None], W * phi)
            size = float(np.abs(dz).max(initial=0.0))
            dz = dz * min(1.0, opts.assembly_max_step / max(size, 1e-300))
            if (float(np.abs(W * phi).max(initial=0.0)) <= opts.assembly_residual
                    and size <= opts.assembly_tol):
                return x, True, it
            alpha, accepted = 1.0, False
            for _ in range(30):
                x_try = (np.array(x) + alpha * D * dz).tolist()
                phi_try, jac_try = evaluate(x_try)
                merit_try = 0.5 * float(np.sum((W * phi_try) ** 2))
                if merit_try < merit:
                    x, phi, jac, merit = x_try, phi_try, jac_try, merit_try
                    accepted = True
                    done = (float(np.abs(alpha * dz).max(initial=0.0)) <= opts.assembly_tol
                            and float(np.abs(W * phi).max(initial=0.0))
                            <= opts.assembly_residual)
                    break
                alpha *= 0.5
            if done:
                break
            if not accepted:
                # no decrease along the Gauss-Newton direction: converged if the residual is
                # nil
                done = float(np.abs(W * phi).max(initial=0.0)) <= opts.assembly_residual
                break
    except FLOAT_ERRORS:
        return None
    return x, done, it
