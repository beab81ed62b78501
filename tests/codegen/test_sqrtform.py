"""The square-root building blocks (symmon.codegen.sqrtform): tria, the Cholesky downdate,
the gain and Joseph factors, in SX and MX."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from symmon.codegen.sqrtform import chol_downdate, gain_factor, residual_factor, tria

KINDS = [ca.SX, ca.MX]


def evaluate(kind, build, *shapes_and_values):
    syms = [kind.sym(f"a{i}", *shape) for i, (shape, _) in enumerate(shapes_and_values)]
    out = build(*syms)
    outs = list(out) if isinstance(out, tuple) else [out]
    f = ca.Function("f", syms, outs)
    res = f(*[v for _, v in shapes_and_values])
    return [np.array(r) for r in (res if isinstance(res, (list, tuple)) else [res])]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("n, m", [(1, 3), (4, 9), (6, 6), (5, 2)])
def test_tria_is_the_cholesky_factor_of_the_gram_matrix(kind, n, m):
    A = np.random.default_rng(n * 10 + m).standard_normal((n, m))
    (L,) = evaluate(kind, tria, ((n, m), A))
    assert np.all(np.triu(L, 1) == 0) and np.all(np.diag(L) >= 0)
    np.testing.assert_allclose(L @ L.T, A @ A.T, atol=1e-13)
    if m >= n:  # positive definite: the unique Cholesky factor
        np.testing.assert_allclose(L, np.linalg.cholesky(A @ A.T), atol=1e-13)


@pytest.mark.parametrize("kind", KINDS)
def test_tria_of_a_zero_row_is_a_factor_with_a_zero_row(kind):
    A = np.array([[1.0, 2, 0, 1], [0, 0, 0, 0], [3, 1, 1, 0]])
    (L,) = evaluate(kind, tria, ((3, 4), A))
    assert np.all(np.isfinite(L)) and np.all(L[1] == 0) and np.all(np.triu(L, 1) == 0)
    np.testing.assert_allclose(L @ L.T, A @ A.T, atol=1e-14)


@pytest.mark.parametrize("kind", KINDS)
def test_downdate_equals_the_factor_of_the_difference_and_is_nan_when_indefinite(kind):
    rng = np.random.default_rng(1)
    A = rng.standard_normal((5, 7))
    P = A @ A.T + np.eye(5)
    b = 0.5 * rng.standard_normal(5)
    (L,) = evaluate(kind, chol_downdate, ((5, 5), np.linalg.cholesky(P)), ((5, 1), b))
    np.testing.assert_allclose(L, np.linalg.cholesky(P - np.outer(b, b)), atol=1e-13)
    big = 3 * np.linalg.cholesky(P)[:, 0]  # P − b bᵀ indefinite
    (L,) = evaluate(kind, chol_downdate, ((5, 5), np.linalg.cholesky(P)), ((5, 1), big))
    assert np.isnan(L).any()


@pytest.mark.parametrize("kind", KINDS)
def test_gain_and_joseph_factor_equal_the_kalman_update(kind):
    """Joint columns of a linear measurement y = H x + e: Y = [H S, √R], X = [S, 0]."""
    rng = np.random.default_rng(2)
    n, ny = 4, 2
    S = np.linalg.cholesky(np.cov(rng.standard_normal((n, 20))))
    H, sR = rng.standard_normal((ny, n)), np.diag([0.3, 0.1])
    Y, X = np.hstack([H @ S, sR]), np.hstack([S, np.zeros((n, ny))])

    def build(Ys, Xs):
        Sy, Kbar, K = gain_factor(Ys, Xs)
        return Sy, K, residual_factor(Xs, Ys, K)

    Sy, K, Sp = evaluate(kind, build, ((ny, n + ny), Y), ((n, n + ny), X))
    P = S @ S.T
    Sc = H @ P @ H.T + sR @ sR.T
    K_ref = P @ H.T @ np.linalg.inv(Sc)
    np.testing.assert_allclose(Sy @ Sy.T, Sc, atol=1e-13)
    np.testing.assert_allclose(K, K_ref, atol=1e-12)
    np.testing.assert_allclose(Sp @ Sp.T, P - K_ref @ Sc @ K_ref.T, atol=1e-13)
    assert np.all(np.triu(Sp, 1) == 0) and np.all(np.diag(Sp) > 0)


@pytest.mark.parametrize("n, m", [(30, 70), (53, 60), (24, 24)])
def test_mx_tria_in_parts_equals_the_sx_tria_to_the_bit(n, m):
    """The MX tria runs its rows in parts of TRIA_PART, each a function of its own: the same
    operations in the same order as the SX tria (one sequence of reflections)."""
    A = np.random.default_rng(n + m).standard_normal((n, m))
    A[3] = 0  # a zero row: no reflection
    (Ls,) = evaluate(ca.SX, tria, ((n, m), A))
    (Lm,) = evaluate(ca.MX, tria, ((n, m), A))
    np.testing.assert_array_equal(Lm, Ls)
    np.testing.assert_allclose(Lm @ Lm.T, A @ A.T, atol=1e-12)


def test_a_large_mx_tria_is_c_of_small_functions():
    """A 64-row tria (a 64-state square-root UKF's time update) generates C whose largest
    function stays below SPLIT_FUNCTION_BYTES, so that a step holding it is built optimised
    (symmon.compile.ccache.background_level), where one function of its 64 reflections was
    too large for that."""
    from symmon.codegen.sqrtform import TRIA_PART
    from symmon.compile.ccache import SPLIT_FUNCTION_BYTES, largest_function_bytes
    from symmon.compile.compiled import generated_c

    A = ca.MX.sym("A", 64, 193)
    code = generated_c(ca.Function("big_tria", [A], [tria(A)]))
    assert TRIA_PART < 64 and largest_function_bytes(code) <= SPLIT_FUNCTION_BYTES
