"""The README and the language reference say what the code does."""

import re

import numpy as np
import pytest

import mechdsl
from closed_forms import slider_crank
from conftest import ROOT

README = (ROOT / "README.md").read_text()
LANGUAGE = (ROOT / "docs" / "language.md").read_text()


def code_blocks(text):
    """The fenced code blocks of a markdown text, in order."""
    blocks, current = [], None
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            if current is None:
                current = []
            else:
                blocks.append("\n".join(current))
                current = None
        elif current is not None:
            current.append(line)
    return blocks


def test_the_readme_mechanism_is_the_validation_case(registry):
    block = next(b for b in code_blocks(README) if b.lstrip().startswith("param r = 2"))
    res = mechdsl.loads(block, registry=registry).simulate()
    t = res["t"]
    x, v, a = slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * t, 4 * np.pi, 0.0)
    np.testing.assert_allclose(res["slider.x"], x, rtol=1e-13)
    np.testing.assert_allclose(res["slider.ax"], a, atol=1e-12 * np.abs(a).max())


def test_the_readme_install_and_test_commands_are_marked_for_ci():
    for marker in ("install", "test"):
        assert f"<!-- {marker} -->\n```sh\n" in README
    assert "readme_command install" in (ROOT / ".ci" / "run").read_text()


JOINTS = (ROOT / "docs" / "joints.md").read_text()


def test_the_library_reference_lists_every_type_with_its_signature(registry):
    joints = JOINTS.split("## Joints")[1].split("## Drives")[0]
    drives = JOINTS.split("## Drives")[1].split("## Notes")[0]
    documented = set()
    for kind, section in (("joint", joints), ("drive", drives)):
        for call, dist in re.findall(r"^\| `(.*?)` \| (mechdsl-[a-z]+) \|", section, flags=re.M):
            name = call.split("(")[0]
            ctype = registry.get(kind, name)
            assert ctype is not None, name
            documented.add((kind, name))
            # the documented call spells the signature: names and defaults, in order
            plain = re.sub(r": [a-z]+(\([a-z]+\))?", "", ctype.describe())
            assert call == plain, (call, plain)
            assert dist == f"mechdsl-{type(ctype).__module__.split('_')[1]}"
    assert documented == set(registry.types)


@pytest.mark.parametrize("page", ["README.md", "docs/cli.md"])
def test_every_documented_run_option_exists(page):
    text = (ROOT / page).read_text()
    block = next(b for b in code_blocks(text) if b.startswith("mechdsl run FILE"))
    # each command's lines (up to the next 'mechdsl COMMAND') against its own --help
    # (the command line's own parser, in this process: its --help is what the program prints)
    import contextlib
    import io

    from mechdsl.cli import main

    for command, text in re.findall(r"^mechdsl (\w+)(.*?)(?=^mechdsl |\Z)", block,
                                    flags=re.M | re.S):
        out = io.StringIO()
        with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as done:
            main([command, "--help"])
        assert done.value.code == 0
        usage = out.getvalue()
        assert usage.startswith(f"usage: mechdsl {command}"), usage[:80]
        for option in re.findall(r"(--?[a-z][a-z0-9-]*)", text.split("#")[0]):
            assert option in usage, (command, option)


def test_documented_functions_are_the_functions():
    from mechdsl.grammar.expr import FUNCTIONS

    line = re.search(r"functions `(.*?)`", LANGUAGE, flags=re.S).group(1)
    names = set(re.findall(r"[a-z][a-z0-9]*", line)) - {"a", "b", "x", "y"}
    assert names == set(FUNCTIONS)
