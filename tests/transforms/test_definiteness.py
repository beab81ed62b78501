"""Cov y is positive semi-definite or refused (issue 26, part 1): one policy for every rule.

A rule with negative weights (the UT with κ < 0, ut1 above 3 dimensions; Gauss–Hermite's
sparse grid; the fifth-degree cubature rule above 4 dimensions) can sum a covariance with a
negative eigenvalue.  ``Transform.moments`` refuses it with an
``IndefiniteCovarianceError`` naming the transform, the Gaussian and the eigenvalue; the
test is scale-invariant (Cov y scaled by the magnitudes it was summed from) with a
tolerance for rounding, so PSD but rank-deficient results of exact rules pass.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile import compiled
from symmon.errors import CovarianceError, IndefiniteCovarianceError, QuadratureWarning, SymmonError
from symmon.transforms import Cubature5
from symmon.transforms.base import DEFINITE_RTOL, Transform

#: Closed forms and exact identities agree to rounding.
EXACT_RTOL = 1e-12


def _sum_of_squares(n: int, factor: float = 1.0) -> tuple[sm.Model, sm.Gaussian]:
    xs = sp.symbols(f"x0:{n}", real=True)
    return sm.Model(list(xs), [factor * sum(s**2 for s in xs)]), sm.Gaussian(np.zeros(n), np.eye(n))


def _hook(transform: Transform, model: sm.Model, u: sm.Gaussian):
    """The rule's own numbers, before the template's checks (to state what is refused)."""
    return transform._moments(compiled(model), u.mean[None], u.cov[None], frozenset(), None)


def _ut_cov_identity(ut: sm.UT, n: int, Y: np.ndarray) -> np.ndarray:
    """Σ_k wᶜ_k (Y_k − ȳ)(Y_k − ȳ)ᵀ written as S + (β − α²) d dᵀ with e_k = Y_k − Y_0,
    S = Σ_{k≥1} w_k e_k e_kᵀ, d = Σ_{k≥1} w_k e_k (using Σ wᵐ = 1, wᶜ_0 = wᵐ_0 + 1 − α² + β).
    It is PSD whenever β ≥ α²; only β < α² with Σ_{k≥1} w_k > 1 can make it indefinite."""
    wm, _, _ = ut.weights(n)
    e = Y[1:] - Y[0]
    S = np.einsum("k,ki,kj->ij", wm[1:], e, e)
    d = wm[1:] @ e
    return S + (ut.beta - ut.alpha**2) * np.outer(d, d)


# --------------------------------------------------------------------------- refused
@pytest.mark.parametrize("n", [4, 5, 8])
def test_ut1_negative_variance_is_refused(n):
    """ut1 (κ = 3 − n < 0 for n > 3) on y = ‖u‖², u ~ N(0, I): the points ±√3 eᵢ give
    ȳ = n (exact) and Var y = n(3 − n) < 0 against the true 2n.  The rule computes that
    number (the identity S − d dᵀ); the template refuses it, naming the transform, the
    Gaussian, the eigenvalue and the negative weight."""
    model, u = _sum_of_squares(n)
    hook = _hook(sm.UT.ut1(), model, u)
    assert hook.cov[0, 0, 0] == pytest.approx(n * (3 - n), rel=EXACT_RTOL)
    Y = hook.details["transformed_points"][0]
    assert hook.cov[0] == pytest.approx(_ut_cov_identity(sm.UT.ut1(), n, Y), rel=1e-10)
    w0c = sm.UT.ut1().weights(n)[1][0]
    with pytest.raises(IndefiniteCovarianceError,
                       match=rf"UT\.ut1\(\): Cov y of Gaussian 0 of 1 .* smallest eigenvalue is {n * (3 - n)}\b"
                             rf".* go down to {w0c:.3g}\..*non-negative"):
        sm.propagate(model, u, transform=sm.UT.ut1())


def test_an_indefinite_result_is_a_covariance_error_and_a_symmon_error():
    """Callers that catch CovarianceError or SymmonError (the CLI: exit 1) see it."""
    assert issubclass(IndefiniteCovarianceError, CovarianceError)
    assert issubclass(IndefiniteCovarianceError, SymmonError)


def test_custom_kappa_indefinite_matrix_is_refused():
    """UT(α=1, β=0, κ=−5), n = 6, y = (x₀², x₁²): points ±e_i, weights ½, w₀ = −5.
    S = I and d = (1, 1), so Cov y = S − d dᵀ = [[0, −1], [−1, 0]] (eigenvalues ±1): two
    non-negative variances, indefinite all the same, along y0 + y1."""
    xs = sp.symbols("x0:6", real=True)
    model, u = sm.Model(list(xs), [xs[0] ** 2, xs[1] ** 2]), sm.Gaussian(np.zeros(6), np.eye(6))
    ut = sm.UT(1.0, 0.0, -5.0)
    assert _hook(ut, model, u).cov[0] == pytest.approx(np.array([[0.0, -1.0], [-1.0, 0.0]]), abs=EXACT_RTOL)
    with pytest.raises(IndefiniteCovarianceError, match=r"smallest eigenvalue is -1, along \+1·y0, \+1·y1"):
        sm.propagate(model, u, transform=ut)


@pytest.mark.parametrize("n", [5, 20])
def test_sparse_gauss_hermite_is_announced_and_its_negative_variance_refused(n):
    """GaussHermite(3) above 4 dimensions falls to the sparse grid of total degree 3, whose
    covariance is exact for affine g only: for ‖u‖² it sums n(3 − n), −10 at n = 5 and −340
    at n = 20, against the exact 2n.  The fall is announced with the degree, and the
    variance refused."""
    model, u = _sum_of_squares(n)
    gh = sm.GaussHermite(3)
    with pytest.warns(QuadratureWarning, match=rf"in {n} dimensions uses the Smolyak sparse grid .*negative "
                                               r"weights.*total degree 3 only"):
        hook = _hook(gh, model, u)
    assert hook.cov[0, 0, 0] == pytest.approx({5: -10.0, 20: -340.0}[n], rel=EXACT_RTOL)
    assert hook.details["degree"] == 3 == gh.degree(n)
    with pytest.raises(IndefiniteCovarianceError, match=rf"GaussHermite\(order=3.*smallest eigenvalue is "
                                                        rf"{hook.cov[0, 0, 0]:.6g}\b"):
        sm.propagate(model, u, transform=gh)


def test_sparse_gauss_hermite_states_its_degree_where_it_is_exact():
    """Within its degree the sparse grid is exact and passes: affine g (covariance degree 1)."""
    xs = sp.symbols("x0:6", real=True)
    model = sm.Model(list(xs), [sum((i + 1) * s for i, s in enumerate(xs)), xs[0] - xs[5]])
    u = sm.Gaussian(np.arange(6.0), np.diag(np.arange(1.0, 7.0)))
    m = sm.propagate(model, u, transform=sm.GaussHermite(3, sparse=True))
    A = np.array([[1, 2, 3, 4, 5, 6], [1, 0, 0, 0, 0, -1]], dtype=float)
    np.testing.assert_allclose(m.cov, A @ u.cov @ A.T, rtol=EXACT_RTOL)
    assert (m.info["sparse"], m.info["degree"]) == (True, 3)


def test_cubature5_above_four_dimensions_refuses_an_indefinite_result():
    """The fifth-degree rule's axis weights (4 − n)/(2(n + 2)²) are negative for n > 4: a
    quartic output of a single coordinate puts all its weight on the axis points."""
    xs = sp.symbols("x0:8", real=True)
    model, u = sm.Model(list(xs), [xs[0] ** 4]), sm.Gaussian(np.zeros(8), np.eye(8))
    assert _hook(Cubature5(), model, u).cov[0, 0, 0] < 0
    with pytest.raises(IndefiniteCovarianceError, match=r"Cubature5\(\)"):
        sm.propagate(model, u, transform=Cubature5())


# --------------------------------------------------------------------------- scale-invariant
@pytest.mark.parametrize("factor", [1e-150, 1.0, 1e100])
def test_the_verdict_does_not_depend_on_the_units_of_the_output(factor):
    """y = c‖u‖² is refused for every c (the relative eigenvalue is −0.6 for ut1 at n = 4)."""
    model, u = _sum_of_squares(4, factor)
    with pytest.raises(IndefiniteCovarianceError, match=r"-0\.6 relative to the magnitudes"):
        sm.propagate(model, u, transform=sm.UT.ut1())


def test_an_indefinite_block_beside_a_large_output_is_found():
    """A test relative to the largest entry of Cov y misses Var ‖u‖² = −4 beside an output
    of variance 1e16; scaled by each output's own magnitude it does not."""
    xs = sp.symbols("x0:4", real=True)
    model = sm.Model(list(xs), [sum(s**2 for s in xs), 1e8 * xs[1]])
    u = sm.Gaussian(np.zeros(4), np.eye(4))
    cov = _hook(sm.UT.ut1(), model, u).cov[0]
    assert np.linalg.eigvalsh(cov)[0] > -1e-10 * np.abs(cov).max()  # what the old test saw
    with pytest.raises(IndefiniteCovarianceError, match=r"smallest eigenvalue is -4, along \+1·y0"):
        sm.propagate(model, u, transform=sm.UT.ut1())


