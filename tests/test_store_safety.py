"""Result stores are written like files and read back as data.

Writing: a run into an existing store keeps the old one until the new one is complete -- a
run killed (SIGKILL) at any moment leaves the old store, byte for byte, an interrupted one
(SIGINT) keeps the old store at its path and its own beside it, a complete one replaces it.
Reading: ``mechdsl plot`` of a hostile store (missing arrays, wrong types, links to
/dev/zero, FIFOs, claims of terabytes, garbage chunks and footers, codecs that would
unpickle) ends promptly in exit 1 with a first line ``STORE...: error: ...``, no traceback,
within a bounded address space, and runs nothing. The truth is independent: the slider's
closed-form position (:func:`closed_form_x`), file hashes taken before, marker files."""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import re
import resource
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import EXAMPLES, ROOT
from mechdsl.outputs.store import create_store, finish_store, open_store, write_chunk
from mechdsl.results import Results

ROD = EXAMPLES / "rod_sweep.mech"
ROD_LS = [3.5, 2.5, 2.2, 2.1]                  # the sweep of examples/rod_sweep.mech
SIBLING = re.compile(r"\..+\.mechdsl-\d+-[0-9a-f]{8}-[0-9a-f]{12}")


def closed_form_x(l, t, r=2.0):
    """The slider's position in rod_sweep.mech: crank r, rod l, the start-up drive."""
    alpha = 4 * np.pi
    theta = np.where(t < 1, np.pi / 4 + alpha * t**2 / 2, np.pi / 4 + alpha / 2 + alpha * (t - 1))
    return r * np.cos(theta) + np.sqrt(l**2 - (r * np.sin(theta)) ** 2)


def _child(limit_memory: bool):
    def setup():
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        if limit_memory:  # reading /dev/zero must end in an error, not in the machine's swap
            resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))
    return setup


def cli(*args, cwd=ROOT, limit_memory: bool = False, timeout: float = 300):
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)], text=True,
                          capture_output=True, cwd=cwd, timeout=timeout,
                          preexec_fn=_child(limit_memory),
                          env={**os.environ, "OMP_NUM_THREADS": "1"})


def big_model(tmp_path, variants: int = 1500):
    """rod_sweep.mech with a sweep that takes several seconds to solve."""
    path = tmp_path / "big.mech"
    path.write_text(re.sub(r"(?m)^sweep l = .*$", f"sweep l = 2.2 .. 4 count {variants}",
                           ROD.read_text()))
    return path


def digest(folder) -> dict[str, str]:
    """Every file of ``folder`` by relative path: its hash."""
    out = {}
    for root, _, files in os.walk(folder):
        for f in files:
            p = os.path.join(root, f)
            out[os.path.relpath(p, folder)] = hashlib.sha256(open(p, "rb").read()).hexdigest()
    return out


def assert_rods(path, ls=ROD_LS, status="ok"):
    """The store at ``path`` holds the run of rod_sweep.mech over ``ls``: every instant
    solved, the slider where the closed form puts it."""
    res = open_store(path)
    assert res.status == status and res.n_variants == len(ls)
    np.testing.assert_array_equal(res.sweep["l"], ls)
    assert (res.n_solved == len(res.times)).all()
    for i, l in enumerate(ls):
        np.testing.assert_allclose(res.array("slider.x", [i])[0],
                                   closed_form_x(l, res.times), rtol=1e-9, atol=1e-9)


def count(folder) -> int:
    """Chunks of solved variants in the store ``folder`` being written (its files come and
    go): Zarr chunks of slider.x, Parquet part files."""
    return sum(len(files) for _, _, files in os.walk(os.path.join(folder, "slider.x"))) + \
        sum(name.startswith("part-") for name in os.listdir(folder) if os.path.isdir(folder))


def siblings(folder) -> list[str]:
    return sorted(p for p in os.listdir(folder) if SIBLING.fullmatch(p))


