"""Lemma 1 of the distance-estimator paper: E|x| for x ~ N(mu, sigma^2).

    E|x| = mu (1 - 2 Phi(-mu/sigma)) + 2 sigma phi(mu/sigma)

(the MMSE estimate of |x| given the Kalman estimate mu and variance sigma^2). Derived
here by sympy's integration of |x| against the Gaussian density, split at 0, and
compared with the formula symbolically; then against scipy quadrature at a few points.
"""
from __future__ import annotations

import numpy as np
import sympy as sp
from scipy import integrate, stats

from _common import Checker, Result, is_zero, main

NAME = "mmse_lemma1"
TITLE = "Lemma 1: E|x| = mu(1 - 2 Phi(-mu/sigma)) + 2 sigma phi(mu/sigma)"
SOURCE = "Shin, Shevlyakov, Jeong, Kim, Math. Probl. Eng. 2020, 9141735, Lemma 1, eq. (8), Appendix (A.1)-(A.4)"

POINTS = [(0.0, 1.0), (0.7, 0.3), (-2.5, 1.7), (10.0, 0.5)]
QUAD_TOL = 1e-10


def lemma1(mu, sigma):
    """The closed form of Lemma 1 (numeric)."""
    return mu * (1 - 2 * stats.norm.cdf(-mu / sigma)) + 2 * sigma * stats.norm.pdf(mu / sigma)


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    x, mu = sp.symbols("x mu", real=True)
    sigma = sp.Symbol("sigma", positive=True)
    pdf = sp.exp(-(x - mu) ** 2 / (2 * sigma ** 2)) / (sp.sqrt(2 * sp.pi) * sigma)
    derived = sp.integrate(x * pdf, (x, 0, sp.oo)) - sp.integrate(x * pdf, (x, -sp.oo, 0))
    Phi = lambda t: (1 + sp.erf(t / sp.sqrt(2))) / 2
    phi = lambda t: sp.exp(-t ** 2 / 2) / sp.sqrt(2 * sp.pi)
    formula = mu * (1 - 2 * Phi(-mu / sigma)) + 2 * sigma * phi(mu / sigma)
    ck.claim("sympy integral of |x| N(x; mu, sigma^2) equals Lemma 1", is_zero((derived - formula).rewrite(sp.erf)))
    ck.claim("plug-in |mu| is not the MMSE estimate (E|x| - |mu| != 0)", not is_zero(formula - sp.Abs(mu)))
    ck.claim("E|x| -> 2 sigma phi(0) = sigma sqrt(2/pi) at mu = 0", is_zero(formula.subs(mu, 0) - sigma * sp.sqrt(2 / sp.pi)))
    worst = 0.0
    for m, s in POINTS:
        def dens(t, m=m, s=s):
            return t * stats.norm.pdf(t, m, s)
        q = integrate.quad(dens, 0, np.inf, epsabs=1e-13)[0] - integrate.quad(dens, -np.inf, 0, epsabs=1e-13)[0]
        worst = max(worst, abs(q - lemma1(m, s)))
    ck.claim(f"quadrature agrees at {len(POINTS)} points within {QUAD_TOL:g}", worst < QUAD_TOL, f"max |diff| = {worst:.2e}")
    ck.tex(r"\mathrm{E}|x| =", sp.simplify(formula))
    return ck.result()


if __name__ == "__main__":
    main(check)
