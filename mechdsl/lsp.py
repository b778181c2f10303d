"""``mechdsl lsp``: a language server for ``.mech`` files over standard input and output.

Built on pygls (``pip install mechdsl[lsp]``; imported only by this command). What it
answers:

* diagnostics when a file is opened, and when it changes once the typing pauses (debounced,
  :data:`DEBOUNCE`): every syntax error, name error and plugin-argument error at once
  (:func:`mechdsl.diagnostics.diagnose`), with the messages and ranges of the command line;
  for a file without one, what ``mechdsl check`` finds (the mobility count as information,
  a failure to assemble at t0 as a warning), computed in a worker thread so that the editor
  stays answered. Types are those of the installed plugins (entry points): a plugin module a
  file names is never imported because the file was opened;
* formatting: the canonical layout of ``mechdsl fmt`` (:mod:`mechdsl.grammar.format`);
* document symbols (an outline), folding ranges, semantic tokens;
* hover: a type's signature and documentation from its plugin, a param's definition and
  value, a body's points, a point's body coordinates, a quantity's meaning and unit;
* go to definition, find references, rename (with prepareRename): of a param, body, point,
  joint, drive, force or named output, from the symbol table of
  :mod:`mechdsl.grammar.symbols`, which a file being typed also has;
* completion: after ``body.`` its points (and, in outputs, its quantities); after
  ``joint NAME:`` (drive, force) the installed types with their signatures; at the start of
  a statement the keywords (inside a body its items); elsewhere the params, bodies,
  functions and constants.

Options, as the client's ``initializationOptions``: ``{"debounce": seconds, "assemble":
false}`` (no ``mechdsl check`` of each file). Ranges are LSP's: lines and characters from 0,
where mechdsl's spans count from 1.
"""

from __future__ import annotations

from .errors import MechError


#: Seconds without a change before a changed file is checked again (initializationOptions
#: ``{"debounce": seconds}``): a check per keystroke would queue behind the typing
DEBOUNCE = 0.3


def _range(span, lsp):
    """An LSP range from a mechdsl Span (1-based, end column exclusive)."""
    return lsp.Range(start=lsp.Position(line=span.line - 1, character=span.column - 1),
                     end=lsp.Position(line=span.end_line - 1, character=span.end_column - 1))


def _diagnostics(text: str, path: str, registry, lsp, assemble: bool = True) -> list:
    """What the editor shows for ``text``: every syntax, name and plugin-argument error (the
    messages of the command line); for a file without one, when ``assemble``, what
    ``mechdsl check`` finds (:meth:`mechdsl.api.Mechanism.check`): the mobility count as
    information, and a failure to assemble at t0 or a mechanism that is not fully driven
    as a warning. Both sit on the ``simulate`` statement (the first line without one)."""
    from .diagnostics import diagnose

    out = []
    for err in diagnose(text, path, registry):
        span = err.span
        if span is None:
            continue
        message = err.message + "".join(f"\n{note}" for note in err.notes)
        out.append(lsp.Diagnostic(range=_range(span, lsp), message=message,
                                  severity=lsp.DiagnosticSeverity.Error, source="mechdsl"))
    if out or not assemble:
        return out
    found = check_summary(text, path, registry)
    if found is None:
        return out
    severity, message, line = found
    row = text.split("\n")[line] if line < len(text.split("\n")) else ""
    where = lsp.Range(start=lsp.Position(line=line, character=len(row) - len(row.lstrip())),
                      end=lsp.Position(line=line, character=len(row.split("#")[0].rstrip())))
    out.append(lsp.Diagnostic(range=where, message=message, source="mechdsl check",
                              severity=getattr(lsp.DiagnosticSeverity, severity)))
    return out


def check_summary(text: str, path: str, registry) -> tuple[str, str, int] | None:
    """(severity, message, 0-based line) of ``mechdsl check`` on a file free of errors:
    ("Information", the degrees of freedom) when it assembles at t0, ("Warning", why) when
    it does not. The file's ``plugin`` lines are left out: only the installed types are
    known here, and nothing a file names is imported."""
    import dataclasses

    from .api import Mechanism
    from .grammar import parse

    try:
        model = dataclasses.replace(parse(text, path), plugins=())
    except MechError:
        return None
    line = model.simulate.span.line - 1 if model.simulate is not None else 0
    try:
        report = Mechanism(model, registry=registry).check()
    except MechError as err:
        return "Warning", err.message, (err.span.line - 1 if err.span else line)
    except Exception as err:  # noqa: BLE001 - a plugin's defect must not stop the server
        return "Warning", f"the check failed: {type(err).__name__}: {err}", line
    if report.error is not None:
        return "Warning", f"{report.error.message}", line
    driven = f"{report.drives} drive{'s' if report.drives != 1 else ''}"
    return "Information", (f"{report.bodies} bodies, {report.coordinates} coordinates, "
                           f"{report.equations} joint equations: mobility {report.mobility}, "
                           f"{driven}; {report.verdict.removeprefix('ok: ')}"), line


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


