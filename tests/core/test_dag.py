"""symmon.core.dag: walks of expression DAGs, each distinct node once, without recursion (issue 26)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.core import dag

from helpers import ROOT

x, y = sp.symbols("x y", real=True)


def _iterated(n: int, start: sp.Expr = x) -> sp.Expr:
    """y = sin(y) + cos(y), n times: n·3 + 1 distinct nodes, a tree of about 2ⁿ⁺².

    Unevaluated: sympy's evaluation asks ``is_number`` of the argument, a recursion as
    deep as the expression (the tracer runs with the stack for it, tests/core/test_tracing.py).
    """
    e = start
    for _ in range(n):
        e = sp.Add(sp.sin(e, evaluate=False), sp.cos(e, evaluate=False), evaluate=False)
    return e


def test_postorder_visits_each_distinct_node_once_children_first():
    e = _iterated(40)
    nodes = dag.postorder([e, e])
    assert len(nodes) == len({id(n) for n in nodes}) == 3 * 40 + 1
    place = {id(n): i for i, n in enumerate(nodes)}
    assert all(place[id(a)] < place[id(n)] for n in nodes for a in n.args)
    assert nodes[-1] is e


def test_measure_counts_the_tree_without_walking_it():
    distinct, tree, depth = dag.measure([_iterated(60)])
    assert distinct == 181 and depth == 2 * 60 + 1
    assert tree == 4 * 2**60 - 3  # t(n) = 2 t(n-1) + 3, t(0) = 1: exact, in integers


def test_free_symbols_and_contains_match_sympy_on_small_and_on_deep_expressions():
    small = sp.Piecewise((x, y > 0), (sp.atan2(y, x), True)) + sp.Integral(x * y, (x, 0, 1))
    assert dag.free_symbols(small) == small.free_symbols == {x, y}
    assert dag.contains(small, sp.atan2) and not dag.contains(small, sp.cos)
    deep = _iterated(300, x + y)  # sympy's own walks: 2³⁰⁰ nodes, or a RecursionError
    assert dag.free_symbols(deep) == {x, y}
    assert dag.contains(deep, sp.cos) and not dag.contains(deep, sp.atan2)


def test_canonical_numbers_equal_nodes_built_twice_alike():
    a = x + 1
    b, c = sp.Add(*a.args, evaluate=False), x + 2
    canon = dag.Canonical()
    canon.add(dag.postorder([a, b, c]))
    assert a is not b and canon.classes[id(a)] == canon.classes[id(b)] != canon.classes[id(c)]


@pytest.mark.parametrize("a, b", [
    ([x + 1], [y + 1]),                                   # a symbol
    ([x + 1], [sp.Symbol("x", positive=True) + 1]),        # its assumptions
    ([x + sp.Float(0.1)], [x + sp.Rational(1, 10)]),      # a Float is not its decimal
    ([x + sp.Float(0.1)], [x + sp.Float(0.1 + 2**-56)]),  # the last bit of a Float
    ([x, y], [y, x]),                                     # the order of the outputs
    ([sp.Tuple(x), sp.Tuple()], [sp.Tuple(), sp.Tuple(x)]),  # which group a symbol is in
])
def test_the_digest_tells_different_expressions_apart(a, b):
    assert dag.digest(a) != dag.digest(b)


def test_the_digest_of_equal_expressions_is_equal():
    assert dag.digest([x + 1, sp.sin(y)]) == dag.digest([1 + x, sp.sin(y)])
    assert dag.digest([_iterated(200)]) == dag.digest([_iterated(200)])


_KEY_SCRIPT = """
import sys; sys.path.insert(0, {root!r})
import numpy as np, symmon as sm
def fx(x):
    y = x
    for _ in range(30):
        y = np.sin(y) + np.cos(y)
    return np.array([y[0] + 0.1, y[1] * 2.5])
m = sm.Model.from_function(fx, inputs=["a", "b"], angles=[1])
from symmon.compile import model_key
print(m.key, model_key(m.outputs, m.inputs))
"""


def test_the_keys_are_the_same_in_two_fresh_processes():
    """Stable across processes (no salted hash()), and cheap on a 30-fold DAG (a tree of ~2³¹)."""
    runs = [subprocess.run([sys.executable, "-c", _KEY_SCRIPT.format(root=str(ROOT))], capture_output=True,
                           text=True, timeout=120, check=True).stdout.split() for _ in range(2)]
    assert runs[0] == runs[1] and len(runs[0]) == 2 and all(len(k) == 64 for k in runs[0])


def test_the_model_key_tells_models_apart():
    a, b, v = sp.symbols("a b v", real=True)
    base = sm.Model([a, b], [a + b, sp.atan2(b, a)], angles=[1])
    others = [
        sm.Model([a, b], [a + b, sp.atan2(b, a)]),                       # the angle declaration
        sm.Model([a, b], [sp.atan2(b, a), a + b], angles=[0]),           # the order of the outputs
        sm.Model([a, b], [a + b + sp.Rational(1, 10), sp.atan2(b, a)], angles=[1]),  # a constant
        sm.Model([b, a], [a + b, sp.atan2(b, a)], angles=[1]),           # the order of the inputs
        sm.Model([a], [a + b, sp.atan2(b, a)], noise=[b], angles=[1]),   # input or noise
    ]
    keys = {m.key for m in [base, *others]}
    assert len(keys) == 1 + len(others)
    assert sm.Model([a, b], [b + a, sp.atan2(b, a)], angles=[1]).key == base.key


def test_bounded_str_summarises_a_tree_too_large_to_print():
    assert dag.bounded_str(x + 1) == "x + 1"
    text = dag.bounded_str(_iterated(100))
    assert text.startswith("<Add of 301 distinct subexpressions, a tree of ") and len(text) < 100


def test_a_model_of_a_deep_dag_is_built_printed_and_classified():
    """Model construction walks the DAG (free symbols, the noise structure, repr) instead
    of sympy's tree walks: 2³⁰⁰ nodes as a tree."""
    a, b, v = sp.symbols("a b v", real=True)
    deep = _iterated(300, a + b)
    m = sm.Model([a, b], [deep + 2 * v, deep], noise=[v])
    assert m.structure == "additive" and m.pi == sp.Matrix([[2], [0]]) and m.f[1] is deep
    assert "distinct subexpressions" in repr(m) and len(repr(m)) < 400
    assert "distinct subexpressions" in m._repr_latex_()
    assert sm.Model([a, b], [deep * v], noise=[v]).structure == "general"
    with pytest.raises(sm.errors.ModelError, match="uses unknown symbols"):
        sm.Model([a], [deep])
    np.testing.assert_array_equal(sorted(dag.free_symbols(m.outputs), key=str), [a, b, v])
