"""The stepper contract (mechdsl/solve/stepper.py), the driver and the registry of
integrators: each explicit pair on the harmonic oscillator's closed form, bare (the contract's
rules: construction, steps that never pass t_bound, dense output on [t_old, t], restart
keeping the step size, counters that add up, the budget) and under the driver; every pair on
Andrews' mechanism against the Test Set's reference at three tolerances; the automatic choice;
and a new integrator added as one class and one registry line, through the API, the options
and the command line."""

import math

import numpy as np
import pytest
from scipy.special import ellipk

import mechdsl
from conftest import EXAMPLES
from mechdsl.solve import SolverOptions
from mechdsl.solve.driver import integrate
from mechdsl.solve.integrators import INTEGRATORS, choose, help_text
from mechdsl.solve.stepper import OUT_OF_BUDGET, Stepper
from test_dynamics import ANDREWS_NAMES, ANDREWS_Q, G, pendulum

#: the registry's explicit steppers: those that need only the right-hand side (an implicit
#: one needs a mechanism's index-3 terms, tested with its own module)
EXPLICIT = [cls for cls in INTEGRATORS.values() if not cls.implicit]


class Oscillator:
    """y'' = -y as y = (q, qd), y' = (qd, -q): q = q0 cos t + v0 sin t. Counts its
    evaluations independently of the stepper's counters."""

    def __init__(self):
        self.calls = 0

    def rhs(self, t, y):
        self.calls += 1
        return np.array([y[1], -y[0]])

    @staticmethod
    def exact(t, q0=1.0, v0=0.0, t0=0.0):
        s = np.asarray(t) - t0
        return np.array([q0 * np.cos(s) + v0 * np.sin(s), -q0 * np.sin(s) + v0 * np.cos(s)])


def _bare(cls, rtol=1e-9, t_bound=10.0):
    eq = Oscillator()
    return eq, cls(eq, 0.0, np.array([1.0, 0.0]), t_bound, rtol=rtol, atol=rtol * 1e-2,
                   scale=np.ones(2))


@pytest.mark.parametrize("cls", EXPLICIT, ids=lambda c: c.name)
def test_the_driver_and_each_pair_follow_the_oscillator_between_and_at_steps(cls):
    t = np.linspace(0.0, 10.0, 401)
    eq, seen = Oscillator(), []
    sol = integrate(cls, eq, [1.0, 0.0], t, rtol=1e-10, atol=1e-12,
                    on_step=lambda tt, attempts: seen.append((tt, attempts)))
    assert sol.status == "ok" and sol.reason == "" and len(sol.t) == len(t)
    assert sol.steps < len(t)  # most outputs fall inside steps: the dense output
    np.testing.assert_allclose(sol.y.T, Oscillator.exact(t), rtol=0, atol=2e-8)
    # counters: the equations' own count, the attempts on_step saw, the time reached
    assert sol.evaluations == eq.calls and sol.njev == sol.nlu == 0
    assert len(seen) == sol.steps and seen[-1] == (10.0, sol.steps + sol.rejected)
    assert sol.t_reached == 10.0


