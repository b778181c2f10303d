"""The contract of a constraint type: what a joint or drive plugin declares and writes.

A constraint type contributes ``n_eq`` rows to Haug's constraint vector Phi(q, t). It declares
a signature of arguments; every *reference* argument (a point ``body.P`` or a ``body``) attaches
one body, called a *slot*. It writes its equations once, in :meth:`ConstraintType.equations`,
as plain arithmetic on named scalars:

* ``bodies``: one :class:`~mechdsl.plugins.geometry.Body` per slot, with its ``x``, ``y``,
  ``phi`` and ``c = cos phi``, ``s = sin phi``, and the helpers ``point(s')`` = r + A s' and
  ``rotate(v)`` = A v;
* ``args``: the other arguments by name (``args.p1``): a point's coordinates in its body's
  frame and a vector as :class:`~mechdsl.plugins.geometry.Vec`, a scalar as a scalar, a
  function (an expression of one variable written by the user) as a callable.

From that one source mechdsl derives, exactly (symbolic differentiation of the traced
arithmetic, :mod:`mechdsl.symbolic`), the Jacobian Phi_q and gamma = -(Phi_q qd)_q qd, and
fuses every constraint of a mechanism into one compiled evaluation. The same source runs on
numpy arrays: :meth:`ConstraintType.phi`, :meth:`~ConstraintType.jacobian` and
:meth:`~ConstraintType.gamma` evaluate a type on its own (poses ``(..., 3)`` per slot,
arguments with broadcasting batch axes), which is how the conformance kit
(:mod:`mechdsl.testing`) tests it.

A type may also supply its own Jacobian (:meth:`~ConstraintType.jacobian_terms`) or gamma
(:meth:`~ConstraintType.gamma_terms`), in the same scalar form; they are then used, and the
kit checks them against the derived ones to round-off.

A *drive* type (``kind = "drive"``) computes one measure g(q) (``n_eq == 1``) and is used as
``drive NAME: TYPE(args) = f(t)``: the core adds the time function, Phi = g(q) - f(t),
nu = f'(t), gamma = -(g_q qd)_q qd + f''(t). Joint types are time-independent: nu = 0.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
from typing import TYPE_CHECKING, Any, ClassVar, Mapping, Protocol, Sequence

import numpy as np

from .geometry import Body, Rate

if TYPE_CHECKING:
    from .derived import Derived

KINDS = ("joint", "drive")
ARG_KINDS = ("point", "body", "vector", "scalar", "function")
#: Words an argument name cannot be: the language's reserved words (``body`` and ``point``
#: may still name arguments, the grammar allows them before ``=``).
RESERVED_ARG_NAMES = frozenset({"param", "guess", "joint", "drive", "simulate", "output",
                                "sweep", "plugin", "if", "then", "else", "and", "or", "not"})


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


#: Default of an argument that must be given.
REQUIRED: Any = _Required()


@dataclass(frozen=True)
class Arg:
    """One argument of a constraint type's signature.

    ``kind`` is ``"point"`` (a reference ``body.P``; attaches the body), ``"body"`` (a body
    name; attaches it), ``"vector"`` (``(x, y)``), ``"scalar"`` (an expression of params) or
    ``"function"`` (an expression of params and of the variable ``var``, e.g. a cam profile
    ``2 + 0.5*sin(psi)``). Vector and scalar arguments may have a default; references and
    functions may not.
    """

    name: str
    kind: str
    default: Any = REQUIRED
    doc: str = ""
    var: str | None = None

    @property
    def is_reference(self) -> bool:
        return self.kind in ("point", "body")

    def describe(self) -> str:
        """``name: kind``, ``name: kind = default`` or ``name: function(var)``."""
        if self.kind == "function":
            return f"{self.name}: function({self.var})"
        if self.default is REQUIRED:
            return f"{self.name}: {self.kind}"
        d = self.default
        if isinstance(d, (tuple, list)):
            d = "(" + ", ".join(f"{x:g}" for x in d) + ")"
        else:
            d = f"{d:g}"
        return f"{self.name}: {self.kind} = {d}"


class Function(Protocol):
    """What a plugin receives for a ``function`` argument: f and its exact first and second
    derivatives, evaluated elementwise on an array of the type's batch shape."""

    def __call__(self, x: np.ndarray) -> np.ndarray: ...

    def d1(self, x: np.ndarray) -> np.ndarray: ...

    def d2(self, x: np.ndarray) -> np.ndarray: ...


