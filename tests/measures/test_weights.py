"""The table of named weights and tr(W D) (Straka & Havlík 2024, (6), (8), (29), (42), (43))."""

import numpy as np
import pytest
import sympy as sp

from symmon.measures import weights
from symmon.errors import SymmonError
from symmon.units import prove_matrix_invariance

#: One product and a 3x3 solve apart: a closed-form comparison.
EXACT_RTOL = 1e-12


def _spd(rng, n):
    A = rng.standard_normal((n, n))
    return A @ A.T + n * np.eye(n)


@pytest.mark.parametrize("name", weights.NAMED)
def test_weighted_trace_is_tr_of_the_resolved_weight_times_d(name):
    rng = np.random.default_rng(3)
    Sgg, D = _spd(rng, 3), _spd(rng, 3)
    W, label = weights.resolve(name, Sgg)
    assert label == name
    assert weights.weighted_trace(name, Sgg, D) == pytest.approx(np.trace(W @ D), rel=EXACT_RTOL)


@pytest.mark.parametrize("name", weights.NAMED)
def test_weighted_trace_is_the_same_formula_on_sympy_matrices(name):
    rng = np.random.default_rng(4)
    Sgg, D = _spd(rng, 2), _spd(rng, 2)
    exact = weights.weighted_trace(name, sp.Matrix(Sgg), sp.Matrix(D))
    assert float(exact) == pytest.approx(weights.weighted_trace(name, Sgg, D), rel=EXACT_RTOL)


def test_unknown_weight_name_is_refused_with_the_known_names():
    with pytest.raises(SymmonError, match="unknown weight 'fulll'.*liu-li-raw"):
        weights.weighted_trace("fulll", np.eye(2), np.eye(2))


def test_table_names_are_the_accepted_names_and_cite_equations():
    assert weights.NAMED == ("full", "diag", "liu-li", "liu-li-raw")
    assert [w.equation for w in weights.NAMED_WEIGHTS.values()] == ["(43)", "(42)", "(8)", "(6)"]


@pytest.mark.parametrize("name", weights.NAMED)
def test_unit_invariant_flag_agrees_with_the_proof(name):
    # Diagonal scales: the changes of units the paper considers for every weight (Sec. IV).
    proof = prove_matrix_invariance(2, 2, name, scales="diagonal")
    assert proof.holds == weights.NAMED_WEIGHTS[name].unit_invariant
