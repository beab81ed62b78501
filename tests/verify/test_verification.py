"""sm.verify and its claims (issue 37, item 3): proved only by exact simplification, refuted with
a counterexample that holds in exact arithmetic, consistent within a reference's error bound."""

from __future__ import annotations

import json

import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.errors import ArgumentError, ShapeError, UndecidedProofError
from symmon.verify.verification import EXACT_RTOL

x, y, mu, a, b, c = sp.symbols("x y mu a b c", real=True)
s = sp.Symbol("sigma", positive=True)


def exact_difference_at(v, lhs, rhs, symbols):
    """lhs − rhs at the counterexample's point, recomputed here from the exact rationals, 60 digits."""
    point = {sym: sp.Rational(v.counterexample["point"][sym.name]) for sym in symbols}
    return sp.N((sp.sympify(lhs) - sp.sympify(rhs)).xreplace(point), 60)


# --------------------------------------------------------------------------- proved
@pytest.mark.parametrize("lhs, rhs", [
    (sp.sin(x)**2 + sp.cos(x)**2, 1),
    ((x**2 - y**2) / (x - y), x + y),
    (sp.exp(x) * sp.exp(y), sp.exp(x + y)),
    (sp.Matrix([[x, y], [0, x]]).inv(), sp.Matrix([[1 / x, -y / x**2], [0, 1 / x]])),
])
def test_exact_identities_are_proved(lhs, rhs):
    v = sm.verify(lhs, rhs)
    assert v.verdict == "proved" and v.proved and v.passed
    assert v.evidence["difference"] == "0" and v.counterexample is None
    assert v.evidence["also_zero_at_random_points"] >= 1


def test_an_expectation_in_closed_form_is_proved():
    v = sm.verify(sm.Expectation(x**2, x, mu, s**2), mu**2 + s**2)
    assert v.verdict == "proved"
    assert any("symmon.expect" in n for n in v.evidence["notes"])
    assert "sigma > 0" in v.assumptions


# --------------------------------------------------------------------------- refuted
def test_a_refutation_holds_in_exact_arithmetic():
    lhs, rhs = sp.cos(2 * x), 1 - sp.sin(x)**2
    v = sm.verify(lhs, rhs)
    assert v.verdict == "refuted" and not v.passed
    d = exact_difference_at(v, lhs, rhs, [x])
    if v.counterexample["exact_difference"] is not None:  # short exact forms are reported, and right
        point = {x: sp.Rational(v.counterexample["point"]["x"])}
        shown = sp.sympify(v.counterexample["exact_difference"])  # test-side parse of symmon's own output
        assert sp.simplify(shown - (lhs - rhs).xreplace(point)) == 0
    assert abs(d) > sp.Float("1e-3")
    assert sp.Float(v.counterexample["difference"], 20) == pytest.approx(float(d), rel=1e-15)
    assert "100 digits" in v.counterexample["recheck"]


def test_the_assumptions_decide_sqrt_of_a_square():
    assert sm.verify(sp.sqrt(x**2), x).verdict == "refuted"
    assert sm.verify(sp.sqrt(x**2), x, assumptions=[x >= 0]).verdict == "proved"
    assert sm.verify(sp.sqrt(x**2), x, assumptions={x: "nonnegative"}).verdict == "proved"
    v = sm.verify(sp.sqrt(x**2), -x, assumptions={"x": "negative"})
    assert v.verdict == "proved" and "x < 0" in v.assumptions


def test_a_relation_between_symbols_restricts_the_random_points_only():
    claim = (sp.Max(x, y), x)
    assert sm.verify(*claim).verdict == "refuted"
    v = sm.verify(*claim, assumptions=[x >= y])
    assert v.verdict in ("proved", "consistent") and any("restricts" in t for t in v.assumptions)


def test_a_counterexample_names_the_entry_of_a_matrix():
    v = sm.verify(sp.Matrix([[x, 0], [0, x**2]]), sp.Matrix([[x, 0], [0, x * abs(x)]]))
    assert v.verdict == "refuted" and v.counterexample["entry"] == "[1, 1]"
    assert sp.Rational(v.counterexample["point"]["x"]) < 0


