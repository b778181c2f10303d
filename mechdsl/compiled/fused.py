"""One evaluation for the whole mechanism: every constraint traced into one graph, the
Jacobian and gamma derived, compiled into straight-line numpy functions.

For states Q of shape (V, b, n) (sweep variants, instants, coordinates) the kernels return

* ``phi``: (V, b, m), the joints' Phi and the drives' measures g(q) (the drives' f(t) is
  the caller's: Phi = g(q) - f(t));
* ``jac``: (V, b, nnz), the non-zero entries of Phi_q in the fixed pattern ``rows, cols``
  (entries that are zero for every state, such as d/dx of an angle, are not stored);
* ``phi_jac``: both at once (Newton needs both at the same q: cos and sin computed once);
* ``gamma``: (V, b, m), -(Phi_q qd)_q qd (the drives' f''(t) is the caller's).

Two layouts, chosen by size. A small mechanism (:data:`MEMBER_LIMIT` constraints or fewer)
is traced constraint by constraint: the ground's coordinates and every argument value that
is the same in all variants are constants, folded away, so that the kernel is the shortest
straight-line code there is (the seed's slider-crank: one function of about 60 numpy
operations for Phi and Phi_q). A large one is traced type by type, each group of J
constraints as arrays of J columns gathered from Q, so that the number of numpy operations
does not grow with the number of constraints.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from ..functions import ExprFunction
from ..grammar.expr import free_names
from ..plugins.derived import _TracedFunction, body_of, trace
from ..plugins.geometry import Body, Vec
from ..symbolic import Graph, Kernel, Node, kernel

#: Up to this many constraints, the model is traced constraint by constraint.
MEMBER_LIMIT = 48


@dataclass(frozen=True)
class Fused:
    """The compiled evaluation of a mechanism (see the module documentation)."""

    phi: Kernel
    jac: Kernel
    phi_jac: Kernel
    gamma: Kernel
    #: the non-zero entries of Phi_q: entry k is (rows[k], cols[k])
    rows: np.ndarray
    cols: np.ndarray
    #: the arrays the kernels read as P[j] (argument values that differ between variants)
    params: tuple[np.ndarray, ...]
    #: the function arguments, as (f, f', f'') triples (f an ExprFunction)
    functions: tuple
    m: int
    n: int
    layout: str
    #: the graph and its outputs (the member layout), for the compiled backend
    graph: Graph | None = None
    phi_nodes: tuple = ()
    jac_nodes: tuple = ()
    gamma_nodes: tuple = ()
    #: the arguments' leaves in the order traced: the constant folded, or None for P[j]
    leaves: tuple = ()

    def evaluate_phi(self, q: np.ndarray) -> np.ndarray:
        return self.phi(q, None, None, self.params, self.functions)

    def evaluate_jac(self, q: np.ndarray) -> np.ndarray:
        return self.jac(q, None, None, self.params, self.functions)

    def evaluate_phi_jac(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        out = self.phi_jac(q, None, None, self.params, self.functions)
        return out[..., : self.m], out[..., self.m :]

    def evaluate_gamma(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return self.gamma(q, qd, None, self.params, self.functions)

    def variant(self, v: int) -> "Fused":
        """The same evaluation for sweep variant ``v`` alone."""
        fns = tuple((g, g.d1, g.d2) for g in (f[0].variant(v) for f in self.functions))
        return replace(self, params=tuple(p[v : v + 1] for p in self.params), functions=fns)

    def dense(self, values: np.ndarray) -> np.ndarray:
        """Phi_q as a dense (..., m, n) array from its entries (..., nnz)."""
        out = np.zeros(values.shape[:-1] + (self.m * self.n,))
        out[..., self.rows * self.n + self.cols] = values
        return out.reshape(values.shape[:-1] + (self.m, self.n))


class TraceFailure(Exception):
    """A type's equations failed to trace for member ``member`` of group ``group``."""

    def __init__(self, group, member: int, error: BaseException) -> None:
        super().__init__(str(error))
        self.group, self.member, self.error = group, member, error


def _trace(group, member: int, graph: Graph, bodies, args):
    try:
        return trace(group.ctype, graph, bodies, args)
    except (Exception, SystemExit) as err:  # any failure of the plugin's code is located
        raise TraceFailure(group, member, err) from None


