"""Theorem 3 of the distance-estimator paper: MMSE estimate of a bilinear form.

For jointly Gaussian [x; y] ~ N([x_hat; y_hat], [[P_xx, P_xy], [P_yx, P_yy]]),

    E[x^T B y] = x_hat^T B y_hat + tr(B P_yx)                                    (34)
    inner product:      E[x^T y]     = x_hat^T y_hat + tr P_xy                   (35)
    squared distance:   E||x - y||^2 = ||x_hat - y_hat||^2 + tr(P_xx + P_yy - P_xy - P_yx)   (37)

Derived exactly with Isserlis' theorem (2 + 2 blocks, fully symbolic joint Cholesky
factor), and (34) is also rederived from Theorem 2 applied to the quadratic form
w^T Q w, Q = [[0, B], [0, 0]], w = [x; y] (the paper's route via (32)-(33)). The
composite range estimator sqrt(x_hat^T x_hat + tr P) of Section 6 is suboptimal: by
Jensen it is at least E||x||; a seeded Monte Carlo shows the gap.
"""
from __future__ import annotations

import numpy as np
import sympy as sp

from _common import Checker, Result, gaussian_expectation, is_zero, lower_triangular, main, matrix_symbols, mc_within

NAME = "mmse_theorem3"
TITLE = "Theorem 3: E[x^T B y] = x_hat^T B y_hat + tr(B P_yx); inner product; squared distance"
SOURCE = "Shin et al., Math. Probl. Eng. 2020, 9141735, Theorem 3, eqs. (32)-(37), Example 4, Section 6"

SEED = 3
N_MC = 1_000_000


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    n = 2
    z = list(sp.symbols(f"z1:{2 * n + 1}", real=True))
    L = lower_triangular("l", 2 * n)
    S = L * L.T
    Pxx, Pxy, Pyx, Pyy = S[:n, :n], S[:n, n:], S[n:, :n], S[n:, n:]
    xhat, yhat = matrix_symbols("xh", n, 1), matrix_symbols("yh", n, 1)
    w = sp.Matrix.vstack(xhat, yhat) + L * sp.Matrix(z)
    x, y = w[:n, :], w[n:, :]
    B = matrix_symbols("b", n, n)
    est = (xhat.T * B * yhat)[0] + (B * Pyx).trace()
    ck.claim("(34): E[x^T B y] = x_hat^T B y_hat + tr(B P_yx)", is_zero(gaussian_expectation((x.T * B * y)[0], z) - est))
    Q = sp.zeros(2 * n, 2 * n)
    Q[:n, n:] = B
    wh = sp.Matrix.vstack(xhat, yhat)
    ck.claim("(34) = Theorem 2 on w^T Q w: w_hat^T Q w_hat + tr(Q S)", is_zero((wh.T * Q * wh)[0] + (Q * S).trace() - est))
    ck.claim("(35): E[x^T y] = x_hat^T y_hat + tr P_xy",
             is_zero(gaussian_expectation((x.T * y)[0], z) - (xhat.T * yhat)[0] - Pxy.trace()))
    d = x - y
    sq = gaussian_expectation((d.T * d)[0], z)
    ck.claim("(37): E||x - y||^2 = ||x_hat - y_hat||^2 + tr(P_xx + P_yy - P_xy - P_yx)",
             is_zero(sq - ((xhat - yhat).T * (xhat - yhat))[0] - (Pxx + Pyy - Pxy - Pyx).trace()))
    ck.claim("tr(B P_xy) in place of tr(B P_yx) is wrong for a non-symmetric B",
             not is_zero(gaussian_expectation((x.T * B * y)[0], z) - (xhat.T * B * yhat)[0] - (B * Pxy).trace()))
    ck.tex(r"\mathrm{E}[x^\top B y] =", r"\hat x^\top B\hat y + \operatorname{tr}(BP_{yx})")
    ck.tex(r"\mathrm{E}\|x - y\|^2 =", r"\|\hat x - \hat y\|^2 + \operatorname{tr}(P_{xx} + P_{yy} - P_{xy} - P_{yx})")

    # Composite (suboptimal) range estimator: sqrt(E||x||^2) >= E||x|| (Jensen).
    rng = np.random.default_rng(SEED)
    xh = np.array([1.0, 0.5])
    P = np.array([[1.0, 0.3], [0.3, 0.6]])
    r = np.linalg.norm(rng.multivariate_normal(xh, P, size=N_MC), axis=1)
    composite = float(np.sqrt(xh @ xh + np.trace(P)))
    ok, msg = mc_within(r, composite)
    ck.claim("composite range sqrt(x_hat^T x_hat + tr P) is not E||x|| (suboptimal, biased up)",
             (not ok) and composite > r.mean(), msg)
    ok2, msg2 = mc_within(r ** 2, float(xh @ xh + np.trace(P)))
    ck.claim("but its square is the exact E||x||^2 (Theorem 2 with A = I)", ok2, msg2)
    return ck.result()


if __name__ == "__main__":
    main(check)
