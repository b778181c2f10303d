"""Results of large sweeps in a Zarr (v3) group or a Parquet dataset, written a chunk of
variants at a time and read back lazily.

A run is stored in four steps: the coordinator calls :func:`create_store` once (the layout,
the times, the whole sweep table), then :func:`write_chunk` is called for each contiguous
range of variants -- in any process, in any order, retried if need be -- and the coordinator
calls :func:`finish_store` at the end (how the run ended). :func:`open_store` reads it back
as a :class:`StoredResults`.

* Zarr (``*.zarr``): a group with one float64 array per output label, shape ``(V, K)``
  (``(V,)`` for reductions), chunked by ``chunk_variants`` variants and filled with NaN;
  ``t`` (K,), one ``(V,)`` array per swept param, and ``n_solved`` (V,), -1 where no chunk
  was written. Writers only touch the chunks of their own region, never the metadata.
* Parquet (``*.parquet``): a folder holding one file per chunk, ``part-{start:09d}.parquet``,
  in long format (``variant``, the swept params, ``t``, the labels; one row per solved
  instant, as the CSV), and ``_mechdsl.json`` with the metadata, the times and the sweep.

zarr and pyarrow are imported only by the functions that need them.
"""

from __future__ import annotations

import json
import os
import shutil
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import MechError
from ..results import Results

KINDS = ("zarr", "parquet")
MARKER = "mechdsl"
META = "_mechdsl.json"
#: Status of a store whose run has not called :func:`finish_store` (yet, or ever).
UNFINISHED = ("interrupted", ["the run did not finish writing this store"])


def store_kind(path) -> str | None:
    """``"zarr"`` or ``"parquet"`` from the suffix of ``path``, None for any other."""
    suffix = os.path.splitext(os.fspath(path).rstrip("/\\"))[1].lower().lstrip(".")
    return suffix if suffix in KINDS else None


def _kind(path) -> str:
    kind = store_kind(path)
    if kind is None:
        raise MechError(f"'{os.fspath(path)}' is not a result store: its name must end "
                        f"in .zarr or .parquet")
    return kind


def _zarr():
    try:
        import zarr
    except ImportError:
        raise MechError('storing results in Zarr needs zarr: pip install "mechdsl[zarr]"') from None
    return zarr


def _arrow():
    try:
        import pyarrow
        import pyarrow.dataset
        import pyarrow.parquet
    except ImportError:
        raise MechError('storing results in Parquet needs pyarrow: '
                        'pip install "mechdsl[parquet]"') from None
    return pyarrow


def _marker(path: str) -> dict | None:
    """The metadata of the mechdsl store at ``path`` (either kind), None if it is not one.
    Read as plain JSON so that replacing or refusing a folder needs neither library."""
    for name in ("zarr.json", META):
        try:
            with open(os.path.join(path, name), encoding="utf-8") as f:
                meta = json.load(f)
        except (OSError, ValueError):
            continue
        attrs = meta.get("attributes", {}) if name == "zarr.json" else meta
        if isinstance(attrs, dict) and attrs.get(MARKER) == 1:
            return attrs
    return None


def _number(x: float) -> float | str:
    # JSON has no NaN or infinity; a failed run's residual may be either.
    return float(x) if np.isfinite(x) else repr(float(x))


