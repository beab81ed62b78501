"""Filter inputs and statistics of issue 38 (items 5-7, 18): None rows and text refused with what
to do, same-name symbols with other assumptions named as such, ANIS of a bank with missing rows
averaged over what was measured, a single run's ANEES caveat, a step outside a result."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from scipy import stats

import symmon as sm
from symmon.errors import ArgumentError, ModelError, ShapeError


@pytest.fixture(scope="module")
def kf():
    x = sp.Symbol("x")
    return sm.NonlinearKalmanFilter(sm.Model([x], [x], name="i38_f"), sm.Model([x], [x, 2 * x], name="i38_h"),
                                    [[0.1]], np.eye(2), sm.TT1())


X0 = sm.Gaussian([0.0], [[1.0]])


def test_none_rows_say_to_use_nan(kf):
    with pytest.raises(ShapeError, match=r"None at index \(1,\).* missing measurement is NaN"):
        kf.filter([[1.0, 2.0], None, [1.0, 2.0]], X0)
    with pytest.raises(ShapeError, match=r"None at index \(1, 0\)"):
        sm.KalmanFilter(np.eye(1), np.eye(1), np.eye(1), np.eye(1)).filter([[1.0], [None]], np.zeros(1), np.eye(1))


@pytest.mark.parametrize("ys", [np.ones((3, 2)).astype(str), [["1", "2"], ["3", "4"]],
                                np.array([[1.0, "2"]], dtype=object)])
def test_numeric_text_is_refused(kf, ys):
    with pytest.raises(ShapeError, match="ys holds text, not real numbers"):
        kf.filter(ys, X0)


def test_same_name_other_assumptions_are_named():
    px, px_real, y = sp.Symbol("px"), sp.Symbol("px", real=True), sp.Symbol("y")
    with pytest.raises(ModelError, match=r"Same names, other assumptions: the output's Symbol\('px'\) is not "
                                         r"the declared Symbol\('px', real=True\)"):
        sm.Model([px_real, y], [px + y])


def test_anis_of_a_bank_with_missing_rows_averages_what_was_measured(kf):
    rng = np.random.default_rng(1)
    ys = rng.normal(size=(6, 4, 2))
    ys[:3, 1] = np.nan  # half the runs miss step 1
    ys[0, 2, 1] = np.nan  # one component of one run at step 2
    res = kf.filter(ys, X0)
    nis, d = res.nis(), res.measured
    t = res.anis()
    assert t.value[1] == pytest.approx(nis[3:, 1].mean(), rel=1e-12)  # the 3 runs that measured
    assert t.value[0] == pytest.approx(nis[:, 0].mean(), rel=1e-12)
    assert t.dof[1] == 6 and t.upper[1] == pytest.approx(stats.chi2.ppf(0.975, 6) / 3, rel=1e-12)
    assert t.dof[2] == 11 and t.upper[2] == pytest.approx(stats.chi2.ppf(0.975, 11) / 6, rel=1e-12)
    assert (d[:3, 1] == 0).all() and t.note == ""


def test_a_single_runs_anees_says_its_interval_is_too_narrow(kf):
    res = kf.filter(np.zeros((5, 2)), X0)
    one = res.anees(np.zeros((5, 1)))
    assert "correlated" in one.note and "correlated" in repr(one)
    bank = kf.filter(np.zeros((3, 5, 2)), X0).anees(np.zeros((3, 5, 1)))
    assert bank.note == "" and "correlated" not in repr(bank)
    assert "correlated" in sm.filters.KalmanResult.anees.__doc__


def test_a_step_outside_the_result_is_named(kf):
    res = kf.filter(np.zeros((5, 2)), X0)
    with pytest.raises(ArgumentError, match=r"k = 99 is outside the 5 steps of this result: use 0 to 4"):
        res.estimate(99)
    assert res.estimate(-1).mean[0] == res.x[-1, 0]
    bank = kf.filter(np.zeros((2, 5, 2)), X0)
    with pytest.raises(ArgumentError, match="run = 2 is outside the 2 runs"):
        bank.estimate(0, run=2)
    sm_res = kf.smooth(np.zeros((5, 2)), X0)
    with pytest.raises(ArgumentError, match="k = 5 is outside"):
        sm_res.estimate(5)


def test_a_nan_names_the_model_the_output_and_the_operation():
    """Issue 38, item 4: a coordinated turn at turn rate 0 (sin(ω dt)/ω) and a range at the sensor."""
    px, py, vx, vy, om, dt = sp.symbols("px py vx vy om dt", real=True)
    s, c = sp.sin(om * dt) / om, (1 - sp.cos(om * dt)) / om
    f = sm.Model([px, py, vx, vy, om], [px + s * vx - c * vy, py + c * vx + s * vy, vx, vy, om], params=[dt],
                 name="i38_ct")
    h = sm.Model([px, py, vx, vy, om], [px, py], name="i38_xy")
    for t in (sm.TT1(), sm.UT.ut1()):
        kf = sm.NonlinearKalmanFilter(f, h, 0.01 * np.eye(5), np.eye(2), t)
        with pytest.raises(sm.errors.SymmonError, match=r"at step 0: f 'i38_ct', output 0 \(.*\), is not finite .*"
                                                        r"om = 0\]: a division by zero: 1/om at om = 0"):
            kf.filter(np.ones((3, 2)), np.zeros(5), np.eye(5), params={"dt": 1.0})
    x, y = sp.symbols("x y", real=True)
    walk = sm.Model([x, y], [x, y], name="i38_walk")
    rng = sm.Model([x, y], [sp.sqrt(x**2 + y**2)], name="i38_range")
    kf = sm.NonlinearKalmanFilter(walk, rng, 0.01 * np.eye(2), [[1.0]], sm.TT1())
    with pytest.raises(sm.errors.SymmonError, match=r"step 0: the derivative of h 'i38_range', output 0 .* by x is "
                                                    r"not finite .* division by zero"):
        kf.filter([[1.0], [1.0]], np.array([0.0, 0.0]), 1e-300 * np.eye(2))
