"""A time-varying SDE end to end: the continuous-discrete filter and smoother at the absolute
time, ``simulate`` at times, the MoN of its flow and a scenario file's ``time`` key.

The reference is the closed form of dx = (−x + sin t) dt + σ (1 + t) dβ
(``forced_moments`` of tests/helpers.py): over [a, b] it is the exact linear
transition x_b = F x_a + c + e, F = e^{−(b−a)}, c the forcing's integral (an input b(t)),
Var e the diffusion's, so the Kalman filter and the RTS smoother with these per-step F, c, Q
(written here in numpy) are the exact filter and smoother at any times.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentError, DiscretizationError, ModelError

from helpers import FORCED_SIGMA, forced_moments as closed_form, forced_sde

FORCED = forced_sde()
x, t = FORCED.states[0], FORCED.time

H = sm.Model([x], [x], name="tv_h")
R = np.array([[0.09]])
X0 = sm.Gaussian([0.3], [[0.2]])
TIMES = 0.7 + np.cumsum(np.random.default_rng(2).uniform(0.1, 1.2, size=12))  # irregular, after t0
T0 = 0.7


def exact_steps(times, t0):
    """The per-step (F, c, Q) of the closed form over [t_{k−1}, t_k]."""
    starts = np.concatenate([[t0], times[:-1]])
    F = np.exp(-(times - starts))
    c = np.array([closed_form(0.0, 0.0, a, b)[0] for a, b in zip(starts, times)])
    Q = np.array([closed_form(0.0, 0.0, a, b)[1] for a, b in zip(starts, times)])
    return F, c, Q


def kalman(ys, times, t0):
    """The scalar Kalman filter with the exact per-step F, c, Q: (x, P, x⁻, P⁻, loglik)."""
    F, c, Q = exact_steps(times, t0)
    m, P = X0.mean[0], X0.cov[0, 0]
    out = []
    for k, y in enumerate(ys[:, 0]):
        mp, Pp = F[k] * m + c[k], F[k] ** 2 * P + Q[k]
        S = Pp + R[0, 0]
        K = Pp / S
        m, P = mp + K * (y - mp), (1 - K) * Pp
        out.append((m, P, mp, Pp, -0.5 * (np.log(2 * np.pi * S) + (y - mp) ** 2 / S)))
    return np.array(out)


def rts(filtered, times, t0):
    """The RTS smoother of :func:`kalman`'s output."""
    F, _, _ = exact_steps(times, t0)
    m, P, mp, Pp = (filtered[:, i].copy() for i in range(4))
    for k in range(len(m) - 2, -1, -1):
        G = P[k] * F[k + 1] / Pp[k + 1]
        m[k] = m[k] + G * (m[k + 1] - mp[k + 1])
        P[k] = P[k] + G * G * (P[k + 1] - Pp[k + 1])
    return m, P


@pytest.fixture(scope="module")
def data():
    xs, ys = sm.simulate(FORCED, H, None, R, X0, times=TIMES, t0=T0, seed=5, substeps=16)
    return np.asarray(ys)


RTOL = 1e-9


@pytest.mark.parametrize("transform", ["ekf", "ukf"])
@pytest.mark.parametrize("square_root", [False, True])
def test_one_interval_is_the_closed_form(transform, square_root):
    """The moments over [2.1, 3.8] from (0.3, 0.2): to the integrator's tolerance (rtol 1e-10,
    atol 1e-12 give errors below 1e-11; measured 7.6e-12 and 3.1e-12)."""
    cd = sm.ContinuousDiscreteKalmanFilter(FORCED, H, R, transform, rtol=1e-10, atol=1e-12, square_root=square_root)
    m, P = cd.predict([0.3], [[0.2]], 1.7, t=2.1)
    mc, Pc = closed_form(0.3, 0.2, 2.1, 3.8)
    assert abs(m[0] - mc) < 1e-10 and abs(P[0, 0] - Pc) < 1e-10
    # A later start is another interval: the time is read (a time-invariant SDE would not).
    m_later, _ = cd.predict([0.3], [[0.2]], 1.7, t=4.0)
    assert abs(m_later[0] - closed_form(0.3, 0.2, 4.0, 5.7)[0]) < 1e-10 and abs(m_later[0] - m[0]) > 0.1
    with pytest.raises(ArgumentError, match="t=..."):
        cd.predict([0.3], [[0.2]], 1.7)
    dm, dP = cd.moment_derivatives([0.3], [[0.2]], t=2.1)
    L2 = (FORCED_SIGMA * (1 + 2.1)) ** 2
    assert dm[0] == pytest.approx(-0.3 + np.sin(2.1), rel=1e-14) and dP[0, 0] == pytest.approx(-0.4 + L2, rel=1e-14)


