"""What mechdsl writes never harms what is there: no output over the model, over a file the
model reads or over another output; every file written atomically, with the mode a plain
open() gives, through symbolic links, and no temporary file left whatever happens; every
failure and every signal (SIGINT, SIGTERM, while solving or while writing) leaves a complete
CSV of what was solved; options checked; standard output's failures reported, a closed pipe
quietly. Each test checks exit statuses, messages, file contents and modes against what they
must be (closed forms, the arrays written, the umask), never against earlier output."""

from __future__ import annotations

import csv
import io
import os
import pty
import re
import select
import signal
import stat
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from closed_forms import slider_crank
from conftest import EXAMPLES, ROOT

SLIDER = EXAMPLES / "slider_crank.mech"
OMEGA = 4 * np.pi


def _default_signals() -> None:
    """In the child: SIGINT and SIGTERM as a shell in the foreground gives them (a test run
    started in the background would pass SIGINT on ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def cli(*args, cwd=ROOT, umask: int | None = None, **kwargs) -> subprocess.CompletedProcess:
    def setup():
        _default_signals()
        if umask is not None:
            os.umask(umask)

    kwargs.setdefault("capture_output", True)
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)], text=True,
                          cwd=cwd, timeout=300, preexec_fn=setup, **kwargs)


def csv_rows(text: str) -> tuple[list[str], np.ndarray]:
    """Header and rows of a CSV (its comment lines, the units, skipped); every row must have
    every column."""
    assert text.endswith("\n")
    rows = [r for r in csv.reader(io.StringIO(text)) if not r[0].startswith("#")]
    assert all(len(r) == len(rows[0]) for r in rows), "a row lacks columns"
    return rows[0], np.array(rows[1:], dtype=float).reshape(-1, len(rows[0]))


def assert_slider_crank(rows: np.ndarray, step: float = 0.001) -> None:
    """Rows t, slider.x, ... of examples/slider_crank.mech: consecutive instants from 0,
    positions equal to the closed form."""
    t = rows[:, 0]
    np.testing.assert_allclose(t, step * np.arange(len(t)), atol=1e-9)
    x, _, _ = slider_crank(2.0, 3.5, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
    np.testing.assert_allclose(rows[:, 1], x, atol=1e-11)


def hidden(folder) -> list[str]:
    """Files whose name starts with a dot: where temporary files would be left."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# -- 1. outputs never destroy inputs -----------------------------------------------------------

@pytest.fixture
def model(tmp_path):
    f = tmp_path / "model.mech"
    f.write_text(SLIDER.read_text())
    return f


@pytest.mark.parametrize("spelling", ["same", "dot", "symlink", "hardlink"])
def test_an_output_over_the_model_is_refused_before_solving(model, spelling):
    folder = model.parent
    name = {"same": "model.mech", "dot": "./sub/../model.mech", "symlink": "link.csv",
            "hardlink": "hard.csv"}[spelling]
    (folder / "sub").mkdir()
    if spelling == "symlink":
        (folder / "link.csv").symlink_to("model.mech")
    if spelling == "hardlink":
        os.link(model, folder / "hard.csv")
    before = model.read_bytes()
    r = cli("run", "model.mech", "-o", name, cwd=folder)
    assert r.returncode == 1
    assert r.stderr == (f"mechdsl: error: -o {name} would overwrite the model file model.mech; "
                        "choose another file name\n")
    assert model.read_bytes() == before
    assert hidden(folder) == []


