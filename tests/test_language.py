"""The .mech language: every construct of the specification, and bad input located."""

import math

import numpy as np
import pytest

import mechdsl
from mechdsl.grammar import expr as E
from mechdsl.grammar.derive import derivative
from mechdsl.errors import MechError, format_error
from mechdsl.grammar import parse

# The language sample of the specification, verbatim, completed into a mechanism.
SPEC = """
# comment to the end of the line
param r = 2                      # named scalar; any later expression may use it
param omega = 4*pi
param l = 3.5

ground {                         # the fixed body; it may declare points
    point O4 = (4, 0)
}

body crank {                     # a rigid body; q = (x, y, phi) of its frame
    guess = (1, 0, 0)            # rough initial pose; the assembly step corrects it (default (0, 0, 0))
    point A = (-r/2, 0)          # a point fixed in the body, in body coordinates
    point B = (r/2, 0)
}
body rod { guess = (3.75, 0, 0)  point B = (-l/2, 0)  point C = (l/2, 0) }
body slider { guess = (5.5, 0, 0) }
# every body, ground included, has the implicit point `origin` = (0, 0)

joint A: revolute(ground.origin, crank.A)                  # the two points coincide (2 equations)
joint B: revolute(crank.B, rod.B)
joint C: revolute(rod.C, slider.origin)
joint D: prismatic(ground.origin, slider.origin, axis = (1, 0))

drive crank_angle: angle(crank) = pi/4 + omega*t            # phi of a body as a function of time

simulate t = 0 .. 1 step 0.001   # instants t0 + k*step, both ends included
output slider.x, slider.vx, slider.ax, crank.B.vy
sweep l = [3.5, 2.5, 2.2, 2.1]   # run once per value (several sweeps: every combination)
"""


def test_the_specification_sample_parses_as_written():
    m = parse(SPEC, "spec.mech")
    assert [p.name for p in m.params] == ["r", "omega", "l"]
    assert [p.name for p in m.ground.points] == ["O4"]
    assert [b.name for b in m.bodies] == ["crank", "rod", "slider"]
    crank = m.bodies[0]
    assert [p.name for p in crank.points] == ["A", "B"]
    assert [e.value for e in crank.guess.items] == [1, 0, 0]
    assert [(j.name, j.type_name) for j in m.joints] == [
        ("A", "revolute"), ("B", "revolute"), ("C", "revolute"), ("D", "prismatic")]
    d = m.joints[3]
    assert d.args[0].value.parts == ("ground", "origin") and d.args[0].name is None
    assert d.args[2].name == "axis" and len(d.args[2].value.items) == 2
    drive = m.drives[0]
    assert (drive.name, drive.type_name) == ("crank_angle", "angle")
    assert E.to_text(drive.function) == "pi/4 + omega*t"
    assert [o.parts for o in m.outputs] == [("slider", "x"), ("slider", "vx"), ("slider", "ax"),
                                            ("crank", "B", "vy")]
    assert m.sweeps[0].name == "l" and [e.value for e in m.sweeps[0].values] == [3.5, 2.5, 2.2, 2.1]
    assert E.to_text(m.simulate.step) == "0.001"


def test_the_specification_sample_runs(registry):
    res = mechdsl.loads(SPEC, registry=registry).simulate()
    assert res.ok
    assert res["slider.x"].shape == (4, 1001)
    assert res.labels == ("slider.x", "slider.vx", "slider.ax", "crank.B.vy")
    # crank.B.vy = r omega cos(theta)
    t = res["t"]
    np.testing.assert_allclose(res["crank.B.vy"][2], 2 * 4 * np.pi * np.cos(np.pi / 4 + 4 * np.pi * t),
                               atol=1e-11)


def test_the_start_from_rest_driver_parses_and_differentiates_exactly():
    m = parse("""param alpha = 8*pi  param t1 = 0.5
        body c { }
        drive d: angle(c) = if t < t1 then pi/4 + alpha*t^2/2 else pi/4 + alpha*t1^2/2 + alpha*t1*(t - t1)""")
    f = m.drives[0].function
    fd, fdd = derivative(f), derivative(derivative(f))
    env = {"alpha": 8 * np.pi, "t1": 0.5, "t": np.array([0.1, 0.49, 0.5, 0.9])}
    np.testing.assert_allclose(E.evaluate(fd, env), 8 * np.pi * np.minimum(env["t"], 0.5))
    np.testing.assert_allclose(E.evaluate(fdd, env), [8 * np.pi, 8 * np.pi, 0, 0])


