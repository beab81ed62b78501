"""The C backward step of the extended RTS smoother (symmon.filters.gaussian._ekfsmooth) against the MX
backward step on CasADi's VM.

Both run the same formulas (the RTS step with TT1's closed-form time update); they differ in
the order of the sums and in the gain (two triangular solves against the products with the
inverse factor), so every output agrees to rounding: 1e-10 relative to its scale over a
dozen steps of a 10-state filter (coordinated turns with heading angles, a parameter that
differs between runs, missing measurements).  The bank's threads each run whole runs, so a
bank equals its runs smoothed one by one, bit for bit.  A singular prediction gives inf or
NaN at the same steps as the MX step, which ``kf.smooth`` reports.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from helpers import assert_close_to_scale, turning_targets
from symmon.compile.compiled import cpu_count
from symmon.errors import SymmonError
from symmon.filters.gaussian._ekfsmooth import backward_in_c
from symmon.filters.gaussian._ekfstep import C_EKF_FROM
from symmon.filters.gaussian.smoother import compiled_smoother
from symmon.filters.gaussian.step import chunk_runs

RTOL = 1e-10
TARGETS = 2
F, H, X, dt, s = turning_targets(TARGETS, sp.Rational(3, 10), "smooth targets")
N = len(X)


def models():
    """The targets' models (helpers.turning_targets)."""
    return F, H


def linear(n_targets: int):
    """Constant-velocity targets with a range bias each (no angle state): affine f."""
    X, f_out, h_out = [], [], []
    for i in range(n_targets):
        px, py, vx, vy, b = blk = sp.symbols(f"lx{i} ly{i} lvx{i} lvy{i} lb{i}", real=True)
        X += blk
        f_out += [px + vx, py + vy, vx, vy, b]
        h_out += [sp.sqrt(px**2 + py**2) + b, sp.atan2(py, px)]
    return (sm.Model(X, f_out, name=f"cv smooth {len(X)}"),
            sm.Model(X, h_out, angles=list(range(1, 2 * n_targets, 2)), name=f"rb smooth {len(X)}"))


@pytest.fixture(scope="module")
def setup():
    f, h = models()
    Q = np.kron(np.eye(TARGETS), np.diag([0.02, 0.02, 0.01, 1e-3, 1e-4]))
    Rm = np.kron(np.eye(TARGETS), np.diag([0.25, 1e-4]))
    kf = sm.NonlinearKalmanFilter(f, h, Q, Rm, sm.TT1())
    sm_ = compiled_smoother(kf.f_model, kf.transform, kf.angle_states, kf.params)
    assert sm_.c_backward and sm_._lib.wait(120)
    rng = np.random.default_rng(5)
    runs, K = 5, 12
    # Headings near ±π, turning through it, so that the wrapping of the states matters.
    x0 = np.concatenate([[10.0 + 4 * i, -3.0 + 2 * i, 1.0, 3.0 - 0.2 * i, 0.3] for i in range(TARGETS)])
    P0 = np.diag(np.tile([1.0, 1.0, 0.05, 0.02, 0.1], TARGETS))
    truth = x0 + rng.normal(size=(runs, K, N)) * 0.1
    hf = sp.lambdify([X, s], h.outputs)
    Y = np.array([[hf(t, 0.5) for t in run] for run in truth]) + rng.normal(size=(runs, K, 2 * TARGETS)) * 0.05
    Y[:, :, 1::2] = np.mod(Y[:, :, 1::2] + np.pi, 2 * np.pi) - np.pi
    Y[0, 3, 2] = np.nan  # a missing range
    Y[1, 5, :] = np.nan  # nothing measured
    dts = np.ones(runs)
    dts[3] = 0.8  # another dt in one run
    params = {"dt": np.broadcast_to(dts[:, None], (runs, K)), "s": 0.5}
    res = kf.smooth(Y, sm.Gaussian(x0, P0), params=params)
    pvals = np.broadcast_to([1.0, 0.5], (runs, K, 2)).copy()
    pvals[3, :, 0] = 0.8
    return kf, sm_, res, Q, pvals


def test_which_smoothers_run_the_c_step():
    f, h = models()
    angles = frozenset(f.angle_outputs)
    assert N >= C_EKF_FROM
    assert backward_in_c(f, sm.TT1(), angles)
    assert not backward_in_c(f, sm.TT1(), angles, square_root=True)
    for transform in (sm.TT2(), sm.UT(1, 2, 0)):  # a nonlinear f: not TT1's closed form
        assert not backward_in_c(f, transform, angles)
    fl, _ = linear(2)
    assert backward_in_c(fl, sm.UT(1, 2, 0), frozenset())  # exact to degree 2 on an affine f
    assert not backward_in_c(fl, sm.UT(1, 2, 0), frozenset({3}))  # angle states: the points
    assert not backward_in_c(linear(1)[0], sm.TT1(), frozenset())  # below C_EKF_FROM


