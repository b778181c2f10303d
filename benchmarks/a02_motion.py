"""The augmented-Lagrangian equations of motion (mechdsl.solve.motion) on IFToMM A02 and on
chains of links: does the formulation pass the N-four-bar's singular positions, how
accurate is it, and how does one evaluation's cost grow with the number of bodies?

    python benchmarks/a02_motion.py            # A02 (N = 40, 20 s) and the chain timings
    python benchmarks/a02_motion.py --quick    # A02 over 2 s, fewer chain sizes

A02 (the IFToMM library's N-four-bar; the facts in shared/reference/dynamics-benchmarks.md):
N + 1 rockers hinged at (k, 0), N couplers joining their tips, every link 1 m, 1 kg,
I = 1/12 kg m^2, gravity -9.81 m/s^2; at t = 0 the rockers stand vertical and turn at
-1 rad/s. Integrated by scipy's DOP853 (rtol 1e-10) on Motion.rhs, with Motion.project
at every output instant (0.01 s), as a driver would. The reference for B0 (the tip of the
first rocker) at t = 20 is the parallelogram branch's one-degree-of-freedom equation
theta'' = -(K / I_eff) cos theta, K = m g L ((N + 1)/2 + N), I_eff = m L^2 ((N + 1)/3 + N),
integrated here at rtol 1e-13 (it reproduces the reference file's table).

The chain: N links of 1 m and 1 kg hinged end to end, the first to the ground, released
horizontal; the cost of one evaluation of Motion.rhs (the minimum over repeated batches of
thread CPU time: the machine is shared) for N = 50 .. 400.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(__file__))

import mechdsl  # noqa: E402
from dynamics_models import a02_text, chain_text  # noqa: E402 - the benchmarks' models
from mechdsl.solve.motion import Motion  # noqa: E402

#: B0 at t = 20 on the parallelogram branch (shared/reference/dynamics-benchmarks.md)
B0_REFERENCE = np.array([0.410901153734, 0.911679900985])


def a02_state(N: int, theta: float, rate: float) -> np.ndarray:
    """(q, qd) on the parallelogram branch of :func:`dynamics_models.a02_text`'s model
    (rocker frames at their pivots, coupler frames at their left ends): every rocker at
    angle theta turning at rate, every coupler translating with the rockers' tips."""
    c, s = np.cos(theta), np.sin(theta)
    q, qd = [], []
    for k in range(N + 1):
        q += [float(k), 0.0, theta]
        qd += [0.0, 0.0, rate]
    for k in range(N):
        q += [k + c, s, 0.0]
        qd += [-s * rate, c * rate, 0.0]
    return np.array(q + qd)


def branch_reference(N: int, t: float) -> np.ndarray:
    """B0 at t on the parallelogram branch (DOP853, rtol 1e-13)."""
    from scipy.integrate import solve_ivp

    ratio = 9.81 * ((N + 1) / 2 + N) / ((N + 1) / 3 + N)
    sol = solve_ivp(lambda _, y: [y[1], -ratio * np.cos(y[0])], (0, t), [np.pi / 2, -1.0],
                    method="DOP853", rtol=1e-13, atol=1e-13)
    th = sol.y[0, -1]
    return np.array([np.cos(th), np.sin(th)])


def run_a02(N: int = 40, t_end: float = 20.0, rtol: float = 1e-10, atol: float = 1e-12,
            every: float = 0.01) -> dict:
    """A02 by DOP853 on Motion.rhs with Motion.project at every output instant."""
    from scipy.integrate import DOP853

    start = time.perf_counter()
    kernels = mechdsl.loads(a02_text(N, t_end), "a02.mech").compile()
    motion = Motion(kernels)
    set_up = time.perf_counter() - start
    n = kernels.system.n
    calls = [0]

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        calls[0] += 1
        return motion.rhs(t, y)

    y = motion.project(0.0, a02_state(N, np.pi / 2, -1.0))
    t, h = 0.0, None
    outputs = int(round(t_end / every))
    steps = 0
    horizontal = 0  # the rockers' passages through the horizontal (phi = k pi)
    last = np.floor(y[2] / np.pi)
    b0 = []
    start, cpu = time.perf_counter(), time.process_time()
    for k in range(1, outputs + 1):
        t1 = k * every
        solver = DOP853(rhs, t, y, t1, rtol=rtol, atol=atol,
                        first_step=None if h is None else min(h, t1 - t))
        taken = []
        while solver.status == "running":
            msg = solver.step()
            steps += 1
            if msg is not None:
                raise RuntimeError(f"DOP853 stopped at t = {solver.t}: {msg}")
            taken.append(solver.step_size)
        # the last step is cut at the output instant: the next segment starts with the
        # step the controller proposes (h_abs), or the largest taken where that was cut
        h = max([solver.h_abs] + taken[:-1])
        y = motion.project(t1, solver.y)
        t = t1
        phi = y[2]
        horizontal += int(abs(np.floor(phi / np.pi) - last))
        last = np.floor(phi / np.pi)
        b0.append((t, y[0] + np.cos(phi), y[1] + np.sin(phi)))  # rocker 0's tip
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    b0 = np.array(b0)
    ref = B0_REFERENCE if (N == 40 and t_end == 20.0) else branch_reference(N, t_end)
    phi_res, jac = motion.phi_jac(t, y[:n])
    return {"N": N, "t_end": t_end, "rtol": rtol, "time_s": elapsed, "cpu_s": cpu,
            "set_up_s": set_up,
            "rhs_calls": calls[0], "steps": steps, "passages": horizontal,
            "B0": b0[-1, 1:], "B0_error": float(np.hypot(*(b0[-1, 1:] - ref))),
            "phi_end": float(np.abs(phi_res).max()),
            "velocity_residual_end": float(np.abs(jac @ y[n:]).max())}


