"""``mechdsl optimize`` keeps its work: an interrupt (SIGINT, SIGTERM, or a sweep that comes
back interrupted) stops the search with the best design solved so far printed, run and
written; a non-finite objective is never a minimum.

The model is test_optimize's slider-crank, on a time grid holding both dead centres, so that
for every design (l, r) the sampled max |ax| is the closed form r omega^2 (1 + r/l) and the
sampled stroke is 2r (see that module's docstring): the best design printed, its objective and
the run written there are checked against those closed forms, not against the program.

Non-finite objectives: ``0*sqrt(range(slider.x) - 4.5)`` is 0 where the stroke 2r >= 4.5 and
nan where 2r < 4.5, so ``minimize max(abs(slider.ax)) + 0*sqrt(range(slider.x) - 4.5)`` over
l in 3.5 .. 6, r in 1 .. 3 (l > r: every design assembles) has its minimum at the smallest
r with a finite objective, r = 2.25, and the largest l, 6: objective 2.25 omega^2 (1 + 2.25/6).
On the 21 x 21 grid (r = 1, 1.1, ..., 3), the 13 values of r below 2.25 give nan for each of
the 21 values of l: 273 of the 441 designs, and the grid's best is r = 2.3, l = 6.
"""

from __future__ import annotations

import csv
import os
import pty
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from conftest import ROOT
from mechdsl.study.optimize import optimize
from mechdsl.writing import Interrupted
from test_optimize import BASE, OPTIMIZE, mechdsl, peak_ax, theta_of, times, write, x_of

#: The instants of the runs: t = 0 .. 1/2 step 1/64, both dead centres among them
T = times()

#: Members per param of the slow search: each generation (300 designs) is a sweep of a good
#: part of a second, and the search goes on for many of them after the first status line
SLOW_POPSIZE = 150

#: Seconds an interrupted search may take to stop, print, run the model at its best and
#: write the CSV (the interpreter's start is not counted: the signal comes mid-search)
STOP_WITHIN = 15.0

NONFINITE = """
optimize l in 3.5 .. 6, r in 1 .. 3
minimize max(abs(slider.ax)) + 0*sqrt(range(slider.x) - 4.5)
"""
R_NONFINITE, L_NONFINITE = 2.25, 6.0


def csv_rows(path) -> np.ndarray:
    rows = [row for row in csv.reader(path.read_text().splitlines())
            if row and not row[0].startswith("#")]
    assert rows[0] == ["t", "slider.x", "slider.vx", "slider.ax"]
    return np.array(rows[1:], dtype=float)


def printed_design(stdout: str) -> tuple[float, float, float]:
    """(l, r, objective) of the design ``mechdsl optimize`` printed."""
    m = re.search(r"^  l = (\S+)\n  r = (\S+)\nobjective: (\S+)$", stdout, re.M)
    assert m, stdout
    return float(m[1]), float(m[2]), float(m[3])


def check_design(l: float, r: float, objective: float) -> None:
    """The design meets both requirements of OPTIMIZE (stroke 2r >= 4, l >= 2r) and its
    objective is the closed-form peak there."""
    assert 2 * r - 4 >= -1e-9 and l - 2 * r >= -1e-9
    assert objective == pytest.approx(peak_ax(r, l), rel=1e-10)


def check_run(path, l: float, r: float) -> None:
    """The CSV at ``path`` is the model's run at (l, r): the slider's closed-form position."""
    data = csv_rows(path)
    np.testing.assert_allclose(data[:, 0], T, rtol=0, atol=1e-15)
    np.testing.assert_allclose(data[:, 1], x_of(theta_of(T), r, l), rtol=1e-10)
    k = np.flatnonzero(data[:, 0] == 7 / 16)[0]  # theta = 2 pi: the outer dead centre
    assert data[k, 1] == pytest.approx(r + l, rel=1e-12)


# --- a signal sent to the command mid-search ------------------------------------------------