def _symbol_at(text: str, line: int, character: int):
    """The symbol table of ``text`` and the occurrence at the 0-based cursor (or None)."""
    from .grammar.symbols import index

    table = index(text)
    return table, table.at(line + 1, character + 1)


def _evaluated(text: str, path: str) -> tuple[object | None, dict[str, float]]:
    """The parsed model of ``text`` (None if it does not parse) and its params' values (those
    that evaluate to a number)."""
    from .grammar import expr as E
    from .grammar import parse

    try:
        model = parse(text, path)
    except MechError:
        model = _declarations(text, path)
    if model is None:
        return None, {}
    values: dict[str, float] = {}
    for p in model.params:
        try:
            value = E.evaluate(p.value, dict(values))
            values[p.name] = float(value)
        except Exception:  # noqa: BLE001 - a param of a sweep or a table: shown as written
            continue
    return model, values


#: The statements a hover reads values from: a file with an error elsewhere still has them
_DECLARATIONS = ("param", "ground", "body", "units")


def _declarations(text: str, path: str):
    """The model of ``text``'s params, ground, bodies and units alone (a file whose joints or
    drives have errors still shows its values on hover), or None if even they do not parse.
    Blank lines replace the other statements, so that lines keep their numbers."""
    from .grammar import parse
    from .grammar.symbols import statement_starts, tokens

    toks = tokens(text)
    starts = statement_starts(toks)
    keep = bytearray(len(text))
    for i, start in enumerate(starts):
        end = toks[starts[i + 1]].offset if i + 1 < len(starts) else len(text)
        if toks[start].text in _DECLARATIONS:
            keep[toks[start].offset:end] = b"\x01" * (end - toks[start].offset)
    kept = "".join(c if keep[k] or c == "\n" else " " for k, c in enumerate(text))
    try:
        return parse(kept + "\nsimulate t = 0 .. 1 step 1\n", path)
    except MechError:
        return None


def _number(e, values: dict[str, float]) -> str:
    from .grammar import expr as E

    try:
        return f"{float(E.evaluate(e, dict(values))):.6g}"
    except Exception:  # noqa: BLE001 - written, not evaluated
        return E.to_text(e)


#: What each output quantity is, for hovers
_QUANTITY_TEXT = {
    "x": "position, x", "y": "position, y", "phi": "angle", "vx": "velocity, x",
    "vy": "velocity, y", "omega": "angular velocity", "ax": "acceleration, x",
    "ay": "acceleration, y", "alpha": "angular acceleration",
    "fx": "reaction force on the joint's last attached moving body, x (global axes)",
    "fy": "reaction force on the joint's last attached moving body, y (global axes)",
    "torque": "reaction torque (a joint: on its last attached moving body, about its point; "
              "a drive: the torque or force it applies)",
    "force": "the force or torque the drive applies", "power": "the drive's power",
    "kinetic_energy": "the kinetic energy of all bodies",
    "potential_energy": "the potential energy of gravity and the conservative forces",
}


