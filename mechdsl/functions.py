"""Function arguments: what a plugin receives for an argument of kind ``function``.

A group of J constraints of one type has J expressions (one each), of the type's variable
and of params. :class:`ExprFunction` evaluates them, with their exact first and second
derivatives, on arrays whose last batch axis is the constraint axis J (member j on
``x[..., j]``); built from a single expression it works elementwise on any shape (the
conformance kit's case).
"""

from __future__ import annotations

import functools
from typing import Mapping, Sequence

import numpy as np

from .grammar import expr as E
from .grammar.derive import derivative


class ExprFunction:
    """f, f' and f'' of expressions in ``var``; params from ``env`` (arrays broadcasting
    against the argument without its last axis, e.g. (V, 1) against (V, b, J))."""

    def __init__(self, exprs: Sequence[E.Expr], var: str,
                 env: Mapping[str, np.ndarray | float], *, elementwise: bool = False) -> None:
        self.exprs = tuple(exprs)
        self.var = var
        self.env = dict(env)
        self.elementwise = elementwise

    @functools.cached_property
    def _fns(self) -> list:
        """Per expression, f, f' and f'' compiled: made where first evaluated, so that the
        value itself is its expressions (what a compiled model holds, and what pickles)."""
        fns = []
        for e in self.exprs:
            d1 = derivative(e, self.var)
            fns.append((E.compile_expr(e), E.compile_expr(d1),
                        E.compile_expr(derivative(d1, self.var))))
        return fns

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_fns"}

    @classmethod
    def of(cls, text: str, var: str, **params: float) -> "ExprFunction":
        """One elementwise function from ``.mech`` expression text (for tests and the kit)."""
        from .grammar.parser import parse_expr

        return cls([parse_expr(text, "function", [var, *params])], var, params,
                   elementwise=True)

    def _eval(self, which: int, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        with np.errstate(all="ignore"):
            if self.elementwise:
                (fns,) = self._fns
                return np.broadcast_to(fns[which]({**self.env, self.var: x}), x.shape).copy()
            out = np.empty(x.shape)
            for j, fns in enumerate(self._fns):
                xj = x[..., j]
                out[..., j] = np.broadcast_to(fns[which]({**self.env, self.var: xj}), xj.shape)
            return out

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self._eval(0, x)

    def d1(self, x: np.ndarray) -> np.ndarray:
        return self._eval(1, x)

    def d2(self, x: np.ndarray) -> np.ndarray:
        return self._eval(2, x)

    def scalar(self, which: int):
        """f (0), f' (1) or f'' (2) of one variant's only expression as a function of a
        float (the one-state kernels of the forward dynamics); None where this function
        has several members or variants."""
        values = {k: np.asarray(a, dtype=float) for k, a in self.env.items()}
        if len(self._fns) != 1 or any(a.size != 1 for a in values.values()):
            return None
        env = {k: float(a.reshape(-1)[0]) for k, a in values.items()}
        fn, var = self._fns[0][which], self.var

        def call(x: float) -> float:
            return float(fn({**env, var: x}))

        return call

    def variant(self, v: int) -> "ExprFunction":
        """The same functions with the params of sweep variant ``v`` only."""
        env = {k: (a[v : v + 1] if np.ndim(a) else a) for k, a in self.env.items()}
        return ExprFunction(self.exprs, self.var, env, elementwise=self.elementwise)

    def member(self, j: int) -> "ExprFunction":
        """The function of constraint ``j`` alone (still on a last axis, of length 1)."""
        return ExprFunction(self.exprs[j : j + 1], self.var, self.env)

    def __repr__(self) -> str:
        return f"ExprFunction({', '.join(E.to_text(e) for e in self.exprs)}; {self.var})"
