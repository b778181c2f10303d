"""mechdsl fmt: the canonical layout keeps every token and comment (so the parsed model is the
input's), is reached from any spacing, and formatting twice changes nothing; on every example
(which are kept in it: fmt --check passes) and on the fuzzer's mutated and generated files."""

import random
import subprocess
import sys

import pytest

from conftest import EXAMPLES, ROOT, load_fuzzer, model_meaning
from mechdsl.errors import MechError
from mechdsl.grammar import parse
from mechdsl.grammar.format import format_text

ALL = sorted(EXAMPLES.glob("*.mech")) + sorted((EXAMPLES / "plugins").glob("*/*.mech"))




def respaced(text: str, rng: random.Random) -> str:
    """The same tokens with random whitespace: spaces and newlines between tokens where the
    language allows them (everywhere but inside a token or a comment)."""
    from mechdsl.grammar.parser import lex

    out = []
    for tok in lex(text, dont_ignore=True):
        if tok.type == "WS":
            out.append("\n" if "\n" in tok and rng.random() < 0.5 else
                       rng.choice([" ", "  ", "\n", " \n\n   "]))
        elif tok.type == "COMMENT":
            out.append(str(tok) + "\n")
        else:
            out.append(str(tok))
            if rng.random() < 0.3:
                out.append(rng.choice([" ", "\t", "\n    "]))
    return "".join(out)


@pytest.mark.parametrize("path", ALL, ids=lambda p: p.name)
def test_every_example_is_in_the_canonical_layout(path):
    text = path.read_text()
    assert format_text(text, str(path)) == text


@pytest.mark.parametrize("path", ALL, ids=lambda p: p.name)
def test_any_spacing_formats_to_the_same_model_and_stays(path):
    text = path.read_text()
    rng = random.Random(path.name)
    for _ in range(3):
        messy = respaced(text, rng)
        assert model_meaning(parse(messy, "m.mech")) == model_meaning(parse(text, "t.mech"))
        once = format_text(messy, "m.mech")
        assert format_text(once, "m.mech") == once
        assert model_meaning(parse(once, "o.mech")) == model_meaning(parse(text, "t.mech"))


def test_comments_stay_where_they_were_written():
    # consecutive lines with trailing comments align them, two spaces after the longest
    text = """# a file comment
param a = 1;param b=2*a # after b

# before the body
body crank{ # the crank
  # before its guess
  guess=(1,0,0)   # its guess
  point A=(-a/2,0)
  # after its points
} # after the body
output crank.x,   # the position
   crank.vx
"""
    out = format_text(text, "c.mech")
    assert out == """# a file comment
param a = 1
param b = 2*a  # after b

# before the body
body crank {  # the crank
    # before its guess
    guess = (1, 0, 0)  # its guess
    point A = (-a/2, 0)
    # after its points
}                # after the body
output crank.x,  # the position
    crank.vx
"""
    assert format_text(out, "c.mech") == out


def test_spacing_rules_keep_unary_signs_and_calls_tight():
    text = "param a=-2^-1*(3+ -4)\nparam b = if a<0 then abs( a ) else -a\n"
    assert format_text(text) == ("param a = -2^-1*(3 + -4)\n"
                                 "param b = if a < 0 then abs(a) else -a\n")


def test_a_file_that_does_not_parse_is_reported_and_left_alone(tmp_path):
    bad = tmp_path / "bad.mech"
    bad.write_text("param a = (\n")
    with pytest.raises(MechError, match="unexpected end of file"):
        format_text(bad.read_text(), str(bad))
    r = subprocess.run([sys.executable, "-m", "mechdsl", "fmt", str(bad)], capture_output=True,
                       text=True)
    assert r.returncode == 1 and f"{bad}:1:12: error:" in r.stderr
    assert bad.read_text() == "param a = (\n"


def test_the_command_checks_and_rewrites(tmp_path):
    path = tmp_path / "m.mech"
    path.write_text("param a=1;param b=2\n")
    check = [sys.executable, "-m", "mechdsl", "fmt", "--check", str(path)]
    r = subprocess.run(check, capture_output=True, text=True)
    assert r.returncode == 1 and "not in the canonical layout" in r.stdout
    assert path.read_text() == "param a=1;param b=2\n"
    r = subprocess.run([sys.executable, "-m", "mechdsl", "fmt", str(path)], capture_output=True,
                       text=True)
    assert r.returncode == 0 and path.read_text() == "param a = 1\nparam b = 2\n"
    assert subprocess.run(check).returncode == 0
    every = [sys.executable, "-m", "mechdsl", "fmt", "--check", *map(str, ALL)]
    assert subprocess.run(every, cwd=ROOT).returncode == 0


def test_the_fuzzers_files_that_parse_format_to_the_same_model():
    fuzz = load_fuzzer()
    rng = random.Random(11)
    tried = 0
    for k in range(600):
        data = fuzz.mutate(fuzz._example(rng)[1], rng) if k % 2 else fuzz.generated(rng)
        try:
            text = data.decode("utf-8")
            model = parse(text, "f.mech")
        except (MechError, UnicodeDecodeError, RecursionError):
            continue
        tried += 1
        once = format_text(text, "f.mech")
        assert format_text(once, "f.mech") == once
        assert model_meaning(parse(once, "f.mech")) == model_meaning(model)
    assert tried >= 50