# --------------------------------------------------------------------------- not refused
@pytest.mark.parametrize("n", [5, 20])
def test_ut2_negative_weight_but_psd_passes(n):
    """ut2 has w₀ = 1 − 1/α² ≈ −10⁶ for every n, but β = 2 ≥ α², so its covariance
    S + (β − α²) d dᵀ is PSD in exact arithmetic: it passes.  For y = ‖u‖² it is
    α²n² + (β − α²)n² = βn² (against the true 2n)."""
    model, u = _sum_of_squares(n)
    m = sm.propagate(model, u, transform=sm.UT.ut2())
    assert m.cov[0, 0] == pytest.approx(2.0 * n**2, rel=1e-8)  # w₀ ≈ −1e6 costs ~6 digits


@pytest.mark.parametrize("offset", [0.0, 1e6])
@pytest.mark.parametrize("transform", [sm.UT.ut1(), sm.UT.ut2(), sm.GaussHermite(3, sparse=True), Cubature5()],
                         ids=repr)
def test_rank_deficient_exact_results_of_negative_weights_pass(transform, offset):
    """An affine g of rank 1 with three outputs, in 6 dimensions, far from the origin or not:
    every rule is exact, Cov y = A P Aᵀ is singular, and its rounding is not refused.  ut2's
    points lie α√6 σ ≈ 1.3e-3 σ apart, so g rounded at 1e6 costs it eps·1e6/1.3e-3 ≈ 2e-7
    of its covariance: its own inaccuracy, not refused either."""
    xs = sp.symbols("x0:6", real=True)
    s = xs[0] + 3 * xs[1] - xs[4]
    model = sm.Model(list(xs), [s, 2 * s + 1, -s / 7])
    P = 0.3 * np.eye(6) + 0.1
    u = sm.Gaussian(offset + np.arange(6.0), P)
    a = np.array([1, 3, 0, 0, -1, 0], dtype=float)
    A = np.outer([1, 2, -1 / 7], a)
    m = sm.propagate(model, u, transform=transform)
    rtol = 1e-6 if transform == sm.UT.ut2() and offset else 1e-9
    np.testing.assert_allclose(m.cov, A @ P @ A.T, rtol=rtol, atol=rtol * (a @ P @ a))
    assert np.linalg.matrix_rank(A @ P @ A.T) == 1


