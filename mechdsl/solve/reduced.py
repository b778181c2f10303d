"""Relative coordinates that the joints fix, eliminated: the implicit integrator's minimal form.

Why. In the relative coordinates z of :mod:`mechdsl.solve.relative` a joint along the
forest's edge often holds coordinates of the child's pose in its parent's frame constant: a
pin at the child's frame origin fixes s_i, a slider through the frames' origins along a body
axis fixes the offset across the axis and rho_i. The Radau IIA stages still carry those
equations, with their multipliers, velocities and accelerations of z_S that are zero, and an
iteration matrix of 3 (2n + m) unknowns. Removing z_S and the rows that fix it leaves the
joints' own coordinates: for a tree of such joints
(the stiff pendulum: a rod on a pin, a bob on a slider along it) an ODE in as many
coordinates as the mechanism has degrees of freedom, the form scipy's Radau is given by hand
in the benchmark (docs/dynamics.md), with none of the multipliers' arithmetic.

Which rows. Only a joint's rows, never a drive's (a drive at rest for a while is
constant where it is probed, and not after), and only those whose traced expressions are
analytic in q: no opaque function (a table, a cam's profile: piecewise, affine over a
dwell and not beyond it), no abs, sign or mod (the compiled model's member layout shows
each row's expression; without it no row is eliminated). A joint's rows R (together, else
each alone) fix the coordinates S where, at the start z0 (on the constraints), their
gradient in z touches exactly |R| coordinates S (each column weighted by its coordinate's
scale, the others below :data:`PATTERN_RTOL` of the largest and ten times the rows'
residual), Phi_R,S is regular (condition below :data:`MAX_COND`), their rates nu_R are zero, and
at :data:`PROBES` states and instants drawn far from the run's (every coordinate outside
the fixed ones moved by up to its scale: the model's length for positions, a radian for
angles; the instants across the span) with every S at its value, Phi_R vanishes (to
:data:`LINEAR_RTOL`) and Phi_R,S stays regular. Then Phi_R = 0 holds with z_S = z_S0
whatever the other coordinates (an analytic function that vanishes at random points
vanishes), and by the implicit function theorem only there: the joint's own equations are
z_S = z_S0, with z_S0 solved from Phi_R(z0) = 0. A pin at the child's frame origin fixes
its s_i in the parent's frame, whether the parent is the ground (two rows, each affine in
one coordinate) or a moving body (two rows in world axes, A(phi_p) (s_A - s_i): they turn
with the parent, yet vanish wherever s_i = s_A); a slider through the frames' origins along
a body axis fixes the offset across the axis and rho_i. A redundant joint's rows that
touch only coordinates another joint fixed (a second pin where the first is) go too, where
they vanish at the probes: on the coordinates left they are rows of zeros, which would
leave the implicit stepper's matrix singular. Every other row stays an equation of the
stepper (loop closures, drives, a slider whose axis is skewed in the parent's frame), with
the remaining coordinates.

The equations. With w the coordinates left (``free``) and the rows kept (``keep``), every
term is the relative coordinates' own restricted: (G^T M G)_ww, (G^T (Q - M c))_w, the
kept rows of Phi, gamma and Phi_q G (their columns w), the loads' derivatives' (w, w)
blocks and the kept multipliers' curvature (an eliminated row's is zero: it vanishes
identically on the coordinates w). The accelerations are those of z (the absolute ones solved with every row,
mapped back), which keep z_k's zero. Nothing is approximated beyond the relative
coordinates' own Jacobian terms.
"""

from __future__ import annotations

import numpy as np

from .reduced_terms import TracedReduced, traced
from .relative import Relative

__all__ = ["Reduced", "pin_points", "reduce"]

