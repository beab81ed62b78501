"""Appendix A: the stochastic part J_n for multiplicative noise, (27) and (28).

For g(u, v) = f(u) + pi(u) gamma(v) with E gamma = 0 and u independent of v
(assumption A1), the paper minimises J_n = min E ||g - n||_W^2 over zero-mean n
that may depend on v (A2) and finds the minimiser n = pi_bar gamma(v),
pi_bar = E pi(u), with

    J_n = E ||g||_W^2 - tr(W pi_bar S_gamgam pi_bar^T)                           (27)
    M^2 = tr(W (S_gg - S_gu S_uu^-1 S_ug - pi_bar S_gamgam pi_bar^T))            (28a)
        = tr(W (S_ff - S_fu S_uu^-1 S_uf + E[pi~ S_gamgam pi~^T]))               (28b)

The script checks every step exactly on a polynomial model with symbolic
coefficients, u ~ N(mu, diag(s^2)) in R^2, v ~ N(0, 1), gamma(v) = [v, v^2 - 1]
(non-Gaussian, zero mean) and a symbolic symmetric W: all moments are computed with
Isserlis' theorem, so every equality is decided by sympy.
"""
from __future__ import annotations

import sympy as sp

from _common import Checker, Result, gaussian_expectation, is_zero, main, symmetric_matrix

NAME = "appendix_a"
TITLE = "Appendix A: minimising n, J_n (27) and M^2 (28) for multiplicative noise"
SOURCE = "Straka & Havlik, FUSION 2024, eqs. (3), (12), (25)-(28), Appendix A (48)-(51)"


def multiplicative_model():
    """Symbolic polynomial instance of g = f(u) + pi(u) gamma(v) with its variables."""
    z1, z2, v = sp.symbols("z1 z2 v", real=True)
    mu1, mu2 = sp.symbols("mu1 mu2", real=True)
    s1, s2 = sp.symbols("s1 s2", positive=True)
    a, b, c = sp.symbols("a b c", real=True)
    u = sp.Matrix([mu1 + s1 * z1, mu2 + s2 * z2])
    f = sp.Matrix([a * u[0] * u[1] + u[0], u[1] ** 2])
    pi = sp.Matrix([[1 + b * u[0], u[1]], [u[0] ** 2, c]])
    gamma = sp.Matrix([v, v ** 2 - 1])
    return dict(z=[z1, z2], v=v, u=u, mu=sp.Matrix([mu1, mu2]), s=(s1, s2), f=f, pi=pi, gamma=gamma)