def cpu_time_per_call(f, reps: int = 20, batch: float = 5e-3) -> float:
    """The minimum over ``reps`` batches of the thread CPU time per call of f()."""
    f()
    t = time.thread_time()
    f()
    k = max(1, int(batch / max(time.thread_time() - t, 1e-6)))
    best = np.inf
    for _ in range(reps):
        t = time.thread_time()
        for _ in range(k):
            f()
        best = min(best, (time.thread_time() - t) / k)
    return best


def chain_costs(sizes=(50, 100, 200, 400)) -> list[dict]:
    """One evaluation of Motion.rhs (and its parts) for chains of N links."""
    rows = []
    for N in sizes:
        kernels = mechdsl.loads(chain_text(N), "chain.mech").compile()
        motion = Motion(kernels)
        rng = np.random.default_rng(0)
        q = kernels.system.guess[0] + 1e-3 * rng.normal(size=kernels.system.n)
        y = motion.project(0.0, np.concatenate((q, rng.normal(size=kernels.system.n))))
        q, qd = y[:kernels.system.n], y[kernels.system.n:]
        entries, load, gamma = motion._terms(0.0, q, qd)
        fac = motion.factor(entries)
        rows.append({"N": N, "n": kernels.system.n, "kd": motion.plan.kd,
                     "rhs_us": 1e6 * cpu_time_per_call(lambda: motion.rhs(0.0, y)),
                     "terms_us": 1e6 * cpu_time_per_call(lambda: motion._terms(0.0, q, qd)),
                     "factor_us": 1e6 * cpu_time_per_call(lambda: motion.factor(entries)),
                     "saddle_us": 1e6 * cpu_time_per_call(
                         lambda: motion.saddle(fac, load, gamma)),
                     "iterations": motion.saddle(fac, load, gamma)[2]})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-a02", action="store_true")
    args = ap.parse_args()
    sizes = (50, 100, 200) if args.quick else (50, 100, 200, 400)
    print("chain of N links: one evaluation of Motion.rhs (thread CPU time, us)")
    for r in chain_costs(sizes):
        print(f"  N {r['N']:4d}  n {r['n']:5d}  band {r['kd']:3d}  rhs {r['rhs_us']:8.1f}  "
              f"(terms {r['terms_us']:7.1f}, factor {r['factor_us']:7.1f}, "
              f"iteration {r['saddle_us']:7.1f}: {r['iterations']} solves)")
    if args.no_a02:
        return
    res = run_a02(t_end=2.0 if args.quick else 20.0)
    print(f"A02 N = {res['N']}, {res['t_end']} s, DOP853 rtol {res['rtol']:g}: "
          f"{res['time_s']:.2f} s wall, {res['cpu_s']:.2f} s CPU (+ {res['set_up_s']:.2f} s "
          f"set-up), {res['steps']} steps, "
          f"{res['rhs_calls']} evaluations, {res['passages']} passages through the "
          f"horizontal; B0 = ({res['B0'][0]:.12f}, {res['B0'][1]:.12f}), error "
          f"{res['B0_error']:.3g} m; |Phi| {res['phi_end']:.2g}, |Phi_q qd| "
          f"{res['velocity_residual_end']:.2g} at the end")


if __name__ == "__main__":
    main()
