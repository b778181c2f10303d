"""mechdsl view in a real browser (issue 29): `mechdsl view` started as a user starts it,
its page opened in headless Chromium (Debian's chromium and chromedriver, driven by
selenium). The first frame is drawn, the positions the page holds are `mechdsl run`'s to
1e-12, a slider move re-solves and redraws (the rod too short locks up at t = 0.005), a save
reloads the page, a broken file shows its located error, a request without the token is
refused, and a unit written as markup is shown as text.

These tests need /usr/bin/chromium and /usr/bin/chromedriver (`apt-get install chromium
chromium-driver`; .ci/run installs them): without them they fail, they do not skip."""

import csv
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from browser import READY, Viewer, chromium, wait_for
from closed_forms import slider_crank
from conftest import EXAMPLES

OMEGA = 4 * np.pi


@pytest.fixture(scope="module")
def browser():
    driver = chromium()
    yield driver
    driver.quit()


@pytest.fixture
def seed(tmp_path):
    path = tmp_path / "slider_crank.mech"
    path.write_text((EXAMPLES / "slider_crank.mech").read_text())
    viewer = Viewer(path)
    yield path, viewer
    status = viewer.stop()
    assert status in (0, 130), status  # Ctrl-C stops it cleanly


def events(driver):
    return driver.execute_script("return window.mechdslView.events.length")


