"""Results of large sweeps in a Zarr (v3) group or a Parquet dataset, written a chunk of
variants at a time and read back lazily.

A run is stored in four steps: the coordinator calls :func:`create_store` once (the layout,
the times, the whole sweep table), then :func:`write_chunk` is called for each contiguous
range of variants -- in any process, in any order, retried if need be -- and the coordinator
calls :func:`finish_store` at the end (how the run ended). :func:`open_store` reads it back
as a :class:`StoredResults`.

A store is written like a file: :func:`create_store` builds it in a hidden sibling of its
path (``.out.zarr.mechdsl-PID-HOST-RANDOM``, which it returns and the writers are given) and
:func:`finish_store` puts it in place whole, exchanging the two folders atomically
(``renameat2(RENAME_EXCHANGE)`` on Linux; elsewhere the old one is renamed aside, then the
new one in) and removing the old one after. A run killed at any moment leaves the old store
or the complete new one at the path, never a mix; it may leave its hidden sibling, which the
next run into the same path removes when the process named in it is gone (siblings of
another machine, or of a live process, are left alone). A run interrupted (Ctrl-C,
SIGTERM) keeps everything it solved: at the path if there was no store there, else beside it
as ``out.interrupted.zarr`` (replacing only an earlier mechdsl store of that name), the
earlier results staying at the path.

A store read back is data (:mod:`.store_check`): only regular files, checked metadata,
bounded sizes, no codec but ``bytes`` and ``zstd``; every defect is a located MechError.

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
import re
import shutil
import signal
import sys
import threading
from contextlib import contextmanager
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from ..errors import MechError
from ..results import Results
from . import store_check as check

KINDS = ("zarr", "parquet")
MARKER = "mechdsl"
META = "_mechdsl.json"
#: Status of a store whose run has not called :func:`finish_store` (yet, or ever).
UNFINISHED = ("interrupted", ["the run did not finish writing this store"])
#: The hidden sibling a store is built in: ``.NAME.mechdsl-PID-HOST-RANDOM``.
SIBLING = re.compile(r"\.(?P<name>.+)\.mechdsl-(?P<pid>\d{1,10})-(?P<host>[0-9a-f]{8})"
                     r"-[0-9a-f]{12}")
_AT_FDCWD, _RENAME_EXCHANGE = -100, 2


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
    Read as plain JSON (regular files only, bounded, without blocking) so that replacing or
    refusing a folder needs neither library."""
    from ..reading import read_data

    for name in ("zarr.json", META):
        try:
            if os.path.islink(os.path.join(path, name)):
                continue
            meta = json.loads(read_data(os.path.join(path, name), ""))
        except (MechError, ValueError, RecursionError):
            continue
        attrs = meta.get("attributes", {}) if name == "zarr.json" and isinstance(meta, dict) \
            else meta
        if isinstance(attrs, dict) and attrs.get(MARKER) == 1:
            return attrs
    return None


def _is_store(path: str) -> bool:
    """A real folder (not a link) holding a mechdsl store."""
    return os.path.isdir(path) and not os.path.islink(path) and _marker(path) is not None


def _host() -> str:
    import hashlib
    import socket

    return hashlib.sha1(socket.gethostname().encode("utf-8", "replace")).hexdigest()[:8]


def _sibling(path: str) -> str:
    """A new hidden sibling of ``path`` to build its store in."""
    folder, name = os.path.split(path)
    return os.path.join(folder, f".{name}.mechdsl-{os.getpid()}-{_host()}-"
                                f"{os.urandom(6).hex()}")


def _destination(work: str) -> str | None:
    """The path a store built in the sibling ``work`` is for (None: ``work`` is no
    sibling)."""
    folder, name = os.path.split(work)
    m = SIBLING.fullmatch(name)
    return os.path.join(folder, m.group("name")) if m else None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):  # another user's process; or no such number
        return True
    return True


def _clean_siblings(path: str) -> None:
    """Remove the siblings that runs into ``path`` killed on this machine left (their
    process is gone): a swap interrupted there leaves the old store, already replaced."""
    folder, name = os.path.split(path)
    host = _host()
    try:
        entries = list(os.scandir(folder or "."))
    except OSError:
        return
    for entry in entries:
        m = SIBLING.fullmatch(entry.name)
        if m and m.group("name") == name and m.group("host") == host \
                and entry.is_dir(follow_symlinks=False) and not _alive(int(m.group("pid"))):
            shutil.rmtree(entry.path, ignore_errors=True)


