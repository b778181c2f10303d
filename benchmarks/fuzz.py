"""Fuzz the whole pipeline: every input must end in a result (exit 0), a located user error
(exit 1) or a numerical failure (exit 2) -- never an internal error, a traceback or a hang --
and must do nothing a data file may not make happen.

    python benchmarks/fuzz.py --inputs 100000 --jobs 2
    python benchmarks/fuzz.py --seed 0 --replay 1234      # one input again, described

Inputs come from three generators: byte-level mutations of the example files (40 %: flips,
insertions, deletions, repeated or swapped lines, numbers replaced by extreme values,
truncation), random statements drawn from the grammar's vocabulary with random names and
expressions (40 %), and hostile cases (20 %, :func:`hostile`): ``plugin`` lines naming
standard or planted modules; tables and shapes naming devices, FIFOs, folders, other
people's files, random bytes, huge lines or corrupt meshes; expressions thousands of terms
long or nested up to 200,000 deep, in params, drives, ``--set``, sweeps and ``simulate``;
lines of up to 5 MB with an error in the middle, models over the size limit, byte-order
marks and CR or CRLF line endings; output paths that would destroy the model, a data file
or another output; and meaningless option values.

Each input runs in-process (``mechdsl.cli.main``: ``run FILE -q`` or ``check FILE``) in a
fresh folder of its own, with a time bound (SIGALRM) and ``--max-memory`` 400M (the limit
bounds the whole process: interpreter and libraries included), warnings shown as the command
line shows them. Exit 1 must come with a first line ``FILE:LINE:COL: error: ...`` or
``FILE: error: ...`` (a usage error of the option parser may come after its usage lines, as
``mechdsl run: error: ...``), else it is ``unlocated``; a status other than 0, 1 and 2 is
``internal``. Besides the exit status the harness checks that the input

* imported no module a ``plugin`` line named (``sys.modules`` before and after, a planted
  module's marker file, the ``this`` module's text on standard output, ``sys.path``):
  ``imported``;
* printed nothing on standard output under ``run -q`` (Python's and file descriptor 1):
  ``printed``;
* echoed no data file: no 41 characters in a row of a file the model names appear in the
  messages: ``echoed``;
* changed no file it was not asked to write (the model, its data files, other files; a
  symbolic link stays a link): ``clobbered``; wrote its outputs with the mode ``open()``
  gives (an existing file keeps its mode): ``mode``;
* left no temporary file (``.mechdsl-*``, ``*.tmp``, ``*.tmp.EXT``) in its folder or the
  temporary folder: ``stray``;
* ended with the status it must have (a hostile path, a clash of outputs, a meaningless
  option value must be refused: ``accepted`` otherwise; a model with a byte-order mark or
  CR/CRLF line endings must end as the original does: ``differs``);
* printed less than 100 kB of messages: ``flooded``; kept the peak resident memory within
  1.5 times --max-memory: ``memory``.

An exception in the harness's own code is reported too, as ``harness``.

With ``--jobs`` > 1 each worker process takes at most 200 inputs, so that a worker that
crashes (a segmentation fault: ``crash``) or hangs where SIGALRM cannot reach (``hang``) costs
one input, which is reported, and the run goes on. Inputs are numbered: input I of seed S is
the same whatever the number of jobs (``--replay I``). The counts are printed at the end; an
offending input is saved under --failures with a description and its files.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import os
import random
import re
import shutil
import signal
import stat
import struct
import sys
import tempfile
import time
import warnings
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
import fuzz_stores  # noqa: E402 - the stores' generator, beside this file
EXAMPLES = sorted((ROOT / "examples").glob("*.mech"))
DATA = {f"data/{p.name}": p.read_bytes() for p in sorted((ROOT / "examples" / "data").iterdir())
        if p.is_file()}
LOCATED = re.compile(r"^\S.*?(:\d+:\d+)?: error: ")
EXTREMES = ["0", "-0", "1e308", "-1e308", "1e-308", "1e400", "0.0000001", "123456789", "-1",
            "pi", "t", "(1", "2)", "1/0", "sqrt(-1)", "2^2000"]
WORDS = ["param", "body", "ground", "point", "guess", "joint", "drive", "simulate", "output",
         "sweep", "plugin", "if", "then", "else", "and", "or", "not", "step", "count", "t",
         "pi", "origin", "revolute", "prismatic", "angle", "x", "y", "rel_angle", "distance",
         "gear", "table", "sin", "atan2", "min", ".", "..", "(", ")", "{", "}", "[", "]", ",",
         "=", ":", ";", "+", "-", "*", "/", "^", "<", ">=", '"a.csv"', "#", "\n"]

#: --max-memory of every input that does not choose its own: it bounds the whole process
#: (40-60 MB for the interpreter and numpy, 150-250 MB once matplotlib and meshio are in)
MAX_MEMORY = "400M"
MAX_MEMORY_BYTES = 400 * 2**20
#: the share of each generator
MIX = (("mutated", 0.4), ("generated", 0.4), ("hostile", 0.2))
#: inputs per worker process (jobs > 1): a fresh interpreter after that many
RECYCLE = 200
#: messages longer than this are a defect (an error on a 5 MB line must not print it)
FLOOD = 100_000
#: a data file's content must not appear in the messages over this many characters in a row
ECHO = 41
#: names of temporary files an interrupted or failed write would leave behind
STRAY = re.compile(r"(^\.mechdsl-)|(\.tmp(\.[A-Za-z0-9]{1,20})?$)")
#: defects, in the order one is chosen to name an input that shows several
DEFECTS = ("crash", "hang", "internal", "unlocated", "imported", "clobbered", "echoed",
           "printed", "stray", "mode", "accepted", "differs", "flooded", "memory",
           "harness")  # the last: an exception in this file's own code, reported as well
ZEN = "Beautiful is better than ugly"


class Hang(BaseException):
    """The time bound passed (a BaseException: the command's own handlers must not catch it)."""


def _alarm(signum, frame):
    raise Hang()


# -----------------------------------------------------------------------------------------
# an input


@dataclass
class Case:
    """One input: a model file, the command line and the files around it, and what must
    hold afterwards besides the exit status being 0, 1 (located) or 2.

    In ``args`` and in link targets, ``{model}`` stands for the model's absolute path and
    ``{dir}`` for the input's folder (the current directory while it runs)."""

    data: bytes
    args: list[str] = field(default_factory=list)
    command: str = "run"
    name: str = "fuzz.mech"
    #: (path in the folder, spec) made before the run, in order: ("file", bytes, mode|None),
    #: ("fifo",), ("dir",), ("link", target), ("hardlink", target), ("sparse", size);
    #: a spec for ``name`` replaces the model file
    setup: list = field(default_factory=list)
    #: modules named by plugin lines: none may be imported
    plugins: tuple[str, ...] = ()
    #: files (in the folder, or absolute) whose content must not be echoed
    secrets: tuple[str, ...] = ()
    #: files the input is meant to write (everything else must be left as it was)
    writes: tuple[str, ...] = ()
    #: path -> the permission bits the file must have after the run, if it exists
    modes: dict = field(default_factory=dict)
    #: exit statuses allowed (None: any of 0, 1, 2)
    expect: frozenset | None = None
    #: an input that must end with the same status as this one (the original of a BOM or a
    #: CRLF variant)
    like: "Case | None" = None
    gen: str = "mutated"
    #: a fake Dask scheduler on the loopback interface for the input's ``{scheduler}``:
    #: (reply bytes, seconds between bytes, close after the reply), or None
    scheduler: tuple | None = None
    #: the hostile class (:data:`HOSTILE`) and a few words on the case
    cls: str = ""
    label: str = ""

    def describe(self) -> str:
        lines = [f"generator: {self.gen}" + (f", {self.cls}: {self.label}" if self.cls else ""),
                 "command: mechdsl " + " ".join([self.command, "{model}", *_shown_args(self)]),
                 f"model: {self.name} ({len(self.data):,} bytes)"]
        for path, spec in self.setup:
            if spec[0] == "file":
                mode = f", mode {spec[2]:o}" if spec[2] is not None else ""
                lines.append(f"file {path}: {len(spec[1]):,} bytes{mode}")
            else:
                lines.append(f"{spec[0]} {path}" + (f" -> {spec[1]}" if len(spec) > 1 else ""))
        if self.expect is not None:
            lines.append("must exit with " + " or ".join(map(str, sorted(self.expect))))
        if self.like is not None:
            lines.append("must exit as the original does (saved as ORIGINAL.mech)")
        return "\n".join(lines)


def _shown_args(case: Case) -> list[str]:
    return [a if len(a) <= 200 else f"{a[:80]}...({len(a):,} characters)...{a[-40:]}"
            for a in _command(case)[2:]]


def _command(case: Case) -> list[str]:
    argv = [case.command, "{model}", *case.args]
    if case.command == "run":
        if "-q" not in argv:
            argv.append("-q")
        if not any(a.startswith("--max-memory") for a in argv):
            argv += ["--max-memory", MAX_MEMORY]
    return argv


def _fill(text: str, model: str, folder: str) -> str:
    return text.replace("{model}", model).replace("{dir}", folder)


# -----------------------------------------------------------------------------------------
# generators 1 and 2: mutated examples, generated statements


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One to four random edits of a file's bytes."""
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(8)
        i = rng.randrange(len(data) + 1)
        if op == 0 and data:
            j = min(len(data) - 1, i)
            data = data[:j] + bytes([data[j] ^ (1 << rng.randrange(8))]) + data[j + 1:]
        elif op == 1:
            data = data[:i] + bytes([rng.randrange(256)]) + data[i:]
        elif op == 2:
            data = data[:i] + data[i + rng.randint(1, 20):]
        elif op == 3 or op == 4:
            lines = data.split(b"\n")
            a, b = rng.randrange(len(lines)), rng.randrange(len(lines))
            if op == 3:
                lines.insert(b, lines[a])
            else:
                lines[a], lines[b] = lines[b], lines[a]
            data = b"\n".join(lines)
        elif op == 5:
            numbers = list(re.finditer(rb"\d+(\.\d+)?", data))
            if numbers:
                m = rng.choice(numbers)
                data = data[:m.start()] + rng.choice(EXTREMES).encode() + data[m.end():]
        elif op == 6:
            data = data[:i] + rng.choice(WORDS).encode() + b" " + data[i:]
        else:
            data = data[:i]
    return data


def expression(rng: random.Random, names: list[str], depth: int = 0) -> str:
    pick = rng.randrange(9 if depth < 3 else 3)
    if pick == 0:
        return rng.choice(["0", "1", "2.5", "1e-3", "3", rng.choice(EXTREMES)])
    if pick == 1:
        return rng.choice(names + ["t", "pi"])
    if pick == 2:
        return f"{rng.uniform(-5, 5):.3g}"
    if pick in (3, 4):
        op = rng.choice("+-*/^")
        return f"{expression(rng, names, depth + 1)} {op} {expression(rng, names, depth + 1)}"
    if pick == 5:
        f = rng.choice(["sin", "cos", "sqrt", "log", "exp", "abs", "atan2", "min", "max"])
        args = ", ".join(expression(rng, names, depth + 1) for _ in range(rng.randint(1, 2)))
        return f"{f}({args})"
    if pick == 6:
        return f"({expression(rng, names, depth + 1)})"
    if pick == 7:
        return (f"if {expression(rng, names, depth + 1)} < {expression(rng, names, depth + 1)} "
                f"then {expression(rng, names, depth + 1)} else {expression(rng, names, depth + 1)}")
    return f"-{expression(rng, names, depth + 1)}"


def generated(rng: random.Random) -> bytes:
    """A random file of plausible statements over a few names."""
    params = [f"p{i}" for i in range(rng.randint(0, 3))]
    bodies = [f"b{i}" for i in range(rng.randint(1, 3))]
    out = []
    for p in params:
        out.append(f"param {p} = {expression(rng, params[:params.index(p)])}")
    for b in bodies:
        pts = " ".join(f"point P{k} = ({expression(rng, params)}, {expression(rng, params)})"
                       for k in range(rng.randint(0, 2)))
        guess = f"guess = ({expression(rng, params)}, 0, {expression(rng, params)})" \
            if rng.random() < 0.5 else ""
        out.append(f"body {b} {{ {guess} {pts} }}")
    refs = ["ground.origin"] + [f"{b}.{rng.choice(['origin', 'P0', 'P1', 'Q'])}" for b in bodies]
    for k in range(rng.randint(0, 4)):
        kind = rng.choice(["revolute", "prismatic", "pin_slot", "distance", "rigid", "gear",
                           "nosuch"])
        if kind in ("rigid", "gear"):
            args = f"{rng.choice(['ground'] + bodies)}, {rng.choice(bodies)}"
            if kind == "gear":
                args += f", ratio = {expression(rng, params)}"
        else:
            args = f"{rng.choice(refs)}, {rng.choice(refs)}"
            if kind == "distance":
                args += f", length = {expression(rng, params)}"
        out.append(f"joint j{k}: {kind}({args})")
    for k in range(rng.randint(0, 3)):
        kind = rng.choice(["angle", "x", "y", "rel_angle"])
        arg = rng.choice(bodies) if kind in ("angle",) else rng.choice(refs)
        if kind == "rel_angle":
            arg = f"{rng.choice(bodies)}, {rng.choice(bodies)}"
        out.append(f"drive d{k}: {kind}({arg}) = {expression(rng, params)}")
    if rng.random() < 0.9:
        out.append(f"simulate t = {expression(rng, params)} .. {expression(rng, params)} "
                   f"step {rng.choice(['0.1', '0.01', expression(rng, params)])}")
    if rng.random() < 0.5:
        out.append("output " + ", ".join(f"{b}.{rng.choice(['x', 'vy', 'alpha', 'P0.ax'])}"
                                         for b in bodies))
    if params and rng.random() < 0.3:
        out.append(f"sweep {rng.choice(params)} = [{expression(rng, params)}, 1]")
    rng.shuffle(out) if rng.random() < 0.1 else None
    return "\n".join(out).encode()


# -----------------------------------------------------------------------------------------
# generator 3: hostile cases

#: the examples a hostile case is built on (their data files are copied beside them)
SOURCES = {p.name: p.read_bytes() for p in EXAMPLES}
#: modules a plugin line may name: the standard library's with side effects on import
#: (antigravity opens a browser, this prints, venv.__main__ makes a virtual environment) and
#: others, imported already or not; none may be imported (names that mechdsl or its
#: libraries import by themselves, such as json, would make the check of sys.modules
#: meaningless, and are not used)
STDLIB_PLUGINS = ["antigravity", "os", "this", "venv.__main__", "os.path", "smtplib",
                  "http.server", "turtledemo.__main__", "pydoc", "mechdsl", "mechdsl.cli",
                  "__main__"]
ODD_PLUGINS = ["", " ", "../evil", "a b", "x" * 300, "os;import this", "this.", ".this",
               "\\this", "/tmp/evil", "évil", "mechdsl_revolute.nosuch"]


def _params(data: bytes) -> list[tuple[str, str]]:
    """(name, value text) of an example's params."""
    return [(m.group(1).decode(), m.group(2).decode().strip()) for m in
            re.finditer(rb"^param (\w+) = ([^#\n]*)", data, re.M)]


def _data_setup(data: bytes) -> list:
    """The example data files a model names, to copy beside it."""
    return [(path, ("file", content, None)) for path, content in DATA.items()
            if path.encode() in data]


def _statement_starts(data: bytes) -> list[int]:
    """Offsets of the lines that begin a top-level statement."""
    return [m.start() for m in re.finditer(
        rb"^(param|body|ground|joint|drive|simulate|output|trace|units|sweep)\b", data, re.M)]


def _append_to_line(data: bytes, pattern: bytes, text: bytes) -> bytes:
    """``text`` added at the end of the first line matching ``pattern`` (before a comment)."""
    m = re.search(pattern, data, re.M)
    if m is None:
        return data
    end = data.index(b"\n", m.start()) if b"\n" in data[m.start():] else len(data)
    line = data[m.start():end]
    cut = line.find(b"#")
    code, comment = (line, b"") if cut < 0 else (line[:cut].rstrip(), b"  " + line[cut:])
    return data[:m.start()] + code + text + comment + data[end:]


def _log_int(rng: random.Random, lo: int, hi: int) -> int:
    return int(round(lo * (hi / lo) ** rng.random()))


def _example(rng: random.Random, runnable: bool = True) -> tuple[str, bytes]:
    names = sorted(SOURCES)
    if runnable:  # the parallelogram ends in a numerical failure: a poor base for "ok"
        names = [n for n in names if n != "parallelogram.mech"]
    name = rng.choice(names)
    return name, SOURCES[name]


def hostile_plugin(rng: random.Random) -> Case:
    """``plugin "X"`` naming a standard module, a module planted beside the model, an odd
    name or a random one: refused, and nothing imported."""
    name, data = _example(rng)
    pick = rng.random()
    setup = _data_setup(data)
    if pick < 0.5:
        module = rng.choice(STDLIB_PLUGINS)
    elif pick < 0.75:  # a module beside the model, which proves it ran
        module = f"fuzzplug_{rng.randrange(16**6):06x}"
        setup.append((f"{module}.py", ("file", (
            f"open({module!r} + '.ran', 'w').close()\nprint('IMPORTED {module}')\n").encode(),
            None)))
    elif pick < 0.95:
        module = rng.choice(ODD_PLUGINS)
    else:
        module = "".join(rng.choice("abcdefghijklmnopqrstuvwxyz_") for _ in range(8))
    lines = [f'plugin "{module}"'.encode()]
    if rng.random() < 0.3:
        lines.append(f'plugin "{rng.choice(STDLIB_PLUGINS)}"'.encode())
    where = 0 if rng.random() < 0.7 else rng.choice(_statement_starts(data) + [len(data)])
    text = data[:where] + b"\n".join(lines) + b"\n" + data[where:]
    named = tuple(re.findall(r'plugin "([^"\n]*)"', b"\n".join(lines).decode()))
    args = []
    others = [m for m in ("json", "nosuch", "fuzzplug_other") if m not in named]
    if rng.random() < 0.2:  # allowing another module allows not this one
        args += ["--allow-plugin", rng.choice(others)]
    command = rng.choice(["run", "run", "check"])
    if command == "run" and rng.random() < 0.5:
        args += ["--step", "0.01"]
    return Case(text, args, command=command, setup=setup,
                plugins=named, expect=frozenset({1}), gen="hostile", label="plugin")


_MESH = {
    "msh": DATA.get("data/plate.msh", b""),
    "vtk": b"# vtk DataFile Version 5.1\nwritten by meshio v5.3.5\nASCII\nDATASET "
           b"UNSTRUCTURED_GRID\nPOINTS 4 double\n0.0 0.0 0.0 1.0 0.0 0.0 1.0 1.0 0.0 0.0 1.0 "
           b"0.0\nCELLS 3 6\nOFFSETS vtktypeint64\n0\n3\n6\nCONNECTIVITY vtktypeint64\n0\n1\n2"
           b"\n0\n2\n3\nCELL_TYPES 2\n5\n5\n",
    "vtu": b'<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="0.1" '
           b'byte_order="LittleEndian">\n<UnstructuredGrid>\n<Piece NumberOfPoints="4" '
           b'NumberOfCells="2">\n<Points>\n<DataArray type="Float64" Name="Points" '
           b'NumberOfComponents="3" format="ascii">\n0 0 0 1 0 0 1 1 0 0 1 0\n</DataArray>\n'
           b'</Points>\n<Cells>\n<DataArray type="Int64" Name="connectivity" format="ascii">\n'
           b'0 1 2 0 2 3\n</DataArray>\n<DataArray type="Int64" Name="offsets" format="ascii">'
           b'\n3 6\n</DataArray>\n<DataArray type="Int64" Name="types" format="ascii">\n5 5\n'
           b'</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n',
    "obj": b"# a square\nv 0.0 0.0 0.0\nv 1.0 0.0 0.0\nv 1.0 1.0 0.0\nv 0.0 1.0 0.0\n"
           b"f 1 2 3\nf 1 3 4\n",
    "stl": b"solid\nfacet normal 0.0 0.0 1.0\n outer loop\n  vertex 0.0 0.0 0.0\n  vertex 1.0 "
           b"0.0 0.0\n  vertex 1.0 1.0 0.0\n endloop\nendfacet\nfacet normal 0.0 0.0 1.0\n "
           b"outer loop\n  vertex 0.0 0.0 0.0\n  vertex 1.0 1.0 0.0\n  vertex 0.0 1.0 0.0\n "
           b"endloop\nendfacet\nendsolid\n",
    "xdmf": b'<?xml version="1.0"?>\n<Xdmf Version="3.0"><Domain><Grid Name="mesh">'
            b'<Topology TopologyType="Triangle" NumberOfElements="2"><DataItem Dimensions='
            b'"2 3" NumberType="Int" Format="XML">0 1 2 0 2 3</DataItem></Topology><Geometry '
            b'GeometryType="XYZ"><DataItem Dimensions="4 3" Format="Binary" NumberType="Float" '
            b'Precision="8">FILE</DataItem></Geometry></Grid></Domain></Xdmf>\n',
}


def _binary_stl(count: int, facets: int) -> bytes:
    facet = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 1, 1, 0, 0)
    return b"\0" * 80 + struct.pack("<I", count) + facet * facets


