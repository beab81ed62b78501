"""A catalogue of bad inputs across the API and the ``symmon`` command (issue 7).

Each case asserts a clear error (its type and the key words of its message) and that
nothing is lost: no half-written file, no pre-existing file changed, no code from a
model file executed.
"""

from __future__ import annotations

import builtins
import dataclasses
import importlib
import os
import pkgutil
import re
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.cli import parser as cli
from symmon import io as sio
from symmon.errors import (
    CovarianceError,
    DerivativeError,
    ModelError,
    SamplingError,
    ShapeError,
    SingularMatrixError,
    SymmonError,
    UnsupportedFunctionError,
)
from symmon.files.modelfile import ModelFileError, load_model_file

from helpers import EXAMPLES

x, y, z = sp.symbols("x y z", real=True)
e1, e2 = sp.symbols("e1 e2", real=True)
POLAR = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar")
NOISY = sm.Model([x, y], [x * y + e1, y + e2], noise=[e1, e2], name="noisy")
U = sm.Gaussian([1.0, 10.0], np.diag([0.17, 17.0]))
#: Two closed-form TT2 computations of the same quantity agree to rounding.
EXACT_TOL = 1e-10


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def model_text(output: str = '"x*y"', mean: str = "[1, 2]", extra: str = "") -> str:
    return (f'name = "m"\ninputs = ["x", "y"]\noutputs = [\n  {output},\n]\n{extra}'
            f'[u]\nmean = {mean}\ncov = [[1, 0], [0, 1]]\n')


# --------------------------------------------------------------------------- shapes
@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (lambda: sm.Gaussian([[1.0, 2.0]], np.eye(2)), ShapeError, r"mean must be a vector \(1-D\), got shape \(1, 2\)"),
        (lambda: sm.Gaussian([1.0, 2.0], np.eye(3)), ShapeError, "cov must be 2x2, got 3x3"),
        (lambda: sm.propagate(POLAR, sm.Gaussian([1.0], [[1.0]])), ShapeError, r"u has dimension 1 but the model has 2 inputs"),
        (lambda: sm.propagate(NOISY, U, v=sm.Gaussian([0.0], [[1.0]])), ShapeError, "v has dimension 1 but the model has 2 noise"),
        (lambda: sm.fuse(sm.Gaussian([1.0], [[1.0]]), U), ShapeError, r"fuse: dimensions differ: \[1, 2\]"),
        (lambda: U.condition([5], [1.0]), ShapeError, r"idx \[5\] out of range for dimension 2"),
        (lambda: sm.estimation.direct(sm.problems.radar_hinv(), [sm.Gaussian([1.0, 2.0, 3.0], np.eye(3))]),
         ShapeError, r"measurements\[0\] has dimension 3 but the inverse model 'radar_hinv' has 2 inputs"),
    ],
    ids=["mean-2d", "cov-size", "u-dim", "v-dim", "fuse-dims", "condition-index", "direct-measurement-dim"],
)
def test_shapes(make, error, match):
    with pytest.raises(error, match=match):
        make()


# --------------------------------------------------------------------------- covariances
@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: sm.Gaussian([0.0, 0.0], [[1.0, 0.5], [0.4, 1.0]]), r"cov is not symmetric: max \|P - P\^T\| = 0.1"),
        (lambda: sm.Gaussian([0.0, 0.0], [[1.0, 2.0], [2.0, 1.0]]), "cov is not positive semi-definite: smallest eigenvalue -1"),
        (lambda: sm.Gaussian([0.0, 0.0], [[1.0, 0.0], [0.0, np.inf]]), "cov contains NaN or inf"),
        (lambda: sm.mmse.quadratic(np.eye(2), [1.0, 2.0], [[1.0, 2.0], [2.0, 1.0]]), "P is not positive semi-definite"),
        (lambda: sm.mmse.abs_value(1.0, -1.0), "var must be >= 0, got minimum -1"),
    ],
    ids=["asymmetric", "indefinite", "infinite", "mmse-indefinite-P", "mmse-negative-variance"],
)
def test_bad_covariances(make, match):
    with pytest.raises(CovarianceError, match=match):
        make()


