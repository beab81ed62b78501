"""The square-root filters (``square_root=True``): the same filter as the standard form on
well-conditioned problems, and a positive definite P where the standard form loses it."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentTypeError, SymmonError

px, py, th, v, dt, om = sp.symbols("px py th v dt om", real=True)
STATE = [px, py, th, v]
#: A unicycle turning at rate om, heading th an angle state; dt and om parameters.
F_PAR = sm.Model(STATE, [px + dt * v * sp.cos(th), py + dt * v * sp.sin(th), th + dt * om, v], angles=[2],
                 params=[dt, om], name="sr_unicycle_p")
F_FIX = sm.Model(STATE, [px + v * sp.cos(th), py + v * sp.sin(th), th + sp.Rational(1, 10), v], angles=[2],
                 name="sr_unicycle")
H_RB = sm.Model(STATE, [sp.sqrt(px**2 + py**2), sp.atan2(py, px)], angles=[1], name="sr_rb")
Q = np.diag([0.05, 0.05, 0.01, 0.02])
R = np.diag([0.3**2, 0.01**2])
X0 = sm.Gaussian([30.0, 10.0, 0.5, 2.0], np.diag([1.0, 1.0, 0.05, 0.1]))
K = 12

FAMILIES = {
    "EKF": dict(transform=sm.TT1()),
    "EKF2": dict(transform=sm.TT2()),
    "IEKF": dict(transform=sm.TT1(), iterations=3),
    "UKF-negative-centre": dict(transform=sm.UT(alpha=0.5, beta=2.0, kappa=0.0)),
    "CKF": dict(transform=sm.UT.cubature()),
    "GHKF": dict(transform=sm.GaussHermite(3)),
}


def measurements(runs: int = 2, seed: int = 3) -> np.ndarray:
    """A bank of range–bearing measurements along a turn, with a missing row and a missing
    component in each run."""
    rng = np.random.default_rng(seed)
    x = np.array(X0.mean)
    ys = np.empty((runs, K, 2))
    for k in range(K):
        x = np.array([x[0] + x[3] * np.cos(x[2]), x[1] + x[3] * np.sin(x[2]), x[2] + 0.1, x[3]])
        ys[:, k] = [np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])] + rng.standard_normal((runs, 2)) * [0.3, 0.01]
    ys[:, 4] = np.nan
    ys[0, 7, 1] = np.nan
    ys[1, 9, 0] = np.nan
    return ys


YS = measurements()
PARAMS = {"dt": 1.0, "om": np.linspace(0.08, 0.12, K)}


def assert_same(a: sm.KalmanResult, b: sm.KalmanResult, tol: float = 1e-10) -> None:
    for name in ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik", "nis_values"):
        u, w = getattr(a, name), getattr(b, name)
        scale = np.maximum(np.abs(w), 1.0)
        assert np.all(np.abs(u - w) <= tol * scale), (name, np.max(np.abs(u - w) / scale))


@pytest.mark.parametrize("family", list(FAMILIES))
def test_square_root_equals_the_standard_form_with_params_angles_and_missing_rows(family):
    opts = FAMILIES[family]
    std = sm.NonlinearKalmanFilter(F_PAR, H_RB, Q, R, **opts)
    sr = sm.NonlinearKalmanFilter(F_PAR, H_RB, Q, R, square_root=True, **opts)
    a, b = sr.filter(YS, X0, params=PARAMS), std.filter(YS, X0, params=PARAMS)
    assert_same(a, b)
    assert sr.method == "SR-" + std.method
    # The factors are lower triangular with a positive diagonal: the Cholesky factors of P.
    assert np.all(np.triu(a.P_chol, 1) == 0) and np.all(np.diagonal(a.P_chol, axis1=-2, axis2=-1) > 0)
    np.testing.assert_allclose(a.P_chol, np.linalg.cholesky(b.P), rtol=1e-9, atol=1e-12)
    assert b.P_chol is None


@pytest.mark.parametrize("family", ["UKF-negative-centre"])
def test_square_root_equals_the_standard_form_without_params(family):
    opts = FAMILIES[family]
    std = sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, **opts)
    sr = sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, square_root=True, **opts)
    assert_same(sr.filter(YS[0], X0), std.filter(YS[0], X0))


# --- Ill-conditioned problems: the standard form fails, the square-root form keeps P definite.

EPS = np.finfo(float).eps


def kalman_mp(F, H, Q, R, x0, P0, ys, dps: int = 60, smooth: bool = False):
    """The Kalman filter (``smooth``: its RTS smoother) in mpmath at ``dps`` digits: (x (K, n),
    P (K, n, n)) as floats."""
    mp = pytest.importorskip("mpmath")
    mp.mp.dps = dps
    F, H, Q, R = (mp.matrix(np.asarray(a, dtype=float).tolist()) for a in (F, H, Q, R))
    x, P = mp.matrix([float(a) for a in x0]), mp.matrix(np.asarray(P0, dtype=float).tolist())
    xs, Ps = [], []
    for y in ys:
        x, P = F * x, F * P * F.T + Q
        S = H * P * H.T + R
        G = P * H.T * mp.inverse(S)
        x = x + G * (mp.matrix([float(a) for a in y]) - H * x)
        P = P - G * S * G.T
        P = (P + P.T) / 2
        xs.append(x)
        Ps.append(P)
    if smooth:  # the RTS backward pass: G = P_k Fᵀ (F P_k Fᵀ + Q)⁻¹
        for k in range(len(ys) - 2, -1, -1):
            G = Ps[k] * F.T * mp.inverse(F * Ps[k] * F.T + Q)
            xs[k] = xs[k] + G * (xs[k + 1] - F * xs[k])
            Ps[k] = Ps[k] + G * (Ps[k + 1] - F * Ps[k] * F.T - Q) * G.T
    return (np.array([[float(a) for a in x] for x in xs]),
            np.array([[[float(P[i, j]) for j in range(P.cols)] for i in range(P.rows)] for P in Ps]))


def correlation_errors(x, P, xr, Pr):
    """(max |x − x_ref| / (σ + |x_ref|), max |P − P_ref| / σσᵀ) with σ the reference's standard
    deviations (the error relative to the state's uncertainty or its size, whichever is
    larger, and in correlation units), and the largest condition number κ of the reference's
    correlation matrices."""
    sd = np.sqrt(np.einsum("kii->ki", Pr))
    outer = np.einsum("ki,kj->kij", sd, sd)
    return (float(np.max(np.abs(x - xr) / (sd + np.abs(xr)))), float(np.max(np.abs(P - Pr) / outer)),
            float(np.max(np.linalg.cond(Pr / outer))))


def assert_definite_factor(res: sm.KalmanResult) -> None:
    """Every P_chol is lower triangular with a positive diagonal: P = S Sᵀ is positive definite."""
    d = np.diagonal(res.P_chol, axis1=-2, axis2=-1)
    assert np.all(np.triu(res.P_chol, 1) == 0) and np.all(d > 0)


def test_filterpy_linear_rts_with_r_1e_16():
    """FilterPy's test_linear_rts (test_ukf.py): a 1-D constant-velocity model, Q of
    Q_discrete_white_noise(2, 1, 0.01) (rank 1), R = 1e-16, P0 = I, the UT of
    MerweScaledSigmaPoints(2, alpha=.1, beta=2, kappa=1) (centre weight −62.7), 50 steps.

    FilterPy's UKF stops with a failed Cholesky factor; symmon's standard form runs but its
    position variance (≈ 1e-16 after each update) is rounding, off by a factor up to 4.4;
    the square-root form equals the exact filter (mpmath) to 1e-12 in correlation units."""
    p, v = sp.symbols("p v", real=True)
    f = sm.Model([p, v], [p + v, v], name="sr_frts_f")
    h = sm.Model([p, v], [p], name="sr_frts_h")
    Q1 = 0.01 * np.array([[0.25, 0.5], [0.5, 1.0]])
    R1 = np.array([[1e-16]])
    ys = (np.arange(1, 51) + 1e-8 * np.random.default_rng(7).standard_normal(50))[:, None]
    x0 = sm.Gaussian([0.0, 1.0], np.eye(2))
    ut = sm.UT(alpha=0.1, beta=2.0, kappa=1.0)
    xr, Pr = kalman_mp([[1, 1], [0, 1]], [[1, 0]], Q1, R1, x0.mean, x0.cov, ys)
    sr = sm.NonlinearKalmanFilter(f, h, Q1, R1, ut, square_root=True).filter(ys, x0)
    assert_definite_factor(sr)
    ex, eP, kappa = correlation_errors(sr.x, sr.P, xr, Pr)
    # A backward-stable square-root recursion: errors of order ε √κ per step (Verhaegen & Van
    # Dooren 1986); κ ≈ 1 here, 50 steps: 1e-12 is 50 × 100 ε √κ rounded up.
    assert kappa < 10 and ex < 1e-12 and eP < 1e-12
    std = sm.NonlinearKalmanFilter(f, h, Q1, R1, ut).filter(ys, x0)
    assert correlation_errors(std.x, std.P, xr, Pr)[1] > 1.0  # the difference P⁻ − K S Kᵀ: rounding
    # The test's point: the RTS smoother.  Same bound.
    xs_r, Ps_r = kalman_mp([[1, 1], [0, 1]], [[1, 0]], Q1, R1, x0.mean, x0.cov, ys, smooth=True)
    smoothed = sm.NonlinearKalmanFilter(f, h, Q1, R1, ut, square_root=True).smooth(ys, x0)
    assert np.all(np.diagonal(smoothed.P_chol, axis1=-2, axis2=-1) > 0)
    ex, eP, kappa = correlation_errors(smoothed.x, smoothed.P, xs_r, Ps_r)
    assert kappa < 10 and ex < 1e-12 and eP < 1e-12

    ukf_module = pytest.importorskip("filterpy.kalman")
    fp = ukf_module.UnscentedKalmanFilter(2, 1, 1.0, lambda x: x[:1], lambda x, dt: np.array([x[0] + x[1], x[1]]),
                                          ukf_module.MerweScaledSigmaPoints(2, alpha=0.1, beta=2.0, kappa=1.0))
    fp.x, fp.P, fp.Q, fp.R = np.array([0.0, 1.0]), np.eye(2), Q1.copy(), R1.copy()
    with pytest.raises(np.linalg.LinAlgError):
        fp.batch_filter(ys)


def test_ten_thousand_steps_of_a_noise_free_tracker_with_a_diffuse_prior():
    """Constant acceleration, position and velocity noise-free, Q = 1e-20 on the acceleration,
    P0 = 1e12 I, R = 1e-6, 10⁴ steps (tests/reference/make_sqrt_reference.py, mpmath at 60
    digits): the standard form's S loses definiteness within a few steps; the square-root
    form runs, keeps a positive factor, and equals the exact filter within 100 ε √κ."""
    import json
    from pathlib import Path

    ref = json.loads((Path(__file__).parents[1] / "reference" / "sqrt_filter.json").read_text())
    K_ref, steps = ref["K"], ref["steps"]
    t = np.arange(1, K_ref + 1, dtype=float)
    ys = (t + 5e-4 * t**2 + np.sqrt(ref["R"]) * np.sin(1.7 * t))[:, None]  # as the script's measurements()
    p, v, a = sp.symbols("p v a", real=True)
    f = sm.Model([p, v, a], [p + v + a / 2, v + a, a], name="sr_ca_f")
    h = sm.Model([p, v, a], [p], name="sr_ca_h")
    Q3, R3 = np.diag([0.0, 0.0, ref["Q_acc"]]), np.array([[ref["R"]]])
    x0 = sm.Gaussian([0.0, 1.0, 0.0], ref["P0"] * np.eye(3))
    with pytest.raises(SymmonError, match="NaN or inf at step"):
        sm.NonlinearKalmanFilter(f, h, Q3, R3, sm.TT1()).filter(ys, x0)
    res = sm.NonlinearKalmanFilter(f, h, Q3, R3, sm.TT1(), square_root=True).filter(ys, x0)
    assert_definite_factor(res)
    ex, eP, kappa = correlation_errors(res.x[steps], res.P[steps], np.array(ref["x"]), np.array(ref["P"]))
    # κ ≈ 4e16 after the second measurement (p and v pinned, almost perfectly correlated):
    # the factors' condition is √κ ≈ 2e8, and the early errors persist in a noise-free model.
    bound = 100 * EPS * np.sqrt(kappa)
    assert kappa > 1e16 and ex < bound and eP < bound


# --- General noise, large (MX) steps, the VM, NEES in the step, refusals.

e1, e2 = sp.symbols("e1 e2", real=True)
#: Range with a multiplicative error and bearing with an additive one: general noise.
H_GEN = sm.Model(STATE, [sp.sqrt(px**2 + py**2) * (1 + e1), sp.atan2(py, px) + e2], noise=[e1, e2], angles=[1],
                 name="sr_rb_gen")
R_GEN = np.diag([0.01**2, 0.01**2])


@pytest.mark.parametrize("family", ["EKF", "CKF"])
def test_square_root_with_general_noise_equals_the_standard_form(family):
    opts = FAMILIES[family]
    std = sm.NonlinearKalmanFilter(F_FIX, H_GEN, Q, R_GEN, **opts)
    sr = sm.NonlinearKalmanFilter(F_FIX, H_GEN, Q, R_GEN, square_root=True, **opts)
    assert_same(sr.filter(YS, X0), std.filter(YS, X0))


def stacked_tracker(k: int):
    """k constant-velocity targets in range and bearing: 4k states (MX from 10)."""
    X, fo, ho = [], [], []
    for i in range(k):
        a, b, c, d = sp.symbols(f"sx{i} sy{i} svx{i} svy{i}", real=True)
        X += [a, b, c, d]
        fo += [a + c, b + d, c, d]
        ho += [sp.sqrt(a**2 + b**2), sp.atan2(b, a)]
    f = sm.Model(X, fo, name=f"sr_cv{k}")
    h = sm.Model(X, ho, name=f"sr_rb{k}", angles=list(range(1, 2 * k, 2)))
    x0 = sm.Gaussian(np.concatenate([[20.0 + 5 * i, 5.0 - 3 * i, -1.0, 0.5] for i in range(k)]),
                     np.kron(np.eye(k), np.diag([1.0, 1.0, 0.1, 0.1])))
    return f, h, np.kron(np.eye(k), np.diag([0.01, 0.01, 0.001, 0.001])), np.kron(np.eye(k), R), x0


def test_square_root_mx_step_equals_the_standard_form_and_the_vm():
    f, h, Q3, R3, x0 = stacked_tracker(3)  # 12 states: the MX step
    rng = np.random.default_rng(5)
    hx = sp.lambdify(f.inputs, h.outputs, "numpy")
    ys = np.array([hx(*(x0.mean + [0, 0, 0, 0] * 3)) for _ in range(6)]) + 0.01 * rng.standard_normal((6, 6))
    ys[2, 3] = np.nan
    std = sm.NonlinearKalmanFilter(f, h, Q3, R3, sm.UT.cubature())
    sr = sm.NonlinearKalmanFilter(f, h, Q3, R3, sm.UT.cubature(), square_root=True)
    a = sr.filter(ys, x0)
    assert_same(a, std.filter(ys, x0))
    from symmon.filters.gaussian.step import compiled_step

    step = compiled_step(f, h, sm.UT.cubature(), sr.angle_states, 1, True)
    vm = step(np.asarray(x0.mean), np.asarray(x0.cov), ys[None], sr.Q, sr.R, use_c=False)
    np.testing.assert_allclose(vm["x"][0], a.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(vm["P_chol"][0], a.P_chol, rtol=1e-12, atol=1e-14)


def stacked_unicycles(k: int):
    """k unicycles (heading an angle state; dt and om parameters) in range and bearing: 4k
    states, with a rank-deficient Q (the speeds noise-free) and a dense P0."""
    X, fo, ho, angles = [], [], [], []
    for i in range(k):
        a, b, c, d = sp.symbols(f"ux{i} uy{i} uth{i} uv{i}", real=True)
        X += [a, b, c, d]
        fo += [a + dt * d * sp.cos(c), b + dt * d * sp.sin(c), c + dt * om, d]
        ho += [sp.sqrt(a**2 + b**2), sp.atan2(b, a)]
        angles.append(4 * i + 2)
    f = sm.Model(X, fo, angles=angles, params=[dt, om], name=f"sr_uni{k}")
    h = sm.Model(X, ho, angles=list(range(1, 2 * k, 2)), name=f"sr_unirb{k}")
    mean = np.concatenate([[30.0 + 6 * i, 10.0 - 4 * i, 0.5 + 0.2 * i, 2.0] for i in range(k)])
    A = np.random.default_rng(11).standard_normal((4 * k, 4 * k))
    P0 = np.kron(np.eye(k), np.diag([1.0, 1.0, 0.05, 0.1])) + 0.01 * A @ A.T
    Qk = np.kron(np.eye(k), np.diag([0.05, 0.05, 0.01, 0.0]))
    return f, h, Qk, np.kron(np.eye(k), R), sm.Gaussian(mean, P0)


@pytest.mark.parametrize("iterations", [1, 3])
def test_c_square_root_ekf_step_equals_the_standard_form_and_the_vm(iterations):
    """From C_SQRT_EKF_FROM states on, the square-root EKF and IEKF run the C step of
    sqrt_ekf_step.c (its update by the array form, one triangularisation of the pre-array):
    equal to the MX step on CasADi's VM (the Joseph-form factor) to 1e-12, and to the
    standard form to the tolerance of assert_same, with parameters, angle states, missing
    components and rows, a dense P0 and a rank-deficient Q."""
    from symmon.filters.gaussian._ekfstep import C_SQRT_EKF_FROM
    from symmon.filters.gaussian.step import compiled_step

    f, h, Qk, Rk, x0 = stacked_unicycles(3)
    assert f.n_u >= C_SQRT_EKF_FROM
    rng = np.random.default_rng(2)
    hx = sp.lambdify(f.inputs, h.outputs, "numpy")
    ys = np.array([hx(*x0.mean) for _ in range(8)]) + 0.05 * rng.standard_normal((8, 6))
    ys = np.stack([ys, ys + 0.02 * rng.standard_normal(ys.shape)])
    ys[0, 2, 3] = np.nan
    ys[1, 4] = np.nan
    ys[1, 6, ::2] = np.nan
    params = {"dt": 1.0, "om": np.linspace(0.05, 0.1, 8)}
    std = sm.NonlinearKalmanFilter(f, h, Qk, Rk, sm.TT1(), iterations=iterations)
    sr = sm.NonlinearKalmanFilter(f, h, Qk, Rk, sm.TT1(), iterations=iterations, square_root=True)
    a = sr.filter(ys, x0, params=params)
    assert_same(a, std.filter(ys, x0, params=params))
    assert_definite_factor(a)
    step = compiled_step(f, h, sm.TT1(), sr.angle_states, iterations, True)
    assert step.c_sqrt_ekf and not step.c_ekf and step._lib.wait(120)
    pv = np.broadcast_to(np.stack([np.ones(8), params["om"]], axis=1), (2, 8, 2)).copy()
    truth = np.broadcast_to(np.asarray(x0.mean), (2, 8, 12)).copy()
    c = step(np.asarray(x0.mean), np.asarray(x0.cov), ys, sr.Q, sr.R, params=pv, truth=truth)
    vm = step(np.asarray(x0.mean), np.asarray(x0.cov), ys, sr.Q, sr.R, use_c=False, params=pv, truth=truth)
    for key in ("x", "P_chol", "x_pred", "P_pred_chol", "innovation", "S", "loglik", "nis", "nees"):
        scale = np.maximum(np.abs(vm[key]), 1.0)
        assert np.all(np.abs(c[key] - vm[key]) <= 1e-12 * scale), (key, np.max(np.abs(c[key] - vm[key]) / scale))
    assert np.all(np.triu(c["P_chol"], 1) == 0) and np.all(np.triu(c["P_pred_chol"], 1) == 0)


def test_c_square_root_ekf_step_with_a_singular_p0_and_an_exact_measurement():
    """A zero variance in P0 and a zero one in R (singular factors, zero rows in the
    reflections): the C step's x, P = S Sᵀ, S and log-likelihood equal the MX step's to
    rounding; the factor of a singular P is one of several, so S itself may differ."""
    from symmon.filters.gaussian.step import compiled_step

    f, h, Qk, Rk, x0 = stacked_unicycles(3)
    P0 = np.array(x0.cov)
    P0[:, 3] = P0[3, :] = 0
    Rk = Rk.copy()
    Rk[2, 2] = 0.0
    rng = np.random.default_rng(2)
    hx = sp.lambdify(f.inputs, h.outputs, "numpy")
    ys = (np.array([hx(*x0.mean) for _ in range(8)]) + 0.05 * rng.standard_normal((8, 6)))[None]
    sr = sm.NonlinearKalmanFilter(f, h, Qk, Rk, sm.TT1(), square_root=True)
    step = compiled_step(f, h, sm.TT1(), sr.angle_states, 1, True)
    assert step.c_sqrt_ekf and step._lib.wait(120)
    pv = np.broadcast_to(np.stack([np.ones(8), np.full(8, 0.07)], axis=1), (1, 8, 2)).copy()
    c = step(np.asarray(x0.mean), P0, ys, sr.Q, sr.R, params=pv)
    vm = step(np.asarray(x0.mean), P0, ys, sr.Q, sr.R, use_c=False, params=pv)
    for key in ("x", "P", "S", "loglik"):
        assert np.all(np.isfinite(c[key]))
        scale = np.maximum(np.abs(vm[key]), 1.0)
        assert np.all(np.abs(c[key] - vm[key]) <= 1e-12 * scale), key
    assert np.all(np.triu(c["P_chol"], 1) == 0) and np.all(np.diagonal(c["P_chol"], axis1=-2, axis2=-1) >= 0)


def test_the_c_square_root_step_is_the_ekf_and_iekf_from_its_size_on():
    from symmon.filters.gaussian.step import compiled_step

    f, h, *_ = stacked_unicycles(3)
    ang = frozenset(f.angle_outputs)
    assert compiled_step(f, h, sm.TT1(), ang, 3, True).c_sqrt_ekf
    assert not compiled_step(f, h, sm.TT1(), ang).c_sqrt_ekf  # the standard form: the C EKF step
    assert not compiled_step(f, h, sm.UT.cubature(), ang, 1, True).c_sqrt_ekf
    assert not compiled_step(f, h, sm.TT2(), ang, 1, True).c_sqrt_ekf
    assert not compiled_step(F_FIX, H_RB, sm.TT1(), frozenset(F_FIX.angle_outputs), 1, True).c_sqrt_ekf


@pytest.mark.parametrize("transform, k", [(sm.UT(1.0, 2.0, 0.0), 3), (sm.UT.cubature(), 3), (sm.UT(1.0, 2.0, 0.0), 4)],
                         ids=["ut-sx", "cubature-sx", "ut-mx"])
def test_c_square_root_ukf_step_equals_the_standard_form_and_the_vm(transform, k):
    """From C_SQRT_UKF_FROM states on, the square-root UKF (non-negative weights) runs the C
    step of sqrt_ukf_step.c (the sigma points from CasADi, the update by the array form): equal
    to the MX step on CasADi's VM (the Joseph-form factor) to 1e-12 relative, and to the
    standard form to the tolerance of assert_same, with parameters, angle states and outputs,
    missing components and rows, a dense P0 and a rank-deficient Q; the sigma-point pieces in
    SX (12 states) and in MX (16)."""
    from symmon.filters.gaussian._ukfstep import C_SQRT_UKF_FROM, sqrt_ukf_kind
    from symmon.filters.gaussian.step import compiled_step

    f, h, Qk, Rk, x0 = stacked_unicycles(k)
    assert f.n_u >= C_SQRT_UKF_FROM and sqrt_ukf_kind(f.n_u) is (ca.SX if k == 3 else ca.MX)
    rng = np.random.default_rng(4)
    hx = sp.lambdify(f.inputs, h.outputs, "numpy")
    ys = np.array([hx(*x0.mean) for _ in range(8)]) + 0.05 * rng.standard_normal((8, 2 * k))
    ys = np.stack([ys, ys + 0.02 * rng.standard_normal(ys.shape)])
    ys[0, 2, 3] = np.nan
    ys[1, 4] = np.nan
    ys[1, 6, ::2] = np.nan
    params = {"dt": 1.0, "om": np.linspace(0.05, 0.1, 8)}
    std = sm.NonlinearKalmanFilter(f, h, Qk, Rk, transform)
    sr = sm.NonlinearKalmanFilter(f, h, Qk, Rk, transform, square_root=True)
    a = sr.filter(ys, x0, params=params)
    assert_same(a, std.filter(ys, x0, params=params))
    assert_definite_factor(a)
    step = compiled_step(f, h, sr.strategy.transform, sr.angle_states, 1, True)
    assert step.c_sqrt_ukf and not step.c_sqrt_ekf and step._lib.wait(300)
    pv = np.broadcast_to(np.stack([np.ones(8), params["om"]], axis=1), (2, 8, 2)).copy()
    truth = np.broadcast_to(np.asarray(x0.mean), (2, 8, 4 * k)).copy()
    c = step(np.asarray(x0.mean), np.asarray(x0.cov), ys, sr.Q, sr.R, params=pv, truth=truth)
    vm = step(np.asarray(x0.mean), np.asarray(x0.cov), ys, sr.Q, sr.R, use_c=False, params=pv, truth=truth)
    for key in ("x", "P_chol", "x_pred", "P_pred_chol", "innovation", "S", "loglik", "nis", "nees"):
        scale = np.maximum(np.abs(vm[key]), 1.0)
        assert np.all(np.abs(c[key] - vm[key]) <= 1e-12 * scale), (key, np.max(np.abs(c[key] - vm[key]) / scale))
    assert np.all(np.triu(c["P_chol"], 1) == 0) and np.all(np.triu(c["P_pred_chol"], 1) == 0)


def test_the_c_square_root_ukf_step_is_a_plain_rule_without_negative_weights_from_its_size_on():
    from symmon.filters.gaussian.step import compiled_step

    f, h, *_ = stacked_unicycles(3)
    ang = frozenset(f.angle_outputs)
    assert compiled_step(f, h, sm.UT.cubature(), ang, 1, True).c_sqrt_ukf
    assert not compiled_step(f, h, sm.UT.cubature(), ang).c_sqrt_ukf  # the standard form
    assert not compiled_step(f, h, sm.UT.cubature(), ang, 3, True).c_sqrt_ukf  # iterations: the MX step
    assert not compiled_step(f, h, sm.UT(0.5, 2.0, 0.0), ang, 1, True).c_sqrt_ukf  # a negative centre weight
    assert not compiled_step(f, h, sm.TT1(), ang, 1, True).c_sqrt_ukf
    assert not compiled_step(F_FIX, H_RB, sm.UT.cubature(), frozenset(F_FIX.angle_outputs), 1, True).c_sqrt_ukf


def test_square_root_nees_in_the_step_equals_the_nees_of_its_p():
    sr = sm.NonlinearKalmanFilter(F_PAR, H_RB, Q, R, sm.TT1(), square_root=True)
    truth = np.repeat(np.asarray(X0.mean)[None, None], K, axis=1).repeat(2, axis=0)
    res = sr.filter(YS, X0, params=PARAMS, x_true=truth)
    e = truth - res.x
    e[..., 2] = (e[..., 2] + np.pi) % (2 * np.pi) - np.pi
    direct = np.einsum("rki,rki->rk", e, np.linalg.solve(res.P, e[..., None])[..., 0])
    np.testing.assert_allclose(res.nees_values, direct, rtol=1e-9)


def test_square_root_nees_on_the_vm_equals_the_nees_of_its_p():
    """The VM's NEES pass reads each step's factor S as CasADi wrote it (column-major), not
    its transpose: the same NEES as the C loop's and as eᵀ P⁻¹ e."""
    from symmon.filters.gaussian.step import compiled_step

    sr = sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, sm.TT1(), square_root=True)
    step = compiled_step(F_FIX, H_RB, sm.TT1(), sr.angle_states, 1, True)
    ys = np.nan_to_num(YS[:1])
    truth = np.broadcast_to(np.asarray(X0.mean), (1, K, 4)).copy()
    vm = step(np.asarray(X0.mean), np.asarray(X0.cov), ys, sr.Q, sr.R, use_c=False, truth=truth)
    e = truth - vm["x"]
    e[..., 2] = (e[..., 2] + np.pi) % (2 * np.pi) - np.pi
    direct = np.einsum("rki,rki->rk", e, np.linalg.solve(vm["P"], e[..., None])[..., 0])
    np.testing.assert_allclose(vm["nees"], direct, rtol=1e-9)


