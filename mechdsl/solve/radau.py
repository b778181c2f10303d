"""Radau IIA of order 5 on the index-3 equations of motion: stiff models, redundant constraints.

**What is solved.** The equations of motion in the index-3 form, z = (q, v, lambda),

    q' = v,    M(q) v' = Q(q, v, t) - Phi_q(q)^T lambda,    0 = Phi(q, t),

written B(q) z' = F(t, z) with B = diag(I, M(q), 0) and F = (v, Q - Phi_q^T lambda, Phi).
One step of size h from (t0, z0) is the three-stage Radau IIA collocation method (Hairer and
Wanner, Solving Ordinary Differential Equations II, sec. IV.8 and VI.8 (code RADAU5), VII.4 on
index-3 problems): the stage increments Z_j = z(t0 + c_j h) - z0, j = 1..3, solve

    B(Q_j) (sum_k (A^-1)_jk Z_k) / h = F(t0 + c_j h, z0 + Z_j),       c = ((4 -+ sqrt 6)/10, 1),

so every stage, the step's end z1 = z0 + Z_3 included, satisfies Phi(q, t) = 0 exactly (to the
Newton tolerance): no drift, no projection needed by the stepper itself. The multipliers are
unknowns of the step like q and v; velocities and accelerations are never differentiated.

**The simplified Newton iteration.** The stage residual's Jacobian is replaced by
h^-1 A^-1 (x) B0 - I (x) J0, with B0 = diag(I, M(q0), 0) and the exact derivatives

    J0 = [[0, I, 0], [K, dQ/dv, -Phi_q^T], [Phi_q, 0, 0]]      at (t0, q0, v0),

    K = dQ/dq - sum_i lambda_i Phi_i,qq

(dQ/dq, dQ/dv from ``load_derivatives``; the constraints' curvature from
``constraint_curvature`` where the equations give it, :mod:`mechdsl.compiled.curvature`: a
term of relative size |lambda| h^2 / |M|, the weight of the chain on A02's rockers); what is
neglected is the derivative of M(q) v' with respect to q (M varies only through the centres
of mass off the body frames, and v' is bounded).
Transforming the stages by the eigenvectors of A^-1 (one real eigenvalue gamma, one complex
pair alpha +- i beta) splits the 3 (2n + m) unknowns into one real and one complex system
E(c) = c B0 - J0, c = gamma / h or (alpha + i beta) / h. Each is reduced to n + m unknowns by
eliminating dq = (dv + b_q) / c:

    [[c M - dQ/dv - dQ/dq / c,  Phi_q^T],   [dv      ]   [b_v + dQ/dq b_q / c]
     [Phi_q,                    -delta I]] . [dlambda] = [-c b_lambda - Phi_q b_q ],

a sparse saddle-point matrix factorised by SuperLU (``splu``, COLAMD ordering; a system of
at most ``DENSE_MAX`` = 120 unknowns dense, by LAPACK, whose sparse bookkeeping would cost
more than its arithmetic: the stiff pendulum's run 19 % faster): the
factorisation is reused across Newton iterations and across steps while the step size stays
within ``keep_ratio`` and Newton converges fast; the Jacobian is evaluated anew after a step
whose Newton iteration converged slowly (rate > ``jac_rate``) or when it fails to converge;
a non-converging iteration with a fresh Jacobian halves the step. The iteration stops when
rate / (1 - rate) |dW| < ``newton_tol`` (Hairer's test, at most ``max_newton`` iterations)
with the rate measured in the error norm (velocities weighted by h) and |dW| with the
velocities counted in full, down to their rounding (:meth:`RadauStepper._stage_weights`:
the h-weighted test alone left velocities off by the same sign at every step, 190 times rtol
over a run), or where the stage residuals themselves imply an error of at most
``residual_tol`` times ``newton_tol`` in the error norm (:meth:`RadauStepper._residual_norm`).
Near a singular
position both matter: the iteration matrix is ill conditioned along the near-null directions
of Phi_q (on A02 at t = 0.7201 its smallest singular value is 2.8e-4 of the largest), so
the residuals' rounding comes back as corrections that never shrink, while the equations
already hold to 1e-14; and at the singular position itself Newton converges only linearly,
at rates of 0.5 to 0.9 (A02 at t = 7.141), so a rate at most ``singular_rate`` (0.95) may
go on to ``max_newton_singular`` (60) iterations. With both, radau passes A02's twenty
collinear positions at rtol 1e-8, where it stopped at the first (the step size underflowed
at t = 0.7201); with a limit of 0.6 and 20 iterations it stopped at the eighth, t = 7.141.

**An ODE.** Where no constraint is left (the joints' own coordinates, module reduced) the
system is B(w) z' = F(t, z) with B = diag(I, M_w) and no multiplier: Phi, Phi_q and the
range part are not evaluated, and for a few coordinates (2n <= ``OPERATOR_MAX``) the
simplified Newton's correction of the three stages is one matrix made per factorisation
(:func:`_ode_operators`), the stages' derivatives and velocity residuals another (their
linear part), the stages' equations of motion one call of the equations'
``stage_residuals`` where they have it (the generated code of module reduced_terms): an
iteration is then a few products of small arrays (on the stiff pendulum, whose arithmetic
is less than numpy's cost per call, the run took 20 % less).

**Redundant constraints.** Where Phi_q is rank-deficient (consistent redundant constraints, a
parallelogram's extra link, a passage through a singular position), [[S, Phi_q^T], [Phi_q, 0]]
is singular. The lambda block carries -delta I, delta = ``regularization`` |Phi_q|^2 / |S|
(max-norms; relative to the Schur complement's scale): the matrix is then regular, the
perturbation of the iteration matrix is of relative size ``regularization`` (the residual is
exact, so the converged stages are those of the unregularised equations). The multipliers'
components in the null space of Phi_q^T are not determined by the equations and do not act on
the motion: they are excluded from the Newton and error norms, and after every step the
multipliers are replaced by their component in the range of Phi_q, (G G^T + eps I)^-1 G G^T
lambda (without it they drift: the regularised matrix divides the curvature left in Phi along
the redundant directions by delta; on the redundant parallelogram |lambda| reached 1e10 in one
second and the step size underflowed).

**Error control.** The estimate of RADAU5, err = E(gamma / h)^-1 (F(t0, z0) + B0 (e^T Z) / h)
(e the embedded third-order weights), computed again from F(t0, z0 + err) after a rejection
or on the first step (filtering the stiff components), measured as
|err|_rms with sc_i = atol scale_i + rtol max(|y0_i|, |y1_i|) and with the index-3 scaling:
the velocities' error multiplied by h, the multipliers' excluded (Hairer's recommendation for
index-3 components). A step is accepted where |err| <= 1; the next step size comes from the
predictive (Gustafsson) controller, h_new = h fac min(1, (h / h_prev) (err_prev / err)^1/4)
err^-1/4 with the safety factor fac = 0.9 (2 k_max + 1) / (2 k_max + k_newton), limited to
[``min_factor``, ``max_factor``]. Its prediction assumes that h_prev -> h was the
controller's own change; where Newton's failures halved the step instead, the step after
uses the standard controller alone (the prediction read the halving as a trend: on A02 at
t = 1.244 it shrank every following step tenfold, to an underflow); a step size that would
grow by less than ``keep_ratio`` is kept (the factorisation with it), except with the
stages' own Jacobians (radau_stages), factorised at every step anyway (the stiff pendulum
at k = 1e8: 20 % faster). Dense
output: the collocation polynomial of the step (order 3 uniformly, exact at the stages).
"""

from __future__ import annotations

import functools
import math
import sys
from typing import Callable, ClassVar

import numpy as np

