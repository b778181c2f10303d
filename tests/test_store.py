"""Result stores (mechdsl.outputs.store): what is written chunk by chunk, in any order, by
one process or several, reads back exactly. The truth is built by hand: variant v's output
at instant k is sin(v + t_k) (and 2 cos(v * t_k)), NaN from its n_solved[v] on."""

from __future__ import annotations

import json
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from mechdsl.errors import MechError
from mechdsl.outputs.store import (KINDS, create_store, finish_store, open_store, store_kind,
                                   write_chunk)
from mechdsl.results import Results

V, CHUNK = 10, 4
TIMES = np.linspace(0.0, 2.0, 7)
LABELS = ("slider.x", "crank.phi")
UNITS = {"slider.x": "mm", "crank.phi": "rad"}
SWEEP = {"l": 100.0 + 2.5 * np.arange(V), "e": np.arange(V) % 3 - 1.0}
#: instants solved per variant: some stop early, variant 6 solves none
N_SOLVED = np.array([7, 7, 3, 7, 1, 7, 0, 7, 5, 7])


def truth(start: int = 0, stop: int = V, n_solved=N_SOLVED) -> dict[str, np.ndarray]:
    v = np.arange(start, stop)[:, None]
    data = {"slider.x": np.sin(v + TIMES), "crank.phi": 2.0 * np.cos(v * TIMES)}
    late = np.arange(len(TIMES)) >= np.asarray(n_solved)[start:stop, None]
    for a in data.values():
        a[late] = np.nan
    return data


def chunk(start: int, stop: int, *, reduced: bool = False, n_solved=N_SOLVED) -> Results:
    """The Results a worker would return for variants [start, stop)."""
    data = truth(start, stop, n_solved)
    red = {}
    if reduced:
        red = {"peak": np.nanmax(np.abs(data["slider.x"]), axis=1, initial=0.0),
               "mean": np.nanmean(data["crank.phi"], axis=1)}
        red["mean"][np.asarray(n_solved)[start:stop] < len(TIMES)] = np.nan
        data = {}
    return Results(times=TIMES, data=data, sweep={k: v[start:stop] for k, v in SWEEP.items()},
                   n_solved=np.asarray(n_solved)[start:stop].copy(), status="ok",
                   messages=(), solve_time=0.1, residual=1e-12, source_name="crank.mech",
                   units=UNITS, time_unit="s", reduced=red)


def create(path, *, reduced: bool = False, labels=LABELS, n_variants=V, sweep=SWEEP) -> str:
    """A new store for ``path``, built beside it: the path the writers are given."""
    return create_store(path, times=TIMES, labels=labels, sweep=sweep, units=UNITS, time_unit="s",
                 reduced=reduced, chunk_variants=CHUNK, source_name="crank.mech",
                 n_variants=n_variants)


def finish(work, status: str = "ok", **kwargs) -> str:
    """Finish the store built in ``work``: it goes in place; where it went."""
    end = dict(messages=[], warnings=[], solve_time=1.0, residual=0.0)
    end.update(kwargs)
    return finish_store(work, status=status, **end)


def equal(a, b) -> bool:
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


def test_store_kind():
    assert KINDS == ("zarr", "parquet")
    assert store_kind("out/run.zarr") == "zarr"
    assert store_kind("run.ZARR/") == "zarr"
    assert store_kind("run.parquet") == "parquet"
    assert store_kind("run.csv") is None
    assert store_kind("zarr") is None


