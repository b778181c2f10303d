"""The explicit Runge-Kutta pairs of the forward dynamics under the driver, on problems with
closed forms: their steps, their interpolants, their orders, the projection, and how an
integration stops."""

import numpy as np
import pytest

from mechdsl.solve.driver import integrate
from mechdsl.solve.explicit import Dop853, Dopri5, Vern9, coefficients


class Problem:
    """y' = rhs(t, y), projected by ``project`` where given: the equations as the driver and
    the steppers see them, for a plain ODE."""

    def __init__(self, rhs, project=None):
        self.rhs = rhs
        if project is not None:
            self.project = project


def oscillator(t, y):
    return np.array([y[1], -y[0]])


def test_the_harmonic_oscillator_and_its_dense_output():
    t = np.linspace(0.0, 10.0, 201)
    sol = integrate(Dop853, Problem(oscillator), [1.0, 0.0], t, rtol=1e-11, atol=1e-13)
    assert sol.status == "ok" and len(sol.t) == len(t)
    # most outputs fall inside steps: the 7th-order interpolant is as exact as the steps
    assert sol.steps < len(t) / 2
    np.testing.assert_allclose(sol.y[:, 0], np.cos(t), rtol=0, atol=1e-9)
    np.testing.assert_allclose(sol.y[:, 1], -np.sin(t), rtol=0, atol=1e-9)


def test_the_error_falls_like_the_eighth_power_of_the_step():
    # y' = -y + sin t, y(0) = 1: y = 1.5 e^-t + (sin t - cos t) / 2
    def rhs(t, y):
        return -y + np.sin(t)

    exact = 1.5 * np.exp(-4.0) + (np.sin(4.0) - np.cos(4.0)) / 2
    errors = []
    for steps in (8, 16):
        h = 4.0 / steps
        # a tolerance no step can fail: fixed steps of h from the first one
        sol = integrate(Dop853, Problem(rhs), [1.0], [0.0, 4.0], rtol=1.0 - 1e-9, atol=1e9,
                        first_step=h, max_step=h)
        assert sol.steps == steps
        errors.append(abs(sol.y[-1, 0] - exact))
    order = np.log2(errors[0] / errors[1])
    assert 7.0 <= order <= 9.5, errors


def test_the_projection_holds_an_invariant():
    # the oscillator's energy is a circle; projecting onto it after every step keeps
    # |y| = 1 to round-off over a long run at a loose tolerance
    t = np.linspace(0.0, 200.0, 101)

    def project(t, y):
        return y / np.hypot(*y)

    free = integrate(Dop853, Problem(oscillator), [1.0, 0.0], t, rtol=1e-5, atol=1e-7)
    held = integrate(Dop853, Problem(oscillator, project), [1.0, 0.0], t, rtol=1e-5,
                     atol=1e-7)
    assert np.abs(np.hypot(*held.y.T) - 1).max() <= 1e-15
    assert np.abs(np.hypot(*free.y.T) - 1).max() > 1e-8  # what the projection removes


def test_a_derivative_that_stops_being_a_number_fails_with_the_outputs_before():
    def rhs(t, y):
        return np.array([np.nan if t > 0.5 else 1.0])

    t = np.linspace(0.0, 1.0, 11)
    sol = integrate(Dop853, Problem(rhs), [0.0], t, rtol=1e-8, atol=1e-10)
    assert sol.status == "failed"
    assert "t = 0.5" in sol.message or "t = 0.4" in sol.message
    assert 1 <= len(sol.t) <= 6
    np.testing.assert_allclose(sol.y[:, 0], sol.t, atol=1e-12)


def test_a_singular_system_fails_with_the_instant():
    def rhs(t, y):
        if t > 0.25:
            raise np.linalg.LinAlgError("singular matrix")
        return np.array([1.0])

    sol = integrate(Dop853, Problem(rhs), [0.0], np.linspace(0, 1, 5), rtol=1e-8, atol=1e-10)
    assert sol.status == "failed" and "singular" in sol.message


def test_an_interrupt_keeps_the_outputs_before_it():
    seen = []

    def on_output(k, t, y):
        if k == 3:
            raise KeyboardInterrupt
        seen.append(k)

    sol = integrate(Dop853, Problem(oscillator), [1.0, 0.0], np.linspace(0, 1, 11), rtol=1e-8,
                    atol=1e-10, on_output=on_output)
    assert sol.status == "interrupted"
    assert seen == [0, 1, 2]
    np.testing.assert_allclose(sol.y[:3, 0], np.cos(sol.t[:3]), atol=1e-9)


