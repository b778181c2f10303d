"""Tabulated functions: cubic splines with exact derivatives, from files or inline points."""

import numpy as np
import pytest

import mechdsl
from mechdsl.errors import MechError

CRANK = """body crank { point A = (-1, 0) }
joint A: revolute(ground.origin, crank.A)
drive d: angle(crank) = {f}
simulate t = 0 .. 2 step 0.01
output crank.phi, crank.omega, crank.alpha
"""


def run(registry, f, name="table.mech", **kw):
    return mechdsl.loads(CRANK.replace("{f}", f), name, registry=registry).simulate(**kw)


def test_a_sampled_cubic_is_reproduced_with_its_derivatives(registry):
    # a not-a-knot cubic spline through samples of a cubic is that cubic
    res = run(registry, "table([(0, 0), (0.5, -0.875), (1, -1), (1.5, 0.375), (2, 4)], t)")
    t = res["t"]
    np.testing.assert_allclose(res["crank.phi"], t**3 - 2 * t, atol=1e-14)
    np.testing.assert_allclose(res["crank.omega"], 3 * t**2 - 2, atol=1e-13)
    np.testing.assert_allclose(res["crank.alpha"], 6 * t, atol=1e-12)


def test_a_table_file_drives_a_motion(registry, tmp_path):
    t_data = np.linspace(0, 2, 9)
    (tmp_path / "motion.csv").write_text(
        "# a header comment\ntime;angle\n" + "".join(f"{x} {x**3 + x}\n" for x in t_data))
    res = run(registry, 'table("motion.csv", t)', str(tmp_path / "table.mech"))
    t = res["t"]
    np.testing.assert_allclose(res["crank.phi"], t**3 + t, atol=1e-13)
    np.testing.assert_allclose(res["crank.alpha"], 6 * t, atol=1e-11)


def test_a_table_of_a_smooth_function_converges_at_fourth_order(registry):
    def error(n):
        x = np.linspace(0, 2, n)
        pts = ", ".join(f"({float(a)!r}, {float(np.sin(3 * a))!r})" for a in x)
        res = run(registry, f"table([{pts}], t)")
        return np.abs(res["crank.phi"] - np.sin(3 * res["t"])).max()

    order = np.log2(error(21) / error(41))
    assert 3.5 < order < 4.5  # halving the spacing divides the error by about 2^4


def test_a_periodic_table_wraps_and_closes(registry):
    # one period of sin sampled at 64 points; evaluated over three periods
    x = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    pts = ", ".join(f"({float(a)!r}, {float(np.sin(a))!r})" for a in x)
    res = run(registry, f"table([{pts}], 4*t, 2*pi)", span=(0, 5))
    t = res["t"]
    np.testing.assert_allclose(res["crank.phi"], np.sin(4 * t), atol=1e-6)
    np.testing.assert_allclose(res["crank.omega"], 4 * np.cos(4 * t), atol=1e-4)


@pytest.mark.parametrize("f, message, column", [
    ('table("missing.csv", t)', "cannot read the table missing.csv", 31),
    ("table([(0, 0), (0, 1)], t)", "the x values of a table must increase", 31),
    ("table([(0, 0)], t)", "a table needs at least two points", 31),
    ("table([(0, 0), (1, 1)], t, -1)", "the period of a table must be positive", 52),
    ("table([(0, 0), (1, 1)], t, a)", "must be a constant number", 52),
    ("table([(0, 0, 1), (1, 1)], t)", "a table point is (x, y), not 3 numbers", 32),
    ("table([(0, 0), (1, 1)])", "table() takes the data", 25),
    ("sin([(0, 0), (1, 1)])", "only table() takes a file name or a list of points", 29),
    ('table([(0, 0), (3, 1)], t, 2)', "spans 3, more than its period 2", 31),
])
def test_table_mistakes_are_located(registry, f, message, column):
    with pytest.raises(MechError, match=message.replace("(", r"\(").replace(")", r"\)")) as info:
        run(registry, f)
    assert (info.value.span.line, info.value.span.column) == (3, column)


def test_a_bad_line_in_a_table_file_is_named(registry, tmp_path):
    (tmp_path / "bad.csv").write_text("0, 0\n1, x\n")
    with pytest.raises(MechError, match=r"bad.csv:2: expected two numbers \(x, y\)"):
        run(registry, 'table("bad.csv", t)', str(tmp_path / "table.mech"))


def test_running_past_the_end_of_a_table_stops_there(registry):
    res = run(registry, "table([(0, 0), (0.5, 1), (1, 0.5), (1.5, 2)], t)")
    assert res.status == "failed" and res.n_solved[0] == 151
    assert "drive d (line 3) is not defined at t = 1.51" in res.messages[0]
