"""The forward-dynamics benchmark models of issue 28 as ``.mech`` text, and their oracles.

Four models, each a generator of ``.mech`` text (mechdsl's language only, nothing else of
mechdsl is imported here) and an oracle that does not use mechdsl at all: its own equations
of motion in minimal coordinates, derived below and integrated by scipy, or a published
reference.

1. **IFToMM A02, the N-four-bar mechanism** (:func:`a02_text`, oracle :func:`a02_oracle`).
   N + 1 rockers hinged to the ground at (k, 0), k = 0..N, N couplers joining the tips of
   rockers k and k + 1; every link 1 m, 1 kg, uniform (inertia 1/12 kg m^2 about its centre);
   gravity 9.81 m/s^2 in -y. At t = 0 every rocker stands vertical; B0 (the tip of rocker 0)
   moves at +1 m/s in x: every rocker turns at -1 rad/s, every coupler translates at 1 m/s.
   On the parallelogram branch the mechanism is one physical pendulum in the rockers' angle
   theta (from +x): with every rocker at theta and every coupler translating on a unit
   circle,

       T = (N + 1) (1/2) (m L^2 / 3) theta'^2 + N (1/2) m L^2 theta'^2
       V = (N + 1) m g (L / 2) sin theta + N m g L sin theta

   so I_eff theta'' = -K cos theta with I_eff = m L^2 ((N + 1)/3 + N) and
   K = m g L ((N + 1)/2 + N); theta(0) = pi/2, theta'(0) = -1; B0 = L (cos theta, sin theta).

2. **A hanging chain of N pendulum links** (:func:`chain_text`, oracle :func:`chain_oracle`):
   N uniform links of length l = 1 m and mass m = 1 kg (inertia m l^2 / 12 about the centre),
   link 0 hinged to the ground at the origin, link i + 1 hinged to the free end of link i;
   gravity 9.81 in -y; at t = 0 the chain lies straight along +x at rest. Outputs: the free
   end's x, y. Minimal coordinates: the absolute angles theta_j of the links (from +x); the
   centre of link i is c_i = sum_{j<i} l e_j + (l/2) e_i, e_j = (cos theta_j, sin theta_j),
   so with a_ij = 1 (j < i), 1/2 (j = i), 0 (j > i) the kinetic energy is
   (1/2) sum_jk M_jk theta_j' theta_k' with

       M_jk = m l^2 C_jk cos(theta_j - theta_k),
       C_jk = sum_i a_ij a_ik + delta_jk / 12 = N - max(j, k) - 1/2 (j != k),
                                                N - j - 2/3        (j = k),

   V = m g sum_i y_i, dV/dtheta_j = m g l (N - j - 1/2) cos theta_j, and Lagrange's equations
   read (the derivative of M along the motion and dT/dtheta_j combine into one sine term)

       sum_k M_jk theta_k'' + m l^2 sum_k C_jk sin(theta_j - theta_k) theta_k'^2
           + m g l (N - j - 1/2) cos theta_j = 0.

3. **The stiff pendulum** (:func:`stiff_pendulum_text`, oracle :func:`stiff_pendulum_oracle`):
   a rod (length 1 m, mass m_r = 1 kg, uniform: inertia 1/12 about its centre) hinged to the
   ground at the origin, and a bob (mass m_b = 1 kg, inertia J_b = 0.01 kg m^2 about its
   centre, its centre on the rod's axis) that slides along the rod on a prismatic joint
   (which also makes it turn with the rod) and is held by a spring of stiffness k and free
   length L0 = 1 m between the pivot and the bob's centre; gravity 9.81 in -y. At t = 0 the
   rod is horizontal (theta = 0), the bob at s = L0 (spring relaxed), everything at rest.
   Minimal coordinates: the rod's angle theta (from +x) and the bob's distance s from the
   pivot (the spring's extension is s - L0). With I_O = m_r l^2 / 3,

       T = (1/2) (I_O + J_b + m_b s^2) theta'^2 + (1/2) m_b s'^2
       V = (m_r l / 2 + m_b s) g sin theta + (1/2) k (s - L0)^2

   and Lagrange's equations

       (I_O + J_b + m_b s^2) theta'' = -2 m_b s s' theta' - (m_r l / 2 + m_b s) g cos theta
       m_b s'' = m_b s theta'^2 - m_b g sin theta - k (s - L0).

   The radial mode's frequency is sqrt(k / m_b): 10 rad/s at k = 1e2, 1e5 rad/s at 1e10.

4. **The Test Set's car axis problem** (:func:`car_axis_text`, reference :data:`CAR_REF`):
   the Test Set for IVP Solvers' ``caraxis`` (Mazzia and Magherini, release 2.4), read from
   its Fortran (``Ex_car.f``, subroutines ``carfunc`` and ``carsoln``) and R (``ex_caraxis.R``)
   sources: with eps = 1e-2, M = 10, L = 1, L0 = 1/2, r = 0.1, w = 10, g = 1 and
   m = M eps^2 / 2 = 5e-4, two wheels (xl, yl), (xr, yr) of mass m,

       m xl'' = (L0 - Ll) xl / Ll + lam1 xb + 2 lam2 (xl - xr)
       m yl'' = (L0 - Ll) yl / Ll + lam1 yb + 2 lam2 (yl - yr) - m g
       m xr'' = (L0 - Lr) (xr - xb) / Lr - 2 lam2 (xl - xr)
       m yr'' = (L0 - Lr) (yr - yb) / Lr - 2 lam2 (yl - yr) - m g
       0 = xb xl + yb yl,     0 = (xl - xr)^2 + (yl - yr)^2 - L^2

   with Ll = |(xl, yl)|, Lr = |(xr - xb, yr - yb)|, yb = r sin(w t), xb = sqrt(L^2 - yb^2):
   the left wheel on a unit spring (free length L0) to the origin, the right one on a unit
   spring to the road point (xb, yb), the wheels a fixed distance L apart (the axle), and the
   left wheel on the line through the origin normal to (xb, yb). Consistent initial values
   at t = 0: (xl, yl, xr, yr) = (0, L0, L, L0), velocities (-L0/L, 0, -L0/L, 0), lam = 0.
   In mechdsl: the wheels are bodies of mass m whose constraints and loads all act at their
   centres (point masses; their rotations are free and decoupled); the road point is the
   point (L, 0) of a massless body ``road`` hinged at the origin whose angle is driven as
   asin(r sin(w t) / L) (so that its tip is (xb, yb)); ``pin_slot(road.origin, left.origin,
   axis = (0, 1))`` puts the left wheel on the road body's y axis through the origin (the
   first constraint divided by L); ``distance(left.origin, right.origin, L)`` is the axle;
   the springs are ``spring`` forces. mechdsl's multipliers are the Test Set's scaled: the
   force of the pin_slot on the left wheel is lam1 (xb, yb), that of the distance joint on
   the right wheel -2 lam2 (xl - xr, yl - yr). The published lam1, lam2 differ from the
   multipliers of the index-1 equations at the published state by 7.3e-8 relative (1.6e-10
   absolute; mechdsl's agree with the latter to 2e-13): the reference's multipliers are its
   least accurate values, and cap a solver's scd over all ten components near 7.1.

The oracles: A02's branch equation by DOP853 at rtol 1e-13, the chain by DOP853 at rtol 1e-12,
the stiff pendulum by Radau at 1e-10 (1e-8 from k = 1e6: stiff_pendulum_rtol says why and
what it was checked against), the car axis by the Test Set's published values.
"""