@pytest.mark.parametrize("text, value", [
    ("2", 2), ("3.5", 3.5), ("1e-3", 1e-3), ("2.5E+2", 250), ("-2^2", -4), ("2^-1", 0.5),
    ("2^3^2", 512), ("1 - 2 - 3", -4), ("8/4/2", 1), ("-(1+2)*3", -9), ("+3", 3),
    ("pi", math.pi), ("atan2(1, 1)", math.pi / 4), ("min(3, 1, 2)", 1), ("max(3, 1, 2)", 3),
    ("abs(-2)", 2), ("sqrt(16) + exp(0) + log(1)", 5), ("asin(1) + acos(1) + atan(0)", math.pi / 2),
    ("tan(0) + sin(0) + cos(0)", 1),
    ("if 1 < 2 then 10 else 20", 10), ("if 1 >= 2 then 10 else 20", 20),
    ("if 1 <= 1 and not 2 > 3 then 1 else 0", 1), ("if 1 > 2 or 2 > 1 then 1 else 0", 1),
])
def test_expressions_evaluate_with_the_usual_precedence(text, value):
    m = parse(f"param x = {text}")
    assert E.evaluate(m.params[0].value, {}) == pytest.approx(value, rel=1e-15)


def test_sweep_ranges_and_combinations(registry):
    text = """param a = 1  param b = 2
        body c { point P = (a, b) }
        joint j: revolute(ground.origin, c.origin)
        drive d: angle(c) = t
        simulate t = 0 .. 0.1 step 0.05
        output c.P.x
        sweep a = 1 .. 2 step 0.5
        sweep b = 0 .. 1 count 2"""
    res = mechdsl.loads(text, registry=registry).simulate()
    np.testing.assert_allclose(res["a"], [1, 1, 1.5, 1.5, 2, 2])
    np.testing.assert_allclose(res["b"], [0, 1, 0, 1, 0, 1])
    t = res["t"]
    np.testing.assert_allclose(res["c.P.x"], res["a"][:, None] * np.cos(t) - res["b"][:, None] * np.sin(t),
                               atol=1e-14)


def test_the_time_grid_includes_both_ends(registry):
    text = """body c { }  joint j: revolute(ground.origin, c.origin)
        drive d: angle(c) = t  simulate t = 0.5 .. 1.25 step 0.5"""
    res = mechdsl.loads(text, registry=registry).simulate()
    np.testing.assert_allclose(res["t"], [0.5, 1.0, 1.25])


def test_statements_may_share_a_line_and_use_semicolons():
    m = parse("param a = 1; param b = a + 1 body c { point P = (a, b); } ground { point Q = (1, 1) }")
    assert [p.name for p in m.params] == ["a", "b"] and m.ground.points[0].name == "Q"


def test_params_named_like_contextual_keywords_are_allowed():
    m = parse("param step = 1  param count = 2  param ground_y = 3\nsimulate t = 0 .. step step step")
    assert [p.name for p in m.params] == ["step", "count", "ground_y"]


# --- errors -------------------------------------------------------------------------------------

def error_of(text, registry=None):
    with pytest.raises(MechError) as info:
        mech = mechdsl.loads(text, "bad.mech", registry=registry)
        if registry is not None:
            mech.simulate()
    err = info.value
    assert err.source is not None and err.source.name == "bad.mech"
    return err


def where(err):
    return (err.span.line, err.span.column) if err.span else None


