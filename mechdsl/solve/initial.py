"""Where a forward-dynamics run starts: the assembly at t0 with the ``initial`` statements,
the initial velocities, and the warnings that say where either differs from what was given.

A mechanism that is not fully driven has free coordinates; the joints and drives do not say
where they start. Three things may: the bodies' ``guess`` items (rough by design: the
assembly takes the configuration nearest them that closes the joints), the ``initial``
statements (``initial s: angle(crank) = 1.0, rate = 0``: a drive's measure at t0 only), and
the ``v0`` items. Here:

* :func:`positions` adds the ``initial`` statements' equations to the joints' and drives' at
  t0 (as drives frozen there, :class:`mechdsl.compiled.system.Start`), so the assembly puts
  each measure exactly at its value. An ``initial`` statement whose equation depends on the
  joints', the drives' or the statements' before it (it fixes a coordinate they already fix,
  or there are more statements than free coordinates) is an error located at it, as is one
  whose value the mechanism cannot reach. Where the statements do not fix every free
  coordinate, the free ones come from the guesses: a guessed coordinate that the assembly
  moves by more than :data:`GUESS_TOL` (relative to the model's length scale for x and y,
  in radians for phi) is a warning naming the body, the coordinate, the guess and the
  assembled value, with the ``initial`` statement that would state it.
* :func:`velocities` projects the given velocities (``v0``, zero where none is given) onto
  the velocity constraints Phi_q qd = nu, nu holding the drives' rates at t0 and the rates
  of the ``initial`` statements that give one, by the smallest correction in coordinates
  scaled by the model's length (the projection the integrator makes at every output
  instant). A given velocity that this changes is a warning with the size of the change;
  a body without ``v0`` that it sets moving (a free body carried by a driven one) is a
  warning stating its velocity and what carries it.

Nothing here depends on the integrator: :class:`mechdsl.solve.dynamic.DynamicRun` calls
:func:`positions` from its assembly and :func:`velocities` at the start of each variant.
"""

from __future__ import annotations

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from ..compiled.system import System
from ..errors import MechError, listing
from .assembly import gauss_newton
from .diagnose import MAX_NAMED, variant_label
from .mobility import RANK_TOL, independent_rows
from .options import SolverOptions

__all__ = ["GUESS_TOL", "positions", "velocities"]

#: A guessed coordinate that the assembly of a forward dynamics moves by more than this is
#: reported (x and y relative to the model's length scale, phi in radians), unless
#: ``initial`` statements fix every free coordinate. Guesses are rough by design; this
#: catches the start that the user wrote and the assembly quietly changed.
GUESS_TOL = 1e-6

_COORDINATES = ("x", "y", "phi")
_RATES = ("vx", "vy", "omega")


def positions(kernels: Kernels, q: np.ndarray, ok: np.ndarray, t: np.ndarray, D: np.ndarray,
              opts: SolverOptions, guess_tol: float = GUESS_TOL
              ) -> tuple[np.ndarray, list[str]]:
    """The assembly at t0 with the ``initial`` statements, and the warnings about it.

    ``q`` (V, 1, n): the configuration assembled on the joints and drives (from the
    guesses), ``ok`` (V,) where that succeeded; ``t`` (V, 1) the instant t0, ``D`` (V, 1, n)
    the column scale. Returns q with every ``initial`` statement's equation closed too (the
    variants not ``ok`` are left as they are) and the warnings. Raises a MechError located
    at an ``initial`` statement that over-determines the assembly or cannot be reached."""
    system = kernels.system
    start = system.start
    if start is None or not ok.any():
        return q, []
    # the rank costs a pass over Phi_q (a large model's): taken only where it is needed
    free = None
    k = 0
    if start.system is not None:
        free = _free_coordinates(kernels, q, ok, D)
        k = len(start.rows)
        q = _with_initials(kernels, q, ok, t, D, opts, free)
    moved = _moved_guesses(system, q, ok, D, guess_tol)
    if not moved:
        return q, []
    if free is None:
        free = _free_coordinates(kernels, q, ok, D)
    if k >= free:  # every free coordinate stated: the guesses only started the search
        return q, []
    # a coordinate that the joints, drives and initial statements fix moved as they ask,
    # not as the assembly chose (a driven cart, a pendulum's pin on it, an angle stated)
    fixed = _fixed_coordinates(kernels, q, ok, D)
    moved = [(v, ks[~fixed[ks]]) for v, ks in moved]
    moved = [(v, ks) for v, ks in moved if ks.size]
    if not moved:
        return q, []
    return q, [_guess_warning(system, q, moved, float(t[0, 0]), free - k)]


