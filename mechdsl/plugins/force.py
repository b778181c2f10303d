"""The contract of a force type: what a force plugin declares and writes.

A force element (``force NAME: TYPE(args)`` in a ``.mech`` file) applies loads to the bodies
it attaches. Its type declares a signature of arguments exactly as a joint type does
(:class:`~mechdsl.plugins.contract.Arg`: points and bodies attach bodies, vectors, scalars,
and functions, whose variable may be the time ``t``), and writes one method,
:meth:`ForceType.loads`: the generalised force on each attached body, Q_k = (F_x, F_y, n),
with n the moment about the body's frame origin (Haug 1989, sec. 6.1: a force F at the body
point s' contributes (F, (A s') x F)), as plain arithmetic of

* ``bodies``: one :class:`~mechdsl.plugins.geometry.Body` per slot (x, y, phi, c, s,
  ``point``, ``rotate``, ``wrench``);
* ``rates``: one :class:`~mechdsl.plugins.geometry.Rate` per slot (the velocities x, y,
  phi, and ``point``: the velocity of a body point);
* ``args``: the other arguments by name;
* ``t``: the time.

Like a joint's equations, the same code runs on numbers, arrays and traced values: mechdsl
traces every force of a mechanism into the model's one compiled evaluation, and can derive
its partial derivatives exactly. A conservative type may also write :meth:`ForceType.energy`
(its potential V, with Q = -V_q where its damping is zero): the energy balance uses it, and
the conformance kit checks the loads against it.
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from .contract import Arg, signature_problems
from .geometry import Body, Rate


class ForceType:
    """Base class of force types: subclass it, set the class attributes and write
    :meth:`loads` (and :meth:`energy` for a conservative element, :meth:`validate` if some
    values are invalid). Instances must be stateless."""

    #: The name used in ``.mech`` files, e.g. ``spring``.
    name: ClassVar[str]
    kind: ClassVar[str] = "force"
    #: The arguments, in positional order.
    signature: ClassVar[tuple[Arg, ...]]
    #: One line shown by ``mechdsl plugins``.
    doc: ClassVar[str] = ""

    @property
    def slots(self) -> tuple[Arg, ...]:
        """The reference arguments, in order: one attached body each."""
        return tuple(a for a in self.signature if a.is_reference)

    def describe(self) -> str:
        """``name(arg: kind, ...)``."""
        return f"{self.name}({', '.join(a.describe() for a in self.signature)})"

    def validate(self, p: Mapping[str, np.ndarray]) -> None:
        """Check argument values (arrays with batch axes); raise ArgError to reject."""

    def loads(self, bodies: tuple[Body, ...], rates: tuple[Rate, ...], args: Any,
              t: Any) -> Sequence[Sequence[Any]]:
        """The generalised force on each attached body, in slot order: a triple (F_x, F_y, n)
        per body, n the moment about the body's frame origin (``Body.wrench`` makes it from
        a force at a point). Loads on the ground are ignored."""
        raise NotImplementedError

    def energy(self, bodies: tuple[Body, ...], args: Any) -> Any:
        """Optional: the potential energy V(q) of a conservative element, whose loads are
        then -dV/dq when its damping is zero."""
        raise NotImplementedError

    def dissipation(self, bodies: tuple[Body, ...], rates: tuple[Rate, ...], args: Any,
                    t: Any) -> Any:
        """Optional: the power the element dissipates (>= 0; a damper's c v^2), whose time
        integral is the output ``dissipated_energy``: then kinetic plus potential energy
        plus the energy dissipated is constant in a free motion."""
        raise NotImplementedError

    def supplies(self, method: str) -> bool:
        """Whether the type writes ``method`` ("energy", "dissipation") itself."""
        return getattr(type(self), method) is not getattr(ForceType, method)


def force_problems(ftype: object) -> list[str]:
    """What is wrong with the declaration of the force type ``ftype`` (empty when none)."""
    problems = []
    if not isinstance(ftype, ForceType):
        return ["a force type must be an instance of a ForceType subclass"]
    name = getattr(ftype, "name", None)
    if not isinstance(name, str) or not name.isidentifier():
        problems.append(f"name {name!r} is not an identifier")
    if getattr(ftype, "kind", None) != "force":
        problems.append("kind must be 'force'")
    problems += signature_problems(getattr(ftype, "signature", None))
    if type(ftype).loads is ForceType.loads:
        problems.append("method loads() is missing: a force type writes its loads")
    return problems
