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

Limits, those of the command line: a document over :data:`mechdsl.reading.MAX_MODEL_BYTES`
gets one diagnostic that says so and is never parsed (every request on it answers empty), and
a message over :func:`max_message_bytes` is skipped unread (:func:`read_messages`). Requests
read only the documents the client opened, never a file from disk.
"""

from __future__ import annotations

from .errors import MechError
from .grammar import expr as E
from .grammar.motion_functions import SIGNATURES


#: Seconds without a change before a changed file is checked again (initializationOptions
#: ``{"debounce": seconds}``): a check per keystroke would queue behind the typing
DEBOUNCE = 0.3

#: The most one character of a document can grow to in a JSON message, per byte of its UTF-8:
#: a control character (1 byte) is sent as ``\\u0001`` (6); two-, three- and four-byte
#: characters become at most 6, 6 and 12 (a surrogate pair), i.e. 3x, 2x and 3x. A message
#: that carries a document within :data:`mechdsl.reading.MAX_MODEL_BYTES` is therefore at most
#: this many times the limit, plus :data:`MESSAGE_ENVELOPE_BYTES`
JSON_ESCAPE_FACTOR = 6
#: Room for what surrounds a document's text in a message: the method, URI, version, ranges
MESSAGE_ENVELOPE_BYTES = 64 * 2**10
#: A header line longer than this is not one of LSP's (``Content-Length: N``) and is skipped
HEADER_LINE_BYTES = 4 * 2**10
#: A message body over the limit is skipped in pieces of this size; its first
#: :data:`MESSAGE_HEAD_BYTES` are kept to find its method, id and document (:func:`head_fields`)
SKIP_BYTES = 2**20
MESSAGE_HEAD_BYTES = 64 * 2**10
#: Edits are followed while a document and the text they insert stay within this many times
#: the model limit: pygls applies each change to the whole text, line by line, and a larger
#: text is refused in the end anyway
EDIT_FACTOR = 2


def max_message_bytes() -> int:
    """The largest JSON-RPC message the server reads: :data:`JSON_ESCAPE_FACTOR` times
    :data:`mechdsl.reading.MAX_MODEL_BYTES` (read now, so that raising the model limit raises
    this one) plus :data:`MESSAGE_ENVELOPE_BYTES`: 24 MiB and 64 KiB by default. Any document
    the command line would read fits in one message; a larger message is skipped unread."""
    from . import reading

    return JSON_ESCAPE_FACTOR * reading.MAX_MODEL_BYTES + MESSAGE_ENVELOPE_BYTES


def document_size(text: str) -> int:
    """The size of ``text`` in UTF-8 bytes (what the command line's limit counts), measured a
    piece at a time so that a large document is not copied whole."""
    step = 2**20
    return sum(len(text[i:i + step].encode("utf-8", "surrogatepass"))
               for i in range(0, len(text), step))


def over_limit(text: str) -> int | None:
    """The UTF-8 size of ``text`` if it is over :data:`mechdsl.reading.MAX_MODEL_BYTES` (read
    now), else None."""
    from . import reading

    size = document_size(text)
    return size if size > reading.MAX_MODEL_BYTES else None


def too_big_message(size: int, how: str = "file") -> str:
    """The one diagnostic of a document over the model limit. ``how``: ``"file"`` (the
    document is ``size`` bytes), ``"message"`` (it came in a message of ``size`` bytes, over
    :func:`max_message_bytes`, that was not read) or ``"edit"`` (an edit would take it to up
    to ``size`` characters, past what the server follows, and its text was dropped)."""
    from . import reading
    from .memory import size_text

    limit = reading.MAX_MODEL_BYTES
    over = (f"over the limit of {size_text(limit)} ({limit:,} bytes) on a model "
            "(mechdsl.reading.MAX_MODEL_BYTES)")
    if how == "message":
        first = (f"this file came in a message of {size_text(size)} ({size:,} bytes), more than "
                 f"the {size_text(max_message_bytes())} the server reads at once: the file is "
                 + over)
    elif how == "edit":
        first = (f"an edit would make this file up to {size_text(size)} ({size:,} characters), "
                 f"more than the {EDIT_FACTOR} x {size_text(limit)} the server follows, and "
                 f"the file is then {over}")
    else:
        first = f"this file is {size_text(size)} ({size:,} bytes), {over}"
    out = (first + ". The command line refuses to read it too (mechdsl check, run and the "
           "others stop with an error, exit 1), and the editor does not check it: split the "
           "model, or raise mechdsl.reading.MAX_MODEL_BYTES in a program that needs larger "
           "files")
    if how != "file":
        out += ". The server has not kept its text: close and reopen the file once it is smaller"
    return out


def head_fields(head: bytes) -> dict[str, object]:
    """The strings and numbers of the first bytes of a JSON message that are complete there, by
    path (``"method"``, ``"id"``, ``"params.textDocument.uri"``): how a message too large to
    be read whole can still be answered. Stops at the first thing that is not JSON."""
    import json

    text = head.decode("utf-8", "replace")
    decoder = json.JSONDecoder()
    out: dict[str, object] = {}
    frames: list[list] = []  # per open object or array: [is_object, key, expecting_key]
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c in " \t\r\n":
            i += 1
        elif c in "{[":
            frames.append([c == "{", None, c == "{"])
            i += 1
        elif c in "}]":
            if frames:
                frames.pop()
            i += 1
        elif c == ",":
            if frames and frames[-1][0]:
                frames[-1][2] = True
            i += 1
        elif c == ":":
            i += 1
        else:
            try:
                value, end = decoder.raw_decode(text, i)
            except ValueError:
                break
            if end >= n:  # may be cut short by the end of the head
                break
            top = frames[-1] if frames else None
            if top is not None and top[0] and top[2]:
                top[1], top[2] = value, False
            elif top is not None and all(f[0] and isinstance(f[1], str) for f in frames) \
                    and isinstance(value, (str, int, float)):
                out.setdefault(".".join(f[1] for f in frames), value)
            i = end
    return out


async def read_messages(rfile, deliver, refuse, blocking) -> None:
    """Read LSP's framed messages (``Content-Length: N``, a blank line, N bytes) from the
    binary file ``rfile`` until its end, with bounded memory: ``deliver(body)`` gets each body
    within :func:`max_message_bytes`; a larger one is skipped unread, in pieces of
    :data:`SKIP_BYTES`, and ``refuse(size, head)`` gets its size and first bytes. A header
    line that is not LSP's is skipped, and a length is found at the end of a line, so that the
    stream is picked up again after a message whose length was wrong. Each read is
    ``await blocking(function, *args)`` (the event loop's executor in the server), and the next
    one starts only once a message is handled: a slow server reads no further ahead."""
    import re

    length_header = re.compile(rb"Content-Length:[ \t]*(\d{1,20})[ \t]*\r?\n\Z", re.I)
    length = None
    while not rfile.closed:
        line = await blocking(rfile.readline, HEADER_LINE_BYTES)
        if not line:
            return
        found = length_header.search(line)
        if found:
            length = int(found.group(1))
        elif line.strip() or length is None:
            continue  # another header (Content-Type), or not a header at all
        elif length > max_message_bytes():
            head, left = b"", length
            while left:
                piece = await blocking(rfile.read, min(SKIP_BYTES, left))
                if not piece:
                    return
                if len(head) < MESSAGE_HEAD_BYTES:
                    head += piece[:MESSAGE_HEAD_BYTES - len(head)]
                left -= len(piece)
            refuse(length, head)
            length = None
        else:
            body = await blocking(rfile.read, length)
            if len(body) < length:
                return
            deliver(body)
            length = None


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
    "dissipated_power": "the power the dampers dissipate",
    "dissipated_energy": "the energy the dampers dissipated since t0 (forward dynamics)",
}


def hover_text(text: str, path: str, line: int, character: int, registry) -> str | None:
    """What a hover shows at the cursor, as Markdown: a type's signature and documentation
    (from its plugin, found through the entry points), a param's definition and value, a
    body's points, a point's body coordinates, a quantity's meaning and unit, a constraint's
    statement."""
    from .compiled.units import QUANTITY_DIMS, Units

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
        what = _QUANTITY_TEXT.get(sym.name, sym.name)
        unit = ""
        if sym.name in QUANTITY_DIMS:
            unit = Units.of(model.units if model else ()).quantity(sym.name)
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
    """Why what is under the cursor cannot be renamed to ``new_name`` (None if it can; its own
    name is always accepted, which is how prepareRename asks whether it can be renamed).

    Refused, with the reason: anything but a declared param, body, point, joint, drive, force
    or named output; a new name that is not a name of the language (a keyword, ``2x``); the
    time ``t``, a constant, a function (those of expressions, ``table``, those of outputs);
    for a point, ``origin`` and the body's quantities (``x``, ``phi``...); elsewhere the energy
    quantities; and a name already declared in the same scope: params, bodies (and the
    ground), joints, drives, forces and named outputs share one, each body's points another.
    The lists are the language's own (:mod:`mechdsl.grammar.checks`, :mod:`.grammar.symbols`,
    :mod:`.grammar.model`)."""
    from .errors import cut
    from .grammar import expr as E
    from .grammar.checks import RESERVED
    from .grammar.model import BODY_QUANTITIES, ENERGY_QUANTITIES
    from .grammar.parser import lex
    from .grammar.symbols import DECLARED_KINDS, GROUND, ORIGIN, OUTPUT_FUNCTIONS, TIME

    table, sym = _symbol_at(text, line, character)
    if sym is None or sym.kind not in DECLARED_KINDS or table.declaration(sym) is None:
        return "only a param, body, point, joint, drive, force or named output can be renamed"
    if new_name == sym.name:
        return None
    shown = cut(new_name)
    toks = list(lex(new_name)) if new_name.isidentifier() and new_name.isascii() \
        else []
    if len(toks) == 1 and toks[0].type != "NAME":
        return f"'{shown}' is a keyword of the language; choose another name"
    if len(toks) != 1:
        return (f"'{shown}' is not a name: a name is a letter or '_' followed by letters, "
                "digits and '_' (ASCII)")
    if new_name == TIME:
        return "'t' is reserved: it is the time"
    if new_name in E.CONSTANTS:
        return f"'{shown}' is reserved: it is a constant"
    if new_name in RESERVED or new_name in OUTPUT_FUNCTIONS:
        return f"'{shown}' is reserved: it is a function of the language"
    if sym.kind == "point":
        if new_name == ORIGIN:
            return "'origin' is reserved: every body has the point origin = (0, 0)"
        if new_name in BODY_QUANTITIES:
            return f"'{shown}' is reserved: {sym.owner}.{shown} is an output quantity of the body"
        if new_name in table.declared("point", sym.owner):
            return f"body {sym.owner} already has a point named '{shown}'"
        return None
    if new_name in ENERGY_QUANTITIES:
        return f"'{shown}' is reserved: it is an output quantity"
    for kind in ("param", "body", "joint", "drive", "force", "output"):
        if new_name in table.declared(kind) or (kind == "body" and new_name == GROUND):
            return f"there is already a {kind} named '{shown}'"
    return None


_STATEMENTS = ("param", "ground", "body", "joint", "drive", "initial", "force", "gravity",
               "simulate", "output", "trace", "units", "sweep", "plugin", "optimize",
               "minimize", "maximize", "subject to")
_ITEMS = ("point", "guess", "shape", "density", "mass", "inertia", "centroid", "v0")
#: every function an expression may call (an output's functions of points and bodies too)
_FUNCTIONS = (*E.FUNCTIONS, "table", *SIGNATURES)


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
    from .grammar.model import ENERGY_QUANTITIES, REDUCTIONS, TRACE_FUNCTIONS

    reads_motion = statement in ("output", "minimize", "maximize", "subject")
    reductions = ([(name, "function", f"reduction: {what}") for name, what in REDUCTIONS.items()
                   if name not in _FUNCTIONS] if reads_motion else [])
    # the energies are quantities of the motion too (an output's expression may read them)
    energies = [(e, "quantity", _QUANTITY_TEXT[e]) for e in ENERGY_QUANTITIES] \
        if reads_motion else []
    if statement == "trace":  # a point's path, or a trace function's curves
        return ([(b, "body", "body") for b in bodies if b != "ground"]
                + [("ground", "body", "")]
                + [(f, "function", what) for f, what in TRACE_FUNCTIONS.items()])
    return ([(p, "param", "param") for p in params]
            + [(b, "body", "body") for b in bodies if b != "ground"] + [("ground", "body", "")]
            + [(f, "function", "function") for f in _FUNCTIONS] + reductions + energies
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


class _Checker:
    """An executor of one daemon thread, for the checks of files: the process does not wait
    for a check still running when the client says exit (a thread pool's threads are joined
    at exit: a large model kept the server running for its whole check)."""

    def __init__(self) -> None:
        import queue
        import threading

        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        threading.Thread(target=self._work, name="mechdsl-check", daemon=True).start()

    def submit(self, function, *args):
        """Run ``function(*args)`` after the work already queued; its Future."""
        from concurrent.futures import Future

        future: Future = Future()
        self._queue.put((future, function, args))
        return future

    def _work(self) -> None:
        while True:
            future, function, args = self._queue.get()
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(function(*args))
            except BaseException as err:  # noqa: BLE001 - handed to whoever awaits it
                future.set_exception(err)


def _frame(message: dict) -> bytes:
    """``message`` as LSP sends it: a Content-Length header, a blank line, the JSON."""
    import json

    body = json.dumps(message).encode("utf-8")
    return b"Content-Length: %d\r\n\r\n%s" % (len(body), body)


def serve() -> None:
    """Run the server on standard input and output until the client ends it."""
    try:
        import lsprotocol.types as lsp
        from pygls.exceptions import JsonRpcException
        from pygls.lsp.server import LanguageServer
        from pygls.protocol import default_converter
    except ImportError:
        raise MechError("the language server needs pygls: pip install mechdsl[lsp]") from None
    import asyncio
    import json
    import logging
    import sys
    from urllib.parse import unquote, urlparse

    from . import __version__, reading
    from .errors import cut
    from .grammar.format import format_text
    from .memory import size_text
    from .plugins.manager import build_registry

    server = LanguageServer("mechdsl", __version__)
    registry = build_registry()  # the installed types, once; never a file's plugin lines
    # one thread checks the files, off the event loop, so that typing stays answered while
    # a large model assembles; the newest text of a file is checked, older ones are dropped
    checker = _Checker()
    pending: dict[str, asyncio.TimerHandle] = {}
    settings = {"debounce": DEBOUNCE, "assemble": True}
    # the documents over the model limit, each with its one diagnostic: their text is not
    # kept, and every request on them answers empty
    oversized: dict[str, str] = {}
    # initialize seen, shutdown seen: what the server answers before and after
    stage = {"initialized": False, "shut down": False}
    converter = default_converter()
    # pygls's logger of its JSON-RPC protocol: error answers, messages it cannot handle
    pygls_log = logging.getLogger("pygls.protocol.json_rpc")

    class Refusal(JsonRpcException):
        """A request refused on purpose (a rename to a reserved name): answered with its
        reason, not an internal error."""

    class Quiet(logging.Filter):
        # pygls logs every error answer with a traceback, as if the server had failed
        def filter(self, record: logging.LogRecord) -> bool:
            return not (record.exc_info and isinstance(record.exc_info[1], Refusal))

    class Transport:
        """Standard output for pygls's answers and this module's (the protocol's writer);
        closing it (exit) closes standard input too, as pygls 1's adapter did: pygls 2's
        StdoutWriter closes standard output only."""

        def __init__(self, rfile, wfile) -> None:
            self.rfile, self.wfile = rfile, wfile

        def write(self, data: bytes) -> None:
            self.wfile.write(data)
            self.wfile.flush()

        def close(self) -> None:
            self.rfile.close()
            self.wfile.close()

    def path_of(uri: str) -> str:
        parsed = urlparse(uri)
        return unquote(parsed.path) if parsed.scheme == "file" else uri

    def opened(uri: str):
        # pygls keys its documents by the URI unquoted (file:///a%20b.mech as file:///a b.mech)
        return server.workspace.text_documents.get(unquote(uri))

    def text_of(uri: str) -> str | None:
        # only what the client opened: pygls would read any other URI from disk, unbounded
        # (/dev/zero), and a document over the limit is never parsed
        doc = opened(uri)
        return None if doc is None or uri in oversized else doc.source

    def publish_diagnostics(uri: str, diagnostics: list, version=None) -> None:
        server.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(
            uri=uri, diagnostics=diagnostics, version=version))

    async def publish(uri: str) -> None:
        doc = opened(uri)
        if doc is None or uri in oversized:
            return
        version, text = doc.version, doc.source
        found = await asyncio.get_running_loop().run_in_executor(
            checker, _diagnostics, text, path_of(uri), registry, lsp, settings["assemble"])
        now = opened(uri)
        if now is not None and now.version == version and uri not in oversized:
            publish_diagnostics(uri, found, version=version)

    def drop(uri: str, version, message: str) -> None:
        """Keep an empty text for ``uri`` (so that later edits and closing still work) and
        publish its one diagnostic, ``message``, on the first line."""
        old = pending.pop(uri, None)
        if old is not None:
            old.cancel()
        doc = opened(uri)
        version = version if isinstance(version, int) else (doc.version if doc else None)
        server.workspace.put_text_document(lsp.TextDocumentItem(
            uri=uri, language_id=doc.language_id if doc and doc.language_id else "mech",
            version=version or 0, text=""))
        oversized[uri] = message
        start = lsp.Position(line=0, character=0)
        publish_diagnostics(uri, [lsp.Diagnostic(
            range=lsp.Range(start=start, end=start), message=message,
            severity=lsp.DiagnosticSeverity.Error, source="mechdsl")], version=version)

    def reply_error(msg_id, code: int, message: str) -> None:
        # an answer pygls cannot give: to a message it would fail to read, or never read
        transport.write(_frame({"jsonrpc": "2.0", "id": msg_id,
                                "error": {"code": int(code), "message": message}}))

    def log(message: str, shown: bool = False) -> None:
        server.window_log_message(lsp.LogMessageParams(type=lsp.MessageType.Error,
                                                       message=message))
        if shown:
            server.window_show_message(lsp.ShowMessageParams(type=lsp.MessageType.Error,
                                                             message=message))

    def refuse(size: int, head: bytes) -> None:
        """A message over max_message_bytes(), skipped unread: answer what its first bytes
        tell (a request's id, a document's URI), and say so in the client's log."""
        fields = head_fields(head)
        method, msg_id = fields.get("method"), fields.get("id")
        uri = fields.get("params.textDocument.uri")
        limit = max_message_bytes()
        said = (f"a message of {size:,} bytes ({size_text(size)})"
                + (f", {cut(method)}," if isinstance(method, str) else "")
                + f" was refused unread: over the limit of {limit:,} bytes for one message "
                f"({JSON_ESCAPE_FACTOR} x mechdsl.reading.MAX_MODEL_BYTES + "
                f"{MESSAGE_ENVELOPE_BYTES // 1024} KiB)")
        if isinstance(method, str) and isinstance(msg_id, (int, str)) \
                and not isinstance(msg_id, bool):
            log(said)
            reply_error(msg_id, lsp.ErrorCodes.InvalidRequest, said)
        elif method in (lsp.TEXT_DOCUMENT_DID_OPEN, lsp.TEXT_DOCUMENT_DID_CHANGE) \
                and isinstance(uri, str) and stage["initialized"] and not stage["shut down"] \
                and (method == lsp.TEXT_DOCUMENT_DID_OPEN
                     or opened(uri) is not None):
            log(said)
            drop(uri, fields.get("params.textDocument.version"),
                 too_big_message(size, "message"))
        else:
            log(said, shown=True)  # nothing else tells the user

    def problem(data: dict) -> tuple[int, str] | None:
        """What stops pygls from handling a JSON-RPC message, as (error code, message) for
        its answer; None if nothing does. pygls leaves a request it cannot read unanswered
        and logs a traceback, and reads any URI it is asked about from disk."""
        method = data.get("method")
        if not isinstance(method, str):
            return lsp.ErrorCodes.InvalidRequest, "a message without a method"
        known = server.protocol.fm.features.keys() | server.protocol.fm.builtin_features.keys()
        if method not in known:
            return lsp.ErrorCodes.MethodNotFound, f"mechdsl lsp has no method {cut(method)!r}"
        if not stage["initialized"] and method not in (lsp.INITIALIZE, lsp.EXIT):
            return lsp.ErrorCodes.ServerNotInitialized, "the server is not initialized yet"
        if stage["shut down"] and method != lsp.EXIT:
            return lsp.ErrorCodes.InvalidRequest, "the server is shut down; only exit remains"
        types = lsp.METHOD_TO_TYPES.get(method)
        if types is not None:
            try:
                converter.structure(data, types[0])
            except Exception as err:  # noqa: BLE001 - cattrs' errors vary; all mean one thing
                return (lsp.ErrorCodes.InvalidParams,
                        f"invalid params for {method}: {cut(str(err), 200)}")
        if isinstance(data.get("id"), (list, dict)):  # pygls keys its requests by id
            return lsp.ErrorCodes.InvalidRequest, "a request whose id is not a number or a string"
        return None

    def deliver(body: bytes) -> None:
        """One message within the limit: checked here, then handed to pygls whole."""
        nested = []

        def hook(obj: dict) -> dict:
            if "jsonrpc" in obj:  # pygls would take it for a message of its own
                nested.append(obj)
            return obj

        try:
            data = json.loads(body.decode("utf-8"), object_hook=hook)
        except (ValueError, RecursionError):
            log(f"a message of {len(body):,} bytes that is not JSON in UTF-8 was ignored")
            return
        msg_id = data.get("id") if isinstance(data, dict) else None
        valid_id = isinstance(msg_id, (int, str)) and not isinstance(msg_id, bool)
        if not isinstance(data, dict) or data.get("jsonrpc") != "2.0" or len(nested) > 1:
            log("a message that is not one JSON-RPC 2.0 object was ignored")
            if valid_id:
                reply_error(msg_id, lsp.ErrorCodes.InvalidRequest, "not a JSON-RPC 2.0 request")
            return
        if "method" not in data:
            return  # an answer: the server asks the client nothing
        found = problem(data)
        if found is None and data["method"] == lsp.TEXT_DOCUMENT_DID_CHANGE:
            found = changed(data)
            if found == "handled":
                return
        if found is not None:
            code, message = found
            if "id" in data:
                reply_error(msg_id if valid_id else None, code, message)
            elif code != lsp.ErrorCodes.MethodNotFound:  # LSP: notifications may be ignored
                log(message)
            return
        if data["method"] == lsp.INITIALIZE:
            stage["initialized"] = True
        elif data["method"] == lsp.SHUTDOWN:
            stage["shut down"] = True
        del data, nested
        try:  # as pygls's own reader (pygls.io_.run_async) hands it a message
            message = json.loads(body.decode("utf-8"),
                                 object_hook=server.protocol.structure_message)
            server.protocol.handle_message(message)
        except BrokenPipeError:
            raise  # the client is gone: serve() ends
        except Exception as err:  # noqa: BLE001 - the server goes on, as pygls's reader does
            pygls_log.exception("Unable to handle message")
            server.report_server_error(err, JsonRpcException)

    def changed(data: dict):
        """A didChange pygls may apply (None), or why not, or "handled" where the document's
        text is not kept: pygls applies each change to the whole text, so a document is
        followed while its text and what the edit inserts stay within EDIT_FACTOR times
        the model limit."""
        params = data["params"]
        uri = params["textDocument"]["uri"]
        doc = opened(uri)
        if doc is None:
            return lsp.ErrorCodes.InvalidParams, f"didChange of {cut(uri)}, which is not open"
        changes = params["contentChanges"]
        if uri in oversized and not any("range" not in c for c in changes):
            return "handled"  # edits to a text not kept; a whole new text is looked at
        size = grown = len(doc.source)
        for change in changes:  # a change without a range is a whole new text
            size = len(change["text"]) + (size if "range" in change else 0)
            grown = max(grown, size)
        if grown > EDIT_FACTOR * reading.MAX_MODEL_BYTES:
            drop(uri, params["textDocument"]["version"], too_big_message(grown, "edit"))
            return "handled"
        return None

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
    def did_open(ls, params: lsp.DidOpenTextDocumentParams) -> None:
        item = params.text_document
        oversized.pop(item.uri, None)
        size = over_limit(item.text)
        if size is not None:
            drop(item.uri, item.version, too_big_message(size))
            return
        asyncio.get_running_loop().create_task(publish(item.uri))

    @server.feature(lsp.TEXT_DOCUMENT_DID_CHANGE)
    def did_change(ls, params: lsp.DidChangeTextDocumentParams) -> None:
        uri = params.text_document.uri
        doc = opened(uri)
        if doc is None:
            return
        if uri in oversized and any(not hasattr(c, "range") for c in params.content_changes):
            oversized.pop(uri)  # a whole new text: looked at afresh
        if uri in oversized:
            drop(uri, params.text_document.version, oversized[uri])
            return
        size = over_limit(doc.source)
        if size is not None:
            drop(uri, params.text_document.version, too_big_message(size))
            return
        schedule(uri, float(settings["debounce"]))

    @server.feature(lsp.TEXT_DOCUMENT_DID_CLOSE)
    def did_close(ls, params: lsp.DidCloseTextDocumentParams) -> None:
        old = pending.pop(params.text_document.uri, None)
        if old is not None:
            old.cancel()
        oversized.pop(params.text_document.uri, None)
        publish_diagnostics(params.text_document.uri, [])

    @server.feature(lsp.TEXT_DOCUMENT_FORMATTING)
    def formatting(ls, params: lsp.DocumentFormattingParams):
        source = text_of(params.text_document.uri)
        if source is None:
            return []
        try:
            new = format_text(source, path_of(params.text_document.uri))
        except MechError:
            return []  # a file with errors is left as it is; its diagnostics say why
        if new == source:
            return []
        lines = source.split("\n")
        end = lsp.Position(line=len(lines), character=0)
        return [lsp.TextEdit(range=lsp.Range(start=lsp.Position(line=0, character=0),
                                             end=end), new_text=new)]

    @server.feature(lsp.TEXT_DOCUMENT_HOVER)
    def hover(ls, params: lsp.HoverParams):
        source = text_of(params.text_document.uri)
        if source is None:
            return None
        text = hover_text(source, path_of(params.text_document.uri),
                          params.position.line, params.position.character, registry)
        if text is None:
            return None
        return lsp.Hover(contents=lsp.MarkupContent(kind=lsp.MarkupKind.Markdown, value=text))

    @server.feature(lsp.TEXT_DOCUMENT_DEFINITION)
    def definition(ls, params: lsp.DefinitionParams):
        source = text_of(params.text_document.uri)
        found = None if source is None else definition_span(
            source, params.position.line, params.position.character)
        if found is None:
            return None
        return locations(params.text_document.uri, [found])[0]

    def locations(uri: str, spans) -> list:
        return [lsp.Location(uri=uri, range=lsp.Range(
            start=lsp.Position(line=ln, character=a), end=lsp.Position(line=ln, character=b)))
            for ln, a, b in spans]

    @server.feature(lsp.TEXT_DOCUMENT_REFERENCES)
    def find_references(ls, params: lsp.ReferenceParams):
        source = text_of(params.text_document.uri)
        if source is None:
            return []
        return locations(params.text_document.uri, references(
            source, params.position.line, params.position.character))

    @server.feature(lsp.TEXT_DOCUMENT_PREPARE_RENAME)
    def prepare_rename(ls, params: lsp.PrepareRenameParams):
        source = text_of(params.text_document.uri)
        if source is None:
            return None
        line, character = params.position.line, params.position.character
        _, sym = _symbol_at(source, line, character)
        if sym is None or rename_problem(source, line, character, sym.name) is not None:
            return None
        return lsp.Range(start=lsp.Position(line=sym.line - 1, character=sym.column - 1),
                         end=lsp.Position(line=sym.line - 1, character=sym.end_column - 1))

    @server.feature(lsp.TEXT_DOCUMENT_RENAME, lsp.RenameOptions(prepare_provider=True))
    def rename(ls, params: lsp.RenameParams):
        source = text_of(params.text_document.uri)
        if source is None:
            return None
        problem = rename_problem(source, params.position.line, params.position.character,
                                 params.new_name)
        if problem is not None:
            raise Refusal(code=lsp.ErrorCodes.InvalidParams, message=problem)  # shown
        spans = references(source, params.position.line, params.position.character)
        edits = [lsp.TextEdit(range=loc.range, new_text=params.new_name)
                 for loc in locations(params.text_document.uri, spans)]
        return lsp.WorkspaceEdit(changes={params.text_document.uri: edits}) if edits else None

    @server.feature(lsp.TEXT_DOCUMENT_FOLDING_RANGE)
    def folding(ls, params: lsp.FoldingRangeParams):
        source = text_of(params.text_document.uri)
        return [lsp.FoldingRange(start_line=a, end_line=b)
                for a, b in (folding_ranges(source) if source is not None else [])]

    kinds = {"point": lsp.CompletionItemKind.Field, "quantity": lsp.CompletionItemKind.Property,
             "type": lsp.CompletionItemKind.Class, "keyword": lsp.CompletionItemKind.Keyword,
             "param": lsp.CompletionItemKind.Constant, "body": lsp.CompletionItemKind.Struct,
             "function": lsp.CompletionItemKind.Function,
             "constant": lsp.CompletionItemKind.Constant}

    @server.feature(lsp.TEXT_DOCUMENT_COMPLETION,
                    lsp.CompletionOptions(trigger_characters=[".", ":"]))
    def complete(ls, params: lsp.CompletionParams):
        source = text_of(params.text_document.uri)
        items = [] if source is None else completions(
            source, params.position.line, params.position.character, registry)
        return lsp.CompletionList(is_incomplete=False, items=[
            lsp.CompletionItem(label=label, kind=kinds[kind], detail=detail)
            for label, kind, detail in items])

    @server.feature(lsp.TEXT_DOCUMENT_SEMANTIC_TOKENS_FULL, lsp.SemanticTokensLegend(
        token_types=list(SEMANTIC_TYPES), token_modifiers=list(SEMANTIC_MODIFIERS)))
    def tokens_full(ls, params: lsp.SemanticTokensParams):
        source = text_of(params.text_document.uri)
        return lsp.SemanticTokens(data=semantic_tokens(source) if source is not None else [])

    @server.feature(lsp.TEXT_DOCUMENT_DOCUMENT_SYMBOL)
    def document_symbol(ls, params: lsp.DocumentSymbolParams):
        source = text_of(params.text_document.uri)
        return [] if source is None else _symbols(source, path_of(params.text_document.uri),
                                                  lsp)

    # pygls's own reader (start_io, which runs pygls.io_.run_async) reads any message whole,
    # whatever its Content-Length: standard input is read by read_messages instead, and the
    # rest is set up as start_io would, so that pygls handles each message as its own: the
    # writer (set_writer), handle_message, the thread pool, shutdown() at the end; exit
    # closes the writer and raises SystemExit out of handle_message
    rfile = sys.stdin.buffer
    transport = Transport(rfile, sys.stdout.buffer)
    server.protocol.set_writer(transport)

    async def blocking(function, *args):
        return await asyncio.get_running_loop().run_in_executor(server.thread_pool, function,
                                                                *args)

    async def main() -> None:
        try:
            await read_messages(rfile, deliver, refuse, blocking)
        finally:  # no check starts while the loop winds down
            for handle in pending.values():
                handle.cancel()

    quiet = Quiet()
    pygls_log.addFilter(quiet)
    try:
        asyncio.run(main())
    except BrokenPipeError:
        pass  # the client is gone
    except (KeyboardInterrupt, SystemExit):
        pass
    finally:
        pygls_log.removeFilter(quiet)
        server.shutdown()
