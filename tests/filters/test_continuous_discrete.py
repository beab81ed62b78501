"""The continuous-discrete Gaussian filters (issue 50, item 3): the moment ODEs of an SDE between
measurement times, against what does not share their approximation.

- Linear SDE: the CD filter is the Kalman filter of the exact discretisation (Van Loan in
  closed form), to the integrator's tolerance, with irregular times, a missing measurement and
  a bank; its log-likelihood likewise.
- Nonlinear SDE: one interval of the moment ODEs equals the same equations, written here in
  plain numpy, solved by ``scipy.integrate.solve_ivp`` at rtol 1e-12.
- Validation, a stiff and a diverging drift (a clear error, bounded work), the registry.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import scipy.integrate
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentError, ArgumentTypeError, CovarianceError, ModelError, ShapeError, SymmonError
from symmon.filters.registry import filter_entry, filter_names, make_filter

p, v = sp.symbols("p v", real=True)
q = sp.Symbol("q", positive=True)
theta = sp.Symbol("theta", positive=True)
#: A position with an Ornstein–Uhlenbeck velocity: dp = v dt, dv = −θ v dt + dβ, E dβ² = q dt.
#: Its moments are exponentials in t, which an explicit Runge–Kutta method does not integrate
#: exactly (white-noise acceleration would be: its moments are cubic polynomials of t).
IOU = sm.SDE([p, v], [v, -theta * v], diffusion=[0, 1], spectral_density=q, params=[q, theta], name="iou")
H = sm.Model([p, v], [p], name="cd_h")
R = np.array([[4.0]])
X0 = sm.Gaussian([0.0, 10.0], np.diag([25.0, 4.0]))
STEPS = np.random.default_rng(0).uniform(0.2, 3.0, size=25)  # irregular intervals t_k − t_{k−1}
PARAMS = {"q": 0.5, "theta": 0.7, "dt": STEPS}


@pytest.fixture(scope="module")
def exact():
    """The exact discretisation, simulated data with a missing measurement, and the Kalman
    filter of the discretised model (its EKF is exact: the model is linear in x and w)."""
    f = IOU.discretize("exact")
    xs, ys = sm.simulate(f, H, np.eye(f.n_v), R, X0, steps=len(STEPS), params=PARAMS, runs=3, seed=4)
    ys = np.array(ys)
    ys[1, 6] = np.nan
    kf = sm.NonlinearKalmanFilter(f, H, np.eye(f.n_v), R, "ekf")
    return f, np.asarray(xs), ys, kf.filter(ys, X0, params=PARAMS, x_true=xs)


@pytest.mark.parametrize("transform", ["ekf", "ckf", "ukf", "ghkf"])
def test_on_a_linear_sde_it_is_the_kalman_filter_of_the_exact_discretisation(exact, transform):
    """To the integrator's tolerance: solve_ivp keeps each interval's local error below
    rtol·|z| + atol per component (atol = rtol/1000 here, below every moment's scale), and the
    filter's recursion forgets old errors, so the errors of 25 intervals stay of the order of
    rtol relative to each array's scale.  Measured (x, P, P⁻, log-likelihood, relative to
    their largest entry): 0.8e-10, 8e-10, 1.6e-10, 1.2e-10 at rtol 1e-8, and 100 000 times
    more at rtol 1e-3, for every rule.  The test allows 10·rtol, and checks that the same
    comparison fails at rtol = 1e-3 (the tolerance is what sets the agreement)."""
    _, xs, ys, ref = exact
    cd = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, transform, rtol=1e-8, atol=1e-11)
    res = cd.filter(ys, X0, params=PARAMS, x_true=xs)
    tol = 10 * cd.rtol
    for name in ("x", "P", "x_pred", "P_pred", "innovation", "S"):
        a, b = getattr(res, name), getattr(ref, name)
        assert np.abs(a - b).max() <= tol * np.abs(b).max(), name
    np.testing.assert_allclose(res.loglik, ref.loglik, rtol=0, atol=tol * np.abs(ref.loglik).max())
    np.testing.assert_allclose(res.nees_values, ref.nees_values, rtol=tol, atol=tol)
    assert res.loglik[1, 6] == 0.0 and np.array_equal(res.measured, ref.measured)
    coarse = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, transform, rtol=1e-3, atol=1e-6)
    err = np.abs(coarse.filter(ys, X0, params=PARAMS).x - ref.x).max()
    assert err > tol * np.abs(ref.x).max()


def test_a_bank_is_its_runs_filtered_alone(exact):
    _, xs, ys, _ = exact
    cd = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, "ckf")
    bank = cd.filter(ys, X0, params=PARAMS)
    for r in range(ys.shape[0]):
        one = cd.filter(ys[r], X0, params=PARAMS)
        np.testing.assert_array_equal(one.x, bank.x[r])
        np.testing.assert_array_equal(one.loglik, bank.loglik[r])


@pytest.mark.parametrize("t0", [0.0, 1000.0])
def test_irregular_times_after_t0_are_the_kalman_filter_of_their_intervals(exact, t0):
    """times=t0 + cumsum(STEPS): the intervals of the exact discretisation's dt up to the
    rounding of the sums (an ulp of t: 2.3e-13 at t0 = 1000, 1e-12 of the shortest interval),
    far below the integrator's tolerance; so the filter agrees with the Kalman filter of the exact
    discretisation as the dt route does, and its numbers are the dt route's on the same
    intervals bit for bit.  The SDE is time-invariant: t0 shifts nothing."""
    _, xs, ys, ref = exact
    cd = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, "ckf", rtol=1e-8, atol=1e-11)
    times = t0 + np.cumsum(STEPS)
    res = cd.filter(ys, X0, params={"q": 0.5, "theta": 0.7}, x_true=xs, times=times, t0=t0)
    tol = 10 * cd.rtol
    for name in ("x", "P", "x_pred", "P_pred"):
        a, b = getattr(res, name), getattr(ref, name)
        assert np.abs(a - b).max() <= tol * np.abs(b).max(), name
    np.testing.assert_allclose(res.loglik, ref.loglik, rtol=0, atol=tol * np.abs(ref.loglik).max())
    same = cd.filter(ys, X0, params={"q": 0.5, "theta": 0.7, "dt": np.diff(times, prepend=t0)}, x_true=xs)
    for name in ("x", "P", "loglik", "nees_values"):
        np.testing.assert_array_equal(getattr(res, name), getattr(same, name))


def test_each_run_of_a_bank_takes_its_own_times():
    cd = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, "ekf")
    ys = np.array([[[1.0], [2.0], [3.0]], [[1.0], [2.0], [3.0]]])
    times = np.array([[0.5, 1.5, 1.75], [0.5, 1.0, 1.25]])
    bank = cd.filter(ys, X0, params={"q": 0.5, "theta": 0.7}, times=times, t0=-0.5)
    for r in range(2):
        one = cd.filter(ys[r], X0, params={"q": 0.5, "theta": 0.7}, times=times[r], t0=-0.5)
        np.testing.assert_array_equal(one.x, bank.x[r])
    assert not np.allclose(bank.x[0, 1], bank.x[1, 1])
    m, P = cd.predict(X0.mean, X0.cov, 1.0, [0.5, 0.7])  # the first interval: 0.5 − (−0.5)
    np.testing.assert_allclose(m, bank.x_pred[0, 0], rtol=1e-12)
    np.testing.assert_allclose(P, bank.P_pred[0, 0], rtol=1e-12)


def test_per_run_intervals_and_a_missing_row_only_predicts():
    cd = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, "ekf")
    ys = np.array([[[1.0], [np.nan], [3.0]], [[1.0], [np.nan], [3.0]]])
    dts = np.array([[0.5, 1.0, 0.25], [0.5, 0.5, 0.25]])
    res = cd.filter(ys, X0, params={"q": 0.5, "theta": 0.7, "dt": dts})
    np.testing.assert_array_equal(res.x[:, 1], res.x_pred[:, 1])
    assert np.all(res.loglik[:, 1] == 0.0)
    assert not np.allclose(res.x_pred[0, 2], res.x_pred[1, 2])  # the runs' own intervals
    m, P = cd.predict(res.x[0, 0], res.P[0, 0], 1.0, [0.5, 0.7])
    np.testing.assert_allclose(m, res.x_pred[0, 1], rtol=1e-12)
    np.testing.assert_allclose(P, res.P_pred[0, 1], rtol=1e-12)


# ------------------------------------------------------------------ nonlinear: one interval
x1, x2 = sp.symbols("x1 x2", real=True)
MU, SIGMA = 1.5, 0.4
#: Van der Pol with a state-dependent diffusion: E[L Q_c Lᵀ] is not L Q_c Lᵀ at the mean.
VDP = sm.SDE([x1, x2], [x2, MU * (1 - x1**2) * x2 - x1], diffusion=[0, SIGMA * (1 + x1**2 / 4)], name="vdp")


def _vdp_drift(x):
    return np.array([x[..., 1], MU * (1 - x[..., 0] ** 2) * x[..., 1] - x[..., 0]]).T


def _vdp_jacobian(x):
    return np.array([[0.0, 1.0], [-2 * MU * x[0] * x[1] - 1.0, MU * (1 - x[0] ** 2)]])


def _vdp_noise(x):
    """L Q_c Lᵀ at each point (Q_c = 1): only the (1, 1) entry."""
    out = np.zeros(np.shape(x)[:-1] + (2, 2))
    out[..., 1, 1] = (SIGMA * (1 + x[..., 0] ** 2 / 4)) ** 2
    return out


def _reference_rhs(rule):
    """The moment equations in plain numpy: TT1 (the CD-EKF), or the sigma-point form with the
    unscented weights of (alpha, beta, kappa) written out (Särkkä 2007)."""
    n = 2

    def rhs(t, z):
        m, P = z[:n], z[n:].reshape(n, n)
        P = (P + P.T) / 2
        if rule == "tt1":
            A = _vdp_jacobian(m)
            dP = A @ P + P @ A.T + _vdp_noise(m)
            return np.concatenate([_vdp_drift(m), dP.ravel()])
        alpha, beta, kappa = rule
        lam = alpha**2 * (n + kappa) - n
        wm = np.full(2 * n + 1, 1 / (2 * (n + lam)))
        wm[0] = lam / (n + lam)
        wc = wm.copy()
        wc[0] += 1 - alpha**2 + beta
        S = np.linalg.cholesky(P) * np.sqrt(n + lam)
        X = np.vstack([m, m + S.T, m - S.T])  # rows: m, m + columns of S, m − columns
        a = _vdp_drift(X)
        dm = wm @ a
        C = sum(wc[i] * np.outer(X[i] - m, a[i] - dm) for i in range(2 * n + 1))
        D = sum(wm[i] * _vdp_noise(X[i]) for i in range(2 * n + 1))
        return np.concatenate([dm, (C + C.T + D).ravel()])

    return rhs


@pytest.mark.parametrize("transform, rule", [("ekf", "tt1"), ("ckf", (1.0, 0.0, 0.0)),
                                             (sm.UT(0.5, 2.0, 1.0), (0.5, 2.0, 1.0))])
def test_one_interval_of_the_moment_odes_matches_an_independent_solution(transform, rule):
    m0, P0, dt = np.array([1.2, -0.3]), np.array([[0.09, 0.02], [0.02, 0.16]]), 0.8
    ref = scipy.integrate.solve_ivp(_reference_rhs(rule), (0, dt), np.concatenate([m0, P0.ravel()]),
                                    method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
    cd = sm.ContinuousDiscreteKalmanFilter(VDP, sm.Model([x1, x2], [x1]), [[0.1]], transform, rtol=1e-10,
                                           atol=1e-13)
    m, P = cd.predict(m0, P0, dt)
    # rtol 1e-10 on moments of size ~1: 1e-8 leaves two orders for the accumulation over the steps.
    np.testing.assert_allclose(m, ref[:2], rtol=0, atol=1e-8)
    np.testing.assert_allclose(P, ref[2:].reshape(2, 2), rtol=0, atol=1e-8)
    assert np.abs(P - ref[2:].reshape(2, 2)).max() < 1e-3 * np.abs(P - P0).max()  # not trivially small


def test_the_rules_differ_on_a_nonlinear_drift():
    m0, P0 = np.array([1.2, -0.3]), np.array([[0.09, 0.02], [0.02, 0.16]])
    h = sm.Model([x1, x2], [x1])
    ekf = sm.ContinuousDiscreteKalmanFilter(VDP, h, [[0.1]], "ekf").predict(m0, P0, 0.8)
    ckf = sm.ContinuousDiscreteKalmanFilter(VDP, h, [[0.1]], "ckf").predict(m0, P0, 0.8)
    assert np.abs(ekf[0] - ckf[0]).max() > 1e-3


# ------------------------------------------------------------------ failures
@pytest.mark.parametrize("transform, square_root, call", [("ekf", False, "filter"), ("ekf", True, "filter"),
                                                         ("ckf", True, "filter"), ("ekf", False, "smooth"),
                                                         ("ckf", False, "smooth")])
def test_a_stiff_drift_raises_naming_the_step_and_the_state_with_bounded_work(transform, square_root, call):
    """In every form (the square-root ODE, the smoother's pass with the transitions)."""
    y = sp.Symbol("y", real=True)
    stiff = sm.SDE([y], [-1e5 * (y - sp.cos(y))], diffusion=[1])
    cd = sm.ContinuousDiscreteKalmanFilter(stiff, sm.Model([y], [y]), [[1.0]], transform, max_evaluations=600,
                                           square_root=square_root)
    with pytest.raises(SymmonError, match=r"step 1 .*dt = 1.*mean \[.*max_evaluations = 600.*stiff"):
        getattr(cd, call)([[0.0], [0.0]], [0.5], [[1.0]], params={"dt": [1e-6, 1.0]})


def test_a_diverging_drift_raises_naming_the_run_and_the_step():
    y = sp.Symbol("y", real=True)
    blowup = sm.SDE([y], [y**2], diffusion=[0.1])  # y(t) = 1 / (1 − t) from 1: infinite at t = 1
    cd = sm.ContinuousDiscreteKalmanFilter(blowup, sm.Model([y], [y]), [[1.0]], "ekf")
    with pytest.raises(SymmonError, match=r"step 0 of run 1 .*stopped at t = "):
        cd.filter([[[0.0]], [[0.0]]], [[0.1], [1.0]], [[0.01]], params={"dt": 2.0})


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(sde=sm.Model([p, v], [v, 0])), ArgumentTypeError, "sde must be a symmon.SDE"),
    (dict(h=sm.Model([p], [p])), ShapeError, "h has 1 inputs but the SDE has 2"),
    (dict(transform="ekf2"), SymmonError, "transform must be TT1"),
    (dict(transform=sm.MonteCarlo(100)), SymmonError, "transform must be TT1"),
    (dict(transform="adaptive"), SymmonError, "unknown filter or rule|transform must be"),
    (dict(rtol=0.0), SymmonError, "rtol must be a positive"),
    (dict(atol=float("nan")), SymmonError, "atol must be a positive"),
    (dict(max_step=-1.0), SymmonError, "max_step must be a positive"),
    (dict(max_evaluations=2.5), SymmonError, "max_evaluations must be an integer"),
    (dict(R=[[-1.0]]), SymmonError, "R"),
])
def test_bad_settings_are_refused_by_name(kwargs, error, match):
    args = {"sde": IOU, "h": H, "R": R, **kwargs}
    with pytest.raises(error, match=match):
        sm.ContinuousDiscreteKalmanFilter(**args)


