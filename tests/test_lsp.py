"""mechdsl lsp, driven as an editor drives it: the real server as a subprocess over stdio
(pytest-lsp). It answers initialize with its capabilities, publishes every error of a file
with two or more at once with their exact ranges (and none for a valid file), formats as
mechdsl fmt does, gives the outline of examples/slider_crank.mech, and imports no plugin a
file names."""

import sys

import pytest
import pytest_lsp
from lsprotocol import types as lsp
from pytest_lsp import ClientServerConfig, LanguageClient, client_capabilities

from conftest import EXAMPLES, ROOT
from mechdsl.grammar.format import format_text

BROKEN = """param r = 2
param l = 3.5 *
body crank { guess = (1, 0, 0)  point A = (-r/2, 0)  point B = (r/2, 0) }
joint A: revolute(ground.origin, crank.A)
joint B: revolut(crank.B, crank.A)
output crank.x, crnk.x
"""


# started as clients on vscode-languageclient's stdio transport start it, with --stdio (the
# slow_client fixture below starts it without)
@pytest_lsp.fixture(config=ClientServerConfig(server_command=[sys.executable, "-m", "mechdsl",
                                                              "lsp", "--stdio"]))
async def client(lsp_client: LanguageClient):
    result = await lsp_client.initialize_session(
        lsp.InitializeParams(capabilities=client_capabilities("visual-studio-code")))
    lsp_client.capabilities_seen = result.capabilities
    yield
    await lsp_client.shutdown_session()


def open_doc(client: LanguageClient, uri: str, text: str) -> None:
    client.text_document_did_open(lsp.DidOpenTextDocumentParams(
        text_document=lsp.TextDocumentItem(uri=uri, language_id="mech", version=1, text=text)))


@pytest.mark.asyncio
async def test_the_capabilities(client: LanguageClient):
    caps = client.capabilities_seen
    assert caps.document_formatting_provider
    assert caps.document_symbol_provider
    assert caps.text_document_sync is not None
    for provider in ("hover_provider", "definition_provider", "references_provider",
                     "folding_range_provider", "completion_provider"):
        assert getattr(caps, provider), provider
    assert caps.rename_provider.prepare_provider
    legend = caps.semantic_tokens_provider.legend
    assert {"keyword", "class", "property", "type", "variable"} <= set(legend.token_types)


@pytest.mark.asyncio
async def test_every_error_is_published_at_once(client: LanguageClient, tmp_path):
    uri = (tmp_path / "broken.mech").as_uri()
    open_doc(client, uri, BROKEN)
    await client.wait_for_notification(lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS)
    found = client.diagnostics[uri]
    assert [(d.range.start.line, d.range.start.character, d.range.end.character)
            for d in found] == [(1, 15, 16), (4, 9, 16), (5, 16, 22)]
    assert found[1].message.startswith("unknown joint type 'revolut'; did you mean 'revolute'?")
    assert all(d.severity == lsp.DiagnosticSeverity.Error for d in found)


@pytest.mark.asyncio
async def test_a_valid_file_has_no_diagnostic_and_its_outline(client: LanguageClient):
    path = EXAMPLES / "slider_crank.mech"
    open_doc(client, path.as_uri(), path.read_text())
    await client.wait_for_notification(lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS)
    # no error; what mechdsl check finds, as information on the simulate statement
    (info,) = client.diagnostics[path.as_uri()]
    assert info.severity == lsp.DiagnosticSeverity.Information
    assert info.range.start.line == 29  # simulate t = 0 .. 1 step 0.001
    assert info.message.startswith("3 bodies, 9 coordinates, 8 joint equations: mobility 1, "
                                   "1 drive; assembles at t = 0")
    symbols = await client.text_document_document_symbol_async(
        lsp.DocumentSymbolParams(text_document=lsp.TextDocumentIdentifier(uri=path.as_uri())))
    names = [s.name for s in symbols]
    assert names[:3] == ["r", "l", "omega"]
    crank = next(s for s in symbols if s.name == "crank")
    assert [c.name for c in crank.children] == ["A", "B"]
    assert crank.range.start.line == 8 and crank.range.end.line == 12  # lines 9 to 13
    joint = next(s for s in symbols if s.name == "D")
    assert joint.detail == "joint prismatic"


