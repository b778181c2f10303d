"""Haug's kinematic equations of a compiled system, evaluated for a batch of states.

With q the coordinates of the moving bodies and t the time (Haug 1989, ch. 3):

* position:      Phi(q, t) = 0
* velocity:      Phi_q qd = nu,           nu = -Phi_t
* acceleration:  Phi_q qdd = gamma,       gamma = -(Phi_q qd)_q qd - 2 Phi_qt qd - Phi_tt

Joints are time-independent; a drive is g(q) - f(t), so nu has f'(t) in the drive rows and
gamma has f''(t) added there. Every function takes states of shape ``(V, b, n)`` (variants,
instants) and times broadcastable to ``(V, b)``, and evaluates the model's one compiled
function (:mod:`mechdsl.compiled.fused`): no plugin code runs during a solve.
"""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from .kernels import Kernels
from .sparse import LU_BATCH, LUJac, SparseJac
from .system import EnergyOutput, ExprOutput, ReactionOutput


def drive_values(kernels: Kernels, t: np.ndarray, which: str, shape) -> np.ndarray:
    """f, f' or f'' (``which``: 'f', 'fd', 'fdd') of every drive at ``t``: shape + (D,)."""
    system = kernels.system
    env = dict(system.env)
    env["t"] = t
    with np.errstate(all="ignore"):
        cols = [getattr(d, which)(env) for d in kernels.drive_functions]
    # (a value of the shape already is taken as it is, read-only as a broadcast is: a
    # drive may hand back the caller's own t; broadcast_to costs microseconds)
    cols = [_read_only(c) if np.shape(c) == shape else np.broadcast_to(c, shape)
            for c in cols]
    if len(cols) == 1:  # the common case, without the copy of a stack
        return cols[0][..., None]
    return np.stack(cols, axis=-1)


def _read_only(a: np.ndarray) -> np.ndarray:
    view = a.view()
    view.flags.writeable = False
    return view


def drive_table(kernels: Kernels, t: np.ndarray, shape) -> np.ndarray:
    """f, f' and f'' of every drive at ``t``, as one array: shape + (3, D) (D drives)."""
    system = kernels.system
    env = dict(system.env)
    env["t"] = t
    out = np.empty(tuple(shape) + (3, len(kernels.drive_functions)))
    with np.errstate(all="ignore"):
        for j, d in enumerate(kernels.drive_functions):
            for i, f in enumerate((d.f, d.fd, d.fdd)):
                out[..., i, j] = f(env)
    return out


def constraint_values(kernels: Kernels, q: np.ndarray, t: np.ndarray,
                      f: np.ndarray | None = None) -> np.ndarray:
    """Phi(q, t), shape ``(V, b, m)``; ``f``: the drives' f(t) where the caller has them."""
    system = kernels.system
    with np.errstate(all="ignore"):
        phi = kernels.fused.evaluate_phi(q)
    if kernels.drive_functions:
        phi[..., system.drive_rows] -= (drive_values(kernels, t, "f", q.shape[:-1]) if f is None
                                        else f)
    return phi


def jacobian_entries(kernels: Kernels, q: np.ndarray) -> np.ndarray:
    """The non-zero entries of Phi_q in ``system.pattern``'s order, shape ``(V, b, nnz)``."""
    with np.errstate(all="ignore"):
        return kernels.fused.evaluate_jac(q)


def jacobian(kernels: Kernels, q: np.ndarray) -> np.ndarray:
    """Phi_q, shape ``(V, b, m, n)``."""
    return kernels.fused.dense(jacobian_entries(kernels, q))


def jacobian_values(kernels: Kernels, q: np.ndarray) -> SparseJac:
    """Phi_q as its non-zero entries in ``system.pattern``: values of shape ``(V, b, nnz)``."""
    system = kernels.system
    return SparseJac(jacobian_entries(kernels, q), system.pattern)


def solver_jacobian(kernels: Kernels, q: np.ndarray, rows: np.ndarray, sparse: bool):
    """Phi_q (rows ``rows``) as the solver factorises it: dense ``(V, b, len(rows), n)``, or
    sparse (all rows) for a large mechanism."""
    if sparse:
        return jacobian_values(kernels, q)
    return jacobian_for(kernels, jacobian_entries(kernels, q), rows)


def jacobian_for(kernels: Kernels, values: np.ndarray, rows: np.ndarray):
    """The entries as the factorisation wants them: for the generated LU (a square system,
    a batch large enough to pay for it), else dense."""
    system = kernels.system
    # (the batch size first: a small batch never pays for planning the LU)
    if (values[..., 0].size >= LU_BATCH and len(rows) == system.m == system.n
            and kernels.lu is not None):
        return LUJac(values, system.pattern, kernels.lu)
    jac = kernels.fused.dense(values)
    return jac if len(rows) == system.m else jac[..., rows, :]