def _number(x: float) -> float | str:
    # JSON has no NaN or infinity; a failed run's residual may be either.
    return float(x) if np.isfinite(x) else repr(float(x))


def create_store(path, *, times, labels: Sequence[str], sweep: Mapping[str, Any],
                 units: Mapping[str, str], time_unit: str, reduced: bool,
                 chunk_variants: int, source_name: str, n_variants: int) -> str:
    """Create an empty store for ``path`` for ``n_variants`` variants of ``len(times)``
    instants (one value per variant if ``reduced``), in a hidden sibling of ``path`` whose
    path is returned: give it to :func:`write_chunk` and :func:`finish_store`, which puts it
    at ``path`` (replacing a store this module wrote there). Any other file or folder at
    ``path`` is left alone and refused now (MechError).

    ``sweep`` is the whole table ``{name: (n_variants,) values}`` (empty without a sweep).
    """
    kind, path = _kind(path), os.fspath(path)
    path = path.rstrip("/\\") or path
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
    if os.path.lexists(path) and not _is_store(path):
        raise MechError(f"'{path}' exists and is not a mechdsl store; "
                        f"remove it or choose another name")
    _clean_siblings(path)
    work = _sibling(path)
    try:
        # a Ctrl-C inside zarr's writes would leave its writer thread filling the folder
        # being removed: the layout is written whole, the signal acted on after
        with _signals_held():
            _build(work, kind, times, labels, sweep, units, time_unit, reduced,
                   chunk_variants, source_name, n_variants)
    except BaseException:
        discard_store(work)
        raise
    return work


