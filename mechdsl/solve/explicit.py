"""The explicit Runge-Kutta pairs as steppers (:class:`mechdsl.solve.stepper.Stepper`).

Three embedded pairs (coefficients in :mod:`mechdsl.solve.tableaus`, read when a pair first
steps), the derivative at the step's end serving as the next step's first stage in each:

* :class:`Vern9`, Verner's "most efficient" 9(8): a 9th-order step from 16 stages, the error
  estimated against the embedded 8th-order solution, err = h |sum_s E_s K_s / sc|_rms, and
  Verner's interpolant of order 8 (four more stages, computed only for steps that contain
  output instants). The fewest evaluations for a tight tolerance.
* :class:`Dop853`, Dormand and Prince's 8(5,3) (Hairer, Norsett and Wanner, Solving Ordinary
  Differential Equations I, 2nd ed., sec. II.10, code DOP853): an 8th-order step from 12
  stages, an error estimate that combines the embedded 5th- and 3rd-order solutions,

      err = h |e5|^2 / sqrt(|e5|^2 + 0.01 |e3|^2) / sqrt(N),   |e|^2 = sum (e_i / sc_i)^2,

  and a 7th-order interpolant (three more stages).
* :class:`Dopri5`, their 5(4) (sec. II.5, code DOPRI5): a 5th-order step from 6 stages,
  err = h |sum_s E_s K_s / sc|_rms with E the difference of the 5th- and 4th-order weights,
  and a 4th-order interpolant without extra stages. The fewest evaluations for a loose
  tolerance.

With sc_i = atol_i + rtol max(|y_i|, |y_new,i|), a step is accepted where err <= 1 and the
next step is h_new = h min(10, max(0.2, 0.9 err^(-1/(q+1)))) (q the order of the error
estimate: 8, 7 or 4), not larger than h after a rejection. The first step is Hairer's choice
(Solving ODEs I, sec. II.4). A stage that is not a number rejects the step (shorter ones
locate where); a step size below 10 ulp of t ends the integration with a message.

After a projection (:meth:`RungeKutta.restart`), the step's last stage still serves as the
next step's first (first-same-as-last) when the projection moved the state by at most the
step's tolerance, with what the corrected state gives of it exactly (``carry``: a mechanism's
derivative begins with its velocities, which are in y); a larger change evaluates the
derivative anew. (A projection within the tolerance changes the derivative by as little as
the step's own error does: on Andrews' mechanism, evaluating it anew changed neither a step
size nor the error at t = 0.03 in three digits, at every rtol from 1e-4 to 1e-10, and cost
6 % more evaluations.) A lean loop: one preallocated stage array, a handful of numpy calls
per stage besides the derivative.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Callable, ClassVar

import numpy as np

from .stepper import OUT_OF_BUDGET, STIFF, Equations, Stepper


_SAFETY, _MIN_FACTOR, _MAX_FACTOR = 0.9, 0.2, 10.0


@dataclass(frozen=True)
class Pair:
    """The coefficients of an embedded explicit pair whose step's end is the next step's
    first stage: ``stages`` stages per step (stage ``stages`` + 1 is the derivative at the
    step's end), nodes ``c`` and rows ``a`` of its matrix (a[s] (s,); rows past ``stages`` +
    1 are the dense output's extra stages), weights ``b``; ``error(K, h, sc)`` the scaled
    error norm of a step (``inf`` where it is not a number) and ``exponent`` = -1 / (q + 1),
    q the order of that estimate; ``interpolant(f, K, t, h, y, y_new)`` its continuous
    extension, y(t + x h) for x in [0, 1], computing the extra stages it needs into K."""

    stages: int
    c: tuple[float, ...]  # (Python floats: t + c h on numpy scalars costs five times more)
    a: tuple[np.ndarray, ...]
    b: np.ndarray
    exponent: float
    error: Callable[[np.ndarray, float, np.ndarray], float]
    interpolant: Callable[..., Callable[[float], np.ndarray]]
    #: the error weights of the pairs measured by one rms norm (for the order-condition tests)
    E: np.ndarray | None = None
    #: the dense output's coefficients in scipy's and Verner's polynomial form, where it is one
    P: np.ndarray | None = None


#: An output inside a step whose h |lambda| is above this fraction of the interpolant's
#: bound (:func:`interpolant_bound`) is integrated again to it (``beyond_stability``; the
#: estimate of RungeKutta._measure_stiffness for a mechanism's state): a slider-crank's
#: rod on a spring of 1e8 N/m under DOP853 had outputs 1.1e-3 m/s off in steps at 0.90
#: and 1.4 of it. Non-stiff runs stay below it: the stiff pendulum at k = 1e2 to 1e4
#: under vern9 at most 0.57 to 0.73, Andrews 0.42, a chain of 24 links 0.39
INTERPOLANT_MARGIN = 0.8


#: :func:`interpolant_extent` of the pairs, computed once here (their scan takes 0.04 to
#: 0.25 s, which every process's first output would pay; tests/test_explicit.py checks it)
INTERPOLANT_BOUNDS = {"dopri5": 1.14, "dop853": 2.43, "vern9": 2.30}


def interpolant_bound(name: str) -> float:
    """:data:`INTERPOLANT_BOUNDS`, or for another pair :func:`interpolant_extent`."""
    bound = INTERPOLANT_BOUNDS.get(name)
    return bound if bound is not None else interpolant_extent(name)


@functools.cache
def interpolant_extent(name: str) -> float:
    """h rho up to which the interpolant of pair ``name`` amplifies no component: the
    smaller of the extents along the negative real axis and the imaginary axis where
    max over x in [0, 1] of |R_x(z)| <= 1 + 1e-3, R_x(z) the interpolant's value at x h
    after one step of y' = lambda y from y = 1, z = h lambda (the imaginary axis by y' =
    J y, J the rotation by w, whose flow from (1, 0) has the modulus |R_x(i w)|). The
    step's own boundary (:func:`stiffness_probe`) does not bound it: an explicit pair's
    interpolant at the points inside a step is not the step's stability function."""
    pair = coefficients(name)
    xs = np.linspace(0.0, 1.0, 21)

    def worst(J: np.ndarray) -> float:
        n = J.shape[0]
        f = lambda t, y: J @ y  # noqa: E731
        K = np.zeros((max(len(pair.a), pair.stages + 1), n))
        y0 = np.zeros(n)
        y0[0] = 1.0
        K[0] = f(0.0, y0)
        for i in range(1, pair.stages):
            K[i] = f(pair.c[i], y0 + pair.a[i] @ K[:i])
        y_new = y0 + pair.b @ K[:pair.stages]
        K[pair.stages] = f(1.0, y_new)
        at = pair.interpolant(f, K, 0.0, 1.0, y0, y_new)
        return max(float(np.linalg.norm(at(x))) for x in xs)

    real = _extent(lambda x: worst(np.array([[-x]])))
    imaginary = _extent(lambda w: worst(np.array([[0.0, -w], [w, 0.0]])))
    return min(real, imaginary)