@pytest.mark.parametrize("square_root", [False, True])
def test_the_filter_at_irregular_times_is_the_exact_kalman_filter(data, square_root):
    """x, P, x⁻, P⁻ and the log-likelihood of the times route (x0 at t0 = 0.7), against the
    numpy Kalman filter with the exact per-step F, c (the forcing as an input) and Q:
    relative to each array's scale within 10·rtol (rtol 1e-9: measured below 2e-10)."""
    ref = kalman(data, TIMES, T0)
    cd = sm.ContinuousDiscreteKalmanFilter(FORCED, H, R, "ekf", rtol=RTOL, atol=RTOL / 1000, square_root=square_root)
    res = cd.filter(data, X0.mean, X0.cov, times=TIMES, t0=T0)
    for i, got in enumerate((res.x[:, 0], res.P[:, 0, 0], res.x_pred[:, 0], res.P_pred[:, 0, 0], res.loglik)):
        assert np.max(np.abs(got - ref[:, i])) < 10 * RTOL * np.max(np.abs(ref[:, i])), i
    # The same filter with the time ignored (the intervals alone, all from 0) is another one.
    shifted = cd.filter(data, X0.mean, X0.cov, times=TIMES - T0)
    assert np.max(np.abs(shifted.x[:, 0] - ref[:, 0])) > 1e-3


def test_the_dt_route_starts_at_zero_and_sums_the_intervals(data):
    """params={"dt": ...} is the times route with t0 = 0 and t_k the sums of the intervals."""
    times0 = TIMES - T0
    ref = kalman(data, times0, 0.0)
    cd = sm.ContinuousDiscreteKalmanFilter(FORCED, H, R, "ckf", rtol=RTOL, atol=RTOL / 1000)
    res = cd.filter(data, X0.mean, X0.cov, params={"dt": np.diff(times0, prepend=0.0)})
    assert np.max(np.abs(res.x[:, 0] - ref[:, 0])) < 10 * RTOL * np.max(np.abs(ref[:, 0]))
    assert np.max(np.abs(res.P[:, 0, 0] - ref[:, 1])) < 10 * RTOL * np.max(ref[:, 1])


def test_a_bank_takes_each_runs_own_times(data):
    """(R, K) times: each run is its own exact Kalman filter."""
    times = np.stack([TIMES, TIMES + 0.5])
    ys = np.stack([data, data])
    cd = sm.ContinuousDiscreteKalmanFilter(FORCED, H, R, "ekf", rtol=RTOL, atol=RTOL / 1000)
    res = cd.filter(ys, X0.mean, X0.cov, times=times, t0=T0)
    for r in range(2):
        ref = kalman(data, times[r], T0)
        assert np.max(np.abs(res.x[r, :, 0] - ref[:, 0])) < 10 * RTOL * np.max(np.abs(ref[:, 0]))
    assert np.max(np.abs(res.x[0] - res.x[1])) > 1e-3


@pytest.mark.parametrize("square_root", [False, True])
def test_the_smoother_is_the_exact_rts_smoother(data, square_root):
    ref_m, ref_P = rts(kalman(data, TIMES, T0), TIMES, T0)
    cd = sm.ContinuousDiscreteKalmanFilter(FORCED, H, R, "ekf", rtol=RTOL, atol=RTOL / 1000, square_root=square_root)
    sm_ = cd.smooth(data, X0.mean, X0.cov, times=TIMES, t0=T0)
    assert np.max(np.abs(sm_.x[:, 0] - ref_m)) < 10 * RTOL * np.max(np.abs(ref_m))
    assert np.max(np.abs(sm_.P[:, 0, 0] - ref_P)) < 10 * RTOL * np.max(ref_P)


def test_the_exact_prediction_and_the_kalman_filter_refuse_a_time_varying_sde():
    with pytest.raises(ModelError, match="linear time-invariant"):
        sm.ContinuousDiscreteKalmanFilter(FORCED, H, R, "ekf", exact=True)
    with pytest.raises(ModelError, match="time-varying SDE.*absolute time"):
        sm.KalmanFilter(FORCED, None, [[1.0]], R)


