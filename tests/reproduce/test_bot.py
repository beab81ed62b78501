"""The bearings-only study (symmon reproduce bot) on a tiny setting: files, table shapes, χ² bands, the MoN."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import sympy as sp
from scipy import stats

import symmon as sm
from symmon.cli import parser as cli
from symmon.errors import ArgumentError
from symmon.reproduce import bot

RUNS, PARTICLES = 4, 200


@pytest.fixture(scope="module")
def outdir(tmp_path_factory):
    out = tmp_path_factory.mktemp("bot")
    assert cli.main(["reproduce", "bot", "--runs", str(RUNS), "--particles", str(PARTICLES), "--out", str(out),
                     "--no-progress"]) == 0
    return out


@pytest.fixture(scope="module")
def table(outdir):
    with open(outdir / "bot_steps.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        return reader.fieldnames, list(reader)


def test_writes_the_figure_and_the_table(outdir):
    assert sorted(p.name for p in outdir.iterdir()) == sorted(bot.OUTPUTS)
    assert (outdir / "bot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_one_row_per_filter_and_scan_with_the_declared_columns(table):
    header, rows = table
    assert tuple(header) == bot.STEP_COLUMNS
    K = bot.scenario().steps
    assert [(r["filter"], int(r["k"])) for r in rows] == [(f, k) for f in bot.FILTER_NAMES for k in range(1, K + 1)]
    for r in rows:
        assert int(r["runs"]) == RUNS
        assert float(r["position_rmse"]) > 0 and float(r["anees"]) > 0
        assert 0.0 <= float(r["mon_q10"]) <= float(r["mon_median"]) <= float(r["mon_q90"]) <= 1.0
        inside = float(r["anees_lower"]) <= float(r["anees"]) <= float(r["anees_upper"])
        assert int(r["anees_inside"]) == inside


def test_the_chi2_band_is_scipys_two_sided_interval(table):
    """N·ANEES ~ χ²(N n) for N runs of a consistent filter of n = 4 states."""
    _, rows = table
    lo, hi = stats.chi2.ppf([0.025, 0.975], 4 * RUNS) / RUNS
    assert bot.chi2_band(RUNS, 4) == pytest.approx((lo, hi), rel=1e-12)
    for r in rows:
        assert float(r["anees_lower"]) == pytest.approx(lo, rel=1e-12)
        assert float(r["anees_upper"]) == pytest.approx(hi, rel=1e-12)


def test_particle_and_component_columns(table):
    _, rows = table
    for r in rows:
        comps = float(r["components_mean"])
        if r["filter"] in ("pf", "rpf"):
            assert 1.0 <= float(r["ess_mean"]) <= PARTICLES and 0 <= int(r["collapsed_runs"]) <= RUNS
        else:
            assert r["ess_mean"] == r["collapsed_runs"] == ""
        if r["filter"] == "rp_gsf":  # never split: at most its prior's components
            assert 1.0 <= comps <= bot.RP_COMPONENTS
        elif r["filter"] == "mon_gsf":
            assert 1.0 <= comps <= bot.MAX_COMPONENTS
        else:
            assert comps == 1.0
    # The MoN-split GSF splits: the bearing's MoN at the first prior (0.29) is above the level.
    assert max(float(r["components_mean"]) for r in rows if r["filter"] == "mon_gsf") > 1.0


def test_the_mon_at_the_first_prior_is_the_same_for_every_gaussian_prior(table):
    """At scan 1 the EKF, the UKF and the MoN-split GSF predict the same Gaussian (f is
    linear), so the MoN of their priors agrees; the range-parameterised mixture's components
    are narrower in range, so their MoN is smaller."""
    _, rows = table
    first = {r["filter"]: float(r["mon_median"]) for r in rows if r["k"] == "1"}
    assert first["ukf"] == pytest.approx(first["ekf"], rel=1e-10)
    assert first["mon_gsf"] == pytest.approx(first["ekf"], rel=1e-10)
    assert first["rp_gsf"] < first["ekf"]


def test_mon_tt2_equals_nonlinearity_with_tt2():
    """The batched MoN of the study against sm.nonlinearity (W^full, TT2) on y = h(x) + e."""
    sc = bot.scenario()
    X = sc.h.inputs
    e = sp.Symbol("e", real=True)
    h_noisy = sm.Model(X, [sc.h.outputs[0] + e], noise=[e], angles=[0])
    rng = np.random.default_rng(3)
    means = sc.x0.mean + rng.standard_normal((3, 4)) * np.sqrt(np.diag(sc.x0.cov))
    covs = np.stack([sc.x0.cov * s for s in (0.05, 0.5, 1.0)])
    got = bot.mon_tt2(sc.h, sc.R, means, covs)
    for m, P, g in zip(means, covs, got):
        ref = sm.nonlinearity(h_noisy, sm.Gaussian(m, P), sm.Gaussian([0.0], sc.R), weight="full",
                              transform=sm.TT2()).value
        assert g == pytest.approx(ref, rel=1e-10)


def test_range_parameterised_prior_lies_along_the_bearing():
    sc = bot.scenario()
    mix = bot.range_parameterised_prior(sc.x0)
    assert mix.n_components == bot.RP_COMPONENTS
    np.testing.assert_allclose(np.sum(mix.weights), 1.0, rtol=1e-12)
    r = np.hypot(mix.means[:, 0], mix.means[:, 1])
    np.testing.assert_allclose(r[[0, -1]], [1000.0, 11000.0], rtol=1e-12)
    np.testing.assert_allclose(r[1:] / r[:-1], (11.0) ** (1 / (bot.RP_COMPONENTS - 1)), rtol=1e-12)
    u = sc.x0.mean[:2] / np.hypot(*sc.x0.mean[:2])
    np.testing.assert_allclose(mix.means[:, :2], r[:, None] * u, atol=1e-9)  # on the line of sight
    np.testing.assert_allclose(mix.means[:, 2:], np.broadcast_to(sc.x0.mean[2:], (len(r), 2)), rtol=1e-12)
    # weights: the prior's range density at r_j times the width of the interval [r_j/√ρ, r_j √ρ]
    rho = r[1] / r[0]
    sd_r = np.sqrt(u @ sc.x0.cov[:2, :2] @ u)
    w = stats.norm.pdf(r, np.hypot(*sc.x0.mean[:2]), sd_r) * r * (np.sqrt(rho) - 1 / np.sqrt(rho))
    np.testing.assert_allclose(mix.weights, w / w.sum(), rtol=1e-12)
    # each component's range spread: a constant coefficient of variation
    sd_along = np.sqrt(np.einsum("a,jab,b->j", u, mix.covs[:, :2, :2], u))
    np.testing.assert_allclose(sd_along / r, (np.sqrt(rho) - 1 / np.sqrt(rho)) / np.sqrt(12), rtol=1e-12)


def test_bad_settings_are_refused(tmp_path, capsys):
    with pytest.raises(ArgumentError, match="runs"):
        bot.run(tmp_path, runs=1, progress=False)
    with pytest.raises(ArgumentError, match="particles"):
        bot.run(tmp_path, runs=2, particles=5, progress=False)
    assert cli.main(["reproduce", "bot", "--particles", "5", "--out", str(tmp_path)]) == 2
    assert "--particles" in capsys.readouterr().err
