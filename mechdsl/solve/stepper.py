"""The contract of a forward-dynamics integrator: a stepper takes steps, a driver does the rest.

In the spirit of scipy's ``OdeSolver``: a :class:`Stepper` advances the state of one mechanism
by one accepted step at a time, with its own error control, and offers the dense output of
its last step; the driver (:mod:`mechdsl.solve.driver`) owns everything that is not a step:
the output instants, the projections onto the constraint manifolds, the step budget,
failures, interrupts and progress. A new integrator is one module with one subclass of
:class:`Stepper` and one line in :data:`mechdsl.solve.integrators.INTEGRATORS`.

The rules a stepper keeps:

1. **Construction** ``Stepper(equations, t0, y0, t_bound, rtol, atol, scale, first_step)``
   evaluates what it needs at (t0, y0) (at least one derivative) and chooses its first step
   (``first_step`` if given). ``y = (q, qd)`` is consistent on entry: the driver has
   projected it. ``atol`` is absolute in coordinates scaled by ``scale`` (per component, the
   model's length and angle scales), ``rtol`` relative to the state.
2. **step()** attempts steps until one is accepted (rejecting and shrinking as its error
   estimate says), then advances ``t``, ``y`` (keeping ``t_old``, ``y_old``) and returns
   None; or returns a message (the step size underflowed, the iteration diverged, the
   equations are singular at t) and leaves ``t``, ``y`` at the last accepted state. It
   never steps past ``t_bound`` nor takes a step longer than ``max_step``. It attempts no
   step once ``attempts`` has reached ``max_attempts`` (the driver's budget): it returns
   :data:`OUT_OF_BUDGET` instead (a stepper that rejects within ``step`` checks before
   every attempt; the driver also checks before every call). A KeyboardInterrupt and
   numpy's LinAlgError propagate untouched (the driver reports them with the instant).
3. **dense_output()** gives a callable ``u(t) -> y`` valid on ``[t_old, t]`` (the
   interpolant of the last accepted step, as stepped: a later ``restart`` does not change
   it), of the order the method promises. The driver calls it only for steps that contain
   an output instant, so that its extra work (stages) is done only there. Where the class
   attribute ``dense_arrays`` is true, ``u`` also takes an array of K instants and gives
   the states as columns (len(y), K): the driver then reads all the outputs of a step in
   one call.
4. **restart(y)** is called by the driver after it changed the state at ``t`` (a
   projection, an event): the stepper drops whatever it carried from before (an FSAL
   derivative, a history, a Jacobian evaluated at the old state) and continues from ``y``,
   keeping its step size. (It may keep what the change cannot have spoilt beyond its own
   error: the explicit pairs keep their FSAL derivative where y moved by at most the
   step's tolerance, corrected by the equations' optional ``carry``.)
5. **Counters**: ``nfev`` (evaluations of the equations of motion), ``njev`` (of their
   derivatives), ``nlu`` (factorisations), ``naccepted`` and ``nrejected`` steps; the driver
   reads them for the budget and the run's summary, and an optional ``note`` (a line for
   the summary: what the stepper changed in its own course, None if nothing).
6. **Class attributes**: ``name`` (what ``--method`` takes), ``order``, ``implicit`` (it
   uses the derivatives of the equations: stiff models), ``redundant`` (it integrates through
   redundant constraints and singular positions), ``summary``, one line for the command
   line's help, ``auto``: whether the automatic choice
   (:func:`mechdsl.solve.integrators.choose`) may take it, and ``constrained``: its steps
   keep Phi(q, t) = 0 themselves (an index-3 method: positions on the manifold to its Newton
   tolerance, velocities within its error estimate). The driver then projects only the
   outputs it reports and never the state the stepper continues from, so that the stepper
   keeps its extrapolation, its multipliers and its Jacobian across steps (a projection and
   restart after every step cost Radau on A02 a third of its Newton iterations). A
   stepper whose ``exact_outputs`` is true (an instance attribute, which may change
   between steps) integrates, for now, in coordinates in which the constraints hold
   identically (the joints' own: :mod:`mechdsl.solve.reduced`): its states satisfy them
   to round-off, and the driver reports them unprojected.
7. **Stiffness**: a stepper whose ``detect_stiffness`` the driver sets may return
   :data:`STIFF` from ``step`` after an accepted step (``t``, ``y`` advanced): the driver
   then tries the implicit stepper it was given (``stiff``) from that state and goes on
   with it where its steps are longer by far (:mod:`mechdsl.solve.driver`), else with this
   stepper, its ``detect_stiffness`` cleared for a while.

The equations a stepper sees are those of one mechanism (:class:`Equations`, a protocol):
the right-hand side ``rhs(t, y) = (qd, qdd)`` of the index-1 form for explicit methods, and
for implicit ones the terms of the index-3 form and their exact derivatives.
"""

from __future__ import annotations

import math
from typing import Callable, ClassVar, Protocol

import numpy as np


