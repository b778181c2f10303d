"""The figure of docs/images/coupler_synthesis.png: the objective of
examples/coupler_synthesis.mech over a 41 x 41 grid of its ranges (the brute-force sweep,
one batch of 1681 variants), the grid's best point, and the optimum mechdsl optimize finds;
beside it, the coupler curves of both through the five targets.

    .venv/bin/python examples/coupler_synthesis_figure.py [OUT.png]
"""

import sys
from pathlib import Path

import numpy as np

import mechdsl
from mechdsl.compiled.variants import Overrides
from mechdsl.outputs.plot import new_figure, save_figure
from mechdsl.study.optimize import Evaluator, bounds_of, optimize

HERE = Path(__file__).resolve().parent
N = 41


def main(out: str) -> None:
    mech = mechdsl.load(HERE / "coupler_synthesis.mech")
    (c0, c1), (h0, h1) = bounds_of(mech, Overrides())
    cs, hs = np.linspace(c0, c1, N), np.linspace(h0, h1, N)
    grid = np.stack([g.ravel() for g in np.meshgrid(cs, hs, indexing="ij")], axis=-1)
    values = Evaluator(mech, Overrides(), None, None, None)(grid)[:, 0].reshape(N, N)
    k = np.unravel_index(np.argmin(values), values.shape)
    brute = (cs[k[0]], hs[k[1]], values[k])
    best = optimize(mech, run=False)
    fig = new_figure(figsize=(11, 4.6), layout="constrained")
    left, right = fig.subplots(1, 2)
    filled = left.contourf(cs, hs, np.log10(values.T), levels=25, cmap="viridis")
    fig.colorbar(filled, ax=left, label="log10 of the objective [m^2]")
    left.plot(*brute[:2], "s", mfc="none", mec="w", ms=10,
              label=f"best of the {N}x{N} grid: {brute[2]:.2g}")
    left.plot(best.params["c"], best.params["h"], "r+", ms=14, mew=2,
              label=f"mechdsl optimize: {best.objective:.2g}")
    left.set_xlabel("rocker length c [m]")
    left.set_ylabel("coupler point height h [m]")
    left.legend(loc="lower left", fontsize="small")
    for (c, h), style, label in (((brute[0], brute[1]), "--", "grid's best"),
                                 ((best.params["c"], best.params["h"]), "-", "optimum")):
        res = mech.simulate(c=c, h=h)
        right.plot(res["coupler.P.x"], res["coupler.P.y"], style, lw=1.6,
                   label=f"{label}: c = {c:.4f}, h = {h:.4f}")
    ground = {p.name: p for p in mech.model.ground.points}
    targets = np.array([[float(e.value) for e in ground[f"T{i}"].coords.items]
                        for i in range(1, 6)])
    right.plot(*targets.T, "ko", ms=6, label="targets")
    right.set_aspect("equal")
    right.set_xlabel("x [m]")
    right.set_ylabel("y [m]")
    right.legend(fontsize="small", loc="lower right")
    right.grid(True, alpha=0.3)
    fig.suptitle(f"coupler_synthesis.mech: brute force ({N * N} variants) and mechdsl "
                 f"optimize ({best.variants} variants in {best.sweeps} sweeps)")
    save_figure(fig, out)
    print(f"grid best c = {brute[0]!r}, h = {brute[1]!r}, objective {brute[2]!r}")
    print(f"optimum   c = {best.params['c']!r}, h = {best.params['h']!r}, "
          f"objective {best.objective!r}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else str(HERE.parent / "docs" / "images"
                                                    / "coupler_synthesis.png"))
