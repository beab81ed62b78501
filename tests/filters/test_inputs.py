"""The checks of a filter call's inputs live in one module, below the filter (issue 38, item 19).

symmon.filters.inputs holds every check of ys, keep, the bank's size, x_true, x0/P0 and the
parameter values; the filter, its smoother and its fit delegate to :func:`check_call`, and no
module that the filter imports, directly or through others, imports the filter back. The filters
built on it (the particle and Gaussian-sum filters) may import it: it imports none of them.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentError, ModelError, ShapeError
from symmon.filters import inputs, results
from symmon.filters.inputs import FilterCall, check_call

FILTERS = Path(inputs.__file__).parent


def _path(module: str) -> Path:
    """The file of ``module``, a dotted name under symmon.filters (``gaussian.nonlinear``)."""
    return FILTERS.joinpath(*module.split(".")).with_suffix(".py")


def _imports(module: str) -> set[str]:
    """The modules of symmon.filters that ``module`` imports (relative, any scope, annotations
    too), as dotted names under symmon.filters."""
    package = module.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(_path(module).read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level and node.level <= len(package) + 1:
            base = package[: len(package) - node.level + 1]
            names = [node.module] if node.module else [a.name for a in node.names]
            found |= {".".join(base + n.split(".")) for n in names if _path(".".join(base + n.split("."))).exists()}
    return found


def _reached(module: str) -> set[str]:
    """The modules of symmon.filters that ``module`` imports, directly or through others."""
    seen, todo = set(), [module]
    while todo:
        for m in _imports(todo.pop()) - seen:
            seen.add(m)
            todo.append(m)
    return seen


def test_no_module_the_filter_imports_imports_it_back():
    reached = _reached("gaussian.nonlinear")
    # what the filter's methods delegate to
    assert {"gaussian.export", "gaussian.fit", "gaussian.strategy", "inputs"} <= reached
    assert "gaussian.nonlinear" not in reached
    back = sorted(m for m in reached if "gaussian.nonlinear" in _imports(m))
    assert back == []


def test_the_input_checks_import_no_other_filter_module():
    assert _imports("inputs") == set()


def test_results_hold_no_input_check():
    """The checks moved out of results.py: a filter call reads them from one module."""
    defined = {n.name for n in ast.parse(Path(results.__file__).read_text(encoding="utf-8")).body
               if isinstance(n, ast.FunctionDef)}
    assert not defined & {"check_keep", "real_measurements", "check_truth", "check_bank_size", "kept_numbers"}


@pytest.fixture(scope="module")
def kf():
    x, b = sp.symbols("x b")
    f = sm.Model([x], [x], params=[b], name="inputs_f")
    h = sm.Model([x], [x + b], params=[b], name="inputs_h")
    return sm.NonlinearKalmanFilter(f, h, [[0.1]], [[1.0]], sm.TT1())


def test_check_call_checks_and_shapes_a_call(kf):
    ys = np.array([[1.0], [np.nan], [2.0]])
    c = check_call(kf, ys, np.zeros(1), np.eye(1), keep=("x",), params={"b": [0.0, 1.0, 2.0]},
                   x_true=np.zeros((3, 1)))
    assert isinstance(c, FilterCall) and c.runs is None and c.Y.shape[1] == 3
    assert c.Y.shape == (1, 3, 1) and np.isnan(c.Y[0, 1, 0]) and c.keep == frozenset({"x"})
    assert c.truth.shape == (1, 3, 1) and c.pv[0, :, 0].tolist() == [0.0, 1.0, 2.0]
    bank = check_call(kf, np.ones((2, 3, 1)), np.zeros((2, 1)), np.eye(1), params={"b": 1.0})
    assert bank.runs == 2 and bank.x0.shape == (2, 1) and bank.pv.shape == (2, 3, 1)


@pytest.mark.parametrize("call, error, match", [
    (dict(ys=np.ones((3, 2))), ShapeError, r"ys must have shape \(K, 1\)"),
    (dict(ys=[[1.0], [np.inf]]), ShapeError, "ys contains inf"),
    (dict(keep="xP"), ArgumentError, r"keep names \['xP'\]"),
    (dict(params={}), ModelError, "missing"),
    (dict(x_true=np.zeros((2, 1))), ShapeError, "x_true must have the shape"),
])
def test_the_filter_raises_what_check_call_raises(kf, call, error, match):
    args = dict(ys=np.ones((3, 1)), keep=None, params={"b": 0.0}, x_true=None) | call
    with pytest.raises(error, match=match):
        check_call(kf, args["ys"], np.zeros(1), np.eye(1), keep=args["keep"], params=args["params"],
                   x_true=args["x_true"])
    with pytest.raises(error, match=match):
        kf.filter(args["ys"], np.zeros(1), np.eye(1), keep=args["keep"], params=args["params"], x_true=args["x_true"])


# ------------------------------------------------------------------ measurement times
def test_measurement_times_are_checked_and_give_their_intervals():
    t = inputs.measurement_times([1.0, 1.5, 4.0], t0=0.5, steps=3)
    np.testing.assert_array_equal(t, [1.0, 1.5, 4.0])
    np.testing.assert_array_equal(inputs.time_intervals(t, 0.5), [0.5, 0.5, 2.5])
    rows = inputs.measurement_times([[1.0, 2.0], [0.5, 3.0]], runs=2, steps=2)
    np.testing.assert_array_equal(inputs.time_intervals(rows, 0.0), [[1.0, 1.0], [0.5, 2.5]])


@pytest.mark.parametrize("times, kw, match", [
    ([1.0, 1.0], {}, r"strictly increasing: times\[1\] = 1 follows times\[0\] = 1"),
    ([[1.0, 2.0], [1.0, 0.5]], dict(runs=2), r"strictly increasing: times\[1, 1\] = 0.5 follows times\[1, 0\]"),
    ([[1.0, 2.0], [0.0, 0.5]], dict(runs=2), r"after t0 = 0 .*: times\[1, 0\] = 0"),
    ([1.0, np.inf], {}, r"finite: times\[1\] = inf"),
    ([1.0, 2.0], dict(steps=3), r"shape \(3,\); got shape \(2,\)"),
    ([[1.0, 2.0]], {}, r"1-D .*shape \(K,\); got shape \(1, 2\)"),
    ([[1.0, 2.0]], dict(runs=2), r"or one row of them per run, shape \(2, K\); got shape \(1, 2\)"),
    ([], {}, "non-empty"),
    ([1.0], dict(t0=True), "t0 must be a finite number"),
])
def test_bad_measurement_times_name_the_first_bad_index(times, kw, match):
    with pytest.raises(ArgumentError, match=match):
        inputs.measurement_times(times, **kw)


def test_a_call_keeps_its_times_and_a_shard_cuts_per_run_times():
    x = sp.Symbol("x", real=True)
    cd = sm.ContinuousDiscreteKalmanFilter(sm.SDE([x], [-x], diffusion=[1]), sm.Model([x], [x]), [[1.0]])
    ys, prior = np.zeros((3, 2, 1)), sm.Gaussian([0.0], [[1.0]])
    own = np.array([[1.0, 2.0], [0.5, 0.75], [3.0, 4.0]])
    call = inputs.check_call(cd, ys, prior, times=own, t0=0.25)
    assert call.t0 == 0.25
    np.testing.assert_array_equal(call.intervals, [[0.75, 1.0], [0.25, 0.25], [2.75, 1.0]])
    np.testing.assert_array_equal(call.pv[..., 0], call.intervals)  # the dt column
    part = call.shard(1, 3)
    np.testing.assert_array_equal(part.times, own[1:])
    np.testing.assert_array_equal(part.pv[..., 0], call.intervals[1:])
    shared = inputs.check_call(cd, ys, prior, times=[1.0, 2.0])
    assert shared.shard(1, 2).times is shared.times and shared.t0 == 0.0
    plain = inputs.check_call(cd, ys, prior, params={"dt": 1.0})
    assert plain.times is None and plain.intervals is None and plain.shard(0, 1).times is None
