"""Unit invariance from lemmas (symmon.units.proofs), (18)–(21), (29), (34)–(43).

Each lemma is checked to hold, to be able to fail, and against the transform code it is
about; the per-model proof is run on the example models, its refutations are checked against
``sm.nonlinearity``, and the direct route's guard is seen to stop.
"""

from __future__ import annotations


import numpy as np
import pytest
import sympy as sp
from helpers import EXAMPLES, random_spd

import symmon as sm
from symmon.cli import parser as cli
from symmon.units import lemmas, proofs as invariance
from symmon import units
from symmon.errors import SingularMatrixError, SymmonError
from symmon.files.modelfile import load_model_file

#: Moments of a model and of its unit-changed copy, in double precision: a few products and
#: solves with scales of condition number up to ~1e3 separate them.
EQUIVARIANCE_RTOL = 1e-9
#: The counterexample's M² is computed in 40 digits; sm.nonlinearity in double precision.
MON_RTOL = 1e-9

x, y = sp.symbols("x y", real=True)
POLAR = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar")
U_POLAR = sm.Gaussian([1.0, 10.0], 0.17 * np.diag([1.0, 100.0]))


# ------------------------------------------------------------------------------ the lemmas
@pytest.mark.parametrize("lemma", [invariance.lemma_tt2, invariance.lemma_cholesky, invariance.lemma_point_rule])
def test_lemma_holds_claim_by_claim(lemma):
    lem = lemma()
    assert lem.holds
    assert len(lem.claims) >= 3 and all(ok for _, ok in lem.claims)
    assert lem.name in str(lem) and "FAIL" not in str(lem)


def test_the_lemma_checker_rejects_wrong_identities():
    """The reductions the lemmas rest on can say no: a dropped S or a wrong Hessian map."""
    A, S, J, P = (sp.MatrixSymbol(n, 3, 3) for n in "ASJP")
    assert lemmas._is_zero_matrix((A * J * S) * (S.I * P * S.I.T) * (A * J * S).T - A * J * P * J.T * A.T)
    assert not lemmas._is_zero_matrix((A * J) * (S.I * P * S.I.T) * (A * J).T - A * J * P * J.T * A.T)
    H = sp.MatrixSymbol("H", 3, 3)
    assert lemmas._reduce(sp.Trace(S.T * H * S * S.I * P * S.I.T) - sp.Trace(H * P)) == 0
    assert lemmas._reduce(sp.Trace(S * H * S * S.I * P * S.I.T) - sp.Trace(H * P)) != 0


@pytest.mark.parametrize(("weight", "holds"), [("full", True), ("diag", True), ("liu-li", False), ("liu-li-raw", False)])
@pytest.mark.parametrize("n_y", [1, 2, 3])
def test_weight_lemma(weight, n_y, holds):
    """(43) and (42) are invariant for every n_y; Liu–Li's (8) only for a single output, (6) never."""
    lem = invariance.lemma_weight(weight, n_y)
    assert lem.holds == (holds or (weight == "liu-li" and n_y == 1))


def test_weight_lemma_for_a_general_weight():
    wbar = sp.Matrix([[3, 1], [1, 2]]) / 5
    assert invariance.lemma_weight(wbar, 2).holds


def _scales(rng, n, kind):
    if kind == "diagonal":
        return np.diag(rng.uniform(0.01, 100.0, n))
    if kind == "lower":
        return np.tril(rng.uniform(-1.0, 1.0, (n, n)), -1) + np.diag(rng.uniform(0.5, 5.0, n))
    return random_spd(rng, n) + 0.5 * np.eye(n)


def _moments_both_ways(rng, transform, su_kind):
    Su, Sy = _scales(rng, 2, su_kind), _scales(rng, 2, "full")
    ou, oy = rng.standard_normal(2), rng.standard_normal(2)
    g_bar = units.change_units(POLAR, S_u=Su, o_u=ou, S_y=Sy, o_y=oy)
    u_bar = units.change_gaussian(U_POLAR, Su, ou)
    m = sm.propagate(POLAR, U_POLAR, transform=transform)
    mb = sm.propagate(g_bar, u_bar, transform=transform)
    A, Su_inv = np.linalg.inv(Sy), np.linalg.inv(Su)
    return m, mb, A, Su_inv, oy


