"""A deterministic transform whose moments no distribution has gives no MoN (issue 50: a flow's
MoN read 0, "linear", where Monte Carlo gives 1).

M² is a weighted residual variance, never negative for real moments; clamped at 0 it claimed
linearity.  TT2 on the two-sub-step order-1.5 flow of dx = (x − x³) dt + 0.5 dβ over dt = 2
from N(0.5, 0.1) gives M² ≈ −6.9; the UT and Monte Carlo give a positive MoN there.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import InconsistentMomentsError
from symmon.measures.mon import NEGATIVE_MON_RTOL

x = sp.Symbol("x", real=True)
SDE = sm.SDE([x], [x - x**3], diffusion=[0.5])
PRIOR = sm.Gaussian([0.5], [[0.1]])


def test_a_clearly_negative_squared_mon_of_a_deterministic_rule_is_an_error_not_zero():
    with pytest.raises(InconsistentMomentsError, match=r"M² = -6\.9.*would read as 0 \(linear\)"):
        sm.nonlinearity(SDE, PRIOR, dt=2.0, substeps=2)


def test_the_same_flow_by_the_ut_and_monte_carlo_is_clearly_nonlinear():
    ut = sm.nonlinearity(SDE, PRIOR, dt=2.0, substeps=2, transform=sm.UT())
    mc = sm.nonlinearity(SDE, PRIOR, dt=2.0, substeps=2, transform=sm.MonteCarlo(20_000, seed=1))
    assert ut.squared > 0 and float(ut) > 0.5
    # Monte Carlo's M² may dip below 0 by noise only: here it is far above, by many standard errors.
    assert float(mc) - 10 * mc.stderr > 0.5


def test_a_linear_model_rounding_below_zero_is_still_zero():
    # An affine g: M² is 0 up to rounding (either sign), within the relative tolerance.
    a, b = sp.symbols("a b", real=True)
    g = sm.Model([a, b], [3.0 * a - 0.1 * b + 7.0, 1e-3 * a + b])
    m = sm.nonlinearity(g, sm.Gaussian([1.0, -2.0], [[2.0, 0.3], [0.3, 0.5]]))
    assert abs(m.squared) <= NEGATIVE_MON_RTOL and float(m) == pytest.approx(0.0, abs=1e-6)


def test_choose_substeps_measures_one_sub_step_and_is_unaffected():
    from symmon.measures.mon import choose_substeps
    n = choose_substeps(SDE, PRIOR, 2.0, tol=0.5)
    assert n >= 2 and float(sm.nonlinearity(SDE, PRIOR, dt=2.0 / n, substeps=1)) <= 0.5
    assert np.isfinite(float(sm.nonlinearity(SDE, PRIOR, dt=2.0, substeps=1)))


def test_a_mixture_prior_is_checked_too():
    # The same flow from a two-component prior around 0.5: TT2's moments again give M² < 0.
    prior = sm.GaussianMixture([0.5, 0.5], [[0.4], [0.6]], [[[0.1]], [[0.1]]])
    with pytest.raises(InconsistentMomentsError, match="M² = "):
        sm.nonlinearity(SDE, prior, dt=2.0, substeps=2)
