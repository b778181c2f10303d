"""Every error of a file at once (mechdsl.diagnostics, mechdsl check): each syntax error and
each name error with its exact place, no error that only follows from another, nothing for a
valid file, and nothing imported or read that the file names."""

import subprocess
import sys

import pytest

from conftest import EXAMPLES
from mechdsl.diagnostics import diagnose, statement_spans
from mechdsl.plugins import build_registry

BROKEN = """param r = 2
param l = 3.5 *
body crank { guess = (1, 0, 0)  point A = (-r/2, 0)  point B = (r/2, 0) }
body rod { guess = (3.75, 0, 0)  point B = (-l/2, 0)  point C = (l/2, 0 }
joint A: revolute(ground.origin, crank.A)
joint B: revolut(crank.B, rod.B)
drive spin: angle(crank) = 2*pi*t
output crank.x, crank.vy, crnk.x
"""


@pytest.fixture(scope="module")
def registry():
    return build_registry()


def located(errors):
    return [(e.span.line, e.span.column, e.span.end_column, e.message.split(";")[0])
            for e in errors]


def test_two_syntax_errors_and_two_name_errors_in_one_pass(registry):
    assert located(diagnose(BROKEN, "b.mech", registry)) == [
        (2, 16, 17, "the statement ends before it is complete"),
        (4, 73, 74, "unexpected '}'"),
        (6, 10, 17, "unknown joint type 'revolut'"),
        (8, 27, 33, "unknown body 'crnk'"),
    ]


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.mech")), ids=lambda p: p.name)
def test_a_valid_file_has_no_error(path, registry):
    assert diagnose(path.read_text(), str(path), registry) == []  # tables beside it


def test_each_statement_is_cut_where_it_starts():
    text = "param a = 1 param force = a\nbody b { } force f: spring(b.origin, ground.origin, k = force)\n"
    cuts = [text[a:b].strip() for a, b in statement_spans(text)]
    assert cuts == ["param a = 1", "param force = a", "body b { }",
                    "force f: spring(b.origin, ground.origin, k = force)"]


def test_a_file_naming_a_plugin_imports_nothing(registry):
    text = 'plugin "mechdsl_diag_probe"\nbody b { }\njoint j: nosuch(b.origin, ground.origin)\n'
    errors = diagnose(text, "p.mech", registry)
    assert "mechdsl_diag_probe" not in sys.modules
    assert located(errors) == [(3, 10, 16, "unknown joint type 'nosuch'")]


def test_check_prints_every_error(tmp_path):
    path = tmp_path / "b.mech"
    path.write_text(BROKEN)
    r = subprocess.run([sys.executable, "-m", "mechdsl", "check", str(path)],
                       capture_output=True, text=True)
    assert r.returncode == 1
    for line in (2, 4, 6, 8):
        assert f"{path}:{line}:" in r.stderr
    assert "Traceback" not in r.stderr
