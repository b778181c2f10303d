"""mechdsl's sweeps solved chunk by chunk, in this process or on a Dask cluster: throughput
and flat memory, measured in one run on one machine.

    python benchmarks/cluster.py            # everything (~5-10 minutes on 2 cores)
    python benchmarks/cluster.py --quick    # smaller sweeps, fewer repeats (< 2 minutes)
    python benchmarks/cluster.py --only throughput   # one section (throughput, memory)

Sections (each prints tables; a Markdown copy goes to --out, benchmarks/results/cluster.md):

* throughput: the slider-crank over 101 instants (t = 0 .. 1 step 0.01), an l x r grid of
  variants (20,000; --quick 4,000), one reduction (peak = max(abs(slider.ax))), chunks of
  1000 variants, solved in this process, on a local cluster of 1 worker and of 2 workers,
  on the numpy backend and the default (auto: numba's compiled backend for chunks of
  100,000 states or more, when numba is installed). Median wall time of 3 repeats (the
  cluster's start-up and a warm-up run excluded, reported apart), variants/s, ratios to
  in-process, and a check that the reduced arrays are identical. The clusters run twice:
  as local_client starts them, and with the MALLOC_TRIM_THRESHOLD_=65536 that distributed's
  nannies put in their workers' environment by default (it halved the numpy backend's
  speed on a worker here, probably because glibc then keeps its mmap threshold at 128 KiB
  and maps every large temporary afresh). Then the cost of a
  chunk (tiny chunks against one big one, in this process and on 1 worker: the difference
  is the cluster's scheduling overhead per chunk) and an estimate for W machines.
* memory: ``mechdsl run`` as a process, the slider-crank with ``sweep l = 3 .. 4 count N``
  (10,000, 30,000, 100,000; --quick 2,000, 6,000, 20,000) over 101 instants, x vx ax
  written to a Zarr store, in process and with --workers 2: wall time, the store's size
  on disk, the peak resident memory (VmHWM) of the coordinating process and of the
  workers (read from /proc while the run goes on: VmHWM only grows), and whether the peak
  grows with N. The store is read back lazily and one variant's slider.x checked against
  the closed form.

On 2 cores, 2 workers can at best halve the time, and the coordinating process (client
and scheduler) competes with them for a core. Times are medians; ratios are taken
between figures of the same run. Other processes on the machine (os.getloadavg() is
printed) make the figures noisier.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.metadata
import importlib.util
import logging
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import mechdsl  # noqa: E402
from mechdsl.outputs.store import open_store  # noqa: E402
from mechdsl.solve import SolverOptions  # noqa: E402
from mechdsl.study.cluster import local_client  # noqa: E402
from report import Report  # noqa: E402

MODEL = ROOT / "examples" / "slider_crank.mech"
SPAN, STEP = (0.0, 1.0), 0.01                 # 101 instants
REDUCE = "peak = max(abs(slider.ax))"
CHUNK = 1000                                  # variants per chunk, every mode alike
BACKENDS = {"numpy": SolverOptions(backend="numpy"), "auto": SolverOptions()}

#: The CLI run through a wrapper that prints its own peak resident memory on stderr
WRAPPER = ("import sys; from mechdsl.cli import main; code = main(sys.argv[1:]); "
           "print('VmHWM', open('/proc/self/status').read().split('VmHWM:')[1].split()[0], "
           "file=sys.stderr); sys.exit(code)")

NOTES: list[str] = []


def median_time(fn: Callable[[], object], repeat: int) -> tuple[float, list[float], object]:
    """Median wall time of ``repeat`` calls (no warm-up here), all the times, the last result."""
    times, out = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), times, out


def vmhwm_kb(pid: int | str = "self") -> int:
    with open(f"/proc/{pid}/status") as f:
        return int(f.read().split("VmHWM:")[1].split()[0])


def mb(kb: float) -> str:
    return f"{kb / 1024:.0f}"


def du_bytes(path: Path) -> int:
    return sum(f.stat().st_blocks * 512 for f in path.rglob("*") if f.is_file())


# -- the cluster -----------------------------------------------------------------------------

@contextlib.contextmanager
def cluster(workers: int, trim: bool = False):
    """A local cluster of ``workers`` single-threaded processes (local_client), closed at the
    end; yields (client, start-up seconds). ``trim``: its workers started with
    MALLOC_TRIM_THRESHOLD_=65536, as distributed's nannies set it by default
    (``distributed.nanny.pre-spawn-environ``; it also keeps glibc's mmap threshold at
    128 KiB, so every large numpy temporary is, presumably, a fresh mmap); local_client may
    or may not drop it (the start-up table says what the workers got)."""
    # the nannies copy pre-spawn-environ into this process's os.environ and leave it there;
    # a spawned worker inherits os.environ: set it for ``trim``, put os.environ back after
    saved = dict(os.environ)
    os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    if trim:
        os.environ["MALLOC_TRIM_THRESHOLD_"] = "65536"
    start = time.perf_counter()
    try:
        client = local_client(workers)
        client.wait_for_workers(workers)
    finally:
        os.environ.clear()
        os.environ.update(saved)
    elapsed = time.perf_counter() - start
    try:
        yield client, elapsed
    finally:
        c = client.cluster
        client.close()
        c.close()


# -- 1. throughput -----------------------------------------------------------------------------

def grid(quick: bool) -> dict[str, list[float]]:
    """The sweep: every combination of l and r (N = 20,000; quick 4,000)."""
    nl, nr = (100, 40) if quick else (200, 100)
    return {"l": np.linspace(3.0, 4.0, nl).tolist(), "r": np.linspace(1.5, 2.5, nr).tolist()}


def chunk_compute(ts) -> tuple[float, int]:
    """Seconds the workers spent computing mechdsl's chunks in a task stream, and how many."""
    spans = [s["stop"] - s["start"] for d in ts.data if str(d["key"]).startswith("mechdsl-chunk")
             for s in d["startstops"] if s["action"] == "compute"]
    return sum(spans), len(spans)


