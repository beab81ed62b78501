"""Interacting multiple models, ``sm.IMM`` (Blom & Bar-Shalom 1988).

- FilterPy's ``IMMEstimator`` on its own linear cases (its test's Crassidis example and its
  docstring's example), stored in tests/reference/filterpy_imm.json by
  tests/reference/make_imm_reference.py: the combined x and P, the mode probabilities, the
  modes' x and the log-likelihood to 1e-10 (relative to the largest entry; the same sums in
  another order, and a Joseph-form against a short-form update: rounding only).
- With one mode the IMM is that mode's filter, exactly (the mixing weights are 1).
- A target that flies straight, turns at 0.15 rad/s and flies straight again, seen by a
  range–bearing radar: the mode probabilities of a constant-velocity EKF and a
  coordinated-turn UKF switch within a few steps of each change.
- Angle states are mixed with circular means; parameters reach each mode; failures name the
  mode, run and step.
- Square-root modes (all or some) equal the standard IMM, and FilterPy's, to 1e-10; a mixed
  covariance without a Cholesky factor is refused, naming the mode, run and step.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.core.problems import TURN_SERIES, coordinated_turn
from symmon.errors import (ArgumentError, ArgumentTypeError, CovarianceError, ModelError, NonFiniteError,
                           ShapeError)

from helpers import REFERENCE_DIR, assert_close_to_scale

REF = json.loads((REFERENCE_DIR / "filterpy_imm.json").read_text())
RTOL = 1e-10


def close(a, b, rtol=RTOL):
    assert_close_to_scale(a, b, rtol)


# ------------------------------------------------------------------ FilterPy's cases
@pytest.fixture(scope="module", params=["crassidis", "docstring"])
def filterpy_case(request):
    d = REF[request.param]
    kfs = [sm.KalmanFilter(d["F"], Q, d["H"], R) for Q, R in zip(d["Q"], d["R"])]
    imm = sm.IMM(kfs, d["transition"], d["mu0"])
    return d, imm.filter(np.array(d["ys"]), np.array(d["x0"]), np.array(d["P0"]))


def test_imm_equals_filterpy_imm_estimator(filterpy_case):
    d, res = filterpy_case
    close(res.x, d["x"])
    close(res.P[d["P_steps"]], d["P"])
    close(res.mode_probabilities, d["mu"])
    close(res.loglik, d["loglik"])
    if "mode_x" in d:
        close(res.mode_x, d["mode_x"])
    assert res.mode_probabilities.shape == (len(d["ys"]), 2)
    np.testing.assert_allclose(res.mode_probabilities.sum(axis=-1), 1.0, rtol=1e-15)
    assert res.log_likelihood == pytest.approx(sum(d["loglik"]), rel=RTOL)


def test_a_bank_equals_its_runs():
    d = REF["docstring"]
    kfs = [sm.KalmanFilter(d["F"], Q, d["H"], R) for Q, R in zip(d["Q"], d["R"])]
    imm = sm.IMM(kfs, d["transition"], d["mu0"])
    ys = np.array(d["ys"])
    bank = imm.filter(np.stack([ys, ys[::-1], ys + 3.0]), np.array(d["x0"]), np.array(d["P0"]))
    assert bank.x.shape == (3, 30, 6) and bank.mode_P.shape == (3, 30, 2, 6, 6) and bank.runs == 3
    for r, y in enumerate((ys, ys[::-1], ys + 3.0)):
        one = imm.filter(y, np.array(d["x0"]), np.array(d["P0"]))
        close(bank.x[r], one.x, 1e-13)
        close(bank.mode_probabilities[r], one.mode_probabilities, 1e-13)
        close(bank.loglik[r], one.loglik, 1e-13)
    assert bank.log_likelihood.shape == (3,)
    # One initial state per run.
    x0s = np.array(d["x0"]) + np.arange(3)[:, None]
    per_run = imm.filter(np.stack([ys] * 3), x0s, np.array(d["P0"]))
    for r in range(3):
        close(per_run.x[r], imm.filter(ys, x0s[r], np.array(d["P0"])).x, 1e-13)


# ------------------------------------------------------------- the tracking models
X = sp.symbols("x y vx vy omega", real=True)
T = 1.0
SIGMA = np.array([2.0, 0.002])  # range (m) and bearing (rad) noise of the radar


def cv_model():
    """Constant velocity on [x, y, vx, vy, ω], ω carried along unused."""
    x, y, vx, vy, w = X
    return sm.Model(X, [x + T * vx, y + T * vy, vx, vy, w], name="cv_omega")


def radar():
    x, y = X[:2]
    return sm.Model(X, [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], angles=[1], name="rb5")


def noise(q: float, q_omega: float) -> np.ndarray:
    """White-noise acceleration q on x, y and a random-walk turn rate q_omega."""
    Q = np.zeros((5, 5))
    Q[:4, :4] = q * np.kron([[T**3 / 3, T**2 / 2], [T**2 / 2, T]], np.eye(2))
    Q[4, 4] = q_omega
    return Q


@pytest.fixture(scope="module")
def modes():
    R = np.diag(SIGMA**2)
    cv = sm.NonlinearKalmanFilter(cv_model(), radar(), noise(0.01, 1e-8), R, sm.TT1())
    ct = sm.NonlinearKalmanFilter(coordinated_turn(T), radar(), noise(0.01, 1e-4), R, sm.UT.cubature())
    return cv, ct


def manoeuvre(runs: int, seed: int = 36):
    """Straight for 20 steps, a turn at 0.15 rad/s for 15 steps, straight for 15: the truth
    (noise free) and the radar's measurements of ``runs`` runs."""
    rates = np.r_[np.zeros(20), np.full(15, 0.15), np.zeros(15)]
    ct = sm.compile.compiled(coordinated_turn(T))
    s = np.array([[1500.0, 800.0, -20.0, 5.0, 0.0]])
    truth = []
    for w in rates:
        s[0, 4] = w
        s = ct.eval_g(s)
        truth.append(s[0].copy())
    truth = np.array(truth)
    clean = np.stack([np.hypot(truth[:, 0], truth[:, 1]), np.arctan2(truth[:, 1], truth[:, 0])], axis=-1)
    rng = np.random.default_rng(seed)
    return truth, clean + rng.standard_normal((runs, len(rates), 2)) * SIGMA


