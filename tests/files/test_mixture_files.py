"""Mixtures in model files and particle files (CSV) for --samples-file (issue 24)."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import symmon as sm
import symmon.files.samplefile as samplefile
from symmon.errors import ModelFileError
from symmon.files.modelfile import MAX_COMPONENTS, dump_model_file, load_model_file

#: The samples file is read by float() on decimal text: the same doubles as numpy's parse.
EXACT_RTOL = 1e-15
FUZZ = dict(deadline=2000, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

HEAD = '''name = "m"
inputs = ["x", "y"]
noise = ["w"]
outputs = ["x * y + w"]
'''
MIX_U = '''[u]
weights = [0.25, "3/4"]
means = [[1, 2], [3, "2*k"]]
covs = [[[1, 0], [0, 1]], [[2, 0.5], [0.5, 1]]]
'''
MIX_V = '''[v]
weights = [0.9, 0.1]
means = [0, 0]
stds = [0.1, 3]
'''


def write(tmp_path: Path, text: str, name: str = "m.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_mixtures_for_u_and_v_are_read(tmp_path):
    spec = load_model_file(write(tmp_path, HEAD + "[params]\nk = 2\n" + MIX_U + MIX_V))
    assert isinstance(spec.u, sm.GaussianMixture) and isinstance(spec.v, sm.GaussianMixture)
    np.testing.assert_array_equal(spec.u.weights, [0.25, 0.75])
    np.testing.assert_array_equal(spec.u.means, [[1, 2], [3, 4]])
    np.testing.assert_array_equal(spec.u.covs[1], [[2, 0.5], [0.5, 1]])
    np.testing.assert_allclose(spec.v.covs[:, 0, 0], [0.1**2, 9.0], rtol=EXACT_RTOL)  # std² as Gaussian.from_std squares it
    # and they are usable as read
    assert 0 <= sm.nonlinearity(spec.model, spec.u, spec.v).value <= 1


def test_a_dumped_mixture_reads_back(tmp_path):
    spec = load_model_file(write(tmp_path, HEAD + "[params]\nk = 2\n" + MIX_U + MIX_V))
    again = load_model_file(write(tmp_path, dump_model_file(spec), "again.toml"))
    for a, b in ((again.u, spec.u), (again.v, spec.v)):
        np.testing.assert_allclose(a.weights, b.weights, rtol=EXACT_RTOL)
        np.testing.assert_array_equal(a.means, b.means)
        np.testing.assert_array_equal(a.covs, b.covs)


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ("weights = [0.5, 0.6]\nmeans = [[0, 0], [1, 1]]\ncovs = [[[1, 0], [0, 1]], [[1, 0], [0, 1]]]",
         r"\[u\]: WeightError: weights must sum to 1"),
        ("weights = [1.5, -0.5]\nmeans = [[0, 0], [1, 1]]\nstds = [[1, 1], [1, 1]]", "non-negative"),
        ("weights = [1]\nmeans = [[0, 0], [1, 1]]\nstds = [[1, 1], [1, 1]]", "one entry per component"),
        ("weights = [1]\nmeans = [[0, 0]]\nstds = [[1, 1]]\ncovs = [[[1, 0], [0, 1]]]", "exactly one of 'covs'"),
        ("weights = [1]\nmeans = [[0, 0]]", "exactly one of 'covs'"),
        ("weights = [1]\nmean = [0, 0]\nstds = [[1, 1]]", "mixes the keys of a Gaussian"),
        ("weights = [1]\nmeans = [[0, 0, 0]]\nstds = [[1, 1, 1]]", r"component 0: mean has length 3 but there are 2"),
        ("weights = [1]\nmeans = [[0, 0]]\ncovs = [[[1, 2], [2, 1]]]", r"component 0: CovarianceError"),
        ("weights = []\nmeans = []\nstds = []", "non-empty list"),
        ("weights = 1\nmeans = [[0, 0]]\nstds = [[1, 1]]", "non-empty list"),
        ("weights = [\"__import__('os')\"]\nmeans = [[0, 0]]\nstds = [[1, 1]]", "not allowed|unknown|refused"),
        ("weights = [1]\nmeans = [[0, 0]]\nstds = [[1, 1]]\nextra = 1", "unknown key"),
    ],
)
def test_bad_mixture_tables_are_named_errors(tmp_path, table, match):
    text = 'name = "m"\ninputs = ["x", "y"]\noutputs = ["x * y"]\n[u]\n' + table + "\n"
    with pytest.raises(ModelFileError, match=match):
        load_model_file(write(tmp_path, text))


def test_too_many_components_are_refused(tmp_path):
    K = MAX_COMPONENTS + 1
    text = ('name = "m"\ninputs = ["x"]\noutputs = ["x"]\n[u]\n'
            f"weights = [{', '.join(['0'] * (K - 1) + ['1'])}]\nmeans = [{', '.join(['[0]'] * K)}]\n"
            f"stds = [{', '.join(['[1]'] * K)}]\n")
    with pytest.raises(ModelFileError, match=f"at most {MAX_COMPONENTS}"):
        load_model_file(write(tmp_path, text))


# --------------------------------------------------------------------------- particle files
x, y = sp.symbols("x y")
MODEL = sm.Model([x, y], [x * y])


def test_samples_file_columns_by_name_and_weights(tmp_path):
    p = write(tmp_path, "y, x ,weight\n1,2,1\n3.5e0,-4,3\n\n", "c.csv")
    e = sm.load_samples_file(p, MODEL)
    np.testing.assert_array_equal(e.samples, [[2.0, 1.0], [-4.0, 3.5]])
    np.testing.assert_array_equal(e.weights, [0.25, 0.75])
    e2 = sm.load_samples_file(write(tmp_path, "x,y\n1,2\n3,4\n", "d.csv"), MODEL)
    np.testing.assert_array_equal(e2.weights, [0.5, 0.5])


def test_samples_file_round_trips_numpy_doubles(tmp_path, rng):
    X = rng.normal(size=(200, 2)) * 10.0 ** rng.integers(-5, 5, size=(200, 1))
    lines = ["x,y"] + [f"{float(a)!r},{float(b)!r}" for a, b in X]
    e = sm.load_samples_file(write(tmp_path, "\n".join(lines), "c.csv"), MODEL)
    np.testing.assert_array_equal(e.samples, X)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "empty"),
        ("x,y\n", "no particles"),
        ("x,z\n1,2\n", "unknown column 'z'"),
        ("x,x,y\n1,2,3\n", "more than once"),
        ("x,weight\n1,2\n", "no column for the input 'y'"),
        ("x,y\n1,2\n3\n", "line 3: 1 cells, but the header has 2"),
        ("x,y\n1,nan\n", "line 2: column 'y': 'nan' is not a decimal number"),
        ("x,y\n1,inf\n", "not a decimal number"),
        ("x,y\n1,2*3\n", "not a decimal number"),
        ("x,y\n1,__import__('os')\n", "not a decimal number"),
        ("x,y\n1,1e999\n", "overflows a float"),
        ("x,y,weight\n1,2,-1\n", "WeightError: weights must be non-negative"),
        ("x,y,weight\n1,2,0\n", "all zero"),
    ],
)
def test_bad_samples_files_are_named_errors(tmp_path, text, match):
    with pytest.raises(ModelFileError, match=match):
        sm.load_samples_file(write(tmp_path, text, "c.csv"), MODEL)


def test_samples_file_must_be_a_regular_file(tmp_path):
    with pytest.raises(ModelFileError, match="samples file not found"):
        sm.load_samples_file(tmp_path / "none.csv", MODEL)
    with pytest.raises(ModelFileError, match="it is a directory"):
        sm.load_samples_file(tmp_path, MODEL)


def test_samplefile_never_names_an_evaluating_function():
    tree = ast.parse(Path(samplefile.__file__).read_text(encoding="utf-8"))
    used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    used |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
    assert used.isdisjoint({"eval", "exec", "compile", "sympify", "parse_expr", "literal_eval"})


@settings(max_examples=150, **FUZZ)
@given(text=st.text(alphabet=st.sampled_from(list("xyweigh,.0123456789e+-\n nai_()")), max_size=80))
def test_fuzz_samples_file_reads_or_raises_a_named_error(tmp_path, text):
    p = write(tmp_path, text, "f.csv")
    try:
        e = sm.load_samples_file(p, MODEL)
    except ModelFileError:
        return
    assert e.dim == 2 and np.all(np.isfinite(e.samples)) and abs(e.weights.sum() - 1) < 1e-12
