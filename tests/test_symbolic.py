"""The expression graph (mechdsl/symbolic): traced arithmetic compiled by ``kernel`` equals the
same arithmetic run by numpy; ``gradient`` and ``time_derivative`` equal finite differences
and closed forms; hash-consing and constant folding; tracing refuses what it cannot record."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mechdsl.symbolic import Graph, GraphError, kernel

BATCH = (4, 5)


def _leaves(g: Graph):
    """q0, q1, q2, qd0, qd1, p0 as graph variables."""
    return (g.var("q", 0), g.var("q", 1), g.var("q", 2), g.var("qd", 0), g.var("qd", 1),
            g.var("p", 0))


def _inputs(seed: int):
    """Random Q (batch + (3,)), QD (batch + (2,)) and one parameter (4, 1) per variant; the
    domain keeps every expression below smooth (q2 > 0, q0 > 0)."""
    rng = np.random.default_rng(seed)
    Q = rng.uniform(-1.5, 1.5, size=BATCH + (3,))
    Q[..., 0] = rng.uniform(0.3, 1.7, size=BATCH)
    Q[..., 2] = rng.uniform(0.5, 2.0, size=BATCH)
    QD = rng.uniform(-1.0, 1.0, size=BATCH + (2,))
    P = (rng.uniform(0.5, 2.0, size=(BATCH[0], 1)),)
    return Q, QD, P


def _columns(Q, QD, P):
    return (Q[..., 0], Q[..., 1], Q[..., 2], QD[..., 0], QD[..., 1], P[0])


# expressions written once, run on arrays (the reference) and on nodes (the trace)
def expr_trig(x, y, z, u, w, p):
    return (np.sin(x) * np.cos(y) + np.sqrt(z) / (1.0 + x**2)
            - np.arctan2(y, x) * np.exp(-u) + np.log(z + 2.0) * p)


def expr_powers(x, y, z, u, w, p):
    return (x - y) ** 3 / (z + 1.5) + 2.0 ** w + z**y - 3.0 / (x + z) + x**0.5 * p**2


def expr_misc(x, y, z, u, w, p):
    return (np.tan(0.3 * x) + np.arctan(w) * np.abs(y) + np.hypot(x, y) - np.square(u)
            + np.remainder(5.0 * x, 2.0) + (+y) - (-z) + 1.0 - p / z)


def expr_ratio(x, y, z, u, w, p):
    return np.arctan2(y * w + z, x - u) * np.sqrt(x * x + y * y) / (p + np.cos(z) ** 2)


EXPRESSIONS = [expr_trig, expr_powers, expr_misc, expr_ratio]


def test_kernel_equals_numpy():
    g = Graph()
    leaves = _leaves(g)
    outputs = [f(*leaves) for f in EXPRESSIONS]
    k = kernel(g, outputs)
    Q, QD, P = _inputs(1)
    got = k(Q, QD, None, P, ())
    assert got.shape == BATCH + (len(EXPRESSIONS),)
    for i, f in enumerate(EXPRESSIONS):
        want = f(*_columns(Q, QD, P))
        np.testing.assert_allclose(got[..., i], want, rtol=2e-15, atol=1e-15)


def test_kernel_outputs_variables_constants_and_repeats():
    """An output may be a variable, a constant (broadcast over the batch) or repeated."""
    g = Graph()
    x, y, z, u, w, p = _leaves(g)
    e = x * y
    k = kernel(g, [y, g.const(-2.5), e, e, w, p])
    Q, QD, P = _inputs(2)
    got = k(Q, QD, None, P, ())
    assert got.shape == BATCH + (6,)
    np.testing.assert_array_equal(got[..., 0], Q[..., 1])
    np.testing.assert_array_equal(got[..., 1], np.full(BATCH, -2.5))
    np.testing.assert_array_equal(got[..., 2], Q[..., 0] * Q[..., 1])
    np.testing.assert_array_equal(got[..., 3], Q[..., 0] * Q[..., 1])
    np.testing.assert_array_equal(got[..., 4], QD[..., 1])
    np.testing.assert_array_equal(got[..., 5], np.broadcast_to(P[0], BATCH))


def test_kernel_batch_shapes():
    """No batch axis, one, three: always batch + (outputs,)."""
    g = Graph()
    x, y = g.var("q", 0), g.var("q", 1)
    k = kernel(g, [np.sin(x) * y, x - y])
    rng = np.random.default_rng(3)
    for batch in ((), (7,), (2, 3, 4)):
        Q = rng.normal(size=batch + (2,))
        got = k(Q)
        assert got.shape == batch + (2,)
        np.testing.assert_allclose(got[..., 0], np.sin(Q[..., 0]) * Q[..., 1], rtol=1e-15)
        np.testing.assert_array_equal(got[..., 1], Q[..., 0] - Q[..., 1])


def test_kernel_registered_function():
    g = Graph()
    x, y = g.var("q", 0), g.var("q", 1)
    f = g.function(np.sinh, np.cosh, np.sinh)
    k = kernel(g, [g.call(f, 0, x * y), g.call(f, 1, x), g.call(f, 2, x + y)])
    Q = np.random.default_rng(4).normal(size=(3, 4, 2))
    got = k(Q, None, None, (), g.functions)
    a, b = Q[..., 0], Q[..., 1]
    np.testing.assert_allclose(got[..., 0], np.sinh(a * b), rtol=1e-15)
    np.testing.assert_allclose(got[..., 1], np.cosh(a), rtol=1e-15)
    np.testing.assert_allclose(got[..., 2], np.sinh(a + b), rtol=1e-15)


def test_kernel_registered_function_of_a_constant():
    """f(0.5) where the argument is a constant (e.g. a plugin's offset f(x) - f(0))."""
    g = Graph()
    x = g.var("q", 0)
    f = g.function(np.sinh, np.cosh, np.sinh)
    k = kernel(g, [g.call(f, 0, x) - g.call(f, 0, 0.5)])
    Q = np.random.default_rng(5).normal(size=(3, 4, 1))
    got = k(Q, None, None, (), g.functions)
    np.testing.assert_allclose(got[..., 0], np.sinh(Q[..., 0]) - np.sinh(0.5), rtol=1e-14)


# -- gradient ------------------------------------------------------------------------------

def _gradient_fd(f, cols, k, h=1e-5):
    """Central difference in leaf k of f on the arrays ``cols``."""
    plus, minus = list(cols), list(cols)
    step = h * np.maximum(1.0, np.abs(cols[k]))
    plus[k] = cols[k] + step
    minus[k] = cols[k] - step
    return (f(*plus) - f(*minus)) / (2 * step)


@pytest.mark.parametrize("f", EXPRESSIONS, ids=lambda f: f.__name__)
def test_gradient_equals_finite_differences(f):
    g = Graph()
    leaves = _leaves(g)
    grads = g.gradient(f(*leaves), leaves)
    k = kernel(g, grads)
    Q, QD, P = _inputs(6)
    cols = _columns(Q, QD, P)
    got = k(Q, QD, None, P, ())
    for i in range(len(leaves)):
        want = _gradient_fd(f, [np.broadcast_to(c, BATCH).copy() for c in cols], i)
        np.testing.assert_allclose(got[..., i], want, rtol=1e-7, atol=1e-8,
                                   err_msg=f"d/d{leaves[i]!r}")


def test_gradient_of_registered_function_and_second_order():
    g = Graph()
    x, y = g.var("q", 0), g.var("q", 1)
    f = g.function(np.sinh, np.cosh, np.sinh)
    e = g.call(f, 0, x * y) * np.cos(y)
    dx, dy = g.gradient(e, [x, y])
    # d/dx sinh(xy) cos y = y cosh(xy) cos y; its d/dy needs f'' (order 2)
    dxy = g.gradient(dx, [y])[0]
    k = kernel(g, [dx, dy, dxy])
    Q = np.random.default_rng(7).uniform(-1, 1, size=(5, 2))
    got = k(Q, None, None, (), g.functions)
    a, b = Q[:, 0], Q[:, 1]
    np.testing.assert_allclose(got[:, 0], b * np.cosh(a * b) * np.cos(b), rtol=1e-14)
    np.testing.assert_allclose(
        got[:, 1], a * np.cosh(a * b) * np.cos(b) - np.sinh(a * b) * np.sin(b), rtol=1e-14,
        atol=1e-15)
    # and the same against finite differences of numpy's own function
    def ref(u, v):
        return np.sinh(u * v) * np.cos(v)
    for i, want in enumerate((_gradient_fd(ref, [a, b], 0), _gradient_fd(ref, [a, b], 1))):
        np.testing.assert_allclose(got[:, i], want, rtol=1e-7)
    def dref(u, v):
        return v * np.cosh(u * v) * np.cos(v)
    np.testing.assert_allclose(got[:, 2], _gradient_fd(dref, [a, b], 1), rtol=1e-7, atol=1e-9)
    # a third derivative of a function argument is refused
    with pytest.raises(GraphError):
        g.gradient(g.gradient(dxy, [x])[0], [x])


def test_gradient_closed_forms():
    g = Graph()
    x, y = g.var("q", 0), g.var("q", 1)
    cases = [
        (np.arctan2(y, x), x, lambda a, b: -b / (a * a + b * b)),
        (np.arctan2(y, x), y, lambda a, b: a / (a * a + b * b)),
        (np.sqrt(x * x + y * y), y, lambda a, b: b / np.sqrt(a * a + b * b)),
        (x / y, y, lambda a, b: -a / (b * b)),
        (x / y, x, lambda a, b: 1 / b),
        (x**3, x, lambda a, b: 3 * a**2),
        (y**-1.5, y, lambda a, b: -1.5 * b**-2.5),
        (x**y, y, lambda a, b: a**b * np.log(a)),
        (np.exp(x * y), x, lambda a, b: b * np.exp(a * b)),
        (np.log(x), x, lambda a, b: 1 / a),
        (np.tan(x), x, lambda a, b: 1 / np.cos(a) ** 2),
        (np.arctan(y), y, lambda a, b: 1 / (1 + b * b)),
    ]
    k = kernel(g, [g.gradient(e, [v])[0] for e, v, _ in cases])
    Q = np.random.default_rng(8).uniform(0.2, 1.3, size=(6, 2))
    got = k(Q)
    for i, (_, _, closed) in enumerate(cases):
        np.testing.assert_allclose(got[:, i], closed(Q[:, 0], Q[:, 1]), rtol=1e-14,
                                   err_msg=f"case {i}")


def test_gradient_structure():
    """d(xy)/dx is the node y itself; a variable the expression does not use gets zero."""
    g = Graph()
    x, y, z = g.var("q", 0), g.var("q", 1), g.var("q", 2)
    dx, dy, dz = g.gradient(x * y, [x, y, z])
    assert dx is y and dy is x and dz is g.zero
    assert g.gradient(np.sin(x), [x])[0] is np.cos(x)


# -- time derivative -----------------------------------------------------------------------

def _rate(g: Graph):
    def rate(v):
        kind = v.value[0]
        if kind == "q":
            return g.var("qd", v.value[1])
        if kind == "t":
            return g.one
        return None  # qd (qdd = 0) and parameters
    return rate


def _second_derivative_along(f, q0, qd, p, t=None, h=2e-3):
    """d^2/ds^2 f(q0 + qd s) at s = 0 (and t + s where t is given): second central
    differences at h and h/2, Richardson-extrapolated."""
    def at(s):
        q = q0 + s * qd
        args = [q[..., 0], q[..., 1], q[..., 2], qd[..., 0], qd[..., 1], p]
        return f(*args) if t is None else f(*args, t + s)

    def d2(step):
        return (at(step) - 2 * at(0.0) + at(-step)) / step**2
    return (4 * d2(h / 2) - d2(h)) / 3


@pytest.mark.parametrize("f", EXPRESSIONS, ids=lambda f: f.__name__)
def test_time_derivative_twice_is_the_second_derivative_along_the_motion(f):
    """-gamma = D(D(Phi)) with qdd = 0 (Phi here also reads qd, held constant)."""
    g = Graph()
    leaves = _leaves(g)
    e = f(*leaves)
    rate = _rate(g)
    (d1,) = g.time_derivative([e], rate)
    (d2,) = g.time_derivative([d1], rate)
    k = kernel(g, [d1, d2])
    Q, _, P = _inputs(9)
    # the motion q(s) = q0 + qd s: a rate for each of the three coordinates
    QD = np.random.default_rng(10).uniform(-1, 1, size=BATCH + (3,))
    got = k(Q, QD, None, P, ())
    # first derivative: the gradient against qd
    grad = kernel(g, g.gradient(e, leaves[:3]))(Q, QD, None, P, ())
    np.testing.assert_allclose(got[..., 0], (grad * QD).sum(axis=-1), rtol=1e-13, atol=1e-14)
    want = _second_derivative_along(f, Q, QD, P[0])
    np.testing.assert_allclose(got[..., 1], want, rtol=1e-6, atol=1e-7)


def test_time_derivative_with_explicit_time_and_function():
    g = Graph()
    x, y, z = g.var("q", 0), g.var("q", 1), g.var("q", 2)
    t = g.var("t")
    f = g.function(np.sin, np.cos, lambda a: -np.sin(a))
    e = g.call(f, 0, x * t) + y * np.exp(0.5 * t) - np.sqrt(z) * t**2
    rate = _rate(g)
    (d2,) = g.time_derivative(g.time_derivative([e], rate), rate)
    k = kernel(g, [d2])
    rng = np.random.default_rng(11)
    Q = rng.uniform(0.5, 1.5, size=(6, 3))
    QD = rng.uniform(-1, 1, size=(6, 3))
    T = rng.uniform(0, 2, size=6)
    got = k(Q, QD, T, (), g.functions)[:, 0]

    def ref(a, b, c, u, w, p, s):
        return np.sin(a * s) + b * np.exp(0.5 * s) - np.sqrt(c) * s**2
    want = _second_derivative_along(ref, Q, QD, None, t=T)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)


