"""sm.ParticleFilter against references that do not share its approximation.

- Linear Gaussian model: the Kalman filter (TT1 on a linear model) is exact.  A bank of R
  runs on the same measurements has R independent particle streams, so the PF means of the
  runs are independent estimates: their average must lie within 5 standard errors (the
  spread over the runs / √R) of the KF's mean at every step and component, for the bootstrap
  and the EKF proposal; and exp(log-likelihood estimate − KF's exact log-likelihood), whose
  expectation is exactly 1 (the estimator of the likelihood is unbiased), averages to 1
  within 5 standard errors.
- Resampling: systematic copies within 1 of N·w_i, stratified within 2, multinomial
  unbiased (the average count over repetitions within 5 SE of N·w_i).
- Univariate nonstationary growth model (Gordon et al. 1993; Arulampalam et al. 2002): the
  PF's RMSE is well below the EKF's, as the literature reports (Arulampalam et al. 2002,
  Fig. 6: EKF RMSE about 3 times the SIR filter's).
- Exact identities: a missing component equals the model without it (same random streams),
  a parameter equals the model with its value substituted, run 0 of a bank equals the
  single run; angle states get a circular mean; degeneracy warns; bad arguments raise.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentError, ArgumentTypeError, DegeneracyWarning, ModelError, ShapeError
from symmon.filters.particle.particle_filter import resample

x1, x2, dt, kk, w, e = sp.symbols("x1 x2 dt kk w e", real=True)
F_LIN = sm.Model([x1, x2], [x1 + 0.5 * x2, 0.9 * x2], name="pf_lin_f")
H_LIN = sm.Model([x1, x2], [x1], name="pf_lin_h")
Q = np.diag([0.1, 0.2])
R = np.array([[0.5]])
X0 = sm.Gaussian([0.0, 1.0], np.eye(2))
RUNS = 24


@pytest.fixture(scope="module")
def linear():
    xs, ys = sm.simulate(F_LIN, H_LIN, Q, R, X0, 8, seed=4)
    kf = sm.NonlinearKalmanFilter(F_LIN, H_LIN, Q, R, sm.TT1()).filter(ys, X0)
    return xs, ys, kf


@pytest.mark.parametrize("proposal", ["bootstrap", "ekf"])
def test_the_mean_converges_to_the_kalman_filter(linear, proposal):
    xs, ys, kf = linear
    pf = sm.ParticleFilter(F_LIN, H_LIN, Q, R, particles=400, proposal=proposal, seed=1)
    res = pf.filter(np.broadcast_to(ys, (RUNS,) + ys.shape), X0, keep=("x", "P"))
    err = res.x - kf.x  # (RUNS, K, n): independent over runs
    se = err.std(axis=0, ddof=1) / np.sqrt(RUNS)
    assert np.all(np.abs(err.mean(axis=0)) < 5 * se)
    # and the error is Monte Carlo error: a few percent of the posterior spread, not a bias
    assert np.sqrt((err**2).mean()) < 0.2 * np.sqrt(np.diagonal(kf.P, axis1=1, axis2=2).min())
    np.testing.assert_allclose(res.P.mean(axis=0), kf.P, atol=0.1 * kf.P.max())


@pytest.mark.parametrize("proposal", ["bootstrap", "ekf"])
def test_the_likelihood_estimate_is_unbiased(linear, proposal):
    _, ys, kf = linear
    pf = sm.ParticleFilter(F_LIN, H_LIN, Q, R, particles=200, proposal=proposal, seed=2)
    res = pf.filter(np.broadcast_to(ys, (RUNS,) + ys.shape), X0, keep=())
    ratio = np.exp(res.log_likelihood - kf.log_likelihood)
    assert abs(ratio.mean() - 1.0) < 5 * ratio.std(ddof=1) / np.sqrt(RUNS)
    assert res.ess.shape == (RUNS, 8) and np.all((res.ess >= 1) & (res.ess <= 200 + 1e-9))


def test_systematic_and_stratified_copies_are_within_one_and_two_of_n_w():
    rng = np.random.default_rng(0)
    for N in (1, 7, 100):
        W = rng.exponential(size=(20, N)) * (rng.random((20, N)) > 0.3)
        W[:, 0] += 1e-3  # no row of zeros
        W /= W.sum(axis=1, keepdims=True)
        for method, bound in (("systematic", 1.0), ("stratified", 2.0)):
            idx = resample(W, method, np.random.default_rng(N))
            counts = np.stack([np.bincount(row, minlength=N) for row in idx])
            assert np.all(np.abs(counts - N * W) < bound)
            assert np.all(counts[W == 0] == 0)


def test_multinomial_resampling_is_unbiased():
    W = np.array([0.5, 0.25, 0.125, 0.125, 0.0])
    gens = [np.random.default_rng(s) for s in range(2000)]
    idx = resample(np.tile(W, (2000, 1)), "multinomial", gens)
    counts = np.stack([np.bincount(row, minlength=5) for row in idx])
    se = counts.std(axis=0, ddof=1) / np.sqrt(2000)
    assert np.all(np.abs(counts.mean(axis=0) - 5 * W) <= 5 * se)
    assert counts[:, 4].max() == 0
    with pytest.raises(ArgumentError, match="resample must be one of"):
        resample(W, "residual", gens[0])


# The quadratic measurement is very informative far from 0: with 500 particles an odd step
# of an odd run collapses to one particle (reported, as it should be); the RMSE counts it.
@pytest.mark.filterwarnings("ignore::symmon.errors.DegeneracyWarning")
def test_the_pf_beats_the_ekf_on_the_growth_model():
    f = sm.Model([x1], [x1 / 2 + 25 * x1 / (1 + x1**2) + 8 * sp.cos(1.2 * kk)], params=[kk], name="pf_ungm_f")
    h = sm.Model([x1], [x1**2 / 20], name="pf_ungm_h")
    Qg, Rg, x0 = [[10.0]], [[1.0]], sm.Gaussian([0.0], [[5.0]])
    K, runs = 40, 20
    params = {"kk": np.arange(1, K + 1, dtype=float)}
    xs, ys = sm.simulate(f, h, Qg, Rg, x0, K, runs=runs, params=params, seed=5)
    ekf = sm.NonlinearKalmanFilter(f, h, Qg, Rg, sm.TT1()).filter(ys, x0, params=params, keep=("x",))
    pf = sm.ParticleFilter(f, h, Qg, Rg, particles=500).filter(ys, x0, params=params, keep=("x",))
    mse_ekf = ((ekf.x - xs) ** 2).mean(axis=(1, 2))
    mse_pf = ((pf.x - xs) ** 2).mean(axis=(1, 2))
    assert np.sqrt(mse_pf.mean()) < 0.6 * np.sqrt(mse_ekf.mean())
    # A sign test (the EKF's errors are heavy-tailed): P(at least 16 of 20 | a coin) = 0.6 %.
    assert np.sum(mse_pf < mse_ekf) >= 16


def _built(pf: sm.ParticleFilter) -> sm.ParticleFilter:
    """``pf`` with its compiled step built: a C above ccache.BACKGROUND_BYTES builds in the
    background, and a call meanwhile takes the NumPy path, whose draws are others."""
    kernel = pf._bootstrap_kernel
    assert kernel is None or kernel._native.wait(600)
    return pf


def test_a_missing_component_equals_the_model_without_it(linear):
    """The same random streams: a measured-nowhere component changes nothing but NIS's degrees."""
    _, ys, _ = linear
    h2 = sm.Model([x1, x2], [x1, x2], name="pf_lin_h2")
    both = np.column_stack([ys[:, 0], np.full(len(ys), np.nan)])
    a = _built(sm.ParticleFilter(F_LIN, h2, Q, np.diag([0.5, 1.0]), particles=300)).filter(both, X0)
    b = _built(sm.ParticleFilter(F_LIN, H_LIN, Q, R, particles=300)).filter(ys, X0)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.loglik, b.loglik, rtol=1e-12)
    np.testing.assert_allclose(a.nis(), b.nis(), rtol=1e-10)
    assert np.all(a.measured == 1)
    gap = ys.copy()
    gap[3] = np.nan
    c = _built(sm.ParticleFilter(F_LIN, H_LIN, Q, R, particles=300)).filter(gap, X0)
    assert c.loglik[3] == 0.0 and c.ess[3] == c.ess[3] and not c.resampled[3]
    np.testing.assert_allclose(c.ess[3], 300.0 if c.resampled[2] else c.ess[2])


