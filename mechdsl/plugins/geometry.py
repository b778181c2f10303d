"""Planar kinematics for plugin authors: the scalars a type's equations are written on.

Haug's notation: a body's pose is q = (x, y, phi), its rotation matrix A(phi) = [[c, -s],
[s, c]] with c = cos phi, s = sin phi, and B(phi) = dA/dphi = R A with R the rotation by +90
degrees, so that B s' = perp(A s') with perp(v) = (-v_y, v_x).

A type's :meth:`~mechdsl.plugins.ConstraintType.equations` receive

* one :class:`Body` per attached body: ``x``, ``y``, ``phi``, ``c``, ``s``, and
  ``point(s')`` = r + A s' (Haug eq. 2.6.4), ``rotate(v)`` = A v, ``unrotate(v)`` = A^T v,
  ``r`` = (x, y);
* points and vectors as :class:`Vec`: ``+`` and ``-`` of two, ``*`` and ``/`` by a scalar,
  ``dot``, ``cross``, ``perp()``, ``norm()``, ``x``, ``y``;

and a type's optional ``gamma_terms`` one :class:`Rate` (the velocities ``x``, ``y``,
``phi``) per attached body. Their components are scalars: numbers, numpy arrays, or the
traced nodes of :mod:`mechdsl.symbolic` from which mechdsl derives the Jacobian and gamma;
the same arithmetic serves all three.
"""

from __future__ import annotations

import numpy as np


class Vec:
    """A plane vector of two scalars (numbers, numpy arrays or traced nodes: the same
    arithmetic serves all three)."""

    __slots__ = ("x", "y")

    def __init__(self, x, y) -> None:
        self.x, self.y = x, y

    def __add__(self, o: "Vec") -> "Vec":
        return Vec(self.x + o.x, self.y + o.y)

    def __sub__(self, o: "Vec") -> "Vec":
        return Vec(self.x - o.x, self.y - o.y)

    def __neg__(self) -> "Vec":
        return Vec(-self.x, -self.y)

    def __mul__(self, k) -> "Vec":
        return Vec(self.x * k, self.y * k)

    __rmul__ = __mul__

    def __truediv__(self, k) -> "Vec":
        return Vec(self.x / k, self.y / k)

    def dot(self, o: "Vec"):
        """a . b"""
        return self.x * o.x + self.y * o.y

    def cross(self, o: "Vec"):
        """a x b = a_x b_y - a_y b_x (the z component)"""
        return self.x * o.y - self.y * o.x

    def perp(self) -> "Vec":
        """R a = (-a_y, a_x): turned by +90 degrees."""
        return Vec(-self.y, self.x)

    def norm(self):
        """|a|"""
        return np.sqrt(self.x * self.x + self.y * self.y)

    def __iter__(self):
        return iter((self.x, self.y))

    def __repr__(self) -> str:
        return f"Vec({self.x!r}, {self.y!r})"


class Body:
    """A body's pose as scalars, in Haug's notation: r = (x, y), angle phi, and c = cos phi,
    s = sin phi (given, not recomputed: the compiled model computes them once per body).
    A(phi) = [[c, -s], [s, c]]."""

    __slots__ = ("x", "y", "phi", "c", "s")

    def __init__(self, x, y, phi, c, s) -> None:
        self.x, self.y, self.phi, self.c, self.s = x, y, phi, c, s

    @classmethod
    def of(cls, q) -> "Body":
        """From a pose array (..., 3) = (x, y, phi)."""
        q = np.asarray(q, dtype=float)
        return cls(q[..., 0], q[..., 1], q[..., 2], np.cos(q[..., 2]), np.sin(q[..., 2]))

    @property
    def r(self) -> Vec:
        return Vec(self.x, self.y)

    def rotate(self, v: Vec) -> Vec:
        """A s': a vector of the body's frame in the global frame."""
        return Vec(self.c * v.x - self.s * v.y, self.s * v.x + self.c * v.y)

    def unrotate(self, v: Vec) -> Vec:
        """A^T v: a global vector in the body's frame."""
        return Vec(self.c * v.x + self.s * v.y, self.c * v.y - self.s * v.x)

    def point(self, s: Vec) -> Vec:
        """r^P = r + A s' (Haug eq. 2.6.4): where the body point s' is."""
        a = self.rotate(s)
        return Vec(self.x + a.x, self.y + a.y)

    def wrench(self, force: Vec, at: Vec | None = None, torque=0.0) -> tuple:
        """The generalised force (F_x, F_y, n) on the body of a force F at its point s'
        (``at``; the frame origin if None) and a torque: n = (A s') x F + torque, the moment
        about the frame origin (Haug eq. 6.1.12)."""
        if at is None:
            return force.x, force.y, torque
        return force.x, force.y, self.rotate(at).cross(force) + torque


class Rate:
    """A body's velocity as scalars: (xd, yd, phid), named x, y, phi."""

    __slots__ = ("x", "y", "phi")

    def __init__(self, x, y, phi) -> None:
        self.x, self.y, self.phi = x, y, phi

    def point(self, body: Body, s: Vec) -> Vec:
        """rd^P = rd + B s' phid (Haug eq. 2.6.5): the velocity of the point s' of ``body``
        moving at this rate."""
        a = body.rotate(s)
        return Vec(self.x - a.y * self.phi, self.y + a.x * self.phi)

    @classmethod
    def of(cls, qd) -> "Rate":
        qd = np.asarray(qd, dtype=float)
        return cls(qd[..., 0], qd[..., 1], qd[..., 2])