class Terminal:
    """Standard error of a child process on a pseudo-terminal, read as it comes: the search's
    status line is drawn only on a terminal, and tells when the search is under way."""

    def __init__(self) -> None:
        self.master, self.slave = pty.openpty()
        self.text = ""
        self.lock = threading.Lock()
        self.reader = threading.Thread(target=self._read, daemon=True)

    def start(self) -> None:
        os.close(self.slave)
        self.reader.start()

    def _read(self) -> None:
        while True:
            try:
                chunk = os.read(self.master, 4096)
            except OSError:  # EIO: the child closed its end
                return
            if not chunk:
                return
            with self.lock:
                self.text += chunk.decode(errors="replace")

    def wait_for(self, pattern: str, timeout: float) -> re.Match:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                found = list(re.finditer(pattern, self.text))
            if found:
                return found[-1]
            time.sleep(0.05)
        raise AssertionError(f"no {pattern!r} on standard error within {timeout} s: "
                             f"{self.text!r}")

    def close(self) -> None:
        self.reader.join(timeout=5)
        os.close(self.master)


def interrupt_mid_search(tmp_path, signum: int, *extra):
    """Start ``mechdsl optimize`` on the slow search, send ``signum`` once its status line
    shows a best design, and return (the completed process, seconds from the signal to its
    exit, the best objective the status line showed last before the signal)."""
    path = write(tmp_path, BASE + OPTIMIZE)
    term = Terminal()
    proc = subprocess.Popen([sys.executable, "-m", "mechdsl", "optimize", str(path),
                             "--popsize", str(SLOW_POPSIZE), *map(str, extra)],
                            stdout=subprocess.PIPE, stderr=term.slave, stdin=subprocess.DEVNULL,
                            text=True, cwd=ROOT)
    term.start()
    try:
        # a number: the first sweeps may have no feasible design yet (best inf)
        shown = term.wait_for(r"best (\d\S*) after \d+ variants", timeout=90)
        sent = time.monotonic()
        proc.send_signal(signum)
        stdout, _ = proc.communicate(timeout=STOP_WITHIN + 30)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        term.close()
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, term.text), took, \
        float(shown[1])


@pytest.mark.parametrize("signum, status, verb", [(signal.SIGINT, 130, "interrupted"),
                                                  (signal.SIGTERM, 143, "terminated")],
                         ids=["SIGINT", "SIGTERM"])
def test_a_signal_mid_search_prints_and_writes_the_best_design_so_far(tmp_path, signum,
                                                                      status, verb):
    out = tmp_path / "best.csv"
    r, took, shown = interrupt_mid_search(tmp_path, signum, "-o", out)
    assert r.returncode == status, r.stdout + r.stderr
    assert took < STOP_WITHIN, f"{took:.1f} s from the signal to the exit"
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].endswith(f": search {verb}; best design so far at"), r.stdout
    assert re.search(r"\(differential evolution interrupted after \d+ sweeps\)", r.stdout), \
        r.stdout
    assert "requirement range(slider.x) >= 4: holds" in r.stdout
    assert "requirement l >= 2*r: holds" in r.stdout
    l, rr, objective = printed_design(r.stdout)
    check_design(l, rr, objective)
    # the best so far is kept, not the last generation's: no worse than the status showed
    assert objective <= shown * (1 + 1e-5)
    assert objective >= peak_ax(2.0, 6.0) * (1 - 1e-12)  # and no better than the optimum
    check_run(out, l, rr)
    assert f"mechdsl: {verb}; the search stopped early" in r.stderr
    assert str(out) in r.stderr


# --- an interrupted sweep inside the search (in this process) --------------------------------

def interrupting(monkeypatch, at: int, *, kept: float = 0.5, raise_it: bool = False):
    """Make the ``at``-th sweep of the search come back interrupted, as a chunked sweep does
    when Ctrl-C lands in it: the first ``kept`` of its variants solved, the others not (no
    instant, nan), status "interrupted"; or, with ``raise_it``, raise there the interrupt
    that SIGTERM becomes (a signal between two sweeps). Returns the list of the sweeps'
    tables."""
    import mechdsl.study as study

    real = study.solve_sweep
    tables: list[dict[str, np.ndarray]] = []

    def sweep(mech, ov, *args, **kwargs):
        tables.append({k: np.asarray(v, dtype=float) for k, v in ov.table.items()})
        if len(tables) == at and raise_it:
            raise Interrupted(signal.SIGTERM)
        res = real(mech, ov, *args, **kwargs)
        if len(tables) < at:
            return res
        V = len(res.n_solved)
        cut = int(V * kept)
        solved = np.arange(V) < cut
        tables[-1] = {k: v[:cut] for k, v in tables[-1].items()}
        return replace(res, status="interrupted", n_solved=np.where(solved, res.n_solved, 0),
                       reduced={k: np.where(solved, v, np.nan) for k, v in res.reduced.items()})

    monkeypatch.setattr(study, "solve_sweep", sweep)
    return tables