@pytest.mark.asyncio
async def test_formatting_is_mechdsl_fmt(client: LanguageClient, tmp_path):
    text = "param a=1;param b=2*a # b\nbody c{guess=(1,0,0)}\n"
    uri = (tmp_path / "f.mech").as_uri()
    open_doc(client, uri, text)
    edits = await client.text_document_formatting_async(lsp.DocumentFormattingParams(
        text_document=lsp.TextDocumentIdentifier(uri=uri),
        options=lsp.FormattingOptions(tab_size=4, insert_spaces=True)))
    (edit,) = edits
    assert edit.new_text == format_text(text)
    assert edit.range.start == lsp.Position(line=0, character=0)
    # slider_crank.mech, its layout undone (indentation, spacing), formats back to itself
    example = (EXAMPLES / "slider_crank.mech").read_text()
    messy = "\n".join(line if "#" in line else
                      " ".join(line.split()).replace(" = ", "=").replace(", ", ",")
                      for line in example.split("\n"))
    assert messy != example
    uri = (tmp_path / "sc.mech").as_uri()
    open_doc(client, uri, messy)
    (edit,) = await client.text_document_formatting_async(lsp.DocumentFormattingParams(
        text_document=lsp.TextDocumentIdentifier(uri=uri),
        options=lsp.FormattingOptions(tab_size=4, insert_spaces=True)))
    assert edit.new_text == example


@pytest.mark.asyncio
async def test_opening_a_file_that_names_a_plugin_imports_nothing(client: LanguageClient,
                                                                  tmp_path):
    # the probe module writes a file when imported: opening the model must not create it
    probe = tmp_path / "mechdsl_lsp_probe.py"
    marker = tmp_path / "imported"
    probe.write_text(f"open({str(marker)!r}, 'w').close()\n")
    text = 'plugin "mechdsl_lsp_probe"\nbody b { }\njoint j: nosuch(b.origin, ground.origin)\n'
    uri = (tmp_path / "p.mech").as_uri()
    open_doc(client, uri, text)
    await client.wait_for_notification(lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS)
    assert [d.message.split("\n")[0] for d in client.diagnostics[uri]] == \
        ["unknown joint type 'nosuch'"]
    assert not marker.exists()


def position_of(text: str, line_start: str, word: str, offset: int = 1) -> lsp.Position:
    """The position inside ``word`` on the line that starts with ``line_start``."""
    for number, line in enumerate(text.split("\n")):
        if line.startswith(line_start):
            return lsp.Position(line=number, character=line.index(word) + offset)
    raise AssertionError(line_start)


@pytest.mark.asyncio
async def test_hover_shows_a_type_a_param_and_a_body(client: LanguageClient):
    path = EXAMPLES / "slider_crank.mech"
    text = path.read_text()
    open_doc(client, path.as_uri(), text)
    ident = lsp.TextDocumentIdentifier(uri=path.as_uri())

    async def hover(line_start, word):
        result = await client.text_document_hover_async(lsp.HoverParams(
            text_document=ident, position=position_of(text, line_start, word)))
        return result.contents.value

    prismatic = await hover("joint D", "prismatic")
    assert "prismatic(p1: point, p2: point, axis: vector = (1, 0)" in prismatic
    assert "without relative rotation" in prismatic  # the plugin's own description
    assert "param omega = 4*pi" in await hover("drive", "omega")
    assert "points A, B" in await hover("joint A", "crank.A")
    assert "param **omega** = 12.5664" in await hover("drive", "omega")
    # a point's body coordinates, evaluated; an output's meaning and unit
    assert "point **crank.A** at (-1, 0) in body coordinates" in \
        await hover("joint A", "A)")
    assert await hover("output", "vx") == "output **slider.vx**: velocity, x, in m/s"
    assert "drive crank_angle: angle(crank)" in await hover("drive", "crank_angle")


