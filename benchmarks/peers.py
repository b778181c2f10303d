"""The peers mechdsl's benchmark measures itself against, on the mechanisms of models.py.

Two peers:

* Exudyn (a C++ multibody-dynamics code with a Python interface): the mechanism is modelled as
  planar rigid bodies with revolute and prismatic joints, the crank's angle is prescribed by a
  coordinate constraint with a time-dependent offset, and the motion is computed by Exudyn's
  default dynamic solver (generalized-alpha on the index-3 equations). Masses and inertias are
  arbitrary: the motion is fully prescribed, so they do not change it.
* a plain numpy Newton-Raphson per instant in Haug's Cartesian coordinates: the "obvious
  implementation" of kinematic analysis.

Every function returns a plain dict; the errors are relative, max |value - exact| / max |exact|,
against the closed forms of models.py. Exudyn is imported inside the functions, so that this
module imports without it; the Exudyn functions raise ImportError if it is missing.

    >>> import peers
    >>> peers.exudyn_slider_crank(repeat=1)["err_x"] < 1e-10
    True
"""

from __future__ import annotations

import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

try:
    import models
except ImportError:  # imported from outside benchmarks/: models.py lies beside this file
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import models

# Offset functions of a coordinate constraint: (mbs, t, itemNumber, lOffset) -> offset.
OffsetFunction = Callable[[Any, Any, int, Any], Any]

# Sensor outputs recorded at every step, by the names of the result keys.
_KINEMATICS = (("x", "Position"), ("vx", "Velocity"), ("ax", "Acceleration"))


# --------------------------------------------------------------------------------------------
# small shared helpers

def _relative_error(value: np.ndarray, exact: np.ndarray) -> float:
    """max |value - exact| / max |exact|: the error measure of the whole benchmark."""
    return float(np.max(np.abs(value - exact)) / np.max(np.abs(exact)))


def _timed(fn: Callable[[], Any]) -> tuple[float, Any]:
    """Wall time of one call of fn and its result."""
    start = time.perf_counter()
    result = fn()
    return time.perf_counter() - start, result


def user_env(bytecode: bool = True) -> dict[str, str]:
    """The environment of a user's shell: Python caches compiled bytecode (``__pycache__``)
    unless told not to. Some sandboxes set PYTHONDONTWRITEBYTECODE, which makes every start
    recompile an editable install's modules; ``bytecode=False`` measures that case."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    if not bytecode:
        env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def import_time(module: str, repeat: int = 5, bytecode: bool = True) -> float:
    """Median wall time [s] of ``python -c "import <module>"`` in a fresh interpreter
    (sys.executable), interpreter start-up included: what a user waits for before a script
    that imports the module can begin. One warm-up run first writes the bytecode cache."""
    env = user_env(bytecode)
    cmd = [sys.executable, "-c", f"import {module}"]
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    times = []
    for _ in range(repeat):
        elapsed, _ = _timed(lambda: subprocess.run(cmd, check=True, capture_output=True,
                                                   env=env))
        times.append(elapsed)
    return statistics.median(times)


# --------------------------------------------------------------------------------------------
# Exudyn: model building blocks

def _exudyn():
    """The exudyn module; ImportError propagates, so that the caller can skip the Exudyn rows."""
    import exudyn
    return exudyn


def _add_rigid_body(mbs, q: np.ndarray, qd: np.ndarray, mass: float = 1.0,
                    inertia: float = 0.1) -> tuple[Any, Any]:
    """A planar rigid body whose node starts at q = (x, y, phi) with velocity qd.

    The configuration goes into the node's reference coordinates (the displacements start at
    zero), so that the bodies start assembled and the driver's offset is the angle's change."""
    from exudyn.itemInterface import NodeRigidBody2D, ObjectRigidBody2D
    node = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[float(v) for v in q],
                                       initialVelocities=[float(v) for v in qd]))
    body = mbs.AddObject(ObjectRigidBody2D(nodeNumber=node, mass=mass, inertia=inertia))
    return node, body


def _add_revolute(mbs, body0, point0: tuple[float, float], body1,
                  point1: tuple[float, float]) -> None:
    """A revolute joint between a point of body0 and a point of body1 (body frames)."""
    from exudyn.itemInterface import MarkerBodyPosition, ObjectJointRevolute2D
    markers = [mbs.AddMarker(MarkerBodyPosition(bodyNumber=b, localPosition=[p[0], p[1], 0.0]))
               for b, p in ((body0, point0), (body1, point1))]
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=markers))


def _add_x_slide(mbs, ground, body) -> None:
    """A prismatic joint keeping body's origin on the x axis and its angle at zero."""
    from exudyn.itemInterface import MarkerBodyRigid, ObjectJointPrismatic2D
    markers = [mbs.AddMarker(MarkerBodyRigid(bodyNumber=b, localPosition=[0.0, 0.0, 0.0]))
               for b in (ground, body)]
    # axis along x in the ground frame; the slider's y axis stays normal to it, which with
    # constrainRotation=True also fixes the slider's angle
    mbs.AddObject(ObjectJointPrismatic2D(markerNumbers=markers, axisMarker0=[1.0, 0.0, 0.0],
                                         normalMarker1=[0.0, 1.0, 0.0], constrainRotation=True))