def test_the_interval_is_a_required_strictly_positive_parameter():
    cd = sm.ContinuousDiscreteKalmanFilter(IOU, H, R)
    assert [str(s) for s in cd.params] == ["q", "theta", "dt"]
    with pytest.raises(ModelError, match=r"CD-EKF needs the measurement times: filter\(ys, x0, times=.*or the "
                                         r"intervals params\['dt'\]"):
        cd.filter([[1.0]], X0, params={"q": 0.5, "theta": 0.7})
    with pytest.raises(ModelError, match=r"missing \['theta'\]"):  # times give dt, not the SDE's parameters
        cd.filter([[1.0]], X0, params={"q": 0.5}, times=[1.0])
    with pytest.raises(ShapeError, match=r"'dt' .*strictly positive, got 0.0 at step 1"):
        cd.filter([[1.0], [2.0]], X0, params={"q": 0.5, "theta": 0.7, "dt": [1.0, 0.0]})
    named_dt = sm.SDE([p], [-p], params=[sp.Symbol("dt")])
    with pytest.raises(ModelError, match="parameter named 'dt'"):
        sm.ContinuousDiscreteKalmanFilter(named_dt, sm.Model([p], [p]), R)


@pytest.mark.parametrize("kw, match", [
    (dict(params={"q": 0.5, "theta": 0.7, "dt": [1.0, 1.0]}, times=[1.0, 2.0]), "by times or by params.* not both"),
    (dict(times=[1.0, 0.5]), r"times must be strictly increasing: times\[1\] = 0.5 follows times\[0\] = 1"),
    (dict(times=[1.0, 2.0], t0=1.0), r"times must be after t0 = 1 \(the time of x_0\): times\[0\] = 1"),
    (dict(times=[1.0, float("nan")]), r"times must be finite: times\[1\] = nan"),
    (dict(times=[1.0, 2.0], t0=float("inf")), "t0 must be a finite number"),
    (dict(params={"q": 0.5, "theta": 0.7, "dt": 1.0}, t0=1.0), "t0 .*applies only with times"),
])
def test_bad_times_are_refused_by_name(kw, match):
    cd = sm.ContinuousDiscreteKalmanFilter(IOU, H, R)
    kw = {"params": {"q": 0.5, "theta": 0.7}, **kw}
    with pytest.raises(ArgumentError, match=match):
        cd.filter([[1.0], [2.0]], X0, **kw)