@pytest.mark.asyncio
async def test_hover_evaluates_values_in_a_file_with_mistakes(client: LanguageClient, tmp_path):
    # the joints and the drive are wrong (the README's captured session): the params and the
    # points still hover with their values, r = 2 and l = 3.5 giving crank.B at (1, 0)
    text = (EXAMPLES / "slider_crank.mech").read_text()
    text = text.replace("revolute(crank.B", "revolute(cranck.B").replace("+ omega*t", "+ omga*t")
    uri = (tmp_path / "mistakes.mech").as_uri()
    open_doc(client, uri, text)
    await client.wait_for_notification(lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS)
    assert len(client.diagnostics[uri]) == 2
    ident = lsp.TextDocumentIdentifier(uri=uri)

    async def hover(line_start, word):
        result = await client.text_document_hover_async(lsp.HoverParams(
            text_document=ident, position=position_of(text, line_start, word)))
        return result.contents.value

    assert "point **rod.B** at (-1.75, 0) in body coordinates" in \
        await hover("joint B", ".B)")
    assert "param **omega** = 12.5664" in await hover("param omega", "omega")


@pytest.mark.asyncio
async def test_go_to_the_definition_of_a_point_a_body_and_a_param(client: LanguageClient):
    path = EXAMPLES / "slider_crank.mech"
    text = path.read_text()
    open_doc(client, path.as_uri(), text)
    ident = lsp.TextDocumentIdentifier(uri=path.as_uri())
    lines = text.split("\n")

    async def target(line_start, word, offset):
        loc = await client.text_document_definition_async(lsp.DefinitionParams(
            text_document=ident, position=position_of(text, line_start, word, offset)))
        return lines[loc.range.start.line].strip()

    assert (await target("joint A", "crank.A", 6)).startswith("point A = (-r/2, 0)")
    assert (await target("joint C", "slider.origin", 2)).startswith("body slider {")
    assert (await target("drive", "omega", 2)).startswith("param omega = 4*pi")


@pytest.mark.asyncio
async def test_references_rename_and_folding(client: LanguageClient, tmp_path):
    text = (EXAMPLES / "slider_crank.mech").read_text()
    uri = (tmp_path / "sc.mech").as_uri()
    open_doc(client, uri, text)
    ident = lsp.TextDocumentIdentifier(uri=uri)
    lines = text.split("\n")

    async def uses(line_start, word, offset):
        locs = await client.text_document_references_async(lsp.ReferenceParams(
            text_document=ident, position=position_of(text, line_start, word, offset),
            context=lsp.ReferenceContext(include_declaration=True)))
        return [(loc.range.start.line + 1, lines[loc.range.start.line][
            loc.range.start.character:loc.range.end.character]) for loc in locs]

    # the point crank.A: declared in crank, used by joint A (not the joint named A)
    assert await uses("joint A", "crank.A", 6) == [(11, "A"), (23, "A")]
    # the body crank: declared, and the four references to it
    assert await uses("drive", "crank)", 1) == [(9, "crank"), (23, "crank"), (24, "crank"),
                                                (28, "crank")]
    assert await uses("drive", "omega", 1) == [(5, "omega"), (28, "omega")]
    edit = await client.text_document_rename_async(lsp.RenameParams(
        text_document=ident, position=position_of(text, "param omega", "omega"),
        new_name="speed"))
    changes = edit.changes[uri]
    assert {(c.range.start.line + 1, c.new_text) for c in changes} == {(5, "speed"),
                                                                       (28, "speed")}
    folds = await client.text_document_folding_range_async(lsp.FoldingRangeParams(
        text_document=ident))
    assert [(f.start_line + 1, f.end_line + 1) for f in folds] == [(9, 13), (14, 18), (19, 21)]


@pytest.mark.asyncio
async def test_completion_offers_points_types_keywords_and_names(client: LanguageClient,
                                                                  tmp_path):
    base = (EXAMPLES / "slider_crank.mech").read_text()
    uri = (tmp_path / "c.mech").as_uri()

    async def offered(tail):
        text = base + tail
        lines = text.split("\n")
        client.text_document_did_open(lsp.DidOpenTextDocumentParams(
            text_document=lsp.TextDocumentItem(uri=uri, language_id="mech", version=1,
                                               text=text)))
        result = await client.text_document_completion_async(lsp.CompletionParams(
            text_document=lsp.TextDocumentIdentifier(uri=uri),
            position=lsp.Position(line=len(lines) - 1, character=len(lines[-1]))))
        return {item.label: item for item in result.items}

    points = await offered("output crank.")
    assert {"origin", "A", "B", "x", "omega", "ax"} <= set(points)
    types = await offered("joint E: ")
    assert {"revolute", "prismatic", "gear"} <= set(types)
    assert types["revolute"].detail == "revolute(p1: point, p2: point)"
    assert {"angle", "distance"} <= set(await offered("drive d: "))
    assert {"spring", "torque"} <= set(await offered("force f: "))
    names = await offered("param k = 2*")
    assert {"r", "l", "omega", "crank", "sin", "pi"} <= set(names)
    assert {"param", "body", "joint", "simulate"} <= set(await offered("\n"))
    traced = await offered("trace rod.C, ")  # a body's point, or a centrode's function
    assert {"crank", "rod", "ground", "ic"} <= set(traced) and "sin" not in traced
    assert "centrodes" in traced["ic"].detail


