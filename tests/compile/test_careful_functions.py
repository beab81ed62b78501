"""Numerically careful compiled functions (issue 26, item 3).

sympy writes hypot, expm1 and log1p out as sqrt(a² + b²), exp(a) − 1 and log(1 + a); compiled
literally, tiny a underflow (sqrt(1e-200² + 1e-200²) = 0) and near a = 0 every digit is lost
(exp(1e-10) − 1 keeps 6). The compiler emits C99's hypot, expm1 and log1p for these forms:
the values must equal Python's math functions to rounding (1e-15 relative), the derivatives
stay CasADi's exact ones, and an undefined point stays NaN.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile import compiled

x, y, z = sp.symbols("x y z", real=True)


@pytest.mark.parametrize("point", [(1e-200, 1e-200, 3e-200), (3e200, 4e200, 1e200), (3.0, 4.0, 12.0),
                                   (-2.0, 0.0, 0.0)])
def test_norms_neither_underflow_nor_overflow(point):
    m = sm.Model([x, y, z], [sp.sqrt(x**2 + y**2), sp.sqrt(x**2 + y**2 + z**2), 1 / sp.sqrt(x**2 + y**2)],
                 name="norms")
    got = compiled(m).eval_g(np.array([point]))[0]
    a, b, c = point
    want = [math.hypot(a, b), math.hypot(a, b, c), 1 / math.hypot(a, b)]
    np.testing.assert_allclose(got, want, rtol=1e-15)


@pytest.mark.parametrize("a", [1e-300, 1e-12, -1e-9, 0.5, -0.75, 3.0])
def test_exp_minus_one_and_log_one_plus_keep_their_digits(a):
    m = sm.Model([x, y], [sp.exp(x) - 1, sp.log(1 + x), sp.exp(x) - 1 + y, sp.log(1 + x + y)], name="near0")
    got = compiled(m).eval_g(np.array([[a, 0.0]]))[0]
    want = [math.expm1(a), math.log1p(a), math.expm1(a), math.log1p(a)]
    np.testing.assert_allclose(got, want, rtol=1e-15, atol=0)


def test_the_same_from_a_traced_function_and_a_model_file(tmp_path):
    traced = sm.Model.from_function(lambda v: np.array([np.expm1(v[0]), np.log1p(v[0]), np.hypot(v[0], v[1])]),
                                    inputs=["x", "y"], name="traced")
    got = compiled(traced).eval_g(np.array([[1e-12, 1e-250]]))[0]
    np.testing.assert_allclose(got, [math.expm1(1e-12), math.log1p(1e-12), math.hypot(1e-12, 1e-250)], rtol=1e-15)
    path = tmp_path / "m.toml"
    path.write_text('name = "file"\ninputs = ["x", "y"]\noutputs = ["exp(x) - 1", "hypot(x, y)"]\n'
                    '[u]\nmean = [0, 0]\nstd = [1, 1]\n')
    spec = sm.modelfile.load_model_file(path)
    got = compiled(spec.model).eval_g(np.array([[1e-13, 1e-300]]))[0]
    np.testing.assert_allclose(got, [math.expm1(1e-13), math.hypot(1e-13, 1e-300)], rtol=1e-15)


def test_derivatives_stay_exact_and_an_undefined_point_stays_nan():
    m = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.exp(x) - 1, sp.log(1 + y)], name="derivs")
    _, J, H = compiled(m).eval_gjh(np.array([[3.0, 4.0], [0.0, 0.0]]))
    np.testing.assert_allclose(J[0], [[0.6, 0.8], [math.exp(3.0), 0.0], [0.0, 0.2]], rtol=1e-15)
    np.testing.assert_allclose(H[0, 0], np.array([[16.0, -12.0], [-12.0, 9.0]]) / 125, rtol=1e-14)
    assert np.isnan(J[1, 0]).all()  # the norm has no derivative at the origin
    np.testing.assert_allclose(J[1, 1:], [[1.0, 0.0], [0.0, 1.0]], rtol=0)
