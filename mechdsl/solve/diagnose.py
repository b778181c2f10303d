"""Messages for numerical failures: which variant, which instant, which joints and drives."""

from __future__ import annotations


import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from ..compiled.system import System
from ..errors import listing


#: A condition number above which a state next to a failure is called near-singular.
NEAR_SINGULAR = 1e6
#: Above this many coordinates a singular Jacobian is analysed with the sparse LU instead of
#: a dense SVD (which would need n^2 memory and n^3 time).
DENSE_ANALYSIS_MAX = 600


def instant_text(system: System, k: int) -> str:
    """'instant 537 of 2001': recorded instant ``k`` (0-based) counted from 1, out of all of
    them, as the summary and the CSV count them (t0 is instant 1)."""
    return f"instant {k + 1} of {len(system.times)}"


def variant_label(system: System, v: int) -> str:
    """' (l = 2.1, r = 2)' for sweep variant ``v``; '' without a sweep."""
    if not system.sweep:
        return ""
    return " (" + ", ".join(f"{k} = {a[v]:g}" for k, a in system.sweep.items()) + ")"


#: Joints and drives named in one message at most; the rest are counted.
MAX_NAMED = 8


def constraint_names(system: System, rows) -> str:
    """'joint B (revolute, line 24), ...' for the owners of equation ``rows``, in order; after
    MAX_NAMED of them, 'and N more'."""
    seen: dict[str, None] = {}
    for r in rows:
        c = system.row_owner(int(r))
        seen[f"{c.kind} {c.name} ({c.type_name}, line {c.span.line})"] = None
    return listing(seen, MAX_NAMED)


def jumps_text(system: System, jumps) -> str:
    """'drive push (x, line 7) jumps at t = 1 (its position by 0.1)' for each
    :class:`~mechdsl.solve.jumps.Jump`."""
    return "; ".join(f"{constraint_names(system, [j.row])} jumps at t = {j.t:.10g} (its "
                     f"{j.level} by {j.size:.3g})" for j in jumps)


#: A projection whose Gauss-Newton steps do not fall to newton_tol (module motion, dynamic)
#: is closed all the same where every constraint holds to this many units of round-off of
#: the configuration's size (:func:`closed_to_roundoff`)
RESIDUAL_ROUNDOFF = 1000.0


def closed_to_roundoff(phi: np.ndarray, q: np.ndarray, D: np.ndarray) -> bool:
    """Whether the constraints hold at q to round-off: max |Phi| <= RESIDUAL_ROUNDOFF eps
    max(|x|, |y|, D), over the bodies' positions, D the coordinates' scale (Phi sums body
    positions and rotated points, each rounded at eps times the configuration's size).

    Near a singular position the Gauss-Newton steps of a projection are the residual's
    rounding divided by Phi_q's smallest singular value: they stop shrinking while Phi
    itself holds to round-off (a parallelogram driven through its collinear position at
    t = 1.4708: |Phi| 3e-14 m, the scaled steps 2.3e-10 falling by 1.5 % an iteration,
    against newton_tol 1e-10), and the state is on both branches that cross there as
    nearly as double precision tells. Away from one, a residual this small means a step
    far below newton_tol, which the step test has already seen."""
    # (the lengths only: a crank's angle that has turned for long says nothing of a size)
    lengths = np.concatenate((q[0::3], q[1::3]))
    size = max(float(np.abs(lengths).max(initial=0.0)), float(np.max(D)))
    return bool(np.abs(phi).max(initial=0.0) <= RESIDUAL_ROUNDOFF * np.finfo(float).eps * size)


def col_scale(system: System) -> np.ndarray:
    """(V, 1, n): the model's length scale L for x and y, 1 for phi."""
    d = np.ones((system.n_variants, 1, system.n))
    d[..., 0::3] = system.scale[:, None, None]
    d[..., 1::3] = system.scale[:, None, None]
    return d