def residual_and_jacobian(kernels: Kernels, q: np.ndarray, t: np.ndarray, rows: np.ndarray,
                          sparse: bool, f: np.ndarray | None = None):
    """Phi(q, t) ``(V, b, m)`` and Phi_q as :func:`solver_jacobian` gives it, from one
    evaluation (Newton needs both at the same q: each body's cos and sin computed once);
    ``f``: the drives' f(t) where the caller has them."""
    system = kernels.system
    with np.errstate(all="ignore"):
        phi, vals = kernels.fused.evaluate_phi_jac(q)
    if kernels.drive_functions:
        phi = phi.copy()
        phi[..., system.drive_rows] -= (drive_values(kernels, t, "f", q.shape[:-1]) if f is None
                                        else f)
    if sparse:
        return phi, SparseJac(vals, system.pattern)
    return phi, jacobian_for(kernels, vals, rows)


def velocity_rhs(kernels: Kernels, t: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """nu = -Phi_t, shape ``shape + (m,)``: f'(t) in the drive rows, zero elsewhere."""
    system = kernels.system
    nu = np.zeros(tuple(shape) + (system.m,))
    if kernels.drive_functions:
        nu[..., system.drive_rows] = drive_values(kernels, t, "fd", tuple(shape))
    return nu


def acceleration_rhs(kernels: Kernels, q: np.ndarray, qd: np.ndarray,
                     t: np.ndarray) -> np.ndarray:
    """gamma = -(Phi_q qd)_q qd + f''(t) in the drive rows, shape ``(V, b, m)``."""
    system = kernels.system
    with np.errstate(all="ignore"):
        gamma = kernels.fused.evaluate_gamma(q, qd)
    if kernels.drive_functions:
        gamma[..., system.drive_rows] += drive_values(kernels, t, "fdd", q.shape[:-1])
    return gamma


def multipliers(kernels: Kernels, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                t: np.ndarray) -> np.ndarray:
    """The Lagrange multipliers of states (q, qd, qdd) that satisfy the constraints, from the
    equations of motion M qdd + Phi_q^T lambda = Q (Haug 1989, eq. 6.3.18): Phi_q^T lambda =
    Q - M qdd, shape (V, b, m). A square Phi_q (fully driven) is solved as it is; with free
    coordinates (m < n) the system is consistent and solved by QR in the least-squares
    sense, which is then exact. Redundant equations (m > n) leave lambda undetermined: NaN."""
    system = kernels.system
    d = kernels.dynamics
    shape = q.shape[:-1]
    t = np.broadcast_to(t, shape)
    if system.m > system.n:
        return np.full(shape + (system.m,), np.nan)
    with np.errstate(all="ignore"):
        rhs = d.generalised_forces(q, qd, t) - np.einsum("...ij,...j->...i", d.mass_matrix(q),
                                                          qdd)
        jt = np.swapaxes(np.nan_to_num(jacobian(kernels, q)), -1, -2)  # (..., n, m)
        if system.m == system.n:
            try:
                return np.linalg.solve(jt, rhs[..., None])[..., 0]
            except np.linalg.LinAlgError:
                return np.full(shape + (system.m,), np.nan)
        qm, r = np.linalg.qr(jt)
        y = np.einsum("...ji,...j->...i", qm, rhs)
        return np.linalg.solve(r, y[..., None])[..., 0]


def reaction_values(kernels: Kernels, spec: ReactionOutput, q: np.ndarray, lam: np.ndarray,
                    t: np.ndarray | None) -> np.ndarray:
    """A joint's reaction on its body, or a drive's effort or power, from the multipliers
    ``lam`` (V, b, m). The load of constraint k on body b is -Phi_q[rows_k, q_b]^T lambda_k
    = (F_x, F_y, n_O), n_O its moment about b's origin; about the joint's point s' of b it is
    n_O - (A s') x F. A drive's effort is -lambda (the generalised force along its measure
    g: a torque for an angle, a force for a length), its power -lambda f'(t)."""
    system = kernels.system
    c = system.constraints[spec.constraint]
    r0, r1 = c.rows
    if c.kind == "drive":
        effort = -lam[..., r0]
        if spec.quantity != "power":
            return effort
        j = int(np.flatnonzero(system.drive_rows == r0)[0])
        fd = drive_values(kernels, np.broadcast_to(t, q.shape[:-1]), "fd", q.shape[:-1])
        return effort * fd[..., j]
    k = 3 * spec.body
    jac = jacobian(kernels, q)[..., r0:r1, k : k + 3]  # (..., rows, 3)
    load = -np.einsum("...ri,...r->...i", jac, lam[..., r0:r1])
    if spec.quantity == "fx":
        return load[..., 0]
    if spec.quantity == "fy":
        return load[..., 1]
    torque = load[..., 2]
    if spec.point is not None:
        phi = q[..., k + 2]
        c_, s_ = np.cos(phi), np.sin(phi)
        sx, sy = spec.point[..., 0], spec.point[..., 1]
        ax, ay = c_ * sx - s_ * sy, s_ * sx + c_ * sy
        torque = torque - (ax * load[..., 1] - ay * load[..., 0])
    return torque


#: the coordinate (x, y, phi) each body quantity reads
_AXIS = MappingProxyType({"x": 0, "y": 1, "phi": 2, "vx": 0, "vy": 1, "omega": 2,
                          "ax": 0, "ay": 1, "alpha": 2})


def output_values(kernels: Kernels, spec, q: np.ndarray, qd: np.ndarray | None,
                  qdd: np.ndarray | None, t: np.ndarray | None = None,
                  cache: dict | None = None) -> np.ndarray:
    """One output quantity for states ``(V, b, n)`` at times ``t`` (V, b): shape ``(V, b)``.

    A point P with body coordinates s' (Haug eqs. 2.6.4 and their derivatives):
    r^P = r + A s', rd^P = rd + B s' phid, rdd^P = rdd + B s' phidd - A s' phid^2.
    A named output (:class:`~mechdsl.compiled.system.ExprOutput`) is its expression evaluated on the
    params, t and the quantities it reads. The value is reported in the column's unit (times
    ``spec.scale``: degrees for an angle where the model asks for them). ``cache``: what
    the outputs of these states share (the multipliers, the quantities the expressions
    read), filled as they are computed.
    """
    values = _values(kernels, spec, q, qd, qdd, t, cache)
    return values * spec.scale if spec.scale != 1.0 else values


def _values(kernels: Kernels, spec, q: np.ndarray, qd: np.ndarray | None,
            qdd: np.ndarray | None, t: np.ndarray | None, cache: dict | None) -> np.ndarray:
    """output_values in the computed unit (radians)."""
    system = kernels.system
    if isinstance(spec, EnergyOutput):
        d = kernels.dynamics
        with np.errstate(all="ignore"):
            if spec.label == "dissipated_power":
                return d.dissipated_power(q, qd, np.zeros(q.shape[:-1]) if t is None else t)
            if spec.label == "dissipated_energy":  # integrated by the run (DynamicRun)
                return np.array(np.broadcast_to(cache["dissipated_energy"], q.shape[:-1]))
            return (d.kinetic_energy(q, qd) if spec.order else d.potential_energy(q)).copy()
    if isinstance(spec, ReactionOutput):
        cache = {} if cache is None else cache
        if "lambda" not in cache:
            cache["lambda"] = multipliers(kernels, q, qd, qdd, t)
        return reaction_values(kernels, spec, q, cache["lambda"], t)
    if isinstance(spec, ExprOutput):
        env = dict(system.env)
        env["t"] = np.zeros(q.shape[:-1]) if t is None else t
        cache = {} if cache is None else cache
        for name, read in spec.inputs:
            # a quantity read by several outputs (a distance and its rates read the same
            # points), or a reaction's multipliers, computed once for the states given
            key = ("read", name, getattr(read, "scale", 1.0))
            if key not in cache:
                cache[key] = output_values(kernels, read, q, qd, qdd, t, cache)
            env[name] = cache[key]
        with np.errstate(all="ignore"):
            return np.broadcast_to(np.asarray(kernels.expressions[spec.label](env), dtype=float),
                                   q.shape[:-1]).copy()
    i = spec.body
    k = 3 * i
    shape = q.shape[:-1]
    name = spec.quantity
    if spec.point is None:  # a coordinate of the body, or its rate
        source = (q, qd, qdd)[spec.order]
        if i == system.n_bodies or source is None:  # the ground does not move
            return np.zeros(shape)
        return source[..., k + _AXIS[name]].copy()

    def part(a: np.ndarray | None) -> np.ndarray:
        if i == system.n_bodies or a is None:  # the ground does not move
            return np.zeros(shape + (3,))
        return a[..., k : k + 3]

    pose = part(q)
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
