"""The force elements of the standard library. Each writes the generalised loads (F_x, F_y,
n) on the bodies it attaches, n the moment about the body's frame origin (Haug 1989, sec.
6.1); mechdsl traces them into the model's compiled evaluation.

=====================================================  ==========================================
type                                                   loads
=====================================================  ==========================================
``spring(p1, p2, k, length = 0, c = 0)``               with d = r^P2 - r^P1, L = |d|, e = d / L
                                                       and the tension f = k (L - length)
                                                       + c dL/dt (dL/dt = e . (rd^P2 - rd^P1)):
                                                       f e at P1, -f e at P2; V = k (L -
                                                       length)^2 / 2; dissipating c (dL/dt)^2
``rotary_spring(body1, body2, k, angle = 0, c = 0)``   tau = -(k (phi2 - phi1 - angle) + c
                                                       (phid2 - phid1)) on body 2, -tau on body
                                                       1; V = k (phi2 - phi1 - angle)^2 / 2;
                                                       dissipating c (phid2 - phid1)^2
``torque(body, value)``                                a torque value(t) on the body
``point_force(point, fx, fy)``                         the force (fx(t), fy(t)), global axes, at
                                                       a point of a body
=====================================================  ==========================================
"""

from __future__ import annotations

from mechdsl.plugins import Arg, ArgError, ForceType, hookimpl
from mechdsl.plugins.geometry import Vec

import numpy as np

#: The plugin contract this module is written for (mechdsl.plugins.version)
MECHDSL_CONTRACT = 2


def _not_negative(p, *names: str) -> None:
    for name in names:
        if not np.all(np.asarray(p[name]) >= 0):
            raise ArgError(name, f"{name} must not be negative")


class Spring(ForceType):
    name = "spring"
    signature = (Arg("p1", "point", doc="the end on the first body"),
                 Arg("p2", "point", doc="the end on the second body"),
                 Arg("k", "scalar", doc="stiffness (force per length)"),
                 Arg("length", "scalar", 0.0, doc="free length"),
                 Arg("c", "scalar", 0.0, doc="damping (force per speed)"))
    doc = "translational spring-damper between two points"

    def validate(self, p):
        _not_negative(p, "k", "length", "c")

    def loads(self, bodies, rates, args, t):
        b1, b2 = bodies
        r1, r2 = rates
        d = b2.point(args.p2) - b1.point(args.p1)
        length = d.norm()
        e = d / length
        rate = e.dot(r2.point(b2, args.p2) - r1.point(b1, args.p1))
        # k (L - length) e written as k (1 - length / L) d: a spring of free length 0 and
        # no damper pulls with k d, finite where its ends meet (0 / L and c = 0 fold away
        # where they are constants; a length or c that a sweep varies is traced as a
        # param, and where the ends meet its loads are not numbers, as for any length)
        pull = d * (args.k * (1.0 - args.length / length)) + e * (args.c * rate)
        return b1.wrench(pull, args.p1), b2.wrench(-pull, args.p2)

    def energy(self, bodies, args):
        b1, b2 = bodies
        stretch = (b2.point(args.p2) - b1.point(args.p1)).norm() - args.length
        return 0.5 * args.k * stretch * stretch

    def dissipation(self, bodies, rates, args, t):
        b1, b2 = bodies
        r1, r2 = rates
        d = b2.point(args.p2) - b1.point(args.p1)
        rate = (d / d.norm()).dot(r2.point(b2, args.p2) - r1.point(b1, args.p1))
        return args.c * rate * rate


class RotarySpring(ForceType):
    name = "rotary_spring"
    signature = (Arg("body1", "body"), Arg("body2", "body"),
                 Arg("k", "scalar", doc="stiffness (torque per radian)"),
                 Arg("angle", "scalar", 0.0, doc="phi2 - phi1 where it is relaxed"),
                 Arg("c", "scalar", 0.0, doc="damping (torque per radian per time)"))
    doc = "rotational spring-damper between two bodies"

    def validate(self, p):
        _not_negative(p, "k", "c")

    def loads(self, bodies, rates, args, t):
        twist = bodies[1].phi - bodies[0].phi - args.angle
        tau = -(args.k * twist + args.c * (rates[1].phi - rates[0].phi))
        return (0.0, 0.0, -tau), (0.0, 0.0, tau)

    def energy(self, bodies, args):
        twist = bodies[1].phi - bodies[0].phi - args.angle
        return 0.5 * args.k * twist * twist

    def dissipation(self, bodies, rates, args, t):
        spin = rates[1].phi - rates[0].phi
        return args.c * spin * spin


class Torque(ForceType):
    name = "torque"
    signature = (Arg("body", "body"),
                 Arg("value", "function", var="t", doc="the torque, a function of time"))
    doc = "a torque on a body"

    def loads(self, bodies, rates, args, t):
        return ((0.0, 0.0, args.value(t)),)


class PointForce(ForceType):
    name = "point_force"
    signature = (Arg("point", "point", doc="where it acts"),
                 Arg("fx", "function", var="t", doc="x component (global), of time"),
                 Arg("fy", "function", var="t", doc="y component (global), of time"))
    doc = "a force given in the global frame at a point of a body"

    def loads(self, bodies, rates, args, t):
        return (bodies[0].wrench(Vec(args.fx(t), args.fy(t)), args.point),)


@hookimpl
def mechdsl_force_types():
    return [Spring(), RotarySpring(), Torque(), PointForce()]