def check() -> Result:
    """Exact check of Appendix A and of (27), (28) on a symbolic polynomial model."""
    ck = Checker(NAME, TITLE, SOURCE)
    m = multiplicative_model()
    z, v, u, f, pi, gamma = m["z"], m["v"], m["u"], m["f"], m["pi"], m["gamma"]
    allvars = z + [v]
    W = symmetric_matrix("w", 2)

    def E(expr):  # expectation over u and v
        return gaussian_expectation(expr, allvars)

    def EM(M):
        return M.applyfunc(E)

    def Eu(M):  # conditional expectation given v: integrate u out only
        return M.applyfunc(lambda e: gaussian_expectation(e, z))

    def sqn(x):  # squared W-norm x^T W x
        return (x.T * W * x)[0]

    g = f + pi * gamma
    Eg, Ef, Eu_ = EM(g), EM(f), m["mu"]
    S_uu = sp.diag(m["s"][0] ** 2, m["s"][1] ** 2)
    S_gg = EM((g - Eg) * (g - Eg).T)
    S_gu = EM((g - Eg) * (u - Eu_).T)
    S_ff = EM((f - Ef) * (f - Ef).T)
    S_fu = EM((f - Ef) * (u - Eu_).T)
    S_gamgam = EM(gamma * gamma.T)
    pi_bar = EM(pi)
    pi_t = pi - pi_bar
    E_pt = EM(pi_t * S_gamgam * pi_t.T)

    ck.claim("E gamma(v) = 0 and S_gamgam = diag(1, 2)",
             is_zero(EM(gamma)) and is_zero(S_gamgam - sp.diag(1, 2)))
    ck.claim("S_gu = S_fu and S_gg = S_ff + E[pi S_gamgam pi^T] (used for (28b))",
             is_zero(S_gu - S_fu) and is_zero(S_gg - S_ff - EM(pi * S_gamgam * pi.T)))

    # The minimiser: n* = E[g | v] - E g, which here is pi_bar gamma(v).
    n_star = Eu(g) - Eg
    ck.claim("E[g|v] - E g = pi_bar gamma(v) (the minimising n of Appendix A)",
             is_zero(n_star - pi_bar * gamma))

    # Optimality: any other zero-mean n = n* + delta(v) costs exactly E||delta||_W^2 more.
    d = sp.symbols("d1:6", real=True)
    delta = sp.Matrix([d[0] * v + d[1] * (v ** 2 - 1) + d[2] * v ** 3, d[3] * v + d[4] * v ** 3])
    J_of = lambda n: E(sqn(g - n))
    J_star = J_of(n_star)
    ck.claim("E||g - n* - delta||_W^2 = E||g - n*||_W^2 + E||delta||_W^2 for zero-mean delta(v)",
             is_zero(J_of(n_star + delta) - J_star - E(sqn(delta))))

    Eg2 = E(sqn(g))
    J_n_27 = Eg2 - (W * pi_bar * S_gamgam * pi_bar.T).trace()
    ck.claim("J_n = E||g||_W^2 - tr(W pi_bar S_gamgam pi_bar^T) (27), (51)", is_zero(J_star - J_n_27))

    # Intermediate steps (48)-(50).
    Ef2 = E(sqn(f))
    ck.claim("(48): E||g - n||_W^2 = E||f||_W^2 + E||pi gamma - n||_W^2 at n = n*",
             is_zero(J_star - Ef2 - E(sqn(pi * gamma - n_star))))
    ck.claim("(49): min E||pi gamma - n||_W^2 = tr(W E[pi~ S_gamgam pi~^T])",
             is_zero(E(sqn(pi * gamma - n_star)) - (W * E_pt).trace()))
    ck.claim("(50): E||g||_W^2 = E||f||_W^2 + tr(W E[pi~ S pi~^T]) + tr(W pi_bar S pi_bar^T)",
             is_zero(Eg2 - Ef2 - (W * E_pt).trace() - (W * pi_bar * S_gamgam * pi_bar.T).trace()))

    J_ab = (W * (S_gg - S_gu * S_uu.inv() * S_gu.T)).trace()       # (26)
    M2_25 = J_ab + J_star - Eg2                                     # (25)
    M2_28a = (W * (S_gg - S_gu * S_uu.inv() * S_gu.T - pi_bar * S_gamgam * pi_bar.T)).trace()
    M2_28b = (W * (S_ff - S_fu * S_uu.inv() * S_fu.T + E_pt)).trace()
    ck.claim("M^2 = J_Ab + J_n - E||g||_W^2 (25) equals (28), first form", is_zero(M2_25 - M2_28a))
    ck.claim("(28) first form equals (28) second form", is_zero(M2_28a - M2_28b))

    # Direct: the residual of the optimal fit A* u + b* + n*.
    A = S_gu * S_uu.inv()
    b = Eg - A * Eu_
    ck.claim("E||g - A*u - b* - n*||_W^2 equals (28)", is_zero(E(sqn(g - A * u - b - n_star)) - M2_28a))

    # Liu-Li (12), W = I: tr(E[pi~^T pi~ S]) = tr(E[pi~ S pi~^T]) (cyclic trace).
    ck.claim("(12) with W = I: tr E[pi~^T pi~ S_gamgam] = tr E[pi~ S_gamgam pi~^T]",
             is_zero(EM(pi_t.T * pi_t * S_gamgam).trace() - E_pt.trace()))

    # The checks can fail: dropping the noise term (treating the noise as absent) is wrong here.
    ck.claim("the additive formula tr(W(S_ff - S_fu S_uu^-1 S_uf)) alone differs from (28)",
             not is_zero(M2_28a - (W * (S_ff - S_fu * S_uu.inv() * S_fu.T)).trace()))

    ck.tex(r"n^\ast(v) =", r"\bar\pi\,\gamma(v) = \mathrm{E}[g\mid v] - \mathrm{E}\,g")
    ck.tex(r"J_n =", r"\mathrm{E}\|g\|_W^2 - \operatorname{tr}(W\bar\pi\Sigma_{\gamma\gamma}\bar\pi^\top)")
    ck.tex(r"M^2 =", r"\operatorname{tr}\big(W(\Sigma_{gg} - \Sigma_{gu}\Sigma_{uu}^{-1}\Sigma_{ug} - \bar\pi\Sigma_{\gamma\gamma}\bar\pi^\top)\big)"
           r" = \operatorname{tr}\big(W(\Sigma_{ff} - \Sigma_{fu}\Sigma_{uu}^{-1}\Sigma_{uf} + \mathrm{E}[\tilde\pi\Sigma_{\gamma\gamma}\tilde\pi^\top])\big)")
    ck.tex(r"\bar\pi =", pi_bar)
    ck.tex(r"M^2\big|_{W=I} =", sp.factor(M2_28a.subs({W[0, 0]: 1, W[1, 1]: 1, W[0, 1]: 0})))
    return ck.result()


if __name__ == "__main__":
    main(check)
