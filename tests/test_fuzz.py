"""Fuzzing the model-file and scenario-file parsers and the ``symmon`` command with hostile input
(issues 13 and 26).

Hypothesis generates expression texts from the grammar of :mod:`symmon.files.modelfile` (and
around it: unknown names and functions, refused syntax, huge or odd numbers, deep nesting,
unicode) and model files that follow its TOML schema loosely (hostile names, wrong
lengths, odd numbers, unknown keys, truncated text). The properties:

- :func:`parse_expression`, :func:`load_model_file` and :func:`load_filter_file` (scenario
  files made from the schema, and the examples with random edits) raise nothing but
  ``SymmonError``;
- ``symmon propagate`` / ``symmon nonlinearity`` (cheap transforms) and, on a few scenario
  files, ``symmon filter`` exit with 0, 1 or 2;
  an exit 1 is a clear one-line ``symmon: error:`` (never an "internal error"), and an
  exit 0 prints only finite numbers.

The runs are derandomized and use no example database, so CI sees the same examples
every time; the example counts keep the whole file to a few tens of seconds.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from symmon.cli import parser as cli
from symmon.errors import SymmonError
from symmon.files.filterfile import MAX_STEPS, load_filter_file
from symmon.files.modelfile import FUNCTIONS, load_model_file, parse_expression

from helpers import ROOT

#: Reproducible and bounded: the same examples on every run, no deadline per example.
FUZZ = dict(derandomize=True, database=None, deadline=None,
            suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

# --------------------------------------------------------------------------- expressions
DECLARED = ("x", "y", "z", "k")  # inputs x, y, z and the parameter k (below)
HOSTILE_NAMES = ("w", "__import__", "__builtins__", "nan", "inf", "I", "oo", "ñ", "x\u0301", "𝑥",
                 "True", "None", "lambda", "sympy", "os")
ODD_NUMBERS = ("1e400", "-1e400", "1e-400", "0.0", "0x10", "0o7", "0b1", "1_000", "1j", "1e15",
               "1000000000000001", "9" * 120, "2.5e-310", "'s'", "b'x'", "...", "[]", "()", "{}")
OPERATORS = ("+", "-", "*", "/", "**", "//", "%", "@", "<", "and", "|", "<<")
CALLABLE = tuple(FUNCTIONS) + ("system", "eval", "getattr", "gamma", "open", "print")

leaves = st.one_of(
    st.sampled_from(DECLARED + ("pi", "e", "E")),
    st.sampled_from(HOSTILE_NAMES),
    st.integers(-(10**17), 10**17).map(str),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.sampled_from(ODD_NUMBERS),
)


def _grow(children: st.SearchStrategy[str]) -> st.SearchStrategy[str]:
    return st.one_of(
        st.tuples(children, st.sampled_from(OPERATORS), children).map(lambda t: f"({t[0]} {t[1]} {t[2]})"),
        st.tuples(children, st.sampled_from(("+", "-", "*", "/")), children).map(lambda t: f"{t[0]} {t[1]} {t[2]}"),
        children.map(lambda c: f"-{c}"),
        st.tuples(st.sampled_from(CALLABLE), st.lists(children, max_size=3)).map(
            lambda t: f"{t[0]}({', '.join(t[1])})"),
        children.map(lambda c: f"{c}.real"),
        children.map(lambda c: f"{c}[0]"),
        children.map(lambda c: f"(lambda: {c})()"),
    )


def _deep(n: int, kind: str) -> str:
    return {"brackets": "(" * n + "x" + ")" * n, "calls": "sin(" * n + "x" + ")" * n,
            "minus": "-" * n + "x", "powers": "x" + "**2" * n, "sum": " + ".join(["x"] * n),
            "exp": "exp(" * n + "x" + ")" * n}[kind]


expressions = st.one_of(
    st.recursive(leaves, _grow, max_leaves=25),
    st.builds(_deep, st.integers(1, 80), st.sampled_from(("brackets", "calls", "minus", "powers", "sum", "exp"))),
    st.text(max_size=40),
)

SYMBOLS = {name: sp.Symbol(name, real=True) for name in ("x", "y", "z")} | {"k": sp.Float(0.5)}


@settings(max_examples=400, **FUZZ)
@given(expressions)
def test_parse_expression_raises_only_symmon_errors(text):
    try:
        expr = parse_expression(text, SYMBOLS)
    except SymmonError:
        event("refused")
        return
    event("parsed")
    assert isinstance(expr, sp.Expr)
    assert expr.free_symbols <= set(SYMBOLS.values())


# --------------------------------------------------------------------------- model files
def _toml(value) -> str:
    """A TOML value: strings JSON-escaped (a subset of TOML's escapes), lists recursively."""
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value == math.inf else "-inf" if value == -math.inf
                                                else repr(value))
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return str(value)