def _extent(modulus: Callable[[float], float]) -> float:
    """The last x of the scan 0, 0.01, ... up to 20 before ``modulus(x)`` exceeds 1 + 1e-3
    (the extent of a stability region along a ray)."""
    x, dx = 0.0, 0.01
    while x < 20.0:
        if modulus(x + dx) > 1 + 1e-3:
            break
        x += dx
    return x


#: Hairer's counts (DOPRI5): steps in a row with h rho above the stability boundary that
#: make a model stiff, and steps below it that reset the count
STIFF_STEPS, CALM_STEPS = 15, 6

#: A first step whose h rho is this many times the stability boundary proves the model
#: stiff at once: Hairer's first step, chosen for the accuracy the motion asks for, is
#: beyond what stability allows (h the step first tried, before any rejection; rho
#: estimated on the first accepted one). The stiff pendulum (h = 5.2e-4 s first tried):
#: h rho = 22 at k = 1e8 (8.3 times vern9's boundary; 15 more steps to the report in a
#: row), 32 at 1e9, 17 at 1e10 (after rejections that cut the step to the boundary), 4.3
#: at 1e7 (1.6 times: there 50 steps to the periodic trial, twice scipy's Radau's time),
#: 5e-4 at 1e4; models that are not stiff 1e-6 (Andrews) to 0.08 (a chain of 30 links).
#: The driver's trial still decides (module driver)
EARLY_STIFF = 1.5


