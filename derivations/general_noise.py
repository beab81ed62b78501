"""General (non-additive, non-multiplicative) noise: closed form of the MoN.

The paper states that J_n has no closed form for a general g(u, v) ((11) and the text
after (26)). Under its assumptions A1 (u independent of v, n) and A2 (psi_v fixed,
E n = 0), the fit A u + b + n(v) is a sum of an affine function of u and a function
of v. Because u and v are independent, centred affine functions of u and centred
functions of v are orthogonal in L2, so the best fit is the sum of the two
projections:

    A = S_gu S_uu^-1,  b = E g - A E u,  n(v) = E[g | v] - E g,
    M^2 = tr(W (S_gg - Cov(E[g|v]) - S_gu S_uu^-1 S_ug))
        = tr(W (E_v[Cov_u(g | v)] - S_gu S_uu^-1 S_ug)).

(A randomised n given v only adds variance, so a deterministic n(v) is optimal.)

Checked here:

1. exactly (sympy, Isserlis moments) on a polynomial model that is neither additive
   nor of the simple form f + pi gamma with one gamma: every perturbation of
   (A, b, n) costs exactly tr(W dA S_uu dA^T) + ||db||_W^2 + E||delta(v)||_W^2;
2. the reduction to (28) (multiplicative) and (29) (additive);
3. numerically on g = sin(u + v) and g = u exp(v) + v^3, scalar Gaussian u, v:
   the formula, evaluated by Gauss-Hermite quadrature (and in closed form for the
   sine), against a brute-force least-squares fit over [1, u, He_1(v), ..., He_K(v)]
   fitted on one half of a seeded Monte Carlo sample and evaluated on the other
   half, within 5 standard errors plus 1e-4 relative for the basis truncation.
"""
from __future__ import annotations

import numpy as np
import sympy as sp
from numpy.polynomial.hermite_e import hermegauss, hermevander

from _common import Checker, Result, gaussian_expectation, is_zero, main, mc_within, symmetric_matrix

NAME = "general_noise"
TITLE = "General-noise MoN: n(v) = E[g|v] - E g and its closed-form M^2 (beyond the paper)"
SOURCE = "docs/guide/nonlinearity.md (general noise, our derivation); Straka & Havlik (11), (23)-(29)"

SEED = 20240711
N_MC = 400_000           # per half (fit / evaluate)
HERMITE_DEGREE = 14
GH_NODES = 80
TRUNCATION_RTOL = 1e-4   # allowance for the finite polynomial basis in v


# --------------------------------------------------------------------------- symbolic

def _moments(g, u, zs, W):
    """Exact first and second moments of g, u (polynomials in the normals ``zs``)."""
    def E(M):
        if isinstance(M, sp.MatrixBase):
            return M.applyfunc(lambda e: gaussian_expectation(e, zs))
        return gaussian_expectation(M, zs)
    Eg, Eu = E(g), E(u)
    return dict(
        E=E, Eg=Eg, Eu=Eu,
        S_gg=E((g - Eg) * (g - Eg).T), S_gu=E((g - Eg) * (u - Eu).T), S_uu=E((u - Eu) * (u - Eu).T),
    )


def general_formula(g, u, zu, v_syms, W):
    """tr(W(S_gg - Cov(E[g|v]) - S_gu S_uu^-1 S_ug)) and its ingredients, exactly."""
    m = _moments(g, u, zu + v_syms, W)
    cond = g.applyfunc(lambda e: gaussian_expectation(e, zu))          # E[g | v]
    n_star = cond - m["Eg"]
    cov_cond = m["E"](n_star * n_star.T)
    D = m["S_gg"] - cov_cond - m["S_gu"] * m["S_uu"].inv() * m["S_gu"].T
    return (W * D).trace(), n_star, m


