"""Every example solved by the fast paths and by the general ones gives the same answers: the
one-state float code (assembly, coarse march, first instant), the batched settle of the
parallel-in-time march, and the lean march of a large mechanism, each switched off in turn
(the general path handles every case; the fast ones must not change a digit that matters)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import EXAMPLES, ROOT
from mechdsl.solve import SolverOptions, batch, large, simulate

sys.path.insert(0, str(ROOT / "benchmarks"))
import models  # noqa: E402

KINEMATIC = sorted(p.name for p in EXAMPLES.glob("*.mech")
                   if p.name not in ("andrews.mech", "coupler_synthesis.mech"))


def _compare(a, b, what: str) -> None:
    assert a.status == b.status, what
    assert list(a.n_solved) == list(b.n_solved), what
    for name in a.labels:
        x, y = np.asarray(a[name], float), np.asarray(b[name], float)
        scale = max(1.0, float(np.nanmax(np.abs(y))) if np.isfinite(y).any() else 1.0)
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-11 * scale, equal_nan=True,
                                   err_msg=f"{what}: {name}")


@pytest.mark.parametrize("example", KINEMATIC)
def test_float_code_and_batched_settle_change_no_answer(load_example, example, monkeypatch):
    mech = load_example(example)
    fast = mech.simulate(options=SolverOptions(backend="numpy"))
    kernels = mech.compile()
    kernels.__dict__["one_state"] = None  # (a cached property: the batched code throughout)
    monkeypatch.setattr(batch, "applies", lambda system, states: False)
    general = simulate(kernels, SolverOptions(backend="numpy"))
    _compare(fast, general, example)


def test_lean_march_changes_no_answer(loads, monkeypatch):
    text = models.chain_text(60, t1=0.6, step=0.01)
    opts = SolverOptions(sparse_from=0)
    fast = simulate(loads(text).compile(), opts)
    monkeypatch.setattr(large, "applies", lambda run: False)
    general = simulate(loads(text).compile(), opts)
    _compare(fast, general, "row of 60 parallelograms")
