"""Gaussian: validation, repair policies, display, marginal, conditioning (Lemma 7.1), fusion."""

from __future__ import annotations

import re
from fractions import Fraction

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.core.gaussian import PSD_RTOL, SCHUR_RTOL
from symmon.errors import CovarianceError, ShapeError, SingularMatrixError

#: Closed forms in double precision (a few solves of 3x3 systems).
CLOSED_FORM_RTOL = 1e-10
#: Exact identities (a matrix clipped or jittered by a known amount) agree to rounding.
EXACT_TOL = 1e-12
#: Monte Carlo checks: a seeded generator and 5 standard errors.
N_SE = 5.0

# A 3-D example: x = component 0, y = components 1 and 2.
MEAN3 = np.array([1.0, -2.0, 0.5])
COV3 = np.array([[4.0, 1.2, -0.8], [1.2, 2.0, 0.3], [-0.8, 0.3, 1.5]])


# --------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    ("mean", "cov", "error", "match"),
    [
        ([[1.0, 2.0]], np.eye(2), ShapeError, "mean must be a vector"),
        ([1.0, 2.0], np.eye(3), ShapeError, "cov must be 2x2"),
        ([1.0, 2.0], np.ones((2, 3)), ShapeError, "cov must be a square matrix"),
        ([1.0, 2.0], [[1.0, 0.5], [0.4, 1.0]], CovarianceError, "cov is not symmetric"),
        ([1.0, 2.0], [[1.0, 2.0], [2.0, 1.0]], CovarianceError, "cov is not positive semi-definite"),
        ([1.0, np.nan], np.eye(2), ShapeError, "mean contains NaN"),
        ([1.0, 2.0], [[1.0, np.nan], [np.nan, 1.0]], CovarianceError, "cov contains NaN"),
        ([1.0, 2.0], [[np.inf, 0.0], [0.0, 1.0]], CovarianceError, "cov contains NaN or inf"),
    ],
)
def test_validation_names_the_argument(mean, cov, error, match):
    with pytest.raises(error, match=match):
        sm.Gaussian(mean, cov)


def test_validation_errors_are_value_errors():
    with pytest.raises(ValueError):
        sm.Gaussian([0.0, 0.0], [[1.0, 2.0], [2.0, 1.0]])


def test_unknown_psd_policy_is_rejected():
    with pytest.raises(ValueError, match="psd must be one of"):
        sm.Gaussian([0.0], [[1.0]], psd="fix")


def test_singular_psd_covariance_is_accepted():
    g = sm.Gaussian([0.0, 0.0], [[1.0, 1.0], [1.0, 1.0]])
    L = g.sqrt_cov()
    np.testing.assert_allclose(L @ L.T, g.cov, rtol=CLOSED_FORM_RTOL, atol=1e-14)


def test_psd_clip_warns_with_clipped_mass():
    P = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and -1: clipped mass 1
    with pytest.warns(RuntimeWarning, match=r"clipped mass 1\b"):
        g = sm.Gaussian([0.0, 0.0], P, psd="clip")
    w = np.linalg.eigvalsh(g.cov)
    np.testing.assert_allclose(w, [0.0, 3.0], atol=1e-12)
    # Clipping keeps the eigenvectors: the repaired matrix is the PSD projection.
    np.testing.assert_allclose(g.cov, 1.5 * np.ones((2, 2)), rtol=CLOSED_FORM_RTOL)


def test_psd_jitter_warns_with_eps():
    P = np.array([[1.0, 2.0], [2.0, 1.0]])  # smallest eigenvalue -1
    with pytest.warns(RuntimeWarning, match=r"eps = 1 times I"):
        g = sm.Gaussian([0.0, 0.0], P, psd="jitter")
    assert np.linalg.eigvalsh(g.cov)[0] >= 0.0
    np.testing.assert_allclose(g.cov - P, np.eye(2) * (g.cov[0, 0] - 1.0), atol=1e-12)


