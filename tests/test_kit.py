"""The conformance kit catches each kind of broken constraint type, with the numbers."""

import numpy as np
import pytest

from mechdsl.plugins import Arg, ConstraintType
from mechdsl.testing import ContractViolation, check_constraint_type


class SameX(ConstraintType):
    """Point P2 has the x coordinate of point P1 (a correct, minimal joint)."""

    name = "same_x"
    signature = (Arg("p1", "point"), Arg("p2", "point"), Arg("gap", "scalar", 0.0))
    n_eq = 1
    invariant = False  # x is a world coordinate

    def equations(self, bodies, args):
        b1, b2 = bodies
        return (b2.point(args.p2).x - b1.point(args.p1).x - args.gap,)


def same_x_jacobian(bodies, args, scale=(1.0, 1.0)):
    """dPhi/dq_k by hand: d(A s')_x/dphi = perp(A s')_x = -(A s')_y; block k times scale[k]."""
    a1, a2 = bodies[0].rotate(args.p1), bodies[1].rotate(args.p2)
    return [[-scale[0], 0.0, a1.y * scale[0]]], [[scale[1], 0.0, -a2.y * scale[1]]]


def same_x_gamma(bodies, rates, args):
    """gamma by hand: A_2 s'_2 phid_2^2 - A_1 s'_1 phid_1^2, its x component."""
    a1, a2 = bodies[0].rotate(args.p1), bodies[1].rotate(args.p2)
    return a2.x * rates[1].phi ** 2 - a1.x * rates[0].phi ** 2


class Supplied(SameX):
    """The same joint with its Jacobian and gamma written by hand: right, so it passes."""

    def jacobian_terms(self, bodies, args):
        return same_x_jacobian(bodies, args)

    def gamma_terms(self, bodies, rates, args):
        return (same_x_gamma(bodies, rates, args),)


def test_a_correct_type_passes():
    check_constraint_type(SameX())


def test_a_type_with_a_correct_supplied_jacobian_and_gamma_passes():
    check_constraint_type(Supplied())


class WrongJacobian(SameX):
    def jacobian_terms(self, bodies, args):
        [a], [b] = same_x_jacobian(bodies, args)
        return [a], [[b[0], b[1], b[2] * 1.001]]


class MissingGammaTerm(SameX):
    def gamma_terms(self, bodies, rates, args):
        a1 = bodies[0].rotate(args.p1)
        return (-a1.x * rates[0].phi ** 2,)  # forgot body 2's term


class WrongCount(SameX):
    def equations(self, bodies, args):
        (phi,) = super().equations(bodies, args)
        return phi, phi  # two values for n_eq = 1


class IgnoresBatchAxes(SameX):
    # A type cannot write this defect in equations(): the batch axes are mechdsl's. An
    # override of the array evaluation is itself refused: the compiled model would not use it.
    def gamma(self, q, qd, p):
        g = super().gamma(q, qd, p)
        return g if g.ndim == 2 else g[..., :1, :]  # right for one batch axis only


class TooFewBlocks(SameX):
    def jacobian_terms(self, bodies, args):
        return same_x_jacobian(bodies, args)[:1]


class NotFinite(SameX):
    def equations(self, bodies, args):
        (phi,) = super().equations(bodies, args)
        return (phi / (1 + np.sign(bodies[0].phi)),)  # inf where phi1 < 0


class FalselyInvariant(SameX):
    invariant = True


class SharesOneGap(SameX):
    # Not writable in equations() either (each constraint's arguments are scalars there);
    # overriding the array evaluation is refused.
    def phi(self, q, p):
        return super().phi(q, {**p, "gap": p["gap"][..., :1]})  # the first gap for all


class RejectsValidValues(SameX):
    def validate(self, p):
        raise ValueError("gap too small")


class BadDeclaration(SameX):
    n_eq = 0
    signature = (Arg("p1", "point"), Arg("if", "point"))


class GuideOfNoVector(SameX):
    guide = ("p1", "p2", "gap")  # gap is a scalar: a guide's line needs a vector


class Branches(SameX):
    def equations(self, bodies, args):
        (phi,) = super().equations(bodies, args)
        if bodies[0].phi:  # a branch on a traced value
            return (phi,)
        return (-phi,)