from __future__ import annotations

import math

import numpy as np

G = 9.81

# -- A02 -------------------------------------------------------------------------------------

#: B0 on the parallelogram branch, from ../shared/reference/dynamics-benchmarks.md (DOP853 at
#: rtol 1e-13 on the one-degree-of-freedom equation, N = 40): t -> (x, y)
A02_TABLE = {1.0: (-0.115356880632, -0.993324111300),
             5.0: (-0.540190050669, -0.841543052468),
             10.0: (0.180512226681, 0.983572740583),
             20.0: (0.410901153734, 0.911679900985)}


def a02_text(n: int = 40, t1: float = 20.0, step: float = 0.01, rtol: float = 1e-8,
             atol: float = 1e-10) -> str:
    """The ``.mech`` text of IFToMM A02 with ``n`` four-bar windows (2 n + 1 bodies).

    Rocker k: frame at its ground pivot (k, 0), tip ``B`` = (1, 0), centre (0.5, 0), angle pi/2
    at t = 0, ``v0 = (0, 0, -1)``. Coupler k: frame at its left end (the tip of rocker k),
    right end ``R`` = (1, 0), centre (0.5, 0), angle 0, ``v0 = (1, 0, 0)`` (the velocity of a
    body's frame origin and its angular velocity). Joints: ``revolute`` at every pivot and at
    both ends of every coupler. Outputs: B0's position ``b0x``, ``b0y`` (rocker0.B)."""
    lines = [f"# IFToMM A02: {n} four-bar windows, {2 * n + 1} bodies of 1 m and 1 kg",
             "param L = 1", "param m = 1", "param J = m*L^2/12", "gravity = (0, -9.81)",
             "ground {"]
    lines += [f"    point O{k} = ({k}*L, 0)" for k in range(n + 1)]
    lines.append("}")
    for k in range(n + 1):
        lines.append(f"body rocker{k} {{ guess = ({k}, 0, pi/2)  point B = (L, 0)  "
                     "mass = m  inertia = J  centroid = (L/2, 0)  v0 = (0, 0, -1) }")
    for k in range(n):
        lines.append(f"body coupler{k} {{ guess = ({k}, 1, 0)  point R = (L, 0)  "
                     "mass = m  inertia = J  centroid = (L/2, 0)  v0 = (1, 0, 0) }")
    for k in range(n + 1):
        lines.append(f"joint O{k}: revolute(ground.O{k}, rocker{k}.origin)")
    for k in range(n):
        lines.append(f"joint A{k}: revolute(rocker{k}.B, coupler{k}.origin)")
        lines.append(f"joint C{k}: revolute(rocker{k + 1}.B, coupler{k}.R)")
    lines += [f"simulate t = 0 .. {t1} step {step}, rtol = {rtol}, atol = {atol}",
              'units length = "m", time = "s"',
              "output b0x = rocker0.B.x, b0y = rocker0.B.y"]
    return "\n".join(lines) + "\n"


