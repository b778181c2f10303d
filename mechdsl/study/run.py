"""A sweep solved chunk by chunk, in this process or on a Dask cluster, its results merged in
variant order or written chunk by chunk into a Zarr or Parquet store.

What goes to a worker is the :class:`~mechdsl.study.chunks.Study` (the parsed model and the
overrides, plain data) and a range of variants; the worker compiles and solves that chunk
with the vectorised engine and sends back its results, or writes them into its own region
of the store and sends back only how the chunk ended. A worker lost mid-run costs its
chunks: the scheduler runs them again elsewhere, and the run says so in its warnings.
dask is imported here only when a client is given.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..compiled.system import System
from ..errors import MechError
from ..results import Results
from .chunks import Study, chunk_ranges, empty_like, merge

#: Seconds between two looks at the cluster's workers while chunks are being solved
POLL = 0.25


def labels_and_units(system: System) -> tuple[list[str], dict[str, str]]:
    """The columns a run of ``system`` gives (its reductions, or its outputs) and their units."""
    columns = system.reductions or system.outputs
    return [c.label for c in columns], {c.label: c.unit for c in columns if c.unit}


def solve_chunk(study: Study, start: int, stop: int, store: str | None = None,
                system: System | None = None) -> Results:
    """Solve variants ``start`` .. ``stop - 1`` of ``study`` (compiled as ``system``, if
    given). With ``store``, write them into their region of it and return how they ended
    only (no arrays but ``n_solved``)."""
    results = study.solve(start, stop, system=system)
    if store is None:
        return results
    from ..outputs.store import write_chunk

    write_chunk(store, start, results)
    return light(results)


def light(results: Results) -> Results:
    """``results`` without their arrays, as a chunk written into a store reports back."""
    return replace(results, data={}, reduced={}, poses=None, rates=None)


@dataclass
class StudyRun:
    """One run of a study: the chunks solved so far and what the run has to say about the
    cluster. The only mutable state of a study."""

    study: Study
    ranges: list[tuple[int, int]]
    sweep: dict[str, np.ndarray]
    store: str | None = None
    progress: Callable[[int, int], None] | None = None
    instants: int = 1
    done: dict[int, Results] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    status: str | None = None

    def finished(self, start: int, results: Results) -> None:
        self.done[start] = results
        if self.progress is not None:
            solved = sum(r.n_variants for r in self.done.values())
            total = self.ranges[-1][1]
            self.progress(solved * self.instants, total * self.instants)

    def in_process(self, probe: System) -> None:
        """Every chunk, one after the other, here; the first is ``probe`` if it has as many
        variants (compiled already)."""
        for start, stop in self.ranges:
            system = probe if start == 0 and probe.n_variants == stop else None
            try:
                results = solve_chunk(self.study, start, stop, self.store, system)
            except KeyboardInterrupt:
                self.status = "interrupted"
                return
            self.finished(start, results)
            if results.status == "interrupted":
                self.status = "interrupted"
                return

    def on_cluster(self, client) -> None:
        """Every chunk as a task of the Dask ``client``'s cluster, in variant order; the
        workers lost meanwhile are noted with the chunks they were solving."""
        from dask.base import tokenize
        from distributed import wait

        token = tokenize(self.study.model.source.text, repr(self.study.overrides),
                         self.store, time.time_ns())
        shared = client.scatter(self.study, broadcast=True, hash=False)
        futures = {client.submit(solve_chunk, shared, a, b, self.store, pure=False,
                                 key=f"mechdsl-chunk-{a:09d}-{token}"): (a, b)
                   for a, b in self.ranges}
        by_key = {f.key: ab for f, ab in futures.items()}
        pending = set(futures)
        workers = set(client.scheduler_info()["workers"])
        held = client.processing()
        try:
            while pending:
                try:
                    finished, pending = wait(pending, timeout=POLL,
                                             return_when="FIRST_COMPLETED")
                except TimeoutError:  # distributed's wait raises when nothing ended
                    finished = set()
                for f in sorted(finished, key=lambda f: futures[f][0]):
                    self.finished(futures[f][0], f.result())
                now = set(client.scheduler_info()["workers"])
                for lost in sorted(workers - now):
                    chunks = [by_key[k] for k in held.get(lost, ()) if k in by_key]
                    what = (", ".join(f"variants {a}..{b - 1}" for a, b in chunks)
                            if chunks else "no chunk")
                    self.notes.append(f"the worker {lost} was lost during the run; its "
                                      f"chunks ({what}) were solved again on another worker")
                workers = now
                held = client.processing() if pending else held
        except BaseException as err:
            client.cancel(list(pending))
            if not isinstance(err, KeyboardInterrupt):
                raise
            self.status = "interrupted"

    def results(self, template: Results, elapsed: float) -> Results:
        """The chunks' results merged in variant order; chunks never solved are empty."""
        parts = [self.done.get(a) or empty_like(template, a, b, self.sweep)
                 for a, b in self.ranges]
        status = self.status
        if status is None and any(a not in self.done for a, _ in self.ranges):
            status = "interrupted"
        return merge(parts, solve_time=elapsed, status=status, warnings=tuple(self.notes))


