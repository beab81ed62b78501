"""The RTS smoothers (symmon.filters.gaussian.smoother) against FilterPy's, and their consistency.

FilterPy's smoothers ran on the same recorded measurements, stored with their results in
tests/reference/filterpy_rts.json by tests/reference/make_smoother_reference.py. The UKF and
the unscented RTS smoother of both libraries compute the same sums in another order, and the
extended RTS smoother with linear dynamics is FilterPy's linear ``rts_smoother`` on the EKF's
output, so they agree to rounding: 1e-9 relative is the issue's bound, with margin.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ShapeError, SymmonError
from helpers import REFERENCE_DIR, assert_close_to_scale

REF = json.loads((REFERENCE_DIR / "filterpy_rts.json").read_text())
RTOL = 1e-9


def close(a, b):
    assert_close_to_scale(a, b, RTOL)


def cv_filter(transform):
    d = REF["cv"]
    px, py, vx, vy = X = sp.symbols("px py vx vy", real=True)
    f = sm.Model(X, list(sp.Matrix(d["F"]) * sp.Matrix(X)), name="cv")
    h = sm.Model(X, [sp.sqrt(px**2 + py**2), sp.atan2(py, px)], angles=[1], name="rb")
    return sm.NonlinearKalmanFilter(f, h, d["Q"], d["R"], transform), d


def heading_filter(transform):
    d = REF["heading"]
    px, py, th, v = X = sp.symbols("px py th v", real=True)
    f = sm.Model(X, [px + v * sp.cos(th), py + v * sp.sin(th), th + 0.3, v], angles=[2], name="turn")
    h = sm.Model(X, [sp.sqrt(px**2 + py**2), sp.atan2(py, px)], angles=[1], name="rb")
    return sm.NonlinearKalmanFilter(f, h, d["Q"], d["R"], transform), d


def test_unscented_rts_equals_filterpy_behind_the_sensor():
    kf, d = cv_filter(sm.UT(1.0, 2.0, 0.0))
    res = kf.smooth(d["ys"], d["x0"], d["P0"])
    close(res.filtered.x, d["ukf_filtered_x"])
    close(res.x, d["ukf_x"])
    close(res.P, d["ukf_P"])
    assert isinstance(res, sm.filters.SmootherResult) and res.x.shape == (40, 4)


def test_extended_rts_equals_filterpy_linear_smoother_on_the_ekf_output():
    kf, d = cv_filter(sm.TT1())
    res = kf.smooth(d["ys"], d["x0"], d["P0"])
    close(res.filtered.x, d["ekf_filtered_x"])
    close(res.x, d["ekf_x"])
    close(res.P, d["ekf_P"])


def test_unscented_rts_with_an_angle_state_through_pi_equals_filterpy():
    kf, d = heading_filter(sm.UT(1.0, 2.0, 0.0))
    res = kf.smooth(d["ys"], d["x0"], d["P0"])
    assert np.abs(np.diff(res.x[:, 2])).max() > np.pi  # the heading wraps
    assert np.all(np.abs(res.x[:, 2]) <= np.pi)
    close(res.filtered.x, d["ukf_filtered_x"])
    close(res.x, d["ukf_x"])
    close(res.P, d["ukf_P"])


@pytest.mark.parametrize("transform", [sm.TT2(), sm.UT.cubature(), sm.GaussHermite(3)])
def test_on_linear_dynamics_every_family_smooths_as_the_linear_smoother(transform):
    """With linear f every rule integrates the time update exactly: the backward pass is the
    linear RTS step on the filter's own output (here checked against a NumPy loop)."""
    kf, d = cv_filter(transform)
    res = kf.smooth(d["ys"], d["x0"], d["P0"])
    F, Q = np.array(d["F"]), np.array(d["Q"])
    x, P = np.array(res.filtered.x), np.array(res.filtered.P)
    xs, Ps = x.copy(), P.copy()
    for k in range(len(x) - 2, -1, -1):
        Pp = F @ P[k] @ F.T + Q
        G = P[k] @ F.T @ np.linalg.inv(Pp)
        xs[k] = x[k] + G @ (xs[k + 1] - F @ x[k])
        Ps[k] = P[k] + G @ (Ps[k + 1] - Pp) @ G.T
    close(res.x, xs)
    close(res.P, Ps)


