"""A sweep cut into chunks of variants: what a worker needs to solve one (:class:`Study`,
plain data that pickles), the cut (:func:`chunk_ranges`, :func:`default_chunk`) and the
merge of the chunks' results in variant order (:func:`merge`).

The cut depends on the model and the sweep only, never on how many processes solve it: a
chunk is solved the same way (the same batch of variants, the same arithmetic) in this
process or on any worker of a cluster, so the merged results are the same bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..compiled.kernels import Kernels
from ..compiled.system import System
from ..compiled.variants import Overrides
from ..grammar import Model
from ..results import Results
from ..solve.options import SolverOptions

#: Variants per chunk, at most, unless the caller chooses
CHUNK_VARIANTS = 1000
#: Bytes a chunk's histories (every output at every instant) may take, unless the caller
#: chooses: what one worker holds at once beyond the model
CHUNK_BYTES = 2**27


@dataclass(frozen=True)
class Study:
    """A sweep to be solved chunk by chunk: the parsed model, the overrides (params, sweeps,
    span), the solver options, and ``compiler``, what compiles the model with its plugins in
    whichever process solves a chunk (the API's :class:`~mechdsl.api.PortableModel`: it
    pickles as the model and the plugins' module names, and each process builds its own
    registry). ``poses``/``rates`` keep the bodies' poses (drawings, exports)."""

    model: Model
    overrides: Overrides
    options: SolverOptions | None = None
    compiler: object = None
    poses: bool = False
    rates: bool = False

    def __post_init__(self) -> None:
        if not callable(getattr(self.compiler, "compile", None)):
            raise TypeError("a Study needs the compiler its API hands it (Mechanism.portable())")

    def kernels(self, start: int, stop: int) -> Kernels:
        """The compiled model of variants ``start`` .. ``stop - 1``."""
        return self.compiler.compile(replace(self.overrides, variant_range=(start, stop)))

    def solve(self, start: int, stop: int, progress=None, kernels: Kernels | None = None
              ) -> Results:
        """Solve variants ``start`` .. ``stop - 1`` (their reductions, if the model asks for
        them): :func:`mechdsl.solve.simulate` on their compiled model (``kernels``, if the
        caller has it already)."""
        from ..solve import simulate

        return simulate(kernels or self.kernels(start, stop), self.options,
                        poses=self.poses or self.rates, rates=self.rates, progress=progress)


def chunk_ranges(n_variants: int, chunk: int) -> list[tuple[int, int]]:
    """[(0, chunk), (chunk, 2 chunk), ..., (.., n_variants)]."""
    return [(a, min(a + chunk, n_variants)) for a in range(0, n_variants, chunk)]


def default_chunk(probe: System, n_variants: int, max_bytes: int = CHUNK_BYTES) -> int:
    """Variants per chunk for a sweep of ``n_variants`` whose compiled model (of any chunk)
    is ``probe``: at most :data:`CHUNK_VARIANTS`, and few enough that a chunk's results and
    coordinates at every instant take at most ``max_bytes``."""
    per_variant = 8 * len(probe.times) * (len(probe.outputs) + 3 * probe.n)
    return int(max(1, min(n_variants, CHUNK_VARIANTS, max_bytes // max(per_variant, 1))))


def empty_like(template: Results, start: int, stop: int, sweep: dict[str, np.ndarray]) -> Results:
    """The results of variants ``start`` .. ``stop - 1`` that were never solved (the run was
    interrupted first): no instant, NaN everywhere."""
    V, K = stop - start, len(template.times)
    return replace(
        template, data={k: np.full((V, K), np.nan) for k in template.data},
        reduced={k: np.full(V, np.nan) for k in template.reduced},
        sweep={k: np.asarray(v)[start:stop] for k, v in sweep.items()},
        n_solved=np.zeros(V, dtype=template.n_solved.dtype), messages=(), warnings=(),
        condition=None if template.condition is None else np.full(V, np.nan),
        poses=None if template.poses is None else np.full((V, *template.poses.shape[1:]), np.nan),
        rates=None if template.rates is None else np.full((V, *template.rates.shape[1:]), np.nan))


def merge(parts: list[Results], solve_time: float | None = None,
          status: str | None = None, warnings: tuple[str, ...] = ()) -> Results:
    """The chunks' results, in variant order, as the results of one run: arrays joined along
    the variants; the status the worst of theirs (interrupted, failed, ok) unless given;
    messages in variant order; warnings each once, then ``warnings``."""
    if len(parts) == 1 and status is None and not warnings:
        return parts[0] if solve_time is None else replace(parts[0], solve_time=solve_time)
    first = parts[0]

    def joined(get):
        arrays = [get(p) for p in parts]
        return None if any(a is None for a in arrays) else np.concatenate(arrays)

    statuses = {p.status for p in parts}
    worst = next((s for s in ("interrupted", "failed") if s in statuses), "ok")
    return replace(
        first,
        data={k: joined(lambda p, k=k: p.data[k]) for k in first.data},
        reduced={k: joined(lambda p, k=k: p.reduced[k]) for k in first.reduced},
        sweep={k: joined(lambda p, k=k: p.sweep[k]) for k in first.sweep},
        n_solved=joined(lambda p: p.n_solved),
        # refined between the samples only where every chunk refined it
        refined=tuple(r for r in first.refined if all(r in p.refined for p in parts)),
        status=status or worst,
        messages=tuple(m for p in parts for m in p.messages),
        warnings=tuple(dict.fromkeys(w for p in parts for w in p.warnings)) + warnings,
        solve_time=sum(p.solve_time for p in parts) if solve_time is None else solve_time,
        residual=max(p.residual for p in parts),
        condition=joined(lambda p: p.condition),
        poses=joined(lambda p: p.poses),
        rates=joined(lambda p: p.rates),
    )
