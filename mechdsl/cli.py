"""The ``mechdsl`` command: ``run``, ``check``, ``view``, ``plot`` and ``plugins``.

Exit status (:class:`ExitCode`): 0 success; 1 the input is wrong (printed as
``FILE:LINE:COL: error: ...`` with the source line and a caret), an output cannot be written,
or a plugin failed while solving; 2 a numerical failure (no assembly, lock-up, singular
Jacobian); 130 interrupted (Ctrl-C) and 143 terminated (SIGTERM); 141 standard output's
reader went away (``mechdsl run X -o - | head``), quietly; 3 an internal error. Every one of
them after writing every instant solved before it.
"""

from __future__ import annotations

import argparse
import enum
import errno
import gc
import math
import os
import sys
import warnings
from typing import Sequence

from .errors import MechError, format_error
from .writing import (
    SignalGuard, StdoutError, emit, exit_status, silence_stdout, stdout_errors,
)


class ExitCode(enum.IntEnum):
    OK = 0
    USER_ERROR = 1
    NUMERICAL_FAILURE = 2
    INTERNAL_ERROR = 3
    INTERRUPTED = 130  # 128 + SIGINT
    BROKEN_PIPE = 141  # 128 + SIGPIPE: what a Unix tool ends with when its reader has gone
    TERMINATED = 143  # 128 + SIGTERM


class _Parser(argparse.ArgumentParser):
    """argparse exits with status 2 on a usage error; here 2 means a numerical failure. A
    bad value of an option is reported as the options' own checks report theirs,
    ``mechdsl: error: --max-steps: ...``; other usage errors with the usage."""

    def error(self, message: str):  # type: ignore[override]
        if message.startswith("argument -"):
            self.exit(ExitCode.USER_ERROR, f"mechdsl: error: {message[len('argument '):]}\n")
        self.print_usage(sys.stderr)
        self.exit(ExitCode.USER_ERROR, f"{self.prog}: error: {message}\n")


