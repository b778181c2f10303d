"""The worked third-party plugin of docs/plugins.md: the guide shows its files as they are,
it packages with its entry point, and it is found and run like any installed plugin."""

import os
import subprocess
import sys
import zipfile

import numpy as np
from scipy.optimize import minimize_scalar
import pytest

from conftest import ROOT
from test_docs import code_blocks

PACKAGE = ROOT / "examples" / "plugins" / "curve_slot"
GUIDE = (ROOT / "docs" / "plugins.md").read_text()


@pytest.mark.parametrize("path", ["mechdsl_curve_slot/__init__.py", "pyproject.toml",
                                  "tests/test_curve_slot.py", "curve_slot.mech"])
def test_the_guide_shows_the_example_files_as_they_are(path):
    text = (PACKAGE / path).read_text()
    assert text.rstrip("\n") in [b.rstrip("\n") for b in code_blocks(GUIDE)]


def test_the_package_builds_with_its_entry_point(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                        "-q", "-w", str(tmp_path), str(PACKAGE)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    (wheel,) = tmp_path.glob("mechdsl_curve_slot-0.1.0-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        entry_points = z.read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "mechdsl_curve_slot/__init__.py" in names
    assert "[mechdsl]\ncurve_slot = mechdsl_curve_slot" in entry_points


def mechdsl(*args, env=None):
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, timeout=120, env={**os.environ, **(env or {})})


def test_the_installed_plugin_is_listed_with_its_distribution():
    r = mechdsl("plugins")
    assert "curve_slot(p1: point, p2: point, shape: function(x))" in r.stdout
    assert "[mechdsl-curve-slot 0.1.0]" in r.stdout


def exact_pin(t, a=0.8):
    """The pin on y = a x^2 in a disc turned by 0.5 t, at distance 0.2 + 0.3 t from its axle."""
    rho = 0.2 + 0.3 * t
    x = np.sqrt((-1 + np.sqrt(1 + 4 * a * a * rho * rho)) / (2 * a * a))
    local = np.stack((x, a * x * x), -1)
    c, s = np.cos(0.5 * t), np.sin(0.5 * t)
    return c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1]


def check_output(stdout):
    rows = np.array([line.split(",") for line in stdout.splitlines()[1:]], dtype=float)
    x, y = exact_pin(rows[:, 0])
    np.testing.assert_allclose(rows[:, 1], x, atol=1e-13)
    np.testing.assert_allclose(rows[:, 2], y, atol=1e-13)


def test_the_example_mechanism_runs_through_the_entry_point():
    r = mechdsl("run", PACKAGE / "curve_slot.mech", "-o", "-")
    assert r.returncode == 0, r.stderr
    check_output(r.stdout)


@pytest.mark.parametrize("how", ["plugin line", "--plugin"])
def test_the_plugin_loads_without_entry_points(tmp_path, how):
    text = (PACKAGE / "curve_slot.mech").read_text()
    env = {"MECHDSL_DISABLE_PLUGIN_AUTOLOAD": "1", "PYTHONPATH": str(PACKAGE)}
    if how == "--plugin":
        f = tmp_path / "no_line.mech"
        f.write_text(text.replace('plugin "mechdsl_curve_slot"', ""))
        r = mechdsl("run", f, "-o", "-", "--plugin", "mechdsl_curve_slot",
                    "--plugin", "mechdsl_revolute", "--plugin", "mechdsl_drives", env=env)
    else:
        f = tmp_path / "lines.mech"
        f.write_text('plugin "mechdsl_revolute"\nplugin "mechdsl_drives"\n' + text)
        r = mechdsl("run", f, "-o", "-", env=env)
    assert r.returncode == 0, r.stderr
    check_output(r.stdout)


def test_autoload_off_means_only_what_is_asked_for():
    r = mechdsl("run", PACKAGE / "curve_slot.mech", env={"MECHDSL_DISABLE_PLUGIN_AUTOLOAD": "1"})
    assert r.returncode == 1
    assert "unknown joint type 'revolute'" in r.stderr


def test_plugins_named_on_the_command_line_reach_every_chunk_of_a_reduced_sweep(tmp_path):
    # --reduce replaces the outputs and --chunk 1 solves each variant on its own: the
    # plugins given by name (no entry points) still load for every chunk
    f = tmp_path / "no_line.mech"
    f.write_text((PACKAGE / "curve_slot.mech").read_text().replace(
        'plugin "mechdsl_curve_slot"', ""))
    env = {"MECHDSL_DISABLE_PLUGIN_AUTOLOAD": "1", "PYTHONPATH": str(PACKAGE)}
    r = mechdsl("run", f, "-o", "-", "--plugin", "mechdsl_curve_slot", "--plugin",
                "mechdsl_revolute", "--plugin", "mechdsl_drives", "--sweep", "a=0.5,0.6",
                "--chunk", "1", "--reduce", "m = max(pin.x)", env=env)
    assert r.returncode == 0, r.stderr
    rows = np.array([line.split(",") for line in r.stdout.splitlines()
                     if not line.startswith("#")][1:], dtype=float)
    t = np.linspace(0, 2, 201)  # simulate t = 0 .. 2 step 0.01
    for a, m in rows:
        # the maximum between the samples (mechdsl.solve.extrema): of the closed form, by a
        # bounded search around its sampled maximum
        k = int(np.argmax(exact_pin(t, a)[0]))
        best = minimize_scalar(lambda s: -exact_pin(np.array([s]), a)[0][0], method="bounded",
                               bounds=(t[max(k - 1, 0)], t[min(k + 1, 200)]),
                               options={"xatol": 1e-12})
        assert m == pytest.approx(max(-best.fun, exact_pin(t, a)[0].max()), abs=1e-13)
