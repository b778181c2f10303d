"""The documentation site builds from docs/ with warnings as errors (a broken link, a
reference or a picture missing fails), with its API reference and a gallery of every
example with its picture; the README stays a short front door whose commands all run."""

import re
import subprocess
import sys

import pytest

from conftest import EXAMPLES, ROOT
from test_docs import code_blocks

README = (ROOT / "README.md").read_text()


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("site")
    r = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b",
                        "html", "-d", str(out / ".doctrees"), str(ROOT / "docs"), str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return out


def test_the_site_builds_with_warnings_as_errors_and_has_every_page(site):
    for page in ("index", "api", "gallery", "plugins", "language", "dynamics", "cli",
                 "drawings", "performance", "architecture"):
        assert (site / f"{page}.html").exists(), page
    api = (site / "api.html").read_text()
    for name in ("mechdsl.loads", "Mechanism.simulate", "SolverOptions", "Results",
                 "ConstraintType", "check_constraint_type", "CONTRACT_VERSION"):
        assert name in api, name


def test_the_gallery_shows_every_example_with_its_picture(site):
    gallery = (site / "gallery.html").read_text()
    for path in sorted(EXAMPLES.glob("*.mech")):
        assert f"{path.name}" in gallery, path.name
        assert re.search(rf'<img [^>]*src="_images/{path.stem}(_[^"]*)?\.png"', gallery), \
            path.name


def test_each_picture_is_shown_under_its_own_example():
    import sys as _sys

    _sys.path.insert(0, str(ROOT / "docs" / "_ext"))
    from gallery import pictures

    assert pictures("fourbar") == ["images/fourbar.png", "images/fourbar_curve.png",
                                   "images/fourbar_sweep.png"]
    assert pictures("fourbar_coupler") == ["images/fourbar_coupler.png"]


def test_the_readme_is_short_and_links_into_the_docs():
    assert len(README.splitlines()) <= 250
    for target in re.findall(r"\]\((docs/[^)#]+)", README):
        assert (ROOT / target).exists(), target


def test_every_command_of_the_readme_runs(tmp_path):
    """The sh blocks other than the install and test commands (which CI runs), as a user
    runs them from the repository's root (here with the files written elsewhere)."""
    # (the synopsis of the command line, with its FILE and OUT.csv placeholders, is checked
    # against each command's --help by test_docs.py)
    blocks = [b for b in code_blocks(README) if b.startswith("mechdsl ") and "FILE" not in b]
    commands = [line for b in blocks for line in b.splitlines() if line.startswith("mechdsl ")]
    assert len(commands) >= 3
    for line in commands:
        args = [str(ROOT / a) if a.startswith("examples/") else a for a in line.split()[1:]]
        r = subprocess.run([sys.executable, "-m", "mechdsl", *args], capture_output=True,
                           text=True, cwd=tmp_path, timeout=300)
        assert r.returncode == 0, (line, r.stderr)
        written = [a for a in args if re.fullmatch(r"[\w.-]+\.(png|gif|csv)", a)]
        assert written and all((tmp_path / w).stat().st_size > 0 for w in written), line
