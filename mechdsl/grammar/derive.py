"""Exact derivatives of expression trees: d e / d var as a new, simplified tree.

The drives' f'(t) and f''(t) (for nu and gamma) and the derivatives of function arguments of
plugins come from here: derived from the expression, never by finite differences.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

from .expr import (
    DERIVATIVES, TREE, Binary, Call, Compare, Cond, Expr, Logic, Name, Num, Table, Unary, add,
    atan2_partials, call, children, cond, div, mul, neg, postorder, power, sub,
)


def derivative(e: Expr, var: str = "t", seeds: dict[str, Expr] | None = None) -> Expr:
    """The exact derivative d e / d var as a new (simplified) tree; with ``seeds``, the
    derivative along the directions the seeds give each name (forward mode: d name = the
    name's seed, every name not in ``seeds`` a constant; ``var`` is then one of them).

    Piecewise expressions differentiate branch by branch: d/dt (if C then A else B) =
    if C then A' else B' (the derivative where it exists; at a switch point the branch the
    condition selects). ``min``, ``max`` and ``abs`` become such conditionals
    (``abs(u)' = if u >= 0 then u' else -u'``).

    The rules are applied node by node in post-order, without recursion (a sum of thousands
    of terms is as deep); a subtree shared by several parents is derived once, and the
    result shares the operands of ``e``.
    """
    if seeds is None:
        seeds = {var: Num(1.0)}
    depends: dict[int, bool] = {}  # node -> does it read a seeded name?
    for node in postorder(e):
        depends[id(node)] = (node.id in seeds if isinstance(node, Name)
                             else any(depends[id(k)] for k in children(node)))

    def needed(node: Expr) -> tuple:
        # the operands whose derivatives the rule of ``node`` uses: none where the node does
        # not read var (its derivative is 0), never the condition of an 'if'
        if not depends[id(node)] or isinstance(node, (Compare, Logic)) or (
                isinstance(node, Unary) and node.op == "not"):
            return ()
        if isinstance(node, Cond):
            return (node.then, node.orelse)
        return children(node)

    done: dict[int, Expr] = {}
    d = lambda x: done[id(x)]  # noqa: E731
    for node in postorder(e, needed):
        done[id(node)] = _rule(node, d, depends, seeds)
    return done[id(e)]


def _rule(e: Expr, d: Callable[[Expr], Expr], depends: dict[int, bool],
          seeds: dict[str, Expr]) -> Expr:
    """The derivative of ``e`` given ``d``, the derivatives of its operands."""
    if not depends[id(e)]:  # numbers, references, other names, constant subtrees
        return Num(0.0)
    if isinstance(e, Name):
        return seeds[e.id]
    if isinstance(e, Unary):
        if e.op == "-":
            return neg(d(e.operand))
        raise ValueError("a truth value has no derivative")
    if isinstance(e, Binary):
        a, b = e.left, e.right
        if e.op == "+":
            return add(d(a), d(b))
        if e.op == "-":
            return sub(d(a), d(b))
        if e.op == "*":
            return add(mul(d(a), b), mul(a, d(b)))
        if e.op == "/":
            # (a/b)' = a'/b - a b'/b^2
            return sub(div(d(a), b), div(mul(a, d(b)), power(b, Num(2.0))))
        if e.op == "^":
            if not depends[id(b)]:
                # (a^c)' = c a^(c-1) a'
                return mul(mul(b, power(a, sub(b, Num(1.0)))), d(a))
            # (a^b)' = a^b (b' log a + b a'/a)
            return mul(e, add(mul(d(b), call("log", a)), div(mul(b, d(a)), a)))
    if isinstance(e, Cond):
        return cond(e.test, d(e.then), d(e.orelse))
    if isinstance(e, Call):
        return _call_derivative(e, d)
    if isinstance(e, Table):
        # a cubic's fourth derivative vanishes; the chain rule for the argument
        outer = replace(e, order=e.order + 1, span=None) if e.order < 3 else Num(0.0)
        return mul(outer, d(e.arg))
    raise ValueError(f"cannot differentiate {type(e).__name__}")


def _call_derivative(e: Call, d: Callable[[Expr], Expr]) -> Expr:
    f, args = e.func, e.args
    if f in ("min", "max"):
        # min(a1, ..., an) = min(min(a1, ..., a(n-1)), an): the branch of each pair in turn,
        # the running min as a chain of two-argument calls (the same values, in the same
        # order, as the n-ary call; prefixes copied as n-ary calls would cost n^2)
        op = "<=" if f == "min" else ">="
        out = cond(Compare(op, args[0], args[1]), d(args[0]), d(args[1]))
        running = Call(f, args[:2])
        for a in args[2:]:
            out = cond(Compare(op, running, a), out, d(a))
            running = Call(f, (running, a))
        return out
    if f == "atan2":
        y, x = args
        dy, dx = atan2_partials(TREE, y, x)
        return add(mul(dy, d(y)), mul(dx, d(x)))
    (u,) = args
    du = d(u)
    if f == "abs":
        # branch by branch, as a conditional: sign(u) would give 0 at u = 0 even where
        # abs(u)^2 and the like are smooth
        return cond(Compare(">=", u, Num(0.0)), du, neg(du))
    if f not in DERIVATIVES:  # pragma: no cover - FUNCTIONS and the table kept in step (tests)
        raise ValueError(f"no derivative rule for {f}")
    return mul(DERIVATIVES[f](TREE, u, e), du)


def total_derivative(e: Expr, functions: set[str], rates: dict[str, str],
                     var: str = "t") -> Expr | None:
    """d e / d var where the names ``functions`` are themselves functions of ``var``, each
    with the derivative named ``rates[name]`` (the chain rule: de/dvar = e_var +
    sum e_n n'); other names are constants. None where ``e`` depends on a function with no
    derivative given (an acceleration: the jerk is not computed). One pass in forward
    mode (each function's seed its rate), not one per function read."""
    seeds: dict[str, Expr] = {name: Name(rates.get(name, _NO_RATE)) for name in functions}
    seeds[var] = Num(1.0)
    out = derivative(e, var, seeds)
    if any(isinstance(node, Name) and node.id == _NO_RATE for node in postorder(out)):
        return None
    return out


#: the seed of a function with no derivative given: a result that still reads it needs one
_NO_RATE = "\x00no rate"
