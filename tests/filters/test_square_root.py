"""The square-root filters (``square_root=True``): the same filter as the standard form on
well-conditioned problems, and a positive definite P where the standard form loses it."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentTypeError, SymmonError

px, py, th, v, dt, om = sp.symbols("px py th v dt om", real=True)
STATE = [px, py, th, v]
#: A unicycle turning at rate om, heading th an angle state; dt and om parameters.
F_PAR = sm.Model(STATE, [px + dt * v * sp.cos(th), py + dt * v * sp.sin(th), th + dt * om, v], angles=[2],
                 params=[dt, om], name="sr_unicycle_p")
F_FIX = sm.Model(STATE, [px + v * sp.cos(th), py + v * sp.sin(th), th + sp.Rational(1, 10), v], angles=[2],
                 name="sr_unicycle")
H_RB = sm.Model(STATE, [sp.sqrt(px**2 + py**2), sp.atan2(py, px)], angles=[1], name="sr_rb")
Q = np.diag([0.05, 0.05, 0.01, 0.02])
R = np.diag([0.3**2, 0.01**2])
X0 = sm.Gaussian([30.0, 10.0, 0.5, 2.0], np.diag([1.0, 1.0, 0.05, 0.1]))
K = 12

FAMILIES = {
    "EKF": dict(transform=sm.TT1()),
    "EKF2": dict(transform=sm.TT2()),
    "IEKF": dict(transform=sm.TT1(), iterations=3),
    "UKF-negative-centre": dict(transform=sm.UT(alpha=0.5, beta=2.0, kappa=0.0)),
    "CKF": dict(transform=sm.UT.cubature()),
    "GHKF": dict(transform=sm.GaussHermite(3)),
}


def measurements(runs: int = 2, seed: int = 3) -> np.ndarray:
    """A bank of range–bearing measurements along a turn, with a missing row and a missing
    component in each run."""
    rng = np.random.default_rng(seed)
    x = np.array(X0.mean)
    ys = np.empty((runs, K, 2))
    for k in range(K):
        x = np.array([x[0] + x[3] * np.cos(x[2]), x[1] + x[3] * np.sin(x[2]), x[2] + 0.1, x[3]])
        ys[:, k] = [np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])] + rng.standard_normal((runs, 2)) * [0.3, 0.01]
    ys[:, 4] = np.nan
    ys[0, 7, 1] = np.nan
    ys[1, 9, 0] = np.nan
    return ys


YS = measurements()
PARAMS = {"dt": 1.0, "om": np.linspace(0.08, 0.12, K)}


def assert_same(a: sm.KalmanResult, b: sm.KalmanResult, tol: float = 1e-10) -> None:
    for name in ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik", "nis_values"):
        u, w = getattr(a, name), getattr(b, name)
        scale = np.maximum(np.abs(w), 1.0)
        assert np.all(np.abs(u - w) <= tol * scale), (name, np.max(np.abs(u - w) / scale))


@pytest.mark.parametrize("family", list(FAMILIES))
def test_square_root_equals_the_standard_form_with_params_angles_and_missing_rows(family):
    opts = FAMILIES[family]
    std = sm.NonlinearKalmanFilter(F_PAR, H_RB, Q, R, **opts)
    sr = sm.NonlinearKalmanFilter(F_PAR, H_RB, Q, R, square_root=True, **opts)
    a, b = sr.filter(YS, X0, params=PARAMS), std.filter(YS, X0, params=PARAMS)
    assert_same(a, b)
    assert sr.method == "SR-" + std.method
    # The factors are lower triangular with a positive diagonal: the Cholesky factors of P.
    assert np.all(np.triu(a.P_chol, 1) == 0) and np.all(np.diagonal(a.P_chol, axis1=-2, axis2=-1) > 0)
    np.testing.assert_allclose(a.P_chol, np.linalg.cholesky(b.P), rtol=1e-9, atol=1e-12)
    assert b.P_chol is None


@pytest.mark.parametrize("family", ["EKF", "UKF-negative-centre"])
def test_square_root_equals_the_standard_form_without_params(family):
    opts = FAMILIES[family]
    std = sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, **opts)
    sr = sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, square_root=True, **opts)
    assert_same(sr.filter(YS[0], X0), std.filter(YS[0], X0))
