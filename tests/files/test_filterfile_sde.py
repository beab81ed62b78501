"""The ``[sde]`` table of filter scenario files: the dynamics and Q derived by discretisation."""

import re

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.files.filterfile import load_filter_file, run_bank, simulate_scenario
from symmon.files.modelfile import ModelFileError

from helpers import EXAMPLES

BASE = """
name = "wna"
states = ["p", "v"]
measurements = ["p"]
steps = 10
[params]
q = 0.5
[R]
std = [2.0]
[x0]
mean = [0, 10]
std = [5, 2]
"""
WNA_SDE = """
[sde]
drift = ["v", "0"]
diffusion = [["0"], ["1"]]
spectral_density = "q"
dt = 0.5
time_unit = "s"
"""


def write(tmp_path, text, name="s.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_dynamics_and_q_are_the_exact_discretisation(tmp_path):
    spec = load_filter_file(write(tmp_path, BASE + WNA_SDE))
    assert spec.sde is not None and spec.sde.method == "exact" and spec.sde.dt == 0.5
    assert spec.sde.time_unit == "s" and spec.sde.substeps == 1
    assert [str(s) for s in spec.sde.sde.params] == ["q"] and spec.sde.sde.params[0].is_positive
    assert spec.f.n_v == 2 and np.array_equal(spec.Q, np.eye(2)) and not spec.f.params
    # the derived f: F x + G w with G Gᵀ = Q(0.5) of q = 0.5
    p, v = spec.f.inputs
    J = sp.Matrix(spec.f.outputs).jacobian(list(spec.f.noise))
    G = np.array(J, dtype=float)
    dt, q = 0.5, 0.5
    np.testing.assert_allclose(G @ G.T, q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]), rtol=1e-14)
    mean = [e.subs({w: 0 for w in spec.f.noise}) for e in spec.f.outputs]
    assert sp.simplify(mean[0] - (p + 0.5 * v)) == 0 and mean[1] == v


def test_approximate_methods_and_defaults(tmp_path):
    text = BASE.replace('"p", "v"]', '"x"]').replace('mean = [0, 10]\nstd = [5, 2]', 'mean = [1]\nstd = [0.1]')
    text = text.replace('measurements = ["p"]', 'measurements = ["x"]')
    sde = '\n[sde]\ndrift = ["sin(x) - x**3/2"]\nmethod = "taylor1.5"\nsubsteps = 2\ndt = 0.1\n'
    spec = load_filter_file(write(tmp_path, text + sde))
    assert spec.f.n_v == 4 and spec.Q.shape == (4, 4)  # ξ₁, ξ₂ of 2 sub-steps; L and Q_c default to I
    assert spec.sde.sde.diffusion == sp.eye(1) and spec.sde.time_unit is None


def test_a_nonlinear_sde_takes_more_than_four_substeps(tmp_path):
    """8 sub-steps of taylor1.5 (the cap was 4: the composed expression grew geometrically)."""
    text = BASE.replace('"p", "v"]', '"x"]').replace('mean = [0, 10]\nstd = [5, 2]', 'mean = [1]\nstd = [0.1]')
    text = text.replace('measurements = ["p"]', 'measurements = ["x"]')
    sde = '\n[sde]\ndrift = ["sin(x) - x**3/2"]\nmethod = "taylor1.5"\nsubsteps = 8\ndt = 0.4\n'
    spec = load_filter_file(write(tmp_path, text + sde))
    assert spec.f.n_v == 16 and spec.sde.substeps == 8


def test_a_scalar_and_a_matrix_spectral_density_agree(tmp_path):
    scalar = load_filter_file(write(tmp_path, BASE + WNA_SDE, "a.toml"))
    matrix = load_filter_file(write(tmp_path, BASE + WNA_SDE.replace('"q"', '[["q"]]'), "b.toml"))
    flat = load_filter_file(write(tmp_path, BASE + WNA_SDE.replace('[["0"], ["1"]]', '[0, 1]'), "c.toml"))
    assert scalar.f.outputs == matrix.f.outputs == flat.f.outputs


def test_the_example_runs_the_filters(tmp_path):
    spec = load_filter_file(EXAMPLES / "wna_sde.toml")
    assert spec.sde.method == "exact" and spec.sde.time_unit == "s"
    xs, ys = sm.simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, steps=5, runs=2, seed=0)
    assert xs.shape == (2, 5, 2)


