"""Params, sweeps and the time grid, evaluated for every sweep variant.

A sweep runs every combination of the swept values (the first sweep varies slowest); params
defined from a swept param follow it. Every value is checked to be finite, every list to be
within its limit, and the time grid to be the same for all variants.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..errors import MechError, OptionError, Span, suggest
from ..grammar import expr as E
from ..grammar.model import Model, Sweep, Vector
from ..memory import size_text

#: Largest memory (bytes) a run's results may take unless the caller raises it.
MAX_MEMORY = 4 * 2**30
#: Largest number of sweep variants unless the caller raises it.
MAX_VARIANTS = 1_000_000
#: Relative slack when deciding whether (t1 - t0) / step is a whole number of steps.
GRID_SLACK = 1e-9


@dataclass
class Overrides:
    """Values that replace what the file says: params, sweeps, and the simulated span.

    Values are expressions or plain numbers; ``params`` entries replace a file's sweep of the
    same name (giving both a value and a sweep for one name is an error).
    """

    params: dict[str, E.Expr | float] = field(default_factory=dict)
    sweeps: dict[str, Sequence[E.Expr | float]] = field(default_factory=dict)
    t0: E.Expr | float | None = None
    t1: E.Expr | float | None = None
    step: E.Expr | float | None = None
    max_memory: int = MAX_MEMORY
    max_variants: int = MAX_VARIANTS
    #: (start, stop): compile only the variants start .. stop-1 of the sweep (a chunk of a
    #: study, :mod:`mechdsl.study`), None for all
    variant_range: tuple[int, int] | None = None
    #: the variants as rows of given values, {param: (V,)} (an optimiser's population)
    #: instead of every combination of ``sweeps``
    table: dict[str, np.ndarray] | None = None
    #: what the caller calls t0, t1 and step, for the errors of values given here (the
    #: API's arguments; the command line's options: ("--t0", "--t1", "--step")): a bad value
    #: is reported as that option's, not at the file's ``simulate`` line
    time_names: tuple[str, str, str] = ("span", "span", "step")


def as_expr(v: E.Expr | float) -> E.Expr:
    """A plain number as an expression; expressions unchanged."""
    return E.Num(float(v)) if isinstance(v, (int, float, np.number)) else v


#: Expressions whose compiled form a memo keeps at most (a long session of values given as
#: text would otherwise keep every one)
MEMO_SIZE = 10_000


def remembered(memo: dict | None, tag: str, obj: object, make):
    """``make()``, kept in ``memo`` (the caller's, per model) under ``obj``'s identity and
    ``tag``, with ``obj`` itself, so that its id is not reused while the entry lives; made
    anew without a memo. The memo is emptied when it holds :data:`MEMO_SIZE` entries."""
    if memo is None:
        return make()
    held = memo.get((tag, id(obj)))
    if held is not None and held[0] is obj:
        return held[1]
    made = make()
    _keep(memo, (tag, id(obj)), (obj, made))
    return made


def _keep(memo: dict, key: tuple, value: object) -> None:
    """``memo[key] = value``, the memo emptied first when it holds :data:`MEMO_SIZE`
    entries."""
    if len(memo) >= MEMO_SIZE:
        memo.clear()
    memo[key] = value


@dataclass(frozen=True)
class Variants:
    """The swept values ``sweep[name]`` and every param's value ``env[name]``, each (V,).
    ``memo`` (the caller's, kept across compilations of one model) holds each expression's
    compiled form by identity, with the expression itself (so that its id is not reused)."""

    sweep: dict[str, np.ndarray]
    env: dict[str, np.ndarray]
    memo: dict | None = field(default=None, compare=False, repr=False)
    #: the params' ranges, ``param l = 3.5 in 2 .. 6`` (:func:`param_ranges`)
    ranges: dict = field(default_factory=dict, compare=False)

    @functools.cached_property
    def count(self) -> int:
        return len(next(iter(self.sweep.values()))) if self.sweep else 1

    def values(self, e: E.Expr, what: str, span: Span | None) -> np.ndarray:
        """An expression of params, for every variant: shape (V,); finite or an error."""
        V = self.count
        if type(e) is E.Num and math.isfinite(e.value):  # a number: most values are
            return np.full(V, float(e.value))
        value = np.asarray(self._run(e), dtype=float)
        if value.shape != (V,):
            value = np.broadcast_to(value, (V,))
        if not (math.isfinite(value[0]) if V == 1 else np.isfinite(value).all()):
            raise MechError(f"{what} is {_first_bad(value)}", span)
        return value

    def _run(self, e: E.Expr):
        return _evaluate(e, self.env, self.memo)  # (the caller checks finiteness)

    def vector(self, v: Vector, what: str) -> np.ndarray:
        """A vector of expressions: shape (V, len)."""
        out = np.empty((self.count, len(v.items)))
        for k, e in enumerate(v.items):
            out[:, k] = self.values(e, what, e.span)
        return out


def evaluate(model: Model, ov: Overrides, memo: dict | None = None) -> Variants:
    """Every param for every combination of the sweeps (after overrides); the params'
    ranges checked (:func:`param_ranges`). ``memo``: see :class:`Variants`."""
    sweep = sweep_table(model, ov)
    env = _params(model, ov, sweep, memo)
    return Variants(sweep, env, memo, param_ranges(model, env, memo))


def _evaluate(e: E.Expr, env: dict, memo: dict | None) -> "float | np.ndarray":
    """``e`` at ``env`` (as :func:`mechdsl.grammar.expr.evaluate`), its compiled form kept in
    ``memo``: a param's name is read, a small expression's form is kept under its shape
    (``l/2`` written at 300 bodies is compiled once), any other under its identity
    (:func:`remembered`)."""
    if type(e) is E.Name:
        return env[e.id]
    shape = _shape(e, SHAPE_DEPTH) if memo is not None else None
    if shape is None:
        run = remembered(memo, "expr", e, lambda: E.compile_expr(e))
    else:
        run = memo.get(("shape", shape))
        if run is None:
            run = E.compile_expr(e)
            _keep(memo, ("shape", shape), run)
    with np.errstate(all="ignore"):
        return run(env)


#: the nesting down to which an expression's form is kept under its shape
SHAPE_DEPTH = 3


def _shape(e: E.Expr, depth: int) -> tuple | None:
    """What ``e`` computes, without its spans, for a number, a name, or a sum, product,
    difference, quotient, power or negation of such within ``depth`` levels; else None."""
    t = type(e)
    if t is E.Num:
        return ("num", e.value, math.copysign(1.0, e.value))  # (-0.0 == 0.0 as keys)
    if t is E.Name:
        return ("name", e.id)
    if depth and t is E.Binary:
        a, b = _shape(e.left, depth - 1), _shape(e.right, depth - 1)
        return None if a is None or b is None else ("bin", e.op, a, b)
    if depth and t is E.Unary:
        a = _shape(e.operand, depth - 1)
        return None if a is None else ("un", e.op, a)
    return None


def param_ranges(model: Model, env: dict[str, np.ndarray], memo: dict | None = None
                 ) -> dict[str, tuple[float, float]]:
    """The range ``lo .. hi`` of each param that gives one (``param l = 3.5 in 2 .. 6``), in
    the first variant of ``env``; a bound that is not finite, or lo >= hi in some variant, is
    an error located at the range."""
    out = {}
    V = len(next(iter(env.values()))) if env else 1
    for p in model.params:
        if p.range is None:
            continue
        lo, hi = (np.broadcast_to(np.asarray(_evaluate(b, env, memo), dtype=float), (V,))
                  for b in p.range)
        span = p.range[0].span or p.span
        for what, v in (("lower", lo), ("upper", hi)):
            if not np.all(np.isfinite(v)):
                raise MechError(f"the {what} end of the range of param '{p.name}' is "
                                f"{_first_bad(v)}", span)
        if not np.all(lo < hi):
            i = int(np.flatnonzero(~(lo < hi))[0])  # the first variant where it is empty
            raise MechError(f"the range of param '{p.name}' is empty: {float(lo[i]):g} .. "
                            f"{float(hi[i]):g} (give lo .. hi with lo < hi)", span)
        out[p.name] = (float(lo[0]), float(hi[0]))
    return out


def _check_overrides(model: Model, ov: Overrides) -> None:
    names = [p.name for p in model.params]
    for name in ov.params:
        known_param(name, names, "cannot set")
    for name in ov.sweeps:
        known_param(name, names, "cannot sweep")
        if name in ov.params:
            raise MechError(f"param '{name}' is given both a value and a sweep; give one")
        if len(ov.sweeps[name]) == 0:
            raise MechError(f"the sweep of '{name}' has no values")


def _given_table(model: Model, ov: Overrides) -> dict[str, np.ndarray]:
    """``ov.table``'s rows (of ``ov.variant_range``), checked: known params, finite values,
    columns of one length; the file's sweeps do not apply."""
    names = [p.name for p in model.params]
    columns = {k: np.asarray(v, dtype=float).ravel() for k, v in ov.table.items()}
    for name, values in columns.items():
        known_param(name, names, "cannot vary")
        if name in ov.params or name in ov.sweeps:
            raise MechError(f"param '{name}' is given both a value and a table of values")
        if not np.all(np.isfinite(values)):
            raise MechError(f"a value of '{name}' is {_first_bad(values)}")
    lengths = {len(v) for v in columns.values()}
    if len(lengths) != 1 or 0 in lengths:
        raise MechError("the table of variants needs columns of one, non-zero length")
    total = lengths.pop()
    start, stop = ov.variant_range or (0, total)
    if not 0 <= start < stop <= total:
        raise MechError(f"variants {start} .. {stop - 1} are not among the table's {total:,}")
    return {k: v[start:stop].copy() for k, v in columns.items()}


def sweep_table(model: Model, ov: Overrides) -> dict[str, np.ndarray]:
    """The swept params' values of every variant (of ``ov.variant_range`` if given), each
    (V,), without evaluating the other params: what a study's store records."""
    _check_overrides(model, ov)
    return _given_table(model, ov) if ov.table is not None else _sweep_table(model, ov)


def known_param(name: str, names: list[str], what: str) -> None:
    """A MechError "WHAT 'NAME': there is no param of that name" (with the nearest names)
    unless ``name`` is one of ``names``: checked before a value's text is parsed, so that
    ``--set method=radau`` names the param, not the value."""
    if name not in names:
        raise MechError(f"{what} '{name}': there is no param of that name"
                        + suggest(name, names))


def _sweep_table(model: Model, ov: Overrides) -> dict[str, np.ndarray]:
    if not model.sweeps and not ov.sweeps:
        return {}
    base = _params(model, ov, {})
    swept = {s.name for s in model.sweeps if s.name not in ov.params} | set(ov.sweeps)
    tainted = _dependents(model, ov, swept)
    lists: dict[str, np.ndarray] = {}
    for sw in model.sweeps:
        if sw.name in ov.params or sw.name in ov.sweeps:
            continue
        lists[sw.name] = _sweep_values(sw, base, tainted, ov.max_variants)
    for name, values in ov.sweeps.items():
        lists[name] = np.array([_scalar(as_expr(v), base, f"a value of the sweep of '{name}'",
                                        None) for v in values], dtype=float)
    if not lists:
        return {}
    total = math.prod(len(v) for v in lists.values())
    if total > ov.max_variants:
        raise MechError(f"the sweeps make {total:,} variants, more than the limit of "
                        f"{ov.max_variants:,}")
    start, stop = ov.variant_range or (0, total)
    if not 0 <= start < stop <= total:
        raise MechError(f"variants {start} .. {stop - 1} are not among the sweep's {total:,}")
    # variant i is the i-th combination in row-major order (the first sweep varies slowest),
    # found from its index so that a chunk never builds the whole table
    digits = np.unravel_index(np.arange(start, stop), [len(v) for v in lists.values()])
    return {name: values[d].astype(float) for (name, values), d in zip(lists.items(), digits)}


def _dependents(model: Model, ov: Overrides, swept: set[str]) -> set[str]:
    """The params whose values follow a swept param, directly or through others."""
    out = set(swept)
    for p in model.params:
        if p.name not in ov.params and E.free_names(p.value) & out:
            out.add(p.name)
    return out


def _sweep_values(sw: Sweep, base: dict[str, np.ndarray], tainted: set[str],
                  limit: int) -> np.ndarray:
    exprs = [e for e in (sw.values or (sw.start, sw.stop, sw.step, sw.count)) if e is not None]
    for e in exprs:
        dep = E.free_names(e) & tainted
        if dep:
            raise MechError(f"sweep values cannot depend on '{sorted(dep)[0]}', which follows "
                            "a swept param", e.span)
    if sw.values is not None:
        return np.array([_scalar(e, base, "a sweep value", e.span) for e in sw.values])
    a = _scalar(sw.start, base, "a sweep bound", sw.start.span)
    b = _scalar(sw.stop, base, "a sweep bound", sw.stop.span)
    if sw.count is not None:
        c = _scalar(sw.count, base, "a sweep count", sw.count.span)
        if c != int(c) or c < 1 or (c == 1 and a != b):
            raise MechError("a sweep count must be a whole number, at least 2 when the ends "
                            f"differ, not {c:g}", sw.count.span)
        if c > limit:
            raise MechError(f"a sweep of {c:,.0f} values is more than the limit of {limit:,}",
                            sw.count.span)
        return np.linspace(a, b, int(c))
    h = _scalar(sw.step, base, "a sweep step", sw.step.span)
    return grid(a, b, h, sw.span, "sweep", "values", limit)


def _scalar(e: E.Expr, env: dict[str, np.ndarray], what: str, span: Span | None) -> float:
    v = np.asarray(E.evaluate(e, {k: x[0] for k, x in env.items()}), dtype=float)
    if v.ndim or not math.isfinite(float(v)):
        raise MechError(f"{what} must be a finite number, not {float(v)!r}", span)
    return float(v)


def _params(model: Model, ov: Overrides, sweep: dict[str, np.ndarray],
            memo: dict | None = None) -> dict:
    V = len(next(iter(sweep.values()))) if sweep else 1
    env: dict[str, np.ndarray] = {}
    for p in model.params:
        if p.name in sweep:
            value = sweep[p.name]
        elif p.name in ov.params:
            given = ov.params[p.name]
            where = f"the value given for param '{p.name}'"
            if isinstance(given, (int, float, np.number)):
                value = float(given)  # a number: nothing to evaluate
            else:
                late = E.free_names(given) - env.keys()
                if late:
                    raise MechError(f"{where}: '{sorted(late)[0]}' is not a param defined "
                                    f"before '{p.name}'")
                value = E.evaluate(given, env)
            if not np.all(np.isfinite(value)):
                raise MechError(f"{where} gives {_first_bad(value)}")
        else:
            value = _evaluate(p.value, env, memo)
        value = np.broadcast_to(np.asarray(value, dtype=float), (V,)).copy()
        if not np.all(np.isfinite(value)):
            raise MechError(f"param '{p.name}' is {_first_bad(value)}"
                            + _variant_note(sweep, value), p.span)
        env[p.name] = value
    return env


def _variant_note(sweep: dict[str, np.ndarray], value: np.ndarray) -> str:
    if not sweep:
        return ""
    i = int(np.flatnonzero(~np.isfinite(value))[0])
    return " for " + ", ".join(f"{k} = {v[i]:g}" for k, v in sweep.items())


def _first_bad(value) -> str:
    v = np.asarray(value, dtype=float).ravel()
    bad = v[~np.isfinite(v)]
    return repr(float(bad[0])) if bad.size else "not finite"


def time_grid(model: Model, ov: Overrides, variants: Variants, outputs: int) -> np.ndarray:
    """The instants of the run: the file's ``simulate`` line, after overrides. A grid whose
    results (``outputs`` quantities of every variant at every instant, 8 bytes each) would
    take more than ``ov.max_memory`` is refused before anything is allocated."""
    sim = model.simulate
    if sim is None and (ov.t1 is None or ov.step is None):
        raise MechError("nothing to simulate: add a line such as "
                        "'simulate t = 0 .. 1 step 0.001'")

    names = dict(zip(("t0", "t1", "step"), ov.time_names))

    def pick(name, e, what):
        o = getattr(ov, name)
        if o is None:
            return variants.values(e, what, e.span)
        try:
            return variants.values(as_expr(o), what, None)
        except MechError as err:  # (not finite: the option's value, not the file's)
            raise OptionError(f"{names[name]}: {err.message}") from None

    t0 = pick("t0", sim.t0 if sim else E.Num(0.0), "the start time")
    t1 = pick("t1", sim.t1 if sim else None, "the end time")
    h = pick("step", sim.step if sim else None, "the step")
    span = sim.span if sim else None
    for v, what in ((t0, "start time"), (t1, "end time"), (h, "step")):
        if np.ptp(v) != 0:
            raise MechError(f"the {what} differs between sweep variants; the time grid "
                            "cannot depend on a swept param", span)
    # a bad value given as an override is that option's error, not the file's line's
    if not float(h[0]) > 0 and ov.step is not None:
        raise OptionError(f"{names['step']}: the simulated time step must be positive, not "
                        f"{float(h[0]):g}")
    if float(t1[0]) < float(t0[0]) and (ov.t0 is not None or ov.t1 is not None):
        option = names["t1"] if ov.t1 is not None else names["t0"]
        raise OptionError(f"{option}: the simulated time range ends ({float(t1[0]):g}) before "
                        f"it starts ({float(t0[0]):g})")
    per_instant = 8 * (1 + variants.count * max(outputs, 1))
    args = (float(t0[0]), float(t1[0]), float(h[0]), span, "simulated time", "instants",
            max(2, ov.max_memory // per_instant))
    memo = variants.memo
    if memo is None:
        return grid(*args, bytes_per_item=per_instant)
    # a model solved again with new values of its params has, most often, the same grid
    key = ("grid", *(float(x).hex() for x in args[:3]), args[-1], per_instant)
    made = memo.get(key)
    if made is None:
        made = grid(*args, bytes_per_item=per_instant)
        made.flags.writeable = False  # shared by the models compiled with it
        _keep(memo, key, made)
    return made


def grid(a: float, b: float, h: float, span: Span | None, what: str, items: str,
         limit: int, bytes_per_item: int = 0) -> np.ndarray:
    """a + k h for k = 0, 1, ... up to b, and b itself: both ends included; at most
    ``limit`` items (checked before the grid is made)."""
    if not h > 0:
        raise MechError(f"the {what} step must be positive, not {h:g}", span)
    if b < a:
        raise MechError(f"the {what} range ends ({b:g}) before it starts ({a:g})", span)
    steps = (b - a) / h
    if not steps < 2**62:
        steps = float(2**62)
    n = math.floor(steps + GRID_SLACK)
    if n + 2 > limit:
        if bytes_per_item:
            need = (n + 1) * bytes_per_item
            raise MechError(
                f"the {what} has {n + 1:,} {items}, whose results would take "
                f"{size_text(need)}, more than the limit of {size_text(limit * bytes_per_item)}",
                span, notes=["raise the limit with --max-memory (e.g. --max-memory 16G) if "
                             "the machine has the memory, or take a longer step"])
        raise MechError(f"the {what} has {n + 1:,} {items}, more than the limit of {limit:,}",
                        span)
    out = a + h * np.arange(n + 1, dtype=float)
    if b - out[-1] > GRID_SLACK * min(h, b - a):
        out = np.append(out, b)
    elif n > 0:
        out[-1] = b  # a whole number of steps, up to round-off: end exactly at b
    return out


def parse_size(text: str) -> int:
    """'4G', '500M', '2048k' or a plain number of bytes -> bytes."""
    text = text.strip().upper().rstrip("B")
    scale = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}.get(text[-1:], 1)
    number = float(text[:-1] if scale > 1 else text)
    if not 0 < number * scale < 2**60:  # also refuses nan and inf
        raise ValueError("the size must be positive and finite")
    return int(number * scale)
