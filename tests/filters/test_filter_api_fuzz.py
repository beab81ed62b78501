"""Fuzzing the public filter API (issue 26, item 3d): every failure is a SymmonError.

``KalmanFilter`` and ``NonlinearKalmanFilter`` (made, ``filter``, ``smooth``, ``fit``,
``simulate``, NEES and NIS) get one hostile argument at a time, the others valid: a value
of another shape, dtype or kind (lists, strings, None, complex, objects, empty arrays),
NaN, inf, huge and tiny numbers.  And all the numbers at once of extreme magnitudes that
pass the checks (ys of 1e300, P0 of 1e-300, ...), which exercise the numerics.  The
properties: a call returns finite results or raises a ``SymmonError``, never numpy's
``LinAlgError``, a ``ValueError``, ``TypeError``, ``OverflowError``, ``IndexError``, ...

The models are compiled once per module (a few filter steps); the runs are derandomized
and use no example database, as in tests/test_fuzz.py.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.errors import SymmonError

FUZZ = dict(derandomize=True, database=None, deadline=None,
            suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

x1, x2, b = sp.symbols("x1 x2 b", real=True)
F_MODEL = sm.Model([x1, x2], [x1 + 0.1 * x2, x2], name="fuzz_cv")
H_MODEL = sm.Model([x1, x2], [sp.sqrt(x1**2 + x2**2), sp.atan2(x2, x1)], name="fuzz_rb", angles=[1])
HB_MODEL = sm.Model([x1, x2], [x1 + b, x2], params=[b], name="fuzz_bias")

#: Values of every kind but the right one.
HOSTILE = (None, "a", "1.0", "", b"x", 1j, True, [], [[]], [1, [2]], {}, {"a": 1}, object(), np.nan, np.inf,
           -np.inf, 1e308, -1e308, 1e-320, 0, -1, 10**400, np.array(["a"]), np.array([1 + 1j]), np.zeros(0),
           np.zeros((2, 0)), np.zeros((3, 3, 3)), np.float32(1.0), np.array([True, False]), np.ones((2, 2), dtype=object),
           np.full((2, 2), np.nan), np.full((2, 2), 1e308), -np.eye(2), np.array([[1.0, 2.0], [0.0, 1.0]]), range(3))
MAGNITUDES = (1.0, 0.0, -1.0, 1e-300, 1e-160, 1e154, 1e200, 1e300, -1e300)


def hostile_arrays() -> st.SearchStrategy:
    """Arrays of random shapes and kinds, and the values of HOSTILE."""
    shaped = st.builds(lambda shape, v, kind: _array(tuple(shape), v, kind),
                       st.lists(st.integers(0, 3), max_size=3), st.sampled_from(MAGNITUDES + (np.nan, np.inf)),
                       st.sampled_from(("fill", "eye", "list", "int", "complex", "str")))
    return st.one_of(st.sampled_from(HOSTILE), shaped)


def _array(shape, v, kind):
    a = np.full(shape, v)
    if kind == "eye" and len(shape) >= 2:
        a = np.broadcast_to(np.where(np.eye(shape[-2], shape[-1]) > 0, v, 0.0), shape).copy()
    return {"list": lambda: a.tolist(), "int": lambda: a.astype(int) if np.all(np.abs(a) < 2.0**62) else a,
            "complex": lambda: a + 1j, "str": lambda: a.astype(str)}.get(kind, lambda: a)()


def call(fn, *args, **kwargs):
    """``fn(...)``: its result, or None after a SymmonError; any other exception fails."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # warnings are not the property here (e.g. AngleWarning)
        try:
            out = fn(*args, **kwargs)
        except SymmonError as exc:
            event(type(exc).__name__)
            return None
    event("accepted")
    return out


def assert_finite(res) -> None:
    for k in ("x", "P", "loglik", "x_pred", "P_pred", "innovation", "S"):
        v = getattr(res, k, None)
        if v is not None:
            assert np.all(np.isfinite(v)), k


