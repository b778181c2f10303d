"""``mechdsl view``: a local server that keeps a page in step with a ``.mech`` file.

The page (``page/``, beside this module: one HTML file, one script, one style sheet, no
library, no build step) opens a WebSocket and receives one binary message per run
(:mod:`.payload`); it sends small JSON messages: ``{"type": "set", "params": {"l": 1.5},
"id": 7}`` when a slider moves, ``{"type": "reset"}``. The server answers every change with
the run of the latest values only: requests that arrive while a solve runs are merged, so a
fast slider never queues stale runs. A save of the file (or of a table or mesh it names),
seen by watchfiles, loads it again and sends the new run (or its errors) to every page.

**Not an open door** (the security model, docs/view.md):

1. the server binds the loopback interface only (127.0.0.1);
2. every path starts with a random token (``secrets.token_urlsafe``, 192 bits), compared in
   constant time: without it every request is 404, and the WebSocket is refused;
3. the Host header must name the server as the page does (``127.0.0.1:PORT`` or
   ``localhost:PORT``): a page of another site that a DNS name resolves to 127.0.0.1 (DNS
   rebinding) is refused with 400; a WebSocket must come from the page's own Origin;
4. nothing is read but the page's three files, the named ``.mech`` file and what it names,
   as ``mechdsl run`` reads them; plugins are allowed exactly as for ``run``;
5. nothing from the file reaches the page as markup: every name and message travels as a
   JSON string and is shown as text (and a Content-Security-Policy forbids inline script);
6. messages from the page are bounded (:data:`MAX_MESSAGE` bytes) and checked; a malformed
   one gets an error message back, never a crash.

Ctrl-C stops the server and its watcher.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import hmac
import json
import math
import os
import secrets
import socket
from dataclasses import dataclass, field
from pathlib import Path

from ..outputs import payload
from .session import Session

#: The page's files, the only ones served (name -> media type).
PAGE_FILES = {"index.html": "text/html; charset=utf-8",
              "view.js": "text/javascript; charset=utf-8",
              "view.css": "text/css; charset=utf-8"}
#: The largest message a page may send (bytes).
MAX_MESSAGE = 16 * 1024
#: Replies kept for a page that does not read them (the oldest dropped beyond)
MAX_REPLIES = 64
#: How long a save waits for more writes before the file is read again (ms): editors write
#: a file in several steps
SAVE_SETTLE_MS = 30

_PAGE = Path(__file__).with_name("page")


def _headers(port: int) -> dict[str, str]:
    origins = f"ws://127.0.0.1:{port} ws://localhost:{port}"
    return {
        "Content-Security-Policy": (
            "default-src 'none'; script-src 'self'; style-src 'self'; "
            f"img-src 'self' data: blob:; connect-src 'self' {origins}; base-uri 'none'; "
            # VS Code's Simple Browser shows the page in a frame of its webview
            "form-action 'none'; frame-ancestors 'self' vscode-webview: vscode-file:"),
        "X-Content-Type-Options": "nosniff",
        "Referrer-Policy": "no-referrer",  # the token is in the URL
        "Cache-Control": "no-store",
    }


class Outbox:
    """What goes to one page, sent by one task of its own (:meth:`pump`): the replies to its
    requests in order, and of the runs only the latest not yet sent. A page that reads
    slowly, or not at all, skips the runs it could not take and holds up no other page, and
    what waits for it is bounded: one run and :data:`MAX_REPLIES` replies."""

    def __init__(self, ws) -> None:
        self.ws = ws
        self.replies: collections.deque[bytes] = collections.deque(maxlen=MAX_REPLIES)
        self.run: bytes | None = None
        self.ready = asyncio.Event()

    def put_run(self, message: bytes) -> None:
        self.run = message  # a run not yet sent is stale: replaced
        self.ready.set()

    def put_reply(self, message: bytes) -> None:
        self.replies.append(message)
        self.ready.set()

    async def pump(self) -> None:
        """Send what is waiting, until the page goes away (its send fails)."""
        while True:
            await self.ready.wait()
            self.ready.clear()
            while self.replies or self.run is not None:
                if self.replies:
                    message = self.replies.popleft()
                else:
                    message, self.run = self.run, None
                await self.ws.send_bytes(message)


@dataclass
class Hub:
    """The pages connected (each with its :class:`Outbox`), the last message (a page that
    connects gets it first) and the requests waiting for the solver (merged: only the latest
    values and one reload)."""

    session: Session
    sockets: dict = field(default_factory=dict)  # WebSocket -> Outbox
    last: bytes | None = None
    pending: dict = field(default_factory=dict)  # values not solved yet
    reload: bool = False
    reset: bool = False
    opened: bool = False  # the file read at start: its first run
    last_id: object = None
    wake: asyncio.Event | None = None

    async def worker(self) -> None:
        """Solve what is pending, one request at a time, and send the result to every page."""
        assert self.wake is not None
        while True:
            await self.wake.wait()
            self.wake.clear()
            while self.reload or self.reset or self.opened or self.pending:
                if self.reload:
                    self.reload, reason, job = False, "saved", self.session.load
                    self.pending.clear()
                elif self.reset or self.opened:  # the file's values, read already
                    reason = "reset" if self.reset else "opened"
                    self.reset = self.opened = False
                    job = self.session.reset
                    self.pending.clear()
                else:
                    values, self.pending = self.pending, {}
                    reason = "set"

                    def job(values=values):
                        return self.session.solve(values)
                ident = self.last_id
                try:
                    message = _tag(await _in_thread(job), reason, ident)
                except Exception as err:  # noqa: BLE001 - a defect: said on the page, the
                    # server goes on (the command line reports the same as an internal error)
                    message = payload.error_message(
                        "failed", [f"mechdsl: internal error: {type(err).__name__}: {err}"])
                self.broadcast(message)

    def request(self, **what) -> None:
        if what.get("values"):
            self.pending.update(what["values"])
        self.reload |= bool(what.get("reload"))
        self.reset |= bool(what.get("reset"))
        self.opened |= bool(what.get("opened"))
        if self.wake is not None:
            self.wake.set()

    def broadcast(self, message: bytes) -> None:
        self.last = message
        for box in self.sockets.values():
            box.put_run(message)


async def _in_thread(job):
    """``job()`` in a thread of its own, awaited. A daemon thread, not the event loop's
    executor: Ctrl-C stops the server at once, where the executor would wait for a long
    solve to end."""
    import threading

    loop = asyncio.get_running_loop()
    done = loop.create_future()

    def run() -> None:
        try:
            result, error = job(), None
        except BaseException as err:  # noqa: BLE001 - handed to the awaiting task
            result, error = None, err
        if not loop.is_closed():
            loop.call_soon_threadsafe(_settle, done, result, error)

    threading.Thread(target=run, daemon=True, name="mechdsl-view-solve").start()
    return await done


def _settle(future, result, error) -> None:
    if future.cancelled():
        return
    if error is not None:
        future.set_exception(error)
    else:
        future.set_result(result)


def _ident(value: object) -> int | float | str | None:
    """A request's id as the page may give it: a finite number or a short text, else None
    (JSON allows NaN, which the replies, strict JSON, cannot carry)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        try:
            return value if math.isfinite(value) else None
        except OverflowError:  # an integer of a thousand digits
            return None
    return value if isinstance(value, str) and len(value) <= 100 else None


