"""An output inside a step that its projection moves far is integrated again from the
step's start (mechdsl.solve.driver): the oscillator y'' = -y against cos t, the budget, an
interrupt inside that integration, and an output at a singular position."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import mechdsl
from mechdsl.solve.driver import integrate
from mechdsl.solve.integrators import INTEGRATORS

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_redundant_dynamics import FOUR_CRANKS_PENDULUM  # noqa: E402


class _Shaken:
    """y'' = -y whose projection moves a state by 1 (far) the first time it is asked at
    an instant before the end, and leaves it after: each output inside a step is moved
    far, and what the driver keeps must come from its integration again to that instant
    (whose end is projected a second time). ``interrupt_after``: a KeyboardInterrupt at
    that evaluation."""

    n, m = 1, 0

    def __init__(self, interrupt_after: int | None = None) -> None:
        self.calls, self.interrupt_after = 0, interrupt_after
        self.seen: set[float] = set()

    def rhs(self, t, y):
        self.calls += 1
        if self.calls == self.interrupt_after:
            raise KeyboardInterrupt
        return np.array([y[1], -y[0]])

    def project(self, t, y):
        if t < 3.0 and t not in self.seen:
            self.seen.add(t)
            return y + 1.0
        return y

    def settle(self, t, y):
        return y


def _run(equations, max_steps=1_000_000):
    return integrate(INTEGRATORS["dop853"], equations, np.array([1.0, 0.0]),
                     np.linspace(0, 3, 301), rtol=1e-10, atol=1e-12, scale=np.ones(2),
                     max_steps=max_steps)


def test_outputs_moved_far_are_integrated_again_to_the_closed_form():
    sol = _run(_Shaken())
    assert sol.status == "ok" and len(sol.t) == 301
    # every output inside a step was moved by 1 and replaced by an integration to it
    assert np.abs(sol.y[:, 0] - np.cos(sol.t)).max() < 1e-8


def test_the_integrations_again_count_in_the_budget():
    for budget in (5, 30):
        sol = _run(_Shaken(), max_steps=budget)
        assert sol.status == "failed" and sol.reason == "budget"
        assert sol.steps + sol.rejected <= budget


def test_an_interrupt_inside_an_integration_again_ends_the_run():
    shaken = _Shaken()
    _run(shaken)
    first_steps = 40  # well inside the first integration again, past the first step
    sol = _run(_Shaken(interrupt_after=first_steps))
    assert sol.status == "interrupted"
    assert len(sol.t) < 301


def test_an_output_at_a_singular_position_is_integrated_again_to_it():
    # the four-crank parallelogram's cranks are collinear at t = 3.33184; an output at
    # 3.332 lies inside a step over it. A step ending there could not be projected (its
    # Gauss-Newton steps, the residual's rounding over Phi_q's smallest singular value,
    # never fell to newton_tol), and the run kept the interpolant, saying so; the
    # positions are now closed where Phi holds to round-off (diagnose.closed_to_roundoff),
    # and the output is integrated again to the pendulum's own equation
    from test_redundant_dynamics import _about_circling_pivot

    text = FOUR_CRANKS_PENDULUM.replace("simulate t = 0 .. 2 step 0.01",
                                        "simulate t = 0 .. 3.4 step 0.001, rtol = 1e-8")
    res = mechdsl.loads(text, "p.mech").simulate()
    assert res.ok, res.messages
    assert not [w for w in res.warnings if "inside a step over a singular position" in w]
    ref = _about_circling_pivot(res["t"], res["pend.omega"][0])
    at = int(np.argmin(np.abs(res["t"] - 3.332)))
    assert abs(res["pend.phi"][at] - ref[0][at]) < 1e-7
    assert abs(res["pend.omega"][at] - ref[1][at]) < 1e-6
    assert np.abs(res["pend.omega"] - ref[1]).max() < 1e-6
