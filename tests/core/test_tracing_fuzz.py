"""A hypothesis fuzz of traced functions (issue 26): random compositions of the supported
NumPy operations, traced by ``Model.from_function`` and evaluated (CasADi's VM, which the
compiled C matches to the bit), against the same function run by NumPy on numbers.

The compositions keep every operation inside its domain (sqrt and log of 1 + |a|, a
division by 1 + b²) and their values bounded (depth 3 from inputs in [-2, 2]), so NumPy's
result is finite; sympy may reorder or cancel terms (x − x is 0), which moves the value by
rounding of the largest intermediate (below 1e5): 1e-9 relative to max(1, |value|) leaves
four orders of magnitude for that.  Where a composition goes outside a domain, symmon must
not return a finite number where NumPy has none: a separate test feeds NaN and infinite
inputs.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.compile.compiled import CompiledModel

#: Rounding of reordered arithmetic on values below 1e5, relative to max(1, |y|).
FUZZ_RTOL = 1e-9
N_IN = 3

UNARY = {
    "sin": np.sin, "cos": np.cos, "tanh": np.tanh, "arctan": np.arctan, "abs": np.abs, "square": np.square,
    "negative": np.negative, "sqrt1": lambda a: np.sqrt(1 + np.abs(a)), "log1p": lambda a: np.log1p(np.abs(a)),
    "expm1": lambda a: np.expm1(np.tanh(a)), "exp": lambda a: np.exp(np.sin(a)),
}
BINARY = {
    "add": lambda a, b: a + b, "sub": lambda a, b: a - b, "mul": lambda a, b: a * b,
    "div": lambda a, b: a / (1 + b * b), "hypot": np.hypot, "maximum": np.maximum, "minimum": np.minimum,
    "fmax": np.fmax, "arctan2": np.arctan2, "where": lambda a, b: np.where(a > b, a - b, b * a),
}


def trees(depth: int):
    leaf = st.one_of(st.integers(0, N_IN - 1).map(lambda i: ("x", i)),
                     st.floats(-3, 3, allow_nan=False).map(lambda c: ("c", c)))
    if depth == 0:
        return leaf
    sub = trees(depth - 1)
    return st.one_of(leaf, st.tuples(st.sampled_from(sorted(UNARY)), sub),
                     st.tuples(st.sampled_from(sorted(BINARY)), sub, sub))


def run(tree, x):
    """The composition on x: traced values (a tracer's array) or numbers (a NumPy array)."""
    kind = tree[0]
    if kind == "x":
        return x[tree[1]]
    if kind == "c":
        return tree[1]
    if kind in UNARY:
        return UNARY[kind](run(tree[1], x))
    return BINARY[kind](run(tree[1], x), run(tree[2], x))


def evaluate(trees_, W: np.ndarray, name: str) -> np.ndarray:
    model = sm.Model.from_function(lambda x: np.array([run(t, x) + 0 * x[0] for t in trees_]),
                                   inputs=[f"u{i}" for i in range(N_IN)], name=name)
    cm = CompiledModel(list(model.outputs), list(model.inputs), name=name, compiled=False)
    return cm.eval_g(W)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(trees(3), min_size=1, max_size=3), st.lists(st.floats(-2, 2), min_size=3 * N_IN, max_size=3 * N_IN))
def test_traced_compositions_equal_numpy(compositions, values):
    W = np.array(values).reshape(3, N_IN)
    got = evaluate(compositions, W, "fuzz_traced")
    with np.errstate(all="ignore"):
        want = np.array([[run(t, w) for t in compositions] for w in W], dtype=float)
    assert np.all(np.isfinite(want))
    assert np.all(np.abs(got - want) <= FUZZ_RTOL * np.maximum(1.0, np.abs(want))), (compositions, got, want)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(trees(2), st.lists(st.sampled_from([np.nan, np.inf, -np.inf, 0.5, -1.5]), min_size=N_IN, max_size=N_IN))
def test_nan_and_inf_inputs_never_give_a_finite_number_where_numpy_has_none(composition, values):
    """A NaN input reaches the output as NaN (or an infinite one as inf or NaN) as in NumPy,
    unless sympy's algebra removed the input (x − x, 0·x), which NumPy cannot know: then
    the function does not depend on it and symmon's value is that of the function."""
    W = np.array([values])
    with np.errstate(all="ignore"):
        want = np.array([[run(composition, W[0])]], dtype=float)
    model = sm.Model.from_function(lambda x: np.array([run(composition, x) + 0 * x[0]]),
                                   inputs=[f"u{i}" for i in range(N_IN)], name="fuzz_nan")
    got = CompiledModel(list(model.outputs), list(model.inputs), name="fuzz_nan", compiled=False).eval_g(W)
    if np.isfinite(got).all() and not np.isfinite(want).all():
        used = {int(str(s)[1:]) for s in model.outputs[0].free_symbols}
        assert all(np.isfinite(W[0, i]) for i in used), (composition, values, got, want)
    elif np.isfinite(want).all():
        assert np.all(np.isfinite(got)) and np.allclose(got, want, rtol=FUZZ_RTOL, atol=FUZZ_RTOL)
    else:
        assert not np.isfinite(got).all()


def test_the_fuzz_compares_values_not_only_finiteness():
    """A known composition through the same path: a wrong operator would be caught."""
    tree = ("add", ("sin", ("x", 0)), ("hypot", ("x", 1), ("c", 2.0)))
    W = np.array([[0.3, -1.2, 0.0]])
    got = evaluate([tree], W, "fuzz_known")
    assert got[0, 0] == pytest.approx(np.sin(0.3) + np.hypot(-1.2, 2.0), rel=1e-15)
