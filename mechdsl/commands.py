"""The subcommands behind :mod:`mechdsl.cli`: each takes parsed arguments, prints, and
returns an exit status. Errors are raised as MechError and formatted by the caller."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from typing import Iterator

import numpy as np

from .api import Mechanism, load, parse_value
from .compiled.system import System
from .compiled.variants import MAX_MEMORY, Overrides, known_param
from .errors import MechError, NumericalError, Source, format_error, format_warning, suggest
from .outputs import FORMATS
from .results import summary
from .writing import Interrupted, Output, SignalGuard, check_distinct, emit


def _overrides(mech: Mechanism, args) -> Overrides:
    names = [p.name for p in mech.model.params]
    ov = Overrides()
    for opt, target, many, what in (("--set", ov.params, False, "cannot set"),
                                    ("--sweep", ov.sweeps, True, "cannot sweep")):
        for item in getattr(args, opt.lstrip("-")):
            name, eq_sign, value = item.partition("=")
            name = name.strip()
            if not eq_sign or not name.isidentifier():
                raise MechError(f"{opt} takes NAME=VALUE, not '{item}'")
            known_param(name, names, f"{opt}: {what}")
            target[name] = parse_value(value, f"{opt} {name}", names, many)
    for attr in ("t0", "t1", "step"):
        value = getattr(args, attr, None)
        if value is not None:
            setattr(ov, attr, value)
    ov.time_names = ("--t0", "--t1", "--step")
    limit = _max_memory(args)
    if limit is not None:
        ov.max_memory = limit
    return ov


def _max_memory(args) -> int | None:
    """The bytes of --max-memory, if given."""
    if not getattr(args, "max_memory", None):
        return None
    from .compiled.variants import parse_size

    try:
        return parse_size(args.max_memory)
    except (ValueError, IndexError):
        raise MechError(f"--max-memory takes a size such as 16G or 500M, not "
                        f"'{args.max_memory}'") from None


def _options(args):
    from .api import SolverOptions

    given = {}
    if getattr(args, "newton_tol", None) is not None:
        given["newton_tol"] = args.newton_tol
    if getattr(args, "through_singular", False):
        given["at_singular"] = "continue"
    if getattr(args, "keep_nonfinite", False):
        given["nonfinite"] = "keep"
    for name in ("backend", "method"):
        if getattr(args, name, None) is not None:
            given[name] = getattr(args, name)
    for name in ("rtol", "atol", "max_steps", "blas_threads"):
        if getattr(args, name, None) is not None:
            given[name] = getattr(args, name)
    limit = _max_memory(args)
    if limit is not None:
        given["max_memory"] = limit
    try:
        return SolverOptions(**given)
    except ValueError as err:
        option = next((f"--{name.replace('_', '-')}" for name in ("backend", "method", "rtol",
                                                                   "atol", "max_steps",
                                                                   "blas_threads")
                       if str(err).startswith(name)), "--newton-tol")
        raise MechError(f"{option}: {err}") from None


def _outputs(args) -> list[tuple[str, str]]:
    """The files ``mechdsl run`` is asked to write, as (option, path), in the order written."""
    given = ((f.option, getattr(args, f.arg)) for f in FORMATS.values())
    return [(option, path) for option, path in given if path and path != "-"]


def _check_targets(args) -> None:
    """Refuse unwritable output paths, unknown formats and bad drawing options before
    loading anything."""
    from .writing import is_direct

    for option, path in _outputs(args):
        if is_direct(path):
            continue  # a device, a pipe, a stream: written in place
        target = os.path.realpath(path)  # a link is written through: check what it names
        if os.path.isdir(target) and not (option == "-o" and _is_store_path(path)):
            raise MechError(f"{option} {path}: that is a folder; give a file name")
        folder = os.path.dirname(target)
        if not os.path.isdir(folder):
            raise MechError(f"{option} {path}: the folder {folder} does not exist")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise MechError(f"{option} {path}: the folder {folder} is not writable")
        if os.path.exists(target) and not os.access(target, os.W_OK):
            # a plain open() would fail; replacing the read-only file would defeat its mode
            raise MechError(f"{option} {path}: the file is read-only")
    for fmt in FORMATS.values():
        path = getattr(args, fmt.arg)
        if path and fmt.kind != "csv":
            fmt.check(path)
    if args.animate and os.path.splitext(args.animate)[1].lower() == ".mp4":
        from matplotlib import animation
        if not animation.writers.is_available("ffmpeg"):
            raise MechError(f"--animate {args.animate}: an .mp4 needs ffmpeg on the PATH, "
                            "which is not there; install ffmpeg or write a .gif")
    if args.frames is not None and args.frames < 2:
        raise MechError(f"--frames {args.frames}: an animation needs at least 2 frames")
    if args.at is not None and not (args.snapshot or args.export):
        raise MechError("--at chooses the instants of --snapshot and --export, neither of "
                        "which is given")


def _is_store_path(path: str) -> bool:
    """A .zarr or .parquet path: a folder that -o may replace if mechdsl wrote it
    (:func:`mechdsl.outputs.store.create_store` checks which)."""
    from .outputs.store import store_kind

    return store_kind(path) is not None


def _override_files(ov: Overrides) -> list[str]:
    """The files that tables in --set and --sweep values read."""
    from .grammar import expr as E

    values = [*ov.params.values(), *(v for vs in ov.sweeps.values() for v in vs)]
    return [n.path for v in values if isinstance(v, E.NODES)
            for n in E.walk(v) if isinstance(n, E.Table) and n.path]


def _check_outputs(args, mech: Mechanism, ov: Overrides, system: System,
                   at: list[float] | None, n_variants: int | None = None) -> None:
    """Once the model is read and the run known, before solving: refuse an output that is
    the model file, a file the model reads, or another output of the run (every file of an
    --export series included); refuse --at instants outside the run. ``system`` may be the
    compiled model of the run's first chunk: ``n_variants`` is then the run's."""
    from .outputs.export import series

    inputs = [("the model file", args.file)]
    inputs += [("the model's data file", f) for f in mech.model.files]
    inputs += [("a table file of --set or --sweep", f) for f in _override_files(ov)]
    outputs = [Output(option, path, folder=option == "-o" and _is_store_path(path))
               for option, path in _outputs(args) if option != "--export"]
    if args.export:
        outputs.append(Output("--export", args.export,
                              series(args.export, n_variants or system.n_variants,
                                     len(system.times))))
    check_distinct(inputs, outputs)
    if at:
        lo, hi = float(system.times[0]), float(system.times[-1])
        slack = 1e-9 * max(abs(lo), abs(hi), hi - lo)
        outside = [a for a in at if not lo - slack <= a <= hi + slack]
        if outside:
            raise MechError(f"--at {outside[0]:g}: outside the run, which goes from t = {lo:g} "
                            f"to t = {hi:g}")


class ProgressBar:
    """A progress bar on ``stream`` for runs longer than ``delay`` seconds, drawn only when the
    stream is a terminal (never into a file or a pipe), at most ``rate`` times a second. A
    forward dynamics feeds :meth:`motion` instead, after every step; its estimate of the
    time left waits for ``estimate_after`` seconds of integration."""

    def __init__(self, stream, delay: float = 1.0, rate: float = 10.0, width: int = 30,
                 estimate_after: float = 1.0) -> None:
        import time

        self.stream, self.delay, self.period, self.width = stream, delay, 1.0 / rate, width
        self.estimate_after = estimate_after
        self.clock = time.monotonic
        self.start = self.clock()
        self.last = 0.0
        self.shown = False
        self.live = hasattr(stream, "isatty") and stream.isatty()
        #: the longest line drawn, blanked by the next one and by close
        self.drawn = 0
        #: (wall clock, fraction of the run done) at the first step of a forward dynamics
        self.origin: tuple[float, float] | None = None
        #: (variant, wall clock, steps) at the first step of the variant being integrated
        self.begun: tuple[int, float, int] | None = None

    def __call__(self, done: int, total: int) -> None:
        now = self._due()
        if now is None:
            return
        frac = done / max(total, 1)
        filled = int(round(frac * self.width))
        eta = (now - self.start) * (1 - frac) / frac if frac > 0 else float("nan")
        self._show(f"[{'#' * filled}{'.' * (self.width - filled)}] {100 * frac:5.1f} % "
                   f"{done}/{total} instants, {eta:.0f} s left ")

    def motion(self, t: float, steps: int, t0: float, t1: float, variant: int = 0,
               variants: int = 1, max_steps: int | None = None) -> None:
        """A forward dynamics after a step (:meth:`mechdsl.solve.dynamic.DynamicRun.run`):
        the simulated time t reached in t0 .. t1, the steps taken (of ``max_steps``) and the
        wall time left, extrapolated from the simulated time per second since the first step
        (the start-up before it is no part of the rate), "estimating" until that has been
        measured over ``estimate_after`` seconds; and, where the step budget would end the
        variant first at the steps per second so far, "budget: X", the wall time X until it
        does. At most ``columns() - 1`` characters."""
        # called after every step: what is not drawn returns at once
        if not self.live:
            return
        if self.begun is None or self.begun[0] != variant:  # the budget is per variant
            self.begun = (variant, self.clock(), steps)
            if self.origin is None:
                self.origin = (self.begun[1], (variant + (t - t0) / (t1 - t0)) / variants)
        now = self._due()
        if now is None:
            return
        local = (t - t0) / (t1 - t0)
        frac = (variant + local) / variants
        elapsed, gained = now - self.origin[0], frac - self.origin[1]
        if elapsed < self.estimate_after or not gained > 0:
            left = "estimating"
        else:
            left = f"{self.duration(elapsed * (1 - frac) / gained)} left"
            ran, taken = now - self.begun[1], steps - self.begun[2]
            if max_steps is not None and ran >= self.estimate_after and taken > 0:
                out = ran * (max_steps - steps) / taken
                if out < elapsed * (1 - local) / variants / gained:
                    left += f", budget: {self.duration(out)}"
        which = f"variant {variant + 1}/{variants}: " if variants > 1 else ""
        span = f" in {t0:g} .. {t1:g}" if t0 != 0 else f"/{t1:g}"
        budget = f"/{max_steps:,}" if max_steps is not None else ""
        line = (f"{which}t = {t:.5g}{span} ({100 * local:.1f} %), {steps:,}{budget} steps, "
                f"{left}")
        # a line longer than the terminal wraps, and the next "\r" redraws only its end
        self._show(line[: self.columns() - 1])

    def columns(self) -> int:
        """The width of the terminal behind the stream (80 where it does not say)."""
        try:
            return os.get_terminal_size(self.stream.fileno()).columns or 80
        except (AttributeError, OSError, ValueError):
            return 80

    def _due(self) -> float | None:
        """The time now if a line is to be drawn now (a terminal, past the delay, not
        sooner than the rate allows), else None."""
        if not self.live:
            return None
        now = self.clock()
        if now - self.start < self.delay or now - self.last < self.period:
            return None
        self.last = now
        return now

    def _show(self, text: str) -> None:
        self.stream.write("\r" + text.ljust(self.drawn))  # over the whole of a longer line
        self.stream.flush()
        self.shown = True
        self.drawn = max(self.drawn, len(text))

    def close(self) -> None:
        if self.shown:
            self.stream.write("\r" + " " * max(self.width + 50, self.drawn) + "\r")
            self.stream.flush()

    @staticmethod
    def duration(seconds: float) -> str:
        """A wall time in the unit a reader takes in at a glance."""
        for limit, unit, size in ((100, "s", 1), (6000, "min", 60), (172800, "h", 3600),
                                  (63115200, "days", 86400)):
            if seconds < limit:
                return f"{seconds / size:.0f} {unit}"
        return f"{seconds / 31557600:.3g} years"


class SearchStatus(ProgressBar):
    """The state of an optimisation on one line of ``stream`` (a terminal only, after a
    second): the best objective so far and the variants solved."""

    def __call__(self, best: float, variants: int, sweeps: int) -> None:
        now = self._due()
        if now is not None:
            self._show(f"best {best:.6g} after {variants} variants in {sweeps} sweep"
                       f"{'s' if sweeps != 1 else ''}, {now - self.start:.0f} s ")


def _settings(args, at: list[float] | None) -> dict:
    """The run's settings that the output formats read (:func:`mechdsl.outputs.settings`):
    the plot's title (the file's name, and the params set), --at, --labels, --frames."""
    from .outputs import settings

    title = os.path.basename(args.file)
    if args.set:
        title += " (" + ", ".join(s.replace("=", " = ", 1) for s in args.set) + ")"
    return settings(title=title, at=at, labels=getattr(args, "labels", False),
                    frames=args.frames)


def _instants_option(text: str | None) -> list[float] | None:
    if text is None:
        return None
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise MechError(f"--at {text}: expected times separated by commas, such as "
                        "0,0.25,0.5") from None
    if not values:
        raise MechError("--at: give at least one time")
    bad = [x for x in values if not np.isfinite(x)]
    if bad:
        raise MechError(f"--at {text}: {bad[0]} is not a time; give finite numbers")
    return values


def run_command(args, signals: SignalGuard | None = None) -> int:
    """``mechdsl run``: solve; write the CSV and the pictures, also after a numerical
    failure, a plugin's error or an interrupt (with the instants solved before it); print a
    summary or what stopped the run. ``signals``, entered by the caller, turns SIGTERM into
    an interrupt as Ctrl-C and holds both back while the CSV is written."""
    signals = signals or SignalGuard()
    _check_targets(args)
    at = _instants_option(args.at)
    # compile() comes next and finds the same mistakes: no separate check of the names
    mech = load(args.file, plugins=args.plugin, allow_plugins=args.allow_plugin, check=False,
                max_memory=_max_memory(args) or MAX_MEMORY)
    if args.trace:
        mech = mech.tracing(args.trace)
    if getattr(args, "reduce", None):
        mech = mech.reducing(args.reduce)
    ov = _overrides(mech, args)
    prepared = mech.prepare(ov, args.chunk)
    system, total = prepared.system, prepared.total
    _check_outputs(args, mech, ov, system, at, total)  # system: the first chunk's
    if system.reductions:
        _check_reduced(args, system)
    store = _store(args)
    client = _client(args)
    asked = [f for f in FORMATS.values() if getattr(args, f.arg)]
    drawing = any(f.mechanism for f in asked)  # every body's pose at every instant
    # their velocities and accelerations: the formats that show them, and centrodes
    rates = any(f.rates for f in asked) or (
        drawing and system.sketch is not None and bool(system.sketch.centrodes))
    from .outputs import outputs_bytes

    run_settings = _settings(args, at)
    extra = outputs_bytes(system, {f.kind: getattr(args, f.arg) for f in asked
                                   if f.kind != "csv"}, run_settings)
    bar = ProgressBar(sys.stderr) if not args.quiet else None
    options = _options(args)
    placed: list[str] = []  # where the store went: beside -o if an interrupt kept the old one
    try:
        results = prepared.solve(options, client=client, store=store, poses=drawing,
                                 rates=rates, progress=bar, extra_memory=extra,
                                 placed=placed.append)
    finally:
        signals.hold()  # what was solved is written whole before any signal acts
        if bar is not None:
            bar.close()
        if client is not None:
            _close(client)
    if store is not None:
        return _report(args, results, placed[-1:] or [store], None, signals, run_settings)
    if total > system.n_variants and drawing:
        # the drawings and exports need every variant's geometry, not the first chunk's
        system = mech.compile(ov).system
    written, stop = _write_outputs(args, system, results, run_settings, signals)
    return _report(args, results, written, stop, signals, run_settings)


def _store(args) -> str | None:
    """The -o path when it names a store (.zarr, .parquet), which takes the results chunk by
    chunk; None for a CSV. Drawings need the histories in memory: refused with a store."""
    from .outputs.store import store_kind

    if not args.output or store_kind(args.output) is None:
        return None
    for option, given in ((f.option, getattr(args, f.arg)) for f in FORMATS.values()
                          if f.kind == "plot" or f.mechanism):
        if given:
            raise MechError(f"{option} with -o {args.output}: a store is written a chunk at "
                            f"a time and never held whole; draw from it afterwards with "
                            f"mechdsl plot {args.output}")
    return args.output


def _client(args):
    """The Dask client of --workers N (a local cluster) or --scheduler ADDRESS, or None."""
    if args.workers is not None and args.scheduler is not None:
        raise MechError("--workers starts a local cluster and --scheduler names one; give "
                        "one of them")
    from .api import local_cluster, remote_cluster

    timeout = args.scheduler_timeout
    if not timeout > 0:  # NaN too
        raise MechError(f"--scheduler-timeout {timeout}: give a number of seconds above 0")
    tls = (args.tls_ca_file, args.tls_cert, args.tls_key)
    if args.scheduler is None and any(tls):
        raise MechError("--tls-ca-file, --tls-cert and --tls-key are for --scheduler: the "
                        "cluster of --workers makes credentials of its own")
    if args.workers is not None:
        return local_cluster(args.workers, timeout)
    if args.scheduler is not None:
        return remote_cluster(args.scheduler, timeout, tls)
    return None


def _close(client) -> None:
    """Close a client, and the local cluster it started (not a remote one)."""
    from .api import close_cluster

    close_cluster(client)


def optimize_command(args, signals: SignalGuard | None = None) -> int:
    """``mechdsl optimize``: the params of the model's ``optimize`` statement at the minimum
    of its objective under its requirements (:func:`mechdsl.study.optimize.optimize`), on
    the cluster of --workers or --scheduler if given; printed, then the model run there with
    the options of ``run`` (``-o``, ``--plot``, ...). No design satisfying the requirements
    with a finite objective: exit 2, nothing run. SIGINT or SIGTERM during the search stops
    it: the best design so far is printed and run as above (a second signal stops that run,
    which keeps what it solved), and the exit status is 130 or 143."""
    _check_targets(args)
    mech = load(args.file, plugins=args.plugin, allow_plugins=args.allow_plugin,
                max_memory=_max_memory(args) or MAX_MEMORY)
    if mech.model.optimization is None:
        raise MechError(f"{args.file} has no 'optimize' statement: add one, such as "
                        "'optimize l in 2.5 .. 4', and 'minimize EXPR'")
    if args.reduce:
        raise MechError("--reduce: the outputs of the run at the optimum are the file's; the "
                        "objective is its 'minimize' statement")
    ov = _overrides(mech, args)
    signals = signals or SignalGuard()
    client = _client(args)
    status = SearchStatus(sys.stderr) if not args.quiet else None
    best, signum = None, None
    try:
        try:
            best = mech.search(ov, _options(args), client=client, chunk=args.chunk,
                               popsize=args.popsize, maxiter=args.maxiter, tol=args.tol,
                               seed=args.seed, refine=not args.no_refine, run=False,
                               grid=args.grid, progress=status)
        finally:
            if status is not None:
                status.close()
            if client is not None:
                _close(client)
    except KeyboardInterrupt as err:
        if best is None:
            raise
        # the search had ended; the signal came while the cluster was closed: keep its answer
        signum = getattr(err, "signum", signal.SIGINT)
    if best.interrupted is not None:
        # the guard knows the signal when the solver took it and the sweep only came back
        # "interrupted"; after a second signal, the last one received is not the first
        signum = signals.received if signals.count == 1 else best.interrupted
    emit("\n".join(_optimum_lines(args.file, mech, best, signum)))
    if signum is None and not best.feasible:
        finite = " with a finite objective" if best.nonfinite else ""
        raise NumericalError(f"no design in the ranges satisfies every requirement{finite}; "
                             "the best found is above", source=Source(args.file, ""))
    if signum is not None:
        verb = "terminated" if signum == signal.SIGTERM else "interrupted"
        if not best.feasible:
            what = ("a design that meets every requirement with a finite objective"
                    if best.params else "any design")
            print(f"mechdsl: {verb} before the search solved {what}; nothing was run",
                  file=sys.stderr)
            return 128 + signum
        try:
            # the search's signal is dealt with: the next one may stop the run at the best
            signals.release()
        except KeyboardInterrupt as err:
            from .writing import exit_status

            print(f"mechdsl: {verb} twice; the best design so far is above, not run",
                  file=sys.stderr)
            return exit_status(err)
    args.set = list(args.set) + [f"{k}={v!r}" for k, v in best.params.items()]
    args.workers = args.scheduler = None
    code = run_command(args, signals)
    if signum is None or code != 0:
        return code
    where = f", its run is in {args.output}" if args.output and args.output != "-" else ""
    print(f"mechdsl: {verb}; the search stopped early: the best design so far is above{where}",
          file=sys.stderr)
    return 128 + signum


def _optimum_lines(file: str, mech: Mechanism, best, signum: int | None) -> list[str]:
    """What ``mechdsl optimize`` prints of the :class:`~mechdsl.study.optimize.Optimum`
    ``best``: the params, the objective, each requirement's slack, the work done, and, when
    the search was stopped by the signal ``signum``, that it was."""
    opt = mech.model.optimization
    verb = "terminated" if signum == signal.SIGTERM else "interrupted"
    if signum is None:
        head = f"{file}: {'minimum' if opt.sense == 'min' else 'maximum'} found at"
    elif best.feasible:
        head = f"{file}: search {verb}; best design so far at"
    elif best.params:
        head = (f"{file}: search {verb} before any design met every requirement; the least "
                "violating so far at")
    else:
        head = f"{file}: search {verb} before any design was solved"
    lines = [head]
    if best.params:
        width = max(len(k) for k in best.params)
        lines += [f"  {k:<{width}} = {v!r}" for k, v in best.params.items()]
        lines.append(f"objective: {best.objective!r}")
        for text, slack in best.requirements.items():
            lines.append(f"requirement {text}: "
                         f"{'holds' if best.holds(slack) else 'VIOLATED'} (slack {slack:.6g})")
    lines.append(f"{best.variants} variants solved in {best.sweeps} "
                 f"sweep{'s' if best.sweeps != 1 else ''}, "
                 f"{best.seconds:.2f} s ({best.message})"
                 + (f"; {best.nonfinite} of {best.variants} designs gave no finite objective"
                    if best.nonfinite else "")
                 + (f" ({best.failed} could not be solved)" if best.failed else ""))
    return lines


def _check_reduced(args, system: System) -> None:
    """A run of reductions keeps one value per variant, no motion: refuse what draws one."""
    first = system.reductions[0].label
    for option, given in ((f.option, getattr(args, f.arg)) for f in FORMATS.values()
                          if f.mechanism):
        if given:
            raise MechError(f"{option} draws the motion, and this run keeps one value per "
                            f"variant ('{first}'): write the histories in a run without "
                            "reductions to draw them")
    if args.plot and not system.sweep:
        raise MechError(f"--plot: the outputs are reductions ('{first}'), one value for the "
                        "run, nothing to plot without a sweep")


@contextlib.contextmanager
def _writing(option: str, path: str) -> Iterator[None]:
    """An OSError while writing an output becomes a user error naming it."""
    try:
        yield
    except OSError as err:
        raise MechError(f"cannot write {path} ({option}): {err.strerror or err}") from None


def _write_outputs(args, system: System, results, run_settings: dict,
                   signals: SignalGuard) -> tuple[list[str], KeyboardInterrupt | None]:
    """Write every output asked for (:data:`mechdsl.outputs.FORMATS`), the CSV first and
    whole: a signal from the end of the solve until the CSV is complete is held back until
    then. Returns the outputs written and the interrupt that stopped the others, if one did
    (their temporary files are removed as it goes up)."""
    written: list[str] = []
    solved = results.n_solved.max(initial=0) > 0
    try:
        csv = FORMATS["csv"]
        if args.output:
            with signals.held(), _writing(csv.option, args.output):
                csv.write(results, system, args.output)
                written.append(args.output)
        # the CSV is whole: a signal received meanwhile stops the rest now, and the next one
        # may interrupt the pictures and exports
        signals.release()
        before = signals.count
        for fmt in FORMATS.values():
            path = getattr(args, fmt.arg)
            if fmt is csv or not path or (fmt.mechanism and not solved):
                continue
            try:
                with _writing(fmt.option, path):
                    fmt.write(results, system, path, run_settings)
            except Exception:
                # an interrupt that lands inside matplotlib's compiled code can come out as
                # that code's own error (Agg's "Invalid bounding box"): it is the interrupt
                if signals.count > before:
                    raise Interrupted(signals.received) from None
                raise
            written.append(path)
    except KeyboardInterrupt as err:
        return written, err
    return written, None


def _solved_text(results) -> str:
    """'the 57 instants' or, with a sweep, 'the 570 rows (10 variants)': the CSV's rows."""
    if results.sweep:
        return f"the {int(results.n_solved.sum())} rows ({results.n_variants} variants)"
    return f"the {int(results.n_solved[0])} instants"


