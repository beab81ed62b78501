"""Missing measurements (NaN in ys) in the nonlinear filters and the linear one.

A row of NaN is a step without an update (FilterPy's ``update(None)``: stored reference in
tests/reference/filterpy_rts.json, made by tests/reference/make_smoother_reference.py); a
row with some NaN updates on the measured components, which must equal a filter whose h has
only those components. The same sums in another order: rounding only, 1e-9 relative.
The linear ``sm.KalmanFilter`` must equal the EKF (TT1) of the same linear model, missing
rows and components in a bank included, to 1e-10.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ShapeError
from helpers import REFERENCE_DIR, assert_close_to_scale

REF = json.loads((REFERENCE_DIR / "filterpy_rts.json").read_text())
RTOL = 1e-9
X = sp.symbols("px py vx vy", real=True)


def close(a, b):
    assert_close_to_scale(a, b, RTOL)


def cv_filter(transform, outputs=(0, 1)):
    d = REF["cv"]
    px, py = X[:2]
    h_all = [sp.sqrt(px**2 + py**2), sp.atan2(py, px)]
    h = sm.Model(X, [h_all[i] for i in outputs], angles=[j for j, i in enumerate(outputs) if i == 1],
                 name=f"rb{''.join(map(str, outputs))}")
    f = sm.Model(X, list(sp.Matrix(d["F"]) * sp.Matrix(X)), name="cv")
    R = np.array(d["R"])[np.ix_(outputs, outputs)]
    return sm.NonlinearKalmanFilter(f, h, d["Q"], R, transform), d


def with_missing(rows, cols=(0, 1)):
    ys = np.array(REF["cv"]["ys"])
    for k in rows:
        ys[k, list(cols)] = np.nan
    return ys


def test_rows_without_a_measurement_equal_filterpy_update_none():
    kf, d = cv_filter(sm.UT(1.0, 2.0, 0.0))
    rows = REF["missing"]["rows"]
    res = kf.filter(with_missing(rows), d["x0"], d["P0"])
    close(res.x, REF["missing"]["ukf_x"])
    close(res.P, REF["missing"]["ukf_P"])
    for k in rows:  # a pure prediction, with a zero log-likelihood term
        np.testing.assert_array_equal(res.x[k], res.x_pred[k])
        np.testing.assert_array_equal(res.P[k], res.P_pred[k])
        assert res.loglik[k] == 0.0
    assert list(np.flatnonzero(res.measured == 0)) == rows and set(res.measured[res.measured > 0]) == {2}


@pytest.mark.parametrize("transform", [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.GaussHermite(3)])
@pytest.mark.parametrize("kept", [0, 1])
def test_a_partly_measured_row_updates_on_the_measured_block(transform, kept):
    """Step k with only component ``kept`` measured equals one step of the filter whose h is
    that component alone, from the same x_{k−1}, P_{k−1}."""
    kf, d = cv_filter(transform)
    k = 12
    ys = with_missing([k], cols=[1 - kept])
    res = kf.filter(ys, d["x0"], d["P0"])
    part, _ = cv_filter(transform, outputs=(kept,))
    one = part.filter(ys[k:k + 1, [kept]], res.x[k - 1], res.P[k - 1])
    close(res.x[k], one.x[0])
    close(res.P[k], one.P[0])
    assert res.loglik[k] == pytest.approx(one.loglik[0], rel=RTOL)
    assert res.innovation[k, 1 - kept] == 0.0 and res.S[k, 1 - kept, 1 - kept] == 1.0
    assert res.S[k, 0, 1] == 0.0 and res.measured[k] == 1
    assert res.nis()[k] == pytest.approx(one.nis()[0], rel=RTOL)
    # The steps before are untouched.
    full = kf.filter(np.array(d["ys"]), d["x0"], d["P0"])
    np.testing.assert_array_equal(res.x[:k], full.x[:k])


def test_a_bank_with_missing_rows_equals_its_runs_and_the_vm():
    from symmon.filters.gaussian.step import compiled_step

    kf, d = cv_filter(sm.UT.ut1())
    ys = np.array(d["ys"])
    bank = np.stack([ys, with_missing([3, 9]), with_missing([20], cols=[0])])
    res = kf.filter(bank, d["x0"], d["P0"])
    for r in range(3):
        one = kf.filter(bank[r], d["x0"], d["P0"])
        np.testing.assert_array_equal(res.x[r], one.x)
        np.testing.assert_array_equal(res.loglik[r], one.loglik)
    assert res.measured.shape == (3, 40) and res.measured[1, 3] == 0 and res.measured[2, 20] == 1
    step = compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states)
    c = step(np.array(d["x0"]), np.array(d["P0"]), bank, kf.Q, kf.R)
    vm = step(np.array(d["x0"]), np.array(d["P0"]), bank, kf.Q, kf.R, use_c=False)
    for name in c:
        np.testing.assert_allclose(c[name], vm[name], rtol=1e-12, atol=1e-12)


def test_nis_degrees_of_freedom_count_the_measured_components():
    kf, d = cv_filter(sm.UT.ut1())
    res = kf.filter(with_missing([5, 6]), d["x0"], d["P0"])
    test = res.anis(confidence=0.9)
    assert test.dof == 2 * 38  # two rows not measured: 38 steps of 2 components
    part = kf.filter(with_missing([5], cols=[0]), d["x0"], d["P0"]).anis()
    assert part.dof == 2 * 40 - 1
    bank = kf.filter(np.stack([with_missing([5]), np.array(d["ys"])]), d["x0"], d["P0"]).anis()
    assert bank.dof[5] == 2 and bank.dof[4] == 4 and np.ndim(bank.lower) == 1
    assert "per step" in repr(bank)


def test_inf_is_still_an_error_and_nan_everywhere_is_a_prediction():
    kf, d = cv_filter(sm.TT1())
    ys = np.array(d["ys"])
    ys[3, 1] = np.inf
    with pytest.raises(ShapeError, match=r"inf \(at index \(3, 1\)\); a missing measurement is NaN"):
        kf.filter(ys, d["x0"], d["P0"])
    res = kf.filter(np.full((5, 2), np.nan), d["x0"], d["P0"])
    F, Q = np.array(d["F"]), np.array(d["Q"])
    x, P = np.array(d["x0"]), np.array(d["P0"])
    for k in range(5):
        x, P = F @ x, F @ P @ F.T + Q
        close(res.x[k], x)
        close(res.P[k], P)
    assert res.log_likelihood == 0.0


def test_the_smoother_runs_over_missing_rows():
    kf, d = cv_filter(sm.UT.ut1())
    res = kf.smooth(with_missing([10, 11, 12]), d["x0"], d["P0"])
    # Smoothed gaps lean on the later measurements: smaller variances than the filter's there.
    assert np.all(np.trace(res.P[10:13], axis1=1, axis2=2) < np.trace(res.filtered.P[10:13], axis1=1, axis2=2))


def test_the_adaptive_filter_skips_missing_rows_too():
    kf, d = cv_filter(sm.Adaptive(0.01))
    res = kf.filter(with_missing([7]), d["x0"], d["P0"])
    np.testing.assert_array_equal(res.x[7], res.x_pred[7])
    assert res.loglik[7] == 0.0 and res.measured[7] == 0


def test_a_step_unmeasured_in_every_run_has_no_average_nis():
    kf, d = cv_filter(sm.UT.ut1())
    ys = np.stack([with_missing([5]), with_missing([5])])
    res = kf.filter(ys, d["x0"], d["P0"])
    with pytest.raises(sm.errors.SymmonError, match="step 5 has no measured component in any run"):
        res.anis()


def test_a_diverging_simulation_is_reported_not_read_as_missing_data():
    from symmon.files.filterfile import MAX_SIMULATED, simulate

    x = sp.Symbol("x", real=True)
    f = sm.Model([x], [x**3 + 10], name="explodes")
    h = sm.Model([x], [x], name="id")
    with pytest.raises(sm.errors.SymmonError, match=r"simulated truth diverged: run 0 .* at step \d+"):
        simulate(f, h, np.eye(1), np.eye(1), sm.Gaussian([1.0], [[1.0]]), 50, 2, seed=0)
    with pytest.raises(sm.errors.SymmonError, match="exceeds"):
        simulate(f, h, np.eye(1), np.eye(1), sm.Gaussian([1.0], [[1.0]]), 10**5, MAX_SIMULATED // 10**5, seed=0)


# --------------------------------------------------- the linear filter, against the EKF

LINEAR_RTOL = 1e-10  # Joseph form against P⁻ − K S Kᵀ, a solve against a Cholesky factor: rounding only


def lclose(a, b):
    assert_close_to_scale(a, b, LINEAR_RTOL)


@pytest.fixture(scope="module")
def linear_pair():
    """sm.KalmanFilter and the EKF (TT1) of the same linear model: the CV model of the
    reference, both positions measured with correlated noise (so masking S's off-diagonal
    entries matters)."""
    d = REF["cv"]
    F, H = np.array(d["F"]), np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    R = np.array([[0.5, 0.2], [0.2, 0.3]])
    f = sm.Model(X, list(sp.Matrix(F) * sp.Matrix(X)), name="cv")
    h = sm.Model(X, list(sp.Matrix(H) * sp.Matrix(X)), name="pos")
    ys = np.array(d["ys"])  # range–bearing numbers, read as positions: any data will do
    ys = np.stack([ys[:, 0] * np.cos(ys[:, 1]), ys[:, 0] * np.sin(ys[:, 1])], axis=-1)
    return sm.KalmanFilter(F, d["Q"], H, R), sm.NonlinearKalmanFilter(f, h, d["Q"], R, sm.TT1()), ys, d


def missing_bank(ys):
    full, rows, parts = ys.copy(), ys.copy(), ys.copy()
    rows[[3, 4, 17]] = np.nan
    parts[5, 0] = parts[6, 1] = parts[30, 0] = np.nan
    parts[31] = np.nan
    return np.stack([full, rows, parts, rows])


def test_linear_filter_skips_missing_measurements_as_the_nonlinear_one(linear_pair):
    kf, ekf, ys, d = linear_pair
    bank = missing_bank(ys)
    lin, ext = kf.filter(bank, d["x0"], d["P0"]), ekf.filter(bank, d["x0"], d["P0"])
    for name in ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik"):
        lclose(getattr(lin, name), getattr(ext, name))
    lclose(lin.nis(), ext.nis())
    np.testing.assert_array_equal(lin.measured, ext.measured)
    assert lin.P.shape == (4, 40, 4, 4)  # different missing measurements: one covariance per run
    np.testing.assert_array_equal(lin.P[1], lin.P[3])
    for k in (3, 4, 17):  # a pure prediction with a zero log-likelihood term
        np.testing.assert_array_equal(lin.x[1, k], lin.x_pred[1, k])
        np.testing.assert_array_equal(lin.P[1, k], lin.P_pred[1, k])
        assert lin.loglik[1, k] == 0.0 and lin.nis()[1, k] == 0.0
    assert lin.innovation[2, 5, 0] == 0.0 and lin.S[2, 5, 0, 0] == 1.0 and lin.S[2, 5, 0, 1] == 0.0
    assert np.all(lin.gain[2, 5][:, 0] == 0.0) and np.all(lin.gain[2, 31] == 0.0)
    assert lin.anis().dof[5] == 4 * 2 - 1 and lin.anis().dof[3] == 2 * 2
    np.testing.assert_array_equal(lin.estimate(5, run=2).cov, lin.P[2, 5])
    lclose(lin.nees(np.zeros((4, 40, 4))), ext.nees(np.zeros((4, 40, 4))))


def test_linear_filter_with_one_missing_pattern_shares_its_covariances(linear_pair):
    kf, ekf, ys, d = linear_pair
    rows = missing_bank(ys)[1]
    one, ext = kf.filter(rows, d["x0"], d["P0"]), ekf.filter(rows, d["x0"], d["P0"])
    for name in ("x", "P", "loglik"):
        lclose(getattr(one, name), getattr(ext, name))
    assert one.measured[3] == 0 and one.measured[2] == 2 and one.P.shape == (40, 4, 4)
    assert one.log_likelihood == pytest.approx(ext.log_likelihood, rel=LINEAR_RTOL)
    bank = kf.filter(np.stack([rows, rows + 1.0]), d["x0"], d["P0"])  # the same pattern: P shared
    assert bank.P.shape == (40, 4, 4)
    np.testing.assert_array_equal(bank.P, one.P)
    lclose(bank.x[0], one.x)  # (2, n) and (n,) products: rounding
    full = kf.filter(ys, d["x0"], d["P0"])
    assert full.measured is None  # nothing missing: as before
    with pytest.raises(ShapeError, match=r"ys contains inf \(at index \(2, 1\)\)"):
        kf.filter(np.where(np.arange(40)[:, None] * [0, 1] == 2, np.inf, ys), d["x0"], d["P0"])
