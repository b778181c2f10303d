"""The kinematic solver: assembly at t0, then Newton-Raphson at every instant, with velocities
and accelerations from the same Jacobian (Haug 1989, ch. 4).

Position: Newton-Raphson on Phi(q, t) = 0, Phi_q dq = -Phi, started from the Taylor predictor
q + tau qd + tau^2/2 qdd of the last solved instant. Velocity: Phi_q qd = nu. Acceleration:
Phi_q qdd = gamma. The Jacobian used for qd and qdd is evaluated at the converged q.

Speed comes from batching: several instants (a *block*) and every sweep variant are solved as
one batched array problem. The block grows while Newton converges in few iterations and
shrinks when it does not. When even one instant fails, the interval before it is bisected
(intermediate states are solved but not recorded) before the failure is declared, so a coarse
output step does not cause a failure on its own.

No silent branch switching: the correction Newton applies to the predictor is compared with
the motion since the last solved instant; on the branch the motion is on, their ratio is of
order tau^2, while a jump to another assembly branch makes it of order one. A ratio above
``branch_ratio`` is treated like a failure to converge (bisection, then a located error).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import equations as eq
from .compile import System
from .errors import MechError, NumericalError
from .results import Results


@dataclass(frozen=True)
class SolverOptions:
    """Tolerances and limits of the solver. Lengths are relative to the model's length scale
    L (its largest point coordinate or guessed position); angles are in radians."""

    #: Newton-Raphson stops when the step is at most this (|dx|/L, |dy|/L, |dphi|).
    newton_tol: float = 1e-10
    #: Newton iterations allowed per attempt at an instant.
    max_iterations: int = 12
    #: Assembly stops when its step is at most this (scaled as newton_tol).
    assembly_tol: float = 1e-10
    #: Largest scaled residual (each equation divided by the norm of its Jacobian row) that
    #: counts as assembled.
    assembly_residual: float = 1e-8
    #: Gauss-Newton iterations allowed for the assembly.
    assembly_max_iterations: int = 200
    #: A Jacobian whose reciprocal condition number (smallest over largest singular value of
    #: the scaled Jacobian) is below this counts as singular.
    singular_rcond: float = 1e-12
    #: Largest accepted ratio of Newton's correction to the predictor over the motion since
    #: the last solved state; above it the solution is taken to have jumped branch.
    branch_ratio: float = 0.5
    #: Instants solved together at most, and at the start.
    max_block: int = 256
    initial_block: int = 8
    #: Cap on V * b * m * n, the size of a batched Jacobian (memory bound).
    max_batch_elements: int = 2**22
    #: Halvings of the interval before a failing instant before the failure is reported.
    max_bisections: int = 12


@dataclass
class _State:
    """The last solved state of each variant (the solver's only mutable data)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    active: np.ndarray
    n_solved: np.ndarray
    sign: np.ndarray
    failures: list[str] = field(default_factory=list)
    residual: float = 0.0


def _col_scale(system: System) -> np.ndarray:
    """(V, 1, n): L for x and y, 1 for phi."""
    d = np.ones((system.n_variants, 1, system.n))
    d[..., 0::3] = system.scale[:, None, None]
    d[..., 1::3] = system.scale[:, None, None]
    return d


def _solve(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched a x = b; ``ok`` is False (and x NaN) where a is singular or x not finite."""
    with np.errstate(all="ignore"):
        try:
            x = np.linalg.solve(a, b[..., None])[..., 0]
        except np.linalg.LinAlgError:
            x = np.full(b.shape, np.nan)
            flat_a = a.reshape((-1,) + a.shape[-2:])
            flat_b = b.reshape((-1, b.shape[-1]))
            flat_x = x.reshape(flat_b.shape)
            for i in range(flat_a.shape[0]):
                try:
                    flat_x[i] = np.linalg.solve(flat_a[i], flat_b[i])
                except np.linalg.LinAlgError:
                    pass
    ok = np.isfinite(x).all(axis=-1)
    return x, ok


def check_mobility(system: System) -> None:
    """Raise MechError unless there are as many equations as coordinates (a fully driven
    kinematic model), naming the bodies that no constraint attaches."""
    n, m = system.n, system.m
    src = system.source
    if n == 0:
        raise MechError("the model has no moving body", source=src)
    attached = {b for c in system.constraints for b in c.bodies}
    loose = [b for b in system.body_names if b not in attached]
    notes = [f"body '{b}' is attached to nothing" for b in loose]
    if m < n:
        dof = n - m
        s = "s" if dof > 1 else ""
        raise MechError(
            f"the mechanism is not fully driven: {n} coordinates and {m} equations leave "
            f"{dof} degree{s} of freedom; add {dof} drive{s} or joint equation{s}",
            source=src, notes=notes)
    if m > n:
        raise MechError(f"the mechanism is over-constrained: {m} equations for {n} "
                        f"coordinates ({m - n} too many); remove a joint or a drive",
                        source=src, notes=notes)


# ---------------------------------------------------------------------------------------------
# Assembly


@dataclass(frozen=True)
class Assembly:
    """The configuration at t0 of every variant; ``ok[v]`` False where it was not found."""

    q: np.ndarray
    ok: np.ndarray
    messages: tuple[str, ...]
    iterations: int


def assemble(system: System, t0: float, options: SolverOptions | None = None) -> Assembly:
    """Find q with Phi(q, t0) = 0 near the guesses (Haug's assembly analysis).

    Damped Gauss-Newton on the scaled equations: with D the column scale and W the row
    weights (1 / norm of each row of Phi_q D at the guess), the step solves
    min || W (Phi + Phi_q D dz) || in the least-squares, minimum-norm sense (SVD), and is
    halved until the residual || W Phi || decreases. This converges from rough guesses and
    through configurations where the Jacobian is singular.
    """
    opts = options or SolverOptions()
    V, n = system.n_variants, system.n
    D = _col_scale(system)
    q = system.guess.reshape(V, 1, n).copy()
    t = np.full((V, 1), float(t0))
    phi = eq.constraint_values(system, q, t)
    A = eq.jacobian(system, q) * D[..., None, :]
    norms = np.linalg.norm(A, axis=-1)
    W = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
    merit = 0.5 * np.sum((W * phi) ** 2, axis=-1)
    done = np.zeros((V, 1), bool)
    stuck = np.zeros((V, 1), bool)
    it = 0
    for it in range(1, opts.assembly_max_iterations + 1):
        A = eq.jacobian(system, q) * D[..., None, :] * W[..., None]
        r = W * phi
        u, s, vt = np.linalg.svd(A, full_matrices=False)
        cut = s > s[..., :1] * 1e-12
        inv = np.where(cut, 1.0 / np.where(cut, s, 1.0), 0.0)
        dz = -np.einsum("...ji,...j,...j->...i", vt, inv, np.einsum("...ji,...j->...i", u, r))
        alpha = np.ones((V, 1))
        todo = ~(done | stuck)
        accepted = np.zeros((V, 1), bool)
        for _ in range(30):
            q_try = q + (alpha * todo)[..., None] * D * dz
            phi_try = eq.constraint_values(system, q_try, t)
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
    ok = done[:, 0]
    messages = []
    for v in np.flatnonzero(~ok):
        worst = np.argsort(-np.abs(W[v, 0] * phi[v, 0]))[:3]
        names = _constraint_names(system, worst)
        messages.append(
            f"the mechanism cannot be assembled at t = {t0:g} from the guesses"
            f"{_variant(system, v)}: the closest configuration found leaves equations of "
            f"{names} unsatisfied (scaled residual {np.abs(W[v, 0] * phi[v, 0]).max():.3g}); "
            "check the dimensions, or give guesses nearer the intended configuration")
    return Assembly(q[:, 0], ok, tuple(messages), it)


def _variant(system: System, v: int) -> str:
    if not system.sweep:
        return ""
    return " (" + ", ".join(f"{k} = {a[v]:g}" for k, a in system.sweep.items()) + ")"


def _constraint_names(system: System, rows) -> str:
    seen: list[str] = []
    for r in rows:
        c = system.row_owner(int(r))
        label = f"{c.kind} {c.name} ({c.type_name}, line {c.span.line})"
        if label not in seen:
            seen.append(label)
    return ", ".join(seen)


def singularity(system: System, q: np.ndarray, v: int) -> tuple[float, str]:
    """Condition number of the scaled Jacobian at ``q`` (n,) of variant ``v`` and the
    constraints whose equations take part in its near-dependency (the largest components of
    the left singular vector of the smallest singular value)."""
    D = _col_scale(system)[v : v + 1]
    jac = eq.jacobian(_single(system, v), q.reshape(1, 1, -1))[0, 0] * D[0]
    rn = np.linalg.norm(jac, axis=-1)
    jac = jac / np.where(rn > 0, rn, 1.0)[:, None]
    u, s, _ = np.linalg.svd(jac)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    weights = np.abs(u[:, -1])
    rows = [i for i in np.argsort(-weights) if weights[i] > 0.2 * weights.max()]
    return cond, _constraint_names(system, rows)


def _single(system: System, v: int) -> System:
    """The system restricted to variant ``v`` (for diagnostics only)."""
    from dataclasses import replace

    groups = tuple(replace(g, params={k: a[v : v + 1] for k, a in g.params.items()})
                   for g in system.groups)
    return replace(system, groups=groups, env={k: a[v : v + 1] for k, a in system.env.items()},
                   n_variants=1, scale=system.scale[v : v + 1], guess=system.guess[v : v + 1])


# ---------------------------------------------------------------------------------------------
# Time marching


def _newton(system: System, q: np.ndarray, t: np.ndarray, D: np.ndarray,
            opts: SolverOptions) -> tuple[np.ndarray, np.ndarray, int]:
    """Newton-Raphson from ``q`` (V, b, n) at times ``t`` (V, b). Returns the iterates, a
    (V, b) mask of the converged ones and the number of iterations used."""
    q = q.copy()
    done = np.zeros(q.shape[:-1], bool)
    failed = np.zeros_like(done)
    prev = np.full(done.shape, np.inf)
    it = 0
    for it in range(1, opts.max_iterations + 1):
        phi = eq.constraint_values(system, q, t)
        dq, solved = _solve(eq.jacobian(system, q), -phi)
        with np.errstate(invalid="ignore"):
            step = np.abs(dq / D).max(axis=-1)
        failed |= ~solved & ~done
        live = ~done & ~failed
        q += np.where(live[..., None], np.nan_to_num(dq), 0.0)
        converged = live & (step <= opts.newton_tol)
        done |= converged
        # Newton from a good predictor contracts quadratically; if it stops contracting,
        # give up early so that the block shrinks or the interval is bisected.
        if it >= 3:
            failed |= live & ~converged & (step > 0.5 * prev)
        prev = np.where(live, step, prev)
        if (done | failed).all():
            break
    return q, done, it


def simulate(system: System, options: SolverOptions | None = None) -> Results:
    """Solve positions (and, where outputs need them, velocities and accelerations) at every
    instant of ``system.times``, for every variant.

    Raises MechError if the model is not fully driven. Numerical failures do not raise: the
    failing variant stops, the instants solved before are kept, and ``Results.status`` is
    ``"failed"`` with the reasons in ``Results.messages``.
    """
    opts = options or SolverOptions()
    check_mobility(system)
    times = system.times
    if times is None:
        raise MechError("the system was compiled without a time grid")
    V, n, K = system.n_variants, system.n, len(times)
    data = {o.label: np.full((V, K), np.nan) for o in system.outputs}
    start = time.perf_counter()
    asm = assemble(system, float(times[0]), opts)
    st = _State(t=np.full(V, times[0]), q=asm.q.copy(), qd=np.zeros((V, n)),
                qdd=np.zeros((V, n)), active=asm.ok.copy(), n_solved=np.zeros(V, int),
                sign=np.ones(V), failures=list(asm.messages))
    status = "ok"
    try:
        if st.active.any():
            _check_regular(system, st, opts, float(times[0]))
        if st.active.any():
            q0 = asm.q[:, None]
            jac0 = eq.jacobian(system, q0)
            st.sign = np.linalg.slogdet(jac0)[0][:, 0]
            _accept(system, st, q0, np.full((V, 1), times[0]), np.array([0]), jac0,
                    st.active.copy(), data)
            _march(system, st, opts, data)
    except KeyboardInterrupt:
        status = "interrupted"
    elapsed = time.perf_counter() - start
    if status == "ok" and st.failures:
        status = "failed"
    return Results(
        times=times, data=data, sweep=dict(system.sweep), n_solved=st.n_solved,
        status=status, messages=tuple(st.failures), solve_time=elapsed,
        residual=st.residual, source_name=system.source.name,
    )


def _check_regular(system: System, st: _State, opts: SolverOptions, t0: float) -> None:
    """Stop the variants whose Jacobian is singular at the assembled configuration."""
    for v in np.flatnonzero(st.active):
        cond, names = singularity(system, st.q[v], int(v))
        if not cond * opts.singular_rcond < 1:
            st.active[v] = False
            st.failures.append(
                f"the Jacobian is singular at the assembled configuration (t = {t0:g})"
                f"{_variant(system, int(v))}: condition number {cond:.3g}; dependent "
                f"equations involve {names}. The constraints are redundant, or the mechanism "
                "starts at a dead point or a change point")


def _accept(system: System, st: _State, q: np.ndarray, t: np.ndarray, rec: np.ndarray,
            jac: np.ndarray, mask: np.ndarray, data: dict) -> None:
    """Take the solved positions ``q`` (V, c, n) at ``t`` (V, c), with their Jacobians
    ``jac``, as the new state of the variants in ``mask``; solve velocities and accelerations
    (at every column when an output needs them, else at the last column only, for the
    predictor); record the columns whose ``rec`` index is not negative."""
    order = system.order
    c = q.shape[1]
    cols = slice(None) if order >= 1 else slice(c - 1, c)
    qs, ts, js = q[:, cols], t[:, cols], jac[:, cols]
    nu = eq.velocity_rhs(system, ts, qs.shape[:-1])
    qd, _ = _solve(js, nu)
    gamma = eq.acceleration_rhs(system, qs, qd, ts)
    qdd, _ = _solve(js, gamma)
    with np.errstate(invalid="ignore"):
        res = np.abs(eq.constraint_values(system, q, t)[mask]).max(initial=0.0)
    st.residual = max(st.residual, float(res))
    st.q[mask], st.t[mask] = q[mask, -1], t[mask, -1]
    st.qd[mask], st.qdd[mask] = qd[mask, -1], qdd[mask, -1]
    keep = rec >= 0
    if not keep.any():
        return
    k = rec[keep]
    full_qd = qd if order >= 1 else None
    full_qdd = qdd if order >= 2 else None
    for spec in system.outputs:
        values = eq.output_values(system, spec, q, full_qd, full_qdd)
        data[spec.label][np.ix_(mask, k)] = values[mask][:, keep]
    st.n_solved[mask] = k[-1] + 1


def _march(system: System, st: _State, opts: SolverOptions, data: dict) -> None:
    times = system.times
    V, n, K = system.n_variants, system.n, len(times)
    D = _col_scale(system)
    cap = max(1, opts.max_batch_elements // max(1, V * system.m * n))
    b = max(1, min(opts.initial_block, cap))
    k = 1  # the next instant to record
    sub: list[float] = []  # pending intermediate times before times[k], ascending
    floor = np.sqrt(opts.newton_tol)
    while k < K and st.active.any():
        if sub:
            targets, rec = np.array(sub[:1]), np.array([-1])
        else:
            bb = min(b, K - k, cap)
            targets, rec = times[k : k + bb], np.arange(k, k + bb)
        bb = len(targets)
        act = st.active[:, None]
        T = np.where(act, targets[None, :], st.t[:, None])
        tau = (T - st.t[:, None])[..., None]
        pred = st.q[:, None] + tau * st.qd[:, None] + 0.5 * tau**2 * st.qdd[:, None]
        qn, ok, iters = _newton(system, pred, T, D, opts)
        with np.errstate(invalid="ignore", divide="ignore"):
            moved = np.maximum(np.abs((qn - st.q[:, None]) / D).max(axis=-1),
                               np.abs((pred - st.q[:, None]) / D).max(axis=-1))
            ratio = np.abs((qn - pred) / D).max(axis=-1) / np.maximum(moved, floor)
        jump = ok & ~(ratio <= opts.branch_ratio)
        # det(Phi_q) changes sign where the path crosses a singular configuration
        jac = eq.jacobian(system, qn)
        sign = np.linalg.slogdet(jac)[0]
        before = np.concatenate((st.sign[:, None], sign[:, :-1]), axis=1)
        crossing = ok & ~jump & ((sign != before) | (sign == 0))
        good = (ok & ~jump & ~crossing) | ~act
        col_ok = good.all(axis=0)
        nacc = bb if col_ok.all() else int(np.argmin(col_ok))
        if nacc:
            st.sign = np.where(st.active, sign[:, nacc - 1], st.sign)
            _accept(system, st, qn[:, :nacc], T[:, :nacc], rec[:nacc], jac[:, :nacc],
                    st.active.copy(), data)
            if sub:
                sub.pop(0)
            else:
                k += nacc
        if nacc == bb:
            if iters <= 3 and not sub:
                b = min(2 * b, opts.max_block, cap)
            elif iters >= 6:
                b = max(1, b // 2)
            continue
        if bb > 1:
            b = max(1, min(nacc, bb // 2))
            continue
        # a single step fails: bisect the interval, then give up on the failing variants
        t_act = float(st.t[st.active][0])
        target = float(targets[0])
        h = times[k] - times[k - 1]
        if target - t_act > h / 2**opts.max_bisections:
            sub.insert(0, t_act + 0.5 * (target - t_act))
            b = 1
            continue
        bad = st.active & ~good[:, 0]
        for v in np.flatnonzero(bad):
            why = "jump" if jump[v, 0] else "crossing" if crossing[v, 0] else "diverged"
            st.failures.append(_failure(system, st, int(v), target, k, why))
        st.active &= ~bad
        if st.active.any():
            st.sign = np.where(st.active, sign[:, 0], st.sign)
            _accept(system, st, qn, T, rec, jac, st.active.copy(), data)
            if sub:
                sub.pop(0)
            else:
                k += 1


def _failure(system: System, st: _State, v: int, target: float, k: int, why: str) -> str:
    times = system.times
    cond, names = singularity(system, st.q[v], v)
    variant = _variant(system, v)
    at = f"t = {times[k]:.10g} (instant {k} of {len(times) - 1}){variant}"
    between = f"between t = {st.t[v]:.10g} and t = {target:.10g}"
    if why == "crossing":
        what = (f"the mechanism passes through a singular position {between}, before {at}: "
                "the Jacobian loses rank there (a dead point or a change point), where the "
                "motion could continue on more than one branch")
    elif why == "jump":
        what = (f"the solution jumps to another assembly branch {between}, before {at}: "
                "the mechanism passes close to a singular position")
    else:
        what = (f"no configuration satisfies the constraints at {at}; tracking stopped "
                f"{between}: the mechanism locks up (a loop can no longer close) or reaches a "
                "singular position")
    return (f"{what}. At t = {st.t[v]:.10g}, the last solved state, the Jacobian's condition "
            f"number is {cond:.3g}; the equations involved belong to {names}")
