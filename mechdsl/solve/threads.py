"""The BLAS threads of a solve: one, unless the options say otherwise.

A forward-dynamics evaluation calls LAPACK on small matrices thousands of times per second
(the dense saddle-point LU of a small model, the band Cholesky of
:mod:`mechdsl.solve.augmented`); threads started and joined around each call cost more than
the call, and on a machine whose cores are busy with other work a thread that waits for a
core stalls every evaluation. Measured (benchmarks/dynamics.py, OpenBLAS, two cores busy
with other jobs): the dense 485 x 485 solve of IFToMM A02 ran seven times slower with
OpenBLAS's default threads than with one; the augmented Lagrangian's band Cholesky of a
chain of 30 links 14 % slower with two than with one, and no faster for 100 links. So the
dynamics limits BLAS to ``SolverOptions.blas_threads`` threads (1) while it integrates a
model of ``augmented_band_from`` coordinates or more (a smaller one's dense solves, 41 x 41
for Andrews, are below the sizes at which OpenBLAS starts threads, and finding the
libraries to limit costs 2 ms, 4 % of Andrews' run),
through threadpoolctl (the library scikit-learn uses for the same purpose: it finds every
BLAS loaded in the process, numpy's and scipy's alike, and restores their settings after).
"""

from __future__ import annotations

import contextlib
from typing import Iterator


@contextlib.contextmanager
def blas_threads(limit: int) -> Iterator[None]:
    """At most ``limit`` BLAS threads inside the block (0: the library's own setting)."""
    if limit <= 0:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=limit, user_api="blas"):
        yield