@pytest.mark.parametrize("text, message, at", [
    ("param a = 2 +", "unexpected end of file", (1, 14)),
    ("param a = (2", "unexpected end of file", (1, 13)),
    ("param a = 2 3", "unexpected number 3", (1, 13)),
    ("param a = 2 $", "unexpected character '$'", (1, 13)),
    ("param a = 2\nbody b { point P = (1, 2) \n\n", "unexpected end of file", (2, 26)),
    ("param a = 2*\nsimulate t = 0 .. 1 step 0.1", "unexpected 'simulate'", (2, 1)),
    ("param body = 1", "unexpected 'body'; expected a name", (1, 7)),
    ("param a = .5", "unexpected '.'; expected '(', '+', '-', 'if', 'not', a name", (1, 11)),
    ("joint j revolute(a.b, c.d)", "unexpected name 'revolute'; expected ':'", (1, 9)),
])
def test_syntax_errors_are_located(text, message, at):
    err = error_of(text)
    assert message in err.message
    assert where(err) == at


@pytest.mark.parametrize("text, message, at", [
    ("param a = b", "unknown name 'b'", (1, 11)),
    ("param alpha = 1\nparam b = alpah", "did you mean 'alpha'", (2, 11)),
    ("param a = t", "time 't' cannot appear in param 'a'", (1, 11)),
    ("param a = 1\nparam a = 2", "param 'a' is declared twice", (2, 7)),
    ("param t = 1", "'t' is reserved", (1, 7)),
    ("param pi = 1", "'pi' is reserved", (1, 7)),
    ("param a = sinn(1)", "unknown function 'sinn'; did you mean 'sin'", (1, 11)),
    ("param a = atan2(1)", "atan2() takes 2 arguments, got 1", (1, 11)),
    ("param a = min(1)", "min() takes at least 2 arguments, got 1", (1, 11)),
    ("param a = 1 < 2", "a comparison is not a number", (1, 11)),
    ("param a = if 1 then 2 else 3", "the condition of an 'if' must be a comparison", (1, 14)),
    ("param a = b.c", "'b.c' is a reference, not a number", (1, 11)),
    ("body b { guess = (1, 2) }", "a guess (x, y, phi) takes 3 numbers, got 2", (1, 18)),
    ("body b { point P = (1, 2, 3) }", "a point (x, y) takes 2 numbers, got 3", (1, 20)),
    ("body b { point P = (1, 2) point P = (2, 3) }", "point of b 'P' is declared twice", (1, 33)),
    ("body b { point origin = (1, 2) }", "'origin' is implicit", (1, 16)),
    ("body b { point vx = (1, 2) }", "cannot be named 'vx'", (1, 16)),
    ("body b { }\nbody b { }", "body 'b' is declared twice", (2, 6)),
    ("body ground { }", "declared with 'ground { ... }'", (1, 6)),
    ("ground { }\nground { }", "the ground is declared twice", (2, 1)),
    ("ground { guess = (1, 2, 3) }", "the ground is fixed", (1, 10)),
    ("body b { guess = (1, 1, 1) guess = (2, 2, 2) }", "two guesses", (1, 28)),
    ("joint j: revolute(a.b, c.d)\njoint j: revolute(a.b, c.d)", "'j' is declared twice", (2, 7)),
    ("joint j: revolute(a.b, c.d, p1 = x.y, p1 = x.z)", "argument of j 'p1' is declared twice", (1, 39)),
    ("simulate x = 0 .. 1 step 0.1", "the simulated variable is time 't'", (1, 10)),
    ("simulate t = 0 .. 1 step 0.1\nsimulate t = 0 .. 2 step 0.1", "a second 'simulate'", (2, 1)),
    ("param a = 1\nsweep b = [1, 2]", "'b' is not a param", (2, 7)),
    ("param a = 1\nsweep a = [1]\nsweep a = [2]", "sweep of 'a' is declared twice", (3, 7)),
    ("drive d: angle(b) = q", "unknown name 'q' in the function of drive 'd'", (1, 21)),
])
def test_model_errors_are_located(text, message, at):
    err = error_of(text)
    assert message in err.message
    assert where(err) == at


BASE = """param r = 1
body c { point A = (-r, 0) }
joint j: revolute(ground.origin, c.A)
drive d: angle(c) = t
simulate t = 0 .. 1 step 0.1
"""


