"""``mechdsl lsp``: a language server for ``.mech`` files over standard input and output.

Built on pygls (``pip install mechdsl[lsp]``; imported only by this command). What it
answers, today:

* diagnostics when a file is opened or changed: every syntax error and every name error at
  once (:func:`mechdsl.diagnostics.diagnose`), with the messages and ranges of the command
  line, checked against the installed plugin types (entry points: a plugin a file names is
  never imported because the file was opened);
* formatting: the canonical layout of ``mechdsl fmt`` (:mod:`mechdsl.grammar.format`);
* document symbols: an outline of the params, bodies (with their points), joints, drives
  and forces;
* hover: a joint, drive or force type's signature and documentation from its plugin, a
  param's definition, a body's points;
* go to definition: of a param, a body, or a point (``crank.A``);
* find references and rename: of a param, a body or a point, every use in the file (a point
  is the name after ``body.``; the other names are the words that are not after a dot);
* folding ranges: each body's braces, and each statement that spans lines;
* completion: after ``body.`` its points (and, in outputs, its quantities); after
  ``joint NAME:`` (drive, force) the installed types with their signatures; at the start of
  a statement the keywords (inside a body its items); elsewhere the params, bodies,
  functions and constants.

Ranges are LSP's: lines and characters from 0, where mechdsl's spans count from 1.
"""

from __future__ import annotations

from .errors import MechError


def _range(span, lsp):
    """An LSP range from a mechdsl Span (1-based, end column exclusive)."""
    return lsp.Range(start=lsp.Position(line=span.line - 1, character=span.column - 1),
                     end=lsp.Position(line=span.end_line - 1, character=span.end_column - 1))


def _diagnostics(text: str, path: str, registry, lsp) -> list:
    from .diagnostics import diagnose

    out = []
    for err in diagnose(text, path, registry):
        span = err.span
        if span is None:
            continue
        message = err.message + "".join(f"\n{note}" for note in err.notes)
        out.append(lsp.Diagnostic(range=_range(span, lsp), message=message,
                                  severity=lsp.DiagnosticSeverity.Error, source="mechdsl"))
    return out


def _symbols(text: str, path: str, lsp) -> list:
    """The outline of a file that parses (none for one that does not)."""
    from .grammar import parse

    try:
        model = parse(text, path)
    except MechError:
        return []
    kinds = lsp.SymbolKind

    def symbol(name: str, kind, span, name_span=None, children=()):
        return lsp.DocumentSymbol(name=name, kind=kind, range=_range(span, lsp),
                                  selection_range=_range(name_span or span, lsp),
                                  children=list(children))

    out = [symbol(p.name, kinds.Constant, p.span) for p in model.params]
    for body in model.bodies:
        points = [symbol(pt.name, kinds.Field, pt.span) for pt in body.points]
        out.append(symbol(body.name, kinds.Class, body.span, children=points))
    for kind, items in (("joint", model.joints), ("drive", model.drives),
                        ("force", model.forces)):
        for c in items:
            out.append(lsp.DocumentSymbol(
                name=c.name, detail=f"{kind} {c.type_name}", kind=kinds.Function,
                range=_range(c.span, lsp), selection_range=_range(c.span, lsp)))
    return out


def _word_at(text: str, line: int, character: int) -> tuple[str, str | None] | None:
    """The name under the cursor (0-based line and character) and, for ``body.point``, the
    body before the dot; None where there is no name."""
    lines = text.split("\n")
    if not 0 <= line < len(lines):
        return None
    row = lines[line]
    start = end = character
    while start > 0 and (row[start - 1].isalnum() or row[start - 1] == "_"):
        start -= 1
    while end < len(row) and (row[end].isalnum() or row[end] == "_"):
        end += 1
    if start == end or row[start].isdigit():
        return None
    owner = None
    if start >= 2 and row[start - 1] == ".":
        j = start - 1
        while j > 0 and (row[j - 1].isalnum() or row[j - 1] == "_"):
            j -= 1
        owner = row[j : start - 1] or None
    return row[start:end], owner


