"""``symmon discretize``: F(dt) and Q(dt) of a scenario's [sde] table, and ``symmon filter`` on an SDE
scenario (issue 50, item 6)."""

import json

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.cli import parser as cli
from symmon.files.filterfile import load_filter_file

from helpers import EXAMPLES

WNA = EXAMPLES / "wna_sde.toml"
DT = sp.Symbol("dt", positive=True)

SINGER = """
name = "singer"
states = ["p", "v", "a"]
measurements = ["p"]
steps = 5
[params]
alpha = 0.5
s2 = 2.0
[sde]
drift = ["v", "a", "-alpha*a"]
diffusion = [0, 0, 1]
spectral_density = "2*alpha*s2"
dt = 0.25
[R]
std = [1.0]
[x0]
mean = [0, 0, 0]
std = [1, 1, 1]
"""


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def parse(rows, sde):
    """A matrix of the command's JSON strings, read with the SDE's own symbols (test side only)."""
    names = {str(s): s for s in (*sde.states, *sde.params)} | {"dt": DT}
    return sp.Matrix([[sp.sympify(e, locals=names) for e in row] for row in rows])


@pytest.mark.parametrize("path", ["wna", "singer"])
def test_json_is_the_sdes_symbolic_discretisation(capsys, tmp_path, path):
    if path == "wna":
        file = WNA
    else:
        file = tmp_path / "singer.toml"
        file.write_text(SINGER)
    code, out, err = run(capsys, "discretize", file, "--method", "exact", "--json")
    assert code == 0, err
    doc = json.loads(out)
    sde = load_filter_file(file).sde.sde
    F, Q = parse(doc["F"], sde), parse(doc["Q"], sde)
    assert sp.simplify(F - sde.transition_matrix(DT)) == sp.zeros(sde.n, sde.n)
    assert sp.simplify(Q - sde.noise_cov(DT)) == sp.zeros(sde.n, sde.n)
    assert doc["latex"]["Q"] == sp.latex(sde.noise_cov(DT))
    values = {s: load_filter_file(file).params[str(s)] for s in sde.params} | {DT: doc["dt"]}
    np.testing.assert_allclose(doc["Q_at_dt"], np.array(sde.noise_cov(DT).subs(values), dtype=float), rtol=1e-14)
    assert "scales Q_c" in doc["time_unit_note"]


def test_wna_json_against_the_textbook_closed_form(capsys):
    code, out, _ = run(capsys, "discretize", WNA, "--json")
    doc = json.loads(out)
    assert doc["method"] == "exact" and doc["time_unit"] == "s" and doc["units"] == {"p": "m", "v": "m/s"}
    q = sp.Symbol("q", positive=True)
    sde = load_filter_file(WNA).sde.sde
    expected = q * sp.Matrix([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]])
    assert sp.simplify(parse(doc["Q"], sde) - expected) == sp.zeros(2, 2)
    np.testing.assert_allclose(doc["Q_at_dt"], 0.5 * np.array([[1 / 3, 1 / 2], [1 / 2, 1]]), rtol=1e-15)
    assert doc["F_at_dt"] == [[1.0, 1.0], [0.0, 1.0]]


def test_text_prints_f_q_latex_and_the_time_unit(capsys):
    code, out, _ = run(capsys, "discretize", WNA)
    assert code == 0
    sde = load_filter_file(WNA).sde.sde
    assert "time unit: s" in out and "the time unit scales Q_c" in out
    assert sp.latex(sde.noise_cov(DT)) in out and sp.latex(sde.transition_matrix(DT)) in out
    assert "p [m], v [m/s]" in out and "at dt = 1 s" in out


def test_an_approximate_method_prints_the_transition(capsys):
    code, out, _ = run(capsys, "discretize", WNA, "--method", "euler", "--json")
    doc = json.loads(out)
    sde = load_filter_file(WNA).sde.sde
    f = sde.discretize("euler")
    assert doc["transition"] == [str(e) for e in f.outputs] and doc["noise"] == ["w0"]


def test_a_file_without_sde_is_an_input_error(capsys):
    code, _, err = run(capsys, "discretize", EXAMPLES / "rb_close.toml")
    assert code == 1 and "no [sde] table" in err


def test_a_bad_method_is_a_usage_error(capsys):
    code, _, err = run(capsys, "discretize", WNA, "--method", "magic")
    assert code == 2 and "invalid choice" in err


def test_the_example_runs_the_filters(capsys):
    code, out, err = run(capsys, "filter", WNA, "--runs", "5", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["scenario"] == "wna-sde" and doc["steps"] == 50
    ekf = next(f for f in doc["filters"] if f["name"] == "ekf")
    assert "error" not in ekf and len(ekf["rmse"]) == 50
    code, out, err = run(capsys, "filter", WNA, "--runs", "5")
    assert code == 0 and "ekf" in out, err