class ArgError(ValueError):
    """Raised by :meth:`ConstraintType.validate` to reject the value of argument ``arg``."""

    def __init__(self, arg: str, message: str) -> None:
        super().__init__(message)
        self.arg = arg
        self.message = message


class Args(dict):
    """A constraint's argument values by name, also as attributes: ``args.p1``. Points and
    vectors are :class:`~mechdsl.plugins.geometry.Vec`, scalars are scalars, functions are
    callables with exact derivatives (``f(x)``, ``f.d1(x)``)."""

    def __getattr__(self, name: str):
        try:
            return self[name]
        except KeyError:
            raise AttributeError(name) from None


class ConstraintType:
    """Base class of joint and drive types: subclass it, set the class attributes and write
    :meth:`equations` (and :meth:`validate` if some values are invalid). Instances must be
    stateless: one instance serves every constraint of the type.

    mechdsl derives the Jacobian and gamma from :meth:`equations` exactly; a type may supply
    its own (:meth:`jacobian_terms`, :meth:`gamma_terms`), which are then used, and which the
    conformance kit checks against the derived ones to round-off. The array methods
    :meth:`phi`, :meth:`jacobian` and :meth:`gamma` evaluate a type on its own, for its
    tests; they are not meant to be overridden.
    """

    #: The name used in ``.mech`` files, e.g. ``revolute``.
    name: ClassVar[str]
    #: ``"joint"`` or ``"drive"``.
    kind: ClassVar[str] = "joint"
    #: The arguments, in positional order.
    signature: ClassVar[tuple[Arg, ...]]
    #: Number of equations (rows of Phi) per constraint; 1 for a drive.
    n_eq: ClassVar[int]
    #: One line shown by ``mechdsl plugins``.
    doc: ClassVar[str] = ""
    #: Whether |Phi| is unchanged when every attached body undergoes the same rigid motion
    #: (true of joints, which constrain relative positions; false of drives such as x()).
    #: The conformance kit checks it where it is claimed.
    invariant: ClassVar[bool] = True
    #: For drawings: ``(P1, P2, AXIS)``, the names of a point argument on the first body, a
    #: point argument on the second and a vector argument, where the joint holds P2 on the
    #: line through P1 along AXIS (in the first body's frame): a slider's guide or a slot.
    #: Drawings show the line as a rail over P2's travel, and P1 as no pivot. None: the
    #: points are pins.
    guide: ClassVar[tuple[str, str, str] | None] = None

    @property
    def slots(self) -> tuple[Arg, ...]:
        """The reference arguments, in order: one attached body each."""
        return tuple(a for a in self.signature if a.is_reference)

    def describe(self) -> str:
        """``name(arg: kind, ...)``."""
        return f"{self.name}({', '.join(a.describe() for a in self.signature)})"

    def validate(self, p: Mapping[str, np.ndarray]) -> None:
        """Check argument values (arrays with batch axes); raise :class:`ArgError` to reject."""

    def equations(self, bodies: tuple[Body, ...], args: Args) -> Sequence[Any]:
        """Phi: ``n_eq`` scalars, written as plain arithmetic and numpy functions of the
        attached bodies' scalars (``bodies[k].x, .y, .phi, .c, .s``, one
        :class:`~mechdsl.plugins.geometry.Body` per reference argument, in order) and of
        ``args``. The same code runs on numbers, on arrays and on traced values, so it may
        not branch on them."""
        raise NotImplementedError

    def jacobian_terms(self, bodies: tuple[Body, ...], args: Args) -> Sequence[Sequence[Any]]:
        """Optional: dPhi/dq_k for each attached body k, as ``n_eq`` rows of 3 scalars
        (d/dx, d/dy, d/dphi). Leave it out to have it derived from :meth:`equations`."""
        raise NotImplementedError

    def gamma_terms(self, bodies: tuple[Body, ...], rates: tuple[Rate, ...],
                    args: Args) -> Sequence[Any]:
        """Optional: gamma = -(Phi_q qd)_q qd, ``n_eq`` scalars, with ``rates[k]`` the
        velocity (x, y, phi) of attached body k. Leave it out to have it derived."""
        raise NotImplementedError

    def supplies_equations(self) -> bool:
        return type(self).equations is not ConstraintType.equations

    def supplies(self, method: str) -> bool:
        """Whether the type writes ``method`` ("jacobian_terms" or "gamma_terms") itself."""
        return getattr(type(self), method) is not getattr(ConstraintType, method)

    @functools.cached_property
    def derived(self) -> "Derived":
        """The type's equations traced and differentiated, compiled for arrays."""
        from .derived import Derived
        return Derived(self)

    def phi(self, q: tuple[np.ndarray, ...], p: Mapping[str, np.ndarray]) -> np.ndarray:
        """Phi for poses ``q`` (one ``(..., 3)`` array per attached body): ``(..., n_eq)``."""
        return self.derived.phi(q, p)

    def jacobian(self, q: tuple[np.ndarray, ...],
                 p: Mapping[str, np.ndarray]) -> tuple[np.ndarray, ...]:
        """dPhi/dq_k for each slot k, each of shape ``(..., n_eq, 3)`` (the supplied terms
        where the type writes them, else the derived ones)."""
        return self.derived.jacobian(q, p)

    def gamma(self, q: tuple[np.ndarray, ...], qd: tuple[np.ndarray, ...],
              p: Mapping[str, np.ndarray]) -> np.ndarray:
        """gamma = -(Phi_q qd)_q qd, shape ``(..., n_eq)``."""
        return self.derived.gamma(q, qd, p)