def test_c_backward_equals_the_mx_step(setup):
    kf, smoother, res, Q, pvals = setup
    X, P = res.filtered.x, res.filtered.P
    xs, Ps = smoother(X, P, Q, params=pvals)
    vx, vP = smoother(X, P, Q, use_c=False, params=pvals)
    np.testing.assert_array_equal(res.x, xs)  # kf.smooth ran the C step
    np.testing.assert_array_equal(res.P, Ps)
    assert np.isfinite(xs).all() and np.isfinite(Ps).all()
    assert_close_to_scale(xs, vx, RTOL)
    assert_close_to_scale(Ps, vP, RTOL)
    np.testing.assert_array_equal(Ps, np.swapaxes(Ps, -1, -2))
    assert (np.abs(xs[..., 3::5]) <= np.pi).all()
    # The headings cross ±π somewhere, so the wraps were exercised.
    assert (np.abs(xs[..., 3::5]) > 3.0).any()


def test_bank_threads_equal_one_run_at_a_time(setup):
    kf, smoother, res, Q, pvals = setup
    # The runs five times over: enough work for a thread per CPU (chunk_runs).
    X, P, pvals = (np.concatenate([a] * 5) for a in (res.filtered.x, res.filtered.P, pvals))
    runs, K = X.shape[:2]
    xs, Ps = smoother(X, P, Q, params=pvals)
    for r in range(runs):
        x1, P1 = smoother(X[r:r + 1], P[r:r + 1], Q, params=pvals[r:r + 1])
        np.testing.assert_array_equal(xs[r], x1[0])
        np.testing.assert_array_equal(Ps[r], P1[0])
    assert len(chunk_runs(runs, K, N)) == min(2, cpu_count())


def test_a_singular_prediction_gives_the_same_failures(setup):
    """No process noise and no prior variance in the speeds and headings: P⁻ is singular at
    every step; the C step's output is non-finite where the MX step's is, and smooth says so."""
    kf, smoother, res, Q, pvals = setup
    X, P = res.filtered.x[:2], res.filtered.P[:2].copy()
    keep = np.tile([1.0, 1.0, 0.0, 0.0, 1.0], TARGETS)
    P = P * np.outer(keep, keep)
    xs, Ps = smoother(X, P, np.zeros_like(Q), params=pvals[:2])
    vx, vP = smoother(X, P, np.zeros_like(Q), use_c=False, params=pvals[:2])
    bad = ~(np.isfinite(xs).all(-1) & np.isfinite(Ps).all((-1, -2)))
    bad_vm = ~(np.isfinite(vx).all(-1) & np.isfinite(vP).all((-1, -2)))
    np.testing.assert_array_equal(bad, bad_vm)
    assert bad[:, :-1].all() and not bad[:, -1].any()
    kf0 = sm.NonlinearKalmanFilter(kf.f_model, kf.h_model, np.zeros_like(Q), kf.R, sm.TT1())
    ys = np.array([[12.0, 0.1, 14.0, 0.2]] * 3)
    with pytest.raises(SymmonError, match="smoother: NaN or inf at step 1"):
        kf0.smooth(ys, np.concatenate([[10.0 + 4 * i, -3.0 + 2 * i, 1.0, 3.0, 0.3] for i in range(TARGETS)]),
                   np.diag(keep), params={"dt": 1.0, "s": 0.5})


def test_the_ukf_on_linear_dynamics_runs_it():
    """A UT on an affine f without angle states has TT1's time update: the same C step, equal
    to its MX step."""
    f, h = linear(2)
    n = f.n_u
    Q = np.kron(np.eye(2), np.diag([0.02, 0.02, 0.05, 0.05, 1e-4]))
    kf = sm.NonlinearKalmanFilter(f, h, Q, np.kron(np.eye(2), np.diag([0.25, 1e-4])), sm.UT(1, 2, 0))
    smoother = compiled_smoother(kf.f_model, kf.transform, kf.angle_states, kf.params)
    assert smoother.c_backward and smoother._lib.wait(120)
    x0 = np.array([20.0, 5.0, -1.0, 0.5, 0.5, 30.0, 8.0, -1.0, 0.5, 0.5])
    rng = np.random.default_rng(3)
    ys = np.array([[np.hypot(20 - k, 5 + k / 2) + 0.5, np.arctan2(5 + k / 2, 20 - k),
                    np.hypot(30 - k, 8 + k / 2) + 0.5, np.arctan2(8 + k / 2, 30 - k)] for k in range(1, 9)])
    ys = ys + rng.normal(size=ys.shape) * [0.5, 0.01, 0.5, 0.01]
    res = kf.smooth(ys, x0, np.eye(n) * 0.5)
    vx, vP = smoother(res.filtered.x[None], res.filtered.P[None], Q, use_c=False)
    assert_close_to_scale(res.x, vx[0], RTOL)
    assert_close_to_scale(res.P, vP[0], RTOL)
