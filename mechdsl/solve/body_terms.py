"""The bodies' part of M(q) and Q(q, qd): every body at once, by array arithmetic.

Each moving body i, with coordinates q_i = (x_i, y_i, phi_i), mass m_i, moment of inertia
J_i about its centre of mass, the centre of mass at s'_i in its frame and gravity g, has
(Haug 1989, sec. 6.2, the frame off the centre of mass; a_i = A(phi_i) s'_i)

    M_i = [[m, 0, -m a_y], [0, m, m a_x], [-m a_y, m a_x, J + m |s'|^2]],
    Q_i = (m g_x + m a_x phid^2,  m g_y + m a_y phid^2,  a x (m g)),

the terms :func:`mechdsl.compiled.dynamics.build` traces body by body (the same values, to a
rounding). Traced, they are a dozen scalar operations per body in the generated code: on a
chain of 300 links the evaluation of M and Q took 0.2 ms of Python arithmetic per state;
here they are a dozen numpy operations on arrays of all the bodies. The force elements'
loads, which differ from model to model, stay traced (``Dynamics.force_load_nodes``).
"""

from __future__ import annotations

import numpy as np

#: the entries of a body's M in the order ``Dynamics.rows/cols`` lists them
BLOCK = 7
#: the fewest moving bodies for which the arrays pay: a dozen numpy calls cost about 16 us
#: whatever the size, the traced scalar code about 0.7 us per body (measured on chains of
#: 2 to 80 links: 2.7 us against 14.6 at 2 bodies, 15.1 against 18.2 at 20, 29.8 against
#: 16.8 at 40)
FROM_BODIES = 24


class BodyTerms:
    """The bodies' M entries and loads of one variant of ``dynamics`` (module docstring)."""

    def __init__(self, dynamics) -> None:
        m = np.asarray(dynamics.mass[0], dtype=float)
        J = np.asarray(dynamics.inertia[0], dtype=float)
        s = np.asarray(dynamics.centroid[0], dtype=float)
        g = np.asarray(dynamics.gravity[0], dtype=float)
        self.nb = len(m)
        self.m, self.sx, self.sy = m, s[:, 0], s[:, 1]
        self.mgx, self.mgy = m * g[0], m * g[1]
        self.mass = np.empty((self.nb, BLOCK))
        self.mass[:, 0] = self.mass[:, 1] = m
        self.mass[:, 6] = J + m * (self.sx * self.sx + self.sy * self.sy)

    @staticmethod
    def applies(dynamics) -> bool:
        """Whether the arrays pay (at least :data:`FROM_BODIES` bodies) and M holds the
        bodies' blocks only, body by body, with Q's force part traced apart (a Dynamics of
        :func:`~mechdsl.compiled.dynamics.build`)."""
        nb = dynamics.mass.shape[1]
        return (nb >= FROM_BODIES and len(dynamics.force_load_nodes) == dynamics.n == 3 * nb
                and len(dynamics.rows) == BLOCK * nb)

    def evaluate(self, q: np.ndarray, qd: np.ndarray, loads: np.ndarray) -> np.ndarray:
        """M's entries (7 nb,) at q; the bodies' loads at (q, qd) added to ``loads`` (n,)."""
        phi, w = q[2::3], qd[2::3]
        c, s = np.cos(phi), np.sin(phi)
        ax = c * self.sx - s * self.sy
        ay = s * self.sx + c * self.sy
        m = self.m
        max_, may = m * ax, m * ay
        mass = self.mass.copy()
        mass[:, 2] = mass[:, 3] = -may
        mass[:, 4] = mass[:, 5] = max_
        ww = w * w
        loads[0::3] += self.mgx + max_ * ww
        loads[1::3] += self.mgy + may * ww
        loads[2::3] += ax * self.mgy - ay * self.mgx
        return mass.ravel()