#: gradient entries below this fraction of a row's largest are round-off of the map
#: (Phi_q G formed in floating point), not a dependence
PATTERN_RTOL = 1e-12
#: far states and instants at which an eliminated row is checked to be affine in one
#: coordinate
PROBES = 3
#: how far from zero a joint's rows may be at the probes, relative to their gradient times
#: the coordinates' scale (round-off is about 1e-16 of it; a row that the coordinates fixed
#: do not fix is off by about the scale)
LINEAR_RTOL = 1e-9
#: the largest condition number of a joint's block Phi_R,S (rows R on the coordinates S
#: they fix) at the start and at the probes: beyond it the rows do not fix S uniquely
MAX_COND = 1e8


#: what the generated terms raise outside a function's domain (the map then gives NaN or inf)
_OUTSIDE = (ValueError, ZeroDivisionError, OverflowError)


def _cond(a: np.ndarray) -> float:
    """The 2-norm condition number of a square block: a joint's are 1 x 1 or 2 x 2, in
    closed form (sigma_max^2 + sigma_min^2 = |a|_F^2, sigma_max sigma_min = |det a|: an
    SVD per block cost half of the elimination's checks), larger ones by numpy's SVD."""
    if a.shape == (1, 1):
        return 1.0 if a[0, 0] != 0 else np.inf
    if a.shape == (2, 2):
        det = abs(float(a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]))
        fro = float(np.vdot(a, a))
        if not det > 0 or not np.isfinite(fro):
            return np.inf
        return (fro + np.sqrt(max(fro * fro - 4 * det * det, 0.0))) / (2 * det)
    return float(np.linalg.cond(a))


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


def _groups(base, rows: set[int]) -> list[list[int]]:
    """``rows`` grouped by the joint that owns them (in the compiled model's order); each
    row alone where the base equations do not say which joint owns it."""
    system = getattr(getattr(base, "kernels", None), "system", None)
    if system is None:
        return [[r] for r in sorted(rows)]
    out: list[list[int]] = []
    for c in system.constraints:
        group = [r for r in range(*c.rows) if r in rows]
        if group:
            out.append(group)
    return out


def pin_points(rel: Relative, t: float, z: np.ndarray) -> np.ndarray | None:
    """Each body's reference point u_i (body axes) for relative coordinates in which its
    pin to its parent fixes s_i: where the joint along the forest's edge has two rows,
    analytic in q, whose gradient at z (the frames' origins as reference, on the
    constraints) touches the child's s_i and rho_i alone, with Phi_s regular. A pin at the
    child's point u reads Phi = A(phi_p) (v - s_i - A(rho_i) u) (to a sign), so that
    Phi_s^-1 Phi_rho = A(rho_i) perp(u) and u = perp^-1(A(rho_i)^T Phi_s^-1 Phi_rho). Any
    point is a valid reference (the map stays one to one); :func:`reduce` checks what the
    joint fixes. None where no body gets a point off its origin. The latest is kept with
    the compiled model for the same forest and state (as :func:`reduce`'s choice)."""
    kernels = getattr(rel.base, "kernels", None)
    system = getattr(kernels, "system", None)
    if system is None:
        return None
    key = ("pin_points", tuple(rel.parent), tuple(rel.points), float(t),
           np.asarray(z, dtype=float).tobytes())
    dynamics = getattr(kernels, "dynamics", None)
    if dynamics is None:
        return _pin_points(rel, t, z, system)
    return dynamics.latest("pin_points", key, lambda: _pin_points(rel, t, z, system))


def _pin_points(rel: Relative, t: float, z: np.ndarray, system) -> np.ndarray | None:
    """:func:`pin_points`, made."""
    phi, jac = rel.phi_jac(t, z)
    phi, jac = np.asarray(phi, dtype=float), np.asarray(jac, dtype=float)
    scale = _coordinate_scale(rel)
    analytic = _analytic_rows(rel.base)
    names = {name: i for i, name in enumerate(system.body_names)}
    points = np.zeros((len(rel.parent), 2))
    for c in system.constraints:
        R = [r for r in range(*c.rows) if r in analytic]
        ends = {names.get(b, -1) for b in c.bodies}
        if len(R) != 2 or len(R) != c.rows[1] - c.rows[0] or len(ends) != 2:
            continue
        child = next((i for i in ends if i >= 0 and rel.parent[i] in ends), None)
        if child is None:
            continue
        k = 3 * child
        block = jac[R]
        if not np.abs(block).max() > 0 or \
                set(_touched(block, phi[R], scale).tolist()) - {k, k + 1, k + 2}:
            continue
        Js, Jr = block[:, k:k + 2], block[:, k + 2]
        if _cond(Js) > MAX_COND:
            continue
        x = np.linalg.solve(Js, Jr)  # A(rho) perp(u)
        rho = float(z[k + 2])
        cr, sr = np.cos(rho), np.sin(rho)
        px, py = cr * x[0] + sr * x[1], -sr * x[0] + cr * x[1]  # perp(u)
        points[child] = (py, -px)
    if not np.abs(points).max() > 0:
        return None
    points.flags.writeable = False  # (kept with the model: shared by the runs)
    return points


