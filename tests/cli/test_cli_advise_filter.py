"""``symmon advise FILE.toml --filter``: the filter advice for a filter scenario file."""

from __future__ import annotations

import json

import pytest

import symmon as sm
from symmon import cli
from symmon.files.filterfile import load_filter_file
from symmon.filters.selection import MIN_RUNS

SCENARIO = """
name = "cv-position"
states = ["p", "v"]
dynamics = ["p + v", "v"]
measurements = ["p"]
steps = 12
[Q]
std = [0.1, 0.1]
[R]
std = [1.0]
[x0]
mean = [0, 1]
std = [1, 1]
"""


@pytest.fixture
def scenario(tmp_path):
    path = tmp_path / "cv.toml"
    path.write_text(SCENARIO)
    return path


def test_the_table_and_one_recommendation(capsys, scenario) -> None:
    assert cli.main(["advise", str(scenario), "--filter", "--runs", "8"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("cv-position: filter advice:")
    assert out.count("recommendation:") == 1 and out.count("<- choice") == 1
    assert "(unitless)" in out and "(evals/step)" in out and "pilot of 8 simulated runs" in out


def test_json_equals_the_api(capsys, scenario) -> None:
    assert cli.main(["advise", str(scenario), "--filter", "--runs", "8", "--seed", "2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    spec = load_filter_file(scenario)
    a = sm.advise_filter(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, runs=8, seed=2)
    assert out["scenario"] == "cv-position" and out["choice"] == a.choice and out["runs"] == 8
    assert [c["name"] for c in out["candidates"]] == [c.name for c in a.candidates]
    assert [c["rmse"] for c in out["candidates"]] == [c.rmse for c in a.candidates]
    assert out["units"]["mon"] == "unitless"


def test_budget_and_refusals(capsys, scenario, tmp_path) -> None:
    assert cli.main(["advise", str(scenario), "--filter", "--runs", "16", "--budget", "1e-9", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["runs"] == MIN_RUNS
    assert cli.main(["advise", str(scenario), "--filter", "--budget", "-1"]) == 2
    assert "positive number of seconds" in capsys.readouterr().err
    samples = tmp_path / "s.csv"
    samples.write_text("p,v\n0,1\n")
    assert cli.main(["advise", str(scenario), "--filter", "--samples-file", str(samples)]) != 0
    assert "--samples-file is for a model file" in capsys.readouterr().err