def _scaled_jacobian(code: Kernels, q: np.ndarray, ok: np.ndarray, D: np.ndarray
                     ) -> np.ndarray:
    """Phi_q D (m, n) of ``code``'s equations at the first assembled variant."""
    v = int(np.flatnonzero(ok)[0])
    one = code.variant(v) if code.system.n_variants > 1 else code
    with np.errstate(all="ignore"):
        return eq.jacobian(one, q[v : v + 1])[0, 0] * D[v, 0]


def _fixed_coordinates(kernels: Kernels, q: np.ndarray, ok: np.ndarray, D: np.ndarray
                       ) -> np.ndarray:
    """Which coordinates (n,) the joints', drives' and initial statements' equations fix
    at the first assembled variant: those along which no motion they allow moves, the
    columns of the null space of their independent rows (:func:`independent_rows`, the
    rank the count of free coordinates takes) that vanish (to FIXED_TOL)."""
    code = kernels.start if kernels.system.start is not None and kernels.start is not None \
        else kernels
    jac = _scaled_jacobian(code, q, ok, D)
    kept, _ = independent_rows(jac)
    if not kept:
        return np.zeros(kernels.system.n, dtype=bool)
    _, _, vt = np.linalg.svd(jac[kept])
    null = vt[len(kept):]  # (n - rank, n): the motions the equations allow, orthonormal
    return np.linalg.norm(null, axis=0) <= FIXED_TOL


#: a coordinate whose component in every allowed motion (orthonormal, scaled) is at most
#: this is fixed by the equations (:func:`_fixed_coordinates`)
FIXED_TOL = 1e-8


def _free_coordinates(kernels: Kernels, q: np.ndarray, ok: np.ndarray, D: np.ndarray) -> int:
    """n - the rank of the joints' and drives' equations at the first assembled variant."""
    kept, _ = independent_rows(_scaled_jacobian(kernels, q, ok, D))
    return kernels.system.n - len(kept)


def _with_initials(kernels: Kernels, q: np.ndarray, ok: np.ndarray, t: np.ndarray,
                   D: np.ndarray, opts: SolverOptions, free: int) -> np.ndarray:
    """q assembled on the joints, the drives and the ``initial`` statements (see
    :func:`positions`)."""
    system, code = kernels.system, kernels.start
    start = system.start
    aug, rows = start.system, start.rows
    # over-determination: the rows of the statements, after the joints' and drives', in
    # order, at the configuration that closes the joints (the rank there is the rank at the
    # start wherever that is not a singular position)
    _, dropped = independent_rows(_scaled_jacobian(code, q, ok, D))
    bad = [r for r in dropped if r >= rows[0]]
    if bad:
        c = aug.row_owner(int(bad[0]))
        before = int(bad[0] - rows[0])
        s = "s" if free != 1 else ""
        if free == 0:
            why = "the joints and drives already fix every coordinate"
        elif before >= free:
            why = (f"the joints and drives leave {free} degree{s} of freedom, and the "
                   f"initial statement{'s' if before != 1 else ''} before it already fix "
                   f"{'them' if free != 1 else 'it'}")
        else:
            why = (f"it fixes a coordinate that the joints, drives or other initial "
                   f"statements already fix (its equation depends on theirs at t0; they "
                   f"leave {free} degree{s} of freedom)")
        raise MechError(f"initial '{c.name}' over-determines the start: {why}; remove it",
                        c.span, system.source)
    every = np.arange(aug.m)
    q2, ok2, _ = gauss_newton(code, q, t, D, every, opts)
    failed = np.flatnonzero(ok & ~ok2)
    if failed.size:
        v = int(failed[0])
        with np.errstate(all="ignore"):
            phi = np.abs(eq.constraint_values(code, q2[v : v + 1], t[v : v + 1])[0, 0][rows])
        worst = int(np.argmax(np.nan_to_num(phi, nan=np.inf)))
        c = aug.row_owner(int(rows[worst]))
        raise MechError(
            f"the mechanism cannot be assembled at t = {float(t[v, 0]):g} with initial "
            f"'{c.name}'{variant_label(system, v)}: its value is out of the mechanism's "
            "reach from the guessed configuration (the joints and drives close without it)",
            c.span, system.source)
    return np.where(ok[:, None, None], q2, q)


