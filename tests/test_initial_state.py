"""The starting state of a forward dynamics (issue 28, item 5): the ``initial`` statement,
the warnings where the assembly moves a given position or velocity, and the degrees of
freedom that ``mechdsl check`` counts in models with both drives and free coordinates.

Each is checked against an independent truth: the pendulum's own ODE integrated by scipy at
rtol 1e-12, the closed-form counts n - rank, and the velocity constraints written by hand."""

import math
import re

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import mechdsl
from mechdsl.errors import MechError, format_error
from mechdsl.grammar import parse
from mechdsl.grammar.format import format_text
from mechdsl.grammar.symbols import index, statement_starts, tokens
from mechdsl.solve.initial import GUESS_TOL

G, M, A, IC = 9.81, 1.0, 0.5, 0.1  # gravity, the rod's mass, its centroid, its inertia

ROD = f"""body rod {{
    point O = (0, 0)
    point tip = (1, 0)
    mass = {M}
    inertia = {IC}
    centroid = ({A}, 0)
    guess = (0, 0, -0.5)
}}
joint pin: revolute(rod.O, ground.origin)
gravity = (0, -{G})
"""


def run(text: str, name: str = "start.mech"):
    return mechdsl.loads(text, name).simulate()


def pendulum_oracle(phi0: float, omega0: float, times: np.ndarray) -> np.ndarray:
    """phi(t) of the rod pinned at its origin: (I_c + m a^2) phi'' = -m g a cos(phi),
    integrated by scipy (DOP853, rtol 1e-12): the truth the run is compared with."""
    J = IC + M * A * A

    def f(t, y):
        return [y[1], -M * G * A * math.cos(y[0]) / J]

    sol = solve_ivp(f, (times[0], times[-1]), [phi0, omega0], method="DOP853", rtol=1e-12,
                    atol=1e-12, t_eval=times)
    return sol.y[0]


def located(err: MechError) -> tuple[int, int]:
    """(line, column) of FILE:LINE:COL in the error as the command line prints it."""
    m = re.match(r"[^:]+:(\d+):(\d+): error", format_error(err))
    assert m, format_error(err)
    return int(m.group(1)), int(m.group(2))


# -- the statement -------------------------------------------------------------------------


def test_the_statement_takes_the_drive_syntax_with_an_optional_rate():
    model = parse(ROD + "initial start: angle(rod) = 1.0, rate = -2\n"
                  "initial bend: x(point = rod.tip) = 0.5\noutput initial(rod.phi)\n")
    first, second = model.initials
    assert (first.name, first.type_name, first.value.value) == ("start", "angle", 1.0)
    assert first.rate is not None and second.rate is None
    assert second.args[0].name == "point"
    # initial(...) is still the reduction of an output
    assert model.outputs[0].reductions[0].func == "initial"


@pytest.mark.parametrize("line, message, column", [
    ("initial s: angle(rod) = t", "time 't' cannot appear", 25),
    ("initial s: angle(rod) = 1, rat = 0", "not 'rat'", 28),
    ("initial s: angle(rod) = 1, rate = 0, rate = 1", "given twice", 38),
    ("initial pin: angle(rod) = 1", "declared twice", 9),
])
def test_a_misused_statement_is_a_located_error(line, message, column):
    with pytest.raises(MechError, match=message) as err:
        parse(ROD + line + "\n", "bad.mech")
    assert located(err.value) == (ROD.count("\n") + 1, column)


@pytest.mark.parametrize("line, message, column", [
    ("initial s: angle(rod) = 1.2, rate = 1/0", "the rate of initial 's' is inf", 37),
    ("initial s: angle(rod) = log(0)", "the value of initial 's' is -inf", 25),
])
def test_a_value_that_is_not_a_number_is_its_own_located_error(line, message, column):
    # (it read "its value is out of the mechanism's reach from the guessed configuration")
    with pytest.raises(MechError, match=re.escape(message)) as err:
        run(ROD + "simulate t = 0 .. 0.1 step 0.05\n" + line + "\n", "bad.mech")
    assert located(err.value) == (ROD.count("\n") + 2, column)


def test_a_joint_type_is_no_initial_type():
    with pytest.raises(MechError, match="is a joint type, not a drive type") as err:
        mechdsl.loads(ROD + "initial s: revolute(rod.O, ground.origin) = 1\n", "bad.mech")
    assert located(err.value) == (ROD.count("\n") + 1, 12)


