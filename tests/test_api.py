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


def test_a_name_that_is_no_param_is_the_error_not_its_value(loads):
    """The name is checked before the value's text is parsed; a solver option passed as a
    param says where it belongs."""
    mech = loads(SLIDER)
    with pytest.raises(mechdsl.MechError, match=r"^cannot set 'method': there is no param of "
                       r"that name \('method' is a solver option: options=SolverOptions"):
        mech.simulate(method="radau")
    with pytest.raises(mechdsl.MechError, match="^cannot sweep 'L': .*did you mean 'l'"):
        mech.simulate(sweep={"L": ["r"]})


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


# -- a Mechanism compiles once (issue 29): the same overrides give the same compiled model --

def test_the_same_overrides_give_the_compiled_model_kept():
    from mechdsl.compiled.variants import Overrides

    mech = mechdsl.loads(SLIDER)
    first = mech.compile()
    assert mech.compile() is first
    assert mech.compile(Overrides(params={"l": 3.0})) is mech.compile(Overrides(params={"l": 3.0}))
    assert mech.compile(Overrides(params={"l": 3.0})) is not first
    # numbers are compared by their bits: -0.0 is not 0.0 (atan2 tells them apart)
    a = mech.compile(Overrides(params={"omega": 0.0}))
    assert mech.compile(Overrides(params={"omega": -0.0})) is not a
    # an expression by its identity: the same object is the same model; one parsed anew is
    # compiled anew (never another's model), and a deep one is no recursion
    e = mechdsl.api.parse_expr("2*r", "l", ["r"])
    assert mech.compile(Overrides(params={"l": e})) is mech.compile(Overrides(params={"l": e}))
    other = mechdsl.api.parse_expr("2*r", "l", ["r"])
    assert mech.compile(Overrides(params={"l": other})) is not \
        mech.compile(Overrides(params={"l": e}))
    deep = mechdsl.api.parse_expr("0*2" + "^1" * 3000, "l", ["r"])
    assert mech.compile(Overrides(params={"omega": deep})).system.n_variants == 1


