"""Results of a run: arrays keyed by quantity name, how the run ended, and the CSV writer."""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from typing import IO, Iterator, Mapping

import numpy as np


@dataclass(frozen=True)
class Results:
    """Outputs of a run.

    ``data[label]`` has shape ``(V, K)`` (variants, instants); values after a variant's
    ``n_solved[v]`` instants are NaN. ``status`` is ``"ok"``, ``"failed"`` (a numerical
    failure; ``messages`` says where and why), ``"error"`` (a plugin raised while solving;
    ``error`` is the located error naming it) or ``"interrupted"``.
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
    #: With status "error": the located error (a MechError naming the plugin and the joint)
    error: Exception | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def labels(self) -> tuple[str, ...]:
        """The output quantities, in the order requested."""
        return tuple(self.data)

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
        if key not in self.data:
            raise KeyError(f"no output '{key}'; outputs: {', '.join(self.data)}")
        a = self.data[key][:, :last]
        return a[0] if not self.sweep else a

    def __contains__(self, key: str) -> bool:
        return key == "t" or key in self.data or key in self.sweep

    @property
    def header(self) -> list[str]:
        """The CSV's columns: swept params, ``t``, then the outputs."""
        return [*self.sweep, "t", *self.data]

    def row_blocks(self, rows: int | None = None) -> Iterator[np.ndarray]:
        """The CSV's rows (one per solved instant of each variant, columns as
        :attr:`header`) as arrays of at most ``rows`` rows (None: a variant's at once)."""
        ncols = len(self.header)
        for v in range(self.n_variants):
            k = int(self.n_solved[v])
            step = rows or max(k, 1)
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
        """The CSV's header and all its rows as one array (see :meth:`row_blocks`)."""
        blocks = list(self.row_blocks())
        rows = np.concatenate(blocks) if blocks else np.empty((0, len(self.header)))
        return self.header, rows


#: Values formatted at a time by the CSV writer: its memory stays bounded (about a megabyte
#: of text) whatever the length of the run.
CHUNK_VALUES = 2**16


def write_csv(results: Results, target: str | os.PathLike | IO[str]) -> None:
    """Write the results as CSV (17 significant digits), streaming rows in bounded chunks.
    ``"-"`` writes to standard output (a failure there raises
    :class:`~mechdsl.writing.StdoutError`); a path is written atomically
    (:func:`~mechdsl.writing.write_text`): a reader never sees a half-written file."""
    from .writing import stdout_errors, write_text

    if target == "-":
        with stdout_errors():
            write_rows(results, sys.stdout)
            sys.stdout.flush()
        return
    if hasattr(target, "write"):
        write_rows(results, target)  # type: ignore[arg-type]
        return
    write_text(os.fspath(target), lambda f: write_rows(results, f))


def write_rows(results: Results, f: IO[str]) -> None:
    """The CSV of :meth:`Results.table` written into ``f`` a chunk of rows at a time."""
    header = results.header
    f.write(",".join(header) + "\n")
    # the format np.savetxt(fmt="%.17g", delimiter=",") gives each row
    row_format = ",".join(["%.17g"] * len(header)) + "\n"
    for block in results.row_blocks(max(1, CHUNK_VALUES // max(len(header), 1))):
        f.write((row_format * len(block)) % tuple(block.ravel().tolist()))


def read_csv(path: str) -> Results:
    """Read a CSV written by :func:`write_csv` back into Results: the columns before ``t``
    are swept params (one variant per combination of their values, in the order met), the
    columns after it the outputs."""
    from .errors import MechError

    try:
        with open(path, newline="") as f:
            header = f.readline().strip().split(",")
            rows = np.loadtxt(f, delimiter=",", ndmin=2) if header != [""] else None
    except OSError as err:
        raise MechError(f"cannot read {path}: {err.strerror}") from None
    except ValueError as err:
        raise MechError(f"{path}: not a CSV of numbers written by mechdsl run: {err}") from None
    if "t" not in header or rows is None or (rows.size and rows.shape[1] != len(header)):
        raise MechError(f"{path}: not a CSV written by mechdsl run (it needs a column 't' and "
                        "a number in every column)")
    it = header.index("t")
    swept, labels = header[:it], header[it + 1:]
    keys = [tuple(r) for r in rows[:, :it]] if rows.size else []
    variants = list(dict.fromkeys(keys)) or [()]
    groups = [rows[[k == v for k in keys]] if rows.size else rows for v in variants]
    longest = max(groups, key=len)
    times = longest[:, it] if len(longest) else np.zeros(0)
    n_solved = np.array([len(g) for g in groups])
    data = {}
    for j, label in enumerate(labels):
        a = np.full((len(variants), len(times)), np.nan)
        for v, g in enumerate(groups):
            a[v, : len(g)] = g[:, it + 1 + j]
        data[label] = a
    sweep = {name: np.array([v[i] for v in variants]) for i, name in enumerate(swept)}
    return Results(times=times, data=data, sweep=sweep, n_solved=n_solved, status="ok",
                   messages=(), solve_time=0.0, residual=float("nan"), source_name=path)


def summary(results: Results) -> str:
    """A few lines for the terminal: instants, time, residual, range of each output."""
    k = int(results.n_solved.max(initial=0))
    t = results.times
    lines = [
        f"{results.source_name}: {k} of {len(t)} instants (t = {t[0]:g} .. {t[-1]:g})"
        + (f" x {results.n_variants} variants" if results.sweep else "")
        + f", solved in {results.solve_time * 1e3:.1f} ms",
        f"largest constraint residual: {results.residual:.3g}",
    ]
    if results.data:
        width = max(len(label) for label in results.data)
        lines.append(f"{'quantity':<{width}}  {'min':>14}  {'max':>14}")
        for label, a in results.data.items():
            finite = a[np.isfinite(a)]
            lo, hi = (finite.min(), finite.max()) if finite.size else (np.nan, np.nan)
            lines.append(f"{label:<{width}}  {lo:>14.6g}  {hi:>14.6g}")
    return "\n".join(lines)