@pytest.mark.parametrize(
    ("transform", "su_kind"),
    [(sm.TT2(), "full"), (sm.UT.ut1(), "diagonal"), (sm.UT.ut2(), "lower"), (sm.GaussHermite(order=5), "lower"),
     (sm.MonteCarlo(n=2000, seed=3), "diagonal")],
    ids=["tt2-full-S", "ut1-diagonal-S", "ut2-lower-S", "gh-lower-S", "mc-diagonal-S"],
)
def test_the_transforms_obey_their_lemma(rng, transform, su_kind):
    """E ḡ = A(E g − o_y), Σ_ḡḡ = A Σ_gg Aᵀ, Σ_ḡū = A Σ_gu S_u⁻ᵀ with A = S_y⁻¹, for the scales the lemma allows."""
    m, mb, A, Su_inv, oy = _moments_both_ways(rng, transform, su_kind)
    np.testing.assert_allclose(mb.mean, A @ (m.mean - oy), rtol=EQUIVARIANCE_RTOL, atol=EQUIVARIANCE_RTOL)
    np.testing.assert_allclose(mb.cov, A @ m.cov @ A.T, rtol=EQUIVARIANCE_RTOL, atol=EQUIVARIANCE_RTOL)
    np.testing.assert_allclose(mb.cross_cov, A @ m.cross_cov @ Su_inv.T, rtol=EQUIVARIANCE_RTOL, atol=EQUIVARIANCE_RTOL)


def test_a_full_input_scale_breaks_the_sigma_point_lemma(rng):
    """The Cholesky assumption matters: a full symmetric S_u rotates the UT sigma points."""
    m, mb, A, _, _ = _moments_both_ways(rng, sm.UT.ut1(), "full")
    assert not np.allclose(mb.cov, A @ m.cov @ A.T, rtol=1e-6)


# --------------------------------------------------------------------- per-model proofs
def _expected(weight: str, n_y: int) -> bool:
    return weight in ("full", "diag") or (weight == "liu-li" and n_y == 1)


@pytest.mark.parametrize("weight", ["full", "diag", "liu-li"])
@pytest.mark.parametrize("name", ["polar", "radar", "bot", "gmti", "rdcos"])
def test_examples(name, weight):
    """full and diag hold; liu-li is refuted, except for BOT, whose single output makes (8) invariant."""
    model = load_model_file(EXAMPLES / f"{name}.toml").model
    proof = units.prove_invariance(model, weight)
    assert proof.holds == _expected(weight, model.n_y)
    assert proof.lemmas[0] == "tt2-equivariance" and proof.lemmas[1].startswith(f"weight-{weight}")
    assert "by the lemmas: tt2-equivariance" in str(proof)
    if not proof.holds:
        cex = proof.counterexample
        assert cex["lhs"] != cex["rhs"]


@pytest.mark.parametrize("name", ["polar", "gmti", "rdcos"])
@pytest.mark.parametrize("weight", ["liu-li", "liu-li-raw"])
def test_counterexample_agrees_with_nonlinearity(name, weight):
    """The two M² of the refutation are those sm.nonlinearity computes (TT2) for g and for ḡ."""
    spec = load_model_file(EXAMPLES / f"{name}.toml")
    proof = units.prove_invariance(spec.model, weight, mean=spec.u)
    cex = proof.counterexample
    f = lambda M: np.array(sp.Matrix(M).evalf(), dtype=float)  # noqa: E731
    plain = spec.model.with_angles([])
    g_bar = units.change_units(plain, S_u=f(cex["S_u"]), o_u=f(cex["o_u"]).ravel(), S_y=f(cex["S_y"]), o_y=f(cex["o_y"]).ravel())
    u_bar = units.change_gaussian(spec.u, f(cex["S_u"]), f(cex["o_u"]).ravel())
    old = sm.nonlinearity(plain, spec.u, weight=weight, transform=sm.TT2()).squared
    new = sm.nonlinearity(g_bar, u_bar, weight=weight, transform=sm.TT2()).squared
    assert float(cex["lhs"]) == pytest.approx(old, rel=MON_RTOL)
    assert float(cex["rhs"]) == pytest.approx(new, rel=MON_RTOL)
    assert abs(old - new) > 1e-3 * abs(old)
    # The point is the file's distribution, made exact.
    assert np.allclose(f(cex["mean"]).ravel(), spec.u.mean) and np.allclose(f(cex["cov"]), spec.u.cov)


def test_noise_models_use_the_same_lemma():
    e1, e2 = sp.symbols("e1 e2", real=True)
    h = sm.Model([x, y], [x * y + x * e1, y**2 + sp.exp(x * e2)], noise=[e1, e2])
    assert h.structure == "general"
    assert units.prove_invariance(h, "full").holds
    proof = units.prove_invariance(h, "liu-li-raw", mean=[1, 2], cov=np.eye(2), noise_cov=np.diag([0.1, 0.2]))
    assert not proof.holds and proof.counterexample["lhs"] != proof.counterexample["rhs"]


