"""A type's equations traced into an expression graph, with the Jacobian and gamma derived.

:func:`trace` is what the compiled model does for every constraint of a mechanism (with
the bodies' coordinates as variables and the arguments' values as constants);
:class:`Derived` does it once for a type on its own, with the arguments as variables too, so
that a type can be evaluated on arrays (its tests, the conformance kit) from the same source.

In Haug's notation, for one constraint with attached bodies k = 1..S, q_k = (x_k, y_k,
phi_k):

* Phi_q: row i, block k = (dPhi_i/dx_k, dPhi_i/dy_k, dPhi_i/dphi_k), by reverse
  accumulation over the graph of Phi_i;
* gamma = -(Phi_q qd)_q qd = -D(D(Phi)) with D q = qd and D qd = 0 (so that the qdd terms
  of the second time derivative vanish).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

from ..symbolic import Graph, GraphError, Node, kernel
from .geometry import Body, Rate, Vec


class EquationError(ValueError):
    """A type's equations (or its supplied terms) are malformed: wrong count, or arithmetic
    that cannot be traced."""


@dataclass(frozen=True)
class Traced:
    """One constraint's rows as graph nodes: Phi (n_eq), Phi_q (n_eq rows of 3 S entries,
    body by body), gamma (n_eq)."""

    phi: tuple[Node, ...]
    jacobian: tuple[tuple[Node, ...], ...]
    gamma: tuple[Node, ...]


def rate_of(graph: Graph) -> Callable[[Node], Node | None]:
    """D of a variable: D q_k = qd_k (gathered columns alike); every other variable is
    constant in time."""

    def rate(v: Node) -> Node | None:
        kind = v.value[0]
        if kind == "q":
            return graph.var("qd", v.value[1])
        if kind == "gq":  # a gathered coordinate: its rate is gathered alike
            return graph.var("gqd", v.value[1])
        return None

    return rate


def _rows(ctype, graph: Graph, values, what: str, count: int) -> tuple[Node, ...]:
    try:
        rows = list(values)
    except TypeError:
        rows = [values]
    if len(rows) != count:
        raise EquationError(f"the {ctype.kind} type '{ctype.name}': {what} gave {len(rows)} "
                            f"values, expected {count}")
    try:
        return tuple(graph.lift(r) for r in rows)
    except GraphError as err:
        raise EquationError(f"the {ctype.kind} type '{ctype.name}': {what}: {err}") from None


def trace(ctype, graph: Graph, bodies: Sequence[Body], args: Mapping[str, object]) -> Traced:
    """Trace one constraint of ``ctype`` whose attached bodies and arguments are given as
    graph nodes (or constants); derive what the type does not supply."""
    from .contract import Args

    args = Args(args)
    m = ctype.n_eq
    try:
        phi = _rows(ctype, graph, ctype.equations(tuple(bodies), args), "equations()", m)
        coords = [graph.lift(c) for b in bodies for c in (b.x, b.y, b.phi)]
        if ctype.supplies("jacobian_terms"):
            blocks = list(ctype.jacobian_terms(tuple(bodies), args))
            if len(blocks) != len(bodies):
                raise EquationError(f"the {ctype.kind} type '{ctype.name}': jacobian_terms() "
                                    f"gave {len(blocks)} blocks, expected one per attached "
                                    f"body ({len(bodies)}), each of n_eq = {m} rows of 3")
            rows_k = [[_rows(ctype, graph, r, "a row of jacobian_terms()", 3)
                       for r in _rows_list(ctype, blk, m)] for blk in blocks]
            jac = tuple(tuple(x for k in range(len(bodies)) for x in rows_k[k][i])
                        for i in range(m))
        else:
            jac = tuple(tuple(graph.gradient(row, coords)) if coords else () for row in phi)
        if ctype.supplies("gamma_terms"):
            rates = tuple(Rate(*(graph.time_derivative([graph.lift(c)], rate_of(graph))[0]
                                 for c in (b.x, b.y, b.phi))) for b in bodies)
            gamma = _rows(ctype, graph, ctype.gamma_terms(tuple(bodies), rates, args),
                          "gamma_terms()", m)
        else:
            rate = rate_of(graph)
            first = graph.time_derivative(list(phi), rate)
            gamma = tuple(graph.op("neg", d) for d in graph.time_derivative(first, rate))
    except GraphError as err:
        raise EquationError(f"the {ctype.kind} type '{ctype.name}': {err}") from None
    return Traced(phi, jac, gamma)


def _rows_list(ctype, block, m: int) -> list:
    rows = list(block)
    if len(rows) != m:
        raise EquationError(f"the {ctype.kind} type '{ctype.name}': a block of "
                            f"jacobian_terms() has {len(rows)} rows, expected {m}")
    return rows


class _TracedFunction:
    """A function argument inside a trace: calls become graph nodes."""

    def __init__(self, graph: Graph, index: int) -> None:
        self.graph, self.index = graph, index

    def __call__(self, x):
        return self.graph.call(self.index, 0, x)

    def d1(self, x):
        return self.graph.call(self.index, 1, x)

    def d2(self, x):
        return self.graph.call(self.index, 2, x)


def body_of(graph: Graph, first: int) -> Body:
    """The body whose coordinates are the variables q_first .. q_first+2."""
    phi = graph.var("q", first + 2)
    return Body(graph.var("q", first), graph.var("q", first + 1), phi, np.cos(phi),
                np.sin(phi))


class Derived:
    """A type traced on its own: bodies and arguments as variables; evaluates Phi, Phi_q
    and gamma on arrays with batch axes (the kit's and a plugin's own tests)."""

    def __init__(self, ctype) -> None:
        self.ctype = ctype
        g = self.graph = Graph()
        S = len(ctype.slots)
        bodies = [body_of(g, 3 * k) for k in range(S)]
        self.reads: list[tuple[str, int | None]] = []  # parameter leaf j: (arg, component)
        self.function_args: list[str] = []
        args: dict[str, object] = {}
        for a in ctype.signature:
            if a.kind == "body":
                continue
            if a.kind == "function":
                args[a.name] = _TracedFunction(g, g.function(None, None, None))
                self.function_args.append(a.name)
            elif a.kind in ("point", "vector"):
                args[a.name] = Vec(self._param(a.name, 0), self._param(a.name, 1))
            else:
                args[a.name] = self._param(a.name, None)
        self.traced = trace(ctype, g, bodies, args)
        t = self.traced
        self._phi = kernel(g, t.phi, "phi")
        self._jac = kernel(g, [x for row in t.jacobian for x in row], "jacobian")
        self._gamma = kernel(g, t.gamma, "gamma")
        self.derived_jacobian_kernel = self._jac
        self.derived_gamma_kernel = self._gamma
        if ctype.supplies("jacobian_terms") or ctype.supplies("gamma_terms"):
            plain = _Plain(ctype)
            alone = trace(plain, g, bodies, args)
            self.derived_jacobian_kernel = kernel(
                g, [x for row in alone.jacobian for x in row], "derived_jacobian")
            self.derived_gamma_kernel = kernel(g, alone.gamma, "derived_gamma")

    def _param(self, name: str, component: int | None) -> Node:
        self.reads.append((name, component))
        return self.graph.var("p", len(self.reads) - 1)

    def _inputs(self, q, p, qd=None):
        S = len(self.ctype.slots)
        q = [np.asarray(x, dtype=float) for x in q]
        if len(q) != S:
            raise ValueError(f"{len(q)} poses for {S} attached bodies")
        params = []
        for name, c in self.reads:
            v = np.asarray(p[name], dtype=float)
            params.append(v if c is None else v[..., c])
        shapes = [x.shape[:-1] for x in q] + [v.shape for v in params]
        if qd is not None:
            qd = [np.asarray(x, dtype=float) for x in qd]
            shapes += [x.shape[:-1] for x in qd]
        batch = np.broadcast_shapes(*shapes)
        Q = np.concatenate([np.broadcast_to(x, batch + (3,)) for x in q], axis=-1)
        # the kernels reverse the axes of every input: all of them carry the full batch shape
        params = [np.broadcast_to(v, batch) for v in params]
        QD = None if qd is None else np.concatenate(
            [np.broadcast_to(x, batch + (3,)) for x in qd], axis=-1)
        F = [(p[n], p[n].d1, p[n].d2) for n in self.function_args]
        return Q, QD, params, F

    def phi(self, q, p) -> np.ndarray:
        Q, _, P, F = self._inputs(q, p)
        with np.errstate(all="ignore"):
            return self._phi(Q, None, None, P, F)

    def _blocks(self, k, q, p) -> tuple[np.ndarray, ...]:
        Q, _, P, F = self._inputs(q, p)
        S, m = len(self.ctype.slots), self.ctype.n_eq
        with np.errstate(all="ignore"):
            flat = k(Q, None, None, P, F).reshape(Q.shape[:-1] + (m, S, 3))
        return tuple(flat[..., j, :] for j in range(S))

    def jacobian(self, q, p) -> tuple[np.ndarray, ...]:
        return self._blocks(self._jac, q, p)

    def derived_jacobian(self, q, p) -> tuple[np.ndarray, ...]:
        """The Jacobian derived from the equations, even where the type supplies its own."""
        return self._blocks(self.derived_jacobian_kernel, q, p)

    def _gamma_with(self, k, q, qd, p) -> np.ndarray:
        Q, QD, P, F = self._inputs(q, p, qd)
        with np.errstate(all="ignore"):
            return k(Q, QD, None, P, F)

    def gamma(self, q, qd, p) -> np.ndarray:
        return self._gamma_with(self._gamma, q, qd, p)

    def derived_gamma(self, q, qd, p) -> np.ndarray:
        return self._gamma_with(self.derived_gamma_kernel, q, qd, p)


class _Plain:
    """A type seen through its equations only (its supplied terms ignored)."""

    def __init__(self, ctype) -> None:
        self.ctype = ctype
        self.name, self.kind, self.n_eq = ctype.name, ctype.kind, ctype.n_eq
        self.equations = ctype.equations

    def supplies(self, method: str) -> bool:
        return False
