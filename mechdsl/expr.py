"""Expression trees: the nodes, simplifying constructors, and evaluation over numpy arrays.

A driving constraint ``g(q) = f(t)`` needs f, f' and f'' exactly (Haug's nu = f'(t) and the
f''(t) term of gamma): :mod:`mechdsl.derive` derives them from these trees, never by finite
differences. Every node keeps the :class:`~mechdsl.errors.Span` it was written at.

Evaluation is vectorised: a compiled expression takes a mapping of names to floats or arrays
and returns whatever numpy broadcasting of those gives (so one call serves every instant of a
run and every variant of a sweep).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Union

import numpy as np

from .errors import Span

# ---------------------------------------------------------------------------------------------
# Nodes


@dataclass(frozen=True)
class Num:
    value: float
    span: Span | None = None


@dataclass(frozen=True)
class Name:
    """A param, ``t``, or (as a joint argument) a body name."""

    id: str
    span: Span | None = None


@dataclass(frozen=True)
class Ref:
    """A dotted reference ``body.point``; valid only as a joint or drive argument."""

    parts: tuple[str, ...]
    span: Span | None = None


@dataclass(frozen=True)
class Unary:
    op: str  # '-' or 'not'
    operand: "Expr"
    span: Span | None = None


@dataclass(frozen=True)
class Binary:
    op: str  # + - * / ^
    left: "Expr"
    right: "Expr"
    span: Span | None = None


@dataclass(frozen=True)
class Compare:
    op: str  # < <= > >=
    left: "Expr"
    right: "Expr"
    span: Span | None = None


@dataclass(frozen=True)
class Logic:
    op: str  # and, or
    left: "Expr"
    right: "Expr"
    span: Span | None = None


@dataclass(frozen=True)
class Call:
    func: str
    args: tuple["Expr", ...]
    span: Span | None = None


@dataclass(frozen=True)
class Cond:
    """``if test then then else orelse``."""

    test: "Expr"
    then: "Expr"
    orelse: "Expr"
    span: Span | None = None


@dataclass(frozen=True)
class Table:
    """A cubic spline through the points (xs, ys), continuous in value, slope and curvature,
    evaluated at ``arg``; ``order`` > 0 is its derivative of that order. Periodic with period
    ``period`` when given (then ys[0] == ys[-1] over one period), else undefined (NaN)
    outside [xs[0], xs[-1]]. ``label`` is how the data was written, for display."""

    xs: tuple[float, ...]
    ys: tuple[float, ...]
    arg: "Expr"
    period: float | None = None
    order: int = 0
    label: str = ""
    span: Span | None = field(default=None, compare=False)


Expr = Union[Num, Name, Ref, Unary, Binary, Compare, Logic, Call, Cond, Table]

#: Function name -> (min args, max args or None for variadic). ``sign`` is the derivative of abs.
FUNCTIONS: dict[str, tuple[int, int | None]] = {
    "sin": (1, 1), "cos": (1, 1), "tan": (1, 1),
    "asin": (1, 1), "acos": (1, 1), "atan": (1, 1), "atan2": (2, 2),
    "sqrt": (1, 1), "exp": (1, 1), "log": (1, 1), "abs": (1, 1), "sign": (1, 1),
    "min": (2, None), "max": (2, None),
}
CONSTANTS: dict[str, float] = {"pi": math.pi}
BOOLEAN = (Compare, Logic)


def is_boolean(e: Expr) -> bool:
    """True for nodes whose value is a truth value (comparisons, and/or/not)."""
    return isinstance(e, BOOLEAN) or (isinstance(e, Unary) and e.op == "not")


def children(e: Expr) -> tuple[Expr, ...]:
    """The direct sub-expressions of ``e``."""
    if isinstance(e, (Binary, Compare, Logic)):
        return (e.left, e.right)
    if isinstance(e, Unary):
        return (e.operand,)
    if isinstance(e, Call):
        return e.args
    if isinstance(e, Cond):
        return (e.test, e.then, e.orelse)
    if isinstance(e, Table):
        return (e.arg,)
    return ()


def walk(e: Expr):
    """Every node of ``e``, parents before children."""
    stack = [e]
    while stack:
        node = stack.pop()
        yield node
        stack.extend(reversed(children(node)))


def free_names(e: Expr) -> set[str]:
    """The names (params, ``t``) that ``e`` reads."""
    return {n.id for n in walk(e) if isinstance(n, Name)}


# ---------------------------------------------------------------------------------------------
# Simplifying constructors: keep derivative trees small so that evaluating them stays cheap.


def _num(e: Expr) -> float | None:
    return e.value if isinstance(e, Num) else None


def add(a: Expr, b: Expr) -> Expr:
    x, y = _num(a), _num(b)
    if x is not None and y is not None:
        return Num(x + y)
    if x == 0:
        return b
    if y == 0:
        return a
    return Binary("+", a, b)


def sub(a: Expr, b: Expr) -> Expr:
    x, y = _num(a), _num(b)
    if x is not None and y is not None:
        return Num(x - y)
    if y == 0:
        return a
    if x == 0:
        return neg(b)
    return Binary("-", a, b)


def mul(a: Expr, b: Expr) -> Expr:
    x, y = _num(a), _num(b)
    if x is not None and y is not None:
        return Num(x * y)
    if x == 0 or y == 0:
        return Num(0.0)
    if x == 1:
        return b
    if y == 1:
        return a
    if x == -1:
        return neg(b)
    if y == -1:
        return neg(a)
    return Binary("*", a, b)


def div(a: Expr, b: Expr) -> Expr:
    x, y = _num(a), _num(b)
    if x == 0:
        return Num(0.0)
    if y == 1:
        return a
    if x is not None and y is not None and y != 0:
        return Num(x / y)
    return Binary("/", a, b)


def power(a: Expr, b: Expr) -> Expr:
    x, y = _num(a), _num(b)
    if y == 0:
        return Num(1.0)
    if y == 1:
        return a
    if x is not None and y is not None:
        try:
            return Num(float(x**y)) if not (x < 0 and y != int(y)) else Binary("^", a, b)
        except (OverflowError, ZeroDivisionError):
            return Binary("^", a, b)
    return Binary("^", a, b)


def neg(a: Expr) -> Expr:
    x = _num(a)
    if x is not None:
        return Num(-x)
    if isinstance(a, Unary) and a.op == "-":
        return a.operand
    return Unary("-", a)


def call(func: str, *args: Expr) -> Expr:
    return Call(func, tuple(args))


def cond(test: Expr, then: Expr, orelse: Expr) -> Expr:
    if then == orelse:
        return then
    return Cond(test, then, orelse)


# ---------------------------------------------------------------------------------------------
# Evaluation

Env = Mapping[str, "float | np.ndarray"]
Compiled = Callable[[Env], "float | np.ndarray"]

_UFUNCS: dict[str, Callable] = {
    "sin": np.sin, "cos": np.cos, "tan": np.tan, "asin": np.arcsin, "acos": np.arccos,
    "atan": np.arctan, "atan2": np.arctan2, "sqrt": np.sqrt, "exp": np.exp, "log": np.log,
    "abs": np.abs, "sign": np.sign,
}
_BINOPS: dict[str, Callable] = {
    "+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide, "^": np.power,
    "<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal,
    "and": np.logical_and, "or": np.logical_or,
}


def compile_expr(e: Expr) -> Compiled:
    """Turn ``e`` into a function of an environment (name -> float or array).

    The result broadcasts like numpy: names bound to arrays of shapes (V, 1) and (K,) give a
    (V, K) result. Domain errors give NaN (callers check finiteness where it matters).
    """
    if isinstance(e, Num):
        v = float(e.value)
        return lambda env: v
    if isinstance(e, Name):
        key = e.id
        return lambda env: env[key]
    if isinstance(e, Unary):
        f = compile_expr(e.operand)
        op = np.negative if e.op == "-" else np.logical_not
        return lambda env: op(f(env))
    if isinstance(e, (Binary, Compare, Logic)):
        fl, fr, op = compile_expr(e.left), compile_expr(e.right), _BINOPS[e.op]
        return lambda env: op(fl(env), fr(env))
    if isinstance(e, Cond):
        ft, fa, fb = compile_expr(e.test), compile_expr(e.then), compile_expr(e.orelse)
        return lambda env: np.where(ft(env), fa(env), fb(env))
    if isinstance(e, Table):
        spline = _spline(e)
        fa = compile_expr(e.arg)
        return lambda env: spline(fa(env))
    if isinstance(e, Call):
        fs = [compile_expr(a) for a in e.args]
        if e.func in ("min", "max"):
            red = np.minimum if e.func == "min" else np.maximum

            def minmax(env: Env):
                out = fs[0](env)
                for g in fs[1:]:
                    out = red(out, g(env))
                return out

            return minmax
        uf = _UFUNCS[e.func]
        if len(fs) == 1:
            (g,) = fs
            return lambda env: uf(g(env))
        g, h = fs
        return lambda env: uf(g(env), h(env))
    raise TypeError(f"cannot evaluate {type(e).__name__}")


def _spline(e: Table) -> Callable:
    """The scipy spline (or its derivative) of a table; scipy is imported only here."""
    from scipy.interpolate import CubicSpline

    xs, ys = np.asarray(e.xs), np.asarray(e.ys)
    if e.period is not None:
        s = CubicSpline(xs, ys, bc_type="periodic", extrapolate="periodic")
    else:
        s = CubicSpline(xs, ys, bc_type="not-a-knot", extrapolate=False)
    return s.derivative(e.order) if e.order else s


def evaluate(e: Expr, env: Env) -> "float | np.ndarray":
    """Evaluate ``e`` once (numpy floating-point warnings silenced; check the result)."""
    with np.errstate(all="ignore"):
        return compile_expr(e)(env)


# ---------------------------------------------------------------------------------------------
# Display

_PREC = {"or": 1, "and": 2, "<": 4, "<=": 4, ">": 4, ">=": 4, "+": 5, "-": 5, "*": 6, "/": 6, "^": 8}


def to_text(e: Expr) -> str:
    """Render ``e`` in ``.mech`` syntax with the fewest parentheses that keep its meaning."""
    return _text(e, 0)


def _text(e: Expr, outer: int) -> str:
    if isinstance(e, Num):
        v = e.value
        if v == math.pi:
            return "pi"
        s = repr(float(v))
        s = s[:-2] if s.endswith(".0") else s
        return f"({s})" if v < 0 and outer > 0 else s
    if isinstance(e, Name):
        return e.id
    if isinstance(e, Ref):
        return ".".join(e.parts)
    if isinstance(e, Unary):
        if e.op == "not":
            s = f"not {_text(e.operand, 3)}"
            return f"({s})" if outer > 3 else s
        s = f"-{_text(e.operand, 7)}"
        return f"({s})" if outer > 5 else s
    if isinstance(e, (Binary, Compare, Logic)):
        p = _PREC[e.op]
        sep = e.op if e.op in ("*", "/", "^") else f" {e.op} "
        if e.op == "^":  # right-associative
            s = f"{_text(e.left, p + 1)}{sep}{_text(e.right, p)}"
        else:
            s = f"{_text(e.left, p)}{sep}{_text(e.right, p + 1)}"
        return f"({s})" if p < outer or (p == outer and isinstance(e, Compare)) else s
    if isinstance(e, Call):
        return f"{e.func}({', '.join(_text(a, 0) for a in e.args)})"
    if isinstance(e, Cond):
        s = f"if {_text(e.test, 0)} then {_text(e.then, 0)} else {_text(e.orelse, 0)}"
        return f"({s})" if outer > 0 else s
    if isinstance(e, Table):
        period = f", {e.period!r}" if e.period is not None else ""
        return f"table({e.label}, {_text(e.arg, 0)}{period})" + "'" * e.order
    raise TypeError(type(e).__name__)
