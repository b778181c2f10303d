"""The CSV of a run's results, and the reader of what it wrote (``mechdsl plot``).

One row per solved instant of each variant; the columns are the swept params, ``t``, then
the outputs (:attr:`~mechdsl.results.Results.header`). A comment line under the header gives
the units, when the results know them (:func:`units_line`). Every number is the shortest
text that reads back to the same double, as Python's ``repr`` writes it. The rows are built
and written a chunk at a time (:meth:`~mechdsl.results.Results.rows`), so that the memory stays bounded whatever
the length of the run.
"""

from __future__ import annotations

import os
import re
import sys
from itertools import repeat
from typing import IO, Iterator, Sequence

import numpy as np

from ..results import Results


#: Values formatted at a time by the CSV writer, and converted at a time by the reader: the
#: text in memory stays bounded (about a megabyte) whatever the length of the run.
CHUNK_VALUES = 2**16


def write_csv(results: Results, target: str | os.PathLike | IO[str]) -> None:
    """Write the results as CSV (see :func:`write_rows`), streaming rows in bounded chunks.
    ``"-"`` writes to standard output (a failure there raises
    :class:`~mechdsl.writing.StdoutError`); a path is written atomically
    (:func:`~mechdsl.writing.write_text`): a reader never sees a half-written file."""
    from ..writing import stdout_errors, write_text

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
    """The CSV of :meth:`~mechdsl.results.Results.table` written into ``f`` a chunk of rows at a time.

    The header names the columns; when the results know a unit, a comment line
    (:func:`units_line`) follows it, and in a table of reductions a comment saying the rows
    are variants (``# one row per variant; swept params: l``). Every number is the shortest text that reads back to
    the same double, as Python's ``repr`` writes it (``0.1``, ``0.30000000000000004``,
    ``2.0``, ``1e-05``, ``nan``, ``inf``, ``-inf``)."""
    header = results.header
    f.write(",".join(header) + "\n")  # first: readers take the first line for the names
    units = units_line(results)
    if units is not None:
        f.write(units + "\n")
    if results.reduced:  # (a comment: numpy and pandas skip it; there is no 't')
        f.write(f"# one row per variant; swept params: {', '.join(results.sweep)}\n")
    # '%r' of a Python float is its repr: the shortest round-tripping digits
    row_format = ",".join(["%r"] * len(header)) + "\n"
    for block in results.rows(max(1, CHUNK_VALUES // max(len(header), 1))):
        f.write((row_format * len(block)) % tuple(block.ravel().tolist()))


def units_line(results: Results) -> str | None:
    """The CSV's comment line giving the unit of each column, in the header's order:
    ``# units: t [s], slider.x [m], slider.vx [m/s]`` (a column without a unit, such as a
    swept param, by its name alone); None when the results know no unit.

    A comment, not units in the header: the columns keep their names (``slider.x``) for
    whoever selects them by name, and readers skip it (numpy's ``loadtxt`` and
    ``genfromtxt`` by default, pandas with ``comment="#"``). In a unit, a comma, a backslash
    and any character that is not printable (a line break) are written ``\\xNN``,
    ``\\uNNNN`` or ``\\UNNNNNNNN``, so that the line stays one line and one field per column."""
    units = {"t": results.time_unit, **{k: results.units.get(k, "") for k in results.labels}}
    if not any(units.values()):
        return None
    return "# units: " + ", ".join(f"{name} [{_escape(units[name])}]" if units.get(name)
                                   else name for name in results.header)


def _escape(unit: str) -> str:
    return "".join(c if c.isprintable() and c not in ",\\" else
                   f"\\x{ord(c):02x}" if ord(c) < 0x100 else
                   f"\\u{ord(c):04x}" if ord(c) < 0x10000 else f"\\U{ord(c):08x}"
                   for c in unit)


_ESCAPE = re.compile(r"\\(?:x([0-9a-fA-F]{2})|u([0-9a-fA-F]{4})|U([0-9a-fA-F]{8}))")
_UNITS = re.compile(r"#\s*units\s*:")
_PER_VARIANT = re.compile(r"#\s*one row per variant; swept params:(.*)")


def _unescape(text: str) -> str:
    def char(m: re.Match) -> str:
        code = int(next(g for g in m.groups() if g), 16)
        return chr(code) if code <= 0x10FFFF else m.group(0)

    return _ESCAPE.sub(char, text)


def read_csv(path: str) -> Results:
    """Read a CSV written by :func:`write_csv` back into Results: the columns before ``t``
    are swept params (one variant per combination of their values, in the order met), the
    columns after it the outputs; the units line, if there is one, gives the units of the
    labels (:attr:`Results.units`, :attr:`Results.time_unit`).

    Blank lines and lines starting with ``#`` are skipped, a byte-order mark and ``\\r\\n``
    line ends are accepted. The file is read as data (:func:`mechdsl.reading.read_data`: a
    regular file of at most :data:`~mechdsl.reading.MAX_DATA_BYTES`); anything else than
    such a CSV is a :class:`~mechdsl.errors.MechError` located at the file, line and column
    at fault, which quotes a few characters of it at most (:func:`~mechdsl.reading.excerpt`).
    """
    from ..reading import read_data

    parsed = _CsvReader(path, read_data(path, ""))
    return parsed.results()


class _CsvReader:
    """The parse of one CSV's bytes: header, units, rows; errors located in it."""

    def __init__(self, path: str, raw: bytes) -> None:
        from ..errors import Source

        self.path = path
        # the source has no text: a message locates the fault and never shows the line
        self.source = Source(path, "")
        text = self._decode(raw)
        self.header: list[str] = []
        self.units: dict[str, str] = {}
        #: the swept params of a table of reductions (one row per variant), else None
        self.swept: list[str] | None = None
        units_at: tuple[int, int, str] | None = None
        blocks: list[np.ndarray] = []
        chunk: list[str] = []
        numbers: list[int] = []
        chunk_rows = 1
        self.checked, self.header_line = False, 0
        for first, piece in _pieces(text):
            lines = piece.split("\n")
            if self.header and "#" not in piece:  # most often nothing but rows: at once
                self._check_header()
                rows = list(map(str.strip, lines))
                if all(rows) and set(map(str.count, rows, repeat(","))) == {len(self.header) - 1}:
                    for i in range(0, len(rows), chunk_rows):
                        blocks.append(self._convert(lines[i:i + chunk_rows], range(first + i,
                                                    first + min(len(rows), i + chunk_rows))))
                    continue
            for number, line in enumerate(lines, first):  # the header, comments, faults
                stripped = line.strip()
                if not stripped:
                    continue
                if stripped.startswith("#"):
                    per_variant = _PER_VARIANT.match(stripped)
                    if per_variant and not numbers and not blocks:  # before the rows
                        self.swept = [n.strip() for n in per_variant.group(1).split(",")
                                      if n.strip()]
                    if _UNITS.match(stripped):
                        if units_at is not None:
                            raise self.error(f"a second units line (the first is line "
                                             f"{units_at[0]})", number)
                        units_at = (number, line.index("#") + 1, line)
                    continue
                if not self.header:
                    self._read_header(line, number)
                    chunk_rows = max(1, CHUNK_VALUES // len(self.header))
                    continue
                self._check_header()
                if line.count(",") != len(self.header) - 1:
                    raise self._ragged(line, number)
                chunk.append(line)
                numbers.append(number)
                if len(chunk) == chunk_rows:
                    blocks.append(self._convert(chunk, numbers))
                    chunk, numbers = [], []
            if chunk:
                blocks.append(self._convert(chunk, numbers))
                chunk, numbers = [], []
        if not self.header:
            what = "the file is empty" if not text.strip() else \
                "nothing but blank lines and comments"
            raise self.error(f"no header: {what} (a CSV written by mechdsl run starts with a "
                             "line naming its columns, 't' among them)")
        self._check_header()
        if units_at is not None:
            self._read_units(*units_at)
        self.rows = np.concatenate(blocks) if blocks else np.empty((0, len(self.header)))
        if not len(self.rows):
            raise self.error("no rows under the header (the run that wrote it solved no "
                             "instant)")

    def error(self, message: str, line: int | None = None, column: int = 1, width: int = 1):
        from ..errors import MechError, Span

        span = Span(line, column, line, column + max(1, width)) if line else None
        return MechError(message, span, self.source)

    def _decode(self, raw: bytes) -> str:
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as err:
            before = raw[: err.start].replace(b"\r\n", b"\n").replace(b"\r", b"\n")
            line = before.count(b"\n") + 1
            column = err.start - (before.rfind(b"\n") + 1) + 1
            raise self.error("not a CSV: the bytes here are not UTF-8 text", line, column) \
                from None
        nul = text.find("\0")
        if nul >= 0:
            before = text[:nul]
            raise self.error("not a CSV: a NUL character (binary data)", before.count("\n") + 1,
                             nul - (before.rfind("\n") + 1) + 1)
        return text[1:] if text.startswith("\ufeff") else text  # a spreadsheet's mark

    def _read_header(self, line: str, number: int) -> None:
        from ..reading import excerpt

        names, column = [], 1
        for j, field in enumerate(line.split(",")):
            name = field.strip()
            at = column + len(field) - len(field.lstrip())
            if not name:
                raise self.error(f"column {j + 1} of the header has no name", number, at)
            if name in names:
                raise self.error(f"column {j + 1} of the header is named {excerpt(name)} as "
                                 f"column {names.index(name) + 1} is", number, at, len(name))
            names.append(name)
            column += len(field) + 1
        self.header, self.header_line = names, number

    def _check_header(self) -> None:
        """The header against what the comments under it say (the rows are variants, and the
        swept params lead), once, before the first row."""
        if self.checked:
            return
        from ..reading import excerpt

        self.checked = True
        names, number = self.header, self.header_line
        if self.swept is not None:
            missing = [s for s in self.swept if s not in names[:len(self.swept)]]
            if missing:
                raise self.error(f"the swept param {excerpt(missing[0])} is not a column "
                                 "before the reductions", number)
        elif "t" not in names:
            raise self.error("the header names no column 't' (a CSV written by mechdsl run "
                             "names the swept params, then 't', then the outputs)", number)

    def _ragged(self, line: str, number: int):
        fields = line.split(",")
        width = len(self.header)
        message = (f"{len(fields)} value{'s' if len(fields) > 1 else ''} where the header "
                   f"names {width} columns")
        if len(fields) < width:  # at the end of the row
            return self.error(message, number, len(line.rstrip()) + 1)
        where = sum(len(f) + 1 for f in fields[:width]) + 1  # at the first value too many
        return self.error(message, number, where, len(line) - where + 1)

    def _convert(self, lines: list[str], numbers: Sequence[int]) -> np.ndarray:
        try:
            values = list(map(float, ",".join(lines).split(",")))
        except ValueError:
            raise self._not_a_number(lines, numbers) from None
        return np.array(values, dtype=float).reshape(len(lines), len(self.header))

    def _not_a_number(self, lines: list[str], numbers: Sequence[int]):
        from ..reading import excerpt

        for line, number in zip(lines, numbers):
            column = 1
            for j, field in enumerate(line.split(",")):
                try:
                    float(field)
                except ValueError:
                    value = field.strip()
                    at = column + (len(field) - len(field.lstrip()) if value else 0)
                    what = f"{excerpt(value)} is not a number" if value else "no number"
                    return self.error(f"{what} in column {j + 1} ({excerpt(self.header[j])})",
                                      number, at, len(value))
                column += len(field) + 1
        return self.error("not a CSV of numbers", numbers[0])  # float() failed somewhere

    def _read_units(self, number: int, start: int, line: str) -> None:
        from ..reading import excerpt

        body_at = _UNITS.match(line, start - 1).end()
        column = body_at + 1
        for piece in line[body_at:].split(","):
            item = piece.strip()
            at = column + len(piece) - len(piece.lstrip())
            column += len(piece) + 1
            if not item:
                continue
            name, bracket, rest = item.partition("[")
            name = name.strip()
            if bracket and not rest.endswith("]"):
                raise self.error(f"the unit of {excerpt(name)} has no closing ']'", number, at,
                                 len(item))
            if name not in self.header:
                raise self.error(f"the units line names {excerpt(name)}, which is no column of "
                                 "the header", number, at, len(name))
            if name in self.units:
                raise self.error(f"the units line gives the unit of {excerpt(name)} twice",
                                 number, at, len(name))
            self.units[name] = _unescape(rest[:-1]) if bracket else ""

    def results(self) -> Results:
        rows, header = self.rows, self.header
        if self.swept is not None:  # a table of reductions
            k = len(self.swept)
            units = {label: self.units[label] for label in header[k:] if self.units.get(label)}
            return Results(times=np.zeros(0), data={},
                           sweep={s: rows[:, j].copy() for j, s in enumerate(self.swept)},
                           reduced={label: rows[:, k + j].copy()
                                    for j, label in enumerate(header[k:])},
                           n_solved=np.zeros(len(rows), dtype=int), status="ok", messages=(),
                           solve_time=0.0, residual=float("nan"), source_name=self.path,
                           units=units, time_unit=self.units.get("t", ""))
        it = header.index("t")
        swept, labels = header[:it], header[it + 1:]
        if it:  # one variant per combination of the swept values, in the order met
            _, first, inverse = np.unique(rows[:, :it], axis=0, return_index=True,
                                          return_inverse=True)
            order = np.argsort(first)
            groups = [rows[inverse.ravel() == g] for g in order]
            params = [rows[first[g], :it] for g in order]
        else:
            groups, params = [rows], [rows[0, :0]]
        longest = max(groups, key=len)
        times = longest[:, it]
        n_solved = np.array([len(g) for g in groups])
        data = {}
        for j, label in enumerate(labels):
            a = np.full((len(groups), len(times)), np.nan)
            for v, g in enumerate(groups):
                a[v, : len(g)] = g[:, it + 1 + j]
            data[label] = a
        sweep = {name: np.array([p[i] for p in params]) for i, name in enumerate(swept)}
        units = {label: self.units[label] for label in labels if self.units.get(label)}
        return Results(times=times, data=data, sweep=sweep, n_solved=n_solved, status="ok",
                       messages=(), solve_time=0.0, residual=float("nan"),
                       source_name=self.path, units=units, time_unit=self.units.get("t", ""))


def _pieces(text: str, size: int = 2**20) -> Iterator[tuple[int, str]]:
    """``text`` in pieces of whole lines, about ``size`` characters each, with the number of
    each piece's first line (from 1): line ends '\\n', '\\r\\n' or '\\r', the last one dropped.
    A piece is split into its lines at once: pieces bound the lines held, whatever the file."""
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    end_of_text = len(text) - 1 if text.endswith("\n") else len(text)
    start, number = 0, 1
    while start < end_of_text:
        end = text.find("\n", min(start + size, end_of_text), end_of_text)
        end = end_of_text if end < 0 else end
        piece = text[start:end]
        yield number, piece
        number += piece.count("\n") + 1
        start = end + 1
