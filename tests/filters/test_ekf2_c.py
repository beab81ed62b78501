"""The C step of the second-order EKF (TT2, symmon.filters.gaussian._ekfstep) against the MX step on CasADi's VM.

Both run the TT2 moments of Gustafsson & Hendeby (2012): x⁻ = f(x) + ½[tr(H_i P)],
P⁻ = F P Fᵀ + ½[tr(H_i P H_j P)] + Q, and the same for h in the update; the C sums the trace
terms over the Hessians' nonzeros, the MX graph over their blocks, so the two differ in the
order of the sums only and every output agrees to rounding: 1e-10 relative to its scale over a
dozen steps of a 10-state filter (coordinated turns with heading angles — f and h both with
Hessians —, range–bearing outputs with angles, parameters that change per step, missing
components).  The bank's threads each run whole runs, so a bank equals its runs one by one.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from helpers import assert_close_to_scale
from symmon.compile.compiled import cpu_count
from symmon.filters.gaussian._ekfstep import C_EKF_FROM, ekf_pieces
from symmon.filters.gaussian.step import compiled_step, chunk_runs

RTOL = 1e-10
TARGETS = 2
dt, s = sp.symbols("dt s", real=True)
BLOCKS = [sp.symbols(f"px{i} py{i} v{i} th{i} b{i}", real=True) for i in range(TARGETS)]
X = [v for blk in BLOCKS for v in blk]
N = len(X)
KEYS = ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik", "nis", "nees", "nees_trace")


def models(linear_f: bool = False, coupled: bool = False):
    """Coordinated-turn targets (heading th an angle state; linear_f: constant heading, a
    linear f with the angle state), each with a range bias; range and bearing of each from a
    sensor at (s, 0): f's parameter dt, h's s; coupled: also the distance between the first
    two targets (a Hessian on both targets' positions, and a P that couples them)."""
    f_out, h_out = [], []
    for px, py, v, th, b in BLOCKS:
        if linear_f:
            f_out += [px + dt * v, py + dt * b, v, th + dt * v / 10, b]
        else:
            f_out += [px + dt * v * sp.cos(th), py + dt * v * sp.sin(th), v, th + dt * v / 10, b]
        h_out += [sp.sqrt((px - s) ** 2 + py**2) + b, sp.atan2(py, px - s)]
    if coupled:
        (a, b), (c, d) = BLOCKS[0][:2], BLOCKS[1][:2]
        h_out.append(sp.sqrt((a - c) ** 2 + (b - d) ** 2))
    f = sm.Model(X, f_out, angles=[5 * i + 3 for i in range(TARGETS)], params=[dt], name="ct2 targets")
    h = sm.Model(X, h_out, angles=[2 * i + 1 for i in range(TARGETS)], params=[s], name="rb2 targets")
    return f, h


def data(coupled: bool = False):
    rng = np.random.default_rng(11)
    runs, K = 4, 12
    x0 = np.concatenate([[6.0 + 4 * i, -2.0 + 3 * i, 1.5, 3.0 - 0.5 * i, 0.3] for i in range(TARGETS)])
    # Large heading and speed variances: second-order terms far from negligible.
    P0 = np.diag(np.tile([1.0, 1.0, 0.3, 0.4, 0.1], TARGETS))
    truth = x0 + rng.normal(size=(runs, K, N)) * 0.1
    hf = sp.lambdify([X, s], models(coupled=coupled)[1].outputs)
    Y = np.array([[hf(t, 0.5) for t in run] for run in truth])
    Y += rng.normal(size=Y.shape) * 0.05
    Y[:, :, 1:2 * TARGETS:2] = np.mod(Y[:, :, 1:2 * TARGETS:2] + np.pi, 2 * np.pi) - np.pi
    Y[0, 3, 2] = np.nan  # a missing range
    Y[1, 5, :] = np.nan  # nothing measured
    Y[2, 7, 1::2] = np.nan  # no bearing
    params = np.empty((runs, K, 2))
    params[..., 0] = 1.0 + 0.05 * np.arange(K)  # dt changes per step
    params[..., 1] = 0.5
    params[3, :, 1] = -0.25  # another sensor position in one run
    Q = np.kron(np.eye(TARGETS), np.diag([0.02, 0.02, 0.01, 1e-2, 1e-4]))
    Rm = np.kron(np.eye(TARGETS), np.diag([0.25, 1e-3]))
    if coupled:
        Rm = np.diag(np.append(np.diag(Rm), 0.01))
    return x0, P0, Y, Q, Rm, params, truth


def built(linear_f: bool = False, coupled: bool = False):
    f, h = models(linear_f, coupled)
    x0, P0, Y, Q, Rm, params, truth = data(coupled)
    kf = sm.NonlinearKalmanFilter(f, h, Q, Rm, sm.TT2())
    step = compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states)
    assert step.c_ekf and step._lib.wait(120)
    return kf, step, x0, P0, Y, Q, Rm, params, truth


@pytest.fixture(scope="module")
def setup():
    return built()


