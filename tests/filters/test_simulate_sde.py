"""``sm.simulate`` with an SDE as f: the truth by the exact transition of a linear SDE and by
the order-1.5 scheme otherwise, at measurement times ``times`` (issue 50, item 4)."""

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentError
from symmon.filters.simulation import TRUTH_SUBSTEPS, check_times, truth_model

#: Standard errors allowed between a Monte Carlo moment and its exact value.
N_SE = 4.5

P, V = sp.symbols("p v", real=True)
Q_SYM = sp.Symbol("q", positive=True)
DT = sp.Symbol("dt", positive=True)
WNA = sm.SDE([P, V], [V, 0], diffusion=[0, 1], spectral_density=Q_SYM, params=[Q_SYM], name="wna")
H = sm.Model([P, V], [P])
X = sp.Symbol("x", real=True)
NONLINEAR = sm.SDE([X], [sp.sin(X) - X**3 / 2], diffusion=[0.4], name="nl")
HX = sm.Model([X], [X])
POINT = sm.Gaussian([1.0, 2.0], np.zeros((2, 2)))


def exact_moments(x0, q, dt):
    """F x0 and Q(dt) of white-noise acceleration, from the SDE's symbolic results."""
    F = np.array(WNA.transition_matrix(DT).subs(DT, dt), dtype=float)
    Q = np.array(WNA.noise_cov(DT).subs({DT: dt, Q_SYM: q}), dtype=float)
    return F @ np.asarray(x0), Q


def assert_moments(samples, mean, cov):
    """Sample mean and covariance equal (mean, cov) within N_SE standard errors, entry by entry."""
    N = samples.shape[0]
    c = samples - samples.mean(axis=0)
    se_mean = np.sqrt(np.diag(np.cov(samples.T)) / N)
    assert np.all(np.abs(samples.mean(axis=0) - mean) < N_SE * se_mean), (samples.mean(axis=0), mean)
    S = c.T @ c / (N - 1)
    for i in range(cov.shape[0]):
        for j in range(cov.shape[1]):
            prod = c[:, i] * c[:, j]
            se = np.sqrt(prod.var() / N)
            assert abs(S[i, j] - cov[i, j]) < N_SE * se, (i, j, S[i, j], cov[i, j], se)


def test_shapes_with_times_and_runs():
    times = [0.5, 0.7, 2.0, 2.1]
    xs, ys = sm.simulate(WNA, H, None, [[1.0]], POINT, times=times, params={"q": 0.3}, seed=0)
    assert xs.shape == (4, 2) and ys.shape == (4, 1)
    xs, ys = sm.simulate(WNA, H, None, [[1.0]], POINT, steps=4, runs=3, times=times, params={"q": 0.3})
    assert xs.shape == (3, 4, 2) and ys.shape == (3, 4, 1)


def test_reproducible_per_seed():
    kw = dict(times=[0.5, 1.5, 1.6], runs=4, params={"q": 0.3})
    a = sm.simulate(WNA, H, None, [[1.0]], POINT, seed=7, **kw)
    b = sm.simulate(WNA, H, None, [[1.0]], POINT, seed=7, **kw)
    c = sm.simulate(WNA, H, None, [[1.0]], POINT, seed=8, **kw)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])
    g = sm.simulate(NONLINEAR, HX, None, [[0.1]], sm.Gaussian([1.0], [[0.1]]), times=[0.3, 0.9], runs=3, seed=2)
    assert np.array_equal(g[0], sm.simulate(NONLINEAR, HX, None, [[0.1]], sm.Gaussian([1.0], [[0.1]]),
                                            times=[0.3, 0.9], runs=3, seed=2)[0])


def test_an_sde_is_its_exact_discretisation_with_the_steps_of_its_times():
    """The linear SDE with times is, number for number, the "exact" model with params['dt']
    the differences of the times (from t0)."""
    times = np.array([1.5, 1.7, 3.2, 3.25])
    xs, ys = sm.simulate(WNA, H, None, [[1.0]], POINT, times=times, t0=1.0, runs=3, params={"q": 0.3}, seed=4)
    f = WNA.discretize("exact")
    dts = np.diff(np.concatenate([[1.0], times]))
    xs2, ys2 = sm.simulate(f, H, np.eye(f.n_v), [[1.0]], POINT, steps=4, runs=3, params={"q": 0.3, "dt": dts},
                           seed=4)
    assert np.array_equal(xs, xs2) and np.array_equal(ys, ys2)
    # ... and a discretised Model takes times for its dt parameter
    xs3, _ = sm.simulate(f, H, np.eye(f.n_v), [[1.0]], POINT, times=times, t0=1.0, runs=3, params={"q": 0.3},
                         seed=4)
    assert np.array_equal(xs, xs3)


def test_a_nonlinear_sde_is_simulated_by_the_order_one_and_a_half_scheme_with_substeps():
    """The truth of a nonlinear SDE is the order-1.5 scheme at ``substeps`` sub-steps: the
    same draws as the composed model ``discretize("taylor1.5", substeps=...)``."""
    g = truth_model(NONLINEAR)
    assert g.n_v == 2 and [str(s) for s in g.params] == ["dt"]  # ξ₁ and ξ₂ of one sub-step
    x0 = sm.Gaussian([1.0], [[0.1]])
    times = [0.25, 1.0]
    for substeps in (2, TRUTH_SUBSTEPS):
        xs, ys = sm.simulate(NONLINEAR, HX, None, [[0.1]], x0, times=times, runs=5, seed=3, substeps=substeps)
        ref = NONLINEAR.discretize("taylor1.5", substeps=substeps)
        xs2, ys2 = sm.simulate(ref, HX, np.eye(ref.n_v), [[0.1]], x0, steps=2, runs=5, params={"dt": [0.25, 0.75]},
                               seed=3)
        assert np.allclose(xs, xs2, rtol=1e-13, atol=1e-13) and np.allclose(ys, ys2, rtol=1e-13, atol=1e-13)
    default = sm.simulate(NONLINEAR, HX, None, [[0.1]], x0, times=times, runs=5, seed=3)[0]
    assert np.array_equal(default, xs)  # substeps=None is TRUTH_SUBSTEPS
    one = sm.simulate(NONLINEAR, HX, None, [[0.1]], x0, times=times, runs=5, seed=3, substeps=1)[0]
    assert not np.allclose(one, xs)


