"""The compiled nonlinear Kalman filters (symmon.filters): FilterPy's EKF and UKF, angles,
general noise, filter banks and the NEES/NIS consistency statistics."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import sympy as sp
from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter
from scipy import stats

import symmon as sm
from symmon.estimation import nlt as est
from symmon.errors import ShapeError, SymmonError
from symmon.filters.results import NonlinearKalmanResult
from symmon.filters.gaussian.step import compiled_step
from symmon.filters.results import quadratic_forms

#: Two implementations of the same filter in double precision, over tens of steps: the
#: order of the sums differs, so rounding (1e-16 per operation) grows by the conditioning
#: of S and P over the steps; 1e-9 leaves a wide margin over the 1e-13 observed.
SAME_FILTER_RTOL = 1e-9
#: The same compiled C code on the same numbers (bank against single runs).
SAME_CODE_RTOL = 1e-12

DT = 1.0
F_CV = np.array([[1, 0, DT, 0], [0, 1, 0, DT], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
Q_CV = 0.05 * np.kron(np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]]), np.eye(2))
R_RB = np.diag([0.5**2, 0.02**2])


def rel_err(a: np.ndarray, b: np.ndarray) -> float:
    """max |a − b| relative to max |b|."""
    return float(np.max(np.abs(np.asarray(a) - b)) / np.max(np.abs(b)))


def wrap(a):
    return np.mod(np.asarray(a) + np.pi, 2 * np.pi) - np.pi


def cv_models(rotation: float = 0.0, angles: bool = True, tag: str = ""):
    """Constant velocity and range–bearing from the origin, the bearing measured from the
    direction ``rotation`` (a sensor frame rotated by it)."""
    px, py, vx, vy = sp.symbols("px py vx vy", real=True)
    X = [px, py, vx, vy]
    f = sm.Model(X, list(sp.Matrix(F_CV) * sp.Matrix(X)), name="cv" + tag)
    c, s = np.cos(rotation), np.sin(rotation)
    bearing = sp.atan2(-s * px + c * py, c * px + s * py) if rotation else sp.atan2(py, px)
    h = sm.Model(X, [sp.sqrt(px**2 + py**2), bearing], name=f"rb{tag}", angles=[1] if angles else None)
    return f, h


def simulate(x0: np.ndarray, K: int, seed: int, runs: int | None = None):
    """True states and range–bearing measurements of the CV model."""
    rng = np.random.default_rng(seed)
    lead = () if runs is None else (runs,)
    x = np.broadcast_to(x0, lead + (4,)).copy()
    Lq, Lr = np.linalg.cholesky(Q_CV), np.linalg.cholesky(R_RB)
    xs, ys = np.empty(lead + (K, 4)), np.empty(lead + (K, 2))
    for k in range(K):
        x = x @ F_CV.T + rng.standard_normal(lead + (4,)) @ Lq.T
        xs[..., k, :] = x
        y = np.stack([np.hypot(x[..., 0], x[..., 1]), np.arctan2(x[..., 1], x[..., 0])], axis=-1)
        ys[..., k, :] = y + rng.standard_normal(lead + (2,)) @ Lr.T
    ys[..., 1] = wrap(ys[..., 1])
    return xs, ys


X0 = sm.Gaussian([20.0, 5.0, -1.0, 0.5], np.diag([1.0, 1.0, 0.1, 0.1]))


@pytest.fixture(scope="module")
def track():
    return simulate(X0.mean, 40, seed=1)


# --------------------------------------------------------------------------- FilterPy
def hx(x):
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def residual_z(a, b):
    d = np.asarray(a, dtype=float) - b
    d[1] = wrap(d[1])
    return d


def z_mean(sigmas, Wm):
    """The circular mean of the bearing, as symmon's (centred on the first point)."""
    r = sigmas[0, 0] + Wm @ (sigmas[:, 0] - sigmas[0, 0])
    return np.array([r, np.arctan2(Wm @ np.sin(sigmas[:, 1]), Wm @ np.cos(sigmas[:, 1]))])


@pytest.mark.parametrize("alpha, beta, kappa", [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0), (1.0, 0.0, 0.0)])
def test_ukf_equals_filterpy(track, alpha, beta, kappa):
    _, ys = track
    f, h = cv_models()
    res = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.UT(alpha, beta, kappa)).filter(ys, X0)
    ukf = UnscentedKalmanFilter(4, 2, DT, hx, lambda x, dt: F_CV @ x,
                                MerweScaledSigmaPoints(4, alpha, beta, kappa),
                                z_mean_fn=z_mean, residual_z=residual_z)
    ukf.x, ukf.P, ukf.Q, ukf.R = X0.mean.copy(), X0.cov.copy(), Q_CV, R_RB
    xs, Ps, nus, Ss, lls = [], [], [], [], []
    for y in ys:
        ukf.predict()
        ukf.update(y)
        xs.append(ukf.x.copy()), Ps.append(ukf.P.copy()), nus.append(ukf.y.copy()), Ss.append(ukf.S.copy())
        lls.append(ukf.log_likelihood)  # FilterPy's logpdf(y, S) of the step
    for got, want in ((res.x, xs), (res.P, Ps), (res.innovation, nus), (res.S, Ss), (res.loglik, lls)):
        assert rel_err(got, np.array(want)) < SAME_FILTER_RTOL
    assert res.log_likelihood == pytest.approx(sum(lls), rel=SAME_FILTER_RTOL)


def test_ekf_equals_filterpy(track):
    _, ys = track
    f, h = cv_models()
    res = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.TT1()).filter(ys, X0)
    ekf = ExtendedKalmanFilter(4, 2)
    ekf.x, ekf.P, ekf.F, ekf.Q, ekf.R = X0.mean.copy(), X0.cov.copy(), F_CV, Q_CV, R_RB

    def H_jac(x):
        r2 = x[0] ** 2 + x[1] ** 2
        r = np.sqrt(r2)
        return np.array([[x[0] / r, x[1] / r, 0, 0], [-x[1] / r2, x[0] / r2, 0, 0]])

    xs, Ps, nus, lls = [], [], [], []
    for y in ys:
        ekf.predict()
        ekf.update(y, H_jac, hx, residual=residual_z)
        xs.append(ekf.x.copy()), Ps.append(ekf.P.copy()), nus.append(ekf.y.copy())
        lls.append(ekf.log_likelihood)
    for got, want in ((res.x, xs), (res.P, Ps), (res.innovation, nus), (res.loglik, lls)):
        assert rel_err(got, np.array(want)) < SAME_FILTER_RTOL


