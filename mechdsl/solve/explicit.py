"""Explicit Runge-Kutta integration with error control, dense output and projection.

Three embedded pairs (coefficients in :mod:`mechdsl.solve.tableaus`), the derivative at the
step's end serving as the next step's first stage in each:

* :data:`VERN9`, Verner's "most efficient" 9(8): a 9th-order step from 16 stages, the error
  estimated against the embedded 8th-order solution, err = h |sum_s E_s K_s / sc|_rms, and
  Verner's interpolant of order 8 (four more stages, computed only for steps that contain
  output instants). The fewest evaluations for a tight tolerance.
* :data:`DOP853`, Dormand and Prince's 8(5,3) (Hairer, Norsett and Wanner, Solving Ordinary
  Differential Equations I, 2nd ed., sec. II.10, code DOP853): an 8th-order step from 12
  stages, an error estimate that combines the embedded 5th- and 3rd-order solutions,

      err = h |e5|^2 / sqrt(|e5|^2 + 0.01 |e3|^2) / sqrt(N),   |e|^2 = sum (e_i / sc_i)^2,

  and a 7th-order interpolant (three more stages).
* :data:`DOPRI5`, their 5(4) (sec. II.5, code DOPRI5): a 5th-order step from 6 stages,
  err = h |sum_s E_s K_s / sc|_rms with E the difference of the 5th- and 4th-order weights,
  and a 4th-order interpolant without extra stages. The fewest evaluations for a loose
  tolerance.

With sc_i = atol_i + rtol max(|y_i|, |y_new,i|), a step is accepted where err <= 1 and the
next step is h_new = h min(10, max(0.2, 0.9 err^(-1/(q+1)))) (q the order of the error
estimate: 8, 7 or 4), not larger than h after a rejection.

What is specific to constrained mechanical systems: after every accepted step the state is
passed through ``settle`` (onto the constraint manifolds, to the precision the next step
needs), or through ``project`` where the step ends at an output; the step's last stage serves
as the next step's first (first-same-as-last; ``carry`` puts in what the corrected state
gives of it exactly) unless the projection moved the state by more than the tolerance, when
the derivative is evaluated again there. (A projection within the
tolerance changes the derivative by as little as the step's own error does: on Andrews'
mechanism, evaluating it anew changed neither a step size nor the error at t = 0.03 in three
digits, at every rtol from 1e-4 to 1e-10, and cost 6 % more evaluations.) Every output is
the interpolant at the output instant, projected. A lean loop: one preallocated stage
array, a handful of numpy calls per stage besides the derivative.

What belongs to the loop that drives the steps rather than to a pair's arithmetic: the
outputs, the projections, the failures, the interrupts, a budget of ``max_steps`` attempts
(accepted and rejected steps together: a run that can never end, over 1e12 s at rtol
1e-12, stops there with status "failed", reason "budget", its outputs so far kept) and
``on_step(t, steps)``, called after every accepted step with the time reached and the
attempts so far (one output interval may take millions of steps: a display fed by the
outputs alone would stand still). It costs a Python call per step, against the 6 to 20
evaluations of the derivative a step takes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import tableaus as T


_SAFETY, _MIN_FACTOR, _MAX_FACTOR = 0.9, 0.2, 10.0


@dataclass(frozen=True)
class Method:
    """An embedded explicit Runge-Kutta pair whose step's end is the next step's first stage:
    ``stages`` stages per step (stage ``stages`` + 1 is the derivative at the step's end),
    nodes ``c`` and rows ``a`` of its matrix (a[s] (s,); rows past ``stages`` + 1 are the
    dense output's extra stages), weights ``b``; ``error(K, h, sc)`` the scaled error norm
    of a step (``inf`` where it is not a number) and ``exponent`` = -1 / (q + 1), q the
    order of that estimate; ``interpolant(f, K, t, h, y, y_new)`` its continuous extension,
    y(t + x h) for x in [0, 1], computing the extra stages it needs into K."""

    name: str
    order: int
    stages: int
    c: tuple[float, ...]  # (Python floats: t + c h on numpy scalars costs five times more)
    a: tuple[np.ndarray, ...]
    b: np.ndarray
    exponent: float
    error: Callable[[np.ndarray, float, np.ndarray], float]
    interpolant: Callable[..., Callable[[float], np.ndarray]]


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


def _extra_stages(method: "Method", f, K: np.ndarray, t: float, h: float, y: np.ndarray,
                  first: int) -> None:
    """The interpolant's stages ``first`` .. (0-based rows of K) beyond the step's end."""
    for s in range(first, len(method.a)):
        K[s] = f(t + method.c[s] * h, y + h * (method.a[s] @ K[:s]))


def _polynomial(K: np.ndarray, P: np.ndarray, h: float, y: np.ndarray
                ) -> Callable[[float], np.ndarray]:
    """y(t + x h) = y + h sum_j (K^T P)[:, j] x^(j + 1) (scipy's and Verner's form)."""
    Q = h * (K[: len(P)].T @ P)  # (N, degree)
    powers = np.arange(1, P.shape[1] + 1)

    def at(x: float) -> np.ndarray:
        return y + Q @ (x ** powers)

    return at


# -- DOP853 ------------------------------------------------------------------------------------
_D8 = T.DOP853


def _dop853_error(K: np.ndarray, h: float, sc: np.ndarray) -> float:
    """err = h |e5|^2 / sqrt(|e5|^2 + 0.01 |e3|^2) / sqrt(N), the 5th- and 3rd-order
    estimates combined (Hairer, Norsett and Wanner, sec. II.10)."""
    e5 = (_D8.E5 @ K[: _D8.N_STAGES + 1]) / sc
    e3 = (_D8.E3 @ K[: _D8.N_STAGES + 1]) / sc
    n5, n3 = float(e5 @ e5), float(e3 @ e3)
    denom = n5 + 0.01 * n3
    if not np.isfinite(denom):
        return np.inf
    return abs(h) * n5 / np.sqrt(denom * len(sc)) if denom > 0 else 0.0


def _dop853_interpolant(f, K: np.ndarray, t: float, h: float, y: np.ndarray,
                        y_new: np.ndarray) -> Callable[[float], np.ndarray]:
    """DOP853's continuous extension over the step (three more stages): y(t + x h) for x in
    [0, 1], of order 7."""
    _extra_stages(DOP853, f, K, t, h, y, _D8.N_STAGES + 1)
    dy = y_new - y
    F = np.empty((_D8.INTERPOLATOR_POWER, len(y)))
    F[0] = dy
    F[1] = h * K[0] - dy
    F[2] = 2 * dy - h * (K[_D8.N_STAGES] + K[0])
    F[3:] = h * (_D8.D @ K)
    rev = F[::-1]

    def at(x: float) -> np.ndarray:
        out = np.zeros(len(y))
        for i, row in enumerate(rev):
            out += row
            out *= x if i % 2 == 0 else 1 - x
        return out + y

    return at


#: Dormand and Prince's 8(5,3)
DOP853 = Method(
    "dop853", 8, _D8.N_STAGES, tuple(_D8.C.tolist()),
    tuple(np.ascontiguousarray(_D8.A[s, :s]) for s in range(_D8.N_STAGES_EXTENDED)),
    _D8.B, -1.0 / 8.0, _dop853_error, _dop853_interpolant)

# -- DOPRI5 ------------------------------------------------------------------------------------
_E5_4, _P5 = np.array(T.E5_4), np.array(T.P5)


def _dopri5_interpolant(f, K: np.ndarray, t: float, h: float, y: np.ndarray,
                        y_new: np.ndarray) -> Callable[[float], np.ndarray]:
    """DOPRI5's continuous extension of order 4 (no extra stage)."""
    return _polynomial(K, _P5, h, y)


#: Dormand and Prince's 5(4)
DOPRI5 = Method("dopri5", 5, 6, T.C5, tuple(np.array(row) for row in T.A5),
                np.array(T.A5[6][:6]), -1.0 / 5.0, _rms_error(_E5_4), _dopri5_interpolant)

# -- Verner's 9(8) -----------------------------------------------------------------------------
#: the 9th-order weights (stages 1 .. 15) and the error weights against the 8th-order ones
_B9 = _row(T.B9_8[9], 16)
_E9_8 = _B9 - _row(T.B9_8[8], 16)
_P9 = np.array(T.P9)


def _vern9_interpolant(f, K: np.ndarray, t: float, h: float, y: np.ndarray,
                       y_new: np.ndarray) -> Callable[[float], np.ndarray]:
    """Verner's interpolant of order 8: four more stages after the step's end (stage 17)."""
    _extra_stages(VERN9, f, K, t, h, y, 17)
    return _polynomial(K, _P9, h, y)


#: Verner's "most efficient" 9(8)
VERN9 = Method(
    "vern9", 9, 16, tuple(float(c) for c in T.C9) + (1.0,) + T.C9_INTERPOLANT,
    tuple([np.zeros(0), *_rows(T.A9, 2, 16), _B9, *_rows(T.A9_INTERPOLANT, 18, 21)]),
    _B9, -1.0 / 9.0, _rms_error(_E9_8), _vern9_interpolant)

#: The methods by name.
METHODS = {m.name: m for m in (DOP853, DOPRI5, VERN9)}


@dataclass(frozen=True)
class Problem:
    """y' = rhs(t, y); ``project(t, y)`` moves a state onto the constraints (or None), to
    the precision of the outputs; ``settle(t, y)``, where given, does it after each step
    that does not end at an output, to the precision the next step needs (a cheaper one)."""

    rhs: Callable[[float, np.ndarray], np.ndarray]
    project: Callable[[float, np.ndarray], np.ndarray] | None = None
    settle: Callable[[float, np.ndarray], np.ndarray] | None = None
    #: ``carry(y, f)``: the derivative at a corrected state y from ``f``, the step's last
    #: stage at the state before the correction, with what of it y gives exactly (a
    #: mechanism's derivative begins with its velocities, which are in y)
    carry: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None


@dataclass(frozen=True)
class Solution:
    """The outputs reached (``t`` a prefix of the requested instants, ``y`` their states),
    how the integration ended ("ok", "failed", "interrupted") and why, its counts, the time
    the steps reached (past the last output where it stopped between two) and, for a
    failure, its ``reason``: "budget" where ``max_steps`` ran out, "" otherwise."""

    t: np.ndarray
    y: np.ndarray
    status: str
    message: str
    steps: int
    rejected: int
    evaluations: int
    t_reached: float = float("nan")
    reason: str = ""


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x)))


