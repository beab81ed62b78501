"""advise_filter with an SDE as f: the continuous-discrete filters of the SDE are candidates
beside the discrete filters of its discretisation, scored and chosen by the same rules
(symmon.filters.selection, module notes)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentError
from symmon.filters.selection import MIN_RUNS, SECONDS_PER_EVALUATION, confirm_advice
from symmon.filters.sde_advice import discretize_track

p, v = sp.symbols("p v", real=True)
q = sp.Symbol("q", positive=True)
WNA = sm.SDE([p, v], [v, 0], diffusion=[0, 1], spectral_density=q, params=[q], name="cd_adv_wna")
H = sm.Model([p, v], [p], name="cd_adv_h")
X0 = sm.Gaussian([0.0, 1.0], np.diag([1.0, 0.25]))
TIMES = np.cumsum(np.random.default_rng(2).uniform(0.5, 2.0, 12))
R_WNA = [[0.5]]

x1, x2 = sp.symbols("x1 x2", real=True)
VDP = sm.SDE([x1, x2], [x2, (1 - x1**2) * x2 - x1], diffusion=[0, 0.3], name="cd_adv_vdp")
VDP_H = sm.Model([x1, x2], [x1], name="cd_adv_vdp_h")
VDP_X0 = sm.Gaussian([1.5, 0.0], 0.05 * np.eye(2))
VDP_TIMES = TIMES[:6] / 2
VDP_R = [[0.05]]


@pytest.fixture(scope="module")
def linear():
    return sm.advise_filter(WNA, H, None, R_WNA, X0, None, {"q": 0.3}, times=TIMES, runs=16, seed=1)


@pytest.fixture(scope="module")
def vdp():
    return sm.advise_filter(VDP, VDP_H, None, VDP_R, VDP_X0, None, times=VDP_TIMES, tol=0.1, runs=8, seed=0)


def _row(advice, name):
    return next(c for c in advice.candidates if c.name == name)


def test_on_a_linear_sde_the_cd_ekf_is_credible_and_its_pilot_is_the_kalman_filters(linear) -> None:
    """The CD-EKF integrates the moment ODEs (RK45, rtol 1e-6); on a linear SDE they are
    those of the exact discretisation, so its pilot numbers are the KF's of e^{A dt} and
    Van Loan's Q(dt) on the same runs to the integrator's tolerance (1e-5 relative on
    the RMSE and the NEES: rtol 1e-6 over 12 intervals)."""
    cd = _row(linear, "cd-ekf")
    assert cd.kept and cd.credible and cd.method == "CD-EKF"
    assert cd.cost == sm.ContinuousDiscreteKalmanFilter(WNA, H, R_WNA, "ekf").step_cost()
    assert "moment ODEs integrated between measurements" in cd.reason and "no discretisation" in cd.reason
    # the pilot's truths: the first runs of the advice's simulation (its seed)
    track = discretize_track(WNA, None, X0, None, {"q": 0.3}, times=TIMES)
    xs, ys = sm.simulate(track.f, H, track.Q, R_WNA, X0, track.steps, runs=16, params=track.params, seed=1)
    kf = sm.KalmanFilter(WNA, None, [[1.0, 0.0]], R_WNA)  # the exact transition, no integrator
    res = kf.filter(ys, X0, params={"q": 0.3}, times=TIMES, x_true=xs)
    e = (np.asarray(res.x) - xs) / np.sqrt(np.diag(X0.cov))
    rmse = math.sqrt(np.mean(np.sum(e**2, axis=-1)) / 2)
    run_nees = np.asarray(res.nees()).reshape(16, -1).mean(axis=1)
    assert cd.runs == 16
    np.testing.assert_allclose(cd.rmse, rmse, rtol=1e-5)
    np.testing.assert_allclose(cd.run_nees, run_nees, rtol=1e-5)
    np.testing.assert_allclose(cd.anees, run_nees.mean(), rtol=1e-5)
    # the MoN of the flow is zero (affine): the CD-CKF is pruned as the CKF is, and the
    # choice is the cheaper discrete filter of the same RMSE
    assert not _row(linear, "cd-ckf").kept and not _row(linear, "ckf").kept
    assert linear.choice == "ekf" and _row(linear, "ekf").cost < cd.cost


def test_on_a_nonlinear_sde_the_cd_rows_run_and_are_scored(vdp) -> None:
    track = discretize_track(VDP, None, VDP_X0, None, times=VDP_TIMES, tol=0.1)
    assert vdp.sde == {"method": "taylor1.5", "substeps": track.substeps, "longest_interval": track.longest,
                       "flow_mon": track.flow_mon, "substep_mon": track.substep_mon}
    assert track.substep_mon <= 0.1 < track.flow_mon  # the flow is nonlinear, one sub-step within tol
    M = max(vdp.mon["f"]["prior"], vdp.mon["f"]["truth"], vdp.mon["h"]["prior"], vdp.mon["h"]["truth"])
    assert M > math.sqrt(2) * 0.1  # the sigma-point filters are brought in, the CD-CKF with them
    for name, rule in (("cd-ekf", "ekf"), ("cd-ckf", "ckf")):
        row = _row(vdp, name)
        assert row.kept and row.runs == vdp.runs and row.credible is not None
        assert np.isfinite(row.rmse) and np.isfinite(row.anees) and row.run_nees.shape == (vdp.runs,)
        assert row.cost == sm.ContinuousDiscreteKalmanFilter(VDP, VDP_H, VDP_R, rule).step_cost()
        assert row.mon_f is not None and row.mon_f > 0  # the flow's MoN at its own prior, as every row's
        assert f"{track.flow_mon:.3g}" in row.reason and row.settings["transform"] == rule
    assert _row(vdp, "cd-ckf").method == "CD-CKF"


def test_a_seed_gives_the_same_advice_twice(vdp) -> None:
    again = sm.advise_filter(VDP, VDP_H, None, VDP_R, VDP_X0, None, times=VDP_TIMES, tol=0.1, runs=8, seed=0)
    assert again.choice == vdp.choice and again.runs == vdp.runs
    assert [(c.name, c.rmse, c.anees, c.cost, c.mon_f, c.lost_rate) for c in again.candidates] == \
        [(c.name, c.rmse, c.anees, c.cost, c.mon_f, c.lost_rate) for c in vdp.candidates]


def test_the_table_and_the_dict_hold_the_cd_rows(vdp) -> None:
    text = str(vdp)
    lines = vdp.table.splitlines()
    assert any(line.startswith("cd-ekf") for line in lines) and any(line.startswith("cd-ckf") for line in lines)
    assert "SDE: the MoN of its flow over the longest interval" in text
    d = vdp.as_dict()
    rows = {c["name"]: c for c in d["candidates"]}
    assert rows["cd-ekf"]["method"] == "CD-EKF" and rows["cd-ckf"]["kept"]
    assert rows["cd-ekf"]["rmse"] == _row(vdp, "cd-ekf").rmse
    assert d["sde"]["flow_mon"] == vdp.sde["flow_mon"] and d["units"]["flow_mon"] == "unitless"


def test_a_chosen_cd_filter_is_built_and_takes_the_intervals_either_way() -> None:
    """The CD-EKF is cheaper than the UKF of the discretisation: the rule chooses it when its
    RMSE is within 10 % (no special case), and advice.filter is that filter."""
    a = sm.advise_filter(VDP, VDP_H, None, VDP_R, VDP_X0, None, times=VDP_TIMES, tol=0.1, runs=16, seed=0,
                         candidates=["ukf", "cd-ekf"])
    ukf, cd = _row(a, "ukf"), _row(a, "cd-ekf")
    assert cd.cost < ukf.cost and cd.credible and ukf.credible and cd.rmse <= 1.1 * ukf.rmse
    assert a.choice == "cd-ekf" and isinstance(a.filter, sm.ContinuousDiscreteKalmanFilter)
    assert a.filter.method == "CD-EKF" and a.as_dict()["method"] == "CD-EKF"
    _, ys = sm.simulate(VDP, VDP_H, None, VDP_R, VDP_X0, times=VDP_TIMES, seed=5)
    by_dt = a.filter.filter(ys, VDP_X0, params={"dt": np.diff(VDP_TIMES, prepend=0.0)})
    by_times = a.filter.filter(ys, VDP_X0, times=VDP_TIMES)
    np.testing.assert_array_equal(by_dt.x, by_times.x)  # the pilot's dt route is the times route, bit for bit
    np.testing.assert_array_equal(by_dt.P, by_times.P)
    # confirm_advice rebuilds the whole menu, the CD rows in it
    c = confirm_advice(a, VDP, VDP_H, None, VDP_R, VDP_X0, times=VDP_TIMES, runs=10, seed=3)
    names = [r.name for r in c.rows]
    assert {"ekf", "ukf", "ckf", "cd-ekf", "cd-ckf"} <= set(names)
    assert names.index("cd-ekf") > names.index("ckf") and c.advised.name == "cd-ekf" and c.advised.runs == 10


def test_the_budget_counts_the_cd_filters_cost(linear) -> None:
    """The pilot's runs are budget / (steps · Σ cost · SECONDS_PER_EVALUATION) over the kept
    candidates, the CD-EKF's step_cost among them (its integrator is compiled: one rate)."""
    kept = [c for c in linear.candidates if c.kept]
    assert "cd-ekf" in [c.name for c in kept]

    def seconds(c):
        return c.cost * SECONDS_PER_EVALUATION

    per_run = linear.steps * sum(seconds(c) for c in kept)
    budget = 20.5 * per_run
    a = sm.advise_filter(WNA, H, None, R_WNA, X0, None, {"q": 0.3}, times=TIMES, runs=64, seed=1, budget=budget)
    assert a.runs == 20 >= MIN_RUNS and _row(a, "cd-ekf").runs == 20
    # what is left (half a run's worth) holds neither a tail look nor a second look
    assert a.estimated_seconds <= budget and a.second_look == 0 and a.choice == "ekf"
    assert _row(a, "cd-ekf").credible and _row(a, "ekf").credible and a.tail_look == 0
    without = linear.steps * sum(seconds(c) for c in kept if c.name != "cd-ekf")
    assert math.floor(budget / without) > 64  # without the CD-EKF's cost the pilot would run all it was asked


def test_cd_candidates_by_name_need_an_sde_and_their_own_settings() -> None:
    f = WNA.discretize("exact")
    with pytest.raises(ArgumentError, match="needs an SDE"):
        sm.advise_filter(f, H, np.eye(f.n_v), R_WNA, X0, 12, {"q": 0.3, "dt": 1.0}, runs=8, candidates=["cd-ekf"])
    with pytest.raises(ArgumentError, match="unknown settings"):
        sm.advise_filter(WNA, H, None, R_WNA, X0, None, {"q": 0.3}, times=TIMES, runs=8,
                         candidates=[("cd-ekf", {"particles": 10})])
    a = sm.advise_filter(WNA, H, None, R_WNA, X0, None, {"q": 0.3}, times=TIMES, runs=8,
                         candidates=[("cd-ekf", {"rtol": 1e-8})])
    assert a.choice == "cd-ekf" and a.filter.rtol == 1e-8