X0 = sm.Gaussian([1500.0, 800.0, -20.0, 5.0, 0.0], np.diag([100.0, 100.0, 4.0, 4.0, 0.01]))


def test_coordinated_turn_model_is_the_constant_velocity_step_at_zero_rate():
    ct = sm.compile.compiled(coordinated_turn(2.0))
    s = np.array([[1.0, 2.0, 3.0, -1.0, 0.0]])
    np.testing.assert_array_equal(ct.eval_g(s)[0], [7.0, 0.0, 3.0, -1.0, 0.0])
    # A quarter turn: the velocity rotates by 90°, the position moves along the arc's chord.
    q = ct.eval_g(np.array([[0.0, 0.0, 1.0, 0.0, np.pi / 4]]))[0]
    np.testing.assert_allclose(q, [4 / np.pi, 4 / np.pi, 0.0, 1.0, np.pi / 4], atol=1e-15)
    # On both sides of the switch to the series, f and its Jacobian are those of the exact
    # formulas (sympy at 30 digits): accurate to rounding, no 0/0, no cancellation.
    x, y, vx, vy, w = sp.symbols("x y vx vy omega", real=True)
    a = 2 * w
    exact = sp.Matrix([x + sp.sin(a) / w * vx - (1 - sp.cos(a)) / w * vy, y + (1 - sp.cos(a)) / w * vx
                       + sp.sin(a) / w * vy, sp.cos(a) * vx - sp.sin(a) * vy, sp.sin(a) * vx + sp.cos(a) * vy, w])
    jac = exact.jacobian([x, y, vx, vy, w])
    for rate in (1e-7, 0.999 * TURN_SERIES / 2, 1.001 * TURN_SERIES / 2, 0.3):
        pt = np.array([[1.0, 2.0, 3.0, -1.0, rate]])
        at = dict(zip((x, y, vx, vy, w), [sp.Float(v, 30) for v in pt[0]]))
        want_g = np.array(exact.evalf(30, subs=at), dtype=float)[:, 0]
        want_J = np.array(jac.evalf(30, subs=at), dtype=float)
        close(ct.eval_g(pt)[0], want_g, 1e-14)
        close(ct.dense_jacobian(ct.eval_derivatives(pt)[1])[0], want_J, 1e-11)


