"""The iterated EKF (``NonlinearKalmanFilter(..., sm.TT1(), iterations=N)``).

Its update is Gauss–Newton on the MAP cost (x − x⁻)ᵀ P⁻⁻¹ (x − x⁻) + (y − h(x))ᵀ R⁻¹ (y − h(x))
(Bell & Cathey 1993), so with enough iterations it reaches the minimiser that SciPy finds
on that cost (both to their tolerances: 1e-7 relative); one iteration is the EKF, and a
linear h makes every iteration the same.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from scipy import optimize

import symmon as sm
from symmon.errors import SymmonError

px, py, vx, vy = X = sp.symbols("px py vx vy", real=True)
F = np.eye(4)
F[0, 2] = F[1, 3] = 1.0
Q = 0.01 * np.eye(4)
R = np.diag([0.5**2, 0.05**2])
X0, P0 = np.array([3.0, 4.0, 0.5, -0.2]), np.diag([4.0, 4.0, 0.25, 0.25])


def models():
    f = sm.Model(X, list(sp.Matrix(F) * sp.Matrix(X)), name="cv")
    h = sm.Model(X, [sp.sqrt(px**2 + py**2), sp.atan2(py, px)], angles=[1], name="rb")
    return f, h


def test_one_iteration_is_the_ekf_and_the_label_says_which():
    f, h = models()
    ys = np.array([[5.5, 0.9], [6.0, 0.7], [6.2, 0.5]])
    ekf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1())
    one = sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1(), iterations=1)
    np.testing.assert_array_equal(ekf.filter(ys, X0, P0).x, one.filter(ys, X0, P0).x)
    assert sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1(), iterations=3).method == "IEKF(iterations=3)"


def test_many_iterations_reach_the_map_estimate_of_the_update():
    f, h = models()
    y = np.array([7.0, 1.2])  # far from the prediction: the EKF's single step is off the MAP
    iekf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1(), iterations=20)
    res = iekf.filter(y[None], X0, P0)
    xp, Pp = res.x_pred[0], res.P_pred[0]
    Pi, Ri = np.linalg.inv(Pp), np.linalg.inv(R)

    def cost(x):
        e = y - np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])
        d = x - xp
        return d @ Pi @ d + e @ Ri @ e

    best = optimize.minimize(cost, xp, method="BFGS", options={"gtol": 1e-12}).x
    np.testing.assert_allclose(res.x[0], best, rtol=1e-7, atol=1e-7)
    ekf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1()).filter(y[None], X0, P0)
    assert np.abs(ekf.x[0] - best).max() > 1e-3  # the iterations matter here
    # The innovation and its covariance are the prediction errors at x⁻, as the EKF's.
    np.testing.assert_allclose(res.S, ekf.S, rtol=1e-14)
    assert res.loglik[0] == pytest.approx(ekf.loglik[0], rel=1e-14)


def test_a_linear_measurement_makes_the_iterations_idle():
    f, _ = models()
    h = sm.Model(X, [px, py], name="xy")
    ys = np.array([[3.5, 3.9], [4.1, 3.7]])
    a = sm.NonlinearKalmanFilter(f, h, Q, np.eye(2), sm.TT1()).filter(ys, X0, P0)
    b = sm.NonlinearKalmanFilter(f, h, Q, np.eye(2), sm.TT1(), iterations=5).filter(ys, X0, P0)
    np.testing.assert_allclose(b.x, a.x, rtol=1e-12)
    np.testing.assert_allclose(b.P, a.P, rtol=1e-12)


@pytest.mark.parametrize("kwargs, match", [({"transform": sm.UT.ut1(), "iterations": 2}, "needs transform TT1"),
                                           ({"transform": sm.TT1(), "iterations": 0}, "from 1 to"),
                                           ({"transform": sm.TT1(), "iterations": 2.5}, "an integer")])
def test_bad_iterations(kwargs, match):
    f, h = models()
    with pytest.raises(SymmonError, match=match):
        sm.NonlinearKalmanFilter(f, h, Q, R, **kwargs)
