"""Fits of issue 38 (items 8-9): one name is one parameter; a start where the gradient vanishes at
a minimum or saddle is named; a weakly identified parameter warns with its standard error; a
sensor's noise standard deviation is fitted through a noise symbol (the R idiom)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import IdentifiabilityWarning, SymmonError
from symmon.files.filterfile import simulate

x, e, w = sp.symbols("x e w", real=True)
b_plain, b_positive = sp.Symbol("b"), sp.Symbol("b", positive=True)
X0 = sm.Gaussian([0.0], [[1.0]])


def drift_bias(b_f, b_h):
    """x_{k+1} = x_k + b (a drift), y = x + b (a bias): one b in both models."""
    return sm.Model([x], [x + b_f], params=[b_f], name="i38_drift"), sm.Model([x], [x + b_h], params=[b_h],
                                                                             name="i38_bias")


def test_one_name_is_one_parameter():
    f, h = drift_bias(b_plain, b_positive)
    assert b_plain != b_positive
    kf = sm.NonlinearKalmanFilter(f, h, [[0.01]], [[0.04]], sm.TT1())
    assert [str(s) for s in kf.params] == ["b"]
    _, ys = simulate(*(m.with_params({"b": 0.5}) for m in (f, h)), [[0.01]], [[0.04]], X0, 30, 4, seed=2)
    same = sm.NonlinearKalmanFilter(*drift_bias(b_plain, b_plain), [[0.01]], [[0.04]], sm.TT1())
    got, ref = kf.fit(ys, X0, {"b": 0.0}), same.fit(ys, X0, {"b": 0.0})
    assert got.estimates["b"] == pytest.approx(ref.estimates["b"], rel=1e-9)
    assert abs(got.estimates["b"] - 0.5) < 3 * got.std_errors["b"]
    np.testing.assert_allclose(kf.filter(ys, X0, params={"b": 0.5}).x, same.filter(ys, X0, params={"b": 0.5}).x,
                               rtol=1e-12, atol=1e-12)


def noise_filter():
    """y = x + s·e with Cov e = 1: s is the sensor's noise standard deviation (R = s²)."""
    s = sp.Symbol("s", real=True)
    f = sm.Model([x], [x + w], noise=[w], name="i38_walk")
    h = sm.Model([x], [x + s * e], noise=[e], params=[s], name="i38_noisy")
    return f, h


def test_a_start_at_a_minimum_of_the_likelihood_says_to_start_elsewhere():
    """ℓ(s) = ℓ(−s): the gradient vanishes at s = 0, where ℓ is a minimum along s."""
    f, h = noise_filter()
    kf = sm.NonlinearKalmanFilter(f, h, [[0.01]], [[1.0]], sm.TT1())
    _, ys = simulate(f, h.with_params({"s": 0.3}), [[0.01]], [[1.0]], X0, 30, 3, seed=4)
    with pytest.raises(SymmonError, match=r"fit stopped at \{'s': 0\.0\}.* minimum or a saddle.*start elsewhere"):
        kf.fit(ys, X0, {"s": 0.0})


def test_a_sensor_noise_standard_deviation_is_fitted_through_a_noise_symbol():
    """The R idiom of docs/filters.md: the estimate lies within 3 standard errors of the truth."""
    f, h = noise_filter()
    kf = sm.NonlinearKalmanFilter(f, h, [[0.01]], [[1.0]], sm.TT1())
    _, ys = simulate(f, h.with_params({"s": 0.3}), [[0.01]], [[1.0]], X0, 40, 5, seed=4)
    res = kf.fit(ys, X0, {"s": 1.0}, bounds={"s": (1e-6, None)})
    assert abs(res.estimates["s"] - 0.3) < 3 * res.std_errors["s"] and res.std_errors["s"] < 0.05


def test_a_weakly_identified_bias_warns_with_its_standard_error():
    """A bias of y = x + b from one short run with a 50-unit prior on x: only b + x_0 is seen."""
    f = sm.Model([x], [x], name="i38_still")
    h = sm.Model([x], [x + b_plain], params=[b_plain], name="i38_b")
    prior = sm.Gaussian([0.0], [[2500.0]])
    kf = sm.NonlinearKalmanFilter(f, h, [[1e-4]], [[1.0]], sm.TT1())
    _, ys = simulate(f, h.with_params({"b": 1.0}), [[1e-4]], [[1.0]], sm.Gaussian([0.0], [[1e-12]]), 10, 1, seed=1)
    with pytest.warns(IdentifiabilityWarning, match=r"b = .* has standard error .*larger than the estimate"):
        res = kf.fit(ys[0], prior, {"b": 0.0})
    assert res.std_errors["b"] > 10
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kf.fit(ys[0], sm.Gaussian([0.0], [[1e-4]]), {"b": 0.0})  # x_0 known: b is identified, no warning
