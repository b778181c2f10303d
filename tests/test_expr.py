"""Exact time derivatives of expressions, checked against central differences and closed
forms; evaluation broadcasting; printing that parses back to the same function."""

import numpy as np
import pytest

from mechdsl.grammar import expr as E
from mechdsl.grammar.derive import derivative
from mechdsl.grammar import parse_expr

PARAMS = {"a": 0.7, "b": 1.3}
T = np.linspace(0.05, 0.95, 37)


def f_of(text):
    return parse_expr(text, "test", ["a", "b", "t"])


def central(e, t, h=1e-5):
    """Richardson-extrapolated central difference: error O(h^4)."""
    g = lambda s: np.asarray(E.evaluate(e, {**PARAMS, "t": s}), dtype=float)  # noqa: E731
    d1 = (g(t + h) - g(t - h)) / (2 * h)
    d2 = (g(t + h / 2) - g(t - h / 2)) / h
    return (4 * d2 - d1) / 3


EXPRESSIONS = [
    "sin(a*t) + cos(b*t)", "tan(t)", "asin(t/2)", "acos(t/2)", "atan(3*t)", "atan2(t, 1 + t)",
    "atan2(sin(t), a)", "sqrt(1 + t^2)", "exp(-a*t)", "log(1 + t)", "abs(t - 0.5)",
    "sign(t - 0.5)*t", "min(t, 0.5, a)", "max(t^2, 0.3)", "t^3", "t^b", "b^t", "t^t",
    "1/(1 + t)", "(a*t + 1)/(t^2 + b)", "-t^2", "if t < 0.5 then t^2 else 1 - t",
    "if t > 0.2 and t < 0.6 then sin(t) else cos(t)", "if not t < 0.3 or t > 0.9 then t else 2*t",
    "pi/4 + a*t", "3", "a*b",
]


@pytest.mark.parametrize("text", EXPRESSIONS)
def test_first_and_second_derivatives_match_central_differences(text):
    e = f_of(text)
    d1, d2 = derivative(e), derivative(derivative(e))
    env = {**PARAMS, "t": T}
    # stay away from the kinks of abs, min, max, sign and the switches of if-then-else
    kinks = np.array([0.2, 0.3, 0.5, 0.6, 0.7, 0.9, np.sqrt(0.3)])
    t = T[np.min(np.abs(T[:, None] - kinks[None, :]), axis=1) > 1e-3]
    env["t"] = t
    got1 = np.broadcast_to(E.evaluate(d1, env), t.shape)
    np.testing.assert_allclose(got1, central(e, t), rtol=1e-8, atol=1e-8)
    got2 = np.broadcast_to(E.evaluate(d2, env), t.shape)
    np.testing.assert_allclose(got2, central(d1, t), rtol=1e-7, atol=1e-7)


def test_derivatives_have_exact_closed_forms():
    e = f_of("sin(t^2)")
    d = derivative(e)
    np.testing.assert_allclose(E.evaluate(d, {"t": T}), 2 * T * np.cos(T**2), rtol=1e-15)
    dd = derivative(d)
    np.testing.assert_allclose(E.evaluate(dd, {"t": T}),
                               2 * np.cos(T**2) - 4 * T**2 * np.sin(T**2), rtol=1e-14)


def test_constants_and_params_have_zero_derivative():
    assert derivative(f_of("a*b + pi")) == E.Num(0.0)
    assert E.to_text(derivative(f_of("a*t + b"))) == "a"


def test_every_function_has_a_derivative_rule():
    for name, (lo, _hi) in E.FUNCTIONS.items():
        args = ", ".join(["t"] + ["0.5"] * (lo - 1))
        derivative(f_of(f"{name}({args})"))


@pytest.mark.parametrize("text", EXPRESSIONS)
def test_printed_expressions_parse_back_to_the_same_function(text):
    e = f_of(text)
    back = f_of(E.to_text(e))
    env = {**PARAMS, "t": T}
    np.testing.assert_array_equal(np.broadcast_to(E.evaluate(back, env), T.shape),
                                  np.broadcast_to(E.evaluate(e, env), T.shape))


def test_evaluation_broadcasts_variants_against_instants():
    e = f_of("a*t + b")
    out = E.evaluate(e, {"a": np.array([[1.0], [2.0]]), "b": np.array([[0.0], [1.0]]),
                         "t": np.array([0.0, 1.0, 2.0])})
    np.testing.assert_array_equal(out, [[0, 1, 2], [1, 3, 5]])
