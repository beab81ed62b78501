"""The MoN of the papers' models in rescaled units (issue 26, item 2).

The unitless MoN is invariant under a change of units (Straka & Havlík 2024, Section IV), so
its numerical tests must be too: a model written in mm and rad, or in units 1e6 apart, is
neither "singular" nor different. Each model below is run with its inputs and outputs
rescaled by factors from 1e-6 to 1e6 (different factors per component); the W^full and
W^diag MoN by TT2 (a closed form) must agree with the original to 1e-9 relative — rounding
in the rescaled covariances, amplified by their spread of 1e24 at most.
"""

from __future__ import annotations

import numpy as np
import pytest

import symmon as sm
from symmon.core.rescale import change_gaussian, change_units
from symmon.core import problems

FACTORS = [1e-6, 1e-3, 1.0, 1e3, 1e6]


def cases():
    """The noise-free problems of the paper (Figure 2 and Section IV's polar)."""
    for name, make in (("polar", problems.polar), ("bot", problems.bot), ("gmti", problems.gmti),
                       ("rdcos", problems.rdcos)):
        p = make(0.3)
        yield name, p.model, p.u


@pytest.mark.parametrize("name, model, u", list(cases()), ids=lambda c: c if isinstance(c, str) else "")
@pytest.mark.parametrize("weight", ["full", "diag"])
def test_the_mon_is_the_same_in_any_units(name, model, u, weight):
    ref = sm.nonlinearity(model, u, weight=weight, transform=sm.TT2()).value
    rng = np.random.default_rng(3)
    for _ in range(4):
        su = rng.choice(FACTORS, model.n_u)
        sy = rng.choice(FACTORS, model.n_y)
        scaled = change_units(model, S_u=np.diag(su), S_y=np.diag(sy))
        ub = change_gaussian(u, np.diag(su))
        got = sm.nonlinearity(scaled, ub, weight=weight, transform=sm.TT2()).value
        assert got == pytest.approx(ref, rel=1e-9), (su, sy)


def test_polar_in_mm_is_not_singular():
    """The issue's case: examples/polar.toml with its range in mm (and the bearing in rad)."""
    p = problems.polar(0.17)
    model, u = p.model, p.u
    mm = change_units(model, S_u=np.diag([1e-3, 1e-3]), S_y=np.diag([1e-3, 1.0]))
    ref = sm.nonlinearity(model, u, transform=sm.TT2()).value
    assert sm.nonlinearity(mm, change_gaussian(u, np.diag([1e-3, 1e-3])), transform=sm.TT2()).value == \
        pytest.approx(ref, rel=1e-9)


def test_a_truly_singular_output_covariance_is_still_refused():
    import sympy as sp

    x, y = sp.symbols("x y", real=True)
    twice = sm.Model([x, y], [x + y, 2 * (x + y) * 1e6], name="twice")  # the outputs are proportional
    with pytest.raises(sm.errors.SingularMatrixError, match="correlation matrix"):
        sm.nonlinearity(twice, sm.Gaussian([0.0, 0.0], np.eye(2)), transform=sm.TT2())
