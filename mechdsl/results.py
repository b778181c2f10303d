"""Results of a run: arrays keyed by quantity name, how the run ended, a summary for the
terminal. What writes them, and reads a CSV back, is in :mod:`mechdsl.outputs`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator, Mapping

import numpy as np


@dataclass(frozen=True)
class Results:
    """Outputs of a run.

    ``data[label]`` has shape ``(V, K)`` (variants, instants); values after a variant's
    ``n_solved[v]`` instants are NaN. ``status`` is ``"ok"``, ``"failed"`` (a numerical
    failure; ``messages`` says where and why) or ``"interrupted"``.
    """

    times: np.ndarray
    data: Mapping[str, np.ndarray]
    sweep: Mapping[str, np.ndarray]
    n_solved: np.ndarray
    status: str
    messages: tuple[str, ...]
    solve_time: float
    residual: float
    source_name: str
    #: Things the user should know although the run succeeded (redundant constraints left
    #: out, a singular position come close to or passed).
    warnings: tuple[str, ...] = ()
    #: Per variant, the largest condition number of the scaled Jacobian met during the run.
    condition: np.ndarray | None = None
    #: (V, K, bodies, 3): every body's (x, y, phi) at every instant, when the run was asked
    #: to keep them (for drawings and exports); NaN after a variant's last solved instant.
    poses: np.ndarray | None = None
    #: (V, K, 2, bodies, 3): their velocities and accelerations, when kept (for exports).
    rates: np.ndarray | None = None
    #: the unit of each output quantity and of time, where the model gives them (labels)
    units: Mapping[str, str] = field(default_factory=dict)
    time_unit: str = ""
    #: per-variant reductions (``output peak = max(abs(slider.ax))``), each (V,): a run
    #: asked for them keeps no histories (``data`` is empty); NaN for a variant that did not
    #: solve every instant
    reduced: Mapping[str, np.ndarray] = field(default_factory=dict)
    #: the reductions whose extremes were found between the samples
    #: (:mod:`mechdsl.solve.extrema`); the others are of the samples
    refined: tuple[str, ...] = ()
    #: forward dynamics: the integrator taken and why (the automatic choice's reason, and
    #: where it switched to the implicit method); empty for the kinematics
    method: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def labels(self) -> tuple[str, ...]:
        """The output quantities (or reductions), in the order requested."""
        return tuple(self.reduced or self.data)

    @property
    def n_variants(self) -> int:
        return len(self.n_solved)

    def __getitem__(self, key: str) -> np.ndarray:
        """``res["t"]``: the solved instants; ``res["slider.x"]``: that quantity, shape
        ``(K,)`` without a sweep and ``(V, K)`` with one; ``res["l"]``: a swept param's
        values ``(V,)``. Arrays end at the last instant solved by any variant."""
        last = int(self.n_solved.max(initial=0))
        if key == "t":
            return self.times[:last]
        if key in self.sweep:
            return np.asarray(self.sweep[key])
        if key in self.reduced:
            a = np.asarray(self.reduced[key])
            return a[0] if not self.sweep else a
        if key not in self.data:
            raise KeyError(f"no output '{key}'; outputs: {', '.join(self.data)}")
        a = self.data[key][:, :last]
        return a[0] if not self.sweep else a

    def __contains__(self, key: str) -> bool:
        return key == "t" or key in self.data or key in self.sweep or key in self.reduced

    @property
    def header(self) -> list[str]:
        """The CSV's columns: swept params, ``t``, then the outputs; for reductions, swept
        params then the reductions (one row per variant)."""
        if self.reduced:
            return [*self.sweep, *self.reduced]
        return [*self.sweep, "t", *self.data]

    def rows(self, size: int | None = None) -> Iterator[np.ndarray]:
        """The table's rows (one per solved instant of each variant, columns as
        :attr:`header`; one per variant for reductions) as arrays of at most ``size`` rows
        (None: a variant's at once): what the CSV writes, a block at a time."""
        ncols = len(self.header)
        if self.reduced:  # one row per variant: the swept params, then the reductions
            step = size or self.n_variants
            for start in range(0, self.n_variants, step):
                stop = min(self.n_variants, start + step)
                block = np.empty((stop - start, ncols))
                for j, column in enumerate((*self.sweep.values(), *self.reduced.values())):
                    block[:, j] = np.asarray(column)[start:stop]
                yield block
            return
        for v in range(self.n_variants):
            k = int(self.n_solved[v])
            step = size or max(k, 1)
            for start in range(0, k, step):
                stop = min(k, start + step)
                block = np.empty((stop - start, ncols))
                for j, s in enumerate(self.sweep):
                    block[:, j] = self.sweep[s][v]
                j = len(self.sweep)
                block[:, j] = self.times[start:stop]
                for i, label in enumerate(self.data, start=j + 1):
                    block[:, i] = self.data[label][v, start:stop]
                yield block

    def table(self) -> tuple[list[str], np.ndarray]:
        """The CSV's header and all its rows as one array (:meth:`rows`)."""
        blocks = list(self.rows())
        rows = np.concatenate(blocks) if blocks else np.empty((0, len(self.header)))
        return self.header, rows


def summary(results: Results) -> str:
    """A few lines for the terminal: instants, time, residual, range of each output with
    its unit."""
    k = int(results.n_solved.max(initial=0))
    t = results.times
    tu = f" {results.time_unit}" if results.time_unit else ""
    lines = [
        f"{results.source_name}: {k} of {len(t)} instants (t = {t[0]:g} .. {t[-1]:g}{tu})"
        + (f" x {results.n_variants} variants" if results.sweep else "")
        + f", solved in {results.solve_time * 1e3:.1f} ms",
        f"largest constraint residual: {results.residual:.3g}",
    ]
    if results.method:
        lines.append(f"integrator: {results.method}")
    if results.reduced:
        sampled = [k for k in results.reduced if k not in results.refined]
        if results.refined:
            lines.append("extremes found between the samples: " + ", ".join(results.refined))
        if sampled:
            lines.append("of the samples: " + ", ".join(sampled))
    columns = results.reduced or results.data
    if columns:
        width = max(len(label) for label in columns)
        over = " over the variants" if results.reduced and results.sweep else ""
        units = results.units
        lines.append(f"{'quantity':<{width}}  {'min':>14}  {'max':>14}"
                     + ("  unit" if any(units.get(k) for k in columns) else "") + over)
        for label, a in columns.items():
            finite = a[np.isfinite(a)]
            lo, hi = (finite.min(), finite.max()) if finite.size else (np.nan, np.nan)
            unit = units.get(label, "")
            lines.append(f"{label:<{width}}  {lo:>14.6g}  {hi:>14.6g}"
                         + (f"  {unit}" if unit else ""))
    return "\n".join(lines)
