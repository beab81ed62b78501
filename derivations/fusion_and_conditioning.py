"""Sensor fusion formula and Lemma 7.1 (Gaussian conditioning), lecture notes.

Fusion: independent estimates x_hat_k = x + e_k, e_k ~ N(0, P_k), k = 1, 2, combine to

    P = (P_1^-1 + P_2^-1)^-1,   x_hat = P (P_1^-1 x_hat_1 + P_2^-1 x_hat_2).

This equals the weighted least-squares / MAP (flat prior) estimate of the stacked model
[x_hat_1; x_hat_2] = [I; I] x + e, Cov e = blkdiag(P_1, P_2): the gradient of the cost
vanishes there, the WLS covariance (H^T R^-1 H)^-1 equals P, and the fused estimator is
unbiased with covariance P. Checked with sympy for 2-D x and fully symbolic P_k.

Lemma 7.1: for [x; y] ~ N([x0; y0], [[Pxx, Pxy], [Pyx, Pyy]]), the conditional density
of x given y is N(x0 + Pxy Pyy^-1 (y - y0), Pxx - Pxy Pyy^-1 Pyx). Checked with sympy on
2 + 1 blocks: the joint quadratic form minus the marginal one equals the conditional
quadratic form, and det(joint) = det(Schur complement) det(Pyy) (the normalising
constants agree), which together prove p(x, y) / p(y) is the stated Gaussian.
"""
from __future__ import annotations

import sympy as sp

from _common import Checker, Result, is_zero, lower_triangular, main, matrix_symbols

NAME = "fusion_and_conditioning"
TITLE = "Sensor fusion formula and Lemma 7.1 (conditional Gaussian via the Schur complement)"
SOURCE = "Gustafsson & Hendeby, NLT lecture (sensor fusion formula; Lemma 7.1, indirect approach step 4)"


def spd(prefix: str, n: int) -> sp.Matrix:
    """A generic symbolic SPD matrix L L^T."""
    L = lower_triangular(prefix, n)
    return L * L.T


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    n = 2
    P1, P2 = spd("a", n), spd("b", n)
    x1, x2 = matrix_symbols("xh1", n, 1), matrix_symbols("xh2", n, 1)
    x = matrix_symbols("x", n, 1)
    P = (P1.inv() + P2.inv()).inv()
    xf = P * (P1.inv() * x1 + P2.inv() * x2)

    cost = ((x1 - x).T * P1.inv() * (x1 - x))[0] + ((x2 - x).T * P2.inv() * (x2 - x))[0]
    grad = sp.Matrix([sp.diff(cost, s) for s in x]).subs(dict(zip(x, xf)))
    ck.claim("fused x_hat zeroes the gradient of the stacked WLS / MAP cost", is_zero(grad))
    H = sp.Matrix.vstack(sp.eye(n), sp.eye(n))
    R = sp.diag(P1, P2)
    ck.claim("WLS covariance (H^T R^-1 H)^-1 = (P_1^-1 + P_2^-1)^-1", is_zero((H.T * R.inv() * H).inv() - P))
    K1, K2 = P * P1.inv(), P * P2.inv()
    ck.claim("unbiased: K_1 + K_2 = I", is_zero(K1 + K2 - sp.eye(n)))
    ck.claim("estimator covariance K_1 P_1 K_1^T + K_2 P_2 K_2^T = P", is_zero(K1 * P1 * K1.T + K2 * P2 * K2.T - P))
    # Can fail: the naive average has a larger covariance in general.
    avg = (P1 + P2) / 4
    ck.claim("the plain average (P_1 + P_2)/4 is not the fused covariance", not is_zero(avg - P))
    ck.tex(r"P =", r"\Big(\sum_k P_k^{-1}\Big)^{-1},\quad \hat x = P\sum_k P_k^{-1}\hat x_k")

    # Lemma 7.1, 2 + 1 blocks.
    S = spd("s", 3)
    Pxx, Pxy, Pyy = S[:2, :2], S[:2, 2:], S[2:, 2:]
    m = matrix_symbols("m", 3, 1)
    w = matrix_symbols("w", 3, 1)                   # the point [x; y]
    dy = w[2:, :] - m[2:, :]
    xc = m[:2, :] + Pxy * Pyy.inv() * dy
    Pc = Pxx - Pxy * Pyy.inv() * Pxy.T
    joint_q = ((w - m).T * S.inv() * (w - m))[0]
    marg_q = (dy.T * Pyy.inv() * dy)[0]
    cond_q = ((w[:2, :] - xc).T * Pc.inv() * (w[:2, :] - xc))[0]
    ck.claim("Lemma 7.1: joint quadratic form - marginal of y = conditional quadratic form", is_zero(joint_q - marg_q - cond_q))
    ck.claim("Lemma 7.1: det(joint) = det(P_xx - P_xy P_yy^-1 P_yx) det(P_yy)", is_zero(S.det() - Pc.det() * Pyy.det()))
    wrong = Pxx + Pxy * Pyy.inv() * Pxy.T
    ck.claim("with the wrong sign in the Schur complement the identity fails",
             not is_zero(joint_q - marg_q - ((w[:2, :] - xc).T * wrong.inv() * (w[:2, :] - xc))[0]))
    ck.tex(r"x \mid y \sim", r"\mathcal N\big(\hat x_0 + P^{xy}(P^{yy})^{-1}(y - \hat y),\ P^{xx} - P^{xy}(P^{yy})^{-1}P^{yx}\big)")
    return ck.result()


if __name__ == "__main__":
    main(check)
