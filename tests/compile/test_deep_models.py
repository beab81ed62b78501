"""Traced loops: deep expression DAGs build, compile and evaluate (issue 26, items 4 and 5).

``x = x + 0.1·sin(x)`` 100 or 300 times and ``y = sin(y) + cos(y)`` 18 or 30 times share their
subexpressions: a few thousand distinct nodes, but a tree of up to 2³¹ nodes (sin + cos) and
hundreds of levels deep.  Each is traced, its model built and printed, compiled and evaluated
against NumPy running the same function on floats.
"""

from __future__ import annotations

import numpy as np
import pytest

import symmon as sm
from symmon.compile import CompiledModel, model_key
from symmon.core import dag

#: NumPy and CasADi evaluate the same operations in the same order but for the sums of
#: the loop, which CasADi adds in sympy's order: rounding, a few ulps of |x| per step.
LOOP_RTOL = 1e-10
POINT = np.array([0.3, 1.2])


def euler(x, n):
    for _ in range(n):
        x = x + 0.1 * np.sin(x)
    return x


def sincos(x, n):
    y = x
    for _ in range(n):
        y = np.sin(y) + np.cos(y)
    return y


def _compiled(fn, n):
    m = sm.Model.from_function(lambda x: fn(x, n), inputs=["a", "b"])
    return m, CompiledModel(m.outputs, m.inputs, name=f"deep_{fn.__name__}_{n}", compiled=False)


@pytest.mark.parametrize("fn, n", [(euler, 100), (euler, 300), (sincos, 18), (sincos, 30)])
def test_a_traced_loop_builds_and_evaluates_as_numpy(fn, n):
    m, cm = _compiled(fn, n)
    assert m.structure == "none" and len(repr(m)) < 400
    want = fn(POINT.copy(), n)
    np.testing.assert_allclose(cm.eval_g(POINT[None])[0], want, rtol=LOOP_RTOL)
    # The derivatives too: the chain rule through every step, against central differences
    # (their error ~ h²·g''' + ε/h at h = 1e-6: 1e-7 relative is what they can confirm).
    _, J, _ = cm.eval_gjh(POINT[None])
    h = 1e-6
    fd = np.column_stack([(fn(POINT + h * e, n) - fn(POINT - h * e, n)) / (2 * h) for e in np.eye(2)])
    np.testing.assert_allclose(J[0], fd, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("fn, per_step", [(euler, 6), (sincos, 6)])
def test_the_casadi_graph_grows_linearly_with_the_steps(fn, per_step):
    """Each distinct node is converted once, and a sum that sympy flattened reuses the sum of
    the step before: a few CasADi nodes per step and input (2 inputs), not the tree."""
    sizes = {n: _compiled(fn, n)[1].g.n_nodes() for n in (10, 20, 40)}
    assert sizes[40] - sizes[20] == 2 * (sizes[20] - sizes[10]) <= 2 * per_step * 20


def test_the_cache_key_visits_each_distinct_node_once(monkeypatch):
    m = sm.Model.from_function(lambda x: sincos(x, 30), inputs=["a", "b"])
    visited = []
    original = dag.postorder
    monkeypatch.setattr(dag, "postorder", lambda exprs, done=None: visited.extend(original(exprs, done)) or
                        visited[-len(original(exprs, done)):])
    key = model_key(m.outputs, m.inputs)
    assert len(key) == 64
    assert len(visited) == len({id(n) for n in visited}) <= 2 * (3 * 30 + 1) + 4  # 2 outputs, the tuples
    assert dag.measure(m.outputs)[1] > 2**31  # the tree the earlier key printed


def test_equal_traced_models_share_their_compiled_functions():
    a = sm.Model.from_function(lambda x: sincos(x, 18), inputs=["a", "b"])
    b = sm.Model.from_function(lambda x: sincos(x, 18), inputs=["a", "b"])
    c = sm.Model.from_function(lambda x: sincos(x, 19), inputs=["a", "b"])
    assert sm.compile.compiled(a) is sm.compile.compiled(b) is not sm.compile.compiled(c)
    assert model_key(a.outputs, a.inputs) == model_key(b.outputs, b.inputs) != model_key(b.outputs, b.inputs[::-1])
