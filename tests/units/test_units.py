"""Unit changes (18)–(20), (35), pint conversions and the unit-invariance proofs (21), (34)–(43).

Direction convention under test: u = S_u ū + o_u with u in the old and ū in the new units,
so S is the old-unit value of one new unit (m → km: S = 1000; rad → deg: S = π/180).
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from helpers import random_spd

import symmon as sm
from symmon import units
from symmon.errors import ModelError, ShapeError, SingularMatrixError, SymmonError

#: Closed-form identities in double precision (a handful of matrix products and solves).
EXACT_RTOL = 1e-10
#: Unit invariance of the numeric MoN: TT2 and UT moments map exactly under (18), so only
#: rounding in scales with condition numbers up to ~1e3 separates the two values.
INVARIANCE_ATOL = 1e-9
#: pint's conversion factors are single float operations.
PINT_RTOL = 1e-14

x, y, z = sp.symbols("x y z", real=True)
POLAR = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar")
POLY = sm.Model([x, y, z], [x * y + z**2, x**2 - y * z + x], name="poly")
U_POLAR = sm.Gaussian([1.0, 10.0], 0.17 * np.diag([1.0, 100.0]))  # (14) with α = 0.17


# ------------------------------------------------------------------------------ change_units
def test_polar_rad_to_deg_gives_the_degree_model():
    """(16) → (15): S_y = diag(1, π/180) because 1 deg = π/180 rad."""
    g = units.change_units(POLAR, S_y=[1, sp.pi / 180])
    xb, yb = g.inputs
    assert (xb.name, yb.name) == ("x_bar", "y_bar")
    assert sp.simplify(g.outputs[0] - sp.sqrt(xb**2 + yb**2)) == 0
    assert sp.simplify(g.outputs[1] - 180 * sp.atan2(yb, xb) / sp.pi) == 0
    assert POLAR.change_units(S_y=sp.diag(1, sp.pi / 180)) == g


def test_change_units_is_the_formula_at_a_point():
    """ḡ(ū) = S_y⁻¹(g(S_u ū + o_u) − o_y), checked numerically against the formula."""
    Su, ou = np.array([[2.0, 0.5], [0.5, 3.0]]), np.array([0.3, -1.0])
    Sy, oy = np.array([[1.5, 0.2], [0.2, 0.7]]), np.array([4.0, 0.1])
    g = units.change_units(POLAR, S_u=Su, o_u=ou, S_y=Sy, o_y=oy)
    ub = np.array([0.7, 1.9])
    got = np.array(sp.lambdify(g.inputs, list(g.outputs))(*ub), dtype=float)
    u = Su @ ub + ou
    want = np.linalg.solve(Sy, np.array([np.hypot(*u), np.arctan2(u[1], u[0])]) - oy)
    np.testing.assert_allclose(got, want, rtol=EXACT_RTOL)


def test_change_units_scales_the_noise():
    e = sp.Symbol("e", real=True)
    h = sm.Model([x], [x**2 + x * e], noise=[e])
    g = units.change_units(h, S_v=[3])
    assert sp.expand(g.outputs[0] - (g.inputs[0] ** 2 + 3 * g.inputs[0] * g.noise[0])) == 0


def test_angle_declarations_survive_only_unchanged_units():
    p = POLAR.with_angles([1])
    assert units.change_units(p, S_u=[1000, 1000]).angle_outputs == frozenset({1})
    assert units.change_units(p, S_y=[1, sp.pi / 180]).angle_outputs == frozenset()


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"S_u": [[1, 2], [2, 4]]}, SingularMatrixError),
        ({"S_u": [1, 2, 3]}, ShapeError),
        ({"S_y": [1, -2]}, SymmonError),
        ({"S_y": [[1, 3], [-3, -1]]}, SymmonError),  # invertible, symmetric part indefinite
        ({"o_y": [1, 2, 3]}, ShapeError),
        ({"S_u": ["1", "2"]}, ShapeError),
        ({"S_v": [2]}, ModelError),  # no noise symbols
        ({"S_u": sp.symbols("a b", positive=True)}, ModelError),  # a Model takes no parameters
    ],
)
def test_change_units_validates(kwargs, error):
    with pytest.raises(error):
        units.change_units(POLAR, **kwargs)


def test_changed_relation_accepts_symbolic_scales():
    s, o = sp.symbols("s o", positive=True)
    ub, vb, g = units.changed_relation(POLAR, S_u=[s, s], o_u=[o, 0], S_y=[s, 1])
    assert vb == ()
    assert sp.simplify(g[0] - sp.sqrt((s * ub[0] + o) ** 2 + s**2 * ub[1] ** 2) / s) == 0


# --------------------------------------------------------------------------- change_gaussian
def test_change_gaussian_by_hand():
    """x = 1500 m ± 20 m in km: mean 1.5, variance 400/1000²."""
    g = units.change_gaussian(sm.Gaussian([1500.0], [[400.0]]), S=1000.0)
    np.testing.assert_allclose(g.mean, [1.5], rtol=EXACT_RTOL)
    np.testing.assert_allclose(g.cov, [[4e-4]], rtol=EXACT_RTOL)


def test_change_gaussian_round_trips(rng):
    d = sm.Gaussian(rng.standard_normal(3), random_spd(rng, 3))
    S = random_spd(rng, 3) + np.eye(3)
    o = rng.standard_normal(3)
    there = units.change_gaussian(d, S, o)
    Sinv = np.linalg.inv(S)
    back = units.change_gaussian(there, Sinv, -Sinv @ o)
    np.testing.assert_allclose(there.mean, np.linalg.solve(S, d.mean - o), rtol=EXACT_RTOL)
    np.testing.assert_allclose(back.mean, d.mean, rtol=EXACT_RTOL, atol=EXACT_RTOL)
    np.testing.assert_allclose(back.cov, d.cov, rtol=EXACT_RTOL, atol=EXACT_RTOL)


def test_change_gaussian_rejects_symbols():
    with pytest.raises(ShapeError):
        units.change_gaussian(U_POLAR, [sp.Symbol("s", positive=True), 1])


# ------------------------------------------------------------------------------------ pint
pytest.importorskip("pint")


def polar_with_units():
    return units.with_units(POLAR, inputs={"x": "m", "y": "m"}, outputs={"r": "m", "phi": "rad"},
                            output_names=["r", "phi"])


@pytest.mark.parametrize(
    ("old", "new", "S", "o"),
    [
        ("rad", "deg", np.pi / 180, 0.0),      # 1 deg = π/180 rad
        ("m", "km", 1000.0, 0.0),              # 1 km = 1000 m
        ("km", "m", 1 / 1000, 0.0),            # 1 m = 1/1000 km
        ("m/s", "km/h", 1 / 3.6, 0.0),         # 1 km/h = 1/3.6 m/s
        ("K", "degC", 1.0, 273.15),            # 0 degC = 273.15 K
    ],
)
def test_pint_scales_are_one_new_unit_in_old_units(old, new, S, o):
    t = sp.Symbol("t", real=True)
    um = units.with_units(sm.Model([t], [2 * t]), inputs={"t": old}, outputs=[old])
    conv = um.to(inputs={"t": new}, outputs={0: new})
    np.testing.assert_allclose(conv.S_u, [[S]], rtol=PINT_RTOL)
    np.testing.assert_allclose(conv.S_y, [[S]], rtol=PINT_RTOL)
    np.testing.assert_allclose(conv.o_u, [o], rtol=PINT_RTOL)
    # The direction: an old-unit value is S times the new-unit value plus o.
    ureg = um.registry
    np.testing.assert_allclose(S * 2.5 + o, ureg.Quantity(2.5, new).to(old).magnitude, rtol=PINT_RTOL)


def test_pint_polar_model_m_to_km_and_rad_to_deg():
    conv = polar_with_units().to(inputs={"x": "km", "y": "km"}, outputs={"r": "km", "phi": "deg"})
    np.testing.assert_allclose(conv.S_u, 1000 * np.eye(2), rtol=PINT_RTOL)
    np.testing.assert_allclose(conv.S_y, np.diag([1000, np.pi / 180]), rtol=PINT_RTOL)
    assert conv.units["outputs"] == {"r": "kilometer", "phi": "degree"}
    # The converted model maps km to (km, deg): the point (1, 10) km.
    val = [float(e.subs({x: 1, y: 10})) for e in conv.model.outputs]
    np.testing.assert_allclose(val, [np.hypot(1, 10), np.degrees(np.arctan2(10, 1))], rtol=EXACT_RTOL)
    u_km = conv.convert_gaussian(sm.Gaussian([1000.0, 10000.0], 170.0 * np.diag([1.0, 100.0])))
    np.testing.assert_allclose(u_km.mean, [1.0, 10.0], rtol=EXACT_RTOL)
    np.testing.assert_allclose(u_km.cov, 170e-6 * np.diag([1.0, 100.0]), rtol=EXACT_RTOL)


def test_pint_noise_has_no_offset():
    t, e = sp.symbols("t e", real=True)
    um = units.with_units(sm.Model([t], [t + e], noise=[e]), inputs={"t": "K"}, outputs=["K"], noise={"e": "K"})
    conv = um.to(noise={"e": "degC"})
    np.testing.assert_allclose(conv.S_v, [[1.0]], rtol=1e-12)
    v = conv.convert_gaussian(sm.Gaussian([0.0], [[4.0]]), kind="noise")
    np.testing.assert_allclose(v.mean, [0.0], atol=EXACT_RTOL)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: units.with_units(POLAR, {"x": "m", "y": "meterz"}, ["m", "rad"]), "unknown unit 'meterz'"),
        (lambda: units.with_units(POLAR, {"x": "m"}, ["m", "rad"]), r"no unit given for input \['y'\]"),
        (lambda: units.with_units(POLAR, {"x": "m", "q": "m"}, ["m", "rad"]), "unknown input 'q'"),
        (lambda: polar_with_units().to(outputs={"phi": "m"}), "incompatible dimensions"),
        (lambda: polar_with_units().to(inputs={"x": "s"}), "incompatible dimensions"),
    ],
)
def test_pint_errors_are_clear(call, match):
    with pytest.raises(units.UnitError, match=match):
        call()


# ------------------------------------------------------------------------ prove_invariance
def mixed_weight(corr: sp.Matrix) -> sp.Matrix:
    """(W̄^full + W̄^diag)/2: in the set (41), as tr(W̄ Σ_ḡḡ) = (n + n)/(2n) = 1."""
    return (corr.inv() + sp.eye(corr.rows)) / (2 * corr.rows)


@pytest.mark.parametrize(
    ("model", "weight"),
    [
        (POLAR, "full"),
        (POLAR, "diag"),
        (POLAR, mixed_weight),
        (POLAR, sp.Matrix([[3, 1], [1, 2]]) / 5),
        (POLY, "full"),
        (POLY, "diag"),
    ],
)
def test_unitless_weights_are_invariant_under_tt2(model, weight):
    proof = units.prove_invariance(model, weight)
    assert proof.holds
    assert proof.difference == 0
    assert "holds" in str(proof)


@pytest.mark.parametrize(("model", "weight"), [(POLAR, "liu-li"), (POLAR, "liu-li-raw"), (POLY, "liu-li-raw")])
def test_liu_li_is_not_invariant(model, weight):
    proof = units.prove_invariance(model, weight)
    assert not proof.holds
    assert proof.difference != 0
    # The certificate: an exact point with positive scales where the difference is nonzero.
    cex = proof.counterexample
    assert cex["difference"] != 0
    assert sp.N(proof.difference.xreplace({k: v for k, v in cex.items() if k != "difference"}) - cex["difference"]) == 0
    assert "fails" in str(proof)


def test_invariance_with_the_papers_numbers():
    """(14) with α = 0.17 made exact (17/100); bearing unit changes of Figure 1."""
    assert units.prove_invariance(POLAR, "full", mean=U_POLAR).holds
    assert not units.prove_invariance(POLAR, "liu-li", mean=U_POLAR.mean, cov=U_POLAR.cov).holds


def test_invariance_with_noise():
    e1, e2 = sp.symbols("e1 e2", real=True)
    h = sm.Model([x, y], [x * y + x * e1, y**2 + e2], noise=[e1, e2])
    assert units.prove_invariance(h, "full").holds
    assert not units.prove_invariance(h, "liu-li-raw").holds


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"weight": "euclid"}, SymmonError),
        ({"weight": sp.Matrix([[1, 2], [0, 1]])}, SymmonError),  # not symmetric
        ({"weight": sp.Matrix([[1, 2], [2, 1]])}, SymmonError),  # not positive definite
        ({"weight": "full", "transform": "tt1"}, SymmonError),  # no lemma for TT1 (UT is covered now)
        ({"weight": "full", "cov": [[1, 0], [0, -1]]}, SingularMatrixError),
        ({"weight": "full", "mean": [1, 2, 3]}, ShapeError),
    ],
)
def test_prove_invariance_validates(kwargs, error):
    with pytest.raises(error):
        units.prove_invariance(POLAR, **kwargs)


def test_proof_display():
    proof = units.prove_invariance(POLAR, "full")
    assert proof.latex.endswith(r"= 0\quad\text{(invariant)}")
    assert proof._repr_latex_() == "$" + proof.latex + "$"


# ------------------------------------------------------------------ prove_matrix_invariance
@pytest.mark.parametrize(("n", "weight"), [(2, "full"), (3, "full"), (2, "diag"), (3, "diag")])
def test_matrix_invariance_holds(n, weight):
    proof = units.prove_matrix_invariance(n, n, weight)
    assert proof.holds and proof.difference == 0


@pytest.mark.parametrize(("n_u", "n_y", "weight", "scales"),
                         [(2, 2, "liu-li", None), (3, 3, "liu-li-raw", None), (2, 2, "diag", "full")])
def test_matrix_invariance_fails(n_u, n_y, weight, scales):
    """Liu–Li fails; (42) fails under a full S_y, which mixes the outputs."""
    proof = units.prove_matrix_invariance(n_u, n_y, weight, scales=scales)
    assert not proof.holds
    assert proof.counterexample["difference"] != 0


# ------------------------------------------------- numeric invariance with sm.nonlinearity
def random_scale(rng, n, full):
    return random_spd(rng, n) + 0.5 * np.eye(n) if full else np.diag(rng.uniform(0.01, 100.0, n))


CASES = [
    # (transform, full S_u, full S_y, weight). UT uses a diagonal S_u: the Cholesky factor of
    # S_u⁻¹ P S_u⁻ᵀ is S_u⁻¹ chol(P) only for a diagonal S_u, otherwise the sigma points rotate.
    (sm.TT2(), True, True, "full"),
    (sm.TT2(), False, False, "diag"),
    (sm.TT2(), True, False, "diag"),
    (sm.UT.ut1(), False, True, "full"),
    (sm.UT.ut1(), False, False, "diag"),
]


@pytest.mark.parametrize(("transform", "full_u", "full_y", "weight"), CASES)
def test_numeric_mon_is_unit_invariant(rng, transform, full_u, full_y, weight):
    Su, Sy = random_scale(rng, 2, full_u), random_scale(rng, 2, full_y)
    ou, oy = rng.standard_normal(2), rng.standard_normal(2)
    g_bar = units.change_units(POLAR, S_u=Su, o_u=ou, S_y=Sy, o_y=oy)
    u_bar = units.change_gaussian(U_POLAR, Su, ou)
    before = float(sm.nonlinearity(POLAR, U_POLAR, weight=weight, transform=transform))
    after = float(sm.nonlinearity(g_bar, u_bar, weight=weight, transform=transform))
    assert 0.0 < before < 1.0
    assert after == pytest.approx(before, abs=INVARIANCE_ATOL)


@pytest.mark.parametrize("transform", [sm.TT2(), sm.UT.ut1()])
@pytest.mark.parametrize("weight", ["liu-li", "liu-li-raw"])
def test_numeric_liu_li_changes_with_units(transform, weight):
    """Figure 1: the bearing in degrees instead of radians changes Liu–Li's MoN."""
    g_deg = units.change_units(POLAR, S_y=[1, np.pi / 180])  # the inputs keep their units
    before = float(sm.nonlinearity(POLAR, U_POLAR, weight=weight, transform=transform))
    after = float(sm.nonlinearity(g_deg, U_POLAR, weight=weight, transform=transform))
    assert abs(after - before) > 0.1 * before

