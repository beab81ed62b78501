"""Model.from_function: NumPy-style (FilterPy) model functions traced into sympy models."""

from __future__ import annotations

import math
import re
import textwrap
from pathlib import Path
from typing import Callable

import casadi as ca
import numpy as np
import scipy.linalg
import scipy.special
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ModelError, UnsupportedFunctionError
from symmon.compile import to_casadi
from symmon.core.tracing import SUPPORTED, Condition, Traced, trace

#: Sympy and NumPy evaluate the same expression in a different order: a few ulps.
ROUNDING_RTOL = 1e-12
#: Two models with the same expressions give the same TT2 moments bit for bit, up to the
#: rounding of the constants' decimal form (none here).
EXACT_RTOL = 1e-12

DOCS = Path(__file__).resolve().parents[2] / "docs"

SENSOR = (1.0, 2.5)
DT = 0.1


def hx_range_bearing(x):
    """FilterPy-style measurement function of a constant-velocity state [px, vx, py, vy]."""
    dx = x[0] - SENSOR[0]
    dy = x[2] - SENSOR[1]
    return np.array([np.sqrt(dx**2 + dy**2), np.arctan2(dy, dx)])


def fx_cv(x, dt):
    """FilterPy-style motion function: F @ x."""
    F = np.array([[1, dt, 0, 0], [0, 1, 0, 0], [0, 0, 1, dt], [0, 0, 0, 1]])
    return F @ x


STATE = ["px", "vx", "py", "vy"]


def test_range_bearing_equals_the_sympy_declaration():
    px, vx, py, vy = sp.symbols(STATE, real=True)
    declared = [sp.sqrt((px - 1) ** 2 + (py - sp.Rational(5, 2)) ** 2), sp.atan2(py - sp.Rational(5, 2), px - 1)]
    m = sm.Model.from_function(hx_range_bearing, inputs=STATE, angles=[1])
    assert m.inputs == (px, vx, py, vy)
    assert [sp.simplify(a - b) for a, b in zip(m.outputs, declared)] == [0, 0]
    assert m.angle_outputs == frozenset({1}) and m.name == "hx_range_bearing"


@pytest.mark.parametrize("point", [[3.0, 0.2, -4.0, 1.0], [-0.5, 1.0, 7.25, -2.0], [1e3, 0.0, 1e-3, 5.0]])
def test_traced_model_evaluates_like_the_function(point):
    m = sm.Model.from_function(hx_range_bearing, inputs=STATE)
    subs = dict(zip(m.inputs, point))
    got = np.array([float(e.evalf(subs=subs)) for e in m.outputs])
    np.testing.assert_allclose(got, hx_range_bearing(np.array(point)), rtol=ROUNDING_RTOL)


def test_motion_function_with_args_keeps_the_float_constant():
    m = sm.Model.from_function(fx_cv, inputs=STATE, args=(DT,))
    px, vx, py, vy = m.inputs
    assert m.outputs[1] == vx and m.outputs[3] == vy
    coeff = m.outputs[0].coeff(vx)
    assert coeff == sp.Rational(1, 10) and float(coeff) == DT  # as written, and the same double
    x = np.array([1.0, 2.0, 3.0, 4.0])
    got = [float(e.subs(dict(zip(m.inputs, x)))) for e in m.outputs]
    np.testing.assert_allclose(got, fx_cv(x, DT), rtol=ROUNDING_RTOL)


def test_moments_of_traced_and_declared_models_agree():
    px, vx, py, vy = sp.symbols(STATE, real=True)
    declared = sm.Model([px, vx, py, vy], [sp.sqrt((px - 1) ** 2 + (py - sp.Rational(5, 2)) ** 2),
                                           sp.atan2(py - sp.Rational(5, 2), px - 1)])
    traced = sm.Model.from_function(hx_range_bearing, inputs=STATE)
    u = sm.Gaussian([10.0, 1.0, 6.0, -1.0], np.diag([1.0, 0.1, 2.0, 0.1]))
    for t in (sm.TT2(), sm.UT.ut1()):
        a, b = sm.propagate(declared, u, transform=t), sm.propagate(traced, u, transform=t)
        np.testing.assert_allclose(b.mean, a.mean, rtol=EXACT_RTOL)
        np.testing.assert_allclose(b.cov, a.cov, rtol=EXACT_RTOL)