def integrate(problem: Problem, y0: np.ndarray, t_eval: np.ndarray, *, rtol: float = 1e-8,
              atol: float | np.ndarray = 1e-10, scale: np.ndarray | None = None,
              h0: float | None = None, max_step: float = np.inf, max_steps: int = 1_000_000,
              on_output: Callable[[int, float, np.ndarray], None] | None = None,
              on_step: Callable[[float, int], None] | None = None,
              method: Method = DOP853) -> Solution:
    """Integrate from ``y0`` at ``t_eval[0]`` to ``t_eval[-1]``, returning the state at every
    instant of ``t_eval`` (increasing). ``atol`` (times ``scale``, per component, if given)
    and ``rtol`` bound the local error of each step (see the module); ``h0`` is the first
    step (else Hairer's choice) and ``max_step`` the longest; ``method`` the pair that takes
    the steps (:data:`METHODS`; the forward dynamics chooses it by rtol). ``on_output(k, t,
    y)`` is called with each output as soon as it is known, ``on_step(t, steps)`` after
    each accepted step with the time reached and the steps taken, accepted and rejected;
    a KeyboardInterrupt raised there or in ``rhs`` ends the integration ("interrupted")
    with the outputs before it. A singular system (``rhs`` raising numpy's LinAlgError), a
    derivative that is not finite, or a step size that underflows ends it "failed", the
    message saying where; so does ``max_steps`` steps, accepted and rejected, before the
    end (reason "budget")."""
    rhs, project = problem.rhs, problem.project
    settle = problem.settle or project
    t_eval = np.asarray(t_eval, dtype=float)
    y = np.array(y0, dtype=float)
    n = len(y)
    atol_v = np.broadcast_to(np.asarray(atol, dtype=float) * (1.0 if scale is None else scale),
                             (n,))
    t, t_end = float(t_eval[0]), float(t_eval[-1])
    outs_t, outs_y = [], []
    counts = {"steps": 0, "rejected": 0, "evaluations": 0}

    def f(tt: float, yy: np.ndarray) -> np.ndarray:
        counts["evaluations"] += 1
        return rhs(tt, yy)

    def emit(k: int, tt: float, yy: np.ndarray) -> None:
        outs_t.append(tt)
        outs_y.append(yy)
        if on_output is not None:
            on_output(k, tt, yy)

    def done(status: str, message: str = "", reason: str = "") -> Solution:
        return Solution(np.array(outs_t), np.array(outs_y).reshape(len(outs_t), n), status,
                        message, counts["steps"], counts["rejected"], counts["evaluations"],
                        t, reason)

    stages, c, a, b, error = method.stages, method.c, method.a, method.b, method.error
    exponent = method.exponent
    K = np.empty((max(len(a), stages + 1), n))
    k_next = 1
    try:
        emit(0, t, y.copy())
        if t_end <= t:
            return done("ok")
        fy = f(t, y)
        h = (h0 if h0 is not None
             else _first_step(f, t, y, fy, rtol, atol_v, t_end - t, -exponent))
        rejected = False
        while k_next < len(t_eval):
            # the budget counts rejected steps too: they cost as much, and a step size
            # that never passes is as endless as one that passes and never arrives
            if counts["steps"] + counts["rejected"] >= max_steps:
                return done("failed", f"its budget of {max_steps:,} steps (accepted and "
                                      f"rejected) ran out at t = {t:.10g}", "budget")
            if not np.isfinite(fy).all():
                return done("failed", f"the accelerations are not finite numbers at "
                                      f"t = {t:.10g}")
            h_min = 10 * np.spacing(abs(t))
            h = min(max(h, h_min), max_step, t_end - t)
            # -- one step from (t, y) of size h -------------------------------------------
            K[0] = fy
            for s in range(1, stages):
                K[s] = f(t + c[s] * h, y + h * (a[s] @ K[:s]))
            y_new = y + h * (b @ K[:stages])
            f_new = f(t + h, y_new)
            K[stages] = f_new
            sc = atol_v + rtol * np.maximum(np.abs(y), np.abs(y_new))
            err = error(K, h, sc)
            # a stage that is not a number rejects the step: shorter ones locate where
            finite = err < np.inf and np.isfinite(f_new).all()
            if not finite:
                err = np.inf
            if err > 1.0:
                counts["rejected"] += 1
                rejected = True
                h *= max(_MIN_FACTOR, _SAFETY * err**exponent) if finite else _MIN_FACTOR
                if h < h_min:
                    why = ("the accelerations are not finite numbers" if not finite else
                           "a singular or discontinuous motion")
                    return done("failed", f"the step size fell below {h_min:.3g} after "
                                          f"t = {t:.10g} ({why})")
                continue
            counts["steps"] += 1
            t_new = t + h if t + h < t_end else t_end
            # -- outputs inside the step, by the method's interpolant (one at the step's
            # end is the projected end state, below) -----------------------------------------
            if k_next < len(t_eval) and t_eval[k_next] < t_new:
                dense = method.interpolant(f, K, t, h, y, y_new)
                while k_next < len(t_eval) and t_eval[k_next] < t_new:
                    te = float(t_eval[k_next])
                    yo = dense((te - t) / h)
                    emit(k_next, te, project(te, yo) if project is not None else yo)
                    k_next += 1
            at_output = k_next < len(t_eval) and t_eval[k_next] <= t_new
            if project is not None:
                moved = (project if at_output else settle)(t_new, y_new)
                # a projection within the tolerance (the drift of one step) keeps the
                # derivative of the step's end; a larger one evaluates it anew
                if np.abs((moved - y_new) / sc).max() > 1.0:
                    f_new = f(t_new, moved)
                elif problem.carry is not None:
                    f_new = problem.carry(moved, f_new)
                y_new = moved
            if at_output:
                emit(k_next, t_new, y_new.copy())
                k_next += 1
            factor = (_MAX_FACTOR if err == 0 else
                      min(_MAX_FACTOR, _SAFETY * err**exponent))
            if rejected:
                factor = min(1.0, factor)
            rejected = False
            t, y, fy = t_new, y_new, f_new
            h *= factor
            if on_step is not None:
                on_step(t, counts["steps"] + counts["rejected"])
    except KeyboardInterrupt:
        return done("interrupted")
    except np.linalg.LinAlgError as err:
        return done("failed", f"the equations of motion are singular near t = {t:.10g} "
                              f"({err})")
    return done("ok")


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