#: :func:`stability_threshold` of the pairs, computed once here (its scan takes 3 to 8 ms,
#: which every process's first explicit step would pay; tests/test_explicit.py checks it)
STABILITY_THRESHOLDS = {"dopri5": 1.65, "dop853": 5.364, "vern9": 2.637}


@functools.cache
def stiffness_probe(name: str) -> tuple[int | None, float, np.ndarray]:
    """The stage s of pair ``name`` at c = 1 (None if there is none), the weights w with
    y_new - Y_s = h sum_j w_j K_j (b less the row of A of stage s), and the threshold of h
    rho (:data:`STABILITY_THRESHOLDS`, or for another pair :func:`stability_threshold`)."""
    pair = coefficients(name)
    unit = max((i for i in range(1, pair.stages) if pair.c[i] == 1.0), default=None)
    weights = pair.b[:pair.stages].copy()
    if unit is not None:
        weights[:unit] -= pair.a[unit]
    threshold = STABILITY_THRESHOLDS.get(name)
    return unit, threshold if threshold is not None else stability_threshold(name), weights


@functools.cache
def stability_threshold(name: str) -> float:
    """The threshold of h rho of pair ``name``: 0.9 times its stability boundary, the
    smaller of its extents along the negative real axis and the imaginary axis (an
    undamped stiff spring's eigenvalues are imaginary) where |R(z)| <= 1 + 1e-3, R(z) = 1
    + z b^T (I - z A)^-1 1, and at least half the real extent (DOPRI5 leaves the imaginary
    axis at 1.33: threshold 1.65; DOP853: 6.4 and 6.0, 5.36; Vern9: 4.5 and 2.9, 2.64)."""
    pair = coefficients(name)
    s = pair.stages
    A = np.zeros((s, s))
    for i in range(1, s):
        A[i, :len(pair.a[i])] = pair.a[i]
    b, one, eye = pair.b[:s], np.ones(s), np.eye(s)

    def modulus(z: complex) -> float:  # |R(z)|
        return abs(1 + z * (b @ np.linalg.solve(eye - z * A, one)))

    real = _extent(lambda x: modulus(-x))
    return max(0.9 * min(real, _extent(lambda x: modulus(1j * x))), 0.5 * real)