class Equations(Protocol):
    """Haug's constrained equations of motion of one mechanism,

        M(q) qdd + Phi_q^T lambda = Q(q, qd, t),   Phi(q, t) = 0,

    in coordinates q (n,), with the m constraint equations Phi (drives included)."""

    n: int
    m: int

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        """y' = (qd, qdd) at y = (q, qd), qdd from the index-1 form."""

    def project(self, t: float, y: np.ndarray) -> np.ndarray:
        """y moved onto Phi(q, t) = 0 and Phi_q qd = nu (iterated to the solver's
        tolerance), mass-orthogonally, tolerating redundant constraints."""

    # Optional, read by the driver and the explicit steppers where present (getattr):
    # ``settle(t, y)``, the correction after a step that does not end at an output (to the
    # precision the next step needs: cheaper than ``project``, which it defaults to), and
    # ``carry(y, f)``, the derivative at a corrected state y from ``f`` at the state before
    # the correction, with what of it y gives exactly (a mechanism's y' begins with qd);
    # ``factorises``, True where every evaluation of ``rhs`` factorises a matrix of the
    # model's size (the driver's trial of an implicit stepper asks less of it there);
    # ``impulse(t, y)``, the state just after the constraints' velocity terms jumped at t
    # (their impulsive motion: the velocities' mass-orthogonal projection; ``project``
    # where absent, which must then be mass-orthogonal too).

    # -- the terms of the index-3 form, for implicit methods (sparse matrices: CSR) ---------
    def phi_jac(self, t: float, q: np.ndarray) -> tuple[np.ndarray, object]:
        """Phi(q, t) (m,) and Phi_q (m, n)."""

    def nu(self, t: float) -> np.ndarray:
        """Phi_q qd = nu: minus the partial time derivative of Phi (m,)."""

    def gamma(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Phi_q qdd = gamma (m,)."""

    def mass(self, q: np.ndarray) -> object:
        """M(q) (n, n)."""

    def loads(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Q(q, qd, t) (n,)."""

    def load_derivatives(self, t: float, q: np.ndarray, qd: np.ndarray
                         ) -> tuple[object, object]:
        """dQ/dq and dQ/dqd (n, n), exact (derived from the traced loads)."""

    # Optional (getattr): ``mass_loads(t, q, qd)``, M(q) and Q(q, qd, t) from one
    # evaluation, which the implicit steppers' stage residuals take where it is present.

    def accelerations(self, t: float, q: np.ndarray, qd: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """qdd (n,) and lambda (m,) of the index-1 form; with redundant constraints the
        multipliers are those of the augmented Lagrangian's limit."""


#: What :meth:`Stepper.step` returns when it stopped at ``max_attempts`` (rule 2): the driver
#: reports the budget, with the instant reached.
OUT_OF_BUDGET = "the step budget ran out"

#: What an explicit :meth:`Stepper.step` returns, after an accepted step, where it has found
#: the model stiff (its step size held by stability, not accuracy; rule 7): the driver goes on
#: from there with the implicit method it was given, else ignores it.
STIFF = "the model is stiff"


class Stepper:
    """One integrator of the equations of motion (see the module's rules)."""

    name: ClassVar[str] = ""
    order: ClassVar[int] = 0
    implicit: ClassVar[bool] = False
    redundant: ClassVar[bool] = False
    summary: ClassVar[str] = ""
    auto: ClassVar[bool] = False
    constrained: ClassVar[bool] = False
    #: its states satisfy the constraints identically, not to a tolerance (rule 6)
    exact_outputs: bool = False
    #: its dense output takes an array of instants too (rule 3)
    dense_arrays: ClassVar[bool] = False
    #: an explicit pair whose error estimate stays reliable where the right-hand side is
    #: smooth only to a tolerance (the augmented Lagrangian's accelerations: an iteration
    #: stopped at round-off, and near a singular position the penalty's blend): the
    #: automatic choice takes such a pair for the models integrated on it
    robust: ClassVar[bool] = False
    #: set by the driver on the instance where it has a limit (rule 2)
    max_step: float = math.inf
    max_attempts: float = math.inf

    def __init__(self, equations: Equations, t0: float, y0: np.ndarray, t_bound: float, *,
                 rtol: float, atol: float, scale: np.ndarray,
                 first_step: float | None = None) -> None:
        self.equations = equations
        self.t = self.t_old = float(t0)
        self.y = self.y_old = np.asarray(y0, dtype=float)
        self.t_bound = float(t_bound)
        self.rtol, self.atol, self.scale = rtol, atol, scale
        self.nfev = self.njev = self.nlu = self.naccepted = self.nrejected = 0

    def step(self) -> str | None:  # pragma: no cover - the contract
        """Rule 2."""
        raise NotImplementedError

    def dense_output(self) -> Callable[[float], np.ndarray]:  # pragma: no cover
        """Rule 3."""
        raise NotImplementedError

    def restart(self, y: np.ndarray) -> None:  # pragma: no cover
        """Rule 4."""
        raise NotImplementedError

    @property
    def attempts(self) -> int:
        """Steps attempted so far, accepted and rejected (what the budget counts)."""
        return self.naccepted + self.nrejected
