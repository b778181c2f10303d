"""The force library against independent truth: the virtual work of each element's loads
against finite differences of where its forces act, Hooke's law and the damper's rate in
closed form, action and reaction, and the conformance kit."""

import numpy as np
import pytest

from mechdsl.functions import ExprFunction
from mechdsl.plugins.geometry import Body
from mechdsl.testing import check_force_type, force_loads
from mechdsl_forces import PointForce, RotarySpring, Spring, Torque

POSITIVE = {"length": lambda rng, s: rng.uniform(0.1, 1.0, s),
            "c": lambda rng, s: rng.uniform(0.0, 2.0, s),
            "k": lambda rng, s: rng.uniform(0.5, 3.0, s),
            "angle": lambda rng, s: rng.uniform(-1.0, 1.0, s)}


@pytest.mark.parametrize("ftype", [Spring(), RotarySpring(), Torque(), PointForce()],
                         ids=lambda f: f.name)
def test_each_type_meets_the_contract(ftype):
    check_force_type(ftype, samples=40, params=POSITIVE)


def _point(q, s):
    """r^P = r + A s' of body poses q (..., 3)."""
    c, sn = np.cos(q[..., 2]), np.sin(q[..., 2])
    return np.stack((q[..., 0] + c * s[..., 0] - sn * s[..., 1],
                     q[..., 1] + sn * s[..., 0] + c * s[..., 1]), axis=-1)


def _virtual_work(loads, dq):
    return sum((loads[:, k] * dq[k]).sum(axis=-1) for k in range(len(dq)))