def hover_text(text: str, path: str, line: int, character: int, registry) -> str | None:
    """What a hover shows at the cursor, as Markdown: a type's signature and documentation
    (from its plugin, found through the entry points), a param's definition and value, a
    body's points, a point's body coordinates, a quantity's meaning and unit, a constraint's
    statement."""
    from .compiled.compile import unit_of

    table, sym = _symbol_at(text, line, character)
    if sym is None:
        return None
    if sym.kind == "type":
        ctype = registry.get(sym.owner, sym.name)
        if ctype is None:
            return None
        return f"```\n{sym.owner} type {ctype.describe()}\n```\n{ctype.doc}"
    if sym.kind == "function":
        from .grammar.model import REDUCTIONS

        if sym.name in REDUCTIONS:
            return (f"reduction **{sym.name}**(E): {REDUCTIONS[sym.name]}, one value per "
                    "variant" + (" (with two or more arguments, elementwise)"
                                 if sym.name in ("max", "min") else ""))
        return None
    lines = text.split("\n")
    decl = table.declaration(sym)
    written = lines[decl.line - 1].split("#")[0].strip() if decl else None
    model, values = _evaluated(text, path)
    if sym.kind == "param":
        value = f" = {values[sym.name]:.6g}" if sym.name in values else ""
        return f"```\n{written}\n```\nparam **{sym.name}**{value}" if written else None
    bodies = {b.name: b for b in (model.ground, *model.bodies)} if model else {}
    if sym.kind == "body":
        points = ", ".join(table.declared("point", sym.name)) or "none but its origin"
        out = f"body **{sym.name}**: points {points}"
        body = bodies.get(sym.name)
        if body is not None and body.mass is not None:
            out += f"; mass {_number(body.mass, values)}"
        return out
    if sym.kind == "point":
        out = f"point **{sym.owner}.{sym.name}**"
        if sym.name == "origin":
            return out + ": the origin of the body's frame, (0, 0) in body coordinates"
        body = bodies.get(sym.owner)
        point = next((p for p in body.points if p.name == sym.name), None) if body else None
        if point is not None:
            coords = ", ".join(_number(c, values) for c in point.coords.items)
            return out + f" at ({coords}) in body coordinates"
        return out + (f": `{written}` in body coordinates" if written else "")
    if sym.kind == "quantity":
        units = dict(model.units) if model else {}
        what = _QUANTITY_TEXT.get(sym.name, sym.name)
        unit = ""
        if sym.name in _QUANTITY_TEXT and sym.name in ("x", "y", "phi", "vx", "vy", "omega",
                                                       "ax", "ay", "alpha"):
            unit = unit_of(sym.name, units.get("length", ""), units.get("time", ""))
        name = f"{sym.owner}.{sym.name}" if sym.owner else sym.name
        return f"output **{name}**: {what}" + (f", in {unit}" if unit else "")
    if sym.kind in ("joint", "drive", "force", "output") and written:
        return f"```\n{written}\n```"
    if sym.kind == "time":
        return "the time **t**"
    if sym.kind == "constant":
        return f"constant **{sym.name}**"
    return None


def definition_span(text: str, line: int, character: int) -> tuple[int, int, int] | None:
    """(line, start, end), 0-based, of the declaration of what is under the cursor (a param,
    body, point, joint, drive, force or named output), or None."""
    table, sym = _symbol_at(text, line, character)
    decl = table.declaration(sym) if sym is not None else None
    if decl is None:
        return None
    return decl.line - 1, decl.column - 1, decl.end_column - 1


def references(text: str, line: int, character: int) -> list[tuple[int, int, int]]:
    """(line, start, end), 0-based, of every occurrence of what the name under the cursor
    names, its declaration included ([] where the cursor is on no declared thing)."""
    table, sym = _symbol_at(text, line, character)
    if sym is None or table.declaration(sym) is None:
        return []
    return [(s.line - 1, s.column - 1, s.end_column - 1) for s in table.uses(sym)]


def rename_problem(text: str, line: int, character: int, new_name: str) -> str | None:
    """Why what is under the cursor cannot be renamed to ``new_name`` (None if it can)."""
    from .grammar.parser import _parser
    from .grammar.symbols import DECLARED_KINDS

    table, sym = _symbol_at(text, line, character)
    if sym is None or sym.kind not in DECLARED_KINDS or table.declaration(sym) is None:
        return "only a param, body, point, joint, drive, force or named output can be renamed"
    toks = list(_parser().lex(new_name)) if new_name.isidentifier() else []
    if not (new_name.isascii() and len(toks) == 1 and toks[0].type == "NAME"):
        return f"'{new_name}' is not a name the language accepts (a keyword, or not a name)"
    clash = table.declared(sym.kind, sym.owner if sym.kind == "point" else None)
    if new_name in clash and new_name != sym.name:
        return f"there is already a {sym.kind} named '{new_name}'"
    return None


_STATEMENTS = ("param", "ground", "body", "joint", "drive", "force", "gravity", "simulate",
               "output", "trace", "units", "sweep", "plugin", "optimize", "minimize",
               "maximize", "subject to")
_ITEMS = ("point", "guess", "shape", "density", "mass", "inertia", "centroid", "v0")
_FUNCTIONS = ("sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sqrt", "exp", "log",
              "abs", "sign", "min", "max", "table", "distance")