from .options import raised_to
from .radau_stages import DENSE_MAX, CoupledStages, DenseLU, dense, triplets
from .stepper import OUT_OF_BUDGET, Equations, Stepper
from .triplets import Triplets


def _radau_constants() -> dict[str, np.ndarray | float | complex]:
    """The Radau IIA (3 stages) coefficients, their eigen-decomposition and the error and
    dense-output weights (as in scipy's Radau and Hairer's RADAU5)."""
    s6 = 6.0 ** 0.5
    c = np.array([(4 - s6) / 10, (4 + s6) / 10, 1.0])
    A = np.array([[(88 - 7 * s6) / 360, (296 - 169 * s6) / 1800, (-2 + 3 * s6) / 225],
                  [(296 + 169 * s6) / 1800, (88 + 7 * s6) / 360, (-2 - 3 * s6) / 225],
                  [(16 - s6) / 36, (16 + s6) / 36, 1 / 9]])
    mu_real = 3 + 3 ** (2 / 3) - 3 ** (1 / 3)
    mu_complex = 3 + 0.5 * (3 ** (1 / 3) - 3 ** (2 / 3)) - 0.5j * (3 ** (5 / 6) + 3 ** (7 / 6))
    T = np.array([[0.09443876248897524, -0.14125529502095421, 0.03002919410514742],
                  [0.25021312296533332, 0.20412935229379994, -0.38294211275726192],
                  [1.0, 1.0, 0.0]])
    TI = np.linalg.inv(T)
    E = np.array([-13 - 7 * s6, -13 + 7 * s6, -1.0]) / 3
    P = np.array([[13 / 3 + 7 * s6 / 3, -23 / 3 - 22 * s6 / 3, 10 / 3 + 5 * s6],
                  [13 / 3 - 7 * s6 / 3, -23 / 3 + 22 * s6 / 3, 10 / 3 - 5 * s6],
                  [1 / 3, -8 / 3, 10 / 3]])
    out = dict(c=c, A=A, Ainv=np.linalg.inv(A), T=T, TI_real=TI[0], TI_complex=TI[1] + 1j * TI[2],
               E=E, P=P)
    for a in out.values():
        a.flags.writeable = False  # shared constants: nobody may change them
    out.update(mu_real=mu_real, mu_complex=mu_complex)
    return out


_K = _radau_constants()
_CUBIC = np.arange(1.0, 4.0)  # the powers of the collocation polynomial (dense output)
_C = _K["c"].tolist()  # the stages' nodes, as floats


@functools.cache
def _posv() -> Callable:
    """LAPACK's dposv, looked up once (lazily: the registry's import stays cheap)."""
    from scipy.linalg import lapack
    return lapack.dposv


#: An ODE (no constraint left: module reduced) of at most this many unknowns (2n) solves
#: its Newton corrections by explicit inverses (:func:`_ode_operators`), not LU solves
OPERATOR_MAX = 16