@pytest.mark.parametrize("kind", KINDS)
def test_chunks_out_of_order_and_retried_read_back_exactly(tmp_path, kind):
    path = tmp_path / f"run.{kind}"
    work = create(path)
    assert not path.exists()                  # built beside it, in place when finished
    # out of order, the last chunk short, the middle one written twice (a retried task);
    # variants 0..3 are never written
    write_chunk(work, 8, chunk(8, 10))
    write_chunk(work, 4, chunk(4, 8))
    write_chunk(work, 4, chunk(4, 8))
    where = finish_store(work, status="interrupted", messages=["stopped by the user"],
                         warnings=["a singular position was passed"], solve_time=3.5,
                         residual=2e-11)
    assert where == str(path) and sorted(os.listdir(tmp_path)) == [path.name]

    res = open_store(path)
    assert res.kind == kind and not res.reduced
    assert res.n_variants == V and res.labels == LABELS and res.units == UNITS
    assert res.time_unit == "s" and res.source_name == "crank.mech"
    assert res.status == "interrupted" and res.messages == ("stopped by the user",)
    assert res.warnings == ("a singular position was passed",)
    assert res.solve_time == 3.5 and res.residual == 2e-11
    assert np.array_equal(res.times, TIMES)
    assert list(res.sweep) == ["l", "e"]
    for name, values in SWEEP.items():
        assert np.array_equal(res.sweep[name], values)
    expected_n = np.where(np.arange(V) < 4, -1, N_SOLVED)
    assert np.array_equal(res.n_solved, expected_n)
    assert "slider.x" in res and "t" not in res and "nope" not in res

    full = truth()
    for label in LABELS:
        expected = full[label].copy()
        expected[:4] = np.nan                                 # never written
        got = np.asarray(res[label][:]) if kind == "zarr" else res[label]
        assert got.shape == (V, len(TIMES))
        assert equal(got, expected)
        assert equal(res.array(label), expected)
        assert equal(res.array(label, slice(3, 9)), expected[3:9])
        assert equal(res.array(label, slice(None, None, -3)), expected[::-3])
        picks = np.array([9, 2, 5, 5, 0])
        assert equal(res.array(label, picks), expected[picks])
    with pytest.raises(KeyError):
        res["nope"]

    part = res.to_results(np.array([5, 8, 1]))
    assert isinstance(part, Results) and part.status == "interrupted"
    assert np.array_equal(part.n_solved, [7, 5, 0])            # never written: nothing solved
    assert np.array_equal(part.sweep["l"], SWEEP["l"][[5, 8, 1]])
    assert equal(part.data["slider.x"], np.where(np.arange(V)[:, None] < 4, np.nan,
                                                 full["slider.x"])[[5, 8, 1]])
    assert part.units == UNITS and part.time_unit == "s" and part.labels == LABELS
    everything = res.to_results()
    assert everything.n_variants == V and everything.data["crank.phi"].shape == (V, len(TIMES))


def test_zarr_layout(tmp_path):
    import zarr

    path = tmp_path / "run.zarr"
    work = create(path)
    write_chunk(work, 0, chunk(0, 4))
    finish(work)
    group = zarr.open_group(path, mode="r")
    attrs = dict(group.attrs)
    assert attrs["mechdsl"] == 1 and attrs["labels"] == list(LABELS)
    assert attrs["units"] == UNITS and attrs["time_unit"] == "s"
    assert attrs["sweep"] == ["l", "e"] and attrs["reduced"] is False
    assert attrs["source"] == "crank.mech" and attrs["chunk_variants"] == CHUNK
    a = group["slider.x"]
    assert a.shape == (V, len(TIMES)) and a.chunks == (CHUNK, len(TIMES))
    assert a.dtype == np.float64 and np.isnan(a.fill_value)
    assert a.attrs["unit"] == "mm" and group["crank.phi"].attrs["unit"] == "rad"
    assert group["n_solved"].dtype == np.int64
    assert np.array_equal(group["n_solved"][:], np.r_[N_SOLVED[:4], [-1] * 6])
    assert np.array_equal(group["t"][:], TIMES)
    res = open_store(path)
    assert isinstance(res["slider.x"], zarr.Array)
    assert equal(res["slider.x"][1:3, 2:5], truth()["slider.x"][1:3, 2:5])
    assert res.dataset is None


