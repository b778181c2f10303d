"""Random closed-loop mechanisms built from a known configuration: the solver recovers the
configuration, and its velocities and accelerations agree with differences of its own
positions."""

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import mechdsl
from mechdsl.solve import assemble
from mechdsl.solve.diagnose import col_scale
from mechdsl.compiled import equations as eq
from mechdsl.solve.linalg import factor

coord = st.floats(-2, 2, allow_nan=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False)
pose = st.tuples(coord, coord, angle)


def local(pose, point):
    """The body coordinates of global ``point`` in a body at ``pose``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = np.asarray(point) - pose[:2]
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def fmt(v):
    return "(" + ", ".join(repr(float(x)) for x in v) + ")"


def four_bar_text(poses, O2, A, B, O4, omega):
    """Three bodies at ``poses``, their pins at the global points O2, A, B, O4."""
    p1, p2, p3 = (np.array(p) for p in poses)
    lines = [
        f"ground {{ point O2 = {fmt(O2)}  point O4 = {fmt(O4)} }}",
        f"body one   {{ guess = {fmt(p1)}  point O = {fmt(local(p1, O2))}  point A = {fmt(local(p1, A))} }}",
        f"body two   {{ guess = {fmt(p2)}  point A = {fmt(local(p2, A))}  point B = {fmt(local(p2, B))} }}",
        f"body three {{ guess = {fmt(p3)}  point B = {fmt(local(p3, B))}  point O = {fmt(local(p3, O4))} }}",
        "joint j1: revolute(ground.O2, one.O)",
        "joint j2: revolute(one.A, two.A)",
        "joint j3: revolute(two.B, three.B)",
        "joint j4: revolute(three.O, ground.O4)",
        f"drive d: angle(one) = {float(p1[2])!r} + {omega!r}*t",
        "simulate t = 0 .. 0.06 step 0.0001",
    ]
    return "\n".join(lines)


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.filter_too_much, HealthCheck.too_slow])
@given(poses=st.tuples(pose, pose, pose),
       points=st.tuples(*[st.tuples(coord, coord)] * 4),
       omega=st.floats(0.5, 3), nudge=st.tuples(*[st.floats(-0.02, 0.02)] * 9))
def test_random_four_bars(registry, poses, points, omega, nudge):
    O2, A, B, O4 = (np.array(p) for p in points)
    # links of sensible length, not folded onto one another
    for u, v in ((O2, A), (A, B), (B, O4), (O2, O4)):
        assume(np.linalg.norm(u - v) > 0.3)
    text = four_bar_text(poses, O2, A, B, O4, omega)
    mech = mechdsl.loads(text, registry=registry)
    kernels = mech.compile()
    truth = np.array(poses, dtype=float).ravel()
    D = col_scale(kernels.system)
    rcond = factor(eq.jacobian(kernels, truth.reshape(1, 1, -1)), D).rcond[0, 0]
    assume(rcond > 0.05)  # away from dead points: the motion over the span stays regular
    # the configuration is recovered from guesses nudged by up to 2 % of the size
    from dataclasses import replace

    nudged = kernels.with_system(
        replace(kernels.system, guess=(truth + np.array(nudge) * 4.0).reshape(1, -1)))
    asm = assemble(nudged, 0.0)
    assert asm.ok[0]
    np.testing.assert_allclose(asm.q[0][0::3], truth[0::3], atol=1e-11)
    np.testing.assert_allclose(asm.q[0][1::3], truth[1::3], atol=1e-11)
    np.testing.assert_allclose(np.cos(asm.q[0][2::3] - truth[2::3]), 1.0, atol=1e-12)
    # rates against differences of the solver's own positions
    res = mech.simulate()
    assert res.ok, res.messages
    # differences carry round-off of eps L / h (velocity) and eps L / h^2 (acceleration),
    # and truncation errors of order h^2 of the third and fourth derivatives
    h, L, eps = 1e-4, 4.0, np.finfo(float).eps
    for body in ("two", "three"):
        for q, v, a in (("x", "vx", "ax"), ("y", "vy", "ay"), ("phi", "omega", "alpha")):
            x = res[f"{body}.{q}"]
            scale_v = np.abs(res[f"{body}.{v}"]).max()
            scale_a = np.abs(res[f"{body}.{a}"]).max()
            dv = (x[2:] - x[:-2]) / (2 * h)
            da = (x[2:] - 2 * x[1:-1] + x[:-2]) / h**2
            np.testing.assert_allclose(res[f"{body}.{v}"][1:-1], dv,
                                       atol=1e-5 * scale_v + 100 * eps * L / h)
            np.testing.assert_allclose(res[f"{body}.{a}"][1:-1], da,
                                       atol=1e-3 * scale_a + 100 * eps * L / h**2)
