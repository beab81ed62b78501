"""sm.advise: the error of each candidate transform against a reference, and the choice."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.measures.advice import CANDIDATES, moment_error
from symmon.errors import SymmonError

#: The unitless error of an exact transform is rounding only.
EXACT_ATOL = 1e-12
#: Invariance of the unitless error under a change of units: rounding of the rescaling.
INVARIANCE_RTOL = 1e-10

x, y = sp.symbols("x y", real=True)


def test_affine_model_chooses_tt1():
    a = sm.advise(sm.Model([x, y], [3 * x - y + 1, x + 2 * y]), sm.Gaussian([1.0, -2.0], [[0.5, 0.1], [0.1, 2.0]]))
    assert a.choice_name == "TT1" and isinstance(a.choice, sm.TT1)
    assert a.reference == "Gauss-Hermite 7" and a.reference_error < EXACT_ATOL
    by = {r["name"]: r for r in a.rows}
    assert by["TT1"]["error"] < EXACT_ATOL and by["TT1"]["within_tol"]


def test_quadratic_model_chooses_tt2_which_is_exact():
    a = sm.advise(sm.Model([x], [x**2]), sm.Gaussian([1.0], [[0.3]]))
    by = {r["name"]: r for r in a.rows}
    assert by["TT2"]["error"] < EXACT_ATOL
    assert not by["TT1"]["within_tol"]  # TT1 misses ½ tr(H P) in the mean
    assert a.choice_name == "TT2"


def test_strongly_nonlinear_case_rejects_the_taylor_transforms():
    """Polar example at α = 1 (Figure 1): the MoN is large and TT1, TT2 fail."""
    p = sm.problems.polar(1.0, "rad")
    a = sm.advise(p.model, p.u, tol=1e-2, samples=200_000)
    by = {r["name"]: r for r in a.rows}
    assert a.reference_mon > 0.5
    assert not by["TT1"]["within_tol"] and not by["TT2"]["within_tol"]
    assert a.choice_name not in ("TT1", "TT2")
    assert "Monte Carlo" in a.reference  # Gauss-Hermite 7 does not converge here
    assert any("did not converge" in n for n in a.notes)


def test_error_is_unitless():
    p = sm.problems.gmti(1.0)
    ref = sm.propagate(p.model, p.u, transform=sm.GaussHermite(7))
    m = sm.propagate(p.model, p.u, transform=sm.TT2())
    S = np.diag([1e3, np.pi / 180, 3.6])  # km → m, rad → deg-ish, m/s → km/h scalings
    scaled = sm.Model(p.model.inputs, [s * g for s, g in zip(np.diag(S), p.model.outputs)])
    ref_s = sm.propagate(scaled, p.u, transform=sm.GaussHermite(7))
    m_s = sm.propagate(scaled, p.u, transform=sm.TT2())
    assert moment_error(m_s, ref_s) == pytest.approx(moment_error(m, ref), rel=INVARIANCE_RTOL)


def test_table_and_print():
    a = sm.advise(sm.Model([x], [sp.sin(x)]), sm.Gaussian([0.3], [[0.01]]))
    text = str(a)
    assert "choice:" in text and "<- choice" in a.table
    assert len(a.table.splitlines()) == len(CANDIDATES) + 1
    assert repr(a).startswith("Advice(choice=")


@pytest.mark.parametrize("tol", [0, 1, -1e-3, "0.1", True])
def test_bad_tol(tol):
    with pytest.raises(SymmonError, match="tol"):
        sm.advise(sm.Model([x], [x]), sm.Gaussian([0.0], [[1.0]]), tol=tol)


def test_bad_model():
    with pytest.raises(TypeError, match="symmon.Model"):
        sm.advise("x**2", sm.Gaussian([0.0], [[1.0]]))
