"""Degrees of freedom and redundancy: which equations the solver can use.

Counting (Grubler) compares equations with coordinates; the rank of the joints' Jacobian at
their assembled configuration tells the truth. With n coordinates and the joint equations of
rank r, the mobility is n - r, and a fully driven mechanism has exactly that many drives, each
independent of the joints and of one another. Joint equations that depend on the others are
*redundant* (a parallelogram with a third parallel bar, two hinges on one axis): where they
hold (consistent redundancy) the model is solved with all its equations in the least-squares
sense, with a warning naming them, and its residuals are watched at every instant; where they
cannot hold the model is over-constrained, an error naming them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..compiled import equations as eq
from ..compiled.kernels import Kernels
from ..compiled.system import System
from ..errors import MechError, NumericalError, listing
from .diagnose import MAX_NAMED

#: A row is independent of the rows kept before it when its component orthogonal to them is
#: larger than this (rows scaled to unit norm, columns by the model's length scale).
RANK_TOL = 1e-8


def count_check(system: System) -> None:
    """Raise MechError where counting alone proves the model cannot be solved: no moving body,
    or fewer equations than coordinates (naming the bodies no constraint attaches)."""
    n, m = system.n, system.m
    src = system.source
    if n == 0:
        raise MechError("the model has no moving body", source=src)
    if m < n:
        attached = {b for c in system.constraints for b in c.bodies}
        loose = [b for b in system.body_names if b not in attached]
        notes = [f"body '{b}' is attached to nothing" for b in loose[:MAX_NAMED]]
        if len(loose) > MAX_NAMED:
            notes.append(f"and {len(loose) - MAX_NAMED} more bodies are attached to nothing")
        dof = n - m
        s = "s" if dof > 1 else ""
        raise MechError(
            f"the mechanism is not fully driven: {n} coordinates and {m} equations leave "
            f"{dof} degree{s} of freedom; add {dof} drive{s} or joint equation{s}",
            source=src, notes=notes)


class NotFullyDriven(MechError):
    """The rank at the assembled configuration leaves degrees of freedom that the drives do
    not fix, although the count of equations did not show it (redundant joints): a model
    with masses is forward dynamics (:func:`mechdsl.solve.run.simulate`)."""


@dataclass(frozen=True)
class Mobility:
    """The rank structure found at the joints' assembled configuration (first variant).

    ``rows`` are the equations the solver uses: all of them (least squares where some are
    redundant). ``dropped`` names the redundant joint rows (those that depend on the rows
    before them); ``dropped_weights`` (1 / norm of every scaled Jacobian row) serve to watch
    all residuals of a redundant model, empty for a square one.
    """

    n: int
    joint_equations: int
    rank: int
    drives: int
    rows: np.ndarray
    dropped: np.ndarray
    dropped_weights: np.ndarray

    @property
    def mobility(self) -> int:
        return self.n - self.rank


def square(system: System) -> Mobility:
    """The structure of a model with as many equations as coordinates: all are used."""
    k = len(system.drive_rows)
    return Mobility(system.n, system.m - k, system.m - k, k, np.arange(system.m, dtype=np.intp),
                    np.zeros(0, np.intp), np.zeros(0))


def report(kernels: Kernels, q: np.ndarray, col_scale: np.ndarray) -> tuple[int, int, str]:
    """(mobility, rank of the joint equations, the redundant ones named) at ``q`` (n,) of a
    one-variant ``kernels``; nothing is raised (for ``mechdsl check``)."""
    system = kernels.system
    joint_rows = system.joint_rows
    with np.errstate(all="ignore"):
        jac = eq.jacobian(kernels, q.reshape(1, 1, -1))[0, 0] * col_scale
    kept, dropped = independent_rows(jac[joint_rows])
    return system.n - len(kept), len(kept), _names(system, joint_rows[dropped])


@dataclass(frozen=True)
class Freedom:
    """The degrees of freedom of a model with drives and free coordinates (``mechdsl
    check``), at one configuration: ``n`` coordinates, the joint equations of rank
    ``joint_rank``, ``drives`` drives of which ``drive_rank`` are independent of the joints
    and of the drives before them, and ``initials`` ``initial`` statements (t0 only)."""

    n: int
    joint_rank: int
    drives: int
    drive_rank: int
    initials: int = 0

    @property
    def mobility(self) -> int:
        """The joints' degrees of freedom, n - rank of the joint equations."""
        return self.n - self.joint_rank

    @property
    def free(self) -> int:
        """The degrees of freedom left to the forward dynamics: the mobility less the
        independent drives (n - rank of the joints' and drives' equations together)."""
        return self.mobility - self.drive_rank


