"""Long runs: no drift of the error over many crank revolutions."""

import numpy as np
import pytest

from closed_forms import slider_crank


def drift(mech, revolutions, per_revolution):
    res = mech.simulate(span=(0, 0.5 * revolutions), step=0.5 / per_revolution)
    assert res.ok and len(res["t"]) == revolutions * per_revolution + 1
    t = res["t"][:-1]
    out = {}
    for name, k in (("slider.x", 0), ("slider.vx", 1), ("slider.ax", 2)):
        exact = slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * t, 4 * np.pi, 0.0)[k]
        err = np.abs(res[name][:-1] - exact).reshape(revolutions, per_revolution).max(axis=1)
        out[name] = (err[0], err[-1], err.max() / np.abs(exact).max())
    return out


def test_a_hundred_revolutions_do_not_drift(load_example):
    for name, (first, last, worst) in drift(load_example("slider_crank.mech"), 100, 100).items():
        assert last <= 10 * max(first, 1e-15), name
        assert worst < 1e-14, name


@pytest.mark.long
def test_a_million_instants_do_not_drift(load_example):
    for name, (first, last, worst) in drift(load_example("slider_crank.mech"), 1000, 1000).items():
        assert last <= 10 * max(first, 1e-15), name
        assert worst < 1e-14, name