@pytest.mark.parametrize("cls", EXPLICIT, ids=lambda c: c.name)
def test_a_bare_stepper_keeps_the_rules_of_the_contract(cls):
    eq, s = _bare(cls)
    # rule 1: at (t0, y0), at least one evaluation, a first step chosen
    assert s.t == s.t_old == 0.0 and np.array_equal(s.y, [1.0, 0.0])
    assert s.nfev == eq.calls >= 1 and s.attempts == 0 and s.h > 0
    steps = 0
    while s.t < s.t_bound:
        t_before, y_before = s.t, s.y.copy()
        assert s.step() is None
        steps += 1
        # rule 2: one accepted step, from where the last ended, never past t_bound
        assert s.t_old == t_before and np.array_equal(s.y_old, y_before)
        assert t_before < s.t <= s.t_bound
        np.testing.assert_allclose(s.y, Oscillator.exact(s.t), rtol=0, atol=1e-7)
        # rule 3: the dense output spans [t_old, t], from the step's start, to its end
        # within the step's absolute tolerance (1e-11: Verner's interpolant of order 8 is
        # not the 9th-order step at x = 1), accurate inside
        u = s.dense_output()
        np.testing.assert_allclose(u(s.t_old), s.y_old, rtol=0, atol=1e-14)
        np.testing.assert_allclose(u(s.t), s.y, rtol=0, atol=1e-11)
        for x in (0.25, 0.5, 0.9):
            tm = s.t_old + x * (s.t - s.t_old)
            np.testing.assert_allclose(u(tm), Oscillator.exact(tm), rtol=0, atol=1e-7)
        # rule 5: the counters add up, against the equations' own count
        assert s.nfev == eq.calls and s.naccepted == steps
        assert s.attempts == s.naccepted + s.nrejected
    assert s.t == s.t_bound and s.njev == s.nlu == 0


@pytest.mark.parametrize("cls", EXPLICIT, ids=lambda c: c.name)
def test_a_restart_continues_from_the_new_state_with_the_step_size(cls):
    """An event at t1 reverses the velocity: after restart(y) the stepper follows the new
    closed form, q = q1 cos(t - t1) - v1 sin(t - t1), from the same step size."""
    eq, s = _bare(cls, t_bound=6.0)
    for _ in range(3):
        assert s.step() is None
    t1, (q1, v1), h = s.t, s.y.copy(), s.h
    s.restart(np.array([q1, -v1]))
    assert s.t == t1 and s.h == h and np.array_equal(s.y, [q1, -v1])
    assert s.nfev == eq.calls  # the evaluation a large change needs, counted
    while s.t < s.t_bound:
        assert s.step() is None
    np.testing.assert_allclose(s.y, Oscillator.exact(6.0, q1, -v1, t1), rtol=0, atol=1e-7)
    # a change within the step's tolerance (a projection) is a restart too
    _, s = _bare(cls)
    assert s.step() is None
    h = s.h
    s.restart(s.y * (1 + 1e-13))
    assert s.h == h and s.step() is None


@pytest.mark.parametrize("cls", EXPLICIT, ids=lambda c: c.name)
def test_a_stepper_keeps_the_driver_s_limits(cls):
    _, s = _bare(cls)
    s.max_step = 0.01
    assert s.step() is None and s.t - s.t_old <= 0.01
    s.max_attempts = s.attempts + 2
    assert s.step() is None and s.step() is None
    t, y = s.t, s.y
    assert s.step() == OUT_OF_BUDGET  # no third attempt, the state left as it was
    assert s.attempts == s.max_attempts and s.t == t and s.y is y


@pytest.mark.parametrize("cls", EXPLICIT, ids=lambda c: c.name)
def test_every_pair_reaches_andrews_reference_at_every_tolerance(cls):
    """The seven angles at t = 0.03 against the Test Set's reference (PSIDE at 1e-14), within
    the tolerance asked (1e-9 at rtol 1e-10: the reference and an independent DOP853 at
    1e-12 agree to 2.8e-10), closer at every tighter tolerance; the constraints held."""
    mech = mechdsl.load(EXAMPLES / "andrews.mech")
    errors = []
    for rtol in (1e-4, 1e-7, 1e-10):
        res = mech.simulate(options=SolverOptions(method=cls.name, rtol=rtol,
                                                  atol=rtol * 1e-2))
        assert res.status == "ok", res.messages
        got = np.array([res[name][-1] for name in ANDREWS_NAMES])
        errors.append(float((np.abs(got - ANDREWS_Q) / np.abs(ANDREWS_Q)).max()))
        assert errors[-1] <= max(rtol, 1e-9), (rtol, errors)
        assert res.residual <= 1e-10
    assert errors[0] > errors[1] > errors[2], errors