def test_a_filter_that_is_not_a_gaussian_one_points_an_sde_to_the_continuous_discrete_one():
    with pytest.raises(ArgumentTypeError, match="ContinuousDiscreteKalmanFilter"):
        sm.ParticleFilter(IOU, H, None, R, particles=10)


def test_the_registry_names_it_but_a_scenario_file_cannot_build_it():
    entry = filter_entry("cdkf")
    assert entry.kind is sm.ContinuousDiscreteKalmanFilter and not entry.scenario
    assert "cdkf" in filter_names() and "cdkf" not in filter_names(scenario=True)
    with pytest.raises(SymmonError, match="ContinuousDiscreteKalmanFilter"):
        make_filter("cdkf", sm.Model([p, v], [p + v, v]), H, np.eye(2), R, settings={"transform": "ckf"})


def test_its_name_says_continuous_discrete():
    assert sm.ContinuousDiscreteKalmanFilter(IOU, H, R, "ckf").method == "CD-CKF"
    assert sm.ContinuousDiscreteKalmanFilter(IOU, H, R).method == "CD-EKF"


# ------------------------------------------------------------------ the square-root form
def _close(res, ref, names, tol):
    for name in names:
        a, b = getattr(res, name), getattr(ref, name)
        assert np.abs(a - b).max() <= tol * np.abs(b).max(), name


