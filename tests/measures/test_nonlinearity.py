"""Measures of nonlinearity: the paper's claims, the remarks, and the noise structures.

Straka & Havlík, "Design of unitless normalized measure of nonlinearity for state
estimation", FUSION 2024; equation numbers below are the paper's.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.measures import weights
from symmon.errors import SingularMatrixError, SymmonError
from symmon.measures.conditional import _general_cov, conditional_cov
from symmon.measures.formula import mon_from_moments
from symmon.core.problems import bot, gmti, polar, rdcos
from symmon.transforms import Cubature5

#: Closed forms and exact rescalings agree to rounding.
EXACT_TOL = 1e-10
#: Monte Carlo bound: 5 standard errors.
N_SE = 5
MC = sm.MonteCarlo(2 * 10**5, seed=1)

x, y, z = sp.symbols("x y z", real=True)
v1, v2 = sp.symbols("v1 v2", real=True)


# --------------------------------------------------------------------------- Sec. II-B, Fig. 1
@pytest.fixture(scope="module")
def polar_at_017():
    mc = sm.MonteCarlo(10**6, seed=0)
    out = {}
    for unit in ("rad", "deg"):
        p = polar(0.17, unit)
        out[unit] = {w: sm.nonlinearity(p.model, p.u, weight=w, transform=mc) for w in ("liu-li", "full", "diag")}
    return out


def test_liu_li_depends_on_bearing_unit_sec_2b(polar_at_017):
    """Sec. II-B: at α = 0.17, M^norm ≈ 10 % (rad) and ≈ 80 % (deg)."""
    rad, deg = polar_at_017["rad"]["liu-li"], polar_at_017["deg"]["liu-li"]
    assert abs(rad.value - 0.10) < 0.01
    assert abs(deg.value - 0.80) < 0.01
    # and the difference is far beyond Monte Carlo error
    assert deg.value - rad.value > 100 * (rad.stderr + deg.stderr)


@pytest.mark.parametrize("weight", ["full", "diag"])
def test_unitless_mon_equal_in_rad_and_deg(polar_at_017, weight):
    """The unitless MoNs are the same for (15) and (16): same samples, other units."""
    assert polar_at_017["rad"][weight].value == pytest.approx(polar_at_017["deg"][weight].value, rel=1e-9)


# --------------------------------------------------------------------------- Sec. V
@pytest.mark.parametrize("alpha", [0.1, 1.0, 10.0])
def test_bot_three_mons_coincide(alpha):
    """Sec. V: for the scalar BOT output W^full = W^diag and (8) equals them."""
    p = bot(alpha)
    vals = [float(sm.nonlinearity(p.model, p.u, weight=w, transform=sm.UT.ut1())) for w in ("full", "diag", "liu-li")]
    assert vals[0] == pytest.approx(vals[1], rel=EXACT_TOL)
    assert vals[0] == pytest.approx(vals[2], rel=EXACT_TOL)


@pytest.mark.parametrize("factory, alt", [(gmti, "km-deg-kmh"), (rdcos, "km")])
def test_unit_sets_of_sec_5_change_only_the_original_mon(factory, alt):
    base, other = factory(1.0), factory(1.0, alt)
    for w in ("full", "diag"):
        a = float(sm.nonlinearity(base.model, base.u, weight=w))
        b = float(sm.nonlinearity(other.model, other.u, weight=w))
        assert a == pytest.approx(b, rel=1e-9)
    a = float(sm.nonlinearity(base.model, base.u, weight="liu-li"))
    b = float(sm.nonlinearity(other.model, other.u, weight="liu-li"))
    assert abs(a - b) > 1e-3


# --------------------------------------------------------------------------- Remarks 1 and 2
@pytest.fixture(scope="module")
def gmti_moments():
    p = gmti(2.0)
    return p, sm.propagate(p.model, p.u, transform=sm.GaussHermite(5))


def test_remark2_identity_weight_gives_raw_mse_mon(gmti_moments):
    """W = I gives (6)/(13): √tr(Σ_ff − Σ_fu Σ_uu⁻¹ Σ_uf)."""
    p, m = gmti_moments
    ref = np.sqrt(np.trace(m.cov - m.cross_cov @ np.linalg.solve(p.u.cov, m.cross_cov.T)))
    got = sm.nonlinearity(p.model, p.u, weight="liu-li-raw", transform=sm.GaussHermite(5))
    assert got.value == pytest.approx(ref, rel=EXACT_TOL)
    assert np.allclose(got.weight, np.eye(3))


def test_remark2_trace_weight_gives_normalised_mon(gmti_moments):
    """W = I / tr Σ_gg gives (8) (the paper's 1/√tr is the weight of the unsquared norm)."""
    p, m = gmti_moments
    raw = sm.nonlinearity(p.model, p.u, weight="liu-li-raw", transform=sm.GaussHermite(5)).value
    got = sm.nonlinearity(p.model, p.u, weight="liu-li", transform=sm.GaussHermite(5)).value
    assert got == pytest.approx(raw / np.sqrt(np.trace(m.cov)), rel=EXACT_TOL)


def test_remark1_full_weight_is_coefficient_of_determination(gmti_moments):
    """Remark 1: noise-free W^full gives √(1 − tr(Σ_gg⁻¹ Σ_gu Σ_uu⁻¹ Σ_ug)/n_y)."""
    p, m = gmti_moments
    R2 = np.trace(np.linalg.solve(m.cov, m.cross_cov @ np.linalg.solve(p.u.cov, m.cross_cov.T))) / 3
    got = sm.nonlinearity(p.model, p.u, weight="full", transform=sm.GaussHermite(5)).value
    assert got == pytest.approx(np.sqrt(1 - R2), rel=EXACT_TOL)


def test_squared_parts_add_up_eq_25(gmti_moments):
    p, _ = gmti_moments
    r = sm.nonlinearity(p.model, p.u, weight="diag", transform=sm.UT.ut1())
    Eg2 = np.trace(r.weight @ (r.moments.cov + np.outer(r.moments.mean, r.moments.mean)))
    assert r.squared == pytest.approx(r.J_Ab + r.J_n - Eg2, rel=1e-6)  # (25) loses digits to |E g|²
    assert r.value == pytest.approx(np.sqrt(r.squared), rel=EXACT_TOL)


# --------------------------------------------------------------------------- transforms
AFFINE = sm.Model([x, y], [2 * x - 3 * y + 1, 0.5 * x + 4])
TRANSFORMS = [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.UT.ut2(), sm.UT.cubature(), sm.GaussHermite(3),
              sm.MonteCarlo(4000, seed=3), sm.MonteCarlo(4096, seed=3, qmc=True), sm.Exact()]


@pytest.mark.parametrize("transform", TRANSFORMS, ids=repr)
@pytest.mark.parametrize("weight", ["full", "diag", "liu-li", "liu-li-raw"])
def test_affine_model_has_zero_mon(transform, weight):
    u = sm.Gaussian([1.0, -2.0], [[2.0, 0.3], [0.3, 0.5]])
    r = sm.nonlinearity(AFFINE, u, weight=weight, transform=transform)
    # MC: the sample regression of an exactly affine g has zero residual up to rounding.
    assert r.value < 1e-6


def test_tt1_gives_zero_by_construction():
    p = polar(0.17)
    assert sm.nonlinearity(p.model, p.u, transform=sm.TT1()).value == 0.0


@settings(max_examples=25, deadline=None)
@given(
    a=st.floats(0.1, 3.0), b=st.floats(-2.0, 2.0), c=st.floats(0.05, 2.0),
    rho=st.floats(-0.9, 0.9), weight=st.sampled_from(["full", "diag", "liu-li"]),
)
def test_normalised_mons_lie_in_unit_interval(a, b, c, rho, weight):
    """(33): with tr(W Σ_gg) = 1 the MoN lies in [0, 1]."""
    model = sm.Model([x, y], [sp.sin(a * x) + b * y**2, sp.exp(c * x) * y])
    u = sm.Gaussian([0.3, 0.2], [[1.0, rho * 0.5], [rho * 0.5, 0.25]])
    r = sm.nonlinearity(model, u, weight=weight, transform=sm.GaussHermite(4))
    assert np.trace(r.weight @ r.moments.cov) == pytest.approx(1.0, rel=1e-9)
    assert 0.0 <= r.value <= 1.0 + 1e-12


@pytest.mark.parametrize("alpha", [1e-3, 1e-5])
def test_transforms_agree_as_alpha_goes_to_zero(alpha):
    """For a small spread TT2, Gauss–Hermite and MC approach the same MoN (relative O(α))."""
    p = gmti(alpha)
    ref = sm.nonlinearity(p.model, p.u, transform=sm.GaussHermite(5))
    tt2 = sm.nonlinearity(p.model, p.u, transform=sm.TT2())
    assert tt2.value == pytest.approx(ref.value, rel=10 * alpha)
    mc = sm.nonlinearity(p.model, p.u, transform=sm.MonteCarlo(4 * 10**5, seed=2))
    assert abs(mc.value - ref.value) < N_SE * mc.stderr


SCALAR = sm.Model([x], [sp.sin(x) + sp.exp(0.3 * x) + x**2])


@pytest.mark.parametrize("transform", [sm.UT.ut1(), sm.UT.cubature()], ids=repr)
def test_ut_agrees_as_alpha_goes_to_zero_for_one_input(transform):
    """With one input the sigma points carry the fourth moment of a quadratic (n + κ = 3 for
    ut1); cubature (n + κ = 1) does not, so only ut1 converges to TT2."""
    gaps = []
    for alpha in (1e-4, 1e-6):
        u = sm.Gaussian([0.4], [[alpha]])
        ut = sm.nonlinearity(SCALAR, u, transform=transform).value
        tt2 = sm.nonlinearity(SCALAR, u, transform=sm.TT2()).value
        gaps.append(abs(ut / tt2 - 1))
    if transform == sm.UT.ut1():
        assert gaps[1] < gaps[0] and gaps[1] < 1e-2
    else:
        assert gaps[1] > 0.1


def test_ut_underestimates_mixed_hessian_terms_of_gmti():
    """In several dimensions the UT MoN does not converge to TT2's as α → 0.

    For q = ½ zᵀAz, Var q = ½ Σ_ij A_ij², but the 2n + 1 sigma points give
    (n + κ)/4 Σ_i A_ii² − (tr A)²/4 and miss the A_ij, i ≠ j: the points have
    E[z_i² z_j²] = 0 instead of 1.  So the ratio UT/TT2 stays away from 1.
    """
    ratios = []
    for alpha in (1e-3, 1e-5):
        p = gmti(alpha)
        ut = sm.nonlinearity(p.model, p.u, weight="liu-li-raw", transform=sm.UT.ut1()).value
        tt2 = sm.nonlinearity(p.model, p.u, weight="liu-li-raw", transform=sm.TT2()).value
        ratios.append(ut / tt2)
    assert ratios[0] == pytest.approx(ratios[1], rel=1e-2)
    assert ratios[1] < 0.8


def test_mc_standard_error_covers_reference():
    """The jackknife error bar of the MC MoN is consistent with a quadrature reference."""
    model = sm.Model([x], [sp.exp(x)])
    u = sm.Gaussian([0.0], [[0.25]])
    ref = sm.nonlinearity(model, u, transform=sm.GaussHermite(30)).value
    vals = [sm.nonlinearity(model, u, transform=sm.MonteCarlo(20000, seed=s)) for s in range(8)]
    for r in vals:
        assert abs(r.value - ref) < N_SE * r.stderr
    spread = np.std([r.value for r in vals], ddof=1)
    mean_se = np.mean([r.stderr for r in vals])
    assert 0.3 < spread / mean_se < 3.0


# --------------------------------------------------------------------------- noise structures
def test_additive_noise_eq_29():
    """(29): additive noise leaves D = Σ_ff − Σ_fu Σ_uu⁻¹ Σ_uf, but enters Σ_gg of the weight."""
    f = [sp.sqrt(x**2 + y**2), sp.atan2(y, x)]
    R = np.diag([0.3, 0.01])
    noisy = sm.Model([x, y], [f[0] + v1, f[1] + v2], noise=[v1, v2])
    u = sm.Gaussian([1.0, 3.0], 0.2 * np.eye(2))
    v = sm.Gaussian([0.0, 0.0], R)
    tr = sm.GaussHermite(6)
    r = sm.nonlinearity(noisy, u, v, weight="liu-li-raw", transform=tr)
    clean = sm.nonlinearity(sm.Model([x, y], f), u, weight="liu-li-raw", transform=tr)
    assert r.structure == "additive"
    assert r.value == pytest.approx(clean.value, rel=1e-9)
    full = sm.nonlinearity(noisy, u, v, weight="full", transform=tr)
    Sgg = clean.moments.cov + R
    assert np.allclose(full.weight, np.linalg.inv(Sgg) / 2, rtol=1e-9)


MULT = sm.Model([x, y], [x**2 + x * v1 + y * v2**2, x * y + (1 + y) * v1], noise=[v1, v2])


def test_multiplicative_equals_general_formula():
    """(28) equals the general formula Cov(E[g | v]) on a multiplicative model (exact by GH)."""
    assert MULT.structure == "multiplicative"
    u = sm.Gaussian([0.5, 1.0], [[0.3, 0.1], [0.1, 0.2]])
    v = sm.Gaussian([0.0, 0.0], np.diag([0.2, 0.5]))
    tr = sm.GaussHermite(6)
    mult = conditional_cov(MULT, u, v, tr)
    gen = _general_cov(MULT, u, v, tr)
    assert np.allclose(mult, gen, rtol=1e-10, atol=1e-12)


def test_cubature5_nested_rule_for_general_noise_is_exact_for_polynomials():
    """Σ_c = Cov_v E[g | v] through the rule's declared inner and outer rules: for
    g = u² v² + v the inner mean (P_u + μ_u²) v² + v is quadratic in u, and Σ_c integrates
    its square, of degree 4 in v: degree 5 suffices, as for Gauss–Hermite 5 (exact to 9)."""
    u_, v_ = sp.symbols("u_ v_", real=True)
    model = sm.Model([u_], [u_**2 * v_**2 + v_], noise=[v_], name="arch_general")
    u, v = sm.Gaussian([0.5], [[0.4]]), sm.Gaussian([0.2], [[0.3]])
    got = _general_cov(model, u, v, Cubature5())
    want = _general_cov(model, u, v, sm.GaussHermite(5))
    np.testing.assert_allclose(got, want, rtol=EXACT_TOL)


def test_general_noise_matches_brute_force_least_squares():
    """The general formula equals a least-squares fit over [u, basis(v)] (assumptions A1, A2)."""
    model = sm.Model([x], [sp.sin(x + v1) + x * v1**2], noise=[v1])
    assert model.structure == "general"
    u, v = sm.Gaussian([0.4], [[0.5]]), sm.Gaussian([0.0], [[0.3]])
    r = sm.nonlinearity(model, u, v, weight="liu-li-raw", transform=sm.GaussHermite(12))
    rng = np.random.default_rng(7)
    n = 400_000
    U = u.sample(n, rng)[:, 0]
    V = v.sample(n, rng)[:, 0]
    g = np.sin(U + V) + U * V**2
    basis = np.polynomial.hermite_e.hermevander(V / np.sqrt(0.3), 12)[:, 1:]
    X = np.column_stack([np.ones(n), U, basis])
    coef, *_ = np.linalg.lstsq(X, g, rcond=None)
    res2 = (g - X @ coef) ** 2
    mse, se = res2.mean(), res2.std() / np.sqrt(n)
    assert abs(r.squared - mse) < N_SE * se


def test_general_noise_by_monte_carlo():
    model = sm.Model([x], [sp.sin(x + v1)], noise=[v1])
    u, v = sm.Gaussian([0.4], [[0.5]]), sm.Gaussian([0.0], [[0.3]])
    ref = sm.nonlinearity(model, u, v, weight="liu-li-raw", transform=sm.GaussHermite(12))
    mc = sm.nonlinearity(model, u, v, weight="liu-li-raw", transform=sm.MonteCarlo(4 * 10**5, seed=5))
    assert abs(mc.value - ref.value) < N_SE * mc.stderr


#: Seeds for the spread of the MoN; the sample SD of 20 values is within ±35 % of the
#: true SD with probability > 0.99, so a factor of 2 either way is a safe bound.
SE_SEEDS = 20
SE_FACTOR = 2.0


@pytest.mark.parametrize("structure, g", [
    ("general", sp.sin(x + v1)),
    ("multiplicative", sp.sin(x) + x**2 * v1),
], ids=["general", "multiplicative"])
def test_mc_error_bar_of_the_mon_matches_its_spread_over_seeds(structure, g):
    """The jackknife leaves group i out of the moments and of Σ_c = Cov(E[g | v]): for
    general noise Σ_c comes from a nested Monte Carlo whose error dominates (an error bar
    from the moments alone was 4.6x too small)."""
    model = sm.Model([x], [g], noise=[v1])
    assert model.structure == structure
    u, v = sm.Gaussian([0.4], [[0.5]]), sm.Gaussian([0.0], [[0.3]])
    runs = [sm.nonlinearity(model, u, v, transform=sm.MonteCarlo(20_000, seed=s)) for s in range(SE_SEEDS)]
    spread = np.std([r.value for r in runs], ddof=1)
    reported = np.mean([r.stderr for r in runs])
    assert spread / SE_FACTOR < reported < spread * SE_FACTOR


# --------------------------------------------------------------------------- weights
def test_general_weight_is_in_set_41_and_unitless():
    p = gmti(1.0)
    w = weights.general([0.2, 0.3, 0.5])
    r = sm.nonlinearity(p.model, p.u, weight=w, transform=sm.UT.ut1())
    assert np.trace(r.weight @ r.moments.cov) == pytest.approx(1.0, rel=1e-9)
    alt = gmti(1.0, "km-deg-kmh")
    r2 = sm.nonlinearity(alt.model, alt.u, weight=w, transform=sm.UT.ut1())
    assert r.value == pytest.approx(r2.value, rel=1e-9)


def test_diag_and_full_are_special_cases_of_set_41():
    p = gmti(1.0)
    full = sm.nonlinearity(p.model, p.u, weight="full", transform=sm.UT.ut1())
    diag_bar = sm.nonlinearity(p.model, p.u, weight=np.eye(3) / 3, transform=sm.UT.ut1())  # W̄^diag (39)
    diag = sm.nonlinearity(p.model, p.u, weight="diag", transform=sm.UT.ut1())
    assert diag_bar.value == pytest.approx(diag.value, rel=1e-12)
    S = np.sqrt(np.diag(full.moments.cov))
    corr = full.moments.cov / np.outer(S, S)
    full_bar = sm.nonlinearity(p.model, p.u, weight=np.linalg.inv(corr) / 3, transform=sm.UT.ut1())
    assert full_bar.value == pytest.approx(full.value, rel=1e-9)


@pytest.mark.parametrize("alphas, msg", [([0.5, 0.6], "sum to 1"), ([1.2, -0.2], "positive"), ([[0.5, 0.5]], "vector")])
def test_general_weight_validation(alphas, msg):
    with pytest.raises(SymmonError, match=msg):
        weights.general(alphas)


def test_matrix_weight_outside_set_41_is_refused():
    p = polar(0.1)
    with pytest.raises(SymmonError, match=r"set \(41\)"):
        sm.nonlinearity(p.model, p.u, weight=np.eye(2))


def test_unknown_weight_name():
    p = polar(0.1)
    with pytest.raises(SymmonError, match="unknown weight"):
        sm.nonlinearity(p.model, p.u, weight="fulll")


def test_singular_output_covariance_with_full_weight_names_the_combination():
    model = sm.Model([x, y], [x + y, 2 * x + 2 * y])
    u = sm.Gaussian([0.0, 0.0], np.eye(2))
    with pytest.raises(SingularMatrixError, match=r"y0 .*y1.* has no variance"):
        sm.nonlinearity(model, u, weight="full")
    assert sm.nonlinearity(model, u, weight="diag").value < 1e-8


def test_singular_input_covariance_uses_pseudo_inverse():
    model = sm.Model([x, y], [x**2 + y, sp.sin(x)])
    u = sm.Gaussian([0.3, 1.0], np.diag([0.4, 0.0]))
    r = sm.nonlinearity(model, u, weight="full", transform=sm.GaussHermite(8))
    assert any("pseudo-inverse" in n for n in r.notes)
    ref = sm.nonlinearity(sm.Model([x], [x**2 + 1.0, sp.sin(x)]), sm.Gaussian([0.3], [[0.4]]),
                          weight="full", transform=sm.GaussHermite(8))
    assert r.value == pytest.approx(ref.value, rel=1e-9)


def test_mon_from_moments_matches_definition():
    Sgg = np.array([[2.0, 0.5], [0.5, 1.0]])
    Sgu = np.array([[1.0], [0.3]])
    Suu = np.array([[1.5]])
    p = mon_from_moments(Sgg, Sgu, Suu, "liu-li-raw")
    assert p.squared == pytest.approx(np.trace(Sgg) - (1.0 + 0.09) / 1.5, rel=EXACT_TOL)


def test_compare_tabulates_every_transform():
    p = polar(0.01)
    rows = sm.compare(p.model, p.u)
    names = [r["transform"] for r in rows]
    assert any(n.startswith("TT2") for n in names) and any(n.startswith("MonteCarlo") for n in names)
    mc = [r for r in rows if r["transform"].startswith("MonteCarlo")][0]
    assert mc["stderr"] is not None and mc["stderr"] > 0
    assert [r for r in rows if r["transform"] == "TT1()"][0]["value"] == 0.0


def test_measure_display():
    p = polar(0.1)
    r = sm.nonlinearity(p.model, p.u, transform=MC)
    assert "±" in repr(r) and r"\pm" in r._repr_latex_()
    assert float(r) == r.value
