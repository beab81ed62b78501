"""Model parameters in the filters: inputs of the compiled step, a value per step or per run.

A filter with ``params=`` must equal the filter of the models with the values substituted
(``Model.with_params``): the same graphs with the values as inputs instead of constants, so
they agree to rounding (1e-12 relative).
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from helpers import assert_close_to_scale
from symmon.errors import ModelError, ShapeError, SymmonError

RTOL = 1e-12
px, py, vx, vy, b, dt, s = sp.symbols("px py vx vy b dt s", real=True)
X = [px, py, vx, vy]
Q = 0.01 * np.eye(4)
R = np.diag([1.0, 1e-4])
X0, P0 = np.array([-20.0, 100.0, 0.0, -5.0]), np.diag([25.0, 25.0, 0.25, 0.25])


def models(with_dt: bool = True, with_b: bool = True):
    f = sm.Model(X, [px + (dt if with_dt else 1) * vx, py + (dt if with_dt else 1) * vy, vx, vy],
                 params=[dt] if with_dt else None, name="cv dt")
    h = sm.Model(X, [sp.sqrt(px**2 + py**2) + (b if with_b else 0), sp.atan2(py, px)], angles=[1],
                 params=[b] if with_b else None, name="rb bias")
    return f, h


def track(K: int = 30, seed: int = 1):
    rng = np.random.default_rng(seed)
    x, ys = X0.copy(), []
    for _ in range(K):
        x = x + np.array([x[2], x[3], 0, 0]) + rng.normal(0, 0.1, 4)
        ys.append([np.hypot(x[0], x[1]) + 0.7 + rng.normal(0, 1), np.arctan2(x[1], x[0]) + rng.normal(0, 0.01)])
    ys = np.array(ys)
    ys[:, 1] = np.mod(ys[:, 1] + np.pi, 2 * np.pi) - np.pi
    return ys


def close(a, b):
    assert_close_to_scale(a, b, RTOL)


@pytest.mark.parametrize("transform", [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.GaussHermite(3)])
def test_constant_parameters_equal_the_substituted_models(transform):
    f, h = models()
    values = {"dt": 1.0, "b": 0.7}
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, transform)
    assert [str(p) for p in kf.params] == ["dt", "b"]
    ref = sm.NonlinearKalmanFilter(f.with_params({"dt": 1.0}), h.with_params({"b": 0.7}), Q, R, transform)
    ys = track()
    a, c = kf.filter(ys, X0, P0, params=values), ref.filter(ys, X0, P0)
    for k in ("x", "P", "S", "loglik"):
        close(getattr(a, k), getattr(c, k))


def test_a_time_step_per_step_is_an_irregular_filter():
    """params={"dt": dts}: step k predicts with dt_k, as one-step filters with dt_k substituted."""
    f, h = models(with_b=False)
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1())
    ys = track(12)
    dts = np.linspace(0.5, 1.5, 12)
    res = kf.filter(ys, X0, P0, params={"dt": dts})
    x, P = X0, P0
    for k in range(12):
        one = sm.NonlinearKalmanFilter(f.with_params({"dt": dts[k]}), h, Q, R, sm.UT.ut1()).filter(ys[k:k + 1], x, P)
        close(res.x[k], one.x[0])
        close(res.P[k], one.P[0])
        x, P = one.x[0], one.P[0]


def test_per_run_values_in_a_bank_equal_each_run_alone():
    f, h = models()
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1())
    ys = np.stack([track(10, 1), track(10, 2)])
    bias = np.array([[0.0] * 10, [1.0] * 10])
    res = kf.filter(ys, X0, P0, params={"dt": 1.0, "b": bias})
    for r in range(2):
        one = kf.filter(ys[r], X0, P0, params={"dt": 1.0, "b": bias[r]})
        np.testing.assert_array_equal(res.x[r], one.x)
    assert not np.allclose(res.x[0], res.x[1])


def test_a_parameter_of_the_noise_intensity():
    """x_{k+1} = x + dt v + s w (noise symbols, Cov w = I): the same as additive Q = s² I."""
    w = sp.symbols("w0:4", real=True)
    f = sm.Model(X, [px + vx + s * w[0], py + vy + s * w[1], vx + s * w[2], vy + s * w[3]], noise=list(w),
                 params=[s], name="cv s")
    _, h = models(with_dt=False, with_b=False)
    kf = sm.NonlinearKalmanFilter(f, h, np.eye(4), R, sm.UT.ut1())
    ref = sm.NonlinearKalmanFilter(models(False, False)[0], h, 0.04 * np.eye(4), R, sm.UT.ut1())
    ys = track()
    close(kf.filter(ys, X0, P0, params={"s": 0.2}).x, ref.filter(ys, X0, P0).x)


def test_the_smoother_takes_the_parameters():
    f, h = models()
    values = {"dt": 1.0, "b": 0.7}
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1())
    ref = sm.NonlinearKalmanFilter(f.with_params({"dt": 1.0}), h.with_params({"b": 0.7}), Q, R, sm.UT.ut1())
    ys = track()
    close(kf.smooth(ys, X0, P0, params=values).x, ref.smooth(ys, X0, P0).x)
    dts = np.linspace(0.5, 1.5, 30)
    a = kf.smooth(ys, X0, P0, params={"dt": dts, "b": 0.7})
    assert not np.allclose(a.x, ref.smooth(ys, X0, P0).x)  # the per-step dt reaches the backward pass


@pytest.mark.parametrize("params, error, match", [
    (None, ModelError, r"have parameters \['dt', 'b'\]"),
    ({"dt": 1.0}, ModelError, r"missing \['b'\]"),
    ({"dt": 1.0, "b": 0.0, "c": 1.0}, ModelError, r"unknown \['c'\]"),
    ({"dt": np.ones(3), "b": 0.0}, ShapeError, r"one per step \(30,\)"),
    ({"dt": np.nan, "b": 0.0}, ShapeError, "NaN or inf"),
])
def test_bad_parameter_values_are_named(params, error, match):
    f, h = models()
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1())
    with pytest.raises(error, match=match):
        kf.filter(track(), X0, P0, params=params)


def test_parameters_where_there_are_none_and_in_the_adaptive_filter():
    f, h = models(False, False)
    with pytest.raises(ModelError, match="declare no parameters"):
        sm.NonlinearKalmanFilter(f, h, Q, R).filter(track(), X0, P0, params={"b": 1.0})
    with pytest.raises(SymmonError, match="Adaptive decides on moments"):
        sm.NonlinearKalmanFilter(*models(), Q, R, sm.Adaptive(0.01))


def test_model_parameters_are_declared_and_substituted():
    f, h = models()
    assert h.params == (b,) and h.n_p == 1 and "params=['b']" in repr(h)
    assert h.with_params({"b": 2.0}).outputs[0] == sp.sqrt(px**2 + py**2) + 2.0
    assert h.with_params({b: 2.0}).params == ()
    with pytest.raises(ModelError, match="both as inputs and params"):
        sm.Model([px], [px], params=[px])
    with pytest.raises(ModelError, match="declare parameters with params="):
        sm.Model([px], [px + b])
    with pytest.raises(ModelError, match=r"needs values of its parameters \['b'\]"):
        h.with_params({})
    with pytest.raises(ModelError, match="must be finite"):
        h.with_params({"b": np.inf})
    with pytest.raises(ModelError, match="has no parameters"):
        h.with_params({"b": 1.0, "c": 2.0})
    assert h != h.with_params({"b": 0.0}) and hash(h) == hash(models()[1])


def test_other_evaluators_take_params_or_ask_for_them():
    _, h = models()
    u = sm.Gaussian(X0, P0)
    with pytest.raises(ModelError, match=r"with_params\(\{\.\.\.\}\)"):
        sm.propagate(h, u)
    sub = h.with_params({"b": 0.5})
    a, c = sm.propagate(h, u, params={"b": 0.5}), sm.propagate(sub, u)
    np.testing.assert_array_equal(a.mean, c.mean)
    many = sm.propagate_many(h, [u, u], params={"b": 0.5})
    np.testing.assert_array_equal(many.mean[0], c.mean)
    assert sm.nonlinearity(h, u, params={"b": 0.5}).value == sm.nonlinearity(sub, u).value
    assert [r["value"] for r in sm.compare(h, u, params={"b": 0.5}, transforms=[sm.TT2()])] == \
        [r["value"] for r in sm.compare(sub, u, transforms=[sm.TT2()])]
    assert sm.advise(h, u, params={"b": 0.5}, samples=10**4).choice_name == sm.advise(sub, u, samples=10**4).choice_name
    with pytest.raises(ModelError, match="needs values"):
        sm.nonlinearity(h, u, params={})
    m = sm.propagate(h.with_params({"b": 0.5}), sm.Gaussian(X0, P0), transform=sm.TT1())
    base = sm.propagate(models(False, False)[1], sm.Gaussian(X0, P0), transform=sm.TT1())
    close(m.mean, base.mean + [0.5, 0.0])
