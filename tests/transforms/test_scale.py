"""TT2 on larger models: the sparse evaluation equals the dense formula, and code stays small.

The TT2 second-order terms are computed from the compiled structural nonzeros of the
Hessians, either from the blocks H_i[S_i, S_i] or from the dense H_i P
(:func:`symmon.transforms.taylor.second_order_terms`).  Both are checked against the dense
formula of Gustafsson & Hendeby (2012) on random sparse and dense models, and TT2 against
the closed-form Gaussian moments of quadratic functions.  These are correctness and
code-size tests; the timings are in ``benchmarks/scale.py``, and export_c at scale is in
tests/codegen/test_codegen_scale.py.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile import CompiledModel
from symmon.compile import compiled
from symmon.transforms.taylor import second_order_terms

from helpers import random_gaussian, sparse_ring

#: Both evaluations sum the same products in a different order: rounding only.
SUM_RTOL = 1e-12
#: Closed forms against TT2: rounding of sums of O(n²) terms.
CLOSED_RTOL = 1e-10


def random_model(n: int, n_y: int, dense: bool, rng: np.random.Generator) -> tuple[list[sp.Expr], tuple]:
    """Random smooth outputs of 2–3 inputs each (sparse) or of all inputs (dense)."""
    x = sp.symbols(f"x0:{n}", real=True)
    out = []
    for _ in range(n_y):
        idx = range(n) if dense else rng.choice(n, size=int(rng.integers(2, 4)), replace=False)
        c = [sp.Float(v) for v in rng.normal(size=len(idx))]
        lin = sum(ci * x[i] for ci, i in zip(c, idx))
        sq = sum(ci**2 * x[i] ** 2 for ci, i in zip(c, idx))
        out.append(sp.sqrt(1 + sq) + sp.sin(lin) + x[idx[0]] * x[idx[-1]])
    return out, x


def _dense_reference(cm: CompiledModel, m: np.ndarray, P: np.ndarray):
    """TT2 by the dense formula: y + ½ tr(H_i P), J P Jᵀ + ½ tr(H_i P H_j P), J P."""
    y, J, H = (a[0] for a in cm.eval_gjh(m[None]))
    HP = np.einsum("iab,bc->iac", H, P)
    mean = y + 0.5 * np.einsum("iaa->i", HP)
    cov = J @ P @ J.T + 0.5 * np.einsum("iab,jba->ij", HP, HP)
    return mean, cov, J @ P


@pytest.mark.parametrize("dense", [False, True], ids=["sparse", "dense"])
@pytest.mark.parametrize("n", [6, 9, 12])
def test_both_evaluations_equal_the_dense_formula(n, dense):
    rng = np.random.default_rng(100 * n + dense)
    exprs, x = random_model(n, n_y=n // 2 + 1, dense=dense, rng=rng)
    cm = CompiledModel(exprs, x, name=f"rand{n}{dense}", compiled=False)
    m, P = random_gaussian(n, rng)
    mean, cov, _ = _dense_reference(cm, m, P)
    y = cm.eval_g(m[None])[0]
    H_nz = cm.eval_derivatives(m[None])[2]
    for method in ("blocks", "dense"):
        half_tr, half_tr2 = second_order_terms(cm, H_nz, P[None], method=method)
        np.testing.assert_allclose(y + half_tr[0], mean, rtol=SUM_RTOL, atol=SUM_RTOL * np.abs(mean).max())
        J = cm.eval_gjh(m[None])[1][0]
        np.testing.assert_allclose(J @ P @ J.T + half_tr2[0], cov, rtol=SUM_RTOL, atol=SUM_RTOL * np.abs(cov).max())


def test_sparse_hessians_are_stored_as_blocks():
    cm = compiled(sparse_ring(12))
    # Each H_i lives on {x_i, x_{i+1}, x_{i+2}}: 3 × 3 blocks, lower triangles only.
    assert cm.hess_support.shape == (12, 3)
    assert len(cm.hess_index[0]) <= 12 * 6
    np.testing.assert_array_equal(cm.hess_support[0], [0, 1, 2])


def test_unknown_method_is_rejected():
    cm = compiled(sparse_ring(6))
    with pytest.raises(sm.errors.SymmonError, match="method must be"):
        second_order_terms(cm, np.zeros((1, len(cm.hess_index[0]))), np.eye(6)[None], method="qr")


@pytest.mark.parametrize("dense", [False, True], ids=["sparse", "dense"])
def test_tt2_is_exact_for_quadratic_g(dense):
    """y_i = xᵀA_i x + b_iᵀx: E y_i = m'A_i m + tr(A_i P) + b_i'm,
    Cov(y_i, y_j) = d_iᵀ P d_j + 2 tr(A_i P A_j P) with d_i = 2 A_i m + b_i, Cov(y, x) = D P."""
    n, n_y = 10, 5
    rng = np.random.default_rng(7 + dense)
    x = sp.symbols(f"x0:{n}", real=True)
    A, b = [], rng.normal(size=(n_y, n))
    for _ in range(n_y):
        M = rng.normal(size=(n, n))
        if not dense:  # supported on 3 inputs
            keep = np.zeros(n, bool)
            keep[rng.choice(n, 3, replace=False)] = True
            M = M * np.outer(keep, keep)
        A.append((M + M.T) / 2)
    xs = sp.Matrix(x)
    exprs = [sp.expand((xs.T * sp.Matrix(Ai) * xs)[0] + (sp.Matrix(bi).T * xs)[0]) for Ai, bi in zip(A, b)]
    model = sm.Model(list(x), exprs, name=f"quad{dense}")
    m, P = random_gaussian(n, rng)
    got = sm.propagate(model, sm.Gaussian(m, P), transform=sm.TT2())
    D = np.array([2 * Ai @ m + bi for Ai, bi in zip(A, b)])
    mean = np.array([m @ Ai @ m + np.trace(Ai @ P) + bi @ m for Ai, bi in zip(A, b)])
    cov = D @ P @ D.T + 2 * np.array([[np.trace(Ai @ P @ Aj @ P) for Aj in A] for Ai in A])
    np.testing.assert_allclose(got.mean, mean, rtol=CLOSED_RTOL)
    np.testing.assert_allclose(got.cov, cov, rtol=CLOSED_RTOL)
    np.testing.assert_allclose(got.cross_cov, D @ P, rtol=CLOSED_RTOL, atol=CLOSED_RTOL * np.abs(D @ P).max())


def _c_size(f: ca.Function) -> int:
    gen = ca.CodeGenerator(f.name() + ".c", {"with_header": False})
    gen.add(f)
    return len(gen.dump())


def test_generated_code_grows_with_the_nonzeros():
    """The derivative function of the ring model has O(n) nonzeros: doubling n at most
    doubles its C (3× leaves room for the fixed part); the dense n_y·n² layout grew 8×."""
    sizes = {n: _c_size(compiled(sparse_ring(n)).derivs) for n in (16, 32)}
    assert sizes[32] < 3 * sizes[16], sizes


def test_tt2_at_n40_equals_the_dense_formula():
    n = 40
    model = sparse_ring(n)
    rng = np.random.default_rng(40)
    m, P = random_gaussian(n, rng)
    got = sm.propagate(model, sm.Gaussian(m, P), transform=sm.TT2())
    mean, cov, cross = _dense_reference(compiled(model), m, P)
    np.testing.assert_allclose(got.mean, mean, rtol=SUM_RTOL)
    np.testing.assert_allclose(got.cov, cov, rtol=SUM_RTOL, atol=SUM_RTOL * np.abs(cov).max())
    np.testing.assert_allclose(got.cross_cov, cross, rtol=SUM_RTOL, atol=SUM_RTOL * np.abs(cross).max())
