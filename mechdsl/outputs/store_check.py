"""A result store read back as data: what :class:`~mechdsl.outputs.store.StoredResults`
checks before zarr or pyarrow touch a file of it.

A store may come from anywhere (copied, downloaded, unpacked), so opening one must be as
harmless as opening a CSV:

* only regular files are read, found with ``os.lstat`` component by component: a symbolic
  link, a FIFO, a device or a socket inside the store is refused, never followed or opened;
  the files read are the ones the metadata names (Zarr: each array's ``zarr.json`` and the
  chunk keys of its grid; Parquet: ``_mechdsl.json`` and the ``part-*.parquet`` files), at
  most :data:`MAX_STORE_FILES` of them, each within the size its content can have;
* the metadata's types and values are checked before anything is allocated from them, and
  the memory a read needs is compared with the limit before reading (:func:`claim`);
* Zarr arrays must be float64 or int64 with the ``bytes`` codec, optionally followed by
  ``zstd`` whose single frame must declare exactly the chunk's size (a frame that does not
  say, or says more, could expand without bound); no other codec is ever run, so nothing
  is unpickled;
* every defect is a :class:`~mechdsl.errors.MechError` located at the store, and the file
  in it: ``out.zarr/x/c/0/0: error: ...``.
"""

from __future__ import annotations

import json
import math
import os
import stat
from typing import Any, Iterator

from ..errors import MechError, Source, cut
from ..memory import resident_bytes, size_text

#: Files of a store read at most (metadata and chunks): a million variants in chunks of a
#: thousand, a few hundred outputs.
MAX_STORE_FILES = 1_000_000
#: Variants and instants a store may claim at all (the memory check comes after).
MAX_COUNT = 10**15
#: Outputs and swept params of a store, and the characters of one name.
MAX_NAMES = 100_000
MAX_NAME_CHARS = 1000
#: The names a store's arrays, files and columns may not take.
RESERVED = ("t", "n_solved", "variant")
#: What a zarr.json may hold (the keys of a v3 array and group), and its codecs.
ARRAY_KEYS = {"shape", "data_type", "chunk_grid", "chunk_key_encoding", "fill_value",
              "codecs", "attributes", "zarr_format", "node_type", "storage_transformers",
              "dimension_names"}