def _moved_guesses(system: System, q: np.ndarray, ok: np.ndarray, D: np.ndarray,
                   tol: float) -> list[tuple[int, np.ndarray]]:
    """(variant, the guessed coordinates the assembly moved by more than ``tol``, the
    largest move first) for each variant where it moved one."""
    guessed = system.start.guessed
    if not guessed.any():
        return []
    moved_in = []
    for v in np.flatnonzero(ok):
        delta = np.abs(q[v, 0] - system.guess[v]) / D[v, 0]
        moved = np.flatnonzero(guessed & (delta > tol))
        if moved.size:
            moved_in.append((int(v), moved[np.argsort(-delta[moved], kind="stable")]))
    return moved_in


def _guess_warning(system: System, q: np.ndarray, moved_in: list[tuple[int, np.ndarray]],
                   t0: float, left: int) -> str:
    """The warning for the guessed coordinates the assembly moved (see :func:`positions`),
    for the first variant where it moved one; ``left`` free coordinates are stated by no
    ``initial`` statement."""
    v, moved = moved_in[0]
    parts = [f"{_name(system, k, _COORDINATES)} from {system.guess[v, k]:.6g} to "
             f"{q[v, 0, k]:.6g}" for k in moved]
    others = (f" (and in {len(moved_in) - 1} other variant{'s' if len(moved_in) > 2 else ''})"
              if len(moved_in) > 1 else "")
    angles = [k for k in moved if k % 3 == 2]
    k = int(angles[0] if angles else moved[0])
    body = system.body_names[k // 3]
    example = (f"initial {body}_start: angle({body}) = {system.guess[v, k]:.6g}" if k % 3 == 2
               else f"initial {body}_start: {_COORDINATES[k % 3]}({body}.origin) = "
                    f"{system.guess[v, k]:.6g}")
    return (f"the assembly at t = {t0:g}{variant_label(system, v)} moved the guesses of "
            f"{listing(parts, MAX_NAMED)}{others}: the forward dynamics starts where the "
            f"assembly puts the mechanism, and {left} of its free coordinate"
            f"{'s' if left != 1 else ''} {'are' if left != 1 else 'is'} set by no initial "
            f"statement; to start it at a guessed value, state it (e.g. '{example}')")


def velocities(kernels: Kernels, v: int, t0: float, q0: np.ndarray, D: np.ndarray,
               opts: SolverOptions) -> tuple[np.ndarray, list[str]]:
    """The initial velocities of variant ``v`` at the assembled ``q0`` (n,) and the warnings
    about them (see the module): the given ``v0`` (zero elsewhere) corrected by the least
    D-scaled change onto Phi_q qd = nu, with the rated ``initial`` statements' rows added.
    ``D`` (n,) the column scale of variant ``v``."""
    system = kernels.system
    d = kernels.dynamics
    start = system.start
    given = np.asarray(d.v0_given, dtype=bool)
    qd_given = np.array(d.v0[v], dtype=float)
    code = kernels.start if start is not None and kernels.start is not None else kernels
    aug = code.system
    one = code.variant(v) if aug.n_variants > 1 else code
    rows = np.arange(system.m)
    if aug is not system:
        rows = np.concatenate((rows, start.rows[start.rated]))
    if rows.size == 0:
        return qd_given, []
    T = np.full((1, 1), t0)
    nu = np.zeros(aug.m)
    if aug.drive_rows.size:
        nu[aug.drive_rows] = eq.drive_values(one, T, "fd", (1, 1))[0, 0]
    if not (qd_given.any() or nu[rows].any()):
        return qd_given, []  # at rest, and nothing moves: nothing to project or report
    with np.errstate(all="ignore"):
        jac = eq.jacobian(one, q0.reshape(1, 1, -1))[0, 0]
    a = jac[rows] * D
    residual = jac[rows] @ qd_given - nu[rows]
    qd = qd_given - D * _min_norm(a, residual)
    return qd, _velocity_warnings(system, aug, v, qd, qd_given, given, nu, D, a, opts)


def _min_norm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The minimum-norm solution of a x = b: a^T (a a^T)^-1 b, least squares where a a^T is
    singular."""
    try:
        x = a.T @ np.linalg.solve(a @ a.T, b)
        if np.isfinite(x).all():
            return x
    except np.linalg.LinAlgError:
        pass
    return np.linalg.lstsq(a, b, rcond=None)[0]


def _free_directions(a: np.ndarray) -> np.ndarray:
    """(n, f): an orthonormal basis of the velocities (scaled by D) that the constraints
    leave free, the null space of ``a`` (the scaled Phi_q)."""
    _, s, vt = np.linalg.svd(a, full_matrices=True)
    rank = int((s > RANK_TOL * s.max(initial=0.0)).sum())
    return vt[rank:].T


def _velocity_warnings(system: System, aug: System, v: int, qd: np.ndarray,
                       qd_given: np.ndarray, given: np.ndarray, nu: np.ndarray,
                       D: np.ndarray, a: np.ndarray, opts: SolverOptions) -> list[str]:
    """A given velocity the projection changed; bodies without ``v0`` that it set moving
    and what carries them. Velocities compare in coordinates scaled by D, relative to the
    largest one (``opts.newton_tol``, as the projection's own tolerance)."""
    out = []
    label = variant_label(system, v)
    moved = np.where(given, np.abs(qd - qd_given), 0.0)
    if (moved > opts.newton_tol * (1 + np.abs(qd_given))).any():
        k = int(np.argmax(moved))
        out.append(f"the initial velocities{label} do not satisfy the constraints: projected "
                   f"onto them, changing {_name(system, k, _RATES)} from {qd_given[k]:.6g} to "
                   f"{qd[k]:.6g} (by {moved[k]:.3g})")
    scaled = np.abs(qd) / D
    floor = opts.newton_tol * (1 + scaled.max(initial=0.0))
    carried = [i for i in range(system.n_bodies)
               if not given[3 * i] and (scaled[3 * i : 3 * i + 3] > floor).any()]
    if carried:
        # a body whose velocity the constraints fix (a driven crank, the coupler it moves)
        # has no other start: only those with a free direction of velocity are reported
        free = _free_directions(a)
        carried = [i for i in carried if (np.abs(free[3 * i : 3 * i + 3]) > RANK_TOL).any()]
    if carried:
        sources = []
        for c in aug.constraints:
            r = c.rows[0]
            if c.kind in ("drive", "initial") and r in aug.drive_rows and abs(nu[r]) > 0:
                sources.append(f"{'the drive' if c.kind == 'drive' else 'initial'} {c.name} "
                               f"(rate {nu[r]:.6g} at t0)")
        for i in range(system.n_bodies):
            if given[3 * i] and np.any(qd_given[3 * i : 3 * i + 3] != 0):
                sources.append(f"the v0 of {system.body_names[i]}")
        bodies = [f"{system.body_names[i]} with (vx, vy, omega) = ("
                  + ", ".join(f"{x:.6g}" for x in qd[3 * i : 3 * i + 3]) + ")"
                  for i in carried]
        s = "ies" if len(carried) != 1 else "y"
        out.append(f"bod{s} without v0 start{'s' if len(carried) == 1 else ''} moving{label}: "
                   f"{listing(bodies, MAX_NAMED)}, carried by {listing(sources, MAX_NAMED)} "
                   "(the smallest velocities that satisfy the constraints); give v0, or an "
                   "initial statement with a rate, to state another start")
    return out


def _name(system: System, k: int, names: tuple[str, str, str]) -> str:
    """'crank.phi' for coordinate ``k``."""
    return f"{system.body_names[k // 3]}.{names[k % 3]}"
