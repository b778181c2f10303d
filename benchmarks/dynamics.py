"""Forward-dynamics benchmarks of issue 28, beside the peers, in one run.

    python benchmarks/dynamics.py [--quick] [--only a02,chain,stiff,car] [--out DIR]
    python benchmarks/bench.py --only dynamics [--quick]       # the same, as bench's section

Four benchmarks (the models and their oracles are in dynamics_models.py):

* ``a02``: IFToMM A02 (N = 40, 20 s): error of B0 at t = 20 against run time (work against
  precision), mechdsl over rtol beside Exudyn's generalised-alpha (index 3) over its fixed
  step (1e-2, 2e-3, 1e-3, 5e-4; aborts recorded). Oracle: the parallelogram branch's
  one-degree-of-freedom equation at rtol 1e-13.
* ``chain``: a chain of N pendulum links released horizontal, 0.2 s at rtol 1e-6, N from 10
  to 3000, beside Exudyn (generalised-alpha, sparse solver, h = 1e-3); log-log time against
  N. Oracle (N <= 30): the chain's N-angle Lagrange equations by DOP853 at rtol 1e-12.
* ``stiff``: the stiff pendulum at rtol 1e-6 for k from 1e2 to 1e10, beside scipy's Radau
  and BDF (rtol 1e-6, atol 1e-8, exact Jacobian) on the 2-coordinate minimal ODE and Exudyn
  (h = 1e-3 and 2e-4); error of theta at t = 2 against a tight Radau reference.
* ``car``: the Test Set's car axis problem (index 3, stiff) against its published reference
  at t = 3: mechdsl's scd over rtol.

mechdsl is timed through its public API, ``mechdsl.loads(text).simulate()`` (parse, compile,
assemble, integrate: what a user's script calls), the median of several calls, in a worker
process of this script (``--worker``, reading a JSON request on standard input) so that a
run that fails, hangs or runs out of memory is recorded with its status, message and the
time it reached, not a crash of the benchmark: a run longer than the time limit is stopped
and recorded as such, and the larger sizes of a sweep after it are skipped. The whole
process ``mechdsl run FILE -o OUT.csv -q`` is timed once per benchmark. Exudyn is timed
in-process (building and assembling the model apart from SolveDynamic). Set
``OMP_NUM_THREADS=1`` for comparable figures; every ratio is between figures of one run.
To measure another copy of mechdsl (a clean checkout), put it first on PYTHONPATH: the
worker and ``mechdsl run`` inherit the environment.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import dynamics_models as dm  # noqa: E402

G = dm.G


def _fmt_t(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "-"
    return f"{1e3 * seconds:.1f} ms" if seconds < 1 else f"{seconds:.2f} s"


def _fmt_e(value: float | None) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.1e}"


def _have_exudyn() -> bool:
    import importlib.util
    if importlib.util.find_spec("exudyn") is None:
        print("(exudyn not installed: pip install -e .[bench])")
        return False
    return True


# --------------------------------------------------------------------------------------------
# mechdsl, in a worker process

def _worker() -> None:
    """Read {"text", "repeat", "budget", "outputs"} as JSON on stdin; time
    ``mechdsl.loads(text).simulate()`` up to ``repeat`` times (fewer once ``budget`` seconds
    are spent or a run fails), and with "loaded" also ``simulate()`` of one loaded mechanism
    ``repeat`` times ("loaded_times"); print {"times", "status", "ok", "messages", "t_last",
    "last": {output: value at the last instant}} as JSON. An exception is recorded as the
    status "exception" with its type and message."""
    spec = json.load(sys.stdin)
    out: dict[str, Any] = {"times": [], "status": "exception", "ok": False, "messages": [],
                           "t_last": None, "last": {}}
    try:
        import mechdsl
        from mechdsl.solve.options import SolverOptions
        res = None
        for _ in range(spec["repeat"]):
            start = time.perf_counter()
            options = SolverOptions(method=spec.get("method") or "auto")
            res = mechdsl.loads(spec["text"], "bench.mech").simulate(options=options)
            out["times"].append(time.perf_counter() - start)
            if not res.ok or sum(out["times"]) > spec["budget"]:
                break
        if spec.get("loaded") and res is not None and res.ok:
            # simulate() again on one loaded mechanism (the model parsed and compiled
            # once, as an API user or a study runs it): what the solve alone costs; with
            # "beside" = k, interleaved with scipy's Radau on the stiff pendulum's minimal
            # ODE at its own steps and at the model's 201 output instants (one process,
            # turn by turn: a shared machine's speed drifts by two within minutes)
            model = mechdsl.loads(spec["text"], "bench.mech")
            model.simulate(options=options)
            k = spec.get("beside")
            every = np.linspace(0.0, 2.0, 201)
            runs = {"loaded_times": lambda: model.simulate(options=options)}
            if k is not None:
                runs["radau_times"] = lambda: dm.stiff_pendulum_solve(k, 2.0, "Radau", 1e-6,
                                                                      1e-8)
                runs["radau_201_times"] = lambda: dm.stiff_pendulum_solve(
                    k, 2.0, "Radau", 1e-6, 1e-8, t_eval=every)
            for name in runs:
                out[name] = []
            for _ in range(spec["repeat"]):
                for name, run in runs.items():
                    start = time.perf_counter()
                    run()
                    out[name].append(time.perf_counter() - start)
        t = np.asarray(res["t"], dtype=float)
        out.update(status=str(res.status), ok=bool(res.ok), method=str(res.method),
                   messages=[str(m) for m in res.messages],
                   t_last=float(t[-1]) if len(t) else None,
                   last={k: float(np.asarray(res[k], dtype=float)[-1]) if len(t) else None
                         for k in spec["outputs"]})
    except BaseException as exc:  # noqa: BLE001 - the record is the point
        out["messages"].append(f"{type(exc).__name__}: {exc}")
    print(json.dumps(out))


def mechdsl_api(text: str, outputs: tuple[str, ...], repeat: int = 3, budget: float = 30.0,
                timeout: float = 300.0, method: str | None = None, loaded: bool = False,
                beside: float | None = None) -> dict[str, Any]:
    """Time ``mechdsl.loads(text).simulate()`` in a worker process (module docstring).

    Returns the worker's record with ``time`` (the median of ``times``, None if no run
    finished) and, ``loaded``, ``loaded_time`` (the median of ``simulate()`` of a loaded
    mechanism; with ``beside`` = k, interleaved with scipy's Radau on the stiff pendulum,
    ``radau_time`` and ``radau_201_time``); a worker that exceeds ``timeout`` seconds is killed and recorded with the
    status "timeout", one that dies with the status "crashed" and its standard error's end."""
    spec = json.dumps({"text": text, "repeat": repeat, "budget": budget, "outputs": outputs,
                       "method": method, "loaded": loaded, "beside": beside})
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"))
    try:
        proc = subprocess.run([sys.executable, __file__, "--worker"], input=spec, text=True,
                              capture_output=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return {"times": [], "time": None, "status": "timeout", "ok": False,
                "messages": [f"stopped after {timeout:g} s"], "t_last": None, "last": {}}
    try:
        rec = json.loads(proc.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        return {"times": [], "time": None, "status": "crashed", "ok": False,
                "messages": [f"exit {proc.returncode}: {proc.stderr.strip()[-300:]}"],
                "t_last": None, "last": {}}
    rec["time"] = statistics.median(rec["times"]) if rec["times"] and rec["ok"] else (
        rec["times"][0] if rec["times"] else None)
    for name in ("loaded", "radau", "radau_201"):
        rec[f"{name}_time"] = statistics.median(rec[f"{name}_times"]) \
            if rec.get(f"{name}_times") else None
    return rec


def mechdsl_process(text: str, timeout: float = 300.0) -> dict[str, Any]:
    """Wall time, exit code and the last line of standard error of the whole process
    ``python -m mechdsl run FILE -o OUT.csv -q`` on the text written to a file, once."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mech"
        path.write_text(text)
        cmd = [sys.executable, "-m", "mechdsl", "run", str(path), "-o", str(Path(tmp) / "o.csv"),
               "-q"]
        start = time.perf_counter()
        try:
            # cwd: python -m puts the working directory first on sys.path, which would
            # shadow a PYTHONPATH copy of mechdsl when run from the repository's root
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                                  cwd=tmp)
        except subprocess.TimeoutExpired:
            return {"time": None, "exit": "timeout", "message": f"stopped after {timeout:g} s"}
        elapsed = time.perf_counter() - start
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    return {"time": elapsed, "exit": proc.returncode,
            "message": lines[0][:200] if lines and proc.returncode else ""}


#: What a user of scipy writes for the stiff pendulum: the minimal ODE and its exact
#: Jacobian (benchmarks/dynamics_models.py, imported as the user's own two functions), its
#: 201 output instants, a CSV like mechdsl's
SCIPY_SCRIPT = """import sys
import numpy as np
from scipy.integrate import solve_ivp
sys.path.insert(0, {here!r})
from dynamics_models import PENDULUM, stiff_pendulum_jac, stiff_pendulum_rhs
k = {k!r}
t = np.linspace(0.0, 2.0, 201)
sol = solve_ivp(lambda t, y: stiff_pendulum_rhs(t, y, k), (0.0, 2.0),
                [0.0, PENDULUM["l0"], 0.0, 0.0], method="Radau", rtol=1e-6, atol=1e-8,
                jac=lambda t, y: stiff_pendulum_jac(t, y, k), t_eval=t)
np.savetxt({out!r}, np.column_stack((sol.t, sol.y.T)), delimiter=",",
           header="t,theta,s,theta.vel,s.vel", comments="")
sys.exit(0 if sol.success else 2)
"""


def whole_processes(text: str, k: float, repeat: int = 5, timeout: float = 300.0
                    ) -> dict[str, Any]:
    """The whole process of each, interleaved ``repeat`` times (medians): ``mechdsl run``
    on the stiff pendulum's text (:func:`mechdsl_process`) and ``python`` on
    :data:`SCIPY_SCRIPT` (start-up, imports, scipy's Radau, the CSV)."""
    mech, scipy_times, exits = [], [], set()
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "stiff_scipy.py"
        script.write_text(SCIPY_SCRIPT.format(here=str(Path(__file__).resolve().parent),
                                              k=k, out=str(Path(tmp) / "scipy.csv")))
        for _ in range(repeat):
            rec = mechdsl_process(text, timeout=timeout)
            exits.add(rec["exit"])
            if rec["time"] is not None:
                mech.append(rec["time"])
            start = time.perf_counter()
            proc = subprocess.run([sys.executable, str(script)], capture_output=True,
                                  timeout=timeout, cwd=tmp)
            scipy_times.append(time.perf_counter() - start)
            exits.add(f"scipy {proc.returncode}")
    med = lambda xs: statistics.median(xs) if xs else None  # noqa: E731
    return {"mechdsl": med(mech), "scipy": med(scipy_times), "exits": sorted(map(str, exits))}


def _integrator(rec: dict[str, Any]) -> str:
    """The integrator a run took, and where it went on with another ("vern9, radau from t
    = 0.0058"), from its summary's line."""
    text = rec.get("method", "")
    first = re.match(r"\w*", text).group(0) or "-"
    for part in text.split("; ")[1:]:
        if " from t = " in part:
            name, rest = part.split(" from t = ", 1)
            first += f", {name} from t = {rest.split(',')[0].split(' ')[0]}"
    return first


def _status(rec: dict[str, Any]) -> str:
    """ok, or the status with the time reached and the message's start."""
    if rec["ok"]:
        return "ok"
    reached = f" at t = {rec['t_last']:g}" if rec.get("t_last") is not None else ""
    msg = rec["messages"][0][:110] if rec["messages"] else ""
    return f"{rec['status']}{reached}: {msg}".replace("|", "/")


# --------------------------------------------------------------------------------------------
# Exudyn: planar rigid bodies with their nodes at the centres of mass

class _Exudyn:
    """A planar Exudyn model under construction: bodies (ObjectRigidBody2D, node at the centre
    of mass), gravity as a force at each centre, revolute and prismatic joints, springs."""

    def __init__(self) -> None:
        import exudyn as exu
        from exudyn import itemInterface as ii
        self.exu, self.ii = exu, ii
        self.container = exu.SystemContainer()
        self.mbs = self.container.AddSystem()
        self.ground = self.mbs.AddObject(ii.ObjectGround())
        self.nodes: list[int] = []
        self.bodies: list[int] = []

    def body(self, com, phi, v, omega, mass, inertia, g: float = G) -> int:
        ii, mbs = self.ii, self.mbs
        node = mbs.AddNode(ii.NodeRigidBody2D(referenceCoordinates=[com[0], com[1], phi],
                                              initialVelocities=[v[0], v[1], omega]))
        body = mbs.AddObject(ii.ObjectRigidBody2D(nodeNumber=node, mass=mass, inertia=inertia))
        marker = mbs.AddMarker(ii.MarkerBodyPosition(bodyNumber=body, localPosition=[0, 0, 0]))
        mbs.AddLoad(ii.LoadForceVector(markerNumber=marker, loadVector=[0, -mass * g, 0]))
        self.nodes.append(node)
        self.bodies.append(body)
        return len(self.bodies) - 1

    def _marker(self, body: int, point, rigid: bool = False) -> int:
        """A marker at ``point``: global for the ground (body -1), else relative to the
        body's centre of mass in the body frame."""
        b = self.ground if body < 0 else self.bodies[body]
        kind = self.ii.MarkerBodyRigid if rigid else self.ii.MarkerBodyPosition
        return self.mbs.AddMarker(kind(bodyNumber=b, localPosition=[point[0], point[1], 0.0]))

    def revolute(self, b0, p0, b1, p1) -> None:
        self.mbs.AddObject(self.ii.ObjectJointRevolute2D(
            markerNumbers=[self._marker(b0, p0), self._marker(b1, p1)]))

    def prismatic(self, b0, p0, b1, p1) -> None:
        """p1 of b1 on the line through p0 along b0's x axis, b1 turning with b0."""
        self.mbs.AddObject(self.ii.ObjectJointPrismatic2D(
            markerNumbers=[self._marker(b0, p0, True), self._marker(b1, p1, True)],
            axisMarker0=[1.0, 0.0, 0.0], normalMarker1=[0.0, 1.0, 0.0], constrainRotation=True))

    def spring(self, b0, p0, b1, p1, k, length) -> None:
        self.mbs.AddObject(self.ii.ObjectConnectorSpringDamper(
            markerNumbers=[self._marker(b0, p0), self._marker(b1, p1)], stiffness=k,
            damping=0.0, referenceLength=length))

    def pose(self, body: int) -> tuple[np.ndarray, float]:
        """The centre of mass and the angle of a body now (after a solve: at its end)."""
        exu = self.exu
        pos = self.mbs.GetNodeOutput(self.nodes[body], exu.OutputVariableType.Position)
        rot = self.mbs.GetNodeOutput(self.nodes[body], exu.OutputVariableType.Rotation)
        return np.asarray(pos, dtype=float)[:2], float(np.ravel(rot)[-1])

    def point(self, body: int, local) -> np.ndarray:
        com, phi = self.pose(body)
        c, s = math.cos(phi), math.sin(phi)
        return com + np.array([c * local[0] - s * local[1], s * local[0] + c * local[1]])

    def solve(self, t1: float, h: float, sparse: bool = True) -> dict[str, Any]:
        """Assemble, then generalised-alpha (Exudyn's default dynamic solver, index 3) in
        steps of h to t1; the wall times of both and whether it reached t1. An exception or
        a False return is recorded as an abort with the time reached."""
        exu = self.exu
        start = time.perf_counter()
        self.mbs.Assemble()
        build = time.perf_counter() - start
        ss = exu.SimulationSettings()
        ss.timeIntegration.endTime = t1
        ss.timeIntegration.numberOfSteps = int(round(t1 / h))
        ss.timeIntegration.verboseMode = 0
        ss.solution.file.write = False
        ss.solution.sensors.writePeriod = t1
        if sparse:
            ss.linearSolver.solverType = exu.LinearSolverType.EigenSparse
        start = time.perf_counter()
        try:
            ok, message = bool(exu.SolveDynamic(self.mbs, ss)), ""
        except Exception as exc:  # noqa: BLE001 - an abort is a result
            ok, message = False, f"{type(exc).__name__}: {exc}"[:200]
        solve = time.perf_counter() - start
        reached = float(self.mbs.systemData.GetTime())
        ok = ok and abs(reached - t1) < 1e-9 * max(1.0, t1)
        return {"ok": ok, "solve": solve, "build": build, "reached": reached,
                "message": message or ("" if ok else f"stopped at t = {reached:g}")}


def _exudyn_timed(build_fn, t1: float, h: float, sparse: bool = True):
    """Build (timed with the assembly) and solve an Exudyn model; (model, record) where the
    record's ``total`` is building, assembling and solving, the figure beside mechdsl's API
    call."""
    start = time.perf_counter()
    model = build_fn()
    build = time.perf_counter() - start
    rec = model.solve(t1, h, sparse)
    rec["build"] += build
    rec["total"] = rec["build"] + rec["solve"]
    return model, rec


# --------------------------------------------------------------------------------------------
# A02

def exudyn_a02(h: float, n: int = 40, t1: float = 20.0) -> dict[str, Any]:
    """A02 in Exudyn: rockers' centres at (k, 0.5), angle pi/2, centre velocity (0.5, 0) and
    omega -1; couplers' centres at (k + 0.5, 1), velocity (1, 0); B0's error at t1 (the
    Euclidean distance to the oracle) if it got there."""
    def build():
        m = _Exudyn()
        rockers = [m.body((k, 0.5), math.pi / 2, (0.5, 0.0), -1.0, 1.0, 1 / 12)
                   for k in range(n + 1)]
        couplers = [m.body((k + 0.5, 1.0), 0.0, (1.0, 0.0), 0.0, 1.0, 1 / 12)
                    for k in range(n)]
        for k, r in enumerate(rockers):
            m.revolute(-1, (k, 0.0), r, (-0.5, 0.0))
        for k, c in enumerate(couplers):
            m.revolute(rockers[k], (0.5, 0.0), c, (-0.5, 0.0))
            m.revolute(rockers[k + 1], (0.5, 0.0), c, (0.5, 0.0))
        return m

    model, rec = _exudyn_timed(build, t1, h)
    ref = dm.a02_oracle([t1], n)[0]
    rec["err"] = float(np.linalg.norm(model.point(0, (0.5, 0.0)) - ref)) if rec["ok"] else None
    return rec


def bench_a02(rep, quick: bool, out: Path) -> None:
    """A02's work against precision (module docstring)."""
    n, t1 = 40, 20.0
    ref = dm.a02_oracle([t1], n)[0]
    runs = [(None, 1e-6), (None, 3e-8)] if quick else [
        (None, 1e-4), (None, 1e-6), (None, 1e-7), (None, 3e-8), (None, 1e-8), (None, 1e-9),
        ("radau", 1e-6), ("radau", 1e-8)]
    rows, exu_pts = [], []
    curves: dict[str, list] = {}
    for method, rtol in runs:
        text = dm.a02_text(n, t1=t1, step=0.1, rtol=rtol, atol=rtol * 1e-2)
        rec = mechdsl_api(text, ("b0x", "b0y"), repeat=1 if quick else 3, budget=60,
                          timeout=900, method=method)
        err = None
        label = f"mechdsl {method or 'auto'}"
        if rec["ok"]:
            err = float(np.hypot(rec["last"]["b0x"] - ref[0], rec["last"]["b0y"] - ref[1]))
            curves.setdefault(label, []).append((rec["time"], err))
        taken = _integrator(rec)
        rows.append([f"{label} ({taken}), rtol {rtol:g}", _fmt_t(rec["time"]), _fmt_e(err),
                     _status(rec)])
    if _have_exudyn():
        for h in ((1e-2, 2e-3) if quick else (1e-2, 2e-3, 1e-3, 5e-4)):
            rec = exudyn_a02(h, n, t1)
            if rec["ok"]:
                exu_pts.append((rec["total"], rec["err"]))
            rows.append([f"Exudyn gen.-alpha, h = {h:g}", _fmt_t(rec["total"]),
                         _fmt_e(rec["err"]), "ok" if rec["ok"] else f"abort: {rec['message']}"])
    proc = mechdsl_process(dm.a02_text(n, t1=t1, step=0.1, rtol=1e-6, atol=1e-8), timeout=600)
    rows.append(["mechdsl run (whole process, rtol 1e-6)", _fmt_t(proc["time"]), "-",
                 f"exit {proc['exit']} {proc['message']}".replace("|", "/")])
    rep.table(f"A02 (N = {n}, {t1:g} s): error of B0 at t = {t1:g} [m] against time "
              "(mechdsl: loads + simulate, median; Exudyn: build + assemble + solve)",
              ["run", "time", "error of B0", "status"], rows)
    _plot(out / "dynamics_a02.png", "A02: work against precision", "error of B0 at t = 20 (m)",
          "time (s)", {**curves, "Exudyn generalised-alpha": exu_pts}, swap=True)


# --------------------------------------------------------------------------------------------
# the chain

def exudyn_chain(n: int, h: float = 1e-3, t1: float = 0.2) -> dict[str, Any]:
    """The chain in Exudyn (links' centres at (i + 1/2, 0), at rest), the free end at t1."""
    def build():
        m = _Exudyn()
        links = [m.body((i + 0.5, 0.0), 0.0, (0.0, 0.0), 0.0, 1.0, 1 / 12) for i in range(n)]
        m.revolute(-1, (0.0, 0.0), links[0], (-0.5, 0.0))
        for i in range(1, n):
            m.revolute(links[i - 1], (0.5, 0.0), links[i], (-0.5, 0.0))
        return m

    model, rec = _exudyn_timed(build, t1, h)
    rec["tip"] = model.point(n - 1, (0.5, 0.0)) if rec["ok"] else None
    return rec


def _median_record(recs: list[dict[str, Any]]) -> dict[str, Any]:
    """Of several records of one Exudyn run, the one of median total time (the failed
    first, if any failed)."""
    failed = [r for r in recs if not r["ok"]]
    if failed:
        return failed[0]
    return sorted(recs, key=lambda r: r["total"])[len(recs) // 2]


def bench_chain(rep, quick: bool, out: Path) -> None:
    """The chain from 10 to 3000 links (module docstring)."""
    sizes = (10, 30, 100, 300) if quick else (10, 30, 100, 300, 1000, 3000)
    timeout = 120 if quick else 600
    have_exu = _have_exudyn()
    rows, mech_pts, exu_pts = [], [], []
    stopped = None
    for n in sizes:
        oracle = dm.chain_oracle(n)["tip"] if n <= 30 else None
        exu = _median_record([exudyn_chain(n) for _ in range(3)]) if have_exu else None
        if stopped is None:
            # five calls, the first in a fresh process (imports, the parser's tables): the
            # median is of the others, as Exudyn's three are after its first model
            rec = mechdsl_api(dm.chain_text(n), ("tipx", "tipy"), repeat=5, budget=30,
                              timeout=timeout)
            if rec["status"] == "timeout":
                stopped = n
        else:
            rec = {"ok": False, "time": None, "status": "skipped", "t_last": None,
                   "messages": [f"N = {stopped} exceeded the time limit"], "last": {}}
        tip = np.array([rec["last"]["tipx"], rec["last"]["tipy"]]) if rec["ok"] else None
        against = oracle if oracle is not None else (exu["tip"] if exu and exu["ok"] else None)
        err_m = float(np.linalg.norm(tip - against)) if tip is not None and against is not None \
            else None
        err_e = float(np.linalg.norm(exu["tip"] - oracle)) if exu and exu["ok"] and \
            oracle is not None else None
        if rec["ok"]:
            mech_pts.append((n, rec["time"]))
        if exu and exu["ok"]:
            exu_pts.append((n, exu["total"]))
        ratio = rec["time"] / exu["total"] if rec["ok"] and exu and exu["ok"] else None
        rows.append([str(n), _fmt_t(rec["time"]), _fmt_e(err_m),
                     _fmt_t(exu["total"]) if exu else "-", _fmt_t(exu["solve"]) if exu else "-",
                     _fmt_e(err_e), "-" if ratio is None else f"{ratio:.1f}", _status(rec)])
    rep.table("Chain of N links released horizontal, 0.2 s (mechdsl rtol 1e-6: loads + "
              "simulate, median of 5 in a fresh process; Exudyn gen.-alpha h = 1e-3, sparse: "
              "build + solve, and solve alone, median of 3); error of the free end [m] "
              "against the N-angle oracle (N <= 30), else "
              "mechdsl against Exudyn",
              ["N", "mechdsl", "error", "Exudyn", "Exudyn solve", "Exudyn error",
               "mechdsl / Exudyn", "mechdsl status"], rows)
    _plot(out / "dynamics_chain.png", "Chain of N links, 0.2 s", "links N", "time (s)",
          {"mechdsl (rtol 1e-6)": mech_pts, "Exudyn (h = 1e-3)": exu_pts})


# --------------------------------------------------------------------------------------------
# the stiff pendulum

def exudyn_stiff(k: float, h: float, t1: float = 2.0) -> dict[str, Any]:
    """The stiff pendulum in Exudyn: the rod's centre at (l/2, 0), the bob's at (L0, 0); a
    revolute at the pivot, a prismatic joint (rod frame at the pivot, bob centre) turning
    the bob with the rod, a spring between them; theta at t1."""
    p = dm.PENDULUM

    def build():
        m = _Exudyn()
        rod = m.body((p["l"] / 2, 0.0), 0.0, (0, 0), 0.0, p["mr"], p["mr"] * p["l"] ** 2 / 12)
        bob = m.body((p["l0"], 0.0), 0.0, (0, 0), 0.0, p["mb"], p["jb"])
        m.revolute(-1, (0.0, 0.0), rod, (-p["l"] / 2, 0.0))
        m.prismatic(rod, (-p["l"] / 2, 0.0), bob, (0.0, 0.0))
        m.spring(rod, (-p["l"] / 2, 0.0), bob, (0.0, 0.0), k, p["l0"])
        return m

    model, rec = _exudyn_timed(build, t1, h, sparse=False)
    rec["theta"] = model.pose(0)[1] if rec["ok"] else None
    return rec


def scipy_stiff(k: float, method: str, rtol: float = 1e-6, atol: float = 1e-8,
                repeat: int = 3, t_eval=None) -> dict[str, Any]:
    """scipy's solve_ivp on the minimal ODE (exact Jacobian): median time, theta(2);
    ``t_eval``: the solution also at these instants (its dense output there)."""
    times, sol = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        sol = dm.stiff_pendulum_solve(k, 2.0, method, rtol, atol, t_eval=t_eval)
        times.append(time.perf_counter() - start)
        if times[-1] > 20:
            break
    return {"time": statistics.median(times), "ok": bool(sol.success),
            "theta": float(sol.y[0, -1]), "nfev": int(sol.nfev), "message": sol.message}


def bench_stiff(rep, quick: bool, out: Path) -> None:
    """The stiff pendulum over k (module docstring)."""
    ks = (1e2, 1e4, 1e6, 1e8) if quick else (1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10)
    timeout = 150 if quick else 600
    have_exu = _have_exudyn()
    rows, curves = [], {"mechdsl": [], "mechdsl simulate()": [], "scipy Radau": [],
                        "scipy Radau, 201 outputs": [], "scipy BDF": [],
                        "Exudyn h = 1e-3": [], "Exudyn h = 2e-4": []}
    first_process = None
    for k in ks:
        theta_ref = float(dm.stiff_pendulum_oracle(k)[0])
        text = dm.stiff_pendulum_text(k, rtol=1e-6, atol=1e-8)
        rec = mechdsl_api(text, ("theta", "s"), repeat=3 if quick else 11, budget=30,
                          timeout=timeout, loaded=True, beside=k)
        if first_process is None:
            first_process = mechdsl_process(text, timeout=timeout)
        cells = [f"{k:.0e}"]
        err = abs(rec["last"]["theta"] - theta_ref) if rec["ok"] else None
        cells += [_fmt_t(rec["time"]), _fmt_t(rec["loaded_time"]), _fmt_e(err)]
        if rec["ok"]:
            curves["mechdsl"].append((k, rec["time"]))
            curves["mechdsl simulate()"].append((k, rec["loaded_time"]))
        for method in ("Radau", "BDF"):
            sp = scipy_stiff(k, method, repeat=1)  # (its error; Radau's time interleaved)
            if method == "Radau" and rec.get("radau_time") is not None:
                sp["time"] = rec["radau_time"]
            cells += [_fmt_t(sp["time"]), _fmt_e(abs(sp["theta"] - theta_ref))]
            curves[f"scipy {method}"].append((k, sp["time"]))
            if method == "Radau":
                cells.append(_fmt_t(rec.get("radau_201_time")))
                if rec.get("radau_201_time") is not None:
                    curves["scipy Radau, 201 outputs"].append((k, rec["radau_201_time"]))
        for h in (1e-3, 2e-4):
            if not have_exu:
                cells += ["-", "-"]
                continue
            ex = exudyn_stiff(k, h)
            cells += [_fmt_t(ex["total"]) if ex["ok"] else "abort",
                      _fmt_e(abs(ex["theta"] - theta_ref)) if ex["ok"] else "-"]
            if ex["ok"]:
                curves["Exudyn h = 1e-3" if h == 1e-3 else "Exudyn h = 2e-4"].append(
                    (k, ex["total"]))
        cells += [_integrator(rec), _status(rec)]
        rows.append(cells)
    rep.table("Stiff pendulum, 2 s: time and error of theta(2) [rad] (mechdsl rtol 1e-6 atol "
              "1e-8, medians: loads + simulate (parse, compile, solve, 201 outputs with "
              "accelerations and reactions), and simulate() of the loaded mechanism "
              "interleaved, in the same process, with scipy's Radau (rtol 1e-6 atol 1e-8 on "
              "the minimal ODE written by hand, exact Jacobian) at its own steps and at the "
              "model's 201 output instants; the integrator the automatic choice took; "
              "scipy BDF alike, once; Exudyn gen.-alpha at fixed steps: build + solve)",
              ["k", "mechdsl", "simulate()", "error", "Radau", "error", "Radau 201 out",
               "BDF", "error", "Exudyn 1e-3", "error", "Exudyn 2e-4", "error",
               "mechdsl integrator", "mechdsl status"], rows)
    if first_process:
        rep.text(f"mechdsl run (whole process), stiff pendulum k = {ks[0]:g}: "
                 f"{_fmt_t(first_process['time'])}, exit {first_process['exit']} "
                 f"{first_process['message']}")
    k = 1e8
    both = whole_processes(dm.stiff_pendulum_text(k, rtol=1e-6, atol=1e-8), k,
                           repeat=3 if quick else 7)
    if both["mechdsl"] and both["scipy"]:
        rep.text(f"Whole process, stiff pendulum k = {k:g}, interleaved, medians of "
                 f"{3 if quick else 7}: `mechdsl run` (start-up, parse, compile, solve, the "
                 f"CSV with accelerations) {_fmt_t(both['mechdsl'])}; `python` on a script "
                 f"with scipy's Radau (start-up, imports, the hand-written ODE and Jacobian, "
                 f"201 outputs, the CSV) {_fmt_t(both['scipy'])}: "
                 f"{both['mechdsl'] / both['scipy']:.2f} times; exits "
                 f"{', '.join(both['exits'])}")
    _plot(out / "dynamics_stiff.png", "Stiff pendulum, 2 s", "spring stiffness k (N/m)",
          "time (s)", curves)


# --------------------------------------------------------------------------------------------
# the car axis

def bench_car(rep, quick: bool, out: Path) -> None:
    """The car axis problem against the Test Set's reference at t = 3 (module docstring)."""
    names = dm.CAR_NAMES[:8] + ("slot.fx", "slot.fy", "axle.fx", "axle.fy")
    rows = []
    for rtol in ((1e-6, 1e-8) if quick else (1e-4, 1e-6, 1e-8, 1e-10)):
        rec = mechdsl_api(dm.car_axis_text(rtol=rtol, atol=rtol * 1e-2), names, repeat=3,
                          budget=30, timeout=300)
        scd_all = scd_pos = None
        if rec["ok"]:
            v = rec["last"]
            lam = dm.car_multipliers(v["xl"], v["yl"], v["xr"], v["yr"],
                                     (v["slot.fx"], v["slot.fy"]),
                                     (v["axle.fx"], v["axle.fy"]), 3.0)
            y = np.array([v[n] for n in dm.CAR_NAMES[:8]] + list(lam))
            scd_all, scd_pos = dm.scd(y, dm.CAR_REF), dm.scd(y[:8], dm.CAR_REF[:8])
        rows.append([f"{rtol:g}", _fmt_t(rec["time"]),
                     "-" if scd_pos is None else f"{scd_pos:.1f}",
                     "-" if scd_all is None else f"{scd_all:.1f}", _status(rec)])
    proc = mechdsl_process(dm.car_axis_text(rtol=1e-8, atol=1e-10))
    rows.append(["run, 1e-8", _fmt_t(proc["time"]), "-", "-",
                 f"exit {proc['exit']} {proc['message']}".replace("|", "/")])
    rep.table("Car axis (Test Set, index 3, t = 3): scd against the published reference "
              "(positions and velocities; all ten with the multipliers)",
              ["rtol", "mechdsl", "scd (8)", "scd (10)", "status"], rows)


# --------------------------------------------------------------------------------------------

def _plot(path: Path, title: str, xlabel: str, ylabel: str, curves: dict, swap=False) -> None:
    """A log-log plot of the curves' points (x, y) (swap: points are (y, x))."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for label, pts in curves.items():
        if not pts:
            continue
        pts = np.array(sorted((p[::-1] if swap else p) for p in pts))
        ax.loglog(pts[:, 0], pts[:, 1], "o-", label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


BENCHMARKS = {"a02": bench_a02, "chain": bench_chain, "stiff": bench_stiff, "car": bench_car}


def run(rep, quick: bool, only: str | None = None) -> None:
    """Run the benchmarks (all, or the comma-separated ``only``) into the Report ``rep``;
    the plots go to rep.out. bench.py's ``dynamics`` section calls this."""
    rep.out.mkdir(parents=True, exist_ok=True)
    rep.text(f"Forward dynamics (issue 28){' (quick)' if quick else ''}: "
             f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}")
    for name in (only.split(",") if only else BENCHMARKS):
        try:
            BENCHMARKS[name.strip()](rep, quick, rep.out)
        except Exception as exc:  # noqa: BLE001 - one broken benchmark must not hide the rest
            rep.text(f"benchmark {name} failed: {type(exc).__name__}: {exc}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer sizes, tolerances and repeats")
    ap.add_argument("--only", default=None, help="comma-separated: " + ",".join(BENCHMARKS))
    ap.add_argument("--out", type=Path, default=HERE / "results")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        _worker()
        return
    from report import Report
    rep = Report(args.out)
    run(rep, args.quick, args.only)
    path = rep.save("dynamics-quick.md" if args.quick else "dynamics.md")
    print(f"\ntables in {path}")


if __name__ == "__main__":
    main()
