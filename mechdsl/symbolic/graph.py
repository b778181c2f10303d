"""Expression graphs: a type's equations traced once, differentiated exactly, shared.

A plugin writes its constraint equations as plain arithmetic (``+ - * / **``) and numpy
functions (``np.sin``, ``np.sqrt``, ``np.arctan2``, ...) on scalars. Run on numpy arrays,
that arithmetic computes Phi; run on :class:`Node` objects, it records Phi as a graph, from
which mechdsl derives, exactly and symbolically,

* the Jacobian entries dPhi_i/dq_k by reverse accumulation over each equation's graph, and
* gamma = -(Phi_q qd)_q qd = -D(D(Phi)) with qdd = 0, where D is the total time derivative
  (D q_k = qd_k, D qd_k = 0): for Phi(q), D(D Phi) = Phi_q qdd + (Phi_q qd)_q qd.

Nodes are hash-consed in one :class:`Graph` per compiled model: the same operation on the
same operands is one node, so that cos and sin of a body's angle, or a point's global
position shared by two joints, are computed once (common subexpressions are eliminated by
construction), and constants are folded as the graph is built. Node ids grow with creation,
so ascending ids are a topological order: every pass below is a loop, never a recursion.
"""

from __future__ import annotations

import math
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from ..grammar.expr import DERIVATIVES, atan2_partials

#: the operations of a node besides "const", "var", "call" and "select": one operand, two
UNARY = ("neg", "sin", "cos", "tan", "sqrt", "exp", "log", "arctan", "abs", "sign")
BINARY = ("add", "sub", "mul", "div", "pow", "arctan2", "mod")

_NUMPY = {
    np.add: "add", np.subtract: "sub", np.multiply: "mul", np.true_divide: "div",
    np.power: "pow", np.negative: "neg", np.sin: "sin", np.cos: "cos", np.tan: "tan",
    np.sqrt: "sqrt", np.exp: "exp", np.log: "log", np.arctan: "arctan",
    np.arctan2: "arctan2", np.absolute: "abs", np.sign: "sign", np.remainder: "mod",
    np.square: "square", np.hypot: "hypot", np.positive: "pos",
}

def _quiet(f: Callable) -> Callable:
    """``f`` with numpy's floating-point warnings off (its NaN or inf is the folded value)."""
    def folded(*args: float) -> float:
        with np.errstate(all="ignore"):
            return f(*args)
    return folded


#: constant folding: Python's float arithmetic (no warnings), numpy's only where it is needed
_FOLD = {
    "neg": lambda a: -a, "sin": math.sin, "cos": math.cos, "tan": math.tan,
    "sqrt": lambda a: math.sqrt(a) if a >= 0 else math.nan,
    "exp": math.exp, "log": lambda a: math.log(a) if a > 0 else math.nan,
    "arctan": math.atan, "abs": abs, "sign": lambda a: float(np.sign(a)),
    "add": lambda a, b: a + b, "sub": lambda a, b: a - b, "mul": lambda a, b: a * b,
    "div": lambda a, b: a / b if b != 0 else math.nan, "pow": _quiet(lambda a, b: float(np.power(a, b))),
    "arctan2": math.atan2, "mod": _quiet(lambda a, b: float(np.remainder(a, b))),
}


_NO_BRANCH = ("an equation may not branch on or compare the value of a coordinate (if, ==, <, "
              "min, max): write it as arithmetic; the traced equations must be the same for "
              "every state")


#: the graph's names of the language's functions that it spells otherwise (numpy's), and back
_LANGUAGE_NAME = {"arctan": "atan", "arctan2": "atan2"}
_GRAPH_NAME = {v: k for k, v in _LANGUAGE_NAME.items()}


class _NodeOps:
    """The arithmetic of :class:`mechdsl.grammar.expr.Ops` on the nodes of ``graph``: what
    the language's table of derivatives (:data:`mechdsl.grammar.expr.DERIVATIVES`) is
    written in."""

    def __init__(self, graph: "Graph") -> None:
        self.op, self.const = graph.op, graph.const

    def add(self, x, y):
        return self.op("add", x, y)

    def sub(self, x, y):
        return self.op("sub", x, y)

    def mul(self, x, y):
        return self.op("mul", x, y)

    def div(self, x, y):
        return self.op("div", x, y)

    def neg(self, x):
        return self.op("neg", x)

    def square(self, x):
        return self.op("mul", x, x)

    def call(self, name: str, x):
        return self.op(_GRAPH_NAME.get(name, name), x)