text_no_surrogates = st.text(st.characters(blacklist_categories=("Cs",)), max_size=12)
names = st.one_of(st.sampled_from(("x", "y", "z")), st.sampled_from(HOSTILE_NAMES + ("k", "pi", "sqrt")),
                  text_no_surrogates)
numbers = st.one_of(
    st.floats(-10, 10),
    st.floats(),
    st.integers(-(10**3), 10**3),
    st.integers(-(10**400), 10**400),
    st.sampled_from(("k", "100*k", "sqrt(2)", "pi/4", "acos(2)", "exp(710)", "log(0)", "x", "1/0", "__import__")),
    st.booleans(),
)
positive = st.one_of(st.floats(1e-3, 10), numbers)


def _valid_expressions(scope: tuple[str, ...]) -> st.SearchStrategy[str]:
    """Expressions of the whitelist over the names in ``scope`` (their value may still be NaN)."""
    leaf = st.one_of(st.sampled_from(scope), st.floats(-5, 5).map(repr), st.integers(-5, 5).map(str),
                     st.just("pi"))

    def grow(children):
        call = st.sampled_from(sorted(FUNCTIONS)).flatmap(
            lambda f: st.lists(children, min_size=FUNCTIONS[f].min_args, max_size=FUNCTIONS[f].max_args or 3)
            .map(lambda args: f"{f}({', '.join(args)})"))
        return st.one_of(
            st.tuples(children, st.sampled_from(("+", "-", "*", "/")), children).map(lambda t: f"({t[0]} {t[1]} {t[2]})"),
            st.tuples(children, st.integers(-3, 3)).map(lambda t: f"({t[0]})**{t[1]}"),
            call)

    return st.recursive(leaf, grow, max_leaves=8)


def _gaussian_table(draw, table: str, dim: int, hostile: bool) -> str:
    size = draw(st.integers(0, 3)) if hostile else dim
    means = st.one_of(st.floats(-3, 3), numbers) if hostile else st.floats(-3, 3)
    mean = draw(st.lists(means, min_size=size, max_size=size))
    std = draw(st.lists(positive if hostile else st.floats(1e-3, 10), min_size=size, max_size=size))
    diag = [[s if i == j else 0 for j in range(size)] for i, s in enumerate(std)]
    spread = draw(st.sampled_from((f"std = {_toml(std)}", f"cov = {_toml(diag)}", f"cov = {_toml(std[0] if std else 1)}")))
    if hostile and draw(st.booleans()):
        spread = f"cov = {_toml(draw(st.lists(st.lists(numbers, max_size=3), max_size=3)))}"
    return f"\n[{table}]\nmean = {_toml(mean)}\n{spread}"


#: The parts of a model file that :func:`model_files` may spoil; "" spoils none.
SPOILS = ("name", "inputs", "noise", "outputs", "angles", "extra", "params", "u", "v", "units", "cut")


@st.composite
def model_files(draw) -> str:
    """Model-file text: about half valid, the rest with one part made hostile."""
    spoil = draw(st.sampled_from(SPOILS + ("",) * len(SPOILS)))
    inputs = draw(st.lists(names, max_size=4) if spoil == "inputs"
                  else st.lists(st.sampled_from(("x", "y", "z")), min_size=1, max_size=3, unique=True))
    noise = draw(st.lists(names, max_size=2) if spoil == "noise" else st.sampled_from(([], ["v1"])))
    scope = tuple(inputs) + tuple(noise) + ("k",)
    outputs = draw(st.lists(st.one_of(expressions, _valid_expressions(scope)), max_size=3) if spoil == "outputs"
                   else st.lists(_valid_expressions(scope), min_size=1, max_size=3))
    name = draw(text_no_surrogates) if spoil == "name" else "m"
    lines = [f"name = {_toml(name)}", f"inputs = {_toml(inputs)}", f"outputs = {_toml(outputs)}"]
    if noise:
        lines.append(f"noise = {_toml(noise)}")
    if spoil == "angles":
        lines.append(f"angles = {_toml(draw(st.lists(st.one_of(st.integers(-2, 4), names), max_size=2)))}")
    if spoil == "extra":
        lines.append(draw(st.sampled_from(("extra = 1", "u = 3", 'name = "twice"'))))
    k = draw(numbers if spoil == "params" else st.floats(0.1, 2))
    lines.append(f"\n[params]\nk = {_toml(k)}")
    lines.append(_gaussian_table(draw, "u", len(inputs), spoil == "u"))
    if noise or spoil == "v":
        lines.append(_gaussian_table(draw, "v", len(noise), spoil == "v"))
    if spoil == "units":
        lines.append(f"\n[units]\n{_toml(draw(names))} = {_toml(draw(text_no_surrogates))}")
    text = "\n".join(lines) + "\n"
    return text[: draw(st.integers(0, len(text)))] if spoil == "cut" else text


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def _write(directory: Path, text: str, name: str = "model.toml") -> Path:
    path = directory / name
    path.write_text(text, encoding="utf-8")
    return path