def test_duplicated_quadratic_outputs_of_cubature5_pass():
    """y = (x₀², x₀², x₀² + 1) in 6 dimensions: the fifth-degree rule (negative axis
    weights) is exact for the covariance of a quadratic, 2·(ones), rank 1."""
    xs = sp.symbols("x0:6", real=True)
    model = sm.Model(list(xs), [xs[0] ** 2, xs[0] ** 2, xs[0] ** 2 + 1])
    m = sm.propagate(model, sm.Gaussian(np.zeros(6), np.eye(6)), transform=Cubature5())
    np.testing.assert_allclose(m.cov, 2.0 * np.ones((3, 3)), rtol=EXACT_RTOL)


@pytest.mark.parametrize("transform", [sm.TT1(), sm.TT2(), sm.Exact()], ids=repr)
def test_a_rounding_negative_variance_of_a_psd_rule_passes(transform):
    """y = 1.5 x₀ − 0.1 x₁ with P = a aᵀ, a = (0.1, 1.5): Var y is 0, and J P Jᵀ rounds to
    about −3e-18.  Against its own diagonal that would be −1; against the magnitude it
    was summed from ((|J| s)² ≈ 0.045) it is rounding, and it passes."""
    x0, x1 = sp.symbols("x0 x1", real=True)
    a = np.array([0.1, 1.5])
    model, u = sm.Model([x0, x1], [1.5 * x0 - 0.1 * x1]), sm.Gaussian([0.0, 0.0], np.outer(a, a))
    hook = _hook(transform, model, u)
    assert abs(hook.cov[0, 0, 0]) <= DEFINITE_RTOL * hook.cov_scale[0, 0]
    if transform == sm.TT1():
        assert hook.cov[0, 0, 0] < 0  # the case the scale is there for
    assert abs(sm.propagate(model, u, transform=transform).cov[0, 0]) < 1e-15


