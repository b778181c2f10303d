"""Expression trees: the nodes, simplifying constructors, and evaluation over numpy arrays.

A driving constraint ``g(q) = f(t)`` needs f, f' and f'' exactly (Haug's nu = f'(t) and the
f''(t) term of gamma): :mod:`mechdsl.grammar.derive` derives them from these trees, never by finite
differences. Every node keeps the :class:`~mechdsl.errors.Span` it was written at.

Evaluation is vectorised: a compiled expression takes a mapping of names to floats or arrays
and returns whatever numpy broadcasting of those gives (so one call serves every instant of a
run and every variant of a sweep).

No function here recurses over a tree: a sum of thousands of terms is thousands of levels
deep, far beyond Python's recursion limit. Walks keep their own stacks, compilation makes a
flat program of steps, and display runs generators on an explicit stack (:func:`_run`).
Derived trees share subtrees (a DAG); the walks visit a shared node once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Callable, Generator, Mapping, NamedTuple, Union

import numpy as np

from ..errors import Span

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
    outside [xs[0], xs[-1]]. ``label`` is how the data was written, for display; ``path``
    the real path of the file it is read from, if any (an output must never replace it), and
    ``data_span`` where the data is written. A table of a file is parsed without its points
    (:attr:`unread`); they are read when the model is compiled
    (:func:`mechdsl.compiled.files.read_files`)."""

    xs: tuple[float, ...]
    ys: tuple[float, ...]
    arg: "Expr"
    period: float | None = None
    order: int = 0
    label: str = ""
    span: Span | None = field(default=None, compare=False)
    path: str | None = field(default=None, compare=False)
    data_span: Span | None = field(default=None, compare=False)

    @property
    def unread(self) -> bool:
        """A table of a file whose points are not read yet."""
        return self.path is not None and not self.xs


Expr = Union[Num, Name, Ref, Unary, Binary, Compare, Logic, Call, Cond, Table]
#: the node classes of :data:`Expr`, for isinstance (a check against the Union itself goes
#: through typing's slow path)
NODES = (Num, Name, Ref, Unary, Binary, Compare, Logic, Call, Cond, Table)
_COMPARED = {t: tuple(f.name for f in fields(t) if f.compare) for t in NODES}

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


def with_children(e: Expr, kids: tuple) -> Expr:
    """``e`` with its direct sub-expressions replaced by ``kids`` (in :func:`children`'s
    order); ``e`` itself when they are the same objects."""
    if all(a is b for a, b in zip(kids, children(e))):
        return e
    if isinstance(e, (Binary, Compare, Logic)):
        return replace(e, left=kids[0], right=kids[1])
    if isinstance(e, Unary):
        return replace(e, operand=kids[0])
    if isinstance(e, Call):
        return replace(e, args=tuple(kids))
    if isinstance(e, Cond):
        return replace(e, test=kids[0], then=kids[1], orelse=kids[2])
    if isinstance(e, Table):
        return replace(e, arg=kids[0])
    return e


def rewrite(e: Expr, rule: Callable[[Expr], Expr]) -> Expr:
    """``e`` rewritten bottom-up: every node, its operands already rewritten, is replaced by
    ``rule(node)`` (which returns the node itself to keep it). No recursion; a shared
    subtree is rewritten once."""
    done: dict[int, Expr] = {}
    for node in postorder(e):
        done[id(node)] = rule(with_children(node, tuple(done[id(k)] for k in children(node))))
    return done[id(e)]


def walk(e: Expr):
    """Every node of ``e``, parents before children (a subtree shared by several parents,
    as in derived trees, once)."""
    stack, seen = [e], set()
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        yield node
        stack.extend(reversed(children(node)))


def postorder(e: Expr, kids: Callable[[Expr], tuple] | None = None) -> list[Expr]:
    """The nodes of ``e``, each once, children before parents (``kids`` gives the children
    to visit; default :func:`children`)."""
    kids = kids or children
    order: list[Expr] = []
    seen: set[int] = set()
    stack: list[tuple[Expr, bool]] = [(e, False)]
    while stack:
        node, done = stack.pop()
        if done:
            order.append(node)
        elif id(node) not in seen:
            seen.add(id(node))
            stack.append((node, True))
            stack.extend((k, False) for k in reversed(kids(node)) if id(k) not in seen)
    return order


