"""The constraints' curvature: the derivative of the constraint forces Phi_q^T lambda.

An implicit integrator of the index-3 equations M qdd + Phi_q^T lambda = Q, Phi = 0 solves
for q with Newton's method; the derivative of the residual with respect to q contains

    d/dq (Phi_q^T lambda) = sum_i lambda_i Phi_i,qq        (n x n, symmetric),

the Hessians of the constraints weighted by the multipliers (Haug 1989, sec. 6.3: the
"geometric stiffness" of the joints). Its size relative to M is |lambda| h^2 / |M|: on
IFToMM A02 the rockers carry the weight of the whole chain and the term is of the order of
M itself at the step sizes of a 1e-6 tolerance, so a Newton matrix without it contracts
slowly or not at all. The entries are exact: derived by reverse accumulation from the same
traced graph as Phi_q (:meth:`mechdsl.symbolic.Graph.sparse_gradient`), one entry per
(equation i, coordinate k, coordinate j) with d(Phi_q)_ik / dq_j not identically zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..symbolic.codegen import first_floats
from ..symbolic import Graph
from .fused import _Params, trace_members
from .kernels import Kernels


@dataclass(frozen=True)
class Curvature:
    """The non-zero second derivatives d^2 Phi_i / dq_k dq_j of a mechanism's constraints:
    ``fn(q, (), t, p, F)`` (a kernel of floats, :func:`mechdsl.symbolic.codegen.
    scalar_kernel`) gives their values, entry e at equation ``eq[e]``, row ``rows[e]`` and
    column ``cols[e]``; ``params`` and ``functions`` are the kernel's ``p`` and ``F``."""

    fn: object
    eq: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    params: list
    functions: tuple

    def values(self, q: np.ndarray, t: float = 0.0) -> np.ndarray:
        """The entries at q (the drives' rows: Phi's time dependence is additive)."""
        return np.fromiter(self.fn(q.tolist(), (), t, self.params, self.functions), float,
                           self.eq.size)

    def matrix_entries(self, q: np.ndarray, lam: np.ndarray, t: float = 0.0) -> np.ndarray:
        """The entries of sum_i lambda_i Phi_i,qq at (rows, cols) (repeats add)."""
        return lam[self.eq] * self.values(q, t)


def curvature(kernels: Kernels) -> Curvature | None:
    """The :class:`Curvature` of ``kernels`` (a compiled model of one variant), or None where
    its constraints are linear in q. The constraints are traced member by member (whatever
    the layout of ``kernels.fused``) and only their Jacobian's gradient is compiled."""
    from ..symbolic.codegen import scalar_functions, scalar_kernel

    system = kernels.system
    f = kernels.fused
    if f.layout == "member" and f.graph is not None:
        graph, jac, rows, cols = f.graph, f.jac_nodes, f.rows, f.cols
        arrays = f.params
    else:
        graph = Graph()
        params = _Params(graph)
        _, rows, cols, jac, _ = trace_members(graph, params, system.groups,
                                              system.n_bodies, system.m)
        arrays = tuple(params.arrays)
    position = {graph.var("q", k).id: k for k in range(system.n)}
    nodes, eqs, ks, js = [], [], [], []
    for e, node in enumerate(jac):
        if node.op == "const":
            continue
        for j, d in graph.sparse_gradient(node, position):
            nodes.append(d)
            eqs.append(int(rows[e]))
            ks.append(int(cols[e]))
            js.append(j)
    if not nodes:
        return None
    p = first_floats(arrays)
    return Curvature(scalar_kernel(graph, nodes, "curvature").fn,
                     np.array(eqs, dtype=np.intp), np.array(ks, dtype=np.intp),
                     np.array(js, dtype=np.intp), p, scalar_functions(graph.functions))