def best_of(tables) -> float:
    """The closed-form best objective over the designs of ``tables`` that clearly meet both
    requirements (a margin of 1e-9 over their round-off at the bounds)."""
    l = np.concatenate([t["l"] for t in tables])
    r = np.concatenate([t["r"] for t in tables])
    ok = (2 * r - 4 >= 1e-9) & (l - 2 * r >= 1e-9)
    return float(peak_ax(r[ok], l[ok]).min())


@pytest.mark.parametrize("raise_it", [False, True], ids=["sweep-interrupted", "sigterm"])
def test_an_interrupted_sweep_stops_the_search(monkeypatch, registry, raise_it):
    import mechdsl

    mech = mechdsl.loads(BASE + OPTIMIZE, "slider.mech", registry=registry)
    at = 4
    tables = interrupting(monkeypatch, at, raise_it=raise_it)
    try:
        best = optimize(mech, popsize=10)
    except KeyboardInterrupt:  # (uncaught, it would end the test session)
        pytest.fail("the interrupt went through optimize() instead of stopping the search")
    assert len(tables) == at  # no sweep after the interrupted one
    signum = signal.SIGTERM if raise_it else signal.SIGINT
    assert best.interrupted == signum
    assert best.message == f"differential evolution interrupted after {best.sweeps} sweeps"
    solved = tables[:-1] if raise_it else tables
    assert best.variants == sum(len(t["l"]) for t in solved)
    assert best.sweeps == len(solved)
    assert best.feasible
    check_design(best.params["l"], best.params["r"], best.objective)
    # the best of every design solved, the interrupted sweep's solved ones included
    assert best.objective <= best_of(solved) * (1 + 1e-12)
    # and the run at that best design is the model there
    np.testing.assert_allclose(np.ravel(best.run.data["slider.x"]),
                               x_of(theta_of(T), best.params["r"], best.params["l"]),
                               rtol=1e-10)


def test_the_api_method_returns_the_interrupted_optimum(monkeypatch, registry):
    import mechdsl

    mech = mechdsl.loads(BASE + OPTIMIZE, "slider.mech", registry=registry)
    interrupting(monkeypatch, 3)
    best = mech.optimize(popsize=10)
    assert best.interrupted == signal.SIGINT and best.feasible
    check_design(best.params["l"], best.params["r"], best.objective)
    assert best.run is not None


def test_interrupted_before_any_design_is_solved(monkeypatch, registry, tmp_path, capsys):
    from mechdsl.cli import main

    interrupting(monkeypatch, 1, kept=0.0)
    path = write(tmp_path, BASE + OPTIMIZE)
    out = tmp_path / "best.csv"
    status = main(["optimize", str(path), "-o", str(out), "--popsize", "10"])
    captured = capsys.readouterr()
    assert status == 130, captured.out + captured.err
    assert captured.out.splitlines()[0] == f"{path}: search interrupted before any design " \
                                           "was solved"
    assert "0 variants solved in 0 sweeps" in captured.out
    assert "nothing was run" in captured.err
    assert not out.exists()


def test_the_command_stops_on_an_interrupted_sweep(monkeypatch, tmp_path, capsys):
    """In process, through the command line's main(): the sweep returns "interrupted" (the
    solver took the signal) and the command stops there with 130, not 0 after the search."""
    from mechdsl.cli import main

    tables = interrupting(monkeypatch, 3)
    path = write(tmp_path, BASE + OPTIMIZE)
    out = tmp_path / "best.csv"
    status = main(["optimize", str(path), "-o", str(out), "--popsize", "10"])
    captured = capsys.readouterr()
    assert status == 130, captured.out + captured.err
    assert len(tables) == 3
    assert "search interrupted; best design so far at" in captured.out
    assert "Optimization terminated successfully" not in captured.out
    l, r, objective = printed_design(captured.out)
    check_design(l, r, objective)
    assert objective <= best_of(tables) * (1 + 1e-12)
    check_run(out, l, r)