def test_the_dopri5_tableau_is_the_published_one():
    """Dormand and Prince's 5(4) as scipy's RK45 ships it (nodes, matrix, weights, error
    weights, the continuous extension's coefficients), and the rows of a sum to the nodes."""
    from scipy.integrate._ivp.rk import RK45

    DOPRI5 = coefficients("dopri5")
    _E5_4, _P5 = DOPRI5.E, DOPRI5.P
    assert DOPRI5.stages == RK45.n_stages and Dopri5.order == RK45.order
    np.testing.assert_allclose(DOPRI5.c[:6], RK45.C, rtol=1e-15, atol=0)
    for s in range(1, 6):
        np.testing.assert_allclose(DOPRI5.a[s], RK45.A[s, :s], rtol=1e-15, atol=0)
        assert abs(sum(DOPRI5.a[s]) - DOPRI5.c[s]) < 1e-15
    np.testing.assert_allclose(DOPRI5.b, RK45.B, rtol=1e-15, atol=0)
    np.testing.assert_allclose(DOPRI5.a[6][:6], RK45.B, rtol=1e-15, atol=0)  # FSAL
    np.testing.assert_allclose(-_E5_4, RK45.E, rtol=1e-14, atol=0)
    np.testing.assert_allclose(_P5, RK45.P, rtol=1e-14, atol=0)
    assert DOPRI5.exponent == -1 / (RK45.error_estimator_order + 1)


def _fixed_step_errors(method, steps_list, at=None):
    """y' = -y + sin t, y(0) = 1 on fixed steps: the error at t = 4 (or of the interpolant
    at ``at`` of each step's length into the last step)."""
    def rhs(t, y):
        return -y + np.sin(t)

    def exact(t):
        return 1.5 * np.exp(-t) + (np.sin(t) - np.cos(t)) / 2

    errors = []
    for steps in steps_list:
        h = 4.0 / steps
        grid = [0.0, 4.0] if at is None else [0.0, 4.0 - (1 - at) * h, 4.0]
        sol = integrate(method, Problem(rhs), [1.0], grid, rtol=1.0 - 1e-9, atol=1e9,
                        first_step=h, max_step=h)
        assert sol.steps == steps
        k = 1 if at is not None else -1
        errors.append(abs(sol.y[k, 0] - exact(sol.t[k])))
    return errors


def test_dopri5_steps_are_of_fifth_order_and_its_interpolant_of_fourth():
    e = _fixed_step_errors(Dopri5, (16, 32))
    assert 4.6 <= np.log2(e[0] / e[1]) <= 5.6, e
    # inside a step the continuous extension's local error is O(h^5): halving h divides
    # it by about 32 (of order 4), while the steps before contribute O(h^5) globally
    e = _fixed_step_errors(Dopri5, (16, 32), at=0.4)
    assert 3.7 <= np.log2(e[0] / e[1]) <= 5.6, e


def test_dopri5_holds_the_oscillator_to_its_tolerance_between_steps():
    t = np.linspace(0.0, 10.0, 401)
    sol = integrate(Dopri5, Problem(oscillator), [1.0, 0.0], t, rtol=1e-9, atol=1e-11)
    assert sol.status == "ok" and sol.steps < len(t)  # outputs inside steps, interpolated
    np.testing.assert_allclose(sol.y[:, 0], np.cos(t), rtol=0, atol=2e-8)
    np.testing.assert_allclose(sol.y[:, 1], -np.sin(t), rtol=0, atol=2e-8)


def _trees(order: int) -> list[tuple]:
    """The rooted trees with ``order`` vertices, each a sorted tuple of its subtrees."""
    if order == 1:
        return [()]
    out = set()

    def forests(total: int, smallest: tuple) -> list[tuple]:
        # multisets of trees (as sorted tuples) with ``total`` vertices in all
        if total == 0:
            return [()]
        found = []
        for size in range(1, total + 1):
            for tree in _trees(size):
                if (size, tree) < smallest:
                    continue
                for rest in forests(total - size, (size, tree)):
                    found.append(((size, tree),) + rest)
        return found

    for forest in forests(order - 1, (0, ())):
        out.add(tuple(sorted(forest)))
    return sorted(out)


