"""The fused evaluation of a whole model (mechdsl/compiled/fused.py) and the band LU of large
ones (mechdsl/compiled/band.py), on real models: the Jacobian against finite differences of
Phi, gamma against the second derivative of Phi along q + qd t (qdd = 0), the member and group
layouts against each other, sweeps against single-valued models, the band LU against numpy.

The fused kernels leave the drives' f(t) to the caller: Phi is g(q) for a drive's row and
gamma is -(g_q qd)_q qd, so the identities hold for every row as written."""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
import pytest

import mechdsl
from conftest import EXAMPLES, ROOT
from mechdsl.api import Overrides
from mechdsl.compiled.band import BandLU, band_plan
from mechdsl.compiled.fused import MEMBER_LIMIT, fuse

sys.path.insert(0, str(ROOT / "benchmarks"))
import models  # noqa: E402

EXAMPLE_FILES = ["slider_crank.mech", "fourbar.mech", "cam_roller.mech"]


@pytest.fixture(scope="module")
def compiled(registry):
    """name -> compiled system: the examples, a short chain (member layout) and a longer one
    (more than MEMBER_LIMIT constraints: the group layout)."""
    out = {name: mechdsl.load(EXAMPLES / name, registry=registry).compile()
           for name in EXAMPLE_FILES}
    out["chain5"] = mechdsl.loads(models.chain_text(5), "chain5.mech",
                                  registry=registry).compile()
    out["chain20"] = mechdsl.loads(models.chain_text(20), "chain20.mech",
                                   registry=registry).compile()
    return out


MODELS = EXAMPLE_FILES + ["chain5", "chain20"]


def _states(kernels, seed: int, b: int = 4, spread: float = 0.05):
    """q (V, b, n) near the guess and qd (V, b, n) of order one."""
    rng = np.random.default_rng(seed)
    V, n = kernels.system.n_variants, kernels.system.n
    q = kernels.system.guess[:, None, :] + spread * rng.normal(size=(V, b, n))
    qd = rng.normal(size=(V, b, n))
    return q, qd


def test_layouts_chosen_by_size(compiled):
    assert compiled["slider_crank.mech"].fused.layout == "member"
    assert compiled["chain5"].fused.layout == "member"
    big = compiled["chain20"]
    assert len(big.system.constraints) > MEMBER_LIMIT
    assert big.fused.layout == "group"


@pytest.mark.parametrize("name", MODELS)
def test_jacobian_is_the_derivative_of_phi(compiled, name):
    kernels = compiled[name]
    f = kernels.fused
    q, _ = _states(kernels, 1)
    values = f.evaluate_jac(q)
    assert values.shape == q.shape[:-1] + (len(f.rows),)
    jac = f.dense(values)
    assert jac.shape == q.shape[:-1] + (kernels.system.m, kernels.system.n)
    fd = np.empty_like(jac)
    for k in range(kernels.system.n):
        h = 1e-6 * max(1.0, float(np.abs(q[..., k]).max()))
        qp, qm = q.copy(), q.copy()
        qp[..., k] += h
        qm[..., k] -= h
        fd[..., k] = (f.evaluate_phi(qp) - f.evaluate_phi(qm)) / (2 * h)
    # the whole dense matrix: the entries outside the pattern are zero in the differences too
    np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-7)
    # the pattern is sorted by (row, column), without repeats
    keys = f.rows * kernels.system.n + f.cols
    assert (np.diff(keys) > 0).all()