def test_noise_argument_and_structure():
    def hx_noisy(x, v):
        return np.array([np.hypot(x[0], x[1]) * (1 + v[0]), np.arctan2(x[1], x[0]) + v[1]])

    m = sm.Model.from_function(hx_noisy, inputs=["x", "y"], noise=["e_r", "e_b"])
    assert m.noise == sp.symbols("e_r e_b", real=True)
    assert m.structure == "multiplicative"


@pytest.mark.parametrize("fn, expected", [
    (lambda x: np.exp(x[0]) * np.log(x[1]), lambda a, b: sp.exp(a) * sp.log(b)),
    (lambda x: np.sin(x) ** 2, lambda a, b: [sp.sin(a) ** 2, sp.sin(b) ** 2]),
    (lambda x: np.fmax(x[0], 2) - np.abs(x[1]), lambda a, b: sp.Max(a, 2) - sp.Abs(b)),
    (lambda x: x.sum() / 2, lambda a, b: (a + b) / 2),
    (lambda x: np.dot(x, x), lambda a, b: a**2 + b**2),
    (lambda x: 2.0 ** x[0], lambda a, b: 2 ** a),
    (lambda x: -x[1] + 3, lambda a, b: 3 - b),
    (lambda x: np.tanh(x[0] / x[1]), lambda a, b: sp.tanh(a / b)),
    (lambda x: 7, lambda a, b: 7),
])
def test_supported_operations(fn, expected):
    _, _, got = trace(fn, ["a", "b"])
    a, b = sp.symbols("a b", real=True)
    want = expected(a, b)
    want = list(want) if isinstance(want, list) else [want]
    assert [sp.simplify(g - w) for g, w in zip(got, want)] == [0] * len(want)


