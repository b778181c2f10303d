"""The mechdsl command, end to end, through a subprocess (real entry-point discovery)."""

import csv
import io
import subprocess
import sys

import numpy as np
import pytest

from closed_forms import slider_crank
from conftest import EXAMPLES, ROOT

SLIDER_CRANK = str(EXAMPLES / "slider_crank.mech")


def mechdsl(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd or ROOT, timeout=120)


def read_csv(text):
    """Header and rows of a CSV, its comment lines (the units) skipped."""
    rows = [r for r in csv.reader(io.StringIO(text)) if not r[0].startswith("#")]
    return rows[0], np.array(rows[1:], dtype=float)


def test_run_writes_the_seed_validation_case(tmp_path):
    out = tmp_path / "out.csv"
    r = mechdsl("run", SLIDER_CRANK, "-o", out)
    assert r.returncode == 0, r.stderr
    header, rows = read_csv(out.read_text())
    assert header == ["t", "slider.x", "slider.vx", "slider.ax"]
    assert rows.shape == (1001, 4)
    t = rows[:, 0]
    np.testing.assert_allclose(t, np.linspace(0, 1, 1001), atol=1e-15)
    for col, exact in zip(rows[:, 1:].T, slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * t,
                                                        4 * np.pi, 0.0)):
        assert np.abs(col - exact).max() / np.abs(exact).max() < 1e-9
    lines = out.read_text().splitlines()
    assert lines[1] == "# units: t [s], slider.x [m], slider.vx [m/s], slider.ax [m/s^2]"
    # each number the shortest text that reads back to the same double
    assert lines[2].split(",")[0] == "0.0" and lines[3].split(",")[0] == "0.001"
    assert all(repr(float(x)) == x for line in lines[2:] for x in line.split(","))


def test_summary_without_output_file():
    r = mechdsl("run", SLIDER_CRANK)
    assert r.returncode == 0, r.stderr
    assert "1001 of 1001 instants" in r.stdout and "largest constraint residual" in r.stdout
    assert "slider.vx" in r.stdout


def test_csv_to_standard_output_with_set_and_sweep():
    r = mechdsl("run", SLIDER_CRANK, "-o", "-", "--set", "omega=2*pi", "--sweep", "l=3.5,3",
                "--t1", "0.1", "--step", "0.05")
    assert r.returncode == 0, r.stderr
    header, rows = read_csv(r.stdout)
    assert header == ["l", "t", "slider.x", "slider.vx", "slider.ax"]
    np.testing.assert_array_equal(rows[:, 0], [3.5, 3.5, 3.5, 3, 3, 3])
    for l in (3.5, 3.0):
        sel = rows[rows[:, 0] == l]
        x, v, _ = slider_crank(2.0, l, np.pi / 4 + 2 * np.pi * sel[:, 1], 2 * np.pi, 0.0)
        np.testing.assert_allclose(sel[:, 2], x, rtol=1e-13)
        np.testing.assert_allclose(sel[:, 3], v, rtol=1e-12)


