"""The bodies' part of M(q) and Q(q, qd): every body at once, by array arithmetic.

Each moving body's terms (Haug 1989, sec. 6.2: :func:`mechdsl.compiled.dynamics.body_terms`,
the function :func:`mechdsl.compiled.dynamics.build` traces body by body) are computed here
on arrays of all the bodies. Traced, they are a dozen scalar operations per body in the
generated code: on a chain of 300 links the evaluation of M and Q took 0.2 ms of Python
arithmetic per state; here they are a dozen numpy operations on arrays of all the bodies.
The force elements' loads, which differ from model to model, stay traced
(``Dynamics.force_load_nodes``).
"""

from __future__ import annotations

import numpy as np

from ..compiled.dynamics import body_terms
from ..plugins.geometry import Body, Rate, Vec

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
        self.m = np.asarray(dynamics.mass[0], dtype=float)
        self.J = np.asarray(dynamics.inertia[0], dtype=float)
        centroid = np.asarray(dynamics.centroid[0], dtype=float)
        self.s = Vec(centroid[:, 0], centroid[:, 1])
        self.g = np.asarray(dynamics.gravity[0], dtype=float)
        self.nb = len(self.m)

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
        phi = q[2::3]
        body = Body(q[0::3], q[1::3], phi, np.cos(phi), np.sin(phi))
        rate = Rate(qd[0::3], qd[1::3], qd[2::3])
        terms, entries, _ = body_terms(body, rate, self.m, self.J, self.s, self.g[0],
                                       self.g[1])
        for c in range(3):
            loads[c::3] += terms[c]
        mass = np.empty((self.nb, BLOCK))
        for k, value in enumerate(entries):
            mass[:, k] = value
        return mass.ravel()
