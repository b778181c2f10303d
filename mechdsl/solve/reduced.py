"""Relative coordinates that the joints fix, eliminated: the implicit integrator's minimal form.

Why. In the relative coordinates z of :mod:`mechdsl.solve.relative` a joint along the
forest's edge often holds a coordinate of the child's pose in its parent's frame constant: a
pin at both frames' origins fixes s_i, a slider through them along a body axis fixes the
offset across the axis and rho_i. Such an equation reads Phi_r(z) = a z_k + b, with a and b
constant; the Radau IIA stages still carry it, with its multiplier, a velocity and an
acceleration of z_k that are zero, and an iteration matrix of 3 (2n + m) unknowns. Removing
z_k and the rows that fix it leaves the joints' own coordinates: for a tree of such joints
(the stiff pendulum: a rod on a pin, a bob on a slider along it) an ODE in as many
coordinates as the mechanism has degrees of freedom, the form scipy's Radau is given by hand
in the benchmark (docs/dynamics.md), with none of the multipliers' arithmetic.

Which rows. Only a joint's row, never a drive's (a drive at rest for a while is
constant where it is probed, and not after), and only one whose traced expression is
analytic in q: no opaque function (a table, a cam's profile: piecewise, affine over a
dwell and not beyond it), no abs, sign or mod (the compiled model's member layout shows
each row's expression; without it no row is eliminated). Such a row r is eliminated where
its gradient in z has one entry, a at z_k (the others below :data:`PATTERN_RTOL` of it), its
rate nu_r is zero, and at :data:`PROBES` states and instants drawn far from the run's (each
coordinate moved by up to its scale: the model's length for positions, a radian for
angles; the instants across the span) the gradient is the same and Phi_r moved by a dz_k
alone (both to :data:`LINEAR_RTOL`): then Phi_r is a z_k + b for every state (an analytic
function that is affine at random points is affine), and z_k = z_k0 - Phi_r(z0) / a
exactly. A row that fails any check stays an equation of the stepper (loop closures,
drives, a pin away from a frame's origin, a pin between two moving bodies, whose rows are
in world axes), with the remaining coordinates.

The equations. With w the coordinates left (``free``) and the rows kept (``keep``), every
term is the relative coordinates' own restricted: (G^T M G)_ww, (G^T (Q - M c))_w, the
kept rows of Phi, gamma and Phi_q G (their columns w), the loads' derivatives' (w, w)
blocks and the kept multipliers' curvature (an eliminated row's is zero: its Phi_r is
affine in z). The accelerations are those of z (the absolute ones solved with every row,
mapped back), which keep z_k's zero. Nothing is approximated beyond the relative
coordinates' own Jacobian terms.
"""

from __future__ import annotations

import numpy as np

from .relative import Relative

__all__ = ["Reduced", "reduce"]

#: gradient entries below this fraction of a row's largest are round-off of the map
#: (Phi_q G formed in floating point), not a dependence
PATTERN_RTOL = 1e-12
#: far states and instants at which an eliminated row is checked to be affine in one
#: coordinate
PROBES = 3
#: agreement asked of the gradient and of Phi at the probes, relative to the row's scale
LINEAR_RTOL = 1e-9


def _coordinate_scale(rel: Relative) -> np.ndarray:
    """Each relative coordinate's scale for the probes: the base equations' column scale
    (the model's length for x and y, 1 for phi; the same kinds in z), else 1."""
    D = getattr(rel.base, "D", None)
    if D is None:
        return np.ones(rel.n)
    D = np.asarray(D, dtype=float).reshape(-1)
    return D if D.size == rel.n else np.ones(rel.n)


#: the operations that make a row's expression piecewise or opaque in q (module docstring)
_NOT_ANALYTIC = frozenset(("call", "select", "abs", "sign", "mod"))


