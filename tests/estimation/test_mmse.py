"""Tests of symmon.estimation.mmse against independent methods.

- Lemma 1 against scipy.integrate.quad (1e-8).
- Theorems 2 and 3 and the MSE formulas against tensor Gauss-Hermite quadrature, which is
  exact for the polynomial integrands (degree <= 4) with 5 nodes per axis.
- Lemma 2 against the difference of two quadrature MSEs.
- The MSE of the absolute-value estimators against seeded Monte Carlo within 5 standard errors
  (SE = sample std / sqrt(N), N = 400 000).
- The composite estimators against Monte Carlo: within 5 SE for small covariance, more than
  5 SE off for large covariance (they are not the MMSE estimates).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, stats

from symmon.estimation import mmse
from symmon.errors import CovarianceError, ShapeError

QUAD_RTOL = 1e-8  # Lemma 1 vs adaptive quadrature (brief: 1e-8)
QUAD_ATOL = 1e-13
EXACT_RTOL = 1e-10  # closed forms vs exact quadrature of polynomials (rounding only)
EXACT_ATOL = 1e-12
MC_N = 400_000
MC_SIGMAS = 5.0  # Monte Carlo tolerance in standard errors
GH_NODES = 5  # exact for polynomials of degree <= 9 per axis


# ---------------------------------------------------------------- reference methods


def quad_abs_moments(mu: float, var: float) -> tuple[float, float]:
    """E|x| and Var|x| for x ~ N(mu, var) by adaptive quadrature in z = (x - mu) / sigma."""
    sigma = math.sqrt(var)
    z0 = -mu / sigma  # kink of |mu + sigma z|
    lo, hi = -40.0, 40.0  # phi(40) ~ 1e-348: beyond double precision

    def integrate_split(f: Callable[[float], float]) -> float:
        points = [z0] if lo < z0 < hi else None
        val, _ = integrate.quad(f, lo, hi, points=points, epsabs=1e-15, epsrel=1e-13, limit=400)
        return val

    m = integrate_split(lambda z: abs(mu + sigma * z) * stats.norm.pdf(z))
    v = integrate_split(lambda z: (abs(mu + sigma * z) - m) ** 2 * stats.norm.pdf(z))
    return m, v


def gh_expect(f: Callable[[np.ndarray], np.ndarray], mean: np.ndarray, cov: np.ndarray) -> float:
    """E f(x), x ~ N(mean, cov), by tensor Gauss-Hermite quadrature (probabilists' nodes)."""
    n = mean.shape[0]
    z, w = np.polynomial.hermite_e.hermegauss(GH_NODES)
    w = w / math.sqrt(2.0 * math.pi)
    grids = np.meshgrid(*([z] * n), indexing="ij")
    Z = np.stack([g.ravel() for g in grids], axis=-1)
    W = np.prod(np.stack(np.meshgrid(*([w] * n), indexing="ij"), axis=-1).reshape(-1, n), axis=-1)
    lam, V = np.linalg.eigh(cov)
    L = V * np.sqrt(np.clip(lam, 0.0, None))  # works for singular covariances too
    X = mean + Z @ L.T
    return float(np.sum(W * f(X)))


def random_gaussian(seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((n, n))
    return rng.standard_normal(n), M @ M.T / n + 0.1 * np.eye(n)


def mc_mean_se(values: np.ndarray) -> tuple[float, float]:
    return float(values.mean()), float(values.std(ddof=1) / math.sqrt(values.size))


# --------------------------------------------------------------------------- Lemma 1

ABS_CASES = [
    (0.0, 1.0),
    (0.0, 1e-4),
    (1.0, 1.0),
    (-2.5, 0.3),
    (0.1, 100.0),
    (3.0, 0.01),  # mu / sigma = 30
    (-50.0, 4.0),
    (100.0, 1.0),  # mean >> sigma
    (1e3, 1e-2),
]


@pytest.mark.parametrize("mu,var", ABS_CASES)
def test_abs_value_matches_quadrature(mu: float, var: float) -> None:
    m_ref, _ = quad_abs_moments(mu, var)
    assert mmse.abs_value(mu, var) == pytest.approx(m_ref, rel=QUAD_RTOL, abs=QUAD_ATOL)


@pytest.mark.parametrize("mu,var", ABS_CASES)
def test_abs_value_mse_matches_quadrature(mu: float, var: float) -> None:
    # The reference integrates (|x| - E|x|)^2 directly: no mu^2 + sigma^2 - m^2 cancellation.
    _, v_ref = quad_abs_moments(mu, var)
    assert mmse.abs_value_mse(mu, var) == pytest.approx(v_ref, rel=QUAD_RTOL, abs=QUAD_ATOL)


def test_abs_value_at_zero_mean_is_half_normal_mean() -> None:
    # E|x| = sigma sqrt(2/pi) for x ~ N(0, sigma^2): the half-normal mean.
    assert mmse.abs_value(0.0, 4.0) == pytest.approx(2.0 * math.sqrt(2.0 / math.pi), rel=EXACT_RTOL)


@pytest.mark.parametrize("mu", [0.0, -3.5, 2.0, 1e300])
def test_abs_value_zero_variance_is_abs_mean(mu: float) -> None:
    assert mmse.abs_value(mu, 0.0) == abs(mu)
    assert mmse.abs_value_mse(mu, 0.0) == 0.0


def test_abs_value_vectorised_matches_scalar_calls() -> None:
    mus = np.array([[0.0, -1.0, 2.0], [5.0, 0.3, -0.2]])
    vars_ = np.array([1.0, 0.0, 0.5])  # broadcast over rows
    got = mmse.abs_value(mus, vars_)
    assert isinstance(got, np.ndarray) and got.shape == (2, 3)
    want = np.array([[mmse.abs_value(m, v) for m, v in zip(row, vars_)] for row in mus])
    np.testing.assert_array_equal(got, want)


@settings(max_examples=200, deadline=None)
@given(
    mu=st.floats(-1e3, 1e3, allow_nan=False),
    var=st.floats(0.0, 1e3, allow_nan=False),
)
def test_abs_value_bounds(mu: float, var: float) -> None:
    # |E x| <= E|x| <= sqrt(E x^2) (Jensen), and 0 <= Var|x| <= Var x.
    m = mmse.abs_value(mu, var)
    slack = 1e-12 * (abs(mu) + math.sqrt(var) + 1.0)
    assert abs(mu) - slack <= m <= math.sqrt(mu * mu + var) + slack
    assert -slack <= mmse.abs_value_mse(mu, var) <= var * (1 + 1e-12) + slack
    assert mmse.abs_value(-mu, var) == m  # symmetric in the mean


# ---------------------------------------------------- Theorem 1, Examples 1-3 (MC)


def mc_check(samples_f: np.ndarray, estimate: float, mse: float) -> None:
    """Estimate within 5 SE of the MC mean; MSE within 5 SE of the MC mean squared error."""
    mean, se = mc_mean_se(samples_f)
    assert abs(estimate - mean) <= MC_SIGMAS * se, (estimate, mean, se)
    sq, se_sq = mc_mean_se((samples_f - estimate) ** 2)
    assert abs(mse - sq) <= MC_SIGMAS * se_sq, (mse, sq, se_sq)


def test_abs_linear_matches_monte_carlo() -> None:
    rng = np.random.default_rng(1)
    xhat, P = np.array([0.3, -0.2, 0.1]), np.array([[1.0, 0.3, 0.0], [0.3, 0.5, 0.1], [0.0, 0.1, 0.2]])
    a, b = np.array([1.0, 2.0, -1.0]), 0.25
    x = rng.multivariate_normal(xhat, P, size=MC_N)
    mc_check(np.abs(x @ a + b), mmse.abs_linear(a, b, xhat, P), mmse.abs_linear_mse(a, b, xhat, P))


def test_distance_on_line_matches_monte_carlo() -> None:
    rng = np.random.default_rng(2)
    xhat, P, c = 1.2, 0.8, 0.7
    x = xhat + math.sqrt(P) * rng.standard_normal(MC_N)
    mc_check(np.abs(x - c), mmse.distance_on_line(xhat, P, c), mmse.distance_on_line_mse(xhat, P, c))


def test_point_line_distance_matches_monte_carlo() -> None:
    rng = np.random.default_rng(3)
    xhat, P = np.array([1.0, 0.5]), np.array([[0.6, -0.2], [-0.2, 0.4]])
    a, b, c = 2.0, -1.0, -1.2
    x = rng.multivariate_normal(xhat, P, size=MC_N)
    f = np.abs(a * x[:, 0] + b * x[:, 1] + c) / math.hypot(a, b)
    mc_check(f, mmse.point_line_distance(xhat, P, a, b, c), mmse.point_line_distance_mse(xhat, P, a, b, c))


def test_point_plane_distance_matches_monte_carlo() -> None:
    rng = np.random.default_rng(4)
    xhat = np.array([0.2, -0.1, 0.4])
    P = np.array([[0.5, 0.1, 0.0], [0.1, 0.3, -0.05], [0.0, -0.05, 0.4]])
    a, b, c, d = 1.0, 1.0, -2.0, 0.3
    x = rng.multivariate_normal(xhat, P, size=MC_N)
    f = np.abs(x @ np.array([a, b, c]) + d) / math.sqrt(a * a + b * b + c * c)
    mc_check(
        f, mmse.point_plane_distance(xhat, P, a, b, c, d), mmse.point_plane_distance_mse(xhat, P, a, b, c, d)
    )


def test_point_line_distance_invariant_to_scaling_the_line() -> None:
    xhat, P = np.array([1.0, 0.5]), np.array([[0.6, -0.2], [-0.2, 0.4]])
    one = mmse.point_line_distance(xhat, P, 2.0, -1.0, 0.5)
    assert mmse.point_line_distance(xhat, P, -6.0, 3.0, -1.5) == pytest.approx(one, rel=EXACT_RTOL)


def test_point_line_distance_is_theorem_1_with_unit_normal() -> None:
    # Example 2 reduces to Theorem 1 with mu = (a x1 + b x2 + c)/|n|, sigma^2 = n^T P n / |n|^2.
    xhat, P = np.array([1.0, 0.5]), np.array([[0.6, -0.2], [-0.2, 0.4]])
    n = np.array([3.0, 4.0])
    mu = (n @ xhat + 1.0) / 5.0
    var = n @ P @ n / 25.0
    assert mmse.point_line_distance(xhat, P, 3.0, 4.0, 1.0) == pytest.approx(mmse.abs_value(mu, var), rel=EXACT_RTOL)


def test_abs_linear_broadcasts_over_a_trajectory() -> None:
    rng = np.random.default_rng(5)
    xs = rng.standard_normal((7, 4, 2))  # 7 runs x 4 time steps
    Ps = np.stack([np.diag([0.1 * (k + 1), 0.2]) for k in range(4)])  # one covariance per step
    got = mmse.abs_linear([1.0, -1.0], 0.0, xs, Ps)
    assert got.shape == (7, 4)
    assert got[3, 2] == mmse.abs_linear([1.0, -1.0], 0.0, xs[3, 2], Ps[2])


# ------------------------------------------------------------ Theorem 2 and Lemma 2


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_quadratic_matches_gauss_hermite(seed: int) -> None:
    xhat, P = random_gaussian(seed, 3)
    rng = np.random.default_rng(100 + seed)
    A, b, c = rng.standard_normal((3, 3)), rng.standard_normal(3), 0.7  # A not symmetric
    ref = gh_expect(lambda X: np.einsum("ni,ij,nj->n", X, A, X) + X @ b + c, xhat, P)
    assert mmse.quadratic(A, xhat, P, b, c) == pytest.approx(ref, rel=EXACT_RTOL, abs=EXACT_ATOL)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_quadratic_mse_matches_gauss_hermite(seed: int) -> None:
    xhat, P = random_gaussian(seed, 3)
    rng = np.random.default_rng(200 + seed)
    A, b = rng.standard_normal((3, 3)), rng.standard_normal(3)

    def f(X: np.ndarray) -> np.ndarray:
        return np.einsum("ni,ij,nj->n", X, A, X) + X @ b

    mean = gh_expect(f, xhat, P)
    ref = gh_expect(lambda X: (f(X) - mean) ** 2, xhat, P)  # degree 4: exact
    assert mmse.quadratic_mse(A, xhat, P, b) == pytest.approx(ref, rel=EXACT_RTOL, abs=EXACT_ATOL)


def test_quadratic_mse_matches_monte_carlo() -> None:
    rng = np.random.default_rng(6)
    xhat, P = random_gaussian(7, 2)
    A, b = np.array([[1.0, 0.5], [-0.3, 2.0]]), np.array([0.2, -0.4])
    x = rng.multivariate_normal(xhat, P, size=MC_N)
    f = np.einsum("ni,ij,nj->n", x, A, x) + x @ b
    est = mmse.quadratic(A, xhat, P, b)
    sq, se = mc_mean_se((f - est) ** 2)
    assert abs(mmse.quadratic_mse(A, xhat, P, b) - sq) <= MC_SIGMAS * se


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lemma_2_gap_is_difference_of_quadrature_mses(seed: int) -> None:
    xhat, P = random_gaussian(seed, 3)
    A = np.random.default_rng(300 + seed).standard_normal((3, 3))

    def f(X: np.ndarray) -> np.ndarray:
        return np.einsum("ni,ij,nj->n", X, A, X)

    optimal = gh_expect(f, xhat, P)
    plug_in = float(xhat @ A @ xhat)
    mse_plug_in = gh_expect(lambda X: (f(X) - plug_in) ** 2, xhat, P)
    mse_optimal = gh_expect(lambda X: (f(X) - optimal) ** 2, xhat, P)
    gap = mmse.quadratic_mse_gap(A, xhat, P)
    assert gap == pytest.approx(mse_plug_in - mse_optimal, rel=1e-8, abs=EXACT_ATOL)
    assert gap > 0.0  # the test can fail if the gap were computed as zero


def test_lemma_2_squared_norm_example() -> None:
    # Eq. (31): for A = I the gap is (tr P)^2.
    xhat, P = random_gaussian(3, 4)
    assert mmse.quadratic_mse_gap(np.eye(4), xhat, P) == pytest.approx(np.trace(P) ** 2, rel=EXACT_RTOL)


def test_quadratic_broadcasts_over_batch() -> None:
    rng = np.random.default_rng(8)
    xs = rng.standard_normal((5, 2))
    _, P = random_gaussian(9, 2)
    A = np.array([[1.0, 2.0], [0.0, 1.0]])
    got = mmse.quadratic(A, xs, P)
    assert got.shape == (5,)
    assert got[4] == pytest.approx(mmse.quadratic(A, xs[4], P), rel=EXACT_RTOL)
    assert mmse.quadratic_mse_gap(A, xs, P).shape == (5,)


# ---------------------------------------------------------------------- Theorem 3


def joint_gaussian(seed: int, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    return random_gaussian(seed, nx + ny)


@pytest.mark.parametrize("seed", [0, 1])
def test_bilinear_matches_gauss_hermite(seed: int) -> None:
    nx, ny = 2, 3
    mean, C = joint_gaussian(seed, nx, ny)
    B = np.random.default_rng(400 + seed).standard_normal((nx, ny))
    ref = gh_expect(lambda Z: np.einsum("ni,ij,nj->n", Z[:, :nx], B, Z[:, nx:]), mean, C)
    got = mmse.bilinear(B, mean[:nx], mean[nx:], C[:nx, nx:])
    assert got == pytest.approx(ref, rel=EXACT_RTOL, abs=EXACT_ATOL)


@pytest.mark.parametrize("seed", [0, 1])
def test_inner_product_and_squared_distance_match_gauss_hermite(seed: int) -> None:
    n = 2
    mean, C = joint_gaussian(10 + seed, n, n)
    xh, yh, Pxx, Pyy, Pxy = mean[:n], mean[n:], C[:n, :n], C[n:, n:], C[:n, n:]
    ref_ip = gh_expect(lambda Z: np.sum(Z[:, :n] * Z[:, n:], axis=1), mean, C)
    assert mmse.inner_product(xh, yh, Pxy) == pytest.approx(ref_ip, rel=EXACT_RTOL, abs=EXACT_ATOL)

    def d2(Z: np.ndarray) -> np.ndarray:
        return np.sum((Z[:, :n] - Z[:, n:]) ** 2, axis=1)

    ref_d2 = gh_expect(d2, mean, C)
    assert mmse.squared_distance(xh, yh, Pxx, Pyy, Pxy) == pytest.approx(ref_d2, rel=EXACT_RTOL, abs=EXACT_ATOL)
    ref_mse = gh_expect(lambda Z: (d2(Z) - ref_d2) ** 2, mean, C)
    assert mmse.squared_distance_mse(xh, yh, Pxx, Pyy, Pxy) == pytest.approx(ref_mse, rel=EXACT_RTOL, abs=EXACT_ATOL)


def test_bilinear_uses_cross_covariance_not_its_transpose() -> None:
    # With B and P_xy both non-symmetric, tr(B P_yx) differs from tr(B P_xy).
    B = np.array([[0.0, 1.0], [0.0, 0.0]])
    Pxy = np.array([[0.0, 0.3], [0.0, 0.0]])
    assert mmse.bilinear(B, [0.0, 0.0], [0.0, 0.0], Pxy) == pytest.approx(0.3, rel=EXACT_RTOL)


# ------------------------------------------------------------- composite estimators

COMPOSITE_SMALL = 1e-6  # covariance scale where the composite bias (O(P)) is below the MC error
COMPOSITE_LARGE = 1.0


def plane_samples(xhat: np.ndarray, P: np.ndarray, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).multivariate_normal(xhat, P, size=MC_N)


@pytest.mark.parametrize("scale,agrees", [(COMPOSITE_SMALL, True), (COMPOSITE_LARGE, False)])
def test_range_composite_vs_monte_carlo(scale: float, agrees: bool) -> None:
    xhat, P = np.array([0.6, 0.8]), scale * np.array([[1.0, 0.2], [0.2, 0.5]])
    x = plane_samples(xhat, P, 11)
    mean, se = mc_mean_se(np.linalg.norm(x, axis=1))
    gap = abs(mmse.norm(xhat, P) - mean)
    assert (gap <= MC_SIGMAS * se) is agrees, (gap, se)


@pytest.mark.parametrize("scale,agrees", [(COMPOSITE_SMALL, True), (COMPOSITE_LARGE, False)])
def test_bearing_composite_vs_monte_carlo(scale: float, agrees: bool) -> None:
    xhat, P = np.array([1.0, 0.5]), scale * np.array([[1.0, 0.3], [0.3, 2.0]])
    x = plane_samples(xhat, P, 12)
    mean, se = mc_mean_se(np.arctan2(x[:, 1], x[:, 0]))
    gap = abs(mmse.bearing(xhat, P) - mean)
    assert (gap <= MC_SIGMAS * se) is agrees, (gap, se)


@pytest.mark.parametrize("scale,agrees", [(COMPOSITE_SMALL, True), (COMPOSITE_LARGE, False)])
def test_cosine_angle_composite_vs_monte_carlo(scale: float, agrees: bool) -> None:
    mean4 = np.array([1.0, 0.2, 0.4, 0.9])
    _, C = random_gaussian(13, 4)
    C = scale * C
    z = np.random.default_rng(14).multivariate_normal(mean4, C, size=MC_N)
    x, y = z[:, :2], z[:, 2:]
    cos = np.sum(x * y, axis=1) / (np.linalg.norm(x, axis=1) * np.linalg.norm(y, axis=1))
    mean, se = mc_mean_se(cos)
    est = mmse.cosine_angle(mean4[:2], mean4[2:], C[:2, :2], C[2:, 2:], C[:2, 2:])
    assert (abs(est - mean) <= MC_SIGMAS * se) is agrees, (est, mean, se)


def test_range_composite_exceeds_mmse_at_origin() -> None:
    # x ~ N(0, s^2 I_2): E||x|| = s sqrt(pi/2) (Rayleigh) while the composite gives s sqrt(2).
    s2 = 2.0
    assert mmse.norm([0.0, 0.0], s2 * np.eye(2)) == pytest.approx(math.sqrt(2 * s2), rel=EXACT_RTOL)
    assert mmse.norm([0.0, 0.0], s2 * np.eye(2)) > math.sqrt(s2) * math.sqrt(math.pi / 2)


def test_composites_reduce_to_plug_in_without_uncertainty() -> None:
    x, y, Z = np.array([3.0, 4.0]), np.array([-4.0, 3.0]), np.zeros((2, 2))
    assert mmse.norm(x, Z) == 5.0
    assert mmse.bearing(x, Z) == pytest.approx(math.atan2(4.0, 3.0), rel=EXACT_RTOL)
    assert mmse.cosine_angle(x, y, Z, Z, Z) == pytest.approx(0.0, abs=EXACT_ATOL)


def test_module_exports_norm_and_leaves_the_builtin_range_alone() -> None:
    assert "norm" in mmse.__all__ and not hasattr(mmse, "range")
    assert all(hasattr(mmse, name) for name in mmse.__all__)
    assert mmse.norm([1.0, 0.0], np.zeros((2, 2))) == 1.0


# ---------------------------------------------------------------------- bad input

GOOD_P2 = np.eye(2)
NOT_SYMMETRIC = np.array([[1.0, 0.5], [0.0, 1.0]])
NOT_PSD = np.array([[1.0, 2.0], [2.0, 1.0]])
NAN_P = np.array([[np.nan, 0.0], [0.0, 1.0]])

BAD_INPUTS = [
    ("abs_value negative var", lambda: mmse.abs_value(0.0, -1.0), CovarianceError, "var"),
    ("abs_value nan var", lambda: mmse.abs_value(0.0, np.nan), CovarianceError, "var"),
    ("abs_value inf mean", lambda: mmse.abs_value(np.inf, 1.0), ShapeError, "mean"),
    ("abs_value shapes", lambda: mmse.abs_value(np.zeros(3), np.ones(2)), ShapeError, "mean"),
    ("abs_value_mse negative var", lambda: mmse.abs_value_mse(0.0, -1.0), CovarianceError, "var"),
    ("abs_value text", lambda: mmse.abs_value("x", 1.0), ShapeError, "mean"),
    ("abs_linear a length", lambda: mmse.abs_linear([1.0], 0.0, [0.0, 0.0], GOOD_P2), ShapeError, "xhat"),
    ("abs_linear a matrix", lambda: mmse.abs_linear(np.eye(2), 0.0, [0.0, 0.0], GOOD_P2), ShapeError, "a must"),
    ("abs_linear b vector", lambda: mmse.abs_linear([1.0, 1.0], [0.0, 1.0], [0.0, 0.0], GOOD_P2), ShapeError, "b"),
    ("abs_linear P asym", lambda: mmse.abs_linear([1.0, 1.0], 0.0, [0.0, 0.0], NOT_SYMMETRIC), CovarianceError, "P is not symmetric"),
    ("abs_linear P not psd", lambda: mmse.abs_linear([1.0, 1.0], 0.0, [0.0, 0.0], NOT_PSD), CovarianceError, "P is not positive"),
    ("abs_linear P nan", lambda: mmse.abs_linear([1.0, 1.0], 0.0, [0.0, 0.0], NAN_P), CovarianceError, "P contains"),
    ("abs_linear P shape", lambda: mmse.abs_linear([1.0, 1.0], 0.0, [0.0, 0.0], np.eye(3)), ShapeError, "P must"),
    ("abs_linear_mse P not psd", lambda: mmse.abs_linear_mse([1.0, 1.0], 0.0, [0.0, 0.0], NOT_PSD), CovarianceError, "P"),
    ("abs_linear batch", lambda: mmse.abs_linear([1.0, 1.0], 0.0, np.zeros((3, 2)), np.stack([GOOD_P2] * 4)), ShapeError, "batch"),
    ("distance_on_line var", lambda: mmse.distance_on_line(1.0, -0.1), CovarianceError, "P"),
    ("distance_on_line_mse c nan", lambda: mmse.distance_on_line_mse(1.0, 0.1, np.nan), ShapeError, "c"),
    ("point_line zero", lambda: mmse.point_line_distance([0.0, 0.0], GOOD_P2, 0.0, 0.0, 1.0), ValueError, "a, b"),
    ("point_line xhat", lambda: mmse.point_line_distance([0.0, 0.0, 0.0], GOOD_P2, 1.0, 0.0, 1.0), ShapeError, "xhat"),
    ("point_line_mse P", lambda: mmse.point_line_distance_mse([0.0, 0.0], NOT_SYMMETRIC, 1.0, 0.0, 1.0), CovarianceError, "P"),
    ("point_line coef", lambda: mmse.point_line_distance([0.0, 0.0], GOOD_P2, [1.0, 2.0], 0.0, 1.0), ShapeError, "a must be a scalar"),
    ("point_plane zero", lambda: mmse.point_plane_distance(np.zeros(3), np.eye(3), 0.0, 0.0, 0.0, 1.0), ValueError, "a, b, c"),
    ("point_plane xhat", lambda: mmse.point_plane_distance(np.zeros(2), np.eye(2), 1.0, 0.0, 0.0, 1.0), ShapeError, "xhat"),
    ("point_plane_mse d", lambda: mmse.point_plane_distance_mse(np.zeros(3), np.eye(3), 1.0, 0.0, 0.0, np.inf), ShapeError, "d"),
    ("quadratic A shape", lambda: mmse.quadratic(np.eye(3), [0.0, 0.0], GOOD_P2), ShapeError, "A must"),
    ("quadratic b shape", lambda: mmse.quadratic(np.eye(2), [0.0, 0.0], GOOD_P2, b=[1.0]), ShapeError, "b must"),
    ("quadratic c vector", lambda: mmse.quadratic(np.eye(2), [0.0, 0.0], GOOD_P2, c=[1.0, 2.0]), ShapeError, "c must"),
    ("quadratic P", lambda: mmse.quadratic(np.eye(2), [0.0, 0.0], NOT_PSD), CovarianceError, "P"),
    ("quadratic xhat scalar", lambda: mmse.quadratic(np.eye(1), 1.0, np.eye(1)), ShapeError, "xhat"),
    ("quadratic_mse P", lambda: mmse.quadratic_mse(np.eye(2), [0.0, 0.0], NOT_SYMMETRIC), CovarianceError, "P"),
    ("quadratic_mse_gap A", lambda: mmse.quadratic_mse_gap(np.eye(2)[:1], [0.0, 0.0], GOOD_P2), ShapeError, "A"),
    ("bilinear B shape", lambda: mmse.bilinear(np.eye(2), [0.0, 0.0], [0.0, 0.0, 0.0], np.zeros((2, 3))), ShapeError, "B must"),
    ("bilinear Pxy shape", lambda: mmse.bilinear(np.eye(2), [0.0, 0.0], [0.0, 0.0], np.zeros((3, 2))), ShapeError, "Pxy"),
    ("bilinear Pxy nan", lambda: mmse.bilinear(np.eye(2), [0.0, 0.0], [0.0, 0.0], NAN_P), CovarianceError, "Pxy"),
    ("inner_product lengths", lambda: mmse.inner_product([0.0, 0.0], [0.0], np.zeros((2, 2))), ShapeError, "yhat"),
    ("squared_distance joint", lambda: mmse.squared_distance([0.0, 0.0], [1.0, 1.0], GOOD_P2, GOOD_P2, 2.0 * GOOD_P2), CovarianceError, "joint"),
    ("squared_distance Pyy", lambda: mmse.squared_distance([0.0, 0.0], [1.0, 1.0], GOOD_P2, NOT_PSD, np.zeros((2, 2))), CovarianceError, "Pyy"),
    ("squared_distance_mse Pxx", lambda: mmse.squared_distance_mse([0.0, 0.0], [1.0, 1.0], np.eye(3), GOOD_P2, np.zeros((2, 2))), ShapeError, "Pxx"),
    ("range P", lambda: mmse.norm([1.0, 0.0], NOT_PSD), CovarianceError, "P"),
    ("range xhat nan", lambda: mmse.norm([np.nan, 0.0], GOOD_P2), ShapeError, "xhat"),
    ("bearing 3-D", lambda: mmse.bearing([1.0, 0.0, 0.0], np.eye(3)), ShapeError, "xhat"),
    ("bearing origin", lambda: mmse.bearing([0.0, 0.0], GOOD_P2), ValueError, "origin"),
    ("cosine joint", lambda: mmse.cosine_angle([1.0, 0.0], [0.0, 1.0], GOOD_P2, GOOD_P2, 3.0 * GOOD_P2), CovarianceError, "joint"),
    ("cosine undefined", lambda: mmse.cosine_angle([0.0, 0.0], [0.0, 1.0], np.zeros((2, 2)), GOOD_P2, np.zeros((2, 2))), ValueError, "undefined"),
    ("cosine Pxy shape", lambda: mmse.cosine_angle([1.0, 0.0], [0.0, 1.0], GOOD_P2, GOOD_P2, np.zeros(2)), ShapeError, "Pxy"),
]


@pytest.mark.parametrize("call,error,match", [c[1:] for c in BAD_INPUTS], ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_raises_clear_error(call: Callable[[], object], error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        call()