@pytest.mark.parametrize("fn, name", [
    (lambda x: float(x[0]), "converting a traced value to a number"),
    (lambda x: math.sqrt(x[0]), "converting a traced value to a number"),
    (lambda x: x[0] if x[0] > 0 else -x[0], "deciding a traced comparison as True or False"),
    (lambda x: np.fmod(x[0], 2.0), "np.fmod"),
    (lambda x: x[0] // 2, "floor division"),
    (lambda x: np.mod(x[0], 2.0), r"np.remainder \(also np.mod\)"),
    (lambda x: np.add.at(x, [0], 1.0), "np.add.at"),
])
def test_unsupported_operation_is_named(fn, name):
    with pytest.raises(UnsupportedFunctionError, match=name):
        sm.Model.from_function(fn, inputs=["a", "b"])


def test_bad_functions_and_names():
    with pytest.raises(ModelError, match="callable"):
        trace(3, ["a"])
    with pytest.raises(ModelError, match="no outputs"):
        trace(lambda x: np.array([]), ["a"])
    with pytest.raises(ModelError, match="at least one input"):
        trace(lambda x: x, [])
    with pytest.raises(ModelError, match="non-finite"):
        trace(lambda x: x[0] * np.inf, ["a"])
    with pytest.raises(ModelError, match="must be sympy Symbols"):
        trace(lambda x: x, [1.5])


def test_traced_value_is_not_a_number():
    t = Traced(sp.Symbol("a"))
    with pytest.raises(UnsupportedFunctionError):
        bool(t)
    assert "np.arctan2" in SUPPORTED and "np.sqrt" in SUPPORTED


# --------------------------------------------------------------------------- inputs and indexes
def test_too_few_input_names_say_how_many_to_give():
    def hx(x):
        return np.array([x[0] + x[2]])

    with pytest.raises(ModelError, match=r"the function hx reads x\[2\] but inputs= names 2 symbols "
                                         r"\(a, b\): give 3 names") as err:
        sm.Model.from_function(hx, inputs=["a", "b"])
    assert not isinstance(err.value, UnsupportedFunctionError)
    with pytest.raises(ModelError, match=r"reads x\[2\] and x\[5\] .* give 6 names"):
        trace(lambda x: x[5] * x[2] + x[0], ["a", "b"])


def test_the_index_check_names_the_parameter_and_the_noise():
    def hx(state, noise):
        return state[0] + noise[1]

    with pytest.raises(ModelError, match=r"reads noise\[1\] but noise= names 1 symbol \(e\): give 2 names"):
        trace(hx, ["a"], noise=["e"])
    with pytest.raises(ModelError, match=r"reads state\[3\]"):
        trace(lambda state, noise: state[3] + noise[0], ["a"], noise=["e"])


@pytest.mark.parametrize("fn, message", [
    (lambda x: x[-3], r"reads x\[-3\] .* give at least 3 names"),
    (lambda x: x[[0, 2]].sum(), r"reads x\[2\] .* give 3 names"),
    (lambda x: x[np.array([2, 0])], r"reads x\[2\]"),
    (lambda x: x[(4,)], r"reads x\[4\] .* give 5 names"),
    (lambda x: x[np.int64(2)], r"reads x\[2\]"),
    # a failure after the read past the names (here: the placeholder in a float array)
    (lambda x: np.array([x[2]], dtype=float), r"reads x\[2\]"),
])
def test_reads_past_the_names(fn, message):
    with pytest.raises(ModelError, match=message):
        trace(fn, ["a", "b"])


@pytest.mark.parametrize("fn, expected", [
    (lambda x: x[-1] - x[-2], lambda a, b: b - a),
    (lambda x: x[1:].sum() + x[:1][0], lambda a, b: a + b),
    (lambda x: x[::-1][0], lambda a, b: b),
    (lambda x: x[[1, 0]][0], lambda a, b: b),
    (lambda x: sum(xi**2 for xi in x), lambda a, b: a**2 + b**2),
    (lambda x: (lambda p, q: p * q)(*x), lambda a, b: a * b),
    (lambda x: len(x) * x[0], lambda a, b: 2 * a),
    (lambda x: x.copy()[1], lambda a, b: b),
])
def test_negative_indexes_slices_and_iteration_keep_working(fn, expected):
    a, b = sp.symbols("a b", real=True)
    assert sp.simplify(trace(fn, ["a", "b"])[2][0] - expected(a, b)) == 0


def test_other_index_errors_give_the_names():
    def unpack(x):
        px, py, pz = x
        return px

    with pytest.raises(ModelError, match=r"not enough values to unpack .*x holds the 2 names of inputs= \(a, b\)"):
        trace(unpack, ["a", "b"])
    with pytest.raises(ModelError, match=r"raised IndexError: too many indices.*\(x holds the 2 names"):
        trace(lambda x: x[0, 1], ["a", "b"])
    with pytest.raises(ModelError, match=r"IndexError.*x holds the 1 name of inputs= \(a\) and v holds the 1 name of noise= \(e\)"):
        trace(lambda x, v: np.asarray(x)[3], ["a"], noise=["e"])


def test_a_function_that_cannot_be_called_so_is_a_model_error():
    def fx(x, dt):
        return x * dt

    with pytest.raises(ModelError, match=r"fx cannot be called as fx\(x\): missing a required argument: 'dt'.*args="):
        sm.Model.from_function(fx, inputs=["a"])
    def hx(x):
        return x

    with pytest.raises(ModelError, match=r"cannot be called as hx\(x, v\): too many positional arguments"):
        trace(hx, ["a"], noise=["e"])


def test_indexing_with_traced_values_is_refused():
    with pytest.raises(UnsupportedFunctionError, match=r"indexing with traced values .* np.where"):
        trace(lambda x: x[x > 0], ["a", "b"])
    with pytest.raises(UnsupportedFunctionError, match=r"indexing with traced values"):
        trace(lambda x: x[x[0]], ["a", "b"])


# --------------------------------------------------------------------------- names of what is refused
@pytest.mark.parametrize("fn, name", [
    # ufuncs, by NumPy's or SciPy's qualified name
    (lambda x: np.fmod(x[0], 2.0), "np.fmod"),
    (lambda x: np.isfinite(x), "np.isfinite"),
    (lambda x: scipy.special.gamma(x[0]), "scipy.special.gamma"),
    (lambda x: scipy.special.j0(x), "scipy.special.j0"),
    # NumPy functions, through __array_function__ on a traced scalar or array
    (lambda x: np.sort(x), "np.sort"),
    (lambda x: np.median(x), "np.median"),
    (lambda x: np.sinc(x[0]), "np.sinc"),
    (lambda x: np.round(x[0], 2), r"np.round (also np.around)"),
    (lambda x: np.around(x), r"np.round (also np.around)"),
    (lambda x: np.rint(np.array([x[0], x[1]])), "np.rint"),  # NumPy's loop over an object array
    (lambda x: np.isnan(np.array([x[0], x[1]])), "np.isnan"),  # NumPy has no loop for objects
    (lambda x: np.reshape(x, (3, 3)), "np.reshape"),  # NumPy's ValueError, under its name
    (lambda x: round(x[0]), "round() (also np.round)"),
    (lambda x: math.trunc(x[0]), "np.trunc (also np.fix, math.trunc)"),
    (lambda x: np.linalg.solve(np.eye(2), x), "np.linalg.solve"),
    # NumPy and SciPy functions without a traced argument to dispatch on: named from the call
    (lambda x: np.sort(np.array([x[0], x[1]])), "np.sort"),
    (lambda x: scipy.linalg.expm(np.array([[x[0], 0.0], [0.0, x[1]]])), "scipy.linalg.expm"),
])
def test_unsupported_functions_are_named_by_their_qualified_name(fn, name):
    with pytest.raises(UnsupportedFunctionError) as err:
        sm.Model.from_function(fn, inputs=["a", "b"])
    message = str(err.value)
    assert message.startswith(f"{name} is not supported in a traced model function: "), message
    assert "np.erf" not in message and "np.gamma" not in message


def test_a_refusal_inside_a_numpy_function_says_why():
    with pytest.raises(UnsupportedFunctionError, match=r"^np.median .*: it compares traced values; .*np.where"):
        trace(lambda x: np.median(x), ["a", "b"])
    with pytest.raises(UnsupportedFunctionError, match=r"^scipy.linalg.expm .*: it converts traced values to numbers"):
        trace(lambda x: scipy.linalg.expm(np.array([[x[0], 1.0], [0.0, x[0]]])), ["a"])
    with pytest.raises(UnsupportedFunctionError, match=r"^np.sinc .*AttributeError"):
        trace(lambda x: np.sinc(x[0]), ["a"])


def test_a_refused_ufunc_lists_what_is_supported():
    with pytest.raises(UnsupportedFunctionError) as err:
        trace(lambda x: np.fmod(x[0], 2.0), ["a"])
    assert all(name in str(err.value) for name in SUPPORTED)


def test_scipy_erf_is_traced():
    _, _, (g,) = trace(lambda x: scipy.special.erf(x[0]) + scipy.special.erfc(x[1]), ["a", "b"])
    a, b = sp.symbols("a b", real=True)
    assert sp.simplify(g - (sp.erf(a) + 1 - sp.erf(b))) == 0


# --------------------------------------------------------------------------- SUPPORTED, each against NumPy
M = np.array([[1.0, -2.0, 0.5], [0.0, 3.0, 1.0]])
#: The NumPy functions of SUPPORTED that are not elementwise ufuncs, each on a 3-vector.
FUNCTION_CASES: dict[str, Callable] = {
    "np.array": lambda x: np.array([x[0] * 2, x[1] - x[2]]),
    "np.asarray": lambda x: np.asarray(x) * 2 + 1,
    "np.clip": lambda x: np.hstack([np.clip(x, -0.1, 0.5), np.clip(x[0], 0.0, None)]),
    "np.concatenate": lambda x: np.concatenate([x, [1.5], x[:1]]),
    "np.cumsum": lambda x: np.cumsum(x),
    "np.dot": lambda x: np.dot(M, x),
    "np.hstack": lambda x: np.hstack([x, x[0]]),
    "np.inner": lambda x: np.inner(x, x),
    "np.linalg.norm": lambda x: np.array([np.linalg.norm(x), np.linalg.norm(x, 1)]),
    "np.matmul": lambda x: np.matmul(M, x) + M @ x,
    "np.max": lambda x: np.max(x),
    "np.mean": lambda x: np.mean(x),
    "np.min": lambda x: np.min(x - 0.5),
    "np.outer": lambda x: np.outer(x, x[:2]).ravel(),
    "np.prod": lambda x: np.prod(x),
    "np.stack": lambda x: np.stack([x, 2 * x]).ravel(),
    "np.sum": lambda x: np.sum(x),
    "np.std": lambda x: np.std(x, ddof=1),
    "np.var": lambda x: np.hstack([np.var(x), np.var(np.outer(x, x[:2]), axis=0)]),
    "np.vstack": lambda x: np.vstack([x, x[::-1]]).ravel(),
    "np.where": lambda x: np.where(x > 0.5, x, -x),
}
FUNCTION_POINTS = [(0.3, 0.7, -0.2), (0.9, -0.4, 1.5)]

#: Points inside each ufunc's domain; a ufunc of one argument uses the first coordinate.
POINTS = [(0.3, 0.7), (0.9, -0.2), (-0.4, -0.45), (0.5, 0.5)]
UFUNC_POINTS = {
    **dict.fromkeys(["np.sqrt", "np.log", "np.log2", "np.log10", "np.power", "np.pow", "np.float_power"],
                    [(0.3, 0.7), (2.5, 1.3), (1.0, 0.5)]),
    **dict.fromkeys(["np.arccosh", "np.acosh"], [(1.7, 1.2), (3.0, 1.0)]),
    **dict.fromkeys(["np.logical_and", "np.logical_or", "np.logical_xor", "np.logical_not"],
                    [(0.0, 0.7), (0.3, 0.0), (0.0, 0.0), (0.3, -0.2)]),
    "np.sign": POINTS + [(0.0, 0.0)],
}


def _resolve(name: str):
    module, _, attr = name.rpartition(".")
    return getattr({"np": np, "np.linalg": np.linalg, "scipy.special": scipy.special}[module], attr)


def _ufunc_cases():
    for name in SUPPORTED:
        f = _resolve(name)
        if isinstance(f, np.ufunc) and name not in FUNCTION_CASES:
            points = UFUNC_POINTS.get(name, POINTS)
            if f.nin == 1:
                yield name, "scalar", (lambda x, f=f: f(x[0])), [p[:1] for p in points]
                yield name, "array", (lambda x, f=f: f(x)), points
            else:
                yield name, "scalar", (lambda x, f=f: f(x[0], x[1])), points
                yield name, "array", (lambda x, f=f: f(x, x[::-1])), points


CASES = [*_ufunc_cases(), *[(name, "function", fn, FUNCTION_POINTS) for name, fn in FUNCTION_CASES.items()]]


def _casadi_values(outputs, symbols, point):
    w = ca.SX.sym("w", len(symbols))
    f = ca.Function("f", [w], [ca.vertcat(*to_casadi(outputs, symbols, w))])
    return np.asarray(f(np.asarray(point, dtype=float))).ravel()


def test_every_supported_name_has_a_case():
    assert {name for name, *_ in CASES} == set(SUPPORTED)


@pytest.mark.parametrize("name, kind, fn, points", CASES, ids=[f"{c[0]}-{c[1]}" for c in CASES])
def test_every_supported_operation_traces_to_what_numpy_computes(name, kind, fn, points):
    names = [f"w{i}" for i in range(len(points[0]))]
    inputs, _, outputs = trace(fn, names)
    for point in points:
        want = np.asarray(fn(np.array(point)), dtype=float).ravel()
        subs = dict(zip(inputs, point))
        by_sympy = np.array([float(sp.N(g.subs(subs), 30)) for g in outputs])
        np.testing.assert_allclose(by_sympy, want, rtol=ROUNDING_RTOL, atol=1e-15, err_msg=f"{name} at {point}")
        np.testing.assert_allclose(_casadi_values(outputs, inputs, point), want, rtol=ROUNDING_RTOL,
                                   atol=1e-15, err_msg=f"{name} compiled, at {point}")


@pytest.mark.parametrize("name, call", [
    ("np.fmod", lambda x: np.fmod(x[0], 0.5)),
    ("np.remainder", lambda x: np.remainder(x, 0.5)),
    ("np.heaviside", lambda x: np.heaviside(x[0], 0.5)),
    ("np.isfinite", lambda x: np.isfinite(x)),
    ("np.sort", lambda x: np.sort(x)),
    ("np.median", lambda x: np.median(x)),
    ("np.sinc", lambda x: np.sinc(x[0])),
    ("np.round", lambda x: np.round(x[1])),
    ("scipy.special.gamma", lambda x: scipy.special.gamma(x)),
])
def test_unlisted_functions_are_refused(name, call):
    assert name not in SUPPORTED
    with pytest.raises(UnsupportedFunctionError, match=rf"^{re.escape(name)}.* is not supported in a traced model function: "):
        trace(call, ["a", "b"])


# --------------------------------------------------------------------------- branches on values
def test_a_comparison_is_a_condition_and_np_where_a_piecewise():
    a, b = sp.symbols("a b", real=True)
    _, _, (g,) = trace(lambda x: np.where(x[0] > 0, x[0], -2 * x[0]), ["a"])
    assert g == sp.Piecewise((a, a > 0), (-2 * a, True))
    _, _, g = trace(lambda x: np.where(x > 1, x**2, 0), ["a", "b"])
    assert g == (sp.Piecewise((a**2, a > 1), (0, True)), sp.Piecewise((b**2, b > 1), (0, True)))
    _, _, (g,) = trace(lambda x: np.where((x[0] > 0) & ~(x[1] <= 1) | (x[0] == x[1]), 1.0, x[1]), ["a", "b"])
    assert g == sp.Piecewise((1, ((a > 0) & (b > 1)) | sp.Eq(a, b)), (b, True))
    cond = Traced(a) >= 1
    assert isinstance(cond, Condition) and cond.expr == (a >= 1)


def test_a_condition_in_arithmetic_is_one_or_zero():
    a = sp.Symbol("a", real=True)
    _, _, (g,) = trace(lambda x: (x[0] > 0) * x[0], ["a"])
    assert g == a * sp.Piecewise((1, a > 0), (0, True))
    _, _, (g,) = trace(lambda x: x[0] < 1, ["a"])  # a condition as an output
    assert g == sp.Piecewise((1, a < 1), (0, True))


@pytest.mark.parametrize("fn", [
    lambda x: x[0] if x[0] > 0 else -x[0],
    lambda x: x[0] if x[0] else 1.0,
    lambda x: np.where(x[0] > 0 and x[1] > 0, 1.0, 0.0),
    lambda x: max(x[0], 0.0),
    lambda x: np.maximum(np.array([x[0], x[1]]), 0.0),  # NumPy's loop compares the entries
])
def test_a_python_branch_on_a_traced_comparison_says_how_to_write_it(fn):
    with pytest.raises(UnsupportedFunctionError) as err:
        sm.Model.from_function(fn, inputs=["a", "b"])
    message = str(err.value)
    assert message.startswith("deciding a traced comparison as True or False (Python if, while, and, or, not")
    assert "np.where(cond, a, b)" in message and "sympy Piecewise" in message and "np.maximum" in message


def test_a_comparison_sympy_decides_is_a_bool():
    assert bool(Traced(sp.Symbol("a", real=True)) ** 2 + 1 > 0) is True
    _, _, (g,) = trace(lambda x: x[0] if x[0] == x[0] else 0.0, ["a"])
    assert g == sp.Symbol("a", real=True)


def test_np_where_with_one_argument_is_refused():
    with pytest.raises(UnsupportedFunctionError, match=r"np.where\(cond\) without both a and b .* np.where\(cond, a, b\)"):
        trace(lambda x: np.where(x > 0)[0], ["a", "b"])


def _max(a, b):
    """np.maximum's form: NaN where a or b is NaN (neither comparison holds)."""
    return f"Piecewise(({a}, {a} >= {b}), ({b}, {a} < {b}), (nan, True))"


def _min(a, b):
    return f"Piecewise(({a}, {a} <= {b}), ({b}, {a} > {b}), (nan, True))"


@pytest.mark.parametrize("fn, expected", [
    (lambda x: np.maximum(x, 0.5), lambda a, b: [_max(a, "1/2"), _max(b, "1/2")]),
    (lambda x: np.minimum(x[0], x[1]), lambda a, b: [_min(a, b)]),
    (lambda x: np.fmax(x[0], x[1]), lambda a, b: [str(sp.Max(a, b))]),
    (lambda x: np.fmin(x, 1), lambda a, b: [str(sp.Min(a, 1)), str(sp.Min(b, 1))]),
    (lambda x: np.abs(x - 1), lambda a, b: [str(sp.Abs(a - 1)), str(sp.Abs(b - 1))]),
    (lambda x: np.sign(x), lambda a, b: [str(sp.sign(a)), str(sp.sign(b))]),
    (lambda x: np.clip(x[0], -1, 1), lambda a, b: [_min(_max(a, -1), 1)]),
    (lambda x: x.clip(0, None), lambda a, b: [_max(a, 0), _max(b, 0)]),
    (lambda x: np.max(x), lambda a, b: [_max(a, b)]),
    (lambda x: x.min(), lambda a, b: [_min(a, b)]),
    (lambda x: np.maximum(x[0] ** 2, 0), lambda a, b: [str(a**2)]),  # a comparison sympy decides
    (lambda x: np.logical_and(x[0] > 0, x[1]), lambda a, b: [str(sp.Piecewise((1, (a > 0) & sp.Ne(b, 0)), (0, True)))]),
])
def test_value_branches_are_max_min_abs_sign(fn, expected):
    a, b = sp.symbols("a b", real=True)
    assert [str(g) for g in trace(fn, ["a", "b"])[2]] == expected(a, b)


NAN_CASES = {
    "np.maximum": (lambda x: np.maximum(np.sqrt(x[0]), x[1]), True),
    "np.minimum": (lambda x: np.minimum(x[1], np.log(x[0])), True),
    "np.clip": (lambda x: np.clip(np.sqrt(x[0]), 0.0, x[1]), True),
    "np.max": (lambda x: np.max(np.sqrt(x)), True),
    "np.min": (lambda x: np.min(np.arcsin(x - 0.5)), True),
    "nested": (lambda x: np.maximum(np.minimum(np.sqrt(x[0]), 1.0), x[1]), True),
    "compared": (lambda x: np.where(np.maximum(np.sqrt(x[0]), x[1]) >= 0.5, 1.0, -1.0), None),  # NaN >= 0.5 is False
    "np.fmax": (lambda x: np.fmax(np.sqrt(x[0]), x[1]), False),
    "np.fmin": (lambda x: np.fmin(x[1], np.log(x[0])), False),
}
NAN_POINTS = [(-1.0, 0.25), (4.0, 0.25), (0.25, 3.0), (np.nan, 0.5), (0.5, np.nan), (np.nan, np.nan),
              (0.0, -0.0), (np.inf, 1.0), (-np.inf, 1.0)]


@pytest.mark.parametrize("name", NAN_CASES)
def test_maximum_and_minimum_propagate_nan_as_numpy_does(name):
    """np.maximum, np.minimum, np.clip, np.max and np.min give NaN where an argument is NaN
    (a sqrt or log outside its domain, a NaN input); np.fmax and np.fmin drop it: the
    compiled model against NumPy at each point, NaN for NaN, to rounding elsewhere."""
    fn, propagates = NAN_CASES[name]
    m = sm.Model.from_function(fn, inputs=["a", "b"])
    cm = sm.compile.CompiledModel(m.outputs, m.inputs, name=f"nan_{name[3:]}", compiled=False)
    got = cm.eval_g(np.array(NAN_POINTS))
    with np.errstate(invalid="ignore", divide="ignore"):
        want = np.array([np.atleast_1d(np.asarray(fn(np.array(p)), dtype=float)) for p in NAN_POINTS])
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want), err_msg=name)
    np.testing.assert_allclose(got, want, rtol=ROUNDING_RTOL, equal_nan=True, err_msg=name)
    if propagates is not None:  # at a = -1 the sqrt or log is NaN: kept, or dropped by fmax / fmin
        assert np.isnan(want[0, 0]) == propagates