def symbolic_part(ck: Checker) -> None:
    z1, z2, v = sp.symbols("z1 z2 v", real=True)
    mu1, mu2 = sp.symbols("mu1 mu2", real=True)
    s1, s2 = sp.symbols("s1 s2", positive=True)
    u = sp.Matrix([mu1 + s1 * z1, mu2 + s2 * z2])
    W = symmetric_matrix("w", 2)
    g = sp.Matrix([u[0] ** 2 * v + u[1] * v ** 3 + u[0] * u[1], u[0] * v ** 2 + u[1] ** 2 * v])
    M2, n_star, m = general_formula(g, u, [z1, z2], [v], W)
    E = m["E"]
    A = m["S_gu"] * m["S_uu"].inv()
    b = m["Eg"] - A * m["Eu"]
    sqn = lambda x: (x.T * W * x)[0]
    best = E(sqn(g - A * u - b - n_star))
    ck.claim("general model: E||g - A*u - b* - n*(v)||_W^2 = tr(W(S_gg - Cov E[g|v] - S_gu S_uu^-1 S_ug))",
             is_zero(best - M2))

    dA = sp.Matrix(2, 2, sp.symbols("dA1:5", real=True))
    db = sp.Matrix(sp.symbols("db1:3", real=True))
    d = sp.symbols("d1:5", real=True)
    delta = sp.Matrix([d[0] * v + d[1] * (v ** 2 - 1), d[2] * v ** 3 + d[3] * (v ** 2 - 1)])
    perturbed = E(sqn(g - (A + dA) * u - (b + db) - (n_star + delta)))
    # dA u = dA (u - E u) + dA E u, so the shift seen by the mean is db + dA E u.
    excess = (W * dA * m["S_uu"] * dA.T).trace() + sqn(db + dA * m["Eu"]) + E(sqn(delta))
    ck.claim("any perturbation (dA, db, zero-mean delta(v)) costs "
             "tr(W dA S_uu dA^T) + ||db + dA E u||_W^2 + E||delta||_W^2 >= 0",
             is_zero(perturbed - best - excess))

    # Law of total covariance: S_gg - Cov(E[g|v]) = E_v[Cov_u(g | v)].
    cond = g.applyfunc(lambda e: gaussian_expectation(e, [z1, z2]))
    within = E((g - cond) * (g - cond).T)
    ck.claim("S_gg - Cov(E[g|v]) = E_v[Cov_u(g|v)] (both forms of the general formula)",
             is_zero(m["S_gg"] - E(n_star * n_star.T) - within))
    ck.claim("for this model the paper's (28)-without-noise-term tr(W(S_gg - S_gu S_uu^-1 S_ug)) overstates M^2",
             not is_zero(M2 - (W * (m["S_gg"] - A * m["S_gu"].T)).trace()))
    ck.tex(r"n^\ast(v) =", n_star)
    ck.tex(r"M^2 =", r"\operatorname{tr}\big(W(\Sigma_{gg} - \operatorname{Cov}(\mathrm{E}[g\mid v]) - \Sigma_{gu}\Sigma_{uu}^{-1}\Sigma_{ug})\big)"
           r" = \operatorname{tr}\big(W(\mathrm{E}_v[\operatorname{Cov}_u(g\mid v)] - \Sigma_{gu}\Sigma_{uu}^{-1}\Sigma_{ug})\big)")

    # Reduction to (28): g = f(u) + pi(u) gamma(v).
    f = sp.Matrix([u[0] * u[1], u[0] ** 2])
    pi = sp.Matrix([[u[0], 1], [u[1] ** 2, u[0]]])
    gamma = sp.Matrix([v, v ** 2 - 1])
    gm = f + pi * gamma
    M2m, _, mm = general_formula(gm, u, [z1, z2], [v], W)
    pi_bar = mm["E"](pi)
    S_gamgam = mm["E"](gamma * gamma.T)
    eq28 = (W * (mm["S_gg"] - mm["S_gu"] * mm["S_uu"].inv() * mm["S_gu"].T - pi_bar * S_gamgam * pi_bar.T)).trace()
    ck.claim("multiplicative g = f + pi gamma: general formula = (28)", is_zero(M2m - eq28))

    # Reduction to (29): g = f(u) + v, v ~ N(0, diag(r1, r2)).
    y1, y2 = sp.symbols("y1 y2", real=True)
    r1, r2 = sp.symbols("r1 r2", positive=True)
    ga = f + sp.Matrix([sp.sqrt(r1) * y1, sp.sqrt(r2) * y2])
    M2a, _, ma = general_formula(ga, u, [z1, z2], [y1, y2], W)
    fm = _moments(f, u, [z1, z2], W)
    eq29 = (W * (fm["S_gg"] - fm["S_gu"] * fm["S_uu"].inv() * fm["S_gu"].T)).trace()
    ck.claim("additive g = f + v: general formula = (29)", is_zero(M2a - eq29))


# --------------------------------------------------------------------------- numeric