def _type_before(text: str, line: int, word: str) -> str | None:
    """The kind of statement (joint, drive, force) whose type ``word`` is on this line."""
    row = text.split("\n")[line].split("#")[0]
    head = row.split(":", 1)
    if len(head) == 2 and head[1].lstrip().startswith(word):
        first = head[0].split()
        if first and first[0] in ("joint", "drive", "force"):
            return first[0]
    return None


def hover_text(text: str, path: str, line: int, character: int, registry) -> str | None:
    """What a hover shows at the cursor (see the module), as Markdown."""
    from .grammar import parse

    found = _word_at(text, line, character)
    if found is None:
        return None
    word, owner = found
    kind = _type_before(text, line, word)
    if kind is not None and owner is None:
        ctype = registry.get(kind, word)
        if ctype is None:
            return None
        return f"```\n{kind} type {ctype.describe()}\n```\n{ctype.doc}"
    try:
        model = parse(text, path)
    except MechError:
        return None
    lines = text.split("\n")
    if owner is None:
        for p in model.params:
            if p.name == word:
                return f"```\n{lines[p.span.line - 1].split('#')[0].strip()}\n```"
        for b in model.bodies:
            if b.name == word:
                points = ", ".join(pt.name for pt in b.points) or "none but its origin"
                return f"body **{b.name}**: points {points}"
    for b in (model.ground, *model.bodies):
        if b.name == owner:
            for pt in b.points:
                if pt.name == word:
                    return f"point **{b.name}.{pt.name}** (body coordinates)"
    return None


def definition_span(text: str, path: str, line: int, character: int):
    """The span of the declaration of the param, body or point under the cursor, or None."""
    from .grammar import parse

    found = _word_at(text, line, character)
    if found is None:
        return None
    word, owner = found
    try:
        model = parse(text, path)
    except MechError:
        return None
    if owner is not None:
        for b in (model.ground, *model.bodies):
            if b.name == owner:
                return next((pt.span for pt in b.points if pt.name == word), None)
        return None
    for item in (*model.params, *model.bodies):
        if item.name == word:
            return item.span
    return None


def references(text: str, line: int, character: int) -> list[tuple[int, int, int]]:
    """(line, start, end), 0-based, of every use of the name under the cursor, its
    declaration included: a param or body is each word of that name not after a dot, a
    point each ``body.point`` of that body; [] where the cursor is on no name."""
    from .grammar.parser import _parser

    found = _word_at(text, line, character)
    if found is None:
        return []
    word, owner = found
    out = []
    try:
        tokens = [t for t in _parser().lex(text)]
    except Exception:  # noqa: BLE001 - a character no token takes
        return []
    # a point is also declared as `point NAME` inside its body's braces
    body_of_line: dict[int, str] = {}
    current = None
    for i, t in enumerate(tokens):
        if str(t) == "body" and i + 1 < len(tokens):
            current = str(tokens[i + 1])
        elif str(t) == "ground" and i + 1 < len(tokens) and str(tokens[i + 1]) == "{":
            current = "ground"
        elif str(t) == "}":
            current = None
        body_of_line[i] = current
    if owner is None:  # only a param's or a body's name: the others have no uses
        declared_here = {str(tokens[i + 1]) for i, t in enumerate(tokens[:-1])
                         if str(t) in ("param", "body")}
        if word not in declared_here:
            return []
    for i, t in enumerate(tokens):
        if str(t) != word:
            continue
        after_dot = i > 0 and str(tokens[i - 1]) == "."
        if owner is None:
            # a point, joint, drive or force of the same name is another thing
            if after_dot or (i > 0 and str(tokens[i - 1]) in ("point", "joint", "drive",
                                                                "force")):
                continue
        else:
            declared = (i > 0 and str(tokens[i - 1]) == "point" and body_of_line.get(i) == owner)
            used = after_dot and i > 1 and str(tokens[i - 2]) == owner
            if not (declared or used):
                continue
        out.append((t.line - 1, t.column - 1, t.end_column - 1))
    return out


_STATEMENTS = ("param", "ground", "body", "joint", "drive", "force", "gravity", "simulate",
               "output", "trace", "units", "sweep", "plugin")
_ITEMS = ("point", "guess", "shape", "density", "mass", "inertia", "centroid", "v0")
_FUNCTIONS = ("sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sqrt", "exp", "log",
              "abs", "sign", "min", "max", "table", "distance")


