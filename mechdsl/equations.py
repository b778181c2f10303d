"""Haug's kinematic equations of a compiled system, evaluated for a batch of states.

With q the coordinates of the moving bodies and t the time (Haug 1989, ch. 3):

* position:      Phi(q, t) = 0
* velocity:      Phi_q qd = nu,           nu = -Phi_t
* acceleration:  Phi_q qdd = gamma,       gamma = -(Phi_q qd)_q qd - 2 Phi_qt qd - Phi_tt

Joints are time-independent; a drive is g(q) - f(t), so nu has f'(t) in the drive rows and
gamma has f''(t) added there. Every function takes states of shape ``(V, b, n)`` (variants,
instants) and times broadcastable to ``(V, b)``, and calls each constraint type once.
"""

from __future__ import annotations

import numpy as np

from .system import ExprOutput, Group, System
from .errors import MechError
from .sparse import SparseJac


class PluginError(MechError):
    """A plugin raised or returned a malformed array while the system was evaluated."""


def _poses(system: System, q: np.ndarray) -> np.ndarray:
    """(V, b, n) -> (V, b, bodies + 1, 3), the ground's pose (all zero) appended last."""
    nb = system.n_bodies
    ext = np.zeros(q.shape[:-1] + (nb + 1, 3))
    ext[..., :nb, :] = q.reshape(q.shape[:-1] + (nb, 3))
    return ext


def _slots(group: Group, poses: np.ndarray) -> tuple[np.ndarray, ...]:
    return tuple(poses[..., group.slots[:, k], :] for k in range(group.slots.shape[1]))


def _call(system: System, group: Group, method: str, *args):
    """Call a plugin method; turn its exceptions and wrong shapes into a located error."""
    try:
        return _checked(group, method, args)
    except (Exception, SystemExit) as err:  # any plugin failure is reported as the plugin's
        ctype = group.ctype
        member = _culprit(group, method, args)
        c = system.constraints[group.members[member]]
        raise PluginError(
            f"the {ctype.kind} type '{ctype.name}' failed in {method}() for {c.kind} "
            f"'{c.name}': {type(err).__name__}: {str(err)[:200]}", c.span, system.source,
            notes=[f"the type comes from the plugin {type(ctype).__module__}; this is a "
                   "defect of the plugin, not of the .mech file"]) from None


def _checked(group: Group, method: str, args):
    ctype = group.ctype
    with np.errstate(all="ignore"):
        out = getattr(ctype, method)(*args)
    expect = (ctype.n_eq,) if method != "jacobian" else (ctype.n_eq, 3)
    arrays = tuple(out) if method == "jacobian" else (out,)
    if method == "jacobian" and len(arrays) != group.slots.shape[1]:
        raise ValueError(f"returned {len(arrays)} Jacobian blocks for "
                         f"{group.slots.shape[1]} attached bodies")
    for a in arrays:
        if np.shape(a)[-len(expect):] != expect:
            raise ValueError(f"returned shape {np.shape(a)}, expected (..., "
                             f"{', '.join(map(str, expect))})")
    return out


def _culprit(group: Group, method: str, args) -> int:
    """The first constraint of the group whose own call fails (0 if each works alone)."""
    kinds = {a.name: a.kind for a in group.ctype.signature}

    def member(j: int, name: str, v):
        if kinds[name] == "function":
            return v.member(j)
        # the constraint axis is the last batch axis: before the (2,) of points and vectors
        return v[..., j : j + 1, :] if kinds[name] in ("point", "vector") else v[..., j : j + 1]

    for j in range(len(group.members)):
        sub = tuple(tuple(x[..., j : j + 1, :] for x in a) if isinstance(a, tuple)
                    else {k: member(j, k, v) for k, v in a.items()} for a in args)
        try:
            _checked(group, method, sub)
        except (Exception, SystemExit):  # noqa: BLE001
            return j
    return 0


def drive_values(system: System, t: np.ndarray, which: str, shape) -> np.ndarray:
    """f, f' or f'' (``which``: 'f', 'fd', 'fdd') of every drive at ``t``: shape + (D,)."""
    env = dict(system.env)
    env["t"] = t
    with np.errstate(all="ignore"):
        cols = [np.broadcast_to(getattr(d, which)(env), shape) for d in system.drive_functions]
    if len(cols) == 1:  # the common case, without the copy of a stack
        return cols[0][..., None]
    return np.stack(cols, axis=-1)


