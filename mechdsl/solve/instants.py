"""A forward-dynamics run's output instants, settled together after the steps.

The integrator's dense output at an instant inside a step is on the constraint manifolds
only to the step's tolerance; the reported state is projected there, and its accelerations
and multipliers solved, where an output needs them. Done instant by instant on one-state
kernels this cost a small model more than its steps (the stiff pendulum, 200 instants:
about 60 us each at k = 1e2, 11.7 of its 32 ms; about 100 us each at k = 1e8, 21 of 78 ms,
through radau's relative coordinates). The instants inside steps do not feed back into the
integration, so the run keeps them as the dense output gives them and settles them all at
the end (and on a failure or an interrupt: what was integrated is kept), in one pass of the
array kernels over every instant and numpy's batched LAPACK solves:

* :func:`project`: mass-orthogonal (Bayo and Ledesma), as the augmented Lagrangian projects
  one state: Gauss-Newton steps dq of least M-norm with J dq = -Phi, [M J^T; J 0] [dq; mu]
  = [0; -Phi], until every instant's step is at most ``newton_tol`` (scaled by D), then the
  velocities [M J^T; J 0] [qd'; mu] = [M qd; nu] with J and M at the final q: the
  correction that changes the kinetic energy least (a projection in coordinates scaled by
  D, as the explicit pairs' steps are settled, moved the energy of a four-bar on a spring
  of 1e10 N/m by 2e-5 of itself, at the outputs of radau, whose velocities are held to h
  times the tolerance);
* :func:`accelerations`: [M J^T; J 0] [qdd; lambda] = [Q; gamma] at every instant.

Both need Phi_q of full row rank (the caller takes them for models without redundant
constraints) and a few equations (their matrices are dense); each returns None where a
batched solve meets a singular matrix or a value that is not finite, and the caller then
takes its one-state path, instant by instant, which handles every case.
"""

from __future__ import annotations

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels

__all__ = ["accelerations", "project"]


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """a x = b for a stack of systems (b (K, k)), None where one is singular or the result
    is not finite."""
    try:
        x = np.linalg.solve(a, b[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return None
    return x if np.isfinite(x).all() else None


def _saddle(mass: np.ndarray, jac: np.ndarray) -> np.ndarray:
    """The stack of [M J^T; J 0] (K, n + m, n + m)."""
    K, m, n = jac.shape
    a = np.zeros((K, n + m, n + m))
    a[:, :n, :n] = mass
    a[:, :n, n:] = jac.transpose(0, 2, 1)
    a[:, n:, :n] = jac
    return a


def project(kernels: Kernels, D: np.ndarray, t: np.ndarray, y: np.ndarray,
            newton_tol: float, max_iterations: int) -> np.ndarray | None:
    """The states y (K, 2n) at the instants t (K,) moved onto Phi(q, t) = 0 and Phi_q qd =
    nu mass-orthogonally, as :meth:`mechdsl.solve.motion.Motion.project` moves one (the
    module docstring); None where the batch cannot (the caller projects them one by
    one)."""
    system = kernels.system
    n, m, K = system.n, system.m, len(t)
    q, qd = y[:, :n].copy(), y[:, n:].copy()
    T = t[None]
    rhs = np.zeros((K, n + m))
    with np.errstate(all="ignore"):
        mass = kernels.dynamics.mass_matrix(q[None])[0]
        for _ in range(max_iterations):
            rhs[:, n:] = -eq.constraint_values(kernels, q[None], T)[0]
            x = _solve(_saddle(mass, eq.jacobian(kernels, q[None])[0]), rhs)
            if x is None:
                return None
            q += x[:, :n]
            if np.abs(x[:, :n] / D).max() <= newton_tol:
                break
        else:
            return None
        mass = kernels.dynamics.mass_matrix(q[None])[0]
        rhs[:, :n] = (mass @ qd[..., None])[..., 0]
        rhs[:, n:] = eq.velocity_rhs(kernels, T, (1, K))[0]
        x = _solve(_saddle(mass, eq.jacobian(kernels, q[None])[0]), rhs)
    if x is None:
        return None
    return np.concatenate((q, x[:, :n]), axis=1)


def accelerations(kernels: Kernels, t: np.ndarray, q: np.ndarray, qd: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """qdd (K, n) and lambda (K, m) of Haug's index-1 form at the states (q, qd) (K, n) and
    instants t (K,); None where a saddle-point matrix is singular (the caller solves those
    instants one by one)."""
    system, d = kernels.system, kernels.dynamics
    n, m, K = system.n, system.m, len(t)
    Q3, Qd3, T = q[None], qd[None], t[None]
    with np.errstate(all="ignore"):
        rhs = np.empty((K, n + m))
        rhs[:, :n] = d.generalised_forces(Q3, Qd3, T)[0]
        rhs[:, n:] = eq.acceleration_rhs(kernels, Q3, Qd3, T)[0]
        x = _solve(_saddle(d.mass_matrix(Q3)[0], eq.jacobian(kernels, Q3)[0]), rhs)
    return None if x is None else (x[:, :n], x[:, n:])