@pytest.mark.parametrize("transform", [sm.UT.ut1(), "gh", sm.MonteCarlo(n=4000, seed=1)], ids=["ut1", "gh", "mc"])
def test_point_rules(transform):
    proof = units.prove_invariance(POLAR, "full", transform=transform, mean=U_POLAR)
    assert proof.holds and proof.lemmas == ("cholesky-equivariance", "point-rule-equivariance", "weight-full")
    bad = units.prove_invariance(POLAR, "liu-li", transform=transform, mean=U_POLAR)
    assert not bad.holds and abs(float(bad.counterexample["lhs"]) - float(bad.counterexample["rhs"])) > 1e-4


def test_point_rules_refuse_general_noise():
    e = sp.Symbol("e", real=True)
    with pytest.raises(SymmonError, match="no lemma covers"):
        units.prove_invariance(sm.Model([x], [sp.sin(x * e)], noise=[e]), "full", transform="ut")


def test_singular_sigma_gg_at_the_given_mean_is_an_error():
    twice = sm.Model([x, y], [x + y, 2 * (x + y)])
    with pytest.raises(SingularMatrixError, match="singular"):
        units.prove_invariance(twice, "full", mean=[1, 2], cov=np.eye(2))


def test_a_wrong_changed_model_is_caught(monkeypatch):
    """The per-model check compares ḡ with the chain rule: a ḡ that forgets o_y fails it."""
    real = invariance.changed_parts

    def forgets_offset(model, Su, ou, Sy, oy, Sv, suffix):
        return real(model, Su, ou, Sy, sp.zeros(*oy.shape), Sv, suffix)

    monkeypatch.setattr(invariance, "changed_parts", forgets_offset)
    with pytest.raises(SymmonError, match="not g composed"):
        units.prove_invariance(POLAR, "full")


# --------------------------------------------------------------------------- direct route
def test_direct_route_still_proves_small_models():
    proof = units.prove_invariance(POLAR, "full", mean=U_POLAR, route="direct")
    assert proof.holds and proof.lemmas == ()
    assert not units.prove_invariance(POLAR, "liu-li-raw", mean=U_POLAR, route="direct").holds


def test_direct_route_stops_at_its_budget():
    model = load_model_file(EXAMPLES / "gmti.toml").model
    with pytest.raises(SymmonError, match=r"did not finish in 0\.5 s .*lemma route"):
        units.prove_invariance(model, "full", route="direct", budget=0.5)


def test_direct_route_refuses_large_models(monkeypatch):
    monkeypatch.setattr(invariance, "DIRECT_MAX_SIZE", 10)
    with pytest.raises(SymmonError, match="too large .*lemma route"):
        units.prove_invariance(POLAR, "full", route="direct")


@pytest.mark.parametrize(("kwargs", "match"), [({"route": "fast"}, "route must be"), ({"route": "direct", "budget": -1}, "budget"),
                                               ({"route": "direct", "transform": "ut"}, "TT2 closed form only")])
def test_route_arguments_are_validated(kwargs, match):
    with pytest.raises(SymmonError, match=match):
        units.prove_invariance(POLAR, "full", **kwargs)


def test_cli_direct_route_out_of_budget(capsys):
    code = cli.main(["prove-invariance", str(EXAMPLES / "gmti.toml"), "--weight", "full", "--route", "direct", "--budget", "0.5"])
    _, err = capsys.readouterr()
    assert code != 0
    assert "step 1/3" in err and "did not finish in 0.5 s" in err and "--budget" in err


def test_cli_lemma_route_names_the_lemmas(capsys):
    code = cli.main(["prove-invariance", str(EXAMPLES / "gmti.toml"), "--weight", "diag", "--numeric"])
    out, _ = capsys.readouterr()
    assert code == 0
    assert "holds" in out and "by the lemmas: tt2-equivariance, weight-diag (n_y=3)" in out


def test_symbolic_proof_refuted_at_a_given_distribution():
    proof = units.prove_invariance(POLAR, "liu-li", at=(U_POLAR,))
    assert proof.symbols["mean"].free_symbols  # the statement stays symbolic
    np.testing.assert_allclose(np.array(proof.counterexample["mean"], dtype=float).ravel(), U_POLAR.mean)
    with pytest.raises(SymmonError, match="at must be"):
        units.prove_invariance(POLAR, "liu-li", at=U_POLAR)
