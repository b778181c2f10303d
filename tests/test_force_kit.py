"""The conformance kit catches what is wrong with a force type: loads that are not the
gradient of the energy the type claims, a branch on data, a wrong count, a load that is not
a number; the declaration is checked first."""

import numpy as np
import pytest

from mechdsl.plugins import Arg, ForceType
from mechdsl.testing import ContractViolation, check_force_type


class GoodSpring(ForceType):
    """A zero-length spring between two points: loads k d at P1, -k d at P2, V = k |d|^2 / 2."""

    name = "good_spring"
    signature = (Arg("p1", "point"), Arg("p2", "point"), Arg("k", "scalar"))

    def loads(self, bodies, rates, args, t):
        d = bodies[1].point(args.p2) - bodies[0].point(args.p1)
        return bodies[0].wrench(d * args.k, args.p1), bodies[1].wrench(-d * args.k, args.p2)

    def energy(self, bodies, args):
        d = bodies[1].point(args.p2) - bodies[0].point(args.p1)
        return 0.5 * args.k * d.dot(d)


class WrongSign(GoodSpring):
    name = "wrong_sign"

    def loads(self, bodies, rates, args, t):
        a, b = super().loads(bodies, rates, args, t)
        return a, (b[0], b[1], -b[2])  # the moment on the second body flipped


class WrongEnergy(GoodSpring):
    name = "wrong_energy"

    def energy(self, bodies, args):
        return 2 * super().energy(bodies, args)


class Branching(GoodSpring):
    name = "branching"

    def loads(self, bodies, rates, args, t):
        if bodies[0].x > 0:  # a branch on a traced value
            return super().loads(bodies, rates, args, t)
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)


class OneTriple(GoodSpring):
    name = "one_triple"

    def loads(self, bodies, rates, args, t):
        return super().loads(bodies, rates, args, t)[:1]


class NotANumber(GoodSpring):
    name = "not_a_number"

    def loads(self, bodies, rates, args, t):
        a, b = super().loads(bodies, rates, args, t)
        return a, (b[0], b[1], np.log(-1.0 - 0 * b[2]))


class NoLoads(ForceType):
    name = "no_loads"
    signature = (Arg("body", "body"),)


class NoVariable(GoodSpring):
    name = "no_variable"
    signature = (*GoodSpring.signature, Arg("f", "function"))  # a function of what?


def test_a_correct_type_passes():
    check_force_type(GoodSpring())


@pytest.mark.parametrize("ftype, message", [
    (WrongSign(), "not -dV/dq"),
    (WrongEnergy(), "not -dV/dq"),
    (Branching(), "cannot be traced|branch"),
    (OneTriple(), "one \\(F_x, F_y, n\\) triple per attached body"),
    (NotANumber(), "nan"),
    (NoLoads(), "loads\\(\\) is missing"),
    (NoVariable(), "needs var"),
], ids=lambda x: getattr(x, "name", ""))
def test_the_kit_catches(ftype, message):
    with pytest.raises(ContractViolation, match=message):
        check_force_type(ftype)
