"""Relative coordinates for radau (mechdsl.solve.relative): the map and its derivatives
against finite differences, the transformed equations against the absolute ones' solution,
the forest, and a run that tries them and goes back (a fast loop: against its energy); the
runs that go on in them are in test_reduced.py."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import mechdsl
from mechdsl.solve.motion import Motion
from mechdsl.solve.options import SolverOptions
from mechdsl.solve.relative import RELATIVE_GAIN, Relative, forest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import dynamics_models as dm  # noqa: E402


class _Shape:
    """A base with n coordinates and no equations (the map alone)."""

    def __init__(self, n: int) -> None:
        self.n, self.m = n, 0


def _loop_text(k: float, t1: float = 2.0, rate: float = 8.0) -> str:
    """A four-bar turning at ``rate`` rad/s whose coupler carries a bob on a slider with a
    spring of stiffness k along it (its rest length at t0, no rate along it)."""
    return dm.FOURBAR + f"""body bob {{ guess = (1.5, 1, 0)  mass = 0.5  inertia = 0.01 }}
joint slide: prismatic(coupler.B, bob.origin, axis = (1, 0))
force spring: spring(coupler.B, bob.origin, k = {k!r}, length = 1.5)
initial start: angle(crank) = 1.2, rate = {rate!r}
initial put: distance(coupler.B, bob.origin) = 1.5, rate = 0
simulate t = 0 .. {t1} step 0.01, rtol = 1e-6, atol = 1e-8
output kinetic_energy, potential_energy
"""


def _fd(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central differences of f at x, column by column."""
    return np.column_stack([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(x.size)])


@pytest.mark.parametrize("points", [None, [(0.3, -0.2), (-0.5, 0.1), (0.0, 0.0), (0.7, 0.4)]])
def test_the_map_its_derivatives_and_the_convective_term_match_finite_differences(points):
    # a branching forest: 0 on the ground, 1 and 3 on 0, 2 on 1; with reference points
    # off the frames' origins too (s_i the point's position in the parent's frame)
    rel = Relative(_Shape(12), np.array([-1, 0, 1, 0]), points)
    rng = np.random.default_rng(1)
    z, zd = rng.normal(size=12), rng.normal(size=12)
    _, G = rel._map(z)
    G = G.copy()
    assert np.abs(G - _fd(lambda x: rel._map(x)[0].copy(), z)).max() < 1e-8
    qd, c, H = (a.copy() for a in rel._rates(z, zd, with_h=True))
    assert np.abs(qd - G @ zd).max() < 1e-14
    assert np.abs(H - _fd(lambda x: rel._rates(x, zd)[0].copy(), z)).max() < 1e-8
    # c = dG/dt zd: G's derivative along zd, by differences
    dG = (rel._map(z + 1e-6 * zd)[1].copy() - rel._map(z - 1e-6 * zd)[1].copy()) / 2e-6
    assert np.abs(c - dG @ zd).max() < 1e-8
    y = np.concatenate((z, zd))
    assert np.abs(rel.relative(rel.absolute(y)) - y).max() < 1e-14


def _loop_motion(k: float = 1e10):
    kernels = mechdsl.loads(_loop_text(k), "loop.mech").compile()
    motion = Motion(kernels, SolverOptions())
    forces = tuple(f.bodies for f in kernels.dynamics.forces)
    return kernels, motion, forest(kernels.system, forces)


def test_the_forest_hangs_the_bob_from_the_body_its_spring_pulls():
    kernels, _, parent = _loop_motion()
    names = kernels.system.body_names
    index = {name: i for i, name in enumerate(names)}
    # crank and rocker from the ground, the coupler from the crank, the bob from the
    # coupler, whose slider its spring spans (not from anything else)
    assert parent[index["crank"]] == -1 and parent[index["rocker"]] == -1
    assert parent[index["coupler"]] == index["crank"]
    assert parent[index["bob"]] == index["coupler"]


def test_the_transformed_equations_hold_at_the_absolute_solution():
    """At a consistent state: G zdd + c = qdd and the same multipliers, so that the
    relative force balance G^T M G zdd + (Phi_q G)^T lambda = G^T (Q - M c) and
    Phi_q G zdd = gamma - Phi_q c hold with the absolute coordinates' qdd and lambda; the
    velocity derivative of the loads is exact (differences), and the position derivative
    holds the spring's stiffness."""
    kernels, motion, parent = _loop_motion(1e6)
    rel = Relative(motion, parent)
    q = kernels.system.guess[0]
    y = motion.project(0.0, np.concatenate((q, np.random.default_rng(2).normal(size=q.size))))
    n = motion.n
    qdd, lam = motion.accelerations(0.0, y[:n], y[n:])
    yr = rel.relative(y)
    z, zd = yr[:n], yr[n:]
    zdd, lam_r = rel.accelerations(0.0, z, zd)
    _, G, _, _, c = rel._state(z, zd)
    assert np.abs(G @ zdd + c - qdd).max() < 1e-9 * (1 + np.abs(qdd).max())
    assert np.abs(lam_r - lam).max() < 1e-9 * (1 + np.abs(lam).max())
    Mz, Qz = rel.mass_loads(0.0, z, zd)
    _, jz = rel.phi_jac(0.0, z)
    balance = Mz @ zdd + jz.T @ lam - Qz
    assert np.abs(balance).max() < 1e-9 * (np.abs(Qz).max() + np.abs(jz.T @ lam).max())
    assert np.abs(jz @ zdd - rel.gamma(0.0, z, zd)).max() < 1e-8
    dq, dv = rel.load_derivatives(0.0, z, zd)
    # (the loads are quadratic in zd: central differences are exact but for round-off,
    # least at a long step)
    assert np.abs(dv - _fd(lambda v: rel.loads(0.0, z, v), zd, 1e-3)).max() < 1e-6
    bob = 3 * kernels.system.body_names.index("bob")
    along = _fd(lambda x: rel.loads(0.0, x, zd), z)[bob, bob]  # the slider's coordinate
    assert dq[bob, bob] == pytest.approx(along, rel=1e-6) and along < -0.9e6


