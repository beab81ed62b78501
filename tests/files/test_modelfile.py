"""Tests of symmon.files.modelfile: the whitelist expression parser and the TOML model files."""

from __future__ import annotations

import ast
import builtins
import contextlib
import os
import pickle
import re
import subprocess
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
import pytest
import sympy as sp

import symmon.files.expressions as expressions
import symmon.files.modelfile as modelfile
from symmon.errors import ModelError
from symmon.core.gaussian import Gaussian
from symmon.files.modelfile import (
    MAX_DEPTH,
    MAX_EXPONENT,
    MAX_EXPRESSION_LENGTH,
    MAX_FILE_BYTES,
    MAX_INTEGER_LITERAL,
    ModelFileError,
    ModelSpec,
    dump_model_file,
    load_model_file,
    parse_expression,
)
from symmon.core.model import Model

from helpers import EXAMPLES

#: Numbers that come out of one float operation (e.g. 100 * 0.17) are compared this tightly.
EXACT_RTOL = 1e-12
#: The modules that read file text: the TOML schema and the expression parser.
MODULE_SOURCES = (Path(modelfile.__file__), Path(expressions.__file__))

#: Names the parser module must never call on file text.
FORBIDDEN_CALLS = ("eval", "exec", "compile", "sympify", "parse_expr")
#: Top-level modules an attack would import to reach the system.
DANGEROUS_MODULES = frozenset({"os", "subprocess", "shutil", "socket", "ctypes", "importlib", "pty"})
#: Placeholder, in an attack string, for a file that must never be created.
SENTINEL = "{sentinel}"

x, y, vx, vy = sp.symbols("x y vx vy", real=True)
r, phi = sp.symbols("r phi", real=True)
SYMBOLS = {"x": x, "y": y}
SOURCE = "attack.toml: outputs[0]"


# --------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------


@contextlib.contextmanager
def _tripwire():
    """Replace eval, exec, open, code-making compile, os.system, os.popen,
    subprocess.Popen and imports of system modules by spies; yield the list of what
    they saw.

    The spies are removed on exit, so that pytest can still read files to report a
    failure.
    """
    calls: list = []
    real_import = builtins.__import__
    real_compile = builtins.compile

    def spy_import(name, *args, **kwargs):
        if name.split(".")[0] in DANGEROUS_MODULES:
            calls.append(("import", name))
        return real_import(name, *args, **kwargs)

    def spy_compile(source, filename, mode, flags=0, *args, **kwargs):
        # ast.parse is compile(..., flags=PyCF_ONLY_AST): it builds a tree, runs nothing.
        if not flags & ast.PyCF_ONLY_AST:
            calls.append(("compile", source))
            raise AssertionError("compile was called to make code")
        return real_compile(source, filename, mode, flags, *args, **kwargs)

    def forbidden(label):
        def trap(*args, **kwargs):
            calls.append((label, args))
            raise AssertionError(f"{label} was called")

        return trap

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(builtins, "__import__", spy_import)
        mp.setattr(builtins, "compile", spy_compile)
        for label in ("eval", "exec", "open"):
            mp.setattr(builtins, label, forbidden(label))
        mp.setattr(os, "system", forbidden("os.system"))
        mp.setattr(os, "popen", forbidden("os.popen"))
        mp.setattr(subprocess, "Popen", forbidden("subprocess.Popen"))
        yield calls


def _parse_under_tripwire(text: str) -> tuple[ModelFileError | None, list]:
    """Parse ``text`` under :func:`_tripwire`; return the refusal (or None) and the calls."""
    err = None
    with _tripwire() as calls:
        try:
            parse_expression(text, SYMBOLS, source=SOURCE)
        except ModelFileError as exc:
            err = exc
    return err, calls


