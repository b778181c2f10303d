"""The contract of a constraint type: what a joint or drive plugin declares and computes.

A constraint type contributes ``n_eq`` rows to Haug's constraint vector Phi(q, t). It declares
a signature of arguments; every *reference* argument (a point ``body.P`` or a ``body``) attaches
one body, called a *slot*. The solver hands the type, for all constraints of that type at once,

* ``q``: a tuple with one pose array per slot, each of shape ``(..., 3)`` = (x, y, phi);
* ``qd``: the matching velocities (for :meth:`ConstraintType.gamma`);
* ``p``: a dict from argument name to values: a point's coordinates in its body's frame
  ``(..., 2)``, a vector ``(..., 2)``, a scalar ``(...)``, a function (:class:`Function`: an
  expression of one variable written by the user, with exact derivatives); body arguments
  have no entry.

The leading axes ``...`` are batch axes (constraints of the type, instants, sweep variants);
they broadcast against each other, and every method must return arrays with the full
broadcast batch shape. A type implements, in Haug's notation,

* :meth:`~ConstraintType.phi`: Phi, shape ``(..., n_eq)``;
* :meth:`~ConstraintType.jacobian`: the blocks dPhi/dq_k, one ``(..., n_eq, 3)`` per slot;
* :meth:`~ConstraintType.gamma`: the velocity-quadratic right-hand side of the acceleration
  equation, gamma = -(Phi_q qd)_q qd, shape ``(..., n_eq)``.

A *drive* type (``kind = "drive"``) computes one measure g(q) (``n_eq == 1``) and is used as
``drive NAME: TYPE(args) = f(t)``: the core adds the time function, Phi = g(q) - f(t),
nu = f'(t), gamma = -(g_q qd)_q qd + f''(t). Joint types are time-independent: nu = 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, Protocol

import numpy as np

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


class ConstraintType:
    """Base class of joint and drive types; subclass it, set the class attributes, implement
    :meth:`phi`, :meth:`jacobian` and :meth:`gamma` (and :meth:`validate` if some values are
    invalid). Instances must be stateless: one instance serves every constraint of the type.
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

    @property
    def slots(self) -> tuple[Arg, ...]:
        """The reference arguments, in order: one attached body each."""
        return tuple(a for a in self.signature if a.is_reference)

    def describe(self) -> str:
        """``name(arg: kind, ...)``."""
        return f"{self.name}({', '.join(a.describe() for a in self.signature)})"

    def validate(self, p: Mapping[str, np.ndarray]) -> None:
        """Check argument values (arrays with batch axes); raise :class:`ArgError` to reject."""

    def phi(self, q: tuple[np.ndarray, ...], p: Mapping[str, np.ndarray]) -> np.ndarray:
        """Phi, shape ``(..., n_eq)``."""
        raise NotImplementedError

    def jacobian(self, q: tuple[np.ndarray, ...],
                 p: Mapping[str, np.ndarray]) -> tuple[np.ndarray, ...]:
        """dPhi/dq_k for each slot k, each of shape ``(..., n_eq, 3)``."""
        raise NotImplementedError

    def gamma(self, q: tuple[np.ndarray, ...], qd: tuple[np.ndarray, ...],
              p: Mapping[str, np.ndarray]) -> np.ndarray:
        """gamma = -(Phi_q qd)_q qd, shape ``(..., n_eq)``."""
        raise NotImplementedError


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
    sig = getattr(ctype, "signature", None)
    if not isinstance(sig, tuple) or not all(isinstance(a, Arg) for a in sig):
        problems.append("signature must be a tuple of Arg")
    else:
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
    for method in ("phi", "jacobian", "gamma"):
        if not callable(getattr(ctype, method, None)):
            problems.append(f"method {method}() is missing")
    return problems