# --------------------------------------------------------------------------- Gaussian(psd=...) (issue 8)
INDEFINITE = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and −1


def test_psd_default_raises():
    with pytest.raises(CovarianceError, match=r"not positive semi-definite: smallest eigenvalue -1.*psd='clip'"):
        sm.Gaussian([0.0, 0.0], INDEFINITE)


def test_psd_clip_warns_with_the_clipped_mass_and_clips():
    """Eigenvalues (3, −1) → (3, 0): P = 3 v vᵀ with v = (1, 1)/√2, i.e. 1.5 · ones; the
    clipped mass is the sum of the negative eigenvalues' magnitudes, 1."""
    with pytest.warns(RuntimeWarning, match=r"clipped negative eigenvalues to 0 \(clipped mass 1\)"):
        g = sm.Gaussian([0.0, 0.0], INDEFINITE, psd="clip")
    assert g.cov == pytest.approx(1.5 * np.ones((2, 2)), abs=EXACT_TOL)


def test_psd_jitter_warns_with_eps_and_is_positive_definite():
    with pytest.warns(RuntimeWarning, match=r"added jitter eps = ([0-9.e+-]+) times I") as rec:
        g = sm.Gaussian([0.0, 0.0], INDEFINITE, psd="jitter")
    eps_reported = float(re.search(r"eps = ([0-9.e+-]+)", str(rec[0].message)).group(1))
    added = g.cov - INDEFINITE
    eps = added[0, 0]
    assert added == pytest.approx(eps * np.eye(2), abs=EXACT_TOL)  # εI, nothing else
    assert eps == pytest.approx(eps_reported, rel=5e-3)  # the message rounds to 3 digits
    assert eps == pytest.approx(1.0 + PSD_RTOL * 2.0, rel=EXACT_TOL)  # −λ_min plus the tolerance
    assert np.linalg.eigvalsh(g.cov)[0] > 0
    np.linalg.cholesky(g.cov)  # positive definite: Cholesky succeeds


def test_psd_unknown_mode():
    with pytest.raises(ValueError, match="psd must be one of"):
        sm.Gaussian([0.0], [[1.0]], psd="fix")


def test_asymmetry_beyond_rounding_raises():
    """No silent symmetrization: only rounding-level asymmetry is averaged away."""
    with pytest.raises(CovarianceError, match="not symmetric"):
        sm.Gaussian([0.0, 0.0], [[1.0, 0.1], [0.0, 1.0]])


@pytest.mark.parametrize("mode", ["clip", "jitter"])
def test_psd_repair_is_silent_only_when_nothing_is_repaired(mode):
    """A PSD matrix passes unchanged through every mode (filterwarnings=error checks it)."""
    P = np.array([[2.0, 1.0], [1.0, 2.0]])
    assert np.array_equal(sm.Gaussian([0.0, 0.0], P, psd=mode).cov, P)


# --------------------------------------------------------------------------- immutability
def test_gaussian_is_immutable():
    g = sm.Gaussian([1.0, 2.0], np.eye(2))
    with pytest.raises(AttributeError):
        g.mean = np.zeros(2)  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        g.mean[0] = 5.0
    with pytest.raises(ValueError, match="read-only"):
        g.cov[0, 0] = 5.0


def test_gaussian_does_not_alias_its_input():
    m = np.array([1.0, 2.0])
    P = np.eye(2)
    g = sm.Gaussian(m, P)
    m[0] = 99.0
    P[0, 0] = 99.0
    assert g.mean[0] == 1.0 and g.cov[0, 0] == 1.0


# --------------------------------------------------------------------------- display
def test_repr_like_sigsys_three_significant_digits():
    g = sm.Gaussian([95.1234, 95.09], [[954.2, -854.4], [-854.4, 954.2]])
    assert repr(g) == "N([95.1, 95.1], [[954, -854], [-854, 954]])"