def test_a_fast_loop_tries_relative_coordinates_and_goes_back():
    """The four-bar turning at 8 rad/s with its stiff slider spring: radau's steps are held
    by the motion's accuracy in either coordinates; the relative ones' are not
    RELATIVE_GAIN times longer and the run goes back. Its energy T + V within 1e-5 of its
    start over 0.5 s (conservative: no damper), the constraints to 1e-10."""
    res = mechdsl.loads(_loop_text(1e10, t1=0.5), "loop.mech").simulate(
        options=SolverOptions(method="radau"))
    assert res.ok, res.messages
    assert "absolute ones kept" in res.method, res.method
    assert f"under {RELATIVE_GAIN:g}" in res.method
    energy = res.data["kinetic_energy"][0] + res.data["potential_energy"][0]
    assert np.abs(energy - energy[0]).max() < 1e-5 * abs(energy[0])
    assert res.residual < 1e-10


def test_relative_coordinates_are_tried_only_where_a_force_acts_across_a_joint():
    """A02 with four windows (27 coordinates, under relative_max) has no force element:
    the stages that need their own Jacobians at its first collinear passage (t = 0.72) have
    a singular position as their cause, not a force that turns, and the run stays in
    absolute coordinates (it tried relative ones there before); B0 on the parallelogram
    branch's oracle. The stiff pendulum's spring acts across the joint its forest takes."""
    from mechdsl.solve.relative import spanned_joints

    res = mechdsl.loads(dm.a02_text(4, t1=1.0), "a02.mech").simulate(
        options=SolverOptions(method="radau"))
    assert res.ok, res.messages
    assert "relative" not in res.method, res.method
    b0 = np.column_stack((res.data["b0x"][0], res.data["b0y"][0]))
    assert np.abs(b0 - dm.a02_oracle(res.times, 4)).max() < 1e-6
    pend = mechdsl.loads(dm.stiff_pendulum_text(1e8), "pendulum.mech").compile()
    forces = pend.dynamics.forces
    assert spanned_joints(pend.system, forces) == ["spring"]
    a02 = mechdsl.loads(dm.a02_text(4, t1=1.0), "a02.mech").compile()
    assert spanned_joints(a02.system, a02.dynamics.forces) == []


def test_the_forest_takes_a_spanned_joint_even_where_another_reaches_the_body_sooner():
    """Prim's choice, not breadth first: ``a`` and ``b`` both pinned to the ground, a
    slider with a spring between them; ``b`` hangs from ``a`` (the spring's joint), the
    ground's pin at ``b`` left as a loop's closure. Two bodies tied only to each other hang
    one from the other, the first from the ground."""
    text = """ground { point P = (0, 0)  point R = (2, 0) }
body a { guess = (0, 0, 0)  point S = (1, 0)  mass = 1  inertia = 0.1 }
body b { guess = (2, 0, 0)  mass = 1  inertia = 0.1 }
body c { guess = (5, 0, 0)  mass = 1  inertia = 0.1 }
body d { guess = (6, 0, 0)  mass = 1  inertia = 0.1 }
joint pa: revolute(ground.P, a.origin)
joint pb: revolute(ground.R, b.origin)
joint ab: prismatic(a.S, b.origin, axis = (1, 0))
joint cd: revolute(c.origin, d.origin)
force spring: spring(a.S, b.origin, k = 100, length = 1)
simulate t = 0 .. 1 step 0.1
"""
    kernels = mechdsl.loads(text, "prim.mech").compile()
    index = {name: i for i, name in enumerate(kernels.system.body_names)}
    parent = forest(kernels.system, tuple(f.bodies for f in kernels.dynamics.forces))
    assert parent[index["a"]] == -1 and parent[index["b"]] == index["a"]
    assert parent[index["c"]] == -1 and parent[index["d"]] == index["c"]
    # without the spring, breadth first: both from the ground
    assert list(forest(kernels.system, ())[[index["a"], index["b"]]]) == [-1, -1]


def test_a_trial_that_met_a_singular_position_is_not_quoted_to_three_digits():
    """The relative-coordinates note quotes the work per simulated second as a ratio; a
    trial whose steps collapsed at a singular position (trial 49's driven parallelogram
    under radau: "8.15e+07 times more work") measures that position, not the coordinates,
    and is said as "over 1000 times"."""
    from mechdsl.solve.relative import _ratio

    assert _ratio(6.43) == "6.43 times less"
    assert _ratio(1 / 3.38) == "3.38 times more"
    assert _ratio(1 / 8.15e7) == "over 1000 times more"
    assert _ratio(2e4) == "over 1000 times less"
