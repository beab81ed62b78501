"""GaussianMixture and Empirical: validation, moments, sampling, marginals, display (issue 24)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.core.mixture import WEIGHT_SUM_ATOL, mixture_moments
from symmon.errors import ArgumentError, ArgumentTypeError, CovarianceError, ShapeError, SymmonError, WeightError

#: Closed forms (sums of a few products) agree to rounding.
CLOSED_FORM_RTOL = 1e-12
#: Monte Carlo checks: 5 standard errors of a seeded sample.
N_SE = 5.0
#: Property tests: bounded, with a deadline that a slow example cannot pass silently.
FUZZ = dict(deadline=2000, suppress_health_check=[HealthCheck.too_slow])

W3 = [0.2, 0.5, 0.3]
M3 = [[0.0, 1.0], [2.0, -1.0], [5.0, 5.0]]
P3 = [np.eye(2), [[2.0, 0.5], [0.5, 1.0]], 0.1 * np.eye(2)]


def mix3() -> sm.GaussianMixture:
    return sm.GaussianMixture(W3, M3, P3)


# --------------------------------------------------------------------------- GaussianMixture
def test_mean_and_cov_are_the_law_of_total_covariance():
    g = mix3()
    M, P, w = np.array(M3), np.array(P3), np.array(W3)
    mean = w @ M
    second = sum(wk * (Pk + np.outer(mk, mk)) for wk, mk, Pk in zip(w, M, P))  # E xxᵀ, the raw form
    np.testing.assert_allclose(g.mean, mean, rtol=CLOSED_FORM_RTOL)
    np.testing.assert_allclose(g.cov, second - np.outer(mean, mean), rtol=CLOSED_FORM_RTOL, atol=1e-13)
    assert g.n_components == 3 and g.dim == 2
    assert [c.mean.tolist() for c in g.components] == M3


def test_scalar_mixture_shorthand():
    g = sm.GaussianMixture([0.5, 0.5], [-1.0, 1.0], [1.0, 1.0])
    assert g.dim == 1 and g.mean.tolist() == [0.0] and g.cov.tolist() == [[2.0]]


def test_weights_are_normalised_within_rounding():
    w = np.array([0.1, 0.2, 0.7])  # sums to 0.9999999999999999
    g = sm.GaussianMixture(w * (1 + 0.5 * WEIGHT_SUM_ATOL), M3, P3)
    assert abs(g.weights.sum() - 1.0) < 1e-15


def test_from_components_and_as_gaussian():
    g = mix3()
    h = sm.GaussianMixture.from_components(W3, g.components)
    assert h == g and hash(h) == hash(g)
    assert g.as_gaussian() == sm.Gaussian(g.mean, g.cov)


def test_arrays_are_read_only_and_the_object_immutable():
    g = mix3()
    with pytest.raises(ValueError):
        g.weights[0] = 1.0
    with pytest.raises(AttributeError):
        g.weights = [1.0]


def test_marginal_is_the_mixture_of_the_marginals():
    g = mix3().marginal([1])
    assert g.dim == 1
    np.testing.assert_array_equal(g.means[:, 0], np.array(M3)[:, 1])
    np.testing.assert_array_equal(g.covs[:, 0, 0], [1.0, 1.0, 0.1])
    with pytest.raises(ShapeError, match="out of range"):
        mix3().marginal([2])


def test_sample_matches_the_moments(rng):
    g = mix3()
    n = 200_000
    X = g.sample(n, rng)
    assert X.shape == (n, 2)
    se = np.sqrt(np.diag(g.cov) / n)
    assert np.all(np.abs(X.mean(axis=0) - g.mean) < N_SE * se)
    # the variance's standard error from the sample's fourth central moment
    d2 = (X - X.mean(axis=0)) ** 2
    se_var = d2.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(d2.mean(axis=0) - np.diag(g.cov)) < N_SE * se_var)
    np.testing.assert_array_equal(g.sample(5, 3), g.sample(5, 3))  # a seed reproduces


def test_repr_is_readable_and_elides_many_components():
    text = repr(mix3())
    assert text.startswith("GaussianMixture(3 components in 2 dimensions:")
    assert "0.5 * N([2, -1], [[2, 0.5], [0.5, 1]])" in text
    many = sm.GaussianMixture(np.full(10, 0.1), np.arange(10.0), np.ones(10))
    assert "... (4 more)" in repr(many)


@pytest.mark.parametrize(
    ("weights", "means", "covs", "error", "match"),
    [
        ([0.5, 0.6], [[0.0], [1.0]], [[[1.0]], [[1.0]]], WeightError, "must sum to 1"),
        ([1.5, -0.5], [[0.0], [1.0]], [[[1.0]], [[1.0]]], WeightError, r"non-negative: weights\[1\]"),
        ([np.nan, 1.0], [[0.0], [1.0]], [[[1.0]], [[1.0]]], WeightError, "NaN"),
        ([0.0, 0.0], [[0.0], [1.0]], [[[1.0]], [[1.0]]], WeightError, "all zero"),
        ([1.0], [[0.0], [1.0]], [[[1.0]], [[1.0]]], ShapeError, "1 entries but there are 2"),
        ([0.5, 0.5], [[0.0], [np.inf]], [[[1.0]], [[1.0]]], ShapeError, r"means\[1\] contains NaN"),
        ([0.5, 0.5], [[0.0], [1.0]], [[[1.0]], [[-1.0]]], CovarianceError, r"covs\[1\] is not positive"),
        ([0.5, 0.5], [[0.0, 0.0], [1.0, 1.0]], [[[1.0, 0.5], [0.4, 1.0]], np.eye(2)], CovarianceError,
         r"covs\[0\] is not symmetric"),
        ([0.5, 0.5], [[0.0, 0.0], [1.0, 1.0]], [np.eye(3), np.eye(3)], ShapeError, "covs must have shape"),
        ([0.5, 0.5], [0.0, 1.0], [[[1.0]], [[1.0]]], ShapeError, "means must have shape"),
        ([], np.zeros((0, 2)), np.zeros((0, 2, 2)), ShapeError, "at least one component"),
        ([1.0], [["a"]], [[[1.0]]], ShapeError, "real numbers"),
    ],
)
def test_bad_mixtures_are_named_errors(weights, means, covs, error, match):
    with pytest.raises(error, match=match):
        sm.GaussianMixture(weights, means, covs)


def test_bad_sample_arguments():
    with pytest.raises(ArgumentError, match="positive integer"):
        mix3().sample(0)
    with pytest.raises(ArgumentError, match="seed"):
        mix3().sample(3, rng=-1)
    with pytest.raises(ArgumentTypeError):
        sm.GaussianMixture.from_components([1.0], [np.eye(2)])
    with pytest.raises(ShapeError, match="different dimensions"):
        sm.GaussianMixture.from_components([0.5, 0.5], [sm.Gaussian([0.0], [[1.0]]), sm.Gaussian([0, 0], np.eye(2))])


finite = st.floats(-1e3, 1e3, allow_nan=False)
anything = st.one_of(finite, st.just(np.nan), st.just(np.inf), st.floats(-2.0, 2.0))


@settings(max_examples=150, **FUZZ)
@given(K=st.integers(1, 4), n=st.integers(1, 3), data=st.data())
def test_fuzz_mixture_either_validates_or_raises_a_named_error(K, n, data):
    w = data.draw(st.lists(anything, min_size=K, max_size=K))
    M = data.draw(st.lists(st.lists(anything, min_size=n, max_size=n), min_size=K, max_size=K))
    A = np.array(data.draw(st.lists(anything, min_size=K * n * n, max_size=K * n * n))).reshape(K, n, n)
    P = A if data.draw(st.booleans()) else np.einsum("kij,klj->kil", A, A)  # raw, or PSD when finite
    try:
        g = sm.GaussianMixture(w, M, P)
    except SymmonError:
        return
    # Whatever validates is a mixture of finite, PSD components with weights summing to 1.
    assert abs(g.weights.sum() - 1.0) < 1e-12 and np.all(g.weights >= 0)
    assert np.all(np.isfinite(g.mean)) and np.all(np.isfinite(g.cov))
    assert np.linalg.eigvalsh(g.cov)[0] >= -1e-9 * max(1.0, np.abs(g.cov).max())


def test_mixture_moments_keeps_digits_far_from_zero():
    # |μ| = 1e8, σ = 1: the raw second moment minus μ² would lose every digit.
    w = np.array([0.5, 0.5])
    mean, cov = mixture_moments(w, np.array([[1e8 - 1.0], [1e8 + 1.0]]), np.ones((2, 1, 1)))
    assert mean.tolist() == [1e8] and cov.tolist() == [[2.0]]


# --------------------------------------------------------------------------- Empirical
def test_empirical_weighted_moments_and_ess():
    X = np.array([[0.0, 1.0], [2.0, 3.0], [4.0, -1.0]])
    w = np.array([1.0, 2.0, 1.0])
    e = sm.Empirical(X, w)
    p = w / w.sum()
    mean = p @ X
    np.testing.assert_allclose(e.mean, mean, rtol=CLOSED_FORM_RTOL)
    np.testing.assert_allclose(e.cov, (X - mean).T @ np.diag(p) @ (X - mean), rtol=CLOSED_FORM_RTOL)
    assert e.ess == pytest.approx(1 / np.sum(p**2), rel=CLOSED_FORM_RTOL)
    assert sm.Empirical(X).ess == pytest.approx(3.0, rel=CLOSED_FORM_RTOL)
    assert e.n_samples == 3 and e.dim == 2
    assert repr(e) == "Empirical(3 particles in 2 dimensions, ESS 2.667, mean [2, 1.5])"


def test_empirical_duplicates_with_halved_weights_are_the_same_measure():
    X = np.array([[0.0], [1.0], [5.0]])
    w = np.array([0.2, 0.3, 0.5])
    a = sm.Empirical(X, w)
    b = sm.Empirical(np.vstack([X, X]), np.concatenate([w, w]) / 2)
    np.testing.assert_allclose(b.mean, a.mean, rtol=CLOSED_FORM_RTOL)
    np.testing.assert_allclose(b.cov, a.cov, rtol=CLOSED_FORM_RTOL)


def test_empirical_marginal_and_resampling(rng):
    e = sm.Empirical(rng.normal(size=(50, 3)), rng.uniform(size=50))
    m = e.marginal([2, 0])
    np.testing.assert_array_equal(m.samples, e.samples[:, [2, 0]])
    np.testing.assert_array_equal(m.weights, e.weights)
    R = sm.Empirical([[0.0], [1.0]], [0.0, 1.0]).sample(10, rng)
    assert R.tolist() == [[1.0]] * 10  # a zero weight is never drawn


@pytest.mark.parametrize(
    ("samples", "weights", "error", "match"),
    [
        (np.zeros((0, 2)), None, ShapeError, "N, n >= 1"),
        (np.zeros((2, 2, 2)), None, ShapeError, "one row a particle"),
        ([[0.0], [np.nan]], None, ShapeError, "1 of 2 particles, the first at row 1"),
        ([[0.0], [1.0]], [1.0, -1.0], WeightError, "non-negative"),
        ([[0.0], [1.0]], [0.0, 0.0], WeightError, "all zero"),
        ([[0.0], [1.0]], [1.0, np.inf], WeightError, "NaN or inf"),
        ([[0.0], [1.0]], [1.0, 1.0, 1.0], ShapeError, "3 entries but there are 2"),
        ([["x"], ["y"]], None, ShapeError, "real numbers"),
        ([[1e308], [-1e308], [1e308]], None, ShapeError, "overflows"),
    ],
)
def test_bad_empirical_inputs_are_named_errors(samples, weights, error, match):
    with pytest.raises(error, match=match):
        sm.Empirical(samples, weights)


@settings(max_examples=150, **FUZZ)
@given(N=st.integers(1, 6), n=st.integers(1, 3), data=st.data())
def test_fuzz_empirical_either_validates_or_raises_a_named_error(N, n, data):
    X = data.draw(st.lists(st.lists(anything, min_size=n, max_size=n), min_size=N, max_size=N))
    w = data.draw(st.one_of(st.none(), st.lists(anything, min_size=N, max_size=N)))
    try:
        e = sm.Empirical(X, w)
    except SymmonError:
        return
    assert abs(e.weights.sum() - 1.0) < 1e-12 and np.all(e.weights >= 0)
    assert 1.0 - 1e-12 <= e.ess <= N + 1e-9
    assert np.all(np.isfinite(e.cov)) and np.linalg.eigvalsh(e.cov)[0] >= -1e-9 * max(1.0, np.abs(e.cov).max())
