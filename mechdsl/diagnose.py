"""Messages for numerical failures: which variant, which instant, which joints and drives."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from . import equations as eq
from .system import System


#: A condition number above which a state next to a failure is called near-singular.
NEAR_SINGULAR = 1e6
#: Above this many coordinates a singular Jacobian is analysed with the sparse LU instead of
#: a dense SVD (which would need n^2 memory and n^3 time).
DENSE_ANALYSIS_MAX = 600


def variant_label(system: System, v: int) -> str:
    """' (l = 2.1, r = 2)' for sweep variant ``v``; '' without a sweep."""
    if not system.sweep:
        return ""
    return " (" + ", ".join(f"{k} = {a[v]:g}" for k, a in system.sweep.items()) + ")"


def constraint_names(system: System, rows) -> str:
    """'joint B (revolute, line 24), ...' for the owners of equation ``rows``, in order."""
    seen: list[str] = []
    for r in rows:
        c = system.row_owner(int(r))
        label = f"{c.kind} {c.name} ({c.type_name}, line {c.span.line})"
        if label not in seen:
            seen.append(label)
    return ", ".join(seen)


def col_scale(system: System) -> np.ndarray:
    """(V, 1, n): the model's length scale L for x and y, 1 for phi."""
    d = np.ones((system.n_variants, 1, system.n))
    d[..., 0::3] = system.scale[:, None, None]
    d[..., 1::3] = system.scale[:, None, None]
    return d


def singularity(system: System, q: np.ndarray, v: int) -> tuple[float, str]:
    """Condition number of the scaled Jacobian at ``q`` (n,) of variant ``v``, and the joints
    and drives whose equations take part in its near-dependency: the largest components of
    the left singular vector of the smallest singular value."""
    one = one_variant(system, v)
    if system.m == system.n and system.n > DENSE_ANALYSIS_MAX:
        return _sparse_singularity(one, q)
    jac = eq.jacobian(one, q.reshape(1, 1, -1))[0, 0] * col_scale(one)[0]
    rn = np.linalg.norm(jac, axis=-1)
    jac = jac / np.where(rn > 0, rn, 1.0)[:, None]
    try:
        u, s, _ = np.linalg.svd(np.nan_to_num(jac))
    except np.linalg.LinAlgError:
        return float("inf"), "(the Jacobian could not be analysed)"
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    weights = np.abs(u[:, -1])
    rows = [i for i in np.argsort(-weights) if weights[i] > 0.2 * weights.max()]
    return cond, constraint_names(system, rows)


def _sparse_singularity(one: System, q: np.ndarray) -> tuple[float, str]:
    """:func:`singularity` for a large mechanism, without a dense SVD: the condition estimate
    of the sparse LU, and the left singular direction by two steps of inverse iteration,
    u = (A A^T)^-1 r (the smallest singular value's direction dominates)."""
    from .sparse import TransposedLU, inverse_norm1

    vals = eq.jacobian_values(one, q.reshape(1, 1, -1)).values[0, 0]
    p = one.pattern
    D = col_scale(one)[0, 0]
    a = vals * D[p.cols]
    rn = np.sqrt(np.bincount(p.rows, a * a, minlength=p.shape[0]))
    a = np.nan_to_num(a / np.where(rn > 0, rn, 1.0)[p.rows])
    try:
        lu = TransposedLU(a, p)
        u = np.random.default_rng(0).standard_normal(p.shape[0])
        for _ in range(2):
            u = lu.solve_transposed(lu.solve(u))
            u /= np.abs(u).max()
        norm_a = float(np.bincount(p.cols, np.abs(a), minlength=p.shape[1]).max())
        cond = norm_a * inverse_norm1(lu)
    except RuntimeError:  # exactly singular: SuperLU gives no factors to iterate with
        return float("inf"), "(the equations could not be separated: exactly singular)"
    if not np.isfinite(u).all() or not np.isfinite(cond):
        return float("inf"), "(the Jacobian could not be analysed)"
    weights = np.abs(u)
    rows = [i for i in np.argsort(-weights)[:50] if weights[i] > 0.2]
    return cond, constraint_names(one, rows)


def one_variant(system: System, v: int) -> System:
    """The system restricted to variant ``v``."""
    groups = tuple(replace(g, params={k: a.variant(v) if hasattr(a, "variant") else a[v : v + 1]
                                      for k, a in g.params.items()})
                   for g in system.groups)
    return replace(system, groups=groups, env={k: a[v : v + 1] for k, a in system.env.items()},
                   n_variants=1, scale=system.scale[v : v + 1], guess=system.guess[v : v + 1])


def failure(system: System, q_last: np.ndarray, t_last: float, v: int, target: float,
            k: int, why: str) -> str:
    """The message for variant ``v`` failing on its way from ``t_last`` to ``target``, before
    recorded instant ``k``. ``why``: 'diverged', 'singular', 'crossing' or 'jump'."""
    times = system.times
    cond, names = singularity(system, q_last, v)
    if why == "diverged" and cond > NEAR_SINGULAR:
        why = "singular"  # Newton stalls right at a dead point: say what it is
    at = f"t = {times[k]:.10g} (instant {k} of {len(times) - 1}){variant_label(system, v)}"
    between = f"between t = {t_last:.10g} and t = {target:.10g}"
    if why == "singular":
        where = at if target == times[k] else f"t = {target:.10g}, before {at}"
        what = (f"the mechanism reaches a singular position at {where}: the Jacobian loses "
                "rank (a dead point, a change point or a lock-up), where velocities are not "
                "determined and the motion may continue on more than one branch")
    elif why == "crossing":
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
    return (f"{what}. At t = {t_last:.10g}, the last solved state, the Jacobian's condition "
            f"number is {cond:.3g}; the equations involved belong to {names}")
