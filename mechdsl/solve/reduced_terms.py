"""The reduced equations of motion traced and generated as one function of floats.

Why. An evaluation of :class:`~mechdsl.solve.reduced.Reduced` goes through the relative
map (q = g(z), G = dg/dz, qd = G zd and the convective term c, body by body), the compiled
model's kernels of M and Q in absolute coordinates, and the dense products G^T M G and
G^T (Q - M c), each a Python call or a numpy operation on a small array: about 20 us on the
stiff pendulum, four times a hand-written right-hand side, and the implicit stepper
evaluates it at every stage of every Newton iteration.

What. With w the coordinates left (the eliminated ones constants at their values) and q =
g(w) the absolute coordinates written out as expressions of the graph (module relative:
r_i = r_p + A(phi_p) s_i - A(phi_i) u_i), the equations of motion in w (Haug, sec. 11.2, the
velocity transformation qd = G wd, G = dq/dw) are

    M_w wdd = f_w,     M_w = G^T M(q) G,     f_w = G^T (Q(q, qd, t) - M(q) c),

with c = (d/dt G) wd the absolute accelerations at wdd = 0. G is the exact gradient of q's
nodes, qd and c their time derivatives along (wd, wdd = 0) (:meth:`Graph.time_derivative`);
M's and Q's nodes of the compiled model are composed with q(w) and qd(w, wd)
(:meth:`Graph.substitute`) and the products written out on them, zeros folded away. One
generated function of floats then gives M_w and f_w, another the three Radau stages'
residuals M_w a - f_w at once, a third q, qd and G (the outputs and the error's map); the
exact derivatives df_w/dw and df_w/dwd (reverse accumulation over f_w's graph, the same
traced arithmetic) give the implicit stepper's Jacobian. Traced where the model is small
(:data:`TRACE_MAX` absolute coordinates: the products grow like the cube of the bodies'
number, the code with them) and its terms analytic enough to be traced (no member-layout
group values); elsewhere :class:`Reduced` evaluates through the map as before.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..symbolic.graph import Graph, GraphError, Node

__all__ = ["TRACE_MAX", "ReducedCode", "TracedReduced", "traced"]

#: the most absolute coordinates (three a moving body) whose reduced equations are traced:
#: M_w's products grow like the cube of the bodies' number, the generated code with them
TRACE_MAX = 30
#: an eliminated coordinate's value or a point's coordinate below this fraction of the
#: largest of them (and of 1) is zero to round-off (a pin at a frame's origin), folded
#: into the code rather than read
ZERO_RTOL = 1e-14


class ReducedCode:
    """The traced and generated terms of one reduction's structure (module docstring):
    the forest, the bodies with a reference point and the coordinates left; the
    eliminated coordinates' values and the points are inputs (``p`` after the model's
    parameters), so that one code serves every state a run starts from (keyed on them,
    round-off made every trial trace and generate anew, and the graph grow). Its
    functions are generated on first use; :class:`TracedReduced` binds the inputs."""

    def __init__(self, graph: Graph, mass: list[list[Node]], force: list[Node],
                 w: list[Node], wd: list[Node], pose: list[Node], floats: Callable,
                 inputs: int) -> None:
        n = len(force)
        self.n, self.N, self.inputs = n, len(pose) // (2 + n), inputs
        self._graph, self._force, self._w, self._wd, self._pose = graph, force, w, wd, pose
        self._floats = floats
        # M_w's entries both triangles (the upper's nodes: one name each in the code),
        # then f_w: one array of the kernel's list, two views
        nodes = [mass[min(a, b)][max(a, b)] for a in range(n) for b in range(n)]
        self._mass = [nodes[a * n:(a + 1) * n] for a in range(n)]
        self.terms = floats(nodes + list(force), "reduced_terms")
        self._fns: dict[str, Callable] = {}

    def pose(self) -> Callable:
        """The function of (q, qd) = (g(w), G wd) and G's entries."""
        if "pose" not in self._fns:
            self._fns["pose"] = self._floats(self._pose, "reduced_pose")
        return self._fns["pose"]

    def derivatives(self) -> Callable:
        """The function of df_w/dw's and df_w/dwd's entries, row by row."""
        if "derivatives" not in self._fns:
            g, wrt = self._graph, self._w + self._wd
            nodes = [d for root in self._force for d in g.gradient(root, wrt)]
            self._fns["derivatives"] = self._floats(nodes, "reduced_derivatives")
        return self._fns["derivatives"]

    def stages(self, k: int) -> Callable:
        """The function of the k stages' residuals: stage j's coordinates are the
        variables q[2 j n + a] and its rates q[2 j n + n + a], its instant p[P + j] and its
        accelerations p[P + k + j n + b] (P the inputs before: the model's parameters,
        the eliminated coordinates' values and the points)."""
        if ("stages", k) in self._fns:
            return self._fns[("stages", k)]
        g, n, P = self._graph, self.n, self.inputs
        roots = [x for row in self._mass for x in row] + list(self._force)
        out = []
        for j in range(k):
            values = {("q", a): g.var("q", 2 * j * n + a) for a in range(n)}
            values.update({("qd", a): g.var("q", 2 * j * n + n + a) for a in range(n)})
            values[("t",)] = g.var("p", P + j)
            new = g.substitute(roots, values)
            M, f = new[:n * n], new[n * n:]
            for a in range(n):
                acc = g.zero
                for b in range(n):
                    acc = g.op("add", acc, g.op("mul", M[a * n + b],
                                                g.var("p", P + k + j * n + b)))
                out.append(g.op("sub", acc, f[a]))
        self._fns[("stages", k)] = fn = self._floats(out, "reduced_stages")
        return fn


