"""Sweeps on a real Dask cluster: a LocalCluster of worker processes on the loopback
interface, as `mechdsl run --workers N` starts one. What a cluster gives must equal, bit for
bit, what this process gives for the same chunks (the chunks do not depend on who solves
them); a worker killed mid-run costs its chunks, which are solved again, and the run says so.
"""

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from conftest import EXAMPLES
from mechdsl.errors import MechError
from mechdsl.outputs.store import open_store

import distributed

LS = list(np.linspace(2.2, 4.0, 48))


@pytest.fixture(scope="module")
def client():
    # the LocalCluster of `--workers 2`: 2 processes of one thread on 127.0.0.1
    from mechdsl.study.cluster import local_client

    c = local_client(2)
    assert isinstance(c.cluster, distributed.LocalCluster)
    yield c
    cluster = c.cluster
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def rods():
    import mechdsl

    return mechdsl.load(EXAMPLES / "rod_sweep.mech")


def same(a, b) -> bool:
    """Equal bit for bit, NaN where the other has NaN."""
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


def test_the_workers_are_processes_on_the_loopback_interface(client):
    pids = client.run(os.getpid)
    assert len(pids) == 2 and os.getpid() not in pids.values()
    assert all(address.startswith("tls://127.0.0.1:") for address in pids)


def test_a_sweep_on_the_cluster_equals_the_run_here(client, rods):
    here = rods.simulate(sweep={"l": LS}, span=(0, 0.5), chunk=7)
    there = rods.simulate(sweep={"l": LS}, span=(0, 0.5), chunk=7, client=client)
    assert here.ok and there.ok and there.n_variants == len(LS)
    for label in here.labels:
        assert same(here.data[label], there.data[label]), label
    np.testing.assert_array_equal(there.sweep["l"], LS)
    assert here.messages == there.messages == ()
    # and the chunks are the run of one chunk each: variant 10 alone gives the same numbers
    # only where its chunk is solved alone; the merged run is that of its chunks
    chunk = rods.simulate(sweep={"l": LS[7:14]}, span=(0, 0.5))
    assert same(there.data["slider.ax"][7:14], chunk.data["slider.ax"])


def closed_form_x(l, t, r=2.0):
    """The slider's position: crank r from the origin, rod l, the start-up drive of
    rod_sweep.mech (alpha = 4 pi rad/s^2 up to t = 1 s)."""
    alpha = 4 * np.pi
    theta = np.where(t < 1, np.pi / 4 + alpha * t**2 / 2, np.pi / 4 + alpha / 2 + alpha * (t - 1))
    return r * np.cos(theta) + np.sqrt(l**2 - (r * np.sin(theta)) ** 2)


def test_a_worker_killed_mid_run_costs_only_its_chunks(client, rods):
    from mechdsl.compiled.variants import Overrides
    from mechdsl.study import solve_sweep

    ls = list(np.linspace(2.2, 4.0, 120))
    ov = Overrides(sweeps={"l": ls}, t1=1.0)
    here = solve_sweep(rods, ov, chunk=4)
    workers = client.run(os.getpid)  # {address: pid}
    victims, victim = list(workers.values()), list(workers)[0]
    killed = []

    def kill_one(done: int, total: int) -> None:
        # after the first chunk comes back, both workers are busy with the next ones
        if not killed:
            os.kill(victims[0], signal.SIGKILL)
            killed.append(done)

    there = solve_sweep(rods, ov, chunk=4, client=client, progress=kill_one)
    assert killed and killed[0] < 120 * len(here.times)
    assert there.ok, there.messages
    assert int(there.n_solved.min()) == len(here.times)  # complete
    for label in here.labels:
        assert same(here.data[label], there.data[label]), label
    # the killed worker is reported, its chunks solved again; on a loaded machine other
    # workers (the restarted one too) may also miss their heartbeats and be reported the
    # same way (two or three losses, seen in about one run in five): what matters is that
    # the killed one is said, each loss once, and each repaired
    lost = [w for w in there.warnings if "was lost during the run" in w]
    assert any(f"the worker {victim} was lost" in w for w in lost), (victim, lost)
    named = [w.split("the worker ", 1)[1].split(" ", 1)[0] for w in lost]
    assert len(named) == len(set(named)), lost
    assert all("solved again on another worker" in w for w in lost)
    t = here.times
    np.testing.assert_allclose(there.data["slider.x"][-1], closed_form_x(4.0, t), rtol=1e-12)
    client.wait_for_workers(2, timeout=60)  # the nanny restarts the worker