class RungeKutta(Stepper):
    """An embedded explicit Runge-Kutta pair with first-same-as-last, Hairer's first step,
    error control and dense output (see the module); a subclass names its coefficients by
    its ``name`` (:func:`coefficients`). With ``detect_stiffness`` set (the driver sets it
    where it has an implicit method to go on with), :meth:`step` returns :data:`STIFF`
    after an accepted step once the model has proved stiff (:meth:`_stiff`)."""

    implicit: ClassVar[bool] = False
    redundant: ClassVar[bool] = False
    auto: ClassVar[bool] = True
    detect_stiffness: bool = False

    def __init__(self, equations: Equations, t0: float, y0: np.ndarray, t_bound: float, *,
                 rtol: float, atol: float | np.ndarray, scale: np.ndarray | None,
                 first_step: float | None = None) -> None:
        super().__init__(equations, t0, y0, t_bound, rtol=rtol, atol=atol, scale=scale,
                         first_step=first_step)
        self.pair = pair = coefficients(self.name)
        self._rhs = equations.rhs
        #: ``carry(y, f)``, where the equations give one: the derivative at a corrected state
        #: from the one before the correction (:meth:`restart`)
        self._carry = getattr(equations, "carry", None)
        n = len(self.y)
        self.atol_v = np.broadcast_to(
            np.asarray(atol, dtype=float) * (1.0 if scale is None else scale), (n,))
        self.K = np.empty((max(len(pair.a), pair.stages + 1), n))
        #: the derivative at (t, y): the next step's first stage
        self.f = self._eval(self.t, self.y)
        self.h = (first_step if first_step is not None else
                  _first_step(self._eval, self.t, self.y, self.f, rtol, self.atol_v,
                              self.t_bound - self.t, -pair.exponent))
        self._h_first = self.h  # the first step tried (EARLY_STIFF)
        self._sc: np.ndarray | None = None  # the last step's error scale
        self._h_step = 0.0
        self._y_end = self.y  # the last step's end as stepped (the interpolant's)
        self._dense: Callable[[float], np.ndarray] | None = None
        self._stiff_steps = self._calm_steps = 0
        #: the last stiffness estimate h rho (Hairer's), where it was made
        self.h_rho = 0.0
        #: the same for a mechanism's state y = (q, qd), which beyond_stability reads
        self._h_rho_interp = 0.0

    def _eval(self, t: float, y: np.ndarray) -> np.ndarray:
        self.nfev += 1
        return self._rhs(t, y)

    def step(self) -> str | None:
        """Rule 2: steps from (t, y) until one passes the error test (see the module)."""
        pair, K, f = self.pair, self.K, self._eval
        stages, c, a, b, error, exponent = (pair.stages, pair.c, pair.a, pair.b, pair.error,
                                            pair.exponent)
        t, y, fy, h, t_end = self.t, self.y, self.f, self.h, self.t_bound
        rejected = False
        while True:
            # the budget counts rejected steps too: they cost as much, and a step size that
            # never passes is as endless as one that passes and never arrives
            if self.attempts >= self.max_attempts:
                self.h = h
                return OUT_OF_BUDGET
            if not np.isfinite(fy).all():
                return f"the accelerations are not finite numbers at t = {t:.10g}"
            h_min = 10 * np.spacing(abs(t))
            h = min(max(h, h_min), self.max_step, t_end - t)
            K[0] = fy
            singular, finite = None, False
            with np.errstate(over="ignore", invalid="ignore"):  # (overflow: tested below)
                try:
                    for s in range(1, stages):
                        K[s] = f(t + c[s] * h, y + h * (a[s] @ K[:s]))
                    y_new = y + h * (b @ K[:stages])
                    f_new = f(t + h, y_new)
                except np.linalg.LinAlgError as exc:
                    # a stage the equations cannot be solved at: rejected and shortened, as
                    # a stage whose accelerations overflow is (a step far too long for a
                    # stiff spring throws its stages where nothing holds: a chain of 5
                    # links on rotary springs of 1e10 N m/rad stopped at t0, "singular");
                    # a state that is singular itself ends the run once the step underflows
                    singular = str(exc)
                if singular is None:
                    K[stages] = f_new
                    sc = self.atol_v + self.rtol * np.maximum(np.abs(y), np.abs(y_new))
                    err = error(K, h, sc)
                    finite = err < np.inf and np.isfinite(f_new).all()
            if not finite:
                err = np.inf
            if err <= 1.0:
                break
            self.nrejected += 1
            rejected = True
            h *= max(_MIN_FACTOR, _SAFETY * err**exponent) if finite else _MIN_FACTOR
            if h < h_min:
                self.h = h
                why = (f"the equations of motion are singular there: {singular}"
                       if singular is not None else
                       "the accelerations are not finite numbers" if not finite else
                       "a singular or discontinuous motion")
                return f"the step size fell below {h_min:.3g} after t = {t:.10g} ({why})"
        self.naccepted += 1
        factor = _MAX_FACTOR if err == 0 else min(_MAX_FACTOR, _SAFETY * err**exponent)
        if rejected:
            factor = min(1.0, factor)
        self.t_old, self.y_old = t, y
        self.t = t + h if t + h < t_end else t_end
        self.y = self._y_end = y_new
        self.f, self._sc, self._h_step, self._dense = f_new, sc, h, None
        self.h = h * factor
        self._measure_stiffness(h, f_new)
        if not self.detect_stiffness:
            # (counted afresh once it is on again: STIFF_STEPS steps in a row after that)
            self._stiff_steps = self._calm_steps = 0
        elif self._stiff(h):
            return STIFF
        return None

    @property
    def beyond_stability(self) -> bool:
        """Whether the last step's h |lambda| (for a mechanism's state y = (q, qd),
        :meth:`_measure_stiffness`) was beyond what the pair's interpolant holds
        (:func:`interpolant_bound`, times INTERPOLANT_MARGIN): its error estimate held, but
        the interpolant may amplify the stiff component inside the step (a four-bar whose
        rocker bends on a rotary spring of 1e6 N m/rad under DOP853, rtol 1e-6: outputs
        inside steps of h |lambda| 5.9 and 5.5 were 2.8e-3 and 8.4e-5 rad/s off, the steps'
        ends within 2.5e-7). The driver integrates the step's outputs again, together, in
        steps of at most :attr:`interpolant_step`; no other result changes."""
        return self._h_rho_interp > INTERPOLANT_MARGIN * interpolant_bound(self.name)

    @property
    def interpolant_step(self) -> float:
        """The step at which the last step's h |lambda| would be INTERPOLANT_MARGIN times
        the interpolant's bound (inf where none was measured)."""
        if not self._h_rho_interp > 0:
            return np.inf
        return self._h_step * INTERPOLANT_MARGIN * interpolant_bound(self.name) \
            / self._h_rho_interp

    def _measure_stiffness(self, h: float, f_new: np.ndarray) -> None:
        """h rho of the accepted step, Hairer's estimate (:meth:`_stiff`): with the stage s
        at c_s = 1, rho = |f(y_new) - K_s| / |y_new - Y_s|, the dominant eigenvalue of the
        Jacobian along the step's error; and for y = (q, qd) the same eigenvalue's modulus
        from the two parts apart (``beyond_stability``)."""
        unit, _, weights = stiffness_probe(self.name)
        if unit is None:
            self.h_rho = self._h_rho_interp = 0.0
            return
        K = self.K
        dy = h * (weights @ K[:len(weights)])  # y_new - Y_unit
        df = f_new - K[unit]
        den = float(dy @ dy)
        self.h_rho = h * math.sqrt(float(df @ df) / den) if den > 0 else 0.0
        self._h_rho_interp = self.h_rho
        n = dy.size // 2
        if 2 * n == dy.size and n:
            # y = (q, qd), J = [[0, I], [A, B]]: along an eigenvector dy = (e, lambda e),
            # df's velocity part is (A + B lambda) e = lambda^2 e, so |lambda| =
            # sqrt(|df_v| / |dy_q|). Hairer's |J dy| / |dy| mixes the parts' units and read
            # up to four times h omega on a spring (|J| is k / m there, |lambda| its root)
            dq = float(dy[:n] @ dy[:n])
            if dq > 0:
                self._h_rho_interp = h * (float(df[n:] @ df[n:]) / dq) ** 0.25

    @property
    def stiff_steps(self) -> int:
        """The accepted steps in a row with h rho above the stability boundary."""
        return self._stiff_steps

    def _stiff(self, h: float) -> bool:
        """Hairer's stiffness detection (DOPRI5, Solving ODEs II, sec. IV.2) on the step's
        h rho (:meth:`_measure_stiffness`): above the pair's stability boundary
        (:func:`stiffness_probe`) at ``STIFF_STEPS`` accepted steps in a row, not broken by
        ``CALM_STEPS`` below it, it means the step size is held by stability, not by
        accuracy: an implicit method takes far fewer steps. So does h rho above
        ``EARLY_STIFF`` times the boundary for the first step tried, rho from the first
        accepted one."""
        unit, bound, _ = stiffness_probe(self.name)
        if unit is None:
            return False
        if self.naccepted == 1 and self.h_rho * self._h_first > EARLY_STIFF * bound * h:
            self.h_rho *= self._h_first / h  # (reported for the step first tried)
            self._stiff_steps = 1
            return True
        if self.h_rho > bound:
            self._calm_steps = 0
            self._stiff_steps += 1
            return self._stiff_steps >= STIFF_STEPS
        self._calm_steps += 1
        if self._calm_steps >= CALM_STEPS:
            self._stiff_steps = 0
        return False

    def dense_output(self) -> Callable[[float], np.ndarray]:
        """Rule 3: the pair's interpolant of the last step, as stepped (its extra stages
        evaluated at the first call after the step)."""
        if self._dense is None:
            t0, h = self.t_old, self._h_step
            at = self.pair.interpolant(self._eval, self.K, t0, h, self.y_old, self._y_end)
            self._dense = lambda t: at((t - t0) / h)
        return self._dense

    def restart(self, y: np.ndarray) -> None:
        """Rule 4: continue from ``y`` at ``t``. The first-same-as-last derivative is kept,
        with what ``y`` gives of it exactly (``carry``), where y moved from the step's end
        by at most the step's tolerance (|dy_i| <= sc_i: it changes the derivative by as
        little as the step's own error does); a larger change evaluates it anew."""
        if self._sc is None or np.abs((y - self.y) / self._sc).max() > 1.0:
            self.f = self._eval(self.t, y)
        elif self._carry is not None:
            self.f = self._carry(y, self.f)
        self.y = y