def a02_rate(n: int = 40, g: float = G) -> float:
    """K / I_eff of the parallelogram branch [s^-2] (unit links): 11.059099378882 for N = 40."""
    return g * ((n + 1) / 2 + n) / ((n + 1) / 3 + n)


def a02_oracle(t, n: int = 40, rtol: float = 1e-13) -> np.ndarray:
    """B0 = (cos theta, sin theta) at the instants ``t`` (an array (len(t), 2)) on the
    parallelogram branch: theta'' = -(K / I_eff) cos theta, theta(0) = pi/2, theta'(0) = -1,
    integrated by scipy's DOP853 at ``rtol`` (atol rtol / 100) with dense output. Checked
    against the reference table A02_TABLE to 1e-9 (tests/test_dynamics_references.py)."""
    from scipy.integrate import solve_ivp

    t = np.atleast_1d(np.asarray(t, dtype=float))
    rate = a02_rate(n)
    sol = solve_ivp(lambda _, y: (y[1], -rate * math.cos(y[0])), (0.0, float(t.max())),
                    [math.pi / 2, -1.0], method="DOP853", rtol=rtol, atol=rtol * 1e-2,
                    t_eval=t)
    if not sol.success:
        raise RuntimeError(sol.message)
    return np.column_stack((np.cos(sol.y[0]), np.sin(sol.y[0])))


def a02_first_horizontal(n: int = 40) -> float:
    """The first instant the rockers lie horizontal (theta = pi from pi/2), by the energy
    integral: theta'^2 = 1 + 2 (K / I_eff)(1 - sin theta), t = int dtheta / |theta'|
    (0.721581024826 s for N = 40)."""
    from scipy.integrate import quad

    rate = a02_rate(n)
    value, _ = quad(lambda th: 1.0 / math.sqrt(1.0 + 2.0 * rate * (1.0 - math.sin(th))),
                    math.pi / 2, math.pi, epsabs=1e-14, epsrel=1e-13)
    return value


# -- the chain ----------------------------------------------------------------------------------

