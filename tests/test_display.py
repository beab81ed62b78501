"""Notebook display: ``_repr_latex_`` of the objects a notebook user sees.

Each string is one inline math block (``$...$``) with balanced braces and environments,
no Python float syntax (``1e-07`` is not LaTeX), and the numbers and symbols it stands for.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.propagation.joint import latex_number, latex_text

x, y = sp.symbols("x y", real=True)
e_r, e_p = sp.symbols("e_r e_p", real=True)
POLAR = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar")
NOISY = sm.Model([x, y], [sp.sqrt(x**2 + y**2) * (1 + e_r), sp.atan2(y, x) + e_p], noise=[e_r, e_p], name="noisy")
U = sm.Gaussian([1.0, 10.0], np.diag([0.17, 17.0]))
V = sm.Gaussian([0.0, 0.0], np.diag([1e-4, 1e-6]))
#: Python's exponent notation (1e-07, 2.5e+03) outside a LaTeX exponent.
PY_FLOAT = re.compile(r"\d[eE][+-]?\d")


def assert_well_formed(s: str) -> None:
    assert s.startswith("$") and s.endswith("$") and not s.startswith("$$")
    assert s.count("$") - s.count(r"\$") == 2                     # one math block
    body = s.replace(r"\{", "").replace(r"\}", "")
    depth = 0
    for c in body:
        depth += {"{": 1, "}": -1}.get(c, 0)
        assert depth >= 0, s
    assert depth == 0, s
    assert re.findall(r"\\begin\{(\w+)\}", s) == re.findall(r"\\end\{(\w+)\}", s)
    assert not PY_FLOAT.search(s), s


@pytest.mark.parametrize(
    ("value", "digits", "expected"),
    [(0.5, 4, "0.5"), (1.5e-7, 4, r"1.5 \cdot 10^{-7}"), (-2.5e12, 3, r"-2.5 \cdot 10^{12}"),
     (float("nan"), 4, r"\mathrm{NaN}"), (float("inf"), 4, r"\infty"), (-float("inf"), 4, r"-\infty")],
)
def test_latex_number(value, digits, expected):
    assert latex_number(value, digits) == expected


def test_latex_text_escapes_specials():
    assert latex_text("a_b {c} 5% & #1 ~ ^ $") == r"a\_b \{c\} 5\% \& \#1 \~{} \^{} \$"


def test_model():
    s = POLAR._repr_latex_()
    assert_well_formed(s)
    assert s.startswith("$g(x, y) = ")
    assert r"\sqrt{x^{2} + y^{2}}" in s and r"\operatorname{atan}_{2}{\left(y,x \right)}" in s
    assert r"\text{(noise-free)}" in s


def test_model_with_noise_names_its_structure():
    s = NOISY._repr_latex_()
    assert_well_formed(s)
    assert s.startswith("$g(x, y, e_{r}, e_{p}) = ")
    assert rf"\text{{({NOISY.structure} noise)}}" in s


@pytest.mark.parametrize(
    ("g", "pieces"),
    [
        (U, [r"\mathcal{N}\left(", r"\begin{bmatrix}1 \\ 10\end{bmatrix}", r"0.17 & 0 \\ 0 & 17"]),
        (sm.Gaussian([-2.5], [[4.0]]), [r"\begin{bmatrix}-2.5\end{bmatrix}", r"\begin{bmatrix}4\end{bmatrix}"]),
    ],
)
def test_gaussian(g, pieces):
    s = g._repr_latex_()
    assert_well_formed(s)
    for piece in pieces:
        assert piece in s


def test_joint_moments_closed_form():
    m = sm.propagate(POLAR, U, transform=sm.TT2())
    s = m._repr_latex_()
    assert_well_formed(s)
    assert s.startswith(r"$\mathsf{E}\,y = \begin{bmatrix}" + latex_number(m.mean[0]) + r" \\ " + latex_number(m.mean[1]))
    assert r"\operatorname{Cov} y = \begin{bmatrix}" + latex_number(m.cov[0, 0]) in s
    assert r"\operatorname{Cov}(y, u) = \begin{bmatrix}" + latex_number(m.cross_cov[0, 0]) in s
    assert r"\text{(TT2())}" in s


def test_joint_moments_small_numbers_and_an_escaped_transform():
    m = sm.propagate(NOISY, sm.Gaussian([1.0, 10.0], np.diag([1e-6, 1e-6])), V, transform=sm.MonteCarlo(2000, seed=1))
    s = m._repr_latex_()
    assert_well_formed(s)
    assert r"\cdot 10^{-" in s                       # Cov(y, u) entries of order 1e-6
    assert r"\text{(MonteCarlo(n=2000, seed=1" in s


def test_nonlinearity_measure():
    res = sm.nonlinearity(POLAR, U, weight="full", transform=sm.TT2())
    s = res._repr_latex_()
    assert_well_formed(s)
    assert s.startswith(r"$M_{\text{full}} = " + latex_number(res.value, 6))
    assert rf"\text{{({POLAR.structure} noise, TT2)}}" in s  # 'none' since noise-free models say so
    assert r"\pm" not in s


def test_nonlinearity_measure_with_a_standard_error():
    res = sm.nonlinearity(POLAR, U, weight="liu-li", transform=sm.MonteCarlo(2000, seed=1))
    s = res._repr_latex_()
    assert_well_formed(s)
    assert rf"M_{{\text{{liu-li}}}} = {latex_number(res.value, 6)} \pm {latex_number(res.stderr, 2)}" in s


@pytest.mark.parametrize(("weight", "verdict", "nonzero"), [("full", "invariant", False), ("liu-li-raw", "not invariant", True)])
def test_invariance_proof(weight, verdict, nonzero):
    units = pytest.importorskip("symmon.units")
    if not hasattr(units, "prove_invariance"):
        pytest.skip("symmon.units.prove_invariance is not written yet")
    proof = units.prove_invariance(POLAR, weight, mean=U.mean, cov=U.cov)
    s = proof._repr_latex_()
    assert_well_formed(s)
    assert s.startswith(r"$M^2(\mathbf{g}, \mathbf{u}) - M^2(\bar{\mathbf{g}}, \bar{\mathbf{u}}) = ")
    assert s.endswith(rf"\quad\text{{({verdict})}}$")
    assert (r"= 0\quad" not in s) == nonzero


def test_gaussian_latex_writes_small_numbers_as_powers_of_ten():
    import symmon as sm

    text = sm.Gaussian([1e-7, 2.0], [[1e-7, 0.0], [0.0, 1.0]])._repr_latex_()
    assert r"1 \cdot 10^{-7}" in text and "e-07" not in text