def test_plot_is_written(tmp_path):
    png = tmp_path / "out.png"
    r = mechdsl("run", SLIDER_CRANK, "--plot", png, "-q", "-o", tmp_path / "o.csv")
    assert r.returncode == 0, r.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_user_errors_exit_1_with_location_caret_and_no_traceback(tmp_path):
    bad = tmp_path / "bad.mech"
    bad.write_text(open(SLIDER_CRANK).read().replace("joint B: revolute(crank.B",
                                                     "joint B: revolut(crank.B"))
    r = mechdsl("run", bad)
    assert r.returncode == 1
    lines = r.stderr.splitlines()
    assert lines[0] == f"{bad}:24:10: error: unknown joint type 'revolut'; did you mean 'revolute'?"
    assert lines[1].endswith("| joint B: revolut(crank.B, rod.B)")
    assert lines[2].endswith("|          ^^^^^^^")
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("args, message", [
    (["run", "missing.mech"], "cannot read missing.mech"),
    (["run", SLIDER_CRANK, "--set", "L=2"], "cannot set 'L': there is no param of that name; did you mean 'l'?"),
    (["run", SLIDER_CRANK, "--set", "l=2*"], "--set l:1:3: error: unexpected end of file"),
    # the name is checked before its value: the value's text is not the mistake
    (["run", SLIDER_CRANK, "--set", "method=radau"],
     "--set: cannot set 'method': there is no param of that name"),
    (["run", SLIDER_CRANK, "--sweep", "L=r,2*r"],
     "--sweep: cannot sweep 'L': there is no param of that name; did you mean 'l'?"),
    (["run", SLIDER_CRANK, "--set", "l"], "--set takes NAME=VALUE"),
    (["run", SLIDER_CRANK, "--step", "0"], "the simulated time step must be positive"),
    (["run", SLIDER_CRANK, "--bogus"], "unrecognized arguments: --bogus"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
])
def test_bad_command_lines_exit_1(args, message):
    r = mechdsl(*args)
    assert r.returncode == 1, r.stderr
    assert message in r.stderr
    assert "Traceback" not in r.stderr


def test_lock_up_exits_2_naming_the_instant_and_keeps_the_solved_instants(tmp_path):
    out = tmp_path / "out.csv"
    r = mechdsl("run", SLIDER_CRANK, "--set", "l=1.5", "-o", out)
    assert r.returncode == 2
    assert f"{SLIDER_CRANK}: error: no configuration satisfies the constraints at t = 0.005" in r.stderr
    assert "joint B (revolute, line 24: " in r.stderr
    assert "the 5 instants solved before the failure are in" in r.stderr
    header, rows = read_csv(out.read_text())
    assert rows.shape == (5, 4)
    x, _, _ = slider_crank(2.0, 1.5, np.pi / 4 + 4 * np.pi * rows[:, 0], 0, 0)
    np.testing.assert_allclose(rows[:, 1], x, rtol=1e-13)


def test_check_reports_structure_and_assembly():
    r = mechdsl("check", SLIDER_CRANK)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == (f"{SLIDER_CRANK}: 3 moving bodies (9 coordinates); 4 joints "
                        "(8 equations) and 1 drive")
    assert "joint D" in r.stdout and "prismatic" in r.stdout and "2 equations" in r.stdout
    assert "= pi/4 + omega*t" in r.stdout
    # one count, by rank, said once
    assert [x for x in lines if "mobility" in x or "freedom" in x] == [
        "mobility 1 = 9 coordinates - 8 independent joint equations (8 in all, rank of Phi_q "
        "at the assembled configuration); 1 drive: fully driven"]
    assert lines[-1].startswith("ok: assembles at t = 0; scaled Jacobian condition number")


def test_check_of_a_redundant_mechanism_counts_by_rank_once():
    r = mechdsl("check", EXAMPLES / "parallelogram.mech")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].endswith(": 4 moving bodies (12 coordinates); 6 joints (12 equations) and "
                             "1 drive")
    assert [x for x in lines if "mobility" in x or "freedom" in x] == [
        "mobility 1 = 12 coordinates - 11 independent joint equations (12 in all, 1 redundant, "
        "rank of Phi_q at the assembled configuration); 1 drive: fully driven"]
    assert "redundant: joint A3 (1 of 2 equations, line 20)" in lines


def test_check_of_an_underdriven_mechanism_exits_1(tmp_path):
    f = tmp_path / "free.mech"
    f.write_text(open(SLIDER_CRANK).read().replace("drive crank_angle", "# drive crank_angle"))
    r = mechdsl("check", f)
    assert r.returncode == 1
    assert "1 degree of freedom" in r.stderr