def run_study(study: Study, probe: System, n_variants: int, chunk: int,
              sweep: dict[str, np.ndarray], *, client=None, store: str | None = None,
              progress: Callable[[int, int], None] | None = None) -> Results:
    """Solve the ``n_variants`` variants of ``study`` in chunks of ``chunk``: on the Dask
    ``client``'s cluster if one is given, else here, one chunk after the other. ``probe`` is
    the compiled model of the first chunk, ``sweep`` the whole sweep table (for the chunks
    an interrupt left unsolved). Returns the merged
    results; with ``store`` (a store made by :func:`mechdsl.outputs.store.create_store`),
    each chunk is written there where it was solved, and the results hold no arrays."""
    run = StudyRun(study, chunk_ranges(n_variants, chunk), sweep, store, progress,
                   len(probe.times))
    start = time.perf_counter()
    if client is None:
        run.in_process(probe)
    else:
        run.on_cluster(client)
    elapsed = time.perf_counter() - start
    template = next(iter(run.done.values())) if run.done else blank(probe)
    return run.results(template, elapsed)


def blank(system: System) -> Results:
    """Results of ``system``'s variants with no instant solved (a run interrupted before its
    first chunk ended)."""
    labels, units = labels_and_units(system)
    V, K = system.n_variants, len(system.times)
    reduced = bool(system.reductions)
    return Results(times=system.times,
                   data={} if reduced else {k: np.full((V, K), np.nan) for k in labels},
                   reduced={k: np.full(V, np.nan) for k in labels} if reduced else {},
                   sweep=dict(system.sweep), n_solved=np.zeros(V, dtype=np.int64),
                   status="interrupted", messages=(), solve_time=0.0, residual=0.0,
                   source_name=system.source.name, units=units, time_unit=system.time_unit)


def local_client(workers: int):
    """A Dask client of a new cluster of ``workers`` processes on this machine (one thread
    each, on the loopback interface, no dashboard); a MechError saying how to install dask
    where it is missing."""
    if workers < 1:
        raise MechError(f"--workers {workers}: give at least 1")
    distributed = import_distributed("--workers")
    import logging

    import dask

    # distributed's nannies set MALLOC_TRIM_THRESHOLD_=65536 in their workers by default,
    # which pins glibc's mmap threshold at 128 KiB: every large temporary of the numpy path is
    # then mapped and page-faulted afresh, and a chunk takes 1.7 times as long (measured on
    # the slider-crank's sweep): the workers here keep glibc's own adaptive threshold
    #
    # The nannies also write their workers' environment into this process's os.environ
    # (OMP_NUM_THREADS=1, ...), where it would outlive the cluster: it is put back. The
    # scheduler's HTTP server (health checks) takes a free port, not 8787, which another
    # cluster may hold.
    saved = dict(os.environ)
    os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)  # nor inherited (an earlier cluster's)
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_":
                              None}):
            cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                               processes=True, host="127.0.0.1",
                                               dashboard_address="127.0.0.1:0",
                                               silence_logs=logging.ERROR)
    finally:
        os.environ.clear()
        os.environ.update(saved)
    return distributed.Client(cluster)


def remote_client(address: str):
    """A Dask client of the cluster whose scheduler is at ``address``."""
    distributed = import_distributed("--scheduler")
    try:
        return distributed.Client(address, timeout=10)
    except (OSError, TimeoutError, ValueError) as err:
        raise MechError(f"--scheduler {address}: cannot reach a Dask scheduler there "
                        f"({err})") from None


def import_distributed(option: str):
    try:
        import distributed
    except ImportError:
        raise MechError(f"{option} needs Dask's distributed scheduler, which is not "
                        "installed: pip install \"mechdsl[cluster]\"") from None
    return distributed