@pytest.mark.parametrize("args, message", [
    (["-o", "r.png", "--plot", "r.png"], "--plot r.png would overwrite the output of -o r.png"),
    (["--plot", "a.png", "--snapshot", "./a.png"],
     "--snapshot ./a.png would overwrite the output of --plot a.png"),
    (["-o", "a.gif", "--animate", "a.gif"], "--animate a.gif would overwrite the output of -o "
                                           "a.gif"),
    (["-o", "e_0003.vtu", "--export", "e.vtu"],
     "--export e.vtu would overwrite the output of -o e_0003.vtu"),
    (["-o", "e.pvd", "--export", "e.vtu"], "--export e.vtu would overwrite the output of -o "
                                          "e.pvd"),
    (["-o", "e_v1.xdmf", "--export", "e.xdmf", "--sweep", "l=3,3.5"],
     "--export e.xdmf would overwrite the output of -o e_v1.xdmf"),
    (["-o", "e_v0_0010.vtu", "--export", "e.vtu", "--sweep", "l=3,3.5"],
     "--export e.vtu would overwrite the output of -o e_v0_0010.vtu"),
])
def test_two_outputs_on_one_file_are_refused_before_solving(model, args, message):
    r = cli("run", "model.mech", "--t1", "0.01", *args, cwd=model.parent)
    assert r.returncode == 1
    assert r.stderr == f"mechdsl: error: {message}; give each output its own file name\n"
    assert sorted(p.name for p in model.parent.iterdir()) == ["model.mech"]


def test_files_an_export_does_not_write_are_free(model):
    # 11 instants: e_0000.vtu .. e_0010.vtu; e_0011.vtu and e_v0_0000.vtu are other files
    r = cli("run", "model.mech", "--t1", "0.01", "--export", "e.vtu", "-o", "e_0011.vtu",
            "--plot", "e_v0_0000.png", cwd=model.parent)
    assert r.returncode == 0, r.stderr
    assert (model.parent / "e_0010.vtu").exists() and (model.parent / "e.pvd").exists()


def test_an_export_file_linked_to_the_model_is_refused(model):
    (model.parent / "e_0002.vtu").symlink_to("model.mech")
    r = cli("run", "model.mech", "--t1", "0.01", "--export", "e.vtu", cwd=model.parent)
    assert r.returncode == 1
    assert r.stderr == ("mechdsl: error: --export e.vtu would overwrite the model file "
                        "model.mech (it writes e_0002.vtu); choose another file name\n")
    assert model.read_text() == SLIDER.read_text()


@pytest.mark.parametrize("example, data", [("cam_roller.mech", "data/cam_pitch.csv"),
                                           ("fourbar_coupler.mech", "data/plate.msh")])
def test_an_output_over_a_file_the_model_reads_is_refused(tmp_path, example, data):
    (tmp_path / "data").mkdir()
    (tmp_path / example).write_text((EXAMPLES / example).read_text())
    (tmp_path / data).write_bytes((EXAMPLES / data).read_bytes())
    r = cli("run", example, "-o", f"./{data}", cwd=tmp_path)
    assert r.returncode == 1
    assert r.stderr == (f"mechdsl: error: -o ./{data} would overwrite the model's data file "
                        f"{os.path.realpath(tmp_path / data)}; choose another file name\n")
    assert (tmp_path / data).read_bytes() == (EXAMPLES / data).read_bytes()


def test_an_output_over_a_table_a_set_value_reads_is_refused(model):
    table = model.parent / "speed.csv"
    table.write_text("0, 1\n1, 2\n")
    r = cli("run", "model.mech", "--set", 'omega=table("speed.csv", 0.5)', "-o", "speed.csv",
            cwd=model.parent)
    assert r.returncode == 1
    assert r.stderr == ("mechdsl: error: -o speed.csv would overwrite a table file of --set or "
                        f"--sweep {os.path.realpath(table)}; choose another file name\n")
    assert table.read_text() == "0, 1\n1, 2\n"


def test_plot_of_a_csv_over_itself_is_refused(tmp_path):
    out = tmp_path / "out.csv"
    assert cli("run", SLIDER, "--t1", "0.01", "-o", out).returncode == 0
    before = out.read_bytes()
    r = cli("plot", "out.csv", "-o", "./out.csv", cwd=tmp_path)
    assert r.returncode == 1
    assert r.stderr == ("mechdsl: error: -o ./out.csv would overwrite the CSV file out.csv; "
                        "choose another file name\n")
    assert out.read_bytes() == before


# -- 2. atomic writes, modes, links ------------------------------------------------------------