# -- hash-consing and folding --------------------------------------------------------------

def test_hash_consing():
    g = Graph()
    x, y, z = g.var("q", 0), g.var("q", 1), g.var("q", 2)
    assert g.var("q", 0) is x
    first = np.sin(x) * (y + z) / np.sqrt(z)
    count = len(g.nodes)
    second = np.sin(x) * (y + z) / np.sqrt(z)
    assert second is first and len(g.nodes) == count
    assert np.cos(x) is np.cos(x)
    assert x + y is y + x
    assert x * y is y * x
    assert x - y is not y - x
    assert x / y is not y / x
    assert g.const(2.0) is g.const(2)


def test_constant_folding_and_simplification():
    g = Graph()
    x, y = g.var("q", 0), g.var("q", 1)
    assert (x * 0) is g.zero and (0 * x) is g.zero
    assert (1 * x) is x and (x * 1) is x
    assert (x + 0) is x and (0 + x) is x and (x - 0) is x
    assert (x - x) is g.zero
    assert -(-x) is x
    assert x**1 is x and x**0 is g.one
    assert x**2 is x * x and np.square(x) is x * x
    assert x**0.5 is np.sqrt(x)
    assert 0 / x is g.zero and x / 1 is x
    assert x + (-y) is x - y
    assert (-x) * (-y) is x * y
    five = g.const(2.0) + 3
    assert five.op == "const" and five.value == 5.0 and five is g.const(5.0)
    folded = np.sin(g.const(0.5)) * g.const(2.0) - np.sqrt(g.const(9.0))
    assert folded.op == "const"
    assert folded.value == pytest.approx(2 * math.sin(0.5) - 3.0, rel=1e-15)
    assert g.const(-0.0) is g.zero
    # undefined folds give NaN, shared, rather than an exception
    assert g.const(1.0) / 0 is g.const(float("nan"))
    assert np.sqrt(g.const(-1.0)) is g.const(float("nan"))
    assert math.isnan(g.constant_value(np.log(g.const(-1.0))))