def completions(text: str, line: int, character: int, registry) -> list[tuple[str, str, str]]:
    """(label, kind, detail) of what may be written at the cursor (see the module)."""
    import re

    from .grammar.model import BODY_QUANTITIES, POINT_QUANTITIES

    lines = text.split("\n")
    before = lines[line][:character] if line < len(lines) else ""
    from .grammar.symbols import index

    table = index(text)
    params = table.declared("param")
    bodies = {b: table.declared("point", b) for b in ["ground", *table.declared("body")]}
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
    from .grammar.model import REDUCTIONS

    reductions = ([(name, "function", f"reduction: {what}") for name, what in REDUCTIONS.items()
                   if name not in _FUNCTIONS]
                  if statement in ("output", "minimize", "maximize", "subject") else [])
    return ([(p, "param", "param") for p in params]
            + [(b, "body", "body") for b in bodies if b != "ground"] + [("ground", "body", "")]
            + [(f, "function", "function") for f in _FUNCTIONS] + reductions
            + [(c, "constant", "") for c in ("pi", "t")])


#: The legend of the semantic tokens: LSP's standard token types and modifiers
SEMANTIC_TYPES = ("keyword", "variable", "class", "property", "event", "type", "parameter",
                  "function", "number", "string", "enumMember")
SEMANTIC_MODIFIERS = ("declaration", "readonly", "defaultLibrary")
_SEMANTIC_KIND = {"param": "variable", "constant": "variable", "time": "variable",
                  "body": "class", "point": "property", "joint": "event", "drive": "event",
                  "force": "event", "output": "event", "type": "type", "argument": "parameter",
                  "option": "parameter", "variable": "parameter", "function": "function", "quantity": "enumMember"}


def semantic_tokens(text: str) -> list[int]:
    """LSP's encoding of the semantic tokens of ``text``: five integers per token (line and
    start relative to the previous token, length, type and modifier bits of the legend
    :data:`SEMANTIC_TYPES`, :data:`SEMANTIC_MODIFIERS`). Names are coloured by what they name
    (a name the file does not declare gets no token: its diagnostic says why), keywords,
    numbers and strings by their kind; comments are the TextMate grammar's."""
    from .grammar.symbols import index

    table = index(text)
    named = {(s.line, s.column): s for s in table.symbols}
    data: list[int] = []
    last_line, last_col = 1, 1
    for tok in table.tokens:
        s = named.get((tok.line, tok.column))
        mods = 0
        if s is not None:
            if s.kind == "unknown":
                continue
            kind = _SEMANTIC_KIND[s.kind]
            mods |= 1 if s.declaration else 0
            mods |= 2 if s.kind in ("param", "constant") else 0
            mods |= 4 if (s.kind in ("function", "constant", "time", "quantity")
                          or (s.kind == "point" and s.name == "origin")) else 0
        elif tok.type == "NUMBER":
            kind = "number"
        elif tok.type == "STRING":
            kind = "string"
        elif tok.text.isidentifier():
            kind = "keyword"
        else:
            continue
        col = tok.column - last_col if tok.line == last_line else tok.column - 1
        data += [tok.line - last_line, col, len(tok.text), SEMANTIC_TYPES.index(kind), mods]
        last_line, last_col = tok.line, tok.column
    return data


def folding_ranges(text: str) -> list[tuple[int, int]]:
    """(first line, last line), 0-based, of each body's braces that span lines."""
    from .grammar.symbols import tokens

    out, stack = [], []
    for t in tokens(text):
        if t.text == "{":
            stack.append(t.line - 1)
        elif t.text == "}" and stack:
            first = stack.pop()
            if t.line - 1 > first:
                out.append((first, t.line - 1))
    return out