def test_repr_latex():
    g = sm.Gaussian([1.0, 2.5], [[2.0, 0.5], [0.5, 1.0]])
    assert g._repr_latex_() == (
        r"$\mathcal{N}\left(\begin{bmatrix}1 \\ 2.5\end{bmatrix},\ "
        r"\begin{bmatrix}2 & 0.5 \\ 0.5 & 1\end{bmatrix}\right)$"
    )


# --------------------------------------------------------------------------- marginal / condition
def test_marginal_picks_blocks_in_the_given_order():
    g = sm.Gaussian(MEAN3, COV3).marginal([2, 0])
    np.testing.assert_array_equal(g.mean, MEAN3[[2, 0]])
    np.testing.assert_array_equal(g.cov, COV3[np.ix_([2, 0], [2, 0])])


@pytest.mark.parametrize(("idx", "match"), [([3], "out of range"), ([0, 0], "duplicate"), ([], "must not be empty"), ([0.5], "integer")])
def test_marginal_bad_indices(idx, match):
    with pytest.raises(ShapeError, match=match):
        sm.Gaussian(MEAN3, COV3).marginal(idx)


def test_condition_closed_form_3d():
    value = np.array([-1.0, 1.0])
    g = sm.Gaussian(MEAN3, COV3).condition([1, 2], value)
    # Lemma 7.1 written out by hand for x = u0, y = (u1, u2).
    Pxy = COV3[0, 1:]
    Pyy = COV3[1:, 1:]
    det = Pyy[0, 0] * Pyy[1, 1] - Pyy[0, 1] ** 2
    Pyy_inv = np.array([[Pyy[1, 1], -Pyy[0, 1]], [-Pyy[0, 1], Pyy[0, 0]]]) / det
    K = Pxy @ Pyy_inv
    np.testing.assert_allclose(g.mean, [MEAN3[0] + K @ (value - MEAN3[1:])], rtol=CLOSED_FORM_RTOL)
    np.testing.assert_allclose(g.cov, [[COV3[0, 0] - K @ Pxy]], rtol=CLOSED_FORM_RTOL)


def test_condition_keeps_the_original_order():
    # Conditioning on the middle component leaves (u0, u2) in that order.
    g = sm.Gaussian(MEAN3, COV3).condition(1, [0.0])
    K = COV3[[0, 2], 1] / COV3[1, 1]
    np.testing.assert_allclose(g.mean, MEAN3[[0, 2]] + K * (0.0 - MEAN3[1]), rtol=CLOSED_FORM_RTOL)
    np.testing.assert_allclose(g.cov, COV3[np.ix_([0, 2], [0, 2])] - np.outer(K, COV3[1, [0, 2]]), rtol=CLOSED_FORM_RTOL)


def test_condition_against_monte_carlo_regression():
    """Brute force: ordinary least squares of x on y over samples of the joint Gaussian."""
    g = sm.Gaussian(MEAN3, COV3)
    value = np.array([-1.0, 1.0])
    cond = g.condition([1, 2], value)
    S = g.sample(200_000, rng=np.random.default_rng(7))
    X = np.column_stack([np.ones(len(S)), S[:, 1:]])
    coef, *_ = np.linalg.lstsq(X, S[:, 0], rcond=None)
    resid = S[:, 0] - X @ coef
    dof = len(S) - X.shape[1]
    s2 = resid @ resid / dof
    x0 = np.concatenate([[1.0], value])
    pred = x0 @ coef
    se_pred = np.sqrt(s2 * x0 @ np.linalg.solve(X.T @ X, x0))  # OLS prediction standard error
    se_var = s2 * np.sqrt(2.0 / dof)  # standard error of a Gaussian sample variance
    assert abs(pred - cond.mean[0]) < N_SE * se_pred
    assert abs(s2 - cond.cov[0, 0]) < N_SE * se_var