# -- what cannot be traced -----------------------------------------------------------------

def test_branching_and_untraceable_operations_raise():
    g = Graph()
    x, y = g.var("q", 0), g.var("q", 1)
    node = np.sin(x) + y
    with pytest.raises(GraphError):
        if node:
            pass
    with pytest.raises(GraphError):
        node < 1  # noqa: B015
    with pytest.raises(GraphError):
        node == 1  # noqa: B015
    with pytest.raises(GraphError):
        node >= x  # noqa: B015
    with pytest.raises(GraphError):
        max(node, 1.0)
    with pytest.raises(GraphError):
        float(node)
    with pytest.raises(GraphError):
        int(node)
    with pytest.raises(GraphError):
        math.sin(node)
    with pytest.raises(GraphError):
        np.maximum(node, 1.0)
    with pytest.raises(GraphError):
        np.multiply.outer(node, x)
    with pytest.raises(GraphError):
        node + [1.0, 2.0]
    with pytest.raises(GraphError):
        node + Graph().var("q", 0)  # a node of another graph
    with pytest.raises(GraphError):
        g.gradient(x % y, [x])  # mod by a variable has no derivative


def test_substitute_composes_with_a_map_of_the_same_variables():
    """f(q) with q = g(q') written in the same variables (q0 <- q0 + sin(q1), q1 <- q0 q1),
    substituted: the composed graph's kernel equals f evaluated at g by numpy, its
    gradient equals the chain rule's (finite differences), and a registered function
    (an opaque call) is rebuilt on its new argument."""
    from mechdsl.symbolic.codegen import scalar_kernel

    g = Graph()
    q0, q1, qd0 = g.var("q", 0), g.var("q", 1), g.var("qd", 0)
    idx = g.function(np.tanh, lambda x: 1 - np.tanh(x) ** 2,
                     lambda x: -2 * np.tanh(x) * (1 - np.tanh(x) ** 2))
    f = [np.sin(q0) * q1 + qd0 * q0 ** 2, g.call(idx, 0, q1) - np.sqrt(q0 * q0 + 1.0)]
    values = {("q", 0): q0 + np.sin(q1), ("q", 1): q0 * q1}
    composed = g.substitute(f, values)
    fn = scalar_kernel(g, composed, "composed").fn
    grad = scalar_kernel(g, [d for r in composed for d in g.gradient(r, [q0, q1])],
                         "grad").fn

    def direct(z0: float, z1: float, v: float) -> np.ndarray:
        a, b = z0 + math.sin(z1), z0 * z1
        return np.array([math.sin(a) * b + v * a * a, math.tanh(b) - math.sqrt(a * a + 1)])

    F = ((math.tanh, lambda x: 1 - math.tanh(x) ** 2, None),)
    rng = np.random.default_rng(3)
    for _ in range(5):
        z0, z1, v = rng.uniform(-1.5, 1.5, 3)
        assert np.allclose(fn([z0, z1], [v], 0.0, [], F), direct(z0, z1, v), rtol=1e-14,
                           atol=1e-14)
        e = 1e-6
        fd = np.column_stack([(direct(z0 + e, z1, v) - direct(z0 - e, z1, v)) / (2 * e),
                              (direct(z0, z1 + e, v) - direct(z0, z1 - e, v)) / (2 * e)])
        got = np.array(grad([z0, z1], [v], 0.0, [], F)).reshape(2, 2)
        assert np.abs(got - fd).max() < 1e-8