def singularity(kernels: Kernels, q: np.ndarray, v: int) -> tuple[float, str]:
    """Condition number of the scaled Jacobian at ``q`` (n,) of variant ``v``, and the joints
    and drives whose equations take part in its near-dependency: the largest components of
    the left singular vector of the smallest singular value."""
    system = kernels.system
    one = kernels.variant(v)
    if system.m == system.n and system.n > DENSE_ANALYSIS_MAX:
        return _sparse_singularity(one, q)
    jac = eq.jacobian(one, q.reshape(1, 1, -1))[0, 0] * col_scale(one.system)[0]
    rn = np.linalg.norm(jac, axis=-1)
    jac = jac / np.where(rn > 0, rn, 1.0)[:, None]
    try:
        u, s, _ = np.linalg.svd(np.nan_to_num(jac))
    except np.linalg.LinAlgError:
        return float("inf"), "(the Jacobian could not be analysed)"
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    # the left singular vector of the smallest singular value; with more equations than
    # coordinates the columns past len(s) span the permanent (redundant) null space instead
    return cond, loop_names(system, u[:, len(s) - 1])


#: The joints named as the loop that cannot close: the largest shares of the near-null
#: direction, until they carry this fraction of it, and at most LOOP_NAMED of them.
LOOP_SHARE = 0.9
LOOP_NAMED = 4


def loop_names(system: System, u: np.ndarray) -> str:
    """The joints and drives whose equations carry the direction ``u`` (m,) in which the rows
    of Phi_q are (nearly) dependent, ranked by their share of |u|^2 (the sum over their
    rows), with the shares: the loop that can no longer close."""
    share = np.bincount(np.searchsorted(system._row_starts, np.arange(len(u)), "right") - 1,
                        u * u, minlength=len(system.constraints))
    total = share.sum()
    if not total > 0:
        return "(the Jacobian could not be analysed)"
    share = share / total
    order = np.argsort(-share, kind="stable")
    named, carried = [], 0.0
    for i in order[:LOOP_NAMED]:
        if carried >= LOOP_SHARE or share[i] < 0.05 * share[order[0]]:
            break
        c = system.constraints[i]
        named.append(f"{c.kind} {c.name} ({c.type_name}, line {c.span.line}: "
                     f"{100 * share[i]:.2g} %)")
        carried += share[i]
    rest = int((share[order[len(named):]] >= 0.05 * share[order[0]]).sum())
    return ", ".join(named) + (f" and {rest} more" if rest else "")


def _sparse_singularity(one: Kernels, q: np.ndarray) -> tuple[float, str]:
    """:func:`singularity` for a large mechanism, without a dense SVD: the condition estimate
    of the sparse LU, and the left singular direction by two steps of inverse iteration,
    u = (A A^T)^-1 r (the smallest singular value's direction dominates)."""
    from ..compiled.sparse import TransposedLU, inverse_norm1

    vals = eq.jacobian_values(one, q.reshape(1, 1, -1)).values[0, 0]
    p = one.system.pattern
    D = col_scale(one.system)[0, 0]
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
    return cond, loop_names(one.system, u)


def failure(kernels: Kernels, q_last: np.ndarray, t_last: float, v: int, target: float,
            k: int, why: str, q_next: np.ndarray | None = None) -> str:
    """The message for variant ``v`` failing on its way from ``t_last`` to ``target``, before
    recorded instant ``k``. ``why``: 'diverged', 'singular', 'crossing' or 'jump'. Where
    Newton diverged, the Jacobian is checked against Phi at the predicted state ``q_next``
    (and at the last solved one): a plugin's wrong derivative is named as such."""
    system = kernels.system
    times = system.times
    if why == "diverged" and q_next is not None:
        one = kernels.variant(v)
        with np.errstate(all="ignore"):
            phi = eq.constraint_values(one, q_next.reshape(1, 1, -1), np.full((1, 1), target))
        undefined = np.flatnonzero(~np.isfinite(phi[0, 0]))
        if undefined.size:
            return (f"the equations of {constraint_names(system, undefined)} are not defined "
                    f"(not a number) near t = {target:.10g} (before {instant_text(system, k)})"
                    f"{variant_label(system, v)}: the motion leaves their domain after "
                    f"t = {t_last:.10g}, the last solved state (the square root of a negative "
                    "number, a function argument outside its table's range)")
    if why == "diverged":
        defects = (jacobian_defects(kernels, q_next, target, v) if q_next is not None
                   else None) or jacobian_defects(kernels, q_last, t_last, v)
        if defects:
            return (f"Newton-Raphson does not converge at t = {target:.10g} (before "
                    f"{instant_text(system, k)}){variant_label(system, v)}: {defects}")
    cond, names = singularity(kernels, q_last, v)
    if why == "diverged" and cond > NEAR_SINGULAR:
        why = "singular"  # Newton stalls right at a dead point: say what it is
    at = f"t = {times[k]:.10g} ({instant_text(system, k)}){variant_label(system, v)}"
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
            f"number is {cond:.3g}; the loop that can no longer close: {names} (each one's "
            "share of the direction in which the equations become dependent)")