def test_mode_probabilities_switch_within_a_few_steps_of_the_turn(modes):
    cv, ct = modes
    truth, ys = manoeuvre(runs=8)
    imm = sm.IMM([cv, ct], [[0.95, 0.05], [0.05, 0.95]], [0.9, 0.1])
    res = imm.filter(ys, X0, x_true=np.broadcast_to(truth, (8,) + truth.shape))
    p_turn = res.mode_probabilities[..., 1].mean(axis=0)  # over the runs
    # Straight: the constant-velocity mode; the turn's first step is 20 and its last 34: the
    # coordinated-turn mode takes over by step 22 and gives way by step 37.
    assert np.all(p_turn[5:20] < 0.3)
    assert p_turn[20] < 0.5 and p_turn[22] > 0.5 and np.all(p_turn[23:35] > 0.6)
    assert p_turn[35] > 0.5 and p_turn[37] < 0.5 and np.all(p_turn[38:] < 0.3)
    # The combined estimate follows the target through the turn: its NEES is computed, and
    # the position error stays within a few range noises.
    assert res.nees_values.shape == (8, 50)
    np.testing.assert_allclose(res.nees(np.broadcast_to(truth, (8,) + truth.shape)), res.nees_values, rtol=1e-12)
    assert np.abs(res.x[..., :2] - truth[:, :2]).max() < 25.0
    assert res.nis().shape == (8, 50) and res.anis().dof == 16


def test_one_mode_is_that_filter(modes):
    _, ct = modes
    truth, ys = manoeuvre(runs=2)
    ys[:, 7] = np.nan
    ys[1, 9, 0] = np.nan
    one = sm.IMM([ct], [[1.0]], [1.0]).filter(ys, X0)
    ref = ct.filter(ys, X0)
    for name in ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik"):
        np.testing.assert_array_equal(getattr(one, name), getattr(ref, name), err_msg=name)
    np.testing.assert_array_equal(one.measured, ref.measured)
    close(one.nis(), ref.nis(), 1e-12)
    np.testing.assert_array_equal(one.mode_probabilities, 1.0)
    # A second mode that no mode can enter (a zero column of the transition matrix) has
    # probability 0 throughout, and the IMM is the first mode's filter.
    cv, _ = modes
    two = sm.IMM([ct, cv], [[1.0, 0.0], [1.0, 0.0]], [1.0, 0.0]).filter(ys, X0)
    np.testing.assert_array_equal(two.mode_probabilities[..., 1], 0.0)
    close(two.x, ref.x, 1e-14)
    close(two.P, ref.P, 1e-14)


def test_a_row_without_measurement_keeps_the_predicted_mode_probabilities(modes):
    truth, ys = manoeuvre(runs=1)
    ys = ys[0]
    ys[25] = np.nan
    imm = sm.IMM(list(modes), [[0.95, 0.05], [0.05, 0.95]], [0.9, 0.1])
    res = imm.filter(ys, X0)
    close(res.mode_probabilities[25], res.predicted_probabilities[25], 1e-15)  # c̄ renormalised: rounding
    assert res.loglik[25] == 0.0 and np.all(res.mode_loglik[25] == 0.0) and res.measured[25] == 0
    close(res.predicted_probabilities[26], res.mode_probabilities[25] @ imm.transition, 1e-15)


def test_parameters_reach_each_mode():
    x, y, vx, vy, w = X
    dt = sp.Symbol("dt", positive=True)
    cv_dt = sm.Model(X, [x + dt * vx, y + dt * vy, vx, vy, w], params=[dt], name="cv_dt")
    R = np.diag(SIGMA**2)
    fixed = sm.NonlinearKalmanFilter(cv_model(), radar(), noise(0.01, 1e-8), R, sm.TT1())
    free = sm.NonlinearKalmanFilter(cv_dt, radar(), noise(0.01, 1e-8), R, sm.TT1())
    slow = sm.NonlinearKalmanFilter(cv_model(), radar(), noise(1.0, 1e-8), R, sm.TT1())
    _, ys = manoeuvre(runs=1)
    ys = ys[0, :12]
    a = sm.IMM([fixed, slow], [[0.9, 0.1], [0.1, 0.9]], [0.5, 0.5]).filter(ys, X0)
    b = sm.IMM([free, slow], [[0.9, 0.1], [0.1, 0.9]], [0.5, 0.5])
    close(b.filter(ys, X0, params={"dt": 1.0}).x, a.x, 1e-12)
    close(b.filter(ys, X0, params=[{"dt": np.ones(12)}, None]).x, a.x, 1e-12)
    with pytest.raises(ModelError, match=r"params \['speed'\] are declared by no mode"):
        b.filter(ys, X0, params={"dt": 1.0, "speed": 2.0})
    with pytest.raises(ModelError, match=r"mode 0 \(EKF\(cv_dt\)\): .*missing \['dt'\]"):
        b.filter(ys, X0)
    with pytest.raises(ShapeError, match=r"mode 0 \(EKF\(cv_dt\)\): parameter 'dt' must be"):
        b.filter(ys, X0, params={"dt": np.ones(5)})