@pytest.mark.parametrize("change, message, at", [
    (("revolute(", "revolut("), "unknown joint type 'revolut'; did you mean 'revolute'", (3, 10)),
    (("angle(c)", "angel(c)"), "unknown drive type 'angel'; did you mean 'angle'", (4, 10)),
    (("revolute(", "angle("), "'angle' is a drive type, not a joint type", (3, 10)),
    (("c.A)", "c.AA)"), "body 'c' has no point 'AA'; did you mean 'c.A'", (3, 34)),
    (("c.A)", "cc.A)"), "unknown body 'cc'; did you mean 'c'", (3, 34)),
    (("c.A)", "c)"), "argument 'p2' is a point: write c.origin", (3, 34)),
    (("c.A)", "c.A, p3 = c.A)"), "revolute() has no argument 'p3'", (3, 39)),
    (("c.A)", "c.A, c.A)"), "revolute() takes 2 arguments", (3, 39)),
    (("ground.origin, c.A", "p2 = c.A, ground.origin"), "positional argument cannot follow", (3, 29)),
    (("ground.origin, c.A", "ground.origin"), "revolute() needs argument 'p2'", (3, 1)),
    (("ground.origin, c.A", "c.origin, c.A"), "connects body 'c' to itself", (3, 1)),
    (("angle(c)", "angle(ground)"), "a drive on the ground constrains nothing", (4, 1)),
    (("angle(c)", "angle(c.A)"), "argument 'body' must be a body name", (4, 16)),
    (("r = 1", "r = sqrt(-1)"), "param 'r' is nan", (1, 1)),
    (("r = 1", "r = 1/0"), "param 'r' is inf", (1, 1)),
    (("step 0.1", "step 0"), "the simulated time step must be positive", (5, 1)),
    (("step 0.1", "step -1"), "the simulated time step must be positive", (5, 1)),
    (("0 .. 1", "1 .. 0"), "ends (0) before it starts (1)", (5, 1)),
    (("= t\n", "= t\noutput c.vz\n"), "'vz' is neither a quantity of body 'c' nor one of its points", (5, 8)),
    (("= t\n", "= t\noutput c.A.phi\n"), "'phi' is not a point quantity", (5, 8)),
    (("= t\n", "= t\noutput d.x\n"), "'d.x' is not an output of drive 'd'", (5, 8)),
    (("= t\n", "= t\noutput c.x, c.x\n"), "output 'c.x' is requested twice", (5, 13)),
])
def test_compile_errors_are_located(registry, change, message, at):
    err = error_of(BASE.replace(*change), registry)
    assert message in err.message
    assert where(err) == at


def test_free_bodies_and_overconstraint_are_counted(registry):
    err = error_of(BASE.replace("drive d: angle(c) = t", "body free { }\ndrive d: angle(c) = t"),
                   registry)
    assert "3 degrees of freedom" in err.message and "'free' is attached to nothing" in err.notes[0]
    err = error_of(BASE + "drive e: x(c.origin) = 0\n", registry)
    assert err.message == ("the mechanism is over-driven: its joints leave 1 degree of freedom "
                           "and there are 2 drives; drive e (1 equation, line 6) moves "
                           "coordinates that the joints or other drives already fix")


def test_a_swept_time_grid_is_rejected(registry):
    err = error_of(BASE.replace("step 0.1", "step r/10") + "sweep r = [1, 2]\n", registry)
    assert "the time grid cannot depend on a swept param" in err.message


def test_errors_are_formatted_with_the_line_and_a_caret():
    err = error_of("param alpha = 1\nparam b = 2*alpah + 1")
    text = format_error(err)
    assert text.splitlines() == [
        "bad.mech:2:13: error: unknown name 'alpah' in param 'b'; did you mean 'alpha'?",
        "    2 | param b = 2*alpah + 1",
        "      |             ^^^^^",
    ]


def test_a_file_that_is_not_utf8_is_an_error(tmp_path):
    p = tmp_path / "latin.mech"
    p.write_bytes(b"param a = 1\n# caf\xe9\n")
    with pytest.raises(MechError, match="not valid UTF-8") as info:
        mechdsl.load(p)
    assert where(info.value) == (2, 6)


def test_an_empty_file_parses_and_is_reported_as_having_no_body(registry):
    err = error_of("", registry)
    assert "nothing to simulate" in err.message or "no moving body" in err.message