def test_new_files_get_the_mode_open_gives_and_existing_files_keep_theirs(tmp_path):
    outputs = ["out.csv", "plot.png", "snap.png", "anim.gif", "e.xdmf"]
    r = cli("run", SLIDER, "--t1", "0.02", "-o", "out.csv", "--plot", "plot.png",
            "--snapshot", "snap.png", "--animate", "anim.gif", "--frames", "3", "--export",
            "e.xdmf", "-q", cwd=tmp_path, umask=0o027)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(outputs)
    for name in outputs:
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o666 & ~0o027, name
    r = cli("run", SLIDER, "--t1", "0.02", "--export", "v.vtu", "-q", cwd=tmp_path, umask=0o002)
    assert r.returncode == 0, r.stderr
    for p in tmp_path.glob("v*"):
        assert stat.S_IMODE(p.stat().st_mode) == 0o664, p.name
    # existing files keep their modes, whatever the umask
    os.chmod(tmp_path / "out.csv", 0o604)
    os.chmod(tmp_path / "plot.png", 0o600)
    r = cli("run", SLIDER, "--t1", "0.01", "-o", "out.csv", "--plot", "plot.png", "-q",
            cwd=tmp_path, umask=0o077)
    assert r.returncode == 0, r.stderr
    assert stat.S_IMODE((tmp_path / "out.csv").stat().st_mode) == 0o604
    assert stat.S_IMODE((tmp_path / "plot.png").stat().st_mode) == 0o600
    assert len(csv_rows((tmp_path / "out.csv").read_text())[1]) == 11  # the new content
    assert hidden(tmp_path) == []


def test_a_symbolic_link_is_written_through(tmp_path):
    real = tmp_path / "results"
    real.mkdir()
    (real / "old.csv").write_text("old\n")
    (tmp_path / "link.csv").symlink_to("results/old.csv")
    (tmp_path / "pic.png").symlink_to("results/new.png")  # dangling: created, as open() does
    r = cli("run", SLIDER, "--t1", "0.01", "-o", "link.csv", "--plot", "pic.png", "-q",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert os.readlink(tmp_path / "link.csv") == "results/old.csv"
    assert os.readlink(tmp_path / "pic.png") == "results/new.png"
    assert_slider_crank(csv_rows((real / "old.csv").read_text())[1])
    assert (real / "new.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert hidden(tmp_path) == [] and hidden(real) == []


def test_a_device_is_written_in_place(tmp_path):
    r = cli("run", SLIDER, "--t1", "0.01", "-o", os.devnull, "--plot", "p.png", "-q",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.png"]


def test_a_read_only_output_is_refused_as_open_would(tmp_path):
    out = tmp_path / "out.csv"
    out.write_text("keep\n")
    out.chmod(0o444)
    r = cli("run", SLIDER, "-o", out)
    if os.access(out, os.W_OK):  # root: open() would write it too, and so does mechdsl
        assert r.returncode == 0
        assert stat.S_IMODE(out.stat().st_mode) == 0o444
    else:
        assert r.returncode == 1
        assert r.stderr == f"mechdsl: error: -o {out}: the file is read-only\n"
        assert out.read_text() == "keep\n"


@pytest.mark.parametrize("failure", [RuntimeError, KeyboardInterrupt])
def test_an_atomic_write_that_fails_leaves_the_old_file_and_no_temporary(tmp_path, failure):
    from mechdsl.writing import atomic_path

    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with pytest.raises(failure):
        with atomic_path(target) as tmp:
            with open(tmp, "w") as f:
                f.write("half")
            raise failure("stop")
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_an_atomic_write_of_a_new_file_gets_the_mode_open_gives(tmp_path):
    from mechdsl.writing import write_text

    write_text(tmp_path / "new.csv", lambda f: f.write("a\n"))
    open(tmp_path / "plain.csv", "w").close()
    assert stat.S_IMODE((tmp_path / "new.csv").stat().st_mode) == 0o666 & ~umask()
    assert (stat.S_IMODE((tmp_path / "new.csv").stat().st_mode)
            == stat.S_IMODE((tmp_path / "plain.csv").stat().st_mode))


# -- 3. every failure keeps what was solved ----------------------------------------------------

FRAGILE = '''
    import numpy as np
    from mechdsl.plugins import Arg, ConstraintType, hookimpl

    LIMIT = np.pi / 4 + 4 * np.pi * 0.0565  # the crank's angle between instants 57 and 58

    class Fragile(ConstraintType):
        """A revolute joint whose equations are not defined once the first body's angle
        passes LIMIT (the square root of a negative number)."""
        name = "fragile"
        signature = (Arg("p1", "point"), Arg("p2", "point"))
        n_eq = 2

        def equations(self, bodies, args):
            d = bodies[0].point(args.p1) - bodies[1].point(args.p2)
            w = np.sqrt(LIMIT - bodies[0].phi)
            return d.x * w / w, d.y

    @hookimpl
    def mechdsl_constraint_types():
        return [Fragile()]
'''


def test_equations_undefined_mid_run_write_the_csv_then_the_error(tmp_path):
    # a plugin's code runs only when the model is compiled; what can still stop a run midway
    # is arithmetic leaving its domain: everything solved before is written, complete
    site = tmp_path / "site"
    site.mkdir()
    (site / "mechdsl_fragile.py").write_text(textwrap.dedent(FRAGILE))
    info = site / "mechdsl_fragile-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: mechdsl-fragile\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[mechdsl]\nfragile = mechdsl_fragile\n")
    f = tmp_path / "s.mech"
    f.write_text(SLIDER.read_text().replace("joint B: revolute", "joint B: fragile"))
    out = tmp_path / "out.csv"
    r = cli("run", f, "-o", out, env={**os.environ, "PYTHONPATH": str(site)})
    assert r.returncode == 2
    assert ("error: the equations of joint B (fragile, line 24) are not defined (not a number)"
            in r.stderr), r.stderr
    assert f"  note: the 57 instants solved before the failure are in {out}\n" in r.stderr
    header, rows = csv_rows(out.read_text())
    assert header == ["t", "slider.x", "slider.vx", "slider.ax"] and len(rows) == 57
    assert_slider_crank(rows)
    assert "Traceback" not in r.stderr


def start_solving(args, cwd=ROOT, **kwargs) -> tuple[subprocess.Popen, int]:
    """Start ``python -m mechdsl run ARGS`` with standard error on a terminal and return once
    it is solving: the progress bar, which a run draws on a terminal after its first second,
    is the sign. Returns the process and the terminal's reading end."""
    reader, writer = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "mechdsl", "run", *map(str, args)],
                            cwd=cwd, stderr=writer, preexec_fn=_default_signals, **kwargs)
    os.close(writer)
    seen = b""
    while b" instants, " not in seen:
        ready, _, _ = select.select([reader], [], [], 120)
        assert ready, f"no progress bar: {seen!r}"
        seen += os.read(reader, 4096)
    return proc, reader