# --------------------------------------------------------------------------- angles
@pytest.fixture(scope="module")
def behind():
    """A target behind the sensor moving along the negative x axis: the bearing flips about ±π."""
    x0 = np.array([-30.0, 0.2, 0.5, 0.0])
    _, ys = simulate(x0, 10, seed=2)
    assert np.any(ys[:, 1] > 3.0) and np.any(ys[:, 1] < -3.0)
    return sm.Gaussian(x0, np.diag([1.0, 1.0, 0.1, 0.1])), ys


@pytest.mark.parametrize("transform", [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.UT.cubature(), sm.GaussHermite(3)],
                         ids=repr)
def test_bearing_across_pi_equals_rotated_sensor_frame(behind, transform):
    """Measured from a frame rotated by π/2 the bearing stays far from ±π; the states and
    covariances (the same coordinates) must not notice the difference."""
    x0, ys = behind
    phi = np.pi / 2
    f, h = cv_models(tag="_seam")
    fr, hr = cv_models(phi, tag="_rot")
    yr = ys.copy()
    yr[:, 1] = wrap(ys[:, 1] - phi)
    res = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, transform).filter(ys, x0)
    rot = sm.NonlinearKalmanFilter(fr, hr, Q_CV, R_RB, transform).filter(yr, x0)
    assert np.all(np.abs(yr[:, 1]) < 2.0)
    assert rel_err(res.x, rot.x) < SAME_FILTER_RTOL and rel_err(res.P, rot.P) < SAME_FILTER_RTOL
    np.testing.assert_allclose(res.innovation, rot.innovation, atol=SAME_FILTER_RTOL)
    # Undeclared, the bearing innovation jumps by 2π and the estimate runs away.
    _, raw = cv_models(angles=False, tag="_raw")
    off = sm.NonlinearKalmanFilter(f, raw, Q_CV, R_RB, transform).filter(ys, x0)
    assert np.max(np.abs(off.x - res.x)) > 1.0


@pytest.fixture(scope="module")
def heading():
    """A heading θ turning at rate ω, seen as a unit vector: θ passes ±π."""
    th, om = sp.symbols("theta omega", real=True)
    K = 12
    rng = np.random.default_rng(5)
    truth = np.column_stack([wrap(2.6 + 0.15 * np.arange(1, K + 1)), np.full(K, 0.15)])
    ys = np.column_stack([np.cos(truth[:, 0]), np.sin(truth[:, 0])]) + 0.05 * rng.standard_normal((K, 2))
    return th, om, truth, ys


@pytest.mark.parametrize("transform", [sm.TT1(), sm.UT.ut1(), sm.GaussHermite(3)], ids=repr)
def test_angle_state_across_pi_equals_shifted_state(heading, transform):
    """The heading state estimated through ±π equals that of the heading shifted by −π
    (which stays far from ±π), shifted back; ANEES/NEES wrap the heading error."""
    th, om, truth, ys = heading
    phi = np.pi
    Q, R = np.diag([1e-3, 1e-4]), 0.05**2 * np.eye(2)
    x0 = sm.Gaussian([2.6, 0.1], np.diag([0.05, 0.01]))
    f = sm.Model([th, om], [th + om, om], name="turn", angles=[0])
    h = sm.Model([th, om], [sp.cos(th), sp.sin(th)], name="unit")
    h_shift = sm.Model([th, om], [sp.cos(th + phi), sp.sin(th + phi)], name="unit_shift")
    res = sm.NonlinearKalmanFilter(f, h, Q, R, transform).filter(ys, x0)
    x0s = sm.Gaussian(x0.mean - [phi, 0.0], x0.cov)
    shifted = sm.NonlinearKalmanFilter(f, h_shift, Q, R, transform).filter(ys, x0s)
    assert np.all(np.abs(shifted.x[:, 0]) < 2.5) and np.ptp(res.x[:, 0]) > 6.0  # res wraps, shifted not
    np.testing.assert_allclose(wrap(res.x[:, 0] - phi - shifted.x[:, 0]), 0.0, atol=SAME_FILTER_RTOL)
    assert rel_err(res.P, shifted.P) < SAME_FILTER_RTOL
    truth_s = truth - [phi, 0.0]
    np.testing.assert_allclose(res.nees(truth), shifted.nees(truth_s), rtol=SAME_FILTER_RTOL)
    assert res.angle_states == (0,)


# --------------------------------------------------------------------------- general noise
@pytest.mark.parametrize("transform", [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.GaussHermite(3, sparse=False)], ids=repr)
def test_general_noise_equals_augmented_steps(track, transform):
    """Noise inside f and h: the compiled filter equals the augmented-state NLT steps of
    symmon.estimation (predict/update on [x; w] and [x; e], numpy transforms)."""
    _, ys = track
    px, py, vx, vy, a1, a2, er, eb = sp.symbols("px py vx vy a1 a2 e_r e_b", real=True)
    X = [px, py, vx, vy]
    f = sm.Model(X, [px + DT * vx + DT**2 / 2 * a1, py + DT * vy + DT**2 / 2 * a2, vx + DT * a1, vy + DT * a2],
                 noise=[a1, a2], name="cv_accel")
    h = sm.Model(X, [sp.sqrt(px**2 + py**2) * sp.exp(er), sp.atan2(py + 0.1 * eb * px, px) + eb],
                 noise=[er, eb], name="rb_general", angles=[1])
    assert h.structure == "general"
    Qw, Re = 0.05 * np.eye(2), np.diag([0.02**2, 0.02**2])
    ys = ys[:15]
    res = sm.NonlinearKalmanFilter(f, h, Qw, Re, transform).filter(ys, X0)
    x = X0
    for k, y in enumerate(ys):
        x = est.update(h, est.predict(f, x, Qw, transform), y, Re, transform)
        assert rel_err(res.x[k], x.mean) < SAME_FILTER_RTOL
        assert rel_err(res.P[k], x.cov) < SAME_FILTER_RTOL