def create_store(path, *, times, labels: Sequence[str], sweep: Mapping[str, Any],
                 units: Mapping[str, str], time_unit: str, reduced: bool,
                 chunk_variants: int, source_name: str, n_variants: int) -> None:
    """Create an empty store at ``path`` for ``n_variants`` variants of ``len(times)``
    instants (one value per variant if ``reduced``), replacing a store this module wrote
    there; any other file or folder at ``path`` is left alone and refused (MechError).

    ``sweep`` is the whole table ``{name: (n_variants,) values}`` (empty without a sweep).
    """
    kind, path = _kind(path), os.fspath(path)
    times = np.asarray(times, dtype=float)
    labels = list(labels)
    sweep = {name: np.asarray(v) for name, v in sweep.items()}
    if chunk_variants < 1 or n_variants < 1:
        raise MechError("a store needs at least one variant, and chunks of at least one")
    if any(v.shape != (n_variants,) for v in sweep.values()):
        raise MechError(f"every swept param needs {n_variants} values")
    names = ["t", "n_solved", "variant", *sweep, *labels]
    if len(set(names)) != len(names):
        raise MechError(f"'{path}': the names of the outputs and swept params must differ "
                        f"from each other and from t, n_solved and variant")
    if os.path.lexists(path):
        if not os.path.isdir(path) or os.path.islink(path) or _marker(path) is None:
            raise MechError(f"'{path}' exists and is not a mechdsl store; "
                            f"remove it or choose another name")
        shutil.rmtree(path)
    meta = {MARKER: 1, "kind": kind, "labels": labels,
            "units": {label: units.get(label, "") for label in labels},
            "time_unit": time_unit, "sweep": list(sweep), "reduced": bool(reduced),
            "source": source_name, "chunk_variants": int(chunk_variants),
            "n_variants": int(n_variants), "status": UNFINISHED[0],
            "messages": UNFINISHED[1], "warnings": [], "solve_time": 0.0,
            "residual": _number(np.nan)}
    if kind == "parquet":
        _arrow()
        os.makedirs(path)
        meta["times"] = times.tolist()
        meta["sweep_values"] = {name: v.tolist() for name, v in sweep.items()}
        _write_json(path, meta)
        return
    zarr = _zarr()
    group = zarr.create_group(store=path, attributes=meta)
    shape = (n_variants,) if reduced else (n_variants, len(times))
    chunks = (chunk_variants,) if reduced else (chunk_variants, max(len(times), 1))
    for label in labels:
        group.create_array(label, shape=shape, chunks=chunks, dtype="float64",
                           fill_value=np.nan, attributes={"unit": meta["units"][label]})
    group.create_array("t", data=times, attributes={"unit": time_unit})
    for name, v in sweep.items():
        group.create_array(name, data=v, chunks=(chunk_variants,))
    group.create_array("n_solved", shape=(n_variants,), chunks=(chunk_variants,),
                       dtype="int64", fill_value=-1)