@pytest.fixture(scope="module")
def filters():
    return {"ekf": sm.NonlinearKalmanFilter(F_MODEL, H_MODEL, 0.01 * np.eye(2), np.diag([0.1, 0.01]), sm.TT1()),
            "ukf": sm.NonlinearKalmanFilter(F_MODEL, H_MODEL, 0.01 * np.eye(2), np.diag([0.1, 0.01]), sm.UT.ut1()),
            "bias": sm.NonlinearKalmanFilter(F_MODEL, HB_MODEL, 0.01 * np.eye(2), 0.1 * np.eye(2), sm.TT1())}


def _valid(kf) -> dict:
    runs, K = 2, 4
    ys = np.tile(np.array([5.0, 0.3]), (runs, K, 1))
    return {"ys": ys, "x0": np.array([4.0, 1.0]), "P0": np.eye(2)}


# --------------------------------------------------------------------------- construction
CONSTRUCTION = ("f_model", "h_model", "Q", "R", "transform", "iterations")


@settings(max_examples=60, **FUZZ)
@given(which=st.sampled_from(CONSTRUCTION), value=st.one_of(hostile_arrays(), st.sampled_from(
    ("nonsense", 3, sm.MonteCarlo(100, seed=0), sm.Exact(), 0, 21, 1.5, "2", np.int64(2)))))
def test_making_a_filter_with_one_bad_argument(which, value):
    args = {"f_model": F_MODEL, "h_model": H_MODEL, "Q": 0.01 * np.eye(2), "R": np.diag([0.1, 0.01]),
            "transform": sm.TT1(), "iterations": 1}
    args[which] = value
    call(sm.NonlinearKalmanFilter, **args)


@settings(max_examples=50, **FUZZ)
@given(which=st.sampled_from(("F", "Q", "H", "R")), value=hostile_arrays())
def test_making_a_linear_filter_with_one_bad_argument(which, value):
    args = {"F": np.eye(2), "Q": 0.1 * np.eye(2), "H": np.eye(2), "R": np.eye(2)}
    args[which] = value
    call(sm.KalmanFilter, **args)


# --------------------------------------------------------------------------- calls
CALL_ARGS = ("ys", "x0", "P0", "keep", "params")
KEEPS = (None, ("x",), "x", ("zz",), [1], (), ("nis",), {"x": 1}, 3)
PARAMS = (None, {}, {"b": 1.0}, {"b": "a"}, {"b": np.nan}, {"b": np.ones(4)}, {"b": np.ones(3)}, {"c": 1.0},
          [1], {"b": None}, {1: 2.0}, {"b": 10**400}, {"b": 1j}, "b")


@settings(max_examples=120, **FUZZ)
@given(name=st.sampled_from(("ekf", "ukf", "bias")), method=st.sampled_from(("filter", "smooth")),
       which=st.sampled_from(CALL_ARGS), data=st.data())
def test_filter_and_smooth_with_one_bad_argument(filters, name, method, which, data):
    kf = filters[name]
    args = _valid(kf)
    kwargs = {"params": {"b": 0.0}} if name == "bias" else {}
    if which == "keep":
        kwargs["keep"] = data.draw(st.sampled_from(KEEPS))
    elif which == "params":
        kwargs["params"] = data.draw(st.sampled_from(PARAMS))
    else:
        args[which] = data.draw(hostile_arrays())
    res = call(getattr(kf, method), args["ys"], args["x0"], args["P0"], **kwargs)
    if res is not None:
        assert_finite(res)
        if method == "filter" and res.x is not None and res.P is not None:
            call(res.anees, np.zeros(res.x.shape))
            call(res.nees, data.draw(hostile_arrays()))