def _declared(text: str) -> tuple[list[str], dict[str, list[str]]]:
    """The params and the bodies with their points, read from the tokens (a file being
    typed need not parse)."""
    from .grammar.parser import _parser

    params, bodies, current = [], {"ground": []}, None
    try:
        tokens = [str(t) for t in _parser().lex(text)]
    except Exception:  # noqa: BLE001 - a character no token takes: what came before
        tokens = []
    for i, t in enumerate(tokens[:-1]):
        nxt = tokens[i + 1]
        if t == "param":
            params.append(nxt)
        elif t == "body":
            current = nxt
            bodies.setdefault(nxt, [])
        elif t == "ground" and nxt == "{":
            current = "ground"
        elif t == "}":
            current = None
        elif t == "point" and current is not None:
            bodies[current].append(nxt)
    return params, bodies


def completions(text: str, line: int, character: int, registry) -> list[tuple[str, str, str]]:
    """(label, kind, detail) of what may be written at the cursor (see the module)."""
    import re

    from .grammar.model import BODY_QUANTITIES, POINT_QUANTITIES

    lines = text.split("\n")
    before = lines[line][:character] if line < len(lines) else ""
    params, bodies = _declared(text)
    statement = (before.split() or [""])[0]
    dot = re.search(r"([A-Za-z_][A-Za-z0-9_]*)\.([A-Za-z_][A-Za-z0-9_]*)?$", before)
    if dot:
        body = dot.group(1)
        if body not in bodies:
            return []
        out = [(name, "point", f"point of {body}") for name in ["origin", *bodies[body]]]
        if statement in ("output", "trace"):
            out += [(q, "quantity", f"quantity of {body}") for q in BODY_QUANTITIES]
        return out
    typed = re.match(r"\s*(joint|drive|force)\s+[A-Za-z_][A-Za-z0-9_]*\s*:\s*[A-Za-z_0-9]*$",
                     before)
    if typed:
        kind = typed.group(1)
        return [(name, "type", registry.get(kind, name).describe())
                for name in registry.names(kind)]
    depth = text[: sum(len(x) + 1 for x in lines[:line]) + character].count("{") - \
        text[: sum(len(x) + 1 for x in lines[:line]) + character].count("}")
    if re.fullmatch(r"\s*[A-Za-z_]*", before):
        if depth > 0:
            return [(w, "keyword", "body item") for w in _ITEMS]
        return [(w, "keyword", "statement") for w in _STATEMENTS]
    return ([(p, "param", "param") for p in params]
            + [(b, "body", "body") for b in bodies if b != "ground"] + [("ground", "body", "")]
            + [(f, "function", "function") for f in _FUNCTIONS]
            + [(c, "constant", "") for c in ("pi", "t")])


def folding_ranges(text: str) -> list[tuple[int, int]]:
    """(first line, last line), 0-based, of each body's braces and each statement on
    several lines."""
    from .grammar.parser import _parser

    out, stack = [], []
    try:
        for t in _parser().lex(text):
            if str(t) == "{":
                stack.append(t.line - 1)
            elif str(t) == "}" and stack:
                first = stack.pop()
                if t.line - 1 > first:
                    out.append((first, t.line - 1))
    except Exception:  # noqa: BLE001 - a character no token takes: what came before
        pass
    return out