class _Params:
    """Argument values as graph leaves: a constant where every variant has the same value
    (``fold``), else a variable reading P[j]. Without ``fold`` every value is a variable.
    ``leaves`` records each decision in order (the constant, or None for a variable), so
    that the same code can be given other values without tracing again (``replay``:
    :func:`rebind`)."""

    def __init__(self, graph: Graph, fold: bool = True, replay: tuple | None = None) -> None:
        self.graph = graph
        self.fold = fold
        self.arrays: list[np.ndarray] = []
        self.leaves: list[float | None] = []
        self.replay = replay
        self.mismatch = False  # (replaying) a value the code holds as a constant differs

    def leaf(self, values: np.ndarray):
        """``values``: (V,) for one constraint, or (V, J) for a group."""
        values = np.asarray(values, dtype=float)
        first = values.flat[0] if values.size else 0.0
        if self.replay is not None:
            k = len(self.leaves)
            held = self.replay[k] if k < len(self.replay) else None
            fold = k < len(self.replay) and held is not None
            # (one value, as for a single mechanism: compared as a float, not by numpy)
            if fold and not (first == held if values.size == 1 else (values == held).all()):
                self.mismatch = True
        else:
            fold = self.fold and bool((values == first).all())
            held = float(first)
        if fold:
            self.leaves.append(held)
            return self.graph.const(held)
        self.leaves.append(None)
        self.arrays.append(values[:, None] if values.ndim == 1 else values[:, None, :])
        return self.graph.var("p", len(self.arrays) - 1)


def _args(graph: Graph, params: _Params, group, j: int | None = None) -> dict:
    """The arguments of member ``j`` of a group as graph leaves, or (``j`` None) of the whole
    group, one column per member."""
    at = slice(None) if j is None else j
    args: dict[str, object] = {}
    for a in group.ctype.signature:
        if a.kind == "body":
            continue
        value = group.params[a.name]
        if a.kind == "function":
            f = (value if j is None else
                 ExprFunction([value.exprs[j]], value.var, value.env, elementwise=True))
            if j is not None and value.var not in free_names(value.exprs[j]):
                # a constant (a torque's value = mom): a number in the graph, not a call
                V = len(next(iter(value.env.values()))) if value.env else 1
                with np.errstate(all="ignore"):
                    level = np.broadcast_to(f(np.zeros((V, 1))), (V, 1))[:, 0]
                args[a.name] = _Constant(params.leaf(level), graph.zero)
            else:
                args[a.name] = _TracedFunction(graph, graph.function(f, f.d1, f.d2))
        elif a.kind in ("point", "vector"):
            xy = value[:, 0, at]
            args[a.name] = Vec(params.leaf(xy[..., 0]), params.leaf(xy[..., 1]))
        else:
            args[a.name] = params.leaf(value[:, 0, at])
    return args


def fuse(groups, n_bodies: int, m: int, force: str | None = None, fold: bool = True
         ) -> Fused:
    """Trace and compile every constraint of ``groups`` (see :class:`mechdsl.compiled.system.
    Group`) of a mechanism of ``n_bodies`` moving bodies and ``m`` equations. ``force``:
    "member" or "group" to choose the layout (else by size); ``fold``: values the same in
    every variant become constants of the code (else every value is a param, P[j])."""
    n = 3 * n_bodies
    members = sum(len(g.members) for g in groups)
    layout = force or ("member" if members <= MEMBER_LIMIT else "group")
    graph = Graph()
    params = _Params(graph, fold)
    if layout == "group":
        try:
            return _fuse_groups(graph, params, groups, n_bodies, m)
        except _Duplicate:
            graph = Graph()
            params = _Params(graph, fold)
    return _fuse_members(graph, params, groups, n_bodies, m)


def same_leaves(template: Sequence[np.ndarray], arrays: Sequence[np.ndarray]) -> bool:
    """Whether ``arrays`` are values for the leaves of ``template`` (as many, of the same
    shapes but for the variants' axis)."""
    return len(template) == len(arrays) and all(
        a.shape[1:] == b.shape[1:] for a, b in zip(template, arrays))


def replayed(template_leaves: tuple, template_params: tuple, template_functions: tuple,
             params: "_Params", graph: Graph) -> bool:
    """Whether a replay of the leaves (:class:`_Params` with ``replay``) matched the
    template: every leaf made, every constant of the code the same, the params and function
    arguments of the same shapes."""
    return (not params.mismatch and len(params.leaves) == len(template_leaves)
            and same_leaves(template_params, params.arrays)
            and len(graph.functions) == len(template_functions))


