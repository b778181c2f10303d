"""The VS Code extension of editors/vscode: its manifest holds together (the files it names
exist, it activates on the language it contributes, the server command it starts by default
is the console script of pyproject.toml), and its client, extension.js, passes its own test
under node (test/activate.test.js: activate() against mocks of `vscode` and
`vscode-languageclient/node`, so that no npm package is needed). No network."""

import json
import shutil
import subprocess
import sys

if sys.version_info >= (3, 11):
    import tomllib
else:  # the test extra installs tomli on 3.10
    import tomli as tomllib

from conftest import ROOT

VSCODE = ROOT / "editors" / "vscode"
MANIFEST = json.loads((VSCODE / "package.json").read_text())
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def language_ids():
    return {lang["id"] for lang in MANIFEST["contributes"]["languages"]}


def server_setting():
    return MANIFEST["contributes"]["configuration"]["properties"]["mechdsl.server.command"]


def test_main_is_the_client():
    main = VSCODE / MANIFEST["main"]
    assert main.is_file(), f"package.json main: {MANIFEST['main']} does not exist"
    text = main.read_text()
    assert "vscode-languageclient/node" in text
    assert "activate" in text and "deactivate" in text


def test_activates_on_the_language_it_contributes():
    assert language_ids() == {"mech"}
    events = MANIFEST["activationEvents"]
    assert events, "no activationEvents"
    for event in events:
        kind, _, language = event.partition(":")
        assert kind == "onLanguage" and language in language_ids(), event
    assert ".mech" in MANIFEST["contributes"]["languages"][0]["extensions"]


def test_grammar_and_language_configuration_exist():
    for lang in MANIFEST["contributes"]["languages"]:
        assert (VSCODE / lang["configuration"]).is_file(), lang["configuration"]
    grammars = MANIFEST["contributes"]["grammars"]
    assert grammars
    for grammar in grammars:
        assert grammar["language"] in language_ids()
        path = VSCODE / grammar["path"]
        assert path.is_file(), grammar["path"]
        assert json.loads(path.read_text())["scopeName"] == grammar["scopeName"]


def test_server_command_setting_defaults_to_the_console_script():
    setting = server_setting()
    assert setting["type"] == "array" and setting["items"] == {"type": "string"}
    assert setting["default"] == ["mechdsl", "lsp"]
    script, subcommand = setting["default"]
    assert script in PYPROJECT["project"]["scripts"], (
        f"{script!r} is not a console script of pyproject.toml")
    assert PYPROJECT["project"]["scripts"][script] == "mechdsl.cli:entry"
    # `mechdsl lsp` exists, and needs the lsp extra the README and the error message name
    assert "lsp" in PYPROJECT["project"]["optional-dependencies"]
    cli = (ROOT / "mechdsl" / "cli.py").read_text()
    assert f'add_parser("{subcommand}"' in cli
    client = (VSCODE / MANIFEST["main"]).read_text()
    assert 'pip install "mechdsl[lsp]"' in client
    assert 'pip install "mechdsl[lsp]"' in (VSCODE / "README.md").read_text()


def test_client_dependency_and_engine():
    # vscode-languageclient 9 needs VS Code 1.82 or later
    assert MANIFEST["dependencies"]["vscode-languageclient"].lstrip("^~").startswith("9.")
    assert MANIFEST["engines"]["vscode"] == "^1.82.0"
    assert MANIFEST["license"] == "MIT"
    assert (VSCODE / "LICENSE").is_file()
    assert MANIFEST.get("repository"), "vsce asks for a repository field"


def test_package_leaves_out_the_tests():
    # vsce refuses a package.json "files" together with a .vscodeignore
    assert "files" not in MANIFEST
    ignored = (VSCODE / ".vscodeignore").read_text().split()
    assert "test/**" in ignored
    assert not (VSCODE / "node_modules").exists(), "node_modules belongs outside the repository"


def test_activate_under_node():
    node = shutil.which("node")
    assert node is not None, (
        "node is not on PATH: it is needed to run editors/vscode/test/activate.test.js "
        "(install Node.js 18 or later)")
    result = subprocess.run([node, str(VSCODE / "test" / "activate.test.js")], cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 failed" in result.stdout, result.stdout