def test_a_bank_smooths_each_run_as_alone():
    kf, d = cv_filter(sm.UT.ut1())
    ys = np.array(d["ys"])
    bank = np.stack([ys, ys + 0.1, ys[::-1]])
    res = kf.smooth(bank, d["x0"], d["P0"])
    assert res.x.shape == (3, 40, 4) and res.P.shape == (3, 40, 4, 4) and res.runs == 3
    for r in range(3):
        one = kf.smooth(bank[r], d["x0"], d["P0"])
        np.testing.assert_array_equal(res.x[r], one.x)
        np.testing.assert_array_equal(res.P[r], one.P)
    assert res.log_likelihood.shape == (3,)


def test_compiled_backward_pass_equals_casadi_vm():
    from symmon.filters.gaussian.smoother import compiled_smoother

    kf, d = heading_filter(sm.UT.ut1())
    fwd = kf.filter(d["ys"], d["x0"], d["P0"])
    s = compiled_smoother(kf.f_model, kf.transform, kf.angle_states)
    c = s(fwd.x[None], fwd.P[None], kf.Q)
    vm = s(fwd.x[None], fwd.P[None], kf.Q, use_c=False)
    close(c[0], vm[0])
    close(c[1], vm[1])


def test_general_noise_smoother_equals_the_additive_one():
    """x_{k+1} = F x + G w with noise symbols, Cov w = I: the same as additive Q = G Gᵀ."""
    d = REF["cv"]
    X = sp.symbols("px py vx vy", real=True)
    w = sp.symbols("w0:4", real=True)
    Lq = np.linalg.cholesky(np.array(d["Q"]))
    f = sm.Model(X, list(sp.Matrix(d["F"]) * sp.Matrix(X) + sp.Matrix(Lq) * sp.Matrix(w)), noise=list(w), name="cvw")
    kf_add, _ = cv_filter(sm.UT.ut1())
    kf_gen = sm.NonlinearKalmanFilter(f, kf_add.h_model, np.eye(4), d["R"], sm.UT.ut1())
    a = kf_add.smooth(d["ys"], d["x0"], d["P0"])
    b = kf_gen.smooth(d["ys"], d["x0"], d["P0"])
    close(b.x, a.x)
    close(b.P, a.P)


def test_smoother_nees_is_consistent_and_below_the_filters():
    """A linear-Gaussian bank: the smoothed NEES averages to n within its χ² interval, and the
    smoother's RMSE is below the filter's (it uses the later measurements)."""
    F = np.eye(2) + np.diag([1.0], 1)
    Q, R = 0.1 * np.eye(2), np.array([[1.0]])
    x, v = sp.symbols("x v", real=True)
    kf = sm.NonlinearKalmanFilter(sm.Model([x, v], [x + v, v]), sm.Model([x, v], [x]), Q, R, sm.TT1())
    rng = np.random.default_rng(5)
    runs, K = 400, 30
    xs = np.empty((runs, K, 2))
    s = rng.multivariate_normal([0, 1], np.eye(2), runs)
    for k in range(K):
        s = s @ F.T + rng.multivariate_normal([0, 0], Q, runs)
        xs[:, k] = s
    ys = xs[..., :1] + rng.normal(0, 1, (runs, K, 1))
    res = kf.smooth(ys, np.array([0.0, 1.0]), np.eye(2))  # the prior the truth was drawn from
    # 30 steps at 99 %: a consistent smoother leaves about 0.3 outside; 3 is far beyond that.
    test = res.anees(xs, confidence=0.99)
    assert np.sum(~test.inside) <= 3
    err_s = np.sqrt(((res.x - xs) ** 2).mean())
    err_f = np.sqrt(((res.filtered.x - xs) ** 2).mean())
    assert err_s < err_f


def test_smoother_errors():
    kf, d = cv_filter(sm.Adaptive(0.01))
    with pytest.raises(SymmonError, match="one transform for every step"):
        kf.smooth(d["ys"], d["x0"], d["P0"])
    kf, d = cv_filter(sm.UT.ut1())
    with pytest.raises(ShapeError):
        kf.smooth(np.array(d["ys"])[:, :1], d["x0"], d["P0"])
    res = kf.smooth(d["ys"], d["x0"], d["P0"])
    with pytest.raises(ShapeError, match="give run="):
        res.estimate(0, run=0)
    assert res.estimate(3).mean.shape == (4,)
    assert "SmootherResult(UKF" in repr(res)
    with pytest.raises(ValueError):
        res.x[0, 0] = 1.0  # read-only