IRREGULAR = WNA_SDE.replace("dt = 0.5", "times = [0.5, 1.25, 3.0, 3.5]\nt0 = 0.25")


def test_irregular_times_keep_dt_a_per_step_parameter(tmp_path):
    """[sde].times after t0: f keeps dt as a parameter, the intervals are the scenario's
    step_params, steps may be left out, and simulation and filters take them."""
    spec = load_filter_file(write(tmp_path, BASE.replace("steps = 10\n", "") + IRREGULAR))
    assert spec.steps == 4 and [str(s) for s in spec.f.params] == ["dt"]
    np.testing.assert_allclose(spec.step_params["dt"], [0.25, 0.75, 1.75, 0.5], rtol=0, atol=1e-15)
    assert spec.sde.intervals == (0.25, 0.75, 1.75, 0.5) and spec.sde.t0 == 0.25 and spec.sde.dt == 1.75
    by_list = load_filter_file(write(tmp_path, BASE.replace("steps = 10", "steps = 4")
                                     + WNA_SDE.replace("dt = 0.5", "dt = [0.25, 0.75, 1.75, 0.5]"), "b.toml"))
    np.testing.assert_array_equal(by_list.step_params["dt"], spec.step_params["dt"])
    xs, ys = simulate_scenario(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, 3, 0, params=spec.step_params)
    # the truth's steps are the intervals: the same draws as simulate with params dt
    xs2, _ = sm.simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, 4, 3, params={"dt": spec.step_params["dt"]}, seed=0)
    np.testing.assert_array_equal(xs, xs2)
    rows = run_bank(spec.f, spec.h, spec.Q, spec.R, spec.x0, xs, ys, ["ekf", "ukf"], smooth=True,
                    params=spec.step_params)
    assert all(r.error is None for r in rows), [r.error for r in rows]
    kf = sm.NonlinearKalmanFilter(spec.f, spec.h, spec.Q, spec.R, "ekf")
    np.testing.assert_allclose(rows[0].result.x, kf.filter(ys, spec.x0, params=spec.step_params).x, rtol=1e-12)


def test_symmon_filter_runs_a_scenario_with_irregular_times(tmp_path, capsys):
    from symmon import cli

    path = write(tmp_path, BASE.replace("steps = 10\n", "") + IRREGULAR)
    assert cli.main(["filter", str(path), "--runs", "3", "--filters", "ekf,ukf"]) == 0
    assert "3 runs of 4 steps" in capsys.readouterr().out


