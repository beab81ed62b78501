"""Closed-form TT2 MoN: D = 1/2 [tr(H_i P H_j P)]_ij.

For a quadratic model g_i(u) = c_i + J_i d + 1/2 d^T H_i d, d = u - mu, u ~ N(mu, P),
the additive-noise residual covariance of (29) is exactly

    D = S_gg - S_gu S_uu^-1 S_ug = 1/2 [tr(H_i P H_j P)]_ij ,

because S_gg = J P J^T + 1/2 [tr(H_i P H_j P)] and S_gu = J P (tt2_moments.py). For a
smooth non-quadratic g this is the TT2 approximation of D, so the MoN needs only the
Jacobian and Hessians at the mean. Checked exactly with sympy (n_u = n_y = 2) and, for
a non-quadratic g (polar coordinates), against Gauss-Hermite quadrature: the relative
error must shrink as P is scaled down (it is O(P) relative to D).
"""
from __future__ import annotations

import numpy as np
import sympy as sp
from numpy.polynomial.hermite_e import hermegauss

from _common import Checker, Result, gaussian_expectation, is_zero, lower_triangular, main, matrix_symbols, symmetric_matrix

NAME = "tt2_mon"
TITLE = "TT2 closed-form MoN: D = 1/2 [tr(H_i P H_j P)] (exact for quadratic g)"
SOURCE = "docs/guide/nonlinearity.md (TT2 closed form); Straka & Havlik (29), (43)"

N = 2
GH_NODES = 60


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    z = list(sp.symbols(f"z1:{N + 1}", real=True))
    L = lower_triangular("l", N)
    P = L * L.T
    d = L * sp.Matrix(z)
    c = matrix_symbols("c", N, 1)
    J = matrix_symbols("J", N, N)
    Hs = [symmetric_matrix(f"H{i + 1}", N) for i in range(N)]
    g = sp.Matrix([c[i] + (J[i, :] * d)[0] + sp.Rational(1, 2) * (d.T * Hs[i] * d)[0] for i in range(N)])
    E = lambda M: M.applyfunc(lambda e: gaussian_expectation(e, z))
    Eg = E(g)
    S_gg = E((g - Eg) * (g - Eg).T)
    S_gu = E((g - Eg) * d.T)
    D = S_gg - S_gu * P.inv() * S_gu.T
    D_tt2 = sp.Matrix(N, N, lambda i, j: sp.Rational(1, 2) * (Hs[i] * P * Hs[j] * P).trace())
    ck.claim("quadratic g: S_gg - S_gu S_uu^-1 S_ug = 1/2 [tr(H_i P H_j P)] exactly", is_zero(D - D_tt2))
    ck.claim("the Jacobian drops out of the exact D (D with J = 0 equals D)",
             is_zero(D.subs({s: 0 for s in J}) - D))
    ck.claim("D = 0 for an affine g (all H_i = 0)",
             is_zero(D.subs({s: 0 for H in Hs for s in H.free_symbols})))
    ck.tex(r"D \approx \tfrac12\big[\operatorname{tr}(H_i P H_j P)\big]_{ij},\quad D_{11} =", sp.factor(D_tt2[0, 0]))

    # Non-quadratic g: polar coordinates at mu = (1, 10), P = a diag(1, 100) (paper's (14)-(16)).
    x, y = sp.symbols("x y", real=True)
    f = sp.Matrix([sp.sqrt(x ** 2 + y ** 2), sp.atan2(y, x)])
    mu = (1.0, 10.0)
    Hn = [np.array(sp.hessian(fi, (x, y)).subs({x: mu[0], y: mu[1]}).evalf(), dtype=float) for fi in f]
    fn = sp.lambdify((x, y), f, "numpy")
    nodes, w = hermegauss(GH_NODES)
    w = w / w.sum()
    errors = []
    for a in (1e-2, 1e-3, 1e-4):
        Pn = a * np.diag([1.0, 100.0])
        Ln = np.linalg.cholesky(Pn)
        Z = np.stack(np.meshgrid(nodes, nodes, indexing="ij"), -1).reshape(-1, 2)
        ww = np.outer(w, w).ravel()
        U = np.array(mu) + Z @ Ln.T
        G = np.array(fn(U[:, 0], U[:, 1]), dtype=float).reshape(2, -1).T
        Eg_n = ww @ G
        Sgg = (G - Eg_n).T @ ((G - Eg_n) * ww[:, None])
        Sgu = (G - Eg_n).T @ ((U - np.array(mu)) * ww[:, None])
        D_q = Sgg - Sgu @ np.linalg.solve(Pn, Sgu.T)
        D_t = 0.5 * np.array([[np.trace(Hi @ Pn @ Hj @ Pn) for Hj in Hn] for Hi in Hn])
        errors.append(np.linalg.norm(D_q - D_t) / np.linalg.norm(D_t))
    ck.claim("polar g: relative error of the TT2 D decreases with P (O(P))",
             errors[0] > errors[1] > errors[2] and errors[2] < 1e-2,
             ", ".join(f"{e:.2e}" for e in errors))
    return ck.result()


if __name__ == "__main__":
    main(check)
