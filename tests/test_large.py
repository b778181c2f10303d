"""The lean march of a single large mechanism (mechdsl/solve/large.py): its predictor, its
answers against the closed form and the careful march, the instants it hands over, and an
interrupt in its middle."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import ROOT
from mechdsl.solve import SolverOptions, large, simulate

sys.path.insert(0, str(ROOT / "benchmarks"))
import models  # noqa: E402

SPARSE = SolverOptions(sparse_from=0)
N_LOOPS = 40  # 243 coordinates: the band LU applies


@pytest.fixture
def lean_instants(monkeypatch):
    """Count the instants the lean march settles."""
    count = {"n": 0}
    real = large.march_large

    def counted(run, k, end):
        out = real(run, k, end)
        count["n"] += out - k
        return out

    monkeypatch.setattr(large, "march_large", counted)
    return count


def _chain(loads, **kw):
    return loads(models.chain_text(N_LOOPS, **kw)).compile()


def test_extrapolation_is_exact_for_a_quintic():
    rng = np.random.default_rng(7)
    coef = rng.normal(size=6)

    def state(t):
        return (t, np.array([np.polyval(coef, t)]), np.array([np.polyval(np.polyder(coef), t)]),
                np.array([np.polyval(np.polyder(coef, 2), t)]))

    for t in (0.45, 0.6, 0.9):
        got = large._extrapolate(state(0.1), state(0.3), t)
        assert got[0] == pytest.approx(np.polyval(coef, t), abs=1e-12)


def test_lean_march_gives_the_closed_form(loads, lean_instants):
    system = _chain(loads, t1=0.5, step=0.01)
    res = simulate(system, SPARSE)
    assert res.ok, res.messages
    assert lean_instants["n"] >= 45  # of the 50 after t0: the lean march took (nearly) all
    ex = models.chain_exact(res["t"])
    last = f"coupler{N_LOOPS - 1}"
    assert np.abs(res[f"{last}.x"] - (N_LOOPS - 1) * models.D_PITCH - ex["x"]).max() < 1e-12
    assert np.abs(res[f"{last}.vx"] - ex["vx"]).max() < 1e-12
    assert np.abs(res[f"{last}.ax"] - ex["ax"]).max() < 1e-11
    assert np.abs(res[f"crank{N_LOOPS}.alpha"] - ex["alpha"]).max() < 1e-10
    assert res.residual < 1e-12


def test_lean_and_careful_marches_agree(loads, monkeypatch):
    system = _chain(loads, t1=0.3, step=0.01)
    lean = simulate(system, SPARSE)
    monkeypatch.setattr(large, "applies", lambda run: False)
    careful = simulate(system, SPARSE)
    assert lean.ok and careful.ok
    for name in lean.labels:
        np.testing.assert_allclose(lean[name], careful[name], rtol=1e-11, atol=1e-11,
                                   err_msg=name)
    # the condition numbers are estimated alike (Hager and Higham, on the same factors)
    assert lean.condition[0] == pytest.approx(careful.condition[0], rel=1e-6)


def test_a_singular_position_is_handed_over_and_reported_at_the_same_instant(loads,
                                                                              monkeypatch):
    text = models.chain_text(N_LOOPS, t1=0.5, step=0.01).replace(
        "pi/2 + pi/4*sin(2*pi*t)", "pi/2 - 2*pi*t")
    lean = simulate(loads(text).compile(), SPARSE)
    monkeypatch.setattr(large, "applies", lambda run: False)
    careful = simulate(loads(text).compile(), SPARSE)
    assert lean.status == careful.status == "failed"
    assert lean.n_solved[0] == careful.n_solved[0]
    assert lean.messages[0].split(" t = ")[0] == careful.messages[0].split(" t = ")[0]
    k = lean.n_solved[0]
    last = f"coupler{N_LOOPS - 1}.x"
    np.testing.assert_allclose(lean[last][:k], careful[last][:k], atol=1e-12)


def test_an_interrupt_keeps_every_instant_recorded_complete(loads, monkeypatch):
    system = _chain(loads, t1=1.0, step=0.01)
    calls = {"n": 0}
    fused = type(system.fused)
    real = fused.evaluate_gamma

    def interrupting(self, q, qd):
        calls["n"] += 1
        if calls["n"] == 50:
            raise KeyboardInterrupt
        return real(self, q, qd)

    monkeypatch.setattr(fused, "evaluate_gamma", interrupting)
    res = simulate(system, SPARSE)
    assert res.status == "interrupted"
    k = res.n_solved[0]
    assert 40 <= k <= 52  # the block in hand when the interrupt came was recorded
    ex = models.chain_exact(res["t"][:k])
    assert np.abs(res[f"crank{N_LOOPS}.alpha"][:k] - ex["alpha"]).max() < 1e-10
    assert np.isnan(res[f"crank{N_LOOPS}.alpha"][k:]).all()


def test_noise_options_are_checked_and_strict_ones_still_give_the_closed_form(loads):
    for bad in (0.5, 1000.0):
        with pytest.raises(ValueError, match="noise_scatter"):
            SolverOptions(noise_scatter=bad)
    for bad in (-1.0, 1e-5):
        with pytest.raises(ValueError, match="noise_floor"):
            SolverOptions(noise_floor=bad)
    # the strictest checks hand more instants (noise_floor 0: every stall) to the careful
    # march: the same answers
    for strict in (SolverOptions(sparse_from=0, noise_scatter=1.0),
                   SolverOptions(sparse_from=0, noise_floor=0.0)):
        res = simulate(_chain(loads, t1=0.3, step=0.01), strict)
        assert res.ok
        ex = models.chain_exact(res["t"])
        assert np.abs(res[f"crank{N_LOOPS}.alpha"] - ex["alpha"]).max() < 1e-10