def test_indefinite_covariance_repair_is_explicit_only():
    # The error names the two repairs; asking for one gives a valid PSD Gaussian, with a warning.
    with pytest.warns(RuntimeWarning, match=r"cov: clipped negative eigenvalues to 0 \(clipped mass 1e-09\)"):
        g = sm.Gaussian([0.0, 0.0], [[1.0, 1.0 + 1e-9], [1.0 + 1e-9, 1.0]], psd="clip")
    assert np.linalg.eigvalsh(g.cov)[0] >= 0.0


def test_singular_input_covariance_uses_the_pseudo_inverse_and_says_so():
    # y has zero variance: the MoN is that of the model in x alone with y at its mean.
    u = sm.Gaussian([1.0, 10.0], np.diag([0.17, 0.0]))
    res = sm.nonlinearity(POLAR, u, weight="diag", transform=sm.TT2())
    assert any("Σ_uu is singular (rank 1 of 2): the pseudo-inverse was used" in n for n in res.notes)
    reduced = sm.Model([x], [sp.sqrt(x**2 + 100), sp.atan2(10, x)], name="polar_at_y0")
    expected = sm.nonlinearity(reduced, sm.Gaussian([1.0], [[0.17]]), weight="diag", transform=sm.TT2())
    assert res.value == pytest.approx(expected.value, abs=EXACT_TOL)


def test_singular_output_covariance_with_the_full_weight_names_the_combination():
    lin = sm.Model([x, y], [x + y, 2 * x + 2 * y], name="collinear")
    with pytest.raises(SingularMatrixError,
                       match=r"Σ_gg is singular .* the output combination -0.894\*y0 \+ 0.447\*y1 has no variance"
                             r".*use weight='diag'"):
        sm.nonlinearity(lin, U, weight="full")
    # the suggested weight works, and gives 0 for this linear model
    assert sm.nonlinearity(lin, U, weight="diag").value == pytest.approx(0.0, abs=EXACT_TOL)


# --------------------------------------------------------------------------- models
@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (lambda: sm.Model([x], [x + z]), ModelError, r"output 0 \(x \+ z\) uses unknown symbols \['z'\]"),
        (lambda: sm.Model([x, x], [x]), ModelError, r"duplicate symbols in inputs: \['x'\]"),
        (lambda: sm.Model([x], []), ModelError, "a model needs at least one output"),
        (lambda: sm.Model([x**2], [x]), ModelError, r"inputs must be sympy Symbols, got x\*\*2"),
        (lambda: sm.propagate(NOISY, U), ModelError, r"noise symbols \['e1', 'e2'\]: pass v="),
        (lambda: sm.nonlinearity(POLAR, U, weight="fancy"), SymmonError, "unknown weight 'fancy'"),
        (lambda: sm.nonlinearity(POLAR, U, weight=np.eye(2)), SymmonError, r"weight W̄ is not in the set \(41\)"),
        (lambda: sm.export_c(POLAR, "unused", name="bad name"), SymmonError, "name must be a C identifier"),
    ],
    ids=["unknown-symbol", "duplicate-input", "no-output", "non-symbol-input", "missing-noise",
         "unknown-weight", "weight-not-normalised", "c-name"],
)
def test_bad_models_and_options(make, error, match):
    with pytest.raises(error, match=match):
        make()


@pytest.mark.parametrize(("fn", "name"), [(sp.gamma(x), "gamma"), (sp.besselj(0, x), "besselj"),
                                          (sp.zeta(x), "zeta")])
def test_unsupported_functions_are_named(fn, name):
    with pytest.raises(UnsupportedFunctionError, match=rf"cannot compile function '{name}'"):
        sm.propagate(sm.Model([x], [fn]), sm.Gaussian([1.5], [[0.1]]), transform=sm.UT.ut1())


