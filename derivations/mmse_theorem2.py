"""Theorem 2 of the distance-estimator paper: MMSE estimate of a quadratic form and its MSE.

For x ~ N(x_hat, P) and any (not necessarily symmetric) A,

    E[x^T A x]            = x_hat^T A x_hat + tr(A P)                        (26)
    E[(x^T A x - (26))^2] = 2 tr(A_s P A_s P) + 4 x_hat^T A_s P A_s x_hat,   A_s = (A + A^T)/2.

Derived exactly with Isserlis' theorem (x = x_hat + L z, 2-D, A fully symbolic). The MSE
formula is stated with A_s; the script also shows that writing A in place of A_s is wrong
for a non-symmetric A.
"""
from __future__ import annotations

import sympy as sp

from _common import Checker, Result, gaussian_expectation, is_zero, lower_triangular, main, matrix_symbols

NAME = "mmse_theorem2"
TITLE = "Theorem 2: E[x^T A x] = x_hat^T A x_hat + tr(AP) and its MSE"
SOURCE = "Shin et al., Math. Probl. Eng. 2020, 9141735, Theorem 2, eqs. (25)-(27)"


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    n = 2
    z = list(sp.symbols(f"z1:{n + 1}", real=True))
    L = lower_triangular("l", n)
    P = L * L.T
    xhat = matrix_symbols("xh", n, 1)
    A = matrix_symbols("a", n, n)
    As = (A + A.T) / 2
    x = xhat + L * sp.Matrix(z)
    q = (x.T * A * x)[0]
    est = (xhat.T * A * xhat)[0] + (A * P).trace()
    ck.claim("(26): E[x^T A x] = x_hat^T A x_hat + tr(A P)", is_zero(gaussian_expectation(q, z) - est))
    mse = gaussian_expectation((q - est) ** 2, z)
    mse_formula = 2 * (As * P * As * P).trace() + 4 * (xhat.T * As * P * As * xhat)[0]
    ck.claim("MSE = 2 tr(A_s P A_s P) + 4 x_hat^T A_s P A_s x_hat", is_zero(mse - mse_formula))
    with_A = 2 * (A * P * A * P).trace() + 4 * (xhat.T * A * P * A * xhat)[0]
    ck.claim("with A in place of A_s the MSE formula fails for non-symmetric A", not is_zero(mse - with_A))
    ck.tex(r"\mathrm{E}[x^\top A x] =", r"\hat x^\top A\hat x + \operatorname{tr}(AP)")
    ck.tex(r"\mathrm{MSE} =", r"2\operatorname{tr}(A_sPA_sP) + 4\hat x^\top A_sPA_s\hat x,\quad A_s = \tfrac12(A + A^\top)")
    return ck.result()


if __name__ == "__main__":
    main(check)