def test_solving_again_gives_each_values_own_closed_form():
    # kept compiled models are never a stale answer: each run against the closed form of its
    # own l, in an order that revisits one kept model after others
    mech = mechdsl.loads(SLIDER)
    for length in (3.5, 3.0, 4.0, 3.0, 3.5, 5.0, 6.0, 7.0, 3.5):
        res = mech.simulate(l=length, span=(0, 0.25), step=0.01)
        t = res["t"]
        x, v, a = slider_crank(2.0, length, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
        np.testing.assert_allclose(res["slider.x"], x, rtol=0, atol=1e-12 * length)
        np.testing.assert_allclose(res["slider.ax"], a, rtol=0, atol=1e-10 * np.abs(a).max())


def test_the_kept_models_are_few_and_small_and_follow_the_model():
    from dataclasses import replace

    from mechdsl.api import KEEP_COMPILED, KEEP_VARIANTS
    from mechdsl.compiled.variants import Overrides

    mech = mechdsl.loads(SLIDER)
    kept = [mech.compile(Overrides(params={"l": 3.0 + 0.1 * k})) for k in range(KEEP_COMPILED)]
    assert mech.compile(Overrides(params={"l": 3.0})) is kept[0]  # used last now
    mech.compile(Overrides(params={"l": 9.0}))  # one more: the least recently used goes
    assert mech.compile(Overrides(params={"l": 3.0})) is kept[0]
    assert mech.compile(Overrides(params={"l": 3.1})) is not kept[1]
    # a large sweep (a study's chunk) is compiled each time, not kept
    many = Overrides(sweeps={"l": [3.0 + 0.001 * k for k in range(KEEP_VARIANTS + 1)]})
    assert mech.compile(many) is not mech.compile(many)
    # another model (the command line adds traces) is compiled anew
    before = mech.compile()
    mech.model = replace(mech.model, traces=mech.model.traces)
    assert mech.compile() is not before


def test_a_mechanism_travels_without_its_compiled_models():
    import pickle

    mech = mechdsl.loads(SLIDER)
    mech.compile()
    copy = pickle.loads(pickle.dumps(mech))
    res = copy.simulate(span=(0, 0.1), step=0.01)
    x, _, _ = slider_crank(2.0, 3.5, np.pi / 4 + OMEGA * res["t"], OMEGA, 0.0)
    np.testing.assert_allclose(res["slider.x"], x, rtol=0, atol=1e-12)


# -- new param values reuse the code traced once (issue 29) ---------------------------------

OSCILLATOR = """
param k = 400
param m = 4
param x0 = 0.1
ground { point C = (0, 0) }
body block { guess = (1 + x0, 0, 0)  mass = m  inertia = 1  v0 = (0, 0, 0) }
joint slide: prismatic(ground.origin, block.origin, axis = (1, 0))
force s: spring(block.origin, ground.C, k = k, length = 1)
initial start: x(point = block.origin) = 1 + x0, rate = 0
simulate t = 0 .. 1 step 0.01, rtol = 1e-10, atol = 1e-12
output block.x
"""


def test_new_values_reuse_the_traced_code_and_keep_their_own_closed_form():
    # a block on a spring along a guide: x(t) = 1 + x0 cos(sqrt(k/m) t) for each (k, m, x0);
    # after the first two sets of values, the code traced without folding serves the rest
    mech = mechdsl.loads(OSCILLATOR)
    graphs = []
    for k, m, x0 in ((400, 4, 0.1), (100, 1, 0.2), (900, 9, 0.05), (50, 2, 0.3),
                     (400, 1, 0.1), (100, 1, 0.2)):
        res = mech.simulate(k=k, m=m, x0=x0)
        assert res.ok, res.messages
        t = res["t"]
        exact = 1 + x0 * np.cos(np.sqrt(k / m) * t)
        np.testing.assert_allclose(res["block.x"], exact, rtol=0, atol=2e-8)
        graphs.append(mech.compile(mechdsl.api.Overrides(
            params={"k": k, "m": m, "x0": x0})).fused.graph)
    assert graphs[0] is not graphs[1]       # the file's first values: their own folded code
    assert all(g is graphs[1] for g in graphs[2:])  # then one traced code for all


def test_the_seeds_new_values_share_code_and_plans():
    from mechdsl.compiled.variants import Overrides

    mech = mechdsl.loads(SLIDER)
    systems = [mech.compile(Overrides(params={"l": v})) for v in (3.5, 3.6, 3.7, 3.8)]
    for s in systems:
        s.one_state  # what a solve makes on first use
    assert systems[2].fused.graph is systems[1].fused.graph is systems[3].fused.graph
    twin = systems[1].template  # traced for two variants: what a param changes is a param
    assert twin is not None and systems[2].template is twin and systems[3].template is twin
    assert twin.system.n_variants == 2 and systems[3].system.n_variants == 1
    assert systems[3].lu is systems[1].lu is twin.lu
    assert systems[0].template is None  # the file's values: their own folded code
    assert systems[3].one_state.phi_jac is systems[1].one_state.phi_jac
    assert systems[3].one_state.params != systems[1].one_state.params


def test_a_value_the_template_holds_as_a_constant_is_traced_anew_in_a_large_model():
    # 50 driven cranks (the group layout of a large model); the ground's points sit at
    # height max(a, 1) - 1: a constant of the template's code for a = 0.6 (0 in both of its
    # variants and for every crank), which a = 2 changes. The model is then traced anew for
    # a = 2, with its own plans (not the template's): x = 3 i - (a - 2) cos t and
    # y = max(a, 1) - 1 - (a - 2) sin t for crank i
    n = 50
    lines = ["param a = 0.5", "ground {"] + \
        [f"  point O{i} = ({3 * i}, max(a, 1) - 1)" for i in range(n)] + ["}"]
    for i in range(n):
        lines += [f"body c{i} {{ guess = ({3 * i + 1.5}, 0, 0)  point P = (a - 2, 0) }}",
                  f"joint J{i}: revolute(ground.O{i}, c{i}.P)",
                  f"drive D{i}: angle(c{i}) = t"]
    lines += ["simulate t = 0 .. 1 step 0.1", "output c0.x, c0.y, c49.x"]
    mech = mechdsl.loads("\n".join(lines) + "\n")
    for a in (0.5, 0.6, 2.0, 0.8):
        res = mech.simulate(a=a)
        t = res["t"]
        assert res.ok, res.messages
        np.testing.assert_allclose(res["c0.x"], -(a - 2) * np.cos(t), atol=1e-10)
        np.testing.assert_allclose(res["c0.y"], max(a, 1) - 1 - (a - 2) * np.sin(t),
                                   atol=1e-10)
        np.testing.assert_allclose(res["c49.x"], 147 - (a - 2) * np.cos(t), atol=1e-9)
    from mechdsl.compiled.variants import Overrides
    assert mech.compile(Overrides(params={"a": 2.0})).template is None  # traced anew
    assert mech.compile(Overrides(params={"a": 0.8})).template is not None