def test_a_failing_variant_on_the_cluster_is_reported_by_its_values(client, rods):
    # l = 1.5 < r sin(theta) somewhere: the rod cannot reach; its chunk reports it as here
    ls = [3.5, 1.5, 2.5]
    here = rods.simulate(sweep={"l": ls}, span=(0, 0.5), chunk=1)
    there = rods.simulate(sweep={"l": ls}, span=(0, 0.5), chunk=1, client=client)
    assert here.status == there.status == "failed"
    assert here.messages == there.messages
    assert any("l = 1.5" in m for m in there.messages)
    assert same(here.data["slider.x"], there.data["slider.x"])
    assert there.n_solved[0] == there.n_solved[2] == len(here.times) > there.n_solved[1]


@pytest.mark.parametrize("suffix", ["zarr", "parquet"])
def test_workers_write_their_chunks_into_a_store(client, rods, tmp_path, suffix):
    path = tmp_path / f"out.{suffix}"
    here = rods.simulate(sweep={"l": LS}, span=(0, 0.5), chunk=5)
    stored = rods.simulate(sweep={"l": LS}, span=(0, 0.5), chunk=5, client=client, store=path)
    assert stored.status == "ok" and stored.n_variants == len(LS)
    np.testing.assert_array_equal(stored.n_solved, here.n_solved)
    for label in here.labels:
        assert same(stored.array(label), here.data[label]), label
    np.testing.assert_array_equal(stored.sweep["l"], LS)
    assert {k: u for k, u in stored.units.items() if u} == dict(here.units)


def test_reductions_come_back_as_one_row_per_variant(client, rods):
    here = rods.simulate(sweep={"l": LS}, span=(0, 1.0), chunk=6,
                         reduce="peak = max(abs(slider.ax)), stroke = range(slider.x)")
    there = rods.simulate(sweep={"l": LS}, span=(0, 1.0), chunk=6, client=client,
                          reduce="peak = max(abs(slider.ax)), stroke = range(slider.x)")
    assert there.data == {} and set(there.reduced) == {"peak", "stroke"}
    for label in ("peak", "stroke"):
        assert same(here.reduced[label], there.reduced[label])
    # the crank turns 2 pi by t = 1 (theta from pi/4 to pi/4 + 2 pi): the stroke is 2r
    np.testing.assert_allclose(there.reduced["stroke"], 4.0, rtol=2e-4)


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)],
                          capture_output=True, text=True, timeout=300, cwd=cwd)


def test_the_command_line_with_workers_writes_the_same_file(tmp_path):
    here, there = tmp_path / "here.csv", tmp_path / "there.csv"
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "-o", here, "-q")
    assert r.returncode == 0, r.stderr
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "--workers", "2", "-o", there, "-q")
    assert r.returncode == 0, r.stderr
    assert here.read_bytes() == there.read_bytes()
    # chunks of one variant each, spread over both workers: the same as those chunks here
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "--chunk", "1", "-o", here, "-q")
    assert r.returncode == 0, r.stderr
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "--chunk", "1", "--workers", "2",
                "-o", there, "-q")
    assert r.returncode == 0, r.stderr
    assert here.read_bytes() == there.read_bytes()


def test_the_command_line_reaches_a_scheduler_by_its_address(tmp_path):
    # a cluster the user started (plain TCP, as `dask scheduler` starts one); the local
    # cluster of --workers is this run's alone (tests/test_cluster_trust.py)
    here, there = tmp_path / "here.csv", tmp_path / "there.csv"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", protocol="tcp://",
                                  dashboard_address="127.0.0.1:0") as cluster:
        scheduler_run(cluster.scheduler_address, here, there)


def scheduler_run(address, here, there):
    assert run_cli("run", EXAMPLES / "rod_sweep.mech", "--chunk", "2", "-o", here,
                   "-q").returncode == 0
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "--chunk", "2", "--scheduler", address,
                "-o", there, "-q")
    assert r.returncode == 0, r.stderr
    assert here.read_bytes() == there.read_bytes()


def test_the_cluster_options_fail_as_user_errors(tmp_path):
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "--workers", "2", "--scheduler",
                "tcp://127.0.0.1:1", "-o", tmp_path / "o.csv")
    assert r.returncode == 1
    assert r.stderr.startswith("mechdsl: error: --workers starts a local cluster and "
                               "--scheduler names one")
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "--workers", "0")
    assert r.returncode == 1 and "--workers 0: give at least 1" in r.stderr
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "--chunk", "0")
    assert r.returncode == 1 and "--chunk 0: give at least 1 variant per chunk" in r.stderr
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "--workers", "2", "-o",
                tmp_path / "o.zarr", "--plot", tmp_path / "p.png")
    assert r.returncode == 1 and "--plot with -o" in r.stderr
    assert not (tmp_path / "o.zarr").exists()