@pytest.mark.parametrize("name", MODELS)
def test_phi_jac_is_phi_and_jac(compiled, name):
    system = compiled[name]
    f = system.fused
    q, _ = _states(system, 2)
    phi, jac = f.evaluate_phi_jac(q)
    np.testing.assert_allclose(phi, f.evaluate_phi(q), rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(jac, f.evaluate_jac(q), rtol=1e-15, atol=1e-15)


def _second_derivative_along(phi, q, qd, h):
    """d^2/ds^2 phi(q + qd s) at s = 0: second differences at h and h/2, Richardson."""
    def d2(step):
        return (phi(q + step * qd) - 2 * phi(q) + phi(q - step * qd)) / step**2
    return (4 * d2(h / 2) - d2(h)) / 3


KNOT = 2 * np.pi / 180  # the spacing of examples/data/cam_pitch.csv's psi


def _gamma_states(kernels, name: str, seed: int):
    """States for the second-difference check. The cam's pitch curve is a cubic spline, only
    C2 at its knots: there, the cam's angle is set so that the polar angle psi of the roller
    (cam_roller's definition: the angle of follower - cam in the cam's frame) lies mid-way
    between two knots, and the speeds are small enough that q + qd s stays in that piece."""
    q, qd = _states(kernels, seed)
    if name != "cam_roller.mech":
        return q, qd
    assert kernels.system.body_names == ("cam", "follower")
    rng = np.random.default_rng(seed + 100)
    psi0 = np.arctan2(q[..., 4] - q[..., 1], q[..., 3] - q[..., 0])
    q[..., 2] = psi0 - (rng.integers(0, 180, size=psi0.shape) + 0.5) * KNOT
    return q, 0.1 * qd


def _psi(q):
    return np.arctan2(q[..., 4] - q[..., 1], q[..., 3] - q[..., 0]) - q[..., 2]


@pytest.mark.parametrize("name", MODELS)
def test_gamma_is_minus_the_second_derivative_along_the_motion(compiled, name):
    kernels = compiled[name]
    f = kernels.fused
    q, qd = _gamma_states(kernels, name, 3)
    h = 2e-3
    if name == "cam_roller.mech":  # the path stays inside one piece of the spline
        assert (np.abs(_psi(q + h * qd) - _psi(q)) < 0.4 * KNOT).all()
        assert (np.abs(_psi(q - h * qd) - _psi(q)) < 0.4 * KNOT).all()
    gamma = f.evaluate_gamma(q, qd)
    assert gamma.shape == q.shape[:-1] + (kernels.system.m,)
    want = -_second_derivative_along(f.evaluate_phi, q, qd, h)
    np.testing.assert_allclose(gamma, want, rtol=1e-6, atol=1e-6)
    # and gamma is not identically zero (the check has something to compare)
    assert np.abs(gamma).max() > 1e-3


@pytest.mark.parametrize("name", MODELS)
def test_gamma_is_minus_the_jacobians_derivative_along_qd(compiled, name):
    """gamma = -(Phi_q qd)_q qd: a first difference of the fused Jacobian times qd, at any
    state (the spline's kinks are in its third derivative, beyond what this difference sees
    at h = 1e-6)."""
    system = compiled[name]
    f = system.fused
    q, qd = _states(system, 10)
    h = 1e-6

    def jqd(x):
        return np.einsum("...ij,...j->...i", f.dense(f.evaluate_jac(x)), qd)
    want = -(jqd(q + h * qd) - jqd(q - h * qd)) / (2 * h)
    np.testing.assert_allclose(f.evaluate_gamma(q, qd), want, rtol=1e-6, atol=1e-6)


def _both_layouts(kernels):
    data = kernels.system
    member = fuse(list(data.groups), data.n_bodies, data.m, force="member")
    group = fuse(list(data.groups), data.n_bodies, data.m, force="group")
    assert (member.layout, group.layout) == ("member", "group")
    return member, group


@pytest.mark.parametrize("name", MODELS)
def test_member_and_group_layouts_agree(compiled, name):
    system = compiled[name]
    member, group = _both_layouts(system)
    q, qd = _states(system, 4)
    np.testing.assert_allclose(group.evaluate_phi(q), member.evaluate_phi(q),
                               rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(group.dense(group.evaluate_jac(q)),
                               member.dense(member.evaluate_jac(q)), rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(group.evaluate_gamma(q, qd), member.evaluate_gamma(q, qd),
                               rtol=1e-13, atol=1e-13)
    phi, jac = group.evaluate_phi_jac(q)
    np.testing.assert_allclose(phi, member.evaluate_phi(q), rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(group.dense(jac), member.dense(member.evaluate_jac(q)),
                               rtol=1e-14, atol=1e-14)


def test_a_body_attached_twice_gets_the_derivative_of_phi(compiled):
    """One constraint attaching one body in two slots (the compiler refuses it for a joint,
    not for a drive of two bodies): its Jacobian is still the derivative of its Phi. The
    group layout cannot scatter two values into one entry and falls back to the member
    layout. (Revolute derives its Jacobian: the gradient in the shared variables is already
    the total derivative, for either slot.)"""
    kernels = compiled["slider_crank.mech"]
    groups = list(kernels.system.groups)
    revolute = next(g for g in groups if g.ctype.name == "revolute")
    slots = np.array(revolute.slots)
    slots[1] = [0, 0]  # joint B: the crank to itself
    groups[groups.index(revolute)] = replace(revolute, slots=slots)
    q, _ = _states(kernels, 11)
    for force in ("member", "group"):
        f = fuse(groups, kernels.system.n_bodies, kernels.system.m, force=force)
        assert f.layout == "member"
        jac = f.dense(f.evaluate_jac(q))
        fd = np.empty_like(jac)
        for k in range(kernels.system.n):
            qp, qm = q.copy(), q.copy()
            qp[..., k] += 1e-6
            qm[..., k] -= 1e-6
            fd[..., k] = (f.evaluate_phi(qp) - f.evaluate_phi(qm)) / 2e-6
        np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-7)
        # rows 2, 3 (joint B) depend on the crank's angle through both of its points
        assert np.abs(jac[..., 2:4, 2]).min() > 0


def test_a_drive_of_one_body_twice_with_supplied_terms(loads):
    """A real model: the distance drive (which supplies its Jacobian per body) between two
    points of one body; its supplied blocks are added into one entry per coordinate."""
    text = (EXAMPLES / "slider_crank.mech").read_text().replace(
        "drive crank_angle: angle(crank) = pi/4 + omega*t",
        "drive crank_angle: angle(crank) = pi/4 + omega*t\n"
        "drive span: distance(crank.A, rod.B) = 2\n"
        "drive both: distance(crank.A, crank.B) = 2")
    kernels = loads(text).compile(need_times=False)
    f = kernels.fused
    q, _ = _states(kernels, 12)
    jac = f.dense(f.evaluate_jac(q))
    fd = np.empty_like(jac)
    for k in range(kernels.system.n):
        qp, qm = q.copy(), q.copy()
        qp[..., k] += 1e-6
        qm[..., k] -= 1e-6
        fd[..., k] = (f.evaluate_phi(qp) - f.evaluate_phi(qm)) / 2e-6
    np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-7)
    # the span drive (two bodies) does depend on q: the comparison is not all zeros
    assert np.abs(jac[..., -2, :]).max() > 0.1


# -- sweeps --------------------------------------------------------------------------------

SWEEPS = [("slider_crank.mech", "l", [3.0, 3.5, 4.0]),
          ("cam_flat.mech", "e", [0.005, 0.01, 0.02])]  # e: inside a function argument


@pytest.mark.parametrize("example,param,values", SWEEPS)
def test_each_variant_is_the_model_with_that_value(registry, example, param, values):
    mech = mechdsl.load(EXAMPLES / example, registry=registry)
    swept = mech.compile(Overrides(sweeps={param: values}))
    assert swept.system.n_variants == len(values)
    rng = np.random.default_rng(5)
    # one set of states for every variant: the differences come from the param alone
    q = swept.system.guess[:1, None, :] + 0.05 * rng.normal(size=(1, 4, swept.system.n))
    q = np.repeat(q, len(values), axis=0)
    qd = np.repeat(rng.normal(size=(1, 4, swept.system.n)), len(values), axis=0)
    layouts = {"default": swept.fused, **dict(zip(("member", "group"), _both_layouts(swept)))}
    phis = {}
    for v, value in enumerate(values):
        single = mech.compile(Overrides(params={param: value})).fused
        want_phi = single.evaluate_phi(q[v : v + 1])
        want_jac = single.dense(single.evaluate_jac(q[v : v + 1]))
        want_gamma = single.evaluate_gamma(q[v : v + 1], qd[v : v + 1])
        for label, f in layouts.items():
            phi = f.evaluate_phi(q)
            phis[label, v] = phi[v]
            np.testing.assert_allclose(phi[v : v + 1], want_phi, rtol=1e-14, atol=1e-15,
                                       err_msg=label)
            np.testing.assert_allclose(f.dense(f.evaluate_jac(q))[v : v + 1], want_jac,
                                       rtol=1e-14, atol=1e-15, err_msg=label)
            np.testing.assert_allclose(f.evaluate_gamma(q, qd)[v : v + 1], want_gamma,
                                       rtol=1e-13, atol=1e-13, err_msg=label)
    # the param does change Phi: the variants differ
    assert not np.allclose(phis["default", 0], phis["default", 2])


@pytest.mark.parametrize("example,param,values", SWEEPS)
def test_variant_is_the_slice(registry, example, param, values):
    swept = mechdsl.load(EXAMPLES / example, registry=registry).compile(
        Overrides(sweeps={param: values}))
    q, qd = _states(swept, 6)
    for f in (swept.fused, *_both_layouts(swept)):
        phi, jac, gamma = f.evaluate_phi(q), f.evaluate_jac(q), f.evaluate_gamma(q, qd)
        for v in range(len(values)):
            one = f.variant(v)
            sl = slice(v, v + 1)
            np.testing.assert_array_equal(one.evaluate_phi(q[sl]), phi[sl])
            np.testing.assert_array_equal(one.evaluate_jac(q[sl]), jac[sl])
            np.testing.assert_array_equal(one.evaluate_gamma(q[sl], qd[sl]), gamma[sl])


# -- band LU -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def long_chain(registry):
    return mechdsl.loads(models.chain_text(60), "chain60.mech", registry=registry).compile()


def test_band_plan_of_a_long_chain_is_narrow(long_chain):
    kernels = long_chain
    p = band_plan(kernels.system.pattern.rows, kernels.system.pattern.cols, kernels.system.n)
    assert p is not None and p.n == kernels.system.n == 363
    assert p.kl <= 6 and p.ku <= 6
    # prow, pcol are permutations, and every entry lies inside the band after them
    n = kernels.system.n
    assert sorted(p.prow) == list(range(n)) and sorted(p.pcol) == list(range(n))
    rank_r = np.argsort(p.prow)
    rank_c = np.argsort(p.pcol)
    d = rank_c[kernels.system.pattern.cols] - rank_r[kernels.system.pattern.rows]
    assert d.min() >= -p.kl and d.max() <= p.ku


def _check_band(p, values, A, b):
    lu = BandLU(p, values)
    assert lu.ok
    x = lu.solve(b)
    want = np.linalg.solve(A, b)
    np.testing.assert_allclose(x, want, rtol=1e-8, atol=1e-9 * np.abs(want).max())
    z = lu.solve_transposed(b)
    want_t = np.linalg.solve(A.T, b)
    np.testing.assert_allclose(z, want_t, rtol=1e-8, atol=1e-9 * np.abs(want_t).max())
    sign = lu.sign()
    assert sign == np.linalg.slogdet(A)[0]
    return sign


def test_band_lu_on_the_chains_jacobian(long_chain):
    kernels = long_chain
    f = kernels.fused
    p = band_plan(kernels.system.pattern.rows, kernels.system.pattern.cols, kernels.system.n)
    q, _ = _states(kernels, 7, b=3)
    values = f.evaluate_jac(q)[0]
    rng = np.random.default_rng(8)
    for i in range(values.shape[0]):
        A = f.dense(values[i])
        _check_band(p, values[i], A, rng.normal(size=kernels.system.n))


def test_band_lu_on_random_values_of_the_pattern():
    """Any values in the chain's pattern (partial pivoting inside the band); both signs of
    the determinant; negating one row flips the sign."""
    rng = np.random.default_rng(9)
    # a pattern of the same kind: rows and columns of a banded matrix, shuffled
    n, kl, ku = 200, 3, 2
    i, j = np.nonzero(np.triu(np.tril(np.ones((n, n), bool), kl), -ku))
    rperm, cperm = rng.permutation(n), rng.permutation(n)
    rows, cols = rperm[i], cperm[j]
    order = np.argsort(rows * n + cols)
    rows, cols = rows[order], cols[order]
    p = band_plan(rows, cols, n)
    assert p is not None
    d = np.argsort(p.pcol)[cols] - np.argsort(p.prow)[rows]
    assert d.min() >= -p.kl and d.max() <= p.ku and p.kl + p.ku + 1 <= 0.1 * n
    signs = set()
    for _ in range(6):
        values = rng.normal(size=len(rows))
        A = np.zeros((n, n))
        A[rows, cols] = values
        b = rng.normal(size=n)
        sign = _check_band(p, values, A, b)
        signs.add(sign)
        flipped = np.where(rows == rows[0], -values, values)
        A2 = A.copy()
        A2[rows[0]] *= -1
        assert _check_band(p, flipped, A2, b) == -sign
    assert signs == {-1.0, 1.0}


def test_band_plan_refuses_wide_and_structurally_singular_patterns(registry):
    short = mechdsl.loads(models.chain_text(3), "chain3.mech", registry=registry).compile()
    # 21 coordinates: a band of 9 is not narrow
    assert band_plan(short.system.pattern.rows, short.system.pattern.cols, short.system.n) is None
    # a column without entries: no zero-free diagonal
    n = 100
    rows = np.concatenate((np.arange(n), np.arange(n - 1)))
    cols = np.concatenate((np.arange(n), np.arange(1, n)))
    keep = cols != 40
    assert band_plan(rows[keep], cols[keep], n) is None
    assert band_plan(rows, cols, n) is not None