@pytest.mark.parametrize("transform", [sm.TT2(), sm.GaussHermite(3), sm.GaussHermite(3, sparse=True)], ids=repr)
def test_additive_noise_equals_nlt_steps(track, transform):
    """Additive noise: the compiled filter equals estimation.predict/update step by step."""
    _, ys = track
    f, h = cv_models(tag="_steps")
    res = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, transform).filter(ys[:15], X0)
    x = X0
    for k, y in enumerate(ys[:15]):
        x = est.update(h, est.predict(f, x, Q_CV, transform), y, R_RB, transform)
        assert rel_err(res.x[k], x.mean) < SAME_FILTER_RTOL
        assert rel_err(res.P[k], x.cov) < SAME_FILTER_RTOL


# --------------------------------------------------------------------------- banks
@pytest.fixture(scope="module")
def bank():
    xs, ys = simulate(X0.mean, 25, seed=3, runs=6)
    return xs, ys


@pytest.mark.parametrize("transform", [sm.TT1(), sm.UT.ut1()], ids=repr)
def test_bank_equals_single_runs(bank, transform):
    _, ys = bank
    f, h = cv_models()
    nkf = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, transform)
    res = nkf.filter(ys, X0)
    assert res.x.shape == (6, 25, 4) and res.P.shape == (6, 25, 4, 4) and res.S.shape == (6, 25, 2, 2)
    means = X0.mean + np.arange(6)[:, None] * [0.5, -0.5, 0.0, 0.1]
    per_run = nkf.filter(ys, means, X0.cov)
    for r in range(6):
        one = nkf.filter(ys[r], X0)
        for name in ("x", "P", "x_pred", "P_pred", "innovation", "S"):
            np.testing.assert_allclose(getattr(res, name)[r], getattr(one, name), rtol=SAME_CODE_RTOL, atol=0)
        mine = nkf.filter(ys[r], sm.Gaussian(means[r], X0.cov))
        np.testing.assert_allclose(per_run.x[r], mine.x, rtol=SAME_CODE_RTOL, atol=0)
    assert res.estimate(3, run=2) == sm.Gaussian(res.x[2, 3], res.P[2, 3])


def test_compiled_step_equals_casadi_vm(bank):
    """The C run loop and CasADi's virtual machine (the fallback without a compiler)."""
    _, ys = bank
    f, h = cv_models()
    nkf = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.UT.ut1())
    step = compiled_step(f, h, nkf.transform, nkf.angle_states)
    assert step.is_compiled
    c = step(X0.mean, X0.cov, ys, Q_CV, R_RB)
    vm = step(X0.mean, X0.cov, ys, Q_CV, R_RB, use_c=False)
    for name in c:
        np.testing.assert_allclose(c[name], vm[name], rtol=SAME_CODE_RTOL, atol=1e-15)


def test_linear_kalman_filter_takes_a_gaussian_x0():
    """KalmanFilter.filter(ys, x0) with x0 a Gaussian, the NonlinearKalmanFilter signature."""
    kf = sm.KalmanFilter(F_CV, Q_CV, np.eye(2, 4), np.eye(2))
    ys = np.random.default_rng(0).standard_normal((5, 2))
    a, b = kf.filter(ys, X0), kf.filter(ys, X0.mean, X0.cov)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
    with pytest.raises(ShapeError, match="Gaussian, or its mean together with P0"):
        kf.filter(ys, X0, X0.cov)


# --------------------------------------------------------------------------- consistency
@pytest.fixture(scope="module")
def bank_result(bank):
    xs, ys = bank
    f, h = cv_models()
    return xs, sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.UT.cubature()).filter(ys, X0)


def test_nees_and_nis_equal_direct_computation(bank_result):
    xs, res = bank_result
    nees, nis = res.nees(xs), res.nis()
    assert nees.shape == nis.shape == (6, 25)
    for r in range(6):
        for k in range(25):
            e = xs[r, k] - res.x[r, k]
            assert nees[r, k] == pytest.approx(e @ np.linalg.inv(res.P[r, k]) @ e, rel=SAME_FILTER_RTOL)
            nu = res.innovation[r, k]
            assert nis[r, k] == pytest.approx(nu @ np.linalg.inv(res.S[r, k]) @ nu, rel=SAME_FILTER_RTOL)
    single = NonlinearKalmanResult(res.x[0], res.P[0], res.x_pred[0], res.P_pred[0], res.innovation[0], res.S[0])
    np.testing.assert_array_equal(single.nees(xs[0]), nees[0])


def test_chi2_bounds_equal_scipy(bank_result):
    """R runs at a step: R·ANEES ~ χ²(R n); one run over K steps: K·ANEES ~ χ²(K n)."""
    xs, res = bank_result
    t = res.anees(xs, confidence=0.99)
    assert t.value.shape == (25,) and t.dof == 6 * 4
    np.testing.assert_allclose(t.value, res.nees(xs).mean(axis=0), rtol=SAME_CODE_RTOL)
    assert (t.lower, t.upper) == pytest.approx(tuple(stats.chi2.ppf([0.005, 0.995], 24) / 6), rel=SAME_CODE_RTOL)
    np.testing.assert_array_equal(t.inside, (t.value >= t.lower) & (t.value <= t.upper))
    n = res.anis()
    assert n.dof == 6 * 2
    assert (n.lower, n.upper) == pytest.approx(tuple(stats.chi2.ppf([0.025, 0.975], 12) / 6), rel=SAME_CODE_RTOL)
    single = NonlinearKalmanResult(res.x[0], res.P[0], res.x_pred[0], res.P_pred[0], res.innovation[0], res.S[0])
    s = single.anis()
    assert s.value.shape == () and s.dof == 25 * 2
    assert s.value == pytest.approx(res.nis()[0].mean(), rel=SAME_CODE_RTOL)
    assert "CKF" in repr(res) and "runs=6" in repr(res) and "interval" in repr(t)