@pytest.mark.parametrize("transform", ["ekf", "ckf"])
def test_the_square_root_form_is_the_standard_filter_and_the_kalman_filter_of_the_exact_discretisation(
        exact, transform):
    """Eq. (2) integrates S with S Sᵀ = P: on the linear SDE, the Kalman filter of the exact
    discretisation to 10·rtol (measured 2e-10 at rtol 1e-8, as the standard form's 0.8e-10),
    and the standard CD filter likewise; its factors are lower triangular with a positive
    diagonal, and give P."""
    _, xs, ys, ref = exact
    sr = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, transform, rtol=1e-8, atol=1e-11, square_root=True)
    std = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, transform, rtol=1e-8, atol=1e-11)
    res = sr.filter(ys, X0, params=PARAMS, x_true=xs)
    assert res.method == sr.method == "CD-SR-" + transform.upper()
    tol = 10 * sr.rtol
    _close(res, ref, ("x", "P", "x_pred", "P_pred", "S"), tol)
    _close(res, std.filter(ys, X0, params=PARAMS), ("x", "P", "x_pred", "P_pred"), tol)
    np.testing.assert_allclose(res.loglik, ref.loglik, rtol=0, atol=tol * np.abs(ref.loglik).max())
    for S, P in ((res.P_chol, res.P), (res.P_pred_chol, res.P_pred)):
        assert np.array_equal(S, np.tril(S)) and np.all(np.diagonal(S, axis1=-2, axis2=-1) > 0)
        np.testing.assert_allclose(S @ np.swapaxes(S, -1, -2), P, rtol=1e-13, atol=1e-13 * np.abs(P).max())
    coarse = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, transform, rtol=1e-3, atol=1e-6, square_root=True)
    assert np.abs(coarse.filter(ys, X0, params=PARAMS).x - ref.x).max() > tol * np.abs(ref.x).max()