GROUP_KEYS = {"attributes", "zarr_format", "node_type"}
DTYPES = ("float64", "int64")
_ZSTD_MAGIC = 0xFD2FB528
_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISLNK, "a symbolic link"),
          (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def located(store: str, inner: str | None, message: str) -> MechError:
    """A MechError shown as ``STORE/INNER: error: MESSAGE`` (``STORE: error:`` without
    ``inner``)."""
    name = store if not inner else os.path.join(store, inner)
    return MechError(message, source=Source(name, ""))


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a plain file")


def regular(store: str, inner: str, limit: int, *, missing_ok: bool = False
            ) -> os.stat_result | None:
    """The lstat of the regular file ``inner`` of ``store``, each folder on the way a real
    folder (no link followed), at most ``limit`` bytes; None if absent and ``missing_ok``."""
    parts = inner.split("/")
    path = store
    for i, part in enumerate(parts):
        path = os.path.join(path, part)
        try:
            st = os.lstat(path)
        except FileNotFoundError:
            if missing_ok:
                return None
            raise located(store, inner, "missing: the store is incomplete") from None
        except (OSError, ValueError) as err:
            raise located(store, inner, f"cannot read it: {getattr(err, 'strerror', err)}"
                          ) from None
        last = i == len(parts) - 1
        if not last and not stat.S_ISDIR(st.st_mode):
            raise located(store, "/".join(parts[:i + 1]),
                          f"it is {_kind(st.st_mode)}, where the store has a folder")
    if not stat.S_ISREG(st.st_mode):
        raise located(store, inner, f"it is {_kind(st.st_mode)}, not a regular file; a "
                      "store's metadata and chunks are read only from regular files")
    if st.st_size > limit:
        raise located(store, inner, f"it has {size_text(st.st_size, exact=True)}, more than "
                      f"its content can take ({size_text(limit, exact=True)})")
    return st


def read_json(store: str, inner: str) -> Any:
    """The JSON document ``inner`` of ``store``: a regular file within
    :data:`mechdsl.reading.MAX_DATA_BYTES`, opened without blocking."""
    from .. import reading

    regular(store, inner, reading.MAX_DATA_BYTES)
    try:
        data = reading.read_data(os.path.join(store, inner), "", shown=inner)
    except MechError as err:
        raise located(store, inner, err.message) from None
    try:
        return json.loads(data)
    except RecursionError:
        raise located(store, inner, "its JSON is nested too deeply") from None
    except (ValueError, MemoryError) as err:
        raise located(store, inner, f"it is not valid JSON ({cut(err, 80)})") from None


def claim(store: str, n_variants: int, n_instants: int, outputs: int, need: int, what: str,
          limit: int) -> None:
    """Refuse to read ``what`` (``need`` bytes) if, with the process's present size, it is
    more than ``limit``; the message says what the store claims."""
    held = resident_bytes()
    if held + need <= limit:
        return
    size = 8 * n_variants * max(n_instants, 1) * max(outputs, 1)
    raise located(store, None,
                  f"the store claims {n_variants:,} variants x {n_instants:,} instants "
                  f"x {outputs} outputs = {size_text(size)}; {what} needs about "
                  f"{size_text(need)}, with the {size_text(held)} this process holds more "
                  f"than the memory limit of {size_text(limit)}")


# -----------------------------------------------------------------------------------------
# the metadata


def _int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _name(x) -> bool:
    """A name that is one path component (an array's folder, a column)."""
    return (isinstance(x, str) and 0 < len(x) <= MAX_NAME_CHARS and x not in (".", "..")
            and not any(c in x for c in "/\\\0") and x != "zarr.json")


def check_meta(store: str, inner: str, meta: Any, kind: str | None) -> dict:
    """The metadata of a mechdsl store (the group's attributes, or ``_mechdsl.json``) with
    every key of the right type and value, or a located MechError. ``kind``: the kind the
    store's name says (None: any)."""
    def bad(message: str) -> MechError:
        return located(store, inner, message)

    if not isinstance(meta, dict) or meta.get("mechdsl") != 1 or meta.get("mechdsl") is True:
        raise bad("it is not the metadata of a mechdsl result store")
    for key, test, what in (
            ("kind", lambda x: x in ("zarr", "parquet"), "'zarr' or 'parquet'"),
            ("labels", lambda x: isinstance(x, list) and len(x) <= MAX_NAMES
             and all(map(_name, x)), "a list of output names"),
            ("units", lambda x: isinstance(x, dict)
             and all(isinstance(u, str) for u in x.values()), "an object of unit texts"),
            ("time_unit", lambda x: isinstance(x, str), "a text"),
            ("sweep", lambda x: isinstance(x, list) and len(x) <= MAX_NAMES
             and all(map(_name, x)), "a list of param names"),
            ("reduced", lambda x: isinstance(x, bool), "true or false"),
            ("source", lambda x: isinstance(x, str), "a text"),
            ("chunk_variants", lambda x: _int(x) and 1 <= x <= MAX_COUNT,
             f"a whole number from 1 to {MAX_COUNT:.0e}"),
            ("n_variants", lambda x: _int(x) and 1 <= x <= MAX_COUNT,
             f"a whole number from 1 to {MAX_COUNT:.0e}"),
            ("status", lambda x: isinstance(x, str) and len(x) <= MAX_NAME_CHARS, "a text"),
            ("messages", lambda x: isinstance(x, list) and all(isinstance(m, str) for m in x),
             "a list of texts"),
            ("warnings", lambda x: isinstance(x, list) and all(isinstance(m, str) for m in x),
             "a list of texts"),
            ("solve_time", _number, "a number"),
            ("residual", lambda x: _number(x) or x in ("nan", "inf", "-inf"), "a number")):
        if key not in meta:
            raise bad(f"the metadata has no '{key}'")
        if not test(meta[key]):
            raise bad(f"'{key}' must be {what}")
    if kind is not None and meta["kind"] != kind:
        raise bad(f"it describes a {meta['kind']} store, and the name says {kind}")
    names = [*RESERVED, *meta["sweep"], *meta["labels"]]
    if len(set(names)) != len(names):
        raise bad("the names of the outputs and swept params must be distinct, and not "
                  "t, n_solved or variant")
    if set(meta["units"]) != set(meta["labels"]):
        raise bad("'units' must name exactly the outputs of 'labels'")
    if meta["kind"] == "parquet":
        times, values = meta.get("times"), meta.get("sweep_values")
        if not isinstance(times, list) or not all(map(_number, times)):
            raise bad("'times' must be a list of numbers")
        if len(times) > MAX_COUNT:
            raise bad("'times' is too long")
        if not isinstance(values, dict) or set(values) != set(meta["sweep"]) or not all(
                isinstance(v, list) and all(map(_number, v)) for v in values.values()):
            raise bad("'sweep_values' must hold a list of numbers for each swept param")
    return meta


def check_sizes(store: str, inner: str, meta: dict) -> None:
    """After :func:`claim`: the Parquet metadata's lists have the lengths it claims."""
    if meta["kind"] == "parquet":
        wrong = [s for s, v in meta["sweep_values"].items() if len(v) != meta["n_variants"]]
        if wrong:
            raise located(store, inner, f"'sweep_values' of '{cut(wrong[0])}' has "
                          f"{len(meta['sweep_values'][wrong[0]])} values for "
                          f"{meta['n_variants']} variants")


# -----------------------------------------------------------------------------------------
# Zarr


def zarr_group(store: str, kind: str | None) -> dict:
    """The checked attributes of the Zarr group ``store`` (its ``zarr.json``)."""
    doc = read_json(store, "zarr.json")
    if not isinstance(doc, dict) or doc.get("node_type") != "group" \
            or doc.get("zarr_format") != 3 or not set(doc) <= GROUP_KEYS:
        # consolidated metadata, among others, would let zarr read arrays' metadata from
        # here instead of the files checked below
        raise located(store, "zarr.json", "it is not the zarr.json of a mechdsl store "
                      "(a Zarr v3 group with its attributes only)")
    return check_meta(store, "zarr.json", doc.get("attributes"), kind)


def zarr_array(store: str, name: str, dtype: tuple[str, ...], shape: tuple[int, ...] | None,
               chunks: tuple[int, ...] | None, ndim: int) -> tuple[tuple[int, ...],
                                                                   tuple[int, ...], bool]:
    """Check ``name/zarr.json`` of the Zarr store: an array of ``ndim`` dimensions, of one of
    ``dtype``, with this ``shape`` and ``chunks`` (any, if None), the default chunk keys and
    codecs mechdsl writes. Returns its (shape, chunk shape, zstd-compressed)."""
    inner = f"{name}/zarr.json"
    doc = read_json(store, inner)

    def bad(message: str) -> MechError:
        return located(store, inner, message)

    if not isinstance(doc, dict) or doc.get("node_type") != "array" \
            or doc.get("zarr_format") != 3:
        raise bad("it is not the zarr.json of a Zarr v3 array")
    if not set(doc) <= ARRAY_KEYS:
        raise bad(f"unexpected key '{cut(sorted(set(doc) - ARRAY_KEYS)[0])}'")
    if doc.get("data_type") not in dtype:
        raise bad(f"its data type must be {' or '.join(dtype)}")
    got = doc.get("shape")
    if not isinstance(got, list) or len(got) != ndim or not all(
            _int(n) and 0 <= n <= MAX_COUNT for n in got):
        raise bad(f"its shape must be {ndim} whole numbers")
    grid = doc.get("chunk_grid")
    cs = grid.get("configuration", {}).get("chunk_shape") if isinstance(grid, dict) and \
        grid.get("name") == "regular" and isinstance(grid.get("configuration"), dict) else None
    if not isinstance(cs, list) or len(cs) != ndim or not all(
            _int(n) and 1 <= n <= MAX_COUNT for n in cs):
        raise bad("its chunk grid must be regular, with a chunk shape of whole numbers")
    if shape is not None and tuple(got) != shape:
        raise bad(f"its shape is {tuple(got)}, where the store's metadata gives {shape}")
    if chunks is not None and tuple(cs) != chunks:
        raise bad(f"its chunk shape is {tuple(cs)}, where the store's metadata gives {chunks}")
    if doc.get("chunk_key_encoding") != {"name": "default", "configuration": {"separator": "/"}}:
        raise bad("its chunk keys must be the default ones (c/i/j)")
    if doc.get("storage_transformers", []) != []:
        raise bad("it may have no storage transformer")
    if not isinstance(doc.get("attributes", {}), dict):
        raise bad("its attributes must be an object")
    dims = doc.get("dimension_names")
    if dims is not None and not (isinstance(dims, list) and len(dims) == ndim
                                 and all(d is None or isinstance(d, str) for d in dims)):
        raise bad("its dimension names must be a list of texts")
    fill = doc.get("fill_value")
    if not (_number(fill) or fill in ("NaN", "Infinity", "-Infinity")) or (
            doc["data_type"] == "int64" and not _int(fill)):
        raise bad("its fill value must be a number of its data type")
    zstd = _codecs(doc.get("codecs"), bad)
    return tuple(got), tuple(cs), zstd


def _codecs(codecs, bad) -> bool:
    """Whether the (allowed) codecs end in zstd; ``bad(message)`` makes the error."""
    if not isinstance(codecs, list) or not 1 <= len(codecs) <= 2 or not all(
            isinstance(c, dict) and set(c) <= {"name", "configuration"} for c in codecs):
        raise bad("its codecs must be 'bytes', optionally followed by 'zstd'")
    first = codecs[0]
    if first.get("name") != "bytes" or first.get("configuration", {}) not in (
            {}, {"endian": "little"}, {"endian": "big"}):
        raise bad(f"codec '{cut(first.get('name'))}' is not one mechdsl reads: only 'bytes', "
                  "optionally followed by 'zstd' (no other codec is ever run)")
    if len(codecs) == 1:
        return False
    second = codecs[1]
    conf = second.get("configuration", {})
    if second.get("name") != "zstd" or not isinstance(conf, dict) \
            or not set(conf) <= {"level", "checksum"} \
            or not _int(conf.get("level", 0)) or not isinstance(conf.get("checksum", False), bool):
        raise bad(f"codec '{cut(second.get('name'))}' is not one mechdsl reads: only 'bytes', "
                  "optionally followed by 'zstd' (no other codec is ever run)")
    return True


def chunk_keys(shape: tuple[int, ...], chunks: tuple[int, ...]) -> Iterator[str]:
    """The keys (``c/i/j``) of every chunk of the grid."""
    counts = [max(1, math.ceil(n / c)) if n else 0 for n, c in zip(shape, chunks)]
    if 0 in counts:
        return
    index = [0] * len(counts)
    while True:
        yield "c/" + "/".join(map(str, index))
        for d in reversed(range(len(counts))):
            index[d] += 1
            if index[d] < counts[d]:
                break
            index[d] = 0
        else:
            return


def n_chunks(shape: tuple[int, ...], chunks: tuple[int, ...]) -> int:
    """How many chunks the grid has."""
    return math.prod(math.ceil(n / c) for n, c in zip(shape, chunks))


def zarr_chunks(store: str, name: str, shape: tuple[int, ...], chunks: tuple[int, ...],
                zstd: bool) -> None:
    """Every chunk file of the array ``name`` that exists is a regular file of the size its
    codecs give a chunk (raw: exactly the chunk's bytes; zstd: one frame declaring them)."""
    raw = 8 * math.prod(chunks)
    limit = raw + raw // 128 + 1024 if zstd else raw     # zstd's worst-case expansion
    for key in chunk_keys(shape, chunks):
        inner = f"{name}/{key}"
        st = regular(store, inner, limit, missing_ok=True)
        if st is None:
            continue                                      # never written: the fill value
        if not zstd and st.st_size != raw:
            raise located(store, inner, f"it has {st.st_size:,} bytes where a chunk has "
                          f"{raw:,}")
        if zstd:
            zstd_frame(store, inner, raw)


def zstd_frame(store: str, inner: str, expected: int) -> None:
    """The file ``inner`` is one zstd frame declaring ``expected`` bytes of content (blocks
    walked to its end: nothing after it)."""
    from ..reading import _FLAGS

    def bad(why: str) -> MechError:
        return located(store, inner, f"it is not a chunk of this array ({why})")

    fd = os.open(os.path.join(store, inner), _FLAGS)
    try:
        size = os.fstat(fd).st_size
        head = os.pread(fd, 18, 0)
        if len(head) < 6 or int.from_bytes(head[:4], "little") != _ZSTD_MAGIC:
            raise bad("no zstd frame")
        fhd = head[4]
        fcs_flag, single, checksum, dict_flag = fhd >> 6, fhd >> 5 & 1, fhd >> 2 & 1, fhd & 3
        if fhd & 0x08 or dict_flag:
            raise bad("a zstd frame with a dictionary or reserved bits")
        pos = 5 + (0 if single else 1)
        fcs_size = (1 if single else 0, 2, 4, 8)[fcs_flag]
        if fcs_size == 0:
            raise bad("a zstd frame that does not declare its size")
        if pos + fcs_size > len(head):
            raise bad("a truncated zstd frame")
        content = int.from_bytes(head[pos:pos + fcs_size], "little")
        content += 256 if fcs_size == 2 else 0
        if content != expected:
            raise bad(f"a zstd frame of {content:,} bytes where a chunk has {expected:,}")
        pos += fcs_size
        while True:
            block = os.pread(fd, 3, pos)
            if len(block) < 3:
                raise bad("a truncated zstd frame")
            h = int.from_bytes(block, "little")
            last, btype, bsize = h & 1, h >> 1 & 3, h >> 3
            if btype == 3:
                raise bad("a reserved zstd block type")
            pos += 3 + (1 if btype == 1 else bsize)
            if pos > size:
                raise bad("a truncated zstd frame")
            if last:
                break
        if pos + 4 * checksum != size:
            raise bad("bytes after its zstd frame")
    except OSError as err:
        raise located(store, inner, f"cannot read it: {err.strerror}") from None
    finally:
        os.close(fd)


# -----------------------------------------------------------------------------------------
# Parquet


def parquet_parts(store: str, meta: dict) -> list[tuple[str, int]]:
    """The ``part-*.parquet`` files of the Parquet store (name, first variant), in order,
    each a regular file of a start on a chunk boundary within the store; other names are
    never read."""
    import re

    pattern = re.compile(r"part-(\d{9,18})\.parquet")
    parts, seen = [], 0
    try:
        with os.scandir(store) as entries:
            for entry in entries:
                seen += 1
                if seen > MAX_STORE_FILES:
                    raise located(store, None, f"it holds more than {MAX_STORE_FILES:,} "
                                  "files (mechdsl.outputs.store_check.MAX_STORE_FILES)")
                m = pattern.fullmatch(entry.name)
                if m:
                    parts.append((entry.name, int(m.group(1))))
    except OSError as err:
        raise located(store, None, f"cannot list it: {err.strerror}") from None
    cv, total = meta["chunk_variants"], meta["n_variants"]
    for name, start in parts:
        if start % cv or start >= total:
            raise located(store, name, f"variant {start:,} does not start a chunk of {cv:,} "
                          f"among {total:,}")
    return sorted(parts, key=lambda p: p[1])


def parquet_part(pa, store: str, name: str, start: int, meta: dict, schema) -> list[int]:
    """Check the part file ``name`` (a regular file of at most the bytes its rows can take,
    the store's columns and types, its footer metadata, rows as many as its instants
    solved); its n_solved."""
    cv, total, K = meta["chunk_variants"], meta["n_variants"], len(meta["times"])
    count = min(cv, total - start)
    rows = count if meta["reduced"] else count * max(K, 1)
    raw = 8 * rows * len(schema.names)
    regular(store, name, 3 * raw + 2**20)                  # pages, statistics, footer
    path = os.path.join(store, name)

    def bad(message: str) -> MechError:
        return located(store, name, message)

    try:
        md = pa.parquet.read_metadata(path)
        got = md.schema.to_arrow_schema()
    except (OSError, ValueError, TypeError, RuntimeError, MemoryError, IndexError) as err:
        raise bad(f"it is not a Parquet file mechdsl can read ({cut(err, 120)})") from None
    if got.names != schema.names or any(
            not got.field(n).type.equals(schema.field(n).type) for n in schema.names):
        raise bad("its columns are not the store's: " + ", ".join(
            f"{cut(n)} {got.field(n).type}" for n in got.names[:8]))
    user = got.metadata or {}
    try:
        if int(user[b"mechdsl.start"]) != start:
            raise bad("its mechdsl.start is not the variant of its name")
        solved = json.loads(user[b"mechdsl.n_solved"])
    except (KeyError, ValueError, RecursionError):
        raise bad("its metadata has no valid mechdsl.start and mechdsl.n_solved") from None
    if not isinstance(solved, list) or len(solved) != count or not all(
            _int(n) and 0 <= n <= K for n in solved):
        raise bad(f"its mechdsl.n_solved must be {count} counts from 0 to {K}")
    expected_rows = count if meta["reduced"] else sum(solved)
    if md.num_rows > expected_rows or (not meta["reduced"] and md.num_rows != expected_rows):
        raise bad(f"it has {md.num_rows:,} rows where its variants solved {expected_rows:,} "
                  "instants")
    unpacked = sum(md.row_group(i).column(j).total_uncompressed_size
                   for i in range(md.num_row_groups) for j in range(md.num_columns))
    if unpacked > 3 * raw + 2**20:
        raise bad(f"its pages claim {size_text(unpacked)}, more than its rows can take")
    return solved