def test_a_traced_branch_propagates_with_its_derivatives():
    """CasADi compiles the Piecewise to if_else: TT1 takes the value and the slope of the
    branch the mean lies in."""
    def hx(x):
        return np.array([np.where(x[0] > 0, x[0] ** 2, -x[0]), np.clip(x[1], -1.0, 1.0)])

    m = sm.Model.from_function(hx, inputs=["a", "b"])
    for mean, slope in (([2.0, 0.5], [4.0, 1.0]), ([-3.0, 2.0], [-1.0, 0.0])):
        got = sm.propagate(m, sm.Gaussian(mean, np.diag([0.01, 0.04])), transform=sm.TT1())
        np.testing.assert_allclose(got.mean, hx(np.array(mean)), rtol=EXACT_RTOL)
        np.testing.assert_allclose(np.diag(got.cov), np.square(slope) * [0.01, 0.04], rtol=EXACT_RTOL, atol=1e-15)


# --------------------------------------------------------------------------- the documented list
def _bullet_list(text: str, after: str) -> str:
    """The first bullet list after the line ``after``, up to the blank line that ends it."""
    lines = textwrap.dedent(text.split(after, 1)[1]).splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("- "))
    end = next((i for i in range(start, len(lines)) if not lines[i].strip()), len(lines))
    return "\n".join(lines[start:end])