@pytest.mark.parametrize("transform", ["ekf", "ckf", sm.UT(0.5, 2.0, 1.0)])
def test_the_factor_ode_integrates_the_moment_odes_on_a_nonlinear_sde(transform):
    """dS/dt = S Φ(S⁻¹ Ṗ S⁻ᵀ) is Ṗ = S Ṡᵀ + Ṡ Sᵀ: one interval of the Van der Pol moments agrees with
    the standard form (both at rtol 1e-10), which the test above holds to an independent solution."""
    m0, P0, dt = np.array([1.2, -0.3]), np.array([[0.09, 0.02], [0.02, 0.16]]), 0.8
    h = sm.Model([x1, x2], [x1])
    kw = dict(rtol=1e-10, atol=1e-13)
    std = sm.ContinuousDiscreteKalmanFilter(VDP, h, [[0.1]], transform, **kw).predict(m0, P0, dt)
    sr_filter = sm.ContinuousDiscreteKalmanFilter(VDP, h, [[0.1]], transform, square_root=True, **kw)
    sr = sr_filter.predict(m0, P0, dt)
    np.testing.assert_allclose(sr[0], std[0], rtol=0, atol=1e-8)
    np.testing.assert_allclose(sr[1], std[1], rtol=0, atol=1e-8)
    S = np.linalg.cholesky(P0)
    dm, dS = sr_filter.factor_derivative(m0, S, np.zeros(0))
    dm_std, dP = sr_filter.moment_derivatives(m0, P0, np.zeros(0))
    assert np.array_equal(dS, np.tril(dS))
    np.testing.assert_allclose(dm, dm_std, rtol=1e-13)
    np.testing.assert_allclose(S @ dS.T + dS @ S.T, dP, rtol=1e-12, atol=1e-13)


def test_the_square_root_form_needs_a_positive_definite_prior():
    sr = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, "ekf", square_root=True)
    with pytest.raises(CovarianceError, match="P0 must be positive definite"):
        sr.filter([[1.0]], [0.0, 0.0], np.diag([1.0, 0.0]), params={"q": 0.5, "theta": 0.7}, times=[1.0])
    with pytest.raises(ArgumentTypeError, match="square_root must be True or False"):
        sm.ContinuousDiscreteKalmanFilter(IOU, H, R, square_root="yes")


# ------------------------------------------------------------------ the exact prediction
@pytest.mark.parametrize("square_root", [False, True])
def test_the_exact_prediction_is_the_kalman_filter_of_the_exact_discretisation(exact, square_root):
    """Eq. (4) by matrix exponentials at each interval: no integrator, so equal to rounding."""
    _, xs, ys, ref = exact
    kf = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, exact=True, square_root=square_root)
    res = kf.filter(ys, X0, params=PARAMS)
    _close(res, ref, ("x", "P", "x_pred", "P_pred", "S"), 1e-12)
    np.testing.assert_allclose(res.loglik, ref.loglik, rtol=1e-12)
    with pytest.raises(ModelError, match="exact=True needs a linear"):
        sm.ContinuousDiscreteKalmanFilter(VDP, sm.Model([x1, x2], [x1]), [[0.1]], exact=True)