def _corrupt_mesh(rng: random.Random, ext: str) -> bytes:
    """A mesh file of the format ``ext`` spoilt: truncated, mutated, random, empty, claiming
    a huge size, or (XDMF) naming a device or a FIFO as its data."""
    good = _MESH[ext].replace(b"FILE", rng.choice([b"/dev/zero", b"pipe.bin", b"data.bin",
                                                   b"/etc/hosts"]))
    pick = rng.randrange(7)
    if pick == 0:
        return good[:rng.randrange(len(good) + 1)]
    if pick == 1:
        return mutate(good, rng)
    if pick == 2:
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 4096)))
    if pick == 3:
        return b""
    if pick == 4:  # a size far beyond the content
        huge = str(rng.choice([10**7, 10**9, 10**12, 2**63 - 1, -1])).encode()
        if ext == "stl":
            return _binary_stl(int(huge) % 2**32, rng.randint(0, 3))
        return re.sub(rb"(POINTS |NumberOfPoints=\"|NumberOfElements=\"|\$Nodes\n|Dimensions=\")"
                      rb"\d+", lambda m: m.group(1) + huge, good, count=2)
    if pick == 5:
        return good + b"\n" + b"#" + b"x" * rng.randint(50, 2000) + b"\n"
    return good


def _text_file(rng: random.Random) -> bytes:
    """Somebody's text file, with lines longer than 40 characters that must not be echoed."""
    lines = []
    for k in range(rng.randint(1, 20)):
        key = rng.choice(["password", "token", "api_key", "home", "note", "x"])
        value = "".join(rng.choice("abcdefghijklmnopqrstuvwxyz0123456789") for _ in
                        range(rng.randint(45, 150)))
        lines.append(rng.choice([f"{key}={value}", f"{k} {value}", f"# {value}",
                                 f"{value},{value}"]))
    return "\n".join(lines).encode()