def test_condition_on_everything_is_rejected():
    with pytest.raises(ShapeError, match="nothing is left"):
        sm.Gaussian(MEAN3, COV3).condition([0, 1, 2], [0.0, 0.0, 0.0])


def test_condition_singular_block_is_reported():
    g = sm.Gaussian([0.0, 0.0, 0.0], [[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 1.0, 1.0]])
    with pytest.raises(SingularMatrixError, match="P\\^yy is singular"):
        g.condition([1, 2], [0.0, 0.0])


def test_condition_value_shape():
    with pytest.raises(ShapeError, match="value must have length 2"):
        sm.Gaussian(MEAN3, COV3).condition([1, 2], [0.0])


# --------------------------------------------------------------------------- sampling
def test_sample_mean_and_cov_within_5_se():
    g = sm.Gaussian(MEAN3, COV3)
    n = 100_000
    S = g.sample(n, rng=np.random.default_rng(11))
    assert S.shape == (n, 3)
    d = np.sqrt(np.diag(COV3))
    np.testing.assert_array_less(np.abs(S.mean(axis=0) - MEAN3), N_SE * d / np.sqrt(n))
    C = np.cov(S.T)
    # Standard error of a sample covariance entry of a Gaussian: sqrt((P_ii P_jj + P_ij^2) / n).
    se = np.sqrt((np.outer(d**2, d**2) + COV3**2) / n)
    np.testing.assert_array_less(np.abs(C - COV3), N_SE * se)


def test_sample_is_reproducible_for_a_seed():
    g = sm.Gaussian(MEAN3, COV3)
    np.testing.assert_array_equal(g.sample(10, rng=3), g.sample(10, rng=np.random.default_rng(3)))


@pytest.mark.parametrize("n", [0, -1, 2.5])
def test_sample_size_is_validated(n):
    with pytest.raises(ValueError, match="n must be a positive integer"):
        sm.Gaussian(MEAN3, COV3).sample(n)


# --------------------------------------------------------------------------- fusion
P1 = np.array([[3.0, 1.0], [1.0, 2.0]])
P2 = np.array([[1.0, -0.4], [-0.4, 2.5]])
X1 = np.array([1.0, 2.0])
X2 = np.array([1.5, 1.0])


def test_fuse_information_form():
    g = sm.fuse(sm.Gaussian(X1, P1), sm.Gaussian(X2, P2))
    I1, I2 = np.linalg.inv(P1), np.linalg.inv(P2)
    P = np.linalg.inv(I1 + I2)
    np.testing.assert_allclose(g.cov, P, rtol=CLOSED_FORM_RTOL)
    np.testing.assert_allclose(g.mean, P @ (I1 @ X1 + I2 @ X2), rtol=CLOSED_FORM_RTOL)


def test_fuse_equals_a_kalman_update():
    """An independent route: prior N(X1, P1), measurement y = x + e, e ~ N(0, P2), y = X2."""
    joint = sm.Gaussian(np.concatenate([X1, X1]), np.block([[P1, P1], [P1, P1 + P2]]))
    upd = joint.condition([2, 3], X2)
    g = sm.fuse(sm.Gaussian(X1, P1), sm.Gaussian(X2, P2))
    np.testing.assert_allclose(g.mean, upd.mean, rtol=CLOSED_FORM_RTOL)
    np.testing.assert_allclose(g.cov, upd.cov, rtol=CLOSED_FORM_RTOL)


def test_fuse_bad_inputs():
    with pytest.raises(ShapeError, match="at least one"):
        sm.fuse()
    with pytest.raises(ShapeError, match="dimensions differ"):
        sm.fuse(sm.Gaussian([0.0], [[1.0]]), sm.Gaussian([0.0, 0.0], np.eye(2)))
    with pytest.raises(SingularMatrixError, match="estimate 1"):
        sm.fuse(sm.Gaussian([0.0, 0.0], np.eye(2)), sm.Gaussian([0.0, 0.0], np.ones((2, 2))))


