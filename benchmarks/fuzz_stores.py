"""Fuzz the reading of result stores: every hostile store given to ``mechdsl plot`` must end
in a drawing (exit 0) or a located user error (exit 1, first line ``STORE...: error: ...``)
-- never an internal error, a traceback or a hang -- and must run nothing.

    python benchmarks/fuzz_stores.py --inputs 3000
    python benchmarks/fuzz_stores.py --seed 0 --replay 1234      # one input again, described

:func:`hostile_store` builds a store with the real writer (Zarr or Parquet, 1-6 variants,
1-6 instants, 1-3 outputs, reduced or not, 0-2 swept params, some chunks never written),
then corrupts it 1-3 times: JSON metadata with keys removed, values of the wrong type,
huge claims (10**12 variants, shapes, chunk shapes), deep nesting, codecs that would
unpickle or are unknown, object dtypes; bytes of a chunk or of metadata flipped, truncated,
appended or replaced; a file replaced by a link (to /dev/zero, /dev/urandom, another file of
the store, a folder, nowhere), a FIFO, a folder or a sparse file of a terabyte; Parquet parts
rewritten with garbage footer metadata or other columns; files removed; files, folders and
links added. Each input runs in-process (``mechdsl.cli.main(["plot", STORE, "-o", OUT])``)
with a time bound (SIGALRM), as :func:`benchmarks.fuzz._status` runs its inputs; outcomes
are ``ok`` (0), ``located`` (1, located at the store) and the defects ``internal`` (another
status), ``traceback`` (in the messages), ``unlocated`` (exit 1 without the store's name
first), ``hang``, ``unpickled`` (a planted pickle ran) and ``harness``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import pickle
import random
import re
import resource
import shutil
import signal
import stat
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

#: defects, in the order one names an input that shows several
DEFECTS = ("hang", "internal", "traceback", "unlocated", "unpickled", "harness")
#: the file a planted pickle creates if anything unpickles it
MARKER = "UNPICKLED"
HUGE = [10**12, 10**18, 2**63, 10**30, -1, 0, 2**31, 1e300, float("nan")]


class Hang(BaseException):
    """The time bound passed (a BaseException: the command's handlers must not catch it)."""


def _alarm(signum, frame):
    raise Hang()


class _Planted:
    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


# -----------------------------------------------------------------------------------------
# a valid store, then corrupted


def _valid(rng: random.Random, folder: str) -> str:
    import numpy as np

    from mechdsl.outputs.store import create_store, finish_store, write_chunk
    from mechdsl.results import Results

    kind = rng.choice(["zarr", "parquet"])
    path = os.path.join(folder, f"store.{kind}")
    V, K, cv = rng.randint(1, 6), rng.randint(1, 6), rng.randint(1, 3)
    labels = [f"body{i}.x" for i in range(rng.randint(1, 3))]
    reduced = rng.random() < 0.25
    sweep = {f"p{i}": np.linspace(1, 2, V) for i in range(rng.randint(0, 2))}
    times = np.linspace(0, 1, K)
    work = create_store(path, times=times, labels=labels, sweep=sweep,
                        units={l: "m" for l in labels}, time_unit="s", reduced=reduced,
                        chunk_variants=cv, source_name="m.mech", n_variants=V)
    for start in range(0, V, cv):
        if rng.random() < 0.2:
            continue                                       # never written
        stop = min(start + cv, V)
        n = np.array([rng.randint(0, K) for _ in range(stop - start)])
        values = {l: rng.random() + np.arange(start, stop)[:, None] + times for l in labels}
        late = np.arange(K) >= n[:, None]
        for a in values.values():
            a[late] = np.nan
        write_chunk(work, start, Results(
            times=times, data={} if reduced else values,
            sweep={s: v[start:stop] for s, v in sweep.items()}, n_solved=n, status="ok",
            messages=(), solve_time=0.0, residual=0.0, source_name="m.mech",
            units={l: "m" for l in labels}, time_unit="s",
            reduced={l: v[:, 0] for l, v in values.items()} if reduced else {}))
    finish_store(work, status=rng.choice(["ok", "failed", "interrupted"]), messages=["m"],
                 warnings=[], solve_time=1.0, residual=0.0)
    return path


def _files(store: str) -> list[str]:
    """The regular files of the store of at most 1 MB (what a mutation may read)."""
    out = []
    for root, dirs, files in os.walk(store):
        for f in files:
            p = os.path.join(root, f)
            st = os.lstat(p)
            if stat.S_ISREG(st.st_mode) and st.st_size <= 2**20:
                out.append(p)
    return sorted(out)


def _json_files(store: str) -> list[str]:
    return [f for f in _files(store) if f.endswith(".json")]


def _value(rng: random.Random):
    return rng.choice([None, True, "", "x" * rng.randint(1, 300), [], {}, [1, 2], {"a": 1},
                       rng.choice(HUGE), -rng.randint(1, 10**6), 0.5, ["x", "x"],
                       [[]], "NaN", "part-000000000.parquet", "../../etc", "zarr.json",
                       "/dev/zero", {"name": "numcodecs.pickle"}])


def _walk_json(doc, rng: random.Random, depth: int = 0):
    """A random (container, key) inside the JSON ``doc``."""
    if isinstance(doc, dict) and doc and (depth == 0 or rng.random() < 0.6):
        key = rng.choice(list(doc))
        inner = doc[key]
        if isinstance(inner, (dict, list)) and inner and rng.random() < 0.5:
            return _walk_json(inner, rng, depth + 1)
        return doc, key
    if isinstance(doc, list) and doc:
        i = rng.randrange(len(doc))
        if isinstance(doc[i], (dict, list)) and doc[i] and rng.random() < 0.5:
            return _walk_json(doc[i], rng, depth + 1)
        return doc, i
    return None


def _mutate_json(rng: random.Random, store: str) -> str:
    files = _json_files(store)
    if not files:
        return "no JSON"
    path = rng.choice(files)
    try:
        doc = json.loads(Path(path).read_text())
    except (ValueError, OSError):
        return "unreadable JSON"
    spot = _walk_json(doc, rng)
    if spot is None:
        return "empty JSON"
    container, key = spot
    what = rng.random()
    if what < 0.3 and isinstance(container, dict):
        del container[key]
        action = f"removed {key!r}"
    else:
        container[key] = _value(rng)
        action = f"{key!r} = {str(container[key])[:40]}"
    Path(path).write_text(json.dumps(doc))
    return f"{os.path.relpath(path, store)}: {action}"


def _claim(rng: random.Random, store: str) -> str:
    """A huge n_variants, shape or chunk shape."""
    files = _json_files(store)
    path = rng.choice(files)
    doc = json.loads(Path(path).read_text())
    huge = rng.choice(HUGE[:4])
    if "shape" in doc:
        key = rng.choice(["shape", "chunk"])
        if key == "shape":
            doc["shape"] = [huge] * len(doc["shape"])
        else:
            doc["chunk_grid"]["configuration"]["chunk_shape"] = [huge] * len(doc["shape"])
    elif "attributes" in doc:
        doc["attributes"][rng.choice(["n_variants", "chunk_variants"])] = huge
    else:
        doc[rng.choice(["n_variants", "chunk_variants"])] = huge
    Path(path).write_text(json.dumps(doc))
    return f"{os.path.relpath(path, store)}: claims {huge}"


def _codec(rng: random.Random, store: str) -> str:
    arrays = [f for f in _json_files(store) if os.path.dirname(f) != store]
    if not arrays:
        return _mutate_json(rng, store)
    path = rng.choice(arrays)
    doc = json.loads(Path(path).read_text())
    choice = rng.choice(["pickle", "object", "gzip", "unknown", "sharding", "string"])
    if choice == "pickle":
        doc["codecs"] = [{"name": "numcodecs.pickle", "configuration": {"protocol": 2}}]
        marker = os.path.join(os.path.dirname(store), MARKER)
        for chunk in _files(os.path.dirname(path)):
            if not chunk.endswith(".json"):
                Path(chunk).write_bytes(pickle.dumps(_Planted(marker)))
    elif choice == "object":
        doc["data_type"] = rng.choice(["object", "|O", "bytes", "variable_length_utf8"])
    elif choice == "gzip":
        doc["codecs"] = [{"name": "bytes", "configuration": {"endian": "little"}},
                         {"name": "gzip", "configuration": {"level": 1}}]
    elif choice == "unknown":
        doc["codecs"].append({"name": "numcodecs.pickle"})
    elif choice == "sharding":
        doc["codecs"] = [{"name": "sharding_indexed", "configuration": {}}]
    else:
        doc["data_type"] = "string"
    Path(path).write_text(json.dumps(doc))
    return f"{os.path.relpath(path, store)}: {choice}"


def _bytes(rng: random.Random, store: str) -> str:
    files = _files(store)
    if not files:
        return "no file"
    path = rng.choice(files)
    data = bytearray(Path(path).read_bytes())
    what = rng.choice(["flip", "truncate", "append", "garbage", "empty"])
    if what == "flip" and data:
        for _ in range(rng.randint(1, 8)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    elif what == "truncate":
        del data[rng.randint(0, len(data)):]
    elif what == "append":
        data += bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
    elif what == "garbage":
        data = bytearray(rng.randbytes(rng.randint(1, max(1, 2 * len(data)))))
    else:
        data = bytearray()
    Path(path).write_bytes(bytes(data))
    return f"{os.path.relpath(path, store)}: {what}"


def _replace(rng: random.Random, store: str) -> str:
    files = _files(store)
    if not files:
        return "no file"
    path = rng.choice(files)
    others = [f for f in files if f != path]
    what = rng.choice(["/dev/zero", "/dev/urandom", "other", "dir-link", "dangling", "fifo",
                       "folder", "sparse", "/etc/passwd"])
    os.remove(path)
    if what == "fifo":
        os.mkfifo(path)
    elif what == "folder":
        os.mkdir(path)
        Path(path, "zarr.json").write_text("{}")
    elif what == "sparse":
        with open(path, "wb") as f:
            f.truncate(10**12)
    elif what == "other":
        os.symlink(rng.choice(others) if others else "/dev/zero", path)
    elif what == "dir-link":
        os.symlink(store, path)
    elif what == "dangling":
        os.symlink(os.path.join(store, "nowhere"), path)
    else:
        os.symlink(what, path)
    return f"{os.path.relpath(path, store)}: {what}"


def _deep(rng: random.Random, store: str) -> str:
    path = rng.choice(_json_files(store))
    depth = rng.choice([100, 5000, 200_000])
    Path(path).write_text(rng.choice(["[" * depth, '{"a":' * depth + "1" + "}" * depth]))
    return f"{os.path.relpath(path, store)}: JSON {depth} deep"


def _parquet_footer(rng: random.Random, store: str) -> str:
    parts = [f for f in _files(store) if f.endswith(".parquet")]
    if not parts:
        return _mutate_json(rng, store)
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = rng.choice(parts)
    table = pq.read_table(path)
    what = rng.choice(["metadata", "columns", "types", "rows"])
    if what == "metadata":
        md = dict(table.schema.metadata or {})
        key = rng.choice([b"mechdsl.start", b"mechdsl.n_solved"])
        md[key] = rng.choice([b"", b"[[[", b"-1", b"99999999999", b"[1e300]", b"[-5]",
                              b"[" * 100_000, json.dumps([10**12] * 3).encode(), b"\xff"])
        table = table.replace_schema_metadata(md)
    elif what == "columns" and table.num_columns > 1:
        table = table.drop_columns([rng.choice(table.column_names)])
    elif what == "types":
        name = rng.choice(table.column_names)
        i = table.column_names.index(name)
        table = table.set_column(i, name, pa.array([str(x) for x in table[name].to_pylist()]))
    else:
        table = pa.concat_tables([table] * rng.randint(2, 50))
    pq.write_table(table, path)
    return f"{os.path.relpath(path, store)}: {what}"


def _remove(rng: random.Random, store: str) -> str:
    files = _files(store)
    if not files:
        return "no file"
    path = rng.choice(files)
    os.remove(path)
    return f"{os.path.relpath(path, store)}: removed"


def _extra(rng: random.Random, store: str) -> str:
    name = rng.choice(["part-000000000.parquet", "extra.txt", "c", "zarr.json", ".hidden",
                       "part-999999999.parquet", "x"])
    where = rng.choice([store] + [os.path.dirname(f) for f in _files(store)])
    path = os.path.join(where, name)
    if os.path.lexists(path):
        return "extra: exists"
    rng.choice([lambda: os.symlink("/dev/zero", path), lambda: os.mkfifo(path),
                lambda: os.mkdir(path),
                lambda: Path(path).write_bytes(rng.randbytes(rng.randint(0, 100)))])()
    return f"{os.path.relpath(path, store)}: added"


MUTATIONS = [(_mutate_json, 4), (_claim, 1), (_codec, 1), (_bytes, 3), (_replace, 2),
             (_deep, 0.5), (_parquet_footer, 1.5), (_remove, 1), (_extra, 1)]


def hostile_store(rng: random.Random, folder: str) -> str:
    """A store built in ``folder`` by the real writer, then corrupted 1-3 times (see the
    module's docstring); returns its path. What was done is written to
    ``folder/store-mutations.txt``."""
    path = _valid(rng, folder)
    done = []
    for _ in range(rng.randint(1, 3)):
        fn = rng.choices([m for m, _ in MUTATIONS], [w for _, w in MUTATIONS])[0]
        try:
            what = fn(rng, path)
        except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError,
                IndexError) as err:  # an earlier mutation made the file unreadable to it
            what = f"not applied ({type(err).__name__})"
        except Exception as err:  # noqa: BLE001 - pyarrow refusing a corrupted part
            what = f"not applied ({type(err).__name__})"
        done.append(f"{fn.__name__.lstrip('_')}: {what}")
    if rng.random() < 0.05:                      # a store named for the other kind
        other = path.replace(".zarr", ".x.parquet") if path.endswith(".zarr") \
            else path.replace(".parquet", ".x.zarr")
        os.rename(path, other)
        path = other
        done.append("renamed to the other kind")
    Path(folder, "store-mutations.txt").write_text("\n".join(done) + "\n")
    return path


# -----------------------------------------------------------------------------------------
# running one


def run_one(path: str, folder: str, timeout: int) -> tuple[str, str]:
    """``mechdsl plot path`` in-process: (outcome, messages)."""
    from mechdsl.cli import main

    err = io.StringIO()
    out = os.path.join(folder, "out.png")
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(timeout)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(["plot", path, "-o", out])
    except Hang:
        code = "hang"
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else 1
    except BaseException as escaped:  # noqa: BLE001 - out of main(): a defect to report
        import traceback

        code = f"{type(escaped).__name__} raised out of main()"
        err.write("".join(traceback.format_exception(escaped)))
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    text = err.getvalue()
    first = text.splitlines()[0] if text else ""
    if os.path.lexists(os.path.join(folder, MARKER)):
        return "unpickled", text
    if code == "hang":
        return "hang", text
    if "Traceback" in text:
        return "traceback", text
    if code == 0:
        return "ok", text
    if code == 1:
        located = re.match(re.escape(path) + r"(/[^:]*)?: error: ", first)
        return ("located" if located else "unlocated"), text
    return "internal", f"exit status {code}\n{text}"


def fuzz(inputs: int, seed: int, timeout: int, failures: str) -> dict[str, int]:
    """Run ``inputs`` hostile stores; the counts of outcomes (offending inputs saved)."""
    counts: dict[str, int] = {}
    with tempfile.TemporaryDirectory(prefix="mechdsl-fuzz-stores-") as workdir:
        for i in range(inputs):
            folder = tempfile.mkdtemp(dir=workdir)
            try:
                path = hostile_store(random.Random(f"{seed}-{i}"), folder)
                kind, text = run_one(path, folder, timeout)
            except Exception as err:  # noqa: BLE001 - the harness's own failure
                kind, text = "harness", f"{type(err).__name__}: {err}"
            counts[kind] = counts.get(kind, 0) + 1
            if kind in DEFECTS:
                os.makedirs(failures, exist_ok=True)
                how = Path(folder, "store-mutations.txt")
                Path(failures, f"{kind}-{i}.txt").write_text(
                    f"input {i} of seed {seed} (python benchmarks/fuzz_stores.py --seed {seed} "
                    f"--replay {i})\n{how.read_text() if how.exists() else ''}\n{text[:20000]}")
            shutil.rmtree(folder, ignore_errors=True)
    return counts


def main() -> int:
    """The command: ``--inputs N --seed S --timeout T`` (or ``--replay I``)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--inputs", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=int, default=20, help="seconds allowed per input")
    ap.add_argument("--failures", default="fuzz-failures", help="folder for offending inputs")
    ap.add_argument("--replay", type=int, metavar="INDEX", help="run input INDEX of --seed only")
    ap.add_argument("--max-address-space", type=int, default=4 * 2**30,
                    help="RLIMIT_AS of this process, bytes (a read without end fails, "
                         "instead of swapping)")
    args = ap.parse_args()
    os.environ.setdefault("MPLBACKEND", "Agg")
    resource.setrlimit(resource.RLIMIT_AS, (args.max_address_space, args.max_address_space))
    if args.replay is not None:
        with tempfile.TemporaryDirectory(prefix="mechdsl-fuzz-stores-") as folder:
            path = hostile_store(random.Random(f"{args.seed}-{args.replay}"), folder)
            print(Path(folder, "store-mutations.txt").read_text())
            kind, text = run_one(path, folder, args.timeout)
        print(f"outcome: {kind}\n{text[:20000]}")
        return 1 if kind in DEFECTS else 0
    start = time.perf_counter()
    counts = fuzz(args.inputs, args.seed, args.timeout, args.failures)
    elapsed = time.perf_counter() - start
    total = sum(counts.values())
    print(f"{total} inputs in {elapsed:.0f} s ({total / elapsed:.1f}/s): "
          + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    bad = sum(v for k, v in counts.items() if k in DEFECTS)
    if bad:
        print(f"{bad} offending inputs saved in {args.failures}/")
        return 1
    print("no internal error, traceback, unlocated error, hang or unpickling")
    return 0


if __name__ == "__main__":
    sys.exit(main())