def test_linear_gaussian_bank_is_consistent():
    """On a linear-Gaussian model the filter is exact: E NEES = n and E NIS = n_y.  The
    per-run time averages are independent across runs; their mean is tested to 5 SE."""
    px, py, vx, vy = X = sp.symbols("px py vx vy", real=True)
    f = sm.Model(X, list(sp.Matrix(F_CV) * sp.Matrix(X)), name="cv_lin")
    h = sm.Model(X, [px, py], name="pos")
    R = np.diag([0.5, 0.3])
    kf = sm.KalmanFilter(F_CV, Q_CV, np.eye(2, 4), R)
    xs, ys = kf.simulate(30, X0.mean, np.random.default_rng(8), P0=X0.cov, runs=200)
    res = sm.NonlinearKalmanFilter(f, h, Q_CV, R, sm.UT.cubature()).filter(ys, X0)
    for stat, d in ((res.nees(xs), 4), (res.nis(), 2)):
        per_run = stat.mean(axis=1)
        assert abs(per_run.mean() - d) < 5 * per_run.std(ddof=1) / np.sqrt(per_run.size)
    assert np.mean(res.anees(xs).inside) > 0.8  # 95 % intervals, 30 steps


# --------------------------------------------------------------------------- errors
@pytest.fixture(scope="module")
def scalar_models():
    x = sp.Symbol("x", real=True)
    return sm.Model([x], [x], name="ident"), x


@pytest.mark.parametrize(
    "call, error, match",
    [
        (lambda m: sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]], sm.MonteCarlo(n=100)), SymmonError,
         "TT1, TT2, UT or GaussHermite"),
        (lambda m: sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]]).filter([[1.0]], sm.Gaussian([0.0], [[1.0]]), [[1.0]]),
         ShapeError, "P0 must not be given"),
        (lambda m: sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]]).filter([[1.0]], [0.0]), TypeError,
         "together with P0"),
        (lambda m: sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]]).filter(np.ones((3, 2, 1)), np.zeros((2, 1)), [[1.0]]),
         ShapeError, r"x0 has 2 runs \(its leading axis\) but ys has 3"),
        (lambda m: sm.NonlinearKalmanFilter(m, m, [[0.0]], [[0.0]], sm.TT1()).filter([[1.0], [2.0]], sm.Gaussian([0.0], [[0.0]])),
         SymmonError, "NaN or inf at step 0"),
        (lambda m: sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]]).filter([[1.0]], sm.Gaussian([0.0], [[1.0]])).nees([1.0]),
         ShapeError, "x_true must have the shape of x"),
        (lambda m: sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]]).filter([[1.0]], sm.Gaussian([0.0], [[1.0]])).anis(1.5),
         SymmonError, "confidence must lie in"),
    ],
)
def test_bad_inputs_raise_clear_errors(scalar_models, call, error, match):
    model, _ = scalar_models
    with pytest.raises(error, match=match):
        call(model)


def test_ekf_at_a_non_differentiable_point_raises():
    """The range's Jacobian is NaN at the origin (CasADi gives 0/0): an error, not a number."""
    f, h = cv_models()
    ekf = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.TT1())
    with pytest.raises(SymmonError, match=r"NaN or inf at run 1, step 0: the derivative of h 'rb', output 0 .* by px "
                                            r"is not finite .* a division by zero"):
        ekf.filter(np.ones((2, 3, 2)), np.array([[1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]]), np.eye(4))


def test_the_filters_have_one_home():
    assert sm.filters.NonlinearKalmanFilter is sm.NonlinearKalmanFilter
    assert sm.filters.NonlinearKalmanResult is NonlinearKalmanResult
    assert not hasattr(sm.estimation, "NonlinearKalmanFilter")  # no alias left in estimation


# --------------------------------------------------------------------------- adaptive
def linear_models():
    """Constant velocity observed in position: f and h linear."""
    px, py, vx, vy = sp.symbols("px py vx vy", real=True)
    X = [px, py, vx, vy]
    return (sm.Model(X, list(sp.Matrix(F_CV) * sp.Matrix(X)), name="cv_lin"),
            sm.Model(X, [px, py], name="pos_lin"))


def test_adaptive_on_a_linear_model_picks_the_ekf_at_every_step(bank):
    f, h = linear_models()
    X, _ = bank
    rng = np.random.default_rng(3)
    ys = X[..., :2] + rng.standard_normal(X[..., :2].shape) * 0.5
    R = 0.25 * np.eye(2)
    res = sm.NonlinearKalmanFilter(f, h, Q_CV, R, sm.Adaptive(tol=1e-6)).filter(ys, X0)
    ekf = sm.NonlinearKalmanFilter(f, h, Q_CV, R, sm.TT1()).filter(ys, X0)
    assert res.choices.shape == ys.shape[:2]
    assert set(res.choices.ravel()) == {"EKF"}
    # The same compiled EKF step on the same numbers, one step per call.
    assert rel_err(res.x, ekf.x) < SAME_CODE_RTOL and rel_err(res.P, ekf.P) < SAME_CODE_RTOL


def test_adaptive_on_a_strongly_nonlinear_prior_leaves_the_taylor_filters():
    # Range and bearing of a target 3 m away with a 10 m position uncertainty: the range
    # and bearing are far from linear over the prior.
    f, h = cv_models()
    x0 = sm.Gaussian([3.0, 0.0, 0.0, 0.0], np.diag([100.0, 100.0, 0.1, 0.1]))
    res = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.Adaptive(tol=1e-2)).filter([[3.1, 0.05]], x0)
    assert res.choices.shape == (1,)
    assert res.choices[0] not in ("EKF", "EKF2")