def _tag(message: bytes, reason: str, ident: object) -> bytes:
    """``message`` with why it was sent and the id of the last request it answers (the page
    measures its latency from it)."""
    header, data = payload.decode(message)
    header["reason"] = reason
    header["id"] = _ident(ident)
    return payload.encode(header) + data.tobytes()


def create_app(session: Session, token: str, port: int, *, watch: bool = True):
    """The Starlette application of the view of ``session`` (module docstring)."""
    from starlette.applications import Starlette
    from starlette.responses import PlainTextResponse, Response
    from starlette.routing import Route, WebSocketRoute
    from starlette.websockets import WebSocket, WebSocketDisconnect

    hub = Hub(session)
    headers = _headers(port)
    hosts = {f"127.0.0.1:{port}", f"localhost:{port}"}
    origins = {f"http://{h}" for h in hosts}

    async def page(request):
        name = request.path_params.get("name", "index.html")
        if name not in PAGE_FILES:
            return PlainTextResponse("not found", 404, headers=headers)
        return Response((_PAGE / name).read_bytes(), media_type=PAGE_FILES[name],
                        headers=headers)

    async def socket_endpoint(ws: WebSocket):
        if ws.headers.get("origin") not in origins:
            await ws.close(code=1008)  # before accept: the handshake is refused (403)
            return
        await ws.accept()
        box = hub.sockets[ws] = Outbox(ws)
        if hub.last is not None:  # else the first run comes as soon as it is solved
            box.put_run(hub.last)
        sender = asyncio.create_task(box.pump())
        try:
            while True:
                text = await ws.receive_text()
                reply = _handle(hub, text)
                if reply is not None:
                    box.put_reply(reply)
        except (WebSocketDisconnect, KeyError, RuntimeError):
            # KeyError/RuntimeError: a binary frame where text was expected, a closed socket
            pass
        finally:
            hub.sockets.pop(ws, None)
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await sender

    @contextlib.asynccontextmanager
    async def lifespan(app):
        hub.wake = asyncio.Event()
        # read once before the watcher starts, which then knows the files the model names;
        # the first run (or the file's errors) goes to the pages as they connect
        failed = await _in_thread(session.read)
        tasks = [asyncio.create_task(hub.worker())]
        if failed is not None:
            hub.last = _tag(failed, "opened", None)
        else:
            hub.request(opened=True)
        stop = asyncio.Event()
        if watch:
            tasks.append(asyncio.create_task(_watch(session, hub, stop)))
        try:
            yield
        finally:
            stop.set()
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    routes = [Route(f"/{token}/", page), Route(f"/{token}/{{name}}", page),
              WebSocketRoute(f"/{token}/ws", socket_endpoint)]
    app = Starlette(routes=routes, lifespan=lifespan)
    app.state.hub = hub
    return _Guard(app, token, hosts, headers)


