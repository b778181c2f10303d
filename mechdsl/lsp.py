"""``mechdsl lsp``: a language server for ``.mech`` files over standard input and output.

Built on pygls (``pip install mechdsl[lsp]``; imported only by this command). What it
answers, today:

* diagnostics when a file is opened or changed: every syntax error and every name error at
  once (:func:`mechdsl.diagnostics.diagnose`), with the messages and ranges of the command
  line, checked against the installed plugin types (entry points: a plugin a file names is
  never imported because the file was opened);
* formatting: the canonical layout of ``mechdsl fmt`` (:mod:`mechdsl.grammar.format`);
* document symbols: an outline of the params, bodies (with their points), joints, drives,
  forces and outputs.

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

    @server.feature(lsp.TEXT_DOCUMENT_DOCUMENT_SYMBOL)
    def document_symbol(ls, params: lsp.DocumentSymbolParams):
        doc = server.workspace.get_text_document(params.text_document.uri)
        return _symbols(doc.source, path_of(params.text_document.uri), lsp)

    server.start_io()