def test_plugins_are_discovered_through_entry_points():
    r = mechdsl("plugins")
    assert r.returncode == 0, r.stderr
    assert "revolute(p1: point, p2: point)" in r.stdout
    assert "prismatic(p1: point, p2: point, axis: vector = (1, 0), angle: scalar = 0)" in r.stdout
    assert "[mechdsl-revolute 0.1.0]" in r.stdout and "[mechdsl-prismatic 0.1.0]" in r.stdout
    for drive in ("angle(body: body)", "x(point: point)", "y(point: point)",
                  "rel_angle(body1: body, body2: body)", "distance(p1: point, p2: point)"):
        assert drive in r.stdout


def test_a_run_imports_only_the_plugins_and_libraries_it_needs():
    code = ("import sys, mechdsl.cli as c; c.main(['run', %r, '-o', '-']);"
            "print(sorted(m for m in sys.modules if m.startswith(('mechdsl_', 'matplotlib', "
            "'meshio', 'scipy'))), file=sys.stderr)") % SLIDER_CRANK
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.stderr.strip().splitlines()[-1] == \
        "['mechdsl_drives', 'mechdsl_prismatic', 'mechdsl_revolute']"


def test_the_command_freezes_its_imports_and_main_leaves_a_host_collectable():
    """The command (``python -m mechdsl``, the console script: mechdsl.cli.entry) keeps the
    objects of its imports out of the cyclic collector (gc.freeze); main() called by a
    program does not: a reference cycle the program dropped before it is still collected
    after it (found in review: freezing in main() kept a test session's garbage)."""
    code = ("import gc, sys, weakref, mechdsl.cli as c\n"
            "class Node: pass\n"
            "a = Node(); a.me = a; gone = weakref.ref(a); del a\n"
            "c.main(['--version'])\n"
            "gc.collect(); print(gc.get_freeze_count(), gone() is None, file=sys.stderr)\n"
            "try:\n    c.entry()\nexcept SystemExit:\n    pass\n"
            "print(gc.get_freeze_count() > 0, file=sys.stderr)\n")
    r = subprocess.run([sys.executable, "-c", code, "--version"], capture_output=True,
                       text=True, cwd=ROOT)
    assert r.stderr.strip().splitlines()[-2:] == ["0 True", "True"], r.stderr[-500:]


def test_a_small_forward_dynamics_does_not_import_scipy_sparse(tmp_path):
    """The stiff pendulum (two bodies, stiff enough that the run goes on with radau in its
    joints' coordinates) runs with no sparse matrix: scipy.sparse, 25 to 35 ms of the
    process's start-up, is not imported (it was, by the augmented Lagrangian's plan and
    product kernels and radau's type tests, none of which a small model needs)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "dynamics_models", ROOT / "benchmarks" / "dynamics_models.py")
    dm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(dm)
    model = tmp_path / "stiff.mech"
    model.write_text(dm.stiff_pendulum_text(1e8, rtol=1e-6, atol=1e-8))
    code = ("import sys, mechdsl.cli as c; c.main(['run', %r, '-o', %r, '-q']);"
            "print(sorted(m for m in sys.modules if m.startswith('scipy.sparse')) or 'none',"
            " file=sys.stderr)") % (str(model), str(tmp_path / "o.csv"))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.stderr.strip().splitlines()[-1] == "none", r.stderr[-500:]
    text = (tmp_path / "o.csv").read_text()
    assert text.count("\n") > 200  # (the run was made: 201 instants)


def test_a_model_with_forces_imports_only_the_force_plugin_beside_its_joints():
    # the force types have one entry point each, as the joints do: naming `spring` must not
    # make the registry load every installed plugin to find it
    code = ("import sys, mechdsl.cli as c; c.main(['check', %r]);"
            "print(sorted(m for m in sys.modules if m.startswith('mechdsl_')), file=sys.stderr)"
            ) % str(ROOT / "examples" / "andrews.mech")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    loaded = r.stderr.strip().splitlines()[-1]
    assert "'mechdsl_forces'" in loaded and "'mechdsl_revolute'" in loaded
    assert "mechdsl_cams" not in loaded and "mechdsl_gears" not in loaded, loaded