class Dopri5(RungeKutta):
    name = "dopri5"
    order = 5
    robust = True
    summary = "Dormand and Prince's 5(4): the fewest evaluations at a loose tolerance"


class Dop853(RungeKutta):
    name = "dop853"
    order = 8
    # (its error estimate combines the embedded 5th- and 3rd-order ones, Hairer's design
    # against an estimate that vanishes by accident: on A02, whose collinear passages the
    # augmented Lagrangian blends, rtol 1e-8 takes 1.8 s for 5.2e-7 m where vern9's
    # 8th-order estimate takes 6.1 s for 5.8e-7 m)
    robust = True
    summary = "Dormand and Prince's 8(5,3): models on the augmented Lagrangian"


class Vern9(RungeKutta):
    name = "vern9"
    order = 9
    summary = "Verner's 9(8): the fewest evaluations at a tight tolerance"


# -- the coefficients, built from the tableaus when a pair first steps ----------------------------

@functools.cache
def coefficients(name: str) -> Pair:
    """The :class:`Pair` named ``name`` ("dopri5", "dop853", "vern9"), from the published
    tableaus (built once: the tableaus' module reads scipy's file of DOP853's)."""
    return {"dopri5": _dopri5, "dop853": _dop853, "vern9": _vern9}[name]()