@pytest.mark.parametrize("where, text, after", [
    ("docs/guide/models.md", (DOCS / "guide" / "models.md").read_text(encoding="utf-8"),
     "### What a traced function may use"),
    ("Model.from_function", sm.Model.from_function.__doc__, "Notes\n        -----"),
])
def test_the_documented_list_is_supported(where, text, after):
    listed = set(re.findall(r"`{1,2}((?:np|scipy)\.[A-Za-z_][\w.]*)", _bullet_list(text, after)))
    assert set(SUPPORTED) - listed == set(), f"{where} omits these"
    # a name listed but not supported is an alias that this NumPy does not have (np.pow < 2.0)
    assert {n for n in listed - set(SUPPORTED) if hasattr(np, n.removeprefix("np."))} == set(), where


# --------------------------------------------------------------------------- np.var, np.std, arrays built by hand
@pytest.mark.parametrize("call", [
    lambda x: np.var(x), lambda x: np.std(x), lambda x: np.var(x, ddof=1), lambda x: np.std(x, correction=1),
    lambda x: np.var(np.outer(x, x[:2]), axis=0), lambda x: np.std(np.outer(x, x[:2]), axis=1, ddof=1),
    lambda x: np.var(np.outer(x, x[:2]), axis=1, keepdims=True).ravel(),
    lambda x: np.var(np.array([x[0], 2 * x[1], x[2]])),  # NumPy's own np.var on an object array
])
def test_var_and_std_trace_to_what_numpy_computes(call):
    inputs, _, outputs = trace(call, ["a", "b", "c"])
    for point in FUNCTION_POINTS:
        want = np.asarray(call(np.array(point)), dtype=float).ravel()
        np.testing.assert_allclose(_casadi_values(outputs, inputs, point), want, rtol=ROUNDING_RTOL, atol=1e-15)


