"""Checks of a constraint type against its contract, for use in any plugin's tests.

>>> from mechdsl.testing import check_constraint_type
>>> check_constraint_type(Revolute())        # raises ContractViolation with the numbers

Every check uses the type's own ``phi`` as the truth:

* Jacobian: each block against central differences of Phi in each coordinate;
* gamma: against the second time derivative of Phi along random trajectories
  q(t) = q0 + qd t + qdd t^2/2, since d^2 Phi/dt^2 = Phi_q qdd - gamma;
* shapes: outputs ``(..., n_eq)`` and ``(..., n_eq, 3)`` for one and two batch axes, with
  arguments whose batch shapes differ (they must broadcast).
"""

from __future__ import annotations

from typing import Callable, Mapping

import numpy as np

from .plugins.contract import REQUIRED, ConstraintType


class ContractViolation(AssertionError):
    """A constraint type does not meet its contract; the message has the numbers."""


def random_params(ctype: ConstraintType, rng: np.random.Generator, batch: tuple[int, ...],
                  overrides: Mapping[str, Callable] | None = None) -> dict[str, np.ndarray]:
    """Random argument values of shape ``batch + (...)``: points and vectors uniform in
    [-1, 1]^2, scalars at their default or uniform in [0.5, 1.5]. ``overrides`` maps an
    argument name to ``f(rng, shape) -> array`` for types with a restricted domain."""
    p = {}
    for arg in ctype.signature:
        if arg.kind == "body":
            continue
        shape = batch + ((2,) if arg.kind in ("point", "vector") else ())
        if overrides and arg.name in overrides:
            p[arg.name] = np.asarray(overrides[arg.name](rng, shape), dtype=float)
        elif arg.kind == "scalar" and arg.default is not REQUIRED:
            p[arg.name] = np.full(shape, float(arg.default)) + rng.uniform(-0.3, 0.3, shape)
        elif arg.kind == "scalar":
            p[arg.name] = rng.uniform(0.5, 1.5, shape)
        else:
            p[arg.name] = rng.uniform(-1, 1, shape)
    return p


def _fail(ctype: ConstraintType, what: str, got, want, where: str = "") -> None:
    got, want = np.asarray(got), np.asarray(want)
    err = np.abs(got - want)
    i = np.unravel_index(np.nanargmax(err), err.shape) if err.size else ()
    raise ContractViolation(
        f"{ctype.kind} type '{ctype.name}': {what} is wrong{where}: at index {i} got "
        f"{got[i]!r}, expected {want[i]!r} (error {err[i]:.3g})")


def check_constraint_type(ctype: ConstraintType, *, samples: int = 20, seed: int = 0,
                          params: Mapping[str, Callable] | None = None,
                          rtol: float = 1e-6) -> None:
    """Raise :class:`ContractViolation` if ``ctype`` breaks the contract (see module doc)."""
    rng = np.random.default_rng(seed)
    S = len(ctype.slots)
    batch = (samples,)
    p = random_params(ctype, rng, batch, params)
    q = tuple(rng.uniform(-1, 1, batch + (3,)) * [1, 1, np.pi] for _ in range(S))
    qd = tuple(rng.uniform(-1, 1, batch + (3,)) for _ in range(S))
    qdd = tuple(rng.uniform(-1, 1, batch + (3,)) for _ in range(S))

    phi = np.asarray(ctype.phi(q, p))
    if phi.shape != batch + (ctype.n_eq,):
        raise ContractViolation(f"'{ctype.name}'.phi returned shape {phi.shape}, expected "
                                f"{batch + (ctype.n_eq,)}")
    blocks = ctype.jacobian(q, p)
    if len(blocks) != S:
        raise ContractViolation(f"'{ctype.name}'.jacobian returned {len(blocks)} blocks for "
                                f"{S} attached bodies")
    for k, blk in enumerate(blocks):
        if np.shape(blk) != batch + (ctype.n_eq, 3):
            raise ContractViolation(f"'{ctype.name}'.jacobian block {k} has shape "
                                    f"{np.shape(blk)}, expected {batch + (ctype.n_eq, 3)}")
        fd = np.empty(batch + (ctype.n_eq, 3))
        for c in range(3):
            h = 1e-6
            dq = np.zeros(3)
            dq[c] = h
            plus = tuple(x + dq if i == k else x for i, x in enumerate(q))
            minus = tuple(x - dq if i == k else x for i, x in enumerate(q))
            fd[..., c] = (ctype.phi(plus, p) - ctype.phi(minus, p)) / (2 * h)
        scale = 1.0 + np.abs(fd).max()
        if not np.allclose(blk, fd, rtol=0, atol=rtol * scale):
            _fail(ctype, f"Jacobian block {k}", blk, fd, " (against central differences)")

    gamma = np.asarray(ctype.gamma(q, qd, p))
    if gamma.shape != batch + (ctype.n_eq,):
        raise ContractViolation(f"'{ctype.name}'.gamma returned shape {gamma.shape}")
    # d2Phi/dt2 along q(t) = q + qd t + qdd t^2/2, by Richardson-extrapolated differences
    def second(h: float) -> np.ndarray:
        at = lambda s: tuple(x + v * s + a * s * s / 2 for x, v, a in zip(q, qd, qdd))  # noqa
        return (ctype.phi(at(h), p) - 2 * phi + ctype.phi(at(-h), p)) / h**2

    h = 1e-3
    d2 = (4 * second(h / 2) - second(h)) / 3
    phi_q_qdd = sum(np.einsum("...ij,...j->...i", b, a) for b, a in zip(blocks, qdd))
    want = phi_q_qdd - d2
    scale = 1.0 + np.abs(want).max()
    if not np.allclose(gamma, want, rtol=0, atol=1e-5 * scale):
        _fail(ctype, "gamma", gamma, want, " (against d2Phi/dt2 along random trajectories)")

    # broadcasting: two batch axes, points batched differently from poses
    p2 = {k: v[:, None] for k, v in p.items()}
    q2 = tuple(x[None, :] for x in q)
    qd2 = tuple(x[None, :] for x in qd)
    core = {a.name: (1 if a.kind in ("point", "vector") else 0) for a in ctype.signature}
    want_shape = np.broadcast_shapes(*(x.shape[:-1] for x in q2),
                                     *(v.shape[: v.ndim - core[k]] for k, v in p2.items()))
    for name, out, core in (("phi", ctype.phi(q2, p2), (ctype.n_eq,)),
                            ("gamma", ctype.gamma(q2, qd2, p2), (ctype.n_eq,))):
        if np.shape(out) != want_shape + core:
            raise ContractViolation(f"'{ctype.name}'.{name} does not broadcast: shape "
                                    f"{np.shape(out)}, expected {want_shape + core}")
    for k, blk in enumerate(ctype.jacobian(q2, p2)):
        if np.shape(blk) != want_shape + (ctype.n_eq, 3):
            raise ContractViolation(f"'{ctype.name}'.jacobian block {k} does not broadcast: "
                                    f"shape {np.shape(blk)}")
