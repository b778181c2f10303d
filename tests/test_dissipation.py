"""The energy dampers dissipate (issue 30): ``dissipated_power`` (a force type's
``dissipation``: a spring-damper's c (dL/dt)^2, a rotary one's c (phid2 - phid1)^2) and its
time integral over a forward-dynamics run, ``dissipated_energy``, against the damped
oscillator's closed form; kinetic plus potential plus dissipated energy is constant."""

import numpy as np
import pytest

import mechdsl
from mechdsl.errors import MechError


def loads(text):
    """With the installed plugins (the force types among them)."""
    return mechdsl.loads(text)

M, K, C, X0 = 2.0, 50.0, 1.5, 0.3
DAMPED = f"""
param m = {M}
param k = {K}
param c = {C}
ground {{ }}
body block {{ guess = ({X0}, 0, 0)  mass = m  inertia = 0.1 }}
joint guide: prismatic(ground.origin, block.origin, axis = (1, 0))
force spring: spring(ground.origin, block.origin, k = k, c = c)
simulate t = 0 .. 3 step 0.01, rtol = 1e-10, atol = 1e-12
units length = "m", time = "s", mass = "kg"
output block.x, kinetic_energy, potential_energy, dissipated_power, dissipated_energy
"""


def oscillator(t):
    """x, x' of m x'' + c x' + k x = 0 from x0 at rest (underdamped)."""
    w0 = np.sqrt(K / M)
    z = C / (2 * np.sqrt(K * M))
    wd = w0 * np.sqrt(1 - z * z)
    e = np.exp(-z * w0 * t)
    x = e * X0 * (np.cos(wd * t) + z * w0 / wd * np.sin(wd * t))
    v = -e * X0 * (w0 * w0 / wd) * np.sin(wd * t)
    return x, v


def test_the_damped_oscillators_dissipated_energy_equals_the_closed_form():
    res = loads(DAMPED).simulate()
    assert res.ok
    t = res["t"]
    x, v = oscillator(t)
    np.testing.assert_allclose(res["block.x"], x, atol=1e-9)
    np.testing.assert_allclose(res["dissipated_power"], C * v * v, atol=1e-8)
    # what the damper took: the energy lost, E0 - (m v^2 + k x^2) / 2
    lost = 0.5 * K * X0**2 - 0.5 * (M * v * v + K * x * x)
    np.testing.assert_allclose(res["dissipated_energy"], lost, atol=1e-9)
    total = res["kinetic_energy"] + res["potential_energy"] + res["dissipated_energy"]
    assert np.abs(total - total[0]).max() < 1e-9 * total[0]
    assert (res.units["dissipated_power"], res.units["dissipated_energy"]) == ("W", "J")


def test_a_rotary_dampers_power_and_the_balance_of_a_damped_pendulum():
    text = """
gravity = (0, -9.81)
ground { }
body arm { guess = (0, 0, 0)  mass = 1  inertia = 0.1  centroid = (0.5, 0) }
joint pivot: revolute(ground.origin, arm.origin)
force damper: rotary_spring(ground, arm, k = 0, c = 0.4)
simulate t = 0 .. 2 step 0.05, rtol = 1e-10, atol = 1e-12
output arm.omega, kinetic_energy, potential_energy, dissipated_power, dissipated_energy
"""
    res = loads(text).simulate()
    np.testing.assert_allclose(res["dissipated_power"], 0.4 * res["arm.omega"] ** 2,
                               rtol=1e-12, atol=1e-14)
    total = res["kinetic_energy"] + res["potential_energy"] + res["dissipated_energy"]
    assert res["dissipated_energy"][-1] > 0.1  # it did dissipate
    assert np.abs(total - total[0]).max() < 1e-8


def test_a_driven_mechanism_has_no_dissipated_energy_but_its_power():
    text = DAMPED.replace("simulate t = 0 .. 3 step 0.01, rtol = 1e-10, atol = 1e-12",
                          "drive move: x(block.origin) = 0.3*cos(5*t)\nsimulate t = 0 .. 1 step 0.1")
    with pytest.raises(MechError, match="dissipated_energy is integrated over a "
                                        "forward-dynamics run"):
        loads(text).simulate()
    power = loads(text.replace(", dissipated_energy", "")).simulate()
    v = -1.5 * np.sin(5 * power["t"])
    np.testing.assert_allclose(power["dissipated_power"], C * v * v, atol=1e-12)