def _order_conditions(A: np.ndarray, weights, upto: int) -> float:
    """The largest residual of the order conditions sum_i b_i Phi_i(t) = 1 / gamma(t) over
    every rooted tree t with at most ``upto`` vertices (Butcher's theory: Hairer, Norsett
    and Wanner, sec. II.2); ``weights(order)`` gives b, scaled as it must be for trees of
    that order (an interpolant's weights at x carry x^order)."""
    s = A.shape[0]
    cache = {}

    def phi_gamma(tree):
        if tree not in cache:
            phi, gamma, size = np.ones(s), 1.0, 1
            for sub_size, sub in tree:
                p, g = phi_gamma(sub)
                phi = phi * (A @ p)
                gamma *= g
                size += sub_size
            cache[tree] = (phi, gamma * size)
        return cache[tree]

    worst = 0.0
    for order in range(1, upto + 1):
        b, scale = weights(order)
        for tree in _trees(order):
            phi, gamma = phi_gamma(tree)
            worst = max(worst, abs(b @ phi - scale / gamma) * gamma)
    return worst


def _matrix(method) -> np.ndarray:
    s = len(method.a)
    A = np.zeros((s, s))
    for i, row in enumerate(method.a):
        A[i, : len(row)] = row
    return A


def test_every_pair_meets_its_order_conditions():
    """Each tableau against Butcher's conditions for every rooted tree up to its order: 1,
    2, 4, 9, 20, 48, 115 and 286 trees of orders 1 .. 9 (a wrong digit in a coefficient
    breaks some condition by far more than round-off). The embedded solutions meet theirs
    up to their own orders, and not beyond."""
    from mechdsl.solve import tableaus as T

    DOP853, DOPRI5, VERN9 = (coefficients(name) for name in ("dop853", "dopri5", "vern9"))
    assert [len(_trees(k)) for k in range(1, 10)] == [1, 1, 2, 4, 9, 20, 48, 115, 286]
    for name, method, order, embedded, e in (
            ("dop853", DOP853, 8, None, None), ("dopri5", DOPRI5, 5, 4, DOPRI5.E),
            ("vern9", VERN9, 9, 8, VERN9.E)):
        A = _matrix(method)
        b = np.zeros(len(A))
        b[: len(method.b)] = method.b
        assert _order_conditions(A, lambda k: (b, 1.0), order) < 1e-12, name
        assert _order_conditions(A, lambda k: (b, 1.0), order + 1) > 1e-6, name
        if embedded is not None:
            bhat = b.copy()
            bhat[: len(e)] -= e
            assert _order_conditions(A, lambda k: (bhat, 1.0), embedded) < 1e-12
            assert _order_conditions(A, lambda k: (bhat, 1.0), embedded + 1) > 1e-6
    # Verner's interpolant is of order 8 at every x: sum_i b_i(x) Phi_i(t) = x^|t| / gamma(t)
    A = _matrix(VERN9)
    for x in (0.3, 0.77):
        bx = np.array(T.P9) @ (x ** np.arange(1, 9))
        assert _order_conditions(A, lambda k: (bx, x**k), 8) < 1e-11, x
    # and DOPRI5's of order 4
    A = _matrix(DOPRI5)
    bx = np.array(T.P5) @ (0.4 ** np.arange(1, 5))
    assert _order_conditions(A, lambda k: (bx, 0.4**k), 4) < 1e-12


def test_vern9_steps_are_of_ninth_order_and_so_is_its_output_inside_a_step():
    """Fixed steps over 30 s of the harmonic oscillator: halving the step divides the error
    by about 2^9, at the step's end and at 0.4 of the last step (there the interpolant's
    local error, O(h^9), adds to the steps' global one; its own order 8 is checked by the
    order conditions)."""
    for at in (None, 0.4):
        errors = []
        for steps in (60, 120):
            h = 30.0 / steps
            grid = [0.0, 30.0] if at is None else [0.0, 30.0 - (1 - at) * h, 30.0]
            sol = integrate(Vern9, Problem(oscillator), [1.0, 0.0], grid, rtol=1.0 - 1e-9,
                            atol=1e9, first_step=h, max_step=h)
            assert sol.steps == steps
            k = 1 if at is not None else -1
            errors.append(abs(sol.y[k, 0] - np.cos(sol.t[k])))
        assert 8.5 <= np.log2(errors[0] / errors[1]) <= 10.0, (at, errors)