def _loaded(load, path: Path):
    """``load(path)``, or None after a SymmonError; anything else fails the test."""
    try:
        spec = load(path)
    except SymmonError:
        event("refused")
        return None
    event("loaded")
    return spec


@settings(max_examples=200, **FUZZ)
@given(text=model_files())
def test_load_model_file_raises_only_symmon_errors(fuzz_dir, text):
    spec = _loaded(load_model_file, _write(fuzz_dir, text))
    if spec is not None:
        assert spec.u.mean.shape == (len(spec.model.inputs),)


# --------------------------------------------------------------------------- the command
NON_FINITE = re.compile(r"\b(nan|inf|infinity)\b", re.IGNORECASE)


def _numbers(obj):
    """Every number in a JSON value, with None for a null."""
    if isinstance(obj, dict):
        for v in obj.values():
            yield from _numbers(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _numbers(v)
    elif obj is None or (isinstance(obj, (int, float)) and not isinstance(obj, bool)):
        yield obj


def _refuse_constant(name: str):
    raise AssertionError(f"JSON output contains {name}")


@settings(max_examples=60, **FUZZ)
@given(text=model_files(),
       command=st.sampled_from(("propagate", "nonlinearity")),
       transform=st.sampled_from(("tt1", "tt2", "ut1")),
       as_json=st.booleans())
def test_the_command_exits_0_1_or_2_and_prints_only_finite_numbers(fuzz_dir, text, command, transform, as_json):
    path = _write(fuzz_dir, text)
    argv = [command, str(path), "--transform", transform] + (["--json"] if as_json else [])
    out, err = io.StringIO(), io.StringIO()
    # Warnings reach a user as messages on stderr, not as errors: record them, as the
    # interpreter would print them, instead of pytest's filterwarnings = error.
    with warnings.catch_warnings(record=True), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        warnings.simplefilter("always")
        code = cli.main(argv)
    out, err = out.getvalue(), err.getvalue()
    event(f"exit {code}")
    assert code in (0, 1, 2), err
    if code == 1:
        assert out == "" and err.startswith("symmon: error: "), err   # a clear message, not an internal error
        return
    if code == 2:
        assert "usage: symmon" in err
        return
    if as_json:
        doc = json.loads(out, parse_constant=_refuse_constant)
        values = list(_numbers({k: v for k, v in doc.items() if k in ("mean", "cov", "cross_cov", "value",
                                                                     "squared", "J_Ab", "J_n")}))
        assert values and all(v is not None and math.isfinite(v) for v in values), out
    else:
        body = out.split("\n", 1)[1] if command == "propagate" else out.rsplit(" = ", 1)[1]
        assert not NON_FINITE.search(body), out


# --------------------------------------------------------------------------- filter scenario files
EXAMPLE_SCENARIOS = tuple((ROOT / "examples" / n).read_text(encoding="utf-8") for n in ("rb_close.toml", "rb_bias.toml"))
#: The parts of a scenario file that :func:`scenario_files` may spoil; "" spoils none.
SCENARIO_SPOILS = ("name", "states", "dynamics", "measurements", "angles", "state_angles", "steps", "params", "Q",
                   "R", "x0", "process_noise", "measurement_noise", "units", "extra", "cut")
STEPS = st.one_of(st.integers(-5, 200_000), st.sampled_from((0, 10**30, 1.5, "10", True)), numbers)


@st.composite
def scenario_files(draw, spoils: tuple[str, ...] = SCENARIO_SPOILS) -> str:
    """Scenario-file text: about half valid, the rest with one part of ``spoils`` made hostile."""
    spoil = draw(st.sampled_from(spoils + ("",) * max(len(spoils), 1)))
    states = draw(st.lists(names, max_size=4) if spoil == "states"
                  else st.lists(st.sampled_from(("x", "y", "z")), min_size=1, max_size=3, unique=True))
    w = draw(st.lists(names, max_size=2) if spoil == "process_noise" else st.sampled_from(([], ["w1"])))
    e = draw(st.lists(names, max_size=2) if spoil == "measurement_noise" else st.sampled_from(([], ["e1"])))
    scope = tuple(states) + ("k",)
    dynamics = draw(st.lists(st.one_of(expressions, _valid_expressions(scope + tuple(w))), max_size=4)
                    if spoil == "dynamics" else st.lists(_valid_expressions(scope + tuple(w)),
                                                         min_size=len(states), max_size=len(states)))
    measurements = draw(st.lists(st.one_of(expressions, _valid_expressions(scope + tuple(e))), max_size=3)
                        if spoil == "measurements" else st.lists(_valid_expressions(scope + tuple(e)),
                                                                 min_size=1, max_size=3))
    lines = [f"name = {_toml(draw(text_no_surrogates) if spoil == 'name' else 's')}",
             f"states = {_toml(states)}", f"dynamics = {_toml(dynamics)}", f"measurements = {_toml(measurements)}",
             f"steps = {_toml(draw(STEPS) if spoil == 'steps' else draw(st.integers(1, 50)))}"]
    if w:
        lines.append(f"process_noise = {_toml(w)}")
    if e:
        lines.append(f"measurement_noise = {_toml(e)}")
    if spoil == "angles":
        lines.append(f"angles = {_toml(draw(st.lists(st.one_of(st.integers(-2, 4), names), max_size=2)))}")
    if spoil == "state_angles":
        lines.append(f"state_angles = {_toml(draw(st.lists(names, max_size=2)))}")
    if spoil == "extra":
        lines.append(draw(st.sampled_from(("extra = 1", "u = 3", 'name = "twice"', "[v]\nmean = [0]"))))
    k = draw(numbers if spoil == "params" else st.floats(0.1, 2))
    lines.append(f"\n[params]\nk = {_toml(k)}")
    for table, dim in (("Q", len(w) or len(states)), ("R", len(e) or len(measurements))):
        body = _gaussian_table(draw, table, dim, spoil == table)
        # A noise table takes cov or std without a mean (a spoiled one may keep it).
        lines.append(body if spoil == table else re.sub(r"\nmean = .*", "", body))
    lines.append(_gaussian_table(draw, "x0", len(states), spoil == "x0"))
    if spoil == "units":
        lines.append(f"\n[units]\n{_toml(draw(names))} = {_toml(draw(text_no_surrogates))}")
    text = "\n".join(lines) + "\n"
    return text[: draw(st.integers(0, len(text)))] if spoil == "cut" else text


@st.composite
def mutated_scenarios(draw) -> str:
    """An example scenario with a few random edits: a span deleted, a line doubled, or a
    character, a number or a name replaced."""
    text = draw(st.sampled_from(EXAMPLE_SCENARIOS))
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(text)))
        j = draw(st.integers(i, min(len(text), i + 40)))
        edit = draw(st.sampled_from(("delete", "double", "replace", "insert")))
        if edit == "delete":
            text = text[:i] + text[j:]
        elif edit == "double":
            text = text[:j] + text[i:j] + text[j:]
        else:
            piece = draw(st.one_of(st.sampled_from(("]", "[", '"', "=", "\n", "#", "1e400", "nan", "-1", "0",
                                                    "states", "[Q]", "cov = 1", "__import__('os')", "x**99999",
                                                    "1979-05-27T07:32:00Z", "{a = 1}", "\n[[Q]]\n", "[" * 300,
                                                    '"\\u0000"', "\nsteps = 99999999999999999999\n", "'x'")),
                                   text_no_surrogates))
            text = text[:i] + piece + text[j if edit == "replace" else i:]
    return text


