"""mechdsl view's server (issue 29) through starlette's test client: the protocol (a run as
one binary message, sliders that re-solve, saves that reload, errors located as `mechdsl
check` prints them) and the security model of docs/view.md, each point a test. The page
itself is driven in a real browser by tests/test_view_browser.py."""

import json
import math

import numpy as np
import pytest

from closed_forms import slider_crank
from conftest import EXAMPLES
from mechdsl.outputs import payload
from mechdsl.view.server import MAX_MESSAGE, create_app
from mechdsl.view.session import Session

from starlette.testclient import TestClient  # noqa: E402 - after the project's imports

PORT = 8765
HOST = f"127.0.0.1:{PORT}"
TOKEN = "t0ken-for-the-tests"
WS = f"ws://{HOST}/{TOKEN}/ws"
ORIGIN = {"origin": f"http://{HOST}"}
OMEGA = 4 * np.pi


def _client(path, **kwargs):
    app = create_app(Session(str(path), **kwargs), TOKEN, PORT, watch=False)
    return TestClient(app, base_url=f"http://{HOST}")


def _receive(ws, within: int = 60):
    """The next message, decoded; a failure (not a hang) if none comes ``within`` seconds."""
    import signal

    def late(signum, frame):
        raise AssertionError(f"no message from the server within {within} s")

    before = signal.signal(signal.SIGALRM, late)
    signal.alarm(within)
    try:
        return payload.decode(ws.receive_bytes())
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, before)


def _array(header, data, item):
    return data[item["o"]:]


def _body(header, data, name, v=0):
    """The drawn points of body ``name`` at every instant, (K, P, 2)."""
    it = next(i for i in header["items"] if i["kind"] == "body" and i["name"] == name
              and i["v"] == v)
    K, P = header["K"], it["p"]
    return data[it["o"]:it["o"] + K * P * 2].reshape(K, P, 2)


def _series(header, data, name, v=0):
    s = next(s for s in header["series"] if s["name"] == name and s["v"] == v)
    return data[s["o"]:s["o"] + header["K"]]


@pytest.fixture
def seed(tmp_path):
    path = tmp_path / "slider_crank.mech"
    path.write_text((EXAMPLES / "slider_crank.mech").read_text())
    return path