def test_vern9_holds_the_oscillator_to_its_tolerance_between_steps():
    t = np.linspace(0.0, 10.0, 201)
    sol = integrate(Vern9, Problem(oscillator), [1.0, 0.0], t, rtol=1e-11, atol=1e-13)
    assert sol.status == "ok" and sol.steps < len(t) / 2  # outputs inside steps
    np.testing.assert_allclose(sol.y[:, 0], np.cos(t), rtol=0, atol=1e-9)
    np.testing.assert_allclose(sol.y[:, 1], -np.sin(t), rtol=0, atol=1e-9)


def test_the_step_budget_counts_every_attempt_and_keeps_the_outputs_before_it():
    # the oscillator over 1e6 (some 10^6 steps): a budget of 60 stops it early, with the
    # outputs before it on the closed form and the time its steps reached
    t = np.arange(0.0, 1e6, 0.5)
    seen = []
    sol = integrate(Dop853, Problem(oscillator), [1.0, 0.0], t, rtol=1e-10, atol=1e-12,
                    max_steps=60, on_step=lambda tt, steps: seen.append((tt, steps)))
    assert sol.status == "failed" and sol.reason == "budget"
    assert sol.steps + sol.rejected == 60
    assert "budget of 60 steps" in sol.message and f"t = {sol.t_reached:.10g}" in sol.message
    assert len(sol.t) >= 2 and sol.t[-1] <= sol.t_reached < sol.t[-1] + 0.5
    np.testing.assert_allclose(sol.y[:, 0], np.cos(sol.t), rtol=0, atol=1e-8)
    # on_step: after every accepted step, with the time reached and the attempts so far
    assert len(seen) == sol.steps
    assert seen[-1][0] == sol.t_reached and seen[-1][1] <= 60
    assert all(a[0] < b[0] and a[1] < b[1] for a, b in zip(seen, seen[1:]))
    # a step that is never accepted costs as much: rejected steps use up the budget too
    sol = integrate(Dop853, Problem(lambda tt, y: np.array([np.nan if tt > 0 else 1.0])),
                    [0.0], [0.0, 1.0], rtol=1e-8, atol=1e-10, max_steps=5)
    assert sol.reason == "budget" and (sol.steps, sol.rejected) == (0, 5)
    assert len(sol.t) == 1 and sol.t_reached == 0.0


def test_the_integration_reports_each_step_where_its_outputs_are_far_apart():
    # one output interval of 20 periods: the outputs say nothing in between, the steps do
    seen = []
    sol = integrate(Dop853, Problem(oscillator), [1.0, 0.0], [0.0, 40 * np.pi], rtol=1e-10,
                    atol=1e-12, on_step=lambda tt, steps: seen.append(tt))
    assert sol.status == "ok" and sol.reason == "" and len(sol.t) == 2
    assert len(seen) == sol.steps > 100
    assert seen[-1] == sol.t_reached == 40 * np.pi
    np.testing.assert_allclose(sol.y[-1], [1.0, 0.0], atol=1e-8)


#: A crank-rocker four-bar under gravity whose rocker is two links joined by a stiff,
#: damped rotary spring (1e6 N m/rad, 20 N m s/rad), the crank started at 10 rad/s
#: (trial 49's model m05)
FLEX_ROCKER = """param a = 0.3
param b = 1.0
param c1 = 0.4
param c2 = 0.4
param d = 1.0
gravity = (0, -9.81)
ground { point O4 = (d, 0) }
body crank { guess = (0, 0, 3)  point A = (a, 0)  mass = 1  inertia = a^2/12  centroid = (a/2, 0) }
body coupler { guess = (0.12, 0.45, -0.2)  point A = (-b/2, 0)  point B = (b/2, 0)  mass = 1  inertia = 1/12 }
body rocker1 { guess = (d, 0, 2.3)  point H = (c1, 0)  mass = 0.4  inertia = 0.4*c1^2/12  centroid = (c1/2, 0) }
body rocker2 { guess = (d + c1*cos(2.3), c1*sin(2.3), 2.3)  point B = (c2, 0)  mass = 0.4  inertia = 0.4*c2^2/12  centroid = (c2/2, 0) }
joint O2: revolute(ground.origin, crank.origin)
joint A: revolute(crank.A, coupler.A)
joint B: revolute(coupler.B, rocker2.B)
joint H: revolute(rocker1.H, rocker2.origin)
joint O4: revolute(rocker1.origin, ground.O4)
force hinge: rotary_spring(rocker1, rocker2, k = 1e6, c = 20)
initial s: angle(crank) = 3, rate = 10
initial f: rel_angle(rocker1, rocker2) = 0, rate = 0
simulate t = 0 .. 2 step 0.005
output crank.omega
"""


