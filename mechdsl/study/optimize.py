"""The best design: the ``optimize``, ``minimize``/``maximize`` and ``subject to`` statements
of a model, solved with scipy's optimisers, every population or gradient stencil one sweep.

The search is global, then local. Differential evolution (scipy's
``differential_evolution``, vectorised: each generation's population is one sweep, and the
requirements are evaluated from the same sweep) needs no derivative and is not caught by the
local minima that reductions such as max() and min() make; then SLSQP refines its best point
with the requirements as inequality constraints g(p) >= 0 and gradients by central
differences, df/dp_i = (f(p + h_i e_i) - f(p - h_i e_i)) / (2 h_i), h_i = ``REL_STEP`` times
the width of p_i's range, the 2N + 1 points of a stencil again one sweep. The refined point is
kept only if it satisfies every requirement and improves on the evolution's best.

Every sweep goes through :func:`mechdsl.study.solve_sweep`: on the Dask cluster when a client
is given, in chunks of variants otherwise.

A design whose objective is not a finite number (nan, inf: a variant that failed, or an
objective such as log(x) where x <= 0) is infeasible, whatever its requirements say; a search
in which no design has a finite objective is a NumericalError, never a minimum. An interrupt
(KeyboardInterrupt, or a sweep that comes back interrupted) stops the search: :func:`optimize`
returns the best design solved so far, marked ``interrupted``.
"""

from __future__ import annotations

import inspect
import signal
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..compiled.variants import Overrides
from ..errors import MechError, NumericalError
from ..grammar import expr as E
from ..results import Results
from ..solve.options import SolverOptions

#: Central-difference step of the local refinement, relative to each param's range
REL_STEP = 1e-6
#: A requirement holds where its slack is at least -REQUIRE_TOL (in its own units): the
#: round-off of a comparison at its bound, such as range(slider.x) >= 4 where the stroke is
#: 2r and r = 2 exactly, is not a violation
REQUIRE_TOL = 1e-12
#: Defaults of the evolution: population per varied param, generations at most, the relative
#: spread of the population's objectives at which it stops, and its random seed
POPSIZE = 15
MAXITER = 200
TOL = 1e-6
SEED = 0


@dataclass(frozen=True)
class Optimum:
    """What :func:`optimize` found: the ``params`` (the varied ones, at their best), the
    ``objective`` there, each requirement's text and slack (>= -REQUIRE_TOL where it
    holds), whether all hold and the objective is a finite number (``feasible``), the
    variants solved in how many sweeps, the time taken, how the search ended (``message``),
    and ``run``, the model's own outputs at the best params.

    ``nonfinite`` counts the designs solved whose objective was not a finite number, those
    that could not be solved (``failed``: a mechanism that locks, ...) included: they count
    as infeasible. ``interrupted`` is the signal that stopped the search before its end
    (``signal.SIGTERM`` for the Interrupted of :class:`~mechdsl.writing.SignalGuard`,
    ``signal.SIGINT`` for a plain KeyboardInterrupt or a sweep that came back interrupted),
    None if it ran to its end. When it is set, the params are the best feasible design
    solved so far (not a proven optimum), or, if none was feasible yet, the one that violates
    the requirements least (``feasible`` False; ``params`` empty and ``objective`` nan if no
    design was solved at all)."""

    params: dict[str, float]
    objective: float
    requirements: dict[str, float]
    feasible: bool
    variants: int
    sweeps: int
    seconds: float
    message: str
    run: Results | None = None
    nonfinite: int = 0
    failed: int = 0
    interrupted: int | None = None

    @staticmethod
    def holds(slack: float) -> bool:
        """Whether a requirement of this slack holds (slack >= -REQUIRE_TOL)."""
        return bool(slack >= -REQUIRE_TOL)


class SearchInterrupted(BaseException):
    """A sweep of the search came back interrupted (the solver keeps what it solved and
    returns, it does not raise): raised by :class:`Evaluator` to stop the search, and caught
    by :func:`optimize`. A BaseException, as KeyboardInterrupt is, so that it unwinds scipy's
    optimisers, which take some of their callbacks' Exceptions (a ValueError of the
    objective, for instance) as answers, and no ``except Exception`` on the way stops it."""


