"""Fuzz ``mechdsl lsp`` with hostile messages: the server must answer every request it can
read, stay alive, print no traceback and keep its memory bounded.

    python benchmarks/fuzz_lsp.py --sequences 100 --seed 0

:func:`hostile_messages` makes one session of raw framed messages: a valid ``initialize``
and a small valid document first, then a random mix of documents over the model limit
(``didOpen``, a ``didChange`` that inserts them), bodies over the transport bound, wrong
``Content-Length`` headers (too long, too short, negative, not a number), bytes that are not
JSON, valid JSON with params of the wrong types, unknown methods, requests on documents never
opened (``/dev/zero`` among them), positions out of range, ``didChange`` with bad ranges,
deeply nested JSON and random unicode, and ``shutdown`` and ``exit`` last (or, sometimes, a
length that claims more than will ever come, and the end of the input).

:func:`main` runs each session against a ``mechdsl lsp`` subprocess. After every message it
sends a probe (a hover on the valid document), and it waits for the answer to every request
whose framing and JSON are valid. It counts: ``died`` (the process ended before ``exit``),
``traceback`` (a Python traceback on its standard error), ``unanswered`` (a request, or a
probe, without an answer within the time bound), ``stuck`` (a message the server did not read
within the bound), ``memory`` (a peak resident size, VmHWM, over ``--max-mb``) and ``exit``
(a status other than 0 after shutdown and exit, or the process still there after them).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import queue
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MIB = 2**20
#: The command line's limit on a model and the server's on one message (6 x it + 64 KiB),
#: as documented in docs/editor.md; the fuzzer keeps its own copy, so that it tests them
MODEL_LIMIT = 4 * MIB
MESSAGE_LIMIT = 6 * MODEL_LIMIT + 64 * 2**10
GOOD = """param r = 2
param l = 3.5
body crank { guess = (1, 0, 0)  point A = (-r/2, 0)  point B = (r/2, 0) }
body rod { guess = (3.75, 0, 0)  point B = (-l/2, 0)  point C = (l/2, 0) }
body slider { guess = (5.5, 0, 0) }
joint A: revolute(ground.origin, crank.A)
joint B: revolute(crank.B, rod.B)
joint C: revolute(rod.C, slider.origin)
joint D: prismatic(ground.origin, slider.origin, axis = (1, 0))
drive turn: angle(crank) = pi/4 + 4*pi*t
simulate t = 0 .. 1 step 0.01
output slider.x
"""
GOOD_URI = "file:///tmp/mechdsl-fuzz-lsp/good.mech"
REQUESTS = ("textDocument/hover", "textDocument/definition", "textDocument/references",
            "textDocument/completion", "textDocument/prepareRename", "textDocument/rename",
            "textDocument/formatting", "textDocument/semanticTokens/full",
            "textDocument/documentSymbol", "textDocument/foldingRange")


def frame(message: object) -> bytes:
    """``message`` as LSP frames it."""
    return framed(json.dumps(message).encode())


def framed(body: bytes, length: object = None) -> bytes:
    """``body`` after a ``Content-Length`` header of ``length`` (default: its true length)."""
    return b"Content-Length: %s\r\n\r\n" % str(len(body) if length is None else length).encode() \
        + body


def request(msg_id: int, method: str, params: object) -> dict:
    return {"jsonrpc": "2.0", "id": msg_id, "method": method, "params": params}


def notification(method: str, params: object) -> dict:
    return {"jsonrpc": "2.0", "method": method, "params": params}


EXIT = frame(notification("exit", None))


def params_for(method: str, uri: str, line: int, character: int, rng: random.Random) -> dict:
    """Params of ``method`` (one of REQUESTS) on ``uri`` at (line, character)."""
    out: dict = {"textDocument": {"uri": uri}}
    if method in ("textDocument/formatting",):
        out["options"] = {"tabSize": 4, "insertSpaces": True}
    elif method not in ("textDocument/semanticTokens/full", "textDocument/documentSymbol",
                        "textDocument/foldingRange"):
        out["position"] = {"line": line, "character": character}
    if method == "textDocument/references":
        out["context"] = {"includeDeclaration": True}
    if method == "textDocument/rename":
        out["newName"] = rng.choice(["speed", "t", "pi", "sin", "joint", "2x", "r", "", "a b",
                                     random_text(rng, 8), "x" * 5000])
    return out


def random_text(rng: random.Random, n: int) -> str:
    """``n`` characters from everywhere in Unicode: controls, NUL, lone surrogates, RTL marks,
    astral characters, and bits of the language."""
    pools = [lambda: chr(rng.randrange(0, 32)), lambda: chr(rng.randrange(0xD800, 0xE000)),
             lambda: chr(rng.randrange(0x10000, 0x110000)), lambda: rng.choice("\u202e\ufeff\u0000"),
             lambda: chr(rng.randrange(32, 0xD800)),
             lambda: rng.choice(["param ", "body ", "{", "}", "(", ".", "=", "\n", "joint "])]
    return "".join(rng.choice(pools)() for _ in range(n))


def model_text(size: int) -> str:
    """A model of ``size`` characters (one param, repeated: it is never parsed), over the limit
    when size is."""
    line = "param p = 1 + 2*3\n"
    return (line * (size // len(line) + 1))[:size]


def hostile_messages(rng: random.Random) -> list[bytes]:
    """One session of raw framed messages (see the module): initialize and a valid document,
    hostile messages, then shutdown and exit (or a length that never comes, and the end)."""
    ids = itertools.count(1)
    out = [frame(request(next(ids), "initialize", {"capabilities": {}, "processId": None})),
           frame(notification("initialized", {})),
           frame(notification("textDocument/didOpen", {"textDocument": {
               "uri": GOOD_URI, "languageId": "mech", "version": 1, "text": GOOD}}))]
    makers = [_oversized_document, _oversized_body, _wrong_length, _garbage, _wrong_types,
              _unknown_method, _unopened, _out_of_range, _bad_change, _nested, _unicode]
    weights = [1, 1, 3, 3, 4, 2, 3, 4, 4, 2, 3]
    for _ in range(rng.randint(20, 60)):
        maker = rng.choices(makers, weights)[0]
        out.append(maker(rng, ids))
    if rng.random() < 0.1:  # a length no client will honour, then the end of the input
        out.append(b"Content-Length: %d\r\n\r\n{\"jsonrpc\"" % (10**15))
        return out
    out += [frame(request(next(ids), "shutdown", None)), EXIT]
    return out


def _oversized_document(rng, ids) -> bytes:
    size = rng.choice([MODEL_LIMIT + 1, 5 * MIB, 20 * MIB, 30 * MIB, 51 * 10**6])
    text = model_text(size)
    uri = rng.choice([GOOD_URI, f"file:///tmp/mechdsl-fuzz-lsp/big{rng.randrange(3)}.mech"])
    if rng.random() < 0.5:
        return frame(notification("textDocument/didOpen", {"textDocument": {
            "uri": uri, "languageId": "mech", "version": rng.randrange(2, 100), "text": text}}))
    change = {"text": text}
    if rng.random() < 0.5:
        change["range"] = {"start": {"line": 0, "character": 0},
                           "end": {"line": 0, "character": 0}}
    return frame(notification("textDocument/didChange", {
        "textDocument": {"uri": GOOD_URI, "version": rng.randrange(2, 10**6)},
        "contentChanges": [change]}))


def _oversized_body(rng, ids) -> bytes:
    size = rng.choice([MESSAGE_LIMIT + 1, 30 * MIB, 60 * MIB])
    head = json.dumps(request(next(ids), rng.choice(REQUESTS), {"textDocument": {
        "uri": GOOD_URI}, "pad": ""}))[:-3].encode()
    if rng.random() < 0.3:
        head = b""  # nothing to read a method or an id from
    return framed(head + b"x" * (size - len(head)))


def _wrong_length(rng, ids) -> bytes:
    body = json.dumps(request(next(ids), "textDocument/hover", params_for(
        "textDocument/hover", GOOD_URI, 0, 6, rng))).encode()
    kind = rng.choice(["long", "short", "negative", "word", "empty", "spaces", "lf"])
    if kind == "long":  # padded to the length claimed, so that what follows stays framed
        extra = rng.randrange(1, 5000)
        return framed(body + b"!" * extra, len(body) + extra)
    if kind == "short":
        return framed(body, rng.randrange(0, len(body)))
    if kind == "negative":
        return framed(body, -rng.randrange(1, 10**6))
    if kind == "word":
        return framed(body, rng.choice(["abc", "1e3", "0x10", "", "12 34", "\u00b2"]))
    if kind == "empty":
        return framed(b"", 0)
    if kind == "spaces":
        return b"Content-Length:    %d   \r\n\r\n" % len(body) + body
    return b"Content-Length: %d\n\n" % len(body) + body


def _garbage(rng, ids) -> bytes:
    choices = [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))),
               b"{" * rng.randrange(1, 50), b"[]", b"null", b"1", b'"x"', b"{}",
               b'{"jsonrpc": "2.0", "id": 1, "method": ', b"\xff\xfe{}",
               json.dumps(request(next(ids), "textDocument/hover", {})).encode("utf-16"),
               b'[' + frame(request(next(ids), "shutdown", None)) + b']',
               json.dumps([request(next(ids), "textDocument/hover", {})]).encode(),
               json.dumps({"jsonrpc": "1.0", "id": next(ids), "method": "shutdown"}).encode(),
               json.dumps({"jsonrpc": "2.0", "id": next(ids), "result": 1}).encode(),
               json.dumps({"jsonrpc": "2.0", "id": next(ids), "error": 1}).encode()]
    return framed(rng.choice(choices))


def _wrong_types(rng, ids) -> bytes:
    method = rng.choice(REQUESTS + ("textDocument/didOpen", "textDocument/didChange",
                                    "textDocument/didClose", "initialize", "$/cancelRequest"))
    values = [None, 1, -1, 1.5, "x", [], {}, [1, 2], {"uri": 1}, True, 10**30, "\u0000"]
    params = params_for(method, GOOD_URI, 1, 1, rng) if method in REQUESTS else {}
    key = rng.choice(["textDocument", "position", "newName", "options", "contentChanges",
                      "id", "context"])
    params[key] = rng.choice(values)
    if rng.random() < 0.3:
        params = rng.choice(values)
    msg = request(next(ids), method, params) if rng.random() < 0.7 \
        else notification(method, params)
    if rng.random() < 0.2:
        msg["id"] = rng.choice([None, [], {}, 1.5, True, "s" * 100])
    return frame(msg)


def _unknown_method(rng, ids) -> bytes:
    method = rng.choice(["textDocument/codeAction", "$/setTrace", "nosuch", "", "x" * 10000,
                         "workspace/symbol", "$/progress", random_text(rng, 20)])
    if rng.random() < 0.5:
        return frame(request(next(ids), method, {}))
    return frame(notification(method, {}))


def _unopened(rng, ids) -> bytes:
    uri = rng.choice(["file:///dev/zero", "file:///dev/stdin", "file:///etc/passwd",
                      "file:///tmp/mechdsl-fuzz-lsp/never.mech", "untitled:1", "::::", "",
                      "file:///proc/self/mem", "file:///" + "a/" * 3000])
    method = rng.choice(REQUESTS)
    return frame(request(next(ids), method, params_for(method, uri, 0, 0, rng)))


def _out_of_range(rng, ids) -> bytes:
    method = rng.choice(REQUESTS)
    pick = lambda: rng.choice([-1, -(2**31), 2**31 - 1, 2**31, 2**40, 10**6, 0, 3, 1.5])  # noqa: E731
    return frame(request(next(ids), method, params_for(method, GOOD_URI, pick(), pick(), rng)))


def _bad_change(rng, ids) -> bytes:
    pick = lambda: rng.choice([-1, 0, 1, 5, 10**6, 2**31 - 1, 2**40])  # noqa: E731
    changes = []
    for _ in range(rng.randint(1, 5)):
        change = {"range": {"start": {"line": pick(), "character": pick()},
                            "end": {"line": pick(), "character": pick()}},
                  "text": rng.choice(["", "x", "\n" * 50, random_text(rng, 30), GOOD])}
        if rng.random() < 0.2:
            change["rangeLength"] = pick()
        changes.append(change)
    if rng.random() < 0.2:  # the valid document back, so that the session goes on with it
        changes.append({"text": GOOD})
    uri = GOOD_URI if rng.random() < 0.8 else "file:///tmp/mechdsl-fuzz-lsp/never.mech"
    return frame(notification("textDocument/didChange", {
        "textDocument": {"uri": uri, "version": rng.randrange(-5, 10**6)},
        "contentChanges": changes}))


def _nested(rng, ids) -> bytes:
    depth = rng.choice([100, 10_000, 200_000])
    inner = b"[" * depth + b"]" * depth
    if rng.random() < 0.5:
        return framed(inner)
    return framed(b'{"jsonrpc": "2.0", "id": %d, "method": "textDocument/hover", "params": %s}'
                  % (next(ids), b'{"x": ' * depth + b"1" + b"}" * depth))


def _unicode(rng, ids) -> bytes:
    text = random_text(rng, rng.randrange(1, 3000))
    if rng.random() < 0.4:
        return frame(notification("textDocument/didOpen", {"textDocument": {
            "uri": f"file:///tmp/mechdsl-fuzz-lsp/u{rng.randrange(3)}.mech",
            "languageId": "mech", "version": 1, "text": text}}))
    if rng.random() < 0.5:
        method = rng.choice(REQUESTS)
        return frame(request(next(ids), method, params_for(
            method, "file:///tmp/mechdsl-fuzz-lsp/u0.mech", rng.randrange(5),
            rng.randrange(50), rng)))
    return framed(text.encode("utf-8", "surrogatepass"))


class Server:
    """A ``mechdsl lsp`` subprocess spoken to in raw bytes: its answers are collected by a
    thread, its standard error by another."""

    def __init__(self, command: list[str] | None = None) -> None:
        self.process = subprocess.Popen(
            command or [sys.executable, "-m", "mechdsl", "lsp"], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
            env={**os.environ, "PYTHONFAULTHANDLER": "1"})  # SIGABRT: where each thread is
        self.messages: queue.Queue = queue.Queue()
        self.seen: list[dict] = []
        self.stderr = bytearray()
        threading.Thread(target=self._read, daemon=True).start()
        threading.Thread(target=self._read_stderr, daemon=True).start()

    def _read(self) -> None:
        out = self.process.stdout
        while True:
            length = None
            while True:
                line = out.readline()
                if not line:
                    return
                if line.lower().startswith(b"content-length:"):
                    length = int(line.split(b":")[1])
                elif not line.strip() and length is not None:
                    break
            self.messages.put(json.loads(out.read(length)))

    def _read_stderr(self) -> None:
        for line in self.process.stderr:
            if len(self.stderr) < 1_000_000:
                self.stderr += line

    def send(self, data: bytes, timeout: float = 30.0) -> bool:
        """Write ``data``; False if the server did not take it within ``timeout``."""
        def write() -> None:
            try:
                self.process.stdin.write(data)
                self.process.stdin.flush()
            except (BrokenPipeError, ValueError):
                pass

        writer = threading.Thread(target=write, daemon=True)
        writer.start()
        writer.join(timeout)
        return not writer.is_alive()

    def wait_for(self, predicate, timeout: float = 10.0) -> dict | None:
        """The first message, from those not yet looked at, for which ``predicate`` holds."""
        for message in self.seen:
            if predicate(message):
                self.seen.remove(message)
                return message
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            try:
                message = self.messages.get(timeout=left)
            except queue.Empty:
                return None
            if predicate(message):
                return message
            self.seen.append(message)
        return None

    def answer(self, msg_id: object, timeout: float = 10.0) -> dict | None:
        """The answer to the request ``msg_id``, or None after ``timeout``."""
        return self.wait_for(lambda m: "method" not in m and m.get("id") == msg_id, timeout)

    def peak_mb(self) -> float:
        """The peak resident memory of the server so far (VmHWM), in MiB; 0 once it ended."""
        try:
            with open(f"/proc/{self.process.pid}/status") as f:
                for line in f:
                    if line.startswith("VmHWM:"):
                        return int(line.split()[1]) / 1024
        except OSError:
            pass
        return 0.0

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
        for stream in (self.process.stdin, self.process.stdout, self.process.stderr):
            try:
                stream.close()
            except OSError:
                pass


def expected_id(message: bytes) -> object:
    """The id of a request that must be answered: one whose framing and JSON are right and
    that has a method and an int or string id (None for anything else)."""
    head, _, body = message.partition(b"\r\n\r\n")
    try:
        if not head.startswith(b"Content-Length: ") or int(head[16:]) != len(body):
            return None
        data = json.loads(body.decode("utf-8"))
    except (ValueError, RecursionError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("method"), str) or \
            data.get("jsonrpc") != "2.0" or data.get("method") == "exit":
        return None
    msg_id = data.get("id")
    return msg_id if isinstance(msg_id, (int, str)) and not isinstance(msg_id, bool) else None


def run_session(messages: list[bytes], counts: dict, max_mb: float, timeout: float,
                log=print) -> None:
    """Send one session to a new server, probing after each message, and add to ``counts``."""
    server = Server()
    probe_ids = itertools.count(10**9)
    peak = 0.0
    try:
        for k, message in enumerate(messages):
            peak = max(peak, server.peak_mb())
            counts["messages"] += 1
            # the first answer waits for the server to start (imports: seconds on a busy machine)
            bound = timeout * (3 if len(message) > MIB or k == 0 else 1)
            if not server.send(message, bound):
                counts["stuck"] += 1
                log(f"stuck: message {k} ({len(message):,} bytes) not read in {bound} s")
                return
            msg_id = expected_id(message)
            if msg_id is not None:
                counts["requests"] += 1
                if server.answer(msg_id, bound) is None:
                    counts["unanswered"] += 1
                    log(f"unanswered: message {k}: {message[:200]!r}")
            if message == EXIT or k == len(messages) - 1:
                break
            probe = next(probe_ids)
            server.send(frame(request(probe, "textDocument/hover", {
                "textDocument": {"uri": GOOD_URI}, "position": {"line": 0, "character": 7}})))
            if server.answer(probe, bound) is None:
                if server.process.poll() is not None:
                    counts["died"] += 1
                    log(f"died (status {server.process.returncode}) after message {k}: "
                        f"{message[:200]!r}")
                else:
                    counts["unanswered"] += 1
                    log(f"probe unanswered after message {k}: {message[:200]!r}")
                return
        if messages[-1] != EXIT:  # the end of the input instead: the server must end too
            server.process.stdin.close()
        try:
            status = server.process.wait(timeout)
        except subprocess.TimeoutExpired:
            status = None
        if status != 0 and messages[-1] == EXIT or status is None:
            counts["exit"] += 1
            if status is None:  # where it waits, from faulthandler
                server.process.send_signal(signal.SIGABRT)
                time.sleep(2)
            log(f"exit: status {status} at the end of the session\n"
                + bytes(server.stderr[-4000:]).decode(errors="replace"))
    finally:
        peak = max(peak, server.peak_mb())
        server.close()
        counts["max_mb"] = max(counts["max_mb"], peak)
        if peak > max_mb:
            counts["memory"] += 1
            log(f"memory: peak {peak:.0f} MiB over {max_mb:.0f}")
        if b"Traceback" in server.stderr:
            counts["traceback"] += 1
            log("traceback:\n" + bytes(server.stderr[-3000:]).decode(errors="replace"))


def main(argv: list[str] | None = None) -> int:
    """Run the sessions and print the counts; exit status 1 if anything was found."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequences", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=10.0,
                        help="seconds for an answer (three times this for a message over 1 MiB)")
    parser.add_argument("--max-mb", type=float, default=400.0,
                        help="the bound on the server's peak resident memory, MiB")
    args = parser.parse_args(argv)
    os.makedirs("/tmp/mechdsl-fuzz-lsp", exist_ok=True)
    counts = dict.fromkeys(["sessions", "messages", "requests", "died", "traceback",
                            "unanswered", "stuck", "memory", "exit"], 0)
    counts["max_mb"] = 0.0
    start = time.monotonic()
    for s in range(args.sequences):
        rng = random.Random(f"{args.seed}:{s}")
        counts["sessions"] += 1
        run_session(hostile_messages(rng), counts, args.max_mb, args.timeout,
                    log=lambda text, s=s: print(f"[session {s}] {text}", flush=True))
    counts["seconds"] = round(time.monotonic() - start, 1)
    counts["max_mb"] = round(counts["max_mb"], 1)
    print(json.dumps(counts))
    found = sum(counts[k] for k in ("died", "traceback", "unanswered", "stuck", "memory", "exit"))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
