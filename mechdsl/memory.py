"""The memory budget of a run: the process's resident size, the limit it must respect, and
the sum of what each stage says it will need.

``SolverOptions.max_memory`` (``--max-memory``) bounds the peak resident memory of the whole
process. Each stage estimates its own part, and the planner of a run adds them up with
:func:`within`, which refuses the run with the figures when the sum exceeds the limit:

* parsing: :data:`mechdsl.grammar.parser.PARSE_BYTES_PER_BYTE` per byte of the model file;
* compiling: :func:`mechdsl.compiled.compile.check_compile`, the model's arrays;
* solving: :func:`mechdsl.solve.memory.plan`, the results and the solver's work arrays (it
  chooses the largest batch of instants that fits);
* the outputs: each format of :data:`mechdsl.outputs.FORMATS` says what writing it adds
  (:func:`mechdsl.outputs.outputs_bytes` adds them up).

This module knows no stage: the libraries' sizes (:data:`IMPORT_BYTES`) and the process's
resident size are what every estimate shares.
"""

from __future__ import annotations

import contextlib
import gc
import os
from typing import Iterator

from .errors import MechError

BYTES = 8
#: The default limit of a run's resident memory (``SolverOptions.max_memory``).
DEFAULT_MAX_MEMORY = 4 * 2**30
#: Resident size that importing these adds (measured on CPython 3.11, numpy 2, Linux).
IMPORT_BYTES = {"scipy.sparse": 25 * 2**20, "matplotlib": 45 * 2**20, "meshio": 15 * 2**20,
                # numba and LLVM, with one model's march compiled or loaded (measured: 118 MB)
                "numba": 130 * 2**20}


@contextlib.contextmanager
def collection_paused() -> Iterator[None]:
    """Python's cyclic garbage collector paused for a stage that builds many objects and
    frees almost none (parsing, tracing the equations): each collection the allocations
    would set off walks every object built so far, to find no garbage. Measured on the
    300-link chain: parsing and compiling 80 to 120 ms faster. Cycles made meanwhile are
    collected once it is enabled again; a collector already disabled (by the caller) stays
    as it is."""
    if not gc.isenabled():
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.enable()


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