def test_linear_one_interval_moments_are_the_exact_discretisation():
    """x(dt) from a known x0: the sample mean and covariance of 2·10⁴ runs are F x0 and Q(dt)
    (the SDE's symbolic results) within their standard errors."""
    q, dt, N = 0.8, 1.7, 20000
    xs, _ = sm.simulate(WNA, H, None, [[1.0]], POINT, times=[dt], runs=N, params={"q": q}, seed=11)
    mean, cov = exact_moments([1.0, 2.0], q, dt)
    assert_moments(xs[:, 0], mean, cov)


def test_irregular_times_compose_to_the_exact_transition_over_their_span():
    """Exact transitions compose: after steps of 0.2, 1.1, 0.05, 0.9 from t0 = 0.5, x is
    distributed as one exact step of their sum, 2.25."""
    q, N = 0.5, 20000
    times = 0.5 + np.cumsum([0.2, 1.1, 0.05, 0.9])
    xs, _ = sm.simulate(WNA, H, None, [[1.0]], POINT, times=times, t0=0.5, runs=N, params={"q": q}, seed=5)
    mean, cov = exact_moments([1.0, 2.0], q, 2.25)
    assert_moments(xs[:, -1], mean, cov)
    # the moments test can fail: the same runs are not those of a step of 2.0
    wrong_mean, wrong_cov = exact_moments([1.0, 2.0], q, 2.0)
    with pytest.raises(AssertionError):
        assert_moments(xs[:, -1], wrong_mean, wrong_cov)


def test_check_times_gives_the_steps():
    assert np.allclose(check_times([1.0, 1.5, 4.0], t0=0.5), [0.5, 0.5, 2.5])


@pytest.mark.parametrize("kwargs, match", [
    (dict(times=[1.0, 1.0, 2.0]), "strictly increasing: times\\[1\\]"),
    (dict(times=[2.0, 1.0]), "strictly increasing"),
    (dict(times=[0.0, 1.0]), "after t0"),
    (dict(times=[1.0, 2.0], t0=1.5), "after t0"),
    (dict(times=[1.0, np.nan]), "finite"),
    (dict(times=[[1.0, 2.0]]), "1-D"),
    (dict(times=[]), "non-empty"),
    (dict(times="abc"), "times must be"),
    (dict(times=[1.0], t0=np.inf), "t0 must be a finite number"),
    (dict(times=[1.0, 2.0], steps=3), "len\\(times\\)"),
    (dict(times=[1.0], params={"q": 1.0, "dt": 1.0}), "not both"),
    (dict(params={"q": 1.0}, steps=2), "needs its steps"),
    (dict(params={"q": 1.0, "dt": -1.0}, steps=2), "positive"),
    (dict(params={"q": 1.0, "dt": [1.0, 0.0]}, steps=2), "positive"),
    (dict(params={"q": 1.0, "dt": 1.0}, steps=2, t0=1.0), "t0 applies only with times"),
    (dict(times=[1.0], substeps=0), "substeps"),
])
def test_bad_times_and_steps_are_refused_naming_them(kwargs, match):
    kwargs.setdefault("params", {"q": 1.0})
    with pytest.raises(ArgumentError, match=match):
        sm.simulate(WNA, H, None, [[1.0]], POINT, **kwargs)


def test_q_substeps_and_times_where_they_do_not_apply():
    with pytest.raises(ArgumentError, match="Q must be None"):
        sm.simulate(WNA, H, np.eye(2), [[1.0]], POINT, times=[1.0], params={"q": 1.0})
    f = sm.Model([P, V], [P + V, V])
    with pytest.raises(ArgumentError, match="substeps applies to an SDE"):
        sm.simulate(f, H, np.eye(2), [[1.0]], POINT, steps=2, substeps=2)
    with pytest.raises(ArgumentError, match="times needs an SDE"):
        sm.simulate(f, H, np.eye(2), [[1.0]], POINT, times=[1.0, 2.0])


def test_models_without_the_new_arguments_are_unchanged():
    """The Model path draws the same numbers as before the SDE arguments (values recorded
    with the previous implementation: seed 1, 0.9 x, Q 0.1, R 0.01, x0 = 1)."""
    xs, ys = sm.simulate(sm.Model([X], [0.9 * X]), HX, [[0.1]], [[0.01]], sm.Gaussian([1.0], [[0.0]]),
                         steps=3, seed=1)
    rng = np.random.default_rng(1)
    x = np.array([[1.0]]) + 0.0 * rng.standard_normal((1, 1))  # x0 of zero covariance still draws
    expect = []
    for _ in range(3):
        x = 0.9 * x + np.sqrt(0.1) * rng.standard_normal((1, 1))
        rng.standard_normal((1, 1))
        expect.append(x[0, 0])
    assert np.allclose(xs[:, 0], expect, rtol=0, atol=1e-15)