def _report(args, results, written: list[str], stop: KeyboardInterrupt | None,
            signals: SignalGuard, run_settings: dict) -> int:
    """Print the warnings, what stopped the run and where its instants are (each output
    written, by its format with the run's ``run_settings``); return the exit status."""
    in_file = args.output in written and args.output != "-"
    if not args.quiet:
        for w in results.warnings:
            print(format_warning(w, args.file), file=sys.stderr)
    if results.status == "failed":
        source = Source(args.file, "")
        for message in results.messages:
            print(format_error(NumericalError(message, source=source)), file=sys.stderr)
        if in_file:
            if results.sweep:
                note = "the instants each variant solved before it failed are in"
            else:
                note = f"the {int(results.n_solved[0])} instants solved before the failure are in"
            print(f"  note: {note} {args.output}", file=sys.stderr)
    if stop is not None or results.status == "interrupted":
        signum = getattr(stop, "signum", None) or signals.received or signal.SIGINT
        print(_interrupted_text(args, results, written, signum), file=sys.stderr)
        return 128 + signum
    if results.ok:
        if not args.quiet and not args.output:
            emit(summary(results))
        if not args.quiet:
            for line in _written_lines(args, results, written, run_settings):
                print(line, file=sys.stderr)
        return 0
    return 2