class ReplayGraph:
    """Stands for the :class:`Graph` while :func:`rebind` makes the leaves again: only their
    values and the function arguments are kept, no node is made."""

    zero = None

    def __init__(self) -> None:
        self.functions: list = []

    def const(self, value: float) -> None:
        return None

    def var(self, *key) -> None:
        return None

    def function(self, f: Callable, d1: Callable, d2: Callable) -> int:
        self.functions.append((f, d1, d2))
        return len(self.functions) - 1


def rebind(template: Fused, groups) -> Fused | None:
    """``template``'s code with the values of ``groups``: the arguments' leaves made again,
    in the order the trace made them, without tracing (``template`` traced on groups of the
    same structure: the caller's check). None where the values do not fit the code: a value
    that the code holds as a constant differs (the caller traces anew)."""
    graph = ReplayGraph()
    params = _Params(graph, replay=template.leaves)
    for g in groups:
        if template.layout == "group":
            _args(graph, params, g)
        else:
            for j in range(len(g.members)):
                _args(graph, params, g, j)
    if not replayed(template.leaves, template.params, template.functions, params, graph):
        return None
    return replace(template, params=tuple(params.arrays), functions=tuple(graph.functions))


def _fuse_members(graph: Graph, params: _Params, groups, n_bodies: int, m: int) -> Fused:
    phi_n, rows, cols, jac, gamma_n = trace_members(graph, params, groups, n_bodies, m)
    return Fused(kernel(graph, phi_n, "phi"), kernel(graph, jac, "jac"),
                 kernel(graph, phi_n + jac, "phi_jac"), kernel(graph, gamma_n, "gamma"),
                 rows, cols, tuple(params.arrays), tuple(graph.functions), m, 3 * n_bodies,
                 "member", graph, tuple(phi_n), tuple(jac), tuple(gamma_n),
                 tuple(params.leaves))


def trace_members(graph: Graph, params: _Params, groups, n_bodies: int, m: int
                  ) -> tuple[list, np.ndarray, np.ndarray, list, list]:
    """Every constraint of ``groups`` traced member by member into ``graph``: the nodes of
    Phi (m), the positions (rows, cols) and nodes of Phi_q's non-zero entries, and the
    nodes of gamma (m)."""
    ground = Body(graph.zero, graph.zero, graph.zero, graph.one, graph.zero)
    bodies = [body_of(graph, 3 * i) for i in range(n_bodies)] + [ground]
    phi: list[Node | None] = [None] * m
    gamma: list[Node | None] = [None] * m
    entries: dict[tuple[int, int], Node] = {}
    for g in groups:
        for j in range(len(g.members)):
            slots = [int(b) for b in g.slots[j]]
            tr = _trace(g, j, graph, [bodies[b] for b in slots],
                        _args(graph, params, g, j))
            # a derived Jacobian is the total derivative in each body's coordinates: a body
            # attached twice has it in both of its slots, to be counted once; supplied terms
            # are per slot, and add up
            supplied = g.ctype.supplies("jacobian_terms")
            for i, r in enumerate(int(r) for r in g.rows[j]):
                phi[r], gamma[r] = tr.phi[i], tr.gamma[i]
                for k, b in enumerate(slots):
                    if b == n_bodies or (not supplied and b in slots[:k]):
                        continue
                    for c in range(3):
                        d = tr.jacobian[i][3 * k + c]
                        if d is graph.zero:
                            continue
                        key = (r, 3 * b + c)
                        entries[key] = d if key not in entries else graph.op("add", entries[key], d)
    keys = sorted(entries)
    rows = np.array([k[0] for k in keys], dtype=np.intp)
    cols = np.array([k[1] for k in keys], dtype=np.intp)
    jac = [entries[k] for k in keys]
    phi_n = [graph.zero if x is None else x for x in phi]
    gamma_n = [graph.zero if x is None else x for x in gamma]
    return phi_n, rows, cols, jac, gamma_n