class GraphError(ValueError):
    """An equation uses an operation that cannot be traced or differentiated."""


class Node:
    """One value of the graph: a constant, a variable, or an operation on earlier nodes.

    Arithmetic and numpy ufuncs on nodes build new nodes, so that code written for arrays
    traces itself. ``op`` is "const" (``value`` the float), "var" (``value`` its key, e.g.
    ``("q", 4)``), "call" (``value`` = (function index, derivative order)), or an operation
    of :data:`UNARY` / :data:`BINARY`.
    """

    __slots__ = ("graph", "id", "op", "args", "value")
    __array_priority__ = 1000

    def __init__(self, graph: "Graph", id_: int, op: str, args: tuple["Node", ...], value):
        self.graph, self.id, self.op, self.args, self.value = graph, id_, op, args, value

    # arithmetic: each returns a node of the same graph
    def __add__(self, o):
        return self.graph.op("add", self, o)

    def __radd__(self, o):
        return self.graph.op("add", o, self)

    def __sub__(self, o):
        return self.graph.op("sub", self, o)

    def __rsub__(self, o):
        return self.graph.op("sub", o, self)

    def __mul__(self, o):
        return self.graph.op("mul", self, o)

    def __rmul__(self, o):
        return self.graph.op("mul", o, self)

    def __truediv__(self, o):
        return self.graph.op("div", self, o)

    def __rtruediv__(self, o):
        return self.graph.op("div", o, self)

    def __pow__(self, o):
        return self.graph.op("pow", self, o)

    def __rpow__(self, o):
        return self.graph.op("pow", o, self)

    def __neg__(self):
        return self.graph.op("neg", self)

    def __pos__(self):
        return self

    def __mod__(self, o):
        return self.graph.op("mod", self, o)

    def __abs__(self):
        return self.graph.op("abs", self)

    def __bool__(self):
        raise GraphError(_NO_BRANCH)

    def _compare(self, other):
        raise GraphError(_NO_BRANCH)

    __eq__ = __ne__ = __lt__ = __le__ = __gt__ = __ge__ = _compare
    __hash__ = object.__hash__

    def __float__(self):
        raise GraphError("a traced value is not a number: use numpy's functions (np.sin, "
                         "np.sqrt, ...), not the math module's, in equations")

    __int__ = __index__ = __float__

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        name = _NUMPY.get(ufunc)
        if method != "__call__" or name is None or kwargs:
            raise GraphError(f"numpy's {ufunc.__name__} ({method}) cannot be traced in an "
                             "equation; use arithmetic and elementwise functions "
                             f"({', '.join(sorted(set(_NUMPY.values())))})")
        g = self.graph
        if name == "square":
            return g.op("mul", inputs[0], inputs[0])
        if name == "hypot":
            a, b = inputs
            return g.op("sqrt", g.op("add", g.op("mul", a, a), g.op("mul", b, b)))
        if name == "pos":
            return inputs[0]
        return g.op(name, *inputs)

    @property
    def is_const(self) -> bool:
        return self.op == "const"

    def __repr__(self) -> str:
        if self.op == "const":
            return repr(self.value)
        if self.op == "var":
            return "".join(map(str, self.value))
        return f"n{self.id}"


