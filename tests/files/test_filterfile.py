"""Filter scenario files with noise symbols (non-additive noise) and units."""

from __future__ import annotations

import json

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.cli import parser as cli
from symmon.files.filterfile import load_filter_file, run_bank, simulate
from symmon.files.modelfile import ModelFileError

# A constant-velocity target driven by one acceleration noise a (x_k = f(x, a): the noise
# enters through G = [T²/2, T], with fewer components than the states) and seen with one
# position noise r.  Linear and Gaussian, so the EKF on [x; a] is the exact Kalman filter.
NOISY = """
name = "cv-accel"
states = ["p", "v"]
process_noise = ["a"]
dynamics = ["p + T*v + T**2/2*a", "v + T*a"]
measurement_noise = ["r"]
measurements = ["p + r"]
steps = 25
[params]
T = 0.5
[Q]
std = [0.4]
[R]
std = [0.3]
[x0]
mean = [0, 1]
std = [1, 0.5]
[units]
p = "m"
v = "m/s"
"measurements[0]" = "m"
"""


@pytest.fixture
def noisy(tmp_path):
    path = tmp_path / "cv.toml"
    path.write_text(NOISY)
    return path


def test_noise_symbols_make_models_with_noise(noisy):
    spec = load_filter_file(noisy)
    p, v = spec.f.inputs
    (a,), (r,) = spec.f.noise, spec.h.noise
    assert spec.f.outputs == (p + 0.5 * v + 0.125 * a, v + 0.5 * a) and spec.h.outputs == (p + r,)
    np.testing.assert_allclose([spec.Q[0, 0], spec.R[0, 0]], [0.4**2, 0.3**2], rtol=1e-15)  # std², rounding
    assert spec.Q.shape == spec.R.shape == (1, 1)
    assert spec.units == {"p": "m", "v": "m/s", "measurements[0]": "m"}
    assert spec.unit("v") == "m/s" and spec.unit("measurements[1]") is None


def test_simulation_puts_the_noise_into_f_and_h(noisy):
    """Two steps rebuilt by hand from the same generator: the draws are x_0, then for each
    step the process noise and the measurement noise, in that order."""
    spec = load_filter_file(noisy)
    runs = 3
    xs, ys = simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, 2, runs, seed=7)
    rng = np.random.default_rng(7)
    x = spec.x0.mean + rng.standard_normal((runs, 2)) @ np.diag([1.0, 0.5])
    for k in range(2):
        a = 0.4 * rng.standard_normal((runs, 1))[:, 0]
        x = np.column_stack([x[:, 0] + 0.5 * x[:, 1] + 0.125 * a, x[:, 1] + 0.5 * a])
        y = x[:, 0] + 0.3 * rng.standard_normal((runs, 1))[:, 0]
        np.testing.assert_allclose(xs[:, k], x, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(ys[:, k, 0], y, rtol=1e-13, atol=1e-13)


def test_the_exact_filter_of_a_noise_symbol_scenario_is_consistent(noisy):
    """Linear Gaussian with the noise as a model argument: mean NEES n and NIS n_y within 5
    standard errors of the run averages (independent across runs)."""
    spec = load_filter_file(noisy)
    runs = 200
    xs, ys = simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, runs, seed=3)
    (row,) = run_bank(spec.f, spec.h, spec.Q, spec.R, spec.x0, xs, ys, ["ekf"])
    for stat, d in ((row.result.nees(xs), 2), (row.result.nis(), 1)):
        per_run = stat.mean(axis=1)
        assert abs(per_run.mean() - d) < 5 * per_run.std(ddof=1) / np.sqrt(runs)