def test_parquet_layout(tmp_path):
    import pyarrow.dataset as ds
    import pyarrow.parquet as pq

    path = tmp_path / "run.parquet"
    work = create(path)
    write_chunk(work, 4, chunk(4, 8))
    write_chunk(work, 0, chunk(0, 4))
    write_chunk(work, 8, chunk(8, 10))
    finish(work)
    assert sorted(os.listdir(path)) == ["_mechdsl.json", "part-000000000.parquet",
                                        "part-000000004.parquet", "part-000000008.parquet"]
    meta = json.loads((path / "_mechdsl.json").read_text())
    assert meta["mechdsl"] == 1 and meta["labels"] == list(LABELS)
    assert meta["times"] == TIMES.tolist() and meta["sweep_values"]["l"] == SWEEP["l"].tolist()

    res = open_store(path)
    assert isinstance(res.dataset, ds.Dataset)
    table = res.dataset.to_table()
    assert table.num_rows == N_SOLVED.sum()
    assert table.column_names == ["variant", "l", "e", "t", *LABELS]
    assert table.schema.field("slider.x").metadata == {b"unit": b"mm"}
    assert table.schema.field("t").metadata == {b"unit": b"s"}
    # the rows are the CSV's: each solved instant of each variant, nothing after
    one = pq.read_table(path / "part-000000004.parquet")
    assert one["variant"].to_pylist() == [4] * 1 + [5] * 7 + [7] * 7
    assert one["t"].to_pylist() == [TIMES[0], *TIMES, *TIMES]
    assert one["l"].to_pylist() == [SWEEP["l"][4]] * 1 + [SWEEP["l"][5]] * 7 + [SWEEP["l"][7]] * 7
    assert np.array_equal(one["slider.x"].to_numpy(),
                          np.r_[np.sin(4 + TIMES[:1]), np.sin(5 + TIMES), np.sin(7 + TIMES)])
    assert np.array_equal(res.n_solved, N_SOLVED)
    assert equal(res["crank.phi"], truth()["crank.phi"])


@pytest.mark.parametrize("kind", KINDS)
def test_reduced_store(tmp_path, kind):
    path = tmp_path / f"peaks.{kind}"
    work = create(path, reduced=True, labels=("peak", "mean"))
    write_chunk(work, 8, chunk(8, 10, reduced=True))
    write_chunk(work, 0, chunk(0, 4, reduced=True))
    finish(work)
    res = open_store(path)
    assert res.reduced and res.labels == ("peak", "mean") and res.status == "ok"
    expected = {k: np.full(V, np.nan) for k in ("peak", "mean")}
    for s, e in ((0, 4), (8, 10)):
        for k, v in chunk(s, e, reduced=True).reduced.items():
            expected[k][s:e] = v
    for k in ("peak", "mean"):
        got = np.asarray(res[k][:]) if kind == "zarr" else res[k]
        assert got.shape == (V,) and equal(got, expected[k])
        assert equal(res.array(k, [9, 0, 5]), expected[k][[9, 0, 5]])
    assert np.array_equal(res.n_solved, np.r_[N_SOLVED[:4], [-1] * 4, N_SOLVED[8:]])
    back = res.to_results(slice(0, 4))
    assert back.data == {} and equal(back.reduced["peak"], expected["peak"][:4])
    if kind == "parquet":
        assert res.dataset.count_rows() == 6                  # one row per variant written


@pytest.mark.parametrize("kind", KINDS)
def test_no_sweep_one_variant(tmp_path, kind):
    path = tmp_path / f"single.{kind}"
    work = create(path, n_variants=1, sweep={})
    one = Results(times=TIMES, data={k: v[:1] for k, v in truth(0, 1).items()}, sweep={},
                  n_solved=np.array([7]), status="ok", messages=(), solve_time=0.0,
                  residual=0.0, source_name="crank.mech", units=UNITS, time_unit="s")
    write_chunk(work, 0, one)
    finish(work)
    res = open_store(path)
    assert res.sweep == {} and res.n_variants == 1
    assert equal(res.array("slider.x"), np.sin(TIMES)[None])
    assert equal(res.to_results()["slider.x"], np.sin(TIMES))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("existing", ["folder", "file", "other_kind_of_store_file"])
def test_refuses_to_overwrite_what_is_not_a_store(tmp_path, kind, existing):
    path = tmp_path / f"precious.{kind}"
    if existing == "folder":
        path.mkdir()
        (path / "thesis.tex").write_text("years of work")
        (path / "zarr.json").write_text('{"attributes": {"mechdsl": 2}}')
    else:
        path.write_text("years of work")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    with pytest.raises(MechError, match="exists and is not a mechdsl store"):
        create(path)
    assert sorted(p.name for p in tmp_path.rglob("*")) == before
    if existing == "folder":
        assert (path / "thesis.tex").read_text() == "years of work"
    else:
        assert path.read_text() == "years of work"


