"""Every error of a ``.mech`` file in one call: what an editor shows, and ``mechdsl check``.

Parsing stops at a file's first error; an editor wants them all. The file is cut into its
statements at the keywords that start one (a cut the language makes easy: every statement
begins with a keyword, and the reserved ones can name nothing else). Each statement is parsed
alone, in a copy of the text where everything else is blank, so that lines and columns stay
those of the file: every syntax error, located. The statements that parse are then checked
together against each other and the plugin registry (names of bodies, points, types,
arguments, outputs: :func:`mechdsl.compiled.compile.check_structure`); the statement of each
name error found is set aside and the rest checked again, so that every name error is found
too. No plugin module a file names is imported; the mesh files it names are read as data,
as loading the model reads them.
"""

from __future__ import annotations

import re

from .compiled.compile import check_structure
from .compiled.files import read_files
from .errors import MechError, Source
from .grammar import normalise, parse
from .plugins.registry import Registry

def statement_spans(text: str) -> list[tuple[int, int]]:
    """(start, end) offsets of each statement of ``text`` (a best cut for broken text)."""
    from .grammar.symbols import statement_starts, tokens

    toks = tokens(text)
    starts = [toks[i].offset for i in statement_starts(toks)]
    if not starts:
        return [(0, len(text))] if text.strip() else []
    bounds = [0] + starts[1:] + [len(text)]
    if starts[0] > 0 and text[: starts[0]].strip():
        bounds = [0, *starts, len(text)]
    return [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if text[a:b].strip()]


def _blank(text: str, keep: list[tuple[int, int]]) -> str:
    """``text`` with every character outside ``keep`` a space (line ends kept)."""
    chars = [c if c == "\n" else " " for c in text]
    for a, b in keep:
        chars[a:b] = text[a:b]
    return "".join(chars)


def _unfinished(err: MechError, text: str, span: tuple[int, int]) -> MechError:
    """The end of a statement that stops half-way, where its last token ends (not at the
    end of the comments after it), said as such."""
    from .errors import Span
    from .grammar.parser import lex

    last = None
    for tok in lex(_blank(text, [span])):
        last = tok
    if last is None:
        return err
    line, column = last.end_line, last.end_column
    return MechError(err.message.replace("unexpected end of file",
                                         "the statement ends before it is complete"),
                     Span(line, column, line, column + 1), notes=err.notes)


def _offset(text: str, line: int, column: int) -> int:
    lines = text.split("\n")
    return sum(len(x) + 1 for x in lines[: line - 1]) + column - 1


def diagnose(text: str, name: str = "<string>", registry: Registry | None = None,
             max_errors: int = 100) -> list[MechError]:
    """Every syntax error and name error of ``text``, located in it, in the order of the text
    (at most ``max_errors``). ``registry``: the plugin types to check against (None: names
    of types are not checked)."""
    text = normalise(text)
    source = Source(name, text)
    errors: list[MechError] = []
    good: list[tuple[int, int]] = []
    from .grammar.parser import _lark_parse

    #: the names that statements with a syntax error declare: not reported again as unknown
    declared: set[str] = set()
    for span in statement_spans(text):
        try:  # the statement's own syntax (names are checked below, all statements together)
            _lark_parse(Source(name, _blank(text, [span])), "start")
            good.append(span)
        except MechError as err:
            if err.message.startswith("unexpected end of file") and span[1] < len(text):
                err = _unfinished(err, text, span)
            errors.append(err.with_source(source))
            words = text[span[0]:span[1]].split()
            if len(words) > 1:
                declared.add(words[1].rstrip(":{"))
    while good and len(errors) < max_errors:
        try:
            model = parse(_blank(text, good), name)
            if registry is not None:
                # the meshes it names, read as data, as loading the model would
                check_structure(read_files(model), registry)
            break
        except MechError as err:
            unknown = re.match(r"unknown (?:body|name|param) '([^']+)'", err.message)
            if not (unknown and unknown.group(1) in declared):
                errors.append(err.with_source(source))
            if err.span is None:
                break
            at = _offset(text, err.span.line, err.span.column)
            owner = next((s for s in good if s[0] <= at < s[1]), None)
            if owner is None:
                break
            good.remove(owner)
    unique: dict[tuple, MechError] = {}
    for err in errors:
        key = (err.span.line, err.span.column) if err.span else (0, 0)
        unique.setdefault((key, err.message), err)
    return [unique[k] for k in sorted(unique)][:max_errors]


def every_error(err: MechError, text: str | None, name: str, plugins_given: bool = False
                ) -> list[MechError]:
    """``err``, found while loading the file ``name`` of ``text``, with every other syntax
    and name error of that file (:func:`diagnose` against the installed plugins), in the
    order of the text: what ``mechdsl check`` and ``mechdsl view`` show. An error that is not
    in the file (memory, reading), a run given plugin modules, or a file with ``plugin``
    lines (left to the path that loads the plugins it allows) keeps its one error."""
    if err.span is None or text is None or plugins_given or "plugin" in text:
        return [err]
    from .plugins.manager import build_registry

    return diagnose(text, name, build_registry()) or [err]