@pytest.mark.asyncio
async def test_a_file_that_does_not_assemble_is_a_warning(client: LanguageClient, tmp_path):
    text = (EXAMPLES / "slider_crank.mech").read_text().replace("param l = 3.5", "param l = 0.5")
    uri = (tmp_path / "short.mech").as_uri()
    open_doc(client, uri, text)
    await client.wait_for_notification(lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS)
    (warning,) = client.diagnostics[uri]
    assert warning.severity == lsp.DiagnosticSeverity.Warning
    assert warning.message.startswith("the mechanism cannot be assembled at t = 0")


@pytest_lsp.fixture(config=ClientServerConfig(server_command=[sys.executable, "-m", "mechdsl",
                                                              "lsp"]))
async def slow_client(lsp_client: LanguageClient):
    await lsp_client.initialize_session(lsp.InitializeParams(
        capabilities=client_capabilities("visual-studio-code"),
        initialization_options={"debounce": 0.5, "assemble": False}))
    yield
    await lsp_client.shutdown_session()


@pytest.mark.asyncio
async def test_changes_are_debounced(slow_client: LanguageClient, tmp_path):
    import asyncio

    client = slow_client
    uri = (tmp_path / "typing.mech").as_uri()
    open_doc(client, uri, "param a = 1\n")
    await client.wait_for_notification(lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS)
    assert list(client.diagnostics[uri]) == []
    # five keystrokes in a burst: each intermediate text has an error, the last has two
    for version, text in enumerate(["param a = 1\nparam", "param a = 1\nparam b",
                                    "param a = 1\nparam b =", "param a = 1\nparam b = c",
                                    "param a = 1\nparam b = c\nparam"], start=2):
        client.text_document_did_change(lsp.DidChangeTextDocumentParams(
            text_document=lsp.VersionedTextDocumentIdentifier(uri=uri, version=version),
            content_changes=[lsp.TextDocumentContentChangeWholeDocument(text=text)]))
    await client.wait_for_notification(lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS)
    # one check, of the newest text: its two errors, and no other publication follows
    assert [d.range.start.line for d in client.diagnostics[uri]] == [1, 2]
    with pytest.raises(asyncio.TimeoutError):
        await asyncio.wait_for(
            client.wait_for_notification(lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS), 1.0)


def decode(data: list[int], legend, text: str) -> dict[tuple[int, str], tuple[str, set]]:
    """{(line, word): (type, modifiers)} from LSP's relative encoding (a word's first token on
    its line)."""
    lines, out, line, col = text.split("\n"), {}, 0, 0
    for i in range(0, len(data), 5):
        dl, dc, length, kind, mods = data[i : i + 5]
        line, col = line + dl, (col + dc if dl == 0 else dc)
        word = lines[line][col : col + length]
        out.setdefault((line + 1, word), (legend.token_types[kind], {
            m for b, m in enumerate(legend.token_modifiers) if mods >> b & 1}))
    return out