def test_simulate_one_interval_matches_the_closed_form_within_its_standard_errors():
    """40 000 runs over [2.1, 3.8] by 32 order-1.5 sub-steps: the sample mean and variance
    against the closed form, within 4 standard errors (√(P/N), P √(2/N)).  The scheme's own
    bias (its exact moments, as in tests/core/test_sde_time.py) is below a tenth of them."""
    N = 40_000
    xs, _ = sm.simulate(FORCED, H, None, R, X0, times=[3.8], t0=2.1, runs=N, substeps=32, seed=11)
    v = xs[:, 0, 0]
    mc, Pc = closed_form(0.3, 0.2, 2.1, 3.8)
    assert abs(v.mean() - mc) < 4 * np.sqrt(Pc / N)
    assert abs(v.var(ddof=1) - Pc) < 4 * Pc * np.sqrt(2 / N)
    # The dt route starts at 0: the same draws at another time, and a scalar dt is k·dt.
    a, _ = sm.simulate(FORCED, H, None, R, X0, steps=3, params={"dt": 0.5}, runs=2, seed=3)
    b, _ = sm.simulate(FORCED, H, None, R, X0, times=[0.5, 1.0, 1.5], runs=2, seed=3)
    assert np.allclose(a, b, rtol=1e-13, atol=1e-13)
    with pytest.raises(ArgumentError, match="must not give 't'"):
        sm.simulate(FORCED, H, None, R, X0, times=[0.5], params={"t": [0.0]})


def test_the_mon_of_the_flow_needs_the_start_time():
    """A linear SDE's flow is affine whenever it starts (MoN 0); a nonlinear one with a
    forcing in t has a MoN that depends on the start."""
    prior = sm.Gaussian([0.5], [[0.1]])
    assert float(sm.nonlinearity(FORCED, prior, dt=0.5, t=1.0)) < 1e-12
    with pytest.raises(ArgumentError, match="time-varying.*give t="):
        sm.nonlinearity(FORCED, prior, dt=0.5)
    with pytest.raises(ArgumentError, match="are for the flow of an SDE"):
        sm.nonlinearity(H, prior, sm.Gaussian([0.0], [[1.0]]), t=1.0)
    well = sm.SDE([x], [x - x ** 3 * (1 + sp.sin(t))], diffusion=[0.5], time=t)
    at0 = float(sm.nonlinearity(well, prior, dt=0.5, t=0.0, substeps=1))
    at_top = float(sm.nonlinearity(well, prior, dt=0.5, t=np.pi / 2, substeps=1))
    assert at_top > at0 + 0.05
    from symmon.measures.mon import choose_substeps
    assert choose_substeps(FORCED, prior, 1.0, t=0.0) == 1


def test_advise_filter_refuses_a_time_varying_sde():
    with pytest.raises(DiscretizationError, match="does not see the time variation"):
        sm.advise_filter(FORCED, H, None, R, X0, None, times=TIMES, t0=T0)


SCENARIO = """
name = "forced"
states = ["x"]
measurements = ["x"]
{top}
[params]
s = 0.3
[sde]
drift = ["-x + sin(t)"]
diffusion = [["s*(1 + t)"]]
time = "t"
method = "rk4"
substeps = 2
{steps}
[R]
std = [0.3]
[x0]
mean = [0.3]
std = [0.4472135954999579]
"""


def test_a_scenario_file_declares_the_time(tmp_path):
    """``time = "t"``: the dynamics keep t, whose per-step values are the steps' starts."""
    from symmon.files.filterfile import load_filter_file
    from symmon.errors import ModelFileError

    path = tmp_path / "forced.toml"
    path.write_text(SCENARIO.format(top="", steps="times = [0.5, 1.25, 3.0]\nt0 = 0.2"))
    sc = load_filter_file(path)
    assert [str(p) for p in sc.f.params] == ["t", "dt"]
    assert np.allclose(sc.step_params["t"], [0.2, 0.5, 1.25]) and np.allclose(sc.step_params["dt"], [0.3, 0.75, 1.75])
    path.write_text(SCENARIO.format(top="steps = 3", steps="dt = 0.5"))
    sc = load_filter_file(path)
    assert [str(p) for p in sc.f.params] == ["t"] and np.allclose(sc.step_params["t"], [0.0, 0.5, 1.0])
    # The file's model at its parameters is the SDE's rk4 step at (t, dt).
    direct = FORCED.discretize("rk4", substeps=2)
    w = [0.3, -1.1]
    dt = sp.Symbol("dt", positive=True)
    got = sc.f.outputs[0].subs({x: 0.7, t: 1.0, **dict(zip(sc.f.noise, w))})
    want = direct.outputs[0].subs({x: 0.7, t: 1.0, dt: 0.5, **dict(zip(direct.noise, w))})
    assert float(got) == pytest.approx(float(want), rel=1e-13)
    path.write_text(SCENARIO.format(top="steps = 3", steps="dt = 0.5").replace('method = "rk4"\nsubsteps = 2', ""))
    with pytest.raises(ModelFileError, match=r"\[sde\].method.*time-invariant"):
        load_filter_file(path)
    path.write_text(SCENARIO.format(top="steps = 3", steps="dt = 0.5").replace('time = "t"', 'time = "s"'))
    with pytest.raises(ModelFileError, match="duplicate name 's'"):
        load_filter_file(path)
