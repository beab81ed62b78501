"""The tracking study (symmon reproduce tracking): files and basic sanity, with few runs."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from symmon.cli import parser as cli
from symmon.errors import SymmonError
from symmon.reproduce import tracking

RUNS = 20


@pytest.fixture(scope="module")
def outdir(tmp_path_factory):
    out = tmp_path_factory.mktemp("tracking")
    assert cli.main(["reproduce", "tracking", "--runs", str(RUNS), "--out", str(out), "--no-progress"]) == 0
    return out


def rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_writes_the_figures_and_tables(outdir):
    names = sorted(p.name for p in outdir.iterdir())
    assert names == ["tracking_bot.png", "tracking_events.csv", "tracking_rb.png", "tracking_steps.csv",
                     "tracking_summary.csv"] == sorted(tracking.OUTPUTS)
    for png in ("tracking_bot.png", "tracking_rb.png"):
        assert (outdir / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_summary_has_every_filter_of_both_scenarios_with_sane_numbers(outdir):
    summary = rows(outdir / "tracking_summary.csv")
    got = {(r["scenario"], r["filter"]) for r in summary}
    assert got == {(s, f) for s in ("bot", "rb") for f in tracking.FILTER_NAMES}
    for r in summary:
        assert int(r["runs"]) == RUNS and r["error"] == ""
        for key in ("anees_mean", "anis_mean", "position_rmse"):
            assert np.isfinite(float(r[key])) and float(r[key]) > 0
        if r["filter"] == "adaptive":
            assert r["position_rmse_smoothed"] == ""  # no RTS smoother for the adaptive filter
        else:  # the smoother uses the later measurements of its leg
            assert 0 < float(r["position_rmse_smoothed"]) < float(r["position_rmse"])
        assert 0.0 <= float(r["anees_share_inside"]) <= 1.0
    adaptive = [r for r in summary if r["filter"] == "adaptive"]
    for r in adaptive:
        counts = dict(item.split(":") for item in r["adaptive_choices"].split(" "))
        assert set(counts) <= {"EKF", "EKF2", "CKF", "GHKF(order=3)"}
        assert sum(int(v) for v in counts.values()) == RUNS * int(r["steps"])


def test_step_table_has_one_row_per_step_with_the_mon(outdir):
    steps = rows(outdir / "tracking_steps.csv")
    bot, rb = tracking.scenarios()
    assert [int(r["k"]) for r in steps] == list(range(1, bot.steps + 1)) + list(range(1, rb.steps + 1))
    for r in steps:
        assert 0.0 <= float(r["mon_median"]) <= 1.0 and 0.0 <= float(r["mon_clean_median"]) <= 1.0
        assert 0.0 <= float(r["adaptive_share_not_ekf"]) <= 1.0


def test_legs_of_the_observer_shift_truth_and_estimates_alike():
    """The filter restarted at a leg from the shifted estimate equals one run through the
    shift: with no shifts the bank is one filter call."""
    bot, _ = tracking.scenarios()
    rng = np.random.default_rng(1)
    xs, ys = tracking.simulate(bot, 3, rng)
    assert xs.shape == (3, bot.steps, 4) and ys.shape == (3, bot.steps, 1)
    res = tracking.filter_bank(bot, "ukf", ys)
    assert res.x.shape == (3, bot.steps, 4)
    # Across the first leg boundary: the prediction starts from the shifted estimate.
    k = min(bot.shifts)
    F = np.asarray(__import__("sympy").Matrix(bot.f.outputs).jacobian(bot.f.inputs), dtype=float)
    np.testing.assert_allclose(res.x_pred[:, k], (res.x[:, k - 1] + bot.shifts[k]) @ F.T, rtol=1e-12)


def test_bad_runs():
    with pytest.raises(SymmonError, match="runs"):
        tracking.run("unused", runs=1)


def test_event_table_rows_are_ekf_failures(outdir):
    for r in rows(outdir / "tracking_events.csv"):
        assert float(r["ekf_nees"]) > tracking.EVENT_NEES
        assert 0.0 <= float(r["mon_k"]) <= 1.0 and 0.0 <= float(r["mon_k_quantile"]) <= 1.0
        assert r["adaptive_choice"] in {"EKF", "EKF2", "CKF", "GHKF(order=3)"}
