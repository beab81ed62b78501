"""Lemma 2 of the distance-estimator paper: the plug-in quadratic estimator's extra MSE.

For x ~ N(x_hat, P), the plug-in estimate x_hat^T A x_hat of x^T A x has MSE larger than
that of the MMSE estimate (26) by exactly (tr A P)^2 (eq. (29)): the plug-in estimator is
biased by -tr(A P) and bias^2 adds to the MSE. Checked exactly with Isserlis (2-D, A
symbolic), and for the squared norm (A = I): gap = (tr P)^2.
"""
from __future__ import annotations

import sympy as sp

from _common import Checker, Result, gaussian_expectation, is_zero, lower_triangular, main, matrix_symbols

NAME = "mmse_lemma2"
TITLE = "Lemma 2: MSE(plug-in) - MSE(MMSE) = (tr A P)^2"
SOURCE = "Shin et al., Math. Probl. Eng. 2020, 9141735, Lemma 2, eqs. (28)-(31)"


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    n = 2
    z = list(sp.symbols(f"z1:{n + 1}", real=True))
    L = lower_triangular("l", n)
    P = L * L.T
    xhat = matrix_symbols("xh", n, 1)
    A = matrix_symbols("a", n, n)
    x = xhat + L * sp.Matrix(z)
    q = (x.T * A * x)[0]
    plug = (xhat.T * A * xhat)[0]
    opt = plug + (A * P).trace()
    gap = gaussian_expectation((q - plug) ** 2, z) - gaussian_expectation((q - opt) ** 2, z)
    ck.claim("MSE(x_hat^T A x_hat) - MSE(x_hat^T A x_hat + tr AP) = (tr A P)^2", is_zero(gap - (A * P).trace() ** 2))
    ck.claim("A = I (squared norm): gap = (tr P)^2", is_zero(gap.subs({A[0, 0]: 1, A[1, 1]: 1, A[0, 1]: 0, A[1, 0]: 0}) - P.trace() ** 2))
    ck.claim("the gap is not (tr A P) (a first power would be wrong)", not is_zero(gap - (A * P).trace()))
    ck.tex(r"\mathrm{MSE}(\hat x^\top A\hat x) - \mathrm{MSE}(\hat x^\top A\hat x + \operatorname{tr}AP) =", r"(\operatorname{tr}AP)^2")
    ck.tex(r"(\operatorname{tr}AP)^2 =", sp.factor((A * P).trace() ** 2))
    return ck.result()


if __name__ == "__main__":
    main(check)
