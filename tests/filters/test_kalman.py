"""Tests of symmon.filters.gaussian.linear.KalmanFilter.

- A scalar case computed by hand (fractions).
- Steady state against the discrete algebraic Riccati equation (scipy) and Remark 2 of the
  distance paper, to 1e-10.
- Means and covariances against exact conditioning of the joint Gaussian of states and
  measurements (batch least squares), including the cross-covariance of an augmented state.
- simulate() and filter() together against Monte Carlo within 5 standard errors.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from symmon.errors import CovarianceError, ShapeError
from symmon.filters.gaussian.linear import KalmanFilter

EXACT_RTOL = 1e-12  # hand-computed fractions: rounding only
RICCATI_RTOL = 1e-10  # brief: steady state to 1e-10
BATCH_RTOL = 1e-10  # Kalman recursion vs one big conditioning (different rounding paths)
BATCH_ATOL = 1e-12
MC_RUNS = 20_000
MC_SIGMAS = 5.0


def cv_model(q: float = 0.5, r: float = 2.0) -> KalmanFilter:
    """Constant-velocity model: position measured, white-noise acceleration."""
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    Q = q * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    return KalmanFilter(F, Q, np.array([[1.0, 0.0]]), np.array([[r]]))


# ------------------------------------------------------------------- hand computed


def test_scalar_case_by_hand() -> None:
    # F = H = 1, Q = 1/2, R = 2, x0 = 1, P0 = 1, y = (2, 1/2).
    # k=1: P- = 3/2, K = 3/7, x = 1 + 3/7 (2 - 1) = 10/7, P = (1 - 3/7) 3/2 = 6/7.
    # k=2: P- = 6/7 + 1/2 = 19/14, K = (19/14)/(47/14) = 19/47,
    #      x = 10/7 + 19/47 (1/2 - 10/7) = 693/658, P = (28/47)(19/14) = 38/47.
    kf = KalmanFilter(F=1.0, Q=0.5, H=1.0, R=2.0)
    res = kf.filter([[2.0], [0.5]], x0=[1.0], P0=[[1.0]])
    np.testing.assert_allclose(res.x_pred[:, 0], [1.0, 10 / 7], rtol=EXACT_RTOL)
    np.testing.assert_allclose(res.P_pred[:, 0, 0], [3 / 2, 19 / 14], rtol=EXACT_RTOL)
    np.testing.assert_allclose(res.gain[:, 0, 0], [3 / 7, 19 / 47], rtol=EXACT_RTOL)
    np.testing.assert_allclose(res.x[:, 0], [10 / 7, 693 / 658], rtol=EXACT_RTOL)
    np.testing.assert_allclose(res.P[:, 0, 0], [6 / 7, 38 / 47], rtol=EXACT_RTOL)


# ---------------------------------------------------------------------- steady state


def test_steady_state_matches_discrete_riccati() -> None:
    kf = cv_model()
    res = kf.filter(np.zeros((400, 1)), np.zeros(2), 10.0 * np.eye(2))
    P_pred = solve_discrete_are(kf.F.T, kf.H.T, kf.Q, kf.R)  # predicted (a priori) covariance
    S = kf.H @ P_pred @ kf.H.T + kf.R
    P_filt = P_pred - P_pred @ kf.H.T @ np.linalg.solve(S, kf.H @ P_pred)
    np.testing.assert_allclose(res.P_pred[-1], P_pred, rtol=RICCATI_RTOL)
    np.testing.assert_allclose(res.P[-1], P_filt, rtol=RICCATI_RTOL)


@pytest.mark.parametrize("q,r", [(0.01, 0.1), (1.0, 1.0), (0.1, 10.0)])
def test_scalar_steady_state_matches_remark_2(q: float, r: float) -> None:
    # Remark 2 (Section 4.3.1): P^2 + q P - q r = 0, P = (-q + sqrt(q^2 + 4 q r)) / 2.
    kf = KalmanFilter(F=1.0, Q=q, H=1.0, R=r)
    res = kf.filter(np.zeros((500, 1)), [0.0], [[0.0]])
    assert res.P[-1, 0, 0] == pytest.approx((-q + math.sqrt(q * q + 4 * q * r)) / 2, rel=RICCATI_RTOL)


# ---------------------------------------------------- exact conditioning of the joint


def joint_moments(kf: KalmanFilter, x0: np.ndarray, P0: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and covariance of [x_0, x_1, ..., x_K, y_1, ..., y_K] as one Gaussian vector.

    Every component is linear in the independent eps = [x_0 - mean, w_0..w_{K-1}, v_1..v_K].
    """
    n, ny = kf.n, kf.n_y
    dim_eps = n + K * n + K * ny
    Aeps = np.zeros(((K + 1) * n + K * ny, dim_eps))
    mean = np.zeros((K + 1) * n + K * ny)
    Ax = np.zeros((n, dim_eps))
    Ax[:, :n] = np.eye(n)
    mx = np.array(x0, dtype=float)
    Aeps[:n], mean[:n] = Ax, mx
    for k in range(1, K + 1):
        Ax = kf.F @ Ax
        Ax[:, n + (k - 1) * n: n + k * n] += np.eye(n)
        mx = kf.F @ mx
        Aeps[k * n:(k + 1) * n], mean[k * n:(k + 1) * n] = Ax, mx
        Ay = kf.H @ Ax
        Ay[:, n + K * n + (k - 1) * ny: n + K * n + k * ny] += np.eye(ny)
        row = (K + 1) * n + (k - 1) * ny
        Aeps[row:row + ny], mean[row:row + ny] = Ay, kf.H @ mx
    blocks = [P0] + [kf.Q] * K + [kf.R] * K
    C_eps = np.zeros((dim_eps, dim_eps))
    i = 0
    for b in blocks:
        C_eps[i:i + b.shape[0], i:i + b.shape[0]] = b
        i += b.shape[0]
    return mean, Aeps @ C_eps @ Aeps.T, Aeps