def formula_by_quadrature(func, mu_u, s_u, s_v, nodes=GH_NODES):
    """Scalar M^2 (W = 1) of the general formula by tensor Gauss-Hermite quadrature."""
    x, w = hermegauss(nodes)
    w = w / w.sum()
    U = mu_u + s_u * x[:, None]
    V = s_v * x[None, :]
    G = func(U, V)
    WW = w[:, None] * w[None, :]
    Eg = np.sum(WW * G)
    var_g = np.sum(WW * (G - Eg) ** 2)
    cov_gu = np.sum(WW * (G - Eg) * (U - mu_u))
    cond = np.sum(w[:, None] * G, axis=0)            # E[g | v] at the v nodes
    var_cond = np.sum(w * (cond - Eg) ** 2)
    return var_g - var_cond - cov_gu ** 2 / s_u ** 2, var_g, var_cond, cov_gu


def sine_closed_form(mu_u, s_u, s_v):
    """Closed-form M^2 for g = sin(u + v) (characteristic function of a Gaussian)."""
    s2 = s_u ** 2 + s_v ** 2
    var_g = 0.5 * (1 - np.exp(-2 * s2) * np.cos(2 * mu_u)) - np.exp(-s2) * np.sin(mu_u) ** 2
    cov_gu = s_u ** 2 * np.exp(-s2 / 2) * np.cos(mu_u)          # Stein's lemma
    var_h = 0.5 * (1 - np.exp(-2 * s_v ** 2) * np.cos(2 * mu_u)) - np.exp(-s_v ** 2) * np.sin(mu_u) ** 2
    var_cond = np.exp(-s_u ** 2) * var_h                         # E[g|v] = e^{-s_u^2/2} sin(mu_u + v)
    return var_g - var_cond - cov_gu ** 2 / s_u ** 2


def brute_force(func, mu_u, s_u, s_v, rng):
    """Least-squares fit over [1, u, He_k(v/s_v)], held-out squared residuals."""
    def features(u, v):
        return np.column_stack([u, hermevander(v / s_v, HERMITE_DEGREE)])   # He_0 = 1
    u = mu_u + s_u * rng.standard_normal(2 * N_MC)
    v = s_v * rng.standard_normal(2 * N_MC)
    g = func(u, v)
    F = features(u, v)
    coef, *_ = np.linalg.lstsq(F[:N_MC], g[:N_MC], rcond=None)
    resid = g[N_MC:] - F[N_MC:] @ coef
    return resid ** 2, coef


def numeric_part(ck: Checker) -> None:
    rng = np.random.default_rng(SEED)
    cases = [
        ("sin(u + v)", lambda u, v: np.sin(u + v), 0.8, 0.9, 0.6),
        ("u exp(v) + v^3", lambda u, v: u * np.exp(v) + v ** 3, 1.0, 0.5, 0.5),
    ]
    for label, func, mu_u, s_u, s_v in cases:
        M2, var_g, var_cond, cov_gu = formula_by_quadrature(func, mu_u, s_u, s_v)
        if label.startswith("sin"):
            exact = sine_closed_form(mu_u, s_u, s_v)
            ck.claim(f"{label}: quadrature M^2 = closed form", abs(M2 - exact) <= 1e-12,
                     f"{M2:.12g} vs {exact:.12g}")
        r2, coef = brute_force(func, mu_u, s_u, s_v, rng)
        ok, msg = mc_within(r2, M2, extra=TRUNCATION_RTOL * M2)
        ck.claim(f"{label}: brute-force least squares over [1, u, He_k(v)] matches the formula", ok, msg)
        slope_se = np.sqrt(r2.mean() / (N_MC * s_u ** 2))       # OLS standard error of the slope
        ck.claim(f"{label}: fitted slope on u equals S_gu / S_uu",
                 abs(coef[0] - cov_gu / s_u ** 2) <= 5 * slope_se,
                 f"{coef[0]:.5f} vs {cov_gu / s_u ** 2:.5f}, 5 SE = {5 * slope_se:.2g}")
        wrong = var_g - cov_gu ** 2 / s_u ** 2        # (26) alone, ignoring the noise projection
        ok_w, msg_w = mc_within(r2, wrong)
        ck.claim(f"{label}: brute force rejects the formula without the Cov(E[g|v]) term", not ok_w, msg_w)
        tex_g = {"sin(u + v)": r"\sin(u + v)", "u exp(v) + v^3": r"u e^{v} + v^3"}[label]
        ck.tex(rf"M^2\,[g = {tex_g}] \approx", sp.Float(M2, 8))


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    symbolic_part(ck)
    numeric_part(ck)
    return ck.result()


if __name__ == "__main__":
    main(check)