def _written_lines(args, results, written: list[str], run_settings: dict) -> list[str]:
    """One line per output written, in the order written: the CSV's rows (unless it went to
    standard output), the plot, the snapshot's instants, the animation's frames, the files
    of the export."""
    lines = []
    from .outputs.store import store_kind

    kind = store_kind(args.output) if args.output else None
    if kind is not None and args.output in written:
        lines.append(f"{args.output}: {results.n_variants} variant"
                     f"{'s' if results.n_variants != 1 else ''} ({int(results.n_solved.sum())} "
                     f"instants solved), a {kind} store ({results.solve_time * 1e3:.1f} ms)")
    elif args.output in written and args.output != "-":
        rows = results.n_variants if results.reduced else int(results.n_solved.sum())
        lines.append(f"{args.output}: {rows} rows ({results.solve_time * 1e3:.1f} ms)")
    if args.output and results.method:
        # the summary's line that the rows do not say: which integrator, and why (a
        # switch to radau where the motion turned stiff)
        lines.append(f"integrator: {results.method}")
    for fmt in FORMATS.values():  # each format says what it wrote
        path = getattr(args, fmt.arg)
        line = fmt.summary_of(results, path, run_settings) if path in written else None
        if line is not None:
            lines.append(line)
    return lines


def _interrupted_text(args, results, written: list[str], signum: int) -> str:
    """'mechdsl: interrupted; the 57 instants solved so far are in out.csv' and the like."""
    verb = "terminated" if signum == signal.SIGTERM else "interrupted"
    solved = _solved_text(results)
    if args.output in written:
        where = "on standard output" if args.output == "-" else f"in {args.output}"
        text = f"mechdsl: {verb}; {solved} solved so far are {where}"
    elif written and _is_store_path(args.output or ""):
        # an earlier store was at -o: it stays, the interrupted run's store is beside it
        return (f"mechdsl: {verb}; {solved} solved so far are in {written[0]}; "
                f"{args.output} keeps the earlier run's results")
    elif written:
        text = f"mechdsl: {verb}; {solved} solved so far are drawn in {', '.join(written)}"
    else:
        text = f"mechdsl: {verb} after {solved[4:]}; nothing was written"
    missing = [p for _, p in _outputs(args) if p not in written]
    return text + (f"; not written: {', '.join(missing)}" if missing else "")


