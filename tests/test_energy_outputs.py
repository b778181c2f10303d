"""The energies read by named outputs and reductions (``output total = kinetic_energy +
potential_energy``, ``max(kinetic_energy)``): against the conservation of energy, the
compound pendulum's closed forms and a driven crank's 1/2 J omega^2."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ellipk

import mechdsl
from mechdsl.errors import MechError

#: a rod of 1 m and 1 kg pinned at one end, released from the horizontal
PENDULUM = """gravity = (0, -9.81)
ground { }
body rod { guess = (0, 0, 0)  mass = 1  inertia = 1/12  centroid = (0.5, 0) }
joint pin: revolute(ground.origin, rod.origin)
"""


def test_energy_expressions_hold_the_conservation_law():
    """Released at rest from the horizontal (T + V = 0): the named output total stays 0, a
    damper's dissipated_energy closes the balance, and an expression of energies has no
    rate columns (the energies have none)."""
    text = PENDULUM + """force damper: rotary_spring(ground, rod, k = 0, c = 0.05)
simulate t = 0 .. 3 step 0.01
output total = kinetic_energy + potential_energy + dissipated_energy, lost = dissipated_energy
"""
    res = mechdsl.loads(text, "pendulum.mech").simulate()
    assert res.ok, res.messages
    assert [c for c in res.labels if c.startswith("total")] == ["total"]
    assert np.abs(res["total"]).max() < 1e-6  # of about 4.9 J exchanged
    assert res["lost"][-1] > 0.1  # the damper took a real share


def test_reductions_of_the_kinetic_energy_match_the_compound_pendulum():
    """max(kinetic_energy) is m g d (the centre of mass d = 0.5 m below the pivot's level
    at the bottom), reached first at a quarter period, t = sqrt(J / (m g d)) K(sin^2 45 deg)
    with J = m l^2 / 3 (the complete elliptic integral of the first kind)."""
    text = PENDULUM + """simulate t = 0 .. 1.5 step 0.01
output peak = max(kinetic_energy), when = argmax(kinetic_energy), end = final(kinetic_energy + potential_energy)
"""
    res = mechdsl.loads(text, "pendulum.mech").simulate()
    assert res.ok, res.messages
    g, d, J = 9.81, 0.5, 1 / 3
    assert res["peak"] == pytest.approx(g * d, rel=1e-7)
    assert res["when"] == pytest.approx(np.sqrt(J / (g * d)) * ellipk(0.5), rel=1e-6)
    assert abs(res["end"]) < 1e-6


def test_a_driven_cranks_energy_in_an_expression():
    """Fully driven at 2 rad/s: 2 T = J omega^2 with J = 1/12 + 0.25 about the pin, also
    where the model gives no mass to anything else (and 0 where it has no mass at all)."""
    text = """ground { }
body crank { guess = (0, 0, 0)  mass = 1  inertia = 1/12  centroid = (0.5, 0) }
joint pin: revolute(ground.origin, crank.origin)
drive turn: angle(crank) = 2*t
simulate t = 0 .. 1 step 0.1
output twice = 2 * kinetic_energy
"""
    res = mechdsl.loads(text, "crank.mech").simulate()
    assert res.ok, res.messages
    assert np.abs(res["twice"] - (1 / 12 + 0.25) * 4).max() < 1e-12
    massless = text.replace("  mass = 1  inertia = 1/12  centroid = (0.5, 0)", "")
    res = mechdsl.loads(massless, "crank.mech").simulate()
    assert res.ok and np.abs(res["twice"]).max() == 0


def test_the_dissipated_energy_of_a_driven_run_is_refused_in_an_expression_too():
    text = """ground { }
body crank { guess = (0, 0, 0)  mass = 1  inertia = 0.1 }
joint pin: revolute(ground.origin, crank.origin)
drive turn: angle(crank) = 2*t
force damper: rotary_spring(ground, crank, k = 0, c = 0.1)
simulate t = 0 .. 1 step 0.1
output w = 3 * dissipated_energy
"""
    with pytest.raises(MechError, match="dissipated_energy is integrated over a forward"):
        mechdsl.loads(text, "crank.mech").simulate()


@pytest.mark.parametrize("declaration", [
    "param kinetic_energy = 7",
    "body potential_energy { guess = (1, 1, 0) }",
    "force kinetic_energy: torque(crank, 1)",
    "output kinetic_energy = crank.phi"])
def test_an_energys_name_names_nothing_else(declaration):
    """The energies' names are reserved: a param, body, joint, force or output of that
    name would make ``output w = kinetic_energy`` mean one thing to the run and another to
    the editor; refused where declared."""
    text = f"""ground {{ }}
body crank {{ guess = (0, 0, 0)  mass = 1  inertia = 0.1 }}
joint pin: revolute(ground.origin, crank.origin)
drive turn: angle(crank) = 2*t
simulate t = 0 .. 1 step 0.5
{declaration}
"""
    with pytest.raises(MechError, match="is reserved: it is an output quantity") as err:
        mechdsl.loads(text, "crank.mech")
    assert err.value.span.line == 6


@pytest.mark.parametrize("goal, said", [
    ("minimize kinetic_energy", "minimize takes one value per variant"),
    ("minimize max(kinetic_energy)\nsubject to kinetic_energy <= 3",
     "'kinetic_energy' is outside a reduction")])
def test_an_energy_outside_a_reduction_of_an_objective_is_located(goal, said):
    text = f"""param m = 1
ground {{ }}
body crank {{ guess = (0, 0, 0)  mass = m  inertia = 0.1  centroid = (0.5, 0) }}
joint pin: revolute(ground.origin, crank.origin)
drive turn: angle(crank) = 2*t
simulate t = 0 .. 1 step 0.1
optimize m in 0.5 .. 2
{goal}
"""
    with pytest.raises(MechError, match=said) as err:
        mechdsl.loads(text, "o.mech")
    assert err.value.span is not None and err.value.span.line >= 8
