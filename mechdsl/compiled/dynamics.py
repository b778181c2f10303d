"""Mass and loads of a compiled mechanism: what the equations of motion add to Phi.

Haug's equations of motion in Cartesian coordinates (1989, ch. 6), with the body frame at an
arbitrary point of the body and its centre of mass at s'_c in that frame:

    M(q) qdd + Phi_q^T lambda = Q(q, qd, t)

Per body, with a = A s'_c (the centre of mass from the frame origin, global axes), mass m and
moment of inertia J about the centre of mass::

    M_i = [[ m,     0,    -m a_y        ],
           [ 0,     m,     m a_x        ],
           [-m a_y, m a_x, J + m |s'_c|^2]]

and Q_i the loads of the force elements (:mod:`mechdsl.plugins.force`), gravity m g at the
centre of mass (moment a x m g), and the quadratic velocity force m a phid^2 on the
translation (the centripetal term of a frame that is not at the centre of mass; it vanishes
when s'_c = 0, where M_i = diag(m, m, J)).

Everything is traced into one expression graph and compiled (:mod:`mechdsl.symbolic`) like
the constraints: the kernels return Q (V, b, n), the entries of M (V, b, 5 per body) and
the potential energy V(q) (gravity and the elements that write one).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Any, Callable, NamedTuple

import numpy as np

from ..plugins.contract import Args
from ..plugins.derived import body_of
from ..plugins.geometry import Body, Rate, Vec
from ..symbolic import Graph, GraphError, Kernel, kernel
from ..symbolic.codegen import LazyKernel
from .fused import ReplayGraph, _args, _Params, replayed


class ForceError(ValueError):
    """A force type's loads could not be traced (the message names the type and why)."""


@dataclass(frozen=True)
class ForceElement:
    """One ``force`` statement: its name, type, where, and the bodies it attaches."""

    name: str
    type_name: str
    span: object
    bodies: tuple[str, ...]


@dataclass(frozen=True)
class LoadJacobian:
    """dQ/dq and dQ/dqd of a mechanism's loads, derived exactly from the traced graph:
    ``kernel`` returns their non-zero entries (V, b, nnz), entry k at row ``rows[k]`` of Q
    and column ``cols[k]`` of q (``wrt[k]`` 0) or of qd (``wrt[k]`` 1); entries that are
    zero for every state (gravity's, a torque's) are not stored."""

    kernel: Kernel | None
    rows: np.ndarray
    cols: np.ndarray
    wrt: np.ndarray
    #: the graph's nodes of the entries, in order (for a kernel of floats: one state at a
    #: time, as the implicit steppers evaluate them)
    nodes: tuple = ()


