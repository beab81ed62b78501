"""Moments and measures of a weighted sample of u (sm.Empirical, issue 24)."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.core.rescale import change_gaussian
from symmon.errors import ArgumentError, ArgumentTypeError, ModelError, SampleSizeWarning, ShapeError
from symmon.measures.conditional import conditional_cov, empirical_conditional_cov
from symmon.propagation import particles

#: Weighted sums of a few thousand terms, compared with numpy's: rounding.
EXACT_RTOL = 1e-10
#: Monte Carlo checks: 5 standard errors.
N_SE = 5.0

x, y, e1, e2 = sp.symbols("x y e1 e2", real=True)
SMOOTH = sm.Model([x, y], [sp.exp(0.3 * x) * y, sp.sin(x) + 0.5 * y**2])
B = np.array([[1.0, 0.0], [0.5, 2.0]])
ADDITIVE = sm.Model([x, y], [sp.exp(0.3 * x) * y + e1, sp.sin(x) + 0.5 * y**2 + 0.5 * e1 + 2 * e2], noise=[e1, e2])
MULT = sm.Model([x, y], [x + y * e1, sp.sin(x) + x * y * e2], noise=[e1, e2])
GENERAL = sm.Model([x, y], [sp.exp(x * e1) + y, sp.sin(x * e2)], noise=[e1, e2])
V = sm.Gaussian([0.1, 0.0], [[0.02, 0.005], [0.005, 0.01]])


def smooth(X: np.ndarray) -> np.ndarray:
    return np.column_stack([np.exp(0.3 * X[:, 0]) * X[:, 1], np.sin(X[:, 0]) + 0.5 * X[:, 1] ** 2])


@pytest.fixture
def cloud(rng) -> sm.Empirical:
    return sm.Empirical(rng.normal([0.5, 1.0], [1.0, 0.5], size=(3000, 2)), rng.uniform(0.2, 1.0, 3000))


def close(a, b, rtol=EXACT_RTOL):
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(1.0, float(np.max(np.abs(b), initial=0.0))))


def test_noise_free_moments_are_the_weighted_sample_moments(cloud):
    m = sm.propagate(SMOOTH, cloud)
    X, p = cloud.samples, cloud.weights
    Y = smooth(X)
    my, mx = p @ Y, p @ X
    close(m.mean, my)
    close(m.cov, (Y - my).T @ ((Y - my) * p[:, None]))
    close(m.cross_cov, (Y - my).T @ ((X - mx) * p[:, None]))
    close(m.input_cov, cloud.cov)
    assert m.stderr["mean"].shape == (2,) and np.all(m.stderr["mean"] > 0)
    assert m.info["particles"] == 3000 and m.info["jackknife_groups"] == particles.GROUPS


def test_chunks_do_not_change_the_moments(cloud, monkeypatch):
    ref = sm.propagate(ADDITIVE, cloud, V)
    monkeypatch.setattr(particles, "CHUNK", 40)  # 75 chunks instead of one
    m = sm.propagate(ADDITIVE, cloud, V)
    for name in ("mean", "cov", "cross_cov", "noise_cross_cov"):
        close(getattr(m, name), getattr(ref, name), 1e-12)
    close(m.stderr["cov"], ref.stderr["cov"], 1e-12)


def test_additive_noise_is_exact_without_a_rule(cloud):
    m = sm.propagate(ADDITIVE, cloud, V, transform=sm.TT1())
    X, p = cloud.samples, cloud.weights
    F = smooth(X)
    mf = p @ F
    close(m.mean, mf + B @ V.mean)
    close(m.cov, (F - mf).T @ ((F - mf) * p[:, None]) + B @ V.cov @ B.T)
    close(m.noise_cross_cov, B @ V.cov)


@pytest.mark.parametrize("model", [MULT, GENERAL], ids=["multiplicative", "general"])
@pytest.mark.parametrize("rule", [sm.TT2(), sm.UT.ut1(), sm.GaussHermite(order=4)], ids=repr)
def test_noise_at_each_particle_is_the_mixture_of_point_masses(cloud, model, rule):
    """A particle is N(x_i, 0): the same numbers as the mixture path with zero covariances
    (which checks too that every rule accepts the zero block)."""
    cloud = sm.Empirical(cloud.samples[:300], cloud.weights[:300])  # the nested Σ_c of 300 point masses is cost enough
    deg = sm.GaussianMixture(cloud.weights, cloud.samples, np.zeros((cloud.n_samples, 2, 2)))
    a = sm.propagate(model, cloud, V, transform=rule)
    b = sm.propagate(model, deg, V, transform=rule)
    for name in ("mean", "cov", "cross_cov", "noise_cross_cov"):
        close(getattr(a, name), getattr(b, name))
    sa, _ = empirical_conditional_cov(model, cloud, V, rule)
    close(sa, conditional_cov(model, deg, V, rule))


def test_duplicated_particles_with_halved_weights_change_nothing(cloud):
    X, w = cloud.samples, cloud.weights
    twice = sm.Empirical(np.vstack([X, X]), np.concatenate([w, w]) / 2)
    for model, v in ((SMOOTH, None), (ADDITIVE, V), (GENERAL, V)):
        a, b = sm.propagate(model, cloud, v), sm.propagate(model, twice, v)
        close(b.mean, a.mean), close(b.cov, a.cov), close(b.cross_cov, a.cross_cov)
        assert sm.nonlinearity(model, twice, v).value == pytest.approx(sm.nonlinearity(model, cloud, v).value,
                                                                       rel=EXACT_RTOL)


def test_weights_are_honoured(cloud):
    X, w = cloud.samples, cloud.weights
    outlier = sm.Empirical(np.vstack([X, [[50.0, -50.0]]]), np.append(w, 0.0))  # weight 0: not there
    assert sm.nonlinearity(SMOOTH, outlier).value == pytest.approx(sm.nonlinearity(SMOOTH, cloud).value, rel=EXACT_RTOL)
    heavy = sm.Empirical(X, np.where(X[:, 0] > 0.5, 10.0, 1.0))  # another measure: other moments
    assert abs(sm.propagate(SMOOTH, heavy).mean[0] - sm.propagate(SMOOTH, cloud).mean[0]) > 0.1


def test_empirical_mon_of_a_mixture_sample_agrees_with_the_mixture_mon(rng):
    U = sm.GaussianMixture([0.3, 0.45, 0.25], [[0.0, 1.0], [1.5, -0.5], [-1.0, 0.5]],
                           [[[0.3, 0.1], [0.1, 0.2]], 0.1 * np.eye(2), [[0.2, -0.05], [-0.05, 0.4]]])
    e = sm.Empirical(U.sample(200_000, rng))
    for model, v in ((SMOOTH, None), (ADDITIVE, V)):
        mon = sm.nonlinearity(model, e, v)
        ref = sm.nonlinearity(model, U, v, transform=sm.GaussHermite(order=12))
        assert mon.stderr > 0 and abs(mon.value - ref.value) < N_SE * mon.stderr


@pytest.mark.parametrize("weight", ["full", "diag"])
def test_unit_invariance_for_particles(cloud, weight):
    S_u, o_u, S_v = np.diag([2.0, 0.5]), np.array([1.0, -3.0]), np.diag([0.1, 4.0])
    S_y = [[3.0, 1.0], [0.0, 0.2]] if weight == "full" else np.diag([3.0, 0.2])
    for model, v in ((SMOOTH, None), (GENERAL, V)):
        ref = sm.nonlinearity(model, cloud, v, weight=weight)
        bar = sm.core.change_units(model, S_u=S_u, o_u=o_u, S_y=S_y, o_y=[5.0, -1.0], S_v=S_v if v else None)
        vb = change_gaussian(v, S_v) if v else None
        m = sm.nonlinearity(bar, change_gaussian(cloud, S_u, o_u), vb, weight=weight)
        assert m.value == pytest.approx(ref.value, rel=1e-9)


def test_angle_outputs_of_a_cloud_across_the_cut(rng):
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], angles=[1])
    e = sm.Empirical(rng.normal([-10.0, 0.0], [0.1, 0.3], size=(2000, 2)))
    m = sm.propagate(polar, e)
    assert abs(abs(m.mean[1]) - np.pi) < 0.01 and m.cov[1, 1] < 0.01


def test_small_effective_sample_size_warns(rng):
    X = rng.normal(size=(500, 2))
    w = np.full(500, 1e-6)
    w[:20] = 1.0  # ESS ≈ 20
    with pytest.warns(SampleSizeWarning, match="effective sample size is 20"):
        sm.nonlinearity(SMOOTH, sm.Empirical(X, w))
    with pytest.warns(SampleSizeWarning):
        sm.propagate(SMOOTH, sm.Empirical(X, w))


def test_bad_particle_inputs_are_named_errors(cloud):
    with pytest.raises(ShapeError, match="u has dimension 1 but the model has 2 inputs"):
        sm.propagate(SMOOTH, sm.Empirical(np.arange(200.0)))
    with pytest.raises(ModelError, match="pass v="):
        sm.nonlinearity(GENERAL, cloud)
    with pytest.raises(ArgumentTypeError, match="v as an Empirical"):
        sm.propagate(GENERAL, cloud, cloud)
    with pytest.raises(ArgumentError, match="already a sample"):
        sm.propagate(GENERAL, cloud, V, transform=sm.MonteCarlo(n=100, seed=0))
    with pytest.raises(ArgumentTypeError, match="pass an Empirical"):
        sm.propagate_many(SMOOTH, [cloud])


@pytest.mark.parametrize("model", [ADDITIVE, GENERAL], ids=["additive", "general"])
def test_mixture_noise_at_each_particle(cloud, model, monkeypatch):
    """Two components of v per particle (and chunks that split no particle's pair): the
    same numbers as the mixture path with point-mass components of u."""
    v = sm.GaussianMixture([0.7, 0.3], [[0.0, 0.0], [0.2, -0.1]], [V.cov, 4 * V.cov])
    cloud = sm.Empirical(cloud.samples[:310], cloud.weights[:310])  # 310: the last chunk is padded
    deg = sm.GaussianMixture(cloud.weights, cloud.samples, np.zeros((cloud.n_samples, 2, 2)))
    monkeypatch.setattr(particles, "CHUNK", 100)
    a = sm.propagate(model, cloud, v, transform=sm.UT.ut1())
    b = sm.propagate(model, deg, v, transform=sm.UT.ut1())
    for name in ("mean", "cov", "cross_cov", "noise_cross_cov"):
        close(getattr(a, name), getattr(b, name))
    sa, _ = empirical_conditional_cov(model, cloud, v, sm.UT.ut1())
    close(sa, conditional_cov(model, deg, v, sm.UT.ut1()))