class UsesMaximum(SameX):
    def equations(self, bodies, args):
        (phi,) = super().equations(bodies, args)
        return (np.maximum(phi, 0.0),)


class GammaOffByOnePartInABillion(SameX):
    def gamma_terms(self, bodies, rates, args):
        return (same_x_gamma(bodies, rates, args) * (1 + 1e-9),)


class JacobianOffByOnePartInABillion(SameX):
    def jacobian_terms(self, bodies, args):
        return same_x_jacobian(bodies, args, scale=(1 + 1e-9, 1 + 1e-9))


class TooManyGammaTerms(SameX):
    def gamma_terms(self, bodies, rates, args):
        return (0.0, 0.0)


@pytest.mark.parametrize("ctype, message", [
    (WrongJacobian(), r"Jacobian block 1 \(attached body 1\) is wrong \(against central "
                      r"differences of phi\): at index \(\d+, 0, 2\) got"),
    (MissingGammaTerm(), r"gamma is wrong \(against d2Phi/dt2 = Phi_q qdd - gamma"),
    (WrongCount(), r"joint type 'same_x': its equations cannot be traced: equations\(\) gave 2 "
                   r"values, expected 1"),
    (IgnoresBatchAxes(), r"declared wrongly: method gamma\(\) is overridden"),
    # a wrong number of supplied terms is named as the supplied terms' fault (issue 31)
    (TooFewBlocks(), r"its supplied jacobian_terms\(\) does not fit the contract: "
                     r"jacobian_terms\(\) gave 1 blocks, expected one per attached body \(2\)"),
    (TooManyGammaTerms(), r"its supplied gamma_terms\(\) does not fit the contract: "
                          r"gamma_terms\(\) gave 2 values, expected 1"),
    (NotFinite(), r"phi is inf at index \(\d+, 0\) for valid input"),
    (FalselyInvariant(), r"\|phi\| after a rigid motion .* is wrong"),
    (SharesOneGap(), r"declared wrongly: method phi\(\) is overridden"),
    (RejectsValidValues(), r"validate\(\) rejects the test's values \(ValueError: gap too small\)"),
    (BadDeclaration(), r"declared wrongly: n_eq must be a positive int.*'if' is a reserved word"),
    (GuideOfNoVector(), r"declared wrongly: guide must be \(P1, P2, AXIS\)"),
    (Branches(), r"its equations cannot be traced: an equation may not branch on or compare the value"),
    (UsesMaximum(), r"its equations cannot be traced: numpy's maximum"),
    (GammaOffByOnePartInABillion(), r"gamma supplied by gamma_terms\(\) is wrong \(against the "
                                    r"gamma derived from its equations\): at index"),
    (JacobianOffByOnePartInABillion(), r"Jacobian block 0 \(attached body 0\) supplied by "
                                       r"jacobian_terms\(\) is wrong \(against the Jacobian "
                                       r"derived from its equations\): at index"),
], ids=lambda x: type(x).__name__ if isinstance(x, ConstraintType) else "")
def test_the_kit_catches_each_kind_of_defect(ctype, message):
    with pytest.raises(ContractViolation, match=message):
        check_constraint_type(ctype)


def test_the_report_carries_the_numbers():
    with pytest.raises(ContractViolation) as info:
        check_constraint_type(WrongJacobian())
    text = str(info.value)
    got = float(text.split(" got ")[1].split(", expected")[0])
    want = float(text.split("expected ")[1].split(" ")[0])
    assert got == pytest.approx(want * 1.001, rel=1e-6)


def test_a_supplied_term_off_by_one_part_in_a_billion_is_reported_with_its_numbers():
    with pytest.raises(ContractViolation) as info:
        check_constraint_type(GammaOffByOnePartInABillion())
    text = str(info.value)
    got = float(text.split(" got ")[1].split(", expected")[0])
    want = float(text.split("expected ")[1].split(" ")[0])
    assert got == pytest.approx(want * (1 + 1e-9), rel=1e-13) and got != want


class Raises(SameX):
    def jacobian_terms(self, bodies, args):
        raise KeyError("p3")


def test_an_exception_in_the_plugin_is_reported_as_a_violation():
    with pytest.raises(ContractViolation, match=r"jacobian_terms\(\) raised KeyError: 'p3'"):
        check_constraint_type(Raises())