def freedom(kernels: Kernels, q: np.ndarray, col_scale: np.ndarray) -> Freedom:
    """:class:`Freedom` at ``q`` (n,) of a one-variant ``kernels``: the rank of the joint
    equations, then of the drives' after them (a drive on a coordinate the joints or an
    earlier drive already fix adds nothing)."""
    system = kernels.system
    joint_rows = np.asarray(system.joint_rows, dtype=np.intp)
    drive_rows = np.asarray(system.drive_rows, dtype=np.intp)
    with np.errstate(all="ignore"):
        jac = eq.jacobian(kernels, q.reshape(1, 1, -1))[0, 0] * col_scale
    kept, _ = independent_rows(jac[np.concatenate((joint_rows, drive_rows))])
    joint_rank = sum(1 for k in kept if k < len(joint_rows))
    start = getattr(system, "start", None)
    initials = 0 if start is None or start.rows is None else len(start.rows)
    return Freedom(system.n, joint_rank, len(drive_rows), len(kept) - joint_rank, initials)


def hidden_freedom(kernels: Kernels, q: np.ndarray, col_scale: np.ndarray) -> None:
    """Raise :class:`NotFullyDriven` where a model whose count is square (as many equations
    as coordinates) has joint equations that depend on one another at the joints'
    configuration ``q`` (n,): redundant joints (a parallelogram's third crank) leave the
    degree of freedom that the count gave to a drive, and a model with masses moves under
    its loads (the caller asks only for such models). A singular position of the joints
    alone (a four-bar's change point) reads the same at one configuration; its forward
    dynamics passes it as the kinematics would not."""
    system = kernels.system
    joint_rows = np.asarray(system.joint_rows, dtype=np.intp)
    with np.errstate(all="ignore"):
        jac = eq.jacobian(kernels, q.reshape(1, 1, -1))[0, 0] * col_scale
    kept, dropped = independent_rows(jac[joint_rows])
    if not dropped:
        return
    n, k = system.n, len(system.drive_rows)
    raise NotFullyDriven(
        f"the mechanism is not fully driven: its joints leave {n - len(kept)} degrees of "
        f"freedom ({n} coordinates, joint equations of rank {len(kept)}) and there "
        f"{'is' if k == 1 else 'are'} {k} drive{'s' if k != 1 else ''}", source=system.source,
        notes=[f"redundant: {_names(system, joint_rows[dropped])}"])


def independent_rows(a: np.ndarray, tol: float = RANK_TOL) -> tuple[list[int], list[int]]:
    """Split the rows of ``a`` (in order) into those independent of the rows kept before
    them, and the rest: Gram-Schmidt with re-orthogonalisation, rows normalised first, so
    that earlier rows are kept in preference. Returns (kept, dropped) row indices."""
    with np.errstate(all="ignore"):  # huge or non-finite rows are dropped below
        norms = np.linalg.norm(a, axis=1)
    basis: list[np.ndarray] = []
    kept: list[int] = []
    dropped: list[int] = []
    for i, row in enumerate(a):
        if not norms[i] > 0 or not np.isfinite(norms[i]):
            dropped.append(i)
            continue
        v = row / norms[i]
        if basis:
            b = np.array(basis)
            v = v - b.T @ (b @ v)
            v = v - b.T @ (b @ v)
        size = np.linalg.norm(v)
        if size > tol:
            basis.append(v / size)
            kept.append(i)
        else:
            dropped.append(i)
    return kept, dropped


