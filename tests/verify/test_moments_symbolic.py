"""sm.symbolic_moments: E y, Cov y, Cov(y, u) as sympy matrices (issue 37, item 2).

Evaluated at numbers (30 digits), the symbolic moments equal sm.propagate with the same
transform to 1e-12 relative to the largest entry: the formulas are the same, so only the
numeric side's rounding separates them.  ut2 is the exception that proves it: its float
weights (about ±1e6, from α = 1e-3) are themselves off by δ ≈ 3e-11 relative against the
exact rule (measured here), and the numeric moments inherit that, so ut2's tolerance is
derived from δ.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentTypeError, ExpectationNotClosedForm, ModelError, ResourceError

RTOL = 1e-12

x, y, e, f = sp.symbols("x y e f", real=True)
POLAR = sm.problems.polar().model
#: y = [x e^e + y, y e + f, sin(x) + f]: multiplicative and additive noise, n_w = 4 in two blocks
NOISY = sm.Model([x, y], [x * sp.exp(e) + y, y * e + f, sp.sin(x) + f], noise=[e, f], name="verify_noisy")
U = sm.Gaussian([3.0, 1.0], [[0.4, 0.1], [0.1, 0.3]])
V = sm.Gaussian([0.0, 0.0], [[0.05, 0.01], [0.01, 0.02]])
TRANSFORMS = [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.UT.ut2(), sm.UT.cubature(), sm.UT(0.5, 2.0, 1.0)]


def _float_weight_error(tr: sm.Transform, n: int) -> float:
    """The largest relative error of the rule's float weights against its exact ones."""
    _, wm, wc = tr.symbolic_unit_rule(n)
    _, fm, fc = tr.unit_rule(n)
    return max(abs(float(a) - b) / abs(float(a)) for a, b in zip(wm + wc, list(fm) + list(fc)) if a != 0)


def _tolerance(tr: sm.Transform, n: int) -> float:
    # ut2: 1e3 δ covers δ times the cancellation of its ±1e6-weighted sums (measured 2.6 δ on
    # the polar model); every other rule's float weights are exact to 1 ulp.
    return max(RTOL, 1e3 * _float_weight_error(tr, n)) if tr.point_rule else RTOL


def _assert_equal(sym: sm.SymbolicMoments, num, tol: float, v: sm.Gaussian | None = None):
    got = sym.evaluate(num.input, v)
    for name, a, b in zip(("mean", "cov", "cross_cov"), got, (num.mean, num.cov, num.cross_cov)):
        np.testing.assert_allclose(a, b, rtol=0, atol=tol * np.abs(b).max(), err_msg=name)


@pytest.mark.parametrize("tr", TRANSFORMS, ids=repr)
def test_polar_model_equals_propagate(tr):
    sym = sm.symbolic_moments(POLAR, tr)
    assert {str(s) for s in sym.symbols} <= {"mu_x", "mu_y", "P_x_x", "P_x_y", "P_y_y"}
    _assert_equal(sym, sm.propagate(POLAR, U, transform=tr), _tolerance(tr, 2))


@pytest.mark.parametrize("tr", TRANSFORMS, ids=repr)
def test_noisy_model_equals_propagate(tr):
    sym = sm.symbolic_moments(NOISY, tr)
    assert {"P_e_e", "P_e_f", "P_f_f"} <= {str(s) for s in sym.symbols}
    _assert_equal(sym, sm.propagate(NOISY, U, V, transform=tr), _tolerance(tr, 4), V)


def test_exact_moments_equal_propagate_with_exact_for_a_noisy_polynomial():
    model = sm.Model([x, y], [x**2 * y + e, x * y * f + e**2], noise=[e, f], name="verify_poly")
    v = sm.Gaussian([0.2, -0.1], [[0.05, 0.01], [0.01, 0.02]])
    sym = sm.symbolic_moments(model, "exact", noise_mean=sp.symbols("mu_e mu_f", real=True))
    _assert_equal(sym, sm.propagate(model, U, v, transform=sm.Exact()), RTOL, v)


def test_exact_moments_beyond_polynomials_equal_high_order_gauss_hermite():
    """x e^e + y and sin(x) + f: no polynomial, so Exact() refuses; Gauss–Hermite of order
    16 (16⁴ nodes) integrates these entire functions to ~1e-16 at these variances."""
    sym = sm.symbolic_moments(NOISY, sm.Exact())
    _assert_equal(sym, sm.propagate(NOISY, U, V, transform=sm.GaussHermite(order=16)), RTOL, V)


def test_exact_moments_of_the_polar_model_are_refused():
    with pytest.raises(ExpectationNotClosedForm, match="sqrt"):
        sm.symbolic_moments(POLAR, sm.Exact())


# --------------------------------------------------------------------------- the formulas
def test_tt2_of_a_square_is_the_exact_moment_and_prints():
    m = sm.symbolic_moments(sm.Model([x], [x**2]), sm.TT2())
    mu, P = sp.Symbol("mu_x", real=True), sp.Symbol("P_x_x", real=True)
    assert sp.expand(m.mean[0] - (mu**2 + P)) == 0
    assert sp.expand(m.cov[0, 0] - (4 * mu**2 * P + 2 * P**2)) == 0
    assert sp.expand(m.cross_cov[0, 0] - 2 * mu * P) == 0
    exact = sm.symbolic_moments(sm.Model([x], [x**2]), "exact")
    assert sp.expand(exact.mean[0] - m.mean[0]) == 0 and sp.expand(exact.cov[0, 0] - m.cov[0, 0]) == 0
    text = m.latex()
    assert text.startswith(r"\begin{aligned}") and r"\mu_{x}" in text and "TT2()" in text
    assert m._repr_latex_() == f"${text}$"


