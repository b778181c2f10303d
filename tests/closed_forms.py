"""Closed-form kinematics of the test mechanisms, derived by hand (independent truth)."""

from __future__ import annotations

import numpy as np


def slider_crank(r, l, theta, w, al):
    """Slider position, velocity, acceleration for crank angle theta(t) with derivatives
    w = theta', al = theta'': x = r cos(theta) + sqrt(l^2 - r^2 sin^2(theta))."""
    s, c = np.sin(theta), np.cos(theta)
    D = np.sqrt(l * l - r * r * s * s)
    x = r * c + D
    x_th = -r * s - r * r * s * c / D
    x_thth = -r * c - r * r * (c * c - s * s) / D - r**4 * s * s * c * c / D**3
    return x, x_th * w, x_thth * w * w + x_th * al


def start_from_rest(t, t1, alpha):
    """The crank angle, speed and acceleration of the start-from-rest driver."""
    run_up = t < t1
    theta = np.where(run_up, np.pi / 4 + alpha * t**2 / 2,
                     np.pi / 4 + alpha * t1**2 / 2 + alpha * t1 * (t - t1))
    w = np.where(run_up, alpha * t, alpha * t1)
    al = np.where(run_up, alpha, 0.0)
    return theta, w, al


def _e(a):
    return np.stack((np.cos(a), np.sin(a)), axis=-1)


def _perp(v):
    return np.stack((-v[..., 1], v[..., 0]), axis=-1)


def _solve2(c1, c2, rhs):
    """Solve [c1 c2] x = rhs for 2-vectors by Cramer's rule."""
    det = c1[..., 0] * c2[..., 1] - c1[..., 1] * c2[..., 0]
    x1 = (rhs[..., 0] * c2[..., 1] - rhs[..., 1] * c2[..., 0]) / det
    x2 = (c1[..., 0] * rhs[..., 1] - c1[..., 1] * rhs[..., 0]) / det
    return x1, x2


def four_bar(a, b, c, d, th2, w2, al2):
    """Open four-bar O2-A-B-O4 with O2 = (0, 0), O4 = (d, 0), B above the line A-O4.

    Returns the coupler angle th3 (A -> B), the rocker angle th4 (O4 -> B) and their first
    and second derivatives, from the loop a e2 + b e3 = d e0 + c e4 differentiated twice.
    """
    A = a * _e(th2)
    f = np.array([d, 0.0]) - A
    L = np.linalg.norm(f, axis=-1)
    beta = np.arccos((b * b + L * L - c * c) / (2 * b * L))
    th3 = np.arctan2(f[..., 1], f[..., 0]) + beta
    B = A + b * _e(th3)
    th4 = np.arctan2(B[..., 1], B[..., 0] - d)
    # velocity: b w3 perp(e3) - c w4 perp(e4) = -a w2 perp(e2)
    p2, p3, p4 = _perp(_e(th2)), _perp(_e(th3)), _perp(_e(th4))
    w2 = np.broadcast_to(w2, th2.shape)[..., None]
    w3, w4 = _solve2(b * p3, -c * p4, -a * w2 * p2)
    # acceleration: b al3 perp(e3) - c al4 perp(e4) = a w2^2 e2 - a al2 perp(e2)
    #                                                 + b w3^2 e3 - c w4^2 e4
    al2 = np.broadcast_to(al2, th2.shape)[..., None]
    rhs = (a * w2**2 * _e(th2) - a * al2 * p2 + b * (w3**2)[..., None] * _e(th3)
           - c * (w4**2)[..., None] * _e(th4))
    al3, al4 = _solve2(b * p3, -c * p4, rhs)
    return (th3, w3, al3), (th4, w4, al4)


def angle_error(a, b):
    """|a - b| modulo 2 pi."""
    return np.abs(np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b)))))