def test_nan_produced_while_sampling_reports_the_count():
    with pytest.raises(SamplingError, match=r"g is NaN or inf at (\d+) of (\d+) samples") as info:
        sm.propagate(sm.Model([x], [sp.log(x)]), sm.Gaussian([0.1], [[1.0]]), transform=sm.MonteCarlo(5000, seed=0))
    bad, total = map(int, re.search(r"at (\d+) of (\d+) samples", str(info.value)).groups())
    assert 0 < bad <= total
    assert "first bad sample w = [" in str(info.value)


def test_nan_derivative_names_the_output_and_the_point():
    with pytest.raises(DerivativeError, match=r"output 0 \(1/x\) is NaN or inf at the point \(x=0\)"):
        sm.propagate(sm.Model([x], [1 / x]), sm.Gaussian([0.0], [[1.0]]), transform=sm.TT1())


# --------------------------------------------------------------------------- model files
MALICIOUS = {
    "import": ("\"__import__('os').system('touch {marker}')\"", "attribute access is not allowed"),
    "dunder-name": ('"__builtins__"', "dunder names such as '__builtins__' are not allowed"),
    "attribute": ('"x.__class__"', "attribute access is not allowed"),
    "subscript": ('"x[0]"', "subscripts are not allowed"),
    "lambda": ('"(lambda: x)()"', "lambda functions are not allowed"),
    "comprehension": ('"[x for x in (1,)]"', "comprehensions are not allowed"),
    "string": ("\"open('{marker}', 'w')\"", "unknown function 'open'"),
    "unknown-function": ('"system(x)"', "unknown function 'system'"),
    "power-tower": ('"x**10**10"', "power towers are not allowed"),
    "huge-integer": ('"' + "9" * 30 + '"', "integer literal too large"),
    "deep-nesting": ('"' + "(" * 60 + "x" + ")" * 60 + '"', "nested too deeply"),
    "too-long": ('"x' + "+x" * 1500 + '"', "expression too long"),
    "conditional": ('"x if y else 1"', "conditional expressions"),
}


@pytest.fixture
def no_code_runs(monkeypatch):
    """Fail the test if loading a file reaches eval, exec, os.system or sympy's string parser."""
    # The CLI imports modules lazily, and importing runs exec: import them all first, so
    # that only the file's own content can reach the patched functions.
    import symmon

    for info in pkgutil.walk_packages(symmon.__path__, "symmon."):
        try:
            importlib.import_module(info.name)
        except ImportError:  # a module of an extra that is not installed
            pass

    def forbidden(*args, **kwargs):
        raise AssertionError("a model file reached a code-executing function")

    real_sympify = sp.sympify

    def sympify_no_text(a, *args, **kwargs):
        # sympify of sympy objects and numbers is harmless (Model does it); of text it parses code.
        if isinstance(a, str):
            raise AssertionError(f"sympify was called on text {a!r}")
        return real_sympify(a, *args, **kwargs)

    for target, name in [(builtins, "eval"), (builtins, "exec"), (os, "system"),
                         (importlib.import_module("sympy.parsing.sympy_parser"), "parse_expr")]:
        monkeypatch.setattr(target, name, forbidden)
    for module in (sp, importlib.import_module("sympy.core.sympify"), importlib.import_module("symmon.core.model")):
        if hasattr(module, "sympify"):
            monkeypatch.setattr(module, "sympify", sympify_no_text)


def test_the_guard_catches_code_execution(no_code_runs):
    with pytest.raises(AssertionError, match="sympify was called on text 'x'"):
        sp.sympify("x")
    with pytest.raises(AssertionError, match="reached a code-executing function"):
        eval("1")  # noqa: S307 - the guard must stop it


def test_a_valid_file_loads_without_any_code_executing_function(no_code_runs):
    spec = load_model_file(EXAMPLES / "polar.toml")
    assert spec.model.outputs[0] == sp.sqrt(spec.model.inputs[0] ** 2 + spec.model.inputs[1] ** 2)


