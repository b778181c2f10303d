"""Rough guesses: the assembly finds the assembly mode nearest the guesses, or says there is
none."""

import numpy as np
import pytest

import mechdsl
from closed_forms import four_bar
from mechdsl.solve import assemble

FOURBAR = """
param a = 1  param b = 3.5  param c = 3  param d = 4
ground { point O2 = (0, 0)  point O4 = (d, 0) }
body crank   { guess = ({g0})  point O = (-a/2, 0)  point A = (a/2, 0) }
body coupler { guess = ({g1})  point A = (-b/2, 0)  point B = (b/2, 0) }
body rocker  { guess = ({g2})  point B = (-c/2, 0)  point O = (c/2, 0) }
joint O2: revolute(ground.O2, crank.O)
joint A:  revolute(crank.A, coupler.A)
joint B:  revolute(coupler.B, rocker.B)
joint O4: revolute(rocker.O, ground.O4)
drive motor: angle(crank) = pi/4
simulate t = 0 .. 0 step 1
"""


def exact_poses():
    """The open assembly (B above the line of centres) at crank angle pi/4."""
    th2 = np.array([np.pi / 4])
    (th3, _, _), (th4, _, _) = four_bar(1.0, 3.5, 3.0, 4.0, th2, 0.0, 0.0)
    th3, th4 = th3[0], th4[0]
    A = np.array([np.cos(th2[0]), np.sin(th2[0])])
    B = A + 3.5 * np.array([np.cos(th3), np.sin(th3)])
    O4 = np.array([4.0, 0.0])
    return np.array([[*(A / 2), th2[0]], [*((A + B) / 2), th3], [*((B + O4) / 2), th4 + np.pi]])


def mech_with(registry, guesses):
    text = FOURBAR
    for i, g in enumerate(guesses):
        text = text.replace("{g%d}" % i, ", ".join(repr(float(x)) for x in g))
    return mechdsl.loads(text, registry=registry)


@pytest.mark.parametrize("seed", range(25))
def test_rough_guesses_find_the_nearest_assembly_mode(registry, seed):
    rng = np.random.default_rng(seed)
    truth = exact_poses()
    lengths = np.array([1.0, 3.5, 3.0])
    guesses = truth.copy()
    guesses[:, :2] += rng.uniform(-0.3, 0.3, (3, 2)) * lengths[:, None]  # 30 % of each link
    guesses[:, 2] += rng.uniform(-0.5, 0.5, 3)
    kernels = mech_with(registry, guesses).compile()
    asm = assemble(kernels, 0.0)
    assert asm.ok.all(), asm.messages
    got = asm.q[0].reshape(3, 3)
    np.testing.assert_allclose(got[:, :2], truth[:, :2], atol=1e-12)
    np.testing.assert_allclose(np.cos(got[:, 2] - truth[:, 2]), 1.0, atol=1e-12)


def test_the_mirror_guess_finds_the_mirror_mode(registry):
    truth = exact_poses()
    mirror = truth.copy()
    mirror[1:, 1] *= -1  # coupler and rocker below the line
    mirror[1:, 2] *= -1
    asm = assemble(mech_with(registry, mirror).compile(), 0.0)
    got = asm.q[0].reshape(3, 3)
    assert got[2, 1] < 0  # the crossed assembly: the rocker's centre below the line


def test_no_assembly_from_a_guess_is_reported(registry):
    # with the crank at pi/4 its pin is 3.37 from the rocker's pivot, the rocker is 3 long:
    # a coupler of 0.2 cannot span the gap
    mech = mech_with(registry, exact_poses())
    kernels = mechdsl.loads(mech.model.source.text.replace("param b = 3.5", "param b = 0.2"),
                           "short.mech", registry=registry).compile()
    asm = assemble(kernels, 0.0)
    assert not asm.ok[0]
    assert "cannot be assembled at t = 0" in asm.messages[0]
    assert "the drives cannot reach their values at t0" in asm.messages[0]