def test_editors_see_a_statement_with_a_drive_name_a_drive_type_and_an_option():
    text = ROD + "initial start: angle(rod) = 1.0, rate = 0\noutput initial(rod.phi)\n"
    toks = tokens(text)
    starts = [toks[i].text for i in statement_starts(toks)]
    assert starts.count("initial") == 1  # the statement, not the reduction
    kinds = {(s.kind, s.name, s.owner, s.declaration) for s in index(text).symbols}
    assert ("drive", "start", None, True) in kinds
    assert ("type", "angle", "drive", False) in kinds
    assert ("option", "rate", None, False) in kinds
    assert not [s for s in index(text).symbols if s.kind == "unknown"]


def test_the_canonical_layout_keeps_the_statement():
    text = "body rod { }\ninitial  start :angle( rod )=1.0 ,rate= 0\n"
    out = format_text(text)
    assert "initial start: angle(rod) = 1.0, rate = 0" in out
    assert format_text(out) == out


# -- the assembly at t0 ----------------------------------------------------------------------


@pytest.mark.parametrize("rate", [0.0, 2.0])
def test_a_free_pendulum_starts_exactly_where_the_statement_puts_it(rate):
    res = run(ROD + f"initial start: angle(rod) = 1.0, rate = {rate}\n"
              "simulate t = 0 .. 1 step 0.05, rtol = 1e-11, atol = 1e-12\n"
              "output rod.phi, rod.omega\n")
    assert res.status == "ok"
    phi, omega = res.data["rod.phi"][0], res.data["rod.omega"][0]
    # exact at t0 (a constraint of the assembly, not a guess), although the guess is -0.5
    assert abs(phi[0] - 1.0) < 1e-12 and abs(omega[0] - rate) < 1e-12
    # and after t0 the statement plays no role: the motion is the pendulum's ODE from there
    truth = pendulum_oracle(1.0, rate, res.times)
    assert np.abs(phi - truth).max() < 1e-8
    assert not [w for w in res.warnings if "moved the guesses" in w]


def test_relative_and_point_forms_fix_a_double_pendulum():
    text = ROD + """body rod2 {
    point O = (0, 0)
    mass = 1
    inertia = 0.1
    centroid = (0.5, 0)
}
joint pin2: revolute(rod2.O, rod.tip)
initial bend: rel_angle(rod, rod2) = 0.3
initial high: y(rod.tip) = sin(0.8)
simulate t = 0 .. 0.1 step 0.1
output rod.phi, rod2.phi
"""
    res = run(text)
    phi1, phi2 = res.data["rod.phi"][0, 0], res.data["rod2.phi"][0, 0]
    # y of the tip sin(phi1) = sin(0.8), from the guess -0.5 the nearest branch is 0.8;
    # closed to the assembly's tolerance (SolverOptions.assembly_tol, 1e-10)
    assert abs(phi1 - 0.8) < 1e-10 and abs(phi2 - phi1 - 0.3) < 1e-10
    assert not [w for w in res.warnings if "moved the guesses" in w]


DOUBLE = ROD.replace("guess = (0, 0, -0.5)", "guess = (0, 0, 1.0)").replace(
    "{", "{{").replace("}", "}}") + """body rod2 {{
    point O = (0, 0)
    mass = 1
    inertia = 0.1
    centroid = (0.5, 0)
    guess = ({x}, {y}, 0.5)
}}
joint pin2: revolute(rod2.O, rod.tip)
simulate t = 0 .. 0.1 step 0.1
output rod.phi, rod2.x
"""


def test_the_assembly_moving_a_guess_is_a_warning_with_the_numbers():
    # rod2's guess is not at rod's tip: the assembly moves rod's angle, written at 1.0
    res = run(DOUBLE.format(x=0.4, y=0.9))
    (warning,) = [w for w in res.warnings if "moved the guesses" in w]
    phi = res.data["rod.phi"][0, 0]
    assert abs(phi - 1.0) > GUESS_TOL  # the complaint of the issue: moved with no word
    assert f"rod.phi from 1 to {phi:.6g}" in warning
    assert f"rod2.x from 0.4 to {res.data['rod2.x'][0, 0]:.6g}" in warning
    assert "initial rod_start: angle(rod) = 1" in warning  # the remedy, stated