def signature_problems(sig: object) -> list[str]:
    """What is wrong with a type's ``signature`` (joint, drive and force types alike)."""
    if not isinstance(sig, tuple) or not all(isinstance(a, Arg) for a in sig):
        return ["signature must be a tuple of Arg"]
    problems = []
    names = [a.name for a in sig]
    if len(set(names)) != len(names):
        problems.append("signature has two arguments with the same name")
    for a in sig:
        if not isinstance(a.name, str) or not a.name.isidentifier():
            problems.append(f"argument name {a.name!r} is not an identifier")
        elif a.name in RESERVED_ARG_NAMES:
            problems.append(f"argument name {a.name!r} is a reserved word of the language")
        if a.kind not in ARG_KINDS:
            problems.append(f"argument {a.name!r} has kind {a.kind!r}; use one of {ARG_KINDS}")
        elif (a.is_reference or a.kind == "function") and a.default is not REQUIRED:
            problems.append(f"{a.kind} argument {a.name!r} cannot have a default")
        if a.kind == "function" and not (isinstance(a.var, str) and a.var.isidentifier()):
            problems.append(f"function argument {a.name!r} needs var, the name of its "
                            "variable")
    if not any(a.is_reference for a in sig):
        problems.append("signature attaches no body (no point or body argument)")
    return problems


def guide_problems(ctype: object) -> list[str]:
    """What is wrong with a type's ``guide`` (None is right)."""
    guide = getattr(ctype, "guide", None)
    if guide is None:
        return []
    sig = getattr(ctype, "signature", ())
    kinds = {a.name: a.kind for a in sig if isinstance(a, Arg)}
    refs = [a.name for a in sig if isinstance(a, Arg) and a.is_reference]
    if (not isinstance(guide, tuple) or len(guide) != 3
            or [kinds.get(n) for n in guide] != ["point", "point", "vector"]
            or refs[:2] != list(guide[:2])):
        return ["guide must be (P1, P2, AXIS): the point arguments on the first and the "
                "second body and a vector argument"]
    return []


def contract_problems(ctype: object) -> list[str]:
    """What is wrong with the *declaration* of ``ctype`` (empty list when it is well formed)."""
    problems = []
    name = getattr(ctype, "name", None)
    if not isinstance(name, str) or not name.isidentifier():
        problems.append(f"name {name!r} is not an identifier")
    if getattr(ctype, "kind", None) not in KINDS:
        problems.append(f"kind must be one of {KINDS}, not {getattr(ctype, 'kind', None)!r}")
    n_eq = getattr(ctype, "n_eq", None)
    if not isinstance(n_eq, int) or n_eq < 1:
        problems.append(f"n_eq must be a positive int, not {n_eq!r}")
    elif getattr(ctype, "kind", None) == "drive" and n_eq != 1:
        problems.append("a drive type has exactly one equation (n_eq = 1)")
    problems += signature_problems(getattr(ctype, "signature", None))
    problems += guide_problems(ctype)
    if isinstance(ctype, ConstraintType):
        if not ctype.supplies_equations():
            problems.append("method equations() is missing: a type writes its equations")
        for method in ("phi", "jacobian", "gamma"):
            if getattr(type(ctype), method) is not getattr(ConstraintType, method):
                problems.append(f"method {method}() is overridden: the array methods evaluate "
                                "equations() (and jacobian_terms(), gamma_terms()); the "
                                "compiled model would not use an override")
    else:
        problems.append("a type must be an instance of a ConstraintType subclass")
    return problems
