"""Scenario files and ``symmon filter`` with the Gaussian-sum and particle filters."""

from __future__ import annotations

import json

import numpy as np
import pytest

import symmon as sm
from symmon import cli
from symmon.files.filterfile import load_filter_file, make_filter, run_bank
from symmon.files.modelfile import ModelFileError

SCENARIO = """
name = "rb-gsf"
states = ["px", "py", "vx", "vy"]
dynamics = ["px + vx", "py + vy", "vx", "vy"]
measurements = ["hypot(px, py)", "atan2(py, px)"]
angles = [1]
steps = 6
[Q]
std = [0.1, 0.1, 0.05, 0.05]
[R]
std = [1.0, 0.02]
[x0]
mean = [-20, 50, 0, -2]
std = [2, 2, 0.2, 0.2]
"""


@pytest.fixture()
def scenario(tmp_path):
    def write(extra: str = ""):
        p = tmp_path / "s.toml"
        p.write_text(SCENARIO + extra)
        return p
    return write


def test_settings_reach_the_filters(scenario) -> None:
    spec = load_filter_file(scenario('[gsf]\ntransform = "ekf"\nsplit = 0.05\nmax_components = 5\n'
                                     '[pf]\nparticles = 300\nseed = 3\nregularise = true\n'))
    assert spec.settings == {"gsf": {"transform": "ekf", "split": 0.05, "max_components": 5},
                             "pf": {"particles": 300, "seed": 3, "regularise": True}}
    gsf = make_filter("gsf", spec.f, spec.h, spec.Q, spec.R, settings=spec.settings)
    assert isinstance(gsf, sm.GaussianSumFilter) and gsf.transform == sm.TT1() and gsf.split == 0.05
    pf = make_filter("pf", spec.f, spec.h, spec.Q, spec.R, settings=spec.settings)
    assert isinstance(pf, sm.ParticleFilter) and pf.particles == 300 and pf.seed == 3 and pf.regularise
    xs, ys = sm.simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, runs=4, seed=1)
    rows = run_bank(spec.f, spec.h, spec.Q, spec.R, spec.x0, xs, ys, ["ekf", "gsf", "pf"], settings=spec.settings)
    assert all(r.error is None for r in rows), [r.error for r in rows]
    assert rows[1].anis is None and rows[1].anees.value.shape == (spec.steps,)


def test_the_adaptive_settings_reach_the_filters(scenario) -> None:
    """Issue 48, item 2: the GSF's merge-back and the particle filter's action on a collapse,
    from a scenario file through the registry."""
    spec = load_filter_file(scenario('[gsf]\nsplit = 0.05\nmerge_back = 0.001\n'
                                     '[pf]\non_collapse = "shrink"\ncollapse_fraction = 0.3\n'))
    gsf = make_filter("gsf", spec.f, spec.h, spec.Q, spec.R, settings=spec.settings)
    pf = make_filter("pf", spec.f, spec.h, spec.Q, spec.R, settings=spec.settings)
    assert gsf.merge_back == 0.001 and pf.on_collapse == "shrink" and pf.collapse_fraction == 0.3
    with pytest.raises(ModelFileError, match="on_collapse must be"):
        load_filter_file(scenario('[pf]\non_collapse = "inflate"\n'))


@pytest.mark.parametrize("extra, match", [
    ("[gsf]\nsplits = 0.1\n", "unknown setting"),
    ("[gsf]\nsplit = \"big\"\n", "a number"),
    ("[pf]\nparticles = 1.5\n", "an integer"),
    ("[pf]\nregularise = 1\n", "true or false"),
    ("[gsf]\nsplit = 2.0\n", "split must be"),
    ("[gsf]\ntransform = \"kalman\"\n", "unknown filter"),
])
def test_bad_settings_name_the_table(scenario, extra, match) -> None:
    with pytest.raises(ModelFileError, match=match):
        load_filter_file(scenario(extra))


def test_the_cli_runs_gsf_and_pf(scenario, capsys) -> None:
    path = scenario("[pf]\nparticles = 200\n")
    assert cli.main(["filter", str(path), "--filters", "ukf,gsf,pf", "--runs", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    names = [f["name"] for f in out["filters"]]
    assert names == ["ukf", "gsf", "pf"]
    gsf = out["filters"][1]
    assert gsf["anis"] is None and gsf["method"].startswith("GSF(UKF") and np.isfinite(gsf["anees"]).all()
    assert cli.main(["filter", str(path), "--filters", "gsf,pf", "--runs", "2"]) == 0
    assert "gsf" in capsys.readouterr().out