def throughput(report: Report, quick: bool) -> None:
    from distributed import get_task_stream

    mech = mechdsl.load(MODEL)
    sweep = grid(quick)
    n = len(sweep["l"]) * len(sweep["r"])
    n_chunks = -(-n // CHUNK)
    repeat = 3
    warm = {"l": sweep["l"][:2 * CHUNK // len(sweep["r"]) + 1], "r": sweep["r"]}  # >= 2 chunks

    def solve(options, client=None, sw=sweep, chunk=CHUNK):
        res = mech.simulate(sweep=sw, span=SPAN, step=STEP, reduce=REDUCE, options=options,
                            client=client, chunk=chunk)
        if res.status != "ok":
            raise RuntimeError(f"run ended {res.status}: {res.messages[:2]}")
        return res

    def timed(options, client=None, sw=sweep, chunk=CHUNK):
        """(wall s, seconds the workers computed chunks, chunks, results) of one run."""
        with (get_task_stream(client) if client else contextlib.nullcontext()) as ts:
            start = time.perf_counter()
            res = solve(options, client, sw, chunk)
            wall = time.perf_counter() - start
        busy, k = chunk_compute(ts) if client else (wall, -(-len(res.n_solved) // chunk))
        return wall, busy, k, res

    timings: dict[tuple[str, str], tuple[float, list[float], float]] = {}
    peaks: dict[tuple[str, str], np.ndarray] = {}
    startup: dict[str, tuple[float, dict[str, float]]] = {}
    notrim = "(MALLOC_TRIM_THRESHOLD_=65536)"
    modes = ["in process", "1 worker", "2 workers", f"1 worker {notrim}", f"2 workers {notrim}"]
    got_env: dict[str, str] = {}
    n_workers = {m: int(m[0]) if m[0].isdigit() else 0 for m in modes}
    for mode in modes:
        workers = n_workers[mode]
        with (cluster(workers, trim=notrim in mode) if workers
              else contextlib.nullcontext((None, 0.0))) as (client, up):
            if client is not None:
                got_env[mode] = ", ".join(sorted({str(v) for v in client.run(
                    lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_")).values()}))
            firsts = {}
            for name, options in BACKENDS.items():
                # warm-up: imports, numba's JIT and the study's first compile in every process
                start = time.perf_counter()
                solve(options, client, warm)
                firsts[name] = time.perf_counter() - start
                runs = [timed(options, client) for _ in range(repeat)]
                walls = [r[0] for r in runs]
                t = statistics.median(walls)
                busy = statistics.median(r[1] for r in runs)   # summed over the workers
                timings[mode, name] = t, walls, busy
                peaks[mode, name] = runs[-1][3].reduced["peak"]
                print(f"  {mode:10s} {name:5s} {t:7.2f} s  ({', '.join(f'{x:.2f}' for x in walls)})")
            startup[mode] = up, firsts

    rows = []
    for name in BACKENDS:
        base = timings["in process", name][0]
        for mode in modes:
            t, ts, busy = timings[mode, name]
            w = n_workers[mode]
            rows.append([name, mode, f"{t:.2f}", f"{max(ts) - min(ts):.2f}", f"{n / t:,.0f}",
                         f"{base / t:.2f}",
                         f"{1e3 * (busy if w else t) / n_chunks:.0f}",
                         f"{busy / (w * t):.0%}" if w else "-"])
    report.table(f"Throughput: slider-crank, {n:,} variants (l x r grid) x 101 instants, "
                 f"reduce '{REDUCE}', chunks of {CHUNK} variants ({n_chunks} chunks), "
                 f"median of {repeat}",
                 ["backend", "where", "wall s", "spread s", "variants/s", "speed-up vs in process",
                  "ms per chunk (solving)", "workers busy"], rows)
    report.text("'ms per chunk (solving)': in process, the wall time per chunk; on a cluster, "
                "the time the workers spent computing a chunk (Dask's task stream), median "
                "run. 'workers busy': that time summed over the chunks, over workers x wall. "
                f"'{notrim}': the workers started with the environment variable that "
                "distributed's nannies set by default (distributed.nanny.pre-spawn-environ) "
                "and local_client may drop (the start-up table says what the workers got); "
                "probably because it also keeps glibc's mmap threshold at 128 KiB, each large "
                "numpy temporary of the numpy backend is then mmapped and page-faulted afresh.")

    rows = []
    for name in BACKENDS:
        ref = peaks["in process", name]
        for mode in modes[1:]:
            same = np.array_equal(ref, peaks[mode, name])
            rows.append([name, f"in process vs {mode}", "yes" if same else "NO",
                         f"{np.nanmax(np.abs(peaks[mode, name] - ref)):.1e}"])
    a, b = peaks["in process", "numpy"], peaks["in process", "auto"]
    rows.append(["numpy vs auto", "in process", "yes" if np.array_equal(a, b) else "no (not promised)",
                 f"{np.nanmax(np.abs(a - b) / np.abs(a)):.1e} (relative)"])
    report.table("Reduced arrays identical (np.array_equal)",
                 ["backend", "compared", "identical", "max |difference|"], rows)
    if not all(np.array_equal(peaks["in process", k], peaks[m, k])
               for k in BACKENDS for m in modes[1:]):
        NOTES.append("the reduced arrays differ between in-process and cluster runs")

    report.table("Cluster start-up and warm-up (not in the times above)",
                 ["where", "cluster start s", "first run numpy s", "first run auto s",
                  "variants in first run", "workers' MALLOC_TRIM_THRESHOLD_"],
                 [[m, f"{startup[m][0]:.2f}", f"{startup[m][1]['numpy']:.2f}",
                   f"{startup[m][1]['auto']:.2f}",
                   f"{len(warm['l']) * len(warm['r']):,}", got_env.get(m, "-")] for m in modes])

    # -- the cost of a chunk: tiny chunks against one big one ---------------------------------
    # On 1 worker the chunks run one after the other: the wall time not spent computing
    # (gaps) is the coordinator's work (plan, scatter, dispatch, gather, merge); its growth
    # per extra chunk is the scheduling overhead of a chunk.
    m_var, small = 1000, 10
    few = {"l": np.linspace(3.0, 4.0, m_var).tolist()}
    n_small, n_big = -(-m_var // small), 1
    rep = 2 if quick else 3
    numpy = BACKENDS["numpy"]  # auto would switch backend with the chunk's size
    cost: dict[tuple[str, int], tuple[float, float]] = {}
    for size in (small, m_var):
        walls = [timed(numpy, None, few, size)[0] for _ in range(rep)]
        cost["in process", size] = statistics.median(walls), statistics.median(walls)
    with cluster(1) as (client, _):
        solve(numpy, client, few, m_var)  # warm-up
        for size in (small, m_var):
            runs = [timed(numpy, client, few, size) for _ in range(rep)]
            cost["1 worker", size] = (statistics.median(r[0] for r in runs),
                                      statistics.median(r[1] for r in runs))
    rows = []
    for w in ("in process", "1 worker"):
        (ws, bs), (wb, bb) = cost[w, small], cost[w, m_var]
        rows.append([w, f"{ws:.2f}", f"{bs:.2f}", f"{ws - bs:.2f}", f"{wb:.2f}", f"{bb:.2f}",
                     f"{wb - bb:.2f}", f"{1e3 * (bs - bb) / (n_small - n_big):.1f}",
                     f"{1e3 * ((ws - bs) - (wb - bb)) / (n_small - n_big):.1f}"])
    (ws, bs), (wb, bb) = cost["1 worker", small], cost["1 worker", m_var]
    overhead = ((ws - bs) - (wb - bb)) / (n_small - n_big)
    fixed = wb - bb
    report.table(f"Cost of a chunk: {m_var} variants (l) x 101 instants, numpy backend, "
                 f"{n_small} chunks of {small} vs 1 chunk of {m_var}, median of {rep}",
                 ["where", f"{n_small} chunks: wall s", "computing s", "gaps s",
                  "1 chunk: wall s", "computing s", "gaps s",
                  "computing per extra chunk ms", "gaps per extra chunk ms"], rows)
    report.text(f"Scheduling overhead per chunk (1 worker: growth of the gaps per extra chunk): "
                f"{1e3 * overhead:.1f} ms; fixed overhead of a cluster run (gaps with 1 chunk: "
                f"plan and probe compile, scatter, gather): {fixed:.2f} s. 'computing per extra "
                f"chunk' is the cost of cutting finer wherever it runs (each chunk is compiled "
                f"and started on its own).")

    # -- an estimate for W machines --------------------------------------------------------------
    rows = []
    ov = max(overhead, 0.0)
    for name, one in [(k, "1 worker") for k in BACKENDS] + [(f"{k} {notrim}", f"1 worker {notrim}")
                                                         for k in BACKENDS]:
        t1, _, busy1 = timings[one, name.split()[0]]
        t_chunk = busy1 / n_chunks                         # a worker's time per chunk
        rate = CHUNK / t_chunk                             # variants/s of one worker
        per_worker = CHUNK / (t_chunk + ov)
        cap = CHUNK / ov if ov > 0 else float("inf")       # if the overhead were all serial
        for w in (1, 2, 8, 32, 128):
            est = w * per_worker
            rows.append([name, f"{rate:,.0f}", str(w), f"{est:,.0f}", f"{min(est, cap):,.0f}",
                         f"{n / min(est, cap) + fixed:.2f}"])
    report.table(f"Estimate for W machines (one worker each, chunks of {CHUNK}): W x {CHUNK} / "
                 f"(a worker's s per chunk + {1e3 * ov:.1f} ms overhead per chunk); 'capped': at "
                 f"most one chunk per overhead, as if the scheduler did all of it in series "
                 f"(pessimistic: round trips overlap)",
                 ["backend", "variants/s per worker", "W", "variants/s", "capped variants/s",
                  f"s for {n:,} (+ {fixed:.2f} s fixed)"], rows)
    parts = []
    for k in BACKENDS:
        for suffix in ("", f" {notrim}"):
            t_chunk = timings[f"1 worker{suffix}", k][2] / n_chunks
            est2 = 2 * CHUNK / (t_chunk + ov)
            got = n / timings[f"2 workers{suffix}", k][0]
            parts.append(f"{k}{suffix} {got:,.0f} variants/s ({got / est2:.0%} of the "
                         "estimate for W = 2)")
    report.text("Measured on 2 workers here: " + ", ".join(parts)
                + f"; {os.cpu_count()} cores shared by the 2 workers, the coordinating process "
                  "and whatever else runs on the machine (load average above).")


# -- 2. flat memory --------------------------------------------------------------------------

def run_cli(args: list[str], cwd: Path) -> dict:
    """``mechdsl run ARGS`` as a process through the wrapper: its wall time, return code,
    its own VmHWM (printed by the wrapper) and its children's (polled from /proc)."""
    import psutil

    cmd = [sys.executable, "-c", WRAPPER, "run", *args]
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    start = time.perf_counter()
    p = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, env=env)
    children: dict[int, tuple[int, str]] = {}
    proc = psutil.Process(p.pid)
    while p.poll() is None:
        with contextlib.suppress(psutil.Error, OSError):
            for c in proc.children(recursive=True):
                with contextlib.suppress(psutil.Error, OSError, IndexError, ValueError):
                    kb = vmhwm_kb(c.pid)
                    line = " ".join(c.cmdline())
                    children[c.pid] = (max(kb, children.get(c.pid, (0, ""))[0]), line)
        time.sleep(0.05)
    err = p.communicate()[1]
    wall = time.perf_counter() - start
    own = [int(l.split()[1]) for l in err.splitlines() if l.startswith("VmHWM ")]
    # the workers: spawned processes, not multiprocessing's resource tracker
    workers = [kb for kb, line in children.values() if "resource_tracker" not in line]
    return {"rc": p.returncode, "wall": wall, "coord": own[-1] if own else None,
            "workers": workers, "stderr": err}


def closed_form_x(l: float, r: float, t: np.ndarray) -> np.ndarray:
    theta = np.pi / 4 + 4 * np.pi * t
    return r * np.cos(theta) + np.sqrt(l ** 2 - r ** 2 * np.sin(theta) ** 2)


def memory(report: Report, quick: bool) -> None:
    sizes = (2_000, 6_000, 20_000) if quick else (10_000, 30_000, 100_000)
    text = MODEL.read_text()
    rows, checks = [], []
    peaks: dict[str, list[tuple[int, int, list[int]]]] = {"in process": [], "--workers 2": []}
    with tempfile.TemporaryDirectory(prefix="mechdsl-cluster-") as tmp:
        tmp = Path(tmp)
        for n in sizes:
            model = tmp / f"slider_crank_{n}.mech"
            model.write_text(text + f"\nsweep l = 3 .. 4 count {n}\n")
            for where, extra in (("in process", []), ("--workers 2", ["--workers", "2"])):
                out = tmp / "out.zarr"
                shutil.rmtree(out, ignore_errors=True)
                args = [model.name, "--step", str(STEP), "-o", out.name, "-q", *extra]
                r = run_cli(args, tmp)
                if r["rc"] != 0:
                    raise RuntimeError(f"mechdsl run {' '.join(args)} failed:\n{r['stderr'][-2000:]}")
                size = du_bytes(out)
                store = open_store(out)
                solved = store.n_solved
                v = n // 3                                  # one variant, read lazily
                x = store["slider.x"][v]
                l_v = float(store.sweep["l"][v])
                err = float(np.max(np.abs(x - closed_form_x(l_v, 2.0, store.times))))
                checks.append([f"{n:,}", where, store.status, f"{int((solved == len(store.times)).sum()):,}",
                               str(v), f"{l_v:.6f}", f"{err:.1e}"])
                peaks[where].append((n, r["coord"], r["workers"]))
                hist = n * len(store.times) * 3 * 8
                rows.append([f"{n:,}", where, f"{r['wall']:.1f}", f"{size / 2**20:.1f}",
                             f"{hist / 2**20:.0f}", mb(r["coord"]),
                             " / ".join(mb(k) for k in sorted(r["workers"], reverse=True)) or "-"])
                print(f"  N={n:,} {where}: {r['wall']:.1f} s, {size / 2**20:.1f} MiB on disk, "
                      f"VmHWM {mb(r['coord'])} MiB, workers {[mb(k) for k in r['workers']]}")
                del store
                shutil.rmtree(out, ignore_errors=True)
    report.table("Flat memory: `mechdsl run` (a process) of the slider-crank, `sweep l = 3 .. 4 "
                 "count N`, 101 instants, x vx ax to out.zarr, default chunk (1000 variants)",
                 ["N", "where", "wall s", "store MiB (du)", "histories MiB (if held)",
                  "coordinator peak MiB", "worker peaks MiB"], rows)
    report.table("The store read back lazily (open_store): variant v's slider.x against "
                 "x = r cos(theta) + sqrt(l^2 - r^2 sin^2 theta), theta = pi/4 + 4 pi t, r = 2",
                 ["N", "where", "status", "variants with 101 instants", "v", "l", "max |error| m"],
                 checks)
    rows = []
    for where, ps in peaks.items():
        (n0, c0, w0), (n1, c1, w1) = ps[0], ps[-1]
        hist = n1 * (len(np.arange(SPAN[0], SPAN[1] + STEP / 2, STEP))) * 3 * 8 / 1024
        limit = max(10 * 1024, 0.1 * hist)                   # kB
        growth = c1 - c0
        wgrowth = (max(w1) - max(w0)) if w0 and w1 else None
        flat_c = growth < limit
        flat_w = None if wgrowth is None else wgrowth < limit
        rows.append([where, f"{n0:,} -> {n1:,}", f"{hist / 1024:.0f}", f"{limit / 1024:.0f}",
                     f"{mb(c0)} -> {mb(c1)}", f"{growth / 1024:+.0f}", "yes" if flat_c else "NO",
                     (f"{mb(max(w0))} -> {mb(max(w1))}" if w0 and w1 else "-"),
                     "-" if wgrowth is None else f"{wgrowth / 1024:+.0f}",
                     {None: "-", True: "yes", False: "NO"}[flat_w]])
        if not flat_c or flat_w is False:
            NOTES.append(f"the peak memory grows with N ({where}: coordinator "
                         f"{growth / 1024:+.0f} MiB, workers "
                         f"{'-' if wgrowth is None else f'{wgrowth / 1024:+.0f}'} MiB from "
                         f"N = {n0:,} to {n1:,})")
    report.table("Does the peak grow with N? (flat: growth below max(10 MiB, 10% of what the "
                 "largest run's histories would take if held))",
                 ["where", "N", "histories of largest MiB", "allowed MiB", "coordinator MiB",
                  "growth MiB", "flat", "max worker MiB", "growth MiB", "flat"], rows)


# -- main ----------------------------------------------------------------------------------------

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller sweeps, fewer repeats")
    ap.add_argument("--only", default="throughput,memory", help="sections, comma separated")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results",
                    help="folder of cluster.md")
    args = ap.parse_args()
    warnings.filterwarnings("ignore")                     # e.g. "Port 8787 is already in use"
    logging.getLogger("distributed").setLevel(logging.ERROR)
    sections = {s.strip() for s in args.only.split(",")}

    report = Report(args.out)
    numba = importlib.util.find_spec("numba") is not None
    versions = ", ".join(f"{p} {importlib.metadata.version(p)}"
                         for p in ("numpy", "dask", "distributed", "zarr")
                         + (("numba",) if numba else ()))
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    report.text(f"mechdsl cluster benchmark{' (--quick)' if args.quick else ''}: "
                f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
                f"Python {platform.python_version()}, {versions}; load average before: {load}. "
                f"Backend 'auto' = {'numba compiled for chunks of 100,000 states or more' if numba else 'numpy (numba not installed)'}.")
    start = time.perf_counter()
    if "throughput" in sections:
        throughput(report, args.quick)
    if "memory" in sections:
        memory(report, args.quick)
    report.text(f"Total time {time.perf_counter() - start:.0f} s; load average after: "
                + ", ".join(f"{x:.2f}" for x in os.getloadavg()) + ".")
    for note in NOTES:
        report.text(f"Note: {note}")
    print(f"\nwrote {report.save('cluster.md')}")


if __name__ == "__main__":
    main()
