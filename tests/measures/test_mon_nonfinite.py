"""A MoN that is not finite is an error, never a number (issue 13): an α sweep to the ends of
the float range, and an input covariance whose inverse overflows."""

from __future__ import annotations

import numpy as np
import pytest

import symmon as sm
from symmon.errors import NonFiniteError
from symmon.measures.sweep import sweep_alpha


def test_alpha_sweep_to_the_float_range_raises_instead_of_nan():
    """The issue's sweep 1e-300:1e300 gave MoN = nan at the top (Cov y overflows)."""
    p = sm.problems.polar()
    with pytest.raises(NonFiniteError, match=r"TT2\(\): Cov y"):
        sweep_alpha(p.model, p.u, np.logspace(-300, 300, 7), weight="liu-li", transform=sm.TT2())


def test_mon_of_subnormal_input_covariance_raises():
    """Σ_uu ≈ 1e-310 is subnormal: its inverse overflows and M² would be NaN."""
    p = sm.problems.polar()
    with pytest.raises(NonFiniteError, match=r"the MoN with weight .* is not finite"):
        sweep_alpha(p.model, p.u, [1e-310], weight="liu-li-raw", transform=sm.TT2())


def test_nonlinearity_names_the_transform_when_the_mon_is_not_finite():
    p = sm.problems.polar()
    u = sm.Gaussian(p.u.mean, 1e-310 * np.diag([1.0, 100.0]))
    with pytest.raises(NonFiniteError, match=r"^TT2\(\): the MoN"):
        sm.nonlinearity(p.model, u, weight="liu-li-raw", transform=sm.TT2())
