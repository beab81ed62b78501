"""TT2: mean, covariance and cross-covariance of a second-order Taylor expansion.

For u ~ N(mu, P) with P = L L^T, write u = mu + L z with z ~ N(0, I). The
second-order expansion of each output around mu is

    g_i(u) ~ g_i(mu) + J_i d + 1/2 d^T H_i d,   d = L z,

a polynomial in z whose moments follow exactly from Isserlis' theorem. The script
computes them and compares with the TT2 formulas (docs/guide/transforms.md, "TT2"; lecture,
Gustafsson & Hendeby, NLT):

    E g_i          = g_i(mu) + 1/2 tr(H_i P)
    Cov(g_i, g_j)  = J_i P J_j^T + 1/2 tr(H_i P H_j P)
    Cov(g, u)      = J P            (third moments of a Gaussian vanish)

for n_u = 2 inputs and two outputs with fully symbolic J, H_i, L.
"""
from __future__ import annotations

import sympy as sp

from _common import Checker, Result, gaussian_expectation, is_zero, lower_triangular, main, matrix_symbols, symmetric_matrix

NAME = "tt2_moments"
TITLE = "TT2 mean, covariance and cross-covariance from Gaussian moment identities"
SOURCE = "Gustafsson & Hendeby, NLT lecture (TT1/TT2); docs/guide/transforms.md 'TT2'"

N_U = 2
N_Y = 2


def quadratic_model(n_u: int = N_U, n_y: int = N_Y):
    """Symbolic second-order expansion g(mu + L z) and its ingredients.

    Returns
    -------
    g : sympy.Matrix, shape (n_y, 1)
        c + J L z + 1/2 (L z)^T H_i (L z) per output.
    z : list of Symbol
        The standard normal variables.
    c, J, Hs, L : the value at the mean, Jacobian, Hessians and Cholesky factor.
    """
    z = list(sp.symbols(f"z1:{n_u + 1}", real=True))
    zv = sp.Matrix(z)
    L = lower_triangular("l", n_u)
    c = matrix_symbols("c", n_y, 1)
    J = matrix_symbols("J", n_y, n_u)
    Hs = [symmetric_matrix(f"H{i + 1}", n_u) for i in range(n_y)]
    d = L * zv
    g = sp.Matrix([c[i] + (J[i, :] * d)[0] + sp.Rational(1, 2) * (d.T * Hs[i] * d)[0] for i in range(n_y)])
    return g, z, c, J, Hs, L


def check() -> Result:
    """Compare Isserlis moments of the quadratic expansion with the TT2 formulas."""
    ck = Checker(NAME, TITLE, SOURCE)
    g, z, c, J, Hs, L = quadratic_model()
    P = L * L.T
    d = L * sp.Matrix(z)

    mean = sp.Matrix([gaussian_expectation(gi, z) for gi in g])
    mean_tt2 = sp.Matrix([c[i] + sp.Rational(1, 2) * (Hs[i] * P).trace() for i in range(N_Y)])
    ck.claim("E g_i = g_i(mu) + 1/2 tr(H_i P)", is_zero(mean - mean_tt2))

    centred = g - mean
    cov = sp.Matrix(N_Y, N_Y, lambda i, j: gaussian_expectation(centred[i] * centred[j], z))
    cov_tt2 = sp.Matrix(N_Y, N_Y, lambda i, j: (J[i, :] * P * J[j, :].T)[0]
                        + sp.Rational(1, 2) * (Hs[i] * P * Hs[j] * P).trace())
    ck.claim("Cov(g_i, g_j) = J_i P J_j^T + 1/2 tr(H_i P H_j P)", is_zero(cov - cov_tt2))

    cross = sp.Matrix(N_Y, N_U, lambda i, k: gaussian_expectation(centred[i] * d[k], z))
    ck.claim("Cov(g, u) = J P (odd Gaussian moments vanish)", is_zero(cross - J * P))

    # The checks can fail: TT1's covariance J P J^T misses the Hessian term.
    tt1 = J * P * J.T
    ck.claim("TT1 covariance J P J^T differs from the exact quadratic covariance",
             not is_zero(cov - tt1))

    ck.tex(r"\mathrm{E}\,g_i \approx", r"g_i(\mu) + \tfrac12 \operatorname{tr}(H_i P)")
    ck.tex(r"\operatorname{Cov}(g_i, g_j) \approx",
           r"J_i P J_j^\top + \tfrac12 \operatorname{tr}(H_i P H_j P),\quad \operatorname{Cov}(g, u) \approx J P")
    ck.tex(r"\operatorname{Cov}(g_1, g_1) =", sp.factor(cov[0, 0] - tt1[0, 0]) + sp.Symbol(r"(J P J^\top)_{11}"))
    return ck.result()


if __name__ == "__main__":
    main(check)
