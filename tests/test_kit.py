"""The conformance kit catches each kind of broken constraint type, with the numbers."""

import numpy as np
import pytest

from mechdsl.plugins import Arg, ConstraintType
from mechdsl.plugins.geometry import block, perp, rotate
from mechdsl.testing import ContractViolation, check_constraint_type


class SameX(ConstraintType):
    """Point P2 has the x coordinate of point P1 (a correct, minimal joint)."""

    name = "same_x"
    signature = (Arg("p1", "point"), Arg("p2", "point"), Arg("gap", "scalar", 0.0))
    n_eq = 1
    invariant = False  # x is a world coordinate

    def phi(self, q, p):
        a1, a2 = rotate(q[0][..., 2], p["p1"]), rotate(q[1][..., 2], p["p2"])
        return (q[1][..., 0] + a2[..., 0] - q[0][..., 0] - a1[..., 0] - p["gap"])[..., None]

    def jacobian(self, q, p):
        b1, b2 = np.broadcast_arrays(perp(rotate(q[0][..., 2], p["p1"])),
                                     perp(rotate(q[1][..., 2], p["p2"])))
        e = np.zeros(b1.shape[:-1] + (1, 2))
        e[..., 0, 0] = 1.0
        return block(-e, -b1[..., :1]), block(e, b2[..., :1])

    def gamma(self, q, qd, p):
        a1, a2 = rotate(q[0][..., 2], p["p1"]), rotate(q[1][..., 2], p["p2"])
        w1, w2 = qd[0][..., 2], qd[1][..., 2]
        return (a2[..., 0] * w2**2 - a1[..., 0] * w1**2)[..., None]


def test_a_correct_type_passes():
    check_constraint_type(SameX())


class WrongJacobian(SameX):
    def jacobian(self, q, p):
        a, b = super().jacobian(q, p)
        return a, b * np.array([1.0, 1.0, 1.001])


class MissingGammaTerm(SameX):
    def gamma(self, q, qd, p):
        a1 = rotate(q[0][..., 2], p["p1"])
        return (-a1[..., 0] * qd[0][..., 2] ** 2)[..., None]  # forgot body 2's term


class WrongShape(SameX):
    def phi(self, q, p):
        return super().phi(q, p)[..., 0]  # drops the equation axis


class IgnoresBatchAxes(SameX):
    def gamma(self, q, qd, p):
        g = super().gamma(q, qd, p)
        return g if g.ndim == 2 else g[..., :1, :]  # right for one batch axis only


class TooFewBlocks(SameX):
    def jacobian(self, q, p):
        return super().jacobian(q, p)[:1]


class NotFinite(SameX):
    def phi(self, q, p):
        return super().phi(q, p) / (q[0][..., 2:3] > 0)  # inf where phi1 <= 0


class FalselyInvariant(SameX):
    invariant = True


class SharesOneGap(SameX):
    def phi(self, q, p):
        return super().phi(q, {**p, "gap": p["gap"][..., :1]})  # the first gap for all


class RejectsValidValues(SameX):
    def validate(self, p):
        raise ValueError("gap too small")


class BadDeclaration(SameX):
    n_eq = 0
    signature = (Arg("p1", "point"), Arg("if", "point"))


@pytest.mark.parametrize("ctype, message", [
    (WrongJacobian(), r"Jacobian block 1 \(attached body 1\) is wrong \(against central "
                      r"differences of phi\): at index \(\d+, 0, 2\) got"),
    (MissingGammaTerm(), r"gamma is wrong \(against d2Phi/dt2 = Phi_q qdd - gamma"),
    (WrongShape(), r"phi has shape \(24,\), expected \(24, 1\)"),
    (IgnoresBatchAxes(), r"gamma with 2 batch axes has shape"),
    (TooFewBlocks(), r"jacobian returned 1 blocks for 2 attached bodies"),
    (NotFinite(), r"phi is inf at index \(\d+, 0\) for valid input"),
    (FalselyInvariant(), r"\|phi\| after a rigid motion .* is wrong"),
    (SharesOneGap(), r"phi of sample \d+ computed alone \(each constraint must use its own"),
    (RejectsValidValues(), r"validate\(\) rejects the test's values \(ValueError: gap too small\)"),
    (BadDeclaration(), r"declared wrongly: n_eq must be a positive int.*'if' is a reserved word"),
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


class Raises(SameX):
    def jacobian(self, q, p):
        raise KeyError("p3")


def test_an_exception_in_the_plugin_is_reported_as_a_violation():
    with pytest.raises(ContractViolation, match=r"jacobian\(\) raised KeyError: 'p3'"):
        check_constraint_type(Raises())