def _fuse_groups(graph: Graph, params: _Params, groups, n_bodies: int, m: int) -> Fused:
    """Each group traced once on gathered columns: body k of member j reads Q[..., 3 s_jk
    + c], the ground reading a zero column (index n)."""
    n = 3 * n_bodies
    constants: dict[str, np.ndarray] = {}

    def name(arr: np.ndarray, prefix: str) -> str:
        key = f"{prefix}{len(constants)}"
        constants[key] = np.ascontiguousarray(arr, dtype=np.intp)
        return key

    phi_out, gamma_out, jac_out = [], [], []  # (position name, node)
    entry_rows: list[np.ndarray] = []
    entry_cols: list[np.ndarray] = []
    for gi, g in enumerate(groups):
        slots = np.asarray(g.slots, dtype=np.intp)
        J, S = slots.shape
        bodies = []
        for k in range(S):
            col = np.where(slots[:, k] == n_bodies, n, 3 * slots[:, k])
            idx = [name(np.where(slots[:, k] == n_bodies, n, col + c), "G") for c in range(3)]
            phi_k = graph.var("gq", idx[2])
            bodies.append(Body(graph.var("gq", idx[0]), graph.var("gq", idx[1]), phi_k,
                               np.cos(phi_k), np.sin(phi_k)))
        tr = _trace(g, 0, graph, bodies, _args(graph, params, g))
        rows = np.asarray(g.rows, dtype=np.intp)  # (J, n_eq)
        for i in range(g.ctype.n_eq):
            at = name(rows[:, i], "R")
            phi_out.append((at, tr.phi[i]))
            gamma_out.append((at, tr.gamma[i]))
            for k in range(S):
                moving = slots[:, k] != n_bodies
                for c in range(3):
                    d = tr.jacobian[i][3 * k + c]
                    if d is graph.zero:
                        continue
                    jac_out.append((moving, d))
                    entry_rows.append(rows[moving, i])
                    entry_cols.append(3 * slots[moving, k] + c)
    # the pattern: entries sorted by (row, col); each group output scatters its members' values
    all_rows = np.concatenate(entry_rows) if entry_rows else np.zeros(0, np.intp)
    all_cols = np.concatenate(entry_cols) if entry_cols else np.zeros(0, np.intp)
    keys = all_rows * max(n, 1) + all_cols
    uniq, first = np.unique(keys, return_index=True)
    if len(uniq) != len(keys):
        # two entries of one (row, col): a body attached twice to one constraint; the member
        # layout adds them
        raise _Duplicate()
    order_of = np.empty(len(keys), np.intp)
    order_of[np.argsort(keys, kind="stable")] = np.arange(len(keys))
    jac_pos, jac_nodes = [], []
    start = 0
    for moving, d in jac_out:
        count = int(moving.sum())
        pos = order_of[start : start + count]
        start += count
        if count == len(moving):
            jac_pos.append(name(pos, "J"))
            jac_nodes.append(d)
        else:  # members on the ground have no entry: write only the moving ones
            jac_pos.append(name(pos, "J"))
            jac_nodes.append(d if d.op == "const" else
                             graph._make("select", (d,), name(np.flatnonzero(moving), "S")))
    rows_sorted = all_rows[np.argsort(keys, kind="stable")]
    cols_sorted = all_cols[np.argsort(keys, kind="stable")]
    nnz = len(keys)
    p_pos, p_nodes = zip(*phi_out) if phi_out else ((), ())
    g_pos, g_nodes = zip(*gamma_out) if gamma_out else ((), ())
    jac_shift = [name(constants[p] + m, "K") for p in jac_pos]
    return Fused(
        kernel(graph, list(p_nodes), "phi", list(p_pos), m, constants),
        kernel(graph, jac_nodes, "jac", jac_pos, nnz, constants),
        kernel(graph, list(p_nodes) + jac_nodes, "phi_jac", list(p_pos) + jac_shift, m + nnz,
               constants),
        kernel(graph, list(g_nodes), "gamma", list(g_pos), m, constants),
        rows_sorted, cols_sorted, tuple(params.arrays), tuple(graph.functions), m, n, "group",
        leaves=tuple(params.leaves))


class _Constant:
    """A function argument whose expression does not read its variable: its value, with
    zero derivatives."""

    def __init__(self, value, zero) -> None:
        self.value, self.zero = value, zero

    def __call__(self, x):
        return self.value

    def d1(self, x):
        return self.zero

    def d2(self, x):
        return self.zero


class _Duplicate(Exception):
    """A constraint attaches one body twice: the group layout cannot scatter its entries."""