def serve() -> None:
    """Run the server on standard input and output until the client ends it."""
    try:
        import lsprotocol.types as lsp
        from pygls.server import LanguageServer
    except ImportError:
        raise MechError("the language server needs pygls: pip install mechdsl[lsp]") from None
    from urllib.parse import unquote, urlparse

    from . import __version__
    from .grammar.format import format_text
    from .plugins.manager import build_registry

    server = LanguageServer("mechdsl", __version__)
    registry = build_registry()  # the installed types, once; never a file's plugin lines

    def path_of(uri: str) -> str:
        parsed = urlparse(uri)
        return unquote(parsed.path) if parsed.scheme == "file" else uri

    def publish(uri: str) -> None:
        doc = server.workspace.get_text_document(uri)
        server.publish_diagnostics(uri, _diagnostics(doc.source, path_of(uri), registry, lsp))

    @server.feature(lsp.TEXT_DOCUMENT_DID_OPEN)
    def did_open(ls, params: lsp.DidOpenTextDocumentParams) -> None:
        publish(params.text_document.uri)

    @server.feature(lsp.TEXT_DOCUMENT_DID_CHANGE)
    def did_change(ls, params: lsp.DidChangeTextDocumentParams) -> None:
        publish(params.text_document.uri)

    @server.feature(lsp.TEXT_DOCUMENT_FORMATTING)
    def formatting(ls, params: lsp.DocumentFormattingParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        try:
            new = format_text(doc.source, path_of(params.text_document.uri))
        except MechError:
            return []  # a file with errors is left as it is; its diagnostics say why
        if new == doc.source:
            return []
        lines = doc.source.split("\n")
        end = lsp.Position(line=len(lines), character=0)
        return [lsp.TextEdit(range=lsp.Range(start=lsp.Position(line=0, character=0),
                                             end=end), new_text=new)]

    @server.feature(lsp.TEXT_DOCUMENT_HOVER)
    def hover(ls, params: lsp.HoverParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        text = hover_text(doc.source, path_of(params.text_document.uri),
                          params.position.line, params.position.character, registry)
        if text is None:
            return None
        return lsp.Hover(contents=lsp.MarkupContent(kind=lsp.MarkupKind.Markdown, value=text))

    @server.feature(lsp.TEXT_DOCUMENT_DEFINITION)
    def definition(ls, params: lsp.DefinitionParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        span = definition_span(doc.source, path_of(params.text_document.uri),
                               params.position.line, params.position.character)
        if span is None:
            return None
        return lsp.Location(uri=params.text_document.uri, range=_range(span, lsp))

    def locations(uri: str, spans) -> list:
        return [lsp.Location(uri=uri, range=lsp.Range(
            start=lsp.Position(line=ln, character=a), end=lsp.Position(line=ln, character=b)))
            for ln, a, b in spans]

    @server.feature(lsp.TEXT_DOCUMENT_REFERENCES)
    def find_references(ls, params: lsp.ReferenceParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        return locations(params.text_document.uri, references(
            doc.source, params.position.line, params.position.character))

    @server.feature(lsp.TEXT_DOCUMENT_RENAME)
    def rename(ls, params: lsp.RenameParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        if not (params.new_name.isidentifier() and params.new_name.isascii()):
            return None
        spans = references(doc.source, params.position.line, params.position.character)
        edits = [lsp.TextEdit(range=loc.range, new_text=params.new_name)
                 for loc in locations(params.text_document.uri, spans)]
        return lsp.WorkspaceEdit(changes={params.text_document.uri: edits}) if edits else None

    @server.feature(lsp.TEXT_DOCUMENT_FOLDING_RANGE)
    def folding(ls, params: lsp.FoldingRangeParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        return [lsp.FoldingRange(start_line=a, end_line=b) for a, b in folding_ranges(doc.source)]

    kinds = {"point": lsp.CompletionItemKind.Field, "quantity": lsp.CompletionItemKind.Property,
             "type": lsp.CompletionItemKind.Class, "keyword": lsp.CompletionItemKind.Keyword,
             "param": lsp.CompletionItemKind.Constant, "body": lsp.CompletionItemKind.Struct,
             "function": lsp.CompletionItemKind.Function,
             "constant": lsp.CompletionItemKind.Constant}

    @server.feature(lsp.TEXT_DOCUMENT_COMPLETION,
                    lsp.CompletionOptions(trigger_characters=[".", ":"]))
    def complete(ls, params: lsp.CompletionParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        items = completions(doc.source, params.position.line, params.position.character,
                            registry)
        return lsp.CompletionList(is_incomplete=False, items=[
            lsp.CompletionItem(label=label, kind=kinds[kind], detail=detail)
            for label, kind, detail in items])

    @server.feature(lsp.TEXT_DOCUMENT_DOCUMENT_SYMBOL)
    def document_symbol(ls, params: lsp.DocumentSymbolParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        return _symbols(doc.source, path_of(params.text_document.uri), lsp)

    server.start_io()
