"""Maximum-likelihood fit of model parameters (symmon.filters.gaussian.fit).

A range bias b and a process-noise intensity q are recovered from simulated banks (a target
far from the sensor, where the EKF's likelihood is close to exact). Statistical checks are
bounded by their own sampling error: an estimate within 3 standard errors of the truth, and
the spread of the estimates over 12 simulations against the mean standard error within a
factor whose bounds are about 3σ of a 12-sample standard deviation (relative SE ≈ 21 %).
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ModelError, SymmonError
from symmon.files.filterfile import simulate

px, py, vx, vy, b, q, c = sp.symbols("px py vx vy b q c", real=True)
w = sp.symbols("w0:2", real=True)
X = [px, py, vx, vy]
R = np.diag([1.0, 1e-4])
TRUTH = {"q": 0.3, "b": 1.5}
X0 = sm.Gaussian([-200.0, 100.0, 0.0, -5.0], np.diag([4.0, 4.0, 0.1, 0.1]))


def models():
    f = sm.Model(X, [px + vx + q * w[0] / 2, py + vy + q * w[1] / 2, vx + q * w[0], vy + q * w[1]],
                 noise=list(w), params=[q], name="cv q")
    h = sm.Model(X, [sp.sqrt(px**2 + py**2) + b, sp.atan2(py, px)], angles=[1], params=[b], name="rb b")
    return f, h


def data(seed: int, runs: int = 20, K: int = 50):
    f, h = models()
    return simulate(f.with_params({"q": TRUTH["q"]}), h.with_params({"b": TRUTH["b"]}), np.eye(2), R, X0, K, runs,
                    seed=seed)


def kf(transform=None):
    f, h = models()
    return sm.NonlinearKalmanFilter(f, h, np.eye(2), R, transform or sm.TT1())


def test_recovers_a_range_bias_and_a_noise_intensity():
    _, ys = data(7)
    res = kf().fit(ys, X0, {"q": 0.1, "b": 0.0}, bounds={"q": (1e-6, None)})
    for k, v in TRUTH.items():
        assert abs(res.estimates[k] - v) < 3 * res.std_errors[k], (k, res)
    assert res.covariance.shape == (2, 2) and res.iterations > 0 and res.at_bound == ()
    assert res.log_likelihood == pytest.approx(float(np.sum(res.filtered.log_likelihood)))
    assert res.params == res.estimates
    assert "q = " in repr(res) and "log-likelihood" in repr(res)
    # The fitted values maximise the filter's log-likelihood: a step off them lowers it.
    filt = kf()
    for k in TRUTH:
        off = dict(res.params)
        off[k] += 0.5 * res.std_errors[k]
        assert float(np.sum(filt.filter(ys, X0, params=off).log_likelihood)) < res.log_likelihood
    # The filter at the fitted values, with the values substituted into its models.
    sub = res.filter.filter(ys, X0)
    np.testing.assert_allclose(sub.x, res.filtered.x, rtol=1e-12, atol=1e-9)


def test_standard_errors_match_the_spread_over_simulations():
    est, se = [], []
    for seed in range(12):
        _, ys = data(100 + seed)
        res = kf().fit(ys, X0, {"q": 0.1, "b": 0.0}, bounds={"q": (1e-6, None)})
        est.append([res.estimates["q"], res.estimates["b"]])
        se.append([res.std_errors["q"], res.std_errors["b"]])
    ratio = np.std(est, axis=0, ddof=1) / np.mean(se, axis=0)
    assert np.all((ratio > 0.5) & (ratio < 1.7)), ratio


def test_the_gradient_is_the_derivative_of_the_filters_log_likelihood():
    """The graph's ℓ(θ) is the filter's log-likelihood, and its exact gradient agrees with a
    central difference of it (step 1e-5: truncation and rounding below 1e-6 relative)."""
    import casadi as ca

    from symmon.filters.gaussian.fit import _loglik_graph
    from symmon.filters.inputs import check_call

    _, ys = data(3, runs=3, K=20)
    k = kf(sm.UT.ut1())
    theta = np.array([0.25, 1.0])
    checked = check_call(k, ys, X0, None, params={"q": 0.25, "b": 1.0})
    t, total = _loglik_graph(k, checked.Y, checked.x0, checked.P0, checked.pv, [0, 1])
    fn = ca.Function("f", [t], [total, ca.gradient(total, t)])
    value, grad = (np.asarray(a, dtype=float).ravel() for a in fn(theta))

    def ll(th):
        return float(np.sum(k.filter(ys, X0, params={"q": th[0], "b": th[1]}).log_likelihood))

    assert value[0] == pytest.approx(ll(theta), rel=1e-12)
    h = 1e-5
    fd = [(ll(theta + h * e) - ll(theta - h * e)) / (2 * h) for e in np.eye(2)]
    np.testing.assert_allclose(grad, fd, rtol=1e-6)


def test_fixed_parameters_and_missing_measurements():
    _, ys = data(9)
    ys[:, 10] = np.nan
    res = kf().fit(ys, X0, {"b": 0.0}, params={"q": TRUTH["q"]})
    assert set(res.estimates) == {"b"} and res.params["q"] == TRUTH["q"]
    assert abs(res.estimates["b"] - TRUTH["b"]) < 3 * res.std_errors["b"]


def test_an_unidentifiable_parameter_is_a_clear_error():
    f, _ = models()
    h2 = sm.Model(X, [sp.sqrt(px**2 + py**2) + b + c, sp.atan2(py, px)], angles=[1], params=[b, c], name="rb bc")
    k = sm.NonlinearKalmanFilter(f, h2, np.eye(2), R, sm.TT1())
    _, ys = data(1, runs=4, K=20)
    with pytest.raises(SymmonError, match="not identifiable"):
        k.fit(ys, X0, {"b": 0.0, "c": 0.0}, params={"q": 0.3})


@pytest.mark.parametrize("kwargs, error, match", [
    ({"start": {"z": 1.0}}, ModelError, r"cannot fit \['z'\]"),
    ({"start": {"b": 0.0}, "params": {"b": 1.0, "q": 0.3}}, ModelError, "both fitted"),
    ({"start": {"b": 0.0, "q": 0.1}, "bounds": {"q": (1.0, 0.5)}}, ModelError, "low < high"),
    ({"start": {"b": 0.0, "q": 0.1}, "bounds": {"q": (0.5, None)}}, ModelError, "within their bounds"),
    ({"start": {"b": 0.0, "q": 0.1}, "bounds": {"x": (0.5, None)}}, ModelError, "not fitted"),
    ({"start": {"b": 0.0}}, ModelError, r"missing \['q'\]"),
    ({"start": {}}, ModelError, "start must be a dict"),
    ({"start": {"b": 0.0, "q": 0.1}, "max_iter": 1}, SymmonError, "did not converge after 1 iterations"),
])
def test_bad_fits_are_named(kwargs, error, match):
    _, ys = data(2, runs=2, K=15)
    kwargs = dict(kwargs)
    start = kwargs.pop("start")
    with pytest.raises(error, match=match):
        kf().fit(ys, X0, start, **kwargs)


def test_fit_needs_parameters_and_one_transform():
    x = sp.Symbol("x", real=True)
    m = sm.Model([x], [x])
    with pytest.raises(ModelError, match="declare no parameters"):
        sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]], sm.TT1()).fit([[1.0]], sm.Gaussian([0.0], [[1.0]]), {"a": 1})