def test_the_sx_square_root_step_reads_the_lower_triangle_of_its_factor_only():
    """The straight-line step takes the factors' upper triangles as structural zeros (no
    product or reflection works on them): an upper triangle of garbage changes nothing."""
    from symmon.filters.gaussian.step import compiled_step

    sr = sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, sm.TT1(), square_root=True)
    step = compiled_step(F_FIX, H_RB, sm.TT1(), sr.angle_states, 1, True)
    S0 = np.linalg.cholesky(X0.cov)
    dirty = S0 + np.triu(np.full((4, 4), 7.0), 1)
    ys = np.nan_to_num(YS[:1])
    for use_c in (True, False):
        a = step(np.asarray(X0.mean), S0, ys, sr.Q, sr.R, use_c=use_c, factored=True)
        b = step(np.asarray(X0.mean), dirty, ys, sr.Q, sr.R, use_c=use_c, factored=True)
        for key in ("x", "P", "loglik"):
            np.testing.assert_array_equal(a[key], b[key])


def test_square_root_refusals():
    with pytest.raises(ArgumentTypeError, match="square_root must be True or False"):
        sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, sm.TT1(), square_root="yes")
    with pytest.raises(SymmonError, match="square_root=True needs one transform"):
        sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, sm.Adaptive(), square_root=True)
    with pytest.raises(SymmonError, match="do not reproduce the covariance"):
        sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, sm.GaussHermite(1), square_root=True)