_COORDS = (("x", "y", "phi"), ("vx", "vy", "omega"), ("ax", "ay", "alpha"))


def nonfinite_message(kernels: Kernels, v: int, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                      t: float, k: int) -> str:
    """The message for variant ``v`` whose state (q, qd, qdd), each (n,), at time ``t`` (the
    recorded instant ``k``, or -1 between instants) is not all finite: the first output (or
    else body coordinate) that is not, and the equations whose right-hand side is not."""
    system = kernels.system
    values = (q, qd, qdd)
    order = next(o for o, a in enumerate(values) if not np.isfinite(a).all())
    what = None
    V = system.n_variants
    states = []  # variant v's state among zeros: the output specs hold every variant's data
    for a in values:
        full = np.zeros((V, 1, len(a)))
        full[v, 0] = a
        states.append(full)
    for spec in system.outputs:
        if spec.order < order:
            continue
        with np.errstate(all="ignore"):
            x = eq.output_values(kernels, spec, *states, np.full((V, 1), t))[v, 0]
        if not np.isfinite(x):
            what = f"{spec.label} is {float(x)!r}"
            break
    if what is None:
        i = int(np.flatnonzero(~np.isfinite(values[order]))[0])
        x = float(values[order][i])
        what = f"{system.body_names[i // 3]}.{_COORDS[order][i % 3]} is {x!r}"
    when = (f"t = {t:.10g} ({instant_text(system, k)})" if k >= 0
            else f"t = {t:.10g}, between instants")
    cause = _nonfinite_cause(kernels, v, q, qd, t, order)
    return (f"{what} at {when}{variant_label(system, v)}: "
            f"{('a position', 'a velocity', 'an acceleration')[order]} that is not a finite "
            f"number{cause}; the run stops there (SolverOptions(nonfinite='keep'), or "
            "--keep-nonfinite, keeps such values and goes on)")


def _nonfinite_cause(kernels: Kernels, v: int, q: np.ndarray, qd: np.ndarray, t: float,
                     order: int) -> str:
    """', from the right-hand side of ...': the equations whose nu (order 1) or gamma
    (order 2) is not finite at that state, if any."""
    system = kernels.system
    one = kernels.variant(v)
    tt = np.full((1, 1), t)
    with np.errstate(all="ignore"):
        if order == 1:
            rhs = eq.velocity_rhs(one, tt, (1, 1))[0, 0]
            what = "the right-hand side of the velocity equation (nu) in"
        elif order == 2:
            rhs = eq.acceleration_rhs(one, q.reshape(1, 1, -1), qd.reshape(1, 1, -1), tt)[0, 0]
            what = "the right-hand side of the acceleration equation (gamma) in"
        else:
            return ""
    rows = np.flatnonzero(~np.isfinite(rhs))
    if not rows.size:
        return ""
    return (f": {what} the equations of {constraint_names(system, rows[:5])} is not finite "
            "there (a drive "
            "function whose derivative is unbounded, such as sqrt(t) at t = 0, or a plugin "
            "returning NaN or infinity)")


#: Directions in which a Jacobian is compared with central differences of Phi, and the
#: relative disagreement above which it is called inconsistent with Phi. Central differences
#: with a step of 1e-6 (scaled) are good to about 1e-9; a defect is of order 1.
JACOBIAN_CHECK_DIRECTIONS = 2
JACOBIAN_CHECK_TOLERANCE = 1e-5