def equal(a: Expr, b: Expr) -> bool:
    """``a == b`` as the dataclasses compare them (fields, spans included, except a table's),
    without recursion."""
    stack, seen = [(a, b)], set()
    while stack:
        x, y = stack.pop()
        if x is y:
            continue
        if isinstance(x, NODES) or isinstance(y, NODES):
            if type(x) is not type(y):
                return False
            if (id(x), id(y)) in seen:
                continue
            seen.add((id(x), id(y)))
            stack.extend((getattr(x, f), getattr(y, f)) for f in _COMPARED[type(x)])
        elif isinstance(x, tuple) and isinstance(y, tuple):
            if len(x) != len(y):
                return False
            stack.extend(zip(x, y))
        elif not x == y:
            return False
    return True


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
    if equal(then, orelse):
        return then
    return Cond(test, then, orelse)


# ---------------------------------------------------------------------------------------------
# The functions' derivatives, written once for both derivative engines

class Ops(NamedTuple):
    """The arithmetic a derivative rule is written in: on expression trees (:data:`TREE`,
    :mod:`mechdsl.grammar.derive`) or on a traced graph's nodes
    (:meth:`mechdsl.symbolic.graph.Graph.local`). ``call(name, x)`` applies the language's
    function ``name``."""

    add: Callable
    sub: Callable
    mul: Callable
    div: Callable
    neg: Callable
    square: Callable
    call: Callable
    const: Callable


#: the tree arithmetic, simplifying as it builds
TREE = Ops(add, sub, mul, div, neg, lambda x: power(x, Num(2.0)), call, Num)

#: d f(u) / du of the language's smooth functions of one argument, from u and f(u), in the
#: arithmetic ``o`` of the engine that asks: the drives' and outputs' derivatives
#: (:func:`mechdsl.grammar.derive.derivative`) and the plugins' traced equations
#: (:meth:`mechdsl.symbolic.graph.Graph.local`) both read this table. (``abs``, ``min``,
#: ``max`` are piecewise: the trees differentiate them branch by branch.)
DERIVATIVES: Mapping[str, Callable] = MappingProxyType({
    "sin": lambda o, u, fu: o.call("cos", u),
    "cos": lambda o, u, fu: o.neg(o.call("sin", u)),
    "tan": lambda o, u, fu: o.add(o.const(1.0), o.square(fu)),
    "asin": lambda o, u, fu: o.div(o.const(1.0),
                                   o.call("sqrt", o.sub(o.const(1.0), o.square(u)))),
    "acos": lambda o, u, fu: o.neg(o.div(o.const(1.0),
                                         o.call("sqrt", o.sub(o.const(1.0), o.square(u))))),
    "atan": lambda o, u, fu: o.div(o.const(1.0), o.add(o.const(1.0), o.square(u))),
    "sqrt": lambda o, u, fu: o.div(o.const(0.5), fu),
    "exp": lambda o, u, fu: fu,
    "log": lambda o, u, fu: o.div(o.const(1.0), u),
    "sign": lambda o, u, fu: o.const(0.0),
})