def constraint_values(system: System, q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Phi(q, t), shape ``(V, b, m)``."""
    poses = _poses(system, q)
    phi = np.empty(q.shape[:-1] + (system.m,))
    for g in system.groups:
        phi[..., g.rows] = _call(system, g, "phi", _slots(g, poses), g.params)
    if system.drive_functions:
        phi[..., system.drive_rows] -= drive_values(system, t, "f", q.shape[:-1])
    return phi


def jacobian(system: System, q: np.ndarray) -> np.ndarray:
    """Phi_q, shape ``(V, b, m, n)`` (a view; copy before writing)."""
    poses = _poses(system, q)
    batch = q.shape[:-1]
    width = system.n + 3
    flat = np.zeros(batch + (system.m * width,))
    for g in system.groups:
        blocks = _call(system, g, "jacobian", _slots(g, poses), g.params)
        shape = batch + g.rows.shape + (3,)
        for k, blk in enumerate(blocks):
            # scattered through precomputed flat indices: far cheaper than 2-D fancy indexing
            if np.shape(blk) != shape:
                blk = np.broadcast_to(blk, shape)
            flat[..., g.flat[k]] += blk.reshape(batch + (-1,))
    return flat.reshape(batch + (system.m, width))[..., : system.n]


def jacobian_values(system: System, q: np.ndarray) -> SparseJac:
    """Phi_q as its non-zero entries in ``system.pattern``: values of shape ``(V, b, nnz)``."""
    poses = _poses(system, q)
    batch = q.shape[:-1]
    vals = np.zeros(batch + (len(system.pattern.rows),))
    for g in system.groups:
        blocks = _call(system, g, "jacobian", _slots(g, poses), g.params)
        shape = batch + g.rows.shape + (3,)
        for (keep, where), blk in zip(g.nz, blocks):
            if np.shape(blk) != shape:
                blk = np.broadcast_to(blk, shape)
            vals[..., where] += blk.reshape(batch + (-1,))[..., keep]
    return SparseJac(vals, system.pattern)


def solver_jacobian(system: System, q: np.ndarray, rows: np.ndarray, sparse: bool):
    """Phi_q (rows ``rows``) as the solver factorises it: dense ``(V, b, len(rows), n)``, or
    sparse (all rows) for a large mechanism."""
    if sparse:
        return jacobian_values(system, q)
    jac = jacobian(system, q)
    # all rows (the usual case): the view, not a fancy-indexed copy
    return jac if len(rows) == system.m else jac[..., rows, :]


def velocity_rhs(system: System, t: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """nu = -Phi_t, shape ``shape + (m,)``: f'(t) in the drive rows, zero elsewhere."""
    nu = np.zeros(tuple(shape) + (system.m,))
    if system.drive_functions:
        nu[..., system.drive_rows] = drive_values(system, t, "fd", tuple(shape))
    return nu


def acceleration_rhs(system: System, q: np.ndarray, qd: np.ndarray,
                     t: np.ndarray) -> np.ndarray:
    """gamma = -(Phi_q qd)_q qd + f''(t) in the drive rows, shape ``(V, b, m)``."""
    poses, rates = _poses(system, q), _poses(system, qd)
    gamma = np.empty(q.shape[:-1] + (system.m,))
    for g in system.groups:
        gamma[..., g.rows] = _call(system, g, "gamma", _slots(g, poses), _slots(g, rates),
                                   g.params)
    if system.drive_functions:
        gamma[..., system.drive_rows] += drive_values(system, t, "fdd", q.shape[:-1])
    return gamma


def output_values(system: System, spec, q: np.ndarray, qd: np.ndarray | None,
                  qdd: np.ndarray | None, t: np.ndarray | None = None) -> np.ndarray:
    """One output quantity for states ``(V, b, n)`` at times ``t`` (V, b): shape ``(V, b)``.

    A point P with body coordinates s' (Haug eqs. 2.6.4 and their derivatives):
    r^P = r + A s', rd^P = rd + B s' phid, rdd^P = rdd + B s' phidd - A s' phid^2.
    A named output (:class:`~mechdsl.system.ExprOutput`) is its expression evaluated on the
    params, t and the quantities it reads.
    """
    if isinstance(spec, ExprOutput):
        env = dict(system.env)
        env["t"] = np.zeros(q.shape[:-1]) if t is None else t
        for name, read in spec.inputs:
            env[name] = output_values(system, read, q, qd, qdd)
        with np.errstate(all="ignore"):
            return np.broadcast_to(np.asarray(spec.function(env), dtype=float),
                                   q.shape[:-1]).copy()
    i = spec.body
    k = 3 * i
    shape = q.shape[:-1]

    def part(a: np.ndarray | None) -> np.ndarray:
        if i == system.n_bodies or a is None:  # the ground does not move
            return np.zeros(shape + (3,))
        return a[..., k : k + 3]

    pose = part(q)
    name = spec.quantity
    if spec.point is None:
        source = {0: pose, 1: part(qd), 2: part(qdd)}[spec.order]
        return source[..., {"x": 0, "y": 1, "phi": 2, "vx": 0, "vy": 1, "omega": 2,
                            "ax": 0, "ay": 1, "alpha": 2}[name]].copy()
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    sx, sy = spec.point[..., 0], spec.point[..., 1]
    asx, asy = c * sx - s * sy, s * sx + c * sy
    axis = 0 if name[-1] == "x" else 1
    if spec.order == 0:
        return pose[..., axis] + (asx, asy)[axis]
    rate = part(qd)
    w = rate[..., 2]
    bs = (-asy, asx)[axis]  # B s' = perp(A s')
    if spec.order == 1:
        return rate[..., axis] + bs * w
    acc = part(qdd)
    return acc[..., axis] + bs * acc[..., 2] - (asx, asy)[axis] * w**2
