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

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..compiled.kernels import Kernels
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
                kernels: Kernels | None = None) -> Results:
    """Solve variants ``start`` .. ``stop - 1`` of ``study`` (compiled as ``kernels``, if
    given). With ``store``, write them into their region of it and return how they ended
    only (no arrays but ``n_solved``)."""
    results = study.solve(start, stop, kernels=kernels)
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

    def in_process(self, probe: Kernels) -> None:
        """Every chunk, one after the other, here; the first is ``probe`` if it has as many
        variants (compiled already)."""
        for start, stop in self.ranges:
            kernels = probe if start == 0 and probe.system.n_variants == stop else None
            try:
                results = solve_chunk(self.study, start, stop, self.store, kernels)
            except KeyboardInterrupt:
                self.status = "interrupted"
                return
            self.finished(start, results)
            if results.status == "interrupted":
                self.status = "interrupted"
                return

    def on_cluster(self, client) -> None:
        """Every chunk as a task of the Dask ``client``'s cluster, in variant order; the
        workers lost meanwhile are noted with the chunks they were solving. Dask's own
        logging is silent meanwhile (:func:`~mechdsl.study.cluster.quiet_dask`)."""
        from .cluster import quiet_dask

        with quiet_dask():
            self._on_cluster(client)

    def _on_cluster(self, client) -> None:
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
        alive = Liveness(client)
        try:
            while pending:
                try:
                    finished, pending = wait(pending, timeout=POLL,
                                             return_when="FIRST_COMPLETED")
                except TimeoutError:  # distributed's wait raises when nothing ended
                    finished = set()
                for f in sorted(finished, key=lambda f: futures[f][0]):
                    self.finished(futures[f][0], f.result())
                alive.check(bool(finished))
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


class Liveness:
    """Whether the scheduler of ``client`` still answers while no chunk ends: after
    ``timeout`` seconds (the client's, :data:`~mechdsl.study.cluster.SCHEDULER_TIMEOUT` by
    default) without a finished chunk, the scheduler is asked who it is and must answer
    within ``timeout``; a MechError naming it otherwise. A chunk may take longer than that:
    only the scheduler's silence ends the run."""

    def __init__(self, client, timeout: float | None = None) -> None:
        from .cluster import SCHEDULER_TIMEOUT

        self.client = client
        # the timeout the client was made with (distributed keeps it as _timeout)
        given = timeout if timeout is not None else getattr(client, "_timeout", None)
        self.timeout = float(given) if isinstance(given, (int, float)) and given > 0 \
            else SCHEDULER_TIMEOUT
        self.last = time.monotonic()

    def check(self, progressed: bool) -> None:
        now = time.monotonic()
        if progressed or now - self.last < self.timeout:
            self.last = now if progressed else self.last
            return
        address = getattr(self.client.scheduler, "address", "?")
        try:
            self.client.sync(self.client.scheduler.identity, callback_timeout=self.timeout)
        except (TimeoutError, OSError) as err:
            raise MechError(f"the Dask scheduler at {address} stopped answering: no reply "
                            f"within {self.timeout:g} s ({type(err).__name__}); the chunks "
                            "not yet solved are lost (--scheduler-timeout)") from None
        self.last = time.monotonic()


def run_study(study: Study, probe: Kernels, n_variants: int, chunk: int,
              sweep: dict[str, np.ndarray], *, client=None, store: str | None = None,
              progress: Callable[[int, int], None] | None = None) -> Results:
    """Solve the ``n_variants`` variants of ``study`` in chunks of ``chunk``: on the Dask
    ``client``'s cluster if one is given, else here, one chunk after the other. ``probe`` is
    the compiled model of the first chunk, ``sweep`` the whole sweep table (for the chunks
    an interrupt left unsolved). Returns the merged
    results; with ``store`` (a store made by :func:`mechdsl.outputs.store.create_store`),
    each chunk is written there where it was solved, and the results hold no arrays."""
    run = StudyRun(study, chunk_ranges(n_variants, chunk), sweep, store, progress,
                   len(probe.system.times))
    start = time.perf_counter()
    if client is None:
        run.in_process(probe)
    else:
        run.on_cluster(client)
    elapsed = time.perf_counter() - start
    template = next(iter(run.done.values())) if run.done else blank(probe.system)
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