def _build(path: str, kind: str, times: np.ndarray, labels: list[str],
           sweep: dict[str, np.ndarray], units: Mapping[str, str], time_unit: str,
           reduced: bool, chunk_variants: int, source_name: str, n_variants: int) -> None:
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
    if os.path.lexists(path):
        raise MechError(f"'{path}' exists")
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
    writes it over (a retried task). SIGINT and SIGTERM wait until the chunk is written:
    interrupted, zarr's writer thread would go on writing, into a store already put in
    place, and the values could be there without their n_solved."""
    with _signals_held():
        _write_chunk(os.fspath(path), start, results)


def _write_chunk(path: str, start: int, results: Results) -> None:
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
                 residual: float) -> str:
    """Record how the run ended in the store ``path`` that :func:`create_store` returned,
    then put it in place (once, by the coordinator); returns where it is.

    Complete runs (``status`` "ok" or "failed") replace the earlier store at its path, whole.
    An interrupted one goes to the path if no store is there; else beside it
    (:func:`interrupted_path`), the earlier store staying, and its messages say so. SIGINT
    and SIGTERM are held back while the folders are exchanged."""
    with _signals_held():
        return _finish(os.fspath(path), status, list(messages), list(warnings),
                       float(solve_time), residual)


def _finish(path: str, status: str, messages: list[str], warnings: list[str],
            solve_time: float, residual: float) -> str:
    meta = _meta(path)
    final = _destination(path)
    if final is not None and status == UNFINISHED[0] and os.path.lexists(final):
        messages.append(f"this run was interrupted; {final} keeps the earlier run's results")
    end = {"status": status, "messages": messages, "warnings": warnings,
           "solve_time": solve_time, "residual": _number(residual)}
    if meta["kind"] == "zarr":
        _zarr().open_group(path, mode="r+").attrs.update(end)
    else:
        meta.update(end)
        _write_json(path, meta)
    return path if final is None else _place(path, final, status)


def interrupted_path(path) -> str:
    """Where an interrupted run puts its store when an earlier one is at ``path``:
    ``out.zarr`` -> ``out.interrupted.zarr``."""
    root, ext = os.path.splitext(os.fspath(path))
    return f"{root}.interrupted{ext}"


def discard_store(path) -> None:
    """Remove the unfinished store ``path`` that :func:`create_store` returned (a run that
    failed before finishing it), if it is still there and is a hidden sibling."""
    path = os.fspath(path)
    if _destination(path) is not None and os.path.isdir(path) and not os.path.islink(path):
        shutil.rmtree(path, ignore_errors=True)


def _place(work: str, final: str, status: str) -> str:
    """Put the finished store ``work`` at ``final`` (or beside it, for an interrupted run
    that would replace a store); returns where it is."""
    if not os.path.lexists(final):
        _rename(work, final)
        return final
    if not _is_store(final):
        raise MechError(f"'{final}' was replaced during the run by something that is not a "
                        f"mechdsl store; this run's results are in '{work}'")
    target = final
    if status == UNFINISHED[0]:
        candidates = [interrupted_path(final)] + [
            interrupted_path(f"{os.path.splitext(final)[0]}-{i}{os.path.splitext(final)[1]}")
            for i in range(2, 10)]
        free = [c for c in candidates if not os.path.lexists(c) or _is_store(c)]
        if not free:
            return work
        target = free[0]
        if not os.path.lexists(target):
            _rename(work, target)
            return target
    old = _exchange(work, target)
    shutil.rmtree(old, ignore_errors=True)
    return target


def _rename(src: str, dst: str) -> None:
    """Rename the folder ``src`` to ``dst``, which must not exist (an empty folder created in
    between would be replaced by os.rename: refused instead)."""
    if os.path.lexists(dst):
        raise MechError(f"'{dst}' appeared during the run; this run's results are in '{src}'")
    os.rename(src, dst)


def _exchange(work: str, final: str) -> str:
    """Swap the folders ``work`` and ``final`` atomically where the system can (Linux's
    renameat2), else rename ``final`` aside and ``work`` in; returns where the old store
    now is."""
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            libc = ctypes.CDLL(None, use_errno=True)
            renameat2 = libc.renameat2
        except (OSError, AttributeError):  # no libc found, or one before glibc 2.28
            renameat2 = None
        if renameat2 is not None:
            renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int,
                                  ctypes.c_char_p, ctypes.c_uint]
            renameat2.restype = ctypes.c_int
            if renameat2(_AT_FDCWD, os.fsencode(work), _AT_FDCWD, os.fsencode(final),
                         _RENAME_EXCHANGE) == 0:
                return work
            import errno

            err = ctypes.get_errno()
            # the file system or kernel cannot exchange: fall back; any other error is real
            if err not in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
                raise OSError(err, os.strerror(err), final)
    old = f"{work}.old"           # not a sibling's name: never cleaned up by another run
    os.rename(final, old)
    try:
        os.rename(work, final)
    except BaseException:
        os.rename(old, final)
        raise
    return old


@contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM blocked (delivered after) while a store is put in place, so that
    a second Ctrl-C cannot leave the old one half removed."""
    held = {signal.SIGINT, signal.SIGTERM}
    if not hasattr(signal, "pthread_sigmask") or \
            threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def open_store(path, max_memory: int | None = None) -> "StoredResults":
    """The store at ``path``, read lazily (a located MechError if there is none, or if it is
    not one mechdsl can read: see :mod:`.store_check`); ``max_memory`` bounds what a read
    may take (default: the solver's default limit)."""
    return StoredResults(path, max_memory)


