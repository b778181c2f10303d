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

from dataclasses import dataclass
from typing import Callable

from ..symbolic.codegen import ScalarKernel, scalar_functions, scalar_kernel
from .lu import LUPlan


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
    f = ["def factor(values, threshold):", f"    {', '.join(s[:nnz])}, = values"]
    f += [f"    {s[k]} = 0.0" for k in range(nnz, slots)]
    for pr, pc, below, right, p_slot in lu.steps:
        if below:
            terms = [f"abs({s[l]})" for _, l in below]
            big = f"max({', '.join(terms)})" if len(terms) > 1 else terms[0]
            f.append(f"    if not abs({s[p_slot]}) >= threshold * {big}:")
        else:
            f.append(f"    if not {s[p_slot]} != 0.0:")
        f.append("        return None")
        for i, l in below:
            f.append(f"    {s[l]} = {s[l]} / {s[p_slot]}")
            for u, t in right[i]:
                f.append(f"    {s[t]} = {s[t]} - {s[l]} * {s[u]}")
    f.append(f"    return ({', '.join(s)},)")
    y = [f"y{i}" for i in range(n)]
    x = [f"x{i}" for i in range(n)]
    sv = ["def solve(F, b):", f"    {', '.join(s)}, = F", f"    {', '.join(y)}, = b"]
    for pr, pc, below, right, p_slot in lu.steps:
        for i, l in below:
            sv.append(f"    {y[i]} = {y[i]} - {s[l]} * {y[pr]}")
    for pr, pc, terms, p_slot in reversed(lu.back):
        rest = "".join(f" - {s[u]} * {x[c]}" for u, c in terms)
        sv.append(f"    {x[pc]} = ({y[pr]}{rest}) / {s[p_slot]}")
    sv.append(f"    return [{', '.join(x)}]")
    c = [f"c{i}" for i in range(n)]
    w = [f"w{i}" for i in range(n)]
    st = ["def solve_t(F, b):", f"    {', '.join(s)}, = F", f"    {', '.join(c)}, = b"]
    for pr, pc, terms, p_slot in lu.back:
        st.append(f"    {w[pr]} = {c[pc]} / {s[p_slot]}")
        for u, col in terms:
            st.append(f"    {c[col]} = {c[col]} - {s[u]} * {w[pr]}")
    for pr, pc, below, right, p_slot in reversed(lu.steps):
        for i, l in below:
            st.append(f"    {w[pr]} = {w[pr]} - {s[l]} * {w[i]}")
    st.append(f"    return [{', '.join(w)}]")
    return "\n\n".join("\n".join(part) for part in (f, sv, st)) + "\n"


def one_state(system, v: int = 0) -> OneState | None:
    """Variant ``v`` of ``system`` as float code; None where it does not apply: a model
    traced type by type (the group layout of a large mechanism) or without a square
    generated LU."""
    f, lu = system.fused, system.lu
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