def test_an_exact_guess_or_an_initial_statement_gives_no_warning():
    exact = run(DOUBLE.format(x=math.cos(1.0), y=math.sin(1.0)))
    assert not [w for w in exact.warnings if "moved the guesses" in w]
    assert abs(exact.data["rod.phi"][0, 0] - 1.0) < 1e-12
    # both free coordinates stated: the guesses are only where the search starts
    fixed = run(DOUBLE.format(x=0.4, y=0.9).replace(
        "simulate", "initial a: angle(rod) = 1.0\ninitial b: angle(rod2) = 0.5\nsimulate"))
    assert not [w for w in fixed.warnings if "moved the guesses" in w]
    assert abs(fixed.data["rod.phi"][0, 0] - 1.0) < 1e-12


# -- the initial velocities ------------------------------------------------------------------

CARRIED = """body slider { mass = 1 inertia = 0.1 }
body rod { point O = (0, 0) mass = 1 inertia = 0.1 centroid = (0.5, 0) guess = (0, 0, -1)
    ROD_V0 }
joint slide: prismatic(slider.origin, ground.origin, axis = (1, 0))
joint pin: revolute(rod.O, slider.origin)
drive push: x(slider.origin) = 0.5 * t
gravity = (0, -9.81)
simulate t = 0 .. 0.1 step 0.1
output rod.vx, rod.vy, rod.omega, slider.vx
"""


def test_a_free_body_carried_by_a_driven_one_has_its_velocity_stated():
    res = run(CARRIED.replace("ROD_V0", ""))
    (warning,) = [w for w in res.warnings if "without v0" in w]
    v = [res.data[f"rod.{q}"][0, 0] for q in ("vx", "vy", "omega")]
    # the truth of the constraints: the pin moves with the slider, (0.5, 0) at t0
    assert abs(v[0] - 0.5) < 1e-12 and abs(v[1]) < 1e-12
    assert f"rod with (vx, vy, omega) = ({v[0]:.6g}, {v[1]:.6g}, {v[2]:.6g})" in warning
    assert "the drive push (rate 0.5 at t0)" in warning
    # the slider, whose velocity the drive fixes, has no other start: not reported
    assert "slider with" not in warning


def test_a_stated_velocity_is_kept_and_a_changed_one_reported():
    kept = run(CARRIED.replace("ROD_V0", "v0 = (0.5, 0, 3)"))
    assert not [w for w in kept.warnings if "without v0" in w or "do not satisfy" in w]
    assert abs(kept.data["rod.omega"][0, 0] - 3) < 1e-12
    changed = run(CARRIED.replace("ROD_V0", "v0 = (0, 0, 3)"))
    (warning,) = [w for w in changed.warnings if "do not satisfy" in w]
    assert "rod.vx from 0 to 0.5" in warning


def test_an_initial_rate_is_imposed_and_replaces_the_carried_velocity():
    res = run(CARRIED.replace("ROD_V0", "").replace(
        "simulate", "initial swing: rel_angle(slider, rod) = -1, rate = 2\nsimulate"))
    assert abs(res.data["rod.omega"][0, 0] - 2) < 1e-12
    assert abs(res.data["rod.vx"][0, 0] - 0.5) < 1e-12
    assert not [w for w in res.warnings if "without v0" in w]


# -- mechdsl check ---------------------------------------------------------------------------

SLIDER_PENDULUM = CARRIED.replace("ROD_V0", "")
SECOND_LINK = """body rod2 { point O = (0, 0) mass = 1 inertia = 0.1 centroid = (0.5, 0)
    guess = (0.5, -0.9, -1) }
joint pin2: revolute(rod2.O, rod.tip)
"""


@pytest.mark.parametrize("text, n, joint_rank, drives, free", [
    # slider (1 dof) + pendulum (1): 6 coordinates, 4 joint equations, 1 drive: 1 left
    (SLIDER_PENDULUM, 6, 4, 1, 1),
    # and a second link: 9 - 6 = 3, less the drive: 2
    (SLIDER_PENDULUM.replace("body rod {", "body rod { point tip = (1, 0)")
     .replace("simulate", SECOND_LINK + "simulate"), 9, 6, 1, 2),
    # a second drive on the pendulum's angle: 6 - 4 - 2 = 0 is the kinematics; on the
    # double pendulum 9 - 6 - 2 = 1
    (SLIDER_PENDULUM.replace("body rod {", "body rod { point tip = (1, 0)")
     .replace("simulate", SECOND_LINK + "drive tilt: angle(rod) = -1\nsimulate"), 9, 6, 2, 1),
])
def test_check_counts_drives_and_free_coordinates(text, n, joint_rank, drives, free):
    report = mechdsl.loads(text, "mixed.mech").check()
    assert report.coordinates == n and report.drives == drives
    assert report.mobility == n - joint_rank and report.free == free
    s = "s" if free != 1 else ""
    assert (f"{drives} drive{'s' if drives != 1 else ''}: {free} degree{s} of freedom left"
            in report.text)