def test_a_parameter_equals_its_substituted_value_and_run_0_is_the_single_run(linear):
    _, ys, _ = linear
    f_p = sm.Model([x1, x2], [x1 + dt * x2, 0.9 * x2], params=[dt], name="pf_cv_dt")
    a = sm.ParticleFilter(f_p, H_LIN, Q, R, particles=300, proposal="ekf").filter(ys, X0, params={"dt": 0.5})
    b = sm.ParticleFilter(F_LIN, H_LIN, Q, R, particles=300, proposal="ekf").filter(ys, X0)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
    bank = sm.ParticleFilter(F_LIN, H_LIN, Q, R, particles=300, proposal="ekf").filter(np.stack([ys, ys + 1]), X0)
    np.testing.assert_array_equal(bank.x[0], b.x)
    assert not np.array_equal(bank.x[1], b.x)


def test_angle_states_have_a_circular_mean():
    th = sp.Symbol("th", real=True)
    f = sm.Model([th], [th], angles=[0], name="pf_still")
    h = sm.Model([th], [sp.cos(th), sp.sin(th)], name="pf_unit")
    truth = np.pi - 0.02
    ys = np.tile([np.cos(truth), np.sin(truth)], (5, 1))
    res = sm.ParticleFilter(f, h, [[1e-4]], 0.01 * np.eye(2), particles=500).filter(
        ys, sm.Gaussian([3.0], [[0.2]]), x_true=np.full((5, 1), truth))
    assert np.all(np.abs(sm.angles.wrap_angle(res.x[:, 0] - truth)) < 0.05)
    assert np.all(np.abs(res.x) <= np.pi) and np.all(res.P[:, 0, 0] < 0.05)
    assert res.nees().shape == (5,)