def _write(tmp_path: Path, text: str, name: str = "model.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


VALID_HEADER = """\
name = "test"
inputs = ["x", "y"]
outputs = ["sqrt(x**2 + y**2)", "atan2(y, x)"]
"""
VALID_U = """
[u]
mean = [1, 10]
cov = [[1, 0], [0, 4]]
"""

NOISE_FILE = """\
# The lecture's radar with explicit noise: x = h^-1(y - e).
name = "radar-noise"
inputs = ["r", "phi"]
noise = ["e_r", "e_phi"]
outputs = ["(r - e_r)*cos(phi - e_phi)", "(r - e_r)*sin(phi - e_phi)"]
angles = ["phi"]

[u]
mean = ["100*sqrt(2)", "pi/4"]
cov = [[5, 0], [0, 0.1]]

[v]
mean = [0, 0]
std = [2, 0.5]

[units]
r = "m"
phi = "rad"
e_r = "m"
e_phi = "rad"
"outputs[0]" = "m"
"outputs[1]" = "m"
"""


# --------------------------------------------------------------------------------------
# The parser refuses attacks, and nothing runs
# --------------------------------------------------------------------------------------

_NESTED_200 = "(" * 200 + "x" + ")" * 200
_LONG_SUM = "+".join(["x"] * 2500)  # 4999 characters
_UNARY_CHAIN = "-" * 60 + "x"

# (attack text, fragment of the reason, line, column)
ATTACKS = [
    ("__import__('os').system('touch {sentinel}')", "attribute access", 1, 1),
    ("__import__('os')", "dunder names", 1, 1),
    ("().__class__.__bases__[0].__subclasses__()", "attribute access", 1, 1),
    ("x.__class__", "attribute access", 1, 1),
    ("lambda: 1", "lambda", 1, 1),
    ("(lambda: 1)()", "lambda", 1, 2),
    ("[x for x in y]", "comprehensions", 1, 1),
    ("sqrt(sum(x for x in y))", "unknown function 'sum'", 1, 6),
    ("'a'*10", "string literals", 1, 1),
    ("9**9**9", "power towers", 1, 4),
    ("10**100000", "exponent 100000 too large", 1, 5),
    ("x**(x**x**x)", "power towers", 1, 5),
    ("x**(8*9)", "exponent 72 too large", 1, 5),
    ("((10**15)**64)**64", "numeric power too large", 1, 2),
    ("10**15*10**15*10**15*10**15*10**15*10**15*10**15*10**15", "number too large", 1, 1),
    (_NESTED_200, "nested too deeply", 1, MAX_DEPTH + 1),
    (_UNARY_CHAIN, "nested too deeply", 1, MAX_DEPTH + 1),
    (_LONG_SUM, "expression too long", 1, MAX_EXPRESSION_LENGTH + 1),
    ("open('{sentinel}', 'w')", "unknown function 'open'", 1, 1),
    ("exec('1')", "unknown function 'exec'", 1, 1),
    ("eval('1')", "unknown function 'eval'", 1, 1),
    ("compile('1', 'f', 'eval')", "unknown function 'compile'", 1, 1),
    ("getattr(x, 'y')", "unknown function 'getattr'", 1, 1),
    ("x if y else 1", "conditional expressions", 1, 1),
    ("x < y", "comparisons", 1, 1),
    ("x and y", "boolean operators", 1, 1),
    ("not x", "'not'", 1, 1),
    ("f(x=1)", "unknown function 'f'", 1, 1),
    ("sqrt(x=1)", "keyword arguments", 1, 6),
    ("*x", "invalid syntax", 1, 1),
    ("sqrt(*x)", "starred arguments", 1, 6),
    ("(y:=1)", "assignment expressions", 1, 2),
    ("b'x'", "bytes literals", 1, 1),
    ("f'{{x}}'", "f-strings", 1, 1),
    ("x[0]", "subscripts", 1, 1),
    ("Symbol('z')", "unknown function 'Symbol'", 1, 1),
    ("foo(x)", "unknown function 'foo'", 1, 1),
    ("z", "unknown name 'z'", 1, 1),
    ("x + __builtins__", "dunder names", 1, 5),
    ("sqrt(x)(1)", "only the listed functions", 1, 1),
    ("sqrt(x, y)", "sqrt takes 1 argument, got 2", 1, 1),
    ("atan2(x)", "atan2 takes 2 arguments, got 1", 1, 1),
    ("max(x)", "max takes 2 or more arguments, got 1", 1, 1),
    ("x // 2", "'//'", 1, 1),
    ("x % 2", "'%'", 1, 1),
    ("{x: 1}", "dicts", 1, 1),
    ("(x, y)", "tuples", 1, 1),
    ("16000000000000000", "integer literal too large", 1, 1),
    ("1e999", "not finite", 1, 1),
    ("1j", "complex literals", 1, 1),
    ("True", "constant True", 1, 1),
    ("x; import os", "invalid syntax", 1, 2),
    ("1/0", "not finite", 1, 1),
    ("sqrt(-1)", "complex", 1, 1),
    ("x\0", "invalid syntax", 1, 1),
    ("(x +\n  y.real)", "attribute access", 2, 3),
]


@pytest.mark.parametrize(("text", "reason", "line", "column"), ATTACKS, ids=[a[0][:30] for a in ATTACKS])
def test_attack_is_refused_and_nothing_runs(tmp_path, text, reason, line, column):
    sentinel = tmp_path / "pwned"
    err, calls = _parse_under_tripwire(text.replace(SENTINEL, str(sentinel)))
    assert err is not None, f"{text!r} was accepted"
    message = str(err)
    assert message.startswith(SOURCE)
    assert f"line {line}, column {column}:" in message
    assert reason in message
    assert (err.line, err.column) == (line, column)
    assert calls == []
    assert not sentinel.exists()


@pytest.mark.parametrize(
    ("action", "label"),
    [
        (lambda: os.system("true"), "os.system"),
        (lambda: __import__("subprocess"), "import"),
        (lambda: eval("1"), "eval"),
        (lambda: builtins.compile("1", "<t>", "eval"), "compile"),
    ],
    ids=["os.system", "import", "eval", "compile"],
)
def test_tripwire_sees_forbidden_calls(action, label):
    # The spies must be live, or the attack tests above prove nothing.
    with _tripwire() as calls:
        try:
            action()
        except AssertionError:
            pass
    assert [c[0] for c in calls] == [label]


@pytest.mark.parametrize("source", MODULE_SOURCES, ids=lambda p: p.name)
def test_module_never_names_forbidden_functions(source):
    tree = ast.parse(source.read_text(encoding="utf-8"))
    used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    used |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
    used |= {a.name.split(".")[-1] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    assert used.isdisjoint(FORBIDDEN_CALLS)


@pytest.mark.parametrize("source", MODULE_SOURCES, ids=lambda p: p.name)
def test_grep_finds_forbidden_names_only_in_a_comment(source):
    # ast.parse's mode="eval" is a string argument, not a call of eval.
    pattern = re.compile(r"\b(" + "|".join(FORBIDDEN_CALLS) + r")\b")
    hits = [
        line for line in source.read_text(encoding="utf-8").splitlines()
        if pattern.search(line) and 'ast.parse(text, mode="eval")' not in line
    ]
    assert hits and all(h.lstrip().startswith("#") for h in hits)


# --------------------------------------------------------------------------------------
# The parser's limits, at the boundary
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "accepted"),
    [
        (f"x**{MAX_EXPONENT}", True),
        (f"x**{MAX_EXPONENT + 1}", False),
        (f"x**(-{MAX_EXPONENT})", True),
        (f"x**(-{MAX_EXPONENT + 1})", False),
        (str(MAX_INTEGER_LITERAL), True),
        (str(MAX_INTEGER_LITERAL + 1), False),
        ("+".join(["x"] * ((MAX_EXPRESSION_LENGTH + 1) // 2)), True),  # exactly the limit
        ("+".join(["x"] * ((MAX_EXPRESSION_LENGTH + 1) // 2)) + "+", False),
        ("(" * MAX_DEPTH + "x" + ")" * MAX_DEPTH, True),
        ("(" * (MAX_DEPTH + 1) + "x" + ")" * (MAX_DEPTH + 1), False),
        ("-" * (MAX_DEPTH - 1) + "x", True),
        ("-" * MAX_DEPTH + "x", False),
        ("10**15*10**15*10**15*10**15*10**15*10**15", True),  # 91 digits
    ],
)
def test_limits(text, accepted):
    if accepted:
        assert isinstance(parse_expression(text, SYMBOLS), sp.Basic)
    else:
        with pytest.raises(ModelFileError, match=r"line 1, column \d+"):
            parse_expression(text, SYMBOLS)


def test_long_sum_within_limit_is_not_too_deep():
    # A chain of + counts as one level: a 1000-term sum is fine.
    text = "+".join(["x"] * 1000)
    assert parse_expression(text, SYMBOLS) == 1000 * x


# --------------------------------------------------------------------------------------
# The parser builds the right sympy objects
# --------------------------------------------------------------------------------------

VALID = [
    ("sqrt(x**2 + y**2)", sp.sqrt(x**2 + y**2)),
    ("atan2(y, x)*180/pi", sp.atan2(y, x) * 180 / sp.pi),
    ("hypot(x, y)", sp.sqrt(x**2 + y**2)),
    ("e**x", sp.exp(x)),
    ("E*x", sp.E * x),
    ("-x**2", -(x**2)),
    ("+x - -y", x + y),
    ("x**-2", x ** (-2)),
    ("1/2*x", x / 2),
    ("x/y/2", x / (2 * y)),
    ("0.17*x", sp.Float(0.17) * x),
    ("abs(x) + Abs(y) + sign(x)", sp.Abs(x) + sp.Abs(y) + sp.sign(x)),
    ("min(x, y) + Max(x, y, 1)", sp.Min(x, y) + sp.Max(x, y, 1)),
    ("exp(x) + log(y) + sin(x) + cos(x) + tan(x)", sp.exp(x) + sp.log(y) + sp.sin(x) + sp.cos(x) + sp.tan(x)),
    ("asin(x) + acos(x) + atan(x)", sp.asin(x) + sp.acos(x) + sp.atan(x)),
    ("sinh(x) + cosh(x) + tanh(x)", sp.sinh(x) + sp.cosh(x) + sp.tanh(x)),
    ("asinh(x) + acosh(y) + atanh(x)", sp.asinh(x) + sp.acosh(y) + sp.atanh(x)),
    ("(x\n + y)  # a comment", x + y),
    ("2**64", sp.Integer(2) ** 64),
    ("x**0.5", x ** sp.Float(0.5)),
    ("0x10 + 1_000", sp.Integer(1016)),
]


@pytest.mark.parametrize(("text", "expected"), VALID, ids=[v[0] for v in VALID])
def test_parse_valid(text, expected):
    assert parse_expression(text, SYMBOLS) == expected


def test_names_map_to_constants_and_shadow_builtin_constants():
    got = parse_expression("x - sx + e", {"x": x, "sx": sp.Integer(1000), "e": sp.Integer(2)})
    assert got == x - 998


def test_error_position_with_offsets_and_non_ascii():
    with pytest.raises(ModelFileError) as info:
        parse_expression("φ + z", {"φ": x}, source="f.toml", line_offset=4, col_offset=10)
    # z is the 5th character (the 6th byte); offsets shift the first line.
    assert str(info.value) == "f.toml, line 5, column 15: unknown name 'z'; known names: E, e, pi, φ"


def test_parse_rejects_non_text_and_non_sympy_names():
    with pytest.raises(TypeError, match="text must be a str"):
        parse_expression(b"x", SYMBOLS)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="symbols must map"):
        parse_expression("x", {"x": 1.0})  # type: ignore[dict-item]


def test_error_types_and_pickle():
    with pytest.raises(ModelFileError) as info:
        parse_expression("z", SYMBOLS, source="s")
    err = info.value
    assert isinstance(err, ModelError) and isinstance(err, ValueError)
    again = pickle.loads(pickle.dumps(err))
    assert (str(again), again.source, again.line, again.column, again.reason) == (
        str(err), "s", 1, 1, err.reason,
    )


# --------------------------------------------------------------------------------------
# The examples
# --------------------------------------------------------------------------------------

_R_GMTI = sp.sqrt((x - 1000) ** 2 + (y - 1000) ** 2 + 1000**2)
_STATE = (x, y, vx, vy)
_STATE_MEAN = [500, 500, 5, 8.7]
_STATE_COV = np.diag([1e3, 1e3, 1, 1])
_STATE_UNITS = {"x": "m", "y": "m", "vx": "m/s", "vy": "m/s"}

# file, inputs, outputs, mean, cov, angle outputs, angle inputs, units
EXAMPLE_CASES = [
    ("polar.toml", (x, y), [sp.sqrt(x**2 + y**2), sp.atan2(y, x)],
     [1, 10], 0.17 * np.diag([1, 100]), {1}, set(),
     {"x": "km", "y": "km", "outputs[0]": "km", "outputs[1]": "rad"}),
    ("bot.toml", _STATE, [sp.atan2(x, y)], _STATE_MEAN, _STATE_COV, {0}, set(),
     {**_STATE_UNITS, "outputs[0]": "rad"}),
    ("gmti.toml", _STATE,
     [_R_GMTI, sp.atan2(x - 1000, y - 1000), ((x - 1000) * vx + (y - 1000) * vy) / _R_GMTI],
     _STATE_MEAN, _STATE_COV, {1}, set(),
     {**_STATE_UNITS, "outputs[0]": "m", "outputs[1]": "rad", "outputs[2]": "m/s"}),
    ("rdcos.toml", _STATE, [sp.sqrt(x**2 + y**2), x / sp.sqrt(x**2 + y**2)], _STATE_MEAN, _STATE_COV,
     set(), set(), {**_STATE_UNITS, "outputs[0]": "m", "outputs[1]": "dimensionless"}),
    ("radar.toml", (r, phi), [r * sp.cos(phi), r * sp.sin(phi)],
     [100 * np.sqrt(2), np.pi / 4], np.diag([5, 0.1]), set(), {1},
     {"r": "m", "phi": "rad", "outputs[0]": "m", "outputs[1]": "m"}),
]


@pytest.mark.parametrize(
    ("fname", "inputs", "outputs", "mean", "cov", "angle_out", "angle_in", "units"),
    EXAMPLE_CASES, ids=[c[0] for c in EXAMPLE_CASES],
)
def test_example_loads(fname, inputs, outputs, mean, cov, angle_out, angle_in, units):
    spec = load_model_file(EXAMPLES / fname)
    assert isinstance(spec, ModelSpec)
    assert spec.path == EXAMPLES / fname
    assert spec.model.name == fname.removesuffix(".toml")
    assert spec.model.inputs == inputs
    assert spec.model.noise == ()
    assert spec.model.outputs == tuple(outputs)  # structural equality
    assert all(sp.simplify(a - b) == 0 for a, b in zip(spec.model.outputs, outputs))
    assert spec.model.angle_outputs == angle_out
    assert spec.model.angle_inputs == angle_in
    np.testing.assert_allclose(spec.u.mean, mean, rtol=EXACT_RTOL, atol=0)
    np.testing.assert_allclose(spec.u.cov, cov, rtol=EXACT_RTOL, atol=0)
    assert spec.v is None
    assert spec.units == units


@pytest.mark.parametrize("fname", [c[0] for c in EXAMPLE_CASES])
def test_example_round_trip(tmp_path, fname):
    spec = load_model_file(EXAMPLES / fname)
    again = load_model_file(_write(tmp_path, dump_model_file(spec), fname))
    assert (again.model, again.u, again.v, again.units) == (spec.model, spec.u, spec.v, spec.units)
    assert again.model.name == spec.model.name


# --------------------------------------------------------------------------------------
# Valid files: noise, std, params, angles, round trip
# --------------------------------------------------------------------------------------


def test_noise_file(tmp_path):
    spec = load_model_file(_write(tmp_path, NOISE_FILE))
    e_r, e_phi = sp.symbols("e_r e_phi", real=True)
    assert spec.model.noise == (e_r, e_phi)
    assert spec.model.outputs == ((r - e_r) * sp.cos(phi - e_phi), (r - e_r) * sp.sin(phi - e_phi))
    assert spec.model.structure == "general"
    assert spec.v == Gaussian.from_std([0, 0], [2, 0.5])
    assert spec.units["e_phi"] == "rad"


def test_noise_round_trip(tmp_path):
    spec = load_model_file(_write(tmp_path, NOISE_FILE))
    again = load_model_file(_write(tmp_path, dump_model_file(spec), "again.toml"))
    assert (again.model, again.u, again.v, again.units) == (spec.model, spec.u, spec.v, spec.units)


def test_round_trip_keeps_floats_bit_for_bit(tmp_path):
    text = VALID_HEADER.replace(
        '"atan2(y, x)"', '"0.1*x + 1e-5*y**3 + 1/3 + 2.5e20*sin(x)/7"'
    ) + VALID_U
    spec = load_model_file(_write(tmp_path, text))
    again = load_model_file(_write(tmp_path, dump_model_file(spec), "again.toml"))
    assert again.model.outputs == spec.model.outputs


def test_dump_refuses_what_would_not_read_back():
    spec = ModelSpec(model=Model([x], [x + 2**80]), u=Gaussian([0], 1))
    with pytest.raises(ModelFileError, match="integer literal too large"):
        dump_model_file(spec)


@pytest.mark.parametrize(
    ("u_table", "cov"),
    [
        ("mean = [1, 10]\nstd = [1, 2]", np.diag([1.0, 4.0])),
        ("mean = [1, 10]\ncov = [[1, 0.5], [0.5, 4]]", np.array([[1, 0.5], [0.5, 4]])),
        ('mean = [1, 10]\ncov = [["s**2", 0], [0, "4*s**2"]]', np.diag([2.25, 9.0])),
        ('mean = [1, 10]\nstd = ["s", "2*s"]', np.diag([2.25, 9.0])),
    ],
)
def test_std_cov_and_constant_expressions(tmp_path, u_table, cov):
    text = VALID_HEADER + "\n[params]\ns = 1.5\n\n[u]\n" + u_table + "\n"
    spec = load_model_file(_write(tmp_path, text))
    np.testing.assert_allclose(spec.u.cov, cov, rtol=EXACT_RTOL, atol=0)
    np.testing.assert_array_equal(spec.u.mean, [1.0, 10.0])


def test_scalar_cov_in_one_dimension(tmp_path):
    text = 'name = "one"\ninputs = ["x"]\noutputs = ["x**2"]\n[u]\nmean = 2\ncov = 0.5\n'
    spec = load_model_file(_write(tmp_path, text))
    assert spec.u == Gaussian([2.0], [[0.5]])


def test_params_are_substituted(tmp_path):
    text = (
        'name = "p"\ninputs = ["x", "y"]\noutputs = ["hypot(x - sx, y - sy) * k"]\n'
        "[params]\nsx = 3\nsy = -4\nk = 0.5\n" + VALID_U
    )
    spec = load_model_file(_write(tmp_path, text))
    assert spec.model.outputs == (sp.Float(0.5) * sp.sqrt((x - 3) ** 2 + (y + 4) ** 2),)


@pytest.mark.parametrize(
    ("angles", "out", "inp"),
    [("[1]", {1}, set()), ('["y"]', set(), {1}), ('[0, "x"]', {0}, {0}), ("[]", set(), set())],
)
def test_angles(tmp_path, angles, out, inp):
    spec = load_model_file(_write(tmp_path, VALID_HEADER + f"angles = {angles}\n" + VALID_U))
    assert (spec.model.angle_outputs, spec.model.angle_inputs) == (out, inp)


# --------------------------------------------------------------------------------------
# Bad files
# --------------------------------------------------------------------------------------


def test_missing_file(tmp_path):
    path = tmp_path / "nope.toml"
    with pytest.raises(ModelFileError, match=r"nope\.toml: model file not found"):
        load_model_file(path)


def test_unreadable_file(tmp_path):
    path = _write(tmp_path, VALID_HEADER + VALID_U)
    path.chmod(0)
    try:
        if os.access(path, os.R_OK):
            pytest.skip("running with privileges that read a mode-000 file")
        with pytest.raises(ModelFileError, match=r"model\.toml: .*permission denied"):
            load_model_file(path)
    finally:
        path.chmod(0o600)


def test_directory_is_not_a_model_file(tmp_path):
    with pytest.raises(ModelFileError, match=re.escape(str(tmp_path)) + ": model file cannot be read"):
        load_model_file(tmp_path)


def test_not_utf8(tmp_path):
    path = tmp_path / "latin.toml"
    path.write_bytes(b'name = "\xe9"\n')
    with pytest.raises(ModelFileError, match=r"latin\.toml: model file is not UTF-8"):
        load_model_file(path)


def test_file_too_large(tmp_path):
    path = _write(tmp_path, "#" * (MAX_FILE_BYTES + 1))
    with pytest.raises(ModelFileError, match="larger than"):
        load_model_file(path)


def test_invalid_toml_gives_line_and_column(tmp_path):
    path = _write(tmp_path, VALID_HEADER + "mean = [1, \n" + VALID_U)
    with pytest.raises(ModelFileError, match=r"model\.toml: invalid TOML: .*line \d+, column \d+"):
        load_model_file(path)


def test_expression_error_points_into_the_file(tmp_path):
    text = 'name = "t"\ninputs = ["x", "y"]\n\noutputs = ["x", "x + z"]\n' + VALID_U
    with pytest.raises(ModelFileError) as info:
        load_model_file(_write(tmp_path, text))
    msg = str(info.value)
    # z is on line 4 of the file, at column 22 of that line.
    assert msg.startswith(f"{tmp_path / 'model.toml'}: outputs[1], line 4, column 22: unknown name 'z'")


def test_tomli_missing_gives_clear_error(tmp_path, monkeypatch):
    monkeypatch.setattr(modelfile, "_toml", None)
    with pytest.raises(ImportError, match="tomli"):
        load_model_file(_write(tmp_path, VALID_HEADER + VALID_U))


_ALLOWED_TOP = "allowed keys: name, inputs, noise, outputs, angles, params, u, v, units"

# (file text, fragment of the message)
BAD_FILES = [
    (VALID_HEADER, "missing key(s) ['u']; " + _ALLOWED_TOP),
    (VALID_U, "missing key(s) ['name', 'inputs', 'outputs']"),
    (VALID_HEADER + "colour = 1\n" + VALID_U, "unknown key(s) ['colour']; " + _ALLOWED_TOP),
    (VALID_HEADER + VALID_U + "kappa = 1\n", "[u]: unknown key(s) ['kappa']; allowed keys: mean, cov, std"),
    (VALID_HEADER + "\n[u]\ncov = 1\n", "[u]: missing key(s) ['mean']"),
    (VALID_HEADER + "\n[u]\nmean = [1, 2]\n", "give exactly one of 'cov'"),
    (VALID_HEADER + VALID_U + "std = [1, 1]\n", "give exactly one of 'cov'"),
    ('name = 3\ninputs = ["x"]\noutputs = ["x"]\n[u]\nmean = 0\ncov = 1\n', "name: must be a non-empty string"),
    ('name = "t"\ninputs = "x"\noutputs = ["x"]\n[u]\nmean = 0\ncov = 1\n', "inputs: must be a list of names"),
    ('name = "t"\ninputs = []\noutputs = ["1"]\n[u]\nmean = 0\ncov = 1\n', "inputs: at least one input"),
    ('name = "t"\ninputs = ["x"]\noutputs = "x"\n[u]\nmean = 0\ncov = 1\n', "outputs: must be a non-empty list"),
    ('name = "t"\ninputs = ["x"]\noutputs = [1]\n[u]\nmean = 0\ncov = 1\n', "outputs: must be a non-empty list"),
    ('name = "t"\ninputs = ["1x"]\noutputs = ["1"]\n[u]\nmean = 0\ncov = 1\n', "'1x' is not a valid identifier"),
    ('name = "t"\ninputs = ["a-b"]\noutputs = ["1"]\n[u]\nmean = 0\ncov = 1\n', "'a-b' is not a valid identifier"),
    ('name = "t"\ninputs = ["lambda"]\noutputs = ["1"]\n[u]\nmean = 0\ncov = 1\n', "'lambda' is not a valid identifier"),
    ('name = "t"\ninputs = ["__x"]\noutputs = ["1"]\n[u]\nmean = 0\ncov = 1\n', "names starting with '__'"),
    ('name = "t"\ninputs = ["sin"]\noutputs = ["1"]\n[u]\nmean = 0\ncov = 1\n', "'sin' is reserved"),
    ('name = "t"\ninputs = ["pi"]\noutputs = ["1"]\n[u]\nmean = 0\ncov = 1\n', "'pi' is reserved"),
    ('name = "t"\ninputs = ["x", "x"]\noutputs = ["x"]\n[u]\nmean = [0, 0]\ncov = [[1, 0], [0, 1]]\n',
     "duplicate name 'x'"),
    ('name = "t"\ninputs = ["x"]\nnoise = ["x"]\noutputs = ["x"]\n[u]\nmean = 0\ncov = 1\n[v]\nmean = 0\ncov = 1\n',
     "duplicate name 'x'"),
    (VALID_HEADER + "[params]\nx = 1\n" + VALID_U, "duplicate name 'x'"),
    (VALID_HEADER + "[params]\nk = true\n" + VALID_U, "[params].k: must be a number"),
    (VALID_HEADER + "[params]\nk = 10000000000000000\n" + VALID_U, "[params].k: integer too large"),
    (VALID_HEADER + "\n[u]\nmean = [1, 2, 3]\ncov = [[1, 0], [0, 1]]\n", "[u]: mean has length 3 but there are 2 inputs"),
    (VALID_HEADER + "\n[u]\nmean = [1, 2]\ncov = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n", "[u]: cov must be 2x2"),
    (VALID_HEADER + "\n[u]\nmean = [1, 2]\ncov = [[1, 0], [0]]\n", "[u]: cov must be 2x2"),
    (VALID_HEADER + "\n[u]\nmean = [1, 2]\ncov = 1\n", "[u]: a scalar cov is only allowed in one dimension"),
    (VALID_HEADER + "\n[u]\nmean = [1, 2]\nstd = [1]\n", "[u]: std has length 1 but there are 2 inputs"),
    (VALID_HEADER + "\n[u]\nmean = [1, 2]\ncov = [[1, 2], [2, 1]]\n", "[u]: CovarianceError: cov is not positive semi-definite"),
    (VALID_HEADER + "\n[u]\nmean = [1, 2]\nstd = [-1, 1]\n", "[u]: CovarianceError: std must be non-negative"),
    (VALID_HEADER + "\n[u]\nmean = [1, true]\ncov = [[1, 0], [0, 1]]\n", "[u].mean[1]: must be a number"),
    (VALID_HEADER + '\n[u]\nmean = [1, "x"]\ncov = [[1, 0], [0, 1]]\n', "[u].mean[1], line 6, column 13: unknown name 'x'"),
    (VALID_HEADER + '\n[u]\nmean = [1, "log(-1)"]\ncov = [[1, 0], [0, 1]]\n', "complex"),
    (VALID_HEADER + '\n[u]\nmean = [1, "nan"]\ncov = [[1, 0], [0, 1]]\n', "unknown name 'nan'"),
    (VALID_HEADER + '\n[u]\nmean = [1, nan]\ncov = [[1, 0], [0, 1]]\n', "[u].mean[1]: must be finite"),
    (VALID_HEADER + '\n[u]\nmean = [1, 2]\ncov = [[1, 0], [0, [1]]]\n', "[u].cov[1][1]: must be a number"),
    (VALID_HEADER + "u = 3\n", "[u]: must be a table"),
    (VALID_HEADER + "angles = [2]\n" + VALID_U, "angles: output index 2 out of range for 2 outputs"),
    (VALID_HEADER + 'angles = ["r"]\n' + VALID_U, "angles: 'r' is neither an output index nor an input name"),
    (VALID_HEADER + "angles = [true]\n" + VALID_U, "angles: True is neither"),
    (VALID_HEADER + "angles = 1\n" + VALID_U, "angles: must be a list"),
    (NOISE_FILE.replace("[v]\nmean = [0, 0]\nstd = [2, 0.5]\n", ""), "noise ['e_r', 'e_phi'] is declared, so a [v] table"),
    (VALID_HEADER + VALID_U + "[v]\nmean = 0\ncov = 1\n", "[v]: a [v] table needs noise symbols"),
    (NOISE_FILE.replace("std = [2, 0.5]", "std = [2]"), "[v]: std has length 1 but there are 2 noise symbols"),
    (VALID_HEADER + VALID_U + '[units]\nz = "m"\n', "[units]: unknown key 'z'"),
    (VALID_HEADER + VALID_U + '[units]\n"outputs[2]" = "m"\n', "'outputs[2]': there are only 2 outputs"),
    (VALID_HEADER + VALID_U + "[units]\nx = 1\n", "[units].x: must be a non-empty unit string"),
    (VALID_HEADER + VALID_U + '[units]\nx = ""\n', "[units].x: must be a non-empty unit string"),
    (VALID_HEADER + "units = 1\n" + VALID_U, "units: must be a table"),
    (VALID_HEADER + "params = [1]\n" + VALID_U, "params: must be a table"),
]


@pytest.mark.parametrize(("text", "fragment"), BAD_FILES, ids=[f"bad{i}" for i in range(len(BAD_FILES))])
def test_bad_file(tmp_path, text, fragment):
    path = _write(tmp_path, text)
    with pytest.raises(ModelFileError) as info:
        load_model_file(path)
    msg = str(info.value)
    assert msg.startswith(str(path) + ": ")
    assert fragment in msg


# --------------------------------------------------------------------------------------
# Fuzzing: any text is either parsed or refused with a ModelFileError, never anything else
# --------------------------------------------------------------------------------------

_TOKENS = [
    "x", "y", "z", "pi", "e", "E", "0", "1", "2.5", "1e300", "64", "65", "10**15",
    "+", "-", "*", "/", "**", "(", ")", ",", " ", "sqrt", "atan2", "log", "max", "hypot",
    "'", "[", "]", ".", "__class__", "lambda", ":", "=", "<", "if", "else", "\n", "#", "@", "%",
]


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(st.text(max_size=40), st.lists(st.sampled_from(_TOKENS), max_size=25).map("".join)))
def test_fuzz_only_model_file_errors(text):
    try:
        result = parse_expression(text, SYMBOLS)
    except ModelFileError as exc:
        assert re.search(r", line \d+, column \d+: ", str(exc))
    else:
        assert isinstance(result, sp.Expr)
        assert result.free_symbols <= {x, y}