def _write_json(folder: str, meta: dict) -> None:
    tmp = os.path.join(folder, f".{META}.{os.getpid()}.tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(meta, f)
    os.replace(tmp, os.path.join(folder, META))


def _meta(path) -> dict:
    meta = _marker(os.fspath(path))
    if meta is None:
        raise MechError(f"'{os.fspath(path)}' is not a mechdsl result store")
    return meta


def write_chunk(path, start: int, results: Results) -> None:
    """Write the variants ``[start, start + results.n_variants)`` of the store at ``path``.

    ``start`` and the end of the range must fall on chunk boundaries (or the end on the last
    variant), so that concurrent writers never share a Zarr chunk. Writing a chunk again
    writes it over (a retried task)."""
    path = os.fspath(path)
    meta = _meta(path)
    n, cv, total = results.n_variants, meta["chunk_variants"], meta["n_variants"]
    stop = start + n
    if start < 0 or start % cv or stop > total or (stop % cv and stop != total):
        raise MechError(f"'{path}': variants {start}..{stop} are not a range of whole "
                        f"chunks of {cv} among {total}")
    if list(results.labels) != meta["labels"] or list(results.sweep) != meta["sweep"] \
            or bool(results.reduced) != meta["reduced"]:
        raise MechError(f"'{path}': these results do not have the store's outputs and params")
    values = results.reduced if meta["reduced"] else results.data
    if meta["kind"] == "zarr":
        group = _zarr().open_group(path, mode="r+")
        for label in meta["labels"]:
            group[label][start:stop] = np.asarray(values[label], dtype=float)
        group["n_solved"][start:stop] = np.asarray(results.n_solved, dtype=np.int64)
        return
    pa = _arrow()
    variant = np.arange(start, stop, dtype=np.int64)
    if meta["reduced"]:
        rows = variant - start
        columns = {"variant": variant}
        columns.update({s: np.asarray(results.sweep[s]) for s in meta["sweep"]})
        columns.update({label: np.asarray(values[label], dtype=float) for label in meta["labels"]})
    else:
        solved = np.asarray(results.n_solved, dtype=np.int64)
        rows = np.repeat(np.arange(n), solved)           # the variant of each row, local
        k = np.arange(len(rows)) - np.repeat(np.cumsum(solved) - solved, solved)
        columns = {"variant": variant[rows]}
        columns.update({s: np.asarray(results.sweep[s])[rows] for s in meta["sweep"]})
        columns["t"] = np.asarray(results.times, dtype=float)[k]
        columns.update({label: np.asarray(values[label], dtype=float)[rows, k]
                        for label in meta["labels"]})
    schema = _schema(pa, meta, {s: pa.from_numpy_dtype(c.dtype) for s, c in columns.items()})
    # n_solved rides in the file's metadata: a variant with no solved instant has no row.
    schema = schema.with_metadata({"mechdsl.start": str(start), "mechdsl.n_solved":
                                   json.dumps(np.asarray(results.n_solved).tolist())})
    table = pa.table({name: pa.array(columns[name]) for name in schema.names}, schema=schema)
    final = os.path.join(path, f"part-{start:09d}.parquet")
    # a leading dot: pyarrow.dataset skips the file while it is being written
    tmp = os.path.join(path, f".part-{start:09d}.{os.getpid()}.tmp")
    pa.parquet.write_table(table, tmp)
    os.replace(tmp, final)


def _schema(pa, meta: dict, types: Mapping[str, Any] | None = None):
    """The Parquet files' columns; the params' types from ``types`` (or the sweep table)."""
    types = types or {s: pa.from_numpy_dtype(np.asarray(meta["sweep_values"][s]).dtype)
                      for s in meta["sweep"]}
    fields = [pa.field("variant", pa.int64())]
    fields += [pa.field(s, types[s]) for s in meta["sweep"]]
    if not meta["reduced"]:
        fields.append(pa.field("t", pa.float64(), metadata={"unit": meta["time_unit"]}))
    fields += [pa.field(label, pa.float64(), metadata={"unit": meta["units"][label]})
               for label in meta["labels"]]
    return pa.schema(fields)


def finish_store(path, *, status: str, messages, warnings, solve_time: float,
                 residual: float) -> None:
    """Record how the run ended in the store at ``path`` (once, by the coordinator)."""
    path = os.fspath(path)
    meta = _meta(path)
    end = {"status": status, "messages": list(messages), "warnings": list(warnings),
           "solve_time": float(solve_time), "residual": _number(residual)}
    if meta["kind"] == "zarr":
        _zarr().open_group(path, mode="r+").attrs.update(end)
    else:
        meta.update(end)
        _write_json(path, meta)


def open_store(path) -> "StoredResults":
    """The store at ``path``, read lazily (MechError if there is none)."""
    return StoredResults(path)


class StoredResults:
    """A store read back: metadata at once, the values only when asked for.

    ``res[label]`` is the Zarr array itself (slice it to read) or, for Parquet, the
    ``(V, K)`` (``(V,)`` reduced) numpy array; :meth:`array` reads a selection of variants
    and :meth:`to_results` makes a :class:`~mechdsl.results.Results` of one.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        meta = _meta(self.path)
        self.kind: str = meta["kind"]
        self._dataset = None
        if self.kind == "zarr":
            self._group = _zarr().open_group(self.path, mode="r")
            meta = dict(self._group.attrs)
            self.times = self._group["t"][:]
            self.sweep = {s: self._group[s][:] for s in meta["sweep"]}
        else:
            self._pa = _arrow()
            self.times = np.asarray(meta["times"], dtype=float)
            self.sweep = {s: np.asarray(meta["sweep_values"][s]) for s in meta["sweep"]}
        self.labels: tuple[str, ...] = tuple(meta["labels"])
        self.units: dict[str, str] = dict(meta["units"])
        self.time_unit: str = meta["time_unit"]
        self.reduced: bool = meta["reduced"]
        self.n_variants: int = meta["n_variants"]
        self.chunk_variants: int = meta["chunk_variants"]
        self.source_name: str = meta["source"]
        self.status: str = meta["status"]
        self.messages: tuple[str, ...] = tuple(meta["messages"])
        self.warnings: tuple[str, ...] = tuple(meta["warnings"])
        self.solve_time: float = float(meta["solve_time"])
        self.residual: float = float(meta["residual"])
        self._n_solved: np.ndarray | None = None

    def __contains__(self, label: str) -> bool:
        return label in self.labels

    def __getitem__(self, label: str):
        self._check(label)
        if self.kind == "zarr":
            return self._group[label]
        return self.array(label)

    def _check(self, label: str) -> None:
        if label not in self.labels:
            raise KeyError(f"no output '{label}'; outputs: {', '.join(self.labels)}")

    @property
    def dataset(self):
        """The ``pyarrow.dataset.Dataset`` of a Parquet store (None for Zarr)."""
        if self.kind == "parquet" and self._dataset is None:
            # the schema given: a store with no chunk written yet still has its columns
            self._dataset = self._pa.dataset.dataset(
                self.path, format="parquet", schema=_schema(self._pa, self._meta_json()))
        return self._dataset

    def _meta_json(self) -> dict:
        with open(os.path.join(self.path, META), encoding="utf-8") as f:
            return json.load(f)

    @property
    def n_solved(self) -> np.ndarray:
        """Instants solved per variant, -1 where no chunk was written."""
        if self._n_solved is None:
            if self.kind == "zarr":
                self._n_solved = self._group["n_solved"][:]
            else:
                n = np.full(self.n_variants, -1, dtype=np.int64)
                for fragment in self.dataset.get_fragments():
                    md = self._pa.parquet.read_schema(fragment.path).metadata
                    start = int(md[b"mechdsl.start"])
                    solved = json.loads(md[b"mechdsl.n_solved"])
                    n[start:start + len(solved)] = solved
                self._n_solved = n
        return self._n_solved

    def _indices(self, variants) -> np.ndarray:
        return np.arange(self.n_variants)[slice(None) if variants is None else variants]

    def array(self, label: str, variants=None) -> np.ndarray:
        """``label`` for the ``variants`` (a slice or an index array; all if None) as
        numpy, shape ``(v, K)`` (``(v,)`` reduced), NaN where nothing was solved."""
        self._check(label)
        if self.kind == "zarr":
            a = self._group[label]
            if variants is None:
                return a[:]
            if isinstance(variants, slice) and (variants.step or 1) > 0:
                return a[variants]
            # zarr refuses negative steps: those become indices
            return a.oindex[(np.asarray(self._indices(variants)),)]
        wanted = self._indices(variants)
        ds = self._pa.dataset
        columns = ["variant", label] + ([] if self.reduced else ["t"])
        # filter only when it is a selection: the whole store needs no predicate
        flt = None if variants is None else ds.field("variant").isin(np.unique(wanted))
        table = self.dataset.to_table(columns=columns, filter=flt)
        v = table["variant"].to_numpy()
        x = table[label].to_numpy()
        wanted_sorted = np.unique(wanted)
        rows = np.searchsorted(wanted_sorted, v)
        if self.reduced:
            dense = np.full(len(wanted_sorted), np.nan)
            dense[rows] = x
        else:
            # instant k of a row: its rank among its variant's rows, in time order
            order = np.lexsort((table["t"].to_numpy(), v))
            v, x, rows = v[order], x[order], rows[order]
            k = np.arange(len(v)) - np.searchsorted(v, v)
            dense = np.full((len(wanted_sorted), len(self.times)), np.nan)
            dense[rows, k] = x
        return dense[np.searchsorted(wanted_sorted, wanted)]

    def to_results(self, variants=None) -> Results:
        """The ``variants`` (all if None) as in-memory :class:`~mechdsl.results.Results`;
        a variant never written counts 0 instants solved."""
        idx = self._indices(variants)
        values = {label: self.array(label, variants) for label in self.labels}
        return Results(
            times=self.times, data={} if self.reduced else values,
            sweep={s: v[idx] for s, v in self.sweep.items()},
            n_solved=np.maximum(self.n_solved[idx], 0), status=self.status,
            messages=self.messages, warnings=self.warnings, solve_time=self.solve_time,
            residual=self.residual, source_name=self.source_name, units=dict(self.units),
            time_unit=self.time_unit, reduced=values if self.reduced else {})