def atan2_partials(o: Ops, y, x) -> tuple:
    """d atan2(y, x) / dy = x / (x^2 + y^2) and d / dx = -y / (x^2 + y^2), in ``o``."""
    r2 = o.add(o.square(x), o.square(y))
    return o.div(x, r2), o.neg(o.div(y, r2))


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

    The function runs a flat program, one step per node in post-order (the order, and so
    the floating-point result, of evaluating the tree recursively), each shared node once;
    a value is dropped after its last use, so that memory stays that of the recursion.
    """
    if isinstance(e, Num):
        v = float(e.value)
        return lambda env: v
    if isinstance(e, Name):
        key = e.id
        return lambda env: env[key]
    order = postorder(e)
    slot = {id(n): i for i, n in enumerate(order)}
    steps = []
    last_use = [0] * len(order)
    for i, node in enumerate(order):
        args = [slot[id(k)] for k in children(node)]
        for a in args:
            last_use[a] = i
        steps.append(_step(node, args))
    drops: list[list[int]] = [[] for _ in order]
    for a, i in enumerate(last_use[:-1]):
        drops[i].append(a)
    program = list(zip(steps, drops))

    def run(env: Env):
        values: list = [None] * len(program)
        for i, (step, drop) in enumerate(program):
            values[i] = step(values, env)
            for a in drop:
                values[a] = None
        return values[-1]

    return run


def _step(e: Expr, args: list[int]) -> Callable[[list, Env], object]:
    """The step of the program computing node ``e`` from the values of its children, which
    are in the slots ``args``."""
    if isinstance(e, Num):
        v = float(e.value)
        return lambda values, env: v
    if isinstance(e, Name):
        key = e.id
        return lambda values, env: env[key]
    if isinstance(e, Unary):
        (a,) = args
        op = np.negative if e.op == "-" else np.logical_not
        return lambda values, env: op(values[a])
    if isinstance(e, (Binary, Compare, Logic)):
        a, b = args
        op = _BINOPS[e.op]
        return lambda values, env: op(values[a], values[b])
    if isinstance(e, Cond):
        a, b, c = args
        return lambda values, env: np.where(values[a], values[b], values[c])
    if isinstance(e, Table):
        spline = _spline(e)
        (a,) = args
        return lambda values, env: spline(values[a])
    if isinstance(e, Call):
        if e.func in ("min", "max"):
            red = np.minimum if e.func == "min" else np.maximum
            first, rest = args[0], args[1:]

            def minmax(values: list, env: Env):
                out = values[first]
                for a in rest:
                    out = red(out, values[a])
                return out

            return minmax
        uf = _UFUNCS[e.func]
        if len(args) == 1:
            (a,) = args
            return lambda values, env: uf(values[a])
        a, b = args
        return lambda values, env: uf(values[a], values[b])
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
    return _run(_text(e, 0))


def _run(gen: Generator) -> object:
    """Run a recursive generator function without recursion: where it would call itself it
    yields the generator of the call, and receives that call's result (its return value)."""
    stack, value = [gen], None
    while stack:
        try:
            call = stack[-1].send(value)
        except StopIteration as done:
            stack.pop()
            value = done.value
        else:
            stack.append(call)
            value = None
    return value


def _text(e: Expr, outer: int) -> Generator:
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
            s = f"not {(yield _text(e.operand, 3))}"
            return f"({s})" if outer > 3 else s
        s = f"-{(yield _text(e.operand, 7))}"
        return f"({s})" if outer > 5 else s
    if isinstance(e, (Binary, Compare, Logic)):
        p = _PREC[e.op]
        sep = e.op if e.op in ("*", "/", "^") else f" {e.op} "
        if e.op == "^":  # right-associative
            s = f"{(yield _text(e.left, p + 1))}{sep}{(yield _text(e.right, p))}"
        else:
            s = f"{(yield _text(e.left, p))}{sep}{(yield _text(e.right, p + 1))}"
        return f"({s})" if p < outer or (p == outer and isinstance(e, Compare)) else s
    if isinstance(e, Call):
        args = []
        for a in e.args:
            args.append((yield _text(a, 0)))
        return f"{e.func}({', '.join(args)})"
    if isinstance(e, Cond):
        s = (f"if {(yield _text(e.test, 0))} then {(yield _text(e.then, 0))} "
             f"else {(yield _text(e.orelse, 0))}")
        return f"({s})" if outer > 0 else s
    if isinstance(e, Table):
        period = f", {e.period!r}" if e.period is not None else ""
        return f"table({e.label}, {(yield _text(e.arg, 0))}{period})" + "'" * e.order
    raise TypeError(type(e).__name__)