# --- non-finite objectives --------------------------------------------------------------------

NAN_EVERYWHERE = "optimize l in 2.5 .. 6\nminimize sqrt(-max(abs(slider.ax)))\n"


@pytest.mark.parametrize("search, designs", [(["--grid", "5"], "5"),
                                             (["--popsize", "4", "--maxiter", "3"], r"\d+")],
                         ids=["grid", "evolution"])
def test_an_objective_finite_nowhere_exits_2(tmp_path, search, designs):
    # max |ax| > 0 for every design: the square root of its negative is nan everywhere
    path = write(tmp_path, BASE + NAN_EVERYWHERE)
    out = tmp_path / "best.csv"
    r = mechdsl("optimize", path, "-o", out, *search)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    line = (BASE + NAN_EVERYWHERE).splitlines().index("minimize sqrt(-max(abs(slider.ax)))") + 1
    assert re.match(rf"{re.escape(str(path))}:{line}:1: error: the objective is not a finite "
                    rf"number for any of the {designs} designs solved", r.stderr), r.stderr
    assert "minimum found" not in r.stdout and "objective: inf" not in r.stdout
    assert not out.exists()


def test_some_non_finite_objectives_are_counted_and_never_best_on_the_grid(tmp_path):
    path = write(tmp_path, BASE + NONFINITE)
    out = tmp_path / "best.csv"
    r = mechdsl("optimize", path, "--grid", 21, "-o", out)
    assert r.returncode == 0, r.stdout + r.stderr
    rs = np.linspace(1, 3, 21)
    count = int(np.sum(2 * rs < 4.5)) * 21
    assert count == 273
    assert f"; {count} of 441 designs gave no finite objective\n" in r.stdout
    assert "could not be solved" not in r.stdout  # l > r: every design assembles
    l, rr, objective = printed_design(r.stdout)
    assert rr == pytest.approx(rs[np.argmax(2 * rs >= 4.5)], abs=1e-12) == pytest.approx(2.3)
    assert l == 6.0
    assert objective == pytest.approx(peak_ax(2.3, 6.0), rel=1e-10)
    check_run(out, l, rr)


def test_some_non_finite_objectives_in_the_evolution(registry):
    import mechdsl

    mech = mechdsl.loads(BASE + NONFINITE, "slider.mech", registry=registry)
    best = optimize(mech, popsize=8, run=False)
    assert best.feasible and np.isfinite(best.objective)
    assert best.nonfinite > 0
    r, l = best.params["r"], best.params["l"]
    assert 2 * r - 4.5 >= -1e-12  # a design with a finite objective
    assert best.objective == pytest.approx(peak_ax(r, l), rel=1e-10)
    optimum = peak_ax(R_NONFINITE, L_NONFINITE)
    assert optimum * (1 - 1e-12) <= best.objective <= optimum * (1 + 1e-5)
    assert r == pytest.approx(R_NONFINITE, rel=1e-5) and l == pytest.approx(L_NONFINITE, rel=1e-5)


def test_requirements_met_only_where_the_objective_is_not_finite_exit_2(tmp_path):
    # finite only where 2r <= 3, and the stroke must be 4 or more: no design is both
    text = BASE + ("optimize l in 3.5 .. 6, r in 1 .. 3\n"
                   "minimize max(abs(slider.ax)) + 0*sqrt(3 - range(slider.x))\n"
                   "subject to range(slider.x) >= 4\n")
    path = write(tmp_path, text)
    out = tmp_path / "best.csv"
    r = mechdsl("optimize", path, "--grid", 11, "-o", out)
    assert r.returncode == 2, r.stdout + r.stderr
    assert ("no design in the ranges satisfies every requirement with a finite objective"
            in r.stderr)
    assert "objective: inf" not in r.stdout
    assert "requirement range(slider.x) >= 4: VIOLATED" in r.stdout
    # the least violating design with a finite objective: the largest r with 2r <= 3
    l, rr, objective = printed_design(r.stdout)
    assert rr == pytest.approx(1.4) and np.isfinite(objective)
    assert objective == pytest.approx(peak_ax(rr, l), rel=1e-10)
    assert not out.exists()
