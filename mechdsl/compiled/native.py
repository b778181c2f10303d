"""The optional compiled backend: the model's generated code, compiled by numba.

Where numba is installed (``pip install mechdsl[fast]``), the same expression graphs and LU
plan that give the numpy kernels (:mod:`mechdsl.compiled.fused`, :mod:`mechdsl.compiled.lu`)
are written once more as scalar code, inside one loop over variants and instants: a march
that predicts each instant from the ones before (over equal steps, the last accelerations
integrated twice, :func:`stormer`; else q + tau qd + tau^2/2 qdd + tau^3/6 qddd), corrects it
by Newton with the model's own sparse LU, and solves the velocities and accelerations from
the final factorisation, all in machine code. On a smooth motion the prediction is within
``settled_step`` of the solution, and the instant takes one evaluation of the equations.
The bodies' cos phi and sin phi are carried across Newton's small steps by the angle-addition
formulas and shared with gamma. Drive functions are evaluated beforehand by numpy at every
instant (they depend on t alone), so that nothing but arithmetic is compiled. The assembly's
continuation of the drives to t0 (``carry``) is compiled too.

The variants are independent and marched in parallel, a thread each on every core (numba's
prange). The march checks what the numpy march checks (convergence, a pivot of the fixed
order that became small, det(Phi_q)'s sign, Newton's correction against the motion, the
condition number, by the same Hager and Higham estimate, against ``singular_rcond``, rates
that are finite numbers) and stops a variant at its first instant that fails one; the numpy
solver takes over from there and reports it exactly.

The module source is keyed by the hash of the generated code and written, with numba's
cache, under the user's cache folder (only if it is the user's own and private, as for the
parser's tables), so that a model compiles once per machine; elsewhere it compiles in
memory. numba is imported only here, and only when the backend is asked for.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
from typing import Callable

import numpy as np

from ..symbolic.codegen import CALLED, assignments
from ..symbolic.graph import Graph, Node
from .kernels import Kernels
from .lu import scalar_lines

#: States (variants times instants) per call of the compiled march: about 0.1 s of work, so
#: that progress is shown and an interrupt is taken between calls.
CHUNK_STATES = 2**17


def chunk_instants(variants: int) -> int:
    """Instants per call of the compiled march for ``variants`` variants."""
    return max(16, CHUNK_STATES // max(1, variants))


def available() -> bool:
    """Whether numba can be imported (without importing it)."""
    return importlib.util.find_spec("numba") is not None


#: numpy's error model: a division by zero gives inf or nan (which the checks catch) instead
#: of a test and a branch before every division
JIT = '@njit(cache=True, error_model="numpy")'


def _read(key: tuple) -> str:
    kind = key[0]
    if kind == "t":
        return "t"
    if kind not in ("q", "qd", "p"):
        raise ValueError(f"the compiled backend cannot read {kind}")
    return f"{kind}[{key[1]}]"


def _scalar_code(graph: Graph, outputs: list[tuple[str, Node]], indent: str,
                 given: dict[int, str] | None = None) -> list[str]:
    """Straight-line scalar code assigning each output ``target = node``; variables read
    ``q[k]``, ``qd[k]`` and ``p[j]`` (the numpy kernels' code generator, on scalars), the
    nodes of ``given`` their expressions."""
    lines, names = assignments(graph, [node for _, node in outputs], _read, given=given)
    lines += [f"{target} = {names[node.id]}" for target, node in outputs]
    return [indent + ln for ln in lines]


def _angles(graph: Graph, roots: list[Node]) -> tuple[list[int], dict[int, str]]:
    """The coordinates whose cosine or sine the graphs of ``roots`` take (the bodies'
    angles), in increasing order, and the expressions that read those values from ``cs``
    (cos q_k at ``cs[2 j]``, sin q_k at ``cs[2 j + 1]``, j the coordinate's place in the
    list)."""
    trig = [node for node in graph.subgraph(roots)
            if node.op in ("cos", "sin") and node.args[0].op == "var"
            and node.args[0].value[0] == "q"]
    coords = sorted({int(node.args[0].value[1]) for node in trig})
    given = {node.id: f"cs[{2 * coords.index(int(node.args[0].value[1])) + (node.op == 'sin')}]"
             for node in trig}
    return coords, given


def _trig_code(coords: list[int]) -> list[str]:
    """``trig(q, cs)``: cos and sin of the angles ``coords`` at q; ``trig_step(q, qo, cs)``:
    the same from their values at qo by the angle-addition formulas,
    cos(a + h) = cos a cos h - sin a sin h, sin(a + h) = sin a cos h + cos a sin h, with
    cos h and sin h from their series where |h| <= 1e-3 (truncated after h^4 and h^5: the
    error is below 1e-20), else anew. A Newton step from a converged prediction moves the
    angles by about 1e-10: the evaluations that confirm it and the rates at the solution
    take no new cosine or sine."""
    code = [JIT, "def trig(q, cs):", "    pass"]
    for j, k in enumerate(coords):
        code += [f"    cs[{2 * j}] = cos(q[{k}])", f"    cs[{2 * j + 1}] = sin(q[{k}])"]
    code += ["", JIT, "def trig_step(q, qo, cs):", "    pass"]
    for j, k in enumerate(coords):
        c, s = f"cs[{2 * j}]", f"cs[{2 * j + 1}]"
        code += [f"    h = q[{k}] - qo[{k}]",
                 "    if abs(h) <= 1e-3:",
                 "        h2 = h * h",
                 "        ch = 1.0 - h2 / 2 * (1.0 - h2 / 12)",
                 "        sh = h * (1.0 - h2 / 6 * (1.0 - h2 / 20))",
                 f"        c = {c}",
                 f"        {c} = c * ch - {s} * sh",
                 f"        {s} = {s} * ch + c * sh",
                 "    else:",
                 f"        {c} = cos(q[{k}])",
                 f"        {s} = sin(q[{k}])"]
    return code


#: Accelerations the compiled march's predictor extrapolates (see :func:`stormer`): on the
#: seed, 6 left 93 % of the instants to a second evaluation, 8 and 10 about 12 %
HISTORY = 8


def stormer(m: int) -> list:
    """beta_j = integral_0^1 (1 - s) L_j(s) ds, j = 0 .. m-1, exactly: L_j the Lagrange
    basis of the nodes s = 0, -1, .., -(m - 1) (the last m instants, in steps). With equal
    steps tau, q(t + tau) = q + tau qd + tau^2 sum_j beta_j qdd_(-j) + O(tau^(m + 2)): the
    accelerations' extrapolating polynomial integrated twice (Stormer's explicit formula in
    its one-step form). Fractions, exact."""
    from fractions import Fraction  # (only where the backend is built: not at start-up)

    nodes = [Fraction(-j) for j in range(m)]
    betas = []
    for j in range(m):
        poly, denom = [Fraction(1)], Fraction(1)
        for i, node in enumerate(nodes):
            if i == j:
                continue
            grown = [Fraction(0)] * (len(poly) + 1)
            for k, c in enumerate(poly):  # poly * (s - node)
                grown[k + 1] += c
                grown[k] -= c * node
            poly, denom = grown, denom * (nodes[j] - node)
        # integral_0^1 (1 - s) s^k ds = 1/(k + 1) - 1/(k + 2)
        betas.append(sum(c * (Fraction(1, k + 1) - Fraction(1, k + 2))
                         for k, c in enumerate(poly)) / denom)
    return betas


def source(kernels: Kernels) -> str | None:
    """The module source of the compiled march of ``kernels``; None where the backend does
    not apply (a large mechanism's group layout, function arguments, no square LU plan)."""
    system = kernels.system
    f, lu = kernels.fused, kernels.lu
    if f is None or lu is None or f.layout != "member" or f.functions:
        return None
    graph: Graph = f.graph
    m, n, nnz, slots = f.m, f.n, len(f.rows), lu.slots
    code = ["import numpy as np", f"from numpy import {', '.join(CALLED)}, inf, nan",
            "from numba import njit, prange", ""]
    coords, given = _angles(graph, [*f.phi_nodes, *f.jac_nodes, *f.gamma_nodes])
    code += _trig_code(coords)
    code += ["", JIT, "def phi_jac(q, cs, p, phi, a):"]
    code += _scalar_code(graph, [(f"phi[{i}]", x) for i, x in enumerate(f.phi_nodes)]
                         + [(f"a[{k}]", x) for k, x in enumerate(f.jac_nodes)], "    ", given)
    code += ["", JIT, "def gamma(q, cs, qd, p, g):"]
    code += _scalar_code(graph, [(f"g[{i}]", x) for i, x in enumerate(f.gamma_nodes)], "    ",
                         given)
    # the pivots' reciprocals after the factor's slots
    place = {int(k): slots + j for j, k in enumerate(lu.pivots)}
    factor, solve, solve_t = scalar_lines(
        lu, "a[{}]".format, "y[{}]".format, "x[{}]".format, "c[{}]".format, "w[{}]".format,
        "return False", recip=lambda k: f"a[{place[k]}]")
    code += ["", JIT, "def factor(a, threshold):",
             f"    a[{nnz}:{slots}] = 0.0" if slots > nnz else "    pass"]
    code += [f"    {ln}" for ln in factor] + ["    return True"]
    # the solves overwrite their right-hand side (no allocation inside the march)
    code += ["", JIT, "def solve(a, y, x):", "    pass"] + [f"    {ln}" for ln in solve]
    code += ["", JIT, "def solve_t(a, c, w):", "    pass"] + [f"    {ln}" for ln in solve_t]
    pivots = ", ".join(str(k) for k in lu.pivots)
    drive_rows = ", ".join(str(int(r)) for r in system.drive_rows)
    code += ["", f"PIVOTS = np.array([{pivots}], dtype=np.int64)",
             f"DRIVES = np.array([{drive_rows}], dtype=np.int64)",
             f"ROWS = np.array([{', '.join(str(int(r)) for r in f.rows)}], dtype=np.int64)",
             f"COLS = np.array([{', '.join(str(int(c)) for c in f.cols)}], dtype=np.int64)",
             ""]
    sizes = dict(m=m, n=n, nnz=nnz, width=slots + len(place), parity=float(lu.parity),
                 angles=max(1, 2 * len(coords)), drives=max(1, len(system.drive_rows)),
                 history=HISTORY)
    beta = ", ".join(repr(float(b)) for b in stormer(HISTORY))
    code += [f"BETA = np.array([{beta}])", ""]
    # the variants in parallel, and one mechanism without waking numba's threads (measured
    # 20 us less on the seed, called between other work)
    code += [EVALUATE.format(**sizes),
             MARCH.format(name="march", parallel=True, loop="prange", **sizes),
             MARCH.format(name="march_one", parallel=False, loop="range", **sizes),
             CARRY.format(**sizes)]
    return "\n".join(code) + "\n"


EVALUATE = '''
@njit(cache=True, error_model="numpy", inline="always")
def evaluate(x, cs, p, f, d, threshold, phi, a, r, col):
    """Phi(x) - f at the drive rows, and the scaled Jacobian A = R Phi_q D (R: the
    reciprocal row norms of Phi_q D) factorised in place (``cs``: the angles' cos and sin
    at x); returns ||A||_1, or -1 where a pivot of the fixed order became small."""
    phi_jac(x, cs, p, phi, a)
    for j in range(DRIVES.shape[0]):
        phi[DRIVES[j]] -= f[j]
    for i in range({m}):
        r[i] = 0.0
    for k in range({nnz}):
        a[k] *= d[COLS[k]]
        r[ROWS[k]] += a[k] * a[k]
    for i in range({m}):
        r[i] = 1.0 / np.sqrt(r[i]) if r[i] > 0 else 1.0
    for i in range({n}):
        col[i] = 0.0
    for k in range({nnz}):
        a[k] *= r[ROWS[k]]
        col[COLS[k]] += abs(a[k])
    norm_a = 0.0
    for i in range({n}):
        if col[i] > norm_a:
            norm_a = col[i]
    if not factor(a, threshold):
        return -1.0
    return norm_a


@njit(cache=True, error_model="numpy", inline="always")
def det_sign(a):
    """The sign of det Phi_q from the factors ``a``: the permutations' parity times the
    pivots' signs."""
    det = {parity}
    for j in range(PIVOTS.shape[0]):
        det *= np.sign(a[PIVOTS[j]])
    return det


'''


MARCH = '''
@njit(cache=True, parallel={parallel}, error_model="numpy")
def {name}(Q0, QD0, QDD0, SIGN0, TT, FD, P, D, tol, err_tol, settled, maxit, threshold,
          branch_ratio, singular_rcond, first, Q, QD, QDD, RC, SG, status, RES):
    """Instants 1.. of every variant from instant 0 (see the module documentation), and
    with ``first`` instant 0 too: Newton from Q0 (the assembled configuration), whose
    det(Phi_q) sign the march then keeps; status[v] = the first instant not solved
    (len(TT) when all are); RES[v] the largest |Phi| of the solved states."""
    V, K = Q0.shape[0], TT.shape[0]
    floor = np.sqrt(tol)
    for v in {loop}(V):  # the variants are independent: one thread each, on every core
        phi = np.empty({m})
        a = np.empty({width})
        g = np.empty({m})
        rhs = np.empty({n})
        dx = np.empty({n})
        r = np.empty({m})
        col = np.empty({n})
        e = np.empty({n})
        z = np.empty({n})
        pred = np.empty({n})
        x = np.empty({n})
        xo = np.empty({n})
        cs = np.empty({angles})
        jerk = np.zeros({n})
        # the last accelerations (a ring, ``head`` the newest) over equal steps ``spacing``
        # (within this call: a chunk starts with Taylor's predictor)
        past = np.zeros(({history}, {n}))
        head, known, spacing = 0, 0, 0.0
        p = P[:, v].copy()
        d = D[v].copy()
        q = Q0[v].copy()
        qd = QD0[v].copy()
        qdd = QDD0[v].copy()
        sign = SIGN0[v]
        status[v] = K
        for k in range(1 - first, K):
            tau = TT[k] - TT[k - 1] if k > 0 else 0.0
            if not abs(tau - spacing) <= 1e-9 * abs(spacing):  # other steps: a new history
                known, spacing = 0, tau
            smooth = known >= {history}
            if smooth:
                # q + tau qd + tau^2 sum_j beta_j qdd_(k-1-j): the double integral of the
                # accelerations' extrapolating polynomial (Stormer's predictor, error
                # O(tau^(history + 2))): on a smooth motion Newton's first step is at
                # round-off (settled), and one evaluation is the instant's only one
                for i in range({n}):
                    pred[i] = 0.0
                for j in range({history}):
                    w = BETA[j]
                    row = (head - j) % {history}
                    for i in range({n}):
                        pred[i] += w * past[row, i]
                for i in range({n}):
                    pred[i] = q[i] + tau * (qd[i] + tau * pred[i])
                    x[i] = pred[i]
            else:
                # Taylor to the third order, d3q/dt3 from the last two accelerations
                for i in range({n}):
                    pred[i] = q[i] + tau * (qd[i] + tau / 2 * (qdd[i] + tau / 3 * jerk[i]))
                    x[i] = pred[i]
            conv = False
            final = False
            prev = np.inf
            for it in range(maxit):
                if it == 0:
                    trig(x, cs)
                else:
                    trig_step(x, xo, cs)
                norm_a = evaluate(x, cs, p, FD[v, k, 0], d, threshold, phi, a, r, col)
                if norm_a < 0:
                    break
                for i in range({m}):
                    rhs[i] = -phi[i] * r[i]
                solve(a, rhs, dx)  # A (dq / D) = -R Phi
                step = 0.0
                for i in range({n}):
                    s = abs(dx[i])
                    if not s <= step:
                        step = s
                for i in range({n}):
                    xo[i] = x[i]
                    x[i] += d[i] * dx[i]
                if step <= settled:
                    # converged where it started: the factorisation there is kept (as the
                    # numpy path keeps it), the position takes the step (the residual kept,
                    # |Phi| where it started, bounds the one there: the step is round-off)
                    trig_step(x, xo, cs)
                    conv = final = True
                    break
                if it == 0 and smooth and not step <= tol:
                    # off by more than Newton's tolerance (on a smooth motion it is off by
                    # round-off): the accelerations' history spans a kink (a drive's
                    # piecewise law), where their polynomial is no guide; Taylor until the
                    # history is past it
                    known = 0
                if step <= tol or (prev < np.inf and step < 0.25 * prev
                                   and step ** 3 / prev ** 2 <= err_tol):
                    conv = True
                    break
                if it >= 2 and step > 0.5 * prev:
                    break
                prev = step
            if not conv:
                status[v] = k
                break
            if not final:  # the factorisation at the converged position
                trig_step(x, xo, cs)
                norm_a = evaluate(x, cs, p, FD[v, k, 0], d, threshold, phi, a, r, col)
                if norm_a < 0:
                    status[v] = k
                    break
            for i in range({m}):
                if not abs(phi[i]) <= RES[v]:
                    RES[v] = abs(phi[i])
            det = det_sign(a)
            # ||A^-1||_1 by Hager's method with Higham's safeguard, as the numpy path
            for i in range({n}):
                e[i] = 1.0 / {n}
            solve(a, e, dx)
            inv_norm = 0.0
            for i in range({n}):
                inv_norm += abs(dx[i])
                e[i] = 1.0 if dx[i] >= 0 else -1.0
            solve_t(a, e, z)
            zmax, jmax, zsum = 0.0, 0, 0.0
            for i in range({n}):
                zsum += z[i] / {n}
                if abs(z[i]) > zmax:
                    zmax, jmax = abs(z[i]), i
            if zmax > zsum:
                for i in range({n}):
                    e[i] = 0.0
                e[jmax] = 1.0
                solve(a, e, dx)
                s = 0.0
                for i in range({n}):
                    s += abs(dx[i])
                inv_norm = max(inv_norm, s)
            for i in range({n}):
                e[i] = (1.0 if i % 2 == 0 else -1.0) * (1.0 + i / max({n} - 1, 1))
            solve(a, e, dx)
            s = 0.0
            for i in range({n}):
                s += abs(dx[i])
            inv_norm = max(inv_norm, 2.0 * s / (3.0 * {n}))
            rcond = 1.0 / (norm_a * inv_norm)
            moved = 0.0
            corr = 0.0
            for i in range({n}):
                moved = max(moved, abs(x[i] - q[i]) / d[i], abs(pred[i] - q[i]) / d[i])
                corr = max(corr, abs(x[i] - pred[i]) / d[i])
            ratio = corr / max(moved, floor)
            if k == 0:  # the sign the march keeps
                sign, ratio = det, 0.0
            if not (det == sign and rcond >= singular_rcond and ratio <= branch_ratio):
                status[v] = k
                break
            # rates: Phi_q^-1 b = D A^-1 R b
            for i in range({n}):
                rhs[i] = 0.0
            for j in range(DRIVES.shape[0]):
                rhs[DRIVES[j]] = FD[v, k, 1, j]
            for i in range({m}):
                rhs[i] *= r[i]
            solve(a, rhs, dx)
            for i in range({n}):
                qd[i] = d[i] * dx[i]
            gamma(x, cs, qd, p, g)
            for j in range(DRIVES.shape[0]):
                g[DRIVES[j]] += FD[v, k, 2, j]
            for i in range({m}):
                rhs[i] = g[i] * r[i]
            solve(a, rhs, dx)
            finite = True
            head = (head + 1) % {history}
            for i in range({n}):
                qdd_i = d[i] * dx[i]
                jerk[i] = (qdd_i - qdd[i]) / tau if k > 0 else 0.0
                qdd[i] = qdd_i
                past[head, i] = qdd_i
                finite = finite and np.isfinite(qd[i]) and np.isfinite(qdd[i])
            known += 1
            if not finite:  # the numpy march reports it, or keeps it, as asked
                status[v] = k
                break
            for i in range({n}):
                q[i] = x[i]
                Q[v, k, i] = x[i]
                QD[v, k, i] = qd[i]
                QDD[v, k, i] = qdd[i]
            RC[v, k] = rcond
            SG[v, k] = det
    return status
'''


CARRY = '''
@njit(cache=True, error_model="numpy")
def inverse_norm(a, n_cols, e, w):
    """||A^-1||_1 exactly, from the solves of the unit vectors."""
    norm = 0.0
    for j in range(n_cols):
        for i in range(n_cols):
            e[i] = 0.0
        e[j] = 1.0
        solve(a, e, w)
        s = 0.0
        for i in range(n_cols):
            s += abs(w[i])
        if not s <= norm:
            norm = s
    return norm


@njit(cache=True, error_model="numpy")
def carry(x0, f, p, d, tol, err_tol, maxit, threshold, branch_ratio, singular_rcond,
          max_bisections, x, info):
    """The drives carried from their values g(x0) at x0 (the joints closed) to f(t0):
    :func:`mechdsl.solve.assembly._continue_drives` for one state, the same steps and
    checks (Newton on Phi(q, t0) + (1 - s)(f - g) = 0 for s from 0 to 1, each step
    started from the tangent, shortened when Newton struggles, refused where the Jacobian
    turns singular or changes sign, or Newton's correction is large against the motion).
    x: the configuration reached; info[0] = 1 carried, 0 refused, -1 a pivot of the fixed
    order became small (the float code decides); info[1] the Newton iterations."""
    phi = np.empty({m})
    a = np.empty({width})
    ax = np.empty({width})
    r = np.empty({m})
    rx = np.empty({m})
    col = np.empty({n})
    cs = np.empty({angles})
    dx = np.empty({n})
    rhs = np.empty({n})
    e = np.empty({n})
    pred = np.empty({n})
    xn = np.empty({n})
    delta = np.zeros({m})
    g = np.zeros({drives})
    target = np.zeros({drives})
    floor = np.sqrt(tol)
    info[0], info[1] = -1, 0
    for i in range({n}):
        x[i] = x0[i]
    trig(x, cs)
    if evaluate(x, cs, p, target, d, threshold, phi, a, r, col) < 0:
        return
    for j in range(DRIVES.shape[0]):
        g[j] = phi[DRIVES[j]]
        step = f[j] - g[j]
        delta[DRIVES[j]] = step if np.isfinite(step) else 0.0
    sign = det_sign(a)
    ax[:] = a
    rx[:] = r
    s, ds, iterations = 0.0, 1.0, 0
    while s < 1.0:
        s_new = min(1.0, s + ds)
        for i in range({m}):  # the tangent: Phi_q dq/ds = delta at x
            rhs[i] = delta[i] * rx[i]
        solve(ax, rhs, dx)
        for i in range({n}):
            step = (s_new - s) * d[i] * dx[i]
            pred[i] = x[i] + step if np.isfinite(step) else x[i]
            xn[i] = pred[i]
        for j in range(DRIVES.shape[0]):
            target[j] = g[j] - (g[j] - f[j]) * s_new
        conv, prev, it = False, np.inf, 0
        for it in range(1, maxit + 1):
            trig(xn, cs)
            if evaluate(xn, cs, p, target, d, threshold, phi, a, r, col) < 0:
                return
            for i in range({m}):
                rhs[i] = -phi[i] * r[i]
            solve(a, rhs, dx)
            step = 0.0
            for i in range({n}):
                if not abs(dx[i]) <= step:
                    step = abs(dx[i])
            if not np.isfinite(step):
                break
            for i in range({n}):
                xn[i] += d[i] * dx[i]
            left = step ** 3 / prev ** 2 if step < 0.25 * prev and prev < np.inf else np.inf
            if step <= tol or left <= err_tol:
                conv = True
                break
            if it >= 3 and not step <= 0.5 * prev:
                break
            prev = step
        iterations += it
        info[1] = iterations
        trig(xn, cs)
        norm_a = evaluate(xn, cs, p, target, d, threshold, phi, a, r, col)
        if norm_a < 0:
            return
        inv_norm = inverse_norm(a, {n}, e, dx)
        rcond = 1.0 / (norm_a * inv_norm) if inv_norm > 0 else 0.0
        if not np.isfinite(rcond):
            rcond = 0.0
        det = det_sign(a)
        moved, corr = 0.0, 0.0
        finite = True
        for i in range({n}):
            moved = max(moved, abs(xn[i] - x[i]) / d[i], abs(pred[i] - x[i]) / d[i])
            corr = max(corr, abs(xn[i] - pred[i]) / d[i])
            finite = finite and np.isfinite(xn[i]) and np.isfinite(pred[i])
        ratio = corr / max(moved, floor) if finite else np.inf
        if not (conv and rcond >= singular_rcond and det == sign and ratio <= branch_ratio):
            if ds > 2.0 ** -max_bisections:
                ds /= 2
                continue
            info[0] = 0
            return
        for i in range({n}):
            x[i] = xn[i]
        ax[:] = a
        rx[:] = r
        s = s_new
        if it <= 3:
            ds = min(1.0, 2 * ds)
    info[0] = 1
'''


def _cache_folder() -> str | None:
    from ..grammar.cache import safe_folder

    return safe_folder("native")


def load(kernels: Kernels):
    """The compiled module of ``kernels``: its ``march`` and its ``carry`` (numba imported,
    the module compiled or loaded from the cache), or None where the backend does not apply
    or numba is missing."""
    text = source(kernels)
    if text is None or not available():
        return None
    return _module(text)


def _module(text: str):
    """The module of generated source ``text``: imported from the user's cache folder (the
    file written there first, and checked byte for byte), so that numba's cache beside it
    serves the next process; compiled in memory where there is no such folder."""
    key = hashlib.sha256(text.encode()).hexdigest()[:20]
    name = f"mechdsl_native_{key}"
    if name in sys.modules:
        return sys.modules[name]
    folder = _cache_folder()
    if folder is not None:
        path = os.path.join(folder, name + ".py")
        try:
            with open(path, "rb") as fh:
                same = fh.read() == text.encode()
        except OSError:
            same = False
        if not same:
            tmp = f"{path}.{os.getpid()}.tmp"
            with open(tmp, "w") as fh:
                fh.write(text)
            os.replace(tmp, path)
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)  # our own generated source, checked byte for byte
        return module
    import types

    module = types.ModuleType(name)
    # no file, no cache: numba compiles in memory
    exec(compile(text.replace("cache=True", "cache=False"), f"<{name}>", "exec"),  # noqa: S102
         module.__dict__)
    sys.modules[name] = module
    return module