def _whole(text: str) -> int:
    """An option's whole number, also written as 1e6 or 1_000_000 (a step budget, a
    population): the value of ``int`` or of a float that is a whole number."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value.is_integer()):
        raise argparse.ArgumentTypeError(f"a whole number, not '{text}'")
    return int(value)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="mechdsl", description="Kinematics and dynamics of planar mechanisms from .mech files.")
    p.add_argument("--version", action="store_true", help="print the version and exit")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    def model_options(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("file", metavar="FILE", help="the .mech file")
        sp.add_argument("--set", metavar="NAME=VALUE", action="append", default=[],
                        help="override a param (VALUE may be an expression of other params)")
        sp.add_argument("--sweep", metavar="NAME=V1,V2,...", action="append", default=[],
                        help="run once per value of a param (several: every combination)")
        plugin_options(sp)

    def plugin_options(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--plugin", metavar="MODULE", action="append", default=[],
                        help="also load the plugin module MODULE")
        sp.add_argument("--allow-plugin", metavar="MODULE", action="append", default=[],
                        help="let the model's 'plugin \"MODULE\"' line import MODULE (a model "
                             "file imports no module that is not an installed plugin otherwise)")

    def run_options(run: argparse.ArgumentParser) -> None:
        from .outputs import FORMATS  # the registry of output formats: a flag each

        for fmt in FORMATS.values():
            fmt.add_flag(run)
        run.add_argument("--at", metavar="T1,T2,...",
                         help="the instants of --snapshot and --export (default: six, evenly "
                              "spread, for a drawing)")
        run.add_argument("--frames", type=_whole, default=None, metavar="N",
                         help="frames of --animate and instants of --export at most, at least "
                              "2 (default 100; a .dxf or .svg export: the six of a snapshot, "
                              "or --at)")
        run.add_argument("--labels", action="store_true",
                         help="name the bodies and joints in --snapshot and --animate")
        run.add_argument("--trace", metavar="BODY.POINT|ic(A,B)", action="append",
                         default=[],
                         help="draw the path of this point, or with ic(A,B) the centrodes of "
                              "body A relative to B (several separated by commas, or "
                              "repeated; adds to 'trace' lines)")
        run.add_argument("--t0", type=float, help="start time (overrides the file)")
        run.add_argument("--t1", type=float, help="end time (overrides the file)")
        run.add_argument("--step", type=float, help="time step (overrides the file)")
        run.add_argument("--newton-tol", type=float, metavar="TOL",
                         help="Newton-Raphson step tolerance, relative to the model's size "
                              "(default 1e-10)")
        run.add_argument("--rtol", type=float, metavar="TOL",
                         help="forward dynamics: the integrator's relative tolerance (overrides "
                              "the simulate statement's; default 1e-8)")
        run.add_argument("--atol", type=float, metavar="TOL",
                         help="forward dynamics: the integrator's absolute tolerance, relative to "
                              "the model's size (overrides the simulate statement's; default 1e-10)")
        from .api import integrators_help  # the registry of integrators

        run.add_argument("--method", metavar="NAME", help=integrators_help())
        run.add_argument("--max-steps", type=_whole, metavar="N",
                         help="forward dynamics: the integrator's step budget per variant, "
                              "accepted and rejected steps (default 1,000,000); a run that "
                              "uses it up stops with exit 2, the instants so far written")
        run.add_argument("--blas-threads", type=_whole, metavar="N",
                         help="forward dynamics: the BLAS threads while it integrates (default "
                              "1: its small factorisations lose by more; 0 leaves the "
                              "library's setting)")
        run.add_argument("--through-singular", action="store_true",
                         help="at a singular position (dead point, change point) continue on the "
                              "branch the motion was on, instead of stopping")
        run.add_argument("--keep-nonfinite", action="store_true",
                         help="keep positions, velocities or accelerations that are not finite "
                              "numbers (inf, nan) in the results and go on, instead of stopping")
        run.add_argument("--backend", metavar="NAME",
                         help="auto (default: the compiled backend for runs of 100,000 states or "
                              "more when numba is installed), numpy, or compiled")
        run.add_argument("--reduce", metavar="OUTPUTS", action="append",
                         help="replace the outputs by per-variant reductions, e.g. "
                              "'max(abs(slider.ax)), stroke = range(slider.x)': one row per "
                              "variant (max, min, mean, rms, range, initial, final, argmax, argmin)")
        run.add_argument("--workers", metavar="N", type=_whole,
                         help="solve the sweep's chunks on a local Dask cluster of N processes "
                              "(pip install \"mechdsl[cluster]\")")
        run.add_argument("--scheduler", metavar="ADDRESS",
                         help="solve the sweep's chunks on the Dask cluster at ADDRESS "
                              "(tcp://host:8786 or tls://host:8786), which is trusted: a Dask "
                              "scheduler can run code in this process")
        run.add_argument("--scheduler-timeout", metavar="SECONDS", type=float, default=10.0,
                         help="seconds each step of connecting to the scheduler may take, and "
                              "the longest it may stay silent during the run (default 10)")
        run.add_argument("--tls-ca-file", metavar="FILE",
                         help="with --scheduler tls://...: the CA that signed the cluster's "
                              "certificates (default: Dask's configuration)")
        run.add_argument("--tls-cert", metavar="FILE",
                         help="with --scheduler tls://...: this client's certificate")
        run.add_argument("--tls-key", metavar="FILE",
                         help="with --scheduler tls://...: this client's private key")
        run.add_argument("--chunk", metavar="N", type=_whole,
                         help="variants per chunk of a sweep (default: chosen from the model's "
                              "size, at most 1000; the results do not depend on where a chunk runs)")
        run.add_argument("--max-memory", metavar="SIZE",
                         help="refuse runs whose results would take more memory than this "
                              "(e.g. 16G; default 4G)")
        run.add_argument("-q", "--quiet", action="store_true", help="print only errors")

    run = sub.add_parser("run", help="solve a mechanism over time; write CSV and plots")
    model_options(run)
    run_options(run)

    optimize = sub.add_parser("optimize", help="find the params of the model's 'optimize' "
                                               "statement that minimise its objective; then "
                                               "run the model there (the options of run)")
    model_options(optimize)
    run_options(optimize)
    optimize.add_argument("--popsize", type=_whole, metavar="N", default=15,
                          help="differential evolution's population per varied param "
                               "(default 15)")
    optimize.add_argument("--maxiter", type=_whole, metavar="N", default=200,
                          help="generations of the evolution at most (default 200)")
    optimize.add_argument("--tol", type=float, metavar="TOL", default=1e-6,
                          help="the evolution stops when its objectives' spread is below TOL "
                               "times their mean (default 1e-6)")
    optimize.add_argument("--seed", type=_whole, metavar="N", default=0,
                          help="the evolution's random seed (default 0): a run is repeatable")
    optimize.add_argument("--grid", type=_whole, metavar="N",
                          help="brute force instead: the best of an N x N x ... grid of the "
                               "ranges, solved as one sweep")
    optimize.add_argument("--no-refine", action="store_true",
                          help="skip the local refinement (SLSQP) of the evolution's best")

    check = sub.add_parser("check", help="parse, compile and assemble; print the structure")
    model_options(check)

    sub.add_parser("plugins", help="list the installed joint, drive and force types")

    lsp = sub.add_parser("lsp", help="a language server over standard input and output "
                                    "(pip install mechdsl[lsp])")
    # clients built on vscode-languageclient's stdio transport, and some others, append it
    lsp.add_argument("--stdio", action="store_true",
                     help="talk over standard input and output (the default and only way)")

    view = sub.add_parser("view", help="a live page of the mechanism: redrawn on every save, "
                                      "re-solved as a slider moves (pip install mechdsl[view])")
    view.add_argument("file", metavar="FILE", help="the .mech file")
    view.add_argument("--port", type=_whole, default=0, metavar="N",
                      help="the local port (default: a free one)")
    view.add_argument("--no-browser", action="store_true",
                      help="print the page's address, do not open a browser")
    plugin_options(view)

    fmt = sub.add_parser("fmt", help="write .mech files in the canonical layout")
    fmt.add_argument("files", metavar="FILE", nargs="+", help="the .mech files to format")
    fmt.add_argument("--check", action="store_true",
                     help="change nothing; exit 1 if some file is not in the canonical layout")

    plot = sub.add_parser("plot", help="redraw a CSV or a store written by 'run', without "
                                      "solving again")
    plot.add_argument("file", metavar="FILE", help="a CSV, .zarr or .parquet written by "
                                                   "mechdsl run -o")
    plot.add_argument("-o", "--output", metavar="OUT.png",
                      help="the picture (default: FILE with the extension .png)")
    plot.add_argument("--only", metavar="Q1,Q2,...",
                      help="draw only these quantities (default: every column)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line with ``argv`` (default: ``sys.argv[1:]``); return the exit status.

    While a command runs, SIGTERM stops it as Ctrl-C does (:class:`~mechdsl.writing.
    SignalGuard`), and standard output is flushed before returning, so that a full disk or a
    closed pipe is reported here, not by the interpreter's shutdown."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit:  # --help, or a usage error already printed
        _flush_stdout()
        raise
    with SignalGuard() as signals, warnings.catch_warnings():
        # the solver checks what it computes (finite, converged, regular) and says what went
        # wrong where; numpy's warnings about the overflow or NaN of a step it then refuses
        # would only be noise on standard error
        warnings.filterwarnings("ignore", category=RuntimeWarning, module="numpy")
        status = _command(args, signals)
        return _flush_stdout() or status


def entry() -> None:
    """The ``mechdsl`` command (and ``python -m mechdsl``): :func:`main` as the process.

    The objects of the imports (numpy's, lark's, the language's) live as long as the
    process, so they are kept out of the cyclic collector (``gc.freeze``), which scanned
    them again and again: the stiff pendulum's whole ``mechdsl run`` took 375 ms, 330 ms
    frozen. Only here, where the process is the command's own: a program that calls
    :func:`main` keeps its garbage collectable."""
    gc.freeze()
    sys.exit(main())


def _flush_stdout() -> int:
    """Flush standard output; 0, or the exit status of its failure."""
    try:
        with stdout_errors():
            if sys.stdout is not None and not sys.stdout.closed:  # (the language server
                sys.stdout.flush()                                  # closes it at exit)
    except StdoutError as err:
        return _stdout_failed(err)
    return 0


def _stdout_failed(err: StdoutError) -> int:
    # what is still buffered goes to /dev/null at exit, instead of failing again there
    silence_stdout()
    if err.errno == errno.EPIPE:
        return ExitCode.BROKEN_PIPE  # the reader has what it wanted (| head): end quietly
    print(f"mechdsl: error: {err}", file=sys.stderr)
    return ExitCode.USER_ERROR


def _command(args, signals: SignalGuard) -> int:
    """Run the command of ``args``; report what stopped it; return the exit status."""
    try:
        if args.version:
            from . import __version__

            emit(f"mechdsl {__version__}")
            return ExitCode.OK
        if args.command is None:
            _parser().print_help()
            return ExitCode.USER_ERROR
        if args.command == "plugins":
            from .commands import plugins_command

            return plugins_command()
        if args.command == "lsp":
            from .lsp import serve

            serve()
            return ExitCode.OK
        from . import commands

        if args.command in ("run", "optimize"):
            return getattr(commands, f"{args.command}_command")(args, signals)
        return getattr(commands, f"{args.command}_command")(args)
    except StdoutError as err:
        return _stdout_failed(err)
    except BrokenPipeError:  # printed to a closed pipe elsewhere than through emit()
        silence_stdout()
        return ExitCode.BROKEN_PIPE
    except MechError as err:
        text = format_error(err)
        print(text if err.source is not None else f"mechdsl: {text}", file=sys.stderr)
        from .errors import NumericalError

        if isinstance(err, NumericalError):
            return ExitCode.NUMERICAL_FAILURE
        return ExitCode.USER_ERROR
    except KeyboardInterrupt as err:  # before the solver started, or outside a run
        status = exit_status(err)
        verb = "terminated" if status == ExitCode.TERMINATED else "interrupted"
        print(f"mechdsl: {verb}", file=sys.stderr)
        return status
    except MemoryError:
        print(f"{getattr(args, 'file', 'mechdsl')}: error: not enough memory for this run; take "
              "a longer step, fewer outputs or fewer sweep variants (--max-memory is the limit "
              "checked beforehand)", file=sys.stderr)
        return ExitCode.USER_ERROR
    except Exception as err:  # noqa: BLE001 - a bug: say so plainly, with the details
        import traceback

        print(f"mechdsl: internal error: {type(err).__name__}: {err}", file=sys.stderr)
        if os.environ.get("MECHDSL_TRACEBACK"):
            traceback.print_exc()
        else:
            print("  (set MECHDSL_TRACEBACK=1 for the traceback; please report it)",
                  file=sys.stderr)
        return ExitCode.INTERNAL_ERROR


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
