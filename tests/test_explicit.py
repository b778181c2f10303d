"""The explicit Runge-Kutta integrator of the forward dynamics, on problems with closed
forms: its steps, its interpolant, its order, its projection, and how it stops."""

import numpy as np

from mechdsl.solve.explicit import Problem, integrate


def oscillator(t, y):
    return np.array([y[1], -y[0]])


def test_the_harmonic_oscillator_and_its_dense_output():
    t = np.linspace(0.0, 10.0, 201)
    sol = integrate(Problem(oscillator), [1.0, 0.0], t, rtol=1e-11, atol=1e-13)
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
        sol = integrate(Problem(rhs), [1.0], [0.0, 4.0], rtol=1.0 - 1e-9, atol=1e9, h0=h,
                        max_step=h)
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

    free = integrate(Problem(oscillator), [1.0, 0.0], t, rtol=1e-5, atol=1e-7)
    held = integrate(Problem(oscillator, project), [1.0, 0.0], t, rtol=1e-5, atol=1e-7)
    assert np.abs(np.hypot(*held.y.T) - 1).max() <= 1e-15
    assert np.abs(np.hypot(*free.y.T) - 1).max() > 1e-8  # what the projection removes


def test_a_derivative_that_stops_being_a_number_fails_with_the_outputs_before():
    def rhs(t, y):
        return np.array([np.nan if t > 0.5 else 1.0])

    t = np.linspace(0.0, 1.0, 11)
    sol = integrate(Problem(rhs), [0.0], t, rtol=1e-8, atol=1e-10)
    assert sol.status == "failed"
    assert "t = 0.5" in sol.message or "t = 0.4" in sol.message
    assert 1 <= len(sol.t) <= 6
    np.testing.assert_allclose(sol.y[:, 0], sol.t, atol=1e-12)


def test_a_singular_system_fails_with_the_instant():
    def rhs(t, y):
        if t > 0.25:
            raise np.linalg.LinAlgError("singular matrix")
        return np.array([1.0])

    sol = integrate(Problem(rhs), [0.0], np.linspace(0, 1, 5), rtol=1e-8, atol=1e-10)
    assert sol.status == "failed" and "singular" in sol.message


def test_an_interrupt_keeps_the_outputs_before_it():
    seen = []

    def on_output(k, t, y):
        if k == 3:
            raise KeyboardInterrupt
        seen.append(k)

    sol = integrate(Problem(oscillator), [1.0, 0.0], np.linspace(0, 1, 11), rtol=1e-8,
                    atol=1e-10, on_output=on_output)
    assert sol.status == "interrupted"
    assert seen == [0, 1, 2]
    np.testing.assert_allclose(sol.y[:3, 0], np.cos(sol.t[:3]), atol=1e-9)


def test_the_dopri5_tableau_is_the_published_one():
    """Dormand and Prince's 5(4) as scipy's RK45 ships it (nodes, matrix, weights, error
    weights, the continuous extension's coefficients), and the rows of a sum to the nodes."""
    from scipy.integrate._ivp.rk import RK45

    from mechdsl.solve.explicit import DOPRI5, _E5_4, _P5

    assert DOPRI5.stages == RK45.n_stages and DOPRI5.order == RK45.order
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
        sol = integrate(Problem(rhs), [1.0], grid, rtol=1.0 - 1e-9, atol=1e9, h0=h,
                        max_step=h, method=method)
        assert sol.steps == steps
        k = 1 if at is not None else -1
        errors.append(abs(sol.y[k, 0] - exact(sol.t[k])))
    return errors


def test_dopri5_steps_are_of_fifth_order_and_its_interpolant_of_fourth():
    from mechdsl.solve.explicit import DOPRI5

    e = _fixed_step_errors(DOPRI5, (16, 32))
    assert 4.6 <= np.log2(e[0] / e[1]) <= 5.6, e
    # inside a step the continuous extension's local error is O(h^5): halving h divides
    # it by about 32 (of order 4), while the steps before contribute O(h^5) globally
    e = _fixed_step_errors(DOPRI5, (16, 32), at=0.4)
    assert 3.7 <= np.log2(e[0] / e[1]) <= 5.6, e


def test_dopri5_holds_the_oscillator_to_its_tolerance_between_steps():
    from mechdsl.solve.explicit import DOPRI5

    t = np.linspace(0.0, 10.0, 401)
    sol = integrate(Problem(oscillator), [1.0, 0.0], t, rtol=1e-9, atol=1e-11, method=DOPRI5)
    assert sol.status == "ok" and sol.steps < len(t)  # outputs inside steps, interpolated
    np.testing.assert_allclose(sol.y[:, 0], np.cos(t), rtol=0, atol=2e-8)
    np.testing.assert_allclose(sol.y[:, 1], -np.sin(t), rtol=0, atol=2e-8)
