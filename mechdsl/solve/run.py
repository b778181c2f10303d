"""The kinematic run: assembly at t0, then Newton-Raphson at every instant, with velocities
and accelerations from the same factorised Jacobian (Haug 1989, ch. 4); the registry of
solver methods and :func:`simulate`, which builds a run and calls it.

Position: Newton-Raphson on Phi(q, t) = 0, Phi_q dq = -Phi, started from the Taylor predictor
q + tau qd + tau^2/2 qdd of the last solved instant. Velocity: Phi_q qd = nu. Acceleration:
Phi_q qdd = gamma. The Jacobian used for qd and qdd is the one at the converged q.

Speed comes from batching: several instants (a *block*) and every sweep variant are solved as
one batched array problem. The block grows while Newton converges in few iterations and
shrinks when it does not. When even one instant fails, the interval before it is bisected
(intermediate states are solved but not recorded) before the failure is declared, so a coarse
output step does not cause a failure on its own. Before that careful march, each window of
instants is tried parallel in time (:meth:`KinematicRun.parallel`).

No silent branch switching. A solved state is refused when

* its Jacobian is singular (reciprocal condition below ``singular_rcond``): a dead point,
  change point or lock-up, where velocities are undetermined;
* det(Phi_q) has changed sign since the previous state: the path crossed a singular position;
* Newton's correction to the predictor is large against the motion since the last state
  (ratio above ``branch_ratio``) and, once the interval is bisected to its finest, the
  position is still discontinuous: a jump to another assembly branch. (A drive whose
  velocity jumps passes this test: its positions stay continuous.)

Refused states are bisected towards, then reported with the instant and the joints involved.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..compiled import equations as eq
from ..compiled import native
from ..compiled.kernels import Kernels
from ..compiled.lu import THRESHOLD
from ..compiled.sparse import LU_BATCH_STATES
from ..compiled.system import ExprOutput, System
from ..errors import MechError
from .memory import plan
from ..results import Results
from .assembly import Assembly, assemble
from .base import Progress, Run
from .dynamic import DynamicRun
from .diagnose import (
    constraint_names, failure, jacobian_defects, nonfinite_message, passages_warning,
    too_coarse_message, undefined_drive_message, variant_label,
)
from . import batch, extrema, large
from .hermite import quintic_hermite
from .levels import coarse_march, polish
from .linalg import Factor, factor
from .mobility import NotFullyDriven, count_check, redundancy_warning
from .newton import correction_ratio, newton, use_sparse
from .options import SolverOptions
from .reduce import reduce_results
from .rowwise import allfinite
from .single import FLOAT_ERRORS, OneState
from .singular import singular_step

__all__ = ["KinematicRun", "METHODS", "SolverOptions", "simulate"]


@dataclass
class _Regular:
    """The last state of each variant whose Jacobian was well conditioned (rcond >=
    warn_rcond): time (V,), velocity and acceleration (V, n). Near a singular position,
    predictions start from it."""

    t: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


class KinematicRun(Run):
    """The kinematic march of a fully driven mechanism: positions from the constraints alone,
    then velocities and accelerations from the factorised Jacobian, at every instant of the
    system's grid, for every variant.

    The state it advances (the run's only mutable data) is the last solved state of each
    variant: time ``t`` (V,), coordinates ``q``, velocities ``qd``, accelerations ``qdd``
    (V, n), the sign of det(Phi_q) there ``sign`` (V,), and ``active`` (V,), the variants
    still running. ``rows`` are the equations solved (all of them, or an independent subset
    when constraints are redundant; the others, ``watched``, must still hold).
    """

    name = "kinematic"

    def __init__(self, kernels: Kernels, options: SolverOptions | None = None, *,
                 poses: bool = False, rates: bool = False, progress: Progress | None = None,
                 extra_memory: int = 0) -> None:
        system = kernels.system
        super().__init__(kernels, options, progress=progress)
        opts = self.opts
        count_check(system)  # before anything the size of the model is allocated
        if system.reads("dissipated_energy"):
            raise MechError("dissipated_energy is integrated over a forward-dynamics run; a "
                            "fully driven mechanism's dampers dissipate dissipated_power, "
                            "and its drives supply that energy", source=system.source)
        sparse = use_sparse(system, opts, np.arange(system.m))
        compiled = _wants_native(system, opts)
        #: the reductions' extremes refined between the samples (:mod:`.extrema`): the
        #: states of every instant are kept for it, where the memory allows
        self.to_refine = extrema.wanted(system) if opts.refine_extrema else set()
        budget = None
        if self.to_refine and not rates:
            try:
                budget = plan(system, opts.max_memory, opts.max_batch_elements,
                              sparse=sparse, poses=True, rates=True, extra=extra_memory,
                              compiled=compiled)
                poses_kept, rates_kept = True, True
            except MechError:
                self.to_refine = set()  # (the results say so: the samples' extremes)
        if budget is None:
            poses_kept, rates_kept = poses or rates, rates
            try:
                budget = plan(system, opts.max_memory, opts.max_batch_elements,
                              sparse=sparse, poses=poses_kept, rates=rates_kept,
                              extra=extra_memory, compiled=compiled)
            except MechError:
                if not compiled or opts.backend != "auto":
                    raise
                compiled = False  # "auto": the numpy path fits where numba would not
                budget = plan(system, opts.max_memory, opts.max_batch_elements,
                              sparse=sparse, poses=poses_kept, rates=rates_kept,
                              extra=extra_memory)
        self.opts = opts.derived(max_batch_elements=budget.batch_elements,
                                 backend=opts.backend if compiled else "numpy")
        self.keep_poses, self.keep_rates = poses_kept, rates_kept
        self.extrema: dict = {}
        #: sqrt(newton_tol): the smallest motion the branch check measures corrections by
        self.floor = np.sqrt(self.opts.newton_tol)

    # -- the run ---------------------------------------------------------------------------------
    def run(self) -> Results:
        """Assemble at t0, then solve every instant (:meth:`advance`); the results, also
        after a numerical failure or an interrupt."""
        system, opts, times = self.system, self.opts, self.times
        V, K = system.n_variants, len(times)
        start = time.perf_counter()
        self.data = {o.label: np.full((V, K), np.nan) for o in system.outputs}
        try:
            asm = assemble(self.kernels, float(times[0]), opts,
                           compiled=_wants_native(system, opts))
        except KeyboardInterrupt:
            return self.results("interrupted", time.perf_counter() - start)
        self._start(asm)
        status = "ok"
        try:
            if self.active.any():
                module = self._native()
                # the compiled march solves instant 0 too, from the assembled configuration;
                # where it stops there, the numpy solver looks at instant 0 and reports
                k = self.native_march(module, 0) if module is not None else 0
                if k == 0:
                    self._first_instant(asm)
                    k = 1
                    if module is not None and self.active.any():
                        k = self.native_march(module, 1)
                self.advance(k)
        except KeyboardInterrupt:
            status = "interrupted"
        elapsed = time.perf_counter() - start
        if status == "ok" and self.failures:
            status = "failed"
        if self.to_refine and status == "ok":
            try:
                self.extrema = extrema.refine(self, self.to_refine)
            except KeyboardInterrupt:
                status = "interrupted"  # (the samples' extremes stand)
        if self.passages:
            self.warnings.append(passages_warning(self.passages, times))
        for v in np.flatnonzero(self.min_rcond < opts.warn_rcond):
            self.warnings.append(
                f"near a singular position{variant_label(system, int(v))}: the Jacobian's "
                f"condition number reaches {1 / self.min_rcond[v]:.3g} at "
                f"t = {self.min_rcond_t[v]:.10g}; results there are sensitive to the data")
        return self.results(
            status, elapsed, residual=self.residual, condition=1.0 / self.min_rcond,
            poses=None if self.poses is None else self.poses.reshape(V, K, -1, 3),
            rates=None if self.pose_rates is None else self.pose_rates.reshape(V, K, 2, -1, 3))

    def _start(self, asm: Assembly) -> None:
        """The state at t0 from the assembly: the equations to solve, the ones to watch,
        and the arrays of the instants to keep."""
        system, times = self.system, self.times
        V, n, K = system.n_variants, system.n, len(times)
        mob = asm.mobility
        rows = mob.rows if mob is not None else np.arange(system.m)
        redundant = mob is not None and mob.dropped.size > 0
        self.rows = rows
        self.watched = rows if redundant else np.zeros(0, np.intp)
        self.watch_weights = mob.dropped_weights if redundant else np.zeros(0)
        self.t = np.full(V, times[0])
        self.q, self.qd, self.qdd = asm.q.copy(), np.zeros((V, n)), np.zeros((V, n))
        self.sign, self.active = np.ones(V), asm.ok.copy()
        #: per variant, the smallest reciprocal condition number met, and when
        self.min_rcond, self.min_rcond_t = np.ones(V), np.full(V, times[0])
        self.failures = list(asm.messages)
        #: times of the singular positions passed (at_singular = "continue")
        self.passages: list[float] = []
        #: the largest constraint residual of the states accepted
        self.residual = 0.0
        self.regular: _Regular | None = None
        #: sparse systems: the factorised Jacobian of the last state, for simplified Newton
        self.fac: Factor | None = None
        #: (V, K, n): every recorded instant's coordinates, when drawings or exports need
        #: them; (V, K, 2, n) their velocities and accelerations, when exports need them
        self.poses = np.full((V, K, n), np.nan) if self.keep_poses else None
        self.pose_rates = np.full((V, K, 2, n), np.nan) if self.keep_rates else None
        #: instants per block of the march, grown while Newton converges fast
        self.block = self.opts.initial_block
        #: named outputs already warned about for values that are not finite
        self.undefined_outputs: set[str] = set()
        if mob is not None:
            note = redundancy_warning(system, mob)
            if note:
                self.warnings.append(note)

    def _first_instant(self, asm: Assembly) -> None:
        """Accept the assembled configuration as instant 0, unless it is singular."""
        system, opts, times = self.system, self.opts, self.times
        V, rows = system.n_variants, self.rows
        q0, t0 = asm.q[:, None], np.full((V, 1), times[0])
        fac, rates = None, None
        if self.kernels.one_state is not None and len(rows) == system.n:
            # a single mechanism: the factorisation, and the rates and residual where they
            # are finite numbers, on floats
            solver = OneState(self.kernels, self.kernels.one_state, self.D[0, 0], opts)
            x = asm.q[0].tolist()
            start = asm.start  # the assembly's own factorisation at x, where it has one
            one = start.fac if start is not None else solver.factor(x)
            if one is not None:
                f, fd, fdd = ((start.f, start.fd, start.fdd) if start is not None else
                              ([c[0] for c in d] for d in solver.drives(times[:1])))
                try:
                    phi, _ = solver.residual(x, f)
                    # (not max() alone: it passes over a NaN that is not first)
                    res = (max((abs(v) for v in phi), default=0.0)
                           if all(v == v for v in phi) else float("nan"))
                except FLOAT_ERRORS:
                    res = float("nan")
                both = solver.rates(one, x, fd, fdd) if one.rcond > 0 else None
                if both is not None and res < float("inf"):
                    rates = tuple(np.array(v)[None, None] for v in both)
                    self.residual = max(self.residual, res)
                    # the rates are solved: accept needs the condition and the sign alone
                    fac = Factor(None, np.array([[one.rcond]]), np.array([[one.sign]]))
                else:
                    fac = one.batched()
        if fac is None:
            fac = factor(eq.solver_jacobian(self.kernels, q0, rows, use_sparse(system, opts, rows)),
                         self.D)
        singular = self.active & ~(fac.rcond[:, 0] >= opts.singular_rcond)
        for v in np.flatnonzero(singular):
            self.failures.append(failure(self.kernels, self.q[v], float(times[0]), int(v),
                                         float(times[0]), 0, "singular"))
        self.active &= ~singular
        self.sign = fac.sign[:, 0]
        self.accept(q0, t0, np.array([0]), fac, self.active.copy(), rates,
                    checked=rates is not None)

    def advance(self, k: int = 1) -> None:
        """March from the state at instant k - 1 to the last instant, window by window
        (the compiled march, where it applies, has solved the instants before k).

        Each window is tried parallel in time (:meth:`parallel`); what that does not settle
        is marched instant by instant (:meth:`march`), which reports any failure exactly."""
        system, opts, progress = self.system, self.opts, self.progress
        K = len(self.times)
        stride = opts.coarse_stride
        parallel = stride > 1 and not use_sparse(system, opts, self.rows)
        lean = large.applies(self)
        while k < K and self.active.any():
            end = min(K, k + max(opts.window, 2 * stride))
            if parallel and end - k >= 2 * stride:
                k = self.parallel(k, end)
                if progress is not None:
                    progress(k, K)
            while lean and k < end and self.active.any():
                # a large mechanism instant by instant, lean; an instant it does not settle
                # goes to the careful march, and the lean march goes on after it
                k = large.march_large(self, k, end)
                if k < end and self.active.any():
                    self.march(np.arange(k, k + 1))
                    k += 1
            if k < end and self.active.any():
                self.march(np.arange(k, end))
            k = end

    # -- accepting solved states ---------------------------------------------------------------
    def accept(self, q: np.ndarray, t: np.ndarray, rec: np.ndarray, fac: Factor,
               mask: np.ndarray, rates: tuple[np.ndarray, np.ndarray] | None = None,
               checked: bool = False, residual: np.ndarray | None = None) -> None:
        """Take the solved positions ``q`` (V, c, n) at ``t`` (V, c), with their factorised
        Jacobians, as the new state of the variants in ``mask``; solve velocities and
        accelerations, Phi_q qd = nu and Phi_q qdd = gamma (at every column when an output
        needs them, else at the last column only, for the predictor), unless ``rates`` =
        (qd, qdd) gives them; record the columns whose ``rec`` index (into ``system.times``)
        is not negative. Redundant equations left out of the solve must still hold. With
        ``checked``, the compiled march has measured the residual and stopped at the first
        value that is not finite, as it went; ``residual`` (V, c), where given, is max |Phi|
        of each state, measured by the caller (:func:`mechdsl.solve.batch.settle`)."""
        system, opts, rows = self.system, self.opts, self.rows
        order = 2 if self.pose_rates is not None else system.order
        c = q.shape[1]
        if rates is not None:
            qd, qdd = rates
        else:
            cols = slice(None) if order >= 1 else slice(c - 1, c)
            qs, ts = q[:, cols], t[:, cols]
            inv = fac.columns(cols)
            with np.errstate(all="ignore"):
                qd = inv.solve(eq.velocity_rhs(self.kernels, ts, qs.shape[:-1])[..., rows])
                qdd = inv.solve(eq.acceleration_rhs(self.kernels, qs, qd, ts)[..., rows])
        if opts.nonfinite == "stop" and not checked:
            need = 2 if self.pose_rates is not None else system.order
            bad = _nonfinite(q, qd, qdd, need) & mask[:, None]
            if bad.any():
                self._split_at_nonfinite(q, t, rec, fac, mask, (qd, qdd), bad)
                return
        if residual is not None and not self.watched.size:
            self.residual = max(self.residual, float(residual[mask].max(initial=0.0)))
        elif not checked:
            with np.errstate(all="ignore"):
                phi = eq.constraint_values(self.kernels, q, t)
            self.residual = max(self.residual, float(np.abs(phi[mask]).max(initial=0.0)))
            self._watch_redundant(phi, t, mask)
        lower = mask & (fac.rcond.min(axis=1) < self.min_rcond)
        if lower.any():
            worst = np.argmin(fac.rcond[lower], axis=1)
            sub = np.arange(len(worst))
            self.min_rcond[lower] = fac.rcond[lower][sub, worst]
            self.min_rcond_t[lower] = t[lower][sub, worst]
        # (every variant, the usual case: slices, not copies through a mask)
        at = slice(None) if mask.all() else mask
        self.q[at], self.t[at] = q[at, -1], t[at, -1]
        self.qd[at], self.qdd[at] = qd[at, -1], qdd[at, -1]
        self.sign[at] = fac.sign[at, -1]
        # per variant: the variants that stopped are skipped by Newton, whatever their entry
        if fac.lus is not None and mask.any() and (fac.rcond[mask, -1] > 0).all():
            self.fac = fac.columns(slice(c - 1, c))
        well = mask & (fac.rcond[:, -1] >= opts.warn_rcond) & (qd.shape[1] == c)
        if self.regular is None:
            self.regular = _Regular(self.t.copy(), self.qd.copy(), self.qdd.copy())
        g = self.regular
        well = slice(None) if well.all() else well
        g.t[well], g.qd[well], g.qdd[well] = t[well, -1], qd[well, -1], qdd[well, -1]
        keep = rec >= 0
        if not keep.any():
            return
        k = rec[keep]
        whole = (isinstance(at, slice) and keep.all() and k[-1] - k[0] == len(k) - 1)
        if self.poses is not None:
            self.poses[np.ix_(mask, k)] = q[mask][:, keep]
        if self.pose_rates is not None:
            self.pose_rates[np.ix_(mask, k, [0])] = qd[mask][:, keep][:, :, None]
            self.pose_rates[np.ix_(mask, k, [1])] = qdd[mask][:, keep][:, :, None]
        full_qd = qd if order >= 1 else None
        full_qdd = qdd if order >= 2 else None
        # the usual case, every variant and a run of instants: by slices rather than copies
        cache: dict = {}  # the multipliers, once for all the reactions asked for
        for spec in system.outputs:
            values = eq.output_values(self.kernels, spec, q, full_qd, full_qdd, t, cache)
            if whole:
                self.data[spec.label][:, k[0] : k[-1] + 1] = values
            else:
                self.data[spec.label][np.ix_(mask, k)] = values[mask][:, keep]
            if isinstance(spec, ExprOutput) and spec.label not in self.undefined_outputs:
                self._watch_named(spec.label, values[:, keep], t[:, keep], mask)
        self.n_solved[mask] = k[-1] + 1

    def _watch_named(self, label: str, values: np.ndarray, t: np.ndarray,
                     mask: np.ndarray) -> None:
        """Warn, once per named output, where its expression is not a finite number (the rate
        of a distance between coinciding points, log of a negative number): a result the
        user defined, written as it is, but never silently."""
        bad = ~np.isfinite(values) & mask[:, None]
        if bad.any():
            v, j = np.argwhere(bad)[0]
            self.undefined_outputs.add(label)
            self.warnings.append(
                f"output {label} is {float(values[v, j])!r} from t = {t[v, j]:.10g}"
                f"{variant_label(self.system, int(v))} on: its expression is not defined there "
                "(such as the rate of the distance between two points that coincide); those "
                "values are written as they are")

    def _split_at_nonfinite(self, q: np.ndarray, t: np.ndarray, rec: np.ndarray, fac: Factor,
                            mask: np.ndarray, rates: tuple[np.ndarray, np.ndarray],
                            bad: np.ndarray) -> None:
        """Accept the columns before the first one with a non-finite result, stop the
        variants that have one there (a numerical failure naming the quantity and the
        instant), and go on with the others from that column."""
        c = q.shape[1]
        j = int(np.argmax(bad.any(axis=0)))
        full = rates[0].shape[1] == c

        def part(cols: slice) -> tuple[np.ndarray, np.ndarray] | None:
            return (rates[0][:, cols], rates[1][:, cols]) if full else None

        if j:
            self.accept(q[:, :j], t[:, :j], rec[:j], fac.columns(slice(0, j)), mask,
                        part(slice(0, j)))
        qd, qdd = rates if full else (np.full(q.shape, np.nan), np.full(q.shape, np.nan))
        for v in np.flatnonzero(bad[:, j] & mask):
            self.failures.append(nonfinite_message(self.kernels, int(v), q[v, j], qd[v, j],
                                                   qdd[v, j], float(t[v, j]), int(rec[j])))
            self.active[v] = False
            mask[v] = False
        if mask.any():
            self.accept(q[:, j:], t[:, j:], rec[j:], fac.columns(slice(j, c)), mask,
                        part(slice(j, c)))

    def _watch_redundant(self, phi: np.ndarray, t: np.ndarray, mask: np.ndarray) -> None:
        """Stop the variants of a redundant model whose equations no longer all hold: least
        squares converges to a compromise where redundant constraints are inconsistent."""
        if not self.watched.size:
            return
        limit = self.opts.assembly_residual
        resid = np.abs(phi[..., self.watched]) * self.watch_weights
        bad = mask & ~(resid <= limit).all(axis=(1, 2))
        for v in np.flatnonzero(bad):
            col = int(np.argmax((resid[v] > limit).any(axis=-1)))
            worst = self.watched[np.argsort(-resid[v, col])[:3]]
            self.failures.append(
                f"the redundant constraints no longer hold together at t = {t[v, col]:.10g}"
                f"{variant_label(self.system, int(v))}: equations of "
                f"{constraint_names(self.system, worst)} are violated (scaled residual "
                f"{resid[v, col].max():.3g}); the constraints are inconsistent, "
                "over-constraining the mechanism as it moves")
            self.active[v] = False
            mask[v] = False

    # -- parallel in time ------------------------------------------------------------------------
    def parallel(self, k: int, end: int) -> int:
        """Solve the instants k .. end-1 in levels, parallel in time; return the first instant
        not solved.

        1. Coarse: march every ``coarse_stride``-th instant (and end-1) from the state with a
           loose Newton tolerance (:func:`mechdsl.solve.levels.coarse_march`); then correct
           those states all at once to the full tolerance and solve their velocities and
           accelerations (:meth:`level`): the first nodes. (A single mechanism's coarse march
           runs on floats and solves its states exactly at once.)
        2. Levels: split every gap between nodes by ``level_split``; the new instants,
           predicted by the quintic Hermite interpolation of the nodes
           (:mod:`mechdsl.solve.hermite`), are corrected all at once and become nodes, until
           the gaps are at most ``level_split`` instants. (A single mechanism first skips
           them: its instants are predicted from the coarse states directly, and the levels
           refine the gaps only if that prediction fails a check in step 3.)
        3. Settle: every instant of the window, predicted from the nodes, is solved by batched
           Newton (:func:`mechdsl.solve.batch.settle`), factorised, checked against its
           predecessor and recorded.

        At every level each state is checked as the march checks it: converged, regular
        (condition above ``singular_rcond``), det(Phi_q) of the same sign as at the start of
        the window (no singular position crossed), and Newton's correction small against the
        motion from the node before (``branch_ratio``: no jump to another branch). Any failure
        stops here, and the ordinary march takes the window over: it finds and reports the
        failure at its exact instant. The number of sequential batched steps grows like
        log(instants).
        """
        system, opts, times, D, rows = self.system, self.opts, self.times, self.D, self.rows
        act = self.active[:, None]
        first = int(np.flatnonzero(self.active)[0])
        if len(rows) != system.n:
            return k  # not as many independent equations as coordinates: the careful march
        split = opts.level_split
        coarse = coarse_march(self.kernels, (self.t, self.q, self.qd, self.qdd), self.sign,
                              times[k - 1 : end], opts.coarse_stride, D, opts, rows,
                              min_gap=split, active=self.active)
        if coarse is None:
            return k
        # the coarse states, corrected to the full tolerance (unless the march on floats
        # solved them so, with their checks and rates): the first nodes
        idx, states, settled = coarse[0] + k - 1, coarse[1], coarse[2]
        Tc = np.where(act, times[idx][None, :], self.t[:, None])
        start = (self.t[:, None], self.q[:, None], self.qd[:, None], self.qdd[:, None])
        level = (Tc, *states) if settled else self.level(states[0], Tc)
        if level is None:
            return k
        node = np.concatenate(([k - 1], idx))
        nodes = (node, *(np.concatenate((a, b), axis=1) for a, b in zip(start, level)))
        # a single mechanism's coarse states are solved exactly, with their rates: every
        # instant is first predicted from them directly; levels refine the gaps only if that
        # prediction fails a check somewhere (the general march takes over only after)
        direct = settled
        if not direct:
            nodes = self._refine(nodes, first)
            if nodes is None:
                return k
        cap = self._batch_cap()
        j0 = k
        while j0 < end:
            # the last batch's arrays let go before this one's are made (as in batch.settle)
            T = values = pred = done = q = fac = rates = ratio = good = None
            idx = np.arange(j0, min(j0 + cap, end))
            T = np.where(act, times[idx][None, :], self.t[:, None])
            values = _drive_values(self.kernels, T)
            if (_undefined_drives(self.kernels, T, values) & act).any():
                return j0
            _, tn, qn, qdn, qddn = nodes
            with np.errstate(all="ignore"):
                pred = quintic_hermite(tn[first], qn, qdn, qddn, times[idx])
            rates = None
            done = batch.settle(self.kernels, pred, T, D, self.active, opts,
                                rates=self.pose_rates is not None or system.order >= 1,
                                before=self.q, floor=self.floor, drive_values=values)
            if done is not None:
                q, ok, fac, ratio = done.q, done.converged, done.fac, done.ratio
                if done.qd is not None:
                    rates = (done.qd, done.qdd)
            else:
                q, ok, _ = newton(self.kernels, pred, T, D, self.active, opts, rows)
                fac = factor(eq.solver_jacobian(self.kernels, q, rows, False), D)
                previous = np.concatenate((self.q[:, None], q[:, :-1]), axis=1)
                ratio = correction_ratio(q, pred, previous, D, self.floor)
            good = (ok & (fac.rcond >= opts.singular_rcond) & (fac.sign == self._signs_before(fac))
                    & (ratio <= opts.branch_ratio)) | ~act
            nacc = _good_prefix(good)
            if nacc:
                self.accept(q[:, :nacc], T[:, :nacc], idx[:nacc], fac.columns(slice(0, nacc)),
                            self.active.copy(),
                            None if rates is None else tuple(x[:, :nacc] for x in rates),
                            residual=None if done is None else done.residual[:, :nacc])
            if not self.active.any():
                return j0 + nacc
            if nacc < len(idx):
                if not direct:
                    return j0 + nacc
                # predicted too coarsely somewhere: the gaps from the last state on are
                # refined by levels
                direct = False
                node, tn, qn, qdn, qddn = nodes
                keep = node > j0 + nacc - 1
                now = (self.t[:, None], self.q[:, None], self.qd[:, None], self.qdd[:, None])
                nodes = self._refine((np.concatenate(([j0 + nacc - 1], node[keep])),
                                      *(np.concatenate((a, b[:, keep]), axis=1)
                                        for a, b in zip(now, (tn, qn, qdn, qddn)))), first)
                if nodes is None:
                    return j0 + nacc
            j0 += nacc
        return end

    def _refine(self, nodes: tuple, first: int) -> tuple | None:
        """Split every gap between the ``nodes`` (instant indices, t, q, qd, qdd) longer than
        ``level_split`` into level_split parts (or into as few as leave none longer), level
        by level, each level's states predicted by the quintic Hermite interpolation of the
        nodes and corrected all at once (:meth:`level`); the refined nodes, or None where a
        state fails a check."""
        split, times = self.opts.level_split, self.times
        act = self.active[:, None]
        node, tn, qn, qdn, qddn = nodes
        while (np.diff(node) > split).any():
            # (sets, not np.unique: that imports numpy.ma, 10 ms of every start-up)
            have = set(node.tolist())
            pairs = zip(node[:-1].tolist(), node[1:].tolist())
            new = np.array(sorted({a + (i * (b - a)) // parts for a, b in pairs if b - a > split
                                   for parts in (min(split, -(-(b - a) // split)),)
                                   for i in range(1, parts)} - have), np.intp)
            T = np.where(act, times[new][None, :], self.t[:, None])
            with np.errstate(all="ignore"):
                pred = quintic_hermite(tn[first], qn, qdn, qddn, times[new])
            left = np.searchsorted(node, new) - 1
            level = self.level(pred, T, base=qn[:, left])
            if level is None:
                return None
            order = np.argsort(np.concatenate((node, new)), kind="stable")
            node = np.concatenate((node, new))[order]
            tn, qn, qdn, qddn = (np.concatenate((a, b), axis=1)[:, order]
                                 for a, b in zip((tn, qn, qdn, qddn), level))
        return node, tn, qn, qdn, qddn

    def level(self, pred: np.ndarray, T: np.ndarray, base: np.ndarray | None = None
              ) -> tuple[np.ndarray, ...] | None:
        """Correct the predicted states ``pred`` (V, c, n) at ``T`` (V, c) all at once
        (:func:`mechdsl.solve.levels.polish`) and solve their rates: the new nodes
        (t, q, qd, qdd), or None if a state fails a check. Newton's correction is measured
        against the motion from ``base`` (V, c, n), the node before each state; without it
        (the loosely solved states of the coarse march, already checked), it is not."""
        system, opts, D, rows = self.system, self.opts, self.D, self.rows
        act = self.active[:, None]
        values = _drive_values(self.kernels, T)
        if (_undefined_drives(self.kernels, T, values) & act).any():
            return None
        done = _settle_in_batches(self.kernels, pred, T, D, self.active, opts, self._batch_cap(),
                                  values)
        if done is not None:
            q, ok, fac = done.q, done.converged, done.fac
        else:
            q, ok = polish(self.kernels, pred, T, D, opts, rows, self.active)
            fac = factor(eq.solver_jacobian(self.kernels, q, rows, False), D)
        ratio = (correction_ratio(q, pred, base, D, self.floor) if base is not None
                 else np.zeros(q.shape[:-1]))
        good = (ok & (fac.rcond >= opts.singular_rcond) & (fac.sign == self.sign[:, None])
                & (ratio <= opts.branch_ratio)) | ~act
        if not good.all():
            return None
        if done is not None:
            return T, q, done.qd, done.qdd
        with np.errstate(all="ignore"):
            qd = fac.solve(eq.velocity_rhs(self.kernels, T, q.shape[:-1])[..., rows])
            qdd = fac.solve(eq.acceleration_rhs(self.kernels, q, qd, T)[..., rows])
        return T, q, qd, qdd

    # -- the compiled march ----------------------------------------------------------------------
    def _native(self):
        """The compiled module of the model (:mod:`mechdsl.compiled.native`), where the
        options ask for it and it applies (a square system without redundant equations, the
        member layout, no function arguments, numba installed); else None."""
        if not _wants_native(self.system, self.opts) or len(self.rows) != self.system.n:
            return None
        module = self.kernels.native
        if module is None and self.opts.backend == "compiled":
            why = ("numba is not installed (pip install mechdsl[fast])" if not native.available()
                   else "the compiled backend does not compile this model (a function "
                   "argument, or more than a small mechanism's constraints)")
            self.warnings.append(f"backend 'compiled' asked for, but {why}: solved on numpy")
        return module

    def native_march(self, module, k: int) -> int:
        """The instants from k by the compiled march (:mod:`mechdsl.compiled.native`), a
        chunk of ``native.chunk_instants`` at a time from the last state (so that progress
        is shown and an interrupt is taken between chunks; k = 0: from the assembled
        configuration, instant 0 included); each chunk's instants up to the first where
        some variant stops are accepted (with their rates, condition numbers and signs),
        and the numpy march goes on from there. Returns the first instant not solved."""
        system, opts, times, progress = self.system, self.opts, self.times, self.progress
        K, V, n = len(times), system.n_variants, system.n
        every = bool(self.active.all())
        live = slice(None) if every else np.flatnonzero(self.active)  # (a slice copies nothing)
        params = self.kernels.fused.params
        P = (np.stack([np.broadcast_to(p, (V, 1))[:, 0] for p in params]) if params
             else np.zeros((0, V)))
        c = np.ascontiguousarray
        P, D = c(P[:, live]), c(self.D[live, 0])
        L = V if every else len(live)
        march = module.march if L > 1 else module.march_one
        step = native.chunk_instants(L)
        while k < K:
            first = int(k == 0)  # column 0: the state's instant, or instant 0 to solve
            start, end = k - 1 + first, min(K, k + step)
            T = np.broadcast_to(times[start:end], (V, end - start))
            C = end - start
            fd = (eq.drive_table(self.kernels, T, T.shape) if self.kernels.drive_functions
                  else np.zeros((V, C, 3, 0)))
            values = _derivatives(fd) if self.kernels.drive_functions else None
            if (_undefined_drives(self.kernels, T, values) & self.active[:, None]).any():
                return k
            if not every:
                fd = np.ascontiguousarray(fd[live])
            # every column before a variant's status is written by the march; only those
            # are read
            out = [np.empty((L, C, n)) for _ in range(3)] + [np.empty((L, C)) for _ in range(2)]
            status, residual = np.zeros(L, np.int64), np.zeros(L)
            _call_compiled(march, c(self.q[live]), c(self.qd[live]), c(self.qdd[live]),
                  c(self.sign[live], dtype=float), c(times[start:end]), fd, P, D,
                  opts.newton_tol, opts.newton_error, opts.settled_step,
                  opts.max_iterations, THRESHOLD,
                  opts.branch_ratio, opts.singular_rcond, first, *out, status, residual)
            if L == V:  # the usual case: no copies of the results
                Q, QD, QDD, RC, SG = out
            else:
                Q, QD, QDD = (np.full((V, C, n), np.nan) for _ in range(3))
                RC, SG = np.ones((V, C)), np.zeros((V, C))
                for full, part in zip((Q, QD, QDD, RC, SG), out):
                    full[live] = part
            reached = int(status.min())  # the first column of the chunk not solved
            if reached > 1 - first:
                cols = slice(1 - first, reached)
                self.residual = max(self.residual, float(residual.max(initial=0.0)))
                self.accept(Q[:, cols], T[:, cols], np.arange(k, start + reached),
                            Factor(None, RC[:, cols], SG[:, cols]), self.active.copy(),
                            (QD[:, cols], QDD[:, cols]), checked=True)
            k = start + reached
            if progress is not None:
                progress(k, K)
            if reached < C:
                break
        return k

    # -- instant by instant ----------------------------------------------------------------------
    def march(self, grid: np.ndarray) -> None:
        """Solve the instants ``grid`` (indices into ``system.times``, increasing, after the
        state's time) one block after another, each block predicted from the last state
        (:meth:`predict`) and solved by Newton-Raphson, Phi_q dq = -Phi; a failing instant
        is approached by bisection, then passed (:meth:`through`, at_singular = "continue")
        or reported."""
        system, opts, D, rows, progress = self.system, self.opts, self.D, self.rows, self.progress
        # position 0 is the state's own time; position j >= 1 is instant grid[j - 1]
        times = np.concatenate(([float(self.t[self.active][0])], system.times[grid]))
        instant = np.concatenate(([-1], np.asarray(grid)))
        K, K_all = len(times), len(system.times)
        stop_at_singular = opts.at_singular == "stop"
        sparse = use_sparse(system, opts, rows)
        cap = self._batch_cap()
        b = max(1, min(self.block, cap))
        k = 1  # the next position of ``times`` to solve
        # between output instants that cannot be reached in one step the interval is crossed
        # in substeps of adaptive size hsub (halved on failure, doubled on success)
        hsub: float | None = None
        attempts = 0
        floor = self.floor
        while k < K and self.active.any():
            if progress is not None:
                progress(int(instant[k]), K_all)
            t_now = float(self.t[self.active][0])  # the active variants move in lockstep
            h_out = times[k] - times[k - 1]
            if hsub is None:
                bb = min(b, K - k, cap)
                targets, rec = times[k : k + bb], np.arange(k, k + bb)
            elif t_now + hsub < times[k] - 1e-9 * h_out:
                targets, rec = np.array([t_now + hsub]), np.array([-1])
            else:
                targets, rec = times[k : k + 1], np.array([k])
            bb = len(targets)
            act = self.active[:, None]
            T = np.where(act, targets[None, :], self.t[:, None])
            undefined = _undefined_drives(self.kernels, T) & act
            pred = self.predict(T, opts.predictor_order)
            qn, ok, iters = newton(self.kernels, pred, T, D, self.active, opts, rows,
                                   reuse=self.fac if sparse else None)
            fac = factor(eq.solver_jacobian(self.kernels, qn, rows, sparse), D)
            ratio = correction_ratio(qn, pred, self.q[:, None], D, floor)
            singular = ok & ~(fac.rcond >= opts.singular_rcond)
            crossing = (ok & ~singular & (fac.sign != self._signs_before(fac))
                        & stop_at_singular)
            jump = ok & ~singular & ~crossing & ~(ratio <= opts.branch_ratio)
            good = (ok & ~singular & ~crossing & ~jump & ~undefined) | ~act
            nacc = _good_prefix(good)
            if hsub is not None:
                attempts += 1
            if nacc:
                self.accept(qn[:, :nacc], T[:, :nacc], _recorded(instant, rec[:nacc]),
                            fac.columns(slice(0, nacc)), self.active.copy())
                if hsub is None:
                    k += nacc
                elif rec[0] >= 0:
                    hsub, attempts, k = None, 0, k + 1
                else:
                    hsub = 2 * hsub
            if nacc == bb:
                if hsub is None:  # the block grows while Newton converges fast
                    if iters <= 3:
                        b = min(2 * b, opts.max_block, cap)
                    elif iters >= 6:
                        b = max(1, b // 2)
                    self.block = b
                continue
            if bb > 1:
                b = max(1, min(nacc, bb // 2))
                continue
            # a single step fails: shorten it, then decide
            target = float(targets[0])
            gap = target - t_now
            if attempts > opts.max_substeps:
                for v in np.flatnonzero(self.active):
                    defects = (jacobian_defects(self.kernels, pred[v, 0], target, int(v))
                               or jacobian_defects(self.kernels, self.q[v], float(self.t[v]),
                                                   int(v)))
                    self.failures.append(
                        f"Newton-Raphson does not converge after t = {t_now:.10g}: {defects}"
                        if defects else too_coarse_message(system, int(v), t_now,
                                                           int(instant[k]), opts.max_substeps))
                self.active[:] = False
                break
            if gap > h_out / 2**opts.max_bisections and not undefined.any():
                hsub = gap / 2
                b = 1
                continue
            # at the finest interval a large correction with a continuous position is a kink
            # in a drive's velocity, not a branch jump
            jump &= ~self._continuous(qn[:, 0], T[:, 0], fac, gap)
            good = (ok & ~singular & ~crossing & ~jump & ~undefined) | ~act
            rates = None
            if not stop_at_singular and (self.active & ~good[:, 0]).any():
                qn, rates, passed = self.through(pred, T)
                good |= passed[:, None] & ~undefined
            bad = self.active & ~good[:, 0]
            for v in np.flatnonzero(bad):
                if undefined[v, 0]:
                    self.failures.append(undefined_drive_message(self.kernels, int(v), target,
                                                                 int(instant[k])))
                    continue
                why = ("singular" if singular[v, 0] else "crossing" if crossing[v, 0]
                       else "jump" if jump[v, 0] else "diverged")
                self.failures.append(failure(self.kernels, self.q[v], float(self.t[v]), int(v),
                                             target, int(instant[k]), why, pred[v, 0]))
            self.active &= ~bad
            if self.active.any():
                fac = factor(eq.solver_jacobian(self.kernels, qn, rows, sparse), D)
                self.accept(qn, T, _recorded(instant, rec), fac, self.active.copy(), rates)
                if rec[0] >= 0:
                    hsub, attempts, k = None, 0, k + 1
                else:
                    hsub = gap

    def predict(self, T: np.ndarray, order: int = 2) -> np.ndarray:
        """The Taylor predictor from the state to the times ``T`` (V, b):
        q + tau qd + tau^2/2 qdd (to ``order``), falling back to lower orders where that is
        not finite (an infinite acceleration at t0, as for f = t^1.5)."""
        tau = (T - self.t[:, None])[..., None]
        q, qd, qdd = self.q[:, None], self.qd[:, None], self.qdd[:, None]
        with np.errstate(all="ignore"):
            first = q + tau * qd
            second = first + 0.5 * tau**2 * qdd if order >= 2 else first
        first = np.where(np.isfinite(first), first, q)
        return np.where(np.isfinite(second), second, first)

    def through(self, pred: np.ndarray, T: np.ndarray
                ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray], np.ndarray]:
        """One instant on a singular position, for the option at_singular = "continue"
        (:func:`mechdsl.solve.singular.singular_step`, started from the rates of the last
        regular state): the positions, their rates (qd, qdd) and the variants that passed."""
        g = self.regular
        tau = (T[:, 0] - g.t)[:, None]
        q, qd, qdd, ok = singular_step(self.kernels, pred, T, g.qd + tau * g.qdd, g.qdd, self.D,
                                       self.rows, self.opts)
        ratio = correction_ratio(q, pred, self.q[:, None], self.D, self.floor)[:, 0]
        passed = ok & (ratio <= self.opts.branch_ratio) & self.active
        if passed.any():
            self.passages.append(float(T[passed][0, 0]))
        return q, (qd, qdd), passed

    def _continuous(self, q: np.ndarray, t: np.ndarray, fac: Factor, gap: float) -> np.ndarray:
        """(V, 1): whether the step from the state to ``q`` (V, n) over ``gap`` is no larger
        than the velocities at both ends allow (twice their mean times the gap)."""
        D = self.D
        with np.errstate(all="ignore"):
            qd = fac.solve(eq.velocity_rhs(self.kernels, t[:, None], (len(q), 1))
                           [..., self.rows])[:, 0]
            speed = (np.abs(self.qd / D[:, 0]) + np.abs(qd / D[:, 0])).max(axis=-1)
            moved = np.abs((q - self.q) / D[:, 0]).max(axis=-1)
        return (moved <= speed * gap + self.floor * 1e-3)[:, None]

    def _batch_cap(self) -> int:
        """Instants solved together at most: V * b * m * n within ``max_batch_elements``,
        and V * b within ``LU_BATCH_STATES`` where the generated LU factorises them."""
        system = self.system
        per_instant = system.n_variants * system.m * system.n
        cap = max(1, self.opts.max_batch_elements // max(1, per_instant))
        if system.m == system.n and self.kernels.lu is not None:
            cap = min(cap, max(1, LU_BATCH_STATES // system.n_variants))
        return cap

    def _signs_before(self, fac: Factor) -> np.ndarray:
        """(V, b): the sign of det Phi_q at the state before each column of a block."""
        return np.concatenate((self.sign[:, None], fac.sign[:, :-1]), axis=1)


def _settle_in_batches(kernels: Kernels, pred: np.ndarray, T: np.ndarray, D: np.ndarray,
                       active: np.ndarray, opts: SolverOptions, cap: int,
                       values: tuple[np.ndarray, ...] | None):
    """:func:`mechdsl.solve.batch.settle` of a level, ``cap`` instants at a time (a batch
    that fits the processor's cache, as the last step's), joined; None where it does not
    apply to some batch. ``values``: the drives' f, f', f'' at ``T`` (:func:`_drive_values`)."""
    c = pred.shape[1]
    if c <= cap:
        return batch.settle(kernels, pred, T, D, active, opts, rates=True, drive_values=values)
    parts = []
    for j in range(0, c, cap):
        cut = slice(j, j + cap)
        part = batch.settle(kernels, pred[:, cut], T[:, cut], D, active, opts, rates=True,
                            drive_values=None if values is None
                            else tuple(v[:, cut] for v in values))
        if part is None:
            return None
        parts.append(part)
    cat = np.concatenate
    fac = Factor(None, cat([p.fac.rcond for p in parts], axis=1),
                 cat([p.fac.sign for p in parts], axis=1))
    return batch.Settled(cat([p.q for p in parts], axis=1),
                         cat([p.converged for p in parts], axis=1), fac,
                         cat([p.qd for p in parts], axis=1), cat([p.qdd for p in parts], axis=1),
                         cat([p.residual for p in parts], axis=1))


#: The solver methods by name: a compiled system is solved by one of them
#: (:mod:`mechdsl.solve.base` is the contract a method fulfils).
METHODS: dict[str, type[Run]] = {KinematicRun.name: KinematicRun,
                                  DynamicRun.name: DynamicRun}


def simulate(kernels: Kernels, options: SolverOptions | None = None, *,
             poses: bool = False, rates: bool = False, progress: Progress | None = None,
             extra_memory: int = 0) -> Results:
    """Solve positions (and, where outputs need them, velocities and accelerations) at every
    instant of ``system.times``, for every variant; with ``poses``, also keep every body's
    (x, y, phi) at every instant (``Results.poses``), for drawings and exports, and with
    ``rates`` their first and second time derivatives too (``Results.rates``). ``progress``
    is called as progress(instants_done, instants) as the run goes on. A run whose memory,
    with ``extra_memory`` bytes that the caller will add for its outputs, would exceed
    ``options.max_memory`` is refused before it starts (:func:`mechdsl.solve.memory.plan`).

    Raises MechError if the model is not fully driven. Numerical failures do not raise: the
    failing variant stops, the instants solved before are kept, and ``Results.status`` is
    ``"failed"`` with the reasons in ``Results.messages``. Neither does an interrupt (status
    ``"interrupted"``): the instants solved before are kept.
    """
    kwargs = dict(poses=poses, rates=rates, progress=progress, extra_memory=extra_memory)
    run = METHODS[method_for(kernels)](kernels, options, **kwargs)
    try:
        results = run.run()
    except NotFullyDriven:
        # redundant joints hid free degrees of freedom from the count (a parallelogram's
        # third and fourth cranks, one driven, a pendulum hung from its coupler): the
        # rank at the assembly shows them, and a model with masses moves under its loads
        if kernels.dynamics is None or isinstance(run, DynamicRun):
            raise
        run = DynamicRun(kernels, options, **kwargs)
        results = run.run()
    if not rates and results.rates is not None:  # kept for the extremes only
        results = replace(results, rates=None, poses=results.poses if poses else None)
    return reduce_results(results, kernels, getattr(run, "extrema", None))


def method_for(kernels: Kernels) -> str:
    """The method that solves ``kernels``: the kinematic march where the drives determine the
    motion (as many equations as coordinates, or more), the forward dynamics where they do
    not and the model has masses. A model with masses and no drive at all is forward
    dynamics whatever its count of equations: nothing could drive it, and as many joint
    equations as coordinates means redundant constraints (a parallelogram with a third
    crank), which the forward dynamics integrates."""
    system = kernels.system
    if kernels.dynamics is not None and (system.m < system.n or not system.drive_rows.size):
        return "dynamic"
    return "kinematic"


# -- helpers without state -------------------------------------------------------------------------
def _call_compiled(fn, *args) -> None:
    """Call a numba function. A signal whose Python handler runs while numba's dispatcher
    is converting the arguments or the result (an interrupt, SIGTERM made one) comes out as
    a SystemError caused by that exception: raise the interrupt itself."""
    try:
        fn(*args)
    except SystemError as err:
        if isinstance(err.__cause__, KeyboardInterrupt):
            raise err.__cause__ from None
        raise


def _nonfinite(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, need: int) -> np.ndarray:
    """(V, c): the columns of a block whose position, or the rates the outputs need (``need``
    is their highest time derivative), are not all finite. Rates solved at the last column
    only (for the predictor) are not results and are not checked."""
    c = q.shape[1]
    bad = ~allfinite(q)
    for order, a in ((1, qd), (2, qdd)):
        if need >= order and a.shape[1] == c:
            bad |= ~allfinite(a)
    return bad


def _good_prefix(good: np.ndarray) -> int:
    """How many leading columns of a block (V, b) are good in every variant."""
    col_ok = good.all(axis=0)
    return len(col_ok) if col_ok.all() else int(np.argmin(col_ok))


def _recorded(instant: np.ndarray, rec: np.ndarray) -> np.ndarray:
    """The instants (indices into system.times) that the march's positions ``rec`` record;
    -1 for substeps."""
    return np.where(rec >= 0, instant[np.maximum(rec, 0)], -1)


def _wants_native(system: System, opts: SolverOptions) -> bool:
    """Whether the options ask for the compiled backend for this run: "compiled", or "auto"
    for a run of at least ``compiled_from`` states with numba installed (a square system;
    whether the model compiles is known only when it is loaded)."""
    if opts.backend == "numpy" or system.m != system.n or system.times is None:
        return False
    return opts.backend == "compiled" or (
        system.n_variants * len(system.times) >= opts.compiled_from and native.available())


def _undefined_drives(kernels: Kernels, T: np.ndarray,
                      values: tuple[np.ndarray, ...] | None = None) -> np.ndarray:
    """(V, b): where some drive's function, or its derivatives, is not a finite number
    (``values``: f, f', f'' at ``T`` where the caller has them, from :func:`_drive_values`)."""
    if not kernels.drive_functions:
        return np.zeros(T.shape, bool)
    values = values or _drive_values(kernels, T)
    if all(np.isfinite(v).all() for v in values):  # the usual case: a reduction each
        return np.zeros(T.shape, bool)
    ok = np.ones(T.shape, bool)
    for v in values:
        ok &= allfinite(v)
    return ~ok


def _drive_values(kernels: Kernels, T: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """f, f', f'' of every drive at ``T`` (V, b), each (V, b, drives); None without drives."""
    if not kernels.drive_functions:
        return None
    return _derivatives(eq.drive_table(kernels, T, T.shape))


def _derivatives(table: np.ndarray) -> tuple[np.ndarray, ...]:
    """f, f', f'' as views of the drives' table (:func:`mechdsl.compiled.equations.
    drive_table`), each (..., drives)."""
    return tuple(table[..., i, :] for i in range(3))