class TracedReduced:
    """:class:`ReducedCode` bound to one reduction's inputs ``p`` (the model's
    parameters, the eliminated coordinates' values, the points) and functions ``F``.
    ``terms(t, w, wd)`` -> (M_w (n, n), f_w (n,)), ``derivatives(t, w, wd)`` -> (df_w/dw,
    df_w/dwd), ``absolute(w, wd)`` -> ((q, qd), G), ``state(w, wd)`` -> (q, qd),
    ``states(W, Wd)`` -> (q, qd) at K states and ``stage_residuals(ts, Y, A)``; each
    raises ValueError, ZeroDivisionError or OverflowError outside a function's domain (the
    caller then evaluates through the map)."""

    def __init__(self, code: ReducedCode, p: list, F: tuple) -> None:
        self.code, self.n, self.N = code, code.n, code.N
        self._p, self._F = p, F
        self._terms = code.terms

    def terms(self, t: float, w: np.ndarray, wd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """M_w (n, n) and f_w (n,) at (t, w, wd)."""
        n = self.n
        vals = np.array(self._terms(w.tolist(), wd.tolist(), t, self._p, self._F))
        return vals[:n * n].reshape(n, n), vals[n * n:]

    def absolute(self, w: np.ndarray, wd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q, qd) = (g(w), G wd) (2N,) and G = dq/dw (N, n)."""
        N = self.N
        vals = np.array(self.code.pose()(w.tolist(), wd.tolist(), 0.0, self._p, self._F))
        return vals[:2 * N], vals[2 * N:].reshape(N, self.n)

    def state(self, w: np.ndarray, wd: np.ndarray) -> np.ndarray:
        """(q, qd) = (g(w), G wd) (2N,) alone (an output's state; by the same generated
        function: one more for the outputs alone cost more to generate than it saved)."""
        return self.absolute(w, wd)[0]

    def states(self, W: np.ndarray, Wd: np.ndarray) -> np.ndarray:
        """:meth:`state` at K states at once, W and Wd (n, K): (2N, K) (the outputs inside
        one step: one array for them all, not one per output)."""
        pose, p, F = self.code.pose(), self._p, self._F
        rows = [pose(w, wd, 0.0, p, F) for w, wd in zip(W.T.tolist(), Wd.T.tolist())]
        return np.array(rows)[:, :2 * self.N].T

    def stage_residuals(self, ts: list, Y: np.ndarray, A: np.ndarray) -> list:
        """M_w(w_j) A_j - f_w(t_j, w_j, wd_j) for the stages j (rows Y_j = (w_j, wd_j) and
        A_j; ``ts`` their instants), flat, stage by stage: the implicit stepper's residuals
        of the equations of motion, all stages in one generated function."""
        return self.code.stages(len(ts))(Y.ravel().tolist(), (), 0.0,
                                         self._p + list(ts) + A.ravel().tolist(), self._F)

    def derivatives(self, t: float, w: np.ndarray, wd: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """df_w/dw and df_w/dwd (n, n) at (t, w, wd), exact."""
        n = self.n
        vals = np.array(self.code.derivatives()(w.tolist(), wd.tolist(), t, self._p,
                                                 self._F))
        vals = vals.reshape(n, 2 * n)
        return vals[:, :n], vals[:, n:]


def _positions(g: Graph, parent: list[int], order: list[int], points: list,
               z: list[Node]) -> list[Node]:
    """q = g(z) as nodes (module relative's map), body by body, parents first: r_i = r_p +
    A(phi_p) s_i - A(phi_i) u_i, phi_i = phi_p + rho_i (a root body's s_i and rho_i are
    its reference point's position and its angle); ``points[i]`` u_i as two nodes, or None
    for the frame's origin."""
    q: list[Node] = list(z)
    for i in order:
        p, k = parent[i], 3 * i
        if p < 0:
            psi = z[k + 2]
            dx, dy = z[k], z[k + 1]
        else:
            j = 3 * p
            phi = q[j + 2]
            c, s = g.op("cos", phi), g.op("sin", phi)
            sx, sy = z[k], z[k + 1]
            psi = phi + z[k + 2]
            dx, dy = q[j] + (c * sx - s * sy), q[j + 1] + (s * sx + c * sy)
        if points[i] is not None:
            ux, uy = points[i]
            cp, sp = g.op("cos", psi), g.op("sin", psi)
            dx, dy = dx - (cp * ux - sp * uy), dy - (sp * ux + cp * uy)
        q[k], q[k + 1], q[k + 2] = g.lift(dx), g.lift(dy), g.lift(psi)
    return q


def traced(reduced, limit: int = TRACE_MAX) -> TracedReduced | None:
    """The generated terms of ``reduced`` (a :class:`~mechdsl.solve.reduced.Reduced` on
    the base equations of a compiled model): the code of its structure, kept with the
    model's dynamics (:class:`ReducedCode`), bound to its values; None where the model has
    more than ``limit`` absolute coordinates or its terms cannot be traced."""
    rel, base = reduced.rel, reduced.base
    d = getattr(getattr(base, "kernels", None), "dynamics", None)
    p, F = getattr(base, "_mq_p", None), getattr(base, "_mq_F", None)
    if d is None or d.graph is None or p is None or rel.n > limit:
        return None
    free = reduced.free.tolist()
    left = set(free)
    # the inputs: the eliminated coordinates' values and the points' coordinates, those
    # that are zero (to round-off: a pin at a frame's origin) folded into the code
    values = [(k, float(reduced._value[k])) for k in range(rel.n) if k not in left]
    values += [(("u", i, c), float(u[c])) for i, u in enumerate(rel.points)
               for c in (0, 1) if u[0] or u[1]]
    tiny = ZERO_RTOL * max([1.0] + [abs(v) for _, v in values])
    inputs = [(name, v) for name, v in values if abs(v) > tiny]
    key = ("reduced", tuple(rel.parent), tuple(free),
           tuple(name for name, v in values if abs(v) <= tiny),
           tuple(name for name, _ in inputs))

    def make() -> ReducedCode | None:
        try:
            return _trace(d, rel, free, [name for name, _ in inputs], len(p))
        except GraphError:
            return None
    code = d.memo(key, make)
    if code is None:
        return None
    return TracedReduced(code, list(p) + [v for _, v in inputs], F)


def _trace(d, rel, free: list[int], inputs: list, P: int) -> ReducedCode:
    """Trace M_w and f_w (module docstring) into the dynamics' graph; ``inputs`` name the
    eliminated coordinates (k) and the points' coordinates (("u", body, 0 or 1)) read as
    p[P], p[P + 1], ... in that order, the others of them zero."""
    g: Graph = d.graph
    N, n = rel.n, len(free)
    w = [g.var("q", a) for a in range(n)]
    wd = [g.var("qd", a) for a in range(n)]
    read = {name: g.var("p", P + i) for i, name in enumerate(inputs)}
    z: list[Node] = [read.get(k, g.zero) for k in range(N)]
    for a, k in enumerate(free):
        z[k] = w[a]
    points: list = [None] * len(rel.parent)
    for i, u in enumerate(rel.points):
        if u[0] or u[1]:
            points[i] = (read.get(("u", i, 0), g.zero), read.get(("u", i, 1), g.zero))
    q = _positions(g, rel.parent, rel.order, points, z)
    on_w = {x.id: a for a, x in enumerate(w)}

    def rate(v: Node) -> Node | None:  # D w = wd, D wd = wdd = 0
        return wd[on_w[v.id]] if v.id in on_w else None
    qd = g.time_derivative(q, rate)
    c = g.time_derivative(qd, rate)
    G = [g.gradient(qk, w) for qk in q]  # (N, n)
    values = {("q", k): q[k] for k in range(N)}
    values.update({("qd", k): qd[k] for k in range(N)})
    subst = g.substitute([*d.mass_nodes, *d.load_nodes], values)
    n_mass = len(d.mass_nodes)
    mass, Q = subst[:n_mass], subst[n_mass:]
    MG = [[g.zero] * n for _ in range(N)]   # M G
    Mc = [g.zero] * N                        # M c
    for e, (r, col) in enumerate(zip(d.rows.tolist(), d.cols.tolist())):
        m = mass[e]
        if m is g.zero:
            continue
        for b in range(n):
            MG[r][b] = g.op("add", MG[r][b], g.op("mul", m, G[col][b]))
        Mc[r] = g.op("add", Mc[r], g.op("mul", m, c[col]))
    Mw = [[g.zero] * n for _ in range(n)]
    fw = [g.zero] * n
    for r in range(N):
        rest = g.op("sub", Q[r], Mc[r])
        for a in range(n):
            if G[r][a] is g.zero:
                continue
            fw[a] = g.op("add", fw[a], g.op("mul", G[r][a], rest))
            for b in range(a, n):
                Mw[a][b] = g.op("add", Mw[a][b], g.op("mul", G[r][a], MG[r][b]))
    pose = [*q, *qd, *(x for row in G for x in row)]
    return ReducedCode(g, Mw, fw, w, wd, pose, d.floats, P + len(inputs))