# --------------------------------------------------------------------------- the float range (issue 13)
@pytest.mark.parametrize("var", [1e-308, 1e-320])
def test_fuse_refuses_an_information_that_overflows(var):
    """P⁻¹ = 1e308 twice is inf: a clear error, not a RuntimeWarning and a NaN."""
    with pytest.raises(CovarianceError, match=r"fuse: the information .* overflows \(smallest variance"):
        sm.fuse(sm.Gaussian([0.0], [[var]]), sm.Gaussian([1.0], [[var]]))


def test_fuse_near_the_float_maximum_is_exact():
    g = sm.fuse(sm.Gaussian([0.0], [[1e308]]), sm.Gaussian([1.0], [[1e308]]))
    assert g.cov[0, 0] == pytest.approx(5e307, rel=1e-15)  # (2/1e308)⁻¹, rounded twice
    assert g.mean[0] == pytest.approx(0.5, rel=1e-15)


def test_condition_whose_mean_overflows_is_refused():
    """K = P_xy / P_yy ≈ 1e154 times an innovation of 1e300 is inf."""
    g = sm.Gaussian([0.0, 0.0], [[1.0, 1e-154], [1e-154, 1e-308]])
    with pytest.raises(ShapeError, match="mean contains NaN or inf"):
        g.condition([1], [1e300])


# --------------------------------------------------------------------------- conditioning near a zero posterior (issue 13)
x, y = sp.symbols("x y", real=True)


def _exact_schur(P: np.ndarray, iy: list[int]) -> np.ndarray:
    """P_xx − P_xy P_yy⁻¹ P_yx of the float matrix P, in exact rational arithmetic."""
    ix = [i for i in range(P.shape[0]) if i not in iy]
    M = sp.Matrix([[Fraction(float(v)) for v in row] for row in P])
    S = M.extract(ix, ix) - M.extract(ix, iy) * M.extract(iy, iy).inv() * M.extract(iy, ix)
    return np.array(S.tolist(), dtype=float)


def test_condition_near_a_zero_posterior_is_psd():
    """The issue's example: a noise-free observation of the whole polar state.  The
    posterior covariance is rank one (ut2 is almost a linearisation), and rounding put its
    smallest eigenvalue at −6.79e-9.  It must agree with the exact Schur complement of the
    same joint matrix to SCHUR_RTOL times its terms (‖P_xx‖ = 9): that is the rounding
    allowance, and the result is PSD."""
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], angles=[1])
    m = sm.propagate(polar, sm.Gaussian([-30, 0.5], [[4, 1], [1, 9]]), transform=sm.UT.ut2())
    post = m.condition([30.2, 3.13])
    exact = _exact_schur(m.joint.cov, [2, 3])
    scale = max(9.0, np.abs(exact).max())
    np.testing.assert_allclose(post.cov, exact, rtol=0, atol=SCHUR_RTOL * scale)
    eig = np.linalg.eigvalsh(post.cov)
    assert eig[0] >= -PSD_RTOL * np.abs(post.cov).max()
    assert eig[0] <= SCHUR_RTOL * scale  # near zero: the observation pins one direction down


def test_condition_beyond_rounding_of_the_terms_still_raises():
    """A joint with an eigenvalue of −9e-11 passes the Gaussian's own check (−PSD_RTOL·1),
    but conditioning on the component of variance 1e-4 divides it by 1e-4: the complement
    1 − a²/1e-4 = −9e-7 is beyond SCHUR_RTOL of its terms (≈ 1), so it is not rounding."""
    b, delta = 1e-4, 9e-11
    a = np.sqrt(b + delta)
    joint = sm.Gaussian([0.0, 0.0], [[1.0, a], [a, b]])
    with pytest.raises(CovarianceError, match=r"conditional covariance .* smallest eigenvalue -9"):
        joint.condition([1], [0.0])