# ----------------------------------------------------------------------- angle states
def test_angle_states_are_mixed_with_circular_means():
    """Two modes turning a heading θ near ±π left and right: the combined θ and the mixed
    ones are circular means (a linear mean of π − ε and −π + ε would be near 0)."""
    th = sp.Symbol("theta", real=True)
    h = sm.Model([th], [th], angles=[0], name="heading")
    left = sm.NonlinearKalmanFilter(sm.Model([th], [th + 0.2], angles=[0], name="left"), h, [[1e-4]], [[0.01]],
                                    sm.TT1())
    right = sm.NonlinearKalmanFilter(sm.Model([th], [th - 0.2], angles=[0], name="right"), h, [[1e-4]], [[0.01]],
                                     sm.TT1())
    imm = sm.IMM([left, right], [[0.5, 0.5], [0.5, 0.5]], [0.5, 0.5])
    assert imm.angle_states == frozenset({0})
    ys = np.full((6, 1), np.pi)  # measured at the cut
    res = imm.filter(ys, sm.Gaussian([np.pi - 0.01], [[0.04]]))
    assert np.all(np.abs(res.x[:, 0]) > 3.0)
    mu, xm, Pm = res.mode_probabilities, res.mode_x[..., 0], res.mode_P[..., 0, 0]
    mean = np.arctan2((mu * np.sin(xm)).sum(axis=1), (mu * np.cos(xm)).sum(axis=1))
    close(res.x[:, 0], mean, 1e-14)
    d = np.mod(xm - mean[:, None] + np.pi, 2 * np.pi) - np.pi
    close(res.P[:, 0, 0], (mu * (Pm + d**2)).sum(axis=1), 1e-14)
    # NEES against a truth on the other side of the cut: the error is wrapped.
    assert np.all(res.nees(np.full((6, 1), -np.pi + 0.01)) < 1.0)


# ------------------------------------------------------------------------------ errors
def test_a_failing_mode_is_named_with_its_run_and_step(monkeypatch):
    s = sp.Symbol("s", real=True)
    h = sm.Model([s], [sp.log(s)], name="log")
    stay = sm.NonlinearKalmanFilter(sm.Model([s], [s], name="stay"), h, [[1e-6]], [[0.01]], sm.TT1())
    fall = sm.NonlinearKalmanFilter(sm.Model([s], [s - 5.0], name="fall"), h, [[1e-6]], [[0.01]], sm.TT1())
    imm = sm.IMM([stay, fall], [[0.5, 0.5], [0.5, 0.5]], [0.5, 0.5])
    ys = np.log(np.array([[[100.0]] * 3, [[3.0]] * 3]))
    with pytest.raises(NonFiniteError, match=r"mode 1 \(EKF\(fall\)\) produced NaN or inf at run 1, step 0"):
        imm.filter(ys, np.array([[100.0], [3.0]]), np.array([[1e-6]]))
    monkeypatch.setattr("symmon.filters.mixture.imm._FusedLoop.native", lambda self: None)  # the loop over steps
    with pytest.raises(NonFiniteError, match=r"mode 1 \(EKF\(fall\)\) produced NaN or inf at run 1, step 0"):
        imm.filter(ys, np.array([[100.0], [3.0]]), np.array([[1e-6]]))
    with pytest.raises(NonFiniteError, match=r"mode 1 \(EKF\(fall\)\) produced NaN or inf at step 0"):
        imm.filter(ys[1], np.array([3.0]), np.array([[1e-6]]))


I2 = np.eye(2)
KF2 = sm.KalmanFilter(I2, I2, I2, I2)
KF3 = sm.KalmanFilter(np.eye(3), np.eye(3), np.eye(3)[:2], I2)


