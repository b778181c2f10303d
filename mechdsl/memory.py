"""The memory a run will need, estimated before it starts, and the limit it must respect.

``SolverOptions.max_memory`` (``--max-memory``) bounds the peak resident memory of the whole
process. Before solving, :func:`plan` adds up what the run will hold at its peak

* what the process already holds (its resident size now: interpreter, libraries, the model);
* the results: every output quantity of every variant at every instant, and the poses and
  rates that drawings and exports need (8 bytes each);
* the solver's work arrays: a batched dense Newton step keeps about ``DENSE_WORK_ARRAYS``
  arrays of the size of the batched Jacobian (V variants x b instants x m x n) alive at once
  (measured with tracemalloc: 6.3 for the assembly, 6 to 7.8 for the march, and RSS up to 9),
  with a margin; a sparse one
  about ``SPARSE_BYTES_PER_NONZERO`` per non-zero of Phi_q (SuperLU's factors included);
* libraries imported later (scipy.sparse, matplotlib, meshio) and what the caller adds for its
  outputs (``extra``: animation frames, export buffers);

and refuses the run, with the figures, when even one instant of all variants at a time does
not fit; otherwise it chooses the largest batch of instants that fits.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .errors import MechError

if TYPE_CHECKING:
    from .compiled.system import System

BYTES = 8
#: Arrays the size of one batched Jacobian alive at the peak of a dense Newton step.
DENSE_WORK_ARRAYS = 10
#: Bytes per non-zero of Phi_q held by one sparse state (values, SuperLU's factors, solves),
#: and per coordinate (state vectors, permutations).
SPARSE_BYTES_PER_NONZERO = 400
SPARSE_BYTES_PER_COORDINATE = 800
#: Memory that parsing can take per byte of a model file, at worst (a file of nothing but
#: tiny expressions: about 480 MB per MB measured; ordinary models take 130).
PARSE_BYTES_PER_BYTE = 500
#: Resident size that importing these adds (measured on CPython 3.11, numpy 2, Linux).
IMPORT_BYTES = {"scipy.sparse": 25 * 2**20, "matplotlib": 45 * 2**20, "meshio": 15 * 2**20,
                # numba and LLVM, with one model's march compiled or loaded (measured: 118 MB)
                "numba": 130 * 2**20}


@dataclass(frozen=True)
class Plan:
    """What the run may use: the cap on V * b * m * n for a dense batch, and the estimate."""

    batch_elements: int
    estimate: int


def resident_bytes() -> int:
    """The resident memory of this process now (Linux: /proc/self/statm; elsewhere the peak
    so far, an upper bound)."""
    try:
        with open("/proc/self/statm", "rb") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError, AttributeError):
        pass
    peak = peak_bytes()
    return 0 if peak is None else peak


def size_text(n: float, exact: bool = False) -> str:
    """``1.5 GiB``, ``320.0 MiB``, ``12.0 KiB``, ``100 bytes``; with ``exact``, the count of
    bytes first: ``52,428,800 bytes (50.0 MiB)``."""
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return (f"{n:,.0f} bytes ({n / scale:.1f} {unit})" if exact
                    else f"{n / scale:.1f} {unit}")
    return f"{n:,.0f} bytes"


def results_bytes(system: System, *, poses: bool, rates: bool) -> int:
    """The arrays of the results: outputs (V, K) each, poses (V, K, n), rates (V, K, 2, n)."""
    V, K, n = system.n_variants, len(system.times), system.n
    per_instant = len(system.outputs) + (n if poses or rates else 0) + (2 * n if rates else 0)
    return BYTES * V * K * (per_instant + 1)


def peak_bytes() -> int | None:
    """The peak resident memory of this process so far (at least its resident memory now:
    one system call where reading /proc costs ten times more); None where unknown."""
    try:
        import resource
        import sys

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak if sys.platform == "darwin" else peak * 1024
    except (ImportError, OSError):
        return None


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
        from .compiled.native import chunk_instants

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


def within(parts: dict[str, int], limit: int) -> int:
    """The sum of ``parts`` (bytes by what needs them); a MechError naming each if it is more
    than ``limit``."""
    total = sum(parts.values())
    if total > limit:
        detail = ", ".join(f"{k} {size_text(v)}" for k, v in parts.items() if v)
        raise MechError(
            f"this run needs about {size_text(total)} of memory ({detail}), more than the "
            f"limit of {size_text(limit)}",
            notes=["raise the limit with --max-memory (e.g. --max-memory 16G) if the machine "
                   "has the memory; or take a longer step, fewer outputs or fewer sweep "
                   "variants"])
    return total


def check_compile(variants: int, values_per_variant: int, limit: int) -> None:
    """Before a model is compiled for ``variants`` sweep variants: its arrays hold about
    ``values_per_variant`` numbers per variant (points, arguments, guesses, params), built
    through one temporary copy each."""
    within({"the process so far": resident_bytes(),
            "the compiled model": 2 * BYTES * variants * values_per_variant}, limit)


#: A matplotlib figure being drawn (canvas, artists, the renderer's buffer), and one frame of
#: an animation as the GIF writer keeps it until the file is written (a 700 x 550 palette
#: image, 0.38 MiB measured, with margin).
FIGURE_BYTES = 20 * 2**20
FRAME_BYTES = 2**19


def outputs_bytes(system: System, *, figures: bool = False, drawing: bool = False,
                  frames: int = 0, frames_kept: bool = True, export: str | None = None) -> int:
    """Memory that writing a run's outputs adds to it: matplotlib and a figure for plots and
    drawings; for a snapshot or an animation (``drawing``) the world coordinates of every
    drawn point of every variant at every instant (with two temporary copies), and the
    frames of an animation (a GIF keeps them all until it is written; an MP4 streams them);
    for an export (``export``, its file name) meshio and the positions, velocities and
    accelerations of every exported point at every instant of one variant (with one
    temporary copy), and for XDMF, whose XML meshio builds whole, about 25 characters per
    number held four times over."""
    total = 0
    sk = system.sketch
    K, V = len(system.times), system.n_variants
    if figures or drawing or frames:
        total += IMPORT_BYTES["matplotlib"] + FIGURE_BYTES
        total += FRAME_BYTES * (frames if frames_kept else 1)
    if drawing:
        drawn = sum(o.shape[1] + 1 for o in sk.outlines) + sum(p.shape[1] for _, p in sk.pins)
        drawn += len(sk.traces) + 2 * len(sk.centrodes) + sum(2 * e.shape[1] for e in sk.shapes if e is not None)
        total += 3 * 2 * BYTES * V * K * drawn
    if export:
        points = sum(2 * o.shape[1] for o in sk.outlines)
        points += sum(4 * e.shape[1] for e in sk.shapes if e is not None)
        total += IMPORT_BYTES["meshio"] + 2 * 9 * BYTES * K * points
        if export.lower().endswith(".xdmf"):
            total += 4 * 25 * 9 * K * points
    return total