@settings(max_examples=25, deadline=None)
@given(coeffs=st.lists(st.integers(-9, 9), min_size=1, max_size=4),
       digits=st.integers(13, 30), k=st.integers(0, 3), sign=st.sampled_from([-1, 1]))
def test_claims_that_differ_beyond_the_12th_digit_are_never_proved(coeffs, digits, k, sign):
    """A claim off by 10^-13 .. 10^-30 of a term is refuted (or at worst consistent), never proved."""
    f = sum(cf * x**i for i, cf in enumerate(coeffs)) + sp.exp(x)
    g = f + sign * sp.Rational(1, 10**digits) * (x**k + 1)
    v = sm.verify(g, f)
    assert v.verdict != "proved"
    if v.verdict == "refuted":
        assert exact_difference_at(v, g, f, [x]) != 0
    # a float offset is read exactly, not rounded away (up to 14 digits: beyond, sympy's own
    # float arithmetic rounds 1 + 1e-17 to 1.0 before verify sees the claim)
    if digits <= 14:
        assert sm.verify(f + sp.Float(10.0**-digits) * (x**k + 1), f).verdict != "proved"


# --------------------------------------------------------------------------- consistent (numeric references)
def test_no_closed_form_is_consistent_within_the_quadrature_error():
    """E[atan(x)] = 0 for a centred x by symmetry: no closed form, so consistent, never proved."""
    v = sm.verify(sm.Expectation(sp.atan(x), x, 0, s**2), 0)
    assert v.verdict == "consistent"
    assert "quadrature" in v.method and float(v.evidence["max_difference_over_bound"]) <= 1


def test_no_closed_form_and_a_wrong_value_is_refuted_numerically():
    v = sm.verify(sm.Expectation(1 / (1 + x**2), x, mu, s**2), 1 / (1 + mu**2 + s**2))
    assert v.verdict == "refuted"
    assert "refined reference" in v.counterexample["recheck"]


def test_two_dimensional_reference_is_gauss_hermite():
    """E√(x² + y²) = σ√(π/2) (Rayleigh) for x, y ~ N(0, σ²I)."""
    r = sp.sqrt(x**2 + y**2)
    v = sm.verify(sm.Expectation(r, [x, y], [0, 0], sp.eye(2) * s**2), s * sp.sqrt(sp.pi / 2), points=2)
    assert v.verdict == "consistent" and "Gauss-Hermite" in v.method
    wrong = sm.verify(sm.Expectation(r, [x, y], [0, 0], sp.eye(2) * s**2), s * sp.sqrt(2), points=2)
    assert wrong.verdict == "refuted"


def test_four_dimensional_reference_is_monte_carlo_with_its_standard_error():
    """E‖z‖ for z ~ N(0, I_4) is the chi mean √2 Γ(5/2)/Γ(2) = 3√(2π)/4."""
    zs = sp.symbols("z1:5", real=True)
    E = sm.Expectation(sp.sqrt(sum(z**2 for z in zs)), zs, [0] * 4, sp.eye(4))
    v = sm.verify(E, 3 * sp.sqrt(2 * sp.pi) / 4)
    assert v.verdict == "consistent" and "standard errors" in v.method


# --------------------------------------------------------------------------- claims about models
def test_verify_derivatives_of_the_polar_model():
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)])
    r2 = x**2 + y**2
    J = [[x / sp.sqrt(r2), y / sp.sqrt(r2)], [-y / r2, x / r2]]
    assert sm.verify_derivatives(polar, jacobian=J).verdict == "proved"
    H_theta = sp.Matrix([[2 * x * y, y**2 - x**2], [y**2 - x**2, -2 * x * y]]) / r2**2
    H_r = sp.Matrix([[y**2, -x * y], [-x * y, x**2]]) / r2**sp.Rational(3, 2)
    assert sm.verify_derivatives(polar, hessians=[H_r, H_theta]).verdict == "proved"
    v = sm.verify_derivatives(polar, hessians=[H_r, -H_theta])
    assert v.verdict == "refuted" and v.counterexample["entry"].startswith("H_1")