@pytest.mark.parametrize("case", sorted(MALICIOUS))
def test_malicious_model_files_are_refused_and_nothing_runs(tmp_path, no_code_runs, case):
    marker = tmp_path / "pwned"
    text, reason = MALICIOUS[case]
    path = tmp_path / "evil.toml"
    path.write_text(model_text(output=text.format(marker=marker)))
    with pytest.raises(ModelFileError, match=rf"evil.toml: outputs\[0\], line 4, column \d+: .*{re.escape(reason)}"):
        load_model_file(path)
    assert not marker.exists()


def test_malicious_number_in_a_table_is_refused(tmp_path, no_code_runs):
    path = tmp_path / "evil.toml"
    path.write_text(model_text(mean="[\"__import__('os')\", 2]"))
    with pytest.raises(ModelFileError, match=r"\[u\]\.mean\[0\], line 7, column \d+: dunder names"):
        load_model_file(path)


def test_malicious_file_through_the_command_exits_1_and_runs_nothing(capsys, tmp_path, no_code_runs):
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.toml"
    path.write_text(model_text(output=f"\"__import__('os').system('touch {marker}')\""))
    code, out, err = run_cli(capsys, "propagate", path)
    assert (code, out) == (1, "")
    assert "line 4, column 4: attribute access is not allowed" in err
    assert not marker.exists()


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (None, "model file not found"),
        ("directory", "model file cannot be read"),
        (b"\xff\xfe name", "model file is not UTF-8 text"),
        ('name = "m"\ninputs = [\n', "invalid TOML"),
    ],
    ids=["missing", "directory", "binary", "bad-toml"],
)
def test_missing_or_unreadable_model_file(tmp_path, content, match):
    path = tmp_path / "model.toml"
    if content == "directory":
        path.mkdir()
    elif isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(ModelFileError, match=rf"model.toml: {match}"):
        load_model_file(path)


# --------------------------------------------------------------------------- output files
@pytest.fixture
def blocker(tmp_path) -> Path:
    """A regular file: a path under it cannot be created, even by root."""
    f = tmp_path / "file.txt"
    f.write_text("keep me\n")
    return f


def test_unwritable_output_path_in_the_api(blocker):
    with pytest.raises(FileNotFoundError, match="output directory does not exist: .*file.txt"):
        sio.write_csv(blocker / "out.csv", ["a"], [[1.0]])
    assert blocker.read_text() == "keep me\n"


