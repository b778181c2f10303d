"""Andrews' squeezing mechanism for the benchmark suite: the reference, and the two peers
mechdsl's forward dynamics is measured against (../shared/reference/andrews.md has the
equations, parameters, consistent initial values and the reference solution).

* scipy: the published index-1 formulation in the seven mixed angles, y = (q, qd),
  [M G^T; G 0][qdd; lambda] = [f; gamma], integrated by ``scipy.integrate.solve_ivp``
  (DOP853 or Radau) without projection: the plain baseline;
* Exudyn: the same mechanism as seven rigid 2D bodies with ten revolute joints, the spring
  and the torque, solved by its implicit generalised-alpha integrator with fixed steps.
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np

#: The Test Set's reference at t = 0.03 (PSIDE at 1e-14): beta, Theta, gamma, Phi, delta,
#: Omega, epsilon
REF_Q = np.array([0.1581077119629904e+2, -0.1575637105984298e+2, 0.4082224013073101e-1,
                  -0.5347301163226948e+0, 0.5244099658805304e+0, 0.5347301163226948e+0,
                  0.1048080741042263e+1])
Q0 = np.array([-0.0617138900142764496358948458001, 0.0, 0.455279819163070380255912382449,
               0.222668390165885884674473185609, 0.487364979543842550225598953530,
               -0.222668390165885884674473185609, 1.23054744454982119249735015568])
P = dict(m1=.04325, m2=.00365, m3=.02373, m4=.00706, m5=.07050, m6=.00706, m7=.05498,
         xa=-.06934, ya=-.00227, xb=-.03635, yb=.03273, xc=.014, yc=.072, c0=4530.,
         i1=2.194e-6, i2=4.410e-7, i3=5.255e-6, i4=5.667e-7, i5=1.169e-5, i6=5.667e-7,
         i7=1.912e-5, d=28e-3, da=115e-4, e=2e-2, ea=1421e-5, rr=7e-3, ra=92e-5, l0=7785e-5,
         ss=35e-3, sa=1874e-5, sb=1043e-5, sc=18e-3, sd=2e-2, ta=2308e-5, tb=916e-5,
         u=4e-2, ua=1228e-5, ub=449e-5, zf=2e-2, zt=4e-2, fa=1421e-5, mom=33e-3)


def relative_error(q: np.ndarray) -> float:
    """max_i |q_i - REF_i| / |REF_i| over the seven angles at t = 0.03."""
    return float(np.max(np.abs(q - REF_Q) / np.abs(REF_Q)))


# -- the published formulation ------------------------------------------------------------------

def _rhs(t: float, y: np.ndarray) -> np.ndarray:
    """The index-1 right-hand side of the Test Set's andrews problem (its Fortran, rewritten):
    M qdd + G^T lambda = f, G qdd = gamma with gamma = -(G qd)_q qd."""
    p = P
    q, qd = y[:7], y[7:]
    s1, c1 = math.sin(q[0]), math.cos(q[0])
    s2, c2 = math.sin(q[1]), math.cos(q[1])
    s3, c3 = math.sin(q[2]), math.cos(q[2])
    s4, c4 = math.sin(q[3]), math.cos(q[3])
    s5, c5 = math.sin(q[4]), math.cos(q[4])
    s6, c6 = math.sin(q[5]), math.cos(q[5])
    s7, c7 = math.sin(q[6]), math.cos(q[6])
    sibe, cobe = math.sin(q[0] + q[1]), math.cos(q[0] + q[1])
    siph, coph = math.sin(q[3] + q[4]), math.cos(q[3] + q[4])
    siom, coom = math.sin(q[5] + q[6]), math.cos(q[5] + q[6])
    rr, d, da, e, ea, zt, zf, fa, u = (p[k] for k in ("rr", "d", "da", "e", "ea", "zt",
                                                       "zf", "fa", "u"))
    m = np.zeros((7, 7))
    m[0, 0] = p["m1"] * p["ra"]**2 + p["m2"] * (rr**2 - 2 * da * rr * c2 + da**2) + p["i1"] \
        + p["i2"]
    m[1, 0] = m[0, 1] = p["m2"] * (da**2 - da * rr * c2) + p["i2"]
    m[1, 1] = p["m2"] * da**2 + p["i2"]
    m[2, 2] = p["m3"] * (p["sa"]**2 + p["sb"]**2) + p["i3"]
    m[3, 3] = p["m4"] * (e - ea)**2 + p["i4"]
    m[4, 3] = m[3, 4] = p["m4"] * ((e - ea)**2 + zt * (e - ea) * s4) + p["i4"]
    m[4, 4] = p["m4"] * (zt**2 + 2 * zt * (e - ea) * s4 + (e - ea)**2) \
        + p["m5"] * (p["ta"]**2 + p["tb"]**2) + p["i4"] + p["i5"]
    m[5, 5] = p["m6"] * (zf - fa)**2 + p["i6"]
    m[6, 5] = m[5, 6] = p["m6"] * ((zf - fa)**2 - u * (zf - fa) * s6) + p["i6"]
    m[6, 6] = p["m6"] * ((zf - fa)**2 - 2 * u * (zf - fa) * s6 + u**2) \
        + p["m7"] * (p["ua"]**2 + p["ub"]**2) + p["i6"] + p["i7"]
    xd = p["sd"] * c3 + p["sc"] * s3 + p["xb"]
    yd = p["sd"] * s3 - p["sc"] * c3 + p["yb"]
    lang = math.hypot(xd - p["xc"], yd - p["yc"])
    force = -p["c0"] * (lang - p["l0"]) / lang
    fx, fy = force * (xd - p["xc"]), force * (yd - p["yc"])
    f = np.array([
        p["mom"] - p["m2"] * da * rr * qd[1] * (qd[1] + 2 * qd[0]) * s2,
        p["m2"] * da * rr * qd[0]**2 * s2,
        fx * (p["sc"] * c3 - p["sd"] * s3) + fy * (p["sd"] * c3 + p["sc"] * s3),
        p["m4"] * zt * (e - ea) * qd[4]**2 * c4,
        -p["m4"] * zt * (e - ea) * qd[3] * (qd[3] + 2 * qd[4]) * c4,
        -p["m6"] * u * (zf - fa) * qd[6]**2 * c6,
        p["m6"] * u * (zf - fa) * qd[5] * (qd[5] + 2 * qd[6]) * c6])
    g = np.zeros((6, 7))
    g[0, 0] = -rr * s1 + d * sibe
    g[0, 1] = d * sibe
    g[0, 2] = -p["ss"] * c3
    g[1, 0] = rr * c1 - d * cobe
    g[1, 1] = -d * cobe
    g[1, 2] = -p["ss"] * s3
    g[2, 0] = -rr * s1 + d * sibe
    g[2, 1] = d * sibe
    g[2, 3] = -e * coph
    g[2, 4] = -e * coph + zt * s5
    g[3, 0] = rr * c1 - d * cobe
    g[3, 1] = -d * cobe
    g[3, 3] = -e * siph
    g[3, 4] = -e * siph - zt * c5
    g[4, 0] = -rr * s1 + d * sibe
    g[4, 1] = d * sibe
    g[4, 5] = zf * siom
    g[4, 6] = zf * siom - u * c7
    g[5, 0] = rr * c1 - d * cobe
    g[5, 1] = -d * cobe
    g[5, 5] = -zf * coom
    g[5, 6] = -zf * coom - u * s7
    # gamma = -(G qd)_q qd: each term c * trig(angle) of g gives c * trig(angle) * angle'^2
    w1, w12, w3 = qd[0], qd[0] + qd[1], qd[2]
    w45, w5, w67, w7 = qd[3] + qd[4], qd[4], qd[5] + qd[6], qd[6]
    gam = np.array([
        rr * c1 * w1**2 - d * cobe * w12**2 - p["ss"] * s3 * w3**2,
        rr * s1 * w1**2 - d * sibe * w12**2 + p["ss"] * c3 * w3**2,
        rr * c1 * w1**2 - d * cobe * w12**2 - e * siph * w45**2 - zt * c5 * w5**2,
        rr * s1 * w1**2 - d * sibe * w12**2 + e * coph * w45**2 - zt * s5 * w5**2,
        rr * c1 * w1**2 - d * cobe * w12**2 - zf * coom * w67**2 - u * s7 * w7**2,
        rr * s1 * w1**2 - d * sibe * w12**2 - zf * siom * w67**2 + u * c7 * w7**2])
    a = np.zeros((13, 13))
    a[:7, :7], a[:7, 7:], a[7:, :7] = m, g.T, g
    sol = np.linalg.solve(a, np.concatenate((f, gam)))
    return np.concatenate((qd, sol[:7]))


def scipy_andrews(rtol: float, method: str = "DOP853", repeat: int = 3) -> dict:
    """The published index-1 form by solve_ivp: median time [s], relative error of the
    angles at t = 0.03, evaluations."""
    from scipy.integrate import solve_ivp

    y0 = np.concatenate((Q0, np.zeros(7)))
    times, sol = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        sol = solve_ivp(_rhs, (0.0, 0.03), y0, method=method, rtol=rtol, atol=rtol * 1e-2,
                        t_eval=[0.03])
        times.append(time.perf_counter() - start)
    return {"time": statistics.median(times), "err": relative_error(sol.y[:7, -1]),
            "nfev": int(sol.nfev)}


# -- Exudyn ----------------------------------------------------------------------------------------

#: The bodies in Cartesian form (andrews.md, section 6): frame origin at t = 0 (a pin),
#: angle at t = 0, centre of mass in the body frame, mass and inertia keys
_BODIES = [
    ((0.0, 0.0), -0.0617138900142764496, (P["ra"], 0.0), "m1", "i1"),
    ((0.006986674115, -0.000431723065), -0.0617138900142764496, (-P["da"], 0.0), "m2", "i2"),
    ((P["xb"], P["yb"]), 0.455279819163070380, (P["sb"], -P["sa"]), "m3", "i3"),
    ((-0.033997203886, 0.016461971675), 0.710033369709728435, (0.0, -(P["e"] - P["ea"])),
     "m4", "i4"),
    ((P["xa"], P["ya"]), 0.487364979543842550, (P["ta"], P["tb"]), "m5", "i5"),
    ((-0.031633134507, -0.015618868668), 1.007879054383935308, (P["zf"] - P["fa"], 0.0),
     "m6", "i6"),
    ((P["xa"], P["ya"]), 1.230547444549821192, (-P["ub"], -P["ua"]), "m7", "i7"),
]
#: The joints: (body, point in its frame) pairs, body -1 the ground
_JOINTS = [((-1, (0.0, 0.0)), (0, (0.0, 0.0))), ((0, (P["rr"], 0.0)), (1, (0.0, 0.0))),
           ((1, (-P["d"], 0.0)), (2, (0.0, -P["ss"]))), ((1, (-P["d"], 0.0)), (3, (0.0, -P["e"]))),
           ((1, (-P["d"], 0.0)), (5, (P["zf"], 0.0))), ((-1, (P["xb"], P["yb"])), (2, (0.0, 0.0))),
           ((3, (0.0, 0.0)), (4, (P["zt"], 0.0))), ((-1, (P["xa"], P["ya"])), (4, (0.0, 0.0))),
           ((5, (0.0, 0.0)), (6, (0.0, -P["u"]))), ((-1, (P["xa"], P["ya"])), (6, (0.0, 0.0)))]


def _build_exudyn():
    """Exudyn's model: each body's node at its centre of mass (what ObjectRigidBody2D takes),
    markers at the pins relative to it; sensors on the seven angles."""
    import exudyn as exu
    from exudyn.itemInterface import (
        LoadTorqueVector, MarkerBodyPosition, MarkerBodyRigid, NodeRigidBody2D, ObjectConnectorSpringDamper,
        ObjectGround, ObjectJointRevolute2D, ObjectRigidBody2D, SensorNode,
    )

    container = exu.SystemContainer()
    mbs = container.AddSystem()
    ground = mbs.AddObject(ObjectGround())
    bodies, nodes, coms = [], [], []
    for (ox, oy), phi, (cx, cy), mk, ik in _BODIES:
        c, s = math.cos(phi), math.sin(phi)
        com = (ox + c * cx - s * cy, oy + s * cx + c * cy)
        node = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[com[0], com[1], phi],
                                           initialVelocities=[0.0, 0.0, 0.0]))
        bodies.append(mbs.AddObject(ObjectRigidBody2D(nodeNumber=node, mass=P[mk],
                                                      inertia=P[ik])))
        nodes.append(node)
        coms.append((cx, cy))

    def marker(body: int, point):
        if body < 0:
            return mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground,
                                                    localPosition=[point[0], point[1], 0.0]))
        cx, cy = coms[body]
        return mbs.AddMarker(MarkerBodyPosition(
            bodyNumber=bodies[body], localPosition=[point[0] - cx, point[1] - cy, 0.0]))

    for a, b in _JOINTS:
        mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[marker(*a), marker(*b)]))
    mbs.AddObject(ObjectConnectorSpringDamper(
        markerNumbers=[marker(2, (P["sd"], -P["sc"])), marker(-1, (P["xc"], P["yc"]))],
        stiffness=P["c0"], damping=0.0, referenceLength=P["l0"]))
    crank = mbs.AddMarker(MarkerBodyRigid(bodyNumber=bodies[0], localPosition=[0.0, 0.0, 0.0]))
    mbs.AddLoad(LoadTorqueVector(markerNumber=crank, loadVector=[0.0, 0.0, P["mom"]]))
    sensors = [mbs.AddSensor(SensorNode(nodeNumber=n, storeInternal=True, writeToFile=False,
                                        outputVariableType=exu.OutputVariableType.Rotation))
               for n in nodes]
    mbs.Assemble()
    return container, mbs, sensors


def exudyn_andrews(h: float, repeat: int = 3) -> dict:
    """Exudyn's generalised-alpha (spectral radius 1, no numerical damping) with steps h:
    median solve time [s], relative error of the angles at t = 0.03."""
    import exudyn as exu

    steps = int(round(0.03 / h))
    times, angles = [], None
    for _ in range(repeat):
        container, mbs, sensors = _build_exudyn()
        ss = exu.SimulationSettings()
        ss.timeIntegration.endTime = 0.03
        ss.timeIntegration.numberOfSteps = steps
        ss.timeIntegration.verboseMode = 0
        ss.timeIntegration.generalizedAlpha.spectralRadius = 1.0
        ss.timeIntegration.newton.relativeTolerance = 1e-12
        ss.timeIntegration.newton.absoluteTolerance = 1e-14
        ss.solution.file.write = False
        ss.solution.sensors.writePeriod = 0.03
        start = time.perf_counter()
        exu.SolveDynamic(mbs, ss)
        times.append(time.perf_counter() - start)
        phi = np.array([mbs.GetSensorValues(s)[-1] for s in sensors])
        angles = np.array([phi[0], phi[1] - phi[0], phi[2], phi[3] - phi[4], phi[4],
                           phi[5] - phi[6], phi[6]])
    return {"time": statistics.median(times), "err": relative_error(angles), "steps": steps}


if __name__ == "__main__":
    for rtol in (1e-6, 1e-8, 1e-10):
        print("scipy DOP853", rtol, scipy_andrews(rtol))
    for rtol in (1e-6, 1e-8):
        print("scipy Radau", rtol, scipy_andrews(rtol, "Radau", repeat=1))
    for h in (1e-4, 3e-5, 1e-5, 3e-6):
        print("exudyn", h, exudyn_andrews(h, repeat=1))