def chain_text(n: int, t1: float = 0.2, step: float = 0.01, rtol: float = 1e-6,
               atol: float = 1e-8, length: float = 1.0, mass: float = 1.0,
               springs: float | None = None) -> str:
    """The ``.mech`` text of a chain of ``n`` uniform links hinged end to end (n bodies);
    with ``springs``, a rotary spring of that stiffness (relaxed straight) at every pin
    between two links.

    Link i: frame at its left pin, at (i l, 0) at t = 0, angle 0, tip ``E`` = (l, 0), centre
    (l/2, 0), inertia m l^2 / 12; link 0 hinged to the ground's origin, link i + 1's frame
    hinged to link i's tip; at rest. Output: the free end (``tipx``, ``tipy``)."""
    last = n - 1
    lines = [f"# a chain of {n} pendulum links hinged end to end, released horizontal",
             f"param l = {length}", f"param m = {mass}", "param J = m*l^2/12",
             "gravity = (0, -9.81)", "ground { }"]
    for i in range(n):
        lines.append(f"body link{i} {{ guess = ({i}*l, 0, 0)  point E = (l, 0)  mass = m  "
                     "inertia = J  centroid = (l/2, 0) }")
    lines.append("joint P0: revolute(ground.origin, link0.origin)")
    for i in range(1, n):
        lines.append(f"joint P{i}: revolute(link{i - 1}.E, link{i}.origin)")
        if springs is not None:
            lines.append(f"force S{i}: rotary_spring(link{i - 1}, link{i}, k = {springs!r})")
    lines += [f"simulate t = 0 .. {t1} step {step}, rtol = {rtol}, atol = {atol}",
              f"output tipx = link{last}.E.x, tipy = link{last}.E.y"]
    return "\n".join(lines) + "\n"


def chain_mass_matrix(theta: np.ndarray, length: float = 1.0, mass: float = 1.0) -> np.ndarray:
    """M(theta) = m l^2 C_jk cos(theta_j - theta_k) of the chain (module docstring)."""
    n = len(theta)
    j = np.arange(n)
    c = n - np.maximum.outer(j, j) - 0.5
    c[j, j] = n - j - 2.0 / 3.0
    return mass * length**2 * c * np.cos(np.subtract.outer(theta, theta))


def chain_rhs(theta: np.ndarray, omega: np.ndarray, length: float = 1.0, mass: float = 1.0,
              g: float = G) -> np.ndarray:
    """theta'' of the chain from Lagrange's equations (module docstring)."""
    n = len(theta)
    j = np.arange(n)
    c = n - np.maximum.outer(j, j) - 0.5
    c[j, j] = n - j - 2.0 / 3.0
    diff = np.subtract.outer(theta, theta)
    m = mass * length**2 * c * np.cos(diff)
    rhs = -(mass * length**2 * (c * np.sin(diff)) @ (omega * omega)
            + mass * g * length * (n - j - 0.5) * np.cos(theta))
    return np.linalg.solve(m, rhs)


def chain_energy(theta: np.ndarray, omega: np.ndarray, length: float = 1.0, mass: float = 1.0,
                 g: float = G) -> float:
    """T + V of the chain (V = m g sum of the centres' heights)."""
    n = len(theta)
    kinetic = 0.5 * omega @ chain_mass_matrix(theta, length, mass) @ omega
    weights = n - np.arange(n) - 0.5
    return float(kinetic + mass * g * length * weights @ np.sin(theta))


def chain_oracle(n: int, t1: float = 0.2, rtol: float = 1e-12, length: float = 1.0,
                 mass: float = 1.0) -> dict:
    """The chain on its n angles, from rest along +x, by scipy's DOP853 at ``rtol`` (atol
    rtol / 100): the free end's position at t1 and the angles there."""
    from scipy.integrate import solve_ivp

    def f(_, y):
        return np.concatenate((y[n:], chain_rhs(y[:n], y[n:], length, mass)))

    sol = solve_ivp(f, (0.0, t1), np.zeros(2 * n), method="DOP853", rtol=rtol,
                    atol=rtol * 1e-2)
    if not sol.success:
        raise RuntimeError(sol.message)
    theta = sol.y[:n, -1]
    return {"tip": length * np.array([np.cos(theta).sum(), np.sin(theta).sum()]),
            "theta": theta, "omega": sol.y[n:, -1], "nfev": int(sol.nfev)}


