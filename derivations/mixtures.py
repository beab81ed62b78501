"""Moments and the conditional term of the MoN for Gaussian-mixture inputs and noise.

For u ~ sum_k w_k N(mu_k, P_k) (and v likewise, independent of u) symmon computes the
moments of g(u, v) by mixing the per-component moments m_k, P_k, C_k:

    E g        = sum_k w_k m_k,
    Cov g      = sum_k w_k (P_k + (m_k - m)(m_k - m)^T),
    Cov(g, u)  = sum_k w_k (C_k + (m_k - m)(mu_k - mu)^T),

and the conditional term of the general-noise MoN (docs/guide/nonlinearity.md) with

    h(v) = E[g | v] = sum_k w_k E_k[g(u, v)],
    Sigma_c = Cov_v h(v) = sum_{l,j} om_l a_lj (h(V_lj) - hbar)^2,

V_lj, a_lj the Gauss-Hermite points and weights of component l of v.

Checked here:

1. exactly (sympy, Isserlis moments per component) for a scalar two-component mixture
   and a cubic g: the mixed E g, Var g and Cov(g, u) against the raw moments of the
   mixture density, sum_k w_k E_k[.];
2. exactly, for the polynomial g = u v + u^2 v^2 with two-component mixtures of u and v:
   Var_v E[g | v] from the raw moments of the mixture of v against the law of total
   variance over its components;
3. numerically, that the outer points of the components (Gauss-Hermite of order 5 in each,
   exact to degree 9) with the weights om_l a_lj give the same Sigma_c (h of degree 2 in v:
   h^2 of degree 4), to 1e-12.
"""
from __future__ import annotations

import numpy as np
import sympy as sp
from numpy.polynomial.hermite_e import hermegauss

from _common import Checker, Result, gaussian_expectation, is_zero, main

NAME = "mixtures"
TITLE = "Gaussian mixtures: exact mixing of per-component moments and the conditional term"
SOURCE = "docs/guide/mixtures.md (our derivation); Straka & Havlik (23)-(29) for any densities of u and v"

#: Numeric claim 3: sums of a few dozen products.
NUMERIC_RTOL = 1e-12


def _component_expectation(expr: sp.Expr, u: sp.Symbol, mean: sp.Expr, var: sp.Expr, z: sp.Symbol) -> sp.Expr:
    """E[expr] for u ~ N(mean, var), by u = mean + sqrt(var) z and Isserlis."""
    return gaussian_expectation(sp.expand(expr.subs(u, mean + sp.sqrt(var) * z)), [z])


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    u, v, z = sp.symbols("u v z", real=True)
    w = sp.Symbol("w", positive=True)
    a, b = sp.symbols("a b", real=True)
    p, q = sp.symbols("p q", positive=True)
    c0, c1, c2, c3 = sp.symbols("c0:4", real=True)
    g = c0 + c1 * u + c2 * u**2 + c3 * u**3
    comps = [(w, a, p), (1 - w, b, q)]

    # 1. the mixture density's raw moments against the mixing of per-component moments
    def E_mix(expr):
        return sp.expand(sum(wk * _component_expectation(expr, u, m, P, z) for wk, m, P in comps))

    Eg, Eu = E_mix(g), E_mix(u)
    var_raw = E_mix(g**2) - Eg**2
    cross_raw = E_mix(g * u) - Eg * Eu
    m_k = [_component_expectation(g, u, m, P, z) for _, m, P in comps]
    P_k = [_component_expectation(g**2, u, m, P, z) - mk**2 for mk, (_, m, P) in zip(m_k, comps)]
    C_k = [_component_expectation(g * u, u, m, P, z) - mk * m for mk, (_, m, P) in zip(m_k, comps)]
    mean_mix = sum(wk * mk for (wk, _, _), mk in zip(comps, m_k))
    var_mix = sum(wk * (Pk + (mk - mean_mix) ** 2) for (wk, _, _), mk, Pk in zip(comps, m_k, P_k))
    cross_mix = sum(wk * (Ck + (mk - mean_mix) * (m - Eu)) for (wk, m, _), mk, Ck in zip(comps, m_k, C_k))
    ck.claim("E g = sum_k w_k m_k", is_zero(Eg - mean_mix))
    ck.claim("Var g = sum_k w_k (P_k + (m_k - m)^2)", is_zero(var_raw - var_mix))
    ck.claim("Cov(g, u) = sum_k w_k (C_k + (m_k - m)(mu_k - mu))", is_zero(cross_raw - cross_mix))
    # The between term matters: without it the mixed variance is wrong.
    ck.claim("the between-component term is needed", not is_zero(var_raw - sum(wk * Pk for (wk, _, _), Pk in zip(comps, P_k))))

    # 2. Var_v E[g | v] for g = u v + u^2 v^2 with mixtures of u and v
    om = sp.Symbol("omega", positive=True)
    nu1, nu2 = sp.symbols("nu1 nu2", real=True)
    r1, r2 = sp.symbols("r1 r2", positive=True)
    gen = u * v + u**2 * v**2
    h = E_mix(gen)  # E over the mixture of u, a polynomial in v
    vcomps = [(om, nu1, r1), (1 - om, nu2, r2)]

    def E_v(expr):
        return sp.expand(sum(ol * _component_expectation(expr, v, m, R, z) for ol, m, R in vcomps))

    sc_raw = E_v(h**2) - E_v(h) ** 2
    El = [_component_expectation(h, v, m, R, z) for _, m, R in vcomps]
    Vl = [_component_expectation(h**2, v, m, R, z) - e**2 for e, (_, m, R) in zip(El, vcomps)]
    hbar = sum(ol * e for (ol, _, _), e in zip(vcomps, El))
    sc_mix = sum(ol * (V + (e - hbar) ** 2) for (ol, _, _), e, V in zip(vcomps, El, Vl))
    ck.claim("Var_v E[g|v] = sum_l om_l (Var_l h + (E_l h - E h)^2), h = sum_k w_k E_k[g|v]",
             is_zero(sc_raw - sc_mix))

    # 3. one outer rule: the points of every component of v with weights om_l a_lj
    vals = {w: 0.3, a: 0.5, b: 1.5, p: 0.2, q: 0.4, om: 0.7, nu1: 0.0, nu2: 0.4, r1: 0.05, r2: 0.3}
    h_num = sp.lambdify(v, h.subs(vals), "numpy")
    x, wt = hermegauss(5)
    wt = wt / wt.sum()
    pts = np.concatenate([vals[m] + np.sqrt(vals[R]) * x for _, m, R in vcomps])
    wts = np.concatenate([float(ol.subs(vals)) * wt for ol, _, _ in vcomps])
    H = h_num(pts)
    sc_rule = float(wts @ (H - wts @ H) ** 2)
    exact = float(sc_raw.subs(vals))
    ck.claim("the components' Gauss-Hermite points, weighted om_l a_lj, give Sigma_c exactly",
             abs(sc_rule - exact) <= NUMERIC_RTOL * abs(exact), f"{sc_rule:.15g} vs {exact:.15g}")

    ck.tex(r"\operatorname{Cov} g =", r"\sum_k w_k \big(P_k + (m_k - m)(m_k - m)^\top\big)")
    ck.tex(r"\Sigma_c =", r"\sum_{l,j} \omega_l a_{lj} \big(h(V_{lj}) - \bar h\big)\big(h(V_{lj}) - \bar h\big)^\top")
    return ck.result()


if __name__ == "__main__":
    main(check)
