"""The TextMate grammar of editors/vscode on every example: each of its token classes
appears, no character of a line is left unmatched, and the tokens a reader looks for (the
declared names, the types, the keywords) get their classes. The grammar's rules are single
`match` rules, applied as a TextMate engine applies them: at each position the earliest match
of any rule, the first rule on a tie."""

import json
import re

import pytest

from conftest import EXAMPLES, ROOT

VSCODE = ROOT / "editors" / "vscode"
GRAMMAR = json.loads((VSCODE / "syntaxes" / "mech.tmLanguage.json").read_text())
FILES = sorted(EXAMPLES.glob("*.mech")) + sorted((EXAMPLES / "plugins").glob("*/*.mech"))


def rules():
    out = []
    for inc in GRAMMAR["patterns"]:
        rule = GRAMMAR["repository"][inc["include"].lstrip("#")]
        out.append((re.compile(rule["match"]), rule.get("name"), rule.get("captures", {})))
    return out


RULES = rules()


def tokenize(line: str):
    """(text, scope) of every token of the line, and the characters no rule matched."""
    tokens, unmatched, pos = [], [], 0
    while pos < len(line):
        best = None
        for k, (rx, name, captures) in enumerate(RULES):
            m = rx.search(line, pos)
            if m and (best is None or m.start() < best[0].start()):
                best = (m, name, captures)
        if best is None:
            unmatched.append(line[pos:])
            break
        m, name, captures = best
        unmatched.append(line[pos:m.start()])
        if captures:
            for group, spec in captures.items():
                if m.group(int(group)) is not None:
                    tokens.append((m.group(int(group)), spec["name"]))
        else:
            tokens.append((m.group(0), name))
        pos = m.end() if m.end() > pos else pos + 1
    return tokens, "".join(unmatched)


def scopes_of_grammar():
    names = set()
    for rule in GRAMMAR["repository"].values():
        if "name" in rule:
            names.add(rule["name"])
        names.update(c["name"] for c in rule.get("captures", {}).values())
    return names


def test_the_extension_declares_the_language_and_its_files():
    pkg = json.loads((VSCODE / "package.json").read_text())
    (lang,) = pkg["contributes"]["languages"]
    (grammar,) = pkg["contributes"]["grammars"]
    assert lang["extensions"] == [".mech"] and grammar["scopeName"] == GRAMMAR["scopeName"]
    assert (VSCODE / lang["configuration"]).is_file() and (VSCODE / grammar["path"]).is_file()
    config = json.loads((VSCODE / lang["configuration"]).read_text())
    assert config["comments"]["lineComment"] == "#"


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_no_character_of_an_example_is_left_unmatched(path):
    for number, line in enumerate(path.read_text().splitlines(), 1):
        _, rest = tokenize(line)
        assert not rest.strip(), f"{path.name}:{number}: {rest.strip()!r} unmatched"


def test_every_token_class_appears_in_the_examples():
    seen = set()
    for path in FILES:
        for line in path.read_text().splitlines():
            seen.update(scope for _, scope in tokenize(line)[0])
    assert scopes_of_grammar() <= seen, scopes_of_grammar() - seen


def test_the_tokens_a_reader_looks_for():
    text = (EXAMPLES / "slider_crank.mech").read_text()
    tokens = [tok for line in text.splitlines() for tok in tokenize(line)[0]]
    assert ("r", "entity.name.mech") in tokens          # param r = 2
    assert ("crank", "entity.name.mech") in tokens      # body crank {
    assert ("revolute", "entity.name.type.mech") in tokens
    assert ("angle", "entity.name.type.mech") in tokens
    assert ("step", "keyword.operator.word.mech") in tokens
    assert ('"m"', "string.quoted.double.mech") in tokens
    assert ("pi", "constant.language.mech") in tokens
    assert ("0.001", "constant.numeric.mech") in tokens
    assert ("..", "keyword.operator.mech") in tokens
    assert any(scope.startswith("comment") for _, scope in tokens)
    assert tokenize("param a = sin(t)  # x")[0][-1] == ("# x", "comment.line.number-sign.mech")
