"""mechdsl's benchmark suite: run time against error, measured in one run on one machine.

    python benchmarks/bench.py                      # everything (a few minutes)
    python benchmarks/bench.py --quick              # smaller sizes, fewer repeats (~1 min)
    python benchmarks/bench.py --only seed,scaling  # some sections

Sections (each prints a table; the plots and a Markdown copy of the tables go to --out):

* levers: each speed lever of the engine switched off in turn (the parallel-in-time march,
  blocks of instants, the generated LU, the fused evaluation, predictor order, Newton's early
  stop) and the compiled backend, time against the default;
* seed: the slider-crank of the seed (1001 instants), in-process solve time (model compiled)
  and relative error of x, vx, ax against the closed form, on the numpy path and the compiled
  backend (if numba is installed: the ``fast`` extra), beside Exudyn (if installed: the
  ``bench`` extra) and a plain per-instant numpy Newton;
* work-precision: maximal relative error against run time over Newton tolerance, output step
  and predictor order, for the slider-crank, a four-bar and a chain of 101 bodies;
* scaling: time per instant of a row of parallelograms from 11 to 10,001 bodies, dense and
  sparse, beside Exudyn's sparse solver;
* sweep: variants per second for a sweep of slider-cranks over the rod length, on the numpy
  path and the compiled backend;
* long: the slider-crank over 100,001 instants, numpy and compiled;
* startup: wall time of ``mechdsl run examples/slider_crank.mech -o out.csv`` as a process,
  and of importing mechdsl (and exudyn);
* animation: solving a 101-body chain over 1000 instants and writing its GIF;
* andrews: forward dynamics, Andrews' squeezing mechanism (the Test Set for IVP Solvers):
  relative error of the seven angles at t = 0.03 against run time, mechdsl (numpy and
  compiled, its default method) over rtol, and each of its methods on numpy, beside scipy's
  solve_ivp on the published index-1 form (DOP853, Radau) and Exudyn's generalised-alpha
  over its step; and the whole process of ``mechdsl run examples/andrews.mech``;
* dynamics: forward dynamics beside the peers (benchmarks/dynamics.py): IFToMM A02's work
  against precision beside Exudyn, a chain of N links from 10 to 3000 beside Exudyn, the
  stiff pendulum for k from 1e2 to 1e10 beside scipy's Radau and BDF and Exudyn, and the
  Test Set's car axis problem against its reference.

Times are medians of repeated runs; ratios are taken between figures of the same run.
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import replace
import importlib.util
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

import mechdsl  # noqa: E402
import models  # noqa: E402
import peers  # noqa: E402
from report import Report  # noqa: E402
from closed_forms import angle_error, four_bar  # noqa: E402
from mechdsl.compiled import equations as mechdsl_equations  # noqa: E402
from mechdsl.compiled.fused import fuse  # noqa: E402
from mechdsl.compiled.sparse import Pattern  # noqa: E402
from mechdsl.solve import SolverOptions, simulate  # noqa: E402
from mechdsl.compiled.variants import Overrides  # noqa: E402


NUMPY = SolverOptions(backend="numpy")
COMPILED = SolverOptions(backend="compiled")


def have_numba() -> bool:
    if importlib.util.find_spec("numba") is None:
        print("(numba not installed: pip install -e .[fast])")
        return False
    return True


def median_time(fn: Callable[[], object], repeat: int) -> tuple[float, object]:
    """Median wall time of ``repeat`` calls (after one warm-up call) and the last result."""
    out = fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), out


def rel(value: np.ndarray, exact: np.ndarray) -> float:
    return float(np.abs(value - exact).max() / np.abs(exact).max())


# -- the mechanisms, compiled, with their closed forms ---------------------------------------

def slider_crank_system(step: float = 1e-3, outputs: str | None = None):
    text = (ROOT / "examples" / "slider_crank.mech").read_text()
    if outputs:
        text = text.replace("output slider.x, slider.vx, slider.ax", f"output {outputs}")
    return mechdsl.loads(text, "slider_crank.mech").compile(Overrides(step=step))


def slider_crank_errors(res) -> tuple[float, float, float]:
    x, vx, ax = models.slider_crank_exact(res["t"])
    return rel(res["slider.x"], x), rel(res["slider.vx"], vx), rel(res["slider.ax"], ax)


def four_bar_errors(res) -> tuple[float, float, float]:
    th2 = np.pi / 4 + 2 * np.pi * res["t"]
    _, (th4, w4, al4) = four_bar(1.0, 3.5, 3.0, 4.0, th2, 2 * np.pi, 0.0)
    return (float(angle_error(res["rocker.phi"], th4 + np.pi).max() / np.pi),
            rel(res["rocker.omega"], w4), rel(res["rocker.alpha"], al4))


def chain_errors(res, n_loops: int) -> tuple[float, float, float]:
    ex = models.chain_exact(res["t"])
    last = f"coupler{n_loops - 1}"
    return (rel(res[f"{last}.x"] - (n_loops - 1) * models.D_PITCH, ex["x"]),
            rel(res[f"{last}.vx"], ex["vx"]), rel(res[f"{last}.ax"], ex["ax"]))


# -- sections ---------------------------------------------------------------------------------

def seed(rep: Report, quick: bool) -> None:
    """The seed's slider-crank beside Exudyn: the solvers take turns, round after round, so
    that a change of the machine's speed during the run hits all of them alike; each timed
    call follows an untimed call of the same solver, so that none is timed on caches the
    one before it has just filled (mechdsl's numpy solve took 3.4 ms alone and 3.9 ms right
    after an Exudyn solve; Exudyn's time did not change with the order)."""
    repeat = 5 if quick else 15
    full = slider_crank_system()
    pos = slider_crank_system(outputs="slider.x")
    have_exudyn = importlib.util.find_spec("exudyn") is not None
    if not have_exudyn:
        print("(exudyn not installed: pip install -e .[bench])")
    fast = have_numba()
    t_full, t_pos, t_exu, t_fast = [], [], [], []
    res = res_pos = exu = res_fast = None
    for i in range(repeat + 1):  # the first round warms up
        simulate(full, NUMPY)
        start = time.perf_counter()
        res = simulate(full, NUMPY)
        t_full.append(time.perf_counter() - start)
        simulate(pos, NUMPY)
        start = time.perf_counter()
        res_pos = simulate(pos, NUMPY)
        t_pos.append(time.perf_counter() - start)
        if fast:
            simulate(full, COMPILED)
            start = time.perf_counter()
            res_fast = simulate(full, COMPILED)
            t_fast.append(time.perf_counter() - start)
        if have_exudyn:
            peers.exudyn_slider_crank(repeat=1)
            exu = peers.exudyn_slider_crank(repeat=1)
            t_exu.append(exu["time"])
    med = {k: statistics.median(v[1:]) for k, v in
           (("full", t_full), ("pos", t_pos), ("exu", t_exu), ("fast", t_fast)) if v}
    ex, evx, eax = slider_crank_errors(res)
    x_exact = models.slider_crank_exact(res_pos["t"])[0]
    entries = [("mechdsl numpy, x vx ax", med["full"], ex, evx, eax),
               ("mechdsl numpy, x only", med["pos"], rel(res_pos["slider.x"], x_exact), None,
                None)]
    if fast:
        entries.append(("mechdsl compiled (numba), x vx ax", med["fast"],
                        *slider_crank_errors(res_fast)))
    if have_exudyn:
        entries.append(("Exudyn 1.13 (gen.-alpha)", med["exu"], exu["err_x"], exu["err_vx"],
                        exu["err_ax"]))
    base = peers.numpy_baseline_slider_crank(repeat=max(1, repeat // 5))
    entries.append(("numpy Newton per instant", base["time"], base["err_x"], base["err_vx"],
                    base["err_ax"]))
    rows = []
    exu_t = med.get("exu")
    for name, t, a, b, c in entries:
        rows.append([name, f"{1e3 * t:.2f}", f"{t / med['full']:.2f}",
                     "-" if exu_t is None else f"{t / exu_t:.3f}", f"{a:.1e}",
                     "-" if b is None else f"{b:.1e}", "-" if c is None else f"{c:.1e}"])
    rep.table("Seed slider-crank, 1001 instants (solve, model compiled)",
              ["solver", "ms", "x mechdsl numpy", "x Exudyn", "err x", "err vx", "err ax"],
              rows)


def work_precision(rep: Report, quick: bool) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    tols = [1e-4, 1e-6, 1e-8, 1e-10, 1e-12] if not quick else [1e-4, 1e-8, 1e-12]
    n_chain = 50
    cases = [
        ("slider-crank", lambda step: slider_crank_system(step), slider_crank_errors),
        ("four-bar", lambda step: mechdsl.load(ROOT / "examples" / "fourbar.mech")
         .compile(Overrides(step=step)), four_bar_errors),
        (f"chain, {2 * n_chain + 1} bodies",
         lambda step: mechdsl.loads(models.chain_text(n_chain)).compile(Overrides(step=step * 10)),
         lambda res: chain_errors(res, n_chain)),
    ]
    settings = [(1e-3, 2), (1e-3, 1), (1e-2, 2), (1e-2, 1)]
    fig, axes = plt.subplots(len(cases), 3, figsize=(13, 3.6 * len(cases)), squeeze=False)
    rows = []
    for ci, (name, build, errors) in enumerate(cases):
        for step, order in settings:
            kernels = build(step)
            times = kernels.system.times
            pts = []
            for tol in tols:
                opts = SolverOptions(newton_tol=tol, predictor_order=order)
                t, res = median_time(lambda: simulate(kernels, opts), 1 if quick else 3)
                if not res.ok:
                    continue
                pts.append((t, *errors(res)))
                rows.append([name, f"{times[1] - times[0]:g}", str(order),
                             f"{tol:g}", f"{1e3 * t:.1f}",
                             *(f"{e:.1e}" for e in pts[-1][1:])])
            pts = np.array(pts)
            for k, what in enumerate(("position", "velocity", "acceleration")):
                ax = axes[ci, k]
                ax.loglog(pts[:, 0], np.maximum(pts[:, 1 + k], 1e-17), "o-",
                          label=f"step {times[1] - times[0]:g}, predictor {order}")
                ax.set_title(f"{name}: {what}")
                # less than a decade of run time: minor tick labels would overlap
                ax.xaxis.set_minor_formatter(NullFormatter())
                ax.set_xlabel("run time (s)")
                ax.set_ylabel("max relative error")
                ax.axhline(1e-12, color="grey", lw=0.5, ls="--")
        axes[ci, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(rep.out / "work_precision.png", dpi=90)
    plt.close(fig)
    rep.table("Work-precision (points over the Newton tolerance)",
              ["model", "step", "predictor", "newton_tol", "ms", "err pos", "err vel",
               "err acc"], rows)


def per_instant(system_for: Callable[[int], object], opts: SolverOptions,
                k1: int, k2: int, repeat: int) -> tuple[float, tuple]:
    """Time per instant without the assembly: (T(k2 instants) - T(k1)) / (k2 - k1)."""
    t1, _ = median_time(lambda: simulate(system_for(k1), opts), repeat)
    t2, res = median_time(lambda: simulate(system_for(k2), opts), repeat)
    return max(t2 - t1, 1e-9) / (k2 - k1), res


def scaling(rep: Report, quick: bool) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    loops = [5, 15, 50, 150, 500] + ([] if quick else [1500, 5000])
    dense_max = 150
    rows, curves = [], {"dense": [], "sparse": [], "Exudyn (sparse)": []}
    for n_loops in loops:
        mech = mechdsl.loads(models.chain_text(n_loops))
        bodies = 2 * n_loops + 1
        # large rows: more instants between the two runs, so that the difference of their
        # times stands above the machine's noise
        k2 = 86 if n_loops < 500 else 46
        compiled = {k: mech.compile(Overrides(t1=(k - 1) * 0.01, step=0.01)) for k in (6, k2)}
        row = [str(bodies)]
        for kind, threshold in (("dense", 10**9), ("sparse", 0)):
            if kind == "dense" and n_loops > dense_max:
                row.append("-")
                continue
            dt, res = per_instant(compiled.__getitem__, SolverOptions(sparse_from=threshold),
                                  6, k2, 1 if quick else 3)
            err = chain_errors(res, n_loops)[0] if res.ok else float("nan")
            curves[kind].append((bodies, dt))
            row.append(f"{1e3 * dt:.3g} ({err:.0e})")
        try:
            if n_loops <= 1500:
                # the same difference of two runs as for mechdsl: Exudyn's set-up of a
                # solve is not counted as time per step
                reps = 1 if quick else 3
                short = peers.exudyn_chain(n_loops, steps=5, repeat=reps)
                exu = peers.exudyn_chain(n_loops, steps=k2 - 1, repeat=reps)
                per_step = max(exu["time_per_step"] * (k2 - 1) - short["time_per_step"] * 5,
                               1e-9) / (k2 - 6)
                curves["Exudyn (sparse)"].append((bodies, per_step))
                row.append(f"{1e3 * per_step:.3g} ({exu['err_x']:.0e})")
            else:
                row.append("-")
        except ImportError:
            row.append("-")
        rows.append(row)
        print("  " + "  ".join(row), flush=True)
    rep.table("Scaling: row of parallelograms, ms per instant (relative error of x)",
              ["bodies", "mechdsl dense", "mechdsl sparse", "Exudyn sparse"], rows)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for kind, pts in curves.items():
        if pts:
            pts = np.array(pts)
            ax.loglog(pts[:, 0], 1e3 * pts[:, 1], "o-", label=kind)
    ref = np.array([11, 10001])
    ax.loglog(ref, 0.01 * ref, "k:", lw=0.8, label="linear growth")
    ax.set_xlabel("bodies")
    ax.set_ylabel("ms per instant")
    ax.set_title("Row of parallelograms: time per instant")
    ax.legend()
    fig.tight_layout()
    fig.savefig(rep.out / "scaling.png", dpi=90)
    plt.close(fig)


def sweep(rep: Report, quick: bool) -> None:
    variants = 100 if quick else 1000
    mech = mechdsl.load(ROOT / "examples" / "slider_crank.mech")
    rods = np.linspace(2.5, 5.0, variants)
    kernels = mech.compile(Overrides(sweeps={"l": list(rods)}))
    alone = slider_crank_system()
    t1, _ = median_time(lambda: simulate(alone, NUMPY), 5)
    rows = []
    for name, opts in (("numpy", NUMPY), ("compiled (numba)", COMPILED)):
        if opts is COMPILED and not have_numba():
            continue
        t, res = median_time(lambda: simulate(kernels, opts), 1 if quick else 3)
        ex = models.slider_crank_exact(res["t"][None, :], l=rods[:, None])
        err = max(float((np.abs(res[k] - e).max(axis=1) / np.abs(e).max(axis=1)).max())
                  for k, e in zip(("slider.x", "slider.vx", "slider.ax"), ex))
        rows.append([name, str(variants), f"{t:.3f}", f"{variants / t:.0f}",
                     f"{t / (variants * t1):.3f}", f"{err:.1e}"])
    rep.table(f"Sweep: {variants} slider-cranks (rod 2.5 .. 5 m) x 1001 instants "
              f"(one variant alone on numpy: {1e3 * t1:.1f} ms)",
              ["engine", "variants", "s", "variants/s", "batched/loop", "max err"], rows)


def long_span(rep: Report, quick: bool) -> None:
    """The seed's slider-crank over 100,001 instants (step 1e-5)."""
    system = slider_crank_system(1e-4 if quick else 1e-5)
    rows = []
    for name, opts in (("numpy", NUMPY), ("compiled (numba)", COMPILED)):
        if opts is COMPILED and not have_numba():
            continue
        t, res = median_time(lambda: simulate(system, opts), 3)
        rows.append([name, str(len(res["t"])), f"{t:.3f}",
                     f"{1e6 * t / len(res['t']):.2f}", f"{max(slider_crank_errors(res)):.1e}"])
    rep.table("Long span: the seed's slider-crank, step 1e-5",
              ["engine", "instants", "s", "us per instant", "max err (x, vx, ax)"], rows)


def startup(rep: Report, quick: bool) -> None:
    repeat = 3 if quick else 7
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.csv"
        cmd = [sys.executable, "-m", "mechdsl", "run", str(ROOT / "examples" / "slider_crank.mech"),
               "-o", str(out), "-q"]
        t_run, _ = median_time(
            lambda: subprocess.run(cmd, check=True, env=peers.user_env()), repeat)
        t_cold, _ = median_time(
            lambda: subprocess.run(cmd, check=True, env=peers.user_env(bytecode=False)), repeat)
    rows = [["mechdsl run examples/slider_crank.mech -o out.csv", f"{1e3 * t_run:.0f}"],
            ["the same, bytecode cache off (PYTHONDONTWRITEBYTECODE=1)", f"{1e3 * t_cold:.0f}"],
            ["python -c 'import mechdsl'", f"{1e3 * peers.import_time('mechdsl', repeat):.0f}"],
            ["python -c 'import numpy'", f"{1e3 * peers.import_time('numpy', repeat):.0f}"],
            ["python -c 'pass'", f"{1e3 * peers.import_time('sys', repeat):.0f}"]]
    if importlib.util.find_spec("exudyn") is not None:
        rows.append(["python -c 'import exudyn'",
                     f"{1e3 * peers.import_time('exudyn', repeat):.0f}"])
    rep.table("Start-up (whole process, ms)", ["command", "ms"], rows)


def api_again(rep: Report, quick: bool) -> None:
    """What a user of the API pays to solve a loaded model again (issue 29): the seed's
    ``Mechanism.simulate()`` called again, with the same values and with a new ``l``, beside
    the solve of the same model compiled beforehand (the solver alone), in one run."""
    from mechdsl.compiled.compile import compile_model

    repeat = 7 if quick else 21
    mech = mechdsl.load(ROOT / "examples" / "slider_crank.mech")
    kernels = mech.compile()
    # new values of l beside the file's 3.5: the same motion, within 0.3 %, as the solve
    # compared (a rod near 3 takes twice the solver's work: l = 3.0 takes 8.3 ms, folded or
    # not, where 3.5 takes 4.2); each new value's model also compiled beforehand, on its own
    # (its fastest code), to compare the same solve: a new l is a new assembly at t0
    values = [3.5 + 1e-4 * (k + 1) * (-1) ** k for k in range(repeat + 1)]
    before = [compile_model(mech.model, mech.registry, Overrides(params={"l": v}))
              for v in values]
    for s in before:
        simulate(s)  # its plans made, as a model compiled and solved once has them
    k = iter(range(len(values)))
    at = [0]

    def new_value():
        at[0] = next(k)
        return mech.simulate(l=values[at[0]])

    # what a user of a loaded model does (a slider, an optimiser): the calls compared in
    # turn, so that a drift of the machine hits them alike; a fresh mechanism's load and
    # compilation, whose allocations would wake the garbage collector in the others, apart
    calls = [lambda: simulate(kernels), lambda: mech.simulate(), new_value,
             lambda: simulate(before[at[0]])]
    for call in calls:  # warm: the first new value compiles the template
        call()
    times: list[list[float]] = [[] for _ in calls]
    for _ in range(repeat):
        for call, out in zip(calls, times):
            start = time.perf_counter()
            call()
            out.append(time.perf_counter() - start)
    t_solve, t_again, t_new, t_new_solve = (statistics.median(t) for t in times)
    t_first, _ = median_time(lambda: mechdsl.load(ROOT / "examples" / "slider_crank.mech"
                                                  ).simulate(), repeat)
    rows = [["solve, compiled beforehand (simulate(system))", f"{1e3 * t_solve:.2f}", "1.00",
             ""],
            ["mech.simulate() again, same values", f"{1e3 * t_again:.2f}",
             f"{t_again / t_solve:.2f}", ""],
            ["solve of a new l, compiled beforehand", f"{1e3 * t_new_solve:.2f}",
             f"{t_new_solve / t_solve:.2f}", "1.00"],
            ["mech.simulate(l=...) again, a new l each call", f"{1e3 * t_new:.2f}",
             f"{t_new / t_solve:.2f}", f"{t_new / t_new_solve:.2f}"],
            ["load + simulate() (a fresh Mechanism each call)", f"{1e3 * t_first:.2f}",
             f"{t_first / t_solve:.2f}", ""]]
    rep.table("Solving a loaded model again (the seed, 1001 instants; median ms, ratio to "
              "the solve of the same values compiled beforehand)",
              ["call", "ms", "ratio to l = 3.5", "ratio to the same l"], rows)


def animation(rep: Report, quick: bool) -> None:
    """The animation of a 101-body chain over 1000 instants, solve and GIF."""
    from mechdsl.outputs.draw import animate

    n_loops = 50
    text = models.chain_text(n_loops, t1=9.99, step=0.01) + f"trace coupler{n_loops - 1}\n"
    kernels = mechdsl.loads(text).compile()
    start = time.perf_counter()
    res = simulate(kernels, poses=True)
    solved = time.perf_counter() - start
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        animate(res, kernels.system, str(Path(tmp) / "chain.gif"))
        drawn = time.perf_counter() - start
        size = (Path(tmp) / "chain.gif").stat().st_size
    rep.table("Animation: row of 101 bodies, 1000 instants, 100 frames (GIF)",
              ["instants", "solve s", "animation s", "total s", "GIF kB"],
              [[str(len(res["t"])), f"{solved:.2f}", f"{drawn:.2f}", f"{solved + drawn:.2f}",
                f"{size / 1024:.0f}"]])


def levers(rep: Report, quick: bool) -> None:
    """Each speed lever of the engine switched off in turn, on the seed (1001 instants) and
    on the same slider-crank over 10,001 instants: time against the default in one run,
    settings interleaved so that a change of the machine's speed hits all alike."""
    repeat = 3 if quick else 7
    settings = [
        ("default (numpy)", NUMPY),
        ("parallel-in-time march off (coarse_stride=1)", replace(NUMPY, coarse_stride=1)),
        ("no blocks: one instant at a time", replace(NUMPY, coarse_stride=1, max_block=1,
                                                     initial_block=1)),
        ("generated LU off (LAPACK on every batch)", "lapack"),
        ("fusion off (each type evaluated on its own)", "unfused"),
        ("predictor order 1", replace(NUMPY, predictor_order=1)),
        ("no early stop (newton_error=0)", replace(NUMPY, newton_error=0.0)),
    ]
    if have_numba():
        settings.append(("compiled backend (numba)", COMPILED))
    rows = []
    for step in (1e-3, 1e-4):
        kernels = slider_crank_system(step)
        times: dict[str, list[float]] = {name: [] for name, _ in settings}
        errs = {}
        # one instant at a time is ~100 times slower: measured on the 1001 instants only
        chosen = [(n, o) for n, o in settings
                  if step == 1e-3 or isinstance(o, str) or o.max_block > 1]
        data = kernels.system
        plain = fuse(list(data.groups), data.n_bodies, data.m, force="group")
        unfused = dataclasses.replace(kernels, fused=plain, system=dataclasses.replace(
            data, pattern=Pattern.from_entries(plain.rows, plain.cols, (data.m, data.n))))
        for _ in range(repeat + 1):  # the first round warms up
            for name, opts in chosen:
                run_system, run_opts = kernels, opts
                if opts == "unfused":
                    run_system, run_opts = unfused, NUMPY
                saved = mechdsl_equations.LU_BATCH
                if opts == "lapack":
                    run_opts, mechdsl_equations.LU_BATCH = NUMPY, 10**12
                start = time.perf_counter()
                res = simulate(run_system, run_opts)
                times[name].append(time.perf_counter() - start)
                mechdsl_equations.LU_BATCH = saved
                errs[name] = max(slider_crank_errors(res))
        base = statistics.median(times["default (numpy)"][1:])
        for name, _ in chosen:
            t = statistics.median(times[name][1:])
            rows.append([f"{len(kernels.system.times)}", name, f"{1e3 * t:.1f}", f"{t / base:.2f}",
                         f"{errs[name]:.1e}"])
    rep.table("Levers: the slider-crank with one speed lever off at a time",
              ["instants", "setting", "ms", "x default", "max err (x, vx, ax)"], rows)


def time_at(curve: list[tuple[float, float]], error: float) -> float:
    """The time of a work-precision curve (points (time, error)) at ``error``: log-log
    interpolation between the two points around it, the cheapest point where every point
    is more accurate, infinity where none reaches it. The curve is the points no other
    point beats in both time and error (a setting slower and less accurate than another
    is not what a user reaching for that error would choose)."""
    front = [p for p in curve
             if not any(o[0] <= p[0] and o[1] <= p[1] and o != p for o in curve)]
    pts = sorted(front, key=lambda p: p[1])  # by error, most accurate first
    if error < pts[0][1]:
        return math.inf
    if error >= pts[-1][1]:
        return min(t for t, _ in pts)
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if e0 <= error <= e1:
            w = math.log(error / e0) / math.log(e1 / e0) if e1 > e0 else 0.0
            return math.exp((1 - w) * math.log(t0) + w * math.log(t1))
    return math.inf


def andrews(rep: Report, quick: bool) -> None:
    """Andrews' squeezing mechanism: the curves of error at t = 0.03 against time."""
    import andrews as ref
    from mechdsl.compiled.variants import Overrides as Ov

    names = ("beta", "Theta", "gamma", "Phi", "delta", "Omega", "epsilon")
    repeat = 3 if quick else 7
    mech = mechdsl.load(ROOT / "examples" / "andrews.mech")
    one = mech.compile(Ov(step=0.03))  # the reference's instant only, as the peers
    rows, curves = [], {}
    engines = [("mechdsl numpy", NUMPY)] + ([("mechdsl compiled", COMPILED)] if have_numba()
                                           else [])
    # the tolerances span the errors every peer reaches (Exudyn's 2e-3 .. 2e-6 included)
    tols = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
    for label, base in engines:
        for rtol in tols:
            opts = replace(base, rtol=rtol, atol=rtol * 1e-2)
            t, res = median_time(lambda: simulate(one, opts), repeat)
            err = ref.relative_error(np.array([res[n][-1] for n in names]))
            rows.append([label, f"rtol {rtol:g}", f"{1e3 * t:.1f}", f"{err:.1e}"])
            curves.setdefault(label, []).append((t, err))
    for rtol in tols:
        r = ref.scipy_andrews(rtol, repeat=repeat)
        rows.append(["scipy solve_ivp DOP853, index 1", f"rtol {rtol:g}", f"{1e3 * r['time']:.1f}",
                     f"{r['err']:.1e}"])
        curves.setdefault("scipy DOP853", []).append((r["time"], r["err"]))
    for rtol in (1e-5, 1e-6, 1e-7, 1e-8):
        r = ref.scipy_andrews(rtol, "Radau", repeat=1)
        rows.append(["scipy solve_ivp Radau, index 1", f"rtol {rtol:g}", f"{1e3 * r['time']:.1f}",
                     f"{r['err']:.1e}"])
        curves.setdefault("scipy Radau", []).append((r["time"], r["err"]))
    if importlib.util.find_spec("exudyn") is not None:
        for h in (1e-4, 3e-5, 1e-5, 3e-6) if not quick else (1e-4, 1e-5):
            r = ref.exudyn_andrews(h, repeat=1 if h < 1e-5 else 3)
            rows.append(["Exudyn generalised-alpha", f"h {h:g}", f"{1e3 * r['time']:.1f}",
                         f"{r['err']:.1e}"])
            curves.setdefault("Exudyn gen.-alpha", []).append((r["time"], r["err"]))
    rep.table("Andrews' squeezing mechanism: error of the seven angles at t = 0.03 against "
              "solve time (in-process; mechdsl's default method: dopri5 for rtol >= 1e-4, "
              "vern9 below)", ["solver", "setting", "ms", "max rel. error"], rows)
    methods = []
    for method in ("vern9", "dop853", "dopri5"):
        for rtol in tols:
            opts = replace(NUMPY, rtol=rtol, atol=rtol * 1e-2, method=method)
            t, res = median_time(lambda: simulate(one, opts), repeat)
            err = ref.relative_error(np.array([res[n][-1] for n in names]))
            methods.append([method, f"rtol {rtol:g}", f"{1e3 * t:.1f}", f"{err:.1e}"])
    rep.table("Andrews: each of mechdsl's methods at each tolerance (numpy path, in-process)",
              ["method", "setting", "ms", "max rel. error"], methods)
    peers_ = [k for k in curves if not k.startswith("mechdsl")]
    rep.table("Andrews: mechdsl's curves at each error a peer reaches (time on the curve, "
              "log-log between the points no other point beats in both time and error, over "
              "the peer's time; below 1: below the peer)",
              ["peer", "peer's point", *[k for k in curves if k.startswith("mechdsl")]],
              [[peer, f"{1e3 * tp:.1f} ms at {ep:.1e}",
                *[f"{time_at(curves[k], ep) / tp:.2f}" for k in curves if k.startswith("mechdsl")]]
               for peer in peers_ for tp, ep in curves[peer]])
    cmd = [sys.executable, "-m", "mechdsl", "run", str(ROOT / "examples" / "andrews.mech"),
           "-o", "-", "-q"]
    t_run, _ = median_time(lambda: subprocess.run(cmd, check=True, env=peers.user_env(),
                                                  stdout=subprocess.DEVNULL), repeat)
    kernels = mech.compile()
    t_solve, full = median_time(lambda: simulate(kernels, NUMPY), repeat)
    err = ref.relative_error(np.array([full[n][-1] for n in names]))
    t_in, _ = median_time(lambda: mech.simulate(), repeat)
    table = [["error of the angles at t = 0.03", f"{err:.1e}"],
             ["solve, in-process, numpy (model compiled)", f"{1e3 * t_solve:.1f} ms"]]
    if have_numba():
        t_fast, _ = median_time(lambda: simulate(kernels, COMPILED), repeat)
        table.append(["solve, in-process, compiled", f"{1e3 * t_fast:.1f} ms"])
    table += [["compile and solve, in-process, numpy", f"{1e3 * t_in:.1f} ms"],
              ["mechdsl run examples/andrews.mech, whole process", f"{1e3 * t_run:.0f} ms"]]
    rep.table("Andrews: examples/andrews.mech as written (31 instants, rtol 1e-7)",
              ["what", "value"], table)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for label, pts in curves.items():
        pts = np.array(pts)
        ax.loglog(pts[:, 1], 1e3 * pts[:, 0], "o-", label=label)
    ax.set_xlabel("max relative error of the angles at t = 0.03")
    ax.set_ylabel("solve time (ms)")
    ax.set_title("Andrews' squeezing mechanism: work against precision")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(rep.out / "andrews.png", dpi=90)
    plt.close(fig)


def view_section(rep: Report, quick: bool) -> None:
    """mechdsl view's latencies measured by the page in headless Chromium (issue 29), by
    benchmarks/view_latency.py (which also runs alone)."""
    import view_latency
    view_latency.run(rep, quick)


def dynamics_section(rep: Report, quick: bool) -> None:
    """Forward dynamics beside the peers (issue 28): A02, the chain, the stiff pendulum and
    the car axis, by benchmarks/dynamics.py (which also runs alone)."""
    import dynamics
    dynamics.run(rep, quick)


SECTIONS = {"seed": seed, "levers": levers, "work-precision": work_precision, "scaling": scaling,
            "sweep": sweep, "long": long_span, "startup": startup, "api": api_again,
            "animation": animation,
            "andrews": andrews, "dynamics": dynamics_section, "view": view_section}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes and fewer repeats")
    ap.add_argument("--only", default=",".join(SECTIONS), help="comma-separated sections")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results",
                    help="folder for the plots and results.md")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rep = Report(args.out)
    import platform
    print(f"python {platform.python_version()}, numpy {np.__version__}, "
          f"{platform.machine()}, mechdsl {mechdsl.__version__}")
    for name in args.only.split(","):
        SECTIONS[name.strip()](rep, args.quick)
    chosen = [n.strip() for n in args.only.split(",")]
    # a partial run keeps the tables of the last full one
    rep.save("results.md" if set(chosen) == set(SECTIONS) else f"results-{'-'.join(chosen)}.md")
    print(f"\nplots and results.md in {args.out}")


if __name__ == "__main__":
    main()