def _row(entries: dict[int, float], length: int) -> np.ndarray:
    """A row of ``length`` from its non-zero entries {column: value} (columns from 1)."""
    row = np.zeros(length)
    for j, v in entries.items():
        row[j - 1] = v
    return row


def _rows(table: dict[int, dict[int, float]], first: int, last: int) -> list[np.ndarray]:
    """Rows ``first`` .. ``last`` of a matrix A given by stage as {column: value} (from 1)."""
    return [_row(table[i], i - 1) for i in range(first, last + 1)]


def _rms_error(E: np.ndarray) -> Callable[[np.ndarray, float, np.ndarray], float]:
    """The error norm err = h |sum_s E_s K_s / sc|_rms of a pair whose error weights are
    ``E`` (the higher-order weights minus the embedded solution's)."""
    stages = len(E)

    def error(K: np.ndarray, h: float, sc: np.ndarray) -> float:
        e = (E @ K[:stages]) / sc
        n = float(e @ e)
        return abs(h) * np.sqrt(n / len(sc)) if np.isfinite(n) else np.inf

    return error


def _extra_stages(a: tuple[np.ndarray, ...], c: tuple[float, ...], f, K: np.ndarray, t: float,
                  h: float, y: np.ndarray, first: int) -> None:
    """The interpolant's stages ``first`` .. (0-based rows of K) beyond the step's end."""
    for s in range(first, len(a)):
        K[s] = f(t + c[s] * h, y + h * (a[s] @ K[:s]))


def _polynomial(K: np.ndarray, P: np.ndarray, h: float, y: np.ndarray
                ) -> Callable[[float], np.ndarray]:
    """y(t + x h) = y + h sum_j (K^T P)[:, j] x^(j + 1) (scipy's and Verner's form)."""
    Q = h * (K[: len(P)].T @ P)  # (N, degree)
    powers = np.arange(1, P.shape[1] + 1)

    def at(x: float) -> np.ndarray:
        return y + Q @ (x ** powers)

    return at