@pytest.mark.asyncio
async def test_semantic_tokens_colour_names_by_what_they_name(client: LanguageClient):
    path = EXAMPLES / "slider_crank.mech"
    text = path.read_text()
    open_doc(client, path.as_uri(), text)
    result = await client.text_document_semantic_tokens_full_async(lsp.SemanticTokensParams(
        text_document=lsp.TextDocumentIdentifier(uri=path.as_uri())))
    tokens = decode(result.data, client.capabilities_seen.semantic_tokens_provider.legend, text)
    assert tokens[(3, "param")] == ("keyword", set())
    assert tokens[(3, "r")] == ("variable", {"declaration", "readonly"})
    assert tokens[(3, "2")] == ("number", set())
    assert tokens[(9, "crank")] == ("class", {"declaration"})
    assert tokens[(11, "A")] == ("property", {"declaration"})
    assert tokens[(23, "A")][0] == "event"  # the joint A, not the point crank.A
    assert tokens[(23, "revolute")] == ("type", set())
    assert tokens[(23, "origin")] == ("property", {"defaultLibrary"})
    assert tokens[(26, "axis")] == ("parameter", set())
    assert tokens[(28, "t")] == ("variable", {"defaultLibrary"})
    assert tokens[(31, '"m"')] == ("string", set())
    assert tokens[(32, "vx")] == ("enumMember", {"defaultLibrary"})


@pytest.mark.asyncio
async def test_rename_a_joint_and_a_point_and_refuse_a_clash(client: LanguageClient, tmp_path):
    from pygls.exceptions import JsonRpcException

    text = (EXAMPLES / "slider_crank.mech").read_text() + "output D.fx, D.fy, crank.B.x\n"
    uri = (tmp_path / "r.mech").as_uri()
    open_doc(client, uri, text)
    ident = lsp.TextDocumentIdentifier(uri=uri)

    async def rename(line_start, word, new_name, offset=1):
        edit = await client.text_document_rename_async(lsp.RenameParams(
            text_document=ident, position=position_of(text, line_start, word, offset),
            new_name=new_name))
        return sorted((c.range.start.line + 1, c.range.start.character)
                      for c in edit.changes[uri])

    # the joint D: its declaration and its two reactions in the output
    assert await rename("joint D", "D", "guide", 0) == [(26, 6), (33, 7), (33, 13)]
    # the point crank.B: declared, joined, output; not rod.B nor the joint B
    assert await rename("joint B", "crank.B", "tip", 6) == [(12, 10), (24, 24), (33, 25)]
    prepared = await client.text_document_prepare_rename_async(lsp.PrepareRenameParams(
        text_document=ident, position=position_of(text, "joint A", "revolute")))
    assert prepared is None  # a type belongs to its plugin
    with pytest.raises(JsonRpcException, match="already a body named 'rod'"):
        await rename("body crank", "crank", "rod")
    with pytest.raises(JsonRpcException, match="'joint' is a keyword of the language"):
        await rename("param r", "r =", "joint", 0)


@pytest.mark.asyncio
async def test_the_readme_capture_is_what_the_server_says(client: LanguageClient):
    # docs/images/nvim-diagnostics.txt, shown in the README, was captured from Neovim on
    # editors/nvim/mistakes.mech: the server still gives each of those errors on those lines
    path = ROOT / "editors" / "nvim" / "mistakes.mech"
    open_doc(client, path.as_uri(), path.read_text())
    await client.wait_for_notification(lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS)
    published = {(d.range.start.line + 1, d.message.split("\n")[0])
                 for d in client.diagnostics[path.as_uri()]}
    captured = set()
    for line in (ROOT / "docs" / "images" / "nvim-diagnostics.txt").read_text().split("\n"):
        if line.startswith("E ") and "● " in line:
            captured.add((int(line[1:6]), line.split("● ", 1)[1]))
    assert len(captured) == 4 and len(published) == 4
    for number, shown in captured:
        assert any(n == number and message.startswith(shown) for n, message in published), \
            (number, shown, published)


def test_reductions_and_the_optimize_statements_are_known_to_the_editor():
    from mechdsl.lsp import completions, hover_text
    from mechdsl.plugins.manager import build_registry

    registry = build_registry()
    text = (EXAMPLES / "coupler_synthesis.mech").read_text()
    lines = text.split("\n")
    at = next(k for k, line in enumerate(lines) if line.startswith("minimize"))
    hover = hover_text(text, "c.mech", at, lines[at].index("min(") + 1, registry)
    assert hover.startswith("reduction **min**(E): the smallest value over the run")
    offered = {label for label, _, _ in completions(text, at, len("minimize "), registry)}
    assert {"mean", "rms", "range", "argmax", "final"} <= offered
    statements = {label for label, _, _ in completions("", 0, 0, registry)}
    assert {"optimize", "minimize", "maximize", "subject to"} <= statements