def _refuse(text: str, ident: object = None) -> bytes:
    """The error sent back for a request refused, with its id (the page waits for it)."""
    return _tag(payload.error_message("protocol", [text]), "refused", ident)


def _handle(hub: Hub, text: str) -> bytes | None:
    """A page's message: a request queued (None), or the error to send back."""
    if len(text.encode("utf-8", "replace")) > MAX_MESSAGE:
        return _refuse(f"a message is at most {MAX_MESSAGE} bytes")
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError):
        return _refuse("a message is a JSON object")
    ident = msg.get("id") if isinstance(msg, dict) else None
    if not isinstance(msg, dict) or msg.get("type") not in ("set", "reset", "reload"):
        return _refuse('a message is {"type": "set", "params": {...}}, {"type": "reset"} or '
                       '{"type": "reload"}', ident)
    if msg["type"] == "set":
        params = msg.get("params")
        if not isinstance(params, dict):
            return _refuse('"params" is an object of names and numbers', ident)
        try:
            values = hub.session.check_values(params)
        except ValueError as err:
            return _refuse(str(err), ident)
        what = {"values": values}
    else:
        what = {msg["type"]: True}  # reset, reload
    hub.last_id = ident
    hub.request(**what)
    return None


async def _watch(session: Session, hub: Hub, stop: asyncio.Event) -> None:
    """Reload on every save of the watched files (:meth:`Session.watched`: the model and
    the tables and meshes it names, wherever they are): their folders are watched, again
    whenever a reload changes which they are."""
    from watchfiles import awatch

    while not stop.is_set():
        watched = session.watched()
        folders = sorted({os.path.dirname(f) for f in watched if os.path.isdir(
            os.path.dirname(f))})
        moved = asyncio.Event()

        async def relay() -> None:  # stop this watch on the server's stop or a new set
            while not stop.is_set():
                if session.watched() != watched:
                    break
                await asyncio.sleep(0.25)
            moved.set()

        relaying = asyncio.create_task(relay())
        try:
            async for changes in awatch(*folders, stop_event=moved, debounce=400,
                                        step=SAVE_SETTLE_MS, recursive=False,
                                        watch_filter=None):
                now = session.watched()
                if any(os.path.realpath(path) in now for _, path in changes):
                    hub.request(reload=True)
        finally:
            relaying.cancel()


