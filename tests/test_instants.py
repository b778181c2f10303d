"""The output instants of a forward-dynamics run, settled together when a variant ends
(mechdsl.solve.instants): every reported state on both constraint manifolds and satisfying
the equations of motion, checked with the model's own Phi, Phi_q, M, Q and gamma, for an
explicit pair (its dense output between steps) and for radau (its collocation polynomial),
on a closed loop with a spring and on a driven slider-crank."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import mechdsl
from mechdsl.compiled import equations as eq
from mechdsl.solve.options import SolverOptions

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import dynamics_models as dm  # noqa: E402

#: a four-bar with a spring from the ground to the coupler, released from rest
LOOP = dm.FOURBAR + """force s: spring(ground.D, coupler.B, k = 40, length = 2)
initial start: angle(crank) = 1.2
simulate t = 0 .. 3 step 0.002
output crank.phi, A.fx
"""

#: a slider-crank driven at a varying speed, a pendulum swinging from its slider
DRIVEN = """
gravity = (0, -9.81)
ground { point O = (0, 0) }
body crank { guess = (0, 0, 0.5)  point O = (0, 0)  point A = (0.2, 0)  mass = 1  inertia = 0.01  centroid = (0.1, 0) }
body rod { guess = (0.2, 0.1, -0.2)  point A = (0, 0)  point B = (0.6, 0)  mass = 0.5  inertia = 0.02  centroid = (0.3, 0) }
body slider { guess = (0.7, 0, 0)  mass = 2  inertia = 0.01 }
joint O: revolute(ground.O, crank.O)
joint A: revolute(crank.A, rod.A)
joint B: revolute(rod.B, slider.origin)
body bob { guess = (0.7, -0.3, -1.5)  point P = (0, 0)  mass = 0.3  inertia = 0.01  centroid = (0.3, 0) }
joint rail: prismatic(ground.O, slider.origin, axis = (1, 0))
joint P: revolute(slider.origin, bob.P)
drive motor: angle(crank) = 0.5 + 3*t + t^2
simulate t = 0 .. 1.5 step 0.003
output slider.x, bob.phi, motor.torque
"""


def _check(text: str, method: str) -> None:
    mech = mechdsl.loads(text)
    res = mech.simulate(options=SolverOptions(method=method), poses=True, rates=True)
    assert res.ok, res.messages
    kernels = mech.compile()
    K = len(res.times)
    q = res.poses[0].reshape(K, -1)[None]
    qd, qdd = (res.rates[0, :, i].reshape(K, -1)[None] for i in (0, 1))
    t = res.times[None]
    n = q.shape[-1]
    phi = eq.constraint_values(kernels, q, t)[0]
    jac = eq.jacobian(kernels, q)[0]
    nu = eq.velocity_rhs(kernels, t, (1, K))[0]
    speed = np.abs(qd[0]).max()
    assert np.abs(phi).max() < 1e-10
    assert np.abs((jac @ qd[0][..., None])[..., 0] - nu).max() < 1e-10 * (1 + speed)
    # the equations of motion at every instant: Phi_q qdd = gamma, and M qdd - Q in the
    # range of Phi_q^T (the reactions): its part normal to that range vanishes
    gamma = eq.acceleration_rhs(kernels, q, qd, t)[0]
    assert np.abs((jac @ qdd[0][..., None])[..., 0] - gamma).max() < 1e-8 * (
        1 + np.abs(gamma).max())
    d = kernels.dynamics
    force = (d.mass_matrix(q)[0] @ qdd[0][..., None])[..., 0] - d.generalised_forces(q, qd, t)[0]
    assert jac.shape[1] < n  # (a free coordinate is left)
    for k in range(K):
        basis = np.linalg.svd(jac[k])[2][jac.shape[1]:]  # the null space of Phi_q
        assert np.abs(basis @ force[k]).max() < 1e-8 * (1 + np.abs(force[k]).max()), k


@pytest.mark.parametrize("method", ["auto", "radau"])
def test_every_output_of_a_loop_is_on_its_manifolds_and_its_equations(method):
    _check(LOOP, method)


@pytest.mark.parametrize("method", ["auto", "radau"])
def test_every_output_of_a_driven_slider_crank_is_on_its_manifolds_and_its_equations(method):
    _check(DRIVEN, method)


def test_a_ctrl_c_while_the_instants_are_completed_keeps_them(monkeypatch):
    """A KeyboardInterrupt inside the completion (here the batched accelerations): the run
    says interrupted and keeps every instant integrated, on the constraints."""
    from mechdsl.solve import instants

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(instants, "accelerations", interrupt)
    mech = mechdsl.loads(LOOP)
    res = mech.simulate(poses=True)
    assert res.status == "interrupted"
    assert np.isfinite(res["crank.phi"]).all()
    K = len(res.times)
    phi = eq.constraint_values(mech.compile(), res.poses[0].reshape(K, -1)[None],
                               res.times[None])[0]
    assert np.abs(phi).max() < 1e-10
