"""Moments of a Gaussian-mixture input and noise: the exact mixing of per-component
moments, in one batch (issue 24)."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.errors import ArgumentTypeError, ModelError, ShapeError

#: The mixing identities are exact, and a linear model's per-component moments are closed
#: forms under every rule: rounding of a few sums, relative to the moments' scale.
EXACT_RTOL = 1e-10
#: A one-component mixture goes through the same rule as its Gaussian (the mixing adds
#: a zero between-term and multiplies by 1.0): the same numbers up to rounding.
SAME_RTOL = 1e-12
#: Monte Carlo checks: 5 standard errors of a seeded sample.
N_SE = 5.0
#: A high Gauss–Hermite order per component: its error on the smooth test model is far
#: below the Monte Carlo standard errors it is compared with.
GH_HIGH = sm.GaussHermite(order=12)

x, y, e1, e2 = sp.symbols("x y e1 e2")
A = np.array([[1.0, 2.0], [-0.5, 3.0]])
B = np.array([[0.7, 0.0], [0.2, -1.5]])
c = np.array([0.3, -1.0])
#: y = A u + B v + c: general noise in form (no structure is exploited), linear in fact.
LINEAR = sm.Model([x, y], [A[0, 0] * x + A[0, 1] * y + B[0, 0] * e1 + c[0],
                           A[1, 0] * x + A[1, 1] * y + B[1, 0] * e1 + B[1, 1] * e2 + c[1]], noise=[e1, e2])
POLAR = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], angles=[1])
NOISY = sm.Model([x, y], [sp.sqrt(x**2 + y**2) * (1 + e1), x * sp.exp(e2)], noise=[e1, e2])

U_MIX = sm.GaussianMixture([0.2, 0.5, 0.3], [[0.0, 1.0], [2.0, -1.0], [5.0, 5.0]],
                           [np.eye(2), [[2.0, 0.5], [0.5, 1.0]], 0.1 * np.eye(2)])
V_MIX = sm.GaussianMixture([0.9, 0.1], [[0.0, 0.0], [0.5, -0.2]], [0.01 * np.eye(2), [[1.0, 0.3], [0.3, 0.5]]])
#: Deterministic rules: every one is exact for a linear model.
RULES = [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.UT.ut2(), sm.UT.cubature(), sm.GaussHermite(order=3), sm.Cubature5()]


def close(a, b, rtol):
    scale = max(1.0, float(np.max(np.abs(b), initial=0.0)))
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * scale)


@pytest.mark.parametrize("rule", RULES, ids=repr)
@pytest.mark.parametrize("noise", ["gaussian", "mixture"])
def test_linear_model_has_exact_mixture_moments(rule, noise):
    v = V_MIX if noise == "mixture" else sm.Gaussian([0.1, -0.2], [[0.3, 0.1], [0.1, 0.2]])
    m = sm.propagate(LINEAR, U_MIX, v, transform=rule)
    close(m.mean, A @ U_MIX.mean + B @ v.mean + c, EXACT_RTOL)
    close(m.cov, A @ U_MIX.cov @ A.T + B @ v.cov @ B.T, EXACT_RTOL)
    close(m.cross_cov, A @ U_MIX.cov, EXACT_RTOL)
    close(m.noise_cross_cov, B @ v.cov, EXACT_RTOL)
    close(m.input_cov, U_MIX.cov, EXACT_RTOL)
    assert m.input is U_MIX
    assert m.info["components"] == [U_MIX.n_components * (v.n_components if noise == "mixture" else 1)]


@pytest.mark.parametrize("rule", [sm.TT2(), sm.UT.ut1(), sm.GaussHermite(order=5)], ids=repr)
def test_one_component_mixture_equals_its_gaussian(rule):
    u = sm.Gaussian([3.0, 4.0], [[0.5, 0.1], [0.1, 0.3]])
    v = sm.Gaussian([0.0, 0.0], [[0.01, 0.0], [0.0, 0.04]])
    one = lambda g: sm.GaussianMixture([1.0], g.mean[None], g.cov[None])  # noqa: E731
    for model, args, margs in ((POLAR, (u,), (one(u),)), (NOISY, (u, v), (one(u), one(v)))):
        g = sm.propagate(model, *args, transform=rule)
        h = sm.propagate(model, *margs, transform=rule)
        for name in ("mean", "cov", "cross_cov", "noise_cross_cov", "input_cov"):
            close(getattr(h, name), getattr(g, name), SAME_RTOL)


def test_mixture_moments_agree_with_a_large_sample_of_the_mixture(rng):
    n = 400_000
    m = sm.propagate(NOISY, U_MIX, V_MIX, transform=GH_HIGH)
    U, V = U_MIX.sample(n, rng), V_MIX.sample(n, rng)
    Y = np.column_stack([np.hypot(U[:, 0], U[:, 1]) * (1 + V[:, 0]), U[:, 0] * np.exp(V[:, 1])])
    se = Y.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(Y.mean(axis=0) - m.mean) < N_SE * se)
    D = Y - Y.mean(axis=0)
    for Z, est in ((D[:, [0]] * D[:, [1]], m.cov[0, 1]), (D**2, np.diag(m.cov)),
                   (D[:, [0]] * (U - U.mean(axis=0)), m.cross_cov[0]), (D[:, [1]] * (V - V.mean(axis=0)), m.noise_cross_cov[1])):
        # the standard error of a sample (co)variance: that of the mean of the centred products
        assert np.all(np.abs(Z.mean(axis=0) - est) < N_SE * Z.std(axis=0) / np.sqrt(n))


def test_all_components_go_through_one_batched_call(monkeypatch):
    calls = []
    moments = sm.Transform.moments

    def counting(self, cm, means, covs, *args, **kwargs):
        calls.append(means.shape[0])
        return moments(self, cm, means, covs, *args, **kwargs)

    monkeypatch.setattr(sm.Transform, "moments", counting)
    sm.propagate(NOISY, U_MIX, V_MIX, transform=sm.UT.ut1())
    assert calls == [U_MIX.n_components * V_MIX.n_components]
    calls.clear()
    sm.propagate_many(NOISY, [U_MIX, sm.Gaussian([1.0, 1.0], np.eye(2))], V_MIX, transform=sm.TT2())
    assert calls == [(3 + 1) * 2]


def test_propagate_many_mixes_each_input_as_propagate_does():
    g = sm.Gaussian([1.0, 2.0], np.eye(2))
    b = sm.propagate_many(NOISY, [U_MIX, g], [V_MIX, sm.Gaussian([0.0, 0.0], 0.01 * np.eye(2))], transform=sm.TT2())
    one = sm.propagate(NOISY, U_MIX, V_MIX, transform=sm.TT2())
    close(b.mean[0], one.mean, SAME_RTOL)
    close(b.cov[0], one.cov, SAME_RTOL)
    close(b.cross_cov[0], one.cross_cov, SAME_RTOL)
    close(b.noise_cross_cov[0], one.noise_cross_cov, SAME_RTOL)
    plain = sm.propagate(NOISY, g, sm.Gaussian([0.0, 0.0], 0.01 * np.eye(2)), transform=sm.TT2())
    close(b.mean[1], plain.mean, SAME_RTOL)
    close(b.cov[1], plain.cov, SAME_RTOL)


def test_monte_carlo_mixture_has_jackknife_error_bars():
    m = sm.propagate(LINEAR, U_MIX, V_MIX, transform=sm.MonteCarlo(n=20_000, seed=1))
    exact = A @ U_MIX.mean + B @ V_MIX.mean + c
    se = m.stderr["mean"]
    assert se.shape == (2,) and np.all(se > 0)
    assert np.all(np.abs(m.mean - exact) < N_SE * se)
    exact_cov = A @ U_MIX.cov @ A.T + B @ V_MIX.cov @ B.T
    assert np.all(np.abs(m.cov - exact_cov) < N_SE * m.stderr["cov"])
    assert np.all(np.abs(m.cross_cov - A @ U_MIX.cov) < N_SE * m.stderr["cross_cov"])


def test_angle_outputs_mix_across_the_cut():
    # Two components on either side of the bearing cut at ±π: the mixed bearing is near π, not 0.
    u = sm.GaussianMixture([0.5, 0.5], [[-10.0, 0.5], [-10.0, -0.5]], [0.01 * np.eye(2)] * 2)
    m = sm.propagate(POLAR, u, transform=sm.UT.ut1())
    assert abs(abs(m.mean[1]) - np.pi) < 1e-3
    assert m.cov[1, 1] < 0.01  # the spread of ±0.05 rad, not of a full turn


def test_bad_mixture_inputs_are_named_errors():
    with pytest.raises(ShapeError, match="u has dimension 1 but the model has 2 inputs"):
        sm.propagate(POLAR, sm.GaussianMixture([1.0], [0.0], [1.0]))
    with pytest.raises(ShapeError, match="v has dimension 1 but the model has 2 noise"):
        sm.propagate(NOISY, U_MIX, sm.GaussianMixture([1.0], [0.0], [1.0]))
    with pytest.raises(ModelError, match="pass v="):
        sm.propagate(NOISY, U_MIX)
    with pytest.raises(ArgumentTypeError, match="v must be a symmon.Gaussian or GaussianMixture"):
        sm.propagate(NOISY, U_MIX, "noise")
    with pytest.raises(ArgumentTypeError, match="u is one GaussianMixture"):
        sm.propagate_many(POLAR, U_MIX)
    with pytest.raises(ArgumentTypeError, match="one per input"):
        sm.propagate_many(NOISY, [U_MIX, U_MIX], [V_MIX])


def test_gauss_hermite_error_estimate_of_a_mixture_bounds_its_error():
    smooth = sm.Model([x, y], [sp.exp(0.3 * x) * y, sp.sin(x) + 0.5 * y**2])
    u = sm.GaussianMixture([0.3, 0.7], [[0.0, 1.0], [1.5, -0.5]], [[[0.3, 0.1], [0.1, 0.2]], 0.1 * np.eye(2)])
    m = sm.propagate(smooth, u, transform=sm.GaussHermite(order=5, error_estimate=True))
    ref = sm.propagate(smooth, u, transform=sm.GaussHermite(order=14))  # converged to rounding
    for name in ("mean", "cov", "cross_cov"):
        assert np.all(np.abs(getattr(m, name) - getattr(ref, name)) <= m.error[name] + 1e-14)


def test_advise_takes_a_mixture():
    smooth = sm.Model([x, y], [sp.exp(0.3 * x) * y, sp.sin(x) + 0.5 * y**2])
    u = sm.GaussianMixture([0.3, 0.7], [[0.0, 1.0], [1.5, -0.5]], [[[0.3, 0.1], [0.1, 0.2]], 0.1 * np.eye(2)])
    a = sm.advise(smooth, u, tol=1e-2)
    assert a.reference.startswith("Gauss-Hermite") and a.choice_name is not None
    assert a.reference_mon == pytest.approx(sm.nonlinearity(smooth, u, transform=sm.GaussHermite(order=7)).value,
                                            rel=1e-12)


@settings(max_examples=25, deadline=5000, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_mixture_moments_ignore_the_order_and_splitting_of_components(data):
    """A mixture is a measure: permuting its components, or splitting one into two copies
    with half its weight, changes nothing (to rounding of the reordered sums)."""
    K = data.draw(st.integers(1, 4))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    w = rng.dirichlet(np.ones(K))
    M = rng.normal(size=(K, 2)) * 3
    A = rng.normal(size=(K, 2, 2))
    P = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(2)
    perm = rng.permutation(K)
    j = int(rng.integers(K))
    base = sm.propagate(NOISY, sm.GaussianMixture(w, M, P), V_MIX, transform=sm.UT.ut1())
    shuffled = sm.propagate(NOISY, sm.GaussianMixture(w[perm], M[perm], P[perm]), V_MIX, transform=sm.UT.ut1())
    w2 = np.append(w, w[j] / 2)
    w2[j] /= 2
    split = sm.propagate(NOISY, sm.GaussianMixture(w2, np.vstack([M, M[j]]), np.concatenate([P, P[j][None]])), V_MIX,
                         transform=sm.UT.ut1())
    for other in (shuffled, split):
        for name in ("mean", "cov", "cross_cov", "noise_cross_cov"):
            close(getattr(other, name), getattr(base, name), 1e-11)
