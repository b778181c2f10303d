import numpy as np
import pytest

import mechdsl
from mechdsl.plugins import build_registry
from mechdsl.testing import ContractViolation, check_constraint_type
from mechdsl_revolute import Revolute


def test_revolute_meets_the_contract():
    check_constraint_type(Revolute(), samples=50)


def test_phi_is_the_gap_between_the_two_points():
    # body i at (1, 2) turned 90 degrees: its point (1, 0) is at (1, 3);
    # body j at the origin, unturned: its point (0.5, 0.5) is at (0.5, 0.5)
    q = (np.array([1.0, 2.0, np.pi / 2]), np.array([0.0, 0.0, 0.0]))
    p = {"p1": np.array([1.0, 0.0]), "p2": np.array([0.5, 0.5])}
    np.testing.assert_allclose(Revolute().phi(q, p), [0.5, 2.5], atol=1e-15)


def test_gamma_is_the_centripetal_term():
    # a pin at distance 1 on a body spinning at 3 rad/s: gamma = A s' w^2 = (9, 0) at phi = 0
    q = (np.zeros(3), np.zeros(3))
    qd = (np.array([0.0, 0.0, 3.0]), np.zeros(3))
    p = {"p1": np.array([1.0, 0.0]), "p2": np.zeros(2)}
    np.testing.assert_allclose(Revolute().gamma(q, qd, p), [9.0, 0.0])


def test_a_wrong_jacobian_is_caught():
    class Broken(Revolute):
        def jacobian_terms(self, bodies, args):
            # Phi_q = [ I  B_i s'_i | -I  -B_j s'_j ] with B s' = perp(A s'), one entry 1 % off
            bi, bj = bodies[0].rotate(args.p1).perp(), bodies[1].rotate(args.p2).perp()
            return ([[1, 0, bi.x * 1.01], [0, 1, bi.y]],
                    [[-1, 0, -bj.x], [0, -1, -bj.y]])

    with pytest.raises(ContractViolation, match="Jacobian block 0"):
        check_constraint_type(Broken())


def test_pendulum_point_follows_the_circle():
    # a link pinned at its end to the ground, driven in angle: the free end is at L e(theta)
    registry = build_registry(["mechdsl_revolute", "mechdsl_drives"], entry_points=False)
    mech = mechdsl.loads("""
        param L = 0.7
        body link { guess = (0.3, 0.1, 0.2)  point O = (-L/2, 0)  point E = (L/2, 0) }
        joint pin: revolute(ground.origin, link.O)
        drive d: angle(link) = 0.3 + 2*t + t^2
        simulate t = 0 .. 2 step 0.01
        output link.E
    """, registry=registry)
    res = mech.simulate()
    t = res["t"]
    th, w, al = 0.3 + 2 * t + t**2, 2 + 2 * t, 2.0
    L = 0.7
    np.testing.assert_allclose(res["link.E.x"], L * np.cos(th), atol=1e-13)
    np.testing.assert_allclose(res["link.E.y"], L * np.sin(th), atol=1e-13)
    np.testing.assert_allclose(res["link.E.vx"], -L * np.sin(th) * w, atol=1e-12)
    np.testing.assert_allclose(res["link.E.vy"], L * np.cos(th) * w, atol=1e-12)
    np.testing.assert_allclose(res["link.E.ax"], -L * (np.cos(th) * w**2 + np.sin(th) * al),
                               atol=1e-11)
    np.testing.assert_allclose(res["link.E.ay"], L * (-np.sin(th) * w**2 + np.cos(th) * al),
                               atol=1e-11)
