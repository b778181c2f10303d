"""Inverse dynamics against closed forms: the driving torque of the seed's slider-crank with
masses against the power balance (torque times crank speed = dT/dt, T from the closed-form
kinematics, differentiated by the complex step), every joint's reaction against Newton's and
Euler's laws for each body, and a crank with gravity and an offset centre of mass."""

import numpy as np
import pytest

import mechdsl
from mechdsl.errors import MechError

R, L, OMEGA = 2.0, 3.5, 4 * np.pi
M1, M2, M3 = 1.0, 1.5, 0.5
J1, J2, J3 = M1 * R**2 / 12, M2 * L**2 / 12, 0.01
H = 1e-20  # the complex step: derivatives exact to round-off

SLIDER_CRANK = f"""
param r = {R}
param l = {L}
param omega = 4*pi
body crank {{ guess = (1, 0, 0)  point A = (-r/2, 0)  point B = (r/2, 0)
              mass = {M1}  inertia = {J1!r} }}
body rod {{ guess = (3.75, 0, 0)  point B = (-l/2, 0)  point C = (l/2, 0)
            mass = {M2}  inertia = {J2!r} }}
body slider {{ guess = (5.5, 0, 0)  mass = {M3}  inertia = {J3} }}
joint A: revolute(ground.origin, crank.A)
joint B: revolute(crank.B, rod.B)
joint C: revolute(rod.C, slider.origin)
joint D: prismatic(ground.origin, slider.origin, axis = (1, 0))
drive crank_angle: angle(crank) = pi/4 + omega*t
simulate t = 0 .. 0.5 step 0.005
output crank_angle.torque, crank_angle.power, A, B, C, D
"""


def kinematics(t):
    """Centres of mass c1 (crank, at its middle), c2 (rod), x_s (slider), their velocities,
    and the angular velocities, as analytic functions of t (complex t allowed):
    theta = pi/4 + omega t, x_s = r cos theta + sqrt(l^2 - r^2 sin^2 theta),
    sin beta = -r sin theta / l for the rod."""
    th = np.pi / 4 + OMEGA * t
    s, c = np.sin(th), np.cos(th)
    root = np.sqrt(L**2 - R**2 * s**2)
    xs = R * c + root
    xs_d = -R * s * OMEGA - R**2 * s * c * OMEGA / root
    c1 = np.stack((R / 2 * c, R / 2 * s))
    c1_d = np.stack((-R / 2 * s * OMEGA, R / 2 * c * OMEGA))
    c2 = np.stack(((R * c + xs) / 2, R * s / 2))
    c2_d = np.stack(((-R * s * OMEGA + xs_d) / 2, R * c * OMEGA / 2))
    beta_d = -(R * c * OMEGA / L) / np.sqrt(1 - (R * s / L) ** 2)
    return dict(c1=c1, c1_d=c1_d, c2=c2, c2_d=c2_d, xs=xs, xs_d=xs_d, beta_d=beta_d,
                B=np.stack((R * c, R * s)), C=np.stack((xs, 0 * xs)))


def kinetic_energy(t):
    k = kinematics(t)
    return (0.5 * M1 * (k["c1_d"] ** 2).sum(axis=0) + 0.5 * J1 * OMEGA**2
            + 0.5 * M2 * (k["c2_d"] ** 2).sum(axis=0) + 0.5 * J2 * k["beta_d"] ** 2
            + 0.5 * M3 * k["xs_d"] ** 2)


def d_dt(f, t):
    """df/dt by the complex step, Im f(t + i h) / h: no cancellation, exact to round-off."""
    return np.imag(f(t + 1j * H)) / H


def cross(a, f):
    return a[0] * f[1] - a[1] * f[0]


@pytest.fixture(scope="module")
def res():
    out = mechdsl.loads(SLIDER_CRANK, "slider_crank_dynamics.mech").simulate()
    assert out.status == "ok", out.messages
    return out


def test_the_driving_torque_balances_the_kinetic_energy(res):
    t = res["t"]
    dT = d_dt(kinetic_energy, t)
    assert np.abs(res["crank_angle.torque"] * OMEGA - dT).max() <= 1e-10 * np.abs(dT).max()
    np.testing.assert_allclose(res["crank_angle.power"], res["crank_angle.torque"] * OMEGA,
                               rtol=1e-14, atol=1e-12)