def test_priors_of_every_kind(linear):
    _, ys, _ = linear
    pf = sm.ParticleFilter(F_LIN, H_LIN, Q, R, particles=200)
    point = sm.Empirical([[2.0, -1.0]])
    res = pf.filter(ys[:1], point, keep=("x_pred", "P_pred"))
    np.testing.assert_allclose(res.x_pred[0], [1.5, -0.9], atol=4 * np.sqrt(0.2 / 200) * 5)
    mix = sm.GaussianMixture([0.5, 0.5], [[-1.0, 0.0], [1.0, 0.0]], [np.eye(2), np.eye(2)])
    assert pf.filter(ys, mix).x.shape == (8, 2)


def test_collapsed_weights_warn():
    f = sm.Model([x1], [x1], name="pf_id")
    with pytest.warns(DegeneracyWarning, match="collapsed to about one particle"):
        sm.ParticleFilter(f, f, [[1.0]], [[1e-8]], particles=20).filter([[0.3], [0.1]], sm.Gaussian([0.0], [[1.0]]))


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(particles=0), ArgumentError, "particles must be a positive integer"),
    (dict(proposal="optimal"), ArgumentError, "proposal must be one of"),
    (dict(resample="residual"), ArgumentError, "resample must be one of"),
    (dict(ess_threshold=1.5), ArgumentError, "ess_threshold"),
    (dict(seed=-1), ArgumentError, "seed"),
    (dict(R=np.zeros((1, 1))), ShapeError, "singular"),
    (dict(h_model=sm.Model([x1, x2], [x1 * sp.exp(e)], noise=[e])), ModelError, "not affine in its noise"),
    (dict(f_model=sm.Model([x1, x2], [x1 + w, x2], noise=[w]), Q=[[1.0]], proposal="ekf"), ArgumentError,
     "additive process noise"),
    (dict(Q=np.diag([1.0, 0.0]), proposal="ukf"), ArgumentError, "positive definite Q"),
    (dict(f_model="f"), ArgumentTypeError, "f_model must be a symmon.Model"),
])
def test_bad_settings_name_the_fault(kwargs, error, match):
    args = dict(f_model=F_LIN, h_model=H_LIN, Q=Q, R=R)
    args.update(kwargs)
    with pytest.raises(error, match=match):
        sm.ParticleFilter(**args)


def test_bad_calls_name_the_fault(linear):
    _, ys, _ = linear
    pf = sm.ParticleFilter(F_LIN, H_LIN, Q, R, particles=10)
    with pytest.raises(ShapeError, match=r"ys must have shape \(K, 1\)"):
        pf.filter(ys[:, 0], X0)
    with pytest.raises(ShapeError, match="inf"):
        pf.filter(np.full((3, 1), np.inf), X0)
    with pytest.raises(ArgumentTypeError, match="x0 must be a symmon.Gaussian"):
        pf.filter(ys, [0.0, 1.0])
    with pytest.raises(ArgumentError, match="keep names"):
        pf.filter(ys, X0, keep=("gain",))
    with pytest.raises(ModelError, match="declare no parameters"):
        pf.filter(ys, X0, params={"dt": 1.0})


def test_a_seeds_particles_do_not_depend_on_the_builds_timing(tmp_path):
    """A fresh cache under the background policy: the first call waits for the compiled step
    instead of taking the NumPy path, whose streams are others, so the first and the second
    call give the same numbers (a cold and a warm machine agree)."""
    import os
    import subprocess
    import sys

    script = (
        "import numpy as np, sympy as sp, symmon as sm\n"
        "x1, x2 = sp.symbols('x1 x2', real=True)\n"
        "f = sm.Model([x1, x2], [x1 + 0.5 * x2, 0.9 * x2], name='pf_timing_f')\n"
        "h = sm.Model([x1, x2], [x1], name='pf_timing_h')\n"
        "x0 = sm.Gaussian([0.0, 1.0], np.eye(2))\n"
        "_, ys = sm.simulate(f, h, 0.1 * np.eye(2), [[0.5]], x0, 6, seed=2)\n"
        "pf = sm.ParticleFilter(f, h, 0.1 * np.eye(2), [[0.5]], particles=300, seed=5)\n"
        "a = pf.filter(ys, x0).x\n"
        "pf._bootstrap_kernel._native.wait()\n"
        "b = pf.filter(ys, x0).x\n"
        "print(pf._bootstrap_kernel._native.evaluator, bool(np.array_equal(a, b)))\n")
    env = {**os.environ, "SYMMON_CACHE": str(tmp_path / "cache"), "SYMMON_COMPILE": "background"}
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["compiled", "True"]