@pytest.mark.parametrize(
    "argv",
    [
        ["nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "0.1:1:2", "--csv", "{blocker}/out.csv"],
        ["codegen", EXAMPLES / "polar.toml", "-o", "{blocker}/c"],
        ["reproduce", "fig1", "--samples", "100", "--out", "{blocker}/results"],
    ],
    ids=["sweep-csv", "codegen-dir", "reproduce-dir"],
)
def test_unwritable_output_path_in_the_command(capsys, blocker, argv):
    argv = [str(a).replace("{blocker}", str(blocker)) for a in argv]
    code, out, err = run_cli(capsys, *argv)
    assert code == 1
    assert err.startswith("symmon: error: ") and "file.txt" in err
    assert blocker.read_text() == "keep me\n"
    assert sorted(p.name for p in blocker.parent.iterdir()) == ["file.txt"]


class _InterruptedFile:
    """A file object that writes half its data, then is interrupted (Ctrl-C)."""

    def __init__(self, fh):
        self._fh = fh

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()
        return False

    def write(self, data: bytes) -> int:
        self._fh.write(data[: len(data) // 2])
        self._fh.flush()
        raise KeyboardInterrupt

    def __getattr__(self, name):
        return getattr(self._fh, name)


@pytest.fixture
def interrupted_writes(monkeypatch):
    real = os.fdopen
    monkeypatch.setattr(sio.os, "fdopen", lambda fd, mode="r", *a, **k: _InterruptedFile(real(fd, mode, *a, **k)))


def test_interrupted_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, interrupted_writes):
    target = tmp_path / "results.csv"
    target.write_text("old results\n")
    with pytest.raises(KeyboardInterrupt):
        sio.atomic_write_text(target, "new results, " * 1000)
    assert target.read_text() == "old results\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.csv"]


def test_interrupted_write_in_the_command_exits_130_and_keeps_the_old_file(capsys, tmp_path, interrupted_writes):
    target = tmp_path / "mon.csv"
    target.write_text("old results\n")
    code, _, err = run_cli(capsys, "nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "0.1:1:3",
                           "--csv", target)
    assert code == 130
    assert "interrupted; no output file was half-written" in err
    assert target.read_text() == "old results\n"
    assert [p.name for p in tmp_path.iterdir()] == ["mon.csv"]


def test_failed_rename_keeps_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "fig.png"
    target.write_bytes(b"old figure")

    def refuse(src, dst):
        raise PermissionError(13, "Permission denied", str(dst))

    monkeypatch.setattr(sio.os, "replace", refuse)
    with pytest.raises(PermissionError, match="Permission denied"):
        sio.atomic_write_bytes(target, b"new figure")
    assert target.read_bytes() == b"old figure"
    assert [p.name for p in tmp_path.iterdir()] == ["fig.png"]


# --------------------------------------------------------------------------- command-line values
@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["propagate", EXAMPLES / "polar.toml", "--samples", "-5"], "must be a positive integer, got '-5'"),
        (["nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "a:b:c"], "must be A:B:N with numbers"),
        (["nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "1:inf:3"], "needs finite A, B > 0"),
        (["reproduce", "fig9"], "invalid choice: 'fig9'"),
    ],
    ids=["negative-samples", "sweep-words", "sweep-infinite", "unknown-figure"],
)
def test_bad_command_line_values_are_usage_errors(capsys, argv, match):
    code, out, err = run_cli(capsys, *argv)
    assert (code, out) == (2, "")
    assert match in err


def test_model_error_in_a_valid_file_is_exit_1(capsys, tmp_path):
    # The file parses, but its input covariance is indefinite.
    path = tmp_path / "indefinite.toml"
    path.write_text('name = "m"\ninputs = ["x", "y"]\noutputs = ["x*y"]\n[u]\nmean = [1, 2]\ncov = [[1, 2], [2, 1]]\n')
    code, out, err = run_cli(capsys, "propagate", path)
    assert (code, out) == (1, "")
    assert "not positive semi-definite" in err


# --------------------------------------------------------------------------- hostile input (issue 13)
BIG = "1" + "0" * 400  # a 401-digit TOML integer: past the float range


@pytest.mark.parametrize(
    ("table", "match"),
    [
        (f"mean = [{BIG}, 2]\ncov = [[1, 0], [0, 1]]\n", r"\[u\]\.mean\[0\]: integer too large for a float \(beyond ±1.8e308\)"),
        (f"mean = [1, 2]\ncov = [[{BIG}, 0], [0, 1]]\n", r"\[u\]\.cov\[0\]\[0\]: integer too large for a float"),
        (f"mean = [1, 2]\nstd = [1, {BIG}]\n", r"\[u\]\.std\[1\]: integer too large for a float"),
        (f"mean = [1, 2]\nstd = [1, {'9' * 5000}]\n", "invalid TOML: Exceeds the limit"),
        ("mean = [1, 2]\nstd = " + "[" * 5000 + "]" * 5000 + "\n", "invalid TOML: arrays or tables nested too deeply"),
    ],
    ids=["mean", "cov", "std", "5000-digits", "deep-arrays"],
)
def test_huge_numbers_and_deep_toml_are_refused(tmp_path, table, match):
    path = tmp_path / "m.toml"
    path.write_text(f'name = "m"\ninputs = ["x", "y"]\noutputs = ["x*y"]\n[u]\n{table}')
    with pytest.raises(ModelFileError, match=match):
        load_model_file(path)


def test_a_huge_output_index_in_units_is_refused(tmp_path):
    path = tmp_path / "m.toml"
    path.write_text(model_text(extra=f'[units]\n"outputs[{"9" * 5000}]" = "m"\n'))
    with pytest.raises(ModelFileError, match=r"\[units\]: 'outputs\[9999.*there are only 1 outputs"):
        load_model_file(path)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("max(x, acos(2))", r"column 8: the constant acos\(2\) is not a finite real number .*I\)"),
        ("x + (-8)**(1/3)", r"the constant 2\*\(-1\)\*\*\(1/3\) is not a finite real number"),
        ("x*exp(710)", r"the constant exp\(710\) is not a finite real number in double precision"),
        ("min(x, y, log(-1))", "the expression is complex"),
        ("cosh(cosh((4.0)**3))", r"the number 3.104e\+1353945419820308977744228072 is not finite in double precision"),
        ("x*1e308*10.0", r"the number 1.000e\+309 is not finite in double precision"),
        ("x*exp(exp(exp(exp(5))))", r"the constant exp\(exp\(exp\(5\)\)\) is not a finite real number"),
    ],
    ids=["max-acos", "cube-root-of-negative", "overflowing-constant", "min-log", "float-cosh", "float-product",
         "exp-tower"],
)
def test_constants_that_are_complex_or_overflow_are_refused(text, match):
    with pytest.raises(ModelFileError, match=match):
        sm.modelfile.parse_expression(text, {"x": x, "y": y})