def test_a_param_may_give_its_range_for_the_views_slider():
    from mechdsl.compiled.variants import Overrides, evaluate, param_ranges
    from mechdsl.errors import MechError

    m = parse("param r = 2 in 1 .. 3\nparam l = 3.5 in r .. 2*r + 1\nparam k = 1\n")
    assert [p.range is None for p in m.params] == [False, False, True]
    env = evaluate(m, Overrides()).env
    assert param_ranges(m, env) == {"r": (1.0, 3.0), "l": (2.0, 5.0)}
    with pytest.raises(MechError, match="the range of param 'l' is empty: 5 .. 5") as err:
        evaluate(parse("param l = 3.5 in 5 .. 5\n"), Overrides())
    assert (err.value.span.line, err.value.span.column) == (1, 18)
    with pytest.raises(MechError, match="unknown name 'q'"):
        parse("param l = 3.5 in q .. 5\n")


def test_a_range_of_a_swept_param_is_checked_in_every_variant():
    from mechdsl.compiled.variants import Overrides, evaluate, param_ranges
    from mechdsl.errors import MechError

    m = parse("param r = 2\nparam l = 3.5 in r .. 4*r\nsweep r = [1.5, 2]\n")
    assert param_ranges(m, evaluate(m, Overrides()).env) == {"l": (1.5, 6.0)}
    # empty for r = 2 only (3 .. 3): said with that variant's ends
    with pytest.raises(MechError, match="the range of param 'l' is empty: 3 .. 3"):
        evaluate(parse("param r = 2\nparam l = 3.5 in 2*r - 1 .. 3\nsweep r = [1.5, 2]\n"),
                 Overrides())


def test_the_parser_positions_are_larks():
    """The parser's own position callbacks (parser._Positions, faster) and its one-loop
    driver of lark's tables (grammar/lalr.py, faster still) give the tree lark's parser
    gives, every node with the line, column, offsets and containers of lark's
    propagate_positions, on every example and on text whose containers matter
    (parentheses, a keyword before a name, comments, an empty file)."""
    from pathlib import Path

    from mechdsl.grammar import parser as P

    def positions(tree):
        return [(t.data, t.meta.empty, *(getattr(t.meta, a, None) for a in (
            "line", "column", "start_pos", "end_line", "end_column", "end_pos",
            "container_line", "container_column", "container_start_pos",
            "container_end_line", "container_end_column", "container_end_pos")))
            for t in tree.iter_subtrees()]

    fast, lark_own = P._build_parser(), P._build_parser(fast=False)
    loop = P._fast()
    assert loop is not None
    assert any(isinstance(c, P._Positions) for c in fast.parser.parser.parser.callbacks.values())
    texts = [p.read_text() for p in sorted(Path(__file__).parent.parent.glob("examples/*.mech"))]
    texts.append("param a = ((1 + 2)) * (3) - -(4)^2  # c\nparam b = if a > 1 then (a) else -a\n"
                 "body  # note\n  bar { guess = ((0), 0, 0)  point P = (1, (2)) }\n"
                 "output x = max(abs((bar.P.x))), bar.P\n")
    texts += ["", "# only a comment", "\n\n  \n"]
    assert len(texts) > 10
    for text in texts:
        expected = lark_own.parse(text, start="start")
        for tree in (fast.parse(text, start="start"), loop.parse(text, "start")):
            assert tree == expected
            assert positions(tree) == positions(expected)
    # the start points of the command line's values (--set, --sweep, --reduce, --trace)
    for start, text in (("expr_only", "-(2 * (l + 1))^2"), ("expr_list", "(1), 2 * (3 + r)"),
                        ("output_list", "peak = max(abs((slider.ax))), range(s.x)"),
                        ("trace_list", "coupler.P, ic(coupler, ground)")):
        expected = lark_own.parse(text, start=start)
        for tree in (fast.parse(text, start=start), loop.parse(text, start)):
            assert positions(tree) == positions(expected)
            assert tree.meta.end_column == len(text) + 1, start
    # where lark's parser finds an error, the loop gives up and lark's parser says it
    for text in ("body b { guess = (0, 0 }", "param = 1", "param a = 1 $", "joint j: ("):
        assert loop.parse(text, "start") is None
    # the model made while reducing is the one made from lark's tree afterwards, spans
    # (dataclass fields) included, on every example and the texts above
    for text in texts:
        made = loop.parse(text, "start", node=P._ToModel(".").node, max_depth=P.MAX_DEPTH,
                          too_deep=P._too_deep)
        assert made == P._ToModel(".").transform(lark_own.parse(text, start="start"))