@pytest.mark.parametrize("change, key, message", [
    (lambda t: t.replace('drift = ["v", "0"]', 'drift = ["v"]'), "[sde].drift", "one expression per state"),
    (lambda t: t.replace('drift = ["v", "0"]', 'drift = ["v", "u"]'), "[sde].drift[1]", "u"),
    (lambda t: t.replace('drift = ["v", "0"]', 'drift = "v"'), "[sde].drift", "a list of expressions"),
    (lambda t: t.replace('[["0"], ["1"]]', '[["0"], ["1"], ["0"]]'), "[sde].diffusion", "one row per state"),
    (lambda t: t.replace('[["0"], ["1"]]', '[["0", "1"], ["1"]]'), "[sde].diffusion", "rows of one"),
    (lambda t: t.replace('[["0"], ["1"]]', '[["0"], ["p"]]') + 'method = "taylor1.5"\n', "[sde].method",
     "free of the states"),
    (lambda t: t.replace('"q"', '[["q", 0], [0, "q"]]'), "[sde].spectral_density", "columns"),
    (lambda t: t.replace('"q"', '"-q"'), "[sde].spectral_density", "negative"),
    (lambda t: t.replace('"q"', '[[1, 2], [2, 1]]').replace('[["0"], ["1"]]', '[["0", "0"], ["1", "1"]]'),
     "[sde].spectral_density", "positive semi-definite"),
    (lambda t: t.replace('"q"', '"p*q"'), "[sde].spectral_density", "p"),
    (lambda t: t.replace('"q"', '[1, 2]'), "[sde].spectral_density", "flat list"),
    (lambda t: t.replace("dt = 0.5", "dt = -1"), "[sde].dt", "positive"),
    (lambda t: t.replace("dt = 0.5", ""), "[sde]", "exactly one of them"),
    (lambda t: t.replace("dt = 0.5", "dt = 0.5\ntimes = [1, 2]"), "[sde]", "exactly one of them"),
    (lambda t: t.replace("dt = 0.5", "dt = 0.5\nt0 = 1"), "[sde].t0", "only with times"),
    (lambda t: t.replace("dt = 0.5", "times = [0.5, 1.5, 1.5]").replace("steps = 10\n", ""), "[sde].times",
     "times[2] = 1.5 follows times[1] = 1.5"),
    (lambda t: t.replace("dt = 0.5", "times = [0.5, 1.5]\nt0 = 0.5").replace("steps = 10\n", ""), "[sde].times",
     "after t0"),
    (lambda t: t.replace("dt = 0.5", "times = []"), "[sde].times", "non-empty list"),
    (lambda t: t.replace("dt = 0.5", "times = [0.5, \"x\"]"), "[sde].times[1]", "x"),
    (lambda t: t.replace("dt = 0.5", "dt = [0.5, 0, 1]").replace("steps = 10\n", ""), "[sde].dt[1]", "positive"),
    (lambda t: t.replace("dt = 0.5", "times = [0.5, 1.5, 2]"), "steps", "number of measurement times"),
    (lambda t: t.replace("dt = 0.5", "dt = 0.5\nsubsteps = 2"), "[sde].substeps", "does not apply"),
    (lambda t: t.replace("dt = 0.5", "dt = 0.5\nsubsteps = 257\nmethod = \"euler\""), "[sde].substeps",
     "integer in [1, 256]"),
    (lambda t: t.replace("dt = 0.5", "dt = 0.5\nmethod = \"magic\""), "[sde].method", "must be one of"),
    (lambda t: t.replace('drift = ["v", "0"]', 'drift = ["v", "-v**3"]'), "[sde].method", "linear drift"),
    (lambda t: t + "colour = 1\n", "[sde]", "unknown key(s) ['colour']"),
    (lambda t: t.replace("steps = 10", 'steps = 10\ndynamics = ["p", "v"]'), "dynamics", "must be absent"),
    (lambda t: t.replace("[sde]", "[Q]\nstd = [1, 1]\n[sde]"), "Q", "must be absent"),
    (lambda t: t.replace("q = 0.5", "q = 0.5\ndt = 2"), "[sde]", "'dt' is the step"),
])
def test_bad_sde_tables_name_the_file_and_the_key(tmp_path, change, key, message):
    path = write(tmp_path, change(BASE + WNA_SDE))
    with pytest.raises(ModelFileError) as info:
        load_filter_file(path)
    text = str(info.value)
    assert str(path) in text and key in text and message in text, text


def test_without_sde_dynamics_and_q_are_still_required(tmp_path):
    with pytest.raises(ModelFileError, match=re.escape("missing key(s) ['dynamics', 'Q']")):
        load_filter_file(write(tmp_path, BASE))


def test_a_free_parameter_stays_a_parameter_of_the_derived_dynamics(tmp_path):
    """``symmon fit`` keeps [params] free: the SDE's q is then a parameter of f, and f at the
    file's value is the fixed scenario's f."""
    path = write(tmp_path, BASE + WNA_SDE)
    free = load_filter_file(path, free=["q"])
    fixed = load_filter_file(path)
    assert [str(s) for s in free.f.params] == ["q"]
    at = free.f.with_params({"q": 0.5})
    point = {s: 0.3 for s in (*at.inputs, *at.noise)}
    for a, b in zip(at.outputs, fixed.f.outputs):
        assert float(a.subs(point)) == pytest.approx(float(b.subs(point)), rel=1e-14)


def test_symmon_discretize_of_irregular_times_is_at_the_longest_interval(tmp_path, capsys):
    from symmon import cli

    path = write(tmp_path, BASE.replace("steps = 10\n", "") + IRREGULAR)
    assert cli.main(["discretize", str(path)]) == 0
    assert "at dt = 1.75 s (the longest of the file's intervals)" in capsys.readouterr().out


def test_symmon_fit_simulates_and_filters_at_irregular_times(tmp_path, capsys):
    import json

    from symmon import cli

    times = ", ".join(f"{t:.3f}" for t in np.cumsum(np.random.default_rng(4).uniform(0.5, 2.0, 30)))
    path = write(tmp_path, BASE.replace("steps = 10\n", "") + WNA_SDE.replace("dt = 0.5", f"times = [{times}]"))
    assert cli.main(["fit", str(path), "--param", "q=1.0", "--runs", "40", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["steps"] == 30 and abs(out["estimates"]["q"] - 0.5) < 4 * out["std_errors"]["q"]
