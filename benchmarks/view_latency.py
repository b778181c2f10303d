"""How live `mechdsl view` feels, measured by the real browser (issue 29): timestamps taken
by the page itself (performance.now), in headless Chromium, against `mechdsl view` started
as a user starts it.

* slider: from a slider's input event to the new frame on screen (the first animation
  frame after the run's message is drawn), the median over moves that alternate between two
  values of a param: the seed's l, examples/fourbar.mech and examples/andrews.mech;
* save: from the file's write (the clock of this process) to the new frame on screen (the
  page's clock: performance.timeOrigin + now), for the seed;
* animation: a row of 101 bodies (benchmarks/models.py) played at 1x: the frames per second
  the page draws, and the time one frame's drawing takes.

    python benchmarks/view_latency.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from browser import READY, Viewer, chromium, wait_for  # noqa: E402
import models  # noqa: E402

#: (file, param, two values the slider alternates between)
SLIDERS = (("examples/slider_crank.mech", "l", (3.4, 3.6)),
           ("examples/fourbar.mech", None, None),
           ("examples/andrews.mech", None, None))


def _first_param(driver) -> tuple[str, float]:
    s = driver.execute_script("return window.mechdslView.header.sliders[0]")
    return s["name"], float(s["value"])


def until(driver, condition: str, timeout: float = 60.0) -> None:
    """Wait in the page until ``condition`` (a JavaScript expression) holds: one call that
    the page answers, not a poll from here every few milliseconds, whose round trips through
    chromedriver would take the CPU from the server being measured."""
    driver.set_script_timeout(timeout)
    driver.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        f"(function wait() {{ if ({condition}) done(true); else setTimeout(wait, 2); }})();")


def slider_latency(driver, path: Path, param: str | None, values, moves: int) -> dict:
    viewer = Viewer(path)
    try:
        driver.get(viewer.url)
        wait_for(driver, READY, timeout=60)
        if param is None:
            param, v = _first_param(driver)
            values = (v * 0.98, v * 1.02) if v else (-0.01, 0.01)
        for k in range(moves):
            # a new value at every move, as a drag gives (no run of the same values twice)
            value = values[k % 2] * (1 + 1e-4 * k)
            driver.execute_script(
                "const i = document.querySelector(`#sliders input[data-param='${arguments[0]}']`);"
                "i.value = String(arguments[1]); i.dispatchEvent(new Event('input'));",
                param, value)
            until(driver, f"window.mechdslView.latencies.length >= {k + 1}")
        lat = driver.execute_script("return window.mechdslView.latencies")
        page = driver.execute_script("return window.mechdslView.handled.slice(1)")
        status = driver.execute_script("return window.mechdslView.header.status")
    finally:
        viewer.stop()
    return {"param": param, "median": statistics.median(lat), "max": max(lat), "n": len(lat),
            "status": status, "page": statistics.median(page)}


def save_latency(driver, path: Path, saves: int) -> dict:
    text = path.read_text()
    viewer = Viewer(path)
    out = []
    try:
        driver.get(viewer.url)
        wait_for(driver, READY, timeout=60)
        for k in range(saves):
            time.sleep(0.3)  # let the watcher settle between saves
            n = driver.execute_script("return window.mechdslView.events.length")
            written = time.time() * 1000
            path.write_text(text + f"\n# save {k}\n")
            until(driver, f"window.mechdslView.events.length > {n} && "
                          "window.mechdslView.events.some((e, i) => i >= "
                          f"{n} && e.reason === 'saved')")
            at = driver.execute_script(
                f"return window.mechdslView.events.slice({n}).find((e) => "
                "e.reason === 'saved').at")
            out.append(at - written)
    finally:
        viewer.stop()
    return {"median": statistics.median(out), "max": max(out), "n": len(out)}


def animation_rate(driver, path: Path, seconds: float = 3.0) -> dict:
    viewer = Viewer(path)
    try:
        driver.get(viewer.url)
        wait_for(driver, READY, timeout=120)
        driver.execute_script(
            "const v = window.mechdslView; v.stamps = []; const c = v.draw;"
            "v.draw = () => { const t = performance.now(); c(); "
            "v.stamps.push([t, performance.now() - t]); };")
        time.sleep(seconds)
        stamps = driver.execute_script("return window.mechdslView.stamps")
    finally:
        viewer.stop()
    starts = [s[0] for s in stamps]
    gaps = [b - a for a, b in zip(starts, starts[1:])]
    return {"fps": 1000 / statistics.median(gaps) if gaps else 0.0, "frames": len(stamps),
            "draw_ms": statistics.median(s[1] for s in stamps) if stamps else float("nan"),
            "seconds": seconds}


def run(rep, quick: bool) -> None:
    moves = 9 if quick else 31
    driver = chromium()
    rows = []
    try:
        for file, param, values in SLIDERS:
            r = slider_latency(driver, ROOT / file, param, values, moves)
            rows.append([f"{file}: slider {r['param']}", f"{r['median']:.1f}", f"{r['max']:.1f}",
                         f"{r['page']:.1f}", str(r["n"]), r["status"]])
        with tempfile.TemporaryDirectory() as tmp:
            seed = Path(tmp) / "slider_crank.mech"
            seed.write_text((ROOT / "examples" / "slider_crank.mech").read_text())
            s = save_latency(driver, seed, 5 if quick else 15)
            rows.append(["examples/slider_crank.mech: save", f"{s['median']:.1f}",
                         f"{s['max']:.1f}", "-", str(s["n"]), "ok"])
            row = Path(tmp) / "row.mech"
            row.write_text(models.chain_text(50, t1=9.99, step=0.01))
            a = animation_rate(driver, row, 2.0 if quick else 4.0)
    finally:
        driver.quit()
    rep.table("mechdsl view, measured by the page in headless Chromium (ms, from the input "
              "event or the file's write to the new frame on screen)",
              ["what", "median ms", "max ms", "page's share ms", "n", "run"], rows)
    rep.text(f"Animation of a row of 101 bodies (1000 instants) at 1x: {a['fps']:.0f} frames "
             f"per second ({a['frames']} frames in {a['seconds']:g} s), one frame drawn in "
             f"{a['draw_ms']:.2f} ms (median).")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    from report import Report

    out = ROOT / "benchmarks" / "results"
    rep = Report(out)
    run(rep, args.quick)
    rep.save("results-view.md")


if __name__ == "__main__":
    main()
