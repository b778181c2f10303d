"""Relative coordinates for the implicit integrator: each body's frame given in its parent's.

Why. A stiff force between two jointed bodies (a spring along a slider, a rotary spring at a
pin, a bushing) acts along a direction fixed in one body's frame. In the absolute
coordinates q = (x_i, y_i, phi_i) of Haug's formulation that direction turns with the bodies:
the Radau IIA stages of one step see the spring's stiffness k d d^T along directions d apart
by omega h, no common iteration matrix contracts (the rate is about omega h sqrt(k / m)),
and each stage needs its own Jacobian (:mod:`mechdsl.solve.radau_stages`). In relative
coordinates the same direction is one coordinate's (the slider's travel, the pin's relative
angle): one Jacobian serves many steps, as it does on the minimal ODE (the stiff pendulum at
k = 1e8, rtol 1e-6: 134 steps with 393 stage Jacobians in absolute coordinates, 44 steps on
one Jacobian in relative ones; docs/dynamics.md).

The coordinates. Every moving body i has a parent p(i): the ground or a body it is jointed
to (:func:`forest`: a spanning forest of the joints and drives, a joint that a force element
spans preferred). Its coordinates z_i = (s_i, rho_i) are the position of its reference
point u_i (body axes; its frame's origin unless given: :func:`mechdsl.solve.reduced.
pin_points` takes a pin's point) and its angle in the parent's frame,

    r_i = r_p + A(phi_p) s_i - A(phi_i) u_i,     phi_i = phi_p + rho_i,

(the parent's terms absent where it is the ground). This is a change of variables q = g(z),
one to one, whatever the forest and the points: every constraint is kept, the joints along
the forest's edges included (theirs become simple: a pin at the reference point fixes s_i),
and the loops' closures too. With G = dg/dz (lower triangular by bodies in the forest's
order),

    qd = G zd,    qdd = G zdd + c,
    c_i = c_p - phi_p'^2 e_i + 2 phi_p' B(phi_p) s_i' + phi_i'^2 A(phi_i) u_i

(e_i = A(phi_p) s_i, B = dA/dphi, c_p = 0 for the ground), Haug's equations of motion
become, multiplying the force balance by G^T,

    G^T M G zdd + (Phi_q G)^T lambda = G^T (Q - M c),    Phi(g(z), t) = 0,
    Phi_q G zdd = gamma - Phi_q c,

with the same multipliers lambda (the reactions are those of the absolute coordinates).

The iteration matrix. The Newton iteration of the implicit stages needs d/dz and d/dzd of
the loads G^T (Q - M c) - (Phi_q G)^T lambda; this module gives G^T (dQ/dq) G, G^T (dQ/dqd)
G and the constraints' curvature G^T (Phi_q^T lambda)_q G: the loads' exact derivatives
(from the traced loads, as in absolute coordinates), which hold every stiff term. The terms
from the derivatives of G and c themselves are left out: they scale with the loads and the
velocities squared, not with a stiffness, so that the simplified Newton iteration contracts
without them (it converges to the same stages; only its rate depends on the matrix), and the
error estimate is of the converged stages.

The integrator in these coordinates is :class:`mechdsl.solve.radau.RadauStepper`, unchanged;
:class:`Radau` (the registry's ``radau``) runs it on :class:`Relative` where the model has at
most ``SolverOptions.relative_max`` coordinates (G and G^T M G are dense) and states every
step's end, dense output and restart in absolute coordinates, so that the driver, the
projections at the outputs and the results see the model's own coordinates.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from .radau import RadauStepper, floored
from .stepper import Equations, Stepper

__all__ = ["Radau", "Relative", "forest", "spanned_joints"]


def forest(system, forces: tuple = ()) -> np.ndarray:
    """The parent of each moving body (its index, -1 for the ground): a spanning forest of
    the graph whose edges are the joints and drives between two bodies (a body that no
    joint ties to another hangs from the ground), with as many edges that a force element
    also spans as any spanning forest has (each such force then acts along relative
    coordinates). Prim's algorithm from the ground with the weights 0 for a spanned edge
    and 1 for another: the next body placed is reached by a spanned edge wherever one
    leaves the bodies placed, else by the first edge found (breadth first, in the
    constraints' order). Any forest gives a valid change of coordinates; this one makes
    the joints' own coordinates relative ones."""
    from collections import deque

    names = {name: i for i, name in enumerate(system.body_names)}
    spanned = {e for e in (_ends(names, f) for f in forces) if len(e) == 2}
    touching: dict[int, list[tuple[int, int, bool]]] = {}
    for e in (_ends(names, c.bodies) for c in system.constraints):
        if len(e) == 2:
            for here, there in (e, e[::-1]):
                touching.setdefault(here, []).append((here, there, e in spanned))
    parent = np.full(len(names), -1)
    placed: set[int] = set()
    free: deque = deque()   # edges of weight 0 leaving the bodies placed
    other: deque = deque()  # of weight 1

    def place(body: int) -> None:
        placed.add(body)
        for here, there, zero in touching.get(body, ()):
            if there not in placed:
                (free if zero else other).append((here, there))

    # from the ground; then from the first body of each group the ground does not reach
    # (free bodies, bodies tied only to each other), which hangs from the ground itself
    for root in (-1, *range(len(names))):
        if root in placed:
            continue
        place(root)
        while free or other:
            here, there = (free or other).popleft()
            if there not in placed:
                parent[there] = here
                place(there)
    return parent


def _forces(equations: Equations) -> tuple:
    """The force elements of the equations' model (each with its ``name`` and the
    ``bodies`` it acts between)."""
    dynamics = getattr(getattr(equations, "kernels", None), "dynamics", None)
    return tuple(getattr(dynamics, "forces", ()))


def _ends(names: dict[str, int], bodies) -> tuple[int, ...]:
    """The bodies' indices in ``names``, sorted, once each; the ground (every name that is
    not a moving body's) as -1."""
    return tuple(sorted({names.get(b, -1) for b in bodies}))


def spanned_joints(system, forces: tuple, parent: np.ndarray | None = None) -> list[str]:
    """The names of the force elements (``name``, ``bodies``) that act between a body and
    its parent body in the forest ``parent`` (default :func:`forest` of these forces):
    forces along relative coordinates that absolute ones turn. (A force between a body
    and the ground, or between bodies that no joint ties, acts on coordinates that
    relative ones leave as they are.)"""
    if parent is None:
        parent = forest(system, tuple(f.bodies for f in forces))
    names = {name: i for i, name in enumerate(system.body_names)}
    edges = {tuple(sorted((i, int(p)))) for i, p in enumerate(parent) if p >= 0}
    return [f.name for f in forces if _ends(names, f.bodies) in edges]


def _listed(names: list[str]) -> str:
    """'force 'a'', 'forces 'a' and 'b'', 'forces 'a', 'b' and 2 more'."""
    quoted = [f"'{n}'" for n in names[:3]]
    more = len(names) - len(quoted)
    if more:
        quoted[-1:] = [quoted[-1], f"{more} more"]
    words = quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " and " + quoted[-1]
    return ("force " if len(names) == 1 else "forces ") + words


class Relative:
    """Haug's equations of motion of a mechanism (``base``, in absolute coordinates) in the
    relative coordinates z of the module docstring, on the forest ``parent``; the
    :class:`~mechdsl.solve.stepper.Equations` protocol's index-3 terms, dense.

    One evaluation of g, G and c serves the calls at one state (the stages ask for Phi,
    Phi_q, M and Q at the same z in turn)."""

    def __init__(self, base: Equations, parent: np.ndarray,
                 points: np.ndarray | None = None) -> None:
        self.base = base
        self.n, self.m = int(base.n), int(base.m)
        self.parent = [int(p) for p in parent]
        #: each body's reference point u_i (body axes; the frame's origin by default):
        #: s_i is that point's position in the parent's frame (:func:`pin_points`)
        self.points = [(0.0, 0.0)] * len(self.parent) if points is None else \
            [(float(u[0]), float(u[1])) for u in np.asarray(points, dtype=float)]
        # parents before children
        order: list[int] = []
        placed = {-1}
        while len(order) < len(self.parent):
            grown = [i for i, p in enumerate(self.parent) if i not in placed and p in placed]
            if not grown:
                raise ValueError("the parents do not form a forest")
            order += grown
            placed.update(grown)
        self.order = order
        self._key: bytes | None = None
        self._q = self._G = None
        self._rates_key: bytes | None = None
        self._qd = self._c = self._H = None

    # -- the map ----------------------------------------------------------------------------
    def _map(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q = g(z) and G = dg/dz (n, n), kept for the next call at the same z. Body by
        body, parents first: G's rows of body i are its parent's, plus the turn of e_i =
        A(phi_p) s_i with phi_p (dr_i/dphi_p = S e_i, S the rotation by a right angle), plus
        A(phi_p) on s_i and 1 on rho_i, less the turn of A(phi_i) u_i with phi_i (S A(phi_i)
        u_i times phi_i's row). (A loop over the bodies: 5 us for two bodies, 18 for five, 80 for
        twenty; numpy's array expressions cost 20 us at any of these sizes.)"""
        key = z.tobytes()
        if key == self._key:
            return self._q, self._G
        zl = z.tolist()
        q = zl[:]
        G = np.zeros((self.n, self.n))
        for i in self.order:
            p, k = self.parent[i], 3 * i
            ux, uy = self.points[i]
            if p < 0:
                G[k, k] = G[k + 1, k + 1] = G[k + 2, k + 2] = 1.0
                if ux or uy:  # r_i = s_i - A(psi_i) u_i, psi_i = rho_i
                    psi = zl[k + 2]
                    c, s = math.cos(psi), math.sin(psi)
                    ax, ay = c * ux - s * uy, s * ux + c * uy
                    q[k], q[k + 1] = zl[k] - ax, zl[k + 1] - ay
                    G[k, k + 2], G[k + 1, k + 2] = ay, -ax  # -B(psi) u = -perp(A u)
                continue
            j = 3 * p
            sx, sy = zl[k], zl[k + 1]
            phi = q[j + 2]
            c, s = math.cos(phi), math.sin(phi)
            dx, dy = c * sx - s * sy, s * sx + c * sy  # A(phi_p) s_i
            psi = phi + zl[k + 2]
            q[k + 2] = psi
            G[k:k + 3] = G[j:j + 3]
            G[k] -= dy * G[j + 2]
            G[k + 1] += dx * G[j + 2]
            G[k, k], G[k, k + 1], G[k + 1, k], G[k + 1, k + 1], G[k + 2, k + 2] = c, -s, s, c, 1.0
            if ux or uy:
                # the frame's origin is the point's position less A(psi_i) u_i
                cp, sp = math.cos(psi), math.sin(psi)
                ax, ay = cp * ux - sp * uy, sp * ux + cp * uy
                dx, dy = dx - ax, dy - ay
                G[k] += ay * G[k + 2]
                G[k + 1] -= ax * G[k + 2]
            q[k], q[k + 1] = q[j] + dx, q[j + 1] + dy
        out = np.array(q)
        self._key, self._q, self._G = key, out, G
        return out, G

    def _rates(self, z: np.ndarray, zd: np.ndarray, with_h: bool = False
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """qd = G zd, the convective term c = qdd at zdd = 0 and, ``with_h``, H = dG/dt =
        d(G zd)/dz (n, n; G's second derivatives are symmetric, and c = H zd), kept for the
        next call at the same state. Body by body, with w = phi_p' and d_i = r_i - r_p:

            qd_i = qd_p + w S d_i + A s_i',   c_i = c_p - w^2 d_i + 2 w S A s_i',

        and H's rows of body i are its parent's, plus (-w d_i + S A s_i') times phi_p's row
        of G, plus w S A on s_i (the Jacobian's velocity terms only need H)."""
        key = z.tobytes() + zd.tobytes()
        if key == self._rates_key and (self._H is not None or not with_h):
            return self._qd, self._c, self._H
        q, G = self._map(z)
        ql, zdl = q.tolist(), zd.tolist()
        qd, c_out = zdl[:], [0.0] * self.n
        H = np.zeros((self.n, self.n)) if with_h else None
        for i in self.order:
            p, k = self.parent[i], 3 * i
            ux, uy = self.points[i]
            # a = A(psi_i) u_i, psi_i' (the reference point's turn about the frame's origin)
            bx = by = 0.0
            if ux or uy:
                cp, sp = math.cos(ql[k + 2]), math.sin(ql[k + 2])
                bx, by = cp * ux - sp * uy, sp * ux + cp * uy
            if p < 0:
                if ux or uy:  # r_i = s_i - A(psi) u: qd_i = s_i' - psi' perp(a)
                    v = zdl[k + 2]
                    qd[k], qd[k + 1] = zdl[k] + v * by, zdl[k + 1] - v * bx
                    c_out[k], c_out[k + 1] = v * v * bx, v * v * by
                    if H is not None:
                        H[k] += v * bx * G[k + 2]
                        H[k + 1] += v * by * G[k + 2]
                continue
            j = 3 * p
            w = qd[j + 2]
            v = w + zdl[k + 2]  # psi_i'
            # e = A(phi_p) s_i, the reference point's offset from the parent's origin
            dx, dy = ql[k] - ql[j] + bx, ql[k + 1] - ql[j + 1] + by
            c, s = math.cos(ql[j + 2]), math.sin(ql[j + 2])
            ax, ay = c * zdl[k] - s * zdl[k + 1], s * zdl[k] + c * zdl[k + 1]  # A s_i'
            qd[k] = qd[j] - w * dy + ax + v * by
            qd[k + 1] = qd[j + 1] + w * dx + ay - v * bx
            qd[k + 2] = v
            c_out[k] = c_out[j] - w * w * dx - 2 * w * ay + v * v * bx
            c_out[k + 1] = c_out[j + 1] - w * w * dy + 2 * w * ax + v * v * by
            if H is not None:
                H[k:k + 2] = H[j:j + 2]
                H[k] += (-w * dx - ay) * G[j + 2]
                H[k + 1] += (-w * dy + ax) * G[j + 2]
                H[k, k] -= w * s
                H[k, k + 1] -= w * c
                H[k + 1, k] += w * c
                H[k + 1, k + 1] -= w * s
                if ux or uy:
                    H[k] += v * bx * G[k + 2]
                    H[k + 1] += v * by * G[k + 2]
        self._rates_key, self._qd, self._c, self._H = key, np.array(qd), np.array(c_out), H
        return self._qd, self._c, H

    def absolute(self, y: np.ndarray) -> np.ndarray:
        """(q, qd) of the state (z, zd)."""
        n = self.n
        q, _ = self._map(y[:n])
        return np.concatenate((q, self._rates(y[:n], y[n:2 * n])[0]))

    def relative(self, y: np.ndarray) -> np.ndarray:
        """(z, zd) of the state (q, qd): s_i = A(phi_p)^T (r_i + A(phi_i) u_i - r_p), rho_i =
        phi_i - phi_p,
        and zd from qd = G zd (G is invertible: block triangular, rotations on its
        diagonal)."""
        n = self.n
        q = np.asarray(y[:n], dtype=float).tolist()
        z = q[:]
        for i in self.order:
            p, k = self.parent[i], 3 * i
            ux, uy = self.points[i]
            cp, sp = math.cos(q[k + 2]), math.sin(q[k + 2])
            # the reference point r_i + A(phi_i) u_i
            px, py = q[k] + cp * ux - sp * uy, q[k + 1] + sp * ux + cp * uy
            if p < 0:
                z[k], z[k + 1] = px, py
                continue
            j = 3 * p
            c, s = math.cos(q[j + 2]), math.sin(q[j + 2])
            dx, dy = px - q[j], py - q[j + 1]
            z[k], z[k + 1], z[k + 2] = c * dx + s * dy, -s * dx + c * dy, q[k + 2] - q[j + 2]
        z = np.array(z)
        _, G = self._map(z)
        return np.concatenate((z, np.linalg.solve(G, y[n:2 * n])))

    def error_map(self, y: np.ndarray, y_new: np.ndarray, err: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A step's start, end and error estimate (z, zd parts) in absolute coordinates,
        where the tolerance is given: the error by G at the end, dq = G dz, dqd = G dzd
        (the term dG/dz dz zd, of the error's order times the speed, left out). In relative
        coordinates themselves a stiff joint's coordinate stays near zero and its tolerance,
        relative to it, near atol alone: the chain of 20 links on stiff springs took twice
        the steps of the absolute coordinates."""
        n = self.n
        start = self.absolute(y)
        end = self.absolute(y_new)  # (its G kept: the error's map)
        G = self._G
        out = np.concatenate((G @ err[:n], G @ err[n:2 * n], err[2 * n:]))
        return start, end, out

    def _state(self, z: np.ndarray, zd: np.ndarray, with_h: bool = False):
        """q, G, qd, H (``with_h``, else None) and c at (z, zd)."""
        q, G = self._map(z)
        qd, c, H = self._rates(z, zd, with_h)
        return q, G, qd, H, c

    @staticmethod
    def _dense(a) -> np.ndarray:
        return a.toarray() if hasattr(a, "toarray") else np.asarray(a, dtype=float)

    # -- the Equations protocol -------------------------------------------------------------
    def phi_jac(self, t: float, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Phi(g(z), t) and Phi_q G."""
        q, G = self._map(z)
        phi, jac = self.base.phi_jac(t, q)
        return phi, self._dense(jac) @ G

    def nu(self, t: float) -> np.ndarray:
        """nu (the same: Phi_q G zd = Phi_q qd)."""
        return self.base.nu(t)

    def gamma(self, t: float, z: np.ndarray, zd: np.ndarray) -> np.ndarray:
        """gamma - Phi_q c."""
        q, G, qd, _, c = self._state(z, zd)
        _, jac = self.base.phi_jac(t, q)
        return self.base.gamma(t, q, qd) - self._dense(jac) @ c

    def mass(self, z: np.ndarray) -> np.ndarray:
        """G^T M G."""
        q, G = self._map(z)
        return G.T @ self._dense(self.base.mass(q)) @ G

    def mass_loads(self, t: float, z: np.ndarray, zd: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """G^T M G and G^T (Q - M c), from one evaluation of the base's M and Q."""
        q, G, qd, _, c = self._state(z, zd)
        M, Q = self.base.mass_loads(t, q, qd)
        M = self._dense(M)
        return G.T @ M @ G, G.T @ (Q - M @ c)

    def loads(self, t: float, z: np.ndarray, zd: np.ndarray) -> np.ndarray:
        """G^T (Q - M c)."""
        return self.mass_loads(t, z, zd)[1]

    def load_derivatives(self, t: float, z: np.ndarray, zd: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
        """d/dz and d/dzd of G^T (Q - M c), the terms of the module docstring:
        G^T (Q_q G + Q_qd H) and G^T (Q_qd G - 2 M H) (qd = G zd depends on z through H,
        and c = H zd on zd through 2 H)."""
        q, G, qd, H, _ = self._state(z, zd, with_h=True)
        dq, dv = self.base.load_derivatives(t, q, qd)
        dv = self._dense(dv)
        M = self._dense(self.base.mass(q))
        return (G.T @ (self._dense(dq) @ G + dv @ H),
                G.T @ (dv @ G - 2.0 * (M @ H)))

    def constraint_curvature(self, t: float, z: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """G^T (Phi_q^T lambda)_q G (the base's exact curvature; zeros where it has none)."""
        curv = getattr(self.base, "constraint_curvature", None)
        if curv is None:
            return np.zeros((self.n, self.n))
        q, G = self._map(z)
        return G.T @ self._dense(curv(t, q, lam)) @ G

    def accelerations(self, t: float, z: np.ndarray, zd: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """zdd = G^-1 (qdd - c) and lambda, from the base's qdd and lambda."""
        q, G, qd, _, c = self._state(z, zd)
        qdd, lam = self.base.accelerations(t, q, qd)
        return np.linalg.solve(G, qdd - c), lam

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        """(zd, zdd)."""
        n = self.n
        return np.concatenate((y[n:2 * n], self.accelerations(t, y[:n], y[n:2 * n])[0]))


#: The relative coordinates are tried after at least RELATIVE_TRIAL absolute steps (a
#: baseline of steady ones, not the run's first) and kept where their first RELATIVE_TRIAL
#: steps take at least RELATIVE_GAIN times less work per simulated second than the last
#: (at most ten) absolute ones: the ratio of the median step sizes times the inverse ratio
#: of the median work per step, the work being the evaluations of the equations and of
#: their Jacobians, rejected attempts included (counted, not timed: a run makes the same
#: choice on any machine; medians: the step that started the trial, with its stagewise
#: Jacobians, counts once). The margin covers a relative evaluation's higher cost (the map,
#: the dense G^T M G: 1.7 times an absolute one's on the stiff pendulum, the stepper's share
#: included). Measured (rtol 1e-6, median step and evaluations plus Jacobians a step,
#: before and after): the stiff pendulum at k = 1e8, 0.0071 s and 11, 0.029 s and 7 (6.4:
#: kept; 134 steps -> 60), at k = 1e6, 0.0176 s and 17, 0.034 s and 7 (4.7: kept; the
#: step lengths alone, 1.9, sent it back, and the run took 1.5 to 2 times as long); a
#: four-bar carrying a bob on a stiff slider spring (k = 1e10) turning at 8 rad/s, 0.0079 s
#: and 10, 0.0089 s and 11 (1.03: back; its steps are held by the motion's accuracy in
#: either coordinates, and relative ones cost it 250 -> 390 ms). Without the baseline that
#: loop's trial began after two absolute steps of its start, and any count of work rated
#: it at 1.9 to 3.3.
RELATIVE_TRIAL = 8
RELATIVE_GAIN = 2.0


def _ratio(gain: float) -> str:
    """'6.43 times less' (gain >= 1) or '3.38 times more' (below 1); beyond a thousand,
    'over 1000 times': a trial whose steps collapsed at a singular position measures that
    position, not the coordinates (a driven parallelogram: "8.15e+07 times more")."""
    if gain > 1e3 or gain < 1e-3:
        return f"over 1000 times {'less' if gain > 1 else 'more'}"
    return f"{gain:.3g} times less" if gain >= 1 else f"{1 / gain:.3g} times more"


def _gain(before: list[tuple[float, int]], after: list[tuple[float, int]]) -> float:
    """How much less work per simulated second the steps ``after`` take than the steps
    ``before`` ((step size, work) each): (median h_after / median h_before) times (median
    w_before / median w_after) (:data:`RELATIVE_GAIN`)."""
    if not before:
        return np.inf
    h0, w0 = (float(np.median([s[k] for s in before])) for k in (0, 1))
    h1, w1 = (float(np.median([s[k] for s in after])) for k in (0, 1))
    return (h1 / h0) * (w0 / max(w1, 1.0)) if h0 > 0 else np.inf


class Radau(Stepper):
    """The registry's ``radau``: :class:`~mechdsl.solve.radau.RadauStepper` in the model's
    own (absolute) coordinates, going on in relative coordinates (:class:`Relative`) from
    the first step after one whose stages needed their own Jacobians (a stiff force whose
    direction turns: the module docstring) where the model has at most ``relative_max``
    coordinates (``SolverOptions``, read from the equations' options) and a force element
    acts across a joint, and keeping them where they take far less work per simulated
    second (:data:`RELATIVE_GAIN`), else going back for the rest of the run. A stiff
    force whose direction does not turn with the bodies (a rotary spring at a pin) keeps
    one Jacobian in absolute coordinates, where each evaluation costs less. Its state,
    dense output and restart are in absolute coordinates; its counters sum every part."""

    name = RadauStepper.name
    order = RadauStepper.order
    implicit = RadauStepper.implicit
    redundant = RadauStepper.redundant
    summary = RadauStepper.summary
    auto = RadauStepper.auto
    constrained = RadauStepper.constrained
    dense_arrays = RadauStepper.dense_arrays

    def __init__(self, equations: Equations, t0: float, y0: np.ndarray, t_bound: float, *,
                 rtol: float, atol: float, scale: np.ndarray,
                 first_step: float | None = None, **options) -> None:
        #: where the tolerances asked for are below what the method holds (radau.floored)
        rtol, atol, self._floor_note = floored(rtol, atol)
        self.equations, self.rtol, self.atol, self.scale = equations, rtol, atol, scale
        self._options = options
        opts = getattr(equations, "opts", None)
        limit = getattr(opts, "relative_max", 0) if opts is not None else 0
        #: where the run went on in relative coordinates (t), and where it went back to
        #: absolute ones (None while it has not)
        self.relative_from: float | None = None
        self.relative_until: float | None = None
        self.relative: Relative | None = None
        system = getattr(equations, "system", None)
        #: the forest of the relative coordinates, and the force elements across its
        #: joints (module docstring): without one, stages that need their own Jacobians
        #: have another cause (a singular position)
        self._parent, self._spanning = None, []
        if system is not None and 0 < int(equations.n) <= limit:
            forces = _forces(equations)
            self._parent = forest(system, tuple(f.bodies for f in forces))
            self._spanning = spanned_joints(system, forces, self._parent)
        self._may_turn = bool(self._spanning)
        self._before = np.zeros(5, dtype=int)  # the counters of the parts before
        #: (step size, evaluations and Jacobians it took, rejected attempts included) of
        #: the last accepted steps: absolute ones, then relative ones
        self._steps: list[tuple[float, int]] = []
        self._gain = 0.0
        self._before_steps: list[tuple[float, int]] = []
        #: the relative coordinates left where the joints fix the others (module reduced)
        self._left: tuple[int, int] | None = None
        start = self._joint_coordinates(t0, np.asarray(y0, dtype=float), t_bound)
        if start is not None:
            # a tree whose joints leave an ODE in their own coordinates, with a force
            # across a joint: those coordinates from the start, as one writes such a
            # model by hand (module reduced), with no trial against absolute ones
            equations, y0 = start
            self.relative, self.relative_from = equations, t0
        self._from_start = start is not None
        self.inner = RadauStepper(equations, t0, y0, t_bound, rtol=rtol, atol=atol,
                                  scale=scale, first_step=first_step, **options)

    def _joint_coordinates(self, t0: float, y0: np.ndarray, t_bound: float):
        """(equations, state) in the joints' own coordinates where the model is a tree of
        joints that fix every other relative coordinate and a force acts across one of
        them; else None."""
        if not self._spanning:
            return None
        equations, z = self._relative_at(t0, y0, t_bound)
        if equations.m or self._left is None or not equations.n:
            # (no coordinate left: the joints lock the bodies, whose motion, none, the
            # absolute coordinates integrate as they are)
            self._left = None
            return None
        return equations, z

    def _go_on(self, equations: Equations, y: np.ndarray) -> None:
        """A new inner stepper on ``equations`` from the inner stepper's time, with y in
        their coordinates (its step size, budget and limits kept)."""
        old = self.inner
        new = RadauStepper(equations, old.t, y, old.t_bound, rtol=self.rtol, atol=self.atol,
                           scale=self.scale, first_step=old.h_abs, **self._options)
        self._before += [old.nfev, old.njev, old.nlu, old.naccepted, old.nrejected]
        new.max_step = old.max_step
        new.max_attempts = old.max_attempts - old.attempts
        self.inner = new

    def _to_relative(self) -> None:
        t, y = self.inner.t, self.inner.y
        rel, z = self._relative_at(t, y, self.inner.t_bound)
        self._go_on(rel, z)
        self.relative, self.relative_from = rel, t
        self._before_steps, self._steps = self._steps[-10:], []

    def _relative_at(self, t: float, y: np.ndarray, t_bound: float):
        """(equations, state) in relative coordinates from (t, y) on: on the forest, each
        body's reference point at its pin to its parent where it has one
        (:func:`mechdsl.solve.reduced.pin_points`: a body whose frame is at its centre of
        mass, Haug's, pinned at its end), the coordinates the joints fix eliminated where
        there are any (:func:`mechdsl.solve.reduced.reduce`; ``_left`` says how many are
        left)."""
        from .reduced import pin_points, reduce

        rel = Relative(self.equations, self._parent)
        points = pin_points(rel, t, rel.relative(y)[:rel.n])
        if points is not None:
            rel = Relative(self.equations, self._parent, points)
        reduced = reduce(rel, t, rel.relative(y)[:rel.n], t_bound - t)
        if reduced is None:
            return rel, rel.relative(y)
        self._left = (reduced.n, rel.n)
        return reduced, reduced.relative(y)

    def _to_absolute(self) -> None:
        t, y = self.inner.t, self.relative.absolute(self.inner.y)
        self._go_on(self.equations, y)
        self.relative, self.relative_until, self._may_turn = None, t, False

    @property
    def note(self) -> str | None:
        """Rule 5: the tolerances where they were raised to the method's floor; where the
        run went on in relative coordinates, and why."""
        notes = [n for n in (self._floor_note, self._relative_note()) if n]
        return "; ".join(notes) if notes else None

    def _relative_note(self) -> str | None:
        if self.relative_from is None:
            return None
        left = "" if self._left is None else \
            f" ({self._left[0]} of {self._left[1]} left: the joints fix the others)"
        if self._from_start:
            return (f"radau in the joints' own coordinates{left} from its start, with "
                    f"{_listed(self._spanning)} acting across a joint")
        why = (f"its stages needed their own Jacobians, with {_listed(self._spanning)} "
               "acting across a joint")
        if self.relative_until is not None:
            return (f"radau tried relative coordinates{left} from t = "
                    f"{self.relative_from:.6g} to {self.relative_until:.6g} ({why}), which "
                    f"took {_ratio(self._gain)} work per simulated second, under "
                    f"{RELATIVE_GAIN:g}: absolute ones kept")
        rated = (f"{_ratio(self._gain)} work per simulated second" if self._gain else
                 f"the run ended before the trial's {RELATIVE_TRIAL} steps rated them")
        return (f"radau in relative coordinates{left} from t = {self.relative_from:.6g}, "
                f"where {why} ({rated})")

    def _absolute(self, y: np.ndarray) -> np.ndarray:
        return y if self.relative is None else self.relative.absolute(y)

    # what the driver reads and sets on the stepper it was given
    exact_outputs = property(lambda self: getattr(self.relative, "m", None) == 0,
                             doc="rule 6: in the joints' own coordinates, with no "
                                 "equation left")
    t = property(lambda self: self.inner.t)
    t_old = property(lambda self: self.inner.t_old)
    y = property(lambda self: self._absolute(self.inner.y))
    y_old = property(lambda self: self._absolute(self.inner.y_old))
    t_bound = property(lambda self: self.inner.t_bound)
    h_abs = property(lambda self: self.inner.h_abs)
    nfev = property(lambda self: int(self._before[0]) + self.inner.nfev)
    njev = property(lambda self: int(self._before[1]) + self.inner.njev)
    nlu = property(lambda self: int(self._before[2]) + self.inner.nlu)
    naccepted = property(lambda self: int(self._before[3]) + self.inner.naccepted)
    nrejected = property(lambda self: int(self._before[4]) + self.inner.nrejected)

    @property
    def max_step(self) -> float:
        return self.inner.max_step

    @max_step.setter
    def max_step(self, value: float) -> None:
        self.inner.max_step = value

    @property
    def max_attempts(self) -> float:
        return int(self._before[3] + self._before[4]) + self.inner.max_attempts

    @max_attempts.setter
    def max_attempts(self, value: float) -> None:
        self.inner.max_attempts = value - int(self._before[3] + self._before[4])

    def step(self) -> str | None:
        """Rule 2 (the inner stepper's step; first the change of coordinates where the last
        step needed the stages' own Jacobians and a baseline of absolute steps was taken,
        or back where relative ones do not pay)."""
        # (between steps, never after one: the driver asks for the last step's dense
        # output, which is the stepper's that took it)
        if self.relative is None and self._may_turn and self.inner.stagewise and \
                len(self._steps) >= RELATIVE_TRIAL:
            self._to_relative()
        elif self.relative is not None and self._gain and self._gain < RELATIVE_GAIN:
            self._to_absolute()
        inner = self.inner
        t0, work = inner.t, inner.nfev + inner.njev
        message = inner.step()
        if message is None:
            self._steps.append((inner.t - t0, inner.nfev + inner.njev - work))
            if self.relative is None:
                del self._steps[:-10]
            elif len(self._steps) == RELATIVE_TRIAL:
                self._gain = _gain(self._before_steps, self._steps)
        return message

    def dense_output(self) -> Callable[[float], np.ndarray]:
        """Rule 3: the inner stepper's collocation polynomial, as (q, qd)."""
        u = self.inner.dense_output()
        if self.relative is None:
            return u
        rel = self.relative
        many = getattr(rel, "absolute_many", None)

        def absolute(t):
            y = np.asarray(u(t))
            if y.ndim == 1:
                return rel.absolute(y)
            if many is not None:
                return many(y)
            return np.stack([rel.absolute(col) for col in y.T], axis=1)
        return absolute

    def restart(self, y: np.ndarray) -> None:
        """Rule 4, the state given in absolute coordinates."""
        y = np.asarray(y, dtype=float)
        self.inner.restart(y if self.relative is None else self.relative.relative(y))
