"""The CLI with a mixture in the model file and with --samples-file particles (issue 24)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import symmon as sm
from symmon import cli

from helpers import EXAMPLES

#: The CLI prints floats through JSON with repr precision: the API's numbers to rounding.
CLI_API_RTOL = 1e-12

MIXTURE = '''name = "bot_mixture"
inputs = ["x", "y", "vx", "vy"]
outputs = ["atan2(x, y)"]
angles = [0]

[u]
weights = [0.5, 0.3, 0.2]
means = [[300, 300, 5, 8.7], [600, 600, 5, 8.7], [1200, 1200, 5, 8.7]]
stds = [[30, 30, 1, 1], [60, 60, 1, 1], [120, 120, 1, 1]]
'''


def run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def files(tmp_path):
    model = tmp_path / "mix.toml"
    model.write_text(MIXTURE, encoding="utf-8")
    spec = sm.load_model_file(model)
    X = spec.u.sample(2000, 7)
    w = np.random.default_rng(8).uniform(0.5, 1.5, 2000)
    rows = ["vy,x,y,vx,weight"] + [f"{r[3]!r},{r[0]!r},{r[1]!r},{r[2]!r},{wi!r}" for r, wi in zip(X.tolist(), w.tolist())]
    cloud = tmp_path / "particles.csv"
    cloud.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return model, cloud, spec, sm.Empirical(X, w)


def test_propagate_a_mixture_file_equals_the_api(capsys, files):
    model, _, spec, _ = files
    code, out, err = run(capsys, "propagate", model, "--transform", "ut1", "--json")
    assert (code, err) == (0, "")
    m = sm.propagate(spec.model, spec.u, transform=sm.UT.ut1())
    np.testing.assert_allclose(json.loads(out)["mean"], m.mean, rtol=CLI_API_RTOL)
    np.testing.assert_allclose(json.loads(out)["cov"], m.cov, rtol=CLI_API_RTOL)


def test_nonlinearity_of_particles_equals_the_api(capsys, files):
    model, cloud, spec, e = files
    code, out, err = run(capsys, "nonlinearity", EXAMPLES / "bot.toml", "--samples-file", cloud, "--json")
    assert (code, err) == (0, "")
    got = json.loads(out)
    ref = sm.nonlinearity(spec.model, e)
    assert got["value"] == pytest.approx(ref.value, rel=CLI_API_RTOL)
    assert got["stderr"] == pytest.approx(ref.stderr, rel=CLI_API_RTOL)
    code, out, _ = run(capsys, "nonlinearity", EXAMPLES / "bot.toml", "--samples-file", cloud)
    assert code == 0 and "jackknife standard error of the particles" in out and "ESS" in out


def test_propagate_particles_json(capsys, files):
    _, cloud, spec, e = files
    code, out, err = run(capsys, "propagate", EXAMPLES / "bot.toml", "--samples-file", cloud, "--json")
    assert (code, err) == (0, "")
    m = sm.propagate(spec.model, e)
    np.testing.assert_allclose(json.loads(out)["mean"], m.mean, rtol=CLI_API_RTOL)
    np.testing.assert_allclose(json.loads(out)["stderr"]["mean"], m.stderr["mean"], rtol=CLI_API_RTOL)


def test_advise_with_particles_reports_their_mon_and_ranks_their_gaussian(capsys, files):
    _, cloud, spec, e = files
    code, out, err = run(capsys, "advise", EXAMPLES / "bot.toml", "--samples-file", cloud, "--tol", "0.05",
                         "--samples", "20000", "--json")
    assert (code, err) == (0, "")
    got = json.loads(out)
    assert got["samples"]["particles"] == 2000
    assert got["samples"]["mon"] == pytest.approx(sm.nonlinearity(spec.model, e).value, rel=CLI_API_RTOL)
    ref = sm.advise(spec.model, e.as_gaussian(), tol=0.05, samples=20000)
    assert got["choice"] == ref.choice_name and got["reference_mon"] == pytest.approx(ref.reference_mon)


def test_usage_and_file_errors(capsys, files, tmp_path):
    model, cloud, _, _ = files
    code, _, err = run(capsys, "nonlinearity", model, "--alpha-sweep", "0.1:1:3")
    assert code == 2 and "a mixture" in err
    code, _, err = run(capsys, "nonlinearity", EXAMPLES / "bot.toml", "--samples-file", cloud, "--alpha-sweep", "0.1:1:3")
    assert code == 2 and "cannot scale the particles" in err
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,vx\n1,2,3\n", encoding="utf-8")
    code, _, err = run(capsys, "propagate", EXAMPLES / "bot.toml", "--samples-file", bad)
    assert code == 1 and "no column for the input 'vy'" in err
    assert Path(cloud).exists()  # nothing is written next to the inputs


def test_compare_and_prove_invariance_take_a_mixture_file(capsys, files):
    model, _, spec, _ = files
    code, out, err = run(capsys, "compare", model, "--samples", "2000")
    assert code == 0 and "gh" in out
    code, out, err = run(capsys, "prove-invariance", model)
    assert code == 0 and "holds" in out
