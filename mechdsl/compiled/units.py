"""Units of the outputs: dimensions, their names from the model's ``units`` statement, and the
dimension of an output expression.

mechdsl computes in whatever consistent units the model is written in; the ``units``
statement names them (``units length = "m", time = "s", mass = "kg"``) so that every column,
axis, summary line and reduction carries its unit. Only the angle changes numbers: angles are
written and computed in radians, and ``angle = "deg"`` reports every output of angle
dimension in degrees (each column scaled by (180/pi)^a, a its angle exponent).

A dimension is a tuple of exponents of (length, time, mass, angle). Force is mass length
time^-2; with ``force = "N"`` it is named so, and where length, time and mass are m, s and kg
it is N by itself (and energy J, power W); a unit with a time in its denominator is written
with the force (a damping rate N*s/m, not kg/s), a mass alone with the mass. A derived unit is written with its positive
exponents first and the others after one '/': ``N*s/m``, ``rad/s^2``, ``kg/(m*s^2)``. A
small table rather than a units library (pint): outputs need names, not conversions, and the
one conversion (degrees) is a factor.

The dimension of an expression (:func:`expr_dim`) follows its arithmetic; numbers and params
carry none (None: they agree with anything, as ``slider.x - 2`` means two lengths), functions
of angles (sin, exp, ...) are pure numbers, atan2 and the inverse functions give angles. A
sum or comparison of two different known dimensions (an angle added to a length) is a
warning, located at the operator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Callable, Mapping

from ..errors import Span
from ..grammar import expr as E
from ..grammar.model import ANGLE_UNITS as _ANGLE_NAMES

#: exponents of (length, time, mass, angle)
Dim = tuple[Fraction, Fraction, Fraction, Fraction]


def dim(length: float = 0, time: float = 0, mass: float = 0, angle: float = 0) -> Dim:
    """The dimension length^a time^b mass^c angle^d."""
    return tuple(Fraction(x).limit_denominator(1000) for x in (length, time, mass, angle))


NUMBER, LENGTH, TIME, MASS, ANGLE = dim(), dim(1), dim(0, 1), dim(0, 0, 1), dim(0, 0, 0, 1)
FORCE = dim(1, -2, 1)
TORQUE = ENERGY = dim(2, -2, 1)
POWER = dim(2, -3, 1)

#: the dimension of each quantity a reference names (``rod.phi``, ``pivot.fx``, ...)
QUANTITY_DIMS: Mapping[str, Dim] = {
    "x": LENGTH, "y": LENGTH, "phi": ANGLE,
    "vx": dim(1, -1), "vy": dim(1, -1), "omega": dim(0, -1, 0, 1),
    "ax": dim(1, -2), "ay": dim(1, -2), "alpha": dim(0, -2, 0, 1),
    "fx": FORCE, "fy": FORCE, "force": FORCE, "torque": TORQUE, "power": POWER,
    "kinetic_energy": ENERGY, "potential_energy": ENERGY, "dissipated_energy": ENERGY,
    "dissipated_power": POWER,
}

#: the angle units a model may report in, with the factor from radians
ANGLE_UNITS = {"rad": 1.0, "deg": 180.0 / math.pi}
assert set(ANGLE_UNITS) == set(_ANGLE_NAMES)


def _plain(d: Dim) -> Dim:
    """``d`` with the angle dropped where a length or a mass is in it: the radian is a pure
    number (SI), kept only to label the angles and their rates (rad, rad/s): a torque times
    an angular velocity is a power (W), an arc length r phi a length (and so not scaled
    when angles are reported in degrees)."""
    return d[:3] + (Fraction(0),) if d[3] and (d[0] or d[2]) else d


def mul(a: Dim | None, b: Dim | None) -> Dim | None:
    return None if a is None or b is None else _plain(tuple(x + y for x, y in zip(a, b)))


def div(a: Dim | None, b: Dim | None) -> Dim | None:
    return None if a is None or b is None else _plain(tuple(x - y for x, y in zip(a, b)))


def power(a: Dim | None, k: float) -> Dim | None:
    return None if a is None else \
        _plain(tuple(x * Fraction(k).limit_denominator(1000) for x in a))


@dataclass(frozen=True)
class Units:
    """The names of the model's units ("" where not given; angles are radians unless
    ``angle = "deg"``)."""

    length: str = ""
    time: str = ""
    mass: str = ""
    angle: str = "rad"
    force: str = ""

    @classmethod
    def of(cls, pairs) -> "Units":
        """From a model's ``units`` (dimension, name) pairs."""
        return cls(**dict(pairs))

    @property
    def si(self) -> bool:
        return (self.length, self.time, self.mass) == ("m", "s", "kg")

    @property
    def force_name(self) -> str:
        return self.force or ("N" if self.si else "")

    def scale(self, d: Dim | None) -> float:
        """The factor from the computed value (radians) to the reported one."""
        if d is None or not d[3]:
            return 1.0
        return ANGLE_UNITS[self.angle] ** float(d[3])

    def label(self, d: Dim | None, kind: str = "") -> str:
        """The unit of dimension ``d`` ("" where a name it needs is not given, or a pure
        number); ``kind`` "energy" names J (the same dimension as a torque, N*m)."""
        if d is None or not any(d):
            return ""
        length, time, mass, angle = d
        if self.si and angle == 0:
            if d == ENERGY and kind == "energy":
                return "J"
            if d == POWER:
                return "W"
        parts: list[tuple[str, Fraction]] = []
        if mass:
            if self.force_name and (time < 0 or not self.mass):
                # a quantity with a time in its denominator is written with the force
                # (N*s/m, not kg/s); a mass alone stays a mass
                parts.append((self.force_name, mass))
                length, time = length - mass, time + 2 * mass
            else:
                parts.append((self.mass, mass))
        parts += [(self.length, length), (self.angle, angle), (self.time, time)]
        parts = [(name, e) for name, e in parts if e]
        if any(not name for name, _ in parts):
            return ""
        top = [_factor(n, e) for n, e in parts if e > 0]
        bottom = [_factor(n, -e) for n, e in parts if e < 0]
        text = "*".join(top) or "1"
        if bottom:
            below = "*".join(bottom)
            text += "/" + (f"({below})" if len(bottom) > 1 else below)
        return text

    def quantity(self, name: str) -> str:
        """The unit of a named quantity (``phi``, ``fx``, ``kinetic_energy``)."""
        q = name.rsplit(".", 1)[-1]
        return self.label(QUANTITY_DIMS[q], "energy" if q.endswith("energy") else "")