def test_the_parser_loop_agrees_with_lark_on_mutated_models():
    """The one-loop parser (grammar/lalr.py) against lark's own, on 300 random mutations of
    the examples (characters deleted, inserted, runs reversed; keywords, CR LF and a byte
    order mark among the insertions): where lark refuses the text the loop gives up (and
    lark's error is what the user sees); where lark parses it, the trees, their positions and
    the models made from them are the same."""
    import random
    from pathlib import Path

    from lark.exceptions import UnexpectedInput

    from mechdsl.errors import MechError
    from mechdsl.grammar import parser as P

    texts = [p.read_text() for p in sorted(Path(__file__).parent.parent.glob("examples/*.mech"))]
    lark_own, loop = P._build_parser(fast=False), P._fast()
    rng = random.Random(20261128)
    alphabet = list("()[]{},.;:=+-*/^<>!#\"\n \t0123456789abxyz_") + [
        "body", "point", "param", "if", "then", "else", "and", "not", "step", "ground", "1e-3",
        "\r\n", "\ufeff"]

    def positions(tree):
        return [(t.data, t.meta.empty, *(getattr(t.meta, a, None) for a in (
            "line", "column", "start_pos", "end_line", "end_column", "end_pos",
            "container_line", "container_column", "container_end_line", "container_end_column")))
            for t in tree.iter_subtrees()]

    def model(make):
        try:
            return make()
        except MechError as err:
            return ("error", str(err))

    parsed = refused = 0
    for _ in range(300):
        chars = list(rng.choice(texts))
        for _ in range(rng.randint(1, 4)):
            k = rng.randrange(len(chars) + 1)
            if rng.random() < 0.4 and chars:
                del chars[min(k, len(chars) - 1)]
            elif rng.random() < 0.7:
                chars.insert(k, rng.choice(alphabet))
            else:
                j = rng.randrange(len(chars) + 1)
                a, b = sorted((k, j))
                chars[a:b] = chars[a:b][::-1]
        text = P.normalise("".join(chars))
        try:
            expected = lark_own.parse(text, start="start")
        except (UnexpectedInput, MechError) as err:
            refused += 1
            got = model(lambda: loop.parse(text, "start"))
            assert got == (None if isinstance(err, UnexpectedInput) else ("error", str(err))), \
                text
            continue
        parsed += 1
        tree = loop.parse(text, "start")
        assert tree == expected and positions(tree) == positions(expected), text
        assert model(lambda: loop.parse(text, "start", node=P._ToModel(".").node,
                                        max_depth=P.MAX_DEPTH, too_deep=P._too_deep)) == \
            model(lambda: P._ToModel(".").transform(expected)), text
    assert parsed > 30 and refused > 30  # both kinds were exercised


def test_a_parser_loop_that_disagrees_with_lark_is_not_used(monkeypatch):
    """The loop reads lark's internals: where, on some version of lark, it would give other
    trees or positions than lark's own parser on the self-check's texts, parser._fast
    refuses it and lark parses alone, with the same model."""
    from pathlib import Path

    from mechdsl.grammar import lalr
    from mechdsl.grammar import parser as P

    text = (Path(__file__).parent.parent / "examples" / "slider_crank.mech").read_text()
    expected = P.parse(text, "s.mech")
    real = lalr.FastLALR.parse

    def shifted(self, text, start, **kw):  # a loop one column off
        tree = real(self, text, start, **kw)
        if kw.get("node") is None and tree is not None:
            tree.meta.column += 1
        return tree

    P._fast.cache_clear()
    monkeypatch.setattr(lalr.FastLALR, "parse", shifted)
    try:
        assert P._fast() is None
        assert P.parse(text, "s.mech") == expected
    finally:
        P._fast.cache_clear()
