"""Unit-invariance proofs of models with kinks, and refutations that refute (issue 26).

- A model with ``Abs``, ``sign``, ``Max``, ``Min``, ``Heaviside``, ``floor``, ``Piecewise`` is
  proved on the smooth branch of g off its kinks (``symmon.units.kinks.localize``); a numeric
  mean on a kink is refused by the TT2 and direct routes with a ``NonSmoothModelError``; the
  point rules evaluate g only and take it.
- A "holds" from a numeric route (a numeric mean, or a point rule) comes after symmon's own
  MoN agreed in several changes of units; where it does not, ``UndecidedProofError``.
- A refutation shows two values of M² that differ: a linear model's Liu–Li MoN is 0 in every
  unit, so it holds (``residual-zero``), and a distribution where M² happens to be invariant
  is undecided, not "refuted" with two equal numbers.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.cli import parser as cli
from symmon.errors import NonSmoothModelError, SymmonError, UndecidedProofError
from symmon.units import check, prove_invariance
from symmon.units.kinks import kink_text, localize, nonsmooth_atoms

x, y = sp.symbols("x y", real=True)
R = sp.Rational
EYE = [[1, 0], [0, 1]]


# --------------------------------------------------------------------------- the smooth branch
@pytest.mark.parametrize("expr, point, branch", [
    (sp.Abs(x) * x, (R(3, 2), 0), x**2),
    (sp.Abs(x) * x, (R(-5, 2), 0), -x**2),
    (sp.sign(x) * x**2, (R(-1, 3), 0), -x**2),
    (sp.Max(x, y) * x, (R(3, 2), R(1, 3)), x**2),
    (sp.Max(x, y) * x, (R(1, 3), R(3, 2)), x * y),
    (sp.Min(x, y, 2), (5, 7), sp.Integer(2)),
    (sp.Min(x, y, 2), (3, 3), sp.Integer(2)),  # a tie of the others is no kink: the minimum is 2
    (sp.Heaviside(x) * x**2, (R(-1, 2), 0), sp.Integer(0)),
    (sp.floor(x) * x, (R(-5, 2), 0), -3 * x),
    (sp.ceiling(x), (R(3, 2), 0), sp.Integer(2)),
    (sp.Mod(x, 3), (R(-5, 2), 0), x + 3),
    (sp.Piecewise((x**2, x > y), (x, True)), (2, 1), x**2),
])
def test_localize_is_the_branch_of_g_at_the_point(expr, point, branch):
    (got,) = localize([expr], dict(zip((x, y), point)))
    assert sp.simplify(got - branch) == 0
    assert not nonsmooth_atoms([got])


@pytest.mark.parametrize("expr, point, where", [
    (sp.Abs(x) * x, (0, 0), "x = 0"),
    (sp.Max(x, y) * x, (1, 1), "x = y"),
    (sp.Min(x, y, 2), (2, 5), "2 = x"),
    (sp.floor(x), (3, 0), "x is an integer"),
    (sp.Piecewise((x**2, x > y), (x, True)), (1, 1), "x = y"),
    (sp.Abs(sp.sqrt(2) * x - 1), (sp.sqrt(2) / 2, 0), "sqrt(2)*x - 1 = 0"),  # exact, not rounded
])
def test_a_point_on_a_kink_is_refused_naming_the_function(expr, point, where):
    with pytest.raises(NonSmoothModelError, match="has a kink where") as info:
        localize([expr], dict(zip((x, y), point)), hint="do this")
    msg = str(info.value)
    assert where in msg and msg.endswith("; do this") and "\n" not in msg
    assert where in kink_text(nonsmooth_atoms([expr])[0])


# --------------------------------------------------------------------------- the lemma route
KINKED = {
    "abs": sp.Abs(x) * x + y,
    "max": sp.Max(x, y) * x,
    "sign": sp.sign(x) * x**2 + y**2,
    "min": sp.Min(x, y) * y + x,
    "piecewise": sp.Piecewise((x**2, x > y), (x * y, True)),
}


@pytest.mark.parametrize("name", list(KINKED))
def test_models_with_kinks_are_proved_off_the_kinks(name):
    """The DiracDelta of sympy's derivative of Abs or Max is never evaluated: the proof holds
    for every mean off the kinks, and says so."""
    model = sm.Model([x, y], [KINKED[name], x + 2 * y], name=f"kinked_{name}")
    proof = prove_invariance(model, "full")
    assert proof.holds and proof.lemmas == ("tt2-equivariance", "weight-full")
    assert any(a.startswith("μ off the kinks of g: ") for a in proof.assumptions)
    off = prove_invariance(model, "diag", mean=[R(7, 2), R(-3, 2)], cov=[[2, R(1, 3)], [R(1, 3), 1]])
    assert off.holds


def test_a_numeric_mean_on_a_kink_is_refused_by_tt2_and_taken_by_a_point_rule():
    model = sm.Model([x, y], [sp.Max(x, y) * x], name="tie")
    for route in ("lemmas", "direct"):
        with pytest.raises(NonSmoothModelError, match=r"Max\(x, y\) is not differentiable .* where x = y") as info:
            prove_invariance(model, "full", mean=[1, 1], cov=EYE, route=route)
        assert "--transform ut" in str(info.value)
    # A point rule does not differentiate g; Max is continuous, so its points on the tie are fine.
    assert prove_invariance(model, "full", "ut", mean=[1, 1], cov=EYE).holds


def test_a_given_symbolic_check_point_on_a_kink_moves_to_a_rational_point():
    model = sm.Model([x, y], [sp.Max(x, y) * x, x], name="tie_at")
    proof = prove_invariance(model, "full", at=(sm.Gaussian([1, 1], np.eye(2)),))
    assert proof.holds


def test_the_direct_route_refuses_what_sympy_cannot_differentiate():
    model = sm.Model([x, y], [sp.floor(x) * y + x**2, x * y], name="jumpy")
    with pytest.raises(NonSmoothModelError, match=r"cannot differentiate floor\(x\)"):
        prove_invariance(model, "full", route="direct")
    # Off the jumps its branch is smooth: the lemma route, and the direct one at a numeric mean.
    assert prove_invariance(model, "full").holds
    assert prove_invariance(model, "full", mean=[R(3, 2), 1], cov=EYE, route="direct").holds


def test_the_direct_route_proves_models_with_kinks_off_them():
    model = sm.Model([x, y], [sp.Abs(x) * x, y], name="abs_direct")
    proof = prove_invariance(model, "full", route="direct")
    assert proof.holds and any("Abs(x) where x = 0" in a for a in proof.assumptions)
    assert not prove_invariance(model, "liu-li-raw", route="direct").holds


# --------------------------------------------------------------------------- numeric check
def test_a_numeric_holds_needs_the_numbers_to_agree():
    """Heaviside(x − 1/10)·x at the mean 1/10: the UT's centre point is on the jump, and the
    change of units' rounding puts it on the other side. The exact proof holds; the numbers
    do not, so "holds" is not said."""
    model = sm.Model([x], [sp.Heaviside(x - R(1, 10)) * x], name="jump_ut")
    with pytest.raises(UndecidedProofError, match=r"not reporting invariance .*Heaviside") as info:
        prove_invariance(model, "full", "ut", mean=[R(1, 10)], cov=[[1]])
    assert "\n" not in str(info.value) and "diag(1024)" in str(info.value)


def test_every_numeric_route_checks_before_holds(monkeypatch):
    calls = []

    def refuse(model, *args):
        calls.append(model.name)
        raise UndecidedProofError("numbers disagree")

    for mod in ("symmon.units.proofs", "symmon.units.direct"):
        monkeypatch.setattr(f"{mod}._numeric_check", refuse)
    model = sm.Model([x, y], [x**2 + y, x * y], name="checked")
    for kw in (dict(mean=[1, 2], cov=EYE), dict(mean=[1, 2], cov=EYE, route="direct"), dict(transform="ut")):
        with pytest.raises(UndecidedProofError):
            prove_invariance(model, "full", **kw)
    assert calls == ["checked"] * 3
    assert prove_invariance(model, "full").holds  # symbolic TT2: exact, no numbers to compare


def test_the_numeric_check_passes_an_invariant_mon_at_every_scale():
    model = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar_check")
    check._numeric_check(model, "full", "tt2", sp.Matrix([1, 10]), sp.Matrix([[R(17, 100), 0], [0, 17]]), sp.zeros(0, 0))
    with pytest.raises(UndecidedProofError, match="not reporting invariance"):
        check._numeric_check(model, "liu-li-raw", "tt2", sp.Matrix([1, 10]), sp.Matrix([[R(17, 100), 0], [0, 17]]),
                             sp.zeros(0, 0))


# --------------------------------------------------------------------------- refutations
LINEAR = sm.Model([x, y], [2 * x + y, x - 3 * y], name="linear")


@pytest.mark.parametrize("weight", ["liu-li", "liu-li-raw"])
@pytest.mark.parametrize("kw", [{}, dict(mean=[1, 2], cov=EYE), dict(transform="ut"), dict(transform="mc")],
                         ids=["symbolic", "numeric", "ut", "mc"])
def test_a_linear_models_liu_li_mon_is_zero_in_every_unit(weight, kw):
    proof = prove_invariance(LINEAR, weight, **kw)
    assert proof.holds and proof.counterexample is None and proof.difference == 0
    assert proof.lemmas[-1] == "residual-zero"
    assert prove_invariance(LINEAR, weight, route="direct").holds


def test_a_model_affine_in_u_with_a_nonlinear_noise_term_has_d_zero():
    v = sp.Symbol("v", real=True)
    model = sm.Model([x], [2 * x + sp.sin(v)], noise=[v], name="affine_u")
    assert prove_invariance(model, "liu-li-raw").lemmas[-1] == "residual-zero"
    model = sm.Model([x], [x * v], noise=[v], name="bilinear")  # ∂²g/∂x∂v ≠ 0: D ≠ 0
    assert not prove_invariance(model, "liu-li-raw").holds


@pytest.mark.parametrize("kw", [{}, dict(mean=[1, 10], cov=[[R(17, 100), 0], [0, 17]]), dict(transform="gh")])
def test_a_refutation_shows_two_different_values(kw):
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar_refuted")
    cex = prove_invariance(polar, "liu-li", **kw).counterexample
    lhs, rhs = float(cex["lhs"]), float(cex["rhs"])
    assert lhs != 0 and abs(lhs - rhs) > 1e-6 * abs(lhs)


def test_a_distribution_where_liu_li_happens_to_be_invariant_is_undecided_not_refuted():
    """y = (x², y²) with equal moments: D = Σ_gg/3, so tr(D S⁻²)/tr(Σ_gg S⁻²) = 1/3 for every
    S_y; the lemma fails for generic moments, but no counterexample exists here."""
    model = sm.Model([x, y], [x**2, y**2], name="squares")
    with pytest.raises(UndecidedProofError, match="M² is the same in all 4 sets of scales"):
        prove_invariance(model, "liu-li", mean=[1, 1], cov=EYE)
    assert not prove_invariance(model, "liu-li").holds  # a generic rational point refutes it


def test_a_special_rational_point_is_passed_over():
    """At a rational point with y > x, g = (x·y, x·y): Liu–Li's M² is invariant there; the proof
    tries further points rather than show two equal values."""
    model = sm.Model([x, y], [sp.Max(x, y) * x, x * y], name="special_point")
    cex = prove_invariance(model, "liu-li").counterexample
    assert abs(float(cex["lhs"]) - float(cex["rhs"])) > 1e-6


def test_differs_is_relative_to_the_size_of_m2():
    assert not check._differs(0, 0, 1, 1e-6)
    assert not check._differs(1e-17, 3e-17, 1.0, 1e-6)  # two roundings of 0
    assert check._differs(0.109, 0.139, 1.0, 1e-6)


# --------------------------------------------------------------------------- command line
MODEL_FILES = {
    "maxxy": 'name = "maxxy"\ninputs = ["x", "y"]\noutputs = ["max(x, y)*x"]\n[u]\nmean = [1, 1]\ncov = [[1, 0], [0, 1]]\n',
    "absx": 'name = "absx"\ninputs = ["x"]\noutputs = ["abs(x)*x"]\n[u]\nmean = [1]\ncov = [[0.5]]\n',
    "sign": 'name = "sign"\ninputs = ["x"]\noutputs = ["sign(x)*x**2"]\n[u]\nmean = [0]\ncov = [[1]]\n',
    "linear": 'name = "lin"\ninputs = ["x", "y"]\noutputs = ["2*x + y", "x - 3*y"]\n[u]\nmean = [1, 2]\n'
              'cov = [[1, 0], [0, 1]]\n',
}


@pytest.fixture
def files(tmp_path):
    out = {}
    for name, text in MODEL_FILES.items():
        out[name] = tmp_path / f"{name}.toml"
        out[name].write_text(text)
    return out


@pytest.mark.parametrize("name, extra", [
    ("maxxy", ["--numeric"]), ("maxxy", ["--numeric", "--route", "direct"]), ("sign", ["--numeric"]),
])
def test_cli_a_mean_on_a_kink_is_a_one_line_error(capsys, files, name, extra):
    code = cli.main(["prove-invariance", str(files[name]), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert err[-1].startswith("symmon: error: ") and "is not differentiable at the point" in err[-1]
    assert not any("Traceback" in line or "internal error" in line for line in err)


@pytest.mark.parametrize("name, extra", [
    ("maxxy", []), ("maxxy", ["--numeric", "--transform", "ut"]), ("absx", []), ("absx", ["--numeric"]),
    ("absx", ["--route", "direct", "--numeric"]), ("linear", ["--weight", "liu-li"]),
    ("linear", ["--weight", "liu-li", "--numeric"]), ("linear", ["--weight", "liu-li-raw", "--transform", "gh"]),
])
def test_cli_proofs_that_hold(capsys, files, name, extra):
    code = cli.main(["prove-invariance", str(files[name]), *extra])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "holds: M²(g, u) − M²(ḡ, ū) = 0" in out.out and "counterexample" not in out.out


def test_cli_undecided_is_exit_1(capsys, tmp_path):
    f = tmp_path / "squares.toml"
    f.write_text('name = "sq"\ninputs = ["x", "y"]\noutputs = ["x**2", "y**2"]\n[u]\nmean = [1, 1]\n'
                 'cov = [[1, 0], [0, 1]]\n')
    assert cli.main(["prove-invariance", str(f), "--weight", "liu-li", "--numeric"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("symmon: error: cannot decide") and "Traceback" not in "".join(err)


def test_the_new_errors_are_symmon_errors():
    assert issubclass(NonSmoothModelError, SymmonError) and issubclass(UndecidedProofError, SymmonError)