class StoredResults:
    """A store read back: metadata at once, the values only when asked for.

    ``res[label]`` is the Zarr array itself (slice it to read) or, for Parquet, the
    ``(V, K)`` (``(V,)`` reduced) numpy array; :meth:`array` reads a selection of variants
    and :meth:`to_results` makes a :class:`~mechdsl.results.Results` of one.

    Everything is checked before it is read (:mod:`.store_check`): a store that is not one
    mechdsl wrote, or was damaged since, ends in a MechError located at the store and its
    file, never in an error of zarr or pyarrow.
    """

    def __init__(self, path, max_memory: int | None = None):
        self.path = os.fspath(path)
        if max_memory is None:
            from ..memory import DEFAULT_MAX_MEMORY

            max_memory = DEFAULT_MAX_MEMORY
        self.max_memory = max_memory
        with self._reading("opening it"):
            self._open()

    def _open(self) -> None:
        path, kind = self.path, store_kind(self.path)
        try:
            st = os.stat(path)
        except (OSError, ValueError) as err:
            raise check.located(path, None, f"cannot open the store: "
                                f"{getattr(err, 'strerror', None) or err}") from None
        if not os.path.isdir(path) or not (
                os.path.lexists(os.path.join(path, "zarr.json"))
                or os.path.lexists(os.path.join(path, META))):
            what = "a folder" if os.path.isdir(path) else check._kind(st.st_mode)
            raise check.located(path, None, f"it is {what} without a zarr.json or {META}: "
                                "not a mechdsl result store")
        if os.path.lexists(os.path.join(path, "zarr.json")) or kind == "zarr":
            inner, meta = "zarr.json", check.zarr_group(path, kind)
        else:
            inner, meta = META, check.check_meta(path, META, check.read_json(path, META), kind)
        self.kind: str = meta["kind"]
        V, cv, reduced = meta["n_variants"], meta["chunk_variants"], meta["reduced"]
        self._parts: list[tuple[str, int, list[int]]] = []
        if self.kind == "zarr":
            (K,), t_chunks, t_zstd = check.zarr_array(path, "t", ("float64",), None, None, 1)
        else:
            K = len(meta["times"])
        self._claim(V, K, len(meta["labels"]), 8 * V * (len(meta["sweep"]) + 2) + 8 * K,
                    "reading its sweep table and solved counts")
        check.check_sizes(path, inner, meta)
        if self.kind == "zarr":
            arrays = [("t", ("float64",), (K,), t_chunks, t_zstd)]
            for name, dtypes, shape, chunks in (
                    [("n_solved", ("int64",), (V,), (cv,))]
                    + [(s, check.DTYPES, (V,), (cv,)) for s in meta["sweep"]]
                    + [(label, ("float64",), (V,) if reduced else (V, K),
                        (cv,) if reduced else (cv, max(K, 1))) for label in meta["labels"]]):
                arrays.append((name, dtypes, shape, chunks,
                               check.zarr_array(path, name, dtypes, shape, chunks,
                                                len(shape))[2]))
            files = sum(check.n_chunks(a[2], a[3]) for a in arrays)
            if files > check.MAX_STORE_FILES:
                raise check.located(path, None, f"its arrays have {files:,} chunks, more than "
                                    f"{check.MAX_STORE_FILES:,} (mechdsl.outputs.store_check"
                                    ".MAX_STORE_FILES)")
            for name, _, shape, chunks, zstd in arrays:
                check.zarr_chunks(path, name, shape, chunks, zstd)
            self._group = _zarr().open_group(path, mode="r", zarr_format=3,
                                             use_consolidated=False)
            self.times = np.asarray(self._group["t"][:], dtype=float)
            self.sweep = {s: self._group[s][:] for s in meta["sweep"]}
        else:
            self._pa = _arrow()
            self.times = np.asarray(meta["times"], dtype=float)
            self.sweep = {s: np.asarray(meta["sweep_values"][s]) for s in meta["sweep"]}
            self._schema = _schema(self._pa, meta)
            self._parts = [(name, start, check.parquet_part(self._pa, path, name, start, meta,
                                                            self._schema))
                           for name, start in check.parquet_parts(path, meta)]
        self._dataset = None
        self.labels: tuple[str, ...] = tuple(meta["labels"])
        self.units: dict[str, str] = dict(meta["units"])
        self.time_unit: str = meta["time_unit"]
        self.reduced: bool = meta["reduced"]
        self.n_variants: int = V
        self.chunk_variants: int = cv
        self.source_name: str = meta["source"]
        self.status: str = meta["status"]
        self.messages: tuple[str, ...] = tuple(meta["messages"])
        self.warnings: tuple[str, ...] = tuple(meta["warnings"])
        self.solve_time: float = float(meta["solve_time"])
        self.residual: float = float(meta["residual"])
        self._n_solved: np.ndarray | None = None

    @contextmanager
    def _reading(self, what: str) -> Iterator[None]:
        """The libraries' own errors, after the checks, as errors located at the store:
        a last resort, for damage the checks cannot see (a chunk's compressed bytes)."""
        try:
            yield
        except MechError:
            raise
        except MemoryError:
            raise check.located(self.path, None, f"{what} ran out of memory (the store's "
                                "data are not what its metadata claims)") from None
        # zarr, numcodecs, pyarrow, json and numpy raise these (zarr's and pyarrow's errors
        # derive from them); a KeyboardInterrupt or a bug's SystemExit goes through
        except (OSError, ValueError, TypeError, KeyError, IndexError, RuntimeError,
                ArithmeticError, AttributeError, AssertionError) as err:
            raise check.located(self.path, None, f"{what} failed: the store is damaged "
                                f"({type(err).__name__}: {check.cut(err, 200)})") from None

    def _claim(self, V: int, K: int, outputs: int, need: int, what: str) -> None:
        check.claim(self.path, V, K, outputs, need, what, self.max_memory)

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
        """The ``pyarrow.dataset.Dataset`` of a Parquet store (None for Zarr): its checked
        part files only."""
        if self.kind == "parquet" and self._dataset is None:
            # the schema given: a store with no chunk written yet still has its columns
            with self._reading("reading its Parquet files"):
                self._dataset = self._pa.dataset.dataset(
                    [os.path.join(self.path, name) for name, _, _ in self._parts],
                    format="parquet", schema=self._schema)
        return self._dataset

    @property
    def n_solved(self) -> np.ndarray:
        """Instants solved per variant, -1 where no chunk was written."""
        if self._n_solved is None:
            K = len(self.times)
            if self.kind == "zarr":
                with self._reading("reading n_solved"):
                    n = np.asarray(self._group["n_solved"][:], dtype=np.int64)
                if n.shape != (self.n_variants,) or ((n < -1) | (n > K)).any():
                    raise check.located(self.path, "n_solved",
                                        f"its counts must be from -1 to {K}")
            else:
                n = np.full(self.n_variants, -1, dtype=np.int64)
                for _, start, solved in self._parts:
                    n[start:start + len(solved)] = solved
            self._n_solved = n
        return self._n_solved

    def _indices(self, variants) -> np.ndarray:
        try:
            return np.arange(self.n_variants)[slice(None) if variants is None else variants]
        except IndexError as err:
            raise IndexError(f"{self.path}: {err}") from None

    def array(self, label: str, variants=None) -> np.ndarray:
        """``label`` for the ``variants`` (a slice or an index array; all if None) as
        numpy, shape ``(v, K)`` (``(v,)`` reduced), NaN where nothing was solved."""
        self._check(label)
        wanted = self._indices(variants)
        K = len(self.times)
        per_value = 8 if self.kind == "zarr" else 40     # the table's columns, sorted, dense
        self._claim(self.n_variants, K, len(self.labels),
                    per_value * len(wanted) * (1 if self.reduced else max(K, 1)),
                    f"reading {len(wanted):,} variants of '{check.cut(label)}'")
        with self._reading(f"reading '{check.cut(label)}'"):
            if self.kind == "zarr":
                return self._zarr_array(label, variants, wanted)
            return self._parquet_array(label, variants, wanted)

    def _zarr_array(self, label: str, variants, wanted: np.ndarray) -> np.ndarray:
        a = self._group[label]
        if variants is None:
            return a[:]
        if isinstance(variants, slice) and (variants.step or 1) > 0:
            return a[variants]
        # zarr refuses negative steps: those become indices
        return a.oindex[(np.asarray(wanted),)]

    def _parquet_array(self, label: str, variants, wanted: np.ndarray) -> np.ndarray:
        ds = self._pa.dataset
        columns = ["variant", label] + ([] if self.reduced else ["t"])
        # filter only when it is a selection: the whole store needs no predicate
        flt = None if variants is None else ds.field("variant").isin(np.unique(wanted))
        table = self.dataset.to_table(columns=columns, filter=flt)
        v = np.asarray(table["variant"].to_numpy(zero_copy_only=False))
        x = np.asarray(table[label].to_numpy(zero_copy_only=False), dtype=float)
        wanted_sorted = np.unique(wanted)
        rows = np.searchsorted(wanted_sorted, v)
        inside = rows < len(wanted_sorted)
        if not (inside.all() and np.array_equal(wanted_sorted[rows[inside]], v)):
            raise check.located(self.path, None, "a part file has rows of variants that are "
                                "not in its range")
        if self.reduced:
            dense = np.full(len(wanted_sorted), np.nan)
            dense[rows] = x
        else:
            # instant k of a row: its rank among its variant's rows, in time order
            order = np.lexsort((np.asarray(table["t"].to_numpy(zero_copy_only=False)), v))
            v, x, rows = v[order], x[order], rows[order]
            k = np.arange(len(v)) - np.searchsorted(v, v)
            if len(k) and k.max() >= len(self.times):
                raise check.located(self.path, None, "a variant has more rows than the "
                                    "store has instants")
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