def _all_errors(args, err: MechError) -> MechError:
    """The error to raise for ``err``, found while loading or checking the file: every
    syntax and name error of the file at once (:func:`mechdsl.diagnostics.every_error`),
    all but the last printed here, the last returned."""
    from .diagnostics import every_error
    from .reading import read_data

    if err.span is None or args.plugin:
        return err
    try:
        text = read_data(args.file, "", "MAX_MODEL_BYTES").decode("utf-8")
    except (MechError, UnicodeDecodeError):
        return err
    errors = every_error(err, text, args.file)
    for other in errors[:-1]:
        print(format_error(other), file=sys.stderr)
    return errors[-1]


def check_command(args) -> int:
    """``mechdsl check``: what the model declares, its assembly at t0, mobility and
    redundancy at the assembled configuration (:meth:`Mechanism.check`), printed; a file
    with errors has every syntax and name error printed at once."""
    try:
        # compile() comes next and finds the same mistakes: no separate check of the names
        mech = load(args.file, plugins=args.plugin, allow_plugins=args.allow_plugin,
                    check=False, max_memory=_max_memory(args) or MAX_MEMORY)
        report = mech.check(_overrides(mech, args))
    except MechError as err:
        raise _all_errors(args, err) from None
    emit("\n".join(report.lines))
    for warning in report.warnings:
        print(format_warning(warning, report.source), file=sys.stderr)
    if report.error is not None:
        raise report.error
    emit(report.verdict)
    return 0


