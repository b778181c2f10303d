"""Does integrating the variants of a sweep together pay? One evaluation of the index-1
equations of motion for V variants of Andrews' mechanism at once (numpy's array kernels on
(V, 1, n) and a batched LAPACK solve of the V augmented systems), against one variant on the
one-state float kernels the forward dynamics runs (docs/dynamics.md, "Sweeps").

    OMP_NUM_THREADS=1 python benchmarks/batched_eval.py
"""
import time, numpy as np, mechdsl
from mechdsl.compiled import equations as eq
from mechdsl.solve.dynamic import DynamicRun, _Evaluator
m = mechdsl.load("examples/andrews.mech")
for V in (1, 50, 1000):
    from mechdsl.compiled.variants import Overrides
    sysm = m.compile(Overrides(sweeps={"m1": list(np.linspace(0.04, 0.05, V))})) if V > 1 else m.compile()
    n, mm = sysm.n, sysm.m; big = n + mm; d = sysm.dynamics
    q = np.broadcast_to(sysm.guess.reshape(V, -1)[:, :n], (V, n)).copy(); qd = np.zeros((V, n))
    Q3, Qd3, T2 = q[:, None, :], qd[:, None, :], np.zeros((V, 1))
    def batched():
        with np.errstate(all="ignore"):
            jac = eq.jacobian(sysm, Q3)[:, 0]; gamma = eq.acceleration_rhs(sysm, Q3, Qd3, T2)[:, 0]
            mass = d.mass_matrix(Q3)[:, 0]; load = d.generalised_forces(Q3, Qd3, T2)[:, 0]
        a = np.zeros((V, big, big)); a[:, :n, :n] = mass; a[:, :n, n:] = np.swapaxes(jac, 1, 2); a[:, n:, :n] = jac
        return np.linalg.solve(a, np.concatenate((load, gamma), axis=1)[..., None])
    batched()
    t = time.perf_counter()
    for _ in range(20): batched()
    tb = (time.perf_counter() - t) / 20
    from mechdsl.solve.dynamic import _one
    one = _one(sysm, 0)
    ev = _Evaluator(one, np.ones(n))
    y = np.concatenate((q[0], qd[0])); ev.derivative(0.0, y)
    t = time.perf_counter()
    for _ in range(200): ev.derivative(0.0, y)
    ts = (time.perf_counter() - t) / 200
    print(f"V={V}: batched numpy {tb*1e3:.3f} ms ({tb/V*1e6:.1f} us/variant); one variant on floats {ts*1e6:.1f} us")
