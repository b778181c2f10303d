"""The symbol table kept for editors (mechdsl.grammar.symbols): checked against the parser's
own model on every example, and on broken text, where the parser gives up."""

import pytest

from conftest import EXAMPLES
from mechdsl.grammar import parse
from mechdsl.grammar.symbols import index

EXAMPLE_FILES = sorted(EXAMPLES.glob("*.mech"))


@pytest.mark.parametrize("path", EXAMPLE_FILES, ids=lambda p: p.name)
def test_the_declarations_are_the_models(path):
    text = path.read_text()
    model = parse(text, str(path))
    table = index(text)
    assert table.declared("param") == [p.name for p in model.params]
    assert table.declared("body") == (["ground"] if "ground {" in text or "ground{" in text
                                      else []) + [b.name for b in model.bodies]
    for body in (model.ground, *model.bodies):
        assert table.declared("point", body.name) == [p.name for p in body.points]
    for kind, items in (("joint", model.joints), ("drive", model.drives),
                        ("force", model.forces)):
        assert table.declared(kind) == [c.name for c in items]
    # each declaration at the place the parser gives it
    spans = {p.name: p.span for p in model.params}
    for s in table.symbols:
        if s.declaration and s.kind == "param":
            assert (s.line, s.column) == (spans[s.name].line, spans[s.name].column + 6)


@pytest.mark.parametrize("path", EXAMPLE_FILES, ids=lambda p: p.name)
def test_every_name_of_a_valid_file_is_known(path):
    unknown = [s for s in index(path.read_text()).symbols if s.kind == "unknown"]
    assert unknown == []


def kinds(text: str) -> list[tuple[str, str | None, str, bool]]:
    return [(s.kind, s.owner, s.name, s.declaration) for s in index(text).symbols]


def test_a_reference_is_a_point_a_quantity_or_a_constraint_by_what_is_declared():
    text = ("body b { point x = (1, 0) point P = (0, 1) }\n"
            "joint J: revolute(b.P, ground.origin)\n"
            "output b.x, b.vx, b.P.ay, J.fx, s = distance(b.x, b.origin), kinetic_energy\n")
    found = kinds(text)
    assert ("point", "b", "x", False) in found  # b.x names the point x, declared
    assert ("quantity", "b", "vx", False) in found
    assert ("quantity", "b.P", "ay", False) in found
    assert ("joint", None, "J", False) in found and ("quantity", "J", "fx", False) in found
    assert ("output", None, "s", True) in found
    assert ("function", None, "distance", False) in found
    assert ("point", "b", "origin", False) in found
    assert ("quantity", None, "kinetic_energy", False) in found


def test_a_broken_file_keeps_its_table():
    # an unfinished joint, a character no token takes, a body left open
    text = ("param a = 1 $\nbody b { point P = (a, 0)\n"
            "joint j: revolute(b.P, ground.origin\nsweep a = [1, 2]\nbody c {")
    found = kinds(text)
    assert ("param", None, "a", True) in found
    assert ("point", "b", "P", True) in found
    assert ("point", "b", "P", False) in found  # in the unfinished joint
    assert ("type", "joint", "revolute", False) in found
    assert ("param", None, "a", False) in found  # the sweep's param
    assert ("body", None, "c", True) in found


def test_uses_and_declaration_of_a_point_are_of_its_body_only():
    text = "body b { point P = (1, 0) }\nbody c { point P = (2, 0) }\n" \
           "joint j: revolute(b.P, c.P)\noutput c.P.x\n"
    table = index(text)
    c_use = next(s for s in table.symbols if s.owner == "c" and s.line == 4)
    assert [(s.line, s.column) for s in table.uses(c_use)] == [(2, 16), (3, 26), (4, 10)]
    assert table.declaration(c_use).line == 2