def _add_angle_driver(mbs, node, offset: OffsetFunction, offset_t: OffsetFunction,
                      user_function: str) -> list:
    """Prescribe the change of node's angle as offset(t) by a coordinate constraint against a
    ground node; offset_t is its time derivative (used for the initial accelerations).

    user_function "python" calls the Python functions from C++ at every evaluation;
    "symbolic" records them once as Exudyn symbolic expressions evaluated in C++. The returned
    list holds the symbolic functions, which must stay alive as long as the model is solved."""
    from exudyn.itemInterface import (MarkerNodeCoordinate, NodePointGround,
                                      ObjectConnectorCoordinate)
    ground_node = mbs.AddNode(NodePointGround())
    markers = [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n, coordinate=c))
               for n, c in ((ground_node, 0), (node, 2))]
    # the constraint reads angle displacement - 0 - offset(t) = 0
    constraint = mbs.AddObject(ObjectConnectorCoordinate(
        markerNumbers=markers, offsetUserFunction=offset, offsetUserFunction_t=offset_t))
    if user_function == "python":
        return []
    if user_function != "symbolic":
        raise ValueError(f"user_function must be 'python' or 'symbolic', not {user_function!r}")
    from exudyn.advancedUtilities import CreateSymbolicUserFunction
    keep = []
    for name, fn in (("offsetUserFunction", offset), ("offsetUserFunction_t", offset_t)):
        symbolic = CreateSymbolicUserFunction(mbs, fn, name, constraint)
        mbs.SetObjectParameter(constraint, name, symbolic)
        keep.append(symbolic)
    return keep


def _add_sensors(mbs, node, outputs: tuple[tuple[str, str], ...]) -> dict[str, Any]:
    """Sensors storing the node's outputs in memory at every written step, by result key."""
    exu = _exudyn()
    from exudyn.itemInterface import SensorNode
    return {key: mbs.AddSensor(SensorNode(nodeNumber=node, storeInternal=True, writeToFile=False,
                                          outputVariableType=getattr(exu.OutputVariableType, kind)))
            for key, kind in outputs}


def _settings(step: float, n_steps: int, sparse: bool = False):
    """Simulation settings: n_steps steps of size step, no files, no console output, the sensors
    written at every step; the sparse linear solver if asked for."""
    exu = _exudyn()
    ss = exu.SimulationSettings()
    ss.timeIntegration.endTime = step * n_steps
    ss.timeIntegration.numberOfSteps = n_steps
    ss.timeIntegration.verboseMode = 0
    ss.solution.file.write = False
    # the default period is 0.01 s; half a step keeps every step even with rounding of t
    ss.solution.sensors.writePeriod = 0.5 * step
    if sparse:
        ss.linearSolver.solverType = exu.LinearSolverType.EigenSparse
    return ss


def _solve(mbs, ss, solver: str) -> int:
    """Run exudyn's SolveDynamic with the named DynamicSolverType; the Newton iterations used."""
    exu = _exudyn()
    exu.SolveDynamic(mbs, ss, solverType=getattr(exu.DynamicSolverType, solver))
    return int(mbs.sys["dynamicSolver"].it.newtonStepsCount)


# --------------------------------------------------------------------------------------------
# Exudyn: the slider-crank

