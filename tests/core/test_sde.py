"""SDE: the declaration's checks and its discretisation (closed forms against textbooks,
Van Loan against scipy, orders of convergence, one-interval moments against Monte Carlo)."""

from __future__ import annotations

import mpmath as mp
import numpy as np
import pytest
import scipy.linalg
import sympy as sp

import symmon as sm
from symmon.core.discretize import van_loan_numeric
from symmon.errors import CovarianceError, DiscretizationError, ModelError, ShapeError

#: Agreement of two evaluations of one closed form (rounding of ~20 flops in doubles).
EXACT_RTOL = 1e-13
#: Standard errors a Monte Carlo difference may reach.
N_SE = 5.0

dt = sp.Symbol("dt", positive=True)
p, v, acc = sp.symbols("p v acc", real=True)
q, theta, sigma, alpha, sigma_m, omega = sp.symbols("q theta sigma alpha sigma_m omega", positive=True)


def _zero(M) -> bool:
    return sp.simplify(sp.Matrix(M)) == sp.zeros(*sp.Matrix(M).shape)


def _wna():
    return sm.SDE([p, v], [v, 0], diffusion=[0, 1], spectral_density=q, params=[q])


# --------------------------------------------------------------------------- closed forms
def test_white_noise_acceleration_exact_is_the_textbook_F_and_Q():
    sde = _wna()
    assert _zero(sde.transition_matrix(dt) - sp.Matrix([[1, dt], [0, 1]]))
    assert _zero(sde.noise_cov(dt) - q * sp.Matrix([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))


def test_the_discretised_model_has_dt_as_parameter_and_its_noise_factor_gives_Q():
    f = _wna().discretize("exact")
    assert f.params == (q, dt)
    assert f.structure == "additive"
    G = f.pi
    assert _zero(G * G.T - q * sp.Matrix([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))
    assert _zero(f.f - sp.Matrix([p + dt * v, v]))


def test_ornstein_uhlenbeck_exact():
    x = sp.Symbol("x", real=True)
    sde = sm.SDE([x], [-theta * x], diffusion=[sigma], params=[theta, sigma])
    assert _zero(sde.transition_matrix(dt) - sp.Matrix([[sp.exp(-theta * dt)]]))
    assert _zero(sde.noise_cov(dt) - sp.Matrix([[sigma**2 * (1 - sp.exp(-2 * theta * dt)) / (2 * theta)]]))


def test_singer_model_against_bar_shalom_li_kirubarajan():
    # Bar-Shalom, Li & Kirubarajan (2001), Sec. 8.2.3: F and Q of the Singer model, with the
    # continuous noise density 2 α σ_m² of the acceleration.
    sde = sm.SDE([p, v, acc], [v, acc, -alpha * acc], diffusion=[0, 0, 1],
                 spectral_density=2 * alpha * sigma_m**2, params=[alpha, sigma_m])
    a, T = alpha, dt
    e1, e2 = sp.exp(-a * T), sp.exp(-2 * a * T)
    F = sp.Matrix([[1, T, (a * T - 1 + e1) / a**2], [0, 1, (1 - e1) / a], [0, 0, e1]])
    q11 = (1 - e2 + 2 * a * T + 2 * a**3 * T**3 / 3 - 2 * a**2 * T**2 - 4 * a * T * e1) / (2 * a**5)
    q12 = (e2 + 1 - 2 * e1 + 2 * a * T * e1 - 2 * a * T + a**2 * T**2) / (2 * a**4)
    q13 = (1 - e2 - 2 * a * T * e1) / (2 * a**3)
    q22 = (4 * e1 - 3 - e2 + 2 * a * T) / (2 * a**3)
    q23 = (e2 + 1 - 2 * e1) / (2 * a**2)
    q33 = (1 - e2) / (2 * a)
    Q = 2 * a * sigma_m**2 * sp.Matrix([[q11, q12, q13], [q12, q22, q23], [q13, q23, q33]])
    assert _zero(sde.transition_matrix(dt) - F)
    assert _zero(sde.noise_cov(dt) - Q)


def test_coordinated_turn_with_known_rate_against_bar_shalom_li_kirubarajan():
    # Bar-Shalom, Li & Kirubarajan (2001), Sec. 11.7.1 (state [ξ, ξ', η, η']) with white-noise
    # acceleration of density q in both coordinates.
    xi, dxi, eta, deta = sp.symbols("xi dxi eta deta", real=True)
    sde = sm.SDE([xi, dxi, eta, deta], [dxi, -omega * deta, deta, omega * dxi],
                 diffusion=[[0, 0], [1, 0], [0, 0], [0, 1]], spectral_density=q * sp.eye(2), params=[omega, q])
    w, T = omega, dt
    s, c = sp.sin(w * T), sp.cos(w * T)
    F = sp.Matrix([[1, s / w, 0, -(1 - c) / w], [0, c, 0, -s], [0, (1 - c) / w, 1, s / w], [0, s, 0, c]])
    Q = q * sp.Matrix([
        [2 * (w * T - s) / w**3, (1 - c) / w**2, 0, (w * T - s) / w**2],
        [(1 - c) / w**2, T, -(w * T - s) / w**2, 0],
        [0, -(w * T - s) / w**2, 2 * (w * T - s) / w**3, (1 - c) / w**2],
        [(w * T - s) / w**2, 0, (1 - c) / w**2, T]])
    assert _zero(sde.transition_matrix(dt) - F)
    assert _zero(sde.noise_cov(dt) - Q)


A_DAMPED = np.array([[0.0, 1.0, 0.0], [-2.0, -0.5, 1.0], [0.0, 0.0, -1.5]])   # complex eigenvalues
L_DAMPED = np.array([[0.0], [0.3], [1.0]])


@pytest.fixture(scope="module")
def damped():
    states = sp.symbols("x0:3", real=True)
    sde = sm.SDE(states, list(sp.Matrix(A_DAMPED.tolist()) * sp.Matrix(states)), diffusion=L_DAMPED.tolist(),
                 spectral_density=[[0.7]])
    return sde.transition_matrix(dt), sde.noise_cov(dt)


def _van_loan_mpmath(A, B, step, digits=40):
    """Van Loan's block exponential in `digits` digits (mpmath): the reference of both the
    closed form and scipy."""
    with mp.workdps(digits):
        n = A.shape[0]
        M = mp.zeros(2 * n, 2 * n)
        for i in range(n):
            for j in range(n):
                M[i, j] = -mp.mpf(float(A[i, j]))
                M[i, n + j] = mp.mpf(float(B[i, j]))
                M[n + i, n + j] = mp.mpf(float(A[j, i]))
        E = mp.expm(M * mp.mpf(float(step)))
        F = E[n:, n:].T
        Q = F * E[:n, n:]
        return np.array(F.tolist(), dtype=float), np.array(Q.tolist(), dtype=float)


#: scipy's expm of the block matrix loses a few digits at the larger steps (6e-13 relative
#: in Q at dt = 2.5, measured against 40-digit mpmath).
SCIPY_RTOL = 1e-11


@pytest.mark.parametrize("step", [0.01, 0.37, 2.5])
def test_closed_form_van_loan_matches_scipy_expm_of_the_block_matrix(damped, step):
    A, L = A_DAMPED, L_DAMPED
    B = L @ L.T * 0.7
    F_ref, Q_ref = _van_loan_mpmath(A, np.array([[0, 0, 0], [0, 0.09, 0.3], [0, 0.3, 1.0]]) * 0.7, step)
    Fs = np.array(damped[0].subs(dt, step).evalf(30), dtype=float)
    Qs = np.array(damped[1].subs(dt, step).evalf(30), dtype=float)
    scale = np.abs(Q_ref).max()
    np.testing.assert_allclose(Fs, F_ref, rtol=0, atol=EXACT_RTOL * max(1.0, np.abs(F_ref).max()))
    np.testing.assert_allclose(Qs, Q_ref, rtol=0, atol=EXACT_RTOL * scale)
    # scipy.linalg.expm of the block matrix, as written out by hand and as van_loan_numeric
    E = scipy.linalg.expm(np.block([[-A, B], [np.zeros((3, 3)), A.T]]) * step)
    np.testing.assert_allclose(Qs, E[3:, 3:].T @ E[:3, 3:], rtol=0, atol=SCIPY_RTOL * scale)
    F_num, Q_num = van_loan_numeric(A, B, step)
    np.testing.assert_allclose(Q_num, Qs, rtol=0, atol=SCIPY_RTOL * scale)
    np.testing.assert_allclose(F_num, Fs, rtol=0, atol=SCIPY_RTOL)


def test_exact_with_an_affine_drift_has_the_constant_term():
    x = sp.Symbol("x", real=True)
    f = sm.SDE([x], [-theta * (x - 2)], diffusion=[1], params=[theta]).discretize("exact", dt=dt)
    mean = f.noise_free().outputs[0]
    assert sp.simplify(mean - (2 + (x - 2) * sp.exp(-theta * dt))) == 0


def test_exact_refuses_a_nonlinear_drift():
    x = sp.Symbol("x", real=True)
    with pytest.raises(DiscretizationError, match="not linear"):
        sm.SDE([x], [-x**3]).discretize("exact")


def test_local_linear_of_a_linear_drift_is_exact():
    f = _wna().discretize("local_linear", substeps=3)
    g = _wna().discretize("exact")
    assert f.outputs == g.outputs


# --------------------------------------------------------------------------- validation
@pytest.mark.parametrize("kwargs, error, match", [
    (dict(states=[p, v], drift=[v]), ModelError, "one expression per state"),
    (dict(states=[p, v], drift=[v, sp.Symbol("u")]), ModelError, "unknown symbols"),
    (dict(states=[p, v], drift=[v, 0], diffusion=[0, 1, 2]), ShapeError, "one row per state"),
    (dict(states=[p, v], drift=[v, 0], diffusion=[0, 1], spectral_density=[[1, 0], [0, 1]]), ShapeError,
     "1 columns but spectral_density is 2x2"),
    (dict(states=[p, v], drift=[v, 0], diffusion=[0, 1], spectral_density=-1.0), CovarianceError,
     "positive semi-definite"),
    (dict(states=[p, v], drift=[v, 0], spectral_density=[[1, 2], [0, 1]]), CovarianceError, "symmetric"),
    (dict(states=[p, v], drift=[v, 0], spectral_density=[[1, 2], [2, 1]]), CovarianceError, "eigenvalue"),
    (dict(states=[p, v], drift=[v, 0], diffusion=[0, 1], spectral_density=-q, params=[q]), CovarianceError,
     "negative"),
    (dict(states=[p, v], drift=[v, 0], diffusion=[0, 1], spectral_density=p), ModelError, "constant"),
    (dict(states=[p, p], drift=[v, 0]), ModelError, "duplicate"),
    (dict(states=[p, v], drift=[v, q], params=[q, p]), ModelError, "both as states and params"),
    (dict(states=[p, v], drift=["v", 0]), ModelError, "string"),
    (dict(states=[p, v], drift=[v, 0], angles=[5]), ModelError, "out of range"),
    (dict(states=[], drift=[]), ModelError, "at least one state"),
])
def test_bad_declarations_name_the_argument(kwargs, error, match):
    with pytest.raises(error, match=match):
        sm.SDE(**kwargs)


def test_a_symbolic_spectral_density_that_may_be_psd_is_accepted():
    sde = sm.SDE([p, v], [v, 0], diffusion=[0, 1], spectral_density=sp.Symbol("r", real=True),
                 params=[sp.Symbol("r", real=True)])
    assert sde.m == 1


@pytest.mark.parametrize("call, match", [
    (lambda s: s.discretize("heun"), "method must be one of"),
    (lambda s: s.discretize("euler", substeps=0), "substeps"),
    (lambda s: s.discretize("exact", substeps=2), "substeps does not apply"),
    (lambda s: s.discretize("euler", dt=sp.Symbol("q", positive=True)), "name of a state or parameter"),
    (lambda s: s.discretize("euler", dt=-1.0), "positive number"),
])
def test_bad_discretisation_arguments(call, match):
    with pytest.raises(ModelError, match=match):
        call(_wna())


def test_order_15_and_local_linear_need_additive_noise():
    x = sp.Symbol("x", real=True)
    sde = sm.SDE([x], [-x], diffusion=[x])
    for method in ("taylor1.5", "local_linear"):
        with pytest.raises(DiscretizationError, match="additive noise"):
            sde.discretize(method)
    assert sde.discretize("euler").n_v == 1


def test_angles_become_angle_inputs_and_outputs():
    th, om = sp.symbols("th om", real=True)
    f = sm.SDE([th, om], [om, 0], diffusion=[0, 1], angles=[th]).discretize("euler")
    assert f.angle_outputs == {0} and f.angle_inputs == {0}


# --------------------------------------------------------------------------- convergence
X = sp.Symbol("x", real=True)
SIGMA = 0.5
NONLINEAR = sm.SDE([X], [sp.sin(X) - X**3 / 2], diffusion=[SIGMA])


def _brownian(paths: int, fine: int, T: float, seed: int):
    """Increments ΔW and iterated integrals ΔZ = ∫(W(s) − W(t_i)) ds on a fine grid of
    `fine` steps, drawn jointly (Kloeden & Platen 1992, eq. 10.4.4)."""
    rng = np.random.default_rng(seed)
    d = T / fine
    u1, u2 = rng.standard_normal((2, paths, fine))
    dW = np.sqrt(d) * u1
    dZ = 0.5 * d**1.5 * (u1 + u2 / np.sqrt(3))
    return dW, dZ


def _coarsen(dW, dZ, factor: int, d: float):
    """ΔW and ΔZ of steps `factor` times longer, summed exactly from the fine ones."""
    P, K = dW.shape
    dW3 = dW.reshape(P, K // factor, factor)
    dZ3 = dZ.reshape(P, K // factor, factor)
    W_before = np.cumsum(dW3, axis=2) - dW3   # W(t_i) − W(t_start) within the coarse step
    return dW3.sum(axis=2), (W_before * d + dZ3).sum(axis=2)


def _run(model, dW, dZ, h: float, x0: float) -> np.ndarray:
    fn = sp.lambdify([X, *model.noise, *model.params], model.outputs[0], "numpy")
    x = np.full(dW.shape[0], x0)
    for k in range(dW.shape[1]):
        xi1 = dW[:, k] / np.sqrt(h)
        xi2 = np.sqrt(3) * (2 * dZ[:, k] / h**1.5 - xi1)   # ΔZ = ½ h^{3/2}(ξ₁ + ξ₂/√3)
        noise = [xi1, xi2][: model.n_v]
        x = fn(x, *noise, h) * np.ones_like(x)
    return x


@pytest.mark.parametrize("method, order", [("euler", 1.0), ("taylor1.5", 1.5), ("local_linear", 1.0)])
def test_strong_orders_of_convergence(method, order):
    """The RMS error at T = 1 against the order-1.5 scheme on a grid 2⁵ times finer than the
    finest step, fitted on log–log: the slope is the strong order (additive noise: Euler and
    the local-linear scheme 1, the Itô–Taylor scheme 1.5).  The tolerance: 0.15 for the
    curvature of the error curve at the coarse steps plus N_SE bootstrap standard errors of
    the slope."""
    T, paths, fine = 1.0, 1000, 2**11
    dW, dZ = _brownian(paths, fine, T, seed=7)
    d = T / fine
    ref = _run(NONLINEAR.discretize("taylor1.5"), dW, dZ, d, 1.0)
    model = NONLINEAR.discretize(method)
    hs, errs = [], []
    for k in range(2, 7):          # h = 1/4 … 1/64
        factor = fine // 2**k
        cW, cZ = _coarsen(dW, dZ, factor, d)
        x = _run(model, cW, cZ, T / 2**k, 1.0)
        hs.append(T / 2**k)
        errs.append((x - ref) ** 2)
    errs = np.array(errs)
    slope = np.polyfit(np.log(hs), 0.5 * np.log(errs.mean(axis=1)), 1)[0]
    rng = np.random.default_rng(0)
    boot = []
    for _ in range(200):
        idx = rng.integers(0, paths, paths)
        boot.append(np.polyfit(np.log(hs), 0.5 * np.log(errs[:, idx].mean(axis=1)), 1)[0])
    se = float(np.std(boot))
    assert abs(slope - order) < 0.15 + N_SE * se, (slope, se)


def test_exact_discretisation_of_ou_is_exact_at_any_step():
    x = sp.Symbol("x", real=True)
    f = sm.SDE([x], [-theta * x], diffusion=[sigma], params=[theta, sigma]).discretize("exact")
    fn = sp.lambdify([x, *f.noise, *f.params], f.outputs[0])
    # mean and variance of x(dt) from x(0) = 1: e^{−θ dt} and σ²(1 − e^{−2θ dt})/(2θ)
    assert fn(1.0, 0.0, 0.8, 0.3, 2.0) == pytest.approx(np.exp(-1.6), rel=EXACT_RTOL)
    slope = fn(1.0, 1.0, 0.8, 0.3, 2.0) - fn(1.0, 0.0, 0.8, 0.3, 2.0)
    assert slope**2 == pytest.approx(0.09 * (1 - np.exp(-3.2)) / 1.6, rel=EXACT_RTOL)


# --------------------------------------------------------------------------- simulate
@pytest.mark.parametrize("method, substeps", [("taylor1.5", 4), ("rk4", 8), ("local_linear", 8)])
def test_simulate_one_interval_moments_match_a_fine_euler_maruyama_monte_carlo(method, substeps):
    """One interval of dt = 0.5 from x₀ = 1 by ``sm.simulate`` on the discretised model,
    against Euler–Maruyama with 2¹⁰ sub-steps: mean and variance agree within N_SE standard
    errors of their difference (the schemes' weak bias at these sub-steps, O(h²) for the
    order-1.5 scheme, is not resolved by 2·10⁴ runs)."""
    step, N = 0.5, 20000
    f = NONLINEAR.discretize(method, substeps=substeps)
    h = sm.Model([X], [X])
    xs, _ = sm.simulate(f, h, np.eye(f.n_v), [[1.0]], sm.Gaussian([1.0], [[0.0]]), steps=1, runs=N,
                        params={"dt": step}, seed=3)
    a = xs[:, 0, 0]
    rng = np.random.default_rng(11)
    fine = 2**10
    d = step / fine
    b = np.ones(N)
    for _ in range(fine):
        b = b + (np.sin(b) - b**3 / 2) * d + SIGMA * np.sqrt(d) * rng.standard_normal(N)
    se_mean = np.sqrt(a.var() / N + b.var() / N)
    assert abs(a.mean() - b.mean()) < N_SE * se_mean
    def var_se(s):
        c = s - s.mean()
        return np.sqrt(((c**4).mean() - c.var() ** 2) / N)
    se_var = np.hypot(var_se(a), var_se(b))
    assert abs(a.var() - b.var()) < N_SE * se_var


# --------------------------------------------------------------------------- composed sub-steps
def _run_composed(model, dW, dZ, h: float, x0: float, substeps: int) -> np.ndarray:
    """x at the end of the path, by the compiled composed model: each of its steps takes
    ``substeps`` consecutive fine increments (ξ₁, ξ₂ per sub-step, in its noise order)."""
    from symmon.compile.compiled import compiled_with_params

    cm = compiled_with_params(model)
    xi1 = dW / np.sqrt(h)
    xi2 = np.sqrt(3) * (2 * dZ / h**1.5 - xi1)
    P, K = dW.shape
    x = np.full(P, x0)
    for k in range(0, K, substeps):
        noise = np.stack([xi1[:, k:k + substeps], xi2[:, k:k + substeps]], axis=2).reshape(P, -1)
        W = np.column_stack([x, noise, np.full(P, h * substeps)])
        x = cm.eval_g(np.ascontiguousarray(W))[:, 0]
    return x


@pytest.mark.parametrize("substeps", [8, 32])
def test_composed_nonlinear_substeps_stay_linear_in_size_and_converge(substeps):
    """``taylor1.5`` with 8 and 32 sub-steps on sin x − x³/2 (before the composition kept its
    DAG, 8 sub-steps did not finish): its distinct nodes grow linearly with the sub-steps, the
    compiled model equals the one-sub-step model applied ``substeps`` times on the same draws
    (the same arithmetic, to rounding), and on one Brownian path its error at T = 1 against
    the fine reference falls at the scheme's order 1.5 between dt/8 and dt/32."""
    from symmon.core import dag
    from symmon.timelimit import deadline

    with deadline(120):  # fails, rather than hangs, if the growth comes back
        model = NONLINEAR.discretize("taylor1.5", substeps=substeps)
    one = NONLINEAR.discretize("taylor1.5")
    assert model.n_v == 2 * substeps
    assert dag.measure(model.outputs)[0] < 40 * substeps
    T, paths, fine = 1.0, 200, 2**13
    dW, dZ = _brownian(paths, fine, T, seed=5)
    d = T / fine
    ref = _run(one, dW, dZ, d, 1.0)
    h = T / 16 / substeps                      # steps of T/16, sub-steps of it
    cW, cZ = _coarsen(dW, dZ, int(round(h / d)), d)
    composed = _run_composed(model, cW, cZ, h, 1.0, substeps)
    np.testing.assert_allclose(composed, _run(one, cW, cZ, h, 1.0), rtol=1e-10, atol=1e-12)
    err = np.sqrt(np.mean((composed - ref) ** 2))
    coarse = _run(one, *_coarsen(dW, dZ, fine // 16, d), T / 16, 1.0)
    err_one = np.sqrt(np.mean((coarse - ref) ** 2))
    assert err < err_one * substeps ** -1.5 * 3, (err, err_one)   # order 1.5, within a factor 3


def test_with_params_of_composed_substeps_keeps_the_dag():
    """Substituting dt into 32 composed sub-steps rebuilds each node once (xreplace rebuilt
    the tree, 10³⁴ nodes: advise_filter on a nonlinear SDE hung there); the values are those
    of the model with dt as an input."""
    from symmon.compile.compiled import compiled, compiled_with_params
    from symmon.core import dag
    from symmon.timelimit import deadline

    model = NONLINEAR.discretize("taylor1.5", substeps=32)
    with deadline(120):
        fixed = model.with_params({"dt": 0.5})
    assert fixed.params == () and dag.measure(fixed.outputs)[0] <= dag.measure(model.outputs)[0]
    W = np.random.default_rng(0).standard_normal((5, 1 + model.n_v))
    with_dt = compiled_with_params(model).eval_g(np.column_stack([W, np.full(5, 0.5)]))
    np.testing.assert_allclose(compiled(fixed).eval_g(W), with_dt, rtol=1e-13, atol=1e-14)