# -- the stiff pendulum -----------------------------------------------------------------------

#: rod length and mass, bob mass and inertia, the spring's free length (SI units)
PENDULUM = dict(l=1.0, mr=1.0, mb=1.0, jb=0.01, l0=1.0)


def _pendulum_params(k: float) -> list[str]:
    """The stiff pendulum's params (:data:`PENDULUM` and the spring's k), the lines every
    variant of its text starts with."""
    p = PENDULUM
    return [f"param k = {k!r}", f"param l = {p['l']}", f"param mr = {p['mr']}",
            f"param mb = {p['mb']}", f"param jb = {p['jb']}", f"param L0 = {p['l0']}"]


def stiff_pendulum_text(k: float, t1: float = 2.0, step: float = 0.01, rtol: float = 1e-6,
                        atol: float = 1e-8) -> str:
    """The ``.mech`` text of the stiff pendulum with spring stiffness ``k`` (N/m).

    ``rod`` (frame at the pivot, the ground's origin; centre (l/2, 0)) on a ``revolute``;
    ``bob`` (frame at its centre, at (L0, 0) at t = 0) on ``prismatic(rod.origin, bob.origin,
    axis = (1, 0))`` (on the rod's axis, turning with it); ``spring(rod.origin, bob.origin,
    k, length = L0)``. Outputs: ``theta = rod.phi`` and ``s = distance(rod.origin,
    bob.origin)``."""
    return "\n".join([
        f"# a pendulum carrying a bob on a spring of stiffness k = {k:g} N/m",
        *_pendulum_params(k), "gravity = (0, -9.81)", "ground { }",
        "body rod { guess = (0, 0, 0)  mass = mr  inertia = mr*l^2/12  centroid = (l/2, 0) }",
        "body bob { guess = (L0, 0, 0)  mass = mb  inertia = jb }",
        "joint pivot: revolute(ground.origin, rod.origin)",
        "joint slide: prismatic(rod.origin, bob.origin, axis = (1, 0))",
        "force spring: spring(rod.origin, bob.origin, k = k, length = L0)",
        f"simulate t = 0 .. {t1} step {step}, rtol = {rtol}, atol = {atol}",
        "output theta = rod.phi, s = distance(rod.origin, bob.origin)",
    ]) + "\n"


def stiff_pendulum_off_centre_text(k: float) -> str:
    """The stiff pendulum with the rod's frame at its centre: pinned at its point P, the
    slider and the spring from P. The same motion (theta = rod.phi, s = |P bob|), but
    the pin's equations do not fix the rod's frame origin (mechdsl.solve.reduced takes the
    pin's point as the rod's reference point, where they do)."""
    return "\n".join([
        *_pendulum_params(k), "gravity = (0, -9.81)", "ground { }",
        "body rod { guess = (l/2, 0, 0)  point P = (-l/2, 0)  mass = mr  inertia = mr*l^2/12 }",
        "body bob { guess = (L0, 0, 0)  mass = mb  inertia = jb }",
        "joint pivot: revolute(ground.origin, rod.P)",
        "joint slide: prismatic(rod.P, bob.origin, axis = (1, 0))",
        "force spring: spring(rod.P, bob.origin, k = k, length = L0)",
        "simulate t = 0 .. 2 step 0.01, rtol = 1e-6, atol = 1e-8",
        "output theta = rod.phi, s = distance(rod.P, bob.origin)",
    ]) + "\n"


def stiff_pendulum_skew_text(k: float) -> str:
    """The stiff pendulum with the rod's frame turned by -atan2(0.8, 0.6) (its x axis at
    53 degrees to the rod) and the slider's axis (0.6, 0.8) in it: the same motion (theta
    = rod.phi + atan2(0.8, 0.6), s = |rod.origin bob.origin|), but the slider's offset
    across its axis reads in two of the bob's relative coordinates (mechdsl.solve.reduced
    keeps that row as an equation)."""
    return "\n".join([
        *_pendulum_params(k), "param ca = 0.6", "param sa = 0.8",
        "gravity = (0, -9.81)", "ground { }",
        "body rod { guess = (0, 0, -atan2(sa, ca))  mass = mr  inertia = mr*l^2/12  "
        "centroid = (l/2*ca, l/2*sa) }",
        "body bob { guess = (L0, 0, -atan2(sa, ca))  mass = mb  inertia = jb }",
        "joint pivot: revolute(ground.origin, rod.origin)",
        "joint slide: prismatic(rod.origin, bob.origin, axis = (ca, sa))",
        "force spring: spring(rod.origin, bob.origin, k = k, length = L0)",
        "simulate t = 0 .. 2 step 0.01, rtol = 1e-6, atol = 1e-8",
        "output theta = rod.phi + atan2(sa, ca), s = distance(rod.origin, bob.origin)",
    ]) + "\n"