def _hostile_file(rng: random.Random, ext: str) -> tuple[str, list, tuple[str, ...], bool]:
    """A path a table or shape may name, the setup that makes it, the files whose content
    must not be echoed, and whether it must be refused."""
    pick = rng.randrange(12)
    stem = f"f{rng.randrange(1000)}"
    if pick == 0:
        return rng.choice(["/dev/zero", "/dev/null", "/dev/urandom"]), [], (), True
    if pick == 1:
        path = f"{stem}{ext}"
        return path, [(path, ("link", rng.choice(["/dev/zero", "/dev/null"])))], (), True
    if pick == 2:
        path = f"pipe{ext}"
        return path, [(path, ("fifo",))], (), True
    if pick == 3:
        path = rng.choice([f"{stem}{ext}", ".", "/", "data"])
        return path, ([(path, ("dir",))] if path not in (".", "/") else []), (), True
    if pick == 4:
        return "/etc/hosts", [], ("/etc/hosts",), True
    if pick == 5:
        path = f"{stem}{ext}"
        content = bytes(rng.randrange(256) for _ in range(rng.randint(1, 65536)))
        return path, [(path, ("file", content, None))], (path,), True
    if pick == 6:  # a huge line with something wrong in it
        path = f"{stem}{ext}"
        n = _log_int(rng, 100_000, 5_000_000)
        unit = rng.choice([b"1,", b"0.5 ", b"x", b"9", b"abc def "])
        line = (unit * (n // len(unit)))[:n]
        mid = rng.randrange(len(line) + 1)
        content = line[:mid] + rng.choice([b"@", b"nan", b"\xff", b";;"]) + line[mid:]
        return path, [(path, ("file", content, None))], (path,), True
    if pick == 7:
        return rng.choice([f"missing{ext}", f"nodir/x{ext}", f"{stem}{ext}/x"]), [], (), True
    if pick == 8:  # somebody's text file
        path = rng.choice([f"{stem}{ext}", f"{stem}.txt", f"{stem}"])
        return path, [(path, ("file", _text_file(rng), None))], (path,), True
    if pick == 9:  # over the size limit, sparse: costs nothing to make
        path = f"{stem}{ext}"
        size = _data_limit() + rng.randint(1, 2**20)
        return path, [(path, ("sparse", size))], (), True
    if pick == 10:  # a file that is not readable
        path = f"{stem}{ext}"
        return path, [(path, ("file", b"0,0\n1,1\n", 0o000))], (), os.geteuid() != 0
    # a symbolic link to somebody's file
    path = f"{stem}{ext}"
    return path, [(path, ("link", "/etc/hosts"))], ("/etc/hosts",), True


def hostile_data(rng: random.Random) -> Case:
    """Tables and shapes naming devices, FIFOs, folders, others' files, random bytes, huge
    lines, missing files, and corrupt meshes: a located refusal, no hang, no echo."""
    name, data = _example(rng)
    setup = _data_setup(data)
    what = rng.choice(["table", "table", "shape", "mesh"])
    expect: frozenset | None = frozenset({1})
    if what == "table":
        path, more, secrets, refused = _hostile_file(rng, rng.choice([".csv", ".txt", ""]))
        ref = f'table("{path}", t)'.encode()
        if name == "cam_roller.mech" and rng.random() < 0.7:
            text = data.replace(b'"data/cam_pitch.csv"', f'"{path}"'.encode())
        else:
            text = _append_to_line(data, rb"^drive ", b" + 0*" + ref)
            if text == data:  # no drive (a forward-dynamics model): a param reads it
                text = data + f'\nparam fuzz_table = 0*table("{path}", 0)\n'.encode()
    else:
        ext = rng.choice([".msh", ".vtk", ".vtu", ".obj", ".stl", ".xdmf"])
        if what == "shape":
            path, more, secrets, refused = _hostile_file(rng, ext)
        else:
            path = f"mesh{rng.randrange(100)}{ext}"
            content = _corrupt_mesh(rng, ext[1:])
            more = [(path, ("file", content, None))]
            if ext == ".xdmf" and rng.random() < 0.5:
                more.append(("pipe.bin", ("fifo",)))
            secrets, refused = (path,), False
        if name == "fourbar_coupler.mech" and rng.random() < 0.7:
            text = data.replace(b'"data/plate.msh"', f'"{path}"'.encode())
        else:
            body = re.search(rb"^body \w+ *\{", data, re.M)
            if body is None:
                text = data + f'\nbody shaped {{ shape = "{path}" }}\n'.encode()
            else:
                text = data[:body.end()] + f' shape = "{path}" '.encode() + data[body.end():]
        if not refused:
            expect = None  # a spoilt mesh may still be a mesh
    if not refused:
        expect = None
    command = rng.choice(["run", "run", "run", "check"])
    args = ["--step", "0.01"] if command == "run" and rng.random() < 0.7 else []
    if command == "run" and rng.random() < 0.3:  # nothing but the CSV on standard output
        args += ["-o", "-"]
    return Case(text, args, command=command,
                setup=setup + more, secrets=secrets, expect=expect, gen="hostile",
                label=f"{what} {path[:60]}")


def _deep(rng: random.Random, kind: str, n: int, in_t: bool) -> str:
    """An expression of value 0 (about) that is ``n`` terms long or ``n`` deep; ``in_t``: it
    depends on t."""
    leaf = "0*t" if in_t else "0"
    if kind == "sum":
        return " + ".join(rng.choice(["0", leaf, "0*1e-3", "-0"]) for _ in range(n))
    if kind == "fourier":
        arg = "t" if in_t else "1"
        return " + ".join(f"1e-12*{rng.choice(['sin', 'cos'])}({k}*{arg})"
                          for k in range(1, n + 1))
    if kind == "parens":
        return "(" * n + leaf + ")" * n
    if kind == "unary":
        return rng.choice(["-" * n + leaf, "-(" * n + leaf + ")" * n, "- " * n + leaf])
    if kind == "power":  # right-associative: 1^(1^(1^...))
        return f"0*{'t' if in_t else '2'}^" + "^".join(["1"] * n)
    if kind == "calls":
        f = rng.choice(["sin(", "sin(", "atan(", "tanh(", "min(0, ", "max(0, "])
        if f in ("atan(", "tanh("):  # possibly not functions of the language: still no crash
            f = rng.choice([f, "sin("])
        return f * n + ("1e-9*t" if in_t else "0") + ")" * n
    raise AssertionError(kind)


DEEP_SIZES = {"sum": (500, 5000), "fourier": (500, 5000), "parens": (1000, 200_000),
              "unary": (500, 50_000), "power": (500, 50_000), "calls": (500, 50_000)}


def hostile_deep(rng: random.Random) -> Case:
    """Expressions thousands of terms long or deeply nested, in a param, a drive, --set,
    --sweep, a sweep line or simulate: a result or a located error, no internal error."""
    name, data = _example(rng)
    while not _params(data):
        name, data = _example(rng)
    kind = rng.choice(sorted(DEEP_SIZES))
    n = _log_int(rng, *DEEP_SIZES[kind])
    where = rng.choice(["param", "drive", "set", "sweep", "sweep line", "simulate"])
    params = _params(data)
    pname, pvalue = rng.choice(params)
    args: list[str] = []
    text = data
    if where == "param":
        text = _append_to_line(data, rf"^param {pname} = ".encode(),
                               b" + " + _deep(rng, kind, n, False).encode())
    elif where == "drive":
        text = _append_to_line(data, rb"^drive ", b" + " + _deep(rng, kind, n, True).encode())
    elif where == "set":
        args = ["--set", f"{pname}={pvalue} + {_deep(rng, kind, n, False)}"]
    elif where == "sweep":
        deep = _deep(rng, kind if kind != "calls" else "parens", n, False)
        args = ["--sweep", f"{pname}={pvalue},{pvalue} + {deep}"]
    elif where == "sweep line":
        text = re.sub(rb"^sweep .*$", b"", data, flags=re.M) + (
            f"\nsweep {pname} = [{pvalue}, {pvalue} + {_deep(rng, kind, n, False)}]\n").encode()
    else:
        text = re.sub(rb"^(simulate t = [^.\n]+\.\. *)([^\n#]*?)( step)",
                      lambda m: m.group(1) + b"(" + m.group(2) + b") + "
                      + _deep(rng, kind, n, False).encode() + m.group(3),
                      data, count=1, flags=re.M)
    if rng.random() < 0.2:  # and the same again, elsewhere
        args += ["--set", f"{pname}={_deep(rng, kind, n, False)} + {pvalue}"]
    command = "check" if rng.random() < 0.2 else "run"
    if command == "run":
        args += ["--step", rng.choice(["0.01", "0.02", "0.05"])]  # at most 300 instants
    return Case(text, args, command=command, setup=_data_setup(data), gen="hostile",
                label=f"deep {kind} {n} in {where}")


def _model_limit() -> int:
    try:
        from mechdsl import reading
        return int(getattr(reading, "MAX_MODEL_BYTES", 20 * 2**20))
    except Exception:  # noqa: BLE001 - the package being edited: the figure of the issue
        return 20 * 2**20


def _data_limit() -> int:
    try:
        from mechdsl import reading
        return int(getattr(reading, "MAX_DATA_BYTES", 64 * 2**20))
    except Exception:  # noqa: BLE001
        return 64 * 2**20


def _long_line(rng: random.Random, n: int) -> bytes:
    """A line of about ``n`` bytes with an error in the middle."""
    bad = rng.choice([b"@", b"$", b"`", b"\x00", b"?", b"\xc3\xa9", b"}{", b"..", b'"', b"\xff"])
    half = n // 2
    form = rng.randrange(7)
    if form == 0:
        return b"param zz = 1" + b" " * half + bad + b" " * half
    if form == 1:
        return b"param " + b"a" * half + bad + b"a" * half + b" = 1"
    if form == 2:
        return b"param zz = " + b"1" * half + bad + b"1" * half
    if form == 3:  # a string ended in the middle
        return b'units length = "' + b"x" * half + b'"' + bad + b"x" * half + b'"'
    if form == 4:  # a long sum: each term a token (kept shorter: the parser's work grows)
        k = min(half, 150_000) // 4
        return b"param zz = " + b"1 + " * k + bad + b" + 1" * k
    if form == 5:
        k = min(half, 150_000) // 9
        return b"output " + b"crank.x, " * k + bad + b", crank.x" * k
    return b"# " + b"x" * half + b"\nparam zz = " + b"y" * half + bad


def hostile_lines(rng: random.Random) -> Case:
    """Lines of 100 kB - 5 MB with an error in the middle, models over the size limit, a
    byte-order mark, CR-only and CRLF line endings."""
    name, data = _example(rng)
    setup = _data_setup(data)
    pick = rng.randrange(4)
    if pick == 0:
        line = _long_line(rng, _log_int(rng, 100_000, 5_000_000))
        where = rng.choice(_statement_starts(data) + [len(data)])
        text = data[:where] + line + b"\n" + data[where:]
        return Case(text, ["--step", "0.01"], setup=setup, expect=frozenset({1}),
                    gen="hostile", label=f"long line {len(line):,} bytes")
    if pick == 1:
        size = _model_limit() + rng.randint(1, 2**20)
        form = rng.randrange(4)
        if form == 0:
            text = data + b"\n# " + b"x" * (size - len(data)) + b"\n"
        elif form == 1:
            line = b"# padding padding padding padding padding padding padding padding\n"
            text = data + line * (size // len(line) + 1)
        elif form == 2:
            line = b"param q = 1\n"
            text = data + line * (size // len(line) + 1)
        else:  # sparse, all zero bytes
            return Case(b"", setup=setup + [("fuzz.mech", ("sparse", size))],
                        expect=frozenset({1}), gen="hostile", label=f"model of {size:,} zeros")
        return Case(text, setup=setup, expect=frozenset({1}), gen="hostile",
                    label=f"model of {len(text):,} bytes")
    original = Case(data, setup=setup, gen="hostile", label=name)
    form = rng.choice(["BOM", "CRLF", "CR", "BOM+CRLF", "BOM+CR"])
    text = data
    if "CRLF" in form:
        text = text.replace(b"\n", b"\r\n")
    elif "CR" in form:
        text = text.replace(b"\n", b"\r")
    if "BOM" in form:
        text = b"\xef\xbb\xbf" + text
    return Case(text, setup=setup, like=original, gen="hostile", label=f"{form} {name}")


#: options, the extension of the file each writes, and whether it needs a solved run
_OUTPUTS = {"-o": ".csv", "--plot": ".png", "--snapshot": ".png", "--animate": ".gif",
            "--export": ".xdmf"}


def _spellings(rng: random.Random, name: str, exists: bool = True) -> tuple[str, list]:
    """Another way to name the file ``name`` of the folder, and the setup it needs (a hard
    link only if it ``exists``)."""
    pick = rng.randrange(7 if exists else 6)
    if pick == 0:
        return name, []
    if pick == 1:
        return "./" + name, []
    if pick == 2:
        return "{dir}/" + name, []
    if pick == 3:
        return "sub/../" + name, [("sub", ("dir",))]
    if pick == 4:
        return "link-" + os.path.basename(name), [("link-" + os.path.basename(name),
                                                   ("link", name))]
    if pick == 5:
        return "{dir}/./sub/.." + "/" + name, [("sub", ("dir",))]
    return "hard-" + os.path.basename(name), [("hard-" + os.path.basename(name),
                                               ("hardlink", name))]


def hostile_outputs(rng: random.Random) -> Case:
    """Outputs that would destroy data: the model, a data file the model reads, another
    output; and outputs that must be written well (through a link, keeping a file's mode)."""
    name, data = _example(rng)
    setup = _data_setup(data)
    pick = rng.randrange(4)
    step = ["--step", "0.01"]
    if pick == 0:  # the model itself
        option = rng.choice(list(_OUTPUTS))
        model = rng.choice(["fuzz.mech", "model" + _OUTPUTS[option], "model"])
        target, more = _spellings(rng, model)
        if rng.random() < 0.2:
            target = "{model}"
        # the export of a sweep writes NAME_v0.xdmf, ...: not the model (which must still be
        # left as it is)
        swept = option == "--export" and re.search(rb"^sweep ", data, re.M)
        return Case(data, [option, target, *step], name=model, setup=setup + more,
                    expect=None if swept else frozenset({1}), gen="hostile",
                    label=f"{option} the model")
    if pick == 1:  # two outputs, one file
        a, b = rng.sample(list(_OUTPUTS), 2)
        ext = rng.choice([_OUTPUTS[a], _OUTPUTS[b]])
        base = "x" + ext
        more = []
        if rng.random() < 0.3:  # it exists already: it must be left as it was
            more.append((base, ("file", b"precious\n", None)))
        other, extra = _spellings(rng, base, exists=bool(more))
        args = [a, base, b, other, *step]
        if b == "--export" or a == "--export":  # also: a member of the export series
            export = "e" + rng.choice([".vtu", ".xdmf"])
            member = rng.choice(["e_0000.vtu", "e.pvd", "e_0001.vtu", "e_v1_0000.vtu",
                                 "e_v1.xdmf", "e.xdmf"])
            args = ["--export", export, "-o", member, *step]
            if rng.random() < 0.5:
                args += ["--sweep", f"{_params(data)[0][0]}={_params(data)[0][1]},"
                         f"{_params(data)[0][1]}"] if _params(data) else []
            # a member the series would really write clashes; another name may not
            return Case(data, args, setup=setup + more + extra, gen="hostile",
                        label="export series and -o")
        return Case(data, args, setup=setup + more + extra, expect=frozenset({1}),
                    gen="hostile", label=f"{a} and {b} one file")
    if pick == 2:  # a data file the model reads
        name = rng.choice(["cam_roller.mech", "fourbar_coupler.mech"])
        data = SOURCES[name]
        setup = _data_setup(data)
        read = next(p for p in DATA if p.encode() in data)
        target, more = _spellings(rng, read)
        option = "-o" if rng.random() < 0.7 else rng.choice(["--plot", "--export"])
        return Case(data, [option, target, *step], setup=setup + more, expect=frozenset({1}),
                    gen="hostile", label=f"{option} a data file")
    # written as it should be
    original = Case(data, step, setup=setup, gen="hostile", label=name)
    form = rng.randrange(5)
    mask = _umask()
    if form == 0:
        return Case(data, ["-o", "out.csv", *step], setup=setup, writes=("out.csv",),
                    modes={"out.csv": 0o666 & ~mask}, like=original, gen="hostile",
                    label="-o a new file")
    if form == 1:
        mode = rng.choice([0o640, 0o600, 0o664, 0o604])
        return Case(data, ["-o", "old.csv", *step], setup=setup + [
            ("old.csv", ("file", b"old\n", mode))], writes=("old.csv",),
            modes={"old.csv": mode}, like=original, gen="hostile", label="-o a file kept")
    if form == 2:
        exists = rng.random() < 0.5
        more = [("real.csv", ("file", b"old\n", 0o640))] if exists else []
        return Case(data, ["-o", "link.csv", *step],
                    setup=setup + more + [("link.csv", ("link", "real.csv"))],
                    writes=("real.csv",), modes={"real.csv": 0o640 if exists else 0o666 & ~mask},
                    like=original, gen="hostile", label="-o a link")
    if form == 3:
        return Case(data, ["-o", "-", *step], setup=setup, like=original, gen="hostile",
                    label="-o -")
    return Case(data, ["-o", "sub/out.csv", *step], setup=setup + [("sub", ("dir",))],
                writes=("sub/out.csv",), like=original, gen="hostile", label="-o in a folder")


#: (option, value, whether it must be refused)
_BAD_OPTIONS = [
    *[("--frames", v, True) for v in ("0", "-5", "abc", "1", "1e3", "", "nan")],
    *[("--max-memory", v, True) for v in ("inf", "nan", "-1", "0", "abc", "1e30", "9999999T",
                                          "-inf", "1k", "0.5", "M", "1e-9G")],
    *[("--step", v, True) for v in ("nan", "0", "-0.01", "inf", "-inf", "1e-300", "abc", "")],
    ("--step", "1e300", False), ("--step", "3e-5", False),  # 10^5 instants at most
    *[("--t1", v, True) for v in ("inf", "nan", "-inf", "1e308")],
    ("--t1", "-1", False), ("--t1", "0", False),
    *[("--t0", v, True) for v in ("inf", "nan", "-1e308")],
    *[("--at", v, True) for v in ("junk", ",", "nan", "inf", "1e999", "0,,x", "", " ", "-1",
                                  "0;1", "1e-320e")],
    ("--at", "0.5", False), ("--at", "0,0.25", False),
    *[("--newton-tol", v, True) for v in ("nan", "0", "-1", "inf", "abc")],
    ("--newton-tol", "1e-300", False), ("--newton-tol", "0.5", False),
    *[("--trace", v, True) for v in ("nosuch", "", ".", "crank..A", "crank.", "ground.nosuch")],
    *[("--sweep", v, True) for v in ("=1", "1=2", "p", "p=", "p=1,,2")],
    *[("--set", v, True) for v in ("=1", "p", "p=", "p==1", "zz_unknown=1", "p=@", "p=(1")],
    ("--set", "p=1e999", False), ("--set", "p=nan", False),
]


def hostile_options(rng: random.Random) -> Case:
    """Meaningless option values: a located refusal naming the option."""
    name, data = _example(rng)
    params = _params(data) or [("p", "1")]
    args: list[str] = []
    refused = False
    chosen: list = []
    for _ in range(rng.randint(1, 2)):  # two different options (the last of two would win)
        pick = rng.choice(_BAD_OPTIONS)
        if all(pick[0] != c[0] for c in chosen):
            chosen.append(pick)
    for option, value, bad in chosen:
        value = value.replace("p", rng.choice(params)[0], 1) if option in ("--set", "--sweep") \
            else value
        if option == "--at" and rng.random() < 0.7:
            args += ["--snapshot", "snap.png"]
        args += [option, value] if rng.random() < 0.8 else [f"{option}={value}"]
        refused |= bad
    if not any(a.startswith("--step") for a in args) and rng.random() < 0.8:
        args += ["--step", "0.01"]
    if rng.random() < 0.1 and not refused:
        # a huge sweep over three instants, so that a run, if any, stays short (a refused
        # option keeps its own step: the sweep would change which value wins)
        n = _log_int(rng, 1000, 20_000)
        drop = {i for i, a in enumerate(args) if a == "--step"}
        drop |= {i + 1 for i in drop}
        args = [a for i, a in enumerate(args) if i not in drop and not a.startswith("--step=")]
        args += ["--sweep", f"{params[0][0]}=" + ",".join([params[0][1].split()[0]] * n),
                 "--t0", "0", "--t1", "1", "--step", "0.5"]
    return Case(data, args, setup=_data_setup(data), expect=frozenset({1}) if refused else None,
                gen="hostile", label="options " + " ".join(a[:30] for a in args))


def _frames(parts: list[bytes]) -> bytes:
    """Dask's framing: the total length, then the count, the lengths and the frames."""
    body = struct.pack("<Q", len(parts)) + b"".join(struct.pack("<Q", len(p)) for p in parts)
    body += b"".join(parts)
    return struct.pack("<Q", len(body)) + body


def _scheduler_reply(rng: random.Random) -> tuple[bytes, float, bool, str]:
    """What a fake scheduler answers a new connection with: (bytes, seconds between bytes,
    close after, label)."""
    kind = rng.choice(["silent", "claims", "random", "frames", "msgpack", "handshake",
                       "trickle", "closed", "http", "short"])
    if kind == "silent":
        return b"", 0.0, False, "accepts and never answers"
    if kind == "claims":
        n = rng.choice([2**16 + 1, 2**31, 2**40, 2**63, 2**64 - 1, rng.getrandbits(64)])
        return struct.pack("<Q", n) + rng.randbytes(rng.randint(0, 64)), 0.0, rng.random() < .5, \
            f"claims {n} bytes"
    if kind == "random":
        return rng.randbytes(rng.randint(1, 300)), 0.0, True, "random bytes"
    if kind == "frames":
        parts = [rng.randbytes(rng.randint(0, 40)) for _ in range(rng.randint(0, 4))]
        data = _frames(parts)
        if rng.random() < 0.5:  # lengths that do not add up
            data = data[:8] + struct.pack("<Q", rng.getrandbits(64)) + data[16:]
        return data, 0.0, True, "frames of garbage"
    if kind == "msgpack":
        bad = rng.choice([b"\xc1", b"\xa7pickled", b"\x91\x01", b"\xdd\xff\xff\xff\xff",
                          b"\xc7\x05\x01abcde", b"\x91" * 2000 + b"\x01"])
        return _frames([bad]), 0.0, True, "frames of what is not a msgpack map"
    if kind == "handshake":
        # Dask's handshake, then nothing (or garbage) where the client waits for more
        import msgpack

        hs = msgpack.packb({"compression": None, "python": [3, 11, 7],
                            "pickle-protocol": 5})
        more = rng.choice([b"", rng.randbytes(rng.randint(1, 64)),
                           struct.pack("<Q", 2**50)])
        return _frames([hs]) + more, 0.0, rng.random() < 0.5, "a handshake, then garbage"
    if kind == "trickle":
        return struct.pack("<Q", 100) + bytes(100), 0.2, False, "a byte every 0.2 s"
    if kind == "closed":
        return b"", 0.0, True, "closes at once"
    if kind == "http":
        return b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n", 0.0, True, "HTTP"
    return rng.randbytes(rng.randint(1, 7)), 0.0, True, "fewer than 8 bytes"


def hostile_scheduler(rng: random.Random) -> Case:
    """``--scheduler`` pointed at a fake scheduler that answers with garbage, claims
    terabytes, never answers, trickles, or closes: a located refusal naming it, exit 1,
    within the time bound, with nothing unpickled."""
    name, data = _example(rng)
    reply, every, close, label = _scheduler_reply(rng)
    args = ["--scheduler", "tcp://{scheduler}", "--scheduler-timeout",
            rng.choice(["0.5", "1"])]
    return Case(data, args, setup=_data_setup(data), expect=frozenset({1}), gen="hostile",
                label=f"scheduler: {label}", scheduler=(reply, every, close))


def hostile_store(rng: random.Random) -> Case:
    """``mechdsl plot`` of a store made by the real writer, then corrupted
    (:func:`benchmarks.fuzz_stores.hostile_store`: metadata of the wrong types or claiming
    terabytes, chunks that are links to /dev/zero or FIFOs, codecs that would unpickle,
    garbled bytes, Parquet footers of garbage): a drawing or a located refusal, nothing
    read past a bound, nothing unpickled, the store left as it was."""
    key = f"store:{rng.getrandbits(64)}"
    # the kind is the builder's first draw from its generator: the same one, here
    kind = random.Random(key).choice(["zarr", "parquet"])
    name = f"results.{kind}"
    return Case(b"", ["-o", "out.png"], command="plot", name=name,
                setup=[(name, ("store", key))], writes=("out.png",), gen="hostile",
                label="a corrupted store")


HOSTILE = (("plugin", 2, hostile_plugin), ("data", 3, hostile_data), ("deep", 3, hostile_deep),
           ("lines", 2, hostile_lines), ("outputs", 2, hostile_outputs),
           ("options", 2, hostile_options), ("scheduler", 1, hostile_scheduler),
           ("store", 2, hostile_store))


def hostile(rng: random.Random) -> Case:
    """One hostile case of a class drawn by weight."""
    total = sum(w for _, w, _ in HOSTILE)
    r = rng.uniform(0, total)
    for name, weight, make in HOSTILE:
        r -= weight
        if r <= 0:
            break
    case = make(rng)
    case.cls = name
    return case


def make_case(seed: int, index: int) -> Case:
    """Input ``index`` of the run with ``seed``: the same whatever the number of jobs."""
    rng = random.Random(f"{seed}:{index}")
    only = os.environ.get("MECHDSL_FUZZ_ONLY")  # --only CLASS, for the worker processes too
    if only:
        make = dict((name, f) for name, _, f in HOSTILE)[only]
        case = make(rng)
        case.cls = only
        return case
    r = rng.random()
    if r < MIX[0][1]:
        source = rng.choice(EXAMPLES).read_bytes()
        data = mutate(source, rng)
        return Case(data, setup=_data_setup(data), gen="mutated", cls="mutated")
    if r < MIX[0][1] + MIX[1][1]:
        return Case(generated(rng), gen="generated", cls="generated")
    return hostile(rng)


_UMASK: list[int] = []


def _umask() -> int:
    if not _UMASK:
        mask = os.umask(0o22)
        os.umask(mask)
        _UMASK.append(mask)
    return _UMASK[0]


# -----------------------------------------------------------------------------------------
# running one input


def _make(folder: str, model: str, path: str, spec: tuple) -> None:
    full = os.path.join(folder, path)
    os.makedirs(os.path.dirname(full), exist_ok=True)
    if os.path.lexists(full) and spec[0] != "dir":
        os.remove(full)
    kind = spec[0]
    if kind == "file":
        with open(full, "wb") as f:
            f.write(spec[1])
        if spec[2] is not None:
            os.chmod(full, spec[2])
    elif kind == "fifo":
        os.mkfifo(full)
    elif kind == "dir":
        os.makedirs(full, exist_ok=True)
    elif kind == "link":
        os.symlink(_fill(spec[1], model, folder), full)
    elif kind == "hardlink":
        os.link(os.path.join(folder, spec[1]), full)
    elif kind == "sparse":
        with open(full, "wb") as f:
            f.truncate(spec[1])
    elif kind == "store":  # built and corrupted by benchmarks/fuzz_stores.py, then moved
        build = tempfile.mkdtemp(prefix="build-", dir=folder)
        os.rename(fuzz_stores.hostile_store(random.Random(spec[1]), build), full)
        _remove(build)
    else:
        raise AssertionError(kind)


def _snapshot(folder: str) -> dict[str, tuple]:
    """What each entry of the folder is: ('file', digest, mode), ('link', target), ('dir',),
    ('other',)."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(folder):
        for n in dirnames + filenames:
            full = os.path.join(dirpath, n)
            rel = os.path.relpath(full, folder)
            st = os.lstat(full)
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(full))
            elif stat.S_ISREG(st.st_mode):
                out[rel] = ("file", _digest(full, st), stat.S_IMODE(st.st_mode))
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir",)
            else:
                out[rel] = ("other", stat.S_IFMT(st.st_mode))
    return out


def _digest(path: str, st: os.stat_result) -> str:
    if not st.st_mode & 0o444:
        return f"unreadable {st.st_size}"
    if st.st_size > 2**20 and st.st_blocks * 512 < st.st_size // 2:
        return f"sparse {st.st_size} {st.st_blocks}"  # made by truncate(): all zeros
    h = hashlib.blake2b(digest_size=16)
    h.update(str(st.st_size).encode())
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            if not any(block):  # a sparse file of zeros: the size says it
                continue
            h.update(block)
    return h.hexdigest()


def _echo(stderr: str, content: bytes, width: int = ECHO) -> str | None:
    """A run of ``width`` characters of ``content`` that appears in ``stderr``, or None.
    Chunks of 21 bytes at a stride of 20 cover every run of 41; a hit is then extended."""
    err = stderr.encode("utf-8", "surrogateescape")[:1 << 17]  # a flood is reported anyway
    half = width // 2 + 1
    if len(err) < width or not content:
        return None
    windows = {err[i:i + half] for i in range(len(err) - half + 1)}
    for line in content.splitlines():
        if len(line) < width:
            continue
        for p in range(0, len(line) - half + 1, half - 1):
            chunk = line[p:p + half]
            if chunk not in windows:
                continue
            q = err.find(chunk)
            while q >= 0:
                a, b = 0, half
                while p - a > 0 and q - a > 0 and line[p - a - 1] == err[q - a - 1]:
                    a += 1
                while p + b < len(line) and q + b < len(err) and line[p + b] == err[q + b]:
                    b += 1
                if a + b >= width:
                    return line[p - a:p + b][:80].decode("utf-8", "replace")
                q = err.find(chunk, q + 1)
    return None


def _read_secret(path: str, folder: str) -> bytes:
    full = path if os.path.isabs(path) else os.path.join(folder, path)
    try:
        if not stat.S_ISREG(os.stat(full).st_mode):
            return b""
        with open(full, "rb") as f:
            return f.read(8 << 20)
    except OSError:
        return b""


def _peak_rss() -> int:
    try:
        import resource
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    except (ImportError, OSError):
        return 0


@contextlib.contextmanager
def _isolated(folder: str, workdir: str):
    """While an input runs: the current directory is its folder, the temporary folder is
    the worker's (checked for strays), standard output is captured (Python's and fd 1),
    sys.argv is the command's, no plugin is allowed by the environment and a web browser
    opened by a module would be `true`."""
    saved_env = {k: os.environ.get(k) for k in ("MECHDSL_ALLOW_PLUGINS", "BROWSER")}
    os.environ.pop("MECHDSL_ALLOW_PLUGINS", None)
    os.environ["BROWSER"] = "true"
    cwd, argv, tmp = os.getcwd(), sys.argv, tempfile.tempdir
    out = io.StringIO()
    fd_out = tempfile.TemporaryFile()
    sys.stdout.flush()
    saved_fd = os.dup(1)
    os.dup2(fd_out.fileno(), 1)
    try:
        os.chdir(folder)
        sys.argv = ["mechdsl"]
        tempfile.tempdir = workdir
        with contextlib.redirect_stdout(out), _cli_warnings():
            yield out, fd_out
    finally:
        tempfile.tempdir = tmp
        sys.argv = argv
        os.chdir(cwd)
        try:
            sys.stdout.flush()
        except (OSError, ValueError):
            pass
        os.dup2(saved_fd, 1)
        os.close(saved_fd)
        for k, v in saved_env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def _cli_warnings():
    """Warnings as the command line shows them: Python's default filters, printed on
    standard error, each again for every input (not once per process, and not recorded by
    a test runner)."""
    with warnings.catch_warnings():  # entering it also forgets which were shown already
        warnings.resetwarnings()
        for category in (ResourceWarning, ImportWarning, PendingDeprecationWarning,
                         DeprecationWarning):
            warnings.simplefilter("ignore", category)
        warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")
        if hasattr(warnings, "_showwarnmsg_impl"):
            warnings._showwarnmsg_impl = lambda msg: sys.stderr.write(  # type: ignore
                warnings._formatwarnmsg(msg))  # type: ignore[attr-defined]
        warnings.showwarning = getattr(warnings, "_showwarning_orig", warnings.showwarning)
        yield


def _first_message(text: str) -> str:
    """The first line of the message, after argparse's usage lines if there are some."""
    lines = text.splitlines()
    i = 0
    if lines and lines[0].startswith("usage: "):
        i = 1
        while i < len(lines) and lines[i].startswith(" "):
            i += 1
    return lines[i] if i < len(lines) else ""


class FakeScheduler:
    """A TCP server on the loopback interface answering each connection with ``reply``
    (one byte every ``every`` seconds if that is not 0), then closing it or not."""

    def __init__(self, reply: bytes, every: float, close: bool) -> None:
        import socket
        import threading

        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.address = "127.0.0.1:%d" % self.sock.getsockname()[1]
        self.reply, self.every, self.close = reply, every, close
        self.conns: list = []
        self.stopped = False
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while not self.stopped:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            try:
                if self.every:
                    for b in self.reply:
                        if self.stopped:
                            break
                        conn.sendall(bytes([b]))
                        time.sleep(self.every)
                elif self.reply:
                    conn.sendall(self.reply)
                if self.close:
                    conn.close()
            except OSError:
                pass

    def stop(self) -> None:
        self.stopped = True
        self.sock.close()
        for c in self.conns:
            with contextlib.suppress(OSError):
                c.close()


def _status(case: Case, folder: str, workdir: str, timeout: int, main) -> tuple:
    """Run the input; (exit status or 'hang', stderr, stdout, seconds)."""
    model = os.path.join(folder, case.name)
    fake = FakeScheduler(*case.scheduler) if case.scheduler is not None else None
    try:
        return _run_main(case, folder, workdir, timeout, main, model,
                         None if fake is None else fake.address)
    finally:
        if fake is not None:
            fake.stop()


def _run_main(case: Case, folder: str, workdir: str, timeout: int, main, model: str,
              scheduler: str | None) -> tuple:
    argv = [_fill(a, model, folder) for a in _command(case)]
    if scheduler is not None:
        argv = [a.replace("{scheduler}", scheduler) for a in argv]
    err = io.StringIO()
    start = time.perf_counter()
    with _isolated(folder, workdir) as (out, fd_out):
        old = signal.signal(signal.SIGALRM, _alarm)
        signal.alarm(timeout)
        try:
            with contextlib.redirect_stderr(err):
                code = main(argv)
        except Hang:
            code = "hang"
        except SystemExit as exit_:
            code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None
                                                                   else 1)
        except BaseException as escaped:  # noqa: BLE001 - out of main(): a defect to report
            import traceback

            code = f"{type(escaped).__name__} raised out of main()"
            err.write("".join(traceback.format_exception(escaped)))
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, old)
        fd_out.seek(0)
        printed = out.getvalue() + fd_out.read(1 << 16).decode("utf-8", "replace")
        fd_out.close()
    return code, err.getvalue(), printed, time.perf_counter() - start


def _prepare(case: Case, folder: str) -> None:
    model = os.path.join(folder, case.name)
    with open(model, "wb") as f:
        f.write(case.data)
    for path, spec in case.setup:
        _make(folder, model, path, spec)


_BASELINE: dict = {}


def _baseline(case: Case, workdir: str, timeout: int, main) -> object:
    """The exit status of ``case`` (an original), cached."""
    key = (hashlib.blake2b(case.data).hexdigest(), tuple(case.args), case.command)
    if key not in _BASELINE:
        folder = tempfile.mkdtemp(prefix="orig-", dir=workdir)
        try:
            _prepare(case, folder)
            _BASELINE[key] = _status(case, folder, workdir, timeout, main)[0]
        finally:
            _remove(folder)
    return _BASELINE[key]


def _remove(folder: str) -> None:
    for dirpath, dirnames, _ in os.walk(folder):
        for d in dirnames:  # a folder made unreadable or unwritable by the input
            with contextlib.suppress(OSError):
                os.chmod(os.path.join(dirpath, d), 0o700)
    shutil.rmtree(folder, ignore_errors=True)


def run_one(case: Case | bytes, workdir: str, timeout: int) -> tuple[str, str]:
    """(kind, text) for one input: 'ok' | 'user' | 'numerical' or a defect (:data:`DEFECTS`);
    ``text`` is the messages, after the harness's findings for a defect it found itself."""
    from mechdsl.cli import main

    if isinstance(case, bytes):
        case = Case(case)
    folder = tempfile.mkdtemp(prefix="in-", dir=workdir)
    try:
        return _check(case, folder, workdir, timeout, main)
    finally:
        _remove(folder)


def _check(case: Case, folder: str, workdir: str, timeout: int, main) -> tuple[str, str]:
    _prepare(case, folder)
    before = _snapshot(folder)
    around = set(os.listdir(workdir))
    names = {m for p in case.plugins for m in _module_names(p)}
    loaded = {n for n in names if n in sys.modules}
    path_before = list(sys.path)
    peak_before = _peak_rss()

    code, text, printed, seconds = _status(case, folder, workdir, timeout, main)

    found: list[tuple[str, str]] = []  # (kind, why)
    if code == "hang":
        found.append(("hang", f"no end within {timeout} s"))
        kind = "hang"
    elif code == 0:
        kind = "ok"
    elif code == 2:
        kind = "numerical"
    elif code == 1:
        if "Traceback" in text or not LOCATED.match(_first_message(text)):
            found.append(("unlocated", "exit 1 without FILE:LINE:COL: error: or FILE: error:"))
        kind = "user"
    else:
        found.append(("internal", f"exit status {code!r}"))
        kind = "internal"
    if "Traceback" in text and code != 1:
        found.append(("unlocated", "a traceback in the messages"))

    # imported
    new = sorted(n for n in names if n in sys.modules and n not in loaded)
    if new:
        found.append(("imported", "imported " + ", ".join(new)))
        for n in new:
            sys.modules.pop(n, None)
    ran = [p for p in case.plugins if os.path.exists(os.path.join(folder, f"{p}.ran"))]
    if ran:
        found.append(("imported", "the module beside the model ran: " + ", ".join(ran)))
    if ZEN in printed or "IMPORTED " in printed:
        found.append(("imported", "a module printed on import: " + printed[:120]))
    if sys.path != path_before:
        found.append(("imported", f"sys.path changed: {sorted(set(sys.path) ^ set(path_before))}"))
        sys.path[:] = path_before
    # printed
    argv = _command(case)
    if case.command == "run" and printed:
        if not _writes_stdout(argv):
            found.append(("printed", f"standard output under -q: {printed[:200]!r}"))
        elif not _is_csv(printed):
            found.append(("printed", "standard output, the CSV stream of -o -, holds something "
                                     f"else: {printed[:200]!r}"))
    # echoed
    for secret in case.secrets:
        echo = _echo(text, _read_secret(secret, folder))
        if echo is not None:
            found.append(("echoed", f"the content of {secret} in the messages: {echo!r}"))
    # clobbered, mode, stray
    after = _snapshot(folder)
    writes = {os.path.normpath(w) for w in case.writes}
    for rel, what in before.items():
        if rel in writes:
            continue
        now = after.get(rel)
        if now is None:
            found.append(("clobbered", f"{rel} was removed"))
        elif now[0] != what[0] or (now[:2] != what[:2]):
            found.append(("clobbered", f"{rel} changed: {what[0]} -> {now[0]}"
                                       + (f" {now[1]}" if now[0] == "link" else "")))
        elif now != what:
            found.append(("mode", f"{rel}: mode {what[2]:o} became {now[2]:o}"))
    for rel, mode in case.modes.items():
        now = after.get(os.path.normpath(rel))
        if now is not None and now[0] == "file" and now[2] != mode:
            found.append(("mode", f"{rel} written with mode {now[2]:o}, not {mode:o}"))
    strays = [rel for rel in after if STRAY.search(os.path.basename(rel))]
    strays += [n for n in set(os.listdir(workdir)) - around
               if n != os.path.basename(folder) and STRAY.search(n)]
    for n in set(os.listdir(workdir)) - around - {os.path.basename(folder)}:
        full = os.path.join(workdir, n)
        _remove(full) if os.path.isdir(full) else os.remove(full)
    if strays:
        found.append(("stray", "temporary files left: " + ", ".join(sorted(strays))))
    # the status it must have
    if isinstance(code, int) and code in (0, 1, 2):
        if case.expect is not None and code not in case.expect:
            found.append(("accepted", f"exit {code}, but it must exit with "
                                      + " or ".join(map(str, sorted(case.expect)))))
        if case.like is not None:
            original = _baseline(case.like, workdir, timeout, main)
            if original != code:
                found.append(("differs", f"exit {code}; the original exits {original}"))
    if len(text) > FLOOD:
        found.append(("flooded", f"{len(text):,} characters of messages"))
    limit = MAX_MEMORY_BYTES if not any("--max-memory" in a for a in case.args) else None
    peak = _peak_rss()
    if limit and peak_before <= 1.5 * limit < peak:  # this input crossed it
        found.append(("memory", f"the peak resident memory rose to {peak / 2**20:.0f} MB "
                                f"under --max-memory {MAX_MEMORY}"))
    if not found:
        return kind, text
    found.sort(key=lambda kw: DEFECTS.index(kw[0]))
    why = "\n".join(f"harness: {k}: {w}" for k, w in found)
    return found[0][0], f"{why}\n({seconds:.1f} s)\n--- stderr ---\n{text}"


def _module_names(name: str) -> list[str]:
    """The modules to look for in sys.modules for a plugin line naming ``name``: the name
    itself (its parent packages may be imported for other reasons: an installed plugin's
    package, say)."""
    return [name] if name else []


def _is_csv(text: str) -> bool:
    """Whether ``text`` is a CSV as ``-o -`` writes it: a header, then rows of numbers."""
    lines = text.splitlines()
    if not lines or not re.fullmatch(r"[^,\s]+(,[^,\s]+)*", lines[0]):
        return False
    if len(lines) > 1 and lines[1].startswith("# units: "):  # the units line under the header
        del lines[1]
    width = lines[0].count(",") + 1
    for line in lines[1:]:
        fields = line.split(",")
        if len(fields) != width:
            return False
        try:
            [float(f) for f in fields]
        except ValueError:
            return False
    return True


def _writes_stdout(argv: list[str]) -> bool:
    return any(a in ("-o", "--output") and argv[i + 1:i + 2] == ["-"] for i, a in
               enumerate(argv)) or "--output=-" in argv or "-o-" in argv


# -----------------------------------------------------------------------------------------
# workers


@dataclass
class Failure:
    kind: str
    case: Case
    text: str
    index: int
    seed: int


def _worker_setup() -> None:
    """In a worker process: a bound on its address space (a runaway read ends in
    MemoryError, not in the machine's OOM killer), a C-level traceback on a crash."""
    import faulthandler

    faulthandler.enable()
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        want = 8 * 2**30
        if soft == resource.RLIM_INFINITY or soft > want:
            resource.setrlimit(resource.RLIMIT_AS, (want, hard))
    except (ImportError, ValueError, OSError):
        pass


def _loop(seed: int, indexes, timeout: int, workdir: str, report) -> None:
    for index in indexes:
        case = make_case(seed, index)
        start = time.perf_counter()
        try:
            kind, text = run_one(case, workdir, timeout)
        except Exception:  # noqa: BLE001 - a bug of the harness: say so, and go on
            import traceback

            kind, text = "harness", traceback.format_exc()
        seconds = time.perf_counter() - start
        bad = Failure(kind, case, text, index, seed) if kind in DEFECTS else None
        report(index, case, kind, seconds, bad)


def _child(conn, seed: int, indexes: list[int], timeout: int) -> None:
    _worker_setup()
    with tempfile.TemporaryDirectory(prefix="mechdsl-fuzz-") as workdir:
        def report(index, case, kind, seconds, bad):
            conn.send((index, case.gen, case.cls, kind, seconds, bad))
        _loop(seed, indexes, timeout, workdir, report)
    conn.send(None)
    conn.close()


def fuzz(inputs: int, jobs: int = 1, seed: int = 0, timeout: int = 20,
         stats: dict | None = None) -> tuple[dict, list[Failure]]:
    """Run ``inputs`` inputs over ``jobs`` processes (1: in this process); return the counts
    by outcome and the failures. ``stats``, if given, gets per-generator counts and times."""
    counts: dict[str, int] = {}
    bad: list[Failure] = []
    stats = {} if stats is None else stats

    def record(index, gen, label, kind, seconds, failure):
        counts[kind] = counts.get(kind, 0) + 1
        s = stats.setdefault(gen, {"n": 0, "seconds": 0.0, "slow": 0, "kinds": {}})
        s["n"] += 1
        s["seconds"] += seconds
        s["slow"] += seconds > timeout / 2
        s["kinds"][kind] = s["kinds"].get(kind, 0) + 1
        if gen == "hostile":
            h = stats.setdefault("hostile classes", {})
            c = h.setdefault(label, {"n": 0, "seconds": 0.0, "kinds": {}})
            c["n"] += 1
            c["seconds"] += seconds
            c["kinds"][kind] = c["kinds"].get(kind, 0) + 1
        if failure is not None:
            bad.append(failure)

    if jobs <= 1:
        with tempfile.TemporaryDirectory(prefix="mechdsl-fuzz-") as workdir:
            _loop(seed, range(inputs), timeout, workdir,
                  lambda i, case, kind, sec, failure: record(
                      i, case.gen, case.cls, kind, sec, failure))
        return counts, bad
    _parallel(inputs, jobs, seed, timeout, record)
    bad.sort(key=lambda f: f.index)
    return counts, bad


def _parallel(inputs: int, jobs: int, seed: int, timeout: int, record) -> None:
    """Worker processes of at most RECYCLE inputs each; one that dies or stops answering
    costs the input it was on (a 'crash' or a 'hang'), and its other inputs go to another."""
    import multiprocessing
    from multiprocessing.connection import wait

    ctx = multiprocessing.get_context("fork")
    size = max(1, min(RECYCLE, -(-inputs // jobs)))
    todo = deque(list(range(i, min(i + size, inputs))) for i in range(0, inputs, size))
    active: dict = {}  # connection -> [process, remaining indexes, time of the last word]

    def lost(entry, kind: str, why: str) -> None:
        proc, remaining, _ = entry
        index = remaining.pop(0)
        case = make_case(seed, index)
        record(index, case.gen, case.cls, kind, 0.0,
               Failure(kind, case, f"harness: {kind}: {why}", index, seed))
        if remaining:
            todo.appendleft(remaining)

    while todo or active:
        while todo and len(active) < jobs:
            indexes = todo.popleft()
            receive, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_child, args=(send, seed, indexes, timeout), daemon=True)
            proc.start()
            send.close()
            active[receive] = [proc, list(indexes), time.monotonic()]
        for conn in wait(list(active), timeout=1.0):
            entry = active[conn]
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                del active[conn]
                entry[0].join(5)
                code = entry[0].exitcode
                if entry[1]:
                    how = (f"signal {signal.Signals(-code).name}" if code is not None and code < 0
                           else f"exit status {code}")
                    lost(entry, "crash", f"the worker process died ({how})")
                conn.close()
                continue
            if msg is None:
                del active[conn]
                entry[0].join()
                conn.close()
                continue
            index, gen, label, kind, seconds, failure = msg
            entry[1].remove(index)
            entry[2] = time.monotonic()
            record(index, gen, label, kind, seconds, failure)
        for conn, entry in list(active.items()):
            if entry[1] and time.monotonic() - entry[2] > timeout + 60:
                entry[0].kill()
                entry[0].join()
                del active[conn]
                conn.close()
                lost(entry, "hang", f"no word from the worker for {timeout + 60} s (killed)")


# -----------------------------------------------------------------------------------------
# the command


def save(failures: list[Failure], folder: str) -> None:
    """Each failure as KIND-N.mech (the model), KIND-N.txt (what, the command line, the
    files around it, the harness's findings and the messages) and KIND-N.files/ (the files
    made beside the model, up to 1 MB each)."""
    os.makedirs(folder, exist_ok=True)
    for i, f in enumerate(failures):
        stem = Path(folder, f"{f.kind}-{i}")
        Path(f"{stem}.mech").write_bytes(f.case.data)
        Path(f"{stem}.txt").write_text(
            f"input {f.index} of seed {f.seed} (python benchmarks/fuzz.py --seed {f.seed} "
            f"--replay {f.index})\n{f.case.describe()}\n\n{f.text}", errors="replace")
        files = [(p, s) for p, s in f.case.setup if s[0] == "file" and len(s[1]) <= 2**20]
        if files:
            for path, spec in files:
                target = Path(f"{stem}.files", path)
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(spec[1])
        if f.case.like is not None:
            Path(f"{stem}.ORIGINAL.mech").write_bytes(f.case.like.data)


def replay(seed: int, index: int, timeout: int) -> int:
    case = make_case(seed, index)
    print(case.describe())
    with tempfile.TemporaryDirectory(prefix="mechdsl-fuzz-") as workdir:
        start = time.perf_counter()
        kind, text = run_one(case, workdir, timeout)
    print(f"outcome: {kind} ({time.perf_counter() - start:.2f} s)\n{text[:20000]}")
    return 1 if kind in DEFECTS else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--inputs", type=int, default=10_000)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=int, default=20, help="seconds allowed per input")
    ap.add_argument("--failures", default="fuzz-failures", help="folder for offending inputs")
    ap.add_argument("--replay", type=int, metavar="INDEX", help="run input INDEX of --seed only")
    ap.add_argument("--only", metavar="CLASS", choices=[name for name, _, _ in HOSTILE],
                    help="only hostile inputs of this class (numbered as such)")
    ap.add_argument("--view", type=int, default=5, metavar="N",
                    help="sessions of hostile messages to mechdsl view (benchmarks/"
                         "fuzz_view.py; 0: none)")
    args = ap.parse_args()
    if args.only:
        os.environ["MECHDSL_FUZZ_ONLY"] = args.only
    if args.replay is not None:
        return replay(args.seed, args.replay, args.timeout)
    start = time.perf_counter()
    stats: dict = {}
    counts, bad = fuzz(args.inputs, args.jobs, args.seed, args.timeout, stats)
    elapsed = time.perf_counter() - start
    total = sum(counts.values())
    print(f"{total} inputs in {elapsed:.0f} s ({total / elapsed:.0f}/s): "
          + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    for gen, _ in MIX:
        s = stats.get(gen)
        if s:
            print(f"  {gen}: {s['n']} inputs, {s['seconds'] / s['n']:.2f} s each, "
                  f"{s['slow']} over {args.timeout / 2:.0f} s: "
                  + ", ".join(f"{k} {v}" for k, v in sorted(s["kinds"].items())))
    for label, c in sorted(stats.get("hostile classes", {}).items()):
        print(f"    {label}: {c['n']}, {c['seconds'] / c['n']:.2f} s each: "
              + ", ".join(f"{k} {v}" for k, v in sorted(c["kinds"].items())))
    view_bad = False
    if args.view:
        import fuzz_view

        counts_view = fuzz_view.run(args.view, args.seed)
        print(f"mechdsl view: {args.view} sessions of hostile messages: "
              + ", ".join(f"{k} {v}" for k, v in counts_view.items()))
        view_bad = any(counts_view.values())
    if bad:
        save(bad, args.failures)
        kinds = {}
        for f in bad:
            kinds[f.kind] = kinds.get(f.kind, 0) + 1
        print(f"{len(bad)} failures ({', '.join(f'{k} {v}' for k, v in sorted(kinds.items()))})"
              f" saved in {args.failures}/")
        return 1
    if view_bad:
        return 1
    print("no internal error, traceback, unlocated error, hang or other defect")
    return 0


if __name__ == "__main__":
    sys.exit(main())