def _ode_operators(h: float, M: np.ndarray, Cv: np.ndarray, Kq: np.ndarray, pair: bool
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """For an ODE (m = 0) of n coordinates and a step h: E(gamma/h)^-1 (2n, 2n), the
    simplified Newton's whole correction as one matrix L (6n, 6n) on the stage residuals
    in block order (:func:`_block_order`) and the stages' linear map (:func:`_stage_map`)
    (only the first unless ``pair``). With S(c) = c M - dQ/dv - dQ/dq / c, eliminating dq
    = (dv + b_q) / c from E(c) (dq, dv) = (b_q, b_v) (module docstring) gives

        E(c)^-1 = [[(S^-1 K / c + I) / c,  S^-1 / c],
                   [S^-1 K / c,            S^-1    ]],      K = dQ/dq,

    and the transformed iteration dW = -E(mu / h)^-1 (T^-1 (x) I) r, dZ = (T (x) I) dW
    (the real eigenvalue's and the complex pair's parts) is linear in r: L = (T (x) I)
    [A_r; Re A_c; Im A_c] with A = -E^-1 (T^-1 row (x) I). For a small system a few
    products per factorisation save the two LU solves and their bookkeeping at every
    iteration (the stiff pendulum in its two joint coordinates: 60 steps, 130 iterations).
    LinAlgError where S is singular."""
    n = M.shape[0]
    out = []
    for mu in (_K["mu_real"], _K["mu_complex"])[:2 if pair else 1]:
        c = mu / h
        Si = np.linalg.inv(c * M - Cv - Kq / c)
        SK = Si @ Kq / c
        E = np.empty((2 * n, 2 * n), dtype=SK.dtype)
        E[:n, :n], E[:n, n:], E[n:, :n], E[n:, n:] = (SK + _identity(n)) / c, Si / c, SK, Si
        out.append(E)
    if not pair:
        return out[0], None, None
    TIr, TIc, T = _stage_maps(n)
    Ac = out[1] @ TIc
    L = T @ np.vstack((out[0] @ TIr, Ac.real, Ac.imag))
    # (its columns in the block order that RadauStepper._newton_ode keeps the residual in)
    return out[0], -L[:, _block_order(n)], _stage_map(h, n)


def _state_residual(rq: np.ndarray, rv: np.ndarray, w: tuple) -> float:
    """The squared sum of the stages' velocity residuals rq and force residuals rv (3, n)
    as errors of the state in the error norm (RadauStepper._residual_norm: h M^-1 r_v
    moves the velocities, h times that and h r_q the positions)."""
    dv = rv * w[2]  # h M^-1 r_v
    eq = (rq + dv) * w[1]
    ev = dv * w[3]
    return float(np.vdot(eq, eq) + np.vdot(ev, ev))


@functools.cache
def _identity(n: int) -> np.ndarray:
    """I_n, shared (read-only)."""
    out = np.eye(n)
    out.flags.writeable = False
    return out


def _extrapolated(Z: np.ndarray, t: float, h: float, t_old: float, h_prev: float
                  ) -> np.ndarray:
    """The first guess of the stage increments (Hairer's): the last step's collocation
    polynomial, y_old + sum_k x^k (P^T Z)_k on [t_old, t_old + h_prev], at the new stages
    t + c_j h less its value at the step's start t (x = 1). x from the instants themselves,
    not from 1 + c_j h / h_prev: t - t_old is h_prev only to the rounding of t (1.8e-15 s
    at t = 12.5), which the steps that shrink at a singular position make felt (A02 under
    radau at rtol 1e-8: with the guess from the step sizes' ratio the step size underflowed
    at t = 12.52; from the instants, it passes all twenty)."""
    rows = [[x, x * x, x * x * x] for x in ((t + h * c - t_old) / h_prev for c in _C)]
    rows.append([1.0, 1.0, 1.0])  # (the step's start)
    at = np.array(rows) @ (_K["P"].T @ Z)
    return at[:3] - at[3]


@functools.cache
def _block_order(n: int) -> np.ndarray:
    """For each entry of the block order of three stages' (q, v) parts (every stage's q
    part, then every stage's v part), its index in the stage-major order of Z.ravel()
    (stage j's q part, then its v part)."""
    j, a = np.divmod(np.arange(3 * n), n)
    out = np.concatenate((2 * n * j + a, 2 * n * j + n + a))
    out.flags.writeable = False
    return out


def _stage_map(h: float, n: int) -> np.ndarray:
    """The linear part of an ODE's stage residuals as one matrix S (6n, 6n) on z = Z.ravel()
    (stage-major): in block order, the velocity residuals' part D_q,j - Z_v,j and the
    stages' accelerations D_v,j, with D_j = sum_k (A^-1)_jk Z_k / h the stages'
    derivatives (the residual r_q,j = D_q,j - (v0 + Z_v,j))."""
    derivatives, velocities = _stage_map_parts(n)
    return derivatives / h + velocities


@functools.cache
def _stage_map_parts(n: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_stage_map`'s two parts (D, V), S = D / h + V: D of the stages'
    derivatives (A^-1 (x) I), V of the velocity residuals' -Z_v."""
    I = np.eye(n)
    D, V = np.zeros((6 * n, 6 * n)), np.zeros((6 * n, 6 * n))
    for j in range(3):
        for k in range(3):
            D[j * n:(j + 1) * n, 2 * n * k:2 * n * k + n] = _K["Ainv"][j, k] * I
            D[3 * n + j * n:3 * n + (j + 1) * n, 2 * n * k + n:2 * n * (k + 1)] = \
                _K["Ainv"][j, k] * I
        V[j * n:(j + 1) * n, 2 * n * j + n:2 * n * (j + 1)] = -I
    for a in (D, V):
        a.flags.writeable = False
    return D, V


@functools.cache
def _stage_maps(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T^-1's real row, its complex row and T, each (x) I_2n: the maps of
    :func:`_ode_operators` between the stages' residuals and the transformed systems."""
    I2 = np.eye(2 * n)
    out = (np.kron(_K["TI_real"][None, :], I2), np.kron(_K["TI_complex"][None, :], I2),
           np.kron(_K["T"], I2))
    for a in out:
        a.flags.writeable = False
    return out


#: The rounding of the stages' velocities A^-1 Z / h, in units of eps |q|_max / h: over
#: newton_tol, the floor of their scale in the Newton iteration's norms
#: (:meth:`RadauStepper._stage_weights`). Measured at rtol 1e-10, where it decides: without
#: a floor the iteration never converged on a double pendulum's whip (t = 0.883, steps of
#: 1e-5 s: the step size underflowed); 1 left the slower velocities less converged (the
#: spinning rod on a slider, k = 1e4 N/m, 9.5 times rtol off its oracle over 3 s, against
#: 1.7 with 0.3 or 0.1; the double pendulum 9.3e-11 rad, against 5.3e-11 and 2.3e-11, 0.1
#: taking 5 % more evaluations)
ROUNDING = 0.3
_EPS = float(np.finfo(float).eps)

#: up to this many equations the multipliers' range part is solved dense
_DENSE_RANGE = 60

#: The tightest tolerances radau integrates at (rtol, and atol as the driver scales it): on
#: the index-3 form the velocities carry round-off of order eps / h (the multipliers eps /
#: h^2), which smaller steps grow, so that below them the error grows instead of shrinking
#: (measured against vern9 at rtol 1e-13, the first output at the end: a double pendulum at
#: t = 2, 9.1e-12 rad at rtol 1e-10, 1.2e-10 at 1e-11, 2.9e-9 at 1e-12; Andrews at t =
#: 0.03, 1.4e-9 at 1e-10, 1.6e-8 at 1e-11), and below atol 1e-13 steps underflow (Andrews at
#: 3e-14 at t = 3e-7, the stiff pendulum at k = 1e8, the car axis at 1e-14)
RTOL_MIN, ATOL_MIN = 1e-10, 1e-13


def floored(rtol: float, atol: float) -> tuple[float, float, str | None]:
    """(rtol, atol) raised to :data:`RTOL_MIN`, :data:`ATOL_MIN` where below them, and the
    line that says so for the run's summary (None where nothing changed)."""
    rtol, atol, asked = raised_to(rtol, atol, RTOL_MIN, ATOL_MIN)
    if not asked:
        return rtol, atol, None
    return rtol, atol, (f"radau at rtol {rtol:g}, atol {atol:g} (asked {', '.join(asked)}): "
                        "tighter, the round-off of its index-3 equations grows the error "
                        "instead of shrinking it; vern9 or dop853 integrate to tighter "
                        "tolerances")


#: the longest interval between two retries of the common Jacobian, in stagewise_retry's
RETRY_CAP = 16


def _issparse(a: object) -> bool:
    """Whether a is a scipy sparse matrix, without importing scipy.sparse (a small model's
    run, which has none, never needs it: 25 ms of a process)."""
    sp = sys.modules.get("scipy.sparse")
    return sp is not None and sp.issparse(a)


def _mat(a: object) -> object:
    """A matrix as the equations gave it, sparse as CSR, dense as a 2-d float array (both
    multiply vectors with @; assembly takes their triplets)."""
    if isinstance(a, Triplets):
        return a
    return a.tocsr() if _issparse(a) else np.atleast_2d(np.asarray(a, dtype=float))


def _cat(*parts: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triplets joined."""
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))


def _amax(a: object) -> float:
    if isinstance(a, Triplets):
        v = a.data
    else:
        v = a.data if _issparse(a) else a
    return float(np.max(np.abs(v))) if v.size else 0.0


class _Stopping:
    """The simplified Newton iteration's exits (:meth:`RadauStepper._stage_weights`), one
    record per iteration: ``first``, the iterations after which the h-weighted test first
    passed (what the step size control reads, as before the velocities counted in full:
    more iterations for their precision are no sign of a harder step), and ``held``, that
    test's latest passing iterate (first, Z, rate), the answer where the iteration then
    stalls with a current Jacobian. Each exit returns (converged, iterations, Z, rate)."""

    __slots__ = ("tol", "current", "max_newton", "first", "held")

    def __init__(self, tol: float, current: bool, max_newton: int) -> None:
        self.tol, self.current, self.max_newton = tol, current, max_newton
        self.first = self.held = None

    def converged(self, k: int, Z: np.ndarray, rate: float | None) -> tuple:
        return True, self.first or k + 1, Z, (rate if rate is not None else 0.0)

    def failed(self, k: int, Z: np.ndarray, rate: float) -> tuple:
        return (True, *self.held) if self.held else (False, k + 1, Z, rate)

    def after(self, k: int, Z: np.ndarray, rate: float | None, norm: float, full: float
              ) -> tuple | None:
        """After correction k (Z corrected; ``norm`` and ``full`` the correction's norms
        with the velocities weighted by h and counted in full): the exit, or None."""
        passed = rate is not None and rate / (1 - rate) * norm < self.tol
        self.first = self.first or (k + 1 if passed else None)
        if full == 0 or (rate is not None and rate / (1 - rate) * full < self.tol):
            return self.converged(k, Z, rate)
        if self.current and passed:
            self.held = (self.first, Z, rate)
            if k + 1 >= self.max_newton:  # (not on to the singular position's limit)
                return (True, *self.held)
        return None

    def exhausted(self, iterations: int, Z: np.ndarray, rate: float | None) -> tuple:
        if self.held:
            return (True, *self.held)
        return False, iterations, Z, (rate if rate is not None else np.inf)


class RadauStepper(Stepper):
    """Radau IIA (order 5, 3 stages) on the index-3 equations of motion; the module's
    docstring has the formulation. Options (keywords, defaults):

    ``newton_tol`` (None: max(10 eps / rtol, min(0.03, rtol^1/2)), Hairer's and scipy's),
    ``max_newton`` = 6 iterations, ``jac_rate`` = 1e-3 (a Newton contraction rate above which
    the Jacobian is evaluated anew after the step), ``keep_ratio`` = 1.2 (a step-size change
    by a smaller factor is not made, to keep the factorisation), ``min_factor`` = 0.2 and
    ``max_factor`` = 10 (bounds of one step-size change), ``safety`` = 0.9,
    ``regularization`` = 1e-10 (the relative size of the lambda block's -delta I that makes
    redundant constraints solvable), ``stage_jacobians`` = True (where the common Jacobian
    does not converge, each stage gets its own: module radau_stages), ``stagewise_retry``
    = 20 (accepted steps after which the common Jacobian is tried again; doubled after
    each retry that fails at once), and
    ``singular_rate`` = 0.95 and ``max_newton_singular`` = 60 (the Newton contraction rate
    up to which, at a singular position, the iteration goes on, and how far)."""

    name: ClassVar[str] = "radau"
    order: ClassVar[int] = 5
    implicit: ClassVar[bool] = True
    redundant: ClassVar[bool] = True
    constrained: ClassVar[bool] = True
    dense_arrays: ClassVar[bool] = True
    summary: ClassVar[str] = ("Radau IIA order 5 on the index-3 form: stiff models, redundant "
                              "constraints (sparse implicit, error-controlled)")

    def __init__(self, equations: Equations, t0: float, y0: np.ndarray, t_bound: float, *,
                 rtol: float, atol: float, scale: np.ndarray,
                 first_step: float | None = None, newton_tol: float | None = None,
                 max_newton: int = 6, jac_rate: float = 1e-3, keep_ratio: float = 1.2,
                 min_factor: float = 0.2, max_factor: float = 10.0, safety: float = 0.9,
                 regularization: float = 1e-10, stage_jacobians: bool = True,
                 stagewise_retry: int = 20, index3_scaling: bool = True,
                 curvature: bool = True, residual_tol: float = 1.0,
                 max_newton_singular: int = 60, singular_rate: float = 0.95) -> None:
        super().__init__(equations, t0, y0, t_bound, rtol=rtol, atol=atol, scale=scale,
                         first_step=first_step)
        self.n, self.m = int(equations.n), int(equations.m)
        n = self.n
        #: Phi and Phi_q at (t, q): the equations', or for equations without constraints
        #: (an ODE: module reduced) none, not evaluated
        unconstrained = (np.zeros(0), np.zeros((0, n)))
        self._phi_jac = equations.phi_jac if self.m else (lambda t_, q_: unconstrained)
        self.y = self.y_old = np.array(self.y, dtype=float)
        own = getattr(equations, "own_scale", None)
        if scale is None:
            sc = np.ones(2 * n)
        elif own is not None:
            sc = own(scale)
        else:
            sc = np.broadcast_to(np.asarray(scale, dtype=float), (2 * n,))
        self._atol = atol * sc
        self.newton_tol = newton_tol if newton_tol is not None else \
            max(10 * np.finfo(float).eps / rtol, min(0.03, rtol ** 0.5))
        self.max_newton, self.jac_rate, self.keep_ratio = max_newton, jac_rate, keep_ratio
        self.min_factor, self.max_factor, self.safety = min_factor, max_factor, safety
        self.regularization = regularization
        self.stage_jacobians, self.stagewise_retry = stage_jacobians, stagewise_retry
        self._stagewise, self._stagewise_steps = False, 0
        # the stagewise steps before the common Jacobian is tried again: doubled after each
        # retry that fails at once, up to RETRY_CAP times stagewise_retry (a spring that
        # stays stiff: the stiff pendulum tried and failed six times a run at a fixed 20),
        # back to stagewise_retry after one that holds
        self._retry_every, self._retrying = stagewise_retry, False
        # M and Q of a state in one evaluation where the equations give both together
        self._mass_loads = getattr(equations, "mass_loads", None) or (
            lambda t_, q_, v_: (equations.mass(q_), equations.loads(t_, q_, v_)))
        # (kept for an ODE too, module reduced: unscaled, the stiff pendulum at k = 1e4 in
        # its two joint coordinates ended 2.3e-7 m off at rtol 1e-6 against 2.4e-6, but a
        # chain of five links on rotary springs of 1e10 N m/rad, its stiff modes stirred
        # by the explicit pair's steps before the switch, took steps 1e3 times shorter:
        # their velocities' error, omega times their amplitude, is what h discounts)
        self.index3_scaling = index3_scaling
        self._error_map = getattr(equations, "error_map", None)
        #: the error's tolerance in the coordinates ``error_map`` gives it in (the model's,
        #: whose ``scale`` was given), where the equations have coordinates of their own
        self._atol_error = self._atol if own is None else \
            atol * (np.asarray(scale, dtype=float) if scale is not None else 1.0)
        self.curvature = curvature
        self.residual_tol = residual_tol
        self.max_newton_singular, self.singular_rate = max_newton_singular, singular_rate
        self.lam = self._multipliers(self.t, self.y)
        self._jac: tuple | None = None  # (M0, dQ/dq, dQ/dv, Phi_q) at the step's start
        self._jac_current = True  # evaluated at the current state (not an older one)
        self._lu: tuple | None = None   # factorisations for the current h
        self._ops: tuple | None = None  # or, for a small ODE, its inverses (_ode_operators)
        self._lu_h = 0.0
        self._F0 = self._F(self.t, self.y, self.lam, start=True)
        self._Z: np.ndarray | None = None  # the last accepted step's stage increments
        self._h_prev: float | None = None
        self._err_prev: float | None = None
        self.h_abs = float(first_step) if first_step else self._first_step()

    @property
    def stagewise(self) -> bool:
        """Whether its steps now take each stage's own Jacobian (the common one did not
        converge: a stiff force whose direction turns over a step)."""
        return self._stagewise

    # -- evaluations ------------------------------------------------------------------------
    def _multipliers(self, t: float, y: np.ndarray) -> np.ndarray:
        self.nfev += 1
        return np.asarray(self.equations.accelerations(t, y[:self.n], y[self.n:])[1], float)

    def _F(self, t: float, y: np.ndarray, lam: np.ndarray, phi_jac: tuple | None = None,
           start: bool = False) -> np.ndarray:
        """F(t, z) = (v, Q - Phi_q^T lambda, Phi); ``phi_jac``: (Phi, Phi_q) at (t, q) where
        the caller has them. ``start``: z is the next step's start, whose M(q) the error
        estimate reads (``_M0``: from the same evaluation)."""
        eq, n = self.equations, self.n
        q, v = y[:n], y[n:2 * n]
        phi, G = phi_jac if phi_jac is not None else self._phi_jac(t, q)
        self.nfev += 1
        if start:
            # M at the step's start, not the Jacobian's (kept over many steps): where M
            # varies with q (a body's frame off its centre of mass, relative coordinates)
            # the error estimate with an older M rejected a step in four (module relative)
            M0, load = self._mass_loads(t, q, v)
            self._M0 = M0 if type(M0) is np.ndarray and M0.ndim == 2 else _mat(M0)
        else:
            load = eq.loads(t, q, v)
        if not self.m:  # an ODE (module reduced): no constraint force, no Phi
            return np.concatenate((v, load))
        return np.concatenate((v, load - G.T @ lam, phi))

    def _first_step(self) -> float:
        """Hairer's starting step size (Solving ODEs I, sec. II.4) on the index-1 form."""
        y, t = self.y, self.t
        sc = self._atol + self.rtol * np.abs(y)
        f0 = self.equations.rhs(t, y)
        d0, d1 = np.sqrt(np.mean((y / sc) ** 2)), np.sqrt(np.mean((f0 / sc) ** 2))
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        h0 = min(h0, abs(self.t_bound - t))
        f1 = self.equations.rhs(t + h0, y + h0 * f0)
        self.nfev += 2
        d2 = np.sqrt(np.mean(((f1 - f0) / sc) ** 2)) / h0
        h1 = max(1e-6, h0 * 1e-3) if max(d1, d2) <= 1e-15 else \
            (0.01 / max(d1, d2)) ** (1 / (self.order + 1))
        return min(100 * h0, h1, abs(self.t_bound - t))

    def _stiffness(self, t: float, q: np.ndarray, dq: object, lam: np.ndarray) -> object:
        """d/dq of Q - Phi_q^T lambda: the loads' exact derivative ``dq`` less the
        constraints' curvature (where the equations give it: ``constraint_curvature``)."""
        eq = self.equations
        dq = _mat(dq)
        curv = getattr(eq, "constraint_curvature", None)
        if curv is None or not self.curvature:
            return dq
        h = curv(t, q, lam)
        if not (h.nnz if hasattr(h, "nnz") else h.any()):
            return dq
        if self.n + self.m <= DENSE_MAX:  # a few bodies: made dense for the LU anyway
            return dense(dq, (self.n, self.n)) - dense(h, (self.n, self.n))
        r, c, vals = _cat(triplets(dq), triplets(h, f=-1.0))
        return Triplets(vals, r, c, (self.n, self.n))

    def _jacobian(self, t: float, y: np.ndarray) -> None:
        eq, n = self.equations, self.n
        q, v = y[:n], y[n:]
        dq, dv = eq.load_derivatives(t, q, v)
        dq = self._stiffness(t, q, dq, self.lam)
        self._jac = (_mat(eq.mass(q)), _mat(dq), _mat(dv), _mat(self._phi_jac(t, q)[1]))
        self.njev += 1
        self._set_pattern()
        self._lu = None

    # -- the linear algebra -----------------------------------------------------------------
    def _delta(self, c: complex) -> float:
        """The lambda block's regularisation, relative to the Schur complement G S^-1 G^T's
        scale |G|^2 / |S| (S = c M - dQ/dv - dQ/dq / c)."""
        S_scale = max(abs(c) * self._norms[0], self._norms[1], self._norms[2] / abs(c), 1e-300)
        return self.regularization * self._norms[3] ** 2 / S_scale

    def _factor(self, h: float, pair: bool = True) -> None:
        """Factorise the reduced saddle-point matrices for c = gamma / h and (alpha + i
        beta) / h (module docstring; only the real one unless ``pair``), on the sparsity
        pattern fixed with the Jacobian."""
        n, size, lus = self.n, self._pattern[6], []
        self._ops = None
        if self.m == 0 and self._pattern[4] is None and 2 * n <= OPERATOR_MAX:
            try:
                self._ops = _ode_operators(h, *self._pattern[:3], pair)
            except np.linalg.LinAlgError:
                pass  # (singular: the LU's inf or NaN, which the step's tests catch)
            else:
                self.nlu += 2 if pair else 1
                self._lu, self._lu_h = ("operators",), h
                return
        for mu in (_K["mu_real"], _K["mu_complex"])[:2 if pair else 1]:
            c = mu / h
            if self._pattern[4] is None:  # a few bodies: the terms dense (_set_dense)
                M, Cv, Kq, G = self._pattern[:4]
                data = np.zeros((size, size), dtype=np.result_type(c, M))
                data[:n, :n] = c * M - Cv - Kq / c
                data[:n, n:] = G.T
                data[n:, :n] = G
                data[range(n, size), range(n, size)] = -self._delta(c)
                lus.append(DenseLU(data))
            else:
                import scipy.sparse as sp  # (lazily: the registry's import stays cheap)
                from scipy.sparse.linalg import splu
                dM, dC, dK, dI, indices, indptr, _ = self._pattern
                data = c * dM - dC - dK / c - self._delta(c) * dI
                K = sp.csc_matrix((data, indices, indptr), shape=(size, size))
                lus.append(splu(K, permc_spec="COLAMD"))
            self.nlu += 1
        self._lu, self._lu_h = tuple(lus), h

    def _set_pattern(self) -> None:
        """The union sparsity pattern (CSC) of the reduced matrix's terms c M, dQ/dv +- Phi_q
        blocks, dQ/dq / c and the lambda block, and each term's values on it: a
        factorisation then costs one array expression and splu, not a sparse assembly. (A
        system of at most DENSE_MAX unknowns: the terms dense, the pattern all entries.)"""
        M, Kq, Cv, G = self._jac
        n, m = self.n, self.m
        size = n + m
        if size <= DENSE_MAX:
            self._set_dense()
            return
        terms = [triplets(M), _cat(triplets(Cv), triplets(G, 0, n, -1.0, True),
                                   triplets(G, n, 0, -1.0)),
                 triplets(Kq), (np.arange(n, size), np.arange(n, size), np.ones(m))]
        rows = np.concatenate([t[0] for t in terms])
        cols = np.concatenate([t[1] for t in terms])
        key = cols.astype(np.int64) * size + rows  # column-major: CSC order
        uniq, inverse = np.unique(key, return_inverse=True)
        values, start = [], 0
        for t in terms:
            values.append(np.bincount(inverse[start:start + t[2].size], weights=t[2],
                                      minlength=uniq.size))
            start += t[2].size
        indices = (uniq % size).astype(np.int32)
        indptr = np.searchsorted(uniq // size, np.arange(size + 1)).astype(np.int32)
        self._pattern = (*values, indices, indptr, size)
        self._norms = (_amax(M), _amax(Cv), _amax(Kq), _amax(G) if m else 0.0)
        # M's diagonal, for the residual's test (:meth:`_residual_norm`)
        mr, mc, mv = triplets(M)
        diag = np.zeros(n)
        np.add.at(diag, mr[mr == mc], mv[mr == mc])
        self._mass_diag = np.where(diag > 0, diag, max(self._norms[0], 1e-300))

    def _set_dense(self) -> None:
        """:meth:`_set_pattern` for a small system: the terms as dense arrays, kept in
        ``_pattern`` as (M, dQ/dv, dQ/dq, Phi_q, None, None, size) (:meth:`_factor`
        assembles each matrix from them in one pass)."""
        n, m = self.n, self.m
        size = n + m
        M, Kq, Cv, G = (dense(a, shape) for a, shape in zip(
            self._jac, ((n, n), (n, n), (n, n), (m, n))))
        self._pattern = (M, Cv, Kq, G, None, None, size)
        self._norms = (float(np.abs(M).max(initial=0.0)), float(np.abs(Cv).max(initial=0.0)),
                       float(np.abs(Kq).max(initial=0.0)),
                       float(np.abs(G).max(initial=0.0)) if m else 0.0)
        diag = np.diagonal(M).copy()
        self._mass_diag = np.where(diag > 0, diag, max(self._norms[0], 1e-300))
        self._jac = (M, Kq, Cv, G)  # dense from here on: its products are numpy's

    def _solve(self, which: int, c: complex, b: np.ndarray) -> np.ndarray:
        """x with E(c) x = b, E(c) = c B0 - J0, by the reduced saddle-point system."""
        if self._ops is not None:  # (which is 0: the pair's solve is the operator)
            return self._ops[0] @ b
        M, Kq, Cv, G = self._jac
        n = self.n
        bq, bv, bl = b[:n], b[n:2 * n], b[2 * n:]
        rhs = np.concatenate((bv + Kq @ bq / c, -c * bl - G @ bq))
        x = self._lu[which].solve(rhs)
        dv = x[:n]
        return np.concatenate(((dv + bq) / c, dv, x[n:]))

    # -- one step ---------------------------------------------------------------------------
    def _norm(self, x: np.ndarray, sc: np.ndarray, h: float) -> float:
        """The rms norm of the (q, v) parts of x scaled by sc, v's multiplied by h (the
        index-3 scaling); lambda excluded. (Of the coordinates sc is given for: the
        error of equations in coordinates of their own is measured in the model's.)"""
        size = sc.size
        s = x[:size] / sc
        s[size // 2:] *= h
        return math.sqrt(float(np.vdot(s, s).real) / size)

    def _error_norm(self, y: np.ndarray, y_new: np.ndarray, err: np.ndarray, h: float
                    ) -> float:
        """The step's error estimate ``err`` in the norm of :meth:`_norm`, with sc_i = atol
        scale_i + rtol max(|y_i|, |y_new_i|); where the equations integrate in coordinates
        of their own (``error_map``: relative coordinates), in the model's coordinates,
        which the tolerance is given for."""
        if self._error_map is not None:
            y, y_new, err = self._error_map(y, y_new, err)
        sc = np.maximum(np.abs(y), np.abs(y_new))
        sc *= self.rtol
        sc += self._atol_error
        return self._norm(err, sc, self._hv(h))

    def _stage_weights(self, sc: np.ndarray, h: float) -> tuple:
        """The weights of :meth:`_norm_stages` and :meth:`_residual_norm` for one Newton
        iteration's scale sc and step h (made once per iteration, not per norm: on the stiff
        pendulum the norms' arithmetic is less than numpy's cost per call).

        Two norms of a correction: w[0] weighs the velocities by h / sc_v, as the error
        estimate's index-3 scaling does; the contraction rate is measured in it (a
        correction of the positions by dq moves the stages' velocities by about dq / h at the
        next iteration, which a norm without h reads as divergence: a four-bar's stiff slider
        at t = 0, rate 2.3 at every step size). The iteration stops where the correction
        left is below newton_tol with the velocities counted in full, w[5] = 1 / sc_v: a
        stage's velocity left off by newton_tol sc_v / h (the index-3 scaling's allowance)
        is an error of the same sign at every step, which adds up over the run (a spinning
        rod on a slider, 3 s at rtol 1e-8: 1.9e-6 rad off the Lagrange oracle, 2.7e-9
        counted in full). Only down to their rounding, though: the stages' velocities are
        differences of positions over h, A^-1 Z / h, and carry ``ROUNDING`` eps |q|_max / h
        that no iteration removes, so sc_v is at least that over newton_tol (near rtol 1e-10
        on a double pendulum's whip, steps of 1e-5 s, a smaller scale never converged and
        the step size underflowed); and w[5] is never below w[0]'s velocity weights, so the
        test is never looser than the h-weighted one (where h > 1, or at the floor)."""
        n = self.n
        G = self._norms[3] if self._norms[3] > 0 else 1.0
        rounding = ROUNDING * _EPS * float(np.abs(self.y[:n]).max()) / h
        inverse = 1.0 / sc
        dz = inverse.copy()
        dz[n:] *= h
        # (never looser than the h-weighted test: where h > 1, or the floor is above h sc_v)
        full = np.maximum(np.minimum(inverse[n:], max(self.newton_tol, _EPS) / rounding)
                          if rounding > 0 else inverse[n:], dz[n:])
        return dz, h * inverse[:n], h / self._mass_diag, self._hv(h) * inverse[n:], \
            inverse[:n].max() / G if self.m else 0.0, full

    def _norm_stages(self, dZ: np.ndarray, w: tuple) -> tuple[float, float]:
        """sqrt(mean_j |dZ_j|^2) over the three stages, each by :meth:`_norm`, and the same
        with the velocities counted in full (``w`` from :meth:`_stage_weights`)."""
        n = self.n
        x = dZ[:, :2 * n] * w[0]
        xv = dZ[:, n:2 * n] * w[5]
        q2 = float(np.vdot(x[:, :n], x[:, :n]).real)
        return (math.sqrt((q2 + float(np.vdot(x[:, n:], x[:, n:]).real)) / (6 * n)),
                math.sqrt((q2 + float(np.vdot(xv, xv).real)) / (6 * n)))

    def _residual_norm(self, r: np.ndarray, w: tuple) -> float:
        """The stage residuals r (3, 2n + m) as errors of the state they would cause, in the
        error norm: a velocity mismatch r_q over a step moves q by h r_q; a force residual
        r_v changes the velocities by h M^-1 r_v (M's diagonal), the positions by h times
        that; a constraint residual r_lambda is a position error of |r_lambda| / |Phi_q|
        (one entry per stage, its largest). ``w`` from :meth:`_stage_weights`."""
        n = self.n
        total = _state_residual(r[:, :n], r[:, n:2 * n], w)
        count = 6 * n
        if self.m:
            e = np.abs(r[:, 2 * n:]).max(axis=1) * w[4]
            total += float(e @ e)
            count += 3
        return math.sqrt(total / count)

    def _hv(self, h: float) -> float:
        """The factor of the velocities' error in the error norm: h (Hairer's index-3
        scaling) or 1 (``index3_scaling`` False: velocities held to the tolerance too)."""
        return h if self.index3_scaling else 1.0

    def _transformed_solve(self, h: float) -> Callable[[np.ndarray], np.ndarray]:
        """dZ from the stage residuals r by the transformed pair (T^-1 r: one real and one
        complex system with the common Jacobian)."""
        mur, muc = _K["mu_real"] / h, _K["mu_complex"] / h

        def solve(r: np.ndarray) -> np.ndarray:
            dWr = self._solve(0, mur, -(_K["TI_real"] @ r))
            dWc = self._solve(1, muc, -(_K["TI_complex"] @ r))
            return _K["T"] @ np.vstack((dWr, dWc.real, dWc.imag))
        return solve

    def _stage_jacobians(self, t: float, h: float, Z: np.ndarray
                         ) -> tuple[list[tuple], list[tuple]]:
        """(M, dQ/dq - curvature, dQ/dv, Phi_q) at each stage of the guess Z, and the
        terms of the stage residuals there (Phi, Phi_q, M, Q), for the Newton iteration's
        first residual, which is at the same states."""
        eq, n = self.equations, self.n
        jacs, terms = [], []
        for j in range(3):
            tj, qj, vj = t + _K["c"][j] * h, self.y[:n] + Z[j, :n], self.y[n:] + Z[j, n:2 * n]
            dq, dv = eq.load_derivatives(tj, qj, vj)
            dq = self._stiffness(tj, qj, dq, self.lam + Z[j, 2 * n:])
            phi, G = self._phi_jac(tj, qj)
            M, Q = self._mass_loads(tj, qj, vj)
            terms.append((phi, G, M, Q))
            jacs.append((_mat(M), _mat(dq), _mat(dv), _mat(G)))
            self.njev += 1
        return jacs, terms

    def _stagewise_solve(self, t: float, h: float, Z: np.ndarray
                         ) -> tuple[Callable[[np.ndarray], np.ndarray], list[tuple]]:
        """The coupled stage system (module radau_stages) with the stages' own Jacobians at
        the guess Z, and the stages' terms there (:meth:`_stage_jacobians`); the common
        Jacobian (for the error estimate) is the first stage's."""
        jacs, terms = self._stage_jacobians(t, h, Z)
        self._jac = jacs[0]
        self._set_pattern()
        jacs[0] = self._jac  # (made dense there for a few bodies: not again)
        self._factor(h, pair=False)
        coupled = CoupledStages(jacs, h, _K["A"], _K["Ainv"], self.n, self.m,
                                self._delta(_K["mu_real"] / h))
        self.nlu += 1
        return coupled.solve, terms

    def _newton(self, t: float, h: float, Z: np.ndarray, sc: np.ndarray,
                solve: Callable[[np.ndarray], np.ndarray], at_guess: list | None = None
                ) -> tuple[bool, int, np.ndarray, float]:
        """Simplified Newton on the stage system from the guess Z (3, 2n + m), dZ =
        solve(residual); ``at_guess``: each stage's (Phi, Phi_q, M, Q) at Z where the caller
        has them. Returns (converged, iterations, Z, contraction rate): :class:`_Stopping`."""
        n, m = self.n, self.m
        y0, lam0 = self.y, self.lam
        c = _K["c"]
        dZ_norm_old, rate, r = None, None, np.empty_like(Z)
        w = self._stage_weights(sc, h)
        current = self._jac_current or self._stagewise
        stop = _Stopping(self.newton_tol, current, self.max_newton)
        for k in range(max(self.max_newton, self.max_newton_singular)):
            D = _K["Ainv"] @ Z[:, :2 * n] / h  # the stages' derivatives of q and v
            Y = y0 + Z[:, :2 * n]  # the stages' states
            r[:, :n] = D[:, :n] - Y[:, n:]
            for j in range(3):
                qj, vj = Y[j, :n], Y[j, n:]
                if k == 0 and at_guess is not None:
                    phi, G, M, Q = at_guess[j]
                elif m:
                    tj = t + c[j] * h
                    phi, G = self._phi_jac(tj, qj)
                    M, Q = self._mass_loads(tj, qj, vj)
                else:  # an ODE (module reduced): no constraint to evaluate
                    M, Q = self._mass_loads(t + c[j] * h, qj, vj)
                if m:
                    r[j, n:2 * n] = M @ D[j, n:] - Q + G.T @ (lam0 + Z[j, 2 * n:])
                    r[j, 2 * n:] = -np.asarray(phi)
                else:
                    r[j, n:] = M @ D[j, n:] - Q
            self.nfev += 3
            if not math.isfinite(r.sum()):  # (one sum: a NaN or an inf anywhere)
                return stop.failed(k, Z, np.inf)
            if k and self._residual_norm(r, w) <= self.residual_tol * self.newton_tol:
                # the equations hold to far below the tolerance: what a further correction
                # would change is noise (near a singular position the iteration matrix is
                # ill conditioned and amplifies the residual's rounding into corrections
                # that never shrink; A02 at 0.72 s, rtol 1e-8)
                return stop.converged(k, Z, rate)
            dZ = solve(r)
            dZ_norm, full = self._norm_stages(dZ, w)
            if dZ_norm_old is not None:
                rate = dZ_norm / dZ_norm_old
                # at a singular position (a root where Phi_q loses rank) Newton converges
                # only linearly, at 0.5 to 0.9 per iteration: such a rate may go on to
                # ``max_newton_singular`` iterations (A02's collinear passages at rtol 1e-8)
                # (with a Jacobian of the step's start or the stages' own: a slow rate with
                # an older one asks for a new Jacobian, after max_newton)
                limit = self.max_newton_singular if rate <= self.singular_rate and current \
                    else self.max_newton
                if rate >= 1 or k >= limit or rate ** (limit - k) / (1 - rate) * dZ_norm \
                        > self.newton_tol:
                    return stop.failed(k, Z, rate)
            Z = Z + dZ
            done = stop.after(k, Z, rate, dZ_norm, full)
            if done:
                return done
            dZ_norm_old = dZ_norm
        return stop.exhausted(self.max_newton, Z, rate)

    def _newton_ode(self, t: float, h: float, Z: np.ndarray, sc: np.ndarray, L: np.ndarray,
                    S: np.ndarray) -> tuple[bool, int, np.ndarray, float]:
        """:meth:`_newton` for a small ODE (m = 0, the correction one matrix L and the
        stages' linear part one matrix S of :func:`_ode_operators`): the same iteration and
        tests, without the constraints' terms. The iterate is z = Z.ravel() and the residual
        is kept in block order (the stages' velocity residuals, then their equations of
        motion), so that an iteration is a few products of small arrays: on the stiff
        pendulum numpy's cost per call is most of the arithmetic."""
        n = self.n
        y0 = self.y
        stages = getattr(self.equations, "stage_residuals", None) or self._ode_stages
        tj = [t + c * h for c in _C]
        w = self._stage_weights(sc, h)
        # the norms' weights (:meth:`_norm_stages`) on the three stages' corrections:
        # squared, h-weighted and in full, one product for both sums
        squares = np.empty((2 * n, 2))
        squares[:, 0] = w[0] * w[0]
        squares[:n, 1], squares[n:, 1] = squares[:n, 0], w[5] * w[5]
        squares = np.concatenate((squares, squares, squares))
        count = 6 * n
        limit, tol = self.max_newton, self.newton_tol
        y0s = np.concatenate((y0, y0, y0))
        v0s = y0s[_block_order(n)[3 * n:]]
        z = Z.ravel()
        old = rate = None
        stop = _Stopping(tol, self._jac_current, limit)
        for k in range(limit):
            r = S @ z
            r[:3 * n] -= v0s
            r[3 * n:] = stages(tj, y0s + z, r[3 * n:])
            self.nfev += 3
            if k and self._residual_norm_ode(r, w) <= self.residual_tol * tol:
                return stop.converged(k, z.reshape(3, 2 * n), rate)
            dz = L @ r
            sums = (dz * dz) @ squares
            norm, full_norm = math.sqrt(sums[0] / count), math.sqrt(sums[1] / count)
            if not math.isfinite(norm + full_norm):  # (a NaN or an inf in the residual)
                return stop.failed(k, z.reshape(3, 2 * n), np.inf)
            if old is not None:
                rate = norm / old
                if rate >= 1 or rate ** (limit - k) / (1 - rate) * norm > tol:
                    return stop.failed(k, z.reshape(3, 2 * n), rate)
            z = z + dz
            done = stop.after(k, z.reshape(3, 2 * n), rate, norm, full_norm)
            if done:
                return done
            old = norm
        return stop.exhausted(limit, z.reshape(3, 2 * n), rate)

    def _ode_stages(self, ts: list, Y: np.ndarray, A: np.ndarray) -> np.ndarray:
        """M(Y_j) A_j - Q(t_j, Y_j) of the three stages (Y (6n,) and A (3n,) stage-major),
        flat: for equations without ``stage_residuals``."""
        n = self.n
        Y, A = Y.reshape(3, 2 * n), A.reshape(3, n)
        out = np.empty((3, n))
        for j in range(3):
            M, Q = self._mass_loads(ts[j], Y[j, :n], Y[j, n:])
            out[j] = M @ A[j] - Q
        return out.ravel()

    def _residual_norm_ode(self, r: np.ndarray, w: tuple) -> float:
        """:meth:`_residual_norm` of an ODE's residual r in block order (6n,)."""
        rq, rv = r.reshape(2, 3, self.n)
        return math.sqrt(_state_residual(rq, rv, w) / (6 * self.n))

    def step(self) -> str | None:
        """Rule 2: one accepted step (module docstring), or the reason there is none."""
        t, y, n = self.t, self.y, self.n
        N = 2 * n + self.m
        h = min(self.h_abs, self.max_step, self.t_bound - t)
        rejected = cut = False
        while True:
            if self.attempts >= self.max_attempts:  # rule 2: rejected attempts count too
                self.h_abs = h
                return OUT_OF_BUDGET
            if h < 10 * math.ulp(max(abs(t), abs(self.t_bound))):
                return f"the step size underflowed at t = {t:.9g}"
            if self.t_bound - t - h < 1e-10 * h:  # land on t_bound, not a hair before it
                h = self.t_bound - t
            if self._Z is None:
                Z0 = np.zeros((3, N))
            else:  # extrapolate the last step's collocation polynomial (Hairer)
                Z0 = _extrapolated(self._Z, t, h, self.t_old, self._h_prev)
            at_guess, L = None, None
            try:
                if self._stagewise:
                    solve, at_guess = self._stagewise_solve(t, h, Z0)
                else:
                    if self._jac is None:
                        self._jacobian(t, y)
                        self._jac_current = True
                    if self._lu is None or self._lu_h != h:
                        self._factor(h)
                    # a small ODE's correction is one matrix (_ode_operators), else the
                    # transformed pair's solves
                    L = None if self._ops is None else self._ops[1]
                    solve = None if L is not None else self._transformed_solve(h)
            except RuntimeError:  # SuperLU: the matrix is exactly singular
                return f"the equations are singular at t = {t:.9g}"
            sc = self._atol + self.rtol * np.abs(y)
            if L is not None:
                ok, k, Z, rate = self._newton_ode(t, h, Z0, sc, L, self._ops[2])
            else:
                ok, k, Z, rate = self._newton(t, h, Z0, sc, solve, at_guess)
            if not ok:
                self.nrejected += 1
                if not self._stagewise and not self._jac_current:
                    self._jacobian(t, y)
                    self._jac_current = True
                    continue
                if not self._stagewise and self.stage_jacobians:
                    # a fresh common Jacobian does not converge: the stages need their own
                    self._stagewise, self._stagewise_steps = True, 0
                    if self._retrying:
                        self._retry_every = min(2 * self._retry_every,
                                                RETRY_CAP * self.stagewise_retry)
                    self._retrying = False
                    continue
                h *= 0.5
                self._lu, rejected, cut = None, True, True
                continue
            # the error estimate of RADAU5 with the mass matrix B0 = diag(I, M0, 0)
            ZE = _K["E"] @ Z / h
            M0 = self._M0
            base = self._F0.copy()
            base[n:2 * n] += M0 @ ZE[n:2 * n]
            base[:n] += ZE[:n]
            err = self._solve(0, _K["mu_real"] / h, base)
            y_new = y + Z[2, :2 * n]
            err_norm = self._error_norm(y, y_new, err, h)
            if err_norm > 1 and (rejected or self.naccepted == 0):
                F1 = self._F(t, y + err[:2 * n], self.lam + err[2 * n:])
                F1[n:2 * n] += M0 @ ZE[n:2 * n]
                F1[:n] += ZE[:n]
                err_norm = self._error_norm(y, y_new, self._solve(0, _K["mu_real"] / h, F1),
                                            h)
            if not math.isfinite(err_norm):
                err_norm = math.inf
            fac = self.safety * (2 * self.max_newton + 1) / (2 * self.max_newton + k)
            if err_norm > 1:
                self.nrejected += 1
                h *= max(self.min_factor, fac * err_norm ** -0.25)
                self._lu, rejected = None, True
                continue
            break
        # accepted
        if self._err_prev is None or self._h_prev is None or err_norm == 0 or cut:
            mult = 1.0
        else:
            mult = h / self._h_prev * (self._err_prev / err_norm) ** 0.25
        factor = min(1.0, mult) * (err_norm ** -0.25 if err_norm > 0 else self.max_factor)
        factor = min(self.max_factor, fac * factor)
        if rejected:
            factor = min(1.0, factor)  # no growth right after a rejection
        recompute = k > 2 and rate > self.jac_rate
        # a step size kept to keep the factorisations; the stagewise system (radau_stages)
        # is factorised at every step anyway: there the step grows as the error allows
        if not recompute and factor < self.keep_ratio and not self._stagewise:
            factor = 1.0
        self.t_old, self.y_old = t, y
        # Phi and Phi_q at the step's end, once: the multipliers' range parts (the stages'
        # and the step's start's, in one solve) and F there
        phi_jac = self.equations.phi_jac(t + h, y_new[:n]) if self.m else None
        if self.m:  # (an ODE has no multiplier)
            ranged = self._range_part(t + h, y_new,
                                      np.column_stack((Z[:, 2 * n:].T, self.lam)), phi_jac)
            Z[:, 2 * n:] = ranged[:, :3].T
            self.lam = ranged[:, 3] + Z[2, 2 * n:]
        self.t, self.y = t + h, y_new
        self._Z, self._h_prev, self._err_prev = Z, h, err_norm
        self.h_abs = h * factor
        self.naccepted += 1
        self._F0 = self._F(self.t, self.y, self.lam, phi_jac, start=True)
        self._jac_current = False
        if not self._stagewise and self._retrying:  # the common Jacobian held a step
            self._retry_every, self._retrying = self.stagewise_retry, False
        if self._stagewise:
            self._stagewise_steps += 1
            if self._stagewise_steps >= self._retry_every:
                self._stagewise, self._jac, self._lu = False, None, None
                self._retrying = True
        elif recompute:
            self._jacobian(self.t, self.y)
            self._jac_current = True
        return None

    def _range_part(self, t: float, y: np.ndarray, lam: np.ndarray,
                    phi_jac: tuple | None = None) -> np.ndarray:
        """lambda's component in the range of Phi_q (lam (m,) or (m, k)),
        (G G^T + eps I)^-1 G G^T lam with G = Phi_q at (t, y) and eps = ``regularization``
        |G|^2: the part along redundant directions (G^T l = 0), which the equations leave
        free and the regularised Newton lets drift (it divides the curvature left in Phi
        along them by delta), is removed; the motion, which sees only G^T lambda, is
        unchanged. Without redundant constraints it is the identity to
        ``regularization``."""
        if not self.m:
            return lam
        G = (phi_jac if phi_jac is not None else self.equations.phi_jac(t, y[:self.n]))[1]
        if self.m <= _DENSE_RANGE:  # a few equations: dense, no sparse bookkeeping
            g = G.toarray() if hasattr(G, "toarray") else \
                np.atleast_2d(np.asarray(G, dtype=float))
            eps = self.regularization * max(float(np.abs(g).max()), 1e-300) ** 2
            ggt = g @ g.T
            rhs = ggt @ lam
            ggt[range(self.m), range(self.m)] += eps
            # G G^T + eps I is symmetric positive definite: LAPACK's Cholesky solve (where
            # it is not, a NaN in G: the LU's answer, NaN too, which the step's tests catch)
            _, x, info = _posv()(ggt, rhs, lower=1)
            return x if info == 0 else np.linalg.solve(ggt, rhs)
        eps = self.regularization * max(_amax(G), 1e-300) ** 2
        rhs = G @ (G.T @ lam)
        import scipy.sparse as sp  # (lazily: the registry's import stays cheap)
        from scipy.sparse.linalg import splu
        G = G.tocsc() if sp.issparse(G) or isinstance(G, Triplets) else \
            sp.csc_matrix(np.atleast_2d(G))
        GGt = (G @ G.T + eps * sp.eye(self.m, format="csc")).tocsc()
        return splu(GGt, permc_spec="COLAMD").solve(np.asarray(rhs))

    def dense_output(self) -> Callable[[float], np.ndarray]:
        """Rule 3: the collocation polynomial of the last step, y(t_old + x h) =
        y_old + sum_k x^k (P^T Z)_k, x in [0, 1] (exact at the stages)."""
        Qp = _K["P"].T @ self._Z[:, :2 * self.n]  # (3, 2n)
        t_old, h, y_old = self.t_old, self._h_prev, self.y_old

        Q1, Q2, Q3 = Qp

        def u(t: float) -> np.ndarray:
            x = (np.asarray(t, float) - t_old) / h
            if x.ndim == 0:
                x = float(x)
                return y_old + x * (Q1 + x * (Q2 + x * Q3))  # (Horner)
            return (x[:, None] ** _CUBIC @ Qp + y_old).T
        return u

    def restart(self, y: np.ndarray) -> None:
        """Rule 4: continue from y at t. The extrapolation of the last step is dropped. A
        state moved by no more than the tolerance (|y - self.y| <= 1 in the error norm, as a
        projection at an output moves it) keeps the multipliers and the Jacobian: the
        simplified Newton's matrix is an approximation of that order anyway; a larger move
        evaluates both anew."""
        y = np.array(y, dtype=float)
        sc = self._atol + self.rtol * np.abs(y)
        moved = self._norm(y - self.y, sc, 1.0) > 1.0
        self.y, self._Z, self._err_prev = y, None, None
        if moved:
            self.lam = self._multipliers(self.t, y)
            self._jac, self._lu = None, None
        self._F0 = self._F(self.t, y, self.lam, start=True)
