"""Remarks 1 and 2 of the unitless-measure paper.

Remark 1: noise-free y = g(u) with W^full = S_gg^-1 / n_y (43) gives

    M^2 = tr(W^full (S_gg - S_gu S_uu^-1 S_ug)) = 1 - (1/n_y) tr(S_gg^-1 S_gu S_uu^-1 S_ug),

i.e. one minus the mean of the squared canonical correlations between g and u (a
multivariate coefficient of determination R^2, Pillai's trace / n_y). So M is the square
root of 1 - R^2 (a linear g has M = 0 and R^2 = 1), not of R^2 as the remark's wording
can be read.

Remark 2: W = I gives (6), and W = I / tr(S_gg) gives the square of (8),
M_W^2 = M^2 / tr S_gg. The paper prints W = I / sqrt(tr S_gg), which gives
M_W^2 = M^2 / sqrt(tr S_gg), not (M^norm)^2, and violates tr(W S_gg) = 1: a typo
when ||.||_W is the squared norm.
"""
from __future__ import annotations

import numpy as np
import sympy as sp

from _common import Checker, Result, is_zero, main, matrix_symbols, symmetric_matrix

NAME = "remarks"
TITLE = "Remark 1 (W^full, coefficient of determination) and Remark 2 (W = I, W = I/tr S_gg)"
SOURCE = "Straka & Havlik, FUSION 2024, Remarks 1 and 2; eqs. (6), (8), (13), (29), (43)"

SEED = 1


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    n = 2
    S_gg = symmetric_matrix("sigma_gg", n)
    S_uu = symmetric_matrix("sigma_uu", n)
    S_gu = matrix_symbols("sigma_gu", n, n)
    D = S_gg - S_gu * S_uu.inv() * S_gu.T
    W_full = S_gg.inv() / n
    M2 = (W_full * D).trace()
    R2 = (S_gg.inv() * S_gu * S_uu.inv() * S_gu.T).trace() / n
    ck.claim("Remark 1: tr(W^full D) = 1 - (1/n_y) tr(S_gg^-1 S_gu S_uu^-1 S_ug)", is_zero(M2 - (1 - R2)))
    ck.tex(r"M^2\big|_{W^{\mathrm{full}}} =", r"1 - \tfrac{1}{n_y}\operatorname{tr}(\Sigma_{gg}^{-1}\Sigma_{gu}\Sigma_{uu}^{-1}\Sigma_{ug}) = 1 - R^2")

    # R^2 is the mean squared canonical correlation; M = 0 for linear g, where R^2 = 1.
    rng = np.random.default_rng(SEED)
    X = rng.standard_normal((5, 5))
    S = X @ X.T
    Sgg, Sgu, Suu = S[:2, :2], S[:2, 2:], S[2:, 2:]
    Lg, Lu = np.linalg.cholesky(Sgg), np.linalg.cholesky(Suu)
    canon = np.linalg.svd(np.linalg.solve(Lg, Sgu) @ np.linalg.inv(Lu).T, compute_uv=False)
    R2n = np.trace(np.linalg.solve(Sgg, Sgu @ np.linalg.solve(Suu, Sgu.T))) / 2
    ck.claim("R^2 = mean of squared canonical correlations (random covariance)",
             abs(R2n - np.mean(canon ** 2)) < 1e-12, f"{R2n:.12f} vs {np.mean(canon ** 2):.12f}")
    A = matrix_symbols("a", n, n)
    S_gg_lin, S_gu_lin = A * S_uu * A.T, A * S_uu
    M2_lin = ((S_gg_lin.inv() / n) * (S_gg_lin - S_gu_lin * S_uu.inv() * S_gu_lin.T)).trace()
    ck.claim("linear g = A u: M^2 = 0 (so M = sqrt(1 - R^2), not sqrt(R^2))", is_zero(M2_lin))

    # Remark 2.
    M2_I = D.trace()                                               # (6)/(13) squared, W = I
    ck.claim("Remark 2: W = I gives tr(S_gg - S_gu S_uu^-1 S_ug) = M^2 of (6)/(13)", is_zero((sp.eye(n) * D).trace() - M2_I))
    tr = S_gg.trace()
    M2_norm = M2_I / tr                                            # (8) squared
    W_right = sp.eye(n) / tr
    W_printed = sp.eye(n) / sp.sqrt(tr)
    ck.claim("W = I / tr(S_gg) gives (M^norm)^2 = M^2 / tr S_gg (8)", is_zero((W_right * D).trace() - M2_norm))
    ck.claim("W = I / tr(S_gg) satisfies the normalisation tr(W S_gg) = 1", is_zero((W_right * S_gg).trace() - 1))
    ck.claim("the printed W = I / sqrt(tr S_gg) does NOT give (8)^2", not is_zero((W_printed * D).trace() - M2_norm))
    ck.claim("the printed W = I / sqrt(tr S_gg) violates tr(W S_gg) = 1", not is_zero((W_printed * S_gg).trace() - 1))
    ck.tex(r"W = \frac{I}{\operatorname{tr}\Sigma_{gg}}:\ M_W^2 =",
           r"\frac{\operatorname{tr}(\Sigma_{gg} - \Sigma_{gu}\Sigma_{uu}^{-1}\Sigma_{ug})}{\operatorname{tr}\Sigma_{gg}} = (M^{\mathrm{norm}})^2")
    ck.tex(r"W = \frac{I}{\sqrt{\operatorname{tr}\Sigma_{gg}}}:\ \operatorname{tr}(W\Sigma_{gg}) =", (W_printed * S_gg).trace())
    return ck.result()


if __name__ == "__main__":
    main(check)