def test_var_with_no_degrees_of_freedom_left_is_refused():
    with pytest.raises(UnsupportedFunctionError, match=r"np.var with ddof=3 of 3 entries"):
        trace(lambda x: np.var(x, ddof=3), ["a", "b", "c"])


#: The ufuncs whose NumPy loop over an object array compares the entries (refused on an
#: array built with np.array([...]); they work on traced arrays and scalars).
COMPARING = {"np.sign", "np.maximum", "np.minimum", "np.fmax", "np.fmin", "np.greater", "np.greater_equal",
             "np.less", "np.less_equal", "np.equal", "np.not_equal", "np.logical_and", "np.logical_or",
             "np.logical_not"}
#: The ufuncs NumPy has no loop of for object arrays.
NO_OBJECT_LOOP = {"np.float_power", "scipy.special.erf", "scipy.special.erfc"}


@pytest.mark.parametrize("name", [n for n in SUPPORTED if isinstance(_resolve(n), np.ufunc) and n not in FUNCTION_CASES])
def test_every_supported_ufunc_on_an_array_built_by_hand(name):
    """np.floor(np.array([x[0], x[1]])): NumPy's own loop over the entries.  Those that
    compare the entries cannot be decided and are refused with the advice."""
    f = _resolve(name)
    fn = (lambda x: f(np.array([x[0], x[1]]))) if f.nin == 1 else (lambda x: f(np.array([x[0], x[1]]), np.array([x[1], x[0]])))
    if name in COMPARING | NO_OBJECT_LOOP:
        with pytest.raises(UnsupportedFunctionError, match="deciding a traced comparison" if name in COMPARING
                           else rf"^{re.escape(name)} of an array built with np.array\(\[...\]\) is not supported"):
            trace(fn, ["w0", "w1"])
        return
    inputs, _, outputs = trace(fn, ["w0", "w1"])
    for point in UFUNC_POINTS.get(name, POINTS):
        want = np.asarray(fn(np.array(point)), dtype=float).ravel()
        np.testing.assert_allclose(_casadi_values(outputs, inputs, point), want, rtol=ROUNDING_RTOL, atol=1e-15,
                                   err_msg=f"{name} at {point}")