def test_outputs_inside_steps_beyond_the_interpolants_stability_are_integrated_again():
    """DOP853 on a stiff damped hinge inside a closed loop, rtol 1e-6: its steps are held
    near the stability boundary, and inside a step with h rho above what its interpolant
    holds (explicit.interpolant_bound: 2.43 for DOP853, against 5.36 for the step) the
    interpolant amplified the stiff component. Outputs there were off by up to 2.8e-3
    rad/s (the steps' ends within 2.5e-7); such outputs are now integrated again to their
    instants.

    Truth: trial 49's oracle, Lagrange's equations in the crank angle theta and the hinge's
    bend beta (the rocker's effective length |c1 + c2 e^(i beta)| closing the loop in
    closed form), integrated by DOP853 and by Radau at rtol 1e-12 (agreeing to 1.3e-12):
    crank.omega at the instants where the outputs were worst."""
    import mechdsl
    from mechdsl.solve.explicit import interpolant_bound, stiffness_probe
    from mechdsl.solve.options import SolverOptions

    assert 0 < interpolant_bound("dop853") < stiffness_probe("dop853")[1]
    res = mechdsl.loads(FLEX_ROCKER, "flex.mech").simulate(
        options=SolverOptions(method="dop853", rtol=1e-6))
    assert res.ok, res.messages
    reference = {0.025: 12.100122084874783, 0.985: 8.288332089789638,
                 1.545: 9.22943643786445}
    for t, omega in reference.items():
        k = int(np.argmin(np.abs(res.times - t)))
        assert abs(res["crank.omega"][k] - omega) < 2e-5, (t, res["crank.omega"][k] - omega)


def test_the_interpolant_bounds_are_the_pairs_own():
    """explicit.INTERPOLANT_BOUNDS, written out so that no process pays the scan, are what
    interpolant_extent computes from each pair's coefficients: the extent of |R_x(z)| <=
    1 + 1e-3 for every x in [0, 1] along the negative real and imaginary axes, at most
    the step's own (x = 1 is the step)."""
    from mechdsl.solve.explicit import (INTERPOLANT_BOUNDS, interpolant_extent,
                                        stiffness_probe)

    for name, bound in INTERPOLANT_BOUNDS.items():
        assert interpolant_extent(name) == pytest.approx(bound, abs=0.006), name
        assert 0 < bound <= stiffness_probe(name)[1] / 0.9 + 0.01


def test_the_stability_thresholds_are_the_pairs_own():
    """explicit.STABILITY_THRESHOLDS, written out so that no process pays the scan, are
    what stability_threshold computes from each pair's coefficients (0.9 of the smaller of
    the real and imaginary extents of |R(z)| <= 1 + 1e-3, at least half the real one), for
    every explicit pair of the registry; and a bound the scan checks independently: the
    stability polynomial R at the threshold on the axis that sets it stays within 1e-3 of
    the unit circle's inside."""
    from mechdsl.solve.explicit import (STABILITY_THRESHOLDS, coefficients,
                                        stability_threshold, stiffness_probe)
    from mechdsl.solve.integrators import INTEGRATORS

    names = {cls.name for cls in INTEGRATORS.values() if not cls.implicit}
    assert names <= set(STABILITY_THRESHOLDS)
    for name, threshold in STABILITY_THRESHOLDS.items():
        assert stability_threshold(name) == pytest.approx(threshold, abs=1e-9), name
        assert stiffness_probe(name)[1] == threshold
        pair = coefficients(name)
        s = pair.stages
        A = np.zeros((s, s))
        for i in range(1, s):
            A[i, :len(pair.a[i])] = pair.a[i]
        # at 0.9 of the boundary on the negative real axis, |R| < 1: a stable step
        z = -threshold
        R = 1 + z * (pair.b[:s] @ np.linalg.solve(np.eye(s) - z * A, np.ones(s)))
        assert abs(R) <= 1 + 1e-3, name