def _analytic_rows(base) -> set[int]:
    """The joints' rows of the base equations' compiled model whose traced expressions
    are analytic in q (module docstring); none where the model's layout does not show
    each row's expression."""
    kernels = getattr(base, "kernels", None)
    f = getattr(kernels, "fused", None)
    if f is None or f.layout != "member" or f.graph is None or not f.phi_nodes:
        return set()
    drives = {int(r) for r in kernels.system.drive_rows}
    return {r for r, node in enumerate(f.phi_nodes) if r not in drives
            and not any(nd.op in _NOT_ANALYTIC for nd in f.graph.subgraph([node]))}


def reduce(rel: Relative, t: float, z: np.ndarray, span: float) -> "Reduced | None":
    """The equations of ``rel`` with the coordinates that its joints fix eliminated (module
    docstring), checked at state z, time t and over ``span`` after it; None where no row
    fixes a coordinate (or a probe cannot be evaluated)."""
    z = np.asarray(z, dtype=float)
    n, m = rel.n, rel.m
    if m == 0:
        return None
    phi0, jac0 = rel.phi_jac(t, z)
    jac0 = np.asarray(jac0, dtype=float)
    nu0 = np.asarray(rel.nu(t), dtype=float)
    fixing: dict[int, int] = {}
    for r in sorted(_analytic_rows(rel.base)):
        row = np.abs(jac0[r])
        big = row.max()
        if not big > 0 or nu0[r] != 0:
            continue
        touched = np.flatnonzero(row > PATTERN_RTOL * big)
        if len(touched) == 1:
            fixing[r] = int(touched[0])
    if not fixing:
        return None
    rng = np.random.default_rng(12345)  # the same probes every run: the same choice
    scale = _coordinate_scale(rel)
    for _ in range(PROBES):
        dz = rng.uniform(-1.0, 1.0, n) * scale
        tp = t + rng.uniform(0.0, 1.0) * span
        try:
            with np.errstate(all="raise"):
                phi, jac = rel.phi_jac(tp, z + dz)
        except (ArithmeticError, ValueError):
            return None
        jac = np.asarray(jac, dtype=float)
        for r, k in list(fixing.items()):
            a = jac0[r, k]
            tol = LINEAR_RTOL * abs(a) * (1.0 + abs(dz[k]))
            if np.abs(jac[r] - jac0[r]).max() > LINEAR_RTOL * abs(a) or \
                    abs(phi[r] - phi0[r] - a * dz[k]) > tol:
                del fixing[r]
        if not fixing:
            return None
    value = z.copy()
    for r, k in fixing.items():
        value[k] = z[k] - phi0[r] / jac0[r, k]
    fixed = sorted(set(fixing.values()))
    free = np.array([k for k in range(n) if k not in fixed], dtype=np.intp)
    keep = np.array([r for r in range(m) if r not in fixing], dtype=np.intp)
    return Reduced(rel, free, keep, value)