def _dopri5() -> Pair:
    """Dormand and Prince's 5(4) and Shampine's interpolant of order 4 (no extra stage)."""
    from . import tableaus as T

    E, P = np.array(T.E5_4), np.array(T.P5)

    def interpolant(f, K, t, h, y, y_new):
        return _polynomial(K, P, h, y)

    return Pair(6, T.C5, tuple(np.array(row) for row in T.A5), np.array(T.A5[6][:6]),
                -1.0 / 5.0, _rms_error(E), interpolant, E, P)


def _dop853() -> Pair:
    """Dormand and Prince's 8(5,3), its error estimate and its interpolant of order 7."""
    from . import tableaus as T

    D8 = T.DOP853
    c = tuple(D8.C.tolist())
    a = tuple(np.ascontiguousarray(D8.A[s, :s]) for s in range(D8.N_STAGES_EXTENDED))

    def error(K: np.ndarray, h: float, sc: np.ndarray) -> float:
        """err = h |e5|^2 / sqrt(|e5|^2 + 0.01 |e3|^2) / sqrt(N), the 5th- and 3rd-order
        estimates combined (Hairer, Norsett and Wanner, sec. II.10)."""
        e5 = (D8.E5 @ K[: D8.N_STAGES + 1]) / sc
        e3 = (D8.E3 @ K[: D8.N_STAGES + 1]) / sc
        n5, n3 = float(e5 @ e5), float(e3 @ e3)
        denom = n5 + 0.01 * n3
        if not np.isfinite(denom):
            return np.inf
        return abs(h) * n5 / np.sqrt(denom * len(sc)) if denom > 0 else 0.0

    def interpolant(f, K, t, h, y, y_new):
        """DOP853's continuous extension over the step (three more stages)."""
        _extra_stages(a, c, f, K, t, h, y, D8.N_STAGES + 1)
        dy = y_new - y
        F = np.empty((D8.INTERPOLATOR_POWER, len(y)))
        F[0] = dy
        F[1] = h * K[0] - dy
        F[2] = 2 * dy - h * (K[D8.N_STAGES] + K[0])
        F[3:] = h * (D8.D @ K)
        rev = F[::-1]

        def at(x: float) -> np.ndarray:
            out = np.zeros(len(y))
            for i, row in enumerate(rev):
                out += row
                out *= x if i % 2 == 0 else 1 - x
            return out + y

        return at

    return Pair(D8.N_STAGES, c, a, D8.B, -1.0 / 8.0, error, interpolant)


def _vern9() -> Pair:
    """Verner's 9(8) and his interpolant of order 8 (four more stages after the step's end,
    stage 17)."""
    from . import tableaus as T

    b9 = _row(T.B9_8[9], 16)  # the 9th-order weights (stages 1 .. 15)
    E = b9 - _row(T.B9_8[8], 16)  # against the 8th-order ones
    P = np.array(T.P9)
    c = tuple(float(x) for x in T.C9) + (1.0,) + T.C9_INTERPOLANT
    a = tuple([np.zeros(0), *_rows(T.A9, 2, 16), b9, *_rows(T.A9_INTERPOLANT, 18, 21)])

    def interpolant(f, K, t, h, y, y_new):
        _extra_stages(a, c, f, K, t, h, y, 17)
        return _polynomial(K, P, h, y)

    return Pair(16, c, a, b9, -1.0 / 9.0, _rms_error(E), interpolant, E, P)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x)))


def _first_step(f, t: float, y: np.ndarray, fy: np.ndarray, rtol: float, atol: np.ndarray,
                span: float, power: float) -> float:
    """Hairer's starting step (Solving ODEs I, sec. II.4): the step whose local error
    estimate from the first two derivatives is about the tolerance (``power``: 1 / (q + 1),
    q the order of the method's error estimate)."""
    sc = atol + rtol * np.abs(y)
    d0, d1 = _rms(y / sc), _rms(fy / sc)
    h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
    h0 = min(h0, span)
    f1 = f(t + h0, y + h0 * fy)
    d2 = _rms((f1 - fy) / sc) / h0
    h1 = (max(1e-6, h0 * 1e-3) if max(d1, d2) <= 1e-15
          else (0.01 / max(d1, d2)) ** power)
    return min(100 * h0, h1, span)
