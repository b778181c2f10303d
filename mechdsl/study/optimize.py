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
"""

from __future__ import annotations

import inspect
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..compiled.variants import Overrides
from ..errors import MechError
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
    holds), whether all hold (``feasible``), the variants solved in how many sweeps, the time
    taken, how the search ended (``message``), and ``run``, the model's own outputs at the
    best params."""

    params: dict[str, float]
    objective: float
    requirements: dict[str, float]
    feasible: bool
    variants: int
    sweeps: int
    seconds: float
    message: str
    run: Results | None = None


class Evaluator:
    """The objective and the requirements' slacks of rows of param values, each batch of new
    rows solved as one sweep; every row solved is remembered."""

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
        #: the best objective (signed: minimised) of a variant meeting the requirements
        self.best = np.inf
        #: called as progress(best objective, variants, sweeps) after each sweep
        self.progress: Callable[[float, int, int], None] | None = None

    def __call__(self, rows: np.ndarray) -> np.ndarray:
        """(S, 1 + M): the signed objective (minimised) and the M slacks of each row of
        ``rows`` (S, N); a variant that fails has objective inf and slacks -inf."""
        rows = np.atleast_2d(np.asarray(rows, dtype=float))
        if not len(rows):  # the evolution asks for none when no member meets the requirements
            return np.empty((0, len(self.labels)))
        new = {r.tobytes(): r for r in rows if r.tobytes() not in self.seen}
        if new:
            table = np.array(list(new.values()))
            from . import solve_sweep

            ov = replace(self.ov, sweeps={}, table={n: table[:, i]
                                                    for i, n in enumerate(self.names)})
            res = solve_sweep(self.mech, ov, self.options, client=self.client,
                              chunk=self.chunk)
            values = np.column_stack([np.asarray(res.reduced[k], dtype=float)
                                      for k in self.labels])
            values[:, 0] *= self.sign
            bad = ~np.isfinite(values)
            values[:, 0][bad[:, 0]] = np.inf
            values[:, 1:][bad[:, 1:]] = -np.inf
            for key, v in zip(new, values):
                self.seen[key] = v
            feasible = np.all(values[:, 1:] >= -REQUIRE_TOL, axis=1)
            if feasible.any():
                self.best = min(self.best, float(values[feasible, 0].min()))
            self.variants += len(table)
            self.sweeps += 1
            if self.progress is not None:
                self.progress(self.sign * self.best, self.variants, self.sweeps)
        return np.array([self.seen[r.tobytes()] for r in rows])


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
    ``progress(best objective so far, variants, sweeps)`` is called after every sweep."""
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
    if grid is not None:
        best, message = _grid_search(evaluate, bounds, grid)
        refine = False
    else:
        seeding = ({"rng": seed} if "rng" in inspect.signature(differential_evolution).parameters
                   else {"seed": seed})
        found = differential_evolution(
            lambda x: evaluate(np.asarray(x).T)[:, 0], bounds, popsize=popsize,
            maxiter=maxiter, tol=tol, polish=False, vectorized=True, updating="deferred",
            constraints=constraints, init="sobol", **seeding)
        best = np.asarray(found.x, dtype=float)
        message = f"differential evolution: {found.message}"
    if refine:
        refined = _refine(evaluate, best, bounds, M, minimize)
        if refined is not None:
            best, message = refined, message + "; refined by SLSQP"
    values = evaluate(best[None])[0]
    params = dict(zip(evaluate.names, best.tolist()))
    texts = [E.to_text(r.expr) for r in opt.requirements]
    at_best = None
    if run:
        span = None if ov.t0 is None and ov.t1 is None else (ov.t0, ov.t1)
        at_best = mech.simulate(params={**ov.params, **params}, span=span, step=ov.step,
                                options=options)
    return Optimum(params, float(evaluate.sign * values[0]),
                   dict(zip(_requirement_texts(mech, texts), values[1:].tolist())),
                   bool(np.all(values[1:] >= -REQUIRE_TOL)), evaluate.variants, evaluate.sweeps,
                   time.perf_counter() - start, message, at_best)


def _grid_search(evaluate: Evaluator, bounds, n: int) -> tuple[np.ndarray, str]:
    """The best feasible point of the n x n x ... grid of ``bounds``, solved as one sweep."""
    if n < 2:
        raise MechError(f"--grid {n}: give at least 2 points per param")
    axes = [np.linspace(a, b, n) for a, b in bounds]
    rows = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=-1)
    values = evaluate(rows)
    feasible = np.all(values[:, 1:] >= -REQUIRE_TOL, axis=1)
    if feasible.any():
        k = int(np.argmin(np.where(feasible, values[:, 0], np.inf)))
    else:  # none: the point that violates the requirements least
        k = int(np.argmin(np.sum(np.minimum(values[:, 1:], 0.0), axis=1) * -1.0))
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