def test_the_spring_does_the_work_of_its_tension_along_its_line():
    rng = np.random.default_rng(1)
    N = 30
    q = (rng.uniform(-1, 1, (N, 3)), rng.uniform(-1, 1, (N, 3)) + [3.0, 0.0, 0.0])
    qd = (rng.uniform(-1, 1, (N, 3)), rng.uniform(-1, 1, (N, 3)))
    p = {"p1": rng.uniform(-1, 1, (N, 2)), "p2": rng.uniform(-1, 1, (N, 2)),
         "k": rng.uniform(1, 3, N), "length": rng.uniform(0.5, 2, N), "c": rng.uniform(0, 1, N)}
    loads = force_loads(Spring(), q, qd, p, 0.0)
    # the tension f = k (L - L0) + c dL/dt, with L and dL/dt in closed form
    d = _point(q[1], p["p2"]) - _point(q[0], p["p1"])
    L = np.linalg.norm(d, axis=-1)
    e = d / L[:, None]

    def point_velocity(qq, v, s):
        c, sn = np.cos(qq[:, 2]), np.sin(qq[:, 2])
        a = np.stack((c * s[:, 0] - sn * s[:, 1], sn * s[:, 0] + c * s[:, 1]), axis=-1)
        return v[:, :2] + v[:, 2:3] * np.stack((-a[:, 1], a[:, 0]), axis=-1)

    Ld = (e * (point_velocity(q[1], qd[1], p["p2"]) - point_velocity(q[0], qd[0], p["p1"]))
          ).sum(axis=-1)
    f = p["k"] * (L - p["length"]) + p["c"] * Ld
    np.testing.assert_allclose(loads[:, 0, :2], f[:, None] * e, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(loads[:, 1, :2], -f[:, None] * e, rtol=1e-12, atol=1e-12)
    # virtual work: the loads on a small displacement dq do -f dL (a tension resists the
    # stretching), dL by central differences of the length
    h = 1e-6
    dq = tuple(rng.uniform(-1, 1, (N, 3)) for _ in range(2))

    def length(sign):
        moved = tuple(x + sign * h * dx for x, dx in zip(q, dq))
        return np.linalg.norm(_point(moved[1], p["p2"]) - _point(moved[0], p["p1"]), axis=-1)

    dL = (length(1) - length(-1)) / (2 * h)
    np.testing.assert_allclose(_virtual_work(loads, dq), -f * dL, rtol=1e-7, atol=1e-9)


def test_action_and_reaction_of_the_two_body_elements():
    rng = np.random.default_rng(2)
    N = 20
    q = (rng.uniform(-1, 1, (N, 3)), rng.uniform(-1, 1, (N, 3)) + [3.0, 0.0, 0.0])
    qd = (rng.uniform(-1, 1, (N, 3)), rng.uniform(-1, 1, (N, 3)))
    for ftype, p in ((Spring(), {"p1": rng.uniform(-1, 1, (N, 2)),
                                 "p2": rng.uniform(-1, 1, (N, 2)), "k": 2.0, "length": 1.0,
                                 "c": 0.5}),
                     (RotarySpring(), {"k": 2.0, "angle": 0.3, "c": 0.5})):
        loads = force_loads(ftype, q, qd, p, 0.0)
        # no net force, and no net moment about the global origin: n_k + r_k x F_k
        np.testing.assert_allclose(loads[:, 0, :2] + loads[:, 1, :2], 0.0, atol=1e-12)
        moment = sum(loads[:, k, 2] + q[k][:, 0] * loads[:, k, 1] - q[k][:, 1] * loads[:, k, 0]
                     for k in range(2))
        np.testing.assert_allclose(moment, 0.0, atol=1e-11)


def test_the_rotary_spring_damper_against_its_closed_form():
    q = (np.array([[0.0, 0.0, 0.2]]), np.array([[1.0, 2.0, 1.0]]))
    qd = (np.array([[0.0, 0.0, 0.5]]), np.array([[0.0, 0.0, -1.5]]))
    loads = force_loads(RotarySpring(), q, qd, {"k": 3.0, "angle": 0.1, "c": 0.25}, 0.0)
    tau = -(3.0 * (1.0 - 0.2 - 0.1) + 0.25 * (-1.5 - 0.5))
    np.testing.assert_allclose(loads[0], [[0, 0, -tau], [0, 0, tau]], atol=1e-15)


def test_a_point_force_does_the_work_of_its_point():
    rng = np.random.default_rng(3)
    N = 25
    q = (rng.uniform(-1, 1, (N, 3)),)
    s = rng.uniform(-1, 1, (N, 2))
    t = rng.uniform(0, 2, N)
    fx, fy = ExprFunction.of("2 + sin(3*t)", "t"), ExprFunction.of("t^2 - 1", "t")
    loads = force_loads(PointForce(), q, (np.zeros((N, 3)),), {"point": s, "fx": fx,
                                                                "fy": fy}, t)
    F = np.stack((2 + np.sin(3 * t), t**2 - 1), axis=-1)
    h = 1e-6
    dq = (rng.uniform(-1, 1, (N, 3)),)
    dr = (_point(q[0] + h * dq[0], s) - _point(q[0] - h * dq[0], s)) / (2 * h)
    np.testing.assert_allclose(_virtual_work(loads, dq), (F * dr).sum(axis=-1), rtol=1e-7,
                               atol=1e-9)


def test_a_torque_does_the_work_of_its_rotation():
    t = np.linspace(0, 1, 7)
    value = ExprFunction.of("0.5 - t", "t")
    loads = force_loads(Torque(), (np.zeros((7, 3)),), (np.zeros((7, 3)),), {"value": value}, t)
    np.testing.assert_allclose(loads[:, 0], np.stack((0 * t, 0 * t, 0.5 - t), axis=-1))


def test_body_wrench_is_the_moment_about_the_frame_origin():
    b = Body.of(np.array([1.0, 2.0, 0.3]))
    from mechdsl.plugins.geometry import Vec

    fx, fy, n = b.wrench(Vec(3.0, -1.0), Vec(0.5, 0.25))
    a = np.array([np.cos(0.3) * 0.5 - np.sin(0.3) * 0.25, np.sin(0.3) * 0.5 + np.cos(0.3) * 0.25])
    assert (fx, fy) == (3.0, -1.0)
    assert n == pytest.approx(a[0] * -1.0 - a[1] * 3.0, abs=1e-15)


def test_a_spring_of_free_length_zero_pulls_through_its_ends_meeting():
    """A free body on a spring of free length 0 from the ground's origin, starting there
    with a velocity: an isotropic oscillator, r(t) = v0 sin(w t) / w (w^2 = k / m), which
    passes its ends' meeting at every half period. Its loads are k d, finite at d = 0 (the
    run stopped at t = 0 with accelerations that are not numbers before)."""
    import mechdsl

    text = """ground { }
body puck { guess = (0, 0, 0)  mass = 2  inertia = 0.1  v0 = (0.6, -0.8, 0) }
force band: spring(ground.origin, puck.origin, k = 50)
simulate t = 0 .. 2 step 0.01
output x = puck.x, y = puck.y
"""
    res = mechdsl.loads(text, "band.mech").simulate()
    assert res.ok, res.messages
    w = np.sqrt(50 / 2)
    shape = np.sin(w * res.times) / w
    assert np.abs(res["x"] - 0.6 * shape).max() < 1e-8
    assert np.abs(res["y"] + 0.8 * shape).max() < 1e-8


def test_loads_that_are_not_numbers_at_the_start_name_their_force():
    """A spring with a damper whose ends meet has no direction: the run stops at t0 and
    says which force's loads are not numbers on which body (it blamed the constraints of a
    model that has none)."""
    import mechdsl

    text = """ground { }
body puck { guess = (0, 0, 0)  mass = 2  inertia = 0.1  v0 = (0.6, -0.8, 0) }
force band: spring(ground.origin, puck.origin, k = 50, c = 0.5)
simulate t = 0 .. 1 step 0.1
output x = puck.x
"""
    res = mechdsl.loads(text, "band.mech").simulate()
    assert not res.ok
    assert "the loads on puck are not finite numbers at t = 0, from force 'band'" in \
        res.messages[0], res.messages