def analyse(kernels: Kernels, q: np.ndarray, col_scale: np.ndarray) -> Mobility:
    """The mobility at the joints' configuration ``q`` (n,), and the equations to solve;
    ``kernels`` holds one variant (see :meth:`mechdsl.compiled.kernels.Kernels.variant`).

    Raises MechError when the drives do not match the mobility (too few, too many, or a drive
    on a coordinate the joints already fix), and NumericalError when the rank falls short of
    the count only because the configuration is singular (a dead point or change point)."""
    system = kernels.system
    n = system.n
    drive_rows = np.asarray(system.drive_rows, dtype=int)
    joint_rows = system.joint_rows
    with np.errstate(all="ignore"):
        jac = eq.jacobian(kernels, q.reshape(1, 1, n))[0, 0] * col_scale
    kept, dropped = independent_rows(jac[joint_rows])
    kept_rows, dropped_rows = joint_rows[kept], joint_rows[dropped]
    rank = len(kept)
    src = system.source
    names = _names(system, dropped_rows)
    k = len(drive_rows)
    if rank + k < n:
        if dropped_rows.size and n - len(joint_rows) == k:
            raise NumericalError(
                f"the mechanism is assembled at a singular position (a dead point or a change "
                f"point): at t0 the equations of {names} depend on the others, so the "
                f"{k} drive{'s' if k != 1 else ''} cannot fix the motion; start the run at "
                "another instant or give guesses of another configuration", source=src)
        mobility = n - rank
        notes = [f"redundant: {names}"] if dropped_rows.size else []
        raise NotFullyDriven(
            f"the mechanism is not fully driven: its joints leave {mobility} degree"
            f"{'s' if mobility != 1 else ''} of freedom ({n} coordinates, joint equations of "
            f"rank {rank}) and there {'is' if k == 1 else 'are'} {k} drive{'s' if k != 1 else ''}",
            source=src, notes=notes)
    full = np.concatenate((jac[kept_rows], jac[drive_rows]))
    _, bad = independent_rows(full)
    bad_drives = [drive_rows[i - rank] for i in bad if i >= rank]
    if bad_drives or rank + k > n:
        mobility = n - rank
        which = _names(system, bad_drives) if bad_drives else "the drives"
        raise MechError(
            f"the mechanism is over-driven: its joints leave {mobility} degree"
            f"{'s' if mobility != 1 else ''} of freedom and there are {k} drives; {which} "
            f"move{'s' if len(bad_drives) == 1 else ''} coordinates that the joints or other "
            "drives already fix", source=src)
    # every equation is solved, in the least-squares sense: the set of independent ones can
    # change along the motion, and the redundant ones may be what keeps a linkage regular
    # at another's dead point; their residuals are watched, since least squares would
    # otherwise settle for a compromise between inconsistent equations
    rn = np.linalg.norm(jac, axis=1)
    weights = np.where(rn > 0, 1.0 / np.where(rn > 0, rn, 1.0), 1.0)
    rows = np.arange(system.m, dtype=np.intp)
    return Mobility(n, len(joint_rows), rank, k, rows, dropped_rows.astype(np.intp), weights)


def _names(system: System, rows) -> str:
    """'joint bar3 (1 of 2 equations), ...' for the owners of ``rows``."""
    counts: dict[str, list] = {}
    for r in rows:
        c = system.row_owner(int(r))
        counts.setdefault(c.name, [c, 0])[1] += 1
    parts = []
    for c, k in list(counts.values())[:MAX_NAMED + 1]:
        total = c.rows[1] - c.rows[0]
        share = f"{k} of {total} equations" if total > 1 else "1 equation"
        parts.append(f"{c.kind} {c.name} ({share}, line {c.span.line})")
    return listing(parts, MAX_NAMED, total=len(counts))


def redundancy_warning(system: System, mob: Mobility) -> str | None:
    """The warning for consistent redundant joints, or None."""
    if not mob.dropped.size:
        return None
    return (f"redundant constraints: the equations of {_names(system, mob.dropped)} depend on "
            "the others at the assembled configuration; they hold there, and all equations are "
            "solved in the least-squares sense (and checked at every instant)")