def plugins_command() -> int:
    """``mechdsl plugins``: every installed type with its signature and distribution."""
    from .plugins.manager import build_registry
    from .plugins.version import CONTRACT_VERSION, DECLARATION

    registry = build_registry()
    emit(f"plugin contract {CONTRACT_VERSION} (a plugin declares {DECLARATION} = "
         f"{CONTRACT_VERSION})")
    for kind in ("joint", "drive", "force"):
        names = registry.names(kind)
        emit(f"{kind} types:")
        if not names:
            emit("  (none installed)")
        for name in names:
            ctype = registry.get(kind, name)
            provider = registry.provider(kind, name)
            emit(f"  {ctype.describe()}")
            what = ("loads" if kind == "force" else
                    f"{ctype.n_eq} equation{'s' if ctype.n_eq != 1 else ''}")
            emit(f"      {what}; {ctype.doc or ''}  [{provider}]")
    if registry.broken:
        emit("broken plugins:")
        for b in registry.broken:
            emit(f"  {b.provider.plugin} ({b.provider}): {b.reason}")
    return 0



def fmt_command(args) -> int:
    """``mechdsl fmt FILE...``: each file in the canonical layout
    (:mod:`mechdsl.grammar.format`), rewritten in place only where that changes it (whole or
    not at all: written beside it and renamed); with ``--check``, nothing is written and the
    files that would change are listed (exit 1). A file that does not parse is reported as
    ``run`` reports it, and left as it is."""
    from .grammar import normalise
    from .grammar.format import format_text
    from .reading import read_data
    from .writing import write_text

    changed = []
    for path in args.files:
        raw = read_data(path, "", "MAX_MODEL_BYTES")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise MechError(f"{path} is not UTF-8 text") from None
        out = format_text(text, path)
        if out == normalise(text):
            continue
        changed.append(path)
        if not args.check:
            write_text(path, lambda f, out=out: f.write(out))
    for path in changed:
        emit(f"{path}: {'not in the canonical layout' if args.check else 'formatted'}")
    return 1 if (args.check and changed) else 0