class Evaluator:
    """The objective and the requirements' slacks of rows of param values, each batch of new
    rows solved as one sweep; every row solved is remembered, and the best feasible one
    (finite objective, every requirement met) is kept with its params. A sweep that comes
    back interrupted raises :class:`SearchInterrupted` once the variants it solved whole are
    recorded."""

    def __init__(self, mech, ov: Overrides, options, client, chunk) -> None:
        opt = mech.model.optimization
        self.names = [name for name, *_ in opt.ranges]
        self.sign = -1.0 if opt.sense == "max" else 1.0
        outputs = (opt.objective, *opt.requirements)
        self.mech = mech.sharing(replace(mech.model, outputs=outputs, sweeps=()))
        self.ov, self.options, self.client, self.chunk = ov, options, client, chunk
        self.labels = [o.name for o in outputs]
        self.seen: dict[bytes, np.ndarray] = {}
        self.variants = self.sweeps = 0
        #: designs solved whose objective is not a finite number, and those of them that
        #: failed to solve (a locked or singular mechanism, ...)
        self.nonfinite = self.failed = 0
        #: (signed objective, params row, values row) of the best feasible design solved;
        #: one tuple, replaced whole, so that an interrupt never leaves its parts mismatched
        self.best_design: tuple[float, np.ndarray, np.ndarray] | None = None
        #: called as progress(best objective, variants, sweeps) after each sweep
        self.progress: Callable[[float, int, int], None] | None = None

    @property
    def best(self) -> float:
        """The best objective (signed: minimised) of a feasible design solved, inf if none."""
        return np.inf if self.best_design is None else self.best_design[0]

    def __call__(self, rows: np.ndarray) -> np.ndarray:
        """(S, 1 + M): the signed objective (minimised) and the M slacks of each row of
        ``rows`` (S, N); a variant that fails, or whose objective is not a finite number, has
        objective inf, and a slack that is not a finite number is -inf."""
        rows = np.atleast_2d(np.asarray(rows, dtype=float))
        if not len(rows):  # the evolution asks for none when no member meets the requirements
            return np.empty((0, len(self.labels)))
        new = {r.tobytes(): r for r in rows if r.tobytes() not in self.seen}
        if new:
            self._solve(np.array(list(new.values())))
        return np.array([self.seen[r.tobytes()] for r in rows])

    def _solve(self, table: np.ndarray) -> None:
        """Solve the rows of ``table`` as one sweep and record them; raise
        :class:`SearchInterrupted` if the sweep was interrupted."""
        from . import solve_sweep

        ov = replace(self.ov, sweeps={}, table={n: table[:, i]
                                                for i, n in enumerate(self.names)})
        res = solve_sweep(self.mech, ov, self.options, client=self.client, chunk=self.chunk)
        values = np.column_stack([np.asarray(res.reduced[k], dtype=float)
                                  for k in self.labels])
        values[:, 0] *= self.sign
        bad = ~np.isfinite(values)
        values[:, 0][bad[:, 0]] = np.inf
        values[:, 1:][bad[:, 1:]] = -np.inf
        whole = np.asarray(res.n_solved) >= len(res.times)
        interrupted = res.status == "interrupted"
        # of an interrupted sweep, only the variants solved to the end are known: the others
        # were cut short (or never started), their values are not theirs
        keep = whole if interrupted else np.ones(len(table), dtype=bool)
        for row, v in zip(table[keep], values[keep]):
            self.seen[row.tobytes()] = v
        self.variants += int(keep.sum())
        self.sweeps += int(bool(keep.any()) or not interrupted)
        self.nonfinite += int(np.sum(bad[keep, 0]))
        self.failed += int(np.sum(keep & ~whole))
        ok = keep & feasible(values)
        if ok.any():
            k = np.flatnonzero(ok)[np.argmin(values[ok, 0])]
            if values[k, 0] < self.best:
                self.best_design = (float(values[k, 0]), table[k].copy(), values[k].copy())
        if self.progress is not None:
            self.progress(self.sign * self.best, self.variants, self.sweeps)
        if interrupted:
            raise SearchInterrupted()

    def least_violating(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(params row, values row) of the design solved that violates the requirements
        least (a finite objective preferred, then the smaller objective); None if none was
        solved."""
        if not self.seen:
            return None
        keys = list(self.seen)
        values = np.array([self.seen[k] for k in keys])
        violation = -np.sum(np.minimum(values[:, 1:], 0.0), axis=1)
        k = min(range(len(keys)), key=lambda i: (not np.isfinite(values[i, 0]),
                                                 violation[i], values[i, 0]))
        return np.frombuffer(keys[k], dtype=float).copy(), values[k]


def feasible(values: np.ndarray) -> np.ndarray:
    """Which rows of ``values`` (objective, slacks: :class:`Evaluator`'s) are feasible
    designs: a finite objective, every slack at least -REQUIRE_TOL."""
    values = np.atleast_2d(values)
    return np.isfinite(values[:, 0]) & np.all(values[:, 1:] >= -REQUIRE_TOL, axis=1)


def bounds_of(mech, ov: Overrides) -> list[tuple[float, float]]:
    """Each varied param's (low, high), its bounds evaluated with the other params' values."""
    from ..compiled.variants import evaluate

    env = {k: v[0] for k, v in evaluate(mech.model, replace(ov, sweeps={})).env.items()}
    out = []
    for name, lo, hi, span in mech.model.optimization.ranges:
        a, b = (float(np.asarray(E.evaluate(e, env))) for e in (lo, hi))
        if not (np.isfinite(a) and np.isfinite(b) and a < b):
            raise MechError(f"the range of '{name}' is {a:g} .. {b:g}: give finite bounds, "
                            "the first below the second", span, mech.model.source)
        out.append((a, b))
    return out


def optimize(mech, ov: Overrides | None = None, options: SolverOptions | None = None, *,
             client=None, chunk: int | None = None, popsize: int = POPSIZE,
             maxiter: int = MAXITER, tol: float = TOL, seed: int = SEED,
             refine: bool = True, run: bool = True, grid: int | None = None,
             progress: Callable[[float, int, int], None] | None = None) -> Optimum:
    """Minimise (or maximise) the model's objective over its ``optimize`` ranges, subject to
    its requirements: differential evolution, then SLSQP (see the module's docstring). With
    ``run``, the run at the best params, with the model's own outputs, is in ``Optimum.run``.
    With ``grid`` = n, a brute-force search instead: every point of the n x n x ... grid of
    the ranges (ends included) solved as one sweep, the best feasible one taken.
    ``progress(best objective so far, variants, sweeps)`` is called after every sweep.

    The best design reported always has a finite objective; a search in which no design
    solved has one raises :class:`~mechdsl.errors.NumericalError`. An interrupt during the
    search (a KeyboardInterrupt, a SIGTERM turned into one by
    :class:`~mechdsl.writing.SignalGuard`, or a sweep that comes back interrupted) does not
    propagate: the search stops and the Optimum of the best design solved so far is returned
    with ``interrupted`` set (see :class:`Optimum`); with ``run``, the model is still run
    there (a second interrupt stops that run, which keeps the instants it solved)."""
    from scipy.optimize import NonlinearConstraint, differential_evolution, minimize

    opt = mech.model.optimization
    if opt is None:
        raise MechError("the model has no 'optimize' statement: add one, such as "
                        "'optimize l in 2.5 .. 4', and 'minimize EXPR'")
    ov = ov or Overrides()
    start = time.perf_counter()
    bounds = bounds_of(mech, ov)
    evaluate = Evaluator(mech, ov, options, client, chunk)
    evaluate.progress = progress
    M = len(opt.requirements)
    constraints = ()
    if M:
        constraints = (NonlinearConstraint(
            lambda x: evaluate(np.asarray(x).T)[:, 1:].T, -REQUIRE_TOL, np.inf),)
    found: np.ndarray | None = None  # where the search itself ended
    interrupted: int | None = None
    method = "a grid" if grid is not None else "differential evolution"
    try:
        if grid is not None:
            found, message = _grid_search(evaluate, bounds, grid)
            refine = False
        else:
            seeding = ({"rng": seed}
                       if "rng" in inspect.signature(differential_evolution).parameters
                       else {"seed": seed})
            result = differential_evolution(
                lambda x: evaluate(np.asarray(x).T)[:, 0], bounds, popsize=popsize,
                maxiter=maxiter, tol=tol, polish=False, vectorized=True, updating="deferred",
                constraints=constraints, init="sobol", **seeding)
            found = np.asarray(result.x, dtype=float)
            message = f"differential evolution: {result.message}"
        end = evaluate(found[None])[0]
        if not feasible(end)[0] and evaluate.best_design is not None:
            # the evolution's end point is infeasible or not finite (all of its population
            # was, in a generation where only such designs were left): the best one solved
            found = evaluate.best_design[1]
            message += "; the best design it solved is taken"
        elif not np.isfinite(end[0]):  # none feasible: the least violating, finite if any
            found = evaluate.least_violating()[0]
        if refine:
            method = "the SLSQP refinement"
            refined = _refine(evaluate, found, bounds, M, minimize)
            if refined is not None:
                found, message = refined, message + "; refined by SLSQP"
    except (SearchInterrupted, KeyboardInterrupt) as err:
        # (a sweep that the solver's own handler stopped does not know which signal it was:
        # the caller's signal handler does; the message names none)
        interrupted = getattr(err, "signum", None) or signal.SIGINT
        found = None
        message = (f"{method} interrupted after {evaluate.sweeps} "
                   f"sweep{'s' if evaluate.sweeps != 1 else ''}")
    if interrupted is None and evaluate.variants and evaluate.nonfinite == evaluate.variants:
        failed = (f" ({evaluate.failed} of them failed to solve)" if evaluate.failed else "")
        raise NumericalError(
            f"the objective is not a finite number for any of the {evaluate.variants} designs "
            f"solved{failed}: there is no minimum to report; check the objective where it is "
            "evaluated (a log or sqrt of a negative number, a division by zero) and the "
            "ranges", opt.objective.span, mech.model.source)
    if found is not None:
        point, values = found, evaluate(found[None])[0]
    elif evaluate.best_design is not None:
        _, point, values = evaluate.best_design
    else:  # interrupted before any feasible design: the least violating so far, if any
        least = evaluate.least_violating()
        point, values = least if least is not None else (None, None)
    texts = _requirement_texts(mech, [E.to_text(r.expr) for r in opt.requirements])
    if point is None:
        params, objective, slacks = {}, float("nan"), {t: float("nan") for t in texts}
    else:
        params = dict(zip(evaluate.names, point.tolist()))
        objective = float(evaluate.sign * values[0])
        slacks = dict(zip(texts, values[1:].tolist()))
    ok = point is not None and bool(feasible(values)[0])
    at_best = None
    if run and (ok or (interrupted is None and point is not None)):
        span = None if ov.t0 is None and ov.t1 is None else (ov.t0, ov.t1)
        at_best = mech.simulate(params={**ov.params, **params}, span=span, step=ov.step,
                                options=options)
    return Optimum(params, objective, slacks, ok, evaluate.variants, evaluate.sweeps,
                   time.perf_counter() - start, message, at_best, evaluate.nonfinite,
                   evaluate.failed, interrupted)


def _grid_search(evaluate: Evaluator, bounds, n: int) -> tuple[np.ndarray, str]:
    """The best feasible point of the n x n x ... grid of ``bounds``, solved as one sweep;
    if there is none, the one that violates the requirements least (a finite objective
    preferred)."""
    if n < 2:
        raise MechError(f"--grid {n}: give at least 2 points per param")
    axes = [np.linspace(a, b, n) for a, b in bounds]
    rows = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=-1)
    values = evaluate(rows)
    ok = feasible(values)
    if ok.any():
        k = int(np.argmin(np.where(ok, values[:, 0], np.inf)))
    else:
        violation = -np.sum(np.minimum(values[:, 1:], 0.0), axis=1)
        k = int(np.lexsort((violation, ~np.isfinite(values[:, 0])))[0])
    return rows[k], f"the best of a grid of {len(rows)} points"


def _requirement_texts(mech, fallback: list[str]) -> list[str]:
    """Each requirement as written in the file (``range(slider.x) >= 4``)."""
    source = mech.model.source
    out = []
    for r, text in zip(mech.model.optimization.requirements, fallback):
        s = r.span
        if s is not None and s.line == s.end_line:
            out.append(source.line(s.line)[s.column - 1:s.end_column - 1])
        else:
            out.append(text)
    return out


def _refine(evaluate: Evaluator, x0: np.ndarray, bounds, M: int, minimize) -> np.ndarray | None:
    """SLSQP from ``x0``, gradients by central differences, each stencil one sweep; the
    point it ends at if it satisfies the requirements and improves on ``x0``, else None.
    SLSQP works on the params scaled to [0, 1] over their ranges and on the objective divided
    by its size at ``x0``: unscaled, its quadratic model stalls where the params' ranges or the
    objective's size are far from 1."""
    lo, hi = np.array(bounds, dtype=float).T
    width = hi - lo
    h = REL_STEP * width
    start = evaluate(x0[None])[0]
    if not np.all(np.isfinite(start)):
        return None
    size = max(abs(start[0]), np.finfo(float).tiny)

    def values(u):
        """(1+M,) and their gradients (N, 1+M) at the scaled point u."""
        x = np.clip(lo + np.asarray(u, dtype=float) * width, lo, hi)
        up = np.minimum(x + np.diag(h), hi)  # one-sided at a bound
        down = np.maximum(x - np.diag(h), lo)
        v = evaluate(np.vstack([x[None], up, down]))
        n = len(x)
        step = (np.diag(up) - np.diag(down))[:, None]
        return v[0], (v[1:n + 1] - v[n + 1:]) / step * width[:, None]

    cons = [{"type": "ineq", "fun": lambda u, k=k: values(u)[0][1 + k],
             "jac": lambda u, k=k: values(u)[1][:, 1 + k]} for k in range(M)]
    try:
        res = minimize(lambda u: values(u)[0][0] / size, (x0 - lo) / width,
                       jac=lambda u: values(u)[1][:, 0] / size, bounds=[(0.0, 1.0)] * len(x0),
                       constraints=cons, method="SLSQP",
                       options={"maxiter": 100, "ftol": 1e-15})
    except (ValueError, np.linalg.LinAlgError):
        return None
    x = np.clip(lo + np.asarray(res.x, dtype=float) * width, lo, hi)
    end = evaluate(x[None])[0]
    if np.all(end[1:] >= -REQUIRE_TOL) and end[0] < start[0] and np.isfinite(end[0]):
        return x
    return None
