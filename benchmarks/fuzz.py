"""Fuzz the whole pipeline: every input must end in a result (exit 0), a located user error
(exit 1) or a numerical failure (exit 2) -- never an internal error, a traceback or a hang.

    python benchmarks/fuzz.py --inputs 100000 --jobs 2

Inputs come from two generators, half each: byte-level mutations of the example files
(flips, insertions, deletions, repeated or swapped lines, numbers replaced by extreme
values, truncation) and random statements drawn from the grammar's vocabulary with random
names and expressions. Each input runs through ``mechdsl run FILE -q`` in-process, with a time
bound. The counts are printed at the end; an offending input is saved under --failures.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import random
import re
import signal
import sys
import tempfile
import time
from multiprocessing import Pool
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = sorted((ROOT / "examples").glob("*.mech"))
LOCATED = re.compile(r"^\S.*?(:\d+:\d+)?: error: ")
EXTREMES = ["0", "-0", "1e308", "-1e308", "1e-308", "1e400", "0.0000001", "123456789", "-1",
            "pi", "t", "(1", "2)", "1/0", "sqrt(-1)", "2^2000"]
WORDS = ["param", "body", "ground", "point", "guess", "joint", "drive", "simulate", "output",
         "sweep", "plugin", "if", "then", "else", "and", "or", "not", "step", "count", "t",
         "pi", "origin", "revolute", "prismatic", "angle", "x", "y", "rel_angle", "distance",
         "gear", "table", "sin", "atan2", "min", ".", "..", "(", ")", "{", "}", "[", "]", ",",
         "=", ":", ";", "+", "-", "*", "/", "^", "<", ">=", '"a.csv"', "#", "\n"]


class Hang(BaseException):
    """The time bound passed (a BaseException: the command's own handlers must not catch it)."""


def _alarm(signum, frame):
    raise Hang()


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


def run_one(data: bytes, workdir: str, timeout: int) -> tuple[str, str]:
    """('ok'|'user'|'numerical'|'internal'|'hang'|'unlocated', stderr) for one input."""
    from mechdsl.cli import main

    path = os.path.join(workdir, "fuzz.mech")
    with open(path, "wb") as f:
        f.write(data)
    err = io.StringIO()
    signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(timeout)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(["run", path, "-q", "--max-memory", "8M"])
    except Hang:
        return "hang", err.getvalue()
    except SystemExit as exit_:
        code = exit_.code
    finally:
        signal.alarm(0)
    text = err.getvalue()
    if code == 0:
        return "ok", text
    if code == 2:
        return "numerical", text
    if code == 1:
        first = text.splitlines()[0] if text else ""
        if "Traceback" in text or not LOCATED.match(first):
            return "unlocated", text
        return "user", text
    return "internal", text


def _worker(args: tuple[int, int, int]) -> tuple[dict, list]:
    seed, count, timeout = args
    rng = random.Random(seed)
    sources = [p.read_bytes() for p in EXAMPLES]
    counts: dict[str, int] = {}
    bad = []
    with tempfile.TemporaryDirectory() as workdir:
        for _ in range(count):
            data = mutate(rng.choice(sources), rng) if rng.random() < 0.5 else generated(rng)
            kind, text = run_one(data, workdir, timeout)
            counts[kind] = counts.get(kind, 0) + 1
            if kind in ("internal", "hang", "unlocated"):
                bad.append((kind, data, text))
    return counts, bad


def fuzz(inputs: int, jobs: int = 1, seed: int = 0, timeout: int = 20) -> tuple[dict, list]:
    """Run ``inputs`` inputs over ``jobs`` processes; return the counts and the failures."""
    chunks = [(seed * 1000 + i, inputs // jobs + (i < inputs % jobs), timeout)
              for i in range(jobs)]
    if jobs == 1:
        results = [_worker(chunks[0])]
    else:
        with Pool(jobs) as pool:
            results = pool.map(_worker, chunks)
    counts: dict[str, int] = {}
    bad = []
    for c, b in results:
        for k, v in c.items():
            counts[k] = counts.get(k, 0) + v
        bad.extend(b)
    return counts, bad


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--inputs", type=int, default=10_000)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=int, default=20, help="seconds allowed per input")
    ap.add_argument("--failures", default="fuzz-failures", help="folder for offending inputs")
    args = ap.parse_args()
    start = time.perf_counter()
    counts, bad = fuzz(args.inputs, args.jobs, args.seed, args.timeout)
    elapsed = time.perf_counter() - start
    total = sum(counts.values())
    print(f"{total} inputs in {elapsed:.0f} s ({total / elapsed:.0f}/s): "
          + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    if bad:
        os.makedirs(args.failures, exist_ok=True)
        for i, (kind, data, text) in enumerate(bad):
            Path(args.failures, f"{kind}-{i}.mech").write_bytes(data)
            Path(args.failures, f"{kind}-{i}.txt").write_text(text)
        print(f"{len(bad)} failures saved in {args.failures}/")
        return 1
    print("no internal error, traceback, unlocated error or hang")
    return 0


if __name__ == "__main__":
    sys.exit(main())