def test_every_reaction_obeys_newton_and_euler_for_every_body(res):
    t = res["t"]
    k = kinematics(t)
    f = {j: np.stack((res[f"{j}.fx"], res[f"{j}.fy"])) for j in "ABCD"}
    scale = max(np.abs(v).max() for v in f.values())
    tol = 1e-10 * scale
    # the slider (x_s, 0): C pushes it, D holds it on the axis; no torque on either
    xs_dd = d_dt(lambda s: kinematics(s)["xs_d"], t)
    assert np.abs(f["C"][0] - M3 * xs_dd).max() <= tol
    assert np.abs(f["C"][1] + f["D"][1]).max() <= tol
    assert np.abs(f["D"][0]).max() <= tol and np.abs(res["D.torque"]).max() <= tol
    # the rod: B's force on it, and the slider's reaction -C; its rotation about its centre
    a2 = d_dt(lambda s: kinematics(s)["c2_d"], t)
    assert np.abs(M2 * a2 - (f["B"] - f["C"])).max() <= tol
    beta_dd = d_dt(lambda s: kinematics(s)["beta_d"], t)
    moment = cross(k["B"] - k["c2"], f["B"]) + cross(k["C"] - k["c2"], -f["C"])
    assert np.abs(J2 * beta_dd - moment).max() <= tol * L
    # the crank: A holds it, the rod pushes back with -B; it turns steadily (no angular
    # acceleration): the drive's torque balances the two moments about its centre
    a1 = d_dt(lambda s: kinematics(s)["c1_d"], t)
    assert np.abs(M1 * a1 - (f["A"] - f["B"])).max() <= tol
    moment = cross(-k["c1"], f["A"]) + cross(k["B"] - k["c1"], -f["B"])
    assert np.abs(moment + res["crank_angle.torque"]).max() <= tol * R
    # revolutes carry no torque about their pins
    for j in "ABC":
        assert np.abs(res[f"{j}.torque"]).max() <= tol * R


def test_a_crank_with_gravity_and_an_offset_centre_of_mass():
    m, J, a, g = 2.0, 0.3, 0.4, 9.81
    res = mechdsl.loads(f"""
        body arm {{ mass = {m}  inertia = {J}  centroid = ({a}, 0) }}
        joint P: revolute(ground.origin, arm.origin)
        drive turn: angle(arm) = sin(2*t)
        gravity = (0, -{g})
        simulate t = 0 .. 3 step 0.01
        output turn.torque, P.fx, P.fy, P.torque
    """, "arm.mech").simulate()
    assert res.status == "ok", res.messages
    t = res["t"]
    th, thd, thdd = np.sin(2 * t), 2 * np.cos(2 * t), -4 * np.sin(2 * t)
    # about the pivot: (J + m a^2) theta'' = tau - m g a cos(theta)
    torque = (J + m * a**2) * thdd + m * g * a * np.cos(th)
    np.testing.assert_allclose(res["turn.torque"], torque, rtol=0, atol=1e-12 * 20)
    # the centre of mass a (cos, sin): m a_c = P's force + m g
    ax = a * (-np.sin(th) * thdd - np.cos(th) * thd**2)
    ay = a * (np.cos(th) * thdd - np.sin(th) * thd**2)
    np.testing.assert_allclose(res["P.fx"], m * ax, rtol=0, atol=1e-12 * 20)
    np.testing.assert_allclose(res["P.fy"], m * ay + m * g, rtol=0, atol=1e-12 * 20)
    np.testing.assert_allclose(res["P.torque"], 0.0, atol=1e-12 * 20)


@pytest.mark.parametrize("change, message", [
    ("output crank_angle.torque", "output crank_angle.fx"),
    ("mass = 1.0  inertia", "inertia"),
    ("mass = 1.0", "mass = -1"),
])
def test_errors_of_the_dynamics_are_located(change, message):
    if change == "output crank_angle.torque":
        text = SLIDER_CRANK.replace("output crank_angle.torque,", "output crank_angle.fx,")
        expect, where = "'crank_angle.fx' is not an output of drive 'crank_angle'", "crank_angle.fx"
    elif message == "inertia":
        text = SLIDER_CRANK.replace("mass = 1.0  inertia", "inertia")
        expect, where = "has an inertia but no mass", "body crank"
    else:
        text = SLIDER_CRANK.replace("mass = 1.0", "mass = -1")
        expect, where = "the mass of crank must not be negative", "-1"
    with pytest.raises(MechError) as err:
        mechdsl.loads(text, "sc.mech").simulate()
    assert expect in err.value.message
    line = text.splitlines()[err.value.span.line - 1]
    assert where in line[err.value.span.column - 1:]
