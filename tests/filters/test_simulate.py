"""sm.simulate: the truth of a filter study drawn from the symbolic models.

- its sample moments after one step match ``propagate`` with Monte Carlo on the composed
  model h(f(x, w)) + e within 5 standard errors (both estimates' errors combined);
- its indexing matches ``filter``: the exact filter of a linear model has mean NEES n
  against ``xs`` within 5 standard errors (an off-by-one would be far off);
- parameters per step and per run enter step k's transition and measurement (closed form,
  to 1e-12), angle states and measurements are wrapped, any prior distribution is drawn;
- the same seed gives the same runs; bad arguments raise named errors.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from scipy.linalg import block_diag

import symmon as sm
from symmon.errors import (ArgumentError, ArgumentTypeError, CovarianceError, ModelError, NonFiniteError,
                           ResourceError, ShapeError)

x1, x2, w, e1, e2, dt, b = sp.symbols("x1 x2 w e1 e2 dt b", real=True)
F_NOISY = sm.Model([x1, x2], [x1 + 0.5 * x2 + 0.1 * sp.sin(x1), 0.9 * x2 * (1 + 0.2 * w) + w], noise=[w], name="sim_f")
H_ADD = sm.Model([x1, x2], [sp.sqrt(x1**2 + x2**2 + 1), x1 * x2], name="sim_h")
Q1 = np.array([[0.3]])
R2 = np.diag([0.05, 0.2])
X0 = sm.Gaussian([1.0, -0.5], [[0.4, 0.1], [0.1, 0.3]])


def test_one_step_moments_match_monte_carlo_propagation():
    runs = 4000
    xs, ys = sm.simulate(F_NOISY, H_ADD, Q1, R2, X0, steps=1, runs=runs, seed=11)
    assert xs.shape == (runs, 1, 2) and ys.shape == (runs, 1, 2)
    fx = list(F_NOISY.outputs)
    composed = sm.Model([x1, x2], fx + [o.subs({x1: fx[0], x2: fx[1]}, simultaneous=True) + e
                                        for o, e in zip(H_ADD.outputs, (e1, e2))], noise=[w, e1, e2])
    ref = sm.propagate(composed, X0, sm.Gaussian(np.zeros(3), block_diag(Q1, R2)),
                       transform=sm.MonteCarlo(200_000, seed=5))
    Z = np.hstack([xs[:, 0], ys[:, 0]])
    mean = Z.mean(axis=0)
    se = np.sqrt(Z.var(axis=0, ddof=1) / runs + ref.stderr["mean"] ** 2)
    assert np.all(np.abs(mean - ref.mean) < 5 * se), (mean, ref.mean, se)
    D = Z - mean
    prods = D[:, :, None] * D[:, None, :]
    cov = prods.sum(axis=0) / (runs - 1)
    se_cov = np.sqrt(prods.var(axis=0, ddof=1) / runs + ref.stderr["cov"] ** 2)
    assert np.all(np.abs(cov - ref.cov) < 5 * se_cov)


def test_xs_index_matches_the_filter_so_the_exact_filter_is_consistent():
    """Linear Gaussian (TT1 is the Kalman filter): NEES ~ χ²(2) per step; mean over
    runs × steps within 5 SE of 2 (runs are independent; the per-run mean's spread is the SE)."""
    f = sm.Model([x1, x2], [x1 + x2, 0.8 * x2], name="sim_lin_f")
    h = sm.Model([x1, x2], [x1], name="sim_lin_h")
    Q = np.diag([0.1, 0.5])
    xs, ys = sm.simulate(f, h, Q, [[0.2]], X0, steps=10, runs=200, seed=3)
    res = sm.NonlinearKalmanFilter(f, h, Q, [[0.2]], sm.TT1()).filter(ys, X0, x_true=xs)
    per_run = res.nees().mean(axis=1)
    assert abs(per_run.mean() - 2) < 5 * per_run.std(ddof=1) / np.sqrt(len(per_run))
    shifted = res.nees(np.concatenate([xs[:, :1], xs[:, :-1]], axis=1)).mean()  # x_k against x_{k-1}: far off
    assert shifted > 2 + 10 * per_run.std(ddof=1) / np.sqrt(len(per_run))


def test_parameters_per_step_and_per_run_enter_step_k():
    """Noise-free (Q = R = 0, a point prior): x_{k+1} = [p + dt_k v, v], y = p + b."""
    f = sm.Model([x1, x2], [x1 + dt * x2, x2], params=[dt], name="sim_cv")
    h = sm.Model([x1, x2], [x1 + b], params=[b], name="sim_bias")
    x0 = sm.Gaussian([1.0, 2.0], np.zeros((2, 2)))
    dts = np.array([0.1, 0.5, 0.25, 1.0])
    bias = np.array([[0.0, 1.0, 2.0, 3.0], [-1.0, -1.0, -1.0, -1.0]])
    xs, ys = sm.simulate(f, h, np.zeros((2, 2)), [[0.0]], x0, 4, runs=2, params={"dt": dts, "b": bias})
    want = 1.0 + 2.0 * np.cumsum(dts)
    np.testing.assert_allclose(xs[:, :, 0], np.stack([want, want]), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ys[..., 0], want + bias, rtol=1e-12, atol=1e-12)
    one, _ = sm.simulate(f, h, np.zeros((2, 2)), [[0.0]], x0, 4, params={"dt": 0.5, "b": 0.0})
    np.testing.assert_allclose(one[:, 0], 1.0 + np.arange(1, 5), rtol=1e-12)


def test_angles_are_wrapped_and_any_prior_is_drawn():
    th = sp.Symbol("th", real=True)
    f = sm.Model([th], [th + 2.0], angles=[0], name="sim_spin")
    h = sm.Model([th], [3 * th], angles=[0], name="sim_triple")
    prior = sm.Empirical([[0.0], [1.0]], weights=[1, 3])
    xs, ys = sm.simulate(f, h, [[0.0]], [[0.0]], prior, steps=5, runs=2000, seed=2)
    assert np.all(np.abs(xs) <= np.pi) and np.all(np.abs(ys) <= np.pi)
    start = xs[:, 0, 0] - 2.0  # x_1 − 2 = x_0 ∈ {0, 1}
    np.testing.assert_allclose(np.sort(np.unique(start.round(12))), [0.0, 1.0])
    frac = np.mean(np.isclose(start, 1.0))
    assert abs(frac - 0.75) < 5 * np.sqrt(0.75 * 0.25 / 2000)
    np.testing.assert_allclose(ys, sm.angles.wrap_angle(3 * xs), atol=1e-12)
    mix = sm.GaussianMixture([0.5, 0.5], [[-5.0], [5.0]], [[[0.01]], [[0.01]]])
    lin = sm.Model([x1], [x1], name="sim_id")
    xm, _ = sm.simulate(lin, lin, [[0.0]], [[1.0]], mix, steps=1, runs=400, seed=0)
    assert set(np.sign(xm[:, 0, 0])) == {-1.0, 1.0}


def test_the_same_seed_gives_the_same_runs():
    a = sm.simulate(F_NOISY, H_ADD, Q1, R2, X0, 6, runs=3, seed=7)
    b = sm.simulate(F_NOISY, H_ADD, Q1, R2, X0, 6, runs=3, seed=np.random.default_rng(7))
    c = sm.simulate(F_NOISY, H_ADD, Q1, R2, X0, 6, runs=3, seed=8)
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)
    assert not np.array_equal(a[0], c[0])
    xs, ys = sm.simulate(F_NOISY, H_ADD, Q1, R2, X0, 6, seed=7)
    assert xs.shape == (6, 2) and ys.shape == (6, 2)


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(steps=0), ArgumentError, "steps must be a positive integer"),
    (dict(steps=2.0), ArgumentError, "steps"),
    (dict(runs=True), ArgumentError, "runs must be a positive integer or None"),
    (dict(seed=-1), ArgumentError, "seed"),
    (dict(seed=None), ArgumentError, "seed"),
    (dict(x0=[0.0, 0.0]), ArgumentTypeError, "x0 must be a symmon.Gaussian"),
    (dict(x0=sm.Gaussian([0.0], [[1.0]])), ShapeError, "x0 has dimension 1"),
    (dict(Q=np.eye(2)), ShapeError, "Q"),
    (dict(R=-np.eye(2)), CovarianceError, "R"),
    (dict(f="f"), ArgumentTypeError, "f_model must be a symmon.Model"),
    (dict(params={"dt": 1.0}), ModelError, "declare no parameters"),
])
def test_bad_arguments_name_the_fault(kwargs, error, match):
    args = dict(f=F_NOISY, h=H_ADD, Q=Q1, R=R2, x0=X0, steps=3, runs=None, seed=0)
    args.update(kwargs)
    with pytest.raises(error, match=match):
        sm.simulate(**args)


def test_a_diverging_truth_and_a_huge_bank_are_refused():
    f = sm.Model([x1], [x1**3 + 10], name="sim_explodes")
    h = sm.Model([x1], [x1], name="sim_id")
    with pytest.raises(NonFiniteError, match=r"diverged: the run has .* at step \d+"):
        sm.simulate(f, h, [[1.0]], [[1.0]], sm.Gaussian([1.0], [[1.0]]), 50)
    with pytest.raises(ResourceError, match="exceeds"):
        sm.simulate(f, h, [[1.0]], [[1.0]], sm.Gaussian([1.0], [[1.0]]), 10**6, runs=10**3)
    p = sm.Model([x1], [x1 + dt], params=[dt], name="sim_shift")
    with pytest.raises(ShapeError, match="parameter 'dt' must be a number, one per step"):
        sm.simulate(p, h, [[1.0]], [[1.0]], sm.Gaussian([1.0], [[1.0]]), 3, params={"dt": [1.0, 2.0]})