def stiff_pendulum_rhs(t: float, y, k: float, g: float = G) -> np.ndarray:
    """y = (theta, s, theta', s'): Lagrange's equations of the module docstring."""
    p = PENDULUM
    th, s, w, v = y
    inertia = p["mr"] * p["l"] ** 2 / 3 + p["jb"] + p["mb"] * s * s
    wd = (-2 * p["mb"] * s * v * w - (p["mr"] * p["l"] / 2 + p["mb"] * s) * g * math.cos(th)) \
        / inertia
    vd = s * w * w - g * math.sin(th) - k * (s - p["l0"]) / p["mb"]
    return np.array([w, v, wd, vd])


def stiff_pendulum_jac(t: float, y, k: float, g: float = G) -> np.ndarray:
    """The exact Jacobian of stiff_pendulum_rhs (for the implicit methods)."""
    p = PENDULUM
    th, s, w, v = y
    mb, a = p["mb"], p["mr"] * p["l"] / 2
    inertia = p["mr"] * p["l"] ** 2 / 3 + p["jb"] + mb * s * s
    num = -2 * mb * s * v * w - (a + mb * s) * g * math.cos(th)
    jac = np.zeros((4, 4))
    jac[0, 2] = jac[1, 3] = 1.0
    jac[2, 0] = (a + mb * s) * g * math.sin(th) / inertia
    jac[2, 1] = (-2 * mb * v * w - mb * g * math.cos(th)) / inertia \
        - num * 2 * mb * s / inertia**2
    jac[2, 2] = -2 * mb * s * v / inertia
    jac[2, 3] = -2 * mb * s * w / inertia
    jac[3, 0] = -g * math.cos(th)
    jac[3, 1] = w * w - k / mb
    jac[3, 2] = 2 * s * w
    return jac


def stiff_pendulum_energy(y, k: float, g: float = G) -> float:
    """T + V of the stiff pendulum (module docstring)."""
    p = PENDULUM
    th, s, w, v = y
    kinetic = 0.5 * (p["mr"] * p["l"] ** 2 / 3 + p["jb"] + p["mb"] * s * s) * w * w \
        + 0.5 * p["mb"] * v * v
    return kinetic + (p["mr"] * p["l"] / 2 + p["mb"] * s) * g * math.sin(th) \
        + 0.5 * k * (s - p["l0"]) ** 2


def stiff_pendulum_solve(k: float, t1: float = 2.0, method: str = "Radau",
                         rtol: float = 1e-12, atol: float | None = None,
                         jac: bool = True, t_eval=None):
    """solve_ivp on the minimal ODE from theta = 0, s = L0 at rest (atol rtol / 100 unless
    given; the exact Jacobian for the implicit methods)."""
    from scipy.integrate import solve_ivp

    kwargs = {}
    if jac and method in ("Radau", "BDF", "LSODA"):
        kwargs["jac"] = lambda t, y: stiff_pendulum_jac(t, y, k)
    return solve_ivp(lambda t, y: stiff_pendulum_rhs(t, y, k), (0.0, t1),
                     [0.0, PENDULUM["l0"], 0.0, 0.0], method=method, rtol=rtol,
                     atol=rtol * 1e-2 if atol is None else atol, t_eval=t_eval, **kwargs)


def stiff_pendulum_rtol(k: float) -> float:
    """The reference's tolerance: scipy's Radau resolves the radial oscillation at tight
    tolerances at a cost that grows with k (rtol 1e-12 takes 6 s at k = 1e2, 46 s at 1e6 and
    more than 15 min at 1e8), so 1e-10 below k = 1e6 and 1e-8 from there. Cross-checked
    against DOP853 (whose steps the stability limit keeps small): theta(2) agrees to 3e-14
    at k = 1e2 (Radau 1e-12, DOP853 1e-13), 6e-15 at 1e4, 2e-15 at 1e6 (Radau 1e-9, DOP853
    1e-11), 1.6e-11 at 1e8 (Radau 1e-8, DOP853 1e-10): far inside the 1e-5 rad the issue
    asks of the solvers."""
    return 1e-10 if k < 1e6 else 1e-8