class _Guard:
    """ASGI middleware: the token, the Host header and, for a WebSocket, the path checked
    before anything else runs (module docstring, points 2 and 3)."""

    def __init__(self, app, token: str, hosts: set[str], headers: dict[str, str]) -> None:
        self.app, self.token, self.hosts, self.headers = app, token, hosts, headers
        self.state = app.state

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        host = dict(scope.get("headers") or []).get(b"host", b"").decode("latin-1")
        first = scope.get("path", "").split("/")[1:2]
        good_token = bool(first) and hmac.compare_digest(first[0].encode(),
                                                          self.token.encode())
        if host in self.hosts and good_token:
            return await self.app(scope, receive, send)
        status = 400 if host not in self.hosts else 404
        if scope["type"] == "websocket":
            await receive()  # websocket.connect
            await send({"type": "websocket.close", "code": 1008})
            return
        body = b"bad host" if status == 400 else b"not found"
        await send({"type": "http.response.start", "status": status,
                    "headers": [(b"content-type", b"text/plain"),
                                *((k.lower().encode(), v.encode())
                                  for k, v in self.headers.items())]})
        await send({"type": "http.response.body", "body": body})


def bind(port: int) -> socket.socket:
    """A listening socket on the loopback interface (``port`` 0: a free one)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", port))
    sock.listen(16)
    sock.setblocking(False)
    return sock


def serve(session: Session, port: int = 0, *, open_browser: bool = True,
          announce=print) -> None:
    """Serve the view of ``session`` until Ctrl-C (module docstring)."""
    import uvicorn

    sock = bind(port)
    port = sock.getsockname()[1]
    token = secrets.token_urlsafe(24)
    app = create_app(session, token, port)
    url = f"http://127.0.0.1:{port}/{token}/"
    announce(f"mechdsl view: {url}  (Ctrl-C to stop)")
    opened = _open_browser(url) if open_browser else None
    # no permessage-deflate: a run's float64 arrays hardly compress, and deflating a 0.24-0.31 MB
    # message on the loopback costs more than sending it
    config = uvicorn.Config(app, log_level="warning", lifespan="on", ws_max_size=MAX_MESSAGE,
                            ws="websockets-sansio" if _has_sansio() else "auto",
                            ws_per_message_deflate=False)
    try:
        uvicorn.Server(config).run(sockets=[sock])
    finally:
        if opened:
            with contextlib.suppress(OSError):
                os.unlink(opened)


def _open_browser(url: str) -> str | None:
    """Open ``url`` in the user's browser through a file only the user can read that
    redirects to it (as Jupyter does): the token never appears in a process's command line,
    which other users of the machine can list. Returns the file (removed when the server
    stops)."""
    import tempfile
    import webbrowser

    fd, path = tempfile.mkstemp(prefix="mechdsl-view-", suffix=".html")  # mode 0600
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(f'<!DOCTYPE html><meta charset="utf-8"><meta http-equiv="refresh" '
                f'content="0;url={url}"><a href="{url}">mechdsl view</a>\n')
    webbrowser.open(Path(path).as_uri())
    return path


def _has_sansio() -> bool:
    try:
        import uvicorn.protocols.websockets.websockets_sansio_impl  # noqa: F401
    except ImportError:
        return False
    return True