def _touched(block: np.ndarray, phi: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The coordinates that rows of gradient ``block`` and values ``phi`` depend on: the
    columns, each weighted by its coordinate's scale (a length's and an angle's entries
    compared in the same units), above :data:`PATTERN_RTOL` of the largest and ten times
    the rows' residual (a pin between moving bodies turns with its parent by its residual:
    round-off, or the tolerance mid-run)."""
    weighted = np.abs(block) * scale
    floor = PATTERN_RTOL * weighted.max() + 10.0 * np.abs(phi).max(initial=0.0)
    return np.flatnonzero(weighted.max(axis=0) > floor)


def reduce(rel: Relative, t: float, z: np.ndarray, span: float) -> "Reduced | None":
    """The equations of ``rel`` with the coordinates that its joints fix eliminated (module
    docstring), checked at state z, time t and over ``span`` after it; None where no joint
    fixes a coordinate (or a probe cannot be evaluated). The latest choice is kept with
    the compiled model for the same forest, points, state and span (the next
    ``simulate()`` of a mechanism starts where this one did: its probes are not made
    again)."""
    z = np.asarray(z, dtype=float)
    if rel.m == 0:
        return None
    d = getattr(getattr(rel.base, "kernels", None), "dynamics", None)
    if d is None:
        made = _eliminated(rel, t, z, span)
    else:
        key = ("reduce", tuple(rel.parent), tuple(rel.points), float(t), z.tobytes(),
               float(span))
        made = d.latest("reduce", key, lambda: _eliminated(rel, t, z, span))
    return None if made is None else Reduced(rel, *made)


def _eliminated(rel: Relative, t: float, z: np.ndarray, span: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`reduce`'s choice: (free, keep, value), or None."""
    n, m = rel.n, rel.m
    phi0, jac0 = rel.phi_jac(t, z)
    phi0, jac0 = np.asarray(phi0, dtype=float), np.asarray(jac0, dtype=float)
    nu0 = np.asarray(rel.nu(t), dtype=float)
    scale = _coordinate_scale(rel)
    rows = {r for r in _analytic_rows(rel.base) if nu0[r] == 0 and np.abs(jac0[r]).max() > 0}
    #: (rows R, coordinates S they fix, the size of their gradient)
    candidates: list[tuple[list[int], list[int], float]] = []
    taken: set[int] = set()
    for group in _groups(rel.base, rows):
        # a joint's rows together (a pin between two moving bodies: two rows in world axes
        # that fix the child's position in its parent's frame), else each row alone
        for R in [group] + ([[r] for r in group] if len(group) > 1 else []):
            if set(R) & {r for c in candidates for r in c[0]}:
                continue
            block = jac0[R]
            S = [int(k) for k in _touched(block, phi0[R], scale)]
            if len(S) == len(R) and not taken & set(S) and \
                    _cond(block[:, S]) < MAX_COND:
                candidates.append((R, S, float(np.abs(block[:, S]).max())))
                taken.update(S)
    if not candidates:
        return None
    # a redundant joint's rows on coordinates another joint fixed (a second pin where the
    # first is): identically zero once those are held, and no equation to keep (a row of
    # zeros left the implicit stepper's matrix singular)
    for r in sorted(rows - {r for c in candidates for r in c[0]}):
        if set(_touched(jac0[[r]], phi0[[r]], scale).tolist()) <= taken:
            candidates.append(([r], [], float(np.abs(jac0[r]).max())))
    value = z.copy()
    for R, S, _ in candidates:  # the fixed coordinates where the joints' rows hold exactly
        if S:
            value[S] = z[S] - np.linalg.solve(jac0[np.ix_(R, S)], phi0[R])
    while candidates:
        failed = _failing(rel, candidates, value, t, span, scale)
        if failed is None:
            return None
        if not failed:
            break
        # (the others are probed again: with these coordinates free, theirs still hold)
        candidates = [c for c in candidates if c not in failed]
    if not any(S for _, S, _ in candidates):
        return None
    fixed = sorted(k for _, S, _ in candidates for k in S)
    eliminated = {r for R, _, _ in candidates for r in R}
    free = np.array([k for k in range(n) if k not in fixed], dtype=np.intp)
    keep = np.array([r for r in range(m) if r not in eliminated], dtype=np.intp)
    for a in (free, keep, value):
        a.flags.writeable = False  # (kept with the model: shared by the runs)
    return free, keep, value