def finish(proc: subprocess.Popen, reader: int) -> str:
    """Wait for the process; what it wrote on the terminal after the progress bar."""
    seen = b""
    while True:
        ready, _, _ = select.select([reader], [], [], 300)
        assert ready, "the process does not end"
        try:
            chunk = os.read(reader, 4096)
        except OSError:  # EIO: the process closed the terminal
            break
        if not chunk:
            break
        seen += chunk
    os.close(reader)
    proc.wait(timeout=300)
    return seen.decode().replace("\r\n", "\n").split("\r")[-1]


@pytest.mark.parametrize("signum, status, verb", [(signal.SIGINT, 130, "interrupted"),
                                                  (signal.SIGTERM, 143, "terminated")])
def test_a_signal_while_solving_keeps_a_complete_csv_of_the_instants_solved(
        tmp_path, signum, status, verb):
    out = tmp_path / "out.csv"
    out.write_text("the previous run\n")
    proc, reader = start_solving([SLIDER, "--t1", "2000", "-o", out, "--plot",
                                  tmp_path / "p.png"])
    proc.send_signal(signum)
    stderr = finish(proc, reader)
    assert proc.returncode == status, stderr
    m = re.search(rf"^mechdsl: {verb}; the (\d+) instants solved so far are in "
                  rf"{re.escape(str(out))}$", stderr, re.M)
    assert m, stderr
    header, rows = csv_rows(out.read_text())
    assert header == ["t", "slider.x", "slider.vx", "slider.ax"]
    assert 0 < len(rows) == int(m.group(1)) < 2_000_001
    assert_slider_crank(rows)
    assert (tmp_path / "p.png").exists()  # the plot of the instants solved, too
    assert "Traceback" not in stderr and hidden(tmp_path) == []


