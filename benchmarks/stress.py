"""The stress report: near lock-up and long runs, measured against the closed form.

    python benchmarks/stress.py                # tables, then the long stress tests
    python benchmarks/stress.py --quick        # tables at reduced size, no long tests

Prints (1) the seed slider-crank with a 2 m crank and rods approaching it, the relative
error of the slider's x, vx and ax beside the largest condition number met; (2) the error
per revolution over a long run (1000 revolutions at 1000 instants each: 10^6 instants), the
first against the last; then runs the tests marked ``long`` (pytest -m long tests/stress).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import mechdsl  # noqa: E402
from closed_forms import slider_crank  # noqa: E402

QUANTITIES = (("slider.x", 0), ("slider.vx", 1), ("slider.ax", 2))


def near_lock_up(rods=(3.5, 2.1, 2.01, 2.001, 2.0001, 2.00001)) -> None:
    mech = mechdsl.load(ROOT / "examples" / "slider_crank.mech")
    print("slider-crank, crank r = 2 m, 1001 instants: relative error against the closed form")
    print(f"{'rod l':>9} {'l/r':>9} {'cond':>10} {'x':>10} {'vx':>10} {'ax':>10} "
          f"{'ax/(cond eps)':>14}")
    for l in rods:
        res = mech.simulate(l=l)
        t = res["t"]
        exact = slider_crank(2.0, l, np.pi / 4 + 4 * np.pi * t, 4 * np.pi, 0.0)
        errs = [np.abs(res[n] - exact[k]).max() / np.abs(exact[k]).max() for n, k in QUANTITIES]
        cond = res.condition[0]
        print(f"{l:>9} {l / 2:>9.6f} {cond:>10.3g} {errs[0]:>10.2e} {errs[1]:>10.2e} "
              f"{errs[2]:>10.2e} {errs[2] / (cond * np.finfo(float).eps):>14.2f}")


def drift(revolutions: int, per_revolution: int) -> None:
    mech = mechdsl.load(ROOT / "examples" / "slider_crank.mech")
    start = time.perf_counter()
    res = mech.simulate(span=(0, 0.5 * revolutions), step=0.5 / per_revolution)
    elapsed = time.perf_counter() - start
    n = len(res["t"])
    print(f"\nlong run: {revolutions} revolutions x {per_revolution} instants = {n:,} instants "
          f"in {elapsed:.1f} s; relative error per revolution")
    print(f"{'quantity':>10} {'first':>10} {'last':>10} {'last/first':>11} {'worst':>10}")
    t = res["t"][:-1]
    for name, k in QUANTITIES:
        exact = slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * t, 4 * np.pi, 0.0)[k]
        scale = np.abs(exact).max()
        err = (np.abs(res[name][:-1] - exact) / scale).reshape(revolutions, per_revolution)
        per = err.max(axis=1)
        print(f"{name:>10} {per[0]:>10.2e} {per[-1]:>10.2e} {per[-1] / per[0]:>11.2f} "
              f"{per.max():>10.2e}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller long run, no long tests")
    args = ap.parse_args()
    near_lock_up()
    drift(*((100, 100) if args.quick else (1000, 1000)))
    if args.quick:
        return 0
    print("\nlong stress tests:")
    # one process: the long cases measure time and memory, which parallel workers would share
    return subprocess.call([sys.executable, "-m", "pytest", "-q", "-n", "0", "-m", "long",
                            str(ROOT / "tests" / "stress")], cwd=ROOT)


if __name__ == "__main__":
    sys.exit(main())