def _failing(rel: Relative, candidates: list, value: np.ndarray, t: float, span: float,
             scale: np.ndarray) -> list | None:
    """The candidates (rows R, coordinates S, gradient size) whose rows do not vanish at
    :data:`PROBES` far states that hold every candidate's S at its value and draw the
    other coordinates (each within its scale) and the instant (within the span) at random,
    or whose block Phi_R,S turns singular there; None where a probe cannot be evaluated.
    A row that is not a number at a probe does not vanish."""
    rng = np.random.default_rng(12345)  # the same probes every run: the same choice
    fixed = [k for _, S, _ in candidates for k in S]
    failed: list = []
    for _ in range(PROBES):
        zp = value + rng.uniform(-1.0, 1.0, rel.n) * scale
        zp[fixed] = value[fixed]
        tp = t + rng.uniform(0.0, 1.0) * span
        try:
            with np.errstate(all="raise"):
                phi, jac = rel.phi_jac(tp, zp)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            return None
        phi, jac = np.asarray(phi, dtype=float), np.asarray(jac, dtype=float)
        for c in candidates:
            R, S, size = c
            if c in failed:
                continue
            residual = np.abs(phi[R])
            if not np.all(residual <= LINEAR_RTOL * size * scale.max()) or (
                    S and _cond(jac[np.ix_(R, S)]) > MAX_COND):
                failed.append(c)
    return failed


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
        self._terms: TracedReduced | None | bool = False  # traced on first use
        self._pose_key: bytes | None = None
        self._pose_at: tuple | None = None

    @property
    def traced(self) -> "TracedReduced | None":
        """The generated M_w, f_w and their derivatives (:mod:`.reduced_terms`), or None
        where the model is not traced."""
        if self._terms is False:
            self._terms = traced(self)
        return self._terms

    def _by_code(self, name: str, *args):
        """The generated terms' ``name(*args)``; None where the model is not traced or
        the state is outside a function's domain (there they raise: the caller then
        evaluates through the map, which gives NaN or inf)."""
        if self.traced is None:
            return None
        try:
            return getattr(self._terms, name)(*args)
        except _OUTSIDE:
            return None

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

    def _pose(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(q, qd) and G = dq/dw at the state y = (w, wd) by the generated terms (the last
        state's kept: a step's end is the next one's start), None where not traced."""
        key = y.tobytes()
        if key != self._pose_key:
            n = self.n
            pose = self._by_code("absolute", y[:n], y[n:2 * n])
            if pose is None:
                return None
            self._pose_at, self._pose_key = pose, key
        return self._pose_at

    def absolute(self, y: np.ndarray) -> np.ndarray:
        """(q, qd) of the state (w, wd)."""
        if self._pose_key is not None and y.tobytes() == self._pose_key:
            return self._pose_at[0].copy()  # (a step's end, mapped for its error)
        n = self.n
        state = self._by_code("state", y[:n], y[n:2 * n])
        return self.rel.absolute(self._full(y)) if state is None else state

    def absolute_many(self, Y: np.ndarray) -> np.ndarray:
        """(q, qd) (2N, K) of the K states (w, wd), Y (2n, K)."""
        n = self.n
        if not Y.shape[1]:
            return np.empty((2 * self.N, 0))
        out = self._by_code("states", Y[:n], Y[n:2 * n])
        if out is None:
            return np.stack([self.absolute(col) for col in Y.T], axis=1)
        return out

    def relative(self, y: np.ndarray) -> np.ndarray:
        """(w, wd) of the state (q, qd) (the eliminated coordinates are the joints')."""
        zz = self.rel.relative(y)
        return np.concatenate((zz[:self.N][self.free], zz[self.N:][self.free]))

    def error_map(self, y: np.ndarray, y_new: np.ndarray, err: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The step's start, end and error in absolute coordinates (the relative
        coordinates' map; the eliminated coordinates' errors are zero)."""
        n = self.n
        start, end = self._pose(y), self._pose(y_new)
        if start is not None and end is not None:
            # (dq, dqd) = (G dw, G dwd): one product of G with both parts
            mapped = (err[:2 * n].reshape(2, n) @ end[1].T).ravel()
            if self.m:
                mapped = np.concatenate((mapped, err[2 * n:]))
            return start[0], end[0], mapped
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
        """M_w = (G^T M G)_ww."""
        if self.traced is not None:
            return self.mass_loads(0.0, w, np.zeros(self.n))[0]
        return self.rel.mass(self._z(w))[self._ww]

    def mass_loads(self, t: float, w: np.ndarray, wd: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """M_w = (G^T M G)_ww and f_w = (G^T (Q - M c))_w, from one evaluation: the
        generated terms where traced (outside a function's domain, where they raise, and
        elsewhere through the map)."""
        terms = self._by_code("terms", t, w, wd)
        if terms is not None:
            return terms
        M, Q = self.rel.mass_loads(t, self._z(w), self._zd(wd))
        return M[self._ww], Q[self.free]

    def stage_residuals(self, ts: list, Y: np.ndarray, A: np.ndarray) -> list | np.ndarray:
        """M_w(w_j) A_j - f_w(t_j, w_j, wd_j) for the rows j, Y_j = (w_j, wd_j) (an implicit
        stepper's stages; Y and A as rows or flat, row by row), flat, stage by stage: by
        the generated terms where traced (:mod:`.reduced_terms`), else stage by stage
        through the map."""
        out = self._by_code("stage_residuals", ts, Y, A)
        if out is not None:
            return out
        n = self.n
        Y, A = np.reshape(Y, (len(ts), -1)), np.reshape(A, (len(ts), n))
        out = np.empty(A.shape)
        for j, t in enumerate(ts):
            M, f = self.mass_loads(t, Y[j, :n], Y[j, n:2 * n])
            out[j] = M @ A[j] - f
        return out.ravel()

    def loads(self, t: float, w: np.ndarray, wd: np.ndarray) -> np.ndarray:
        """f_w = (G^T (Q - M c))_w."""
        return self.mass_loads(t, w, wd)[1]

    def load_derivatives(self, t: float, w: np.ndarray, wd: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
        """df_w/dw and df_w/dwd: exact where traced (:mod:`.reduced_terms`), else the (w, w)
        blocks of the relative coordinates' load derivatives (which leave out the
        derivatives of G^T and of M c but for their velocity terms)."""
        derivatives = self._by_code("derivatives", t, w, wd)
        if derivatives is not None:
            return derivatives
        dz, dzd = self.rel.load_derivatives(t, self._z(w), self._zd(wd))
        return dz[self._ww], dzd[self._ww]

    def constraint_curvature(self, t: float, w: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """G^T (Phi_q^T lambda)_q G's (w, w) block, the eliminated rows' multipliers zero
        (their Phi_R vanishes identically on the coordinates w, and so do its derivatives:
        they add no curvature there)."""
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