# ------------------------------------------------------------------ the smoother
def _rts(res, params):
    """The RTS backward pass written out on a filter's stored moments with F = e^{A dt} by
    scipy's matrix exponential, independent of symmon's smoothers."""
    A = np.array([[0.0, 1.0], [0.0, -params["theta"]]])
    x, P, xp, Pp = res.x, res.P, res.x_pred, res.P_pred
    xs, Ps = x.copy(), P.copy()
    for k in range(len(x) - 2, -1, -1):
        dt = params["dt"][k + 1]
        F = scipy.linalg.expm(A * dt)
        G = P[k] @ F.T @ np.linalg.inv(Pp[k + 1])
        xs[k] = x[k] + G @ (xs[k + 1] - xp[k + 1])
        Ps[k] = P[k] + G @ (Ps[k + 1] - Pp[k + 1]) @ G.T
    return xs, Ps


@pytest.mark.parametrize("transform, square_root", [("ekf", False), ("ckf", False), ("ekf", True)])
def test_on_a_linear_sde_the_smoother_is_the_rts_smoother_of_the_exact_discretisation(exact, transform,
                                                                                       square_root):
    """Irregular times: the discrete RTS smoother of the exact discretisation (the NKF's compiled
    one, and one written out here) to 10·rtol; Φ of eq. (3) is e^{A dt}.  Measured: 1e-10 (x)
    and 1.6e-9 (P) relative at rtol 1e-8; the same comparison fails at rtol 1e-3."""
    f, _, ys, _ = exact
    kf = sm.NonlinearKalmanFilter(f, H, np.eye(f.n_v), R, "ekf")
    ref = kf.smooth(ys, X0, params=PARAMS)
    times = np.cumsum(STEPS)
    cd = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, transform, rtol=1e-8, atol=1e-11, square_root=square_root)
    res = cd.smooth(ys, X0, params={"q": 0.5, "theta": 0.7}, times=times)
    assert res.method == cd.method and res.x.shape == ref.x.shape
    tol = 10 * cd.rtol
    _close(res, ref, ("x", "P"), tol)
    _close(res.filtered, ref.filtered, ("x", "P"), tol)
    one = cd.smooth(ys[1], X0, params={"q": 0.5, "theta": 0.7}, times=times)
    xs, Ps = _rts(one.filtered, {"theta": 0.7, "dt": STEPS})
    np.testing.assert_allclose(one.x, xs, rtol=0, atol=tol * np.abs(xs).max())
    np.testing.assert_allclose(one.P, Ps, rtol=0, atol=tol * np.abs(Ps).max())
    np.testing.assert_array_equal(one.x, res.x[1])  # a bank is its runs smoothed alone
    assert np.abs(res.x - res.filtered.x).max() > 1.0  # the smoother moved the estimates
    coarse = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, transform, rtol=1e-3, atol=1e-6)
    err = np.abs(coarse.smooth(ys, X0, params={"q": 0.5, "theta": 0.7}, times=times).x - ref.x).max()
    assert err > tol * np.abs(ref.x).max()


def test_the_exact_smoother_is_the_rts_smoother_to_rounding(exact):
    f, _, ys, _ = exact
    ref = sm.NonlinearKalmanFilter(f, H, np.eye(f.n_v), R, "ekf").smooth(ys, X0, params=PARAMS)
    res = sm.KalmanFilter(IOU, None, [[1.0, 0.0]], R).smooth(ys, X0, params=PARAMS, keep="x")
    _close(res, ref, ("x", "P"), 1e-11)
    assert res.filtered.P is not None and res.filtered.S is None  # keep adds what the backward pass reads


def test_the_smoother_on_a_nonlinear_sde_uses_the_linearised_flow():
    """The CD-EKF smoother's Φ is the solution of dΦ/dt = A(m(t)) Φ: the last smoothed step is
    the filtered one, earlier ones move, and Φ's integral matches a finite difference of the
    mean flow (the TT1 prediction's sensitivity to m0)."""
    h = sm.Model([x1, x2], [x1])
    cd = sm.ContinuousDiscreteKalmanFilter(VDP, h, [[0.1]], "ekf", rtol=1e-10, atol=1e-13)
    ys = np.array([[1.0], [0.4], [-0.6], [np.nan], [-1.2]])
    res = cd.smooth(ys, [1.2, -0.3], np.diag([0.09, 0.16]), times=[0.3, 0.7, 1.0, 1.6, 1.9])
    np.testing.assert_array_equal(res.x[-1], res.filtered.x[-1])
    assert np.abs(res.x[0] - res.filtered.x[0]).max() > 1e-3
    assert np.all(np.linalg.eigvalsh(res.P) > 0)
    m0, P0 = np.array([1.2, -0.3]), np.diag([0.09, 0.16])
    _, _, _, Phi, _ = cd._predict(m0, P0, None, 0.5, np.zeros(0), transition=True)
    eps = 1e-6
    cols = [(cd.predict(m0 + eps * e, P0, 0.5)[0] - cd.predict(m0 - eps * e, P0, 0.5)[0]) / (2 * eps)
            for e in np.eye(2)]
    np.testing.assert_allclose(Phi, np.array(cols).T, rtol=1e-5, atol=1e-6)