def test_complex_constant_through_the_command_exits_1(capsys, tmp_path):
    path = tmp_path / "m.toml"
    path.write_text(model_text(output='"max(x, acos(2))"'))
    code, out, err = run_cli(capsys, "propagate", path)
    assert (code, out) == (1, "")
    assert err.startswith("symmon: error: ") and "acos(2)" in err


def _load_in_thread(path: Path) -> BaseException | None:
    """Load a model file in a daemon thread: a file that blocks must fail the test, not hang it."""
    import threading

    box: list[BaseException | None] = []

    def target():
        try:
            load_model_file(path)
            box.append(None)
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            box.append(exc)

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(60)  # a guard against hanging, not a timing assertion: a refusal is immediate
    assert box, "loading the file blocked"
    return box[0]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_fifo_model_file_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "model.toml"
    os.mkfifo(fifo)  # nobody writes to it: opening it for reading the usual way blocks
    exc = _load_in_thread(fifo)
    assert isinstance(exc, ModelFileError)
    assert "model.toml: model file cannot be read: it is a FIFO, not a regular file" in str(exc)


def test_a_device_model_file_is_refused():
    with pytest.raises(ModelFileError, match="/dev/zero: .*it is a device, socket or other special file"):
        load_model_file("/dev/zero")


def test_an_oversize_model_file_is_refused_before_it_is_read(tmp_path):
    path = tmp_path / "big.toml"
    with open(path, "wb") as fh:  # a sparse file: large, but nothing to read
        fh.truncate(sm.modelfile.MAX_FILE_BYTES + 1)
    with pytest.raises(ModelFileError, match=rf"larger than {sm.modelfile.MAX_FILE_BYTES} bytes"):
        load_model_file(path)


