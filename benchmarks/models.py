"""Benchmark mechanisms with closed forms: the seed slider-crank and a row of parallelograms.

The row of N parallelograms (2N + 1 bodies): N + 1 equal cranks of length ``a`` pivoted on
the ground at (i d, 0), i = 0..N, and N couplers, coupler i pinned to the tips of cranks i
and i + 1. Every crank turns with the driven first one, theta(t) = pi/2 + (pi/4) sin(2 pi t)
(away from the change points theta = 0, pi); every coupler translates. Closed form:

    crank i:   (x, y, phi) = (i d, 0, theta)
    coupler i: (x, y, phi) = (i d + a cos theta, a sin theta, 0)

with velocities and accelerations by differentiating in t.
"""

from __future__ import annotations

import numpy as np

A_CRANK = 0.5
D_PITCH = 1.0
SLIDER_CRANK = dict(r=2.0, l=3.5, omega=4 * np.pi, phi0=np.pi / 4)


def slider_crank_exact(t: np.ndarray, r: float = 2.0, l: float = 3.5,
                       omega: float = 4 * np.pi) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slider x, vx, ax for the crank angle pi/4 + omega t (closed form of the loop)."""
    th = np.pi / 4 + omega * t
    s, c = np.sin(th), np.cos(th)
    root = np.sqrt(l * l - r * r * s * s)
    x_th = -r * s - r * r * s * c / root
    x_thth = -r * c - r * r * (c * c - s * s) / root - r**4 * s * s * c * c / root**3
    return r * c + root, x_th * omega, x_thth * omega**2


def theta(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The chain's crank angle and its first two time derivatives."""
    w = 2 * np.pi
    return (np.pi / 2 + np.pi / 4 * np.sin(w * t), np.pi / 4 * w * np.cos(w * t),
            -np.pi / 4 * w * w * np.sin(w * t))


def chain_exact(t: np.ndarray, a: float = A_CRANK) -> dict[str, np.ndarray]:
    """The last coupler's x, vx, ax and the last crank's phi, omega, alpha, by closed form
    (the same for every coupler up to a shift in x)."""
    th, w, al = theta(t)
    c, s = np.cos(th), np.sin(th)
    return {"x": a * c, "vx": -a * s * w, "ax": -a * (c * w * w + s * al),
            "phi": th, "omega": w, "alpha": al}


def chain_text(n_loops: int, t1: float = 1.0, step: float = 0.01, a: float = A_CRANK,
               d: float = D_PITCH) -> str:
    """The ``.mech`` text of a row of ``n_loops`` parallelograms (2 n_loops + 1 bodies)."""
    th0 = np.pi / 2
    lines = [f"# a row of {n_loops} parallelograms: {2 * n_loops + 1} bodies",
             f"param a = {a}", f"param d = {d}", "ground {"]
    lines += [f"    point O{i} = ({i}*d, 0)" for i in range(n_loops + 1)]
    lines.append("}")
    for i in range(n_loops + 1):
        lines.append(f"body crank{i} {{ guess = ({i * d}, 0, {th0:.6f})  point A = (a, 0) }}")
    for i in range(n_loops):
        x = i * d + a * np.cos(th0)
        lines.append(f"body coupler{i} {{ guess = ({x:.6f}, {a * np.sin(th0):.6f}, 0)  "
                     "point R = (d, 0) }")
    for i in range(n_loops + 1):
        lines.append(f"joint O{i}: revolute(ground.O{i}, crank{i}.origin)")
    for i in range(n_loops):
        lines.append(f"joint L{i}: revolute(crank{i}.A, coupler{i}.origin)")
        lines.append(f"joint R{i}: revolute(crank{i + 1}.A, coupler{i}.R)")
    last = n_loops - 1
    lines += ["drive motor: angle(crank0) = pi/2 + pi/4*sin(2*pi*t)",
              f"simulate t = 0 .. {t1} step {step}",
              f"output coupler{last}.x, coupler{last}.vx, coupler{last}.ax, "
              f"crank{n_loops}.phi, crank{n_loops}.omega, crank{n_loops}.alpha"]
    return "\n".join(lines) + "\n"