def _rel(a, b) -> float:
    return float(np.abs(np.asarray(a) - np.asarray(b)).max() / np.abs(np.asarray(b)).max())


def test_the_square_root_smoother_returns_factors_as_the_discrete_one(exact):
    """The contract of ``NonlinearKalmanFilter(..., square_root=True).smooth``: ``P_chol``
    the smoothed lower factors with P = S Sᵀ, ``filtered`` the square-root forward pass.
    With the exact prediction both forward passes are the exact Kalman filter, so the
    square-root backward pass (eq. (7)) equals the covariance form's (5) to rounding
    (measured 5e-16 in P) and the discrete square-root smoother of the exact discretisation
    (measured 9e-14 in P, 1.1e-13 in the factors): held to 1e-10 relative."""
    f, _, ys, _ = exact
    ref = sm.NonlinearKalmanFilter(f, H, np.eye(f.n_v), R, "ekf", square_root=True).smooth(ys, X0, params=PARAMS)
    sr = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, "ekf", exact=True, square_root=True)
    res = sr.smooth(ys, X0.mean, X0.cov, params=PARAMS)
    cov = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, "ekf", exact=True).smooth(ys, X0.mean, X0.cov, params=PARAMS)
    assert ref.P_chol is not None and res.P_chol is not None and cov.P_chol is None
    assert res.P_chol.shape == res.P.shape and res.filtered.P_chol is not None
    assert np.all(np.triu(res.P_chol, 1) == 0) and np.all(np.diagonal(res.P_chol, axis1=-2, axis2=-1) >= 0)
    np.testing.assert_array_equal(res.P, res.P_chol @ np.swapaxes(res.P_chol, -1, -2))
    for a, b in ((res.x, cov.x), (res.P, cov.P), (res.x, ref.x), (res.P, ref.P), (res.P_chol, ref.P_chol)):
        assert _rel(a, b) < 1e-10
    np.testing.assert_array_equal(res.P_chol[:, -1], res.filtered.P_chol[:, -1])
    one = sr.smooth(ys[0], X0.mean, X0.cov, params={**PARAMS})
    assert one.P_chol.shape == res.P_chol.shape[1:] and _rel(one.P_chol, res.P_chol[0]) < 1e-14


@pytest.mark.parametrize("transform", ["ekf", "ckf"])
def test_the_integrated_square_root_smoother_is_the_covariance_one_and_the_exact_one(exact, transform):
    """Integrated at irregular times (rtol 1e-10): the square-root smoother against the
    covariance-form CD smoother and the discrete square-root smoother of the exact
    discretisation, to 10·rtol relative (measured 4.6e-13 in x, 1.2e-11 in P: the two forward
    passes integrate different equations, so they agree to the tolerance, not to rounding)."""
    f, _, ys, _ = exact
    ref = sm.NonlinearKalmanFilter(f, H, np.eye(f.n_v), R, "ekf", square_root=True).smooth(ys, X0, params=PARAMS)
    kw = dict(rtol=1e-10, atol=1e-13)
    times = np.cumsum(STEPS)
    args = (ys, X0.mean, X0.cov)
    res = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, transform, square_root=True, **kw).smooth(
        *args, params={"q": 0.5, "theta": 0.7}, times=times)
    cov = sm.ContinuousDiscreteKalmanFilter(IOU, H, R, transform, **kw).smooth(
        *args, params={"q": 0.5, "theta": 0.7}, times=times)
    for a, b in ((res.x, cov.x), (res.P, cov.P), (res.x, ref.x), (res.P, ref.P), (res.P_chol, ref.P_chol)):
        assert _rel(a, b) < 10 * kw["rtol"]