@pytest.mark.parametrize("kind", KINDS)
def test_replaces_an_earlier_store(tmp_path, kind):
    path = tmp_path / f"run.{kind}"
    work = create(path)
    write_chunk(work, 0, chunk(0, 4))
    finish(work)
    work = create(path, n_variants=4, sweep={k: v[4:8] for k, v in SWEEP.items()})
    res = open_store(path)                   # the earlier store, until the new one is done
    assert res.n_variants == V and res.status == "ok"
    assert equal(res.array("slider.x", slice(0, 4)), truth(0, 4)["slider.x"])
    assert finish(work, "failed") == str(path)                     # complete: replaces it
    res = open_store(path)
    assert res.n_variants == 4 and res.status == "failed"
    assert np.array_equal(res.n_solved, [-1] * 4)
    assert np.isnan(res.array("slider.x")).all()
    assert np.array_equal(res.sweep["l"], SWEEP["l"][4:8])
    assert sorted(os.listdir(tmp_path)) == [path.name]             # the old one removed


@pytest.mark.parametrize("kind", KINDS)
def test_bad_paths_and_chunks(tmp_path, kind):
    with pytest.raises(MechError, match="No such file") as err:
        open_store(tmp_path / f"nothing-here.{kind}")
    assert err.value.file == str(tmp_path / f"nothing-here.{kind}")   # located at the store
    plain = tmp_path / f"plain.{kind}"
    plain.mkdir()
    with pytest.raises(MechError, match="not a mechdsl result store") as err:
        open_store(plain)
    assert err.value.file == str(plain)
    with pytest.raises(MechError, match="zarr or .parquet"):
        create(tmp_path / "run.h5")
    path = tmp_path / f"run.{kind}"
    work = create(path)
    with pytest.raises(MechError, match="whole chunks"):
        write_chunk(work, 2, chunk(2, 6))                     # not on a chunk boundary
    with pytest.raises(MechError, match="whole chunks"):
        write_chunk(work, 4, chunk(4, 6))                     # ends inside a chunk
    with pytest.raises(MechError, match="outputs and params"):
        write_chunk(work, 0, chunk(0, 4, reduced=True))
    finish(work)
    assert np.array_equal(open_store(path).n_solved, [-1] * V)


def test_missing_library_names_the_extra(tmp_path, monkeypatch):
    import builtins

    real = builtins.__import__

    def no_zarr(name, *args, **kwargs):
        if name.split(".")[0] in ("zarr", "pyarrow"):
            raise ImportError(name)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_zarr)
    with pytest.raises(MechError, match=r'pip install "mechdsl\[zarr\]"'):
        create(tmp_path / "a.zarr")
    with pytest.raises(MechError, match=r'pip install "mechdsl\[parquet\]"'):
        create(tmp_path / "a.parquet")


@pytest.mark.parametrize("method", ["spawn", "fork"])
def test_concurrent_writers(tmp_path, method):
    if method not in multiprocessing.get_all_start_methods():
        method = "spawn"
    v = 4 * CHUNK + 3
    n_solved = np.arange(v) % (len(TIMES) + 1)
    path = tmp_path / "run.zarr"
    sweep = {"l": 100.0 + 2.5 * np.arange(v), "e": np.arange(v) % 3 - 1.0}
    work = create(path, n_variants=v, sweep=sweep)

    def piece(start):
        stop = min(start + CHUNK, v)
        data = truth(start, stop, n_solved)
        return Results(times=TIMES, data=data, sweep={k: a[start:stop] for k, a in sweep.items()},
                       n_solved=n_solved[start:stop], status="ok", messages=(),
                       solve_time=0.0, residual=0.0, source_name="crank.mech",
                       units=UNITS, time_unit="s")

    starts = [12, 0, 16, 4, 8, 4]                            # 4 twice: a retried task
    ctx = multiprocessing.get_context(method)
    with ProcessPoolExecutor(2, mp_context=ctx) as pool:
        for future in [pool.submit(write_chunk, work, s, piece(s)) for s in starts]:
            future.result()                                   # a worker's error fails here
    finish(work)
    res = open_store(path)
    assert np.array_equal(res.n_solved, n_solved)
    for label, expected in truth(0, v, n_solved).items():
        assert equal(res[label][:], expected)