class Graph:
    """A hash-consed expression graph (see the module documentation)."""

    def __init__(self) -> None:
        self.nodes: list[Node] = []
        self._table: dict[tuple, Node] = {}
        #: the opaque functions of one variable that "call" nodes refer to:
        #: (f, f', f'') triples of callables on arrays
        self.functions: list[tuple[Callable, Callable, Callable]] = []
        self.zero = self.const(0.0)
        self.one = self.const(1.0)

    def _make(self, op: str, args: tuple[Node, ...], value=None) -> Node:
        key = (op, tuple([a.id for a in args]), value)
        node = self._table.get(key)
        if node is None:
            node = Node(self, len(self.nodes), op, args, value)
            self.nodes.append(node)
            self._table[key] = node
        return node

    def const(self, value: float) -> Node:
        v = float(value)
        if v == 0.0:
            v = 0.0  # -0.0 and 0.0 are one constant
        # NaN != NaN: key NaNs by their text so that they are still shared
        return self._make("const", (), v if v == v else "nan")

    def var(self, *key) -> Node:
        """The variable named by ``key``, e.g. var("q", 3) for coordinate 3."""
        return self._make("var", (), tuple(key))

    def lift(self, x) -> Node:
        if isinstance(x, Node):
            if x.graph is not self:
                raise GraphError("a node of another graph")
            return x
        if isinstance(x, (int, float, np.floating, np.integer)) or (
                isinstance(x, np.ndarray) and x.ndim == 0):
            return self.const(float(x))
        raise GraphError(f"an equation may only combine numbers and traced values, not "
                         f"{type(x).__name__}")

    def constant_value(self, node: Node) -> float:
        v = node.value
        return math.nan if v == "nan" else v

    def function(self, f: Callable, d1: Callable, d2: Callable) -> int:
        """Register a function of one variable with its exact derivatives; its index."""
        self.functions.append((f, d1, d2))
        return len(self.functions) - 1

    def call(self, index: int, order: int, x) -> Node:
        """f^(order)(x) of the registered function ``index`` (order 0, 1 or 2)."""
        x = self.lift(x)
        if order > 2:
            raise GraphError("a function argument's third derivative is not available: an "
                             "equation may use a function and its first derivative at most")
        return self._make("call", (x,), (index, order))

    def op(self, name: str, *operands) -> Node:
        """The node of operation ``name`` on ``operands``, simplified and folded."""
        # (lists, not generators: this runs for every operation a model's equations trace)
        args = tuple([a if type(a) is Node and a.graph is self else self.lift(a)
                      for a in operands])
        if all([a.op == "const" for a in args]):
            try:
                value = _FOLD[name](*[self.constant_value(a) for a in args])
            except (OverflowError, ValueError, ZeroDivisionError):
                value = math.nan
            return self.const(value)
        simple = self._simplify(name, args)
        if simple is not None:
            return simple
        if name in ("add", "mul") and args[0].id > args[1].id:
            args = (args[1], args[0])  # commutative: one node for a + b and b + a
        return self._make(name, args)

    def _simplify(self, name: str, args: tuple[Node, ...]) -> Node | None:
        zero, one = self.zero, self.one
        if name == "add":
            a, b = args
            if a is zero:
                return b
            if b is zero:
                return a
            if b.op == "neg":
                return self.op("sub", a, b.args[0])
            if a.op == "neg":
                return self.op("sub", b, a.args[0])
        elif name == "sub":
            a, b = args
            if b is zero:
                return a
            if a is zero:
                return self.op("neg", b)
            if a is b:
                return zero
            if b.op == "neg":
                return self.op("add", a, b.args[0])
        elif name == "mul":
            a, b = args
            if a is zero or b is zero:
                return zero
            if a is one:
                return b
            if b is one:
                return a
            if a.op == "const" and a.value == -1.0:
                return self.op("neg", b)
            if b.op == "const" and b.value == -1.0:
                return self.op("neg", a)
            if a.op == "neg" and b.op == "neg":
                return self.op("mul", a.args[0], b.args[0])
            if a.op == "neg":
                return self.op("neg", self.op("mul", a.args[0], b))
            if b.op == "neg":
                return self.op("neg", self.op("mul", a, b.args[0]))
        elif name == "div":
            a, b = args
            if a is zero:
                return zero
            if b is one:
                return a
            if a.op == "neg":
                return self.op("neg", self.op("div", a.args[0], b))
        elif name == "neg":
            (a,) = args
            if a.op == "neg":
                return a.args[0]
        elif name == "pow":
            a, b = args
            if b.op == "const":
                if b.value == 1.0:
                    return a
                if b.value == 0.0:
                    return one
                if b.value == 2.0:
                    return self.op("mul", a, a)
                if b.value == 0.5:
                    return self.op("sqrt", a)
        return None

    # -- derivatives -------------------------------------------------------------------

    def subgraph(self, roots: Iterable[Node]) -> list[Node]:
        """Every node the ``roots`` depend on (themselves included), in ascending id order."""
        seen: set[int] = set()
        stack = [r for r in roots]
        out: list[Node] = []
        while stack:
            n = stack.pop()
            if n.id in seen:
                continue
            seen.add(n.id)
            out.append(n)
            stack.extend(n.args)
        out.sort(key=lambda n: n.id)
        return out

    def local(self, node: Node) -> tuple[Node, ...]:
        """d node / d arg for each argument of ``node``, as nodes."""
        op, a = node.op, node.args
        g = self.op
        if op == "neg":
            return (self.const(-1.0),)
        if op == "add":
            return (self.one, self.one)
        if op == "sub":
            return (self.one, self.const(-1.0))
        if op == "mul":
            return (a[1], a[0])
        if op == "div":
            return (g("div", self.one, a[1]), g("neg", g("div", node, a[1])))
        rule = DERIVATIVES.get(_LANGUAGE_NAME.get(op, op))
        if rule is not None:  # the language's functions: their one table of derivatives
            return (rule(_NodeOps(self), a[0], node),)
        if op == "abs":
            return (g("sign", a[0]),)
        if op == "mod":  # x mod c for a constant period: slope 1 wherever it is smooth
            if a[1].op != "const":
                raise GraphError("x mod y is differentiable only for a constant y")
            return (self.one, self.zero)
        if op == "arctan2":  # atan2(y, x)
            return atan2_partials(_NodeOps(self), *a)
        if op == "pow":
            base, ex = a
            d_base = g("mul", ex, g("pow", base, g("sub", ex, self.one)))
            d_ex = self.zero if ex.op == "const" else g("mul", node, g("log", base))
            return (d_base, d_ex)
        if op == "call":
            index, order = node.value
            return (self.call(index, order + 1, a[0]),)
        raise GraphError(f"no derivative for {op}")

    def gradient(self, root: Node, wrt: Sequence[Node]) -> list[Node]:
        """d root / d w for each variable node w of ``wrt``, by reverse accumulation over the
        root's graph (the adjoints are built as nodes, so the result is exact)."""
        adj = self._adjoints(root)
        return [adj.get(w.id, self.zero) for w in wrt]

    def sparse_gradient(self, root: Node, position: Mapping[int, int]
                        ) -> list[tuple[int, Node]]:
        """(k, d root / d w) for the variables w of the root's graph with ``position[w.id]``
        = k whose derivative is not identically zero, in increasing k: :meth:`gradient`
        without its zeros, in time proportional to the root's graph, not to the number of
        variables (a load or a Jacobian entry depends on a few of a model's coordinates)."""
        adj = self._adjoints(root)
        out = [(position[i], d) for i, d in adj.items()
               if i in position and not (d.op == "const" and d.value == 0.0)]
        out.sort(key=lambda kd: kd[0])
        return out

    def _adjoints(self, root: Node) -> dict[int, Node]:
        """d root / d n for every node n of the root's graph that root depends on, by id."""
        nodes = self.subgraph([root])
        adj: dict[int, Node] = {root.id: self.one}
        for n in reversed(nodes):
            a = adj.get(n.id)
            if a is None or not n.args or a is self.zero:
                continue
            for arg, d in zip(n.args, self.local(n)):
                if arg.op == "const" or d is self.zero:
                    continue
                term = self.op("mul", a, d)
                prev = adj.get(arg.id)
                adj[arg.id] = term if prev is None else self.op("add", prev, term)
        return adj

    def substitute(self, roots: Sequence[Node], values: Mapping[tuple, Node]) -> list[Node]:
        """The roots with each variable whose key is in ``values`` replaced by that node:
        the composition f(g(z)) of the roots f(q) with q = g(z). Every operation is built
        again on its replaced operands (folded and shared like any other), so that the
        result is an ordinary graph of the new variables, which the derivatives and the
        code generators read. The replaced variables may themselves be keys of the new
        expressions (f(q) with q_k = g_k(q)): each old node is rebuilt once, by id."""
        new: dict[int, Node] = {}
        for n in self.subgraph(roots):
            if n.op == "const":
                new[n.id] = n
            elif n.op == "var":
                new[n.id] = self.lift(values.get(n.value, n))
            elif n.op == "call":
                new[n.id] = self.call(n.value[0], n.value[1], new[n.args[0].id])
            elif n.op in UNARY or n.op in BINARY:
                new[n.id] = self.op(n.op, *[new[a.id] for a in n.args])
            else:
                raise GraphError(f"cannot substitute into a {n.op!r} node")
        return [new[r.id] for r in roots]

    def time_derivative(self, roots: Sequence[Node], rate: Callable[[Node], Node | None]
                        ) -> list[Node]:
        """D r for each root: the total derivative along the motion, forward over the graph.
        ``rate(var)`` gives D of a variable node (None for a constant one)."""
        nodes = self.subgraph(roots)
        d: dict[int, Node] = {}
        for n in nodes:
            if n.op == "const":
                d[n.id] = self.zero
            elif n.op == "var":
                r = rate(n)
                d[n.id] = self.zero if r is None else r
            else:
                total = self.zero
                for arg, loc in zip(n.args, self.local(n)):
                    da = d[arg.id]
                    if da is self.zero or loc is self.zero:
                        continue
                    total = self.op("add", total, self.op("mul", loc, da))
                d[n.id] = total
        return [d[r.id] for r in roots]
