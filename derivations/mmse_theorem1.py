"""Theorem 1 of the distance-estimator paper: E|a^T x + b| and the distance examples.

For x ~ N(x_hat, P), the linear form l = a^T x + b is Gaussian with mean mu = a^T x_hat + b
and variance sigma^2 = a^T P a (eq. (9)); Lemma 1 then gives E|l| (eq. (10)). The mean and
variance are derived exactly with sympy (Isserlis, 3-D x); the examples -- distance on a
line |x - c|, point to line |a x1 + b x2 + c| / sqrt(a^2 + b^2), point to plane in 3-D --
are checked against seeded Monte Carlo (5 standard errors). A case with mu near 0 shows
that the plug-in |mu| is rejected by the same test.
"""
from __future__ import annotations

import numpy as np
import sympy as sp
from scipy import stats

from _common import Checker, Result, gaussian_expectation, is_zero, lower_triangular, main, matrix_symbols, mc_within

NAME = "mmse_theorem1"
TITLE = "Theorem 1: E|a^T x + b| via Lemma 1; distances to a point, a line, a plane"
SOURCE = "Shin et al., Math. Probl. Eng. 2020, 9141735, eqs. (9), (10), Examples 1-3, Table 2"

SEED = 11
N_MC = 1_000_000


def abs_linear_form(a, b, xhat, P):
    """E|a^T x + b| for x ~ N(xhat, P) by Theorem 1."""
    mu = float(a @ xhat + b)
    s = float(np.sqrt(a @ P @ a))
    return mu * (1 - 2 * stats.norm.cdf(-mu / s)) + 2 * s * stats.norm.pdf(mu / s)


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    n = 3
    z = list(sp.symbols(f"z1:{n + 1}", real=True))
    L = lower_triangular("l", n)
    xhat = matrix_symbols("xh", n, 1)
    a = matrix_symbols("a", n, 1)
    b = sp.Symbol("b", real=True)
    lf = (a.T * (xhat + L * sp.Matrix(z)))[0] + b
    mean = gaussian_expectation(lf, z)
    var = gaussian_expectation((lf - mean) ** 2, z)
    ck.claim("(9): E[a^T x + b] = a^T x_hat + b", is_zero(mean - (a.T * xhat)[0] - b))
    ck.claim("(9): Var[a^T x + b] = a^T P a", is_zero(var - (a.T * L * L.T * a)[0]))
    ck.tex(r"\mu = a^\top\hat x + b,\ \sigma^2 = a^\top P a,\quad \mathrm{E}|a^\top x + b| =",
           r"\mu\big(1 - 2\Phi(-\mu/\sigma)\big) + 2\sigma\,\phi(\mu/\sigma)")

    rng = np.random.default_rng(SEED)
    P2 = np.array([[2.0, 0.6], [0.6, 1.0]])
    P3 = np.array([[1.0, 0.2, 0.1], [0.2, 1.5, -0.3], [0.1, -0.3, 0.8]])
    cases = [
        ("Example 1, |x - c| on a line", np.array([1.0]), -0.4, np.array([0.3]), np.array([[0.5]])),
        ("Example 2, point to line (a, b, c) = (1, -2, 0.5)", np.array([1.0, -2.0]) / np.sqrt(5), 0.5 / np.sqrt(5),
         np.array([0.4, 0.6]), P2),
        ("Example 3, point to plane (1, 2, -1, 0.3)", np.array([1.0, 2.0, -1.0]) / np.sqrt(6), 0.3 / np.sqrt(6),
         np.array([0.2, -0.1, 0.5]), P3),
    ]
    for label, av, bv, xh, P in cases:
        X = rng.multivariate_normal(xh, P, size=N_MC)
        samples = np.abs(X @ av + bv)
        ok, msg = mc_within(samples, abs_linear_form(av, bv, xh, P))
        ck.claim(label, ok, msg)
    label, av, bv, xh, P = cases[1]
    X = rng.multivariate_normal(xh, P, size=N_MC)
    ok, msg = mc_within(np.abs(X @ av + bv), abs(float(av @ xh + bv)))
    ck.claim("the plug-in |a^T x_hat + b| is rejected by the same MC test", not ok, msg)
    return ck.result()


if __name__ == "__main__":
    main(check)