def stiff_pendulum_oracle(k: float, t1: float = 2.0, rtol: float | None = None) -> np.ndarray:
    """(theta, s, theta', s') at t1 by scipy's Radau with the exact Jacobian on the minimal
    ODE, at ``rtol`` (default stiff_pendulum_rtol(k)), atol rtol / 100."""
    sol = stiff_pendulum_solve(k, t1, "Radau", stiff_pendulum_rtol(k) if rtol is None else rtol)
    if not sol.success:
        raise RuntimeError(sol.message)
    return sol.y[:, -1]


# -- a four-bar ----------------------------------------------------------------------------------

#: A four-bar under gravity (crank 1 m, coupler 3 m, rocker 2.5 m, its pivots 3 m apart; the
#: tests add springs, bobs, initial states, a span and outputs to it)
FOURBAR = """gravity = (0, -9.81)
ground { point A = (0, 0)  point D = (3, 0) }
body crank { guess = (0, 0, 1.2)  point A = (0, 0)  point B = (1, 0)  mass = 1  inertia = 0.1  centroid = (0.5, 0) }
body coupler { guess = (0.4, 0.9, 0)  point B = (0, 0)  point C = (3, 0)  mass = 2  inertia = 1.5  centroid = (1.5, 0) }
body rocker { guess = (3, 0, 1.5)  point D = (0, 0)  point C = (2.5, 0)  mass = 1.5  inertia = 0.8  centroid = (1.25, 0) }
joint A: revolute(ground.A, crank.A)
joint B: revolute(crank.B, coupler.B)
joint C: revolute(coupler.C, rocker.C)
joint D: revolute(ground.D, rocker.D)
"""


# -- the car axis -------------------------------------------------------------------------------

#: The Test Set's parameters (ex_caraxis.R)
CAR = dict(eps=1e-2, M=10.0, L=1.0, L0=0.5, r=0.1, w=10.0, g=1.0)
#: The Test Set's reference at t = 3 (carsoln in Ex_car.f): xl, yl, xr, yr, their
#: derivatives, lam1, lam2
CAR_REF = np.array([0.4934557842755629e-1, 0.4969894602303324e+0, 0.1041742524885400e+1,
                    0.3739110272652214e+0, -0.7705836840321485e-1, 0.7446866596327776e-2,
                    0.1755681574942899e-1, 0.7703410437794031e+0, -0.4736886750784630e-2,
                    -0.1104680411345730e-2])
CAR_NAMES = ("xl", "yl", "xr", "yr", "vxl", "vyl", "vxr", "vyr", "lam1", "lam2")


def car_axis_text(t1: float = 3.0, step: float = 0.01, rtol: float = 1e-8,
                  atol: float = 1e-10) -> str:
    """The ``.mech`` text of the Test Set's car axis problem (module docstring, item 4).

    The wheels' inertia (1e-6) is arbitrary: their rotations are free and decoupled. The
    road body is massless and fully driven. Outputs: the wheels' positions and velocities
    (CAR_NAMES' first eight) and the forces ``slot.fx, slot.fy`` (on the left wheel) and
    ``axle.fx, axle.fy`` (on the right wheel), from which lam1 and lam2 follow."""
    c = CAR
    return "\n".join([
        "# the Test Set's car axis problem (Mazzia and Magherini, caraxis): index 3, stiff",
        f"param eps = {c['eps']}", f"param M = {c['M']}", f"param L = {c['L']}",
        f"param L0 = {c['L0']}", f"param r = {c['r']}", f"param w = {c['w']}",
        f"param g = {c['g']}", "param m = M*eps^2/2",
        "gravity = (0, -g)", "ground { }",
        "body road { guess = (0, 0, 0)  point B = (L, 0) }",
        "body left { guess = (0, L0, 0)  mass = m  inertia = 1e-6  v0 = (-L0/L, 0, 0) }",
        "body right { guess = (L, L0, 0)  mass = m  inertia = 1e-6  v0 = (-L0/L, 0, 0) }",
        "joint hinge: revolute(ground.origin, road.origin)",
        "drive excite: angle(road) = asin(r*sin(w*t)/L)",
        "joint slot: pin_slot(road.origin, left.origin, axis = (0, 1))",
        "joint axle: distance(left.origin, right.origin, L)",
        "force sl: spring(ground.origin, left.origin, k = 1, length = L0)",
        "force sr: spring(road.B, right.origin, k = 1, length = L0)",
        f"simulate t = 0 .. {t1} step {step}, rtol = {rtol}, atol = {atol}",
        "output xl = left.x, yl = left.y, xr = right.x, yr = right.y, vxl = left.vx, "
        "vyl = left.vy, vxr = right.vx, vyr = right.vy, slot.fx, slot.fy, axle.fx, axle.fy",
    ]) + "\n"


