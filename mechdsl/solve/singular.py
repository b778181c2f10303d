"""Continuing through a singular position on the branch the motion was on.

At a dead point or change point the Jacobian loses rank: positions are still determined
(the branch's smooth continuation passes through), but Phi_q qd = nu no longer fixes the
velocity. With the option ``at_singular = "continue"``, an instant exactly on such a
position is solved by minimum-norm Gauss-Newton from the Taylor predictor, and the velocity
and acceleration are the minimum-norm solutions completed along the null space N of the
scaled Jacobian by the predicted ones: qd = D (z + N N^T (D^-1 qd_pred - z)) with
z = (Phi_q D)^+ nu; likewise qdd with gamma. The completion is exact in the range of Phi_q^T
and accurate to O(step) along N.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from .assembly import gauss_newton
from .options import SolverOptions

#: Directions whose singular value is below this fraction of the largest count as the null
#: space near a singular position: there the velocity and acceleration equations fix them
#: only through a near-zero divisor, so they are taken from the prediction instead.
NULL_RCUT = 1e-4


def _complete(a: np.ndarray, rhs: np.ndarray, pred: np.ndarray, rcut: float) -> np.ndarray:
    """(V, n): the minimum-norm solution of a z = rhs plus the null-space part of ``pred``."""
    u, s, vt = np.linalg.svd(np.nan_to_num(a), full_matrices=False)  # m >= n: vt is n x n
    keep = s > s[..., :1] * rcut
    inv = np.where(keep, 1.0 / np.where(keep, s, 1.0), 0.0)
    z = np.einsum("...ji,...j,...j->...i", vt, inv, np.einsum("...ji,...j->...i", u, rhs))
    null = vt * (~keep)[..., :, None]  # rows of vt spanning the null space
    return z + np.einsum("...ki,...k->...i", null, np.einsum("...ki,...i->...k", null, pred - z))


def singular_step(kernels: Kernels, q_pred: np.ndarray, t: np.ndarray, qd_pred: np.ndarray,
                  qdd_pred: np.ndarray, D: np.ndarray, rows: np.ndarray, opts: SolverOptions
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Positions (V, 1, n), velocities and accelerations at an instant on a singular
    position, from predictions of all three; and a (V,) mask of where the positions
    converged."""
    # converge as far as a regular instant would: the assembly's residual test is too loose
    tight = replace(opts, assembly_residual=min(opts.assembly_residual, 1e-14),
                    assembly_tol=min(opts.assembly_tol, opts.newton_tol))
    q, ok, _ = gauss_newton(kernels, q_pred, t, D, rows, tight)
    with np.errstate(all="ignore"):
        a = eq.jacobian(kernels, q)[:, 0][:, rows] * D[:, 0, None, :]
        nu = eq.velocity_rhs(kernels, t, q.shape[:-1])[:, 0, rows]
        z = _complete(a, nu, qd_pred / D[:, 0], NULL_RCUT)
        qd = (z * D[:, 0])[:, None]
        gamma = eq.acceleration_rhs(kernels, q, qd, t)[:, 0, rows]
        z2 = _complete(a, gamma, qdd_pred / D[:, 0], NULL_RCUT)
    return q, qd, (z2 * D[:, 0])[:, None], ok & np.isfinite(z).all(-1) & np.isfinite(z2).all(-1)
