"""advise beyond Gaussian filters: the filter it names, from the reference MoN and the moment errors."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.core.mixture import SPLITS
from symmon.measures.advice import GAUSSIAN_MON_LIMIT, MAX_GSF_COMPONENTS, filter_advice

x, y = sp.symbols("x y", real=True)


def test_a_linear_model_gets_the_gaussian_filter_of_the_choice() -> None:
    a = sm.advise(sm.Model([x], [3 * x + 1]), sm.Gaussian([1.0], [[0.5]]))
    assert a.filter["filter"] == "gaussian" and a.filter["transform"] == sm.TT1()
    assert a.filter_name == "NonlinearKalmanFilter(EKF)"
    # the printout answers the transform question only: advise_filter answers the filter one
    assert "filter:" not in str(a) and "ParticleFilter" not in str(a) and str(a).count("choice:") == 1


def test_a_bearing_from_close_by_gets_a_particle_filter() -> None:
    bearing = sm.Model([x, y], [sp.atan2(y, x)], angles=[0])
    a = sm.advise(bearing, sm.Gaussian([1.0, 0.5], 0.5 * np.eye(2)), samples=10**5)
    assert a.choice is None and a.reference_mon > GAUSSIAN_MON_LIMIT
    assert a.filter["filter"] == "pf" and a.filter_name == "ParticleFilter"
    assert "lose consistency" in a.filter["reason"]
    assert "ParticleFilter" not in str(a) and "filter:" not in str(a)


@pytest.mark.parametrize("mon", [0.02, 0.05, 0.1])
def test_the_gsf_levels_bring_a_quadratics_mon_below_the_split_level(mon) -> None:
    tol = 0.01
    adv = filter_advice(mon, None, tol)
    L = adv["levels"]
    assert adv["filter"] == "gsf" and adv["max_components"] == 3**L <= MAX_GSF_COMPONENTS
    assert adv["split"] == pytest.approx(np.sqrt(2) * tol, rel=1e-15)
    # Each level scales a quadratic's MoN along the split direction by σ² (the split's variance).
    s2 = SPLITS[3][0] ** 2
    assert mon * s2**L <= adv["split"] < mon * s2 ** (L - 1)


def test_the_mon_limit_overrules_a_rule_within_tol() -> None:
    assert filter_advice(GAUSSIAN_MON_LIMIT, sm.UT.ut1(), 0.01)["filter"] == "gaussian"
    above = filter_advice(GAUSSIAN_MON_LIMIT * 1.01, sm.UT.ut1(), 0.01)
    assert above["filter"] in ("gsf", "pf") and "lose consistency" in above["reason"]