def _slider_crank_state(t: float, r: float, l: float, omega: float,
                        phi0: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """(q, qd) of crank, rod and slider at time t by the closed form, each body's frame at its
    centre, so that the model starts assembled and with consistent velocities."""
    phi = phi0 + omega * t
    tip = r * np.array([math.cos(phi), math.sin(phi)])
    tip_d = r * omega * np.array([-math.sin(phi), math.cos(phi)])
    x, vx, _ = (float(v) for v in models.slider_crank_exact(np.array(t), r, l, omega))
    slide, slide_d = np.array([x, 0.0]), np.array([vx, 0.0])
    u = (slide - tip) / l                           # unit vector along the rod
    psi = math.atan2(u[1], u[0])
    psi_d = float(np.dot([-u[1], u[0]], slide_d - tip_d)) / l
    return [(np.array([*tip / 2, phi]), np.array([*tip_d / 2, omega])),
            (np.array([*(tip + slide) / 2, psi]), np.array([*(tip_d + slide_d) / 2, psi_d])),
            (np.array([x, 0.0, 0.0]), np.array([vx, 0.0, 0.0]))]


def _build_slider_crank(r: float, l: float, omega: float, phi0: float,
                        user_function: str) -> tuple[Any, dict[str, Any], list]:
    """The Exudyn slider-crank, assembled: (system container, slider sensors, keep-alive list).
    The container is returned because the systems live in it."""
    exu = _exudyn()
    from exudyn.itemInterface import ObjectGround
    container = exu.SystemContainer()
    mbs = container.AddSystem()
    ground = mbs.AddObject(ObjectGround())
    (crank_n, crank), (_, rod), (slider_n, slider) = (
        _add_rigid_body(mbs, q, qd) for q, qd in _slider_crank_state(0.0, r, l, omega, phi0))
    _add_revolute(mbs, ground, (0.0, 0.0), crank, (-r / 2, 0.0))
    _add_revolute(mbs, crank, (r / 2, 0.0), rod, (-l / 2, 0.0))
    _add_revolute(mbs, rod, (l / 2, 0.0), slider, (0.0, 0.0))
    _add_x_slide(mbs, ground, slider)
    # the symbolic conversion needs an expression, hence 0*t in the constant derivative
    keep = _add_angle_driver(mbs, crank_n, lambda mbs, t, i, off: omega * t,
                             lambda mbs, t, i, off: omega + 0 * t, user_function)
    sensors = _add_sensors(mbs, slider_n, _KINEMATICS)
    mbs.Assemble()
    return container, sensors, keep


def exudyn_slider_crank(step: float = 1e-3, t1: float = 1.0, repeat: int = 5,
                        solver: str = "GeneralizedAlpha",
                        user_function: str = "symbolic") -> dict[str, Any]:
    """The seed slider-crank (models.SLIDER_CRANK) in Exudyn, crank angle pi/4 + 4 pi t.

    Crank (r = 2 m) pinned to the ground at the origin, rod (l = 3.5 m) pinned to the crank's
    tip and to a slider on the x axis; rigid 2D bodies, JointRevolute2D, JointPrismatic2D and a
    CoordinateConstraint with a time-dependent offset on the crank's angle. Solved from 0 to t1
    in steps of ``step`` by exudyn.SolveDynamic with ``solver`` (a DynamicSolverType name:
    "GeneralizedAlpha", the default index-3 solver, or "TrapezoidalIndex2", Newmark on the
    velocity-level constraints); ``user_function`` is "symbolic" or "python" (see
    _add_angle_driver). A new model is built for every repeat, outside the timing.

    Returns:
        time: median wall time [s] of SolveDynamic over the repeats;
        times: every repeat's time [s];
        build_time: median time [s] of building and assembling the model;
        err_x, err_vx, err_ax: relative errors of the slider's x, vx, ax over all instants
            (max |value - exact| / max |exact|, exact = models.slider_crank_exact);
        instants: number of instants recorded (t = 0 included);
        newton_iterations: Newton iterations of the last solve.
    """
    r, l = models.SLIDER_CRANK["r"], models.SLIDER_CRANK["l"]
    omega, phi0 = models.SLIDER_CRANK["omega"], models.SLIDER_CRANK["phi0"]
    n_steps = int(round(t1 / step))
    ss = _settings(step, n_steps)
    times, build_times = [], []
    for _ in range(repeat):
        # keep: the symbolic functions, which must outlive the solve
        build_time, (container, sensors, keep) = _timed(
            lambda: _build_slider_crank(r, l, omega, phi0, user_function))
        mbs = container.GetSystem(0)
        elapsed, iterations = _timed(lambda: _solve(mbs, ss, solver))
        times.append(elapsed)
        build_times.append(build_time)
    data = {key: mbs.GetSensorStoredData(s) for key, s in sensors.items()}
    t = data["x"][:, 0]
    exact = models.slider_crank_exact(t, r, l, omega)
    result = {"time": statistics.median(times), "times": times,
              "build_time": statistics.median(build_times)}
    for (key, _), ex in zip(_KINEMATICS, exact):
        result[f"err_{key}"] = _relative_error(data[key][:, 1], ex)
    result.update(instants=len(t), newton_iterations=iterations)
    return result


# --------------------------------------------------------------------------------------------
# Exudyn: the row of parallelograms

def _build_chain(n_loops: int, user_function: str):
    """The Exudyn row of n_loops parallelograms, assembled at its closed form for t = 0:
    (system container, sensors, keep-alive list). Crank frames sit at their pivots and coupler
    frames at their left pins, as in models.chain_text, so the closed form reads directly."""
    exu = _exudyn()
    from exudyn.itemInterface import ObjectGround
    a, d = models.A_CRANK, models.D_PITCH
    th, w, _ = (float(v) for v in models.theta(np.array(0.0)))
    container = exu.SystemContainer()
    mbs = container.AddSystem()
    ground = mbs.AddObject(ObjectGround())
    cranks = [_add_rigid_body(mbs, np.array([i * d, 0.0, th]), np.array([0.0, 0.0, w]))
              for i in range(n_loops + 1)]
    couplers = [_add_rigid_body(mbs, np.array([i * d + a * math.cos(th), a * math.sin(th), 0.0]),
                                np.array([-a * math.sin(th) * w, a * math.cos(th) * w, 0.0]))
                for i in range(n_loops)]
    for i, (_, crank) in enumerate(cranks):
        _add_revolute(mbs, ground, (i * d, 0.0), crank, (0.0, 0.0))
    for i, (_, coupler) in enumerate(couplers):
        _add_revolute(mbs, cranks[i][1], (a, 0.0), coupler, (0.0, 0.0))
        _add_revolute(mbs, cranks[i + 1][1], (a, 0.0), coupler, (d, 0.0))
    # theta(t) - theta(0) = (pi/4) sin(2 pi t); the sine is math.sin for Python calls and
    # exudyn.symbolic.sin when the function is recorded symbolically
    sin, cos = ((exu.symbolic.sin, exu.symbolic.cos) if user_function == "symbolic"
                else (math.sin, math.cos))
    keep = _add_angle_driver(
        mbs, cranks[0][0],
        lambda mbs, t, i, off: math.pi / 4 * sin(2 * math.pi * t),
        lambda mbs, t, i, off: math.pi / 4 * 2 * math.pi * cos(2 * math.pi * t), user_function)
    sensors = _add_sensors(mbs, couplers[-1][0], _KINEMATICS)
    sensors.update(_add_sensors(mbs, cranks[-1][0], (("phi", "Rotation"),)))
    mbs.Assemble()
    return container, sensors, keep


def exudyn_chain(n_loops: int, steps: int = 10, step: float = 1e-2, repeat: int = 3,
                 sparse: bool = True, user_function: str = "symbolic") -> dict[str, Any]:
    """The row of n_loops parallelograms of models.py (2 n_loops + 1 bodies) in Exudyn.

    N + 1 cranks of length a = 0.5 pivoted at (i d, 0), N couplers pinned to the tips of cranks
    i and i + 1, crank 0's angle prescribed as models.theta(t); the bodies start assembled at
    the closed form for t = 0. ``steps`` steps of size ``step`` with Exudyn's default
    generalized-alpha solver, with the sparse linear solver (EigenSparse) if ``sparse``.

    Returns:
        time_per_step: median wall time [s] of SolveDynamic over the repeats, divided by steps;
        times: every repeat's solve time [s];
        build_time: median time [s] of building and assembling the model;
        err_x, err_vx, err_ax: relative errors of the last coupler's x, vx, ax (x shifted by
            its pivot (N - 1) d) against models.chain_exact;
        err_phi: relative error of the last crank's angle against models.theta;
        bodies: 2 n_loops + 1;
        newton_iterations: Newton iterations of the last solve.
    """
    ss = _settings(step, steps, sparse)
    times, build_times = [], []
    for _ in range(repeat):
        # keep: the symbolic functions, which must outlive the solve
        build_time, (container, sensors, keep) = _timed(
            lambda: _build_chain(n_loops, user_function))
        mbs = container.GetSystem(0)
        elapsed, iterations = _timed(lambda: _solve(mbs, ss, "GeneralizedAlpha"))
        times.append(elapsed)
        build_times.append(build_time)
    data = {key: mbs.GetSensorStoredData(s) for key, s in sensors.items()}
    t = data["x"][:, 0]
    exact = models.chain_exact(t)
    shift = (n_loops - 1) * models.D_PITCH
    result = {"time_per_step": statistics.median(times) / steps, "times": times,
              "build_time": statistics.median(build_times),
              "err_x": _relative_error(data["x"][:, 1] - shift, exact["x"]),
              "err_vx": _relative_error(data["vx"][:, 1], exact["vx"]),
              "err_ax": _relative_error(data["ax"][:, 1], exact["ax"]),
              "err_phi": _relative_error(data["phi"][:, -1], exact["phi"]),
              "bodies": 2 * n_loops + 1, "newton_iterations": iterations}
    return result


# --------------------------------------------------------------------------------------------
# numpy: per-instant Newton-Raphson in Haug's Cartesian coordinates

def _rot(phi: float) -> np.ndarray:
    """The planar rotation matrix A(phi)."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s], [s, c]])


_R90 = np.array([[0.0, -1.0], [1.0, 0.0]])  # dA/dphi = A R90


class _SliderCrank:
    """The slider-crank in Haug's Cartesian coordinates q = (x, y, phi) of crank, rod and
    slider, each frame at the body's centre: 9 equations, 3 revolute pairs (2 each), the
    prismatic pair to the ground's x axis (y3 = 0, phi3 = 0) and the driver phi1 = phi0 + w t.

    Each revolute pair is (body i, point s_i, body j, point s_j), body -1 the ground with s
    given in global coordinates: r_i + A_i s_i - r_j - A_j s_j = 0."""

    def __init__(self, r: float, l: float, omega: float, phi0: float) -> None:
        self.omega, self.phi0 = omega, phi0
        self.pairs = [(0, np.array([-r / 2, 0.0]), -1, np.zeros(2)),
                      (0, np.array([r / 2, 0.0]), 1, np.array([-l / 2, 0.0])),
                      (1, np.array([l / 2, 0.0]), 2, np.zeros(2))]

    @staticmethod
    def _point(q: np.ndarray, body: int, s: np.ndarray) -> np.ndarray:
        """Global position of point s of body (s itself for the ground)."""
        return s if body < 0 else q[3 * body:3 * body + 2] + _rot(q[3 * body + 2]) @ s

    def phi(self, q: np.ndarray, t: float) -> np.ndarray:
        """The constraint equations Phi(q, t)."""
        rows = [self._point(q, i, si) - self._point(q, j, sj) for i, si, j, sj in self.pairs]
        return np.concatenate(rows + [[q[7], q[8], q[2] - self.phi0 - self.omega * t]])

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Phi_q, 9 x 9."""
        jac = np.zeros((9, 9))
        for row, (i, si, j, sj) in enumerate(self.pairs):
            for body, s, sign in ((i, si, 1.0), (j, sj, -1.0)):
                if body >= 0:
                    jac[2 * row:2 * row + 2, 3 * body:3 * body + 2] = sign * np.eye(2)
                    jac[2 * row:2 * row + 2, 3 * body + 2] = sign * _rot(q[3 * body + 2]) @ _R90 @ s
        jac[6, 7] = jac[7, 8] = jac[8, 2] = 1.0
        return jac

    def nu(self) -> np.ndarray:
        """Right side of Phi_q qd = nu = -Phi_t."""
        return np.array([0.0] * 8 + [self.omega])

    def gamma(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Right side of Phi_q qdd = gamma: A_i s_i phid_i^2 - A_j s_j phid_j^2 for each
        revolute pair; zero for the prismatic pair and the (linear in t) driver."""
        rows = []
        for i, si, j, sj in self.pairs:
            row = np.zeros(2)
            for body, s, sign in ((i, si, 1.0), (j, sj, -1.0)):
                if body >= 0:
                    row += sign * _rot(q[3 * body + 2]) @ s * qd[3 * body + 2] ** 2
            rows.append(row)
        return np.concatenate(rows + [np.zeros(3)])


def _newton(system: _SliderCrank, q: np.ndarray, t: float, tol: float = 1e-12,
            max_iter: int = 20) -> np.ndarray:
    """Solve Phi(q, t) = 0 by Newton-Raphson from q, np.linalg.solve at each iteration."""
    for _ in range(max_iter):
        dq = np.linalg.solve(system.jacobian(q), -system.phi(q, t))
        q = q + dq
        if np.max(np.abs(dq)) < tol:
            return q
    raise RuntimeError(f"Newton-Raphson did not converge at t = {t}")


def _numpy_slider_crank_run(system: _SliderCrank, q0: np.ndarray,
                            t: np.ndarray) -> np.ndarray:
    """Positions, velocities and accelerations at every instant: an array (len(t), 3, 9)."""
    out = np.empty((len(t), 3, 9))
    q = q0
    for k, tk in enumerate(t):
        q = _newton(system, q, float(tk))       # the previous instant's solution as the start
        jac = system.jacobian(q)
        qd = np.linalg.solve(jac, system.nu())
        out[k] = q, qd, np.linalg.solve(jac, system.gamma(q, qd))
    return out


def numpy_baseline_slider_crank(step: float = 1e-3, t1: float = 1.0,
                                repeat: int = 5) -> dict[str, Any]:
    """The seed slider-crank by a hand-written per-instant Newton-Raphson in numpy.

    Haug's Cartesian coordinates (9 coordinates, 9 equations), the previous instant's
    solution as the start, np.linalg.solve at every iteration, then the velocity from
    Phi_q qd = nu and the acceleration from Phi_q qdd = gamma (exact gamma). The start at
    t = 0 is the rough guess of the bodies lying on the x axis, which Newton assembles.

    Returns:
        time: median wall time [s] of the whole run over the repeats;
        times: every repeat's time [s];
        err_x, err_vx, err_ax: relative errors of the slider's x, vx, ax against
            models.slider_crank_exact;
        instants: number of instants (t = 0 included).
    """
    r, l = models.SLIDER_CRANK["r"], models.SLIDER_CRANK["l"]
    omega, phi0 = models.SLIDER_CRANK["omega"], models.SLIDER_CRANK["phi0"]
    system = _SliderCrank(r, l, omega, phi0)
    t = np.linspace(0.0, t1, int(round(t1 / step)) + 1)
    # a rough, unassembled guess: each body on the x axis near where it belongs
    q0 = np.array([r / 2, 0.5, phi0, r + l / 2, 0.5, 0.0, r + l, 0.0, 0.0])
    times, out = [], None
    for _ in range(repeat):
        elapsed, out = _timed(lambda: _numpy_slider_crank_run(system, q0, t))
        times.append(elapsed)
    exact = models.slider_crank_exact(t, r, l, omega)
    result = {"time": statistics.median(times), "times": times}
    for level, ((key, _), ex) in enumerate(zip(_KINEMATICS, exact)):
        result[f"err_{key}"] = _relative_error(out[:, level, 6], ex)
    result["instants"] = len(t)
    return result


if __name__ == "__main__":
    try:
        print("import exudyn [s]:", import_time("exudyn"))
        print("exudyn slider-crank:", exudyn_slider_crank())
        print("exudyn slider-crank, TrapezoidalIndex2:",
              exudyn_slider_crank(solver="TrapezoidalIndex2"))
        for n in (50, 500):
            print(f"exudyn chain {n}:", exudyn_chain(n))
    except ImportError as exc:
        print("exudyn skipped:", exc)
    print("numpy slider-crank:", numpy_baseline_slider_crank())