def _factor(name: str, e: Fraction) -> str:
    if e == 1:
        return name
    return f"{name}^{e.numerator}" if e.denominator == 1 else f"{name}^{float(e):g}"


#: functions of an angle (or a pure number) whose result is a pure number
_TRIG = {"sin", "cos", "tan"}
#: functions whose result is a pure number
_NUMBER_FUNCS = {"exp", "log", "sign"}
#: functions whose result is an angle
_ANGLE_FUNCS = {"asin", "acos", "atan", "atan2"}
#: functions whose result has their arguments' dimension, all of them agreeing
_SAME_FUNCS = {"abs", "min", "max"}
#: the named constants (pi): pure numbers that scale a quantity without changing its unit
CONSTANTS = frozenset(E.CONSTANTS)
#: a number written in the text (or a constant): it takes the unit of what it is added to
_LITERAL = "literal"


def expr_dim(e: E.Expr, name_dim: Callable[[str], Dim | None],
             warn: Callable[[str, Span | None], None], units: Units) -> Dim | None:
    """The dimension of expression ``e`` (None where it is not known: a param, whose unit
    the model does not say, times a quantity); a name has ``name_dim``'s (None for a param),
    ``t`` is a time, a number written in the text agrees with anything it
    is added to. Mismatches of known dimensions go to ``warn(message, span)``."""
    dims: dict[int, object] = {}

    def agree(a, b, node, what: str):
        if a is None or b is None:  # a param's unit is not known: nor is the sum's
            return None
        if a == _LITERAL or a == b:
            return b
        if b == _LITERAL:
            return a
        warn(f"{what} {_describe(a, units)} and {_describe(b, units)}",
             getattr(node, "span", None))
        return None

    for node in E.postorder(e):
        kids = [dims[id(k)] for k in E.children(node)]
        if isinstance(node, E.Num):
            d = _LITERAL
        elif isinstance(node, E.Name):
            d = TIME if node.id == "t" else _LITERAL if node.id in CONSTANTS else \
                name_dim(node.id)
        elif isinstance(node, E.Unary):
            d = kids[0] if node.op == "-" else NUMBER
        elif isinstance(node, E.Binary):
            a, b = kids
            if node.op in "+-":
                d = agree(a, b, node, "adding" if node.op == "+" else "subtracting")
            elif a is None or b is None:
                d = None
            elif node.op == "*":
                d = b if a == _LITERAL else a if b == _LITERAL else mul(a, b)
            elif node.op == "/":
                d = a if b == _LITERAL else power(b, -1) if a == _LITERAL else div(a, b)
            else:  # ^: a number for an exponent
                k = node.right.value if isinstance(node.right, E.Num) else None
                d = a if a in (_LITERAL, NUMBER) else power(a, k) if k is not None else None
        elif isinstance(node, E.Compare):
            agree(*kids, node, "comparing")
            d = NUMBER
        elif isinstance(node, E.Logic):
            d = NUMBER
        elif isinstance(node, E.Cond):
            d = agree(kids[1], kids[2], node, "the branches of 'if' are")
        elif isinstance(node, E.Call):
            first = kids[0] if kids else None
            if node.func == "sqrt":
                d = first if first in (None, _LITERAL) else power(first, 0.5)
            elif node.func in _TRIG:
                if first not in (None, _LITERAL, ANGLE, NUMBER):
                    warn(f"{node.func} of {_describe(first, units)}: it takes an angle",
                         node.span)
                d = NUMBER
            elif node.func in _NUMBER_FUNCS:
                d = NUMBER
            elif node.func in _ANGLE_FUNCS:
                if node.func == "atan2":
                    agree(kids[0], kids[1], node, "atan2 of")
                d = ANGLE
            elif node.func in _SAME_FUNCS and kids:
                d = first
                for other in kids[1:]:
                    d = agree(d, other, node, f"{node.func} of")
            else:
                d = None
        else:  # a table's value: the unit of its data is not known
            d = None
        dims[id(node)] = d
    out = dims[id(e)]
    return NUMBER if out == _LITERAL else out


def _describe(d: Dim, units: Units) -> str:
    """'a length (m)', 'an angle (rad)', or 'a quantity of unit N*s/m'."""
    names = {LENGTH: "a length", ANGLE: "an angle", TIME: "a time", NUMBER: "a pure number",
             FORCE: "a force", dim(1, -1): "a velocity", dim(1, -2): "an acceleration",
             dim(0, -1, 0, 1): "an angular velocity", dim(0, -2, 0, 1): "an angular acceleration",
             TORQUE: "a torque or an energy", POWER: "a power", MASS: "a mass"}
    unit = units.label(d)
    what = names.get(d, "a quantity")
    return f"{what} ({unit})" if unit else what