def test_adaptive_bank_decides_per_run_as_single_runs(bank):
    # A near and a far start: the runs of a bank decide independently, each on its own prior.
    f, h = cv_models()
    _, ys = bank
    means = np.array([[3.0, 1.0, -0.2, 0.1], [200.0, 50.0, -1.0, 0.5]])
    P0 = np.diag([4.0, 4.0, 0.1, 0.1])
    kf = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.Adaptive(tol=1e-2))
    both = kf.filter(ys[:2], means, P0)
    assert both.choices.shape == (2, ys.shape[1])
    for r in range(2):
        one = kf.filter(ys[r], means[r], P0)
        assert one.choices.shape == (ys.shape[1],)
        np.testing.assert_array_equal(both.choices[r], one.choices)
        assert rel_err(both.x[r], one.x) < SAME_CODE_RTOL
    assert set(both.choices[0]) != set(both.choices[1])
    assert "Adaptive(tol=0.01" in both.method


def test_bank_takes_one_initial_covariance_per_run(bank):
    f, h = cv_models()
    _, ys = bank
    P0s = np.stack([np.diag([1.0, 1.0, 0.1, 0.1]), np.diag([9.0, 4.0, 0.2, 0.3])])
    kf = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.UT.cubature())
    both = kf.filter(ys[:2], X0.mean, P0s)
    for r in range(2):
        assert rel_err(both.P[r], kf.filter(ys[r], X0.mean, P0s[r]).P) < SAME_CODE_RTOL


def test_per_run_initial_covariances_are_made_symmetric_as_a_shared_one(bank):
    """An asymmetry within rounding (accepted, as by Gaussian) is removed from each run's P0,
    as from a shared P0: the run filtered alone and in the bank agree to the bit."""
    f, h = cv_models()
    _, ys = bank
    P0 = np.array([[1.0, 0.3, 0, 0], [0.3, 1.0, 0, 0], [0, 0, 0.1, 0], [0, 0, 0, 0.1]])
    P0[0, 1] += 1e-15  # 3e-15 relative: within SYMMETRY_RTOL
    kf = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.TT1())
    both = kf.filter(ys[:2], X0.mean, np.stack([P0, P0]))
    np.testing.assert_array_equal(both.P[1], kf.filter(ys[1], X0.mean, P0).P)


@pytest.mark.parametrize("kwargs, match", [({"tol": 0.0}, "tol"), ({"tol": True}, "tol"),
                                           ({"candidates": ()}, "empty"),
                                           ({"candidates": (sm.MonteCarlo(1000),)}, "TT1, TT2, UT")])
def test_adaptive_bad_options(kwargs, match):
    with pytest.raises(SymmonError, match=match):
        sm.Adaptive(**kwargs)


# --------------------------------------------------------------------------- scenario files, symmon filter
from symmon.cli import parser as cli  # noqa: E402
from symmon.files.filterfile import load_filter_file, run_bank, simulate as simulate_spec  # noqa: E402
from symmon.files.modelfile import ModelFileError  # noqa: E402

from helpers import EXAMPLES  # noqa: E402

EXAMPLE = EXAMPLES / "rb_close.toml"
SCENARIO = """
name = "lin"
states = ["p", "v"]
dynamics = ["p + T*v", "v"]
measurements = ["p"]
steps = 30
[params]
T = 0.5
[Q]
cov = [["0.01*T**3/3", "0.01*T**2/2"], ["0.01*T**2/2", "0.01*T"]]
[R]
std = [0.3]
[x0]
mean = [0, 1]
std = [1, 0.5]
"""


def test_scenario_file_is_read_into_models_and_covariances(tmp_path):
    path = tmp_path / "lin.toml"
    path.write_text(SCENARIO)
    spec = load_filter_file(path)
    p, v = spec.f.inputs
    assert spec.f.outputs == (p + 0.5 * v, v) and spec.h.outputs == (p,)
    np.testing.assert_allclose(spec.Q, 0.01 * np.array([[0.5**3 / 3, 0.5**2 / 2], [0.5**2 / 2, 0.5]]), rtol=1e-15)
    assert spec.R.tolist() == [[0.09]] and spec.steps == 30
    assert spec.x0 == sm.Gaussian([0.0, 1.0], np.diag([1.0, 0.25]))
    rb = load_filter_file(EXAMPLE)
    assert rb.h.angle_outputs == frozenset({1})


def test_simulated_linear_bank_is_consistent(tmp_path):
    """The scenario's simulation and a linear Kalman filter: mean NEES n and NIS n_y within
    5 standard errors (the run averages are independent, ~χ²(n)/n per step)."""
    path = tmp_path / "lin.toml"
    path.write_text(SCENARIO)
    spec = load_filter_file(path)
    runs = 200
    xs, ys = simulate_spec(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, runs, seed=4)
    (row,) = run_bank(spec.f, spec.h, spec.Q, spec.R, spec.x0, xs, ys, ["ekf"])
    nees, nis = row.result.nees(xs), row.result.nis()
    for stat, d in ((nees, 2), (nis, 1)):
        per_run = stat.mean(axis=1)  # independent across runs
        assert abs(per_run.mean() - d) < 5 * per_run.std(ddof=1) / np.sqrt(runs)
    np.testing.assert_allclose(row.rmse, np.sqrt(np.mean((xs - row.result.x) ** 2, axis=0)), rtol=1e-12)


@pytest.mark.parametrize("edit, match", [
    (("steps = 30", "steps = 0"), "steps"),
    (('dynamics = ["p + T*v", "v"]', 'dynamics = ["p + T*v"]'), "one expression per state"),
    (('measurements = ["p"]', 'measurements = ["__import__(1)"]'), "measurements"),
    (("[R]\nstd = [0.3]", "[R]\nmean = [0]\nstd = [0.3]"), "not a mean"),
    (('name = "lin"', 'name = "lin"\nangles = [3]'), "angles"),
])
def test_bad_scenario_files_name_the_fault(tmp_path, edit, match):
    path = tmp_path / "bad.toml"
    path.write_text(SCENARIO.replace(*edit))
    with pytest.raises(ModelFileError, match=match):
        load_filter_file(path)