# --- The square-root RTS smoother.


@pytest.mark.parametrize("family", ["UKF-negative-centre", "EKF2"])
def test_square_root_smoother_equals_the_standard_smoother(family):
    opts = FAMILIES[family]
    std = sm.NonlinearKalmanFilter(F_PAR, H_RB, Q, R, **opts).smooth(YS, X0, params=PARAMS)
    sr = sm.NonlinearKalmanFilter(F_PAR, H_RB, Q, R, square_root=True, **opts).smooth(YS, X0, params=PARAMS)
    for u, w in ((sr.x, std.x), (sr.P, std.P)):
        assert np.all(np.abs(u - w) <= 1e-10 * np.maximum(np.abs(w), 1.0))
    np.testing.assert_allclose(sr.P_chol, np.linalg.cholesky(std.P), rtol=1e-9, atol=1e-12)
    assert std.P_chol is None


# --- The C export of a square-root filter.


@pytest.mark.skipif(__import__("shutil").which("gcc") is None, reason="gcc not found")
@pytest.mark.parametrize("family", ["UKF-negative-centre", "IEKF"])
def test_exported_square_root_c_equals_the_filter(tmp_path, family):
    """NAME_predict(x, S) and NAME_update(x, S, p, y, &loglik) on the factor S (row-major),
    built with -Wall -Wextra -Werror -pedantic: x, S and the log-likelihood equal
    ``kf.filter``'s to 1e-9 (the same graphs, another evaluation order)."""
    from test_export import build, run_example

    kf = sm.NonlinearKalmanFilter(F_PAR, H_RB, Q, R, square_root=True, **FAMILIES[family])
    paths = kf.export_c(tmp_path, name="sr_rb")
    header = paths[1].read_text()
    assert "double *S, const double *p" in header and "lower triangular Cholesky factor" in header
    ys = YS[0][~np.isnan(YS[0]).any(axis=1)]  # the exported update has no mask
    S0 = np.linalg.cholesky(X0.cov)
    code, rows = run_example(build(tmp_path, "sr_rb"), X0.mean, S0, ys, params=[1.0, 0.1])
    assert code == 0 and rows.shape == (len(ys), 2 + 4 + 16 + 1)
    ref = kf.filter(ys, X0, params={"dt": 1.0, "om": 0.1})
    np.testing.assert_allclose(rows[:, 2:6], ref.x, rtol=1e-9, atol=1e-9 * np.abs(ref.x).max())
    np.testing.assert_allclose(rows[:, 6:-1].reshape(-1, 4, 4), ref.P_chol, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rows[:, -1], np.cumsum(ref.loglik), rtol=1e-9, atol=1e-9)


def test_the_bank_size_limit_counts_the_factors():
    from symmon.errors import ResourceError
    from symmon.filters.inputs import MAX_BANK_NUMBERS, check_call

    # (1 + 4 + 16 + 16) numbers per step with P and its factor: 37; without the factor, 21.
    steps = MAX_BANK_NUMBERS // 30
    ys = np.broadcast_to(np.zeros(2), (steps, 2))
    std = sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, sm.TT1())
    check_call(std, ys, X0, None, keep=("x", "P"))  # the standard form's arrays fit
    with pytest.raises(ResourceError, match="37"):
        sm.NonlinearKalmanFilter(F_FIX, H_RB, Q, R, sm.TT1(), square_root=True).filter(ys, X0, keep=("x", "P"))


def test_the_fitted_filter_of_a_square_root_filter_is_square_root():
    from symmon.filters.gaussian.fit import FitResult

    sr = sm.NonlinearKalmanFilter(F_PAR, H_RB, Q, R, sm.TT1(), square_root=True)
    fit = FitResult({"om": 0.1}, {"om": 0.01}, np.eye(1), 0.0, 1, {"dt": 1.0, "om": 0.1}, None, kf=sr)
    assert fit.filter.square_root and fit.filter.method == "SR-EKF"