#: ``mechdsl plot`` of a store draws at most this many variants' histories
MAX_PLOTTED = 40


def plot_command(args) -> int:
    """``mechdsl plot FILE.csv``: the time-history figure of a CSV written by ``run``."""
    from .outputs.csv import read_csv
    from .outputs.plot import plot_results
    from .outputs.store import open_store, store_kind

    if store_kind(args.file) is not None:
        stored = open_store(args.file)
        shown = np.arange(stored.n_variants)
        if stored.n_variants > MAX_PLOTTED and not stored.reduced:
            # a line per variant: beyond a few dozen, an even selection of them says more
            shown = np.unique(np.linspace(0, stored.n_variants - 1, MAX_PLOTTED).round()
                              ).astype(int)
            print(f"{args.file}: {stored.n_variants} variants; plotting {len(shown)} of them, "
                  "evenly spaced", file=sys.stderr)
        if stored.reduced and not stored.sweep:
            raise MechError("the outputs are reductions, one value for the run, nothing to "
                            "plot without a sweep",
                            source=Source(args.file, ""))
        results = stored.to_results(shown)
    else:
        results = read_csv(args.file)
    out = args.output or os.path.splitext(args.file.rstrip("/"))[0] + ".png"
    what = "the CSV file" if store_kind(args.file) is None else "the store"
    check_distinct([(what, args.file)], [Output("-o", out)])
    FORMATS["plot"].check(out, option="-o")
    labels = None
    if args.only:
        labels = [x.strip() for x in args.only.split(",") if x.strip()]
        unknown = [x for x in labels if x not in results.data]
        if unknown:
            raise MechError(f"--only: {args.file} has no column '{unknown[0]}'"
                            + suggest(unknown[0], results.data))
    with _writing("-o", out):
        plot_results(results, out, title=os.path.basename(args.file), labels=labels)
    return 0


def view_command(args) -> int:
    """``mechdsl view``: serve the live page of the file until Ctrl-C (:mod:`mechdsl.view`)."""
    import importlib.util

    missing = [m for m in ("starlette", "uvicorn", "watchfiles", "websockets")
               if importlib.util.find_spec(m) is None]
    if missing:
        raise MechError(f"mechdsl view needs {', '.join(missing)}: pip install 'mechdsl[view]'")
    if not 0 <= args.port <= 65535:
        raise MechError(f"--port {args.port}: give a port from 1 to 65535, or 0 for a free one")
    from .reading import read_data
    from .view.server import serve
    from .view.session import Session

    read_data(args.file, "", "MAX_MODEL_BYTES")  # a file that cannot be read: said here
    session = Session(args.file, plugins=tuple(args.plugin),
                      allow_plugins=tuple(args.allow_plugin))
    try:
        serve(session, args.port, open_browser=not args.no_browser,
              announce=lambda text: print(text, file=sys.stderr, flush=True))
    except OSError as err:  # the port is taken
        raise MechError(f"--port {args.port}: {err.strerror or err}") from None
    return 0