def test_cli_filter_prints_consistency_and_writes_the_plot(capsys, tmp_path):
    png = tmp_path / "nees.png"
    code = cli.main(["filter", str(EXAMPLE), "--runs", "20", "--filters", "ekf,ukf,adaptive", "--plot", str(png)])
    out = capsys.readouterr().out
    assert code == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "ANEES" in out and "ekf" in out and "adaptive" in out and f"wrote {png}" in out
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_cli_filter_json_equals_the_api(capsys):
    import json

    assert cli.main(["filter", str(EXAMPLE), "--runs", "10", "--seed", "2", "--filters", "ukf", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    spec = load_filter_file(EXAMPLE)
    xs, ys = simulate_spec(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, 10, seed=2)
    res = sm.NonlinearKalmanFilter(spec.f, spec.h, spec.Q, spec.R, sm.UT.ut1()).filter(ys, spec.x0)
    (row,) = out["filters"]
    np.testing.assert_allclose(row["anees"], res.anees(xs).value, rtol=1e-12)
    np.testing.assert_allclose(row["anis"], res.anis().value, rtol=1e-12)
    assert out["runs"] == 10 and out["steps"] == spec.steps


def test_cli_filter_smooth_reports_the_smoother_as_the_api(capsys, tmp_path):
    import json

    assert cli.main(["filter", str(EXAMPLE), "--runs", "10", "--seed", "2", "--filters", "ekf,adaptive",
                     "--smooth", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    spec = load_filter_file(EXAMPLE)
    xs, ys = simulate_spec(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, 10, seed=2)
    sres = sm.NonlinearKalmanFilter(spec.f, spec.h, spec.Q, spec.R, sm.TT1()).smooth(ys, spec.x0)
    ekf, adaptive = out["filters"]
    np.testing.assert_allclose(ekf["smoothed"]["anees"], sres.anees(xs).value, rtol=1e-12)
    rmse = np.sqrt(np.mean((xs - sres.x) ** 2, axis=0))
    np.testing.assert_allclose(ekf["smoothed"]["rmse"], rmse, rtol=1e-12)
    assert np.mean(rmse) < np.mean(ekf["rmse"]) and "smoothed" not in adaptive
    png = tmp_path / "s.png"
    assert cli.main(["filter", str(EXAMPLE), "--runs", "5", "--filters", "ukf,adaptive", "--smooth",
                     "--plot", str(png)]) == 0
    text = capsys.readouterr().out
    assert " smoothed" in text and "no RTS smoother for the adaptive filter" in text and png.exists()


@pytest.mark.parametrize("argv, match", [(["--filters", "ekf,foo"], "must be distinct filters"),
                                         (["--runs", "0"], "positive integer"),
                                         (["--tol", "1.5"], "number in \\(0, 1\\)"),
                                         (["--seed", "-1"], "must be an integer >= 0")])
def test_cli_filter_bad_options_are_usage_errors(capsys, argv, match):
    assert cli.main(["filter", str(EXAMPLE), *argv]) == 2
    assert __import__("re").search(match, capsys.readouterr().err)


def test_adaptive_distance_is_the_unitless_error_of_advise():
    """The batched distance of the adaptive rule equals sm.advise's moment_error."""
    from symmon.measures.advice import moment_distance, moment_error, whiteners
    from symmon.compile import compiled

    _, h = cv_models()
    u = sm.Gaussian([3.0, 1.0, -0.5, 0.2], np.diag([4.0, 9.0, 0.1, 0.2]) + 0.5)
    a, b = sm.propagate(h, u, None, transform=sm.UT.cubature()), sm.propagate(h, u, None, transform=sm.GaussHermite(5))
    cm, angles = compiled(h), frozenset(h.angle_outputs)
    ba = sm.UT.cubature().moments(cm, u.mean[None], u.cov[None], angles)
    bb = sm.GaussHermite(5).moments(cm, u.mean[None], u.cov[None], angles)
    d = moment_distance(ba, bb, whiteners(bb.cov), whiteners(u.cov[None]), angles)[0]
    assert d == pytest.approx(moment_error(a, b), rel=1e-10)


# --------------------------------------------------------------------------- strategies
def test_a_transform_becomes_the_one_rule_strategy_and_any_strategy_runs_the_filter():
    """The filter runs whatever FilterStrategy it is given; a transform is wrapped in RuleStrategy."""
    x = sp.Symbol("x", real=True)
    f, h = sm.Model([x], [x], name="strategy_f"), sm.Model([x], [x], name="strategy_h")
    ekf = sm.NonlinearKalmanFilter(f, h, [[1.0]], [[1.0]], sm.TT1())
    assert ekf.strategy == sm.filters.RuleStrategy(sm.TT1()) and ekf.method == "EKF"

    class Traced(sm.filters.FilterStrategy):
        calls = 0

        def label(self):
            return "traced EKF"

        def run(self, kf, Y, x0, P0, keep=None):
            Traced.calls += 1
            return sm.filters.RuleStrategy(sm.TT1()).run(kf, Y, x0, P0, keep)

    kf = sm.NonlinearKalmanFilter(f, h, [[1.0]], [[1.0]], Traced())
    res = kf.filter([[1.0]], sm.Gaussian([0.0], [[1.0]]))
    assert Traced.calls == 1 and res.method == "traced EKF"
    np.testing.assert_array_equal(res.x, ekf.filter([[1.0]], sm.Gaussian([0.0], [[1.0]])).x)


def test_a_rule_without_a_filter_step_is_refused():
    x = sp.Symbol("x", real=True)
    m = sm.Model([x], [x], name="strategy_mc")
    with pytest.raises(SymmonError, match="a Taylor or point rule"):
        sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]], sm.MonteCarlo(100))
    with pytest.raises(TypeError, match="transform or a filter strategy"):
        sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]], 3)
    with pytest.raises(SymmonError, match="unknown filter or rule 'kalman'"):
        sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]], "kalman")
    # a filter's name is its rule (issue 47, item 11)
    assert sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]], "ukf").transform == sm.UT.ut1()


