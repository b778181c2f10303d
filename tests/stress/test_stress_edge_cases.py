"""Every numeric edge case of the input has its own test and message (FILE:LINE:COL, exit 1)."""

import subprocess
import sys

import numpy as np
import pytest

import mechdsl
from conftest import ROOT
from mechdsl.errors import MechError, format_error

OK = """param r = 1
body c { point A = (-r, 0) }
joint j: revolute(ground.origin, c.A)
drive d: angle(c) = t
simulate t = 0 .. 1 step 0.1
"""


def error(registry, text, **kw):
    with pytest.raises(MechError) as info:
        mechdsl.loads(text, "edge.mech", registry=registry).simulate(**kw)
    return info.value


def where(err):
    return (err.span.line, err.span.column) if err.span else None


@pytest.mark.parametrize("value, shown", [("0/0", "nan"), ("1/0", "inf"), ("-1/0", "-inf"),
                                          ("sqrt(-1)", "nan"), ("exp(1000)", "inf")])
def test_a_param_that_is_not_finite(registry, value, shown):
    err = error(registry, OK.replace("r = 1", f"r = {value}"))
    assert err.message == f"param 'r' is {shown}" and where(err) == (1, 1)


def test_a_param_not_finite_in_one_sweep_variant(registry):
    err = error(registry, OK.replace("param r = 1", "param k = 1\nparam r = 1/k") +
                "sweep k = [1, 0, 2]\n")
    assert err.message == "param 'r' is inf for k = 0" and where(err) == (2, 1)


@pytest.mark.parametrize("step", ["0", "-0.1"])
def test_a_step_that_is_not_positive(registry, step):
    err = error(registry, OK.replace("step 0.1", f"step {step}"))
    assert err.message == f"the simulated time step must be positive, not {float(step):g}"
    assert where(err) == (5, 1)


def test_an_end_before_the_start(registry):
    err = error(registry, OK.replace("0 .. 1", "2 .. 1"))
    assert err.message == "the simulated time range ends (1) before it starts (2)"
    assert where(err) == (5, 1)


def test_a_body_may_be_referenced_before_it_is_declared(registry):
    # bodies and points are resolved after the whole file is read: order is free
    text = "joint j: revolute(ground.origin, c.A)\ndrive d: angle(c) = t\n" \
           "body c { point A = (-1, 0) }\nsimulate t = 0 .. 1 step 0.5\noutput c.A.x\n"
    res = mechdsl.loads(text, registry=registry).simulate()
    np.testing.assert_allclose(res["c.A.x"], 0.0, atol=1e-15)


def test_a_point_of_a_body_never_declared(registry):
    err = error(registry, OK.replace("revolute(ground.origin, c.A)", "revolute(ground.origin, d.A)"))
    assert err.message == "unknown body 'd'" and where(err) == (3, 34)


def test_a_param_used_before_it_is_defined(registry):
    err = error(registry, "param a = b\nparam b = 1\n")
    assert err.message == "unknown name 'b' in param 'a'" and where(err) == (1, 11)


def test_a_body_with_no_joints(registry):
    err = error(registry, OK.replace("drive d", "body loose { }\ndrive d"))
    assert err.message.startswith("the mechanism is not fully driven: 6 coordinates and 3 "
                                  "equations leave 3 degrees of freedom")
    assert err.notes == ("body 'loose' is attached to nothing",)


@pytest.mark.parametrize("text, message, at", [
    ("param r = 1\nparam r = 2\n", "param 'r' is declared twice", (2, 7)),
    (OK + "body c { }\n", "body 'c' is declared twice", (6, 6)),
    (OK + "joint j: revolute(ground.origin, c.origin)\n", "joint, drive or force 'j' is declared twice", (6, 7)),
    (OK + "drive j: angle(c) = 1\n", "joint, drive or force 'j' is declared twice", (6, 7)),
    ("body c { point A = (1, 0)  point A = (2, 0) }", "point of c 'A' is declared twice", (1, 34)),
])
def test_duplicate_names(registry, text, message, at):
    err = error(registry, text)
    assert err.message == message and where(err) == at


def test_a_drive_on_the_ground(registry):
    err = error(registry, OK.replace("angle(c)", "angle(ground)"))
    assert err.message == "a drive on the ground constrains nothing" and where(err) == (4, 1)


def test_a_huge_number_of_instants_is_refused_before_allocating(registry):
    err = error(registry, OK.replace("step 0.1", "step 1e-12"))
    assert err.message == ("the simulated time has 1,000,000,000,001 instants, whose results "
                           "would take 72.8 TiB, more than the limit of 4.0 GiB")  # 9 outputs
    assert "--max-memory" in err.notes[0]


def test_the_memory_limit_can_be_raised(tmp_path):
    f = tmp_path / "big.mech"
    f.write_text(OK.replace("step 0.1", "step 1e-7"))  # 10^7 instants: 160 MB of results
    r = subprocess.run([sys.executable, "-m", "mechdsl", "run", str(f), "--max-memory", "100M",
                        "-q"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 1 and "more than the limit of 100.0 MiB" in r.stderr


def test_a_file_that_is_not_utf8(tmp_path):
    f = tmp_path / "latin1.mech"
    f.write_bytes(b"param r = 1 # r\xe9glage\n")
    with pytest.raises(MechError) as info:
        mechdsl.load(f)
    err = info.value
    assert err.message == "the file is not valid UTF-8 (byte 0xe9)" and where(err) == (1, 16)
    assert format_error(err).startswith(f"{f}:1:16: error: the file is not valid UTF-8")


@pytest.mark.parametrize("text", ["", "\n\n  # only a comment\n"])
def test_an_empty_file(registry, text):
    err = error(registry, text)
    assert err.message == "nothing to simulate: add a line such as 'simulate t = 0 .. 1 step 0.001'"
