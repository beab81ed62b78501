"""Gauss–Hermite error estimates from two orders: ERROR_SAFETY · |Q_p − Q_{p+2}|.

The estimate is checked against the true error: against :class:`symmon.Exact` on
polynomials (where Q_{p+2} is exact once its degree suffices, so the estimate is exactly
ERROR_SAFETY times the error), and against a converged high-order rule on a smooth
non-polynomial model.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import SymmonError
from symmon.propagation import quadrature_error
from symmon.transforms.quadrature import ERROR_SAFETY

#: Closed forms and exact rules agree to rounding of sums of O(10²) terms.
CLOSED_RTOL = 1e-10
#: Below this size an error is rounding, not truncation: the estimate cannot resolve it.
ROUNDING_ATOL = 1e-12

MOMENTS = ("mean", "cov", "cross_cov")

x, y = sp.symbols("x y", real=True)
#: Per-coordinate degree 4 (mean), 8 (cov: products of outputs), 5 (cross).
POLY = sm.Model([x, y], [x**3 * y + y**4, x**2 * y**2 - x], name="qerr_poly")
POLY_U = sm.Gaussian([0.3, -0.2], [[1.0, 0.3], [0.3, 0.7]])
POLY_DEGREE = {"mean": 4, "cov": 8, "cross_cov": 5}

a, b = sp.symbols("a b", real=True)
SMOOTH = sm.Model([a, b], [sp.exp(a / 2) * sp.cos(b), a * b + sp.sin(a)], name="qerr_smooth")
SMOOTH_U = sm.Gaussian([0.2, 0.5], [[0.5, 0.1], [0.1, 0.3]])
#: The reference rule; REFERENCE_CHECK is a second high order to show it has converged.
REFERENCE_ORDER, REFERENCE_CHECK = 30, 24


@pytest.fixture(scope="module")
def poly_exact():
    return sm.propagate(POLY, POLY_U, transform=sm.Exact())


@pytest.fixture(scope="module")
def smooth_reference():
    ref = sm.propagate(SMOOTH, SMOOTH_U, transform=sm.GaussHermite(REFERENCE_ORDER))
    chk = sm.propagate(SMOOTH, SMOOTH_U, transform=sm.GaussHermite(REFERENCE_CHECK))
    for k in MOMENTS:
        np.testing.assert_allclose(getattr(ref, k), getattr(chk, k), rtol=0, atol=ROUNDING_ATOL, err_msg=k)
    return ref


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5])
def test_estimate_bounds_the_error_on_a_polynomial(order, poly_exact):
    m = quadrature_error(POLY, POLY_U, order=order)
    err = m.error
    for k in MOMENTS:
        true = np.abs(getattr(m, k) - getattr(poly_exact, k))
        scale = max(1.0, float(np.abs(getattr(poly_exact, k)).max()))
        assert np.all(true <= err[k] + CLOSED_RTOL * scale), k


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5])
def test_estimate_is_exact_once_the_higher_rule_is(order, poly_exact):
    # Q_{p+2} integrates per-coordinate degree 2(p + 2) − 1 exactly: then |Q_p − Q_{p+2}|
    # is the error itself.
    m = quadrature_error(POLY, POLY_U, order=order)
    err = m.error
    checked = [k for k in MOMENTS if POLY_DEGREE[k] <= 2 * (order + 2) - 1]
    for k in checked:
        true = np.abs(getattr(m, k) - getattr(poly_exact, k))
        scale = max(1.0, float(np.abs(getattr(poly_exact, k)).max()))
        np.testing.assert_allclose(err[k], ERROR_SAFETY * true, rtol=0, atol=CLOSED_RTOL * scale, err_msg=k)
    if order >= 3:  # every moment is covered from order 3 on: the test checks something
        assert checked == list(MOMENTS)


def test_estimate_is_zero_where_the_rule_is_exact(poly_exact):
    # Order 5 is exact for every moment of POLY (degree ≤ 9 per coordinate).
    m = quadrature_error(POLY, POLY_U, order=5)
    err = m.error
    for k in MOMENTS:
        scale = max(1.0, float(np.abs(getattr(poly_exact, k)).max()))
        assert float(err[k].max()) <= CLOSED_RTOL * scale, k


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5, 6, 7, 8])
def test_estimate_bounds_the_error_on_a_smooth_model(order, smooth_reference):
    # Orders up to 8: above, the truncation error of the mean reaches rounding (~1e-14).
    m = quadrature_error(SMOOTH, SMOOTH_U, order=order)
    err = m.error
    for k in MOMENTS:
        true = np.abs(getattr(m, k) - getattr(smooth_reference, k))
        assert np.all(true <= err[k] + ROUNDING_ATOL), (k, true, err[k])
        # And it is not vacuous: within the safety factor of the error it estimates.
        big = true > 1e3 * ROUNDING_ATOL
        np.testing.assert_array_less(err[k][big], 2 * ERROR_SAFETY * true[big], err_msg=k)


@pytest.mark.parametrize("order", [3, 5])
def test_sparse_grid_estimate_bounds_the_error(order):
    # Five inputs: the Smolyak grid; order p → p + 2 raises its level by one.  (Order 1,
    # the single point at the mean, is not yet converging: level 2 is not twice as close.)
    syms = sp.symbols("s0:5", real=True)
    model = sm.Model(list(syms), [syms[0] ** 2 * syms[1] + syms[2] * syms[3] * syms[4] + syms[4] ** 3], name="qerr_sparse")
    u = sm.Gaussian(np.linspace(-0.3, 0.4, 5), np.diag(np.linspace(0.5, 1.2, 5)) + 0.05)
    exact = sm.propagate(model, u, transform=sm.Exact())
    m = quadrature_error(model, u, order=order, sparse=True)
    err = m.error
    assert m.info["sparse"] is True
    for k in MOMENTS:
        true = np.abs(getattr(m, k) - getattr(exact, k))
        scale = max(1.0, float(np.abs(getattr(exact, k)).max()))
        assert np.all(true <= err[k] + CLOSED_RTOL * scale), k
    # The covariance (total degree 6) is not exact at level 3: the bound is not vacuous.
    assert float(np.abs(m.cov - exact.cov).max()) > CLOSED_RTOL


def test_the_estimate_leaves_the_moments_unchanged():
    plain = sm.propagate(SMOOTH, SMOOTH_U, transform=sm.GaussHermite(4))
    with_est = sm.propagate(SMOOTH, SMOOTH_U, transform=sm.GaussHermite(4, error_estimate=True))
    for k in MOMENTS:
        np.testing.assert_array_equal(getattr(with_est, k), getattr(plain, k))
    assert "error_estimate" not in plain.info
    # Two rules: 4² + 6² points.
    assert with_est.info["evaluations"] == 4**2 + 6**2


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_error_estimate_flag_is_validated(bad):
    with pytest.raises(SymmonError, match="error_estimate"):
        sm.GaussHermite(3, error_estimate=bad)