def dynamics_source(kernels: Kernels) -> str | None:
    """The module source of the compiled equations of motion of ``kernels``: ``accel(t, q,
    qd, p, pd, qdd, lam)`` solves [M Phi_q^T; Phi_q 0][qdd; lambda] = [Q; gamma] for one
    state (by M's blocks and the Schur complement, see ``SCHUR``), with the same graphs as
    the numpy kernels written as scalar code; None where the backend does not apply (the
    group layout, function arguments, drives)."""
    system = kernels.system
    f, d = kernels.fused, kernels.dynamics
    if (f is None or d is None or d.graph is None or f.layout != "member" or f.functions
            or d.functions or kernels.drive_functions):
        return None
    n, m = system.n, system.m
    big = n + m
    nnz = len(f.rows)
    code = ["import numpy as np", f"from numpy import {', '.join(CALLED)}, inf, nan",
            "from numba import njit", "", JIT, "def constraint_part(q, qd, p, out):"]
    code += _scalar_code(f.graph, [(f"out[{k}]", x) for k, x in
                                   enumerate([*f.jac_nodes, *f.gamma_nodes])], "    ")
    code += ["", JIT, "def motion_part(q, qd, t, p, out):"]
    code += _scalar_code(d.graph, [(f"out[{k}]", x) for k, x in
                                   enumerate([*d.load_nodes, *d.mass_nodes])], "    ")
    aug_jac = ", ".join(str(int((r + n) * big + c)) for r, c in zip(f.rows, f.cols))
    aug_jac_t = ", ".join(str(int(c * big + r + n)) for r, c in zip(f.rows, f.cols))
    aug_mass = ", ".join(str(int(r * big + c)) for r, c in zip(d.rows, d.cols))
    rows = ", ".join(str(int(r)) for r in f.rows)
    cols = ", ".join(str(int(c)) for c in f.cols)
    mrows = ", ".join(str(int(r)) for r in d.rows)
    mcols = ", ".join(str(int(c)) for c in d.cols)
    nb, nmass = n // 3, len(d.mass_nodes)
    code += ["", f"AUG_JAC = np.array([{aug_jac}], dtype=np.int64)",
             f"AUG_JAC_T = np.array([{aug_jac_t}], dtype=np.int64)",
             f"AUG_MASS = np.array([{aug_mass}], dtype=np.int64)",
             f"ROWS = np.array([{rows}], dtype=np.int64)",
             f"COLS = np.array([{cols}], dtype=np.int64)",
             f"MROWS = np.array([{mrows}], dtype=np.int64)",
             f"MCOLS = np.array([{mcols}], dtype=np.int64)", "",
             SCHUR.format(n=n, m=m, big=big, nnz=nnz, nb=nb, nmass=nmass)]
    return "\n".join(code) + "\n"