# A deterministic hook in a wrapper process: the CSV writer sends the process a real signal
# when it has written a few chunks, so that the signal comes in the middle of the CSV.
SIGNAL_WHILE_WRITING = '''
import os, signal, sys
import mechdsl.outputs.csv as results

results.CHUNK_VALUES = 40  # ten rows a chunk: many writes
write_rows = results.write_rows

class Signalling:
    def __init__(self, f):
        self.f, self.writes = f, 0

    def write(self, text):
        self.writes += 1
        if self.writes == 5:
            os.kill(os.getpid(), signal.%s)
        return self.f.write(text)

results.write_rows = lambda res, f: write_rows(res, Signalling(f))
from mechdsl.cli import main
sys.exit(main(sys.argv[1:]))
'''


@pytest.mark.parametrize("signame, status, verb", [("SIGTERM", 143, "terminated"),
                                                   ("SIGINT", 130, "interrupted")])
@pytest.mark.parametrize("to_stdout", [False, True])
def test_a_signal_while_the_csv_is_written_waits_for_the_whole_csv(
        tmp_path, signame, status, verb, to_stdout):
    out = tmp_path / "out.csv"
    out.write_text("the previous run\n")
    r = subprocess.run([sys.executable, "-c", SIGNAL_WHILE_WRITING % signame, "run", SLIDER,
                        "-o", "-" if to_stdout else out, "--plot", tmp_path / "p.png"],
                       capture_output=True, text=True, cwd=ROOT, timeout=300,
                       preexec_fn=_default_signals)
    assert r.returncode == status, r.stderr
    where = "on standard output" if to_stdout else f"in {out}"
    assert r.stderr == (f"mechdsl: {verb}; the 1001 instants solved so far are {where}; "
                        f"not written: {tmp_path / 'p.png'}\n")
    header, rows = csv_rows(r.stdout if to_stdout else out.read_text())
    assert len(rows) == 1001
    assert_slider_crank(rows)
    assert not (tmp_path / "p.png").exists()
    assert hidden(tmp_path) == []