def test_verify_moments_of_a_model_under_tt1_and_its_mon_is_zero():
    """TT1 linearises: Σ_gg = J P Jᵀ, Σ_gu = J P, so D = 0 and M² = 0 for any weight (29)."""
    p11, p22 = sp.symbols("p11 p22", positive=True)
    p12 = sp.Symbol("p12", real=True)
    P = sp.Matrix([[p11, p12], [p12, p22]])
    model = sm.Model([x, y], [x * y, x**2])
    u = (sp.Matrix([a, b]), P)
    J = sp.Matrix([[b, a], [2 * a, 0]])
    v = sm.verify_moments(model, u, mean=[a * b, a**2], cov=J * P * J.T, cross_cov=J * P, transform="tt1")
    assert v.verdict == "proved"
    assert sm.verify_mon(model, u, 0, weight="liu-li-raw", transform="tt1").verdict == "proved"
    wrong = sm.verify_moments(model, u, cov=J * P * J.T + sp.eye(2) * p11 / 10**12, transform="tt1")
    assert wrong.verdict == "refuted" and wrong.counterexample["entry"] == "Cov y[0, 0]"


def test_verify_estimator_the_mmse_of_a_square_and_a_biased_plug_in():
    v = sm.verify_estimator(x**2, mu**2 + s**2, x, mu, s**2, mse=4 * mu**2 * s**2 + 2 * s**4)
    assert v.verdict == "proved"
    plug_in = sm.verify_estimator(x**2, mu**2, x, mu, s**2)
    assert plug_in.verdict == "refuted" and plug_in.counterexample["entry"] == "bias E[h - est]"
    assert sm.verify_estimator(x**2, mu**2, x, mu, s**2, bias=s**2).verdict == "proved"


# --------------------------------------------------------------------------- the errata of the unitless-measure paper
def test_erratum_remark_2_the_printed_weight_is_refuted_exactly():
    """Remark 2 prints W = I/√tr Σ_gg for (8); it is I/tr Σ_gg (derivations/ERRATA.md, entry 5)."""
    S = sp.Matrix([[a, b], [b, c]])
    v = sm.verify_weight("liu-li", S, sp.eye(2) / sp.sqrt(S.trace()))
    assert v.verdict == "refuted"
    pt = {k: sp.Rational(val) for k, val in v.counterexample["point"].items()}
    Sn = S.xreplace({a: pt["a"], b: pt["b"], c: pt["c"]})
    assert Sn.is_positive_definite  # an admissible covariance
    assert sp.simplify(1 / sp.sqrt(Sn.trace()) - 1 / Sn.trace()) != 0  # exactly
    assert sm.verify_weight("liu-li", S, sp.eye(2) / S.trace()).verdict == "proved"
    assert sm.verify_weight("full", S, S.inv() / 2).verdict == "proved"


def test_erratum_37_38_the_weight_relation_with_s_v_is_refuted_and_with_s_y_proved():
    """M²(ḡ; W̄) = M²(g; S⁻¹ W̄ S⁻¹) holds with S = S_y, not with the printed S_v (entry 2).
    Changes of units are diagonal; D = Σ_gg − C − Σ_gu Σ_uu⁻¹ Σ_ug, D̄ = S_y⁻¹ D S_y⁻¹."""
    sy = sp.symbols("s_y1 s_y2", positive=True)
    sv = sp.symbols("s_v1 s_v2", positive=True)
    d11, d22 = sp.symbols("d11 d22", positive=True)
    d12, w11, w12, w22 = sp.symbols("d12 w11 w12 w22", real=True)
    D = sp.Matrix([[d11, d12], [d12, d22]])
    Wb = sp.Matrix([[w11, w12], [w12, w22]])
    Sy, Sv = sp.diag(*sy), sp.diag(*sv)
    lhs = (Wb * Sy.inv() * D * Sy.inv()).trace()
    good = sm.verify(lhs, (Sy.inv() * Wb * Sy.inv() * D).trace(), domain=[(D, "spd"), (Wb, "spd")])
    assert good.verdict == "proved"
    printed = (Sv.inv() * Wb * Sv.inv() * D).trace()
    bad = sm.verify(lhs, printed, domain=[(D, "spd"), (Wb, "spd")])
    assert bad.verdict == "refuted"
    point = {sym: sp.Rational(bad.counterexample["point"][sym.name]) for sym in lhs.free_symbols | printed.free_symbols}
    exact = (lhs - printed).xreplace(point)
    assert exact.is_Rational and exact != 0  # a rational number: exact
    assert sp.Rational(bad.counterexample["exact_difference"]) == exact
    assert sp.Matrix(D.xreplace(point)).is_positive_definite