def test_an_additive_scenario_simulates_as_before(tmp_path):
    """Without noise symbols the noise is added: x_k = f(x) + w_k, y_k = h(x) + e_k."""
    path = tmp_path / "add.toml"
    path.write_text(NOISY.replace('process_noise = ["a"]\n', "").replace('measurement_noise = ["r"]\n', "")
                    .replace('dynamics = ["p + T*v + T**2/2*a", "v + T*a"]', 'dynamics = ["p + T*v", "v"]')
                    .replace('measurements = ["p + r"]', 'measurements = ["p"]')
                    .replace("[Q]\nstd = [0.4]", "[Q]\nstd = [0.2, 0.4]"))
    spec = load_filter_file(path)
    assert spec.f.n_v == 0 and spec.Q.shape == (2, 2)
    xs, ys = simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, 1, 2, seed=1)
    rng = np.random.default_rng(1)
    x = spec.x0.mean + rng.standard_normal((2, 2)) @ np.diag([1.0, 0.5])
    x = np.column_stack([x[:, 0] + 0.5 * x[:, 1], x[:, 1]]) + rng.standard_normal((2, 2)) @ np.diag([0.2, 0.4])
    np.testing.assert_allclose(xs[:, 0], x, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("edit, match", [
    (('measurements = ["p + r"]', 'measurements = ["p + a"]'), "unknown name 'a'"),      # w only in f
    (('dynamics = ["p + T*v + T**2/2*a", "v + T*a"]', 'dynamics = ["p + r", "v"]'), "unknown name 'r'"),
    (('process_noise = ["a"]', 'process_noise = ["v"]'), "duplicate name 'v'"),
    (("[Q]\nstd = [0.4]", "[Q]\nstd = [0.4, 0.1]"), "Q"),                         # one noise symbol
    (('p = "m"', 'q = "m"'), "unknown key 'q'"),
    (('"measurements[0]" = "m"', '"measurements[1]" = "m"'), "measurements\\[1\\]"),
    (('p = "m"', 'p = ""'), "non-empty unit string"),
])
def test_bad_noise_symbols_and_units_name_the_fault(tmp_path, edit, match):
    path = tmp_path / "bad.toml"
    path.write_text(NOISY.replace(*edit))
    with pytest.raises(ModelFileError, match=match):
        load_filter_file(path)


def test_cli_filter_prints_units_and_plots_one_rmse_panel_per_unit(capsys, monkeypatch, noisy, tmp_path):
    from symmon.reproduce import common

    figures = []
    real = common.save_plot  # every --plot figure is saved by it (300 dpi)

    def keep(fig, path):
        figures.append([ax.get_ylabel() for ax in fig.axes])
        return real(fig, path)

    monkeypatch.setattr(common, "save_plot", keep)
    png = tmp_path / "nees.png"
    assert cli.main(["filter", str(noisy), "--runs", "10", "--filters", "ekf,ukf", "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "RMSE (p [m], v [m/s])" in out
    (labels,) = figures
    assert labels[2].startswith("RMSE of (p) [m]") and labels[3].startswith("RMSE of (v) [m/s]")
    assert "log-lik" in out
    assert cli.main(["filter", str(noisy), "--runs", "5", "--filters", "ukf", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["units"] == {"p": "m", "v": "m/s", "measurements[0]": "m"}
    spec = load_filter_file(noisy)
    xs, ys = simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, 5, seed=0)
    want = sm.NonlinearKalmanFilter(spec.f, spec.h, spec.Q, spec.R, sm.UT.ut1()).filter(ys, spec.x0).log_likelihood
    np.testing.assert_allclose(report["filters"][0]["log_likelihood"], want, rtol=1e-12)


def test_the_filter_on_a_scenario_equals_the_api(noisy):
    spec = load_filter_file(noisy)
    xs, ys = simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, 4, seed=2)
    a = sm.NonlinearKalmanFilter(spec.f, spec.h, spec.Q, spec.R, sm.UT.ut1()).filter(ys, spec.x0)
    (row,) = run_bank(spec.f, spec.h, spec.Q, spec.R, spec.x0, xs, ys, ["ukf"])
    np.testing.assert_array_equal(row.result.x, a.x)
    assert isinstance(spec.f.noise[0], sp.Symbol)


def test_a_filter_whose_statistics_fail_is_reported_not_fatal(tmp_path, capsys):
    """A state known exactly (c: no prior spread, no process noise) has no NEES: the bank
    reports it on that filter's row, and the command still prints the table (it used to end
    with the error)."""
    path = tmp_path / "known.toml"
    path.write_text(NOISY.replace('states = ["p", "v"]', 'states = ["p", "v", "c"]')
                    .replace('dynamics = ["p + T*v + T**2/2*a", "v + T*a"]', 'dynamics = ["p + T*v + T**2/2*a", "v + T*a", "c"]')
                    .replace('measurements = ["p + r"]', 'measurements = ["p + c + r"]')
                    .replace("mean = [0, 1]\nstd = [1, 0.5]", "mean = [0, 1, 2]\nstd = [1, 0.5, 0]"))
    spec = load_filter_file(path)
    xs, ys = simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, 3, seed=0)
    row, = run_bank(spec.f, spec.h, spec.Q, spec.R, spec.x0, xs, ys, ["ekf"])
    assert row.result is None and "is singular: it has variance 0 in component 2" in row.error
    assert cli.main(["filter", str(path), "--runs", "3", "--filters", "ekf"]) == 0
    assert "ekf       failed: the state covariance P" in capsys.readouterr().out