def test_an_interrupt_during_a_long_animation_keeps_the_csv_and_leaves_no_temporary(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "mechdsl", "run", SLIDER, "--t1", "100", "--step", "0.01",
         "-o", "out.csv", "--animate", "anim.gif", "--frames", "300"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=_default_signals)
    # the animation is written under a temporary name (.anim.*.gif, beside it): once it is
    # there, the CSV is complete and frames are being drawn
    deadline = time.monotonic() + 300
    while not [name for name in hidden(tmp_path) if name.endswith(".gif")]:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the animation did not start"
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 130, stderr
    assert stderr == ("mechdsl: interrupted; the 10001 instants solved so far are in out.csv; "
                      "not written: anim.gif\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]
    rows = csv_rows((tmp_path / "out.csv").read_text())[1]
    assert len(rows) == 10001
    assert_slider_crank(rows, step=0.01)


def test_the_signal_guard_holds_signals_and_raises_them_after(monkeypatch):
    from mechdsl.writing import Interrupted, SignalGuard, exit_status

    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        with SignalGuard() as guard:
            done = []
            with pytest.raises(Interrupted) as err:
                with guard.held():
                    os.kill(os.getpid(), signal.SIGTERM)
                    done.append("the rest of the block")
            assert done == ["the rest of the block"]
            assert err.value.signum == signal.SIGTERM and exit_status(err.value) == 143
            assert isinstance(err.value, KeyboardInterrupt)
            # the run is stopping: a second signal must not cut short what it still writes
            guard.received = None
            os.kill(os.getpid(), signal.SIGTERM)
            assert guard.received == signal.SIGTERM
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
        with SignalGuard():
            with pytest.raises(Interrupted):
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(60)  # not reached: the handler raises at once
    finally:
        signal.signal(signal.SIGTERM, previous)


# -- 4. the CSV writer streams ----------------------------------------------------------------

def fake_results(k: int, sweep: bool = False):
    from mechdsl.results import Results

    rng = np.random.default_rng(k)
    V = 3 if sweep else 1
    n_solved = np.array([k, k // 3, 0])[:V]
    data = {"a.x": rng.standard_normal((V, k)) * 1e3, "a.vx": rng.standard_normal((V, k)) / 7}
    for v in range(V):
        for a in data.values():
            a[v, n_solved[v]:] = np.nan
    return Results(times=np.linspace(0, 1, k), data=data,
                   sweep={"l": np.array([2.5, 3.0, 1 / 3])[:V]} if sweep else {},
                   n_solved=n_solved, status="ok", messages=(), solve_time=0.0,
                   residual=0.0, source_name="fake.mech")


@pytest.mark.parametrize("chunk", [1, 7, 2**16])
def test_the_streamed_csv_holds_the_results_exactly(tmp_path, monkeypatch, chunk):
    import mechdsl.outputs.csv
    from mechdsl.outputs.csv import write_csv

    monkeypatch.setattr(mechdsl.outputs.csv, "CHUNK_VALUES", chunk)
    res = fake_results(1000, sweep=True)
    write_csv(res, tmp_path / "out.csv")
    header, rows = csv_rows((tmp_path / "out.csv").read_text())
    assert header == ["l", "t", "a.x", "a.vx"]
    assert len(rows) == 1000 + 333
    first, second = rows[:1000], rows[1000:]
    assert (first[:, 0] == 2.5).all() and (second[:, 0] == 3.0).all()
    for block, v in ((first, 0), (second, 1)):
        k = len(block)
        assert np.array_equal(block[:, 1], res.times[:k])  # exactly: repr round-trips
        assert np.array_equal(block[:, 2], res.data["a.x"][v, :k])
        assert np.array_equal(block[:, 3], res.data["a.vx"][v, :k])


def test_the_csv_writer_holds_bounded_memory(tmp_path):
    import tracemalloc

    from mechdsl.outputs.csv import write_csv

    peaks = {}
    for k in (100_000, 400_000):
        res = fake_results(k)
        tracemalloc.start()
        write_csv(res, tmp_path / "out.csv")
        peaks[k] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert len((tmp_path / "out.csv").read_text().splitlines()) == k + 1
    # the rows alone are 3.2 and 12.8 MB as numbers, about 15 and 60 MB as text
    assert peaks[400_000] < 1.25 * peaks[100_000]
    assert peaks[400_000] < 8 * 2**20


# -- 5. options -------------------------------------------------------------------------------

@pytest.mark.parametrize("args, message", [
    (["--animate", "a.gif", "--frames", "0"], "mechdsl: error: --frames 0: an animation needs "
                                              "at least 2 frames"),
    (["--animate", "a.gif", "--frames", "-5"], "mechdsl: error: --frames -5: an animation "
                                               "needs at least 2 frames"),
    (["--animate", "a.gif", "--frames", "1"], "mechdsl: error: --frames 1: an animation needs "
                                              "at least 2 frames"),
    (["--snapshot", "s.png", "--at", "0,nan"], "mechdsl: error: --at 0,nan: nan is not a time; "
                                               "give finite numbers"),
    (["--snapshot", "s.png", "--at", "inf"], "mechdsl: error: --at inf: inf is not a time; "
                                             "give finite numbers"),
    (["--snapshot", "s.png", "--at", "0.5,1.5"], "mechdsl: error: --at 1.5: outside the run, "
                                                 "which goes from t = 0 to t = 1"),
    (["--snapshot", "s.png", "--at", "-0.1"], "mechdsl: error: --at -0.1: outside the run, "
                                              "which goes from t = 0 to t = 1"),
    (["--t0", "nan"], "mechdsl: error: --t0: the start time is nan"),
    (["--t1", "inf"], "mechdsl: error: --t1: the end time is inf"),
    (["--step", "nan"], "mechdsl: error: --step: the step is nan"),
])
def test_bad_option_values_are_errors_before_solving(tmp_path, args, message):
    r = cli("run", SLIDER, "-o", "out.csv", *args, cwd=tmp_path)
    assert r.returncode == 1
    assert message in r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert list(tmp_path.iterdir()) == []


def svg_texts(path) -> list[str]:
    """The texts of an SVG written by matplotlib, which leaves each as a comment."""
    import html

    return [html.unescape(t) for t in re.findall(r"<!-- (.*?) -->", path.read_text())]


def test_texts_with_dollars_and_backslashes_are_drawn_as_written(tmp_path):
    unit = r"$\frac{a}$"
    name = "a$b\\c$.mech"
    text = SLIDER.read_text().replace('units length = "m", time = "s"',
                                      f'units length = "{unit}", time = "$x^$"')
    (tmp_path / name).write_text(text)
    r = cli("run", name, "--t1", "0.1", "--set", "omega=4*pi",
            "--sweep", "l=3.5,3", "--plot", "p.svg", "--snapshot", "s.svg", "--animate",
            "a.gif", "--frames", "2", "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    texts = svg_texts(tmp_path / "p.svg")
    assert f"slider.x [{unit}]" in texts
    assert f"slider.vx [{unit}/$x^$]" in texts
    assert "t [$x^$]" in texts
    assert f"{name} (omega = 4*pi)" in texts
    assert "l = 3.5" in texts
    assert any(t.startswith(f"{name}: t = 0, ") for t in svg_texts(tmp_path / "s.svg"))


# -- 6. standard output -----------------------------------------------------------------------

@pytest.mark.parametrize("command", [["run", SLIDER, "-o", "-"], ["run", SLIDER],
                                     ["check", SLIDER]])
def test_a_full_standard_output_is_an_error_without_traceback(command):
    with open("/dev/full", "w") as full:
        r = cli(*command, stdout=full, stderr=subprocess.PIPE, capture_output=False)
    assert r.returncode == 1
    assert r.stderr == ("mechdsl: error: cannot write to standard output: No space left on "
                        "device\n")


def test_a_closed_pipe_ends_quietly_with_141():
    proc = subprocess.Popen([sys.executable, "-m", "mechdsl", "run", SLIDER, "--t1", "10",
                             "-o", "-"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, preexec_fn=_default_signals)
    assert proc.stdout.readline() == b"t,slider.x,slider.vx,slider.ax\n"
    proc.stdout.close()  # as `| head -1` does: 10001 rows are far more than a pipe holds
    stderr = proc.stderr.read()
    proc.wait(timeout=300)
    assert proc.returncode == 141
    assert stderr == b""


# -- 7. python -m mechdsl ---------------------------------------------------------------------

def test_python_m_imports_nothing_from_the_current_folder(tmp_path):
    marker = tmp_path / "ran"
    # named like the installed plugin the model needs: found first if the folder were searched
    (tmp_path / "mechdsl_revolute.py").write_text(f"open({str(marker)!r}, 'w').close()\n")
    (tmp_path / "m.mech").write_text(SLIDER.read_text())
    r = cli("run", "m.mech", "--t1", "0.01", "-o", "out.csv", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert not marker.exists()
    assert_slider_crank(csv_rows((tmp_path / "out.csv").read_text())[1])


LATE_SIGNAL = {
    # a SIGTERM that lands just after the solver returned, before the CSV is written
    "after the solve": """
import mechdsl.commands as c
close = c.ProgressBar.close
def late_close(self):
    os.kill(os.getpid(), signal.SIGTERM)
    return close(self)
c.ProgressBar.close = late_close
""",
    # a SIGTERM that lands while the temporary file of the plot is being created
    "creating a temporary file": """
import mechdsl.writing as w
real_open = os.open
class OsProxy:
    def __getattr__(self, name): return getattr(os, name)
    def open(self, path, *a, **k):
        fd = real_open(path, *a, **k)
        if ".tmp" in str(path) and str(path).endswith(".png"):
            os.kill(os.getpid(), signal.SIGTERM)
        return fd
w.os = OsProxy()
""",
}


@pytest.mark.parametrize("when", list(LATE_SIGNAL))
def test_a_signal_at_an_awkward_moment_keeps_the_csv_and_leaves_no_temporary(tmp_path, when):
    script = ("import os, signal, sys\n" + LATE_SIGNAL[when]
              + "from mechdsl.cli import main\nsys.exit(main(sys.argv[1:]))\n")
    r = subprocess.run([sys.executable, "-c", script, "run", str(SLIDER), "-o", "out.csv",
                        "--plot", "p.png"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=120, preexec_fn=_default_signals)
    assert r.returncode == 143, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"], r.stderr
    rows = csv_rows((tmp_path / "out.csv").read_text())[1]
    assert len(rows) == 1001
    assert_slider_crank(rows)


def test_an_interrupt_that_a_drawing_library_turns_into_its_own_error_is_an_interrupt(
        tmp_path, monkeypatch, capsys):
    # an interrupt landing inside matplotlib's compiled code can come out as that code's
    # error (Agg's "Invalid bounding box"): after a signal, the picture's failure is the
    # interrupt (exit 130, the CSV whole, the picture not written), not an internal error
    import mechdsl.outputs.plot as plot
    from mechdsl.cli import main

    def interrupted_plot(results, path, **options):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)  # the handler raises here
        except KeyboardInterrupt:
            raise ValueError("Invalid bounding box") from None

    monkeypatch.setattr(plot, "plot_results", interrupted_plot)
    out, png = tmp_path / "out.csv", tmp_path / "p.png"
    code = main(["run", str(SLIDER), "--t1", "0.01", "-o", str(out), "--plot", str(png)])
    assert code == 130
    assert capsys.readouterr().err == (f"mechdsl: interrupted; the 11 instants solved so far "
                                       f"are in {out}; not written: {png}\n")
    assert len(csv_rows(out.read_text())[1]) == 11 and not png.exists()
    # without a signal, the same error is what it is: a failure of the program
    monkeypatch.setattr(plot, "plot_results", lambda *a, **k: (_ for _ in ()).throw(
        ValueError("Invalid bounding box")))
    assert main(["run", str(SLIDER), "--t1", "0.01", "-o", str(out), "--plot", str(png)]) == 3


def _model_reading(folder, table: str):
    """The seed's slider-crank in ``folder``/m.mech, its drive adding the values of the
    table file ``table`` (a path relative to the model): the model's data file."""
    folder.joinpath("m.mech").write_text(SLIDER.read_text().replace(
        "drive crank_angle: angle(crank) = pi/4 + omega*t",
        f'drive crank_angle: angle(crank) = pi/4 + omega*t + table("{table}", t)'))


def test_an_export_of_a_chunked_sweep_never_overwrites_a_later_variants_input(tmp_path):
    # a sweep cut into chunks is checked against the files of every variant, not only those
    # of the first chunk: variant 2's export would be the table the drive reads
    table = tmp_path / "motion_v2.xdmf"
    table.write_text("0, 0\n1, 0\n2, 0\n")
    _model_reading(tmp_path, "motion_v2.xdmf")
    r = subprocess.run([sys.executable, "-m", "mechdsl", "run", "m.mech", "--t1", "0.01",
                        "--sweep", "l=3,3.5,4", "--chunk", "1", "--export", "motion.xdmf"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 1
    assert "--export motion.xdmf would overwrite the model's data file" in r.stderr
    assert table.read_text() == "0, 0\n1, 0\n2, 0\n"


def test_a_store_is_never_replaced_over_a_file_the_model_reads_inside_it(tmp_path):
    # -o out.zarr replaces the whole folder of an earlier store: a table kept inside it
    # that the model reads is an input, and the run is refused before anything is written
    store = tmp_path / "out.zarr"
    r = subprocess.run([sys.executable, "-m", "mechdsl", "run", str(SLIDER), "--t1", "0.01",
                        "-o", str(store)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    table = store / "motion.csv"
    table.write_text("0, 0\n1, 0\n")
    _model_reading(tmp_path, "out.zarr/motion.csv")
    r = subprocess.run([sys.executable, "-m", "mechdsl", "run", "m.mech", "--t1", "0.01",
                        "-o", "out.zarr"], capture_output=True, text=True, cwd=tmp_path,
                       timeout=120)
    assert r.returncode == 1
    assert "-o out.zarr would overwrite the model's data file" in r.stderr
    assert table.read_text() == "0, 0\n1, 0\n"