def car_multipliers(xl, yl, xr, yr, slot_f, axle_f, t, c=CAR) -> tuple[float, float]:
    """The Test Set's lam1, lam2 from mechdsl's joint forces at time t: the pin_slot's force
    on the left wheel is lam1 (xb, yb) and the distance joint's on the right wheel
    -2 lam2 (xl - xr, yl - yr), so lam1 = F . (xb, yb) / L^2 and
    lam2 = -F . (xl - xr, yl - yr) / (2 L^2)."""
    yb = c["r"] * math.sin(c["w"] * t)
    xb = math.sqrt(c["L"] ** 2 - yb * yb)
    lam1 = (slot_f[0] * xb + slot_f[1] * yb) / c["L"] ** 2
    lam2 = -(axle_f[0] * (xl - xr) + axle_f[1] * (yl - yr)) / (2 * c["L"] ** 2)
    return lam1, lam2


def car_residuals(t: float, y, yp, c=CAR) -> np.ndarray:
    """The Test Set's residual (carres: delta = [y' - f]_{1..4}, [m y' - f]_{5..8},
    -f_{9,10}) of the state y = CAR_NAMES' ten values and its derivative yp."""
    eps, big_m, length, l0, r, w, g = (c[k] for k in ("eps", "M", "L", "L0", "r", "w", "g"))
    m = big_m * eps * eps / 2
    xl, yl, xr, yr, _, _, _, _, lam1, lam2 = y
    yb = r * math.sin(w * t)
    xb = math.sqrt(length**2 - yb * yb)
    ll, lr = math.hypot(xl, yl), math.hypot(xr - xb, yr - yb)
    f = np.empty(10)
    f[:4] = y[4:8]
    f[4] = (l0 - ll) * xl / ll + lam1 * xb + 2 * lam2 * (xl - xr)
    f[5] = (l0 - ll) * yl / ll + lam1 * yb + 2 * lam2 * (yl - yr) - m * g
    f[6] = (l0 - lr) * (xr - xb) / lr - 2 * lam2 * (xl - xr)
    f[7] = (l0 - lr) * (yr - yb) / lr - 2 * lam2 * (yl - yr) - m * g
    f[8] = xb * xl + yb * yl
    f[9] = (xl - xr) ** 2 + (yl - yr) ** 2 - length**2
    delta = np.empty(10)
    delta[:4] = yp[:4] - f[:4]
    delta[4:8] = m * yp[4:8] - f[4:8]
    delta[8:] = -f[8:]
    return delta


def car_initial(c=CAR) -> np.ndarray:
    """The Test Set's consistent initial values (ex_caraxis.R): positions (0, L0, L, L0),
    velocities (-L0/L, 0, -L0/L, 0), lam = 0."""
    return np.array([0.0, c["L0"], c["L"], c["L0"], -c["L0"] / c["L"], 0.0,
                     -c["L0"] / c["L"], 0.0, 0.0, 0.0])


def scd(value: np.ndarray, ref: np.ndarray) -> float:
    """The Test Set's number of significant correct digits, -log10 max_i |value_i - ref_i|
    / |ref_i| (its mixed measure is the same with these references, none of them zero)."""
    return float(-np.log10(np.max(np.abs(value - ref) / np.abs(ref))))