SCHUR = '''
@njit(cache=True, error_model="numpy")
def accel(t, q, qd, p, pd, qdd, lam):
    """qdd and lambda of one state; False where they are not finite numbers. Every body's
    3 x 3 block of M inverted in closed form, then the Schur complement
    (Phi_q M^-1 Phi_q^T) lambda = Phi_q M^-1 Q - gamma, qdd = M^-1 (Q - Phi_q^T lambda);
    where a block is singular (a body without mass), the augmented system instead."""
    c = np.empty({nnz} + {m})
    w = np.empty({n} + {nmass})
    constraint_part(q, qd, p, c)
    motion_part(q, qd, t, pd, w)
    blocks = np.zeros(({nb}, 3, 3))
    for k in range({nmass}):
        blocks[MROWS[k] // 3, MROWS[k] % 3, MCOLS[k] % 3] = w[{n} + k]
    minv = np.empty(({nb}, 3, 3))
    regular = True
    for i in range({nb}):
        b = blocks[i]
        c00 = b[1, 1] * b[2, 2] - b[1, 2] * b[2, 1]
        c01 = b[1, 2] * b[2, 0] - b[1, 0] * b[2, 2]
        c02 = b[1, 0] * b[2, 1] - b[1, 1] * b[2, 0]
        det = b[0, 0] * c00 + b[0, 1] * c01 + b[0, 2] * c02
        if not (abs(det) > 1e-300 and np.isfinite(det)):
            regular = False
            break
        minv[i, 0, 0] = c00 / det
        minv[i, 1, 0] = c01 / det
        minv[i, 2, 0] = c02 / det
        minv[i, 0, 1] = (b[0, 2] * b[2, 1] - b[0, 1] * b[2, 2]) / det
        minv[i, 1, 1] = (b[0, 0] * b[2, 2] - b[0, 2] * b[2, 0]) / det
        minv[i, 2, 1] = (b[0, 1] * b[2, 0] - b[0, 0] * b[2, 1]) / det
        minv[i, 0, 2] = (b[0, 1] * b[1, 2] - b[0, 2] * b[1, 1]) / det
        minv[i, 1, 2] = (b[0, 2] * b[1, 0] - b[0, 0] * b[1, 2]) / det
        minv[i, 2, 2] = (b[0, 0] * b[1, 1] - b[0, 1] * b[1, 0]) / det
    if regular and {m} > 0:
        jac = np.zeros(({m}, {n}))
        for k in range({nnz}):
            jac[ROWS[k], COLS[k]] = c[k]
        u = np.empty({n})
        wt = np.zeros(({n}, {m}))
        for i in range({nb}):
            for a in range(3):
                s = 0.0
                for e in range(3):
                    s += minv[i, a, e] * w[3 * i + e]
                u[3 * i + a] = s
                for r in range({m}):
                    s = 0.0
                    for e in range(3):
                        s += minv[i, a, e] * jac[r, 3 * i + e]
                    wt[3 * i + a, r] = s
        schur = jac @ wt
        rhs = jac @ u - c[{nnz}:]
        lam[:] = np.linalg.solve(schur, rhs)
        qdd[:] = u - wt @ lam
    else:
        a = np.zeros({big} * {big})
        for k in range({nnz}):
            a[AUG_JAC[k]] = c[k]
            a[AUG_JAC_T[k]] = c[k]
        for k in range({nmass}):
            a[AUG_MASS[k]] = w[{n} + k]
        rhs = np.empty({big})
        rhs[:{n}] = w[:{n}]
        rhs[{n}:] = c[{nnz}:]
        sol = np.linalg.solve(a.reshape(({big}, {big})), rhs)
        qdd[:] = sol[:{n}]
        lam[:] = sol[{n}:]
    for i in range({n}):
        if not np.isfinite(qdd[i]):
            return False
    for i in range({m}):
        if not np.isfinite(lam[i]):
            return False
    return True
'''


def load_dynamics(kernels: Kernels) -> Callable | None:
    """The compiled ``accel`` of ``kernels`` (see :func:`dynamics_source`), or None."""
    text = dynamics_source(kernels)
    if text is None or not available():
        return None
    return _module(text).accel