# --------------------------------------------------------------------------- the MX step
@pytest.mark.parametrize("transform", [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.GaussHermite(3, sparse=False)], ids=repr)
def test_the_mx_step_equals_the_sx_step(transform, monkeypatch):
    """From MX_FROM variables on the step is built in MX (loops in C, the blocked Cholesky
    factor); it computes what the unrolled SX step computes, up to rounding."""
    from symmon.codegen import symbolic
    from symmon.filters.gaussian import step

    T = 1 if isinstance(transform, sm.GaussHermite) else 3  # GH3 on 9 states would be 3^11 points
    xs, fo, ho, angles = [], [], [], []
    for t in range(T):
        px, py, th = sp.symbols(f"px{t} py{t} th{t}", real=True)
        xs += [px, py, th]
        fo += [px + 0.1 * sp.cos(th), py + 0.1 * sp.sin(th), th + 0.05]
        ho += [sp.sqrt(px**2 + py**2), sp.atan2(py, px)]
        angles.append(2 * t + 1)
    n = 3 * T
    e = sp.symbols(f"e0:{2 * T}", real=True)  # general noise in h: e multiplies the range
    f = sm.Model(xs, fo, name=f"mxstep_f{T}", angles=[xs[3 * t + 2] for t in range(T)])
    h = sm.Model(xs, [ho[i] * (1 + e[i]) if i % 2 == 0 else ho[i] + e[i] for i in range(2 * T)], noise=e,
                 name=f"mxstep_h{T}", angles=angles)
    states = frozenset(range(2, n, 3))
    rng = np.random.default_rng(5)
    x = np.tile([3.0, 4.0, 0.3], T) + 0.1 * rng.standard_normal(n)
    A = rng.standard_normal((n, n))
    P = 0.01 * (A @ A.T) + 0.05 * np.eye(n)
    y = np.tile([5.1, 0.9], T)
    Q, R = 1e-3 * np.eye(n), np.diag(np.tile([1e-4, 1e-4], T))
    monkeypatch.setattr(symbolic, "MX_FROM", 1)
    mx = step._step_function(f, h, transform, states, "mxstep_mx")
    monkeypatch.setattr(symbolic, "MX_FROM", 10**6)
    monkeypatch.setattr(symbolic, "MAX_SX_POINTS", 10**6)
    sx = step._step_function(f, h, transform, states, "mxstep_sx")
    assert isinstance(mx.mx_in(0), ca.MX) and mx.is_a("MXFunction") and sx.is_a("SXFunction")
    ones = np.ones(len(y))
    for a, b in zip(mx(x, P, y, Q, R, ones, []), sx(x, P, y, Q, R, ones, [])):
        a, b = a.full(), b.full()
        assert np.max(np.abs(a - b)) <= 1e-12 * max(1.0, np.max(np.abs(b)))


def test_a_rule_is_checked_at_the_filter_dimensions_not_at_one():
    """FilterPy's kappa = 3 - n on 4 states (kappa = -1) is a valid UT there; on 1 state it
    is not, and the filter says so when it is made."""
    xs = sp.symbols("a b c d", real=True)
    f, h = sm.Model(list(xs), list(xs), name="dims_f"), sm.Model(list(xs), [xs[0] ** 2, xs[1]], name="dims_h")
    ut = sm.UT(alpha=1, beta=2, kappa=-1)
    kf = sm.NonlinearKalmanFilter(f, h, np.eye(4), np.eye(2), ut)
    assert kf.dimensions == (4, 4)
    assert np.isfinite(kf.filter(np.ones((3, 2)), sm.Gaussian(np.zeros(4), np.eye(4))).x).all()
    one = sm.Model([xs[0]], [xs[0]], name="dims_1")
    with pytest.raises(SymmonError, match="n \\+ lambda = 0 <= 0 for n = 1"):
        sm.NonlinearKalmanFilter(one, one, [[1.0]], [[1.0]], ut)
    with pytest.raises(SymmonError, match="for n = 1"):
        sm.NonlinearKalmanFilter(one, one, [[1.0]], [[1.0]], sm.Adaptive(candidates=(sm.TT1(), ut)))


def test_a_rule_with_many_points_is_built_in_mx_at_any_size():
    """Gauss–Hermite of order 10 on 4 states (10⁴ points): one map in MX, not 10⁴ unrolled
    copies of h (that SX step ran gcc for minutes)."""
    from symmon.filters.gaussian import step

    xs = sp.symbols("px py vx vy", real=True)
    f = sm.Model(list(xs), [xs[0] + 0.5 * xs[2], xs[1] + 0.5 * xs[3], xs[2], xs[3]], name="gh10_f")
    h = sm.Model(list(xs), [sp.sqrt(xs[0] ** 2 + xs[1] ** 2), sp.atan2(xs[1], xs[0])], name="gh10_h", angles=[1])
    assert step._step_function(f, h, sm.GaussHermite(10), frozenset(), "gh10_step").is_a("MXFunction")
    assert step._step_function(f, h, sm.UT.ut1(), frozenset(), "ut_step").is_a("SXFunction")



def test_the_log_likelihood_of_a_bank_is_per_run_and_of_the_linear_filter_its_closed_form():
    """A bank's log-likelihood is one per run, equal to each run filtered alone; on a linear
    model every nonlinear filter's equals the linear Kalman filter's (closed form)."""
    x = sp.symbols("p v", real=True)
    F, H = np.array([[1.0, 0.5], [0.0, 1.0]]), np.array([[1.0, 0.0]])
    f = sm.Model(list(x), list(sp.Matrix(F) * sp.Matrix(x)), name="ll_f")
    h = sm.Model(list(x), [x[0]], name="ll_h")
    Q, R = 0.1 * np.eye(2), np.array([[0.5]])
    kf = sm.KalmanFilter(F, Q, H, R)
    _, ys = kf.simulate(8, np.zeros(2), np.random.default_rng(2), P0=np.eye(2), runs=3)
    ref = kf.filter(ys, np.zeros(2), np.eye(2))
    for transform in (sm.TT1(), sm.UT.ut1(), sm.GaussHermite(3)):
        bank = sm.NonlinearKalmanFilter(f, h, Q, R, transform).filter(ys, np.zeros(2), np.eye(2))
        assert bank.log_likelihood.shape == (3,)
        np.testing.assert_allclose(bank.log_likelihood, ref.log_likelihood, rtol=1e-10)
        single = sm.NonlinearKalmanFilter(f, h, Q, R, transform).filter(ys[1], np.zeros(2), np.eye(2))
        assert single.log_likelihood == pytest.approx(float(bank.log_likelihood[1]), rel=1e-12)
    # The closed form: −½ Σ (νᵀS⁻¹ν + log det 2πS), with the linear filter's own ν and S.
    nu, S = ref.innovation[0], ref.S
    want = -0.5 * sum(float(n @ np.linalg.solve(s, n)) + np.log(np.linalg.det(2 * np.pi * s)) for n, s in zip(nu, S))
    assert float(ref.log_likelihood[0]) == pytest.approx(want, rel=1e-12)