def start_big(tmp_path, store):
    """Start a long run into ``store``; return it once some chunks are written (the hidden
    store it builds holds files), so that a signal lands mid-run."""
    model = big_model(tmp_path)
    proc = subprocess.Popen([sys.executable, "-m", "mechdsl", "run", str(model), "--chunk",
                             "10", "-o", str(store), "-q"], cwd=tmp_path, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=_child(False),
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    deadline = time.monotonic() + 120
    written = 0
    while time.monotonic() < deadline and proc.poll() is None:
        # on main the run writes into the store itself: count its chunks there too
        places = [tmp_path / s for s in siblings(tmp_path)] + [store]
        written = max(count(p) if p.is_dir() else 0 for p in places)
        if written > 3:
            break
        time.sleep(0.05)
    assert proc.poll() is None, f"the run ended before it could be stopped: {proc.stderr.read()}"
    return proc


@pytest.mark.parametrize("kind", ["zarr", "parquet"])
def test_a_run_killed_mid_run_leaves_the_old_store_then_a_complete_run_replaces_it(
        tmp_path, kind):
    store = tmp_path / f"out.{kind}"
    r = cli("run", ROD, "--chunk", "2", "-o", store, "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    before = digest(store)
    proc = start_big(tmp_path, store)
    proc.send_signal(signal.SIGKILL)
    proc.wait(60)
    assert digest(store) == before                       # the old store, byte for byte
    assert_rods(store)
    left = siblings(tmp_path)                            # the killed run's own, hidden
    assert len(left) == 1 and left[0].startswith(f".out.{kind}.mechdsl-")

    r = cli("run", ROD, "--chunk", "3", "--sweep", "l=3,4", "-o", store, "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert_rods(store, [3.0, 4.0])                       # replaced, whole
    assert siblings(tmp_path) == []                      # the dead run's leftover removed
    assert sorted(os.listdir(tmp_path)) == ["big.mech", f"out.{kind}"]


@pytest.mark.parametrize("kind", ["zarr", "parquet"])
def test_an_interrupted_run_keeps_the_old_store_and_its_own_beside_it(tmp_path, kind):
    store = tmp_path / f"out.{kind}"
    r = cli("run", ROD, "--chunk", "2", "-o", store, "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    before = digest(store)
    proc = start_big(tmp_path, store)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert digest(store) == before
    assert_rods(store)
    beside = tmp_path / f"out.interrupted.{kind}"
    assert f"solved so far are in {beside}" in err, err
    assert f"{store} keeps the earlier run's results" in err, err
    assert "Traceback" not in err
    partial = open_store(beside)
    assert partial.status == "interrupted" and partial.n_variants == 1500
    done = np.flatnonzero(partial.n_solved == len(partial.times))
    assert 0 < len(done) < 1500                          # stopped mid-run, its work kept
    for i in done[:3]:
        np.testing.assert_allclose(partial.array("slider.x", [i])[0],
                                   closed_form_x(partial.sweep["l"][i], partial.times),
                                   rtol=1e-9, atol=1e-9)
    assert np.isnan(partial.array("slider.x", [int(np.flatnonzero(partial.n_solved < 0)[0])])
                    ).all()
    assert siblings(tmp_path) == []


def test_the_api_keeps_the_old_store_on_an_interrupt_as_the_command_line(tmp_path):
    from mechdsl.api import load

    store = tmp_path / "out.zarr"
    rods = load(str(ROD))
    assert_rods(rods.simulate(store=store, chunk=2).path)
    big = load(str(big_model(tmp_path, 3000)))

    def interrupt(signum, frame):
        # Ctrl-C once the sweep is being solved: some chunks written in the hidden store. A
        # real SIGINT, as a terminal sends it: held back while a chunk is written, as the
        # command line's is (a KeyboardInterrupt raised here directly could land inside
        # zarr's writer, which a Ctrl-C never does)
        if max([count(tmp_path / s) for s in siblings(tmp_path)] + [0]) > 3:
            os.kill(os.getpid(), signal.SIGINT)
            return
        signal.setitimer(signal.ITIMER_REAL, 0.05)

    old = signal.signal(signal.SIGALRM, interrupt)
    signal.setitimer(signal.ITIMER_REAL, 0.05)
    try:
        res = big.simulate(store=store, chunk=10)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert res.path == str(tmp_path / "out.interrupted.zarr") and res.status == "interrupted"
    assert any("keeps the earlier run's results" in m for m in res.messages)
    assert_rods(store)


# -----------------------------------------------------------------------------------------
# hostile stores given to mechdsl plot

TIMES = np.linspace(0.0, 1.0, 5)


def valid_store(folder, kind: str, name: str = "s") -> str:
    """A store written by the real writer: 3 variants of x = v + t, chunks of 2."""
    path = os.path.join(folder, f"{name}.{kind}")
    work = create_store(path, times=TIMES, labels=["x"], sweep={"l": np.array([1.0, 2, 3])},
                        units={"x": "m"}, time_unit="s", reduced=False, chunk_variants=2,
                        source_name="m.mech", n_variants=3) or path
    for start, stop in ((0, 2), (2, 3)):
        v = np.arange(start, stop)[:, None]
        write_chunk(work, start, Results(
            times=TIMES, data={"x": v + TIMES}, sweep={"l": np.arange(start, stop) + 1.0},
            n_solved=np.full(stop - start, 5), status="ok", messages=(), solve_time=0.0,
            residual=0.0, source_name="m.mech", units={"x": "m"}, time_unit="s"))
    finish_store(work, status="ok", messages=[], warnings=[], solve_time=0.0, residual=0.0)
    return path


def edit_json(path, change) -> None:
    with open(path) as f:
        doc = json.load(f)
    change(doc)
    with open(path, "w") as f:
        json.dump(doc, f)


def replace_by(path, make) -> None:
    os.remove(path)
    make(path)


def rewrite_part(path, metadata) -> None:
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    pq.write_table(table.replace_schema_metadata(metadata), path)


def zattrs(**changes):
    return lambda s: edit_json(os.path.join(s, "zarr.json"),
                               lambda d: d["attributes"].update(changes))


def pattrs(**changes):
    return lambda s: edit_json(os.path.join(s, "_mechdsl.json"), lambda d: d.update(changes))


class Planted:
    """Unpickling this creates the file named: it must never happen."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def pickle_codec(s):
    marker = os.path.join(os.path.dirname(s), "UNPICKLED")
    edit_json(os.path.join(s, "x", "zarr.json"),
              lambda d: d.update(codecs=[{"name": "numcodecs.pickle",
                                          "configuration": {"protocol": 2}}]))
    for key in ("c/0/0", "c/1/0"):
        with open(os.path.join(s, "x", key), "wb") as f:
            f.write(pickle.dumps(Planted(marker)))


HOSTILE = {
    "zarr: no t": ("zarr", lambda s: shutil.rmtree(os.path.join(s, "t")), "t/zarr.json"),
    "zarr: labels not a list": ("zarr", zattrs(labels="x"), "'labels' must be"),
    "zarr: n_variants a text": ("zarr", zattrs(n_variants="3"), "'n_variants' must be"),
    "zarr: units a list": ("zarr", zattrs(units=["m"]), "'units' must be"),
    "zarr: no metadata key": ("zarr", lambda s: edit_json(
        os.path.join(s, "zarr.json"), lambda d: d["attributes"].pop("reduced")), "'reduced'"),
    "zarr: chunk links to /dev/zero": ("zarr", lambda s: replace_by(
        os.path.join(s, "x", "c", "0", "0"), lambda p: os.symlink("/dev/zero", p)),
        "symbolic link"),
    "zarr: chunk is a FIFO": ("zarr", lambda s: replace_by(
        os.path.join(s, "x", "c", "1", "0"), os.mkfifo), "FIFO"),
    "zarr: metadata is a FIFO": ("zarr", lambda s: replace_by(
        os.path.join(s, "x", "zarr.json"), os.mkfifo), "FIFO"),
    "zarr: 10**12 variants": ("zarr", zattrs(n_variants=10**12),
                              "claims 1,000,000,000,000 variants x 5 instants"),
    "zarr: shape of 10**12": ("zarr", lambda s: edit_json(
        os.path.join(s, "x", "zarr.json"), lambda d: d.update(shape=[10**12, 5])), "shape"),
    "zarr: truncated chunk": ("zarr", lambda s: os.truncate(
        os.path.join(s, "x", "c", "0", "0"), 10), "x/c/0/0"),
    "zarr: garbage chunk": ("zarr", lambda s: open(
        os.path.join(s, "x", "c", "0", "0"), "wb").write(os.urandom(40)), "x/c/0/0"),
    "zarr: pickle codec": ("zarr", pickle_codec, "pickle"),
    "zarr: object dtype": ("zarr", lambda s: edit_json(
        os.path.join(s, "x", "zarr.json"), lambda d: d.update(data_type="object")),
        "data type"),
    "zarr: deep JSON": ("zarr", lambda s: open(os.path.join(s, "zarr.json"), "w").write(
        "[" * 200_000), "zarr.json"),
    "parquet: times missing": ("parquet", lambda s: edit_json(
        os.path.join(s, "_mechdsl.json"), lambda d: d.pop("times")), "'times'"),
    "parquet: sweep values wrong": ("parquet", pattrs(sweep_values={"l": "abc"}),
                                    "'sweep_values'"),
    "parquet: 10**12 variants": ("parquet", pattrs(n_variants=10**12),
                                 "claims 1,000,000,000,000 variants x 5 instants"),
    "parquet: part links to /dev/zero": ("parquet", lambda s: replace_by(
        os.path.join(s, "part-000000000.parquet"), lambda p: os.symlink("/dev/zero", p)),
        "symbolic link"),
    "parquet: part is a FIFO": ("parquet", lambda s: replace_by(
        os.path.join(s, "part-000000002.parquet"), os.mkfifo), "FIFO"),
    "parquet: truncated part": ("parquet", lambda s: os.truncate(
        os.path.join(s, "part-000000000.parquet"), 100), "part-000000000.parquet"),
    "parquet: garbage footer metadata": ("parquet", lambda s: rewrite_part(
        os.path.join(s, "part-000000000.parquet"),
        {"mechdsl.start": "0", "mechdsl.n_solved": "[[[garbage"}), "mechdsl.n_solved"),
    "parquet: footer claims too many instants": ("parquet", lambda s: rewrite_part(
        os.path.join(s, "part-000000002.parquet"),
        {"mechdsl.start": "2", "mechdsl.n_solved": "[5000]"}), "mechdsl.n_solved"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_plot_of_a_hostile_store_is_a_located_error(tmp_path, case):
    kind, corrupt, expected = HOSTILE[case]
    store = valid_store(tmp_path, kind)
    corrupt(store)
    start = time.monotonic()
    r = cli("plot", store, "-o", tmp_path / "out.png", cwd=tmp_path, limit_memory=True,
            timeout=120)
    elapsed = time.monotonic() - start
    first = r.stderr.splitlines()[0] if r.stderr else ""
    assert r.returncode == 1, r.stderr
    assert re.match(re.escape(store) + r"(/[^:]*)?: error: ", first), r.stderr
    assert expected in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert "not enough memory" not in r.stderr
    assert elapsed < 30
    assert not (tmp_path / "UNPICKLED").exists()
    assert not (tmp_path / "out.png").exists()


@pytest.mark.parametrize("kind", ["zarr", "parquet"])
def test_a_valid_store_still_plots(tmp_path, kind):
    store = valid_store(tmp_path, kind)
    r = cli("plot", store, "-o", tmp_path / "out.png", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "out.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    res = open_store(store)
    np.testing.assert_array_equal(res.array("x"), np.arange(3)[:, None] + TIMES)
