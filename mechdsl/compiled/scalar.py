"""The compiled model for ONE state: the fused evaluation and the generated LU as code on
Python floats.

A batched numpy operation costs about a microsecond whatever its size, a float operation a
few dozen nanoseconds. The steps of a solve that see one state at a time (the assembly at
t0 of a single mechanism, the coarse march of the parallel-in-time solver, which steps
through a few instants one after the other) would spend nearly all their time in numpy's
per-call overhead: the seed's Newton step is about sixty numpy calls for Phi and Phi_q and
as many for the factorisation. Here the same expression graphs (:mod:`mechdsl.compiled.fused`)
and the same LU plan (:mod:`mechdsl.compiled.lu`) are written once more as straight-line
code on local float variables:

* ``phi_jac(q, p, F)``: Phi's measures g(q) (m) then Phi_q's non-zero entries (nnz), one list;
* ``gamma(q, qd, p, F)``: -(Phi_q qd)_q qd (m);
* ``factor(values, threshold)``: the factors (a tuple of ``slots`` floats) of the matrix
  with entries ``values`` in the pattern's order, eliminated in the plan's fixed pivot
  order, or None where a pivot fell below ``threshold`` times its column's largest entry
  (the caller then factorises with partial pivoting);
* ``solve(factors, b)``: x with A x = b; ``solve_t(factors, c)``: z with A^T z = c.

The numbers are the batched kernels' to round-off: the same operations in the same order.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

from ..symbolic.codegen import ScalarKernel, first_floats, scalar_functions, scalar_kernel
from .kernels import Kernels
from .lu import LUPlan, scalar_lines


@dataclass(frozen=True)
class OneState:
    """One variant's model as float code (see the module documentation); ``params`` and
    ``functions`` are that variant's, as the kernels take them."""

    phi_jac: ScalarKernel
    gamma: ScalarKernel
    factor: Callable
    solve: Callable
    solve_t: Callable
    params: tuple[float, ...]
    functions: tuple
    m: int
    n: int
    nnz: int
    pivots: tuple[int, ...]
    parity: float
    rows: tuple[int, ...]
    cols: tuple[int, ...]
    source: str


def _lu_source(lu: LUPlan) -> str:
    """The plan's elimination and substitutions on local floats ``s0 ..`` (the factors)."""
    nnz, slots, n = lu.nnz, lu.slots, lu.n
    s = [f"s{k}" for k in range(slots)]
    y, x, c, w = ([f"{v}{i}" for i in range(n)] for v in "yxcw")
    factor, solve, solve_t = scalar_lines(lu, s.__getitem__, y.__getitem__, x.__getitem__,
                                          c.__getitem__, w.__getitem__, "return None")
    parts = [["def factor(values, threshold):", f"    {', '.join(s[:nnz])}, = values"]
             + [f"    {s[k]} = 0.0" for k in range(nnz, slots)]
             + [f"    {ln}" for ln in factor] + [f"    return ({', '.join(s)},)"],
             ["def solve(F, b):", f"    {', '.join(s)}, = F", f"    {', '.join(y)}, = b"]
             + [f"    {ln}" for ln in solve] + [f"    return [{', '.join(x)}]"],
             ["def solve_t(F, b):", f"    {', '.join(s)}, = F", f"    {', '.join(c)}, = b"]
             + [f"    {ln}" for ln in solve_t] + [f"    return [{', '.join(w)}]"]]
    return "\n\n".join("\n".join(part) for part in parts) + "\n"


def with_values(one: OneState, fused) -> OneState:
    """``one``'s code with the params of ``fused`` (the same code traced with other values:
    :func:`mechdsl.compiled.fused.rebind`), variant 0."""

    return replace(one, params=tuple(first_floats(fused.params)),
                   functions=scalar_functions(fused.variant(0).functions) if fused.functions
                   else ())


def one_state(kernels: Kernels, v: int = 0) -> OneState | None:
    """Variant ``v`` of ``kernels`` as float code; None where it does not apply: a model
    traced type by type (the group layout of a large mechanism) or without a square
    generated LU."""
    f, lu = kernels.fused, kernels.lu
    if f is None or lu is None or f.layout != "member" or f.graph is None:
        return None
    phi_jac = scalar_kernel(f.graph, [*f.phi_nodes, *f.jac_nodes], "phi_jac")
    gamma = scalar_kernel(f.graph, list(f.gamma_nodes), "gamma")
    text = _lu_source(lu)
    namespace: dict = {}
    exec(compile(text, "<mechdsl generated one-state lu>", "exec"), namespace)  # noqa: S102
    params = tuple(float(p.reshape(p.shape[0], -1)[v, 0]) for p in f.params)
    functions = scalar_functions(f.variant(v).functions) if f.functions else ()
    return OneState(phi_jac, gamma, namespace["factor"], namespace["solve"],
                    namespace["solve_t"], params, functions, f.m, f.n, len(f.rows),
                    tuple(int(k) for k in lu.pivots), float(lu.parity),
                    tuple(int(r) for r in f.rows), tuple(int(c) for c in f.cols),
                    phi_jac.source + gamma.source + text)