class Reduced:
    """The :class:`~mechdsl.solve.relative.Relative` equations on the coordinates ``free``
    with the rows ``keep`` (the others' coordinates held at ``value``); the same
    :class:`~mechdsl.solve.stepper.Equations` protocol and maps to absolute coordinates
    (module docstring)."""

    def __init__(self, rel: Relative, free: np.ndarray, keep: np.ndarray,
                 value: np.ndarray) -> None:
        self.rel, self.base = rel, rel.base
        self.free, self.keep = free, keep
        self.n, self.m = len(free), len(keep)
        self.N = rel.n
        self._value = np.asarray(value, dtype=float)
        self._ww = np.ix_(free, free)
        self._kw = np.ix_(keep, free)

    # -- the coordinates --------------------------------------------------------------------
    def _z(self, w: np.ndarray) -> np.ndarray:
        z = self._value.copy()
        z[self.free] = w
        return z

    def _zd(self, wd: np.ndarray) -> np.ndarray:
        zd = np.zeros(self.N)
        zd[self.free] = wd
        return zd

    def _full(self, y: np.ndarray) -> np.ndarray:
        n = self.n
        return np.concatenate((self._z(y[:n]), self._zd(y[n:2 * n])))

    def own_scale(self, scale: np.ndarray) -> np.ndarray:
        """The scale of (w, wd) from the scale of the absolute (q, qd): a relative
        coordinate is of the kind (x, y or phi) of the absolute one it replaces."""
        scale = np.broadcast_to(np.asarray(scale, dtype=float), (2 * self.N,))
        return np.concatenate((scale[self.free], scale[self.N + self.free]))

    def absolute(self, y: np.ndarray) -> np.ndarray:
        """(q, qd) of the state (w, wd)."""
        return self.rel.absolute(self._full(y))

    def relative(self, y: np.ndarray) -> np.ndarray:
        """(w, wd) of the state (q, qd) (the eliminated coordinates are the joints')."""
        zz = self.rel.relative(y)
        return np.concatenate((zz[:self.N][self.free], zz[self.N:][self.free]))

    def error_map(self, y: np.ndarray, y_new: np.ndarray, err: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The step's start, end and error in absolute coordinates (the relative
        coordinates' map; the eliminated coordinates' errors are zero)."""
        n = self.n
        full = np.concatenate((self._zd(err[:n]), self._zd(err[n:2 * n]),
                               err[2 * n:]))
        return self.rel.error_map(self._full(y), self._full(y_new), full)

    # -- the Equations protocol -------------------------------------------------------------
    def phi_jac(self, t: float, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The kept rows of Phi(g(z(w)), t) and of Phi_q G, their columns w."""
        phi, jac = self.rel.phi_jac(t, self._z(w))
        return phi[self.keep], np.asarray(jac)[self._kw]

    def nu(self, t: float) -> np.ndarray:
        """nu's kept rows."""
        return np.asarray(self.rel.nu(t))[self.keep]

    def gamma(self, t: float, w: np.ndarray, wd: np.ndarray) -> np.ndarray:
        """gamma - Phi_q c, kept rows (the eliminated coordinates' rates are zero)."""
        return self.rel.gamma(t, self._z(w), self._zd(wd))[self.keep]

    def mass(self, w: np.ndarray) -> np.ndarray:
        """(G^T M G)_ww."""
        return self.rel.mass(self._z(w))[self._ww]

    def mass_loads(self, t: float, w: np.ndarray, wd: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """(G^T M G)_ww and (G^T (Q - M c))_w, from one evaluation."""
        M, Q = self.rel.mass_loads(t, self._z(w), self._zd(wd))
        return M[self._ww], Q[self.free]

    def loads(self, t: float, w: np.ndarray, wd: np.ndarray) -> np.ndarray:
        """(G^T (Q - M c))_w."""
        return self.mass_loads(t, w, wd)[1]

    def load_derivatives(self, t: float, w: np.ndarray, wd: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
        """The (w, w) blocks of the relative coordinates' load derivatives."""
        dz, dzd = self.rel.load_derivatives(t, self._z(w), self._zd(wd))
        return dz[self._ww], dzd[self._ww]

    def constraint_curvature(self, t: float, w: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """G^T (Phi_q^T lambda)_q G's (w, w) block, the eliminated rows' multipliers zero
        (their Phi_r is affine in z: no curvature)."""
        full = np.zeros(self.rel.m)
        full[self.keep] = lam
        return self.rel.constraint_curvature(t, self._z(w), full)[self._ww]

    def accelerations(self, t: float, w: np.ndarray, wd: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """wdd and the kept multipliers."""
        if self.m == 0:
            # an ODE: (G^T M G)_ww wdd = (G^T (Q - M c))_w, no multiplier left
            M, Q = self.mass_loads(t, w, wd)
            return np.linalg.solve(M, Q), np.zeros(0)
        zdd, lam = self.rel.accelerations(t, self._z(w), self._zd(wd))
        return zdd[self.free], np.asarray(lam)[self.keep]

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        """(wd, wdd)."""
        n = self.n
        return np.concatenate((y[n:2 * n], self.accelerations(t, y[:n], y[n:2 * n])[0]))
