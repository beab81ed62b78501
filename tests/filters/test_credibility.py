"""Credibility flagged online (issue 48, item 3): every result's ``credibility``, the windowed
NIS against its χ² band, and a particle filter's ESS against its degeneracy floor."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import sympy as sp
from scipy import stats

import symmon as sm
from symmon.errors import ArgumentError, SymmonError
from symmon.filters.results import CREDIBILITY_CONFIDENCE, CREDIBILITY_WINDOW, Credibility, windowed_nis

x = sp.Symbol("x")
F, H = sm.Model([x], [0.9 * x], name="cred_f"), sm.Model([x], [x], name="cred_h")
Q, R = [[0.5]], [[0.1]]
X0 = sm.Gaussian([0.0], [[1.0]])


def _bank(runs: int = 4, steps: int = 200, r=R, seed: int = 1):
    return sm.simulate(F, H, Q, r, X0, steps, runs=runs, seed=seed)


def test_windowed_nis_is_the_mean_over_the_window_and_its_chi2_band() -> None:
    rng = np.random.default_rng(3)
    nis = rng.chisquare(2, size=(3, 25))
    dof = np.full(nis.shape, 2)
    dof[1, 4] = 0  # nothing measured: left out of the mean and of the degrees of freedom
    stat, lo, hi = windowed_nis(nis, dof, 6, 0.9)
    for r in range(3):
        for k in range(25):
            sel = slice(max(0, k - 5), k + 1)
            m = dof[r, sel] > 0
            count, total = m.sum(), dof[r, sel].sum()
            assert stat[r, k] == pytest.approx(nis[r, sel][m].mean(), rel=1e-12)
            assert lo[r, k] == pytest.approx(stats.chi2.ppf(0.05, total) / count, rel=1e-12)
            assert hi[r, k] == pytest.approx(stats.chi2.ppf(0.95, total) / count, rel=1e-12)


def test_a_consistent_filter_is_rarely_flagged_an_overconfident_one_almost_always() -> None:
    xs, ys = _bank()
    good = sm.NonlinearKalmanFilter(F, H, Q, R, "ekf").filter(ys, X0)
    bad = sm.NonlinearKalmanFilter(F, H, [[0.005]], [[0.001]], "ekf").filter(ys, X0)  # Q and R 100x too small
    c = good.credibility
    assert isinstance(c, Credibility) and c.window == CREDIBILITY_WINDOW and c.confidence == CREDIBILITY_CONFIDENCE
    assert c.steps.shape == c.statistic.shape == (4, 200) and c.steps.dtype == bool
    assert c.fraction < 0.05
    assert bad.credibility.fraction > 0.9
    # overconfident: above the band, not below it
    assert np.all(bad.credibility.statistic[bad.credibility.steps] > bad.credibility.band[1][bad.credibility.steps])
    assert good.credibility is c  # computed once
    assert "flagged" in repr(c)


def test_a_too_cautious_filter_is_flagged_below_its_band() -> None:
    xs, ys = _bank()
    cautious = sm.NonlinearKalmanFilter(F, H, [[50.0]], [[10.0]], "ekf").filter(ys[0], X0)  # one run
    c = cautious.credibility
    assert c.steps.shape == (200,) and c.fraction > 0.9
    assert np.all(c.statistic[c.steps] < c.band[0][c.steps])
    assert c.flagged.ndim == 1 and c.flagged.size == int(c.steps.sum())


def test_a_missing_measurement_counts_neither_in_the_window_nor_as_a_flag() -> None:
    xs, ys = _bank(runs=1)
    ys = ys[0].copy()
    ys[:30] = np.nan
    res = sm.NonlinearKalmanFilter(F, H, Q, R, "ekf").filter(ys, X0)
    c = res.credibility
    assert np.all(np.isnan(c.statistic[:30])) and not c.steps[:30].any()
    assert np.isfinite(c.statistic[30:]).all()


def test_a_particle_filter_flags_a_degenerate_cloud_by_its_ess() -> None:
    xs, ys = _bank(runs=2, steps=100)
    ok = sm.ParticleFilter(F, H, Q, R, particles=500).filter(ys, X0)
    assert ok.credibility.ess is not None and ok.credibility.ess_floor == 10.0
    assert ok.credibility.fraction < 0.05
    xs, ys = _bank(runs=2, steps=100, r=[[1e-4]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the DegeneracyWarning this case is about
        bad = sm.ParticleFilter(F, H, Q, [[1e-4]], particles=50).filter(ys, X0)
    c = bad.credibility
    assert c.fraction > 0.5
    assert np.any(c.steps & (c.ess < c.ess_floor))


def test_a_result_without_innovations_says_why_it_has_no_credibility() -> None:
    xs, ys = _bank(runs=1, steps=10)
    res = sm.GaussianSumFilter(F, H, Q, R, sm.TT1()).filter(ys[0], X0)
    with pytest.raises(SymmonError, match="no innovations"):
        res.credibility
    kept = sm.NonlinearKalmanFilter(F, H, Q, R, "ekf").filter(ys[0], X0, keep="x")
    with pytest.raises(SymmonError, match="keep 'nis'"):
        kept.credibility


@pytest.mark.parametrize("window, confidence", [(0, 0.99), (2.5, 0.99), (True, 0.99), (5, 1.0), (5, 0.0)])
def test_a_bad_window_or_confidence_is_refused(window, confidence) -> None:
    xs, ys = _bank(runs=1, steps=10)
    res = sm.NonlinearKalmanFilter(F, H, Q, R, "ekf").filter(ys[0], X0)
    with pytest.raises(ArgumentError, match="window|confidence"):
        res.check_credibility(window, confidence)
