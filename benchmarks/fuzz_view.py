"""Fuzz ``mechdsl view`` with hostile messages: the server must answer, stay alive, print no
traceback and never solve a request it should refuse.

    python benchmarks/fuzz_view.py --sequences 30 --seed 0     (also run by fuzz.py --view)

Each sequence starts ``mechdsl view examples/slider_crank.mech --no-browser`` and sends, on
WebSockets with the page's Origin, a random mix of: text that is not JSON, JSON that is not
an object, objects of unknown types, ``set`` with params of the wrong types (strings, lists,
booleans, nulls, nested objects, NaN and infinities written as text, numbers of a thousand
digits), names that are not sliders (markup, very long, unicode), messages over the size
bound, binary frames, deeply nested arrays, a burst of valid moves out of order with ids of
every type, ``reset`` and ``reload`` in between, connections that close in the middle of a
burst, and a second page connected at the same time that never reads its messages. Plain
HTTP requests go in too: without the token, with another Host header, a WebSocket without
the Origin or from another one.

After every message a probe (a valid ``set`` with a fresh id) must be answered by a run
within the time bound. It counts ``died`` (the process ended), ``traceback`` (a Python
traceback on its standard error), ``unanswered`` (a probe without its run in time),
``opened`` (a request without the token, or from another host or origin, that was served),
and ``exit`` (a status other than 0 or 130 after Ctrl-C).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from browser import Viewer  # noqa: E402 - `mechdsl view` in a child process
from mechdsl.outputs import payload  # noqa: E402
from mechdsl.view.server import MAX_MESSAGE  # noqa: E402

SEED = ROOT / "examples" / "slider_crank.mech"
BOUND = 20.0  # seconds a probe may take


def hostile(rng: random.Random) -> str | bytes:
    """One hostile message (text, or bytes for a binary frame)."""
    kind = rng.randrange(14)
    if kind == 0:
        return rng.choice(["", "{", "nul", "\x00\x01", "}{", "[1,2", "'set'", "\ud800".encode(
            "utf-8", "surrogatepass").decode("utf-8", "replace")])
    if kind == 1:
        return json.dumps(rng.choice([[1, 2], 3, "set", None, True, []]))
    if kind == 2:
        return json.dumps({"type": rng.choice(["exec", "SET", "", None, 7, "set ", "<b>"])})
    if kind == 3:
        bad = rng.choice(["1", [1], True, None, {"x": 1}, "NaN", "Infinity", "1e999", 1e308])
        return json.dumps({"type": "set", "params": {"l": bad}, "id": rng.random()})
    if kind == 4:
        return '{"type": "set", "params": {"l": ' + "9" * 1000 + "}}"
    if kind == 5:
        name = rng.choice(["<img src=x onerror=alert(1)>", "x" * 5000, "\u202e", "__proto__",
                           "constructor", ""])
        return json.dumps({"type": "set", "params": {name: 1.0}})
    if kind == 6:
        return "x" * (MAX_MESSAGE + rng.randrange(1, 100_000))
    if kind == 7:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 2000)))
    if kind == 8:
        return "[" * rng.randrange(1000, 200_000)
    if kind == 9:
        return json.dumps({"type": "set", "params": {"l": rng.uniform(-10, 10)},
                           "id": rng.choice([None, [1], {"a": 1}, "x" * 100, -1, 1e300])})
    if kind == 10:
        return json.dumps({"type": rng.choice(["reset", "reload"])})
    if kind == 11:
        return json.dumps({"type": "set", "params": {"r": rng.uniform(0, 4), "l": rng.uniform(
            0, 7), "omega": rng.uniform(-30, 30)}})
    if kind == 12:
        return json.dumps({"type": "set", "params": "l=3"})
    return json.dumps({"type": "set", "params": {"l": 3.5}, "extra": {"deep": [[[[1]]]]}})


def _http(host: str, path: str, headers: dict) -> int:
    req = urllib.request.Request(f"http://{host}{path}", headers=headers)
    try:
        with urllib.request.urlopen(req, timeout=BOUND) as r:
            return r.status
    except urllib.error.HTTPError as err:
        return err.code


def _probe(ws, ident: str) -> bool:
    """A valid move; True once its run has come back."""
    ws.send(json.dumps({"type": "set", "params": {"l": 3.5}, "id": ident}))
    end = time.monotonic() + BOUND
    while time.monotonic() < end:
        try:
            msg = ws.recv(timeout=max(0.01, end - time.monotonic()))
        except TimeoutError:
            return False
        if isinstance(msg, bytes):
            header, _ = payload.decode(msg)
            if header.get("id") == ident and header["type"] == "run":
                return True
    return False


def sequence(rng: random.Random, messages: int, counts: dict) -> None:
    import logging

    from websockets.sync.client import connect

    # the client library logs, as errors, the connections the server closes on purpose (an
    # oversized message) and the page that never reads, cut when the server stops
    logging.getLogger("websockets").setLevel(logging.CRITICAL)

    viewer = Viewer(SEED)
    host, token, origin, url = viewer.host, viewer.token, viewer.origin, viewer.socket_url
    stack = contextlib.ExitStack()

    def page(reads: bool = True):
        """A page connected, its first message read; one that does not read (``reads``
        false) stops taking messages from the socket after the first (a frozen tab)."""
        ws = stack.enter_context(connect(url, origin=origin, open_timeout=BOUND,
                                         max_size=2**26, ping_interval=None,
                                         max_queue=16 if reads else 1))
        ws.recv(timeout=BOUND)
        return ws
    try:
        # doors that must stay shut
        for path, headers in ((f"/{token[:-1]}/", {}), ("/", {}),
                              (f"/{token}/", {"Host": "evil.example"}),
                              (f"/{token}/../../etc/passwd", {})):
            if _http(host, path, headers) == 200:
                counts["opened"] += 1
        for hdrs in ({}, {"Origin": "http://evil.example"}):
            try:
                with connect(url, additional_headers=hdrs, open_timeout=BOUND) as bad:
                    bad.recv(timeout=2)
                counts["opened"] += 1
            except Exception:  # noqa: BLE001 - refused, as it must be
                pass
        ws, other = page(), page(reads=False)
        for k in range(messages):
            msg = hostile(rng)
            try:
                ws.send(msg)
            except Exception:  # noqa: BLE001 - the server closed this page (too large)
                ws = page()
            if rng.random() < 0.05:  # a page that goes away in the middle
                ws.close()
                ws = page()
            try:
                answered = _probe(ws, f"probe-{k}")
            except Exception:  # noqa: BLE001 - closed for an oversized frame: reconnect
                ws = page()
                answered = _probe(ws, f"probe-{k}")
            if not answered:
                counts["unanswered"] += 1
            if viewer.proc.poll() is not None:
                counts["died"] += 1
                return
        other.close()
        ws.close()
    finally:
        stack.close()
        alive = viewer.proc.poll() is None  # (a death is counted as such above)
        if viewer.stop(BOUND) not in (0, 130) and alive:
            counts["exit"] += 1
        if "Traceback" in viewer.errors:
            counts["traceback"] += 1
            print(viewer.errors[-2000:], file=sys.stderr)


def run(sequences: int, seed: int, messages: int = 40) -> dict:
    counts = {"died": 0, "traceback": 0, "unanswered": 0, "opened": 0, "exit": 0}
    for s in range(sequences):
        sequence(random.Random(seed * 1_000_003 + s), messages, counts)
    return counts


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=30)
    ap.add_argument("--messages", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    start = time.perf_counter()
    counts = run(args.sequences, args.seed, args.messages)
    total = args.sequences * args.messages
    print(f"mechdsl view: {args.sequences} sessions, {total} hostile messages in "
          f"{time.perf_counter() - start:.0f} s: "
          + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return 1 if any(counts.values()) else 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    sys.exit(main())