def test_cov_scale_of_a_taylor_rule_bounds_its_entries():
    """The Taylor rules' scale: |Cov y_ij| ≤ √(a_i a_j) on a random quadratic model."""
    rng = np.random.default_rng(3)
    xs = sp.symbols("x0:3", real=True)
    outs = [sum(float(rng.standard_normal()) * xs[i] * xs[j] for i in range(3) for j in range(i, 3))
            + float(rng.standard_normal()) * xs[k] for k in range(3)]
    model = sm.Model(list(xs), outs)
    Q = rng.standard_normal((3, 3))
    u = sm.Gaussian(rng.standard_normal(3), Q @ Q.T)
    for t in (sm.TT1(), sm.TT2()):
        b = _hook(t, model, u)
        bound = np.sqrt(np.outer(b.cov_scale[0], b.cov_scale[0]))
        assert np.all(np.abs(b.cov[0]) <= bound * (1 + 1e-12))


# --------------------------------------------------------------------------- the mean alone
def test_expectation_skips_only_the_definiteness_of_an_unreturned_covariance():
    """A nested rule's inner integral reads E y only: ``expectation`` gives it where
    ``moments`` refuses the covariance, and is the same mean where both work."""
    model, u = _sum_of_squares(4)
    cm = compiled(model)
    ut1 = sm.UT.ut1()
    np.testing.assert_allclose(ut1.expectation(cm, u.mean[None], u.cov[None]), [[4.0]], rtol=EXACT_RTOL)
    with pytest.raises(IndefiniteCovarianceError):
        ut1.moments(cm, u.mean[None], u.cov[None])
    other = sm.Gaussian(np.ones(4), 0.5 * np.eye(4))
    for t in (sm.UT.cubature(), sm.TT2()):
        np.testing.assert_array_equal(t.expectation(cm, other.mean[None], other.cov[None]),
                                      t.moments(cm, other.mean[None], other.cov[None]).mean)


