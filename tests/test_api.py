"""The Python API takes what the command line takes and fails as it does: expressions as
values, the same located errors at load time, the location as attributes of the exception."""

import numpy as np
import pytest

import mechdsl
from closed_forms import slider_crank
from conftest import EXAMPLES
from mechdsl.cli import main
from mechdsl.errors import format_error

SLIDER = (EXAMPLES / "slider_crank.mech").read_text()
OMEGA = 4 * np.pi


def test_values_may_be_expressions_as_on_the_command_line(loads):
    mech = loads(SLIDER)
    res = mech.simulate(l="3*2", step="1/20", span=("0", "r/4"))
    t = res["t"]
    np.testing.assert_allclose(t, np.arange(11) * 0.05, atol=1e-15)
    x, _, _ = slider_crank(2.0, 6.0, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
    np.testing.assert_allclose(res["slider.x"], x, atol=1e-13)
    swept = mech.simulate(sweep={"l": ["r + 1.5", 4]}, step=0.1)
    np.testing.assert_array_equal(swept["l"], [3.5, 4.0])
    one = mech.simulate(sweep={"l": "2*r"}, step=0.1)  # a single text is one value
    np.testing.assert_array_equal(one["l"], [4.0])


def test_an_expression_error_is_located_like_the_command_lines(loads, capsys):
    with pytest.raises(mechdsl.MechError) as err:
        loads(SLIDER).simulate(l="3*q")
    e = err.value
    assert (e.file, e.line, e.column) == ("l", 1, 3)
    assert e.message == "unknown name 'q' in l"
    assert main(["run", str(EXAMPLES / "slider_crank.mech"), "--set", "l=3*q"]) == 1
    cli = capsys.readouterr().err
    assert cli.startswith("--set l:1:3: error: unknown name 'q' in --set l")


def test_an_unknown_joint_type_is_an_error_of_loads_located_as_on_the_command_line(
        tmp_path, capsys):
    text = SLIDER.replace("joint B: revolute", "joint B: revolut")
    f = tmp_path / "bad.mech"
    f.write_text(text)
    with pytest.raises(mechdsl.MechError) as err:
        mechdsl.loads(text, str(f))  # not only when simulate() is called
    e = err.value
    assert (e.file, e.line, e.column) == (str(f), 24, 10)
    assert e.message == "unknown joint type 'revolut'; did you mean 'revolute'?"
    with pytest.raises(mechdsl.MechError) as err_load:
        mechdsl.load(f)
    assert format_error(err_load.value) == format_error(e)
    assert main(["run", str(f)]) == 1
    assert capsys.readouterr().err.rstrip("\n") == format_error(e)


@pytest.mark.parametrize("change, line, message", [
    ("output slider.x, slider.vx, slider.ax", 32, "unknown body 'slidr'"),
    ("joint D: prismatic(ground.origin, slider.origin, axis = (1, 0))", 26,
     "prismatic() has no argument 'axes'"),
    ("joint C: revolute(rod.C, slider.origin)", 25, "body 'rod' has no point 'D'"),
])
def test_name_mistakes_are_errors_of_loads(registry, change, line, message):
    broken = {32: change.replace("slider.vx", "slidr.vx"),
              26: change.replace("axis", "axes"),
              25: change.replace("rod.C", "rod.D")}[line]
    text = SLIDER.replace(change, broken)
    with pytest.raises(mechdsl.MechError) as err:
        mechdsl.loads(text, "m.mech", registry=registry)
    assert err.value.line == line and err.value.message.startswith(message)


def test_a_value_out_of_range_is_left_to_the_run_where_an_override_may_fix_it(loads):
    text = SLIDER.replace("step 0.001", "step h").replace("param l = 3.5",
                                                          "param l = 3.5\nparam h = -1")
    mech = loads(text)  # no error yet: a value is not a name
    with pytest.raises(mechdsl.MechError, match="step must be positive"):
        mech.simulate()
    assert mech.simulate(h=0.5).ok