def test_the_automatic_choice_reads_the_registry(monkeypatch):
    # today's rule: the explicit pair of lowest order at loose tolerances, highest below
    assert choose("auto", 1e-4, dopri5_from=1e-4)[0] == "dopri5"
    assert choose("auto", 9e-5, dopri5_from=1e-4)[0] == "vern9"
    name, why = choose("auto", 1e-8, dopri5_from=1e-4)
    assert name == "vern9" and "1e-08" in why
    # a large or redundant model, on the augmented Lagrangian: the highest-order pair
    # whose error estimate is robust (registry attribute), dopri5 at loose tolerances
    name, why = choose("auto", 1e-8, dopri5_from=1e-4, large=True)
    assert name == "dop853" and "augmented Lagrangian" in why and "radau takes over" in why
    assert choose("auto", 1e-3, dopri5_from=1e-4, redundant=True)[0] == "dopri5"
    monkeypatch.setattr(INTEGRATORS["dop853"], "robust", False)
    assert choose("auto", 1e-8, dopri5_from=1e-4, large=True)[0] == "dopri5"
    monkeypatch.undo()
    assert choose("dop853", 1e-8, dopri5_from=1e-4) == ("dop853",
                                                        "dop853, as the options name it")
    with pytest.raises(ValueError, match="method must be 'auto', .*'dopri5'.*not 'rk4'"):
        choose("rk4", 1e-8, dopri5_from=1e-4)
    # the hook: a stiff, large or redundant model takes an implicit stepper where one is
    # registered, one that tolerates redundant constraints where they are redundant
    # radau is registered, not for the start: it takes over where the run proves stiff
    why = choose("auto", 1e-8, dopri5_from=1e-4, stiff=True)[1]
    assert "radau takes over where the run proves stiff" in why
    monkeypatch.delitem(INTEGRATORS, "radau")
    assert "no implicit method is registered" in choose("auto", 1e-8, dopri5_from=1e-4,
                                                        stiff=True)[1]
    monkeypatch.undo()

    class Implicit(Stepper):
        name, order, implicit, redundant, auto = "implicit-test", 2, True, False, True

    monkeypatch.setitem(INTEGRATORS, Implicit.name, Implicit)
    assert choose("auto", 1e-8, dopri5_from=1e-4, stiff=True)[0] == "implicit-test"
    assert choose("auto", 1e-8, dopri5_from=1e-4, large=True)[0] == "implicit-test"
    assert choose("auto", 1e-8, dopri5_from=1e-4)[0] == "vern9"
    assert choose("auto", 1e-8, dopri5_from=1e-4, redundant=True)[0] == "dop853"
    monkeypatch.setattr(Implicit, "redundant", True)
    assert choose("auto", 1e-8, dopri5_from=1e-4, redundant=True)[0] == "implicit-test"


# -- a new integrator: one class (here, in this file) and one registry line ---------------------

