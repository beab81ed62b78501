"""The C EKF and IEKF step of larger filters (symmon.filters.gaussian._ekfstep) against the MX step on CasADi's VM.

Both run the same formulas (TT1, Lemma 7.1 of Gustafsson & Hendeby 2012); they differ in the
order of the sums only, so every output agrees to rounding: 1e-10 relative to its scale over
a dozen steps of a 20-state filter (a nonlinear motion with heading angles, range–bearing
measurements, parameters, missing components).  The bank's threads each run whole runs, so a
bank equals its runs filtered one by one, bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from helpers import assert_close_to_scale, turning_targets
from symmon.compile.compiled import cpu_count
from symmon.filters.gaussian._ekfstep import C_EKF_FROM
from symmon.filters.gaussian.step import compiled_step, chunk_runs

RTOL = 1e-10
TARGETS = 4
F, H, X, dt, s = turning_targets(TARGETS, sp.Rational(1, 10), "targets")
N = len(X)


def models():
    """The targets' models (helpers.turning_targets)."""
    return F, H


@pytest.fixture(scope="module")
def setup():
    f, h = models()
    Q = np.kron(np.eye(TARGETS), np.diag([0.02, 0.02, 0.01, 1e-3, 1e-4]))
    Rm = np.kron(np.eye(TARGETS), np.diag([0.25, 1e-4]))
    kf = sm.NonlinearKalmanFilter(f, h, Q, Rm, sm.TT1())
    step = compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states)
    assert step.c_ekf and step._lib.wait(120)
    rng = np.random.default_rng(7)
    runs, K = 5, 12
    x0 = np.concatenate([[10.0 + 4 * i, -3.0 + 2 * i, 1.0, 3.0 - 0.5 * i, 0.3] for i in range(TARGETS)])
    P0 = np.diag(np.tile([1.0, 1.0, 0.05, 0.02, 0.1], TARGETS))
    truth = x0 + rng.normal(size=(runs, K, N)) * 0.1
    hf = sp.lambdify([X, s], h.outputs)
    Y = np.array([[hf(t, 0.5) for t in run] for run in truth]) + rng.normal(size=(runs, K, 2 * TARGETS)) * 0.05
    Y[:, :, 1::2] = np.mod(Y[:, :, 1::2] + np.pi, 2 * np.pi) - np.pi
    Y[0, 3, 2] = np.nan  # a missing range
    Y[1, 5, :] = np.nan  # nothing measured
    Y[2, 7, 1::2] = np.nan  # no bearing
    params = np.broadcast_to([1.0, 0.5], (runs, K, 2)).copy()
    params[3, :, 0] = 0.8  # another dt in one run
    return kf, step, x0, P0, Y, Q, Rm, params, truth


def test_the_step_is_the_c_step_from_its_size_on():
    f, h = models()
    assert N >= C_EKF_FROM
    assert not compiled_step(f, h, sm.UT(1, 2, 0), frozenset(f.angle_outputs)).c_ekf
    assert compiled_step(f, h, sm.TT2(), frozenset(f.angle_outputs)).c_ekf  # the EKF2: test_ekf2_c.py
    assert compiled_step(f, h, sm.TT1(), frozenset(f.angle_outputs), 3).c_ekf
    assert not compiled_step(f, h, sm.TT1(), frozenset(f.angle_outputs), square_root=True).c_ekf


def test_c_step_equals_the_mx_step(setup):
    kf, step, x0, P0, Y, Q, Rm, params, truth = setup
    c = step(x0, P0, Y, Q, Rm, params=params, truth=truth, check_finite=True)
    vm = step(x0, P0, Y, Q, Rm, use_c=False, params=params, truth=truth, check_finite=True)
    assert set(c) == set(vm)
    for key in ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik", "nis", "nees", "nees_trace"):
        assert np.isfinite(c[key]).all(), key
        assert_close_to_scale(c[key], vm[key], RTOL)
    np.testing.assert_array_equal(c["first_nonfinite"], -1)
    # Missing components: a zero innovation, the unit diagonal of S; nothing measured: loglik 0.
    assert c["innovation"][0, 3, 2] == 0 and c["S"][0, 3, 2, 2] == 1
    assert c["loglik"][1, 5] == 0 and np.array_equal(c["x"][1, 5], c["x_pred"][1, 5])
    # The heading states are wrapped, P and P⁻ exactly symmetric.
    th = c["x"][..., 3::5]
    assert (np.abs(th) <= np.pi).all()
    for key in ("P", "P_pred", "S"):
        np.testing.assert_array_equal(c[key], np.swapaxes(c[key], -1, -2))


def test_filter_uses_the_c_step(setup):
    kf, step, x0, P0, Y, Q, Rm, params, truth = setup
    res = kf.filter(Y[0], sm.Gaussian(x0, P0), params={"dt": 1.0, "s": 0.5})
    out = step(x0, P0, Y[:1], Q, Rm, params=params[:1])
    np.testing.assert_array_equal(res.x, out["x"][0])
    np.testing.assert_array_equal(res.P, out["P"][0])


def test_bank_threads_equal_one_run_at_a_time(setup):
    kf, step, x0, P0, Y, Q, Rm, params, truth = setup
    runs, K = Y.shape[:2]
    keep = frozenset(("x", "P", "loglik"))
    bank = step(x0, P0, Y, Q, Rm, keep=keep, params=params)
    for r in range(runs):
        one = step(x0, P0, Y[r:r + 1], Q, Rm, keep=keep, params=params[r:r + 1])
        for key in keep:
            np.testing.assert_array_equal(bank[key][r], one[key][0])
    assert len(chunk_runs(runs, K, N)) == min(2, cpu_count())


def test_non_positive_innovation_covariance_stops_the_run(setup):
    """A negative R: once P⁻ has shrunk, S has a negative pivot, the log-likelihood is NaN,
    and the C loop reports that step as the VM path does."""
    kf, step, x0, P0, Y, Q, Rm, params, truth = setup
    bad = -Rm
    c = step(x0, P0, Y[:2], Q, bad, params=params[:2], check_finite=True)
    vm = step(x0, P0, Y[:2], Q, bad, use_c=False, params=params[:2], check_finite=True)
    first = c["first_nonfinite"]
    np.testing.assert_array_equal(first, vm["first_nonfinite"])
    assert (first >= 0).all() and np.isnan(c["loglik"][[0, 1], first]).all()


def test_iterated_c_step_equals_the_mx_step(setup):
    """The IEKF (3 Gauss–Newton steps): H_i (x⁻ − x_i) from H's nonzeros in C, through a solve
    with P⁻ in the MX graph; the same to rounding."""
    kf, step, x0, P0, Y, Q, Rm, params, truth = setup
    iekf = compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states, 3)
    assert iekf.c_ekf and iekf._lib.wait(120)
    c = iekf(x0, P0, Y, Q, Rm, params=params)
    vm = iekf(x0, P0, Y, Q, Rm, use_c=False, params=params)
    for key in ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik", "nis"):
        assert_close_to_scale(c[key], vm[key], RTOL)
    one = step(x0, P0, Y, Q, Rm, params=params)
    assert np.abs(c["x"] - one["x"]).max() > 1e-6  # the iterations move the estimate