@pytest.mark.parametrize("make, error, match", [
    (lambda: sm.IMM([], [[1.0]], [1.0]), ArgumentError, "at least one filter"),
    (lambda: sm.IMM(KF2, [[1.0]], [1.0]), ArgumentTypeError, "a sequence of filters"),
    (lambda: sm.IMM([KF2, "ekf"], np.eye(2), [0.5, 0.5]), ArgumentTypeError, "mode 1: filters must be"),
    (lambda: sm.IMM([KF2, KF3], np.eye(2), [0.5, 0.5]), ShapeError, "mode 1 has 3 states"),
    (lambda: sm.IMM([KF2, KF2], [[0.9, 0.1], [0.2, 0.9]], [0.5, 0.5]), ArgumentError, "row 1 of transition sums to"),
    (lambda: sm.IMM([KF2, KF2], [[1.1, -0.1], [0.1, 0.9]], [0.5, 0.5]), ArgumentError, "probabilities ≥ 0"),
    (lambda: sm.IMM([KF2, KF2], np.eye(3), [0.5, 0.5]), ShapeError, r"transition must have shape \(2, 2\)"),
    (lambda: sm.IMM([KF2, KF2], np.eye(2), [0.5, 0.6]), ArgumentError, "probabilities sums to"),
    (lambda: sm.IMM([KF2, KF2], np.eye(2), [np.nan, 1.0]), ArgumentError, "finite probabilities"),
    (lambda: sm.IMM([KF2, KF2], np.eye(2), [0.5, 0.5]).filter(np.zeros((3, 3)), np.zeros(2), I2), ShapeError,
     "ys must have shape"),
    (lambda: sm.IMM([KF2, KF2], np.eye(2), [0.5, 0.5]).filter([[np.inf, 0.0]], np.zeros(2), I2), ShapeError,
     "ys contains inf"),
])
def test_bad_inputs_are_named(make, error, match):
    with pytest.raises(error, match=match):
        make()


def test_modes_must_agree_on_angles():
    th = sp.Symbol("theta", real=True)
    h = sm.Model([th], [sp.sin(th)], name="sin")
    a = sm.NonlinearKalmanFilter(sm.Model([th], [th], angles=[0], name="a"), h, [[1.0]], [[1.0]], sm.TT1())
    b = sm.NonlinearKalmanFilter(sm.Model([th], [th], name="b"), h, [[1.0]], [[1.0]], sm.TT1())
    with pytest.raises(ShapeError, match=r"mode 1 has angle states \[\], mode 0 \[0\]"):
        sm.IMM([a, b], np.eye(2), [0.5, 0.5])


# ---------------------------------------------------------- the compiled loop and its fallback
def heading_imm():
    th = sp.Symbol("theta", real=True)
    h = sm.Model([th], [th], angles=[0], name="heading")
    turns = [sm.NonlinearKalmanFilter(sm.Model([th], [th + a], angles=[0], name=f"turn{a}"), h, [[1e-4]], [[0.01]],
                                      sm.TT1()) for a in (0.2, -0.2)]
    return sm.IMM(turns, [[0.7, 0.3], [0.4, 0.6]], [0.5, 0.5])


def test_the_compiled_loop_equals_the_loop_over_steps(modes, monkeypatch):
    """The fused C loop (mixing, steps and mode probabilities in C) and the fallback that calls
    each mode's compiled step per time step (an adaptive mode, or no compiler): the same sums
    in another order, to 1e-12; angle states, missing rows and components, and parameters."""
    _, ys = manoeuvre(runs=3)
    ys[0, 4] = np.nan
    ys[2, 30, 1] = np.nan
    imm = sm.IMM(list(modes), [[0.95, 0.05], [0.05, 0.95]], [0.9, 0.1])
    cases = [(imm, ys, X0), (heading_imm(), np.full((2, 6, 1), np.pi), sm.Gaussian([np.pi - 0.01], [[0.04]]))]
    fused = [m.filter(y, x0) for m, y, x0 in cases]
    assert all(m._fused_loop().native() is not None for m, _, _ in cases)
    monkeypatch.setattr("symmon.filters.mixture.imm._FusedLoop.native", lambda self: None)
    for (m, y, x0), a in zip(cases, fused):
        b = m.filter(y, x0)
        for name in ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik", "mode_probabilities",
                     "predicted_probabilities", "mode_x", "mode_P", "mode_loglik"):
            close(getattr(b, name), getattr(a, name), 1e-12)