@dataclass(frozen=True)
class Dynamics:
    """The mass and loads of a mechanism (see the module documentation)."""

    #: (V, nb): mass, moment of inertia about the centre of mass; (V, nb, 2) the centre
    #: of mass in the body frame; (V, 2) gravity
    mass: np.ndarray
    inertia: np.ndarray
    centroid: np.ndarray
    gravity: np.ndarray
    #: the non-zero entries of M: entry k is (rows[k], cols[k]) (both triangles)
    rows: np.ndarray
    cols: np.ndarray
    params: tuple[np.ndarray, ...]
    functions: tuple
    forces: tuple[ForceElement, ...]
    #: (V, n) the initial velocities given by ``v0`` statements; ``given`` (n,) where
    v0: np.ndarray
    v0_given: np.ndarray
    n: int
    #: the graph (for one-state (scalar) kernels), and the bodies' terms traced into it
    #: where first needed (:class:`BodyTrace`: Q's and M's nodes, the loads, the mass
    #: matrix and the potential as kernels)
    graph: Graph | None = None
    bodies: "BodyTrace | None" = None
    #: Q's nodes with the force elements' loads only (gravity's and the bodies' inertia
    #: terms not added): the bodies' part is then evaluated for all bodies at once
    #: (:mod:`mechdsl.solve.body_terms`)
    force_load_nodes: tuple = ()
    #: the force groups traced (their structure: what :func:`rebind` may serve)
    force_groups: tuple = ()
    #: the values' leaves in the order traced: the constant folded, or None for P[j]
    leaves: tuple = ()
    #: the power the force elements dissipate, P(q, qd, t) (their ``dissipation``)
    dissipation: Kernel | LazyKernel | None = None

    # the bodies' terms (traced on first use: a run on the augmented Lagrangian of a large
    # model evaluates them as arrays, solve/body_terms.py, and never needs them traced)
    load_nodes = property(lambda self: self.bodies.terms().load_nodes,
                          doc="Q's nodes (n,): the force elements' loads and the bodies'")
    mass_nodes = property(lambda self: self.bodies.terms().mass_nodes,
                          doc="the nodes of M's entries, in ``rows/cols``' order")
    loads = property(lambda self: self.bodies.terms().loads, doc="Q as a kernel")
    mass_entries = property(lambda self: self.bodies.terms().mass_entries,
                            doc="M's entries as a kernel")
    potential = property(lambda self: self.bodies.terms().potential,
                         doc="the potential V(q) as a kernel")

    def variant(self, v: int) -> "Dynamics":
        """The same for sweep variant ``v`` alone."""
        fns = tuple((g, g.d1, g.d2) for g in (f[0].variant(v) for f in self.functions))
        out = replace(self, params=tuple(p[v : v + 1] for p in self.params), functions=fns,
                      mass=self.mass[v : v + 1], inertia=self.inertia[v : v + 1],
                      centroid=self.centroid[v : v + 1], gravity=self.gravity[v : v + 1],
                      v0=self.v0[v : v + 1])
        # the code generated on the graph takes the values as inputs: every variant's
        # (and every run's of a sweep) is the model's, made once
        out.__dict__["_floats"] = self._floats
        return out

    @functools.cached_property
    def load_jacobian(self) -> LoadJacobian:
        """The exact derivatives of Q (:class:`LoadJacobian`), by reverse accumulation over
        each load's graph (:meth:`mechdsl.symbolic.Graph.gradient`), compiled once per
        model on first use (the explicit integrators never need them)."""
        g = self.graph
        wrt = [g.var("q", k) for k in range(self.n)] + [g.var("qd", k) for k in range(self.n)]
        position = {w.id: k for k, w in enumerate(wrt)}
        nodes, rows, cols, which = [], [], [], []
        for i, root in enumerate(self.load_nodes):
            if root.op == "const":
                continue
            for k, d in g.sparse_gradient(root, position):
                nodes.append(d)
                rows.append(i)
                cols.append(k % self.n)
                which.append(k // self.n)
        return LoadJacobian(kernel(g, nodes, "load_jacobian") if nodes else None,
                            np.array(rows, dtype=np.intp), np.array(cols, dtype=np.intp),
                            np.array(which, dtype=np.intp), tuple(nodes))

    @functools.cached_property
    def _floats(self) -> dict:
        # the kernels of floats generated for this model, by name and nodes (:meth:`floats`),
        # and what :meth:`memo` keeps
        return {}

    def memo(self, key: tuple, make: Callable[[], Any]) -> Any:
        """What ``make()`` builds for ``key`` from this model's graph (a solver's traced
        terms, e.g. :func:`mechdsl.solve.reduced_terms.traced`), built once per model: the
        next run on it (each ``simulate()`` of a mechanism) reuses it."""
        if key not in self._floats:
            self._floats[key] = make()
        return self._floats[key]

    def latest(self, kind: str, key: tuple, make: Callable[[], Any]) -> Any:
        """:meth:`memo` that keeps one entry of each ``kind``, the latest: for what depends
        on a run's state (a solver's choice at the start of a run), which the next
        ``simulate()`` from the same start reuses, and which must not pile up over the
        runs of a study."""
        slot = ("latest", kind)
        kept = self._floats.get(slot)
        if kept is not None and kept[0] == key:
            return kept[1]
        value = make()
        self._floats[slot] = (key, value)
        return value

    def floats(self, nodes, name: str):
        """The function of floats ``fn(q, qd, t, p, F)`` that gives ``nodes`` of this
        model's graph (:func:`mechdsl.symbolic.codegen.scalar_kernel`), generated once
        per model: every run on the model (each ``simulate()`` of a mechanism) reuses it."""
        from ..symbolic.codegen import scalar_kernel

        key = (name, tuple(nd.id for nd in nodes))
        fn = self._floats.get(key)
        if fn is None:
            fn = self._floats[key] = scalar_kernel(self.graph, list(nodes), name).fn
        return fn

    def load_derivative_values(self, q: np.ndarray, qd: np.ndarray, t: np.ndarray
                               ) -> np.ndarray:
        """The entries of dQ/dq and dQ/dqd in :attr:`load_jacobian`'s order, (V, b, nnz)."""
        lj = self.load_jacobian
        if lj.kernel is None:
            return np.zeros(q.shape[:-1] + (0,))
        with np.errstate(all="ignore"):
            return lj.kernel(q, qd, np.broadcast_to(t, q.shape[:-1]), self.params,
                             self.functions)

    def generalised_forces(self, q: np.ndarray, qd: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Q(q, qd, t), shape (V, b, n)."""
        with np.errstate(all="ignore"):
            return self.loads(q, qd, np.broadcast_to(t, q.shape[:-1]), self.params,
                              self.functions)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q), shape (V, b, n, n)."""
        vals = self.mass_entries(q, None, None, self.params, self.functions)
        out = np.zeros(q.shape[:-1] + (self.n * self.n,))
        out[..., self.rows * self.n + self.cols] = vals
        return out.reshape(q.shape[:-1] + (self.n, self.n))

    def kinetic_energy(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """T = 1/2 qd^T M(q) qd, shape (V, b)."""
        return 0.5 * np.einsum("...i,...ij,...j->...", qd, self.mass_matrix(q), qd)

    def dissipated_power(self, q: np.ndarray, qd: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The power the force elements dissipate (their ``dissipation``), shape (V, b)."""
        if self.dissipation is None:
            return np.zeros(q.shape[:-1])
        with np.errstate(all="ignore"):
            out = self.dissipation(q, qd, np.broadcast_to(t, q.shape[:-1]), self.params,
                                   self.functions)
        return np.broadcast_to(out[..., 0], q.shape[:-1]).copy()

    def potential_energy(self, q: np.ndarray) -> np.ndarray:
        """V(q): gravity's and the elements' that write one, shape (V, b)."""
        with np.errstate(all="ignore"):
            out = self.potential(q, None, None, self.params, self.functions)
        return np.broadcast_to(out[..., 0], q.shape[:-1])


class TracedBodies(NamedTuple):
    """The bodies' terms traced: Q's and M's nodes, and the kernels of Q, M and V."""

    load_nodes: tuple
    mass_nodes: tuple
    loads: LazyKernel
    mass_entries: LazyKernel
    potential: LazyKernel


class BodyTrace:
    """The bodies' terms of Q, M and the potential (Haug 1989, sec. 6.2, the frame off the
    centre of mass, a = A(phi) s'),

        Q_i += (m g_x + m a_x phid^2, m g_y + m a_y phid^2, a x m g),
        M_i = [[m, 0, -m a_y], [0, m, m a_x], [-m a_y, m a_x, J + m |s'|^2]],
        V -= m g . (r + a),

    traced into the model's graph after the force elements' where first needed (the
    tracing is about 30 ms of the 300-link chain's compilation, which a run of the
    augmented Lagrangian, evaluating them as arrays, does not need). Once traced, they
    are shared by every copy of the Dynamics (variants, rebound values)."""

    def __init__(self, graph: Graph, bodies: list, rates: list, leaves: list, loads: list,
                 potential) -> None:
        import threading

        self._args: tuple | None = (graph, bodies, rates, leaves, list(loads), potential)
        self._terms: TracedBodies | None = None
        self._lock = threading.Lock()  # (the graph grows: one thread traces)

    def terms(self) -> TracedBodies:
        """The terms, traced at the first call."""
        with self._lock:
            if self._terms is None:
                self._terms, self._args = _trace_bodies(*self._args), None
            return self._terms


def _trace_bodies(graph: Graph, bodies: list, rates: list, leaves: list, Q: list,
                  potential) -> TracedBodies:
    """:class:`BodyTrace`'s terms, added to the force elements' ``Q`` and ``potential``."""

    def add(k: int, value) -> None:
        Q[k] = graph.lift(value) if Q[k] is graph.zero else graph.lift(Q[k] + value)

    entries: list = []
    for i, (body, rate) in enumerate(zip(bodies, rates)):
        m, J, s, gx, gy = leaves[i]
        a = body.rotate(s)
        add(3 * i, m * gx + m * a.x * rate.phi * rate.phi)
        add(3 * i + 1, m * gy + m * a.y * rate.phi * rate.phi)
        add(3 * i + 2, a.cross(Vec(m * gx, m * gy)))
        potential = graph.lift(potential - m * (gx * (body.x + a.x) + gy * (body.y + a.y)))
        # (in the order of build's rows and cols)
        entries += [graph.lift(v) for v in (m, m, -m * a.y, -m * a.y, m * a.x, m * a.x,
                                            J + m * (s.x * s.x + s.y * s.y))]
    return TracedBodies(tuple(Q), tuple(entries), LazyKernel(graph, Q, "loads"),
                        LazyKernel(graph, entries, "mass"),
                        LazyKernel(graph, [potential], "potential"))


def _inputs(graph: Graph, params: _Params, n_bodies: int, mass: np.ndarray,
            inertia: np.ndarray, centroid: np.ndarray, gravity: np.ndarray,
            force_groups: list) -> tuple[list, list]:
    """The leaves of the values, in the order the code reads them: each force element's
    arguments (per group, per member), then per body (m, J, centroid s', gravity g)."""
    forces = [[Args(_args(graph, params, g, j)) for j in range(len(g.members))]
              for g in force_groups]
    bodies = [(params.leaf(mass[:, i]), params.leaf(inertia[:, i]),
               Vec(params.leaf(centroid[:, i, 0]), params.leaf(centroid[:, i, 1])),
               params.leaf(gravity[:, 0]), params.leaf(gravity[:, 1]))
              for i in range(n_bodies)]
    return forces, bodies


def rebind(template: Dynamics, n_bodies: int, mass: np.ndarray, inertia: np.ndarray,
           centroid: np.ndarray, gravity: np.ndarray, force_groups: list,
           elements: tuple[ForceElement, ...], v0: np.ndarray, v0_given: np.ndarray
           ) -> Dynamics | None:
    """``template``'s code (traced by :func:`build` for force groups of the same structure)
    with these values; None where they do not fit it (as
    :func:`mechdsl.compiled.fused.rebind`)."""
    graph = ReplayGraph()
    params = _Params(graph, replay=template.leaves)
    _inputs(graph, params, n_bodies, mass, inertia, centroid, gravity, force_groups)
    if not replayed(template.leaves, template.params, template.functions, params, graph):
        return None
    again = replace(template, mass=mass, inertia=inertia, centroid=centroid, gravity=gravity,
                    params=tuple(params.arrays), functions=tuple(graph.functions),
                    forces=elements, v0=v0, v0_given=v0_given, force_groups=tuple(force_groups))
    if "load_jacobian" in template.__dict__:  # its code: no value in it
        again.__dict__["load_jacobian"] = template.__dict__["load_jacobian"]
    return again


def build(n_bodies: int, mass: np.ndarray, inertia: np.ndarray, centroid: np.ndarray,
          gravity: np.ndarray, force_groups: list, elements: tuple[ForceElement, ...],
          v0: np.ndarray, v0_given: np.ndarray, fold: bool = True) -> Dynamics:
    """Trace the loads, the mass matrix and the potential of a mechanism of ``n_bodies``
    moving bodies; ``force_groups``: :class:`~mechdsl.compiled.system.Group` per force
    type (its ``ctype`` a :class:`~mechdsl.plugins.force.ForceType`); ``fold`` as for
    :func:`mechdsl.compiled.fused.fuse`."""
    n = 3 * n_bodies
    graph = Graph()
    params = _Params(graph, fold)
    force_args, body_leaves = _inputs(graph, params, n_bodies, mass, inertia, centroid,
                                      gravity, force_groups)
    t = graph.var("t")
    zero = graph.zero
    ground = Body(zero, zero, zero, graph.one, zero)
    bodies = [body_of(graph, 3 * i) for i in range(n_bodies)] + [ground]
    rates = [Rate(graph.var("qd", 3 * i), graph.var("qd", 3 * i + 1), graph.var("qd", 3 * i + 2))
             for i in range(n_bodies)] + [Rate(zero, zero, zero)]
    Q = [zero] * n
    potential = dissipation = zero

    def add(k: int, value) -> None:
        Q[k] = graph.lift(value) if Q[k] is zero else graph.lift(Q[k] + value)

    for g, group_args in zip(force_groups, force_args):
        ftype = g.ctype
        for j in range(len(g.members)):
            slots = [int(b) for b in g.slots[j]]
            args = group_args[j]
            try:
                loads = list(ftype.loads(tuple(bodies[b] for b in slots),
                                         tuple(rates[b] for b in slots), args, t))
                if len(loads) != len(slots):
                    raise ForceError(f"the force type '{ftype.name}': loads() gave "
                                     f"{len(loads)} triples for {len(slots)} bodies")
                for b, load in zip(slots, loads):
                    load = list(load)
                    if len(load) != 3:
                        raise ForceError(f"the force type '{ftype.name}': a load has "
                                         f"{len(load)} components, not 3 (F_x, F_y, n)")
                    if b == n_bodies:
                        continue  # a load on the ground moves nothing
                    for c in range(3):
                        add(3 * b + c, load[c])
                if ftype.supplies("energy"):
                    potential = graph.lift(potential + ftype.energy(
                        tuple(bodies[b] for b in slots), args))
                if ftype.supplies("dissipation"):
                    dissipation = graph.lift(dissipation + ftype.dissipation(
                        tuple(bodies[b] for b in slots), tuple(rates[b] for b in slots),
                        args, t))
            except GraphError as err:
                raise ForceError(f"the force type '{ftype.name}': {err}") from None
    force_loads = tuple(Q)
    rows, cols = [], []
    for i in range(n_bodies):  # M's pattern: a body's block, entries as BodyTrace writes them
        k = 3 * i
        rows += [k, k + 1, k, k + 2, k + 1, k + 2, k + 2]
        cols += [k, k + 1, k + 2, k, k + 2, k + 1, k + 2]
    return Dynamics(
        mass=mass, inertia=inertia, centroid=centroid, gravity=gravity,
        dissipation=LazyKernel(graph, [dissipation], "dissipation"),
        rows=np.array(rows, dtype=np.intp), cols=np.array(cols, dtype=np.intp),
        params=tuple(params.arrays), functions=tuple(graph.functions), forces=elements,
        v0=v0, v0_given=v0_given, n=n, graph=graph,
        bodies=BodyTrace(graph, bodies[:n_bodies], rates[:n_bodies], body_leaves, Q, potential),
        force_load_nodes=force_loads, force_groups=tuple(force_groups),
        leaves=tuple(params.leaves))