def jacobian_defects(kernels: Kernels, q: np.ndarray, t: float, v: int) -> str | None:
    """Where the solver cannot converge: compare Phi_q d with (Phi(q + h d) - Phi(q - h d)) / 2h
    at ``q`` (n,) of variant ``v`` for random scaled directions d, in the rows of the types
    that supply their own Jacobian (``jacobian_terms``; a derived one is exact): a row that
    disagrees means the plugin's Jacobian is not the derivative of its equations. Returns the
    message naming the joints and their plugins, or None when the Jacobian agrees (two Phi
    evaluations and one Jacobian per direction, whatever the size of the mechanism)."""
    system = kernels.system
    supplied = [g.rows.ravel() for g in system.groups if g.ctype.supplies("jacobian_terms")]
    if not supplied:
        return None
    one = kernels.variant(v)
    D = col_scale(one.system)[0, 0]
    rng = np.random.default_rng(12345)
    h = 1e-6
    tt = np.full((1, 1), t)

    def phi(x: np.ndarray) -> np.ndarray:
        return eq.constraint_values(one, x.reshape(1, 1, -1), tt)[0, 0]

    worst = np.zeros(system.m)
    with np.errstate(all="ignore"):
        for _ in range(JACOBIAN_CHECK_DIRECTIONS):
            d = rng.standard_normal(system.n) * D
            fd = (phi(q + h * d) - phi(q - h * d)) / (2 * h)
            if system.n > DENSE_ANALYSIS_MAX and system.pattern is not None:
                vals = eq.jacobian_values(one, q.reshape(1, 1, -1)).values[0, 0]
                p = one.system.pattern
                jd = np.bincount(p.rows, vals * d[p.cols], minlength=system.m)
                size = np.sqrt(np.bincount(p.rows, (vals * D[p.cols]) ** 2, minlength=system.m))
            else:
                jac = eq.jacobian(one, q.reshape(1, 1, -1))[0, 0]
                jd = jac @ d
                size = np.linalg.norm(jac * D, axis=-1)
            scale = size * np.linalg.norm(d / D) + np.abs(fd) + 1e-300
            worst = np.maximum(worst, np.nan_to_num(np.abs(jd - fd) / scale, nan=np.inf))
    checked = np.zeros(system.m, bool)
    checked[np.concatenate(supplied)] = True
    rows = np.flatnonzero((worst > JACOBIAN_CHECK_TOLERANCE) & checked)
    if not rows.size:
        return None
    owners = []
    for r in rows:
        c = system.row_owner(int(r))
        if c not in owners:
            owners.append(c)
    plugins = sorted({_plugin_of(system, c.type_name) for c in owners})
    return (f"the Jacobian of {constraint_names(system, rows[:20])} is not the derivative of "
            f"its equations (a relative difference of {worst[rows].max():.3g} from central "
            "differences of Phi): Newton-Raphson cannot converge with it. This is a defect of "
            f"the plugin {', '.join(plugins)}, not of the .mech file")


def _plugin_of(system: System, type_name: str) -> str:
    for g in system.groups:
        if g.ctype.name == type_name:
            return type(g.ctype).__module__
    return "?"


def too_coarse_message(system: System, v: int, t_now: float, k: int, budget: int) -> str:
    """Substeps ran out between t_now and instant ``k``: the output step is too coarse."""
    return (f"the time step is too coarse for the motion: going on from t = {t_now:.10g} to "
            f"the next instant t = {system.times[k]:.10g} ({instant_text(system, k)})"
            f"{variant_label(system, v)} took more than {budget} "
            "substeps (the mechanism moves far, or to and fro, between instants); take a "
            "smaller step")


def passages_warning(times_passed: list[float], grid: np.ndarray) -> str:
    """One warning for the singular positions passed, one time per output step."""
    h = float(np.min(np.diff(grid))) if len(grid) > 1 else 1.0
    marks: list[float] = []
    for t in sorted(times_passed):
        # name the output instant the passage belongs to, not an internal substep
        t = float(grid[min(np.searchsorted(grid, t), len(grid) - 1)])
        if not marks or t - marks[-1] > h / 2:
            marks.append(t)
    shown = ", ".join(f"{t:.6g}" for t in marks)
    return (f"the mechanism passes singular positions near t = {shown} and continues on the "
            "branch it was moving on; velocities and accelerations exactly there are completed "
            "from their predicted values (accurate to about one step)")


def undefined_drive_message(kernels: Kernels, v: int, target: float, k: int) -> str:
    """The drives whose function is not a number at ``target`` (instant ``k``)."""
    system = kernels.system
    values = eq.drive_values(kernels, np.full((system.n_variants, 1), target), "f",
                             (system.n_variants, 1))[v, 0]
    drives = [c for c in system.constraints if c.kind == "drive"]
    bad = [drives[i] for i in np.flatnonzero(~np.isfinite(values))] or drives
    names = ", ".join(f"drive {c.name} (line {c.span.line})" for c in bad)
    return (f"the function of {names} is not defined at t = {target:.10g} "
            f"({instant_text(system, k)}){variant_label(system, v)}: outside its table's range, "
            "or a domain error such as sqrt of a negative number")