@settings(max_examples=120, **FUZZ)
@given(text=st.one_of(scenario_files(), mutated_scenarios()))
def test_load_filter_file_raises_only_symmon_errors(fuzz_dir, text):
    """The parser alone (nothing is compiled): a loaded scenario is consistent."""
    spec = _loaded(load_filter_file, _write(fuzz_dir, text, "scenario.toml"))
    if spec is None:
        return
    n = len(spec.f.inputs)
    assert spec.f.n_y == n and spec.h.n_u == n and 1 <= spec.steps <= MAX_STEPS
    assert spec.x0.mean.shape == (n,) and spec.Q.shape[0] == (spec.f.n_v or n)
    assert spec.R.shape[0] == (spec.h.n_v or spec.h.n_y)
    assert all(np.isfinite(a).all() for a in (spec.Q, spec.R, spec.x0.mean, spec.x0.cov))


@settings(max_examples=6, **FUZZ)
@given(text=scenario_files(spoils=()), smooth=st.booleans())
def test_symmon_filter_on_a_scenario_exits_0_1_or_2(fuzz_dir, text, smooth):
    """A few valid scenarios end to end (each compiles a filter step; the refusals are the
    parser's, above): odd but valid models, never an internal error."""
    path = _write(fuzz_dir, text, "scenario.toml")
    argv = ["filter", str(path), "--runs", "2", "--filters", "ekf"] + (["--smooth"] if smooth else [])
    out, err = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(record=True), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        warnings.simplefilter("always")
        code = cli.main(argv)
    event(f"exit {code}")
    assert code in (0, 1, 2), err.getvalue()
    assert "internal error" not in err.getvalue(), err.getvalue()
    if code == 1:
        assert out.getvalue() == "" and err.getvalue().startswith("symmon: error: "), err.getvalue()