def test_the_nis_computed_in_the_step_equals_the_one_from_the_innovations(bank):
    """keep=("nis",): the bank's NIS test without storing ν and S (the step computes νᵀS⁻¹ν)."""
    _, ys = bank
    f, h = cv_models()
    kf = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.UT.ut1())
    full = kf.filter(ys, X0)
    lean = kf.filter(ys, X0, keep=("nis",))
    assert lean.innovation is None and lean.S is None and lean.x is None
    np.testing.assert_allclose(lean.nis(), quadratic_forms(full.innovation, full.S), rtol=1e-10)
    np.testing.assert_allclose(lean.anis().value, full.anis().value, rtol=1e-10)
    assert lean.anis().dof == full.anis().dof
    lin = sm.KalmanFilter(np.eye(2), np.eye(2), np.eye(2), np.eye(2))
    a, b = lin.filter(np.ones((3, 2)), np.zeros(2), np.eye(2)), lin.filter(np.ones((3, 2)), np.zeros(2), np.eye(2),
                                                                           keep=("nis",))
    np.testing.assert_allclose(b.nis(), quadratic_forms(a.innovation, a.S), rtol=1e-12)
    assert b.anis().dof == a.anis().dof


@pytest.mark.parametrize("keep", [("x", "P"), ("x",), ("innovation", "S"), ()])
def test_a_bank_keeps_only_what_is_asked_and_the_numbers_do_not_change(bank, keep):
    """keep= stores only the named arrays (the compiled loop writes the others to one slot):
    the kept ones, the log-likelihood and a failure's report are those of the full run."""
    _, ys = bank
    f, h = cv_models()
    kf = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.UT.ut1())
    full = kf.filter(ys, X0)
    part = kf.filter(ys, X0, keep=keep)
    for k in ("x", "P", "x_pred", "P_pred", "innovation", "S"):
        if k in keep:
            np.testing.assert_array_equal(getattr(part, k), getattr(full, k))
        else:
            assert getattr(part, k) is None
    np.testing.assert_array_equal(part.log_likelihood, full.log_likelihood)
    assert part.runs == full.runs and part.steps == full.steps
    if "x" not in keep:
        with pytest.raises(SymmonError, match="does not hold x"):
            part.nees(full.x)
    linear = sm.KalmanFilter(np.eye(2), np.eye(2), np.eye(2), np.eye(2)).filter(np.ones((3, 2)), np.zeros(2), np.eye(2),
                                                                                keep=keep)
    assert all((getattr(linear, k) is None) == (k not in keep) for k in ("x", "P", "S"))


def test_keep_names_are_checked():
    x = sp.Symbol("x", real=True)
    m = sm.Model([x], [x], name="keep_m")
    kf = sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]], sm.TT1())
    with pytest.raises(SymmonError, match=r"keep names \['gain'\]"):
        kf.filter([[1.0]], sm.Gaussian([0.0], [[1.0]]), keep=("x", "gain"))
    # A string is one name (issue 47, item 8), never its letters.
    assert kf.filter([[1.0]], sm.Gaussian([0.0], [[1.0]]), keep="x").P is None
    with pytest.raises(SymmonError, match=r"keep names \['xP'\]"):
        kf.filter([[1.0]], sm.Gaussian([0.0], [[1.0]]), keep="xP")


@pytest.mark.parametrize("keep", [None, ("x",)])
def test_a_bank_split_over_threads_equals_one_call(bank, keep, monkeypatch):
    """The runs of a bank split over threads (the GIL is released in the C call) give the
    numbers of one call bit for bit, kept arrays and log-likelihoods alike."""
    from symmon.filters.gaussian import step

    _, ys = bank
    f, h = cv_models()
    kf = sm.NonlinearKalmanFilter(f, h, Q_CV, R_RB, sm.UT.ut1())
    monkeypatch.setattr(step, "MIN_WORK_PER_THREAD", 10**18)
    one = kf.filter(ys, X0, keep=keep)
    monkeypatch.setattr(step, "MIN_WORK_PER_THREAD", 1)
    monkeypatch.setattr(step, "cpu_count", lambda: 4)
    assert len(step.chunk_runs(6, 25, 4)) == 4
    split = kf.filter(ys, X0, keep=keep)
    for k in ("x", "P", "loglik"):
        a, b = getattr(one, k), getattr(split, k)
        assert (a is None and b is None) or np.array_equal(a, b), k


def test_complex_measurements_and_a_singular_covariance_are_clear_errors():
    """Complex ys are refused, not cast to their real part; NEES on a singular P is a named error."""
    x = sp.Symbol("x", real=True)
    m = sm.Model([x], [x], name="clear_m")
    ekf = sm.NonlinearKalmanFilter(m, m, [[1.0]], [[1.0]], sm.TT1())
    with pytest.raises(ShapeError, match="complex"):
        ekf.filter(np.array([[1.0 + 2.0j]]), sm.Gaussian([0.0], [[1.0]]))
    with pytest.raises(ShapeError, match="real numbers"):
        ekf.filter([["a"]], sm.Gaussian([0.0], [[1.0]]))
    with pytest.raises(ShapeError, match="complex"):
        sm.KalmanFilter(np.eye(1), np.eye(1), np.eye(1), np.eye(1)).filter(np.ones((2, 1)) * 1j, np.zeros(1), np.eye(1))
    known = sm.KalmanFilter(np.eye(1), np.zeros((1, 1)), np.eye(1), np.eye(1)).filter(np.ones((2, 1)), np.zeros(1),
                                                                                    np.zeros((1, 1)))
    with pytest.raises(sm.errors.SingularMatrixError, match="singular"):
        known.nees(np.zeros((2, 1)))