@pytest.mark.parametrize(
    ("head", "match"),
    [
        (f'name = "m"\ninputs = {[f"x{i}" for i in range(101)]}\noutputs = ["x0"]\n'.replace("'", '"'),
         "101 inputs and 0 noise symbols: at most 100 in all"),
        ('name = "m"\ninputs = ["x"]\noutputs = [' + ", ".join(['"x"'] * 101) + "]\n", "101 outputs: at most 100"),
        ('name = "m"\ninputs = ["' + "a" * 101 + '"]\noutputs = ["x"]\n', "names are at most 100 characters long"),
        ('name = "m\\u001b[2J"\ninputs = ["x"]\noutputs = ["x"]\n', "name: must be at most 100 printable characters"),
        ('name = "' + "m" * 101 + '"\ninputs = ["x"]\noutputs = ["x"]\n', "name: must be at most 100 printable"),
    ],
    ids=["inputs", "outputs", "long-symbol", "escape-in-name", "long-name"],
)
def test_declared_size_limits_of_a_model_file(tmp_path, head, match):
    path = tmp_path / "m.toml"
    path.write_text(head + "[u]\nmean = [0]\ncov = 1\n")
    with pytest.raises(ModelFileError, match=re.escape(match)):
        load_model_file(path)


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--seed", "-1"], "argument --seed: must be an integer >= 0, got '-1'"),
        (["--seed", str(2**64)], "argument --seed: must be at most"),
        (["--order", "1000000"], f"argument --order: must be at most {cli.MAX_ORDER}, got '1000000'"),
        (["--samples", str(10 * cli.MAX_SAMPLES)], "argument --samples: must be at most"),
        (["--groups", "100000"], f"argument --groups: must be at most {cli.MAX_GROUPS:,}"),
        (["--workers", "100000"], f"argument --workers: must be at most {cli.MAX_WORKERS:,}"),
        (["--alpha-sweep", "0.1:10:10000000000"], f"N must be at most {cli.MAX_SWEEP_POINTS}"),
        (["--alpha-sweep", "0.1:10:3", "--plot", "out.xyz"], "argument --plot: cannot write a figure as 'xyz'"),
        (["--alpha-sweep", "0.1:10:3", "--plot", ""], "argument --plot: must be a file name, got an empty string"),
        (["--alpha-sweep", "0.1:10:3", "--csv", ""], "argument --csv: must be a file name, got an empty string"),
        (["--dask", "127.0.0.1:"], "the port must be a number from 1 to 65535, got ''"),
        (["--dask", "tcp://127.0.0.1:abc"], "the port must be a number from 1 to 65535, got 'abc'"),
        (["--dask", "tcp://127.0.0.1:65536"], "got '65536'"),
        (["--dask", "tcp://127.0.0.1:0"], "got '0'"),
        (["--dask", "foo://127.0.0.1:8786"], "unknown scheme 'foo'"),
        (["--dask", "tcp://:8786"], "--dask takes threads, processes, synchronous or a scheduler address"),
        (["--dask", "tcp://bad_host!:8786"], "invalid host 'bad_host!'"),
        (["--dask", "tcp://[::1:8786"], "invalid host '[::1'"),
    ],
    ids=lambda a: " ".join(a) if isinstance(a, list) else None,
)
def test_hostile_options_are_usage_errors_found_before_any_work(capsys, monkeypatch, argv, match):
    nl = importlib.import_module("symmon.measures.mon")
    monkeypatch.setattr(nl, "nonlinearity", lambda *a, **k: pytest.fail("the computation started"))
    code, out, err = run_cli(capsys, "nonlinearity", EXAMPLES / "polar.toml", "--transform", "mc", *argv)
    assert (code, out) == (2, "")
    assert "usage: symmon nonlinearity" in err and match in err


@pytest.mark.parametrize("figure", ["fig1", "radar", "mmse"])
def test_reproduce_with_too_few_samples_is_a_usage_error(capsys, figure):
    code, out, err = run_cli(capsys, "reproduce", figure, "--samples", "1")
    assert (code, out) == (2, "")
    assert f"argument --samples: must be an integer >= {cli.REPRODUCE_MIN_SAMPLES}, got '1'" in err


def test_derive_out_empty_is_a_usage_error(capsys):
    code, out, err = run_cli(capsys, "derive", "--out", "")
    assert (code, out) == (2, "")
    assert "argument --out: must be a file name" in err