def test_erratum_3_the_true_norm_does_not_give_26():
    """E√(w e²) = √w σ √(2/π), not w σ² (entry 3)."""
    e, w = sp.Symbol("e", real=True), sp.Symbol("w", positive=True)
    v = sm.verify(sm.Expectation(sp.sqrt(w * e**2), e, 0, s**2), w * s**2)
    assert v.verdict == "refuted"
    right = sm.verify(sm.Expectation(sp.sqrt(w * e**2), e, 0, s**2), sp.sqrt(w) * s * sp.sqrt(2 / sp.pi))
    assert right.verdict in ("proved", "consistent")


# --------------------------------------------------------------------------- the certificate
def test_the_certificate_prints_and_converts_to_json():
    v = sm.verify(sp.cos(2 * x), 1 - sp.sin(x)**2)
    text = str(v)
    for part in ("claim:", "verdict:     REFUTED", "method:", "assumptions:", "evidence:", "counterexample: at x ="):
        assert part in text
    data = json.loads(v.to_json())
    assert data["verdict"] == "refuted" and data["counterexample"]["point"] == v.counterexample["point"]
    assert repr(v).startswith("Verification(verdict='refuted'")


def test_bad_input_is_refused_with_a_clear_error():
    with pytest.raises(ShapeError, match="shapes"):
        sm.verify(sp.Matrix([x, y]), sp.Matrix([x]))
    with pytest.raises(ArgumentError, match="not one of"):
        sm.verify(x, x, assumptions={x: "big"})
    with pytest.raises(ArgumentError, match="points"):
        sm.verify(x, x, points=0)
    with pytest.raises(ArgumentError, match="not a symbol"):
        sm.verify(x, x, domain={"zz": (0, 1)})
    with pytest.raises(ShapeError, match="mean"):
        sm.Expectation(x, [x, y], [0], sp.eye(2))
    with pytest.raises(UndecidedProofError, match="domain"):
        sm.verify(sp.log(x) * 0 + sp.log(-x**2 - 1), 1)  # defined nowhere on the reals


def test_the_exact_tolerance_is_far_below_double_precision():
    assert EXACT_RTOL < sp.Float("1e-30")
def test_exact_moments_without_closed_form_use_a_numeric_reference():
    model = sm.Model([x], [sp.atan(x)])
    v = sm.verify_moments(model, (sp.Matrix([0]), sp.Matrix([[s**2]])), mean=[0], transform="exact")
    assert v.verdict == "consistent"
    bad = sm.verify_moments(model, (sp.Matrix([mu]), sp.Matrix([[s**2]])), mean=[sp.atan(mu)], transform="exact")
    assert bad.verdict == "refuted"



def test_verify_moments_of_a_model_with_noise():
    """y = x·e (multiplicative noise), e ~ N(1, r) independent of x ~ N(m, p): E y = m, Var y = (m² + p)(1 + r) − m²."""
    e = sp.Symbol("e", real=True)
    r = sp.Symbol("r", positive=True)
    p = sp.Symbol("p", positive=True)
    model = sm.Model([x], [x * e], noise=[e])
    u, v = (sp.Matrix([mu]), sp.Matrix([[p]])), (sp.Matrix([1]), sp.Matrix([[r]]))
    good = sm.verify_moments(model, u, mean=[mu], cov=[[(mu**2 + p) * (1 + r) - mu**2]], transform="exact", v=v)
    assert good.verdict == "proved"
    assert sm.verify_moments(model, u, cov=[[p * (1 + r)]], transform="exact", v=v).verdict == "refuted"
    with pytest.raises(ArgumentError, match="noise"):
        sm.verify_moments(model, u, mean=[mu])