class Heun(Stepper):
    """Heun's 2(1) pair: y1 = y + h (k1 + k2) / 2 with k2 = f(t + h, y + h k1), the error
    estimated against Euler's step, |h (k2 - k1) / 2 / sc|_rms, and the cubic Hermite
    interpolant of the step's ends and their derivatives."""

    name, order, summary = "heun", 2, "Heun's 2(1), a test's"

    def __init__(self, equations, t0, y0, t_bound, *, rtol, atol, scale, first_step=None):
        super().__init__(equations, t0, y0, t_bound, rtol=rtol, atol=atol, scale=scale,
                         first_step=first_step)
        self.atol_v = atol * (1.0 if scale is None else np.asarray(scale))
        self.f = self._eval(self.t, self.y)
        self.h = first_step or 1e-4 * (t_bound - t0)

    def _eval(self, t, y):
        self.nfev += 1
        return self.equations.rhs(t, y)

    def step(self):
        t, y, k1 = self.t, self.y, self.f
        while True:
            if self.attempts >= self.max_attempts:
                return OUT_OF_BUDGET
            h = min(self.h, self.max_step, self.t_bound - t)
            k2 = self._eval(t + h, y + h * k1)
            y1 = y + h * (k1 + k2) / 2
            sc = self.atol_v + self.rtol * np.maximum(np.abs(y), np.abs(y1))
            err = math.sqrt(np.mean((h * (k2 - k1) / 2 / sc) ** 2))
            factor = 5.0 if err == 0 else min(5.0, 0.9 / math.sqrt(err))
            self.h = h * max(0.2, factor)
            if err <= 1:
                break
            self.nrejected += 1
            if self.h < 1e-14 * max(1.0, abs(t)):
                return f"the step size underflowed at t = {t:.10g}"
        self.naccepted += 1
        self.t_old, self.y_old, self._f_old = t, y, k1
        self.t = t + h if t + h < self.t_bound else self.t_bound
        self.y = self._y_end = y1
        self.f = self._f_end = self._eval(self.t, y1)
        return None

    def dense_output(self):
        t0, h = self.t_old, self.t - self.t_old
        y0, y1, f0, f1 = self.y_old, self._y_end, self._f_old, self._f_end

        def u(t):
            x = (t - t0) / h
            return ((1 + 2 * x) * (1 - x) ** 2 * y0 + x * (1 - x) ** 2 * h * f0
                    + x * x * (3 - 2 * x) * y1 - x * x * (1 - x) * h * f1)

        return u

    def restart(self, y):
        self.y = y
        self.f = self._eval(self.t, y)


def test_an_integrator_is_one_class_and_one_registry_line(monkeypatch, tmp_path, capsys):
    from mechdsl.cli import main

    with pytest.raises(ValueError, match="method must be"):
        SolverOptions(method="heun")
    monkeypatch.setitem(INTEGRATORS, Heun.name, Heun)  # the one line
    # the oscillator's closed form, as every stepper
    t = np.linspace(0.0, 5.0, 51)
    sol = integrate(Heun, Oscillator(), [1.0, 0.0], t, rtol=1e-8, atol=1e-10)
    assert sol.status == "ok"
    np.testing.assert_allclose(sol.y.T, Oscillator.exact(t), rtol=0, atol=1e-6)
    # the API: the pendulum released from the horizontal crosses the bottom at T/4 and 3T/4,
    # T by the complete elliptic integral
    length = 1.5
    T = 4 * np.sqrt(length / G) * ellipk(0.5)
    text = pendulum(length, per_period=40)
    res = mechdsl.loads(text, "pendulum.mech").simulate(
        options=SolverOptions(method="heun", rtol=1e-5, atol=1e-7))
    assert res.status == "ok", res.messages
    tt, phi, w = res["t"], res["rod.phi"], res["rod.omega"]
    for k, when in ((10, T / 4), (30, 3 * T / 4)):
        assert abs(tt[k] - (phi[k] + np.pi / 2) / w[k] - when) <= 1e-5 * T
    assert res.residual <= 1e-12 * length
    # the automatic choice does not take it unasked
    assert choose("auto", 1e-3, dopri5_from=1e-4)[0] == "dopri5"
    # the command line: its help lists it, --method takes it, an unknown name is refused
    assert "heun (Heun's 2(1), a test's)" in help_text()
    path, out = tmp_path / "p.mech", tmp_path / "out.csv"
    path.write_text(text)
    assert main(["run", str(path), "-o", str(out), "-q", "--method", "heun",
                 "--rtol", "1e-5", "--atol", "1e-7"]) == 0
    header = out.read_text().splitlines()[0].split(",")
    data = np.loadtxt(out, delimiter=",", comments="#", skiprows=1)
    np.testing.assert_allclose(data[:, header.index("rod.phi")], phi, rtol=0, atol=1e-12)
    capsys.readouterr()
    assert main(["run", str(path), "-o", "-", "-q", "--method", "heun2"]) == 1
    err = capsys.readouterr().err
    assert "--method: method must be" in err and "'heun'" in err
