"""The filter-selection study (symmon reproduce select, issue 48 item 5) in a reduced setting:
the table's structure, the advice confirmed on fresh runs where that is robust, the files."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from symmon.errors import ArgumentError
from symmon.filters.selection import ANEES_BAND, BATCH_RUNS, CREDIBLE_PROBABILITY, RMSE_MARGIN
from symmon.reproduce import select

#: The reduced setting: 40 fresh runs (2 batches), a pilot of 24 runs, 20 steps per scenario.
RUNS, PILOT, STEPS = 40, 24, 20
#: Where the advice is credible and within 10 % of the best credible RMSE on the fresh runs of
#: the reduced setting whatever the seed (checked on seeds 0, 1 and 2): the near-linear
#: tracker, the falling body and the coordinated turn, where every credible candidate's RMSE
#: is within 0.5 % of the others' and the chosen filter's ANEES is far inside the band; the
#: growth model, where the particle filter is grown until credible; range-only, where the
#: second look (or the pilot) sends a rare divergence of the Gaussian-sum filter to the
#: particle filter (or the tail look does); bearings-only, where the tail look finds every
#: Gaussian candidate losing truths far in the prior's tail that the regularised particle
#: filter with its tempered update keeps (before that update, seed 2 was not confirmed:
#: docs/select.md).
ROBUST = ("range_bearing", "ungm", "bearings_only", "range_only", "falling_body", "coordinated_turn")


@pytest.fixture(scope="module")
def outdir(tmp_path_factory):
    out = tmp_path_factory.mktemp("select")
    select.run(out, runs=RUNS, pilot=PILOT, steps=STEPS, progress=False)
    return out


@pytest.fixture(scope="module")
def table(outdir):
    with open(outdir / "select.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        return reader.fieldnames, list(reader)


def _advised(rows, name):
    return next(r for r in rows if r["scenario"] == name and r["advised"] == "1")


def test_writes_the_figure_and_the_table(outdir):
    assert sorted(p.name for p in outdir.iterdir()) == sorted(select.OUTPUTS)
    assert (outdir / "select.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_one_row_per_scenario_and_candidate_with_one_advice_each(table):
    header, rows = table
    assert tuple(header) == select.COLUMNS
    assert list(dict.fromkeys(r["scenario"] for r in rows)) == list(select.SCENARIOS)
    for name in select.SCENARIOS:
        mine = [r for r in rows if r["scenario"] == name]
        assert sum(r["advised"] == "1" for r in mine) == 1
        assert len({r["candidate"] for r in mine}) == len(mine) >= 6  # every candidate of the menu
        assert {"ekf", "ukf", "gsf", "pf"} <= {r["candidate"] for r in mine}
        for r in mine:
            assert int(r["runs"]) == RUNS and int(r["batches"]) == RUNS // BATCH_RUNS
            assert 0.0 <= float(r["batch_share"]) <= 1.0
            assert int(r["cost_evals_per_step"]) > 0
        ran = [r for r in mine if r["rmse"]]
        n = float(mine[0]["anees_band_lower"]) / ANEES_BAND[0]
        assert float(mine[0]["anees_band_upper"]) == pytest.approx(ANEES_BAND[1] * n)
        # the reference of the RMSE ratios: the best credible candidate (else the most accurate)
        pool = [r for r in ran if r["credible"] == "1"] or ran
        assert min(float(r["rmse_ratio"]) for r in pool) == pytest.approx(1.0, rel=1e-12)
        for r in ran:
            credible = ANEES_BAND[0] * n <= float(r["anees"]) <= ANEES_BAND[1] * n and not r["failure"]
            assert (r["credible"] == "1") == credible
            assert (r["within_margin"] == "1") == (float(r["rmse_ratio"]) <= 1 + RMSE_MARGIN)
        advised = _advised(rows, name)
        assert advised["advice_confirmed"] == str(int(advised["credible"] == "1" and advised["within_margin"] == "1"))
        assert all(r["advice_confirmed"] == advised["advice_confirmed"] for r in mine)


def test_the_near_linear_tracker_gets_the_ekf(table):
    _, rows = table
    assert _advised(rows, "range_bearing")["candidate"] == "ekf"


def test_the_pilots_predictive_credibility_is_a_probability_where_the_pilot_ran(table):
    _, rows = table
    for r in rows:
        if r["pilot_kept"] == "1":
            assert 0.0 <= float(r["pilot_credibility"]) <= 1.0
        else:
            assert r["pilot_credibility"] == ""


def test_the_pilot_runs_of_the_advice_include_its_second_look(table):
    _, rows = table
    for name in select.SCENARIOS:
        mine = [r for r in rows if r["scenario"] == name and r["pilot_kept"] == "1"]
        advised = _advised(rows, name)
        others = {int(r["pilot_runs"]) for r in mine if r is not advised and r["pilot_runs"]}
        assert int(advised["pilot_runs"]) > PILOT  # the second look's runs too
        assert PILOT in others


def test_the_growth_model_gets_a_particle_filter(table):
    """No Gaussian filter is credible on the growth model; the particle filter (grown where its
    pilot collapses) is."""
    _, rows = table
    assert _advised(rows, "ungm")["candidate"].startswith("pf")
    assert all(r["credible"] == "0" for r in rows if r["scenario"] == "ungm" and r["candidate"] in ("ekf", "ukf"))


@pytest.mark.parametrize("name", ROBUST)
def test_the_advice_is_credible_and_within_the_margin_on_fresh_runs(table, name):
    _, rows = table
    a = _advised(rows, name)
    assert a["pilot_credible"] == "1" and a["credible"] == "1"
    assert float(a["pilot_credibility"]) >= CREDIBLE_PROBABILITY  # not at risk in the pilot
    assert float(a["rmse_ratio"]) <= 1 + RMSE_MARGIN and a["advice_confirmed"] == "1"
    assert float(a["batch_share"]) == 1.0


def test_the_falling_body_gets_a_sigma_point_filter_not_the_overconfident_ekf(table):
    """Athans et al.'s falling body: the EKF is overconfident (its ANEES above the band), a
    sigma-point filter is not (Julier & Uhlmann 2004's point, on its 3-state analogue).  In
    the reduced setting (20 steps, seed 0) the tail look finds the single sigma-point filters
    losing a truth whose ballistic coefficient is 3 prior standard deviations high (NEES 51.6
    at its last step) that the Gaussian-sum filter of sigma-point components keeps: the advice
    is then that filter (on the full track, the UKF: docs/select.md)."""
    _, rows = table
    ekf = next(r for r in rows if r["scenario"] == "falling_body" and r["candidate"] == "ekf")
    assert ekf["credible"] == "0" and float(ekf["anees"]) > float(ekf["anees_band_upper"])
    advised = _advised(rows, "falling_body")
    assert advised["candidate"] in ("ukf", "ckf", "ghkf", "gsf")
    if advised["candidate"] == "gsf":  # only where the sigma-point filters lost tracks in the tail
        assert all(float(r["pilot_lost_rate"]) > 0 for r in rows
                   if r["scenario"] == "falling_body" and r["candidate"] in ("ukf", "ckf", "ghkf"))


def test_the_tail_look_reports_a_lost_track_rate_per_candidate(table):
    """The CSV's pilot_lost_rate: a probability per run where the tail look ran; range-only's
    particle filter keeps the tail's truths that the Gaussian-sum filter loses, or neither loses one."""
    _, rows = table
    rates = [float(r["pilot_lost_rate"]) for r in rows if r["pilot_lost_rate"] not in ("", None)]
    assert rates and all(0.0 <= v <= 1.0 for v in rates)
    assert all(r["pilot_lost_rate"] in ("", None) for r in rows if r["pilot_credible"] != "1")


def test_the_scenarios_are_those_of_the_notes():
    ungm = select.scenario("ungm", 7)
    assert ungm.steps == 7 and np.array_equal(ungm.params["k"], np.arange(1, 8))
    assert ungm.Q[0, 0] == 10.0 and ungm.R[0, 0] == 1.0
    assert select.scenario("coordinated_turn").modes and select.scenario("falling_body").f.n_u == 3
    ro = select.scenario("range_only")
    assert ro.x0.mean[1] > 0 and ro.params["sy"].max() == 0.0  # the prior straddles the sensor's line
    with pytest.raises(ArgumentError, match="name"):
        select.scenario("nope")


@pytest.mark.parametrize("kwargs, match", [({"runs": 1}, "runs"), ({"pilot": 1}, "pilot"), ({"steps": 1}, "steps"),
                                           ({"seed": -1}, "seed")])
def test_bad_settings_are_named(tmp_path, kwargs, match):
    with pytest.raises(ArgumentError, match=match):
        select.run(tmp_path, progress=False, **kwargs)
