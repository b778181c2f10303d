"""Design studies: sweeps cut into chunks of variants and solved in this process or on a
Dask cluster (:mod:`.chunks`, :mod:`.run`), written to stores that do not fit in memory
(:mod:`mechdsl.outputs.store`), and the best design found (:mod:`.optimize`)."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

from ..compiled.kernels import Kernels
from ..compiled.variants import Overrides, sweep_table
from ..errors import MechError
from ..memory import resident_bytes, within
from ..results import Results
from ..solve.memory import results_bytes
from ..solve.options import SolverOptions
from .chunks import CHUNK_VARIANTS, Study, default_chunk
from .run import labels_and_units, run_study

__all__ = ["Study", "plan", "solve_sweep"]


def study_of(mech, ov: Overrides, options: SolverOptions | None = None, *,
             poses: bool = False, rates: bool = False) -> Study:
    """The :class:`Study` of a :class:`~mechdsl.api.Mechanism` with overrides: the
    mechanism's portable form (:meth:`~mechdsl.api.Mechanism.portable`: the model and its
    plugins by module name, as the workers build them) is what the study compiles with."""
    return Study(mech.model, ov, options, mech.portable(), poses, rates)


def plan(mech, ov: Overrides, chunk: int | None = None) -> tuple[Kernels, int, int, dict]:
    """How a sweep is cut: the compiled model of its first chunk (the probe, checked as a
    whole run would be), the number of variants, the variants per chunk (``chunk``, or
    :func:`~mechdsl.study.chunks.default_chunk`) and the whole sweep table."""
    try:
        sweep = sweep_table(mech.model, ov)
    except MechError as err:  # located in the model, as compiling it would
        raise err.with_source(mech.model.source) from None
    total = len(next(iter(sweep.values()))) if sweep else 1
    if chunk is not None and chunk < 1:
        raise MechError(f"--chunk {chunk}: give at least 1 variant per chunk")
    first = min(total, chunk or CHUNK_VARIANTS)
    probe = mech.compile(replace(ov, variant_range=(0, first)) if sweep else ov)
    return probe, total, chunk or default_chunk(probe.system, total), sweep


def solve_sweep(mech, ov: Overrides, options: SolverOptions | None = None, *,
                chunk: int | None = None, client=None, store: str | None = None,
                poses: bool = False, rates: bool = False,
                progress: Callable[[int, int], None] | None = None,
                planned: tuple | None = None, extra_memory: int = 0,
                placed: Callable[[str], None] | None = None) -> Results:
    """Solve ``mech`` with overrides ``ov`` chunk by chunk (:mod:`mechdsl.study.run`): on the
    Dask ``client``'s cluster if given, else here; ``planned`` is :func:`plan`'s answer if
    the caller has it, ``extra_memory`` what the caller's drawings of the first chunk's
    variants will take (scaled to all of them). Returns the merged
    :class:`~mechdsl.results.Results` (the same, bit for bit, wherever the chunks ran). With ``store`` (a ``.zarr`` or ``.parquet`` path),
    each chunk is written there where it was solved, and the results returned hold no
    arrays (read them with :func:`mechdsl.outputs.store.open_store`); the store is built
    beside ``store`` and put in place when the run ends, and ``placed`` is called with
    where it went (``store``, or beside it when an interrupted run kept an earlier store:
    :func:`mechdsl.outputs.store.finish_store`)."""
    kernels, total, size, sweep = planned or plan(mech, ov, chunk)
    probe = kernels.system
    study = study_of(mech, ov, options, poses=poses, rates=rates)
    limit = (options or SolverOptions()).max_memory
    if store is None:
        scale = total / probe.n_variants
        if probe.reductions:
            kept = 8 * total * len(probe.reductions)
        else:
            kept = int(results_bytes(probe, poses=poses or rates, rates=rates) * scale)
        try:  # the chunks' results, then their merge: twice the results at the end
            within({"the process so far": resident_bytes(),
                    "the results, merged from the chunks": 2 * kept,
                    "drawings and exports": int(extra_memory * scale)}, limit)
        except MechError as err:
            err.notes = ["write them to a store (-o results.zarr or results.parquet), ask for "
                         "reductions (--reduce), or raise the limit with --max-memory"]
            raise
        return run_study(study, kernels, total, size, sweep, client=client, progress=progress)
    from ..outputs.store import create_store, discard_store, finish_store

    labels, units = labels_and_units(probe)
    work = create_store(store, times=probe.times, labels=labels, sweep=sweep, units=units,
                        time_unit=probe.time_unit, reduced=bool(probe.reductions),
                        chunk_variants=size, source_name=probe.source.name, n_variants=total)
    try:  # the writers fill the store where it is built; the earlier one stays till the end
        results = run_study(study, kernels, total, size, sweep, client=client, store=work,
                            progress=progress)
        where = finish_store(work, status=results.status, messages=results.messages,
                             warnings=results.warnings, solve_time=results.solve_time,
                             residual=results.residual)
    except BaseException:  # an error stopped the run: the earlier store is the last good one
        discard_store(work)
        raise
    if placed is not None:
        placed(where)
    return results
