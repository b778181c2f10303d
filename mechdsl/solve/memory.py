"""The memory a run's solver will need, estimated before it starts, within the limit of
``SolverOptions.max_memory`` (``--max-memory``: the peak resident memory of the whole
process; the budget and the sum are :mod:`mechdsl.memory`'s). :func:`plan` adds up what the
run will hold at its peak:

* what the process already holds (its resident size now: interpreter, libraries, the model);
* the results: every output quantity of every variant at every instant, and the poses and
  rates that drawings and exports need (8 bytes each);
* the solver's work arrays: a batched dense Newton step keeps about ``DENSE_WORK_ARRAYS``
  arrays of the size of the batched Jacobian (V variants x b instants x m x n) alive at once
  (measured with tracemalloc: 6.3 for the assembly, 6 to 7.8 for the march, and RSS up to 9),
  with a margin; a sparse one about ``SPARSE_BYTES_PER_NONZERO`` per non-zero of Phi_q
  (SuperLU's factors included);
* libraries imported later (scipy.sparse, numba) and what the caller adds for its outputs
  (``extra``: :func:`mechdsl.outputs.outputs_bytes`, the formats' own estimates);

and refuses the run, with the figures, when even one instant of all variants at a time does
not fit; otherwise it chooses the largest batch of instants that fits.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..compiled.system import System
from ..errors import MechError
from ..memory import BYTES, IMPORT_BYTES, peak_bytes, resident_bytes, within

#: Arrays the size of one batched Jacobian alive at the peak of a dense Newton step.
DENSE_WORK_ARRAYS = 10
#: Bytes per non-zero of Phi_q held by one sparse state (values, SuperLU's factors, solves),
#: and per coordinate (state vectors, permutations).
SPARSE_BYTES_PER_NONZERO = 400
SPARSE_BYTES_PER_COORDINATE = 800


@dataclass(frozen=True)
class Plan:
    """What the run may use: the cap on V * b * m * n for a dense batch, and the estimate."""

    batch_elements: int
    estimate: int


def results_bytes(system: System, *, poses: bool, rates: bool) -> int:
    """The arrays of the results: outputs (V, K) each, poses (V, K, n), rates (V, K, 2, n)."""
    V, K, n = system.n_variants, len(system.times), system.n
    per_instant = len(system.outputs) + (n if poses or rates else 0) + (2 * n if rates else 0)
    return BYTES * V * K * (per_instant + 1)


def plan(system: System, limit: int, max_batch_elements: int, *, sparse: bool,
         poses: bool = False, rates: bool = False, extra: int = 0,
         compiled: bool = False) -> Plan:
    """The batch cap for a run of ``system`` within ``limit`` bytes of resident memory, or a
    MechError with the estimate when it does not fit (see the module's docstring). The
    process's peak so far stands for its present size where the run fits beside it with
    the full batch cap; else the present size is read."""
    args = (system, limit, max_batch_elements, sparse, poses, rates, extra, compiled)
    peak = peak_bytes()
    if peak is not None:
        try:
            upper = _plan(peak, *args)
        except MechError:
            pass
        else:
            if upper.batch_elements == max_batch_elements:
                return upper
    return _plan(resident_bytes(), *args)


def _plan(so_far: int, system: System, limit: int, max_batch_elements: int, sparse: bool,
          poses: bool, rates: bool, extra: int, compiled: bool) -> Plan:
    V, m, n = system.n_variants, system.m, system.n
    parts = {"the process so far": so_far,
             "the results": results_bytes(system, poses=poses, rates=rates),
             "libraries to load": IMPORT_BYTES["scipy.sparse"] if sparse else 0,
             "drawings and exports": extra}
    if compiled:  # numba, and a chunk of the compiled march's states, rates and conditions
        from ..compiled.native import chunk_instants

        instants = min(len(system.times), chunk_instants(V) + 1)
        parts["the compiled backend"] = (IMPORT_BYTES["numba"]
                                         + BYTES * V * instants * (3 * n + 6))
    fixed = sum(parts.values())
    if sparse:
        nnz = len(system.pattern.rows) if system.pattern is not None else m * n
        parts["the solver"] = V * (SPARSE_BYTES_PER_NONZERO * nnz
                                   + SPARSE_BYTES_PER_COORDINATE * n)
        cap = max_batch_elements
    else:
        one_instant = V * m * n
        room = (limit - fixed) // (BYTES * DENSE_WORK_ARRAYS)
        cap = int(min(max_batch_elements, max(room, one_instant)))
        parts["the solver"] = BYTES * DENSE_WORK_ARRAYS * max(one_instant, min(
            cap, one_instant * len(system.times)))
    try:
        return Plan(cap, within(parts, limit))
    except MechError as err:
        raise err.with_source(system.source) from None
