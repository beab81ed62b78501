"""Every claim of derivations/ that verify can state is proved or consistent, and the errata it can
state are refuted (issue 37, tests): the two derivation files of examples/verify/ and a few
matrix claims that a derivation file cannot write."""

from __future__ import annotations

import pytest
import sympy as sp

import symmon as sm
from symmon.files.derivationfile import check_derivation_file

from helpers import EXAMPLES

FILES = ["mmse_paper.toml", "unitless_paper.toml"]


@pytest.mark.parametrize("name", FILES)
def test_the_papers_claims_pass_and_their_errata_are_refuted(name):
    spec, verdicts = check_derivation_file(EXAMPLES / "verify" / name, points=4)
    failing = [f"{c.name}: {v.verdict} (expected {c.expected})\n{v}" for c, v in zip(spec.claims, verdicts)
               if not c.passes(v)]
    assert not failing, "\n\n".join(failing)
    for claim, v in zip(spec.claims, verdicts):
        if claim.expected == "refuted":  # an erratum: a counterexample with its re-check
            assert v.counterexample is not None and v.counterexample["recheck"]
        elif claim.expected == "proved":
            assert v.verdict == "proved", claim.name


def symmetric(name: str, positive_diagonal: bool = True) -> sp.Matrix:
    def entry(i, j):
        i, j = min(i, j), max(i, j)
        return sp.Symbol(f"{name}{i + 1}{j + 1}", real=True, positive=(i == j and positive_diagonal) or None)
    return sp.Matrix(2, 2, entry)


def test_remark_1_the_full_weight_gives_one_minus_r_squared():
    """derivations/remarks.py: tr(W^full D) = 1 − (1/n_y) tr(Σ_gg⁻¹ Σ_gu Σ_uu⁻¹ Σ_ug) (43), Remark 1."""
    Sgg, Suu = symmetric("g"), symmetric("u")
    Sgu = sp.Matrix(2, 2, sp.symbols("c11 c12 c21 c22", real=True))
    D = Sgg - Sgu * Suu.inv() * Sgu.T
    r2 = (Sgg.inv() * Sgu * Suu.inv() * Sgu.T).trace() / 2
    v = sm.verify((Sgg.inv() / 2 * D).trace(), 1 - r2, domain=[(Sgg, "spd"), (Suu, "spd")])
    assert v.verdict == "proved"


def test_fusion_formula_is_the_weighted_least_squares_estimate():
    """derivations/fusion_and_conditioning.py: x̂ = P(P1⁻¹x̂1 + P2⁻¹x̂2) with P = (P1⁻¹ + P2⁻¹)⁻¹
    zeroes the gradient of the WLS cost of the stacked model."""
    P1, P2 = symmetric("p"), symmetric("q")
    x1 = sp.Matrix(sp.symbols("a1 a2", real=True))
    x2 = sp.Matrix(sp.symbols("b1 b2", real=True))
    P = (P1.inv() + P2.inv()).inv()
    xf = P * (P1.inv() * x1 + P2.inv() * x2)
    gradient = P1.inv() * (xf - x1) + P2.inv() * (xf - x2)
    assert sm.verify(gradient, sp.zeros(2, 1), domain=[(P1, "spd"), (P2, "spd")]).verdict == "proved"