def test_an_adaptive_mode_runs_step_by_step(modes):
    cv, ct = modes
    rules = sm.Adaptive(0.01, candidates=("tt1", "ct"), reference=sm.GaussHermite(3, sparse=False))
    adaptive = sm.NonlinearKalmanFilter(ct.f_model, ct.h_model, ct.Q, ct.R, rules)
    imm = sm.IMM([cv, adaptive], [[0.95, 0.05], [0.05, 0.95]], [0.9, 0.1])
    assert imm._fused_loop() is None
    _, ys = manoeuvre(runs=1)
    res = imm.filter(ys[0, :25], X0)
    assert res.mode_probabilities[23, 1] > 0.5  # the turn began at step 20


# ------------------------------------------------------------------ square-root modes
def square_root(kf):
    """The square-root form of a mode (a linear KalmanFilter as the EKF of its model)."""
    if isinstance(kf, sm.KalmanFilter):
        kf = kf.as_gaussian_mode()
    return sm.NonlinearKalmanFilter(kf.f_model, kf.h_model, kf.Q, kf.R, kf.strategy.transform, square_root=True)


IMM_OUTPUTS = ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik", "mode_probabilities",
               "predicted_probabilities", "mode_x", "mode_P", "mode_loglik")


def test_square_root_modes_equal_filterpy_imm_estimator():
    """Square-root modes (the mixed P⁰ factored, P = S Sᵀ from the step's factor) on FilterPy's
    linear case: its IMMEstimator to 1e-10, as the standard modes."""
    d = REF["crassidis"]
    kfs = [square_root(sm.KalmanFilter(d["F"], Q, d["H"], R)) for Q, R in zip(d["Q"], d["R"])]
    imm = sm.IMM(kfs, d["transition"], d["mu0"])
    assert imm._fused_loop() is None and imm.modes[0].startswith("SR-EKF")
    res = imm.filter(np.array(d["ys"]), np.array(d["x0"]), np.array(d["P0"]))
    close(res.x, d["x"])
    close(res.P[d["P_steps"]], d["P"])
    close(res.mode_probabilities, d["mu"])
    close(res.loglik, d["loglik"])


@pytest.mark.parametrize("which", [(0, 1), (1,)], ids=["all", "mixed"])
def test_square_root_modes_equal_standard_modes(modes, which):
    """On the manoeuvre (a CV EKF and a CT cubature filter, a bearing, missing rows and
    components, a bank): square-root modes, all or some, give the standard IMM to 1e-10
    (the same filter in exact arithmetic; rounding only on this well-conditioned case)."""
    _, ys = manoeuvre(runs=2)
    ys = ys[:, :30]
    ys[0, 4] = np.nan
    ys[1, 22, 1] = np.nan
    T = [[0.95, 0.05], [0.05, 0.95]]
    ref = sm.IMM(list(modes), T, [0.9, 0.1]).filter(ys, X0)
    sr = [square_root(kf) if j in which else kf for j, kf in enumerate(modes)]
    res = sm.IMM(sr, T, [0.9, 0.1]).filter(ys, X0)
    for name in IMM_OUTPUTS:
        close(getattr(res, name), getattr(ref, name), 1e-10)


def test_a_square_root_mode_refuses_a_mixed_covariance_without_factor(modes):
    """A singular P⁰ of a square-root mode is refused, naming the mode, the run and the step."""
    cv, ct = modes
    imm = sm.IMM([cv, square_root(ct)], [[0.95, 0.05], [0.05, 0.95]], [0.9, 0.1])
    _, ys = manoeuvre(runs=2)
    P0 = np.stack([X0.cov, np.diag([100.0, 100.0, 4.0, 4.0, 0.0])])  # run 1: a known turn rate
    with pytest.raises(CovarianceError, match=r"mode 1 \(SR-CKF\(coordinated_turn_T1\)\) is not positive definite "
                                              r"at run 1, step 0"):
        imm.filter(ys[:, :3], X0.mean[None].repeat(2, axis=0), P0)
    with pytest.raises(CovarianceError, match=r"mode 1 .* not positive definite at step 0"):
        imm.filter(ys[1, :3], X0.mean, P0[1])
