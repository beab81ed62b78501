"""Appendix B: the complete set (41) of normalising weights.

Claim (41): with S_gbar_gbar = V Lambda V^T (V orthogonal, Lambda = diag(lambda_i) > 0),
every W_bar = V Y V^T with Y > 0, [Y]_ii = alpha_i / lambda_i, alpha_i > 0 and
sum_i alpha_i = 1 satisfies tr(W_bar S_gbar_gbar) = 1; conversely every W_bar > 0 with
tr(W_bar S_gbar_gbar) = 1 is of that form (alpha_i = lambda_i [V^T W_bar V]_ii).

Checked symbolically for n_y = 2 (V a rotation) and n_y = 3 (V from the Cayley transform
of a skew-symmetric matrix, so V is orthogonal for all parameter values); the converse
symbolically and on random matrices. Errata: Appendix B prints the condition as
"sum_{i=1}^{n_y} = 1", which lost its alpha_i; the script shows that the sum of the alpha_i
is exactly the trace, so without it the trace is not 1. Appendix B also allows
alpha_i >= 0, but Y > 0 forces [Y]_ii > 0, i.e. alpha_i > 0 as (41) says.
"""
from __future__ import annotations

import numpy as np
import sympy as sp

from _common import Checker, Result, is_zero, main, symmetric_matrix

NAME = "appendix_b"
TITLE = "Appendix B: W_bar = V Y V^T with [Y]_ii = alpha_i/lambda_i, sum alpha_i = 1 (41)"
SOURCE = "Straka & Havlik, FUSION 2024, eq. (41) and Appendix B"

SEED = 41
N_RANDOM = 100


def cayley(n: int) -> sp.Matrix:
    """A symbolic orthogonal matrix (I - K)(I + K)^-1, K skew-symmetric."""
    k = sp.symbols(f"k1:{n * (n - 1) // 2 + 1}", real=True)
    K = sp.zeros(n, n)
    idx = 0
    for i in range(n):
        for j in range(i + 1, n):
            K[i, j], K[j, i] = k[idx], -k[idx]
            idx += 1
    return (sp.eye(n) - K) * (sp.eye(n) + K).inv()


def trace_of_set_member(n: int, V: sp.Matrix, impose_sum: bool = True) -> sp.Expr:
    """tr(V Y V^T V Lambda V^T) for Y with [Y]_ii = alpha_i/lambda_i and free off-diagonals."""
    lam = sp.symbols(f"lambda1:{n + 1}", positive=True)
    alpha = list(sp.symbols(f"alpha1:{n + 1}", positive=True))
    if impose_sum:
        alpha[-1] = 1 - sum(alpha[:-1])
    Y = symmetric_matrix("y", n)
    for i in range(n):
        Y[i, i] = alpha[i] / lam[i]
    Sigma = V * sp.diag(*lam) * V.T
    return (V * Y * V.T * Sigma).trace()


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    th = sp.Symbol("theta", real=True)
    R = sp.Matrix([[sp.cos(th), -sp.sin(th)], [sp.sin(th), sp.cos(th)]])
    ck.claim("n_y = 2, V a rotation: tr(W_bar S_gbar_gbar) = 1", is_zero(trace_of_set_member(2, R) - 1))
    V3 = cayley(3)
    ck.claim("Cayley V is orthogonal (V^T V = I)", is_zero(V3.T * V3 - sp.eye(3)))
    ck.claim("n_y = 3, V orthogonal (Cayley): tr(W_bar S_gbar_gbar) = 1", is_zero(trace_of_set_member(3, V3) - 1))

    # Erratum: the lost alpha_i. Without sum alpha_i = 1 the trace is sum alpha_i, not 1.
    free = sp.simplify(trace_of_set_member(2, R, impose_sum=False))
    a1, a2 = sp.symbols("alpha1 alpha2", positive=True)
    ck.claim("without the constraint, tr(W_bar S_gbar_gbar) = alpha_1 + alpha_2 (so the sum must be of the alpha_i)",
             is_zero(free - (a1 + a2)))
    ck.tex(r"\operatorname{tr}(\bar W\Sigma_{\bar g\bar g}) = \operatorname{tr}(Y\Lambda) =", free)

    # Converse, symbolically: alpha_i := lambda_i [V^T W V]_ii sum to tr(W Sigma).
    Wb = symmetric_matrix("w", 2)
    lam = sp.symbols("lambda1:3", positive=True)
    Y = R.T * Wb * R
    alphas = [lam[i] * Y[i, i] for i in range(2)]
    ck.claim("converse: sum_i lambda_i [V^T W_bar V]_ii = tr(W_bar V Lambda V^T)",
             is_zero(sum(alphas) - (Wb * R * sp.diag(*lam) * R.T).trace()))

    # Converse, numerically: random W_bar > 0 normalised to trace 1 is in the set with alpha_i > 0.
    rng = np.random.default_rng(SEED)
    ok = True
    for _ in range(N_RANDOM):
        A = rng.standard_normal((3, 3))
        Sig = A @ A.T + 0.1 * np.eye(3)
        B = rng.standard_normal((3, 3))
        Wn = B @ B.T + 0.01 * np.eye(3)
        Wn /= np.trace(Wn @ Sig)
        lam_n, V = np.linalg.eigh(Sig)
        Yn = V.T @ Wn @ V
        al = lam_n * np.diag(Yn)
        ok &= bool(np.all(al > 0) and abs(al.sum() - 1) < 1e-12 and np.allclose(V @ Yn @ V.T, Wn, atol=1e-12)
                   and np.all(np.linalg.eigvalsh(Yn) > 0))
    ck.claim(f"converse on {N_RANDOM} random (S, W_bar): alpha_i > 0, sum alpha_i = 1, W_bar = V Y V^T, Y > 0", ok)

    # alpha_i = 0 is incompatible with Y > 0 (Appendix B's alpha_i >= 0 is too loose).
    y12 = sp.Symbol("y12", real=True)
    Yzero = sp.Matrix([[0, y12], [y12, 1]])
    ck.claim("alpha_1 = 0 makes [Y]_11 = 0, and det Y = -y12^2 <= 0: Y is never positive definite",
             is_zero(Yzero.det() + y12 ** 2))
    ck.tex(r"\bar W \in", r"\{V Y V^\top : Y \succ 0,\ [Y]_{ii} = \alpha_i/\lambda_i,\ \alpha_i > 0,\ \textstyle\sum_i \alpha_i = 1\}")
    return ck.result()


if __name__ == "__main__":
    main(check)
