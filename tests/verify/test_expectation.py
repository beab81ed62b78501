"""sm.expect: closed-form Gaussian expectations (issue 37, item 1)."""

from __future__ import annotations

import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ExpectationNotClosedForm

x, y = sp.symbols("x y", real=True)
m, s = sp.symbols("m s", positive=True)


def test_polynomial_moments_of_a_scalar_gaussian():
    assert sp.expand(sm.expect(x**4, x, [m], [[s**2]]) - (m**4 + 6 * m**2 * s**2 + 3 * s**4)) == 0


def test_outside_the_class_is_refused():
    with pytest.raises(ExpectationNotClosedForm):
        sm.expect(sp.sqrt(x**2 + 1), x, [0], [[1]])