def test_without_dask_the_options_say_how_to_install_it(monkeypatch):
    from mechdsl.study.cluster import local_client

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed fails
    with pytest.raises(MechError, match=r'pip install "mechdsl\[cluster\]"'):
        local_client(2)


def test_a_store_is_read_back_lazily_by_plot(tmp_path):
    store = tmp_path / "rods.zarr"
    r = run_cli("run", EXAMPLES / "rod_sweep.mech", "--chunk", "3", "-o", store, "-q")
    assert r.returncode == 0, r.stderr
    stored = open_store(store)
    assert stored.n_variants == 4 and stored.status == "ok"
    assert type(stored["slider.x"]).__module__.startswith("zarr")  # an array on disk
    np.testing.assert_allclose(stored.array("slider.x", [3])[0],
                               closed_form_x(2.1, stored.times), rtol=1e-12)
    png = tmp_path / "rods.png"
    r = run_cli("plot", store, "-o", png)
    assert r.returncode == 0, r.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_an_optimisation_on_the_cluster_finds_what_it_finds_here(client):
    # every population and stencil is one sweep, cut into the same chunks here and there:
    # the same numbers, so the same search, step for step, and the same design
    import mechdsl
    from mechdsl.study.optimize import optimize

    text = (EXAMPLES / "slider_crank.mech").read_text().replace(
        "simulate t = 0 .. 1 step 0.001", "simulate t = 0 .. 0.5 step 1/64") + (
        "optimize l in 2.5 .. 6, r in 1 .. 3\nminimize max(abs(slider.ax))\n"
        "subject to range(slider.x) >= 4, l >= 2*r\n")
    mech = mechdsl.loads(text, "opt.mech")
    here = optimize(mech, chunk=8, popsize=6, maxiter=30, run=False)
    there = optimize(mech, chunk=8, popsize=6, maxiter=30, run=False, client=client)
    assert there.params == here.params and there.objective == here.objective
    assert there.variants == here.variants and there.sweeps == here.sweeps
    # the closed form: r = 2 (the stroke 2r >= 4), l = 6 (the longest rod),
    # peak r omega^2 (1 + r/l) at theta = 0, an instant of this grid
    omega = 4 * np.pi
    assert there.params["l"] == pytest.approx(6.0, rel=1e-6)
    assert there.params["r"] == pytest.approx(2.0, rel=1e-6)
    assert there.objective == pytest.approx(2 * omega**2 * (1 + 2 / 6), rel=1e-6)


def test_the_local_cluster_keeps_the_workers_allocator_and_this_process_environment():
    # distributed's nannies set MALLOC_TRIM_THRESHOLD_=65536 in their workers (which halves
    # the speed of the numpy path) and write their workers' variables into this process
    from mechdsl.study.cluster import local_client

    before = dict(os.environ)
    client = local_client(1)
    try:
        assert dict(os.environ) == before
        (trim,) = client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_")).values()
        (threads,) = client.run(lambda: os.environ.get("OMP_NUM_THREADS")).values()
        assert trim is None and threads == "1"
        assert client.cluster.scheduler.http_server.port != 8787
    finally:
        cluster = client.cluster
        client.close()
        cluster.close()


def test_an_interrupt_keeps_the_chunks_solved_before_it(client, rods):
    # Ctrl-C (or SIGTERM, made one) while the cluster works: the chunks that came back are
    # kept whole, the others cancelled, the status says interrupted
    from mechdsl.compiled.variants import Overrides
    from mechdsl.study import solve_sweep

    ov = Overrides(sweeps={"l": LS}, t1=0.5)

    def interrupt(done: int, total: int) -> None:
        raise KeyboardInterrupt

    there = solve_sweep(rods, ov, chunk=4, client=client, progress=interrupt)
    here = solve_sweep(rods, ov, chunk=4)
    assert there.status == "interrupted"
    K = len(here.times)
    whole = there.n_solved == K
    assert 1 <= whole.sum() < len(LS) and set(there.n_solved) <= {0, K}
    assert whole.sum() % 4 == 0  # whole chunks
    for label in here.labels:
        assert same(there.data[label][whole], here.data[label][whole])
        assert np.isnan(there.data[label][~whole]).all()