def serve() -> None:
    """Run the server on standard input and output until the client ends it."""
    try:
        import lsprotocol.types as lsp
        from pygls.exceptions import JsonRpcException
        from pygls.server import LanguageServer
    except ImportError:
        raise MechError("the language server needs pygls: pip install mechdsl[lsp]") from None
    import asyncio
    from concurrent.futures import ThreadPoolExecutor
    from urllib.parse import unquote, urlparse

    from . import __version__
    from .grammar.format import format_text
    from .plugins.manager import build_registry

    server = LanguageServer("mechdsl", __version__)
    registry = build_registry()  # the installed types, once; never a file's plugin lines
    # one thread checks the files, off the event loop, so that typing stays answered while
    # a large model assembles; the newest text of a file is checked, older ones are dropped
    checker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mechdsl-check")
    pending: dict[str, asyncio.TimerHandle] = {}
    settings = {"debounce": DEBOUNCE, "assemble": True}

    def path_of(uri: str) -> str:
        parsed = urlparse(uri)
        return unquote(parsed.path) if parsed.scheme == "file" else uri

    async def publish(uri: str) -> None:
        doc = server.workspace.get_text_document(uri)
        version, text = doc.version, doc.source
        found = await asyncio.get_running_loop().run_in_executor(
            checker, _diagnostics, text, path_of(uri), registry, lsp, settings["assemble"])
        if server.workspace.get_text_document(uri).version == version:
            server.publish_diagnostics(uri, found, version=version)

    def schedule(uri: str, delay: float) -> None:
        old = pending.pop(uri, None)
        if old is not None:
            old.cancel()
        loop = asyncio.get_running_loop()
        pending[uri] = loop.call_later(delay, lambda: loop.create_task(publish(uri)))

    @server.feature(lsp.INITIALIZE)
    def initialize(ls, params: lsp.InitializeParams) -> None:
        options = params.initialization_options
        if isinstance(options, dict):  # {"debounce": seconds, "assemble": false}
            if isinstance(options.get("debounce"), (int, float)):
                settings["debounce"] = max(0.0, float(options["debounce"]))
            if isinstance(options.get("assemble"), bool):
                settings["assemble"] = options["assemble"]

    @server.feature(lsp.TEXT_DOCUMENT_DID_OPEN)
    async def did_open(ls, params: lsp.DidOpenTextDocumentParams) -> None:
        await publish(params.text_document.uri)

    @server.feature(lsp.TEXT_DOCUMENT_DID_CHANGE)
    def did_change(ls, params: lsp.DidChangeTextDocumentParams) -> None:
        schedule(params.text_document.uri, float(settings["debounce"]))

    @server.feature(lsp.TEXT_DOCUMENT_DID_CLOSE)
    def did_close(ls, params: lsp.DidCloseTextDocumentParams) -> None:
        old = pending.pop(params.text_document.uri, None)
        if old is not None:
            old.cancel()
        server.publish_diagnostics(params.text_document.uri, [])

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
        found = definition_span(doc.source, params.position.line, params.position.character)
        if found is None:
            return None
        return locations(params.text_document.uri, [found])[0]

    def locations(uri: str, spans) -> list:
        return [lsp.Location(uri=uri, range=lsp.Range(
            start=lsp.Position(line=ln, character=a), end=lsp.Position(line=ln, character=b)))
            for ln, a, b in spans]

    @server.feature(lsp.TEXT_DOCUMENT_REFERENCES)
    def find_references(ls, params: lsp.ReferenceParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        return locations(params.text_document.uri, references(
            doc.source, params.position.line, params.position.character))

    @server.feature(lsp.TEXT_DOCUMENT_PREPARE_RENAME)
    def prepare_rename(ls, params: lsp.PrepareRenameParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        line, character = params.position.line, params.position.character
        _, sym = _symbol_at(doc.source, line, character)
        if sym is None or rename_problem(doc.source, line, character, sym.name) is not None:
            return None
        return lsp.Range(start=lsp.Position(line=sym.line - 1, character=sym.column - 1),
                         end=lsp.Position(line=sym.line - 1, character=sym.end_column - 1))

    @server.feature(lsp.TEXT_DOCUMENT_RENAME, lsp.RenameOptions(prepare_provider=True))
    def rename(ls, params: lsp.RenameParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        problem = rename_problem(doc.source, params.position.line, params.position.character,
                                 params.new_name)
        if problem is not None:
            raise JsonRpcException(code=-32602, message=problem)  # InvalidParams, shown
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

    @server.feature(lsp.TEXT_DOCUMENT_SEMANTIC_TOKENS_FULL, lsp.SemanticTokensLegend(
        token_types=list(SEMANTIC_TYPES), token_modifiers=list(SEMANTIC_MODIFIERS)))
    def tokens_full(ls, params: lsp.SemanticTokensParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        return lsp.SemanticTokens(data=semantic_tokens(doc.source))

    @server.feature(lsp.TEXT_DOCUMENT_DOCUMENT_SYMBOL)
    def document_symbol(ls, params: lsp.DocumentSymbolParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        return _symbols(doc.source, path_of(params.text_document.uri), lsp)

    server.start_io()
