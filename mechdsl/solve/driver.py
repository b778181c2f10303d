"""The loop that drives a stepper (:mod:`mechdsl.solve.stepper`): everything that is not a step.

:func:`integrate` takes one :class:`~mechdsl.solve.stepper.Stepper` class and the equations,
and owns

* the **output instants**: every instant that falls inside a step is the stepper's dense
  output there, projected (``equations.project``); one at a step's end is the step's end
  state, projected;
* the **projections**: after every step the state is moved back onto the constraint
  manifolds, by ``project`` where the step ends at an output and by the cheaper ``settle``
  otherwise (to the precision the next step needs), and the stepper is told
  (``restart``);
* the **budget** of ``max_steps`` attempts (accepted and rejected steps together: a run
  that can never end, over 1e12 s at rtol 1e-12, stops there with status "failed", reason
  "budget", its outputs so far kept);
* **failures** (a stepper's message, numpy's LinAlgError from the equations: "failed", with
  the instant) and **interrupts** (a KeyboardInterrupt anywhere: "interrupted", with the
  outputs before it);
* **stiffness**: given ``stiff = (ImplicitStepper, equations_factory)``, the implicit
  stepper (on the equations the factory builds: the index-3 terms,
  :class:`~mechdsl.solve.motion.Motion`) is tried where the explicit one may be held by
  stiffness, in a **trial**: from the state the pair reached, apart, it takes up to
  :data:`TRIAL_STEPS` steps; where its last accepted step is :data:`TRIAL_RATIO` times the
  pair's typical step or longer (:data:`TRIAL_RATIO_FACTORISED` where every evaluation of
  the pair's equations factorises, ``equations.factorises``), the run goes on with the
  trial's stepper from where its steps reached (their outputs emitted from their dense
  outputs); else nothing of the trial is kept. The outputs, the budget and the
  counters run on across the switch, and the solution says where it happened and why
  (``switched``). A trial is made

  - where the pair reports :data:`STIFF` (rule 7: h rho at its stability boundary for
    ``STIFF_STEPS`` steps in a row, or ``EARLY_STIFF`` times the boundary at its first
    step: then against that step and TRIAL_RATIO) and the rest of the span would take it
    more than
    :data:`STIFF_MIN_STEPS` steps; the typical step is the median of its last
    :data:`TRIAL_AFTER`, those the stability holds. A stiff spring's oscillation that the
    pair resolves to the tolerance holds h rho there too, and the implicit steps are then
    no longer: a four-bar on a spring of 1e4 N/m went on with radau for 2.3 times vern9's
    time and 500 times its error. After a trial that says no, the detection pauses for
    :data:`TRIAL_AFTER` accepted steps, twice as many after each further trial that ran
    and said no, and then counts ``STIFF_STEPS`` in a row afresh;
  - after :data:`TRIAL_AFTER` accepted steps, and again after pauses that double from
    there while it runs and says no, where the rest would take the pair more than
    :data:`TRIAL_MIN_STEPS` steps: a stiffness the pair resolves rather than suffers (h
    rho well below the boundary, the step ~ 1 / rho all the same, so that its cost grows
    like sqrt(k)). The typical step is the pair's mean over the run, not its last steps:
    a passage near a singular position holds a few steps small (A02's at t = 5.18, 2e-3
    of the mean), a stiffness all of them.

  The decision reads step sizes only, never a clock: the same run decides the same way;
* **jumps** of the constraints in time (a drive written with a step, or one that starts
  abruptly): where the projection after an explicit step moves the state by more than
  :data:`JUMP_MOVE` times the step's tolerance, the constraints' position and velocity terms
  are searched for a jump in time over the step (:mod:`mechdsl.solve.jumps`). At a jump the step is
  integrated again, by a stepper of its own, up to the instant before it; a jump in
  position then ends the run there ("failed", reason "jump": no motion follows it), a
  jump in velocity goes on from the state the equations' ``impulse(t, y)`` gives (the
  constraints' impulsive motion, the velocities' mass-orthogonal projection; ``project``
  where they have none), with a fresh stepper (rule 1), and the solution lists the jumps
  met (``jumps``);
* **stalls**: where the equations can tell why their steps stall (``stalled(t, y)``: the
  dense index-1 equations, near a singular position of the constraints, which they cannot
  pass), :data:`STALL_STEPS` accepted steps in a row each shorter than :data:`STALL_RATIO`
  times the steps before them ask them; a reason ends the run "failed" there, at once,
  instead of after thousands of ever shorter steps (a parallelogram falling through its
  collinear position: 14,689 steps and 6.5 s before a projection failed; one driven
  through it by a stiff spring: 4263 steps and 2.2 s before its step size underflowed, t
  advancing by 1e-8 s; its caller then goes on by the augmented Lagrangian). No reason:
  the steps go on as before (a kink of a force, a drive's corner);
* **progress**: ``on_output(k, t, y)`` with each output as soon as it is known, and
  ``on_step(t, attempts)`` after every accepted step (one output interval may take
  millions of steps: a display fed by the outputs alone would stand still). It costs a
  Python call per step, against the 6 to 20 evaluations of the derivative a step takes.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .jumps import Jump, constraint_jumps
from .stepper import OUT_OF_BUDGET, STIFF, Equations, Stepper


#: The trial of the implicit stepper (module docstring): after this many accepted explicit
#: steps (and as the first pause before the next), where the rest would take more than
#: TRIAL_MIN_STEPS, up to TRIAL_STEPS implicit steps, and the switch where the implicit
#: step is TRIAL_RATIO times the explicit one (an implicit step costs 3 to 10 explicit
#: ones: one factorisation or two and Newton's iterations, against a pair's 7 to 16
#: evaluations)
TRIAL_AFTER, TRIAL_MIN_STEPS, TRIAL_STEPS, TRIAL_RATIO = 50, 1000, 8, 10.0

#: TRIAL_RATIO where every evaluation of the explicit pair's equations factorises a matrix
#: of the model's size (``equations.factorises``: the augmented Lagrangian of large and
#: redundant models, :class:`~mechdsl.solve.motion.Motion`): there an implicit step, which
#: keeps its factorisations, costs less than an explicit one (measured: A02 4.2 ms against
#: DOP853's 6.0, a chain of 20 links on stiff rotary springs 0.7 against 1.5): steps a
#: tenth longer are a clear gain. (At 1.5, a ladder of 8 cells on hinges of 1e7 N m/rad
#: whose radau steps were 1.1 to 1.4 times DOP853's refused ten trials and kept DOP853 to
#: t = 0.83 of 1 s, 7.9 s where radau from the start takes 4.4; at 1.1 it switches at the
#: first trial, 4.7 s)
TRIAL_RATIO_FACTORISED = 1.1

#: After a report of :data:`STIFF`, a trial is made where the rest would take the pair
#: more than this many steps of its typical size (the trial's own steps cost 24 to 80 of
#: the pair's: with fewer left, it cannot pay)
STIFF_MIN_STEPS = 100


#: A stall (module docstring): STALL_STEPS accepted steps in a row, each shorter than
#: STALL_RATIO times the run's recent step (the longest of the steps before it, fading by
#: STALL_FADE a step, so that a run whose steps shrink for good is not held to its start)
STALL_STEPS, STALL_RATIO, STALL_FADE = 100, 1e-3, 0.99


class _Stall:
    """The count of a stall (module docstring) over the accepted steps of a run."""

    def __init__(self) -> None:
        self.recent = 0.0  # the fading longest step
        self.small = 0

    def after(self, h: float) -> bool:
        """After an accepted step of size h: whether it completes a stall."""
        if h < STALL_RATIO * self.recent:
            self.small += 1
            self.recent *= STALL_FADE
            if self.small >= STALL_STEPS:
                self.small = 0
                return True
            return False
        self.small = 0
        self.recent = max(h, self.recent * STALL_FADE)
        return False


#: A projection after a step that moves the state by more than this many times the step's
#: tolerance (atol scale + rtol |y|, the largest component) has the step searched for a
#: jump of the constraints in time: a step's own error is within the tolerance, so such a
#: move is the constraints' doing (a drive that jumps) or, where none jumps, nothing to act on
JUMP_MOVE = 1e3


@dataclass(frozen=True)
class Solution:
    """The outputs reached (``t`` a prefix of the requested instants, ``y`` their states),
    how the integration ended ("ok", "failed", "interrupted") and why, the stepper's
    counters (``steps`` accepted, ``rejected``, ``evaluations`` of the equations, ``njev``
    of their derivatives, ``nlu`` factorisations), the time the steps reached (past the
    last output where it stopped between two) and, for a failure, its ``reason``: "budget"
    where ``max_steps`` ran out, "" otherwise."""

    t: np.ndarray
    y: np.ndarray
    status: str
    message: str
    steps: int
    rejected: int
    evaluations: int
    t_reached: float = float("nan")
    reason: str = ""
    njev: int = 0
    nlu: int = 0
    #: (the implicit stepper's name, the time, why) where the run switched to it
    switched: tuple | None = None
    #: what the last stepper says of its course (its ``note``, rule 5), None if nothing
    note: str | None = None
    #: the jumps of the constraints in time met on the way (:class:`mechdsl.solve.jumps.
    #: Jump`, module docstring): those gone through (velocity) and the one the run ended at
    #: (position)
    jumps: tuple = ()
    #: the output instants inside steps that their projection moved far and that could not
    #: be integrated again (no step ends there: a singular position), as the interpolant
    #: gave them, projected
    rough: tuple = ()
    #: the stepper's state where the integration ended (at t_reached), None before a step
    y_reached: np.ndarray | None = None


def integrate(stepper: type[Stepper], equations: Equations, y0: np.ndarray,
              t_eval: np.ndarray, *, rtol: float = 1e-8, atol: float | np.ndarray = 1e-10,
              scale: np.ndarray | None = None, first_step: float | None = None,
              max_step: float = np.inf, max_steps: int = 1_000_000,
              on_output: Callable[[int, float, np.ndarray], None] | None = None,
              on_step: Callable[[float, int], None] | None = None,
              stiff: tuple[type[Stepper], Callable[[], Equations]] | None = None,
              on_interval: Callable[[float, float, Callable], None] | None = None,
              raw_outputs: bool = False, redo_outputs: bool = True,
              jumps_ahead: tuple = (),
              on_outputs: Callable[[int, np.ndarray, np.ndarray, bool], None] | None = None
              ) -> Solution:
    """Integrate y' = equations.rhs(t, y) from ``y0`` at ``t_eval[0]`` to ``t_eval[-1]``
    by steps of ``stepper``, returning the state at every instant of ``t_eval``
    (increasing). ``atol`` (times ``scale``, per component, if given) and ``rtol`` bound
    the local error of each step: |err_i| <= atol_i scale_i + rtol |y_i|; ``first_step``
    is the first step (else the stepper's choice) and ``max_step`` the longest. Where
    the equations have ``project`` (and ``settle``), every state after a step and every
    output is corrected by it (see the module). ``on_output(k, t, y)`` is called with
    each output as soon as it is known (``on_outputs(k, ts, ys, raw)``, where given, with
    those a step's dense output gives together, rule 3's ``dense_arrays``: instants ts
    (K,), states ys (K, N), those of k to k + K - 1), ``on_step(t, attempts)`` after each
    accepted step
    with the time reached and the steps taken, accepted and rejected, and
    ``on_interval(t_old, t_new, dense)`` with each accepted step's span and its dense
    output, before its outputs are emitted (a quadrature along the solution); a
    KeyboardInterrupt raised there or in the equations ends the integration
    ("interrupted") with the outputs before it. ``raw_outputs``: the outputs that do not
    feed back into the integration (those inside a step, and a constrained stepper's at a
    step's end) are given to ``on_output(k, t, y, raw)`` as the dense output or the stepper
    gives them, ``raw`` True, for the caller to project (all at once:
    :mod:`mechdsl.solve.instants`); the others are projected here, ``raw`` False, and with
    ``redo_outputs`` one that its projection moves far is integrated again (:func:`_moved_far`).
    ``jumps_ahead``: jumps of the constraints in time known before the run
    (:class:`~mechdsl.solve.jumps.Jump`: a drive whose rate jumps), each met as one a
    projection finds, where a step first goes over it; a constrained stepper, which no
    projection follows, passes them so too.
    A singular
    system (the equations raising
    numpy's LinAlgError where the stepper does not take it for a rejected step: the
    explicit pairs do at a stage) or a step the stepper cannot take (a derivative that is
    not finite, a step size that underflows) ends it "failed", the message saying where;
    so does ``max_steps`` steps, accepted and rejected, before the end (reason
    "budget")."""
    project = getattr(equations, "project", None)
    settle = getattr(equations, "settle", None) or project
    t_eval = np.asarray(t_eval, dtype=float)
    y = np.array(y0, dtype=float)
    n, n_out = len(y), len(t_eval)
    t, t_end = float(t_eval[0]), float(t_eval[-1])
    outs_t: list[float] = []
    outs_y: list[np.ndarray] = []  # the outputs' states, one (n,) or a block (K, n) each
    s: Stepper | None = None

    def emit(k: int, tt: float, yy: np.ndarray, raw: bool = False) -> None:
        outs_t.append(tt)
        outs_y.append(yy)
        if on_output is not None:
            if raw_outputs:
                on_output(k, tt, yy, raw)
            else:
                on_output(k, tt, yy)

    def emit_inside(k: int, tt: float, yy: np.ndarray) -> None:
        """An output inside a step, from its dense output (integrated again from the
        step's start where its projection moves it far: :func:`_moved_far`)."""
        if s.exact_outputs:  # (on the constraints by construction: rule 6)
            emit(k, tt, yy)
        elif raw_outputs or project is None:
            emit(k, tt, yy, project is not None)
        else:
            projecting[0] = tt  # (where a failure of the projection is)
            out = project(tt, yy)
            if redo_outputs and not stepper.constrained and \
                    _moved_far(out, yy, tol_abs, rtol):
                out = again(tt, out)
            emit(k, tt, out)
            projecting[0] = None

    def emit_dense(dense: Callable, k_from: int, k_to: int) -> int:
        """The outputs k_from .. k_to - 1, inside the current step, from its dense output
        ``dense``: all in one call where the stepper's dense output takes an array of
        instants (rule 3) and they are given as it gives them (on the constraints by
        construction, or raw: :func:`emit_inside`), else one by one. Returns k_to."""
        if k_to > k_from and s.dense_arrays and (s.exact_outputs or raw_outputs
                                                 or project is None):
            ts = t_eval[k_from:k_to]
            ys = dense(ts).T
            if ys.shape != (len(ts), n):
                raise ValueError(f"{s.name}'s dense output gave {ys.shape[::-1]} for "
                                 f"{len(ts)} instants of a state of {n}")
            raw = project is not None and not s.exact_outputs
            outs_y.append(ys)
            outs_t.extend(ts.tolist())
            if on_outputs is not None:
                on_outputs(k_from, ts, ys, raw)
            elif on_output is not None:
                for i, tt in enumerate(outs_t[-len(ys):]):
                    if raw_outputs:
                        on_output(k_from + i, tt, ys[i], raw)
                    else:
                        on_output(k_from + i, tt, ys[i])
            return k_to
        for k in range(k_from, k_to):
            te = float(t_eval[k])
            emit_inside(k, te, dense(te))
        return k_to

    def again(tt: float, fallback: np.ndarray) -> np.ndarray:
        """The state at tt inside the current step, integrated apart from the step's start
        to tt as a step's end (error-controlled there), not read off the dense output; where
        no step can end at tt (a singular position there), read off the dense output of
        steps eight times shorter; ``fallback`` where neither reaches it or the budget is
        spent. Its work counts in the run's budget."""
        if not s.t_old < tt < s.t:
            return fallback
        out = None
        # (the first step tried straight to tt: the step's own error held over a longer
        # span, and a fresh stepper's first-step guess crept over A02's passages)
        for points, options in (([tt], dict(first_step=tt - s.t_old, max_step=max_step)),
                                ([tt, s.t], dict(max_step=min(
                                    max_step, (s.t - s.t_old) / 8), redo_outputs=False))):
            sub = redo(points, **options)
            if sub is None:
                break
            if len(sub.t) > 1 and sub.t[1] == tt:
                out = sub.y[1]
                break
        if out is None:
            rough.append(tt)
            return fallback
        return out

    def redo(points, **options) -> Solution | None:
        """:func:`integrate` again from the current step's start through ``points`` (after
        it, increasing), with ``options``, its work counted in the run's budget; None where
        the budget is spent."""
        left = max_steps - int(before[:2].sum()) - s.attempts
        if left <= 0:
            return None
        sub = integrate(stepper, equations, s.y_old, np.concatenate(([s.t_old], points)),
                        rtol=rtol, atol=atol, scale=scale, max_steps=left, **options)
        before[:] += (sub.steps, sub.rejected, sub.evaluations, sub.njev, sub.nlu)
        s.max_attempts = max_steps - int(before[:2].sum())
        if sub.status == "interrupted":
            raise KeyboardInterrupt
        return sub

    def within(ts: np.ndarray) -> list[np.ndarray]:
        """The states at the instants ``ts`` inside the current step, integrated again
        from its start through them, in steps of at most the stepper's
        ``interpolant_step`` (each output then read where the interpolant holds): a
        step's outputs cost one integration together, however many they are (a pendulum
        at rest, whose steps grow to the stability boundary, has 140 outputs a step). Those
        it does not reach are read off the dense output, projected. Its work counts in
        the run's budget."""
        sub = redo(ts, max_step=min(max_step, s.interpolant_step), redo_outputs=False)
        out = [] if sub is None else [np.asarray(y) for y in sub.y[1:]]
        dense = s.dense_output()
        for tt in ts[len(out):]:
            yy = dense(float(tt))
            out.append(yy if project is None else project(float(tt), yy))
        return out

    before = np.zeros(5, dtype=int)  # the counters of a stepper switched from
    projecting: list[float | None] = [None]  # the output instant being projected
    met: list[Jump] = []  # the jumps of the constraints met (module docstring)
    rough: list[float] = []  # the outputs that could not be integrated again (again)
    tol_abs = atol * (scale if scale is not None else 1.0)
    switched = None

    def done(status: str, message: str = "", reason: str = "") -> Solution:
        counts = before + (0 if s is None else np.array(
            (s.naccepted, s.nrejected, s.nfev, s.njev, s.nlu)))
        counts = [int(c) for c in counts]
        states = np.concatenate([np.reshape(a, (-1, n)) for a in outs_y]) if outs_y else \
            np.empty((0, n))
        # (an interrupt between a block's instants and its states leaves one longer)
        k = min(len(outs_t), len(states))
        return Solution(np.array(outs_t[:k]), states[:k], status,
                        message, *counts[:3], t, reason, *counts[3:], switched,
                        None if s is None else getattr(s, "note", None), tuple(met),
                        tuple(rough), None if s is None else np.array(s.y, dtype=float))

    def over_jump(found: list[Jump]) -> Solution | None:
        """The step that went over the jumps ``found`` (those of its earliest instant)
        integrated again, apart, up to the instant before them (its outputs given); then the
        end there (a jump in position), or the stepper afresh from the impulsive motion
        after them (module docstring)."""
        nonlocal s, t, k_next
        # at one instant a jump in position is the one that counts (no velocity follows it)
        jump = min(found, key=lambda j: j.level != "position")
        used = int(before[:2].sum()) + s.attempts
        before[:] += (s.naccepted, s.nrejected, s.nfev, s.njev, s.nlu)
        y_old, s = s.y_old, None
        sub = _up_to(stepper, equations, y_old, t, jump.t_before, t_eval, k_next, emit,
                     dict(rtol=rtol, atol=atol, scale=scale, max_step=max_step,
                          max_steps=max_steps - used, on_interval=on_interval,
                          raw_outputs=raw_outputs), on_step, used)
        before[:] += (sub.steps, sub.rejected, sub.evaluations, sub.njev, sub.nlu)
        met.extend(sub.jumps)
        rough.extend(sub.rough)
        met.extend(found)
        k_next += int(np.searchsorted(t_eval[k_next:], jump.t_before, side="right"))
        if sub.status != "ok":
            t = sub.t_reached
            return done(sub.status, sub.message, sub.reason)
        if jump.level == "position":
            t = jump.t_before
            return done("failed", f"no motion follows the constraints at t = {jump.t:.10g}",
                        "jump")
        impulse = getattr(equations, "impulse", None) or project
        t, y = jump.t, impulse(jump.t, sub.y[-1])
        s = stepper(equations, t, y, t_end, rtol=rtol, atol=atol, scale=scale)
        s.max_attempts = max_steps - int(before[:2].sum())
        if max_step < np.inf:
            s.max_step = max_step
        if watch is not None:  # (the stiffness watched on, as on the stepper before)
            s.detect_stiffness = True
        if k_next < n_out and t_eval[k_next] <= t:
            emit(k_next, t, y.copy())
            k_next += 1
        return None

    def budget() -> Solution:
        return done("failed", f"its budget of {max_steps:,} steps (accepted and rejected) "
                              f"ran out at t = {t:.10g}", "budget")

    k_next = 1
    try:
        emit(0, t, y.copy())
        if t_end <= t:
            return done("ok")
        s = stepper(equations, t, y, t_end, rtol=rtol, atol=atol, scale=scale,
                    first_step=first_step)
        s.max_attempts = max_steps
        if max_step < np.inf:
            s.max_step = max_step
        watch = None
        stall = _Stall()
        ahead = sorted((j for j in jumps_ahead if t < j.t <= t_end), key=lambda j: j.t)
        if stiff is not None and not stepper.implicit:
            s.detect_stiffness = True
            watch = _Watch(stiff, equations, t, t_end, rtol, atol, scale)
        while k_next < n_out:
            # checked here too for steppers that take no more than one attempt per call
            if s.attempts >= s.max_attempts:  # (max_steps less the attempts before)
                return budget()
            message = s.step()
            if message == OUT_OF_BUDGET:
                return budget()
            if message == STIFF:
                # rule 7: the step was accepted; its outputs are emitted below, then the
                # implicit stepper continues from its end
                pass
            elif message is not None:
                return done("failed", message)
            t_new, y_new = s.t, s.y
            due = [j for j in ahead if t < j.t <= t_new]
            if due:  # a jump known ahead, gone over by this step (see the docstring)
                # (with whatever else jumps in the step: a drive whose rate jumps may jump
                # in position at that instant too, which ends the run)
                found = _first_jumps(equations, t, t_new, y_new[:n // 2], tol_abs)
                first = min(j.t for j in due)
                # (the same instant, located apart: within a few units of round-off)
                if not found or min(j.t for j in found) > first + 8 * np.spacing(first):
                    found = [j for j in due if j.t == first]
                # those met now; later ones, in this step too, the steps after it meet
                met_at = max(min(j.t for j in found), first) + 8 * np.spacing(first)
                ahead = [j for j in ahead if j.t > met_at]
                ended = over_jump(found)
                if ended is not None:
                    return ended
                continue
            # the end state projected first (explicit steppers), so that a projection that
            # moves it far, over a constraint that jumps, is seen before any output of the
            # step is given
            end = None
            # (an output at the step's end: the first at or after t_new is t_new itself)
            k_end = k_next + int(np.searchsorted(t_eval[k_next:], t_new))
            at_output = k_end < n_out and t_eval[k_end] <= t_new
            if project is not None and not stepper.constrained:
                end = (project if at_output else settle)(t_new, y_new)
                if _moved_far(end, y_new, tol_abs, rtol):
                    found = _first_jumps(equations, t, t_new, y_new[:n // 2], tol_abs)
                    if found:
                        ended = over_jump(found)
                        if ended is not None:
                            return ended
                        continue
            dense = None  # (made once a step: an interpolant may cost stages of its own)
            if on_interval is not None:  # a quadrature over the step (its dense output)
                dense = s.dense_output()
                on_interval(t, t_new, dense)
            # -- outputs inside the step, by its dense output (one at the step's end is
            # the projected end state, below) -----------------------------------------------
            if k_next < n_out and t_eval[k_next] < t_new and redo_outputs and \
                    getattr(s, "beyond_stability", False):
                # a step beyond what its interpolant holds: its outputs integrated again
                # through them all, in steps within that bound (the stepper's
                # ``interpolant_step``), not read off the interpolant
                inside = t_eval[k_next:][t_eval[k_next:] < t_new]
                for te, ye in zip(inside, within(inside)):
                    emit(k_next, float(te), ye)
                    k_next += 1
            if k_next < k_end:  # (those before the step's end: t_eval[k_end] >= t_new)
                k_next = emit_dense(dense or s.dense_output(), k_next, k_end)
            raw = False
            if project is not None and stepper.constrained and not s.exact_outputs:
                # rule 6: the stepper keeps the constraints; only what is reported is
                # projected (velocities onto Phi_q qd = nu to the solver's tolerance)
                if at_output and raw_outputs:
                    raw = True
                elif at_output:
                    y_new = project(t_new, y_new)
            elif end is not None:
                y_new = end
                s.restart(y_new)
            if at_output:
                emit(k_next, t_new, y_new.copy(), raw)
                k_next += 1
            t_old, t = t, t_new
            stalled = getattr(equations, "stalled", None)
            if stalled is not None and stall.after(t - t_old):
                reason = stalled(t, y_new)
                if reason is not None:
                    return done("failed", reason)
            why, spent, kept = (None, None, None) if watch is None else \
                watch.after(s, message, t_old, t, y_new, s.max_attempts - s.attempts)
            if spent is not None and why is None:  # a trial that said no: its work counts
                before += spent
                s.max_attempts = max_steps - int(before[:2].sum())
            if why is not None:
                # the run goes on with the trial's stepper from where its steps reached:
                # their outputs (and spans) are emitted from their dense outputs
                watch = None
                before += (s.naccepted, s.nrejected, s.nfev, s.njev, s.nlu)
                s, equations, spans = kept
                stepper = type(s)
                project = getattr(equations, "project", None)
                settle = getattr(equations, "settle", None) or project
                s.max_attempts = max_steps - int(before[:2].sum())
                if max_step < np.inf:
                    s.max_step = max_step
                switched = (stepper.name, t, why)
                for t_a, t_b, dense in spans:
                    t = t_a  # (what a failure or an interrupt here reports)
                    if on_interval is not None:
                        on_interval(t_a, t_b, dense)
                    k_next = emit_dense(dense, k_next, k_next + int(
                        np.searchsorted(t_eval[k_next:], t_b, side="right")))
                t = s.t
            if on_step is not None:
                on_step(t, s.attempts + int(before[:2].sum()))
    except KeyboardInterrupt:
        return done("interrupted")
    except np.linalg.LinAlgError as err:
        if projecting[0] is not None:  # an output inside the step, those before it given
            return done("failed", f"the state at t = {projecting[0]:.10g} cannot be moved "
                                  f"onto the constraints ({err})")
        return done("failed", f"the equations of motion are singular near t = {t:.10g} "
                              f"({err})")
    return done("ok")


class _Watch:
    """The explicit pair watched for stiffness (module docstring): when the implicit
    stepper is tried, against which step of the pair, and the pauses after a refusal."""

    def __init__(self, stiff: tuple, equations: Equations, t0: float, t_end: float,
                 rtol: float, atol, scale) -> None:
        self.stiff, self.t0, self.t_end = stiff, t0, t_end
        self.tolerances = (rtol, atol, scale)
        #: the implicit steps' length, in the pair's, that makes a trial say yes
        self.ratio = TRIAL_RATIO_FACTORISED if getattr(equations, "factorises", False) \
            else TRIAL_RATIO
        #: the pair's steps accepted last (their median: its step where stability holds it)
        self.taken: deque[float] = deque(maxlen=TRIAL_AFTER)
        # the accepted steps at which the next periodic trial is made, and after a
        # stiffness report whose trial said no, those until the detection is on again;
        # the pauses after the next refusal of each kind (doubled after a trial that ran)
        self.next_trial, self.resume_at = TRIAL_AFTER, None
        self.trial_pause = self.stiff_pause = TRIAL_AFTER

    def after(self, s: Stepper, message: str | None, t_old: float, t: float, y: np.ndarray,
              left: float = math.inf) -> tuple[str | None, np.ndarray | None, tuple | None]:
        """After the pair ``s`` accepted a step from t_old to (t, y) with ``message``: a
        trial where one is due, as :func:`_trial` returns it ((None, None, None) where none
        is made), within the ``left`` attempts of the run's budget."""
        self.taken.append(t - t_old)
        if self.resume_at is not None and s.naccepted >= self.resume_at:
            s.detect_stiffness, self.resume_at = True, None
        if message == STIFF:
            # tried first: a stiff spring's oscillation that the pair resolves to the
            # tolerance holds h rho at the stability boundary too, and there the implicit
            # stepper's steps are no longer (a four-bar on a spring of 1e4 N/m: radau took
            # 2.3 times vern9's time for 500 times its error)
            in_row = getattr(s, "stiff_steps", 0)
            first = in_row == 1 and s.naccepted == 1
            held = (f"{s.name}'s step held by stability: h rho = "
                    f"{getattr(s, 'h_rho', float('nan')):.3g} " +
                    ("for the first step it tried" if first else
                     f"at {in_row} steps in a row"))
            # (after the first step alone, against that step and the plain ratio: the
            # first step is Hairer's guess, not a step that stability is seen to hold)
            why, spent, kept = _trial(self.stiff, t, y, self.t_end,
                                      float(np.median(self.taken)), s.name,
                                      *self.tolerances, STIFF_MIN_STEPS,
                                      max(self.ratio, TRIAL_RATIO) if first else self.ratio,
                                      left)
            if why is not None:
                return f"{held}, and {why}", spent, kept
            s.detect_stiffness, self.resume_at = False, s.naccepted + self.stiff_pause
            if spent[:2].any():
                self.stiff_pause *= 2
            # not a periodic trial at once after it
            self.next_trial = max(self.next_trial, s.naccepted + self.trial_pause)
            return None, spent, None
        if s.naccepted >= self.next_trial:
            # against the pair's mean step over the run, not its last ones: steps held
            # small for a while (A02 at a collinear passage, 2e-3 of its mean) are not a
            # stiffness
            why, spent, kept = _trial(self.stiff, t, y, self.t_end,
                                      (t - self.t0) / s.naccepted, s.name, *self.tolerances,
                                      TRIAL_MIN_STEPS, self.ratio, left)
            if why is None:
                self.next_trial = s.naccepted + self.trial_pause
                if spent[:2].any():
                    self.trial_pause *= 2
            return why, spent, kept
        return None, None, None


def _moved_far(out: np.ndarray, y: np.ndarray, tol_abs, rtol: float) -> bool:
    """Whether the projection of a state y to ``out`` moved it by more than JUMP_MOVE
    times the tolerance: a step's end (a jump of the constraints: module docstring) or a
    dense output's state. A step's error estimate controls its end, not its
    interpolant: across a singular position, where the augmented Lagrangian's
    accelerations turn within a small interval (docs/dynamics.md), the interpolant of a
    long step can miss the velocities by far (a parallelogram with redundant cranks and a
    pendulum at rtol 1e-8: 0.16 rad/s inside a step whose ends held 1e-8; the projection
    removes the part normal to the constraints, not the tangent part, 4e-3 rad/s left)."""
    return bool(np.max(np.abs(out - y) / (tol_abs + rtol * np.abs(out))) > JUMP_MOVE)


def _trial(stiff: tuple, t: float, y: np.ndarray, t_end: float, h: float, name: str,
           rtol: float, atol, scale, min_steps: int, ratio: float, left: float = math.inf
           ) -> tuple[str | None, np.ndarray, tuple | None]:
    """The implicit stepper tried from (t, y) apart (module docstring): why the run should
    go on with it (None: it should not), the trial's counters (accepted, rejected,
    evaluations, Jacobians, factorisations), and where it says yes, what the run goes on
    with: (the stepper, its equations, each step's (t_old, t_new, dense output)). A trial
    that says no leaves nothing in the run (its equations are its own); one that fails in
    any way only says no. None is tried where the rest of the span takes the pair at
    most ``min_steps`` steps of size h; it says yes where the implicit stepper's last step
    is at least ``ratio`` times h. It attempts at most ``left`` steps, what the run's
    budget has left (its work counts there)."""
    spent = np.zeros(5, dtype=int)
    if not h > 0 or (t_end - t) / h <= min_steps:
        return None, spent, None
    implicit, factory = stiff
    s, last, why, spans = None, 0.0, None, []
    try:
        equations = factory()
        s = implicit(equations, t, y.copy(), t_end, rtol=rtol, atol=atol, scale=scale)
        s.max_attempts = min(4 * TRIAL_STEPS, left)
        while s.naccepted < TRIAL_STEPS and s.t < t_end:
            t_before = s.t
            if s.step() is not None:
                break  # the implicit stepper struggles here: the pair goes on
            last = s.t - t_before
            spans.append((t_before, s.t, s.dense_output()))
        else:
            if s.t >= t_end or last >= ratio * h:
                why = (f"{implicit.name}'s steps {last / h:.3g} times {name}'s over a trial "
                       f"of {s.naccepted} steps")
    except (np.linalg.LinAlgError, ArithmeticError, ValueError, RuntimeError):
        why = None  # (SuperLU says a singular matrix by RuntimeError)
    if s is not None:
        spent[:] = (s.naccepted, s.nrejected, s.nfev, s.njev, s.nlu)
    return why, spent, ((s, equations, spans) if why is not None else None)


def _first_jumps(equations: Equations, a: float, b: float, q: np.ndarray,
                 tol_abs) -> list[Jump]:
    """The jumps at the earliest instant in (a, b] that the constraints' position or
    velocity terms jump at, at the positions q (:mod:`mechdsl.solve.jumps`); none where
    none jumps (the projection moved the state far for another reason)."""
    found = constraint_jumps(equations, q, a, b, float(np.max(tol_abs)))
    first = min((j.t for j in found), default=None)
    return [j for j in found if j.t == first]


def _up_to(stepper: type[Stepper], equations: Equations, y: np.ndarray, t_a: float,
           t_b: float, t_eval: np.ndarray, k_next: int, emit: Callable, options: dict,
           on_step: Callable | None, used: int) -> Solution:
    """:func:`integrate` from (t_a, y) to t_b, its outputs those of ``t_eval`` from index
    ``k_next`` up to t_b, given to ``emit`` with their indices in ``t_eval``, and its state
    at t_b its last; ``used``: the attempts counted before it (for ``on_step``)."""
    inside = t_eval[k_next:][t_eval[k_next:] <= t_b]
    points = np.concatenate(([t_a], inside, [t_b] if not inside.size or inside[-1] < t_b
                             else []))

    def forward(k: int, tt: float, yy: np.ndarray, raw: bool = False) -> None:
        if 1 <= k <= inside.size:
            emit(k_next + k - 1, tt, yy, raw)

    step = None if on_step is None else (lambda tt, attempts: on_step(tt, used + attempts))
    return integrate(stepper, equations, y, points, on_output=forward, on_step=step,
                     **options)