@settings(max_examples=60, **FUZZ)
@given(which=st.sampled_from(("start", "params", "bounds", "max_iter")), data=st.data())
def test_fit_with_one_bad_argument(filters, which, data):
    kf = filters["bias"]
    args = {"start": {"b": 0.0}, "params": None, "bounds": None, "max_iter": 20}
    args[which] = data.draw({
        "start": st.sampled_from(({}, {"b": "a"}, {"b": np.nan}, {"c": 1.0}, None, [1], {"b": 1e308},
                                  {"b": 10**400}, {"b": None}, {"b": 1j}, {"b": [1.0, 2.0]}, "b")),
        "params": st.sampled_from(PARAMS),
        "bounds": st.sampled_from(({"b": (0, 1)}, {"b": (1, 0)}, {"b": "a"}, {"b": (None, None)}, {"b": (np.nan, 1)},
                                   {"c": (0, 1)}, [1], {"b": (0, 1, 2)}, {"b": 1.0}, {"b": ("a", 1)}, "b",
                                   {"b": (-1, 10**400)})),
        "max_iter": st.sampled_from((0, -1, 1, 1.5, "a", None, 10**30, True, np.nan))}[which])
    v = _valid(kf)
    res = call(kf.fit, v["ys"], v["x0"], args["start"], v["P0"], params=args["params"], bounds=args["bounds"],
               max_iter=args["max_iter"])
    if res is not None:
        assert all(np.isfinite(list(res.estimates.values())))


LINEAR_CALLS = ("ys", "x0", "P0", "K", "rng", "runs")


@settings(max_examples=60, **FUZZ)
@given(which=st.sampled_from(LINEAR_CALLS), data=st.data())
def test_linear_filter_and_simulate_with_one_bad_argument(which, data):
    kf = sm.KalmanFilter(np.eye(2), 0.1 * np.eye(2), np.eye(2), np.eye(2))
    if which in ("ys", "x0", "P0"):
        args = {"ys": np.ones((2, 4, 2)), "x0": np.zeros(2), "P0": np.eye(2)}
        args[which] = data.draw(hostile_arrays())
        res = call(kf.filter, args["ys"], args["x0"], args["P0"])
        if res is not None:
            assert_finite(res)
        return
    args = {"K": 4, "rng": np.random.default_rng(0), "runs": 2}
    args[which] = data.draw(st.sampled_from((0, -1, 1.5, "3", None, 10**12, 10**400, True, np.int64(3), np.nan,
                                             0, np.random.RandomState(0), [1])))
    out = call(kf.simulate, args["K"], np.zeros(2), args["rng"], runs=args["runs"])
    if out is not None:
        assert all(np.all(np.isfinite(a)) for a in out)


# --------------------------------------------------------------------------- numerics
@settings(max_examples=60, **FUZZ)
@given(name=st.sampled_from(("ekf", "ukf", "linear")), y=st.sampled_from(MAGNITUDES), x=st.sampled_from(MAGNITUDES),
       p=st.sampled_from(MAGNITUDES[:-2]), q=st.sampled_from((0.0, 1e-300, 1e-12, 1.0, 1e150, 1e300)),
       method=st.sampled_from(("filter", "smooth")))
def test_extreme_magnitudes_give_finite_results_or_a_symmon_error(filters, name, y, x, p, q, method):
    """Numbers that pass every check, at the edges of double precision."""
    P0 = abs(p) * np.eye(2) if p else np.zeros((2, 2))
    ys = np.full((2, 4, 2), y)
    if name == "linear":
        kf = call(sm.KalmanFilter, [[1.0, 0.1], [0.0, 1.0]], q * np.eye(2), np.eye(2), np.eye(2))
        res = None if kf is None else call(kf.filter, ys, np.full(2, x), P0)
    else:
        kf = call(sm.NonlinearKalmanFilter, F_MODEL, H_MODEL, q * np.eye(2), np.diag([0.1, 0.01]),
                  filters[name].transform)
        res = None if kf is None else call(getattr(kf, method), ys, np.full(2, x), P0)
    if res is not None:
        assert_finite(res)
        fwd = getattr(res, "filtered", res)
        call(fwd.nis)
        call(fwd.nees, np.zeros(fwd.x.shape))
