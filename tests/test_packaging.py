"""Packaging: `pip install mechdsl` brings the standard library of joints and drives.

The core names each plugin distribution of plugins/ as a dependency, pinned to its own
version, and each plugin names the core back (the argument is in pyproject.toml). The fast
tests check that the nine pyproject files agree with each other, with mechdsl.__version__ and
with requirements-dev.txt; the slow one builds the wheel of every distribution, installs the
core's wheel by name into a fresh virtual environment (mechdsl's own distributions only from
the built wheels; the third-party distributions they require, and only those, are this
environment's, linked rather than installed again) and runs the slider-crank there against
its closed form. The editable install of requirements-dev.txt on a fresh clone is what CI runs
(.ci/run, the README's install command).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

import mechdsl
from closed_forms import slider_crank
from conftest import EXAMPLES, ROOT

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the test extra brings tomli
    import tomli as tomllib

LIBRARY = sorted(p.parent for p in (ROOT / "plugins").glob("*/pyproject.toml"))
EXAMPLE_PLUGIN = ROOT / "examples" / "plugins" / "curve_slot"
DISTRIBUTIONS = [ROOT, *LIBRARY, EXAMPLE_PLUGIN]

BIN = "Scripts" if os.name == "nt" else "bin"


def project(folder: Path) -> dict:
    return tomllib.loads((folder / "pyproject.toml").read_text())["project"]


def requirement(text: str) -> tuple[str, str]:
    """(normalised name, the rest) of a requirement without markers: 'mechdsl-gears==0.1.0'."""
    m = re.fullmatch(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*(.*?)\s*", text)
    return re.sub(r"[-_.]+", "-", m[1]).lower(), m[2].replace(" ", "")


CORE = project(ROOT)
VERSION = CORE["version"]
LIBRARY_NAMES = [project(d)["name"] for d in LIBRARY]


def test_the_library_is_eight_distributions_of_the_mechdsl_entry_point_group():
    assert CORE["name"] == "mechdsl"
    assert sorted(LIBRARY_NAMES) == ["mechdsl-" + f for f in ("cams", "distance", "drives",
                                                               "forces", "gears", "prismatic",
                                                               "revolute", "rigid")]
    for folder in LIBRARY:
        assert project(folder)["entry-points"]["mechdsl"], folder


def test_one_version_for_the_core_its_code_and_its_library():
    assert mechdsl.__version__ == VERSION      # what `mechdsl --version` prints
    assert {name: project(d)["version"] for name, d in zip(LIBRARY_NAMES, LIBRARY)} \
        == dict.fromkeys(LIBRARY_NAMES, VERSION)


def test_the_core_pins_its_library_and_each_plugin_pins_the_core():
    pinned = dict(map(requirement, CORE["dependencies"]))
    assert {n: pinned.get(n) for n in LIBRARY_NAMES} == dict.fromkeys(LIBRARY_NAMES,
                                                                      "==" + VERSION)
    # nothing else of ours: the example of docs/plugins.md is a third-party plugin
    assert {n for n in pinned if n.startswith("mechdsl")} == set(LIBRARY_NAMES)
    for folder in LIBRARY:
        assert dict(map(requirement, project(folder)["dependencies"]))["mechdsl"] \
            == "==" + VERSION, folder
    # a third-party plugin depends on the range of the core that implements the plugin
    # contract it is written for, as the guide shows: this core's version is in it
    from packaging.specifiers import SpecifierSet

    name, spec = requirement(project(EXAMPLE_PLUGIN)["dependencies"][0])
    assert (name, spec) == ("mechdsl", ">=0.1,<0.2")
    assert SpecifierSet(spec).contains(VERSION)


def test_requirements_dev_installs_each_distribution_editable_from_its_folder():
    """So that the editable plugins satisfy the core's pins and pip never asks the index for
    an unpublished mechdsl-* distribution."""
    lines = [ln.split("#")[0].strip() for ln in (ROOT / "requirements-dev.txt").read_text()
             .splitlines()]
    editable = sorted((ROOT / re.sub(r"\[.*\]$", "", ln[2:].strip())).resolve()
                      for ln in lines if ln.startswith("-e "))
    assert editable == sorted(DISTRIBUTIONS)
    assert [ln for ln in lines if ln and not ln.startswith("-e ")] == []


# --- the wheels, installed alone --------------------------------------------------------------

IGNORED = shutil.ignore_patterns(".git", ".venv", "build", "dist", "*.egg-info", "__pycache__",
                                 ".hypothesis", ".pytest_cache", "fuzz-failures", "out.*")


def run(*args, timeout=600, **kw):
    r = subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=timeout,
                       **kw)
    assert r.returncode == 0, f"{' '.join(map(str, args))}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


#: A PEP 517 build of a wheel, in the distribution's folder, by the backend named: what pip
#: wheel --no-build-isolation and python -m build --no-isolation call, without their own
#: start-up and metadata step (a second and a half each, per distribution)
BUILD_WHEEL = ("import importlib, sys; "
               "print(importlib.import_module(sys.argv[1]).build_wheel(sys.argv[2]))")


def build_wheels(tmp_path: Path) -> Path:
    """Each distribution's wheel, built by the backend its pyproject.toml names, from a copy
    of the tree (setuptools writes build/ and *.egg-info beside the sources: not into the
    working tree, and not racing another run)."""
    source, wheels = tmp_path / "src", tmp_path / "wheels"
    shutil.copytree(ROOT, source, ignore=IGNORED)
    wheels.mkdir()

    def build(folder: Path):
        backend = tomllib.loads((folder / "pyproject.toml").read_text())["build-system"]
        run(sys.executable, "-c", BUILD_WHEEL, backend["build-backend"], wheels,
            cwd=source / folder.relative_to(ROOT))

    with ThreadPoolExecutor(os.cpu_count() or 2) as pool:
        list(pool.map(build, DISTRIBUTIONS))
    return wheels


def wheel_metadata(wheel: Path) -> tuple[str, list[str], str]:
    """(METADATA, the Requires-Dist without extras, entry_points.txt) of a wheel."""
    with zipfile.ZipFile(wheel) as z:
        info = next(n.split("/")[0] for n in z.namelist() if n.endswith(".dist-info/METADATA"))
        meta = z.read(f"{info}/METADATA").decode()
        names = z.namelist()
        entry_points = (z.read(f"{info}/entry_points.txt").decode()
                        if f"{info}/entry_points.txt" in names else "")
    requires = [r for r in re.findall(r"^Requires-Dist: (.*)$", meta, re.M)
                if "extra ==" not in r]
    return meta, requires, entry_points


def clean_env() -> dict:
    """This process's environment without what would let the fresh venv see the tree or the
    development venv (PYTHONPATH, VIRTUAL_ENV) or change which plugins load."""
    return {k: v for k, v in os.environ.items()
            if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP",
                         "PYTHONUSERBASE", "PIP_USER", "PIP_TARGET", "PIP_PREFIX")
            and not k.startswith("MECHDSL_")} | {"PYTHONNOUSERSITE": "1"}


def share_distributions(requirements: set[str], folder: Path) -> list[str]:
    """A folder of links to this environment's installed distributions that ``requirements``
    name, with what those require in turn (markers and extras evaluated here), and nothing
    else: a fresh venv reads them from there (a .pth file) instead of installing them again,
    and its code still finds no module that the wheels do not require. The links are to the
    files that each distribution's RECORD lists (its packages, modules and .dist-info); a pip
    run by the venv never uninstalls them (they are outside its prefix). Returns the names of
    the distributions shared."""
    from importlib.metadata import distribution

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    folder.mkdir()
    todo, done, shared = [Requirement(r) for r in requirements], set(), {}
    while todo:
        req = todo.pop()
        name = canonicalize_name(req.name)
        if (name, frozenset(req.extras)) in done:
            continue
        done.add((name, frozenset(req.extras)))
        dist = distribution(req.name)
        assert req.specifier.contains(dist.version, prereleases=True), (str(req), dist.version)
        if name not in shared:
            shared[name] = dist
            assert dist.files is not None, f"{name}: no RECORD, its files are not known"
            for top in {f.parts[0] for f in dist.files if f.parts[0] != ".."}:
                link = folder / top
                if top != "__pycache__" and not top.endswith(".pth") and not link.exists():
                    link.symlink_to(dist.locate_file(top))
        for r in map(Requirement, dist.requires or ()):
            if r.marker is None or any(r.marker.evaluate({"extra": e})
                                       for e in {"", *req.extras}):
                todo.append(r)
    return sorted(shared)


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """Header names (any unit after a space dropped) and rows; comment lines skipped."""
    lines = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    header = [h.strip().split(" ")[0] for h in lines[0].split(",")]
    return header, np.array([ln.split(",") for ln in lines[1:]], dtype=float)


@pytest.fixture
def scratch(tmp_path):
    """tmp_path, without the copied tree, the venv and the links once the test is over."""
    yield tmp_path
    for big in ("src", "venv", "third-party"):
        shutil.rmtree(tmp_path / big, ignore_errors=True)


def test_the_core_wheel_alone_brings_the_library_and_runs_the_slider_crank(scratch):
    tmp_path = scratch
    wheels = build_wheels(tmp_path)
    built = {w.name.split("-")[0].replace("_", "-"): w for w in wheels.glob("*.whl")}
    assert sorted(built) == sorted(project(d)["name"] for d in DISTRIBUTIONS)
    for name, wheel in built.items():
        assert wheel.name == f"{name.replace('-', '_')}-{VERSION}-py3-none-any.whl"

    # the core's wheel names the library, pinned; each plugin's wheel has its entry points
    meta, core_requires, core_entry_points = wheel_metadata(built["mechdsl"])
    assert f"\nVersion: {VERSION}\n" in meta
    assert {r for r in core_requires if r.startswith("mechdsl")} \
        == {f"{n}=={VERSION}" for n in LIBRARY_NAMES}
    assert "[console_scripts]\nmechdsl = mechdsl.cli:entry" in core_entry_points
    for name in LIBRARY_NAMES:
        _, requires, entry_points = wheel_metadata(built[name])
        assert f"mechdsl=={VERSION}" in requires, name
        assert "[mechdsl]\n" in entry_points, name

    # a fresh venv that sees the third-party distributions the wheels require, then the core
    # installed in it by name from the built wheels only (--no-index: pip never asks the
    # index for ours, and finds the third-party requirements already satisfied)
    venv, env = tmp_path / "venv", clean_env()
    run(sys.executable, "-m", "venv", "--without-pip", venv, env=env)
    python = venv / BIN / "python"
    third_party = {r for name in ["mechdsl", *LIBRARY_NAMES]
                   for r in wheel_metadata(built[name])[1]
                   if not requirement(r)[0].startswith("mechdsl")}
    shared = share_distributions(third_party, tmp_path / "third-party")
    assert not any(n.startswith("mechdsl") for n in shared)
    purelib = Path(run(python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))",
                       env=env).stdout.strip())
    (purelib / "third-party.pth").write_text(f"{tmp_path / 'third-party'}\n")
    pip = [sys.executable, "-m", "pip", "--python", python]  # this pip, run by the venv's python
    r = run(*pip, "install", "--no-index", "--find-links", wheels, "mechdsl", env=env)
    installed = re.search(r"^Successfully installed (.*)$", r.stdout, re.M)[1].split()
    assert sorted(installed) == sorted(f"{n}-{VERSION}" for n in ["mechdsl", *LIBRARY_NAMES])
    run(*pip, "check", env=env)          # the cycle is consistent

    # what the venv imports is the wheels' code, in its site-packages
    probe = run(python, "-c", "import json, mechdsl, importlib.metadata as m; print(json.dumps("
                "{d.metadata['Name']: [d.version, str(d.locate_file(''))] for d in "
                "m.distributions() if d.metadata['Name'].startswith('mechdsl')}"
                " | {'file': mechdsl.__file__}))", env=env, cwd=tmp_path).stdout
    found = json.loads(probe)
    site = Path(found.pop("file")).resolve().parent.parent
    assert site.is_relative_to(venv.resolve()) and site.name == "site-packages"
    assert {n: (v, Path(where).resolve()) for n, (v, where) in found.items()} \
        == {n: (VERSION, site) for n in ["mechdsl", *LIBRARY_NAMES]}

    mechdsl_cmd = venv / BIN / "mechdsl"
    assert run(mechdsl_cmd, "--version", env=env).stdout.strip() == f"mechdsl {VERSION}"
    listing = run(mechdsl_cmd, "plugins", env=env, cwd=tmp_path).stdout
    assert "broken" not in listing
    assert "revolute(p1: point, p2: point)" in listing
    for name in LIBRARY_NAMES:
        assert f"[{name} {VERSION}]" in listing, name
    assert "mechdsl-curve-slot" not in listing

    # the paper's slider-crank, from a folder that holds only the model
    work = tmp_path / "run"
    work.mkdir()
    shutil.copy(EXAMPLES / "slider_crank.mech", work)
    r = run(mechdsl_cmd, "run", "slider_crank.mech", "-o", "out.csv", env=env, cwd=work)
    header, rows = read_csv(work / "out.csv")
    assert header == ["t", "slider.x", "slider.vx", "slider.ax"]
    assert rows.shape == (1001, 4)
    t = rows[:, 0]
    x, v, a = slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * t, 4 * np.pi, 0.0)
    for col, exact in zip(rows[:, 1:].T, (x, v, a)):
        assert np.abs(col - exact).max() / np.abs(exact).max() < 1e-9