def test_check_states_the_start_it_assembles():
    report = mechdsl.loads(SLIDER_PENDULUM.replace(
        "simulate", "initial swing: angle(rod) = -1.2\nsimulate"), "mixed.mech").check()
    assert report.ok and report.free == 1
    assert "initial swing" in report.text and "1 fixed at t0 by 1 initial statement" in report.text
    assert any("without v0" in w for w in report.warnings)


# -- misuse ----------------------------------------------------------------------------------


def test_an_initial_statement_in_a_fully_driven_model_is_a_located_error():
    text = ROD + ("drive turn: angle(rod) = t\ninitial start: angle(rod) = 1.0\n"
                  "simulate t = 0 .. 1 step 0.1\n")
    with pytest.raises(MechError, match="is for forward dynamics: the drives fix every") as err:
        mechdsl.loads(text, "driven.mech").compile()
    assert located(err.value) == (ROD.count("\n") + 2, 1)


def test_an_initial_statement_without_masses_is_a_located_error():
    text = ("body rod { point O = (0, 0) }\njoint pin: revolute(rod.O, ground.origin)\n"
            "initial start: angle(rod) = 1.0\nsimulate t = 0 .. 1 step 0.1\n")
    with pytest.raises(MechError, match="the model has no masses") as err:
        mechdsl.loads(text, "massless.mech").compile()
    assert located(err.value) == (3, 1)


@pytest.mark.parametrize("extra, message", [
    # the drive already fixes the slider's x
    ("initial there: x(slider.origin) = 0.2\n", "already fix"),
    # one free coordinate, two statements
    ("initial a: angle(rod) = -1.2\ninitial b: x(rod.origin) = 0\n", "before it already fix"),
])
def test_an_over_determining_statement_is_a_located_error(extra, message):
    text = SLIDER_PENDULUM.replace("simulate", extra + "simulate")
    with pytest.raises(MechError, match=message) as err:
        run(text, "over.mech")
    line = text[: text.index(extra)].count("\n") + 1 + extra.count("\n") - 1
    assert located(err.value) == (line, 1)


def test_a_value_out_of_reach_is_a_located_error():
    text = ROD + "initial far: x(rod.tip) = 5\nsimulate t = 0 .. 0.1 step 0.1\n"
    with pytest.raises(MechError, match="cannot be assembled .* initial 'far'") as err:
        run(text, "far.mech")
    assert located(err.value) == (ROD.count("\n") + 1, 1)


def test_coordinates_that_the_equations_fix_are_not_named_as_moved_guesses():
    """The warning is about the assembly's choices: a guess that an initial statement, a
    drive or a joint on a driven body fixes moved as they ask (the user's own statement
    moved the plate's angle; the drive moved the cart, and with it the pin of the pendulum,
    whose angle, its one free coordinate, kept its guess); before, both were named and the
    remedy suggested was an initial statement that over-determined the start."""
    plate = run("""gravity = (0, -9.81)
ground { }
body plate { guess = (1, 2, 0.3)  mass = 3  inertia = 0.5  v0 = (4, 10, 3) }
initial spin: angle(plate) = 1, rate = 3
simulate t = 0 .. 0.1 step 0.1
output plate.phi
""")
    assert not [w for w in plate.warnings if "moved the guesses" in w], plate.warnings
    assert abs(plate.data["plate.phi"][0, 0] - 1.0) < 1e-12
    cart = run("""gravity = (0, -9.81)
ground { }
body cart { guess = (0, 0, 0) }
body pend { guess = (0, 0, -1.2)  mass = 1.5  inertia = 1e-6  centroid = (0.8, 0) }
joint guide: prismatic(ground.origin, cart.origin, axis = (1, 0))
joint pivot: revolute(cart.origin, pend.origin)
drive shake: x(cart.origin) = 0.1*cos(5*t)
simulate t = 0 .. 0.1 step 0.1
output cart.x, pend.phi
""")
    assert not [w for w in cart.warnings if "moved the guesses" in w], cart.warnings
    assert abs(cart.data["cart.x"][0, 0] - 0.1) < 1e-12
    assert abs(cart.data["pend.phi"][0, 0] + 1.2) < 1e-12
