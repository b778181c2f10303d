"""Straight-line Python source from expression graphs, compiled once per model.

:func:`kernel` turns a list of graph nodes into one function that evaluates all of them for a
batch of states: each node of their common graph is computed once, in topological order, as
one numpy operation on whole arrays (the batch axes), and each output is written into its
column of one result array. Variables are read as columns of the inputs: ``("q", k)`` from
``Q[..., k]``, ``("qd", k)`` from ``QD[..., k]``, ``("p", j)`` from ``P[j]`` (a sweep
parameter, broadcasting against the batch), ``("t",)`` from ``T``. Functions of one variable
are called as ``F[i][order](x)``.

The optional compiled backend (:mod:`mechdsl.compiled.native`) writes the same graphs
through :func:`assignments`, as scalar code inside its loop.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .graph import Graph, Node

_INFIX = {"add": "+", "sub": "-", "mul": "*", "div": "/", "pow": "**"}
_CALLS = {"sin": "sin", "cos": "cos", "tan": "tan", "sqrt": "sqrt", "exp": "exp",
          "log": "log", "arctan": "arctan", "abs": "absolute", "sign": "sign",
          "arctan2": "arctan2", "mod": "remainder"}
_NAMESPACE = {name: getattr(np, name) for name in set(_CALLS.values())}


def _const(v) -> str:
    if v == "nan":
        return "nan"
    text = repr(float(v))
    if text in ("inf", "-inf"):
        return f"({text[:-3]}inf)"
    return f"({text})" if text.startswith("-") else text


def _read(key: tuple, major: bool) -> str:
    kind = key[0]
    if kind in ("q", "qd"):
        src = "Q" if kind == "q" else "QD"
        return f"{src}t[{key[1]}]" if major else f"{src}[..., {key[1]}]"
    if kind in ("gq", "gqd"):  # a gather of columns, with a zero column for the ground
        return f"{'Q' if kind == 'gq' else 'QD'}x[..., {key[1]}]"
    if kind == "p":  # in the entry-major layout, with its axes reversed like Q's
        return f"P[{key[1]}]{'.T' if major else ''}"
    if kind == "t":
        return f"T{'.T' if major else ''}"
    raise ValueError(f"unknown variable {key!r}")


#: the numpy functions the generated code calls, by the names it calls them
CALLED = sorted(set(_CALLS.values()))


def assignments(graph: Graph, outputs: Sequence[Node], read: Callable[[tuple], str],
                major: bool = False, prefix: str = "", functions: str = "F",
                given: dict[int, str] | None = None) -> tuple[list[str], dict[int, str]]:
    """Assignments for every operation node the outputs need, in topological order, and the
    name of each node (``prefix`` before every name, to join the code of two graphs);
    ``read(key)`` is the expression that reads a variable, ``functions`` the name of the
    table of function arguments that calls index, ``given`` the expressions that read nodes
    the caller has computed (by node id: they are read, not computed). Numpy's
    functions are called by their names in :data:`CALLED` (and constants may be ``nan``,
    ``inf``): the namespace the code runs in provides them. (Also the compiled backend's.)"""
    names: dict[int, str] = {}
    lines: list[str] = []
    given = given or {}
    for n in graph.subgraph(outputs):
        if n.op == "const":
            names[n.id] = _const(n.value)
            continue
        if n.id in given:
            name = f"{prefix}n{n.id}"
            lines.append(f"{name} = {given[n.id]}")
        elif n.op == "var":
            name = f"{prefix}v_" + "_".join(map(str, n.value))
            lines.append(f"{name} = {read(n.value)}")
        else:
            a = [names[x.id] for x in n.args]
            if n.op in _INFIX:
                expr = f"{a[0]} {_INFIX[n.op]} {a[1]}"
            elif n.op == "neg":
                expr = f"-{a[0]}"
            elif n.op == "select":  # some members of a group value (by an index array)
                expr = f"{a[0]}[..., {n.value}]"
            elif n.op == "call":
                index, order = n.value
                # a function sees its argument with the batch axes first, as its params
                expr = (f"_T({functions}[{index}][{order}](_T({a[0]})))" if major
                        else f"{functions}[{index}][{order}]({a[0]})")
            else:
                expr = f"{_CALLS[n.op]}({', '.join(a)})"
            name = f"{prefix}n{n.id}"
            lines.append(f"{name} = {expr}")
        names[n.id] = name
    return lines, names


@dataclass(frozen=True)
class Kernel:
    """A compiled evaluation: ``fn(Q, QD, T, P, F)`` returns an array of shape
    ``batch + (len(outputs),)``; ``source`` is its text (for caching and for numba)."""

    fn: Callable
    source: str
    n_out: int
    key: str = field(default="")

    def __call__(self, Q, QD=None, T=None, P=(), F=()):
        return self.fn(Q, QD, T, P, F)


class LazyKernel:
    """A :class:`Kernel` of ``outputs`` of ``graph`` generated and compiled where it is first
    used (called, or its ``fn``, ``source``, ``n_out`` read): a model carries kernels that
    only some runs need (the loads, the mass matrix and the potential as numpy arrays, which
    the augmented Lagrangian's one-state kernels replace), and generating and compiling one
    costs about 0.1 s for a chain of 300 links."""

    def __init__(self, graph: Graph, outputs: Sequence[Node], name: str) -> None:
        self._args: tuple | None = (graph, tuple(outputs), name)
        self._kernel: Kernel | None = None

    @property
    def compiled(self) -> Kernel:
        """The kernel, generated and compiled at the first use."""
        if self._kernel is None:
            graph, outputs, name = self._args  # type: ignore[misc]
            self._kernel, self._args = kernel(graph, outputs, name), None
        return self._kernel

    fn = property(lambda self: self.compiled.fn)
    source = property(lambda self: self.compiled.source)
    n_out = property(lambda self: self.compiled.n_out)
    key = property(lambda self: self.compiled.key)

    def __call__(self, Q, QD=None, T=None, P=(), F=()):
        return self.compiled.fn(Q, QD, T, P, F)


def kernel(graph: Graph, outputs: Sequence[Node], name: str = "kernel",
           positions: Sequence[int | str] | None = None, width: int | None = None,
           constants: dict[str, np.ndarray] | None = None) -> Kernel:
    """Compile ``outputs`` into one numpy function (see the module documentation).

    By default output k is column k of the result. With ``positions``, output k goes to
    ``out[..., positions[k]]``, an int or the name of an index array of ``constants``
    (a group of constraints evaluated as one array), and the result has ``width`` columns.
    Gather variables ``("gq", NAME)`` read ``Q[..., NAME]`` with a zero column appended
    (index n: the ground's coordinates)."""
    major = positions is None
    lines, names = assignments(graph, outputs, lambda key: _read(key, major), major)
    used = {n.value[0] for n in graph.subgraph(outputs) if n.op == "var"}
    body = [f"def {name}(Q, QD, T, P, F):"]
    for kind, src in (("q", "Q"), ("qd", "QD")):
        if kind in used and positions is None:  # row k: entry-major views (axes reversed)
            body.append(f"    {src}t = {src}.T")
    for kind, src in (("gq", "Q"), ("gqd", "QD")):
        if kind in used:
            body.append(f"    {src}x = concatenate(({src}, zeros({src}.shape[:-1] + (1,))), "
                        "axis=-1)")
    width = len(outputs) if width is None else width
    if positions is None:
        # entry-major: output k is the contiguous row out[k] (what the generated LU reads),
        # handed back as the transposed view, batch axes first
        body.append(f"    out = empty(({width},) + Q.shape[-2::-1])")
        writes = [(f"out[{k}]", n) for k, n in enumerate(outputs)]
        ending = "    return out.T"
    else:
        body.append(f"    out = empty(Q.shape[:-1] + ({width},))")
        writes = [(f"out[..., {k}]", n) for k, n in zip(positions, outputs)]
        ending = "    return out"
    body += [f"    {ln}" for ln in _written_early(lines, names, writes)]
    body.append(ending)
    source = "\n".join(body) + "\n"
    namespace = dict(_NAMESPACE, empty=np.empty, zeros=np.zeros, concatenate=np.concatenate,
                     nan=np.nan, inf=np.inf, _T=lambda a: np.asarray(a).T)
    namespace.update(constants or {})
    code = compile(source, f"<mechdsl generated {name}>", "exec")
    exec(code, namespace)  # noqa: S102 - our own generated source, from the model's graph
    return Kernel(namespace[name], source, width,
                  hashlib.sha256(source.encode()).hexdigest()[:16])


_VALUE = re.compile(r"\b(n\d+|v_\w+)\b")


def _written_early(lines: list[str], names: dict[int, str],
                   writes: list[tuple[str, Node]]) -> list[str]:
    """The assignments ``lines`` with each output written as soon as its value is computed
    (``target = name``; constants last) and each computed value let go after its last use:
    a batch's temporaries then take the memory of a few rows, not of all of them (every
    page a process touches anew is a fault)."""
    defined = {ln.split(" = ", 1)[0]: i for i, ln in enumerate(lines)}
    after: dict[int, list[str]] = {}
    consts = []
    for target, node in writes:
        name = names[node.id]
        if name in defined:
            after.setdefault(defined[name], []).append(f"{target} = {name}")
        else:  # a constant, or a variable read straight into the output
            consts.append(f"{target} = {name}")
    ordered = []
    for i, ln in enumerate(lines):
        ordered.append(ln)
        ordered += after.get(i, [])
    ordered += consts
    last: dict[str, int] = {}
    for i, ln in enumerate(ordered):
        for name in _VALUE.findall(ln):
            last[name] = i
    out = []
    for i, ln in enumerate(ordered):
        out.append(ln)
        dead = [name for name in dict.fromkeys(_VALUE.findall(ln))
                if last[name] == i and name.startswith("n")]
        if dead:
            out.append(f"del {', '.join(dead)}")
    return out


def _read_scalar(key: tuple) -> str:
    kind = key[0]
    if kind in ("q", "qd", "p"):
        return f"{kind}[{key[1]}]"
    if kind == "t":
        return "t"
    raise ValueError(f"a scalar kernel cannot read {key!r}")


def _sign(x: float) -> float:
    return float(bool(x > 0)) - float(bool(x < 0))


#: the scalar kernels' functions: the math module's, on Python floats (a numpy call on a
#: 0-d array costs about a microsecond, a math call on a float a few dozen nanoseconds)
_SCALAR_NAMESPACE = dict(
    sin=math.sin, cos=math.cos, tan=math.tan, sqrt=math.sqrt, exp=math.exp, log=math.log,
    arctan=math.atan, arctan2=math.atan2, absolute=abs, sign=_sign,
    remainder=lambda a, b: a % b, nan=math.nan, inf=math.inf)


@dataclass(frozen=True)
class ScalarKernel:
    """The outputs of a graph for ONE state, on Python floats: ``fn(q, qd, t, p, F)`` with
    ``q``, ``qd``, ``p`` sequences of floats (lists index fastest), ``t`` a float and ``F``
    the functions as ``F[i][order](x) -> float``; returns a list of floats. It raises
    ValueError, ZeroDivisionError or OverflowError where numpy would give nan or inf (the
    square root of a negative number): the caller then evaluates the array kernel. For the
    integrators of the forward dynamics, which evaluate one state at a time."""

    fn: Callable
    source: str

    def __call__(self, q, qd=(), t=0.0, p=(), F=()):
        return self.fn(q, qd, t, p, F)


def scalar_kernel(graph: Graph, outputs: Sequence[Node], name: str = "scalar") -> ScalarKernel:
    """Compile ``outputs`` (variables q, qd, p, t; not the gathered layout) into one
    function of floats (see :class:`ScalarKernel`)."""
    return joint_scalar_kernel([(graph, outputs)], name, single=True)


def joint_scalar_kernel(parts: Sequence[tuple[Graph, Sequence[Node]]],
                        name: str = "scalar", single: bool = False,
                        order: Sequence[int] | None = None) -> ScalarKernel:
    """One function of floats for the outputs of several graphs, in order:
    ``fn(q, qd, t, p, F)`` with ``p`` and ``F`` sequences of each graph's parameters and
    functions (``p[i][j]``, ``F[i][k]``; with ``single``, one graph's, ``p[j]``); one list
    of every output, or of the outputs at the positions ``order`` lists (in the order the
    caller stores them, an output as often as it is stored)."""
    body = [f"def {name}(q, qd, t, p, F):"]
    out = []
    #: across the graphs, a value computed twice (the cosine of a body's angle, read by
    #: the constraints' graph and the masses') is computed once: ``seen`` maps each
    #: right-hand side, written with the earlier names, to its name
    seen: dict[str, str] = {}
    alias: dict[str, str] = {}

    def earlier(match: re.Match) -> str:
        return alias.get(match.group(0), match.group(0))

    for i, (graph, outputs) in enumerate(parts):
        body.append(f"    p{i}, F{i} = p, F" if single else f"    p{i}, F{i} = p[{i}], F[{i}]")

        def read(key: tuple, i: int = i) -> str:
            text = _read_scalar(key)
            return f"p{i}{text[1:]}" if key[0] == "p" else text

        lines, names = assignments(graph, outputs, read, prefix=f"g{i}", functions=f"F{i}")
        for line in lines:
            lhs, rhs = line.split(" = ", 1)
            rhs = _NAME.sub(earlier, rhs)
            if rhs in seen:
                alias[lhs] = seen[rhs]
                continue
            seen[rhs] = lhs
            body.append(f"    {lhs} = {rhs}")
        out += [alias.get(v, v) for v in (names[n.id] for n in outputs)]
    if order is not None:
        out = [out[k] for k in order]
    body.append(f"    return [{', '.join(out)}]")
    source = "\n".join(body) + "\n"
    namespace = dict(_SCALAR_NAMESPACE)
    exec(compile(source, f"<mechdsl generated {name}>", "exec"), namespace)  # noqa: S102
    return ScalarKernel(namespace[name], source)


#: a name :func:`joint_scalar_kernel` gives a value (its prefix, g0, g1, ..., then the rest)
_NAME = re.compile(r"\bg\d+\w*")


def first_floats(arrays: Sequence) -> list[float]:
    """The first variant's value of each param array (``P[j]``, shaped (V, ...)) as a float:
    what the kernels on floats take for their params."""
    return [float(np.asarray(x).reshape(-1)[0]) for x in arrays]


def scalar_functions(functions: Sequence) -> tuple:
    """The function arguments ``(f, f', f'')`` of a kernel as functions of one float."""

    def one(f: Callable) -> Callable:
        # (an expression function evaluates on (variants, instants) arrays, its params
        # broadcasting as (variants, 1): one variant, one instant)
        return lambda x: float(np.asarray(f(np.full((1, 1), x))).reshape(-1)[0])

    out = []
    for triple in functions:
        direct = getattr(triple[0], "scalar", None)
        fast = [direct(k) for k in range(3)] if direct is not None else [None] * 3
        out.append(tuple(f if f is not None else one(g) for f, g in zip(fast, triple)))
    return tuple(out)
