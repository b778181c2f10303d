"""Units on every quantity (issue 30): the names the ``units`` statement gives, the derived
units that follow from them, an output expression's unit from its arithmetic, the angle
reported in degrees (values checked against the slider-crank's closed form), and unit
mismatches as located warnings."""

import numpy as np
import pytest

from closed_forms import slider_crank
from conftest import EXAMPLES
from test_cli import mechdsl
from mechdsl.compiled.units import Units
from mechdsl.errors import MechError, MechWarning

SLIDER = (EXAMPLES / "slider_crank.mech").read_text()
R, L, OMEGA = 2.0, 3.5, 4 * np.pi


def test_the_units_of_each_quantity_follow_from_the_named_ones():
    si, mm = Units("m", "s", "kg"), Units("mm", "s", force="N")
    assert [si.quantity(q) for q in ("x", "vy", "ax", "phi", "omega", "alpha")] == \
        ["m", "m/s", "m/s^2", "rad", "rad/s", "rad/s^2"]
    assert [si.quantity(q) for q in ("fx", "torque", "power", "kinetic_energy")] == \
        ["N", "N*m", "W", "J"]
    assert [mm.quantity(q) for q in ("fx", "torque", "power", "kinetic_energy")] == \
        ["N", "N*mm", "N*mm/s", "N*mm"]
    assert Units("mm", "ms", "g").quantity("fx") == "g*mm/ms^2"
    # a unit a quantity needs and the model does not name: no unit rather than a wrong one
    assert Units("m", "s").quantity("fx") == "" and Units("m").quantity("vx") == ""
    assert Units(angle="deg").quantity("phi") == "deg" and Units().quantity("x") == ""


def _with(text: str, units: str, outputs: str, extra: str = "") -> str:
    """The slider-crank with its units line and its outputs replaced."""
    lines = [units if line.startswith("units ") else
             outputs if line.startswith("output ") else line for line in text.splitlines()]
    return "\n".join(lines) + "\n" + extra


def test_angles_reported_in_degrees_equal_the_closed_form(loads):
    """rod.phi, its rate and a reduction of it in degrees; what other outputs read stays in
    radians (sin(rod.phi) is the sine of the angle, not of its degrees)."""
    text = _with(SLIDER, 'units length = "m", time = "s", angle = "deg"',
                 "output rod.phi, rod.omega, s = sin(rod.phi), twice = 2*rod.phi")
    res = loads(text).simulate(step=0.01)
    theta = np.pi / 4 + OMEGA * res["t"]
    x, _, _ = slider_crank(R, L, theta, OMEGA, 0.0)
    phi = np.arctan2(-R * np.sin(theta), x - R * np.cos(theta))
    np.testing.assert_allclose(res["rod.phi"], np.degrees(phi), atol=1e-9)
    np.testing.assert_allclose(res["s"], np.sin(phi), atol=1e-12)
    np.testing.assert_allclose(res["twice"], 2 * np.degrees(phi), atol=1e-9)
    assert (res.units["rod.phi"], res.units["rod.omega"], res.units["twice.acc"]) == \
        ("deg", "deg/s", "deg/s^2")
    assert "s" not in res.units and res.units["s.vel"] == "1/s"
    rng = loads(text).simulate(step=0.01, reduce="range(rod.phi), argmax(rod.phi)")
    assert rng.units == {"range(rod.phi)": "deg", "argmax(rod.phi)": "s"}
    # the rod swings between -asin(r/l) and asin(r/l) (found between the samples)
    np.testing.assert_allclose(rng.reduced["range(rod.phi)"], 2 * np.degrees(np.arcsin(R / L)),
                               rtol=1e-12)


def test_forces_torques_powers_and_energies_carry_their_units(loads):
    text = (EXAMPLES / "fourbar.mech").read_text()
    body = 'mass = 1  inertia = 0.1  centroid = (0, 0)\n'
    text = text.replace("body rocker {", "body rocker { " + body)
    text = text.replace("body coupler {", "body coupler { " + body)
    text = text.replace('units length = "m", time = "s"',
                        'units length = "m", time = "s", mass = "kg"')
    text += ("\noutput O2.fx, O2.torque, motor.torque, motor.power, kinetic_energy,"
             " p = motor.torque * crank.omega, arc = crank.phi * distance(crank.O, crank.A),"
             " k = motor.torque / distance(crank.O, crank.A), n = a * crank.phi\n")
    res = loads(text).simulate(step=0.05)
    u = res.units
    assert (u["O2.fx"], u["O2.torque"], u["motor.torque"], u["motor.power"]) == \
        ("N", "N*m", "N*m", "W")
    # torque times angular velocity is a power; a length times an angle a length; a param's
    # unit is not known (n)
    assert "n" not in u
    assert (u["kinetic_energy"], u["p"], u["arc"], u["arc.vel"], u["k"]) == \
        ("J", "W", "m", "m/s", "N")
    # the drive's power is its torque times the crank's rate (radians: a pure number)
    np.testing.assert_allclose(res["p"], res["motor.power"], rtol=1e-12, atol=1e-9)


def test_a_unit_mismatch_is_a_located_warning(loads, tmp_path):
    text = _with(SLIDER, 'units length = "m", time = "s"',
                 "output w = rod.phi + slider.x, s = sin(slider.x), ok = slider.x - 2*r")
    res = loads(text).simulate(step=0.1)
    warnings = [w for w in res.warnings if isinstance(w, MechWarning)]
    assert [w.message for w in warnings] == [
        "output 'w': adding an angle (rad) and a length (m)",
        "output 's': sin of a length (m): it takes an angle"]
    line = text.splitlines().index(next(x for x in text.splitlines() if "output w" in x)) + 1
    assert (warnings[0].span.line, warnings[0].span.column) == (line, 12)
    assert str(warnings[0]).startswith(f"line {line}, column 12: output 'w'")
    path = tmp_path / "m.mech"
    path.write_text(text)
    r = mechdsl("run", path, "--step", "0.1", "-o", tmp_path / "o.csv")
    assert r.returncode == 0, r.stderr
    assert f"{path}:{line}:12: warning: output 'w': adding an angle (rad)" in r.stderr
    assert "^^^^^^^^^^^^^^^^^^" in r.stderr
    r = mechdsl("check", path)
    assert f"{path}:{line}:12: warning:" in r.stderr


@pytest.mark.parametrize("line, message", [
    ('units weight = "kg"', "units are given for 'length', 'time', 'mass', 'angle', 'force', "
                            "not 'weight'"),
    ('units angle = "grad"', "angles are reported in 'rad' or 'deg', not 'grad'"),
    ('units length = "m", length = "mm"', "the unit of length is given twice"),
])
def test_bad_units_are_located_errors(loads, line, message):
    with pytest.raises(MechError) as err:
        loads((EXAMPLES / "fourbar.mech").read_text() + "\n" + line + "\n")
    assert message in str(err.value) and err.value.span is not None
