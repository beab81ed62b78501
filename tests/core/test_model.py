"""Model: symbol validation and the noise structure (Straka & Havlík 2024, eqs. (1), (3), (4))."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ModelError

from helpers import ROOT

x, y, z = sp.symbols("x y z", real=True)
v1, v2 = sp.symbols("v1 v2", real=True)


def _zero(expr) -> bool:
    return sp.simplify(expr) == 0


# --------------------------------------------------------------------------- structure
def test_noise_free_model_has_structure_none_and_an_empty_noise_part():
    m = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)])
    assert m.structure == "none"
    assert "structure='none'" in repr(m)
    assert m.f == sp.Matrix([sp.sqrt(x**2 + y**2), sp.atan2(y, x)])
    assert m.pi.shape == (2, 0)
    assert m.gamma.shape == (0, 1)


def test_additive_identity_noise():
    m = sm.Model([x, y], [x * y + v1, sp.sin(x) + v2], noise=[v1, v2])
    assert m.structure == "additive"
    assert m.f == sp.Matrix([x * y, sp.sin(x)])
    assert m.pi == sp.eye(2)
    assert m.gamma == sp.Matrix([v1, v2])


def test_additive_with_constant_matrix_b():
    m = sm.Model([x, y], [x**2 + 2 * v1 - v2, y + 3 * v2], noise=[v1, v2])
    assert m.structure == "additive"
    assert m.f == sp.Matrix([x**2, y])
    assert m.pi == sp.Matrix([[2, -1], [0, 3]])
    # g = f + B v is reconstructed exactly.
    assert all(_zero(e) for e in (m.f + m.pi * m.gamma - sp.Matrix(m.outputs)))


def test_multiplicative_structure():
    # g = f(u) + π(u) γ(v) with f = [x y, x], π = [[x², 0], [0, exp(y)]], γ = [v1, v2²]
    g = [x * y + x**2 * v1, x + sp.exp(y) * v2**2]
    m = sm.Model([x, y], g, noise=[v1, v2])
    assert m.structure == "multiplicative"
    assert m.f == sp.Matrix([x * y, x])
    assert set(m.gamma) == {v1, v2**2}
    # The columns of π follow the order of γ.
    assert all(_zero(e) for e in (m.f + m.pi * m.gamma - sp.Matrix(g)))
    k1 = list(m.gamma).index(v1)
    assert m.pi[0, k1] == x**2 and m.pi[1, k1] == 0


def test_multiplicative_merges_gamma_and_minus_gamma():
    g = [x * v1 - y * v1]
    m = sm.Model([x, y], g, noise=[v1])
    assert m.structure == "multiplicative"
    assert m.gamma == sp.Matrix([v1])
    assert _zero(m.pi[0, 0] - (x - y))
    assert m.f == sp.Matrix([0])


@pytest.mark.parametrize(
    "g",
    [
        [sp.sin(x * v1)],
        [x / (x + v1)],
        [sp.sqrt(x**2 + v1)],
        [x + v1, sp.exp(x * v2)],
    ],
    ids=["sin(x v)", "x/(x+v)", "sqrt(x^2+v)", "exp(x v2)"],
)
def test_general_structure(g):
    m = sm.Model([x], g, noise=[v1, v2])
    assert m.structure == "general"
    with pytest.raises(ModelError, match="general"):
        _ = m.f
    with pytest.raises(ModelError, match="general"):
        _ = m.pi
    with pytest.raises(ModelError, match="general"):
        _ = m.gamma


def _separable_form_equals_g(m: sm.Model, rng) -> bool:
    """f + π γ = g at random points (exact rationals): the form is an identity, not an approximation."""
    g = sp.Matrix(m.outputs)
    form = m.f + m.pi * m.gamma
    for _ in range(3):
        point = {s: sp.Rational(int(rng.integers(1, 9)), int(rng.integers(1, 5))) for s in m.inputs + m.noise}
        if any(sp.nsimplify(a.xreplace(point) - b.xreplace(point)) != 0 for a, b in zip(g, form)):
            return False
    return True


@pytest.mark.parametrize(
    ("g", "n_gamma"),
    [
        ((x + y + v1) ** 5, 5),                       # v1, …, v1⁵
        (sp.exp(x + v1) * y, 1),                      # exp(x) y · exp(v1)
        (2 ** (x - v1) + x, 1),                       # 2^x · 2^(−v1)
        ((x * v1 + y) ** 3 * sp.sin(x), 3),
        ((x + v1) ** 2 - v1**2, 1),                   # the v1² terms cancel: γ = [v1]
        ((x + v1) * (y + v2) * (1 + v1 * v2), 4),    # the v-only factor 1 + v1 v2 is kept whole
        (sp.sqrt(x) * (v1 + v2) ** 2, 1),             # a u-free factor stays one γ
    ],
)
def test_multiplicative_forms_are_read_off_without_expanding(rng, g, n_gamma):
    m = sm.Model([x, y], [g, x * y], noise=[v1, v2])
    assert m.structure == "multiplicative"
    assert m.gamma.shape[0] == n_gamma
    assert _separable_form_equals_g(m, rng)
    assert "without expanding" in m.structure_note


@pytest.mark.parametrize(
    ("g", "note"),
    [
        (sp.sin(x * v1), "sin(v1*x) mixes u and v"),
        (x / (x + v1), r"1/(v1 + x) mixes u and v"),
        (x**v1, "x**v1 mixes u and v"),
        ((x + v1) ** 5000, "more than 2000 terms"),
    ],
)
def test_general_structure_says_why(g, note):
    m = sm.Model([x], [g], noise=[v1])
    assert m.structure == "general"
    assert note in m.structure_note


def test_additive_and_noise_free_notes():
    assert sm.Model([x], [x**2]).structure_note == "no noise symbols"
    assert "constant" in sm.Model([x], [x**2 + 3 * v1], noise=[v1]).structure_note


def test_large_power_is_classified_and_measured_quickly(tmp_path):
    """(a+b+c+d+f+g+h+v)⁶⁴: 65 terms in γ = v^k, not the C(71, 7) ≈ 10⁹ of a full expansion.

    Run in a subprocess so that a regression (a multinomial expansion) hangs only it; the
    timeout is generous (no timing assertion: the first run also compiles C code).
    """
    code = textwrap.dedent("""
        import numpy as np, sympy as sp, symmon as sm
        a, b, c, d, f, g, h, v = sp.symbols("a b c d f g h v", real=True)
        m = sm.Model([a, b, c, d, f, g, h], [(a + b + c + d + f + g + h + v) ** 64], noise=[v])
        print(m.structure, m.gamma.shape[0], m.gamma[0] == v**64)
        u = sm.Gaussian(np.full(7, 1 / 7), 1e-4 * np.eye(7))
        r = sm.nonlinearity(m, u, sm.Gaussian([0.0], [[1e-4]]), transform=sm.TT2())
        print(0.0 < float(r) < 1.0)
    """)
    env = {**os.environ, "SYMMON_CACHE": str(tmp_path), "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, env=env, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["multiplicative", "64", "True", "True"]


def test_noise_free_drops_noise_and_keeps_angles():
    m = sm.Model([x, y], [x + v1, sp.atan2(y, x) + v2], noise=[v1, v2], angles=[1])
    nf = m.noise_free()
    assert nf.noise == () and nf.outputs == (x, sp.atan2(y, x))
    assert nf.angle_outputs == frozenset({1})


# --------------------------------------------------------------------------- symbols
def test_unknown_symbol_is_named():
    with pytest.raises(ModelError, match=r"output 0 .* unknown symbols \['z'\]"):
        sm.Model([x, y], [x + z])


def test_noise_symbol_not_declared_is_unknown():
    with pytest.raises(ModelError, match=r"unknown symbols \['v1'\]"):
        sm.Model([x], [x + v1])


@pytest.mark.parametrize(
    ("inputs", "noise", "match"),
    [
        ([x, x], None, r"duplicate symbols in inputs: \['x'\]"),
        ([x], [v1, v1], r"duplicate symbols in noise: \['v1'\]"),
        ([x, v1], [v1], r"both as inputs and noise: \['v1'\]"),
        ([], None, "at least one input"),
        ([x + 1], None, "inputs must be sympy Symbols"),
    ],
)
def test_bad_symbol_declarations(inputs, noise, match):
    with pytest.raises(ModelError, match=match):
        sm.Model(inputs, [x], noise=noise)


def test_no_outputs_is_rejected():
    with pytest.raises(ModelError, match="at least one output"):
        sm.Model([x], [])


@pytest.mark.parametrize("out", ["x**2", ["x + 1"], "__import__('os')"])
def test_string_outputs_are_rejected(out):
    with pytest.raises(ModelError, match="not strings"):
        sm.Model([x], out)


# --------------------------------------------------------------------------- angles
def test_angles_by_output_index_and_input_symbol():
    m = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], angles=[1, y])
    assert m.angle_outputs == frozenset({1})
    assert m.angle_inputs == frozenset({1})


@pytest.mark.parametrize(
    ("angles", "match"),
    [([2], "out of range"), ([-1], "out of range"), ([z], "angles must be output indices or input symbols"), (["x"], "angles must be")],
)
def test_bad_angles(angles, match):
    with pytest.raises(ModelError, match=match):
        sm.Model([x, y], [x, y], angles=angles)


def test_model_errors_are_value_errors():
    with pytest.raises(ValueError):
        sm.Model([x], [x + z])


def test_equality_and_hash():
    a = sm.Model([x], [x**2])
    b = sm.Model([x], [x**2])
    assert a == b and hash(a) == hash(b)
    assert a != sm.Model([x], [x**3])