def test_the_page_draws_the_run_and_holds_mechdsl_runs_positions(browser, seed, tmp_path):
    path, viewer = seed
    browser.get(viewer.url)
    wait_for(browser, "return window.mechdslView && window.mechdslView.header && "
                      "window.mechdslView.header.status === 'ok'")
    assert browser.find_element("id", "state").text == "ok"
    shots = os.environ.get("MECHDSL_SCREENSHOTS")  # the README's picture comes from here
    if shots:
        browser.set_window_size(1280, 820)
        browser.execute_script("window.dispatchEvent(new Event('resize'));"
                               "window.mechdslView.setFrame(40)")
        browser.save_screenshot(os.path.join(shots, "view.png"))
    # the canvas has been drawn on (not blank)
    inked = browser.execute_script(
        "const c = document.getElementById('mechanism'); const d = c.getContext('2d')"
        ".getImageData(0, 0, c.width, c.height).data; let n = 0;"
        "for (let i = 3; i < d.length; i += 4) if (d[i]) n++; return n;")
    assert inked > 1000
    names = [e.get_attribute("data-param") for e in
             browser.find_elements("css selector", "#sliders input")]
    assert names == ["r", "l", "omega"]
    # the page's slider.x is the CSV's of `mechdsl run`, to 1e-12
    out = tmp_path / "out.csv"
    subprocess.run([sys.executable, "-m", "mechdsl", "run", str(path), "-o", str(out), "-q"],
                   check=True)
    with open(out) as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    ran = np.array([float(r[rows[0].index("slider.x")]) for r in rows[1:]])
    page = np.array(browser.execute_script(
        "const v = window.mechdslView, h = v.header;"
        "const s = h.series.find((s) => s.name === 'slider.x');"
        "return Array.from(v.data.subarray(s.o, s.o + h.K));"))
    np.testing.assert_allclose(page, ran, rtol=0, atol=1e-12)
    # the drawn rod at the shown instant: its end C is the slider's closed form
    browser.execute_script("window.mechdslView.setFrame(123)")
    rod = np.array(browser.execute_script("return window.mechdslView.positions('rod')"))
    t = 0.123
    x, _, _ = slider_crank(2.0, 3.5, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
    np.testing.assert_allclose(rod[1], [x, 0.0], atol=1e-12)


def move(browser, name, value):
    browser.execute_script(
        "const i = document.querySelector(`#sliders input[data-param='${arguments[0]}']`);"
        "i.value = String(arguments[1]); i.dispatchEvent(new Event('input'));", name, value)


def test_a_slider_move_re_solves_and_shows_the_lock_up(browser, seed):
    path, viewer = seed
    browser.get(viewer.url)
    wait_for(browser, "return window.mechdslView && window.mechdslView.header && "
                      "window.mechdslView.header.status === 'ok'")
    move(browser, "l", 3.0)
    wait_for(browser, "return window.mechdslView.latencies.length >= 1")
    move(browser, "l", 1.5)
    wait_for(browser, "return window.mechdslView.header.status === 'failed'")
    assert browser.execute_script("return window.mechdslView.header.solved") == [5]
    errors = browser.find_element("id", "errors")
    assert errors.is_displayed() and "t = 0.005" in errors.text
    assert "--set l=1.5" in browser.find_element("id", "set-text").text


def test_a_save_reloads_and_a_typo_shows_its_located_error(browser, seed):
    path, viewer = seed
    browser.get(viewer.url)
    wait_for(browser, "return window.mechdslView && window.mechdslView.header && "
                      "window.mechdslView.header.status === 'ok'")
    before = events(browser)
    path.write_text(path.read_text().replace("revolute(crank.B", "revolute(cranck.B"))
    wait_for(browser, f"return window.mechdslView.events.length > {before} && "
                      "document.getElementById('errors').textContent.includes('cranck')")
    text = browser.find_element("id", "errors").text
    assert f"{path}:24:" in text and "unknown body 'cranck'" in text and "^" in text
    # the last good drawing stays
    assert browser.execute_script("return window.mechdslView.header.status") == "ok"
    path.write_text((EXAMPLES / "slider_crank.mech").read_text().replace("4*pi", "2*pi"))
    wait_for(browser, "return window.mechdslView.header.sliders.find("
                      "(s) => s.name === 'omega').value < 7")
    assert not browser.find_element("id", "errors").is_displayed()


def test_without_the_token_nothing_is_served(browser, seed):
    path, viewer = seed
    root = viewer.url.rsplit("/", 2)[0] + "/"
    browser.get(root)
    assert "not found" in browser.find_element("tag name", "body").text
    browser.get(root + "view.js")
    assert "not found" in browser.find_element("tag name", "body").text


def test_markup_in_the_file_is_shown_as_text(browser, tmp_path):
    path = tmp_path / "x.mech"
    text = (EXAMPLES / "slider_crank.mech").read_text()
    text = text.replace('units length = "m"',
                        'units length = "<img src=x onerror=window.pwned=1>"')
    path.write_text(text)
    viewer = Viewer(path)
    try:
        browser.get(viewer.url)
        wait_for(browser, "return window.mechdslView && window.mechdslView.header && "
                          "window.mechdslView.header.status === 'ok'")
        label = browser.find_element("css selector", "#plots .label").text
        assert "<img src=x onerror=window.pwned=1>" in label
        assert browser.execute_script("return document.querySelectorAll('img').length") == 0
        assert browser.execute_script("return window.pwned") is None
    finally:
        viewer.stop()


def test_a_saved_page_animates_every_variant_offline(browser, tmp_path):
    # mechdsl run --html: one file, opened from the disk with no server, animates the sweep
    page = tmp_path / "out.html"
    subprocess.run([sys.executable, "-m", "mechdsl", "run", str(EXAMPLES / "fourbar.mech"),
                    "--sweep", "d=3.8,4.2", "--html", str(page), "-q"], check=True)
    browser.get(page.as_uri())
    wait_for(browser, READY)
    header = browser.execute_script("return window.mechdslView.header")
    assert header["V"] == 2 and header["variants"] == ["d = 3.8", "d = 4.2"]
    assert header["status"] == "ok" and header["solved"] == [1001, 1001]
    first = browser.execute_script("return window.mechdslView.frame()")
    wait_for(browser, f"return window.mechdslView.frame() !== {first}")  # it plays
    # both variants are drawn: each one's rocker where its own run puts it
    for v in (0, 1):
        assert browser.execute_script(f"return window.mechdslView.positions('rocker', {v})")
    assert "d = 4.2" in browser.find_element("id", "sliders").text


def test_a_short_run_plays_in_slow_motion_over_two_seconds(browser):
    """Andrews' mechanism moves in 0.03 s: at 1x the page plays it over two seconds (the pace
    0.03 / 2 of real time, said beside the speed), not as a blur of two frames a loop."""
    viewer = Viewer(EXAMPLES / "andrews.mech")
    try:
        browser.get(viewer.url)
        wait_for(browser, READY, timeout=60)
        assert browser.find_element("id", "pace").text == "(1x = 0.015 of real time)"
        # simulated time advanced over the page's own frame clock, at 1x, from t = 0 (0.5 s
        # of play is 0.0075 s of the 0.03: no wrap to the start). The first step after the
        # reset counts from the frame before it, whatever the browser's frame rate under
        # load: measured from that frame's time, the pace is exact
        start = browser.execute_script("const v = window.mechdslView; v.simTime = 0; "
                                       "return [v.simTime, v.frameTime]")
        time.sleep(0.5)
        end = browser.execute_script("const v = window.mechdslView; "
                                     "return [v.simTime, v.frameTime]")
        elapsed = (end[1] - start[1]) / 1000
        assert 0.3 <= elapsed <= 5, elapsed  # it played all along
        rate = (end[0] - start[0]) / elapsed
        assert rate == pytest.approx(0.015, rel=1e-9), rate
    finally:
        viewer.stop()


def test_a_saved_page_draws_the_centrodes(browser, tmp_path):
    """`trace ic(coupler, ground)`: the page draws both centrodes at every frame (a drawing
    that threw would stop the play) and logs no error."""
    model = tmp_path / "fourbar.mech"
    model.write_text((EXAMPLES / "fourbar.mech").read_text() + "trace ic(coupler, ground)\n")
    page = tmp_path / "out.html"
    subprocess.run([sys.executable, "-m", "mechdsl", "run", str(model), "--html", str(page),
                    "-q"], check=True)
    browser.get_log("browser")  # what earlier tests logged
    browser.get(page.as_uri())
    wait_for(browser, READY)
    kinds = browser.execute_script("return window.mechdslView.header.items.map(i => i.kind)")
    assert kinds.count("centrode") == 1
    first = browser.execute_script("return window.mechdslView.frame()")
    wait_for(browser, f"return window.mechdslView.frame() !== {first}")  # it plays
    second = browser.execute_script("return window.mechdslView.frame()")
    wait_for(browser, f"return window.mechdslView.frame() !== {second}")
    assert not [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
