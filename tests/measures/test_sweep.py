"""Sweeps over α and along a trajectory: closed forms, agreement with per-point calls,
common random numbers, and the Dask path."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ModelError, ShapeError, SymmonError
from symmon.core.problems import gmti, polar
from symmon.measures.sweep import SweepResult, sweep_alpha, sweep_states

#: Closed forms and batched-vs-single evaluations: rounding of short sums.
CLOSED_RTOL = 1e-10
#: CRN must shrink the spread of adjacent-α differences of the MC error by at least this
#: factor (measured: ~180 on the problem below; independent streams give √2·s.e.).
CRN_GAIN = 10

x = sp.Symbol("x", real=True)
SQUARE = sm.Model([x], [x**2], name="sweep_square")
MU = 1.0
U1 = sm.Gaussian([MU], [[1.0]])


def square_mon2(alpha: np.ndarray) -> np.ndarray:
    """M² (43) of x² for x ~ N(μ, α): 1 − ρ² with Var x² = 4μ²α + 2α², Cov(x², x) = 2μα."""
    return 2 * alpha / (4 * MU**2 + 2 * alpha)


@pytest.mark.parametrize("transform", [sm.TT2(), sm.GaussHermite(3), sm.Exact()], ids=["tt2", "gh3", "exact"])
def test_alpha_sweep_matches_the_closed_form(transform):
    alphas = np.logspace(-2, 1, 7)
    r = sweep_alpha(SQUARE, U1, alphas, transform=transform)
    assert isinstance(r, SweepResult) and len(r) == 7
    np.testing.assert_allclose(r.squared, square_mon2(alphas), rtol=CLOSED_RTOL)
    np.testing.assert_allclose(r.mean[:, 0], MU**2 + alphas, rtol=CLOSED_RTOL)
    np.testing.assert_array_equal(r.param, alphas)
    assert r.stderr is None and r.moment_stderr is None


@pytest.mark.parametrize("weight", ["full", "diag", "liu-li"])
def test_deterministic_alpha_sweep_equals_per_alpha_nonlinearity(weight):
    p = gmti(1.0)
    alphas = [0.1, 0.5, 2.0, 10.0]
    r = sweep_alpha(p.model, p.u, alphas, weight=weight, transform=sm.UT.ut1())
    for k, a in enumerate(alphas):
        one = sm.nonlinearity(gmti(a).model, gmti(a).u, weight=weight, transform=sm.UT.ut1())
        np.testing.assert_allclose(r.value[k], one.value, rtol=CLOSED_RTOL)
        np.testing.assert_allclose(r.cov[k], one.moments.cov, rtol=CLOSED_RTOL)
        np.testing.assert_allclose(r.cross_cov[k], one.moments.cross_cov, rtol=CLOSED_RTOL)
    assert r.weight_name == one.weight_name


def test_monte_carlo_alpha_sweep_equals_per_alpha_nonlinearity():
    p = polar(1.0)
    tr = sm.MonteCarlo(20_000, seed=5, groups=8)
    alphas = [0.17, 1.0]
    r = sweep_alpha(p.model, p.u, alphas, weight="liu-li", transform=tr)
    for k, a in enumerate(alphas):
        one = sm.nonlinearity(polar(a).model, polar(a).u, weight="liu-li", transform=tr)
        # Same seed, same computation: identical, error bars included.
        assert r.value[k] == one.value and r.stderr[k] == one.stderr
        np.testing.assert_array_equal(r.moment_stderr["cov"][k], one.moments.stderr["cov"])


@pytest.fixture(scope="module")
def crn_curves():
    alphas = np.linspace(0.5, 1.5, 11)
    tr = sm.MonteCarlo(20_000, seed=1, groups=16)
    exact = sweep_alpha(SQUARE, U1, alphas, transform=sm.Exact())
    common = sweep_alpha(SQUARE, U1, alphas, transform=tr)
    indep = sweep_alpha(SQUARE, U1, alphas, transform=tr, crn=False)
    return exact, common, indep


def test_common_random_numbers_make_the_curve_smooth(crn_curves):
    exact, common, indep = crn_curves
    # The Monte Carlo error at each α; CRN makes it a smooth function of α.
    spread_crn = np.std(np.diff(common.value - exact.value))
    spread_ind = np.std(np.diff(indep.value - exact.value))
    assert spread_crn * CRN_GAIN < spread_ind, (spread_crn, spread_ind)


@pytest.mark.parametrize("which", ["common", "indep"])
def test_sweep_values_lie_within_their_error_bars(which, crn_curves):
    exact, common, indep = crn_curves
    r = {"common": common, "indep": indep}[which]
    np.testing.assert_array_less(np.abs(r.value - exact.value), 5 * r.stderr)


def test_independent_streams_differ_per_alpha_and_are_reproducible(crn_curves):
    _, common, indep = crn_curves
    assert not np.array_equal(common.value, indep.value)
    again = sweep_alpha(SQUARE, U1, common.param, transform=common.transform, crn=False)
    np.testing.assert_array_equal(again.value, indep.value)


@pytest.mark.parametrize("scheduler", ["synchronous", "threads"])
def test_dask_alpha_sweep_equals_local(scheduler):
    p = gmti(1.0)
    tr = sm.MonteCarlo(20_000, seed=3, groups=8)
    alphas = [0.2, 1.0, 5.0]
    here = sweep_alpha(p.model, p.u, alphas, transform=tr)
    there = sweep_alpha(p.model, p.u, alphas, transform=tr, executor=sm.Executor(scheduler=scheduler))
    for k in ("value", "squared", "stderr", "mean", "cov", "cross_cov"):
        np.testing.assert_array_equal(getattr(there, k), getattr(here, k), err_msg=k)


def test_alpha_sweep_with_noise_equals_per_alpha_nonlinearity():
    r_, e = sp.symbols("r e", real=True)
    model = sm.Model([x, r_], [x * r_ + e, sp.sin(x) + r_**2], noise=[e], name="sweep_noisy")
    u = sm.Gaussian([0.5, 1.0], [[0.3, 0.05], [0.05, 0.2]])
    v = sm.Gaussian([0.0], [[0.1]])
    alphas = [0.5, 2.0]
    r = sweep_alpha(model, u, alphas, v, transform=sm.GaussHermite(5), executor=sm.Executor(scheduler="synchronous"))
    for k, a in enumerate(alphas):
        one = sm.nonlinearity(model, sm.Gaussian(u.mean, a * u.cov), v, transform=sm.GaussHermite(5))
        np.testing.assert_allclose(r.value[k], one.value, rtol=CLOSED_RTOL)


# --------------------------------------------------------------------------- states
def _trajectory(K: int = 6):
    t = np.linspace(0.0, 1.0, K)
    means = np.stack([3e3 * np.cos(t), 3e3 * np.sin(t) + 500.0, 10.0 * np.ones(K), -5.0 + t], axis=1)
    covs = np.stack([np.diag([1e4, 1e4, 25.0, 25.0]) * (1 + k) for k in range(K)])
    return means, covs


@pytest.mark.parametrize("transform", [sm.TT2(), sm.UT.cubature(), sm.GaussHermite(3)], ids=["tt2", "cubature", "gh3"])
def test_state_sweep_batched_equals_per_state_nonlinearity(transform):
    p = gmti(1.0)
    means, covs = _trajectory()
    r = sweep_states(p.model, (means, covs), transform=transform)
    np.testing.assert_array_equal(r.param, np.arange(len(means)))
    for k in range(len(means)):
        one = sm.nonlinearity(p.model, sm.Gaussian(means[k], covs[k]), transform=transform)
        np.testing.assert_allclose(r.value[k], one.value, rtol=CLOSED_RTOL)
        np.testing.assert_allclose(r.mean[k], one.moments.mean, rtol=CLOSED_RTOL)
        np.testing.assert_allclose(r.cov[k], one.moments.cov, rtol=CLOSED_RTOL)


def test_monte_carlo_state_sweep_distributed_equals_per_state():
    p = gmti(1.0)
    means, covs = _trajectory(3)
    tr = sm.MonteCarlo(10_000, seed=8, groups=4)
    r = sweep_states(p.model, (means, covs), transform=tr, executor=sm.Executor(scheduler="threads"))
    for k in range(3):
        one = sm.nonlinearity(p.model, sm.Gaussian(means[k], covs[k]), transform=tr)
        assert r.value[k] == one.value and r.stderr[k] == one.stderr
        np.testing.assert_array_equal(r.cov[k], one.moments.cov)
        np.testing.assert_array_equal(r.moment_stderr["mean"][k], one.moments.stderr["mean"])


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("alphas, err", [([], ShapeError), ([[1.0]], ShapeError), ([1.0, -2.0], SymmonError),
                                         ([1.0, np.nan], SymmonError), ([0.0], SymmonError)])
def test_bad_alphas(alphas, err):
    with pytest.raises(err, match="alphas"):
        sweep_alpha(SQUARE, U1, alphas)


def test_bad_arguments():
    with pytest.raises(SymmonError, match="client or scheduler"):
        sm.Executor(client=object(), scheduler="threads")
    with pytest.raises(SymmonError, match="scheduler"):
        sm.Executor(scheduler=3)
    with pytest.raises(TypeError, match="executor"):
        sweep_alpha(SQUARE, U1, [1.0], executor="threads")
    with pytest.raises(TypeError, match="instance"):
        sweep_alpha(SQUARE, U1, [1.0], transform=sm.TT2)
    with pytest.raises(TypeError, match="model"):
        sweep_alpha("x**2", U1, [1.0])
    with pytest.raises(ShapeError, match="u has dimension"):
        sweep_alpha(SQUARE, sm.Gaussian([0.0, 0.0], np.eye(2)), [1.0])
    with pytest.raises(ModelError, match="no noise"):
        sweep_alpha(SQUARE, U1, [1.0], v=sm.Gaussian([0.0], [[1.0]]))
    with pytest.raises(ShapeError, match="means"):
        sweep_states(SQUARE, (np.zeros((2, 2)), np.zeros((2, 1, 1))))
    with pytest.raises(ShapeError, match="covs"):
        sweep_states(SQUARE, (np.zeros((2, 1)), np.zeros((3, 1, 1))))
    e = sp.Symbol("e", real=True)
    noisy = sm.Model([x], [x + e], noise=[e], name="sweep_needs_v")
    with pytest.raises(ModelError, match="noise symbols"):
        sweep_states(noisy, (np.zeros((1, 1)), np.ones((1, 1, 1))))


def test_sweep_alpha_of_a_mixture_scales_it_about_its_mean():
    """A one-component mixture sweeps as its Gaussian; a two-component one gives at each α the
    MoN of the mixture with offsets ×√α and covariances ×α (total covariance ×α)."""
    import symmon as sm
    from symmon.measures.sweep import sweep_alpha

    x = sp.Symbol("x", real=True)
    m = sm.Model([x], [x**2 + sp.sin(x)], name="x2 sin")
    alphas = [0.25, 1.0, 4.0]
    one = sm.GaussianMixture([1.0], [[1.0]], [[[0.5]]])
    np.testing.assert_allclose(sweep_alpha(m, one, alphas, transform=sm.GaussHermite(7)).squared,
                               sweep_alpha(m, sm.Gaussian([1.0], [[0.5]]), alphas, transform=sm.GaussHermite(7)).squared,
                               rtol=1e-12)
    mix = sm.GaussianMixture([0.3, 0.7], [[0.0], [2.0]], [[[0.5]], [[0.2]]])
    res = sweep_alpha(m, mix, alphas, transform=sm.GaussHermite(7))
    for a, value in zip(alphas, res.value):
        scaled = sm.GaussianMixture(mix.weights, mix.mean + np.sqrt(a) * (mix.means - mix.mean), a * mix.covs)
        assert np.allclose(scaled.cov, a * mix.cov, rtol=1e-12)
        assert value == pytest.approx(sm.nonlinearity(m, scaled, transform=sm.GaussHermite(7)).value, rel=1e-12)