def test_the_first_message_is_the_run_drawn_exactly(seed):
    with _client(seed) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        header, data = _receive(ws)
    assert header["type"] == "run" and header["status"] == "ok"
    assert [s["name"] for s in header["sliders"]] == ["r", "l", "omega"]
    t = data[header["t"]:header["t"] + header["K"]]
    np.testing.assert_allclose(t, np.linspace(0, 1, 1001), atol=1e-15)
    # the slider's pin C (rod.C): the closed form of the slider-crank
    x, _, _ = slider_crank(2.0, 3.5, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
    rod = _body(header, data, "rod")  # rod drawn through B then C
    np.testing.assert_allclose(rod[:, 1, 0], x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rod[:, 1, 1], 0.0, atol=1e-12)
    # the crank's tip B at (r cos theta, r sin theta)
    crank = _body(header, data, "crank")
    theta = np.pi / 4 + OMEGA * t
    np.testing.assert_allclose(crank[:, 1], np.c_[2 * np.cos(theta), 2 * np.sin(theta)],
                               atol=1e-12)
    np.testing.assert_allclose(_series(header, data, "slider.x"), x, atol=1e-12)


def test_a_slider_move_re_solves_and_a_rod_too_short_shows_where_it_locks(seed):
    with _client(seed) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        _receive(ws)
        ws.send_text(json.dumps({"type": "set", "params": {"l": 3.0}, "id": 1}))
        header, data = _receive(ws)
        assert (header["id"], header["reason"], header["status"]) == (1, "set", "ok")
        t = data[header["t"]:header["t"] + header["K"]]
        x, _, _ = slider_crank(2.0, 3.0, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
        np.testing.assert_allclose(_series(header, data, "slider.x"), x, atol=1e-12)
        # l = 1.5 < r: the lock-up at t = 0.005, the five instants before it kept
        ws.send_text(json.dumps({"type": "set", "params": {"l": 1.5}, "id": 2}))
        header, data = _receive(ws)
        assert header["status"] == "failed" and header["solved"] == [5]
        assert "t = 0.005" in header["messages"][0]
        sl = {s["name"]: s["value"] for s in header["sliders"]}
        assert sl == {"r": 2.0, "l": 1.5, "omega": pytest.approx(OMEGA)}
        solved = _series(header, data, "slider.x")[:5]
        x, _, _ = slider_crank(2.0, 1.5, np.pi / 4 + OMEGA * t[:5], OMEGA, 0.0)
        np.testing.assert_allclose(solved, x, atol=1e-12)
        ws.send_text(json.dumps({"type": "reset"}))
        header, _ = _receive(ws)
        assert header["status"] == "ok" and header["reason"] == "reset"


def test_a_save_with_a_typo_shows_the_located_error_and_keeps_the_sliders(seed):
    with _client(seed) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        _receive(ws)
        seed.write_text(seed.read_text().replace("revolute(crank.B", "revolute(cranck.B"))
        c.app.state.hub.request(reload=True)  # what the watcher does on a save
        header, _ = _receive(ws)
        assert header["type"] == "error" and header["reason"] == "saved"
        text = header["errors"][0]
        assert f"{seed}:24:" in text and "unknown body 'cranck'" in text and "^" in text
        assert [s["name"] for s in header["sliders"]] == ["r", "l", "omega"]
        seed.write_text((EXAMPLES / "slider_crank.mech").read_text())
        c.app.state.hub.request(reload=True)
        header, _ = _receive(ws)
        assert header["type"] == "run" and header["status"] == "ok"


def test_a_forward_dynamics_file_is_integrated_with_the_same_page(tmp_path):
    path = tmp_path / "pendulum.mech"
    path.write_text("param L = 1\nparam m = 2\ngravity = (0, -9.81)\nground { }\n"
                    "body bar { guess = (0, -L/2, 0)  point P = (0, L/2)  mass = m  "
                    "inertia = m*L^2/12 }\n"
                    "joint O: revolute(ground.origin, bar.P)\n"
                    "simulate t = 0 .. 1 step 0.01, rtol = 1e-10\noutput bar.phi\n")
    with _client(path) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        header, data = _receive(ws)
    assert header["type"] == "run" and header["status"] == "ok"
    # at rest hanging straight down: it stays there, energy and all
    np.testing.assert_allclose(_series(header, data, "bar.phi"), 0.0, atol=1e-9)
    assert "integrator" in header["summary"]


# -- the security model (docs/view.md), a test each -----------------------------------------

def test_requests_without_the_token_are_refused(seed):
    with _client(seed) as c:
        assert c.get(f"/{TOKEN}/").status_code == 200
        assert c.get("/").status_code == 404
        assert c.get(f"/{TOKEN}x/").status_code == 404
        assert c.get("/wrong/view.js").status_code == 404
        with pytest.raises(Exception):
            with c.websocket_connect(f"ws://{HOST}/wrong/ws", headers=ORIGIN) as ws:
                ws.receive_bytes()


def test_another_host_or_origin_is_refused(seed):
    with _client(seed) as c:
        # DNS rebinding: a page of evil.example resolved to 127.0.0.1 names its own host
        assert c.get(f"/{TOKEN}/", headers={"host": f"evil.example:{PORT}"}).status_code == 400
        for origin in ({"origin": "http://evil.example"}, {}):
            with pytest.raises(Exception):
                with c.websocket_connect(WS, headers=origin) as ws:
                    ws.receive_bytes()


def test_only_the_pages_files_are_served_with_a_policy_against_inline_script(seed):
    with _client(seed) as c:
        page = c.get(f"/{TOKEN}/")
        csp = page.headers["content-security-policy"]
        assert "script-src 'self'" in csp and "unsafe-inline" not in csp
        assert page.headers["referrer-policy"] == "no-referrer"
        for name in ("view.js", "view.css"):
            assert c.get(f"/{TOKEN}/{name}").status_code == 200
        for name in ("session.py", "..%2Fsession.py", "%2E%2E/server.py", seed.name):
            assert c.get(f"/{TOKEN}/{name}").status_code == 404


def test_malformed_oversized_and_unknown_messages_get_an_error_not_a_crash(seed):
    bad = ["not json", "[1, 2]", '{"type": "exec", "code": "1"}', '{"type": "set"}',
           '{"type": "set", "params": {"nope": 1}}', '{"type": "set", "params": {"l": "1"}}',
           '{"type": "set", "params": {"l": 1e999}}', '{"type": "set", "params": {"l": true}}',
           "[" * 100000, "x" * (MAX_MESSAGE + 1),
           '{"type": "set", "params": {"l": ' + "9" * 1000 + "}}"]  # float() overflows
    with _client(seed) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        _receive(ws)
        for text in bad:
            ws.send_text(text)
            header, _ = _receive(ws)
            assert header["type"] == "protocol", text[:40]
        ws.send_text('{"type": "set", "params": {"l": 3.5}, "id": "after"}')
        header, _ = _receive(ws)
        assert header["type"] == "run" and header["id"] == "after"


def test_names_like_markup_travel_as_text(tmp_path):
    # a name cannot hold markup (the language's names are identifiers); a comment, a unit
    # and a message can: they reach the page as JSON strings only
    path = tmp_path / "x.mech"
    text = (EXAMPLES / "slider_crank.mech").read_text()
    text = text.replace('units length = "m"', 'units length = "<b>m</b>"')
    path.write_text('# <img src=x onerror="alert(1)">\n' + text)
    with _client(path) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        header, _ = _receive(ws)
        assert header["type"] == "run"
        unit = next(s["unit"] for s in header["series"] if s["name"] == "slider.x")
        assert unit == "<b>m</b>"  # the page sets it with textContent (the browser test)
        page = c.get(f"/{TOKEN}/view.js").text
    assert "innerHTML" not in page and "insertAdjacentHTML" not in page
    assert "document.write" not in page and "eval(" not in page


def test_a_model_asking_for_a_module_is_refused_as_for_run(tmp_path):
    path = tmp_path / "p.mech"
    path.write_text('plugin "os"\n' + (EXAMPLES / "slider_crank.mech").read_text())
    with _client(path) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        header, _ = _receive(ws)
    assert header["type"] == "error"
    assert "runs no code unless you allow it" in header["errors"][0]


def test_default_slider_ranges():
    assert payload.default_range(3.5) == (0.0, 7.0)
    assert payload.default_range(-2.0) == (-4.0, 0.0)
    assert payload.default_range(0.0) == (-1.0, 1.0)
    assert payload.default_range(math.inf) == (-1.0, 1.0)


def test_a_params_range_is_its_sliders_and_a_wrong_one_is_located(tmp_path):
    text = (EXAMPLES / "slider_crank.mech").read_text()
    path = tmp_path / "ranged.mech"
    path.write_text(text.replace("param r = 2 ", "param r = 2 in 1 .. 2.5 ")
                        .replace("param l = 3.5 ", "param l = 3.5 in r .. 4*r "))
    with _client(path) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        header, _ = _receive(ws)
        ranges = {s["name"]: (s["lo"], s["hi"]) for s in header["sliders"]}
        assert ranges["r"] == (1.0, 2.5) and ranges["l"] == (2.0, 8.0)
        assert ranges["omega"] == (0.0, pytest.approx(8 * np.pi))
        path.write_text(text.replace("param l = 3.5 ", "param l = 3.5 in 5 .. 4 "))
        c.app.state.hub.request(reload=True)
        header, _ = _receive(ws)
        assert header["type"] == "error"
        assert f"{path}:4:18: error: the range of param 'l' is empty" in header["errors"][0]


def test_traced_points_carry_their_velocity_and_acceleration(tmp_path):
    # the crank's tip B at constant omega: v = omega r (-sin, cos), a = -omega^2 r (cos, sin);
    # the slider's pin C moves along x with the closed form's velocity and acceleration
    path = tmp_path / "traced.mech"
    path.write_text((EXAMPLES / "slider_crank.mech").read_text()
                    .replace("simulate t", "trace crank.B, rod.C\nsimulate t"))
    with _client(path) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        header, data = _receive(ws)
    K = header["K"]
    t = data[header["t"]:header["t"] + K]
    theta = np.pi / 4 + OMEGA * t
    tip, pin = (next(i for i in header["items"] if i["kind"] == "trace" and i["name"] == n)
                for n in ("crank.B", "rod.C"))
    vel = data[tip["vo"]:tip["vo"] + 2 * K].reshape(K, 2)
    acc = data[tip["ao"]:tip["ao"] + 2 * K].reshape(K, 2)
    np.testing.assert_allclose(vel, 2 * OMEGA * np.c_[-np.sin(theta), np.cos(theta)], atol=1e-9)
    np.testing.assert_allclose(acc, -2 * OMEGA ** 2 * np.c_[np.cos(theta), np.sin(theta)],
                               atol=1e-7)
    _, v, a = slider_crank(2.0, 3.5, theta, OMEGA, 0.0)
    np.testing.assert_allclose(data[pin["vo"]:pin["vo"] + 2 * K].reshape(K, 2),
                               np.c_[v, 0 * v], atol=1e-9)
    np.testing.assert_allclose(data[pin["ao"]:pin["ao"] + 2 * K].reshape(K, 2),
                               np.c_[a, 0 * a], atol=1e-7)
    # the drawing's bounds are the positions' (not the vectors', which are far larger)
    x0, y0, x1, y1 = header["bounds"]
    assert -2.01 < x0 < -1.99 and 5.49 < x1 < 5.51 and -2.01 < y0 and y1 < 2.01


def test_a_save_of_a_table_in_another_folder_reloads(tmp_path):
    # the drive reads data/motion.csv: a save of that file (not of the model) reloads, through
    # the real watcher, and the new motion is the closed form's
    (tmp_path / "data").mkdir()
    table = tmp_path / "data" / "motion.csv"
    table.write_text("t,angle\n0,0.7853981633974483\n1,13.351768777756622\n")  # pi/4 + 4 pi t
    path = tmp_path / "tabled.mech"
    path.write_text((EXAMPLES / "slider_crank.mech").read_text().replace(
        "angle(crank) = pi/4 + omega*t", 'angle(crank) = table("data/motion.csv", t)'))
    app = create_app(Session(str(path)), TOKEN, PORT, watch=True)
    with TestClient(app, base_url=f"http://{HOST}") as c, \
            c.websocket_connect(WS, headers=ORIGIN) as ws:
        header, data = _receive(ws)
        assert header["status"] == "ok"
        table.write_text("t,angle\n0,0.7853981633974483\n1,7.0685834705770345\n")  # 2 pi t
        header, data = _receive(ws)
        assert header["reason"] == "saved" and header["status"] == "ok"
        t = data[header["t"]:header["t"] + header["K"]]
        x, _, _ = slider_crank(2.0, 3.5, np.pi / 4 + 2 * np.pi * t, 2 * np.pi, 0.0)
        np.testing.assert_allclose(_series(header, data, "slider.x"), x, atol=1e-9)


def test_refusals_answer_their_request_and_a_nan_id_stops_nothing(seed):
    with _client(seed) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        _receive(ws)
        ws.send_text('{"type": "set", "params": {"nope": 1}, "id": 5}')
        header, _ = _receive(ws)
        assert header["type"] == "protocol" and header["id"] == 5
        ws.send_text('{"type": "reset", "id": NaN}')  # JSON's NaN: no id in the answer
        header, _ = _receive(ws)
        assert header["type"] == "run" and header["id"] is None
        ws.send_text('{"type": "set", "params": {"l": 3.0}, "id": "next"}')
        header, _ = _receive(ws)
        assert header["type"] == "run" and header["id"] == "next"


def test_a_value_for_a_slider_that_a_reload_removed_is_dropped(seed):
    with _client(seed) as c, c.websocket_connect(WS, headers=ORIGIN) as ws:
        _receive(ws)
        session = c.app.state.hub.session
        seed.write_text(seed.read_text().replace("param l = 3.5", "param rod = 3.5")
                        .replace("-l/2", "-rod/2").replace("l/2", "rod/2"))
        c.app.state.hub.request(reload=True)
        header, _ = _receive(ws)
        assert [s["name"] for s in header["sliders"]] == ["r", "rod", "omega"]
        session.solve({"l": 3.0})  # checked against the sliders before the reload
        ws.send_text('{"type": "set", "params": {"rod": 3.0}, "id": 1}')
        header, _ = _receive(ws)
        assert header["status"] == "ok" and header["id"] == 1


def test_ctrl_c_stops_the_view_at_once_during_a_long_solve(tmp_path):
    import time

    from browser import Viewer

    path = tmp_path / "long.mech"  # the seed over 2 million instants: many seconds to solve
    path.write_text((EXAMPLES / "slider_crank.mech").read_text()
                    .replace("step 0.001", "step 5e-7"))
    viewer = Viewer(path)
    time.sleep(1.5)  # the first run is under way
    start = time.monotonic()
    status = viewer.stop()
    assert status in (0, 130) and time.monotonic() - start < 5


def test_a_page_that_does_not_read_holds_up_no_other_page():
    """A page that stops reading (a frozen tab, a hostile client) does not stop another
    page's moves being answered: the server's send to the first would otherwise block,
    after a few megabytes, every page's runs."""
    from websockets.sync.client import connect

    from browser import Viewer

    viewer = Viewer(EXAMPLES / "slider_crank.mech")
    try:
        url, origin = viewer.socket_url, viewer.origin
        # max_queue=1: the client stops reading from the socket after one message. Nor does
        # it read the server's reply to its close, queued behind megabytes of runs: its close
        # ends by dropping the connection once close_timeout is over (websockets' default, 10
        # s, was a pure wait; the server sees the same dropped connection either way)
        with connect(url, origin=origin, max_size=2**26, max_queue=1, ping_interval=None,
                     open_timeout=20, close_timeout=0.5) as frozen, \
                connect(url, origin=origin, max_size=2**26, ping_interval=None,
                        open_timeout=20) as page:
            page.recv(timeout=20)
            size = 0
            # 45 runs of 0.24 MB: beyond the loopback's buffers (a server that sends to each
            # page in turn was held up at the 28th)
            for k in range(45):
                page.send(json.dumps({"type": "set", "params": {"l": 3.4 + 0.002 * k},
                                      "id": k}))
                while True:
                    message = page.recv(timeout=20)  # TimeoutError: held up
                    header, _ = payload.decode(message)
                    if header.get("id") == k:
                        break
                size += len(message)
            assert size > 9e6
    finally:
        assert viewer.stop() in (0, 130)