@pytest.fixture
def no_computation(monkeypatch):
    nl = importlib.import_module("symmon.measures.mon")
    monkeypatch.setattr(nl, "nonlinearity", lambda *a, **k: pytest.fail("the computation started"))


@pytest.mark.parametrize("kind", ["directory", "fifo", "device"])
def test_output_that_is_not_a_regular_file_is_refused_before_any_work(capsys, tmp_path, no_computation, kind):
    if kind == "directory":
        target, what = tmp_path / "out", "a directory"
        target.mkdir()
    elif kind == "fifo":
        if not hasattr(os, "mkfifo"):
            pytest.skip("needs FIFOs")
        target, what = tmp_path / "out", "a FIFO"
        os.mkfifo(target)
    else:
        target, what = Path(os.devnull), "a character device"
    code, out, err = run_cli(capsys, "nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "0.1:1:2",
                             "--csv", target)
    assert (code, out) == (1, "")
    assert f"output file {target} is {what}; only regular files are written" in err
    assert [p.name for p in tmp_path.iterdir()] == ([] if kind == "device" else ["out"])


def test_derive_report_into_a_directory_is_refused_before_running(capsys, tmp_path, monkeypatch):
    derive = importlib.import_module("symmon.derive")
    monkeypatch.setattr(derive, "run", lambda *a, **k: pytest.fail("the derivations ran"))
    code, _, err = run_cli(capsys, "derive", "--out", tmp_path)
    assert code == 1 and "is a directory" in err


def test_csv_and_plot_on_the_same_file_is_a_usage_error(capsys, tmp_path, no_computation):
    target = tmp_path / "out.png"
    code, out, err = run_cli(capsys, "nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "0.1:1:2",
                             "--csv", target, "--plot", target)
    assert (code, out) == (2, "")
    assert f"--csv and --plot name the same file: {target}" in err


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symbolic links")
def test_a_symlinked_output_is_followed_and_the_link_kept(tmp_path):
    target = tmp_path / "real.csv"
    target.write_text("old\n")
    target.chmod(0o640)
    link = tmp_path / "link.csv"
    link.symlink_to(target.name)
    assert sio.write_csv(link, ["a"], [[1.5]]) == link
    assert link.is_symlink() and os.readlink(link) == target.name
    assert target.read_text() == "a\n1.5\n"
    assert (target.stat().st_mode & 0o777) == 0o640        # the permission bits are kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.csv", "real.csv"]


def test_api_writes_refuse_devices_and_empty_names():
    with pytest.raises(sio.OutputPathError, match="is a character device"):
        sio.atomic_write_bytes(os.devnull, b"x")
    with pytest.raises(sio.OutputPathError, match="output file name is empty"):
        sio.atomic_write_text("", "x")


def test_a_non_finite_result_is_not_printed(capsys, monkeypatch):
    # Whatever the transform returns, the command prints no NaN: it names the quantity and exits 1.
    prop = importlib.import_module("symmon.propagation.front")
    real = prop.propagate

    def nan_cov(*args, **kwargs):
        m = real(*args, **kwargs)
        bad = m.cov.copy()
        bad[0, 0] = np.nan
        return dataclasses.replace(m, cov=bad)

    monkeypatch.setattr(prop, "propagate", nan_cov)
    for extra in ([], ["--json"]):
        code, out, err = run_cli(capsys, "propagate", EXAMPLES / "polar.toml", *extra)
        assert (code, out) == (1, "")
        assert "symmon: error: Cov y is not finite" in err


def test_a_nan_mon_is_not_printed(capsys, monkeypatch):
    nl = importlib.import_module("symmon.measures.mon")
    real = nl.nonlinearity

    def nan_value(*args, **kwargs):
        return dataclasses.replace(real(*args, **kwargs), squared=float("nan"))

    monkeypatch.setattr(nl, "nonlinearity", nan_value)
    code, out, err = run_cli(capsys, "nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "0.1:1:2")
    assert (code, out) == (1, "")
    assert "symmon: error: the MoN at alpha=0.1 is not finite" in err