def test_tt2_pieces_hold_the_hessian_blocks_only():
    """The Hessian columns of stacked targets: each output's support is its own target's few
    states (the range's and bearing's (px, py); f's positions' (v, th)), and an affine f has
    none, so that its part stays TT1's."""
    f, h = models()
    x, y, p = ca_syms()
    _, pattern = ekf_pieces(f, h, frozenset(f.angle_outputs), p[0], p[1], x, y, p, "t2", order=2)
    assert pattern["tt2_f"] and pattern["tt2_h"]
    sup_h, off_h = pattern["h2_sup"], pattern["h2_off"]
    assert np.diff(off_h).tolist() == [2] * (2 * TARGETS)
    assert sup_h[:4] == [0, 1, 0, 1] and sup_h[4:8] == [5, 6, 5, 6]
    assert np.diff(pattern["f2_off"]).tolist() == [2, 2, 0, 0, 0] * TARGETS
    assert pattern["f2_sup"][:4] == [2, 3, 2, 3]
    f_lin, _ = models(linear_f=True)
    _, pattern = ekf_pieces(f_lin, h, frozenset(f_lin.angle_outputs), p[0], p[1], x, y, p, "t3", order=2)
    assert not pattern["tt2_f"] and pattern["tt2_h"] and "f2_sup" not in pattern


def ca_syms():
    import casadi as ca

    return ca.SX.sym("x", N), ca.SX.sym("y", 2 * TARGETS), ca.SX.sym("p", 2)


def test_tt2_c_step_equals_the_mx_step(setup):
    kf, step, x0, P0, Y, Q, Rm, params, truth = setup
    assert N >= C_EKF_FROM
    c = step(x0, P0, Y, Q, Rm, params=params, truth=truth, check_finite=True)
    vm = step(x0, P0, Y, Q, Rm, use_c=False, params=params, truth=truth, check_finite=True)
    assert set(c) == set(vm)
    for key in KEYS:
        assert np.isfinite(c[key]).all(), key
        assert_close_to_scale(c[key], vm[key], RTOL)
    np.testing.assert_array_equal(c["first_nonfinite"], -1)
    assert c["innovation"][0, 3, 2] == 0 and c["S"][0, 3, 2, 2] == 1
    assert c["loglik"][1, 5] == 0 and np.array_equal(c["x"][1, 5], c["x_pred"][1, 5])
    assert (np.abs(c["x"][..., 3::5]) <= np.pi).all() and (np.abs(c["x_pred"][..., 3::5]) <= np.pi).all()
    for key in ("P", "P_pred", "S"):
        np.testing.assert_array_equal(c[key], np.swapaxes(c[key], -1, -2))
    # The second-order terms matter here: the EKF's estimates are far from the EKF2's.
    ekf = compiled_step(kf.f_model, kf.h_model, sm.TT1(), kf.angle_states)
    one = ekf(x0, P0, Y, Q, Rm, use_c=False, params=params)
    assert np.abs(one["P_pred"] - c["P_pred"]).max() > 1e-3 * np.abs(c["P_pred"]).max()
    assert np.abs(one["x_pred"] - c["x_pred"]).max() > 1e-3


def test_filter_runs_the_tt2_c_step(setup):
    kf, step, x0, P0, Y, Q, Rm, params, truth = setup
    res = kf.filter(Y[3], sm.Gaussian(x0, P0), params={"dt": params[3, :, 0], "s": params[3, :, 1]})
    out = step(x0, P0, Y[3:4], Q, Rm, params=params[3:4])
    np.testing.assert_array_equal(res.x, out["x"][0])
    np.testing.assert_array_equal(res.P, out["P"][0])


def test_tt2_bank_threads_equal_one_run_at_a_time(setup):
    kf, step, x0, P0, Y, Q, Rm, params, truth = setup
    # 24 runs (the 4 with 6 sensor positions): enough work for a thread per core.
    Y, truth = np.tile(Y, (6, 1, 1)), np.tile(truth, (6, 1, 1))
    params = np.tile(params, (6, 1, 1))
    params[:, :, 1] += np.repeat(0.1 * np.arange(6), 4)[:, None]
    assert len(chunk_runs(Y.shape[0], Y.shape[1], N)) == min(2, cpu_count())
    keep = frozenset(("x", "P", "loglik", "nis"))
    bank = step(x0, P0, Y, Q, Rm, keep=keep, params=params, truth=truth)
    for r in range(Y.shape[0]):
        one = step(x0, P0, Y[r:r + 1], Q, Rm, keep=keep, params=params[r:r + 1], truth=truth[r:r + 1])
        for key in keep | {"nees"}:
            np.testing.assert_array_equal(bank[key][r], one[key][0])


@pytest.mark.parametrize("linear_f, coupled", [(True, False), (False, True)])
def test_tt2_c_step_variants_equal_the_mx_step(linear_f, coupled):
    """An affine f with an angle state: no Hessian nonzeros in f (its TT1 part, wrapped),
    h's second-order terms only.  Coupled targets: an output whose Hessian spans both
    targets' positions (supports of 2 and 4 states), and a P that couples the targets, so
    that the terms between outputs of different targets are not zero."""
    kf, step, x0, P0, Y, Q, Rm, params, truth = built(linear_f, coupled)
    c = step(x0, P0, Y, Q, Rm, params=params, truth=truth)
    vm = step(x0, P0, Y, Q, Rm, use_c=False, params=params, truth=truth)
    for key in KEYS:
        assert np.isfinite(c[key]).all(), key
        assert_close_to_scale(c[key], vm[key], RTOL)
    if coupled:  # the targets are correlated: the off-block trace terms are exercised
        assert np.abs(c["P_pred"][:, 1:, :5, 5:]).max() > 1e-3