def test_given_symbols_and_numbers_are_used():
    a, b = sp.symbols("a b", real=True)
    s = sp.Symbol("s", positive=True)
    m = sm.symbolic_moments(POLAR, sm.TT1(), mean=[a, b], cov=[[s**2, 0], [0, s**2]])
    assert sp.simplify(m.mean[0] - sp.sqrt(a**2 + b**2)) == 0
    assert sp.simplify(m.cov[0, 0] - s**2) == 0  # the range of an isotropic Gaussian, to first order
    exact = sm.symbolic_moments(sm.Model([x], [x**3]), "exact", mean=[1], cov=[[sp.Rational(1, 2)]])
    assert exact.mean[0] == sp.Rational(5, 2)  # 1 + 3·½: exact numbers stay exact


def test_ut1_in_one_dimension_has_the_closed_form_sigma_points():
    """n = 1, κ = 2: points μ ± √3 σ, weights 2/3 and 1/6 (Julier & Uhlmann)."""
    m = sm.symbolic_moments(sm.Model([x], [sp.sin(x)]), sm.UT.ut1())
    mu, P = sp.Symbol("mu_x", real=True), sp.Symbol("P_x_x", real=True)
    r = sp.sqrt(3) * sp.sqrt(P)
    want = sp.Rational(2, 3) * sp.sin(mu) + (sp.sin(mu + r) + sp.sin(mu - r)) / 6
    assert sp.simplify(m.mean[0] - want) == 0


def test_angle_outputs():
    radar = sm.problems.radar_h(noise=False)
    tt2 = sm.symbolic_moments(radar, sm.TT2())
    assert tt2.unwrapped == frozenset({1})
    with pytest.raises(ModelError, match="with_angles"):
        sm.symbolic_moments(radar, sm.UT.ut1())
    plain = sm.symbolic_moments(radar.with_angles(()), sm.UT.ut1())
    assert plain.unwrapped == frozenset()


# --------------------------------------------------------------------------- refusals
def test_large_symbolic_blocks_and_stochastic_rules_are_refused():
    big = sm.Model(list(sp.symbols("a0:4", real=True)), [sp.Add(*sp.symbols("a0:4", real=True))])
    with pytest.raises(ResourceError, match="4 x 4"):
        sm.symbolic_moments(big, sm.UT.ut1())
    # numbers, or a block-diagonal P, keep the factor small: allowed
    sm.symbolic_moments(big, sm.UT.ut1(), cov=np.eye(4))
    assert sm.symbolic_moments(big, sm.TT2()).cov.shape == (1, 1)  # TT needs no factor
    with pytest.raises(ArgumentTypeError, match="stochastic"):
        sm.symbolic_moments(POLAR, sm.MonteCarlo(n=1000, seed=1))
    with pytest.raises(ArgumentTypeError, match="Model"):
        sm.symbolic_moments("polar", sm.TT1())
    with pytest.raises(ModelError, match="noise"):
        sm.symbolic_moments(POLAR, sm.TT1(), noise_cov=[[1]])


@pytest.mark.parametrize("tr", [sm.UT.ut1(), sm.UT.ut2(), sm.UT.cubature(), sm.UT(0.5, 2.0, 1.0)], ids=repr)
def test_the_exact_unit_rule_is_the_float_rule(tr):
    """Transform.symbolic_unit_rule against unit_rule: points and weights to 1 ulp (ut2: to
    the error of its floats, n + λ = 1e-6 n computed by cancellation, below 1e-10 relative)."""
    for n in (1, 2, 3, 4):
        Z, wm, wc = tr.symbolic_unit_rule(n)
        z, fm, fc = tr.unit_rule(n)
        tol = 1e-10 if tr == sm.UT.ut2() else 1e-15
        np.testing.assert_allclose(np.array(Z.evalf(20).tolist(), dtype=float), z, rtol=0, atol=tol * np.abs(z).max())
        np.testing.assert_allclose([float(w) for w in wm + wc], np.concatenate([fm, fc]), rtol=tol, atol=tol)
        assert sum(wm) == 1  # exactly
    assert sm.TT1().symbolic_unit_rule(2) is None


def test_evaluate_refuses_what_it_cannot_give():
    from symmon.errors import ArgumentError, NonFiniteError

    noisy = sm.symbolic_moments(NOISY, sm.TT1())
    with pytest.raises(ArgumentError, match="noise"):
        noisy.evaluate(U)
    polar = sm.symbolic_moments(POLAR, sm.TT1())
    with pytest.raises(ArgumentError, match="no noise"):
        polar.evaluate(U, V)
    with pytest.raises(NonFiniteError, match="not a finite real"):
        polar.evaluate(sm.Gaussian([0.0, 0.0], np.eye(2)))  # the range's Jacobian at the origin
    b = sp.Symbol("b", real=True)
    biased = sm.symbolic_moments(sm.Model([x], [x + b], params=[b]), sm.TT1())
    with pytest.raises(ArgumentError, match="parameter"):
        biased.evaluate(sm.Gaussian([1.0], [[1.0]]))
    fixed = sm.symbolic_moments(POLAR, sm.TT1(), cov=[[sp.Rational(2, 5), 0], [0, sp.Rational(3, 10)]])
    with pytest.raises(ArgumentError, match="derived for"):
        fixed.evaluate(U)  # U has a cross-covariance 0.1, the moments were derived for 0