@pytest.mark.parametrize("transform", ["ekf", "ukf"])
def test_the_square_root_smoother_on_a_nonlinear_sde_is_the_covariance_one(transform):
    """The effective noise Q̃ of eq. (6) is integrated for any rule (Φ and P share Â, so
    Q̃ = P⁻ − Φ P Φᵀ) on the Van der Pol oscillator with a state-dependent diffusion: the two
    forms agree to the tolerance (rtol 1e-10: measured 6e-12 in x, 1.2e-11 in P, as their
    forward passes do, 5e-12 in P)."""
    h = sm.Model([x1, x2], [x1])
    ys = np.array([[1.0], [0.4], [-0.6], [np.nan], [-1.2]])
    args = (ys, [1.2, -0.3], np.diag([0.09, 0.16]))
    kw = dict(rtol=1e-10, atol=1e-13)
    times = [0.3, 0.7, 1.0, 1.6, 1.9]
    res = sm.ContinuousDiscreteKalmanFilter(VDP, h, [[0.1]], transform, square_root=True, **kw).smooth(*args, times=times)
    cov = sm.ContinuousDiscreteKalmanFilter(VDP, h, [[0.1]], transform, **kw).smooth(*args, times=times)
    assert _rel(res.x, cov.x) < 10 * kw["rtol"] and _rel(res.P, cov.P) < 10 * kw["rtol"]
    assert np.abs(res.x[0] - res.filtered.x[0]).max() > 1e-3


def test_the_smoother_names_a_singular_prediction():
    y = sp.Symbol("y", real=True)
    still = sm.SDE([y, p], [0, 0], diffusion=[[0], [0]])  # no noise: P⁻ stays P, singular from P0
    cd = sm.ContinuousDiscreteKalmanFilter(still, sm.Model([y, p], [y]), [[1.0]], "ekf")
    with pytest.raises(SymmonError, match=r"smoother: the predicted covariance of step 1 is singular"):
        cd.smooth([[0.0], [0.0]], [0.0, 0.0], np.diag([1.0, 0.0]), times=[1.0, 2.0])


# ------------------------------------------------------------------ the discrete spellings
def test_the_nonlinear_kalman_filter_of_an_sde_is_its_continuous_discrete_filter(exact):
    """``sm.NonlinearKalmanFilter(sde, h, None, R, transform)``, the issue's spelling: the CD filter
    of the same rule (the discrete default rule, UT.ut1()), with times=, pickling to itself."""
    _, xs, ys, ref = exact
    nkf = sm.NonlinearKalmanFilter(IOU, H, None, R, "ckf", rtol=1e-8, atol=1e-11)
    assert isinstance(nkf, sm.ContinuousDiscreteKalmanFilter) and nkf.method == "CD-CKF"
    res = nkf.filter(ys, X0, params={"q": 0.5, "theta": 0.7}, times=np.cumsum(STEPS))
    _close(res, ref, ("x", "P"), 10 * nkf.rtol)
    again = pickle.loads(pickle.dumps(nkf))
    np.testing.assert_array_equal(again.filter(ys, X0, params=PARAMS).x, nkf.filter(ys, X0, params=PARAMS).x)
    assert sm.NonlinearKalmanFilter(IOU, H, None, R).transform == sm.UT.ut1()
    assert sm.NonlinearKalmanFilter(f_model=IOU, h_model=H, Q=None, R=R, transform="ekf",
                                    square_root=True).method == "CD-SR-EKF"
    with pytest.raises(ArgumentError, match="Q must be None for an SDE"):
        sm.NonlinearKalmanFilter(IOU, H, np.eye(2), R, "ekf")
    with pytest.raises(ArgumentError, match="iterations must be 1 for an SDE"):
        sm.NonlinearKalmanFilter(IOU, H, None, R, "ekf", iterations=2)


def test_the_kalman_filter_of_a_linear_sde_is_exact_at_irregular_times(exact):
    _, xs, ys, ref = exact
    kf = sm.KalmanFilter(IOU, None, [[1.0, 0.0]], R)
    assert isinstance(kf, sm.ContinuousDiscreteKalmanFilter) and kf.exact and kf.method == "CD-KF"
    assert sm.KalmanFilter(F=IOU, Q=None, H=[[1.0, 0.0]], R=R).exact  # by keyword too
    res = kf.filter(ys, X0, params={"q": 0.5, "theta": 0.7}, times=np.cumsum(STEPS), x_true=xs)
    _close(res, ref, ("x", "P", "x_pred", "P_pred"), 1e-12)
    np.testing.assert_allclose(res.nees_values, ref.nees_values, rtol=1e-10)
    again = pickle.loads(pickle.dumps(kf))
    np.testing.assert_array_equal(again.filter(ys, X0, params=PARAMS).x, kf.filter(ys, X0, params=PARAMS).x)
    with pytest.raises(ModelError, match="KalmanFilter needs a linear SDE.*NonlinearKalmanFilter"):
        sm.KalmanFilter(VDP, None, [[1.0, 0.0]], [[0.1]])
    with pytest.raises(ArgumentError, match="Q must be None for an SDE"):
        sm.KalmanFilter(IOU, np.eye(2), [[1.0, 0.0]], R)
    with pytest.raises(ShapeError, match=r"H must be a finite \(n_y, 2\) matrix"):
        sm.KalmanFilter(IOU, None, [[1.0, 0.0, 0.0]], R)