def test_general_noise_nested_inner_rule_needs_no_covariance():
    """Σ_c of a general-noise model with ut1 in 4 dimensions of w: the inner rule at each
    outer point has an indefinite Cov y, which Σ_c does not use, so it is not refused; Σ_c
    equals the nested sum computed by hand from ``expectation``."""
    from symmon.measures.conditional import conditional_cov

    xs = sp.symbols("x0:3", real=True)
    e = sp.Symbol("e", real=True)
    model = sm.Model(list(xs), [sum(s**2 for s in xs) * (1 + e)], noise=[e])
    u, v = sm.Gaussian(np.zeros(3), np.eye(3)), sm.Gaussian([0.0], [[0.04]])
    ut1 = sm.UT.ut1()
    got = conditional_cov(model, u, v, ut1)
    V, w = ut1.outer_rule(v.mean, v.cov)
    means = np.hstack([np.zeros((len(V), 3)), V])
    covs = np.zeros((len(V), 4, 4))
    covs[:, :3, :3] = np.eye(3)
    h = ut1.expectation(compiled(model), means, covs)
    R = h - w @ h
    np.testing.assert_allclose(got, np.einsum("j,ji,jk->ik", w, R, R), rtol=EXACT_RTOL)


def test_a_rule_cannot_override_the_checked_entry_points():
    """``expectation`` is as final as ``moments``: a rule implements the hook only."""
    for name in ("moments", "expectation"):
        with pytest.raises(TypeError, match=rf"overrides {name}\(\)"):
            type("Bad", (Transform,), {name: lambda self, *a: None, "_moments": lambda self, *a: None,
                                       "cost": lambda self, n: 1})


def test_warnings_of_a_valid_rule_are_unchanged():
    """A rule with non-negative weights in many dimensions gives no warning and no error."""
    model, u = _sum_of_squares(6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = sm.propagate(model, u, transform=sm.GaussHermite(3, sparse=False))
    assert m.cov[0, 0] == pytest.approx(12.0, rel=EXACT_RTOL)


# --------------------------------------------------------------------------- semidefinite by construction
@pytest.mark.parametrize("transform, n, expected", [
    (sm.UT(1, 2, 0), 4, True), (sm.UT.cubature(), 6, True), (sm.UT.ut1(), 4, False), (sm.UT.ut1(), 2, True),
    (sm.GaussHermite(3, sparse=False), 3, True), (sm.GaussHermite(3, sparse=True), 6, False),
    (sm.TT1(), 5, True), (sm.TT2(), 5, True), (sm.MonteCarlo(100, seed=0), 5, True), (sm.Exact(), 2, False),
], ids=repr)
def test_which_rules_are_semidefinite_by_construction(transform, n, expected):
    """Non-negative covariance weights, J P Jᵀ (+ a Gram matrix) and a sample covariance
    are sums of PSD terms; a negative weight, or Exact's E yyᵀ − E y E yᵀ, is tested."""
    assert transform.semidefinite(n) is expected
    if transform.point_rule:
        assert expected == bool(np.all(transform.unit_rule(n)[2] >= 0))


def test_a_rule_with_a_negative_weight_is_still_tested(monkeypatch):
    """The test is skipped only where it cannot fail: ut1 on 4 inputs still refuses."""
    from symmon.transforms import base

    calls = []
    real = base.check_moments_definite
    monkeypatch.setattr(base, "check_moments_definite", lambda *a: calls.append(a[-1]) or real(*a))
    model, u = _sum_of_squares(4)
    sm.propagate(model, u, transform=sm.UT(1, 2, 0))
    assert calls == []  # non-negative weights: no test
    with pytest.raises(IndefiniteCovarianceError):
        sm.propagate(model, u, transform=sm.UT.ut1())
    assert calls == [sm.UT.ut1()]


def test_one_gaussian_is_not_checked_twice_but_an_array_batch_is(monkeypatch):
    """A symmon.Gaussian checked itself when it was made: propagate passes its batch as
    validated; propagate_many of raw arrays checks them (and refuses an indefinite one)."""
    from symmon.transforms import base

    calls = []
    real = base.check_batch
    monkeypatch.setattr(base, "check_batch", lambda *a: calls.append(1) or real(*a))
    model, u = _sum_of_squares(2)
    sm.propagate(model, u, transform=sm.TT2())
    assert calls == []
    with pytest.raises(CovarianceError):
        sm.propagate_many(model, (np.zeros((2, 2)), np.array([np.eye(2), -np.eye(2)])), transform=sm.TT2())
    assert calls == [1]