def condition(mean: np.ndarray, C: np.ndarray, keep: np.ndarray, obs: np.ndarray, value: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Coo = C[np.ix_(obs, obs)]
    Cko = C[np.ix_(keep, obs)]
    m = mean[keep] + Cko @ np.linalg.solve(Coo, value - mean[obs])
    P = C[np.ix_(keep, keep)] - Cko @ np.linalg.solve(Coo, Cko.T)
    return m, P


@pytest.mark.parametrize("k", [1, 2, 5])
def test_filter_equals_exact_conditioning(k: int) -> None:
    K = 5
    kf = KalmanFilter(
        F=np.array([[0.9, 0.2], [-0.1, 1.0]]),
        Q=np.array([[0.3, 0.05], [0.05, 0.2]]),
        H=np.array([[1.0, 0.5], [0.0, 1.0]]),
        R=np.array([[1.0, 0.3], [0.3, 0.5]]),
    )
    x0, P0 = np.array([1.0, -0.5]), np.array([[2.0, 0.3], [0.3, 1.0]])
    ys = np.random.default_rng(1).standard_normal((K, 2))
    res = kf.filter(ys, x0, P0)
    mean, C, _ = joint_moments(kf, x0, P0, K)
    n, ny = 2, 2
    keep = np.arange(k * n, (k + 1) * n)
    obs = np.arange((K + 1) * n, (K + 1) * n + k * ny)  # y_1..y_k
    m, P = condition(mean, C, keep, obs, ys[:k].ravel())
    np.testing.assert_allclose(res.x[k - 1], m, rtol=BATCH_RTOL, atol=BATCH_ATOL)
    np.testing.assert_allclose(res.P[k - 1], P, rtol=BATCH_RTOL, atol=BATCH_ATOL)


def test_cross_cov_of_augmented_state_equals_exact_conditioning() -> None:
    # Augmented state [x_k; x_{k-1}] (as in the Section 7 reproduction): the block P[cur][:, lag]
    # must be Cov(x_k, x_{k-1} | y_1..y_k).
    q, r, K = 0.4, 1.5, 4
    base = KalmanFilter(F=1.0, Q=q, H=1.0, R=r)
    aug = KalmanFilter(
        F=np.array([[1.0, 0.0], [1.0, 0.0]]), Q=np.diag([q, 0.0]), H=np.array([[1.0, 0.0]]), R=r
    )
    x0, p0 = 0.5, 0.8
    ys = np.random.default_rng(2).standard_normal((K, 1))
    res = aug.filter(ys, [x0, x0], p0 * np.ones((2, 2)))
    mean, C, _ = joint_moments(base, np.array([x0]), np.array([[p0]]), K)
    keep = np.array([K, K - 1])  # x_K, x_{K-1}
    obs = np.arange(K + 1, 2 * K + 1)
    m, P = condition(mean, C, keep, obs, ys.ravel())
    np.testing.assert_allclose(res.x[-1], m, rtol=BATCH_RTOL, atol=BATCH_ATOL)
    np.testing.assert_allclose(res.cross_cov([0], [1])[-1], P[:1, 1:], rtol=BATCH_RTOL, atol=BATCH_ATOL)
    np.testing.assert_allclose(res.cross_cov(slice(0, 2), slice(0, 2))[-1], P, rtol=BATCH_RTOL, atol=BATCH_ATOL)


def test_cross_cov_shape_and_blocks() -> None:
    kf = KalmanFilter(np.eye(3), 0.1 * np.eye(3), np.eye(3), np.eye(3))
    res = kf.filter(np.ones((4, 3)), np.zeros(3), np.array([[1.0, 0.2, 0.1], [0.2, 1.0, 0.3], [0.1, 0.3, 1.0]]))
    block = res.cross_cov([0, 2], [1])
    assert block.shape == (4, 2, 1)
    np.testing.assert_array_equal(block[:, :, 0], res.P[:, [0, 2], 1])
    np.testing.assert_array_equal(res.cross_cov(slice(1, 3), [0]), res.P[:, 1:3, :1])


# ------------------------------------------------------------------------- batches


@pytest.mark.parametrize("run", [0, 3])
def test_batched_filter_equals_single_runs(run: int) -> None:
    kf = cv_model()
    _, ys = kf.simulate(30, [0.0, 1.0], np.random.default_rng(3), runs=4)
    batch = kf.filter(ys, [0.0, 1.0], np.eye(2))
    single = kf.filter(ys[run], [0.0, 1.0], np.eye(2))
    assert batch.x.shape == (4, 30, 2) and batch.P.shape == (30, 2, 2)
    np.testing.assert_allclose(batch.x[run], single.x, rtol=EXACT_RTOL, atol=BATCH_ATOL)
    np.testing.assert_array_equal(batch.P, single.P)


def test_covariances_are_exactly_symmetric() -> None:
    # Downstream validators (symmon.estimation.mmse) reject asymmetric covariances; rounding in
    # F P F^T and the Joseph update must not leave any.
    kf = KalmanFilter(
        F=np.array([[0.9, 0.2, 0.0], [-0.1, 1.0, 0.3], [0.05, 0.0, 0.7]]),
        Q=np.diag([0.3, 0.1, 0.2]),
        H=np.array([[1.0, 0.5, 0.1]]),
        R=[[0.7]],
    )
    res = kf.filter(np.ones((20, 1)), np.zeros(3), np.diag([2.0, 1.0, 3.0]))
    np.testing.assert_array_equal(res.P, np.swapaxes(res.P, 1, 2))
    np.testing.assert_array_equal(res.P_pred, np.swapaxes(res.P_pred, 1, 2))
    assert np.all(np.linalg.eigvalsh(res.P)[:, 0] > 0.0)


# ---------------------------------------------------------------- simulation and MC


def test_simulate_is_reproducible_and_shaped() -> None:
    kf = cv_model()
    a = kf.simulate(10, [0.0, 1.0], np.random.default_rng(7), runs=3)
    b = kf.simulate(10, [0.0, 1.0], np.random.default_rng(7), runs=3)
    assert a[0].shape == (3, 10, 2) and a[1].shape == (3, 10, 1)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    single = kf.simulate(10, [0.0, 1.0], np.random.default_rng(7))
    assert single[0].shape == (10, 2) and single[1].shape == (10, 1)


def test_simulate_without_process_noise_keeps_state() -> None:
    kf = KalmanFilter(F=np.eye(2), Q=np.zeros((2, 2)), H=np.eye(2), R=np.eye(2))
    states, _ = kf.simulate(5, [1.0, 2.0], np.random.default_rng(0))
    np.testing.assert_array_equal(states, np.tile([1.0, 2.0], (5, 1)))


def test_simulated_random_walk_variance_matches_model() -> None:
    # Var x_K = P0 + K q for a scalar random walk; SE of a sample variance ~ var sqrt(2/(N-1)).
    q, p0, K = 0.3, 0.5, 20
    kf = KalmanFilter(F=1.0, Q=q, H=1.0, R=1.0)
    states, ys = kf.simulate(K, [2.0], np.random.default_rng(8), P0=[[p0]], runs=MC_RUNS)
    var_true = p0 + K * q
    var_mc = float(np.var(states[:, -1, 0], ddof=1))
    assert abs(var_mc - var_true) <= MC_SIGMAS * var_true * math.sqrt(2 / (MC_RUNS - 1))
    resid_var = float(np.var(ys[:, -1, 0] - states[:, -1, 0], ddof=1))  # measurement noise R = 1
    assert abs(resid_var - 1.0) <= MC_SIGMAS * math.sqrt(2 / (MC_RUNS - 1))


@pytest.mark.parametrize("step", [0, 9])
def test_filter_error_covariance_matches_monte_carlo(step: int) -> None:
    kf = cv_model(q=0.2, r=1.0)
    P0 = np.diag([1.0, 0.5])
    states, ys = kf.simulate(10, [0.0, 1.0], np.random.default_rng(9), P0=P0, runs=MC_RUNS)
    res = kf.filter(ys, [0.0, 1.0], P0)
    err = states[:, step] - res.x[:, step]
    P = res.P[step]
    se_mean = np.sqrt(np.diag(P) / MC_RUNS)
    assert np.all(np.abs(err.mean(axis=0)) <= MC_SIGMAS * se_mean)
    cov = np.cov(err.T)
    # SE of a sample covariance entry: sqrt((P_ij^2 + P_ii P_jj) / (N - 1)).
    se_cov = np.sqrt((P**2 + np.outer(np.diag(P), np.diag(P))) / (MC_RUNS - 1))
    assert np.all(np.abs(cov - P) <= MC_SIGMAS * se_cov)


# ----------------------------------------------------------------- immutability


def test_filter_and_result_are_frozen() -> None:
    kf = cv_model()
    with pytest.raises(dataclasses.FrozenInstanceError):
        kf.F = np.eye(2)  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        kf.Q[0, 0] = 5.0
    res = kf.filter(np.zeros((2, 1)), np.zeros(2), np.eye(2))
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.x = res.x  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        res.P[0, 0, 0] = 1.0


def test_constructor_copies_inputs() -> None:
    F = np.eye(2)
    kf = KalmanFilter(F, np.eye(2), np.eye(2), np.eye(2))
    F[0, 0] = 7.0
    assert kf.F[0, 0] == 1.0


# --------------------------------------------------------------------- bad input

I2 = np.eye(2)
KF = KalmanFilter(I2, 0.1 * I2, I2, I2)
RES = KF.filter(np.zeros((3, 2)), np.zeros(2), I2)

BAD_INPUTS = [
    ("F not square", lambda: KalmanFilter(np.ones((2, 3)), I2, I2, I2), ShapeError, "F must be square"),
    ("F 3-D", lambda: KalmanFilter(np.ones((2, 2, 2)), I2, I2, I2), ShapeError, "F must be a 2-D"),
    ("F nan", lambda: KalmanFilter([[np.nan, 0.0], [0.0, 1.0]], I2, I2, I2), ShapeError, "F contains"),
    ("H columns", lambda: KalmanFilter(I2, I2, np.ones((1, 3)), [[1.0]]), ShapeError, "H must have shape"),
    ("Q dimension", lambda: KalmanFilter(I2, np.eye(3), I2, I2), ShapeError, "Q must be 2x2"),
    ("Q not symmetric", lambda: KalmanFilter(I2, [[1.0, 0.5], [0.0, 1.0]], I2, I2), CovarianceError, "Q is not symmetric"),
    ("Q not psd", lambda: KalmanFilter(I2, [[1.0, 2.0], [2.0, 1.0]], I2, I2), CovarianceError, "Q is not positive"),
    ("R dimension", lambda: KalmanFilter(I2, I2, I2, [[1.0]]), ShapeError, "R must be 2x2"),
    ("R not psd", lambda: KalmanFilter(I2, I2, I2, -I2), CovarianceError, "R is not positive"),
    ("R singular", lambda: KalmanFilter(I2, I2, I2, np.diag([1.0, 0.0])), CovarianceError, "R must be positive definite"),
    ("R nan", lambda: KalmanFilter(I2, I2, I2, [[np.nan, 0.0], [0.0, 1.0]]), CovarianceError, "R contains"),
    ("ys columns", lambda: KF.filter(np.zeros((3, 3)), np.zeros(2), I2), ShapeError, "ys must have shape"),
    ("ys 1-D", lambda: KF.filter(np.zeros(3), np.zeros(2), I2), ShapeError, "ys must have shape"),
    ("ys empty", lambda: KF.filter(np.zeros((0, 2)), np.zeros(2), I2), ShapeError, "ys must have shape"),
    ("ys inf", lambda: KF.filter([[np.inf, 0.0]], np.zeros(2), I2), ShapeError, "ys contains inf"),
    ("x0 length", lambda: KF.filter(np.zeros((3, 2)), np.zeros(3), I2), ShapeError, "x0 must have shape"),
    ("x0 batch without ys batch", lambda: KF.filter(np.zeros((3, 2)), np.zeros((4, 2)), I2), ShapeError, "x0"),
    ("x0 inf", lambda: KF.filter(np.zeros((3, 2)), [np.inf, 0.0], I2), ShapeError, "x0 contains"),
    ("P0 not psd", lambda: KF.filter(np.zeros((3, 2)), np.zeros(2), -I2), CovarianceError, "P0"),
    ("P0 shape", lambda: KF.filter(np.zeros((3, 2)), np.zeros(2), np.eye(3)), ShapeError, "P0"),
    ("simulate K zero", lambda: KF.simulate(0, np.zeros(2), np.random.default_rng(0)), ValueError, "K must"),
    ("simulate K float", lambda: KF.simulate(2.5, np.zeros(2), np.random.default_rng(0)), ValueError, "K must"),
    ("simulate runs", lambda: KF.simulate(2, np.zeros(2), np.random.default_rng(0), runs=0), ValueError, "runs must"),
    ("simulate rng", lambda: KF.simulate(2, np.zeros(2), 0), TypeError, "rng must"),
    ("simulate x0", lambda: KF.simulate(2, np.zeros(3), np.random.default_rng(0)), ShapeError, "x0"),
    ("simulate P0", lambda: KF.simulate(2, np.zeros(2), np.random.default_rng(0), P0=-I2), CovarianceError, "P0"),
    ("cross_cov index", lambda: RES.cross_cov([0], [2]), ShapeError, "block_b has an index"),
    ("cross_cov empty", lambda: RES.cross_cov([], [0]), ShapeError, "block_a selects no"),
    ("cross_cov floats", lambda: RES.cross_cov([0.5], [0]), ShapeError, "block_a must be"),
]


@pytest.mark.parametrize("call,error,match", [c[1:] for c in BAD_INPUTS], ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_raises_clear_error(call: Callable[[], object], error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        call()
