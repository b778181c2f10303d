"""The files a model names, read: the points of its tables and the meshes of its shapes.

The front end only names them (:mod:`mechdsl.grammar` reads no file): a table of a file is
parsed as an :class:`~mechdsl.grammar.expr.Table` without points, a mesh as a
:class:`~mechdsl.grammar.model.MeshFile`. :func:`read_files` gives the model with them read;
:func:`mechdsl.load` calls it, so that a file that cannot be read is a located error at
once, and :func:`mechdsl.compiled.compile.compile_model` makes sure of it.

A table file holds two numbers per line (x, then y), separated by a comma, a semicolon, a
tab or spaces; blank lines, lines starting with ``#`` and one header line are skipped. It is
read as data (:mod:`mechdsl.reading`): a regular file of at most
:data:`~mechdsl.reading.MAX_DATA_BYTES`, quoted in messages by a few characters at most. A
mesh is read by :func:`mechdsl.compiled.shapes.read_mesh`.
"""

from __future__ import annotations

import math
import re
from dataclasses import fields, is_dataclass, replace

from ..errors import MechError, Source, Span, cut
from ..grammar import expr as E
from ..grammar.model import MeshFile, Model
from ..grammar.tables import check_points, one_period
from ..reading import excerpt, read_data
from .shapes import read_mesh

_SEP = re.compile(r"[,;\s]+")


def read_files(model: Model) -> Model:
    """``model`` with the points of every table file and the mesh of every shape file it
    names read (the model itself if it names none, or if they are read already). A file
    that cannot be read is a MechError located where the model names it."""
    if not model.files:
        return model
    try:
        return _Reader().value(model)
    except MechError as err:
        raise err.with_source(model.source) from None


def read_tables(value, source: Source | None = None):
    """An expression, a list of them (a value given on the command line or to the API) or
    :class:`~mechdsl.compiled.variants.Overrides`, with the table files it names read;
    errors are located in ``source``, its text."""
    try:
        return _Reader().value(value)
    except MechError as err:
        raise (err.with_source(source) if source is not None else err) from None


class _Reader:
    """Reads each file once, and rebuilds only what holds a file."""

    def __init__(self) -> None:
        self.tables: dict[tuple[str, float | None], tuple[tuple[float, ...], ...]] = {}

    def value(self, obj):
        """``obj`` (a model, any part of it, an expression) with its files read; the same
        object where it names none."""
        if isinstance(obj, E.NODES):
            if not any(isinstance(n, E.Table) and n.unread for n in E.walk(obj)):
                return obj
            return E.rewrite(obj, self._table)
        if isinstance(obj, MeshFile):
            return read_mesh(obj.name, obj.folder, obj.span)
        if isinstance(obj, (tuple, list)):
            items = [self.value(x) for x in obj]
            if all(a is b for a, b in zip(items, obj)):
                return obj
            return type(obj)(items)
        if isinstance(obj, dict):
            entries = {k: self.value(v) for k, v in obj.items()}
            if all(entries[k] is v for k, v in obj.items()):
                return obj
            return entries
        if is_dataclass(obj) and not isinstance(obj, (type, Source, Span)):
            changed = {}
            for f in fields(obj):
                old = getattr(obj, f.name)
                new = self.value(old)
                if new is not old:
                    changed[f.name] = new
            return replace(obj, **changed) if changed else obj
        return obj

    def _table(self, node: E.Expr) -> E.Expr:
        if not (isinstance(node, E.Table) and node.unread):
            return node
        key = (node.path, node.period)
        if key not in self.tables:
            span = node.data_span
            xs, ys = _read(node.path, cut(node.label[1:-1]), span)
            check_points(xs, ys, span)
            if node.period is not None:
                xs, ys = one_period(xs, ys, node.period, span)
            self.tables[key] = (tuple(xs), tuple(ys))
        xs, ys = self.tables[key]
        return replace(node, xs=xs, ys=ys)


def _read(path: str, shown: str, span: Span) -> tuple[list[float], list[float]]:
    # read as data (a regular file, size-checked); messages show a few characters of the
    # offending field at most, never a line of the file (which may be anybody's file)
    raw = read_data(path, "the table ", "MAX_DATA_BYTES", span, shown=shown)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        before = raw[: err.start].replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        line = before.count(b"\n") + 1
        raise MechError(f"the table {shown} is not UTF-8 text (line {line})", span) from None
    if text.startswith("\ufeff"):  # the byte-order mark spreadsheets write
        text = text[1:]
    xs, ys = [], []
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    for number, line in enumerate(lines, 1):
        row = line.strip()
        if not row or row.startswith("#"):
            continue
        fields_ = [f for f in _SEP.split(row) if f]
        try:
            x, y = float(fields_[0]), float(fields_[1])
        except (ValueError, IndexError):
            if not xs and fields_ and not fields_[0][:1].isdigit():
                continue  # a header line
            raise MechError(f"{shown}:{number}: expected two numbers (x, y), "
                            + _bad_fields(fields_), span) from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise MechError(f"{shown}:{number}: the numbers must be finite", span)
        xs.append(x)
        ys.append(y)
    return xs, ys


def _bad_fields(fields_: list[str]) -> str:
    """What is wrong with the fields of a line, showing the bad one cut short."""
    if len(fields_) < 2:
        return "found one" if fields_ else "found none"
    bad = next(f for f in fields_[:2] if not _is_number(f))
    return f"but {excerpt(bad)} is not a number"


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
