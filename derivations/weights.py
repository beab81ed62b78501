"""Weight relation for unit invariance, (35)-(38), and the weight choices (39)-(43).

A unit change u = S_u u_bar + o_u, y = S_y y_bar + o_y, v = S_v v_bar (18) maps the
model to g_bar(u_bar, v_bar) = S_y^-1 (g(S_u u_bar + o_u, S_v v_bar) - o_y). The MoN is
M^2(g; W) = tr(W D) with D = S_gg - Cov(E[g|v]) - S_gu S_uu^-1 S_ug (the general form;
(28) and (29) are special cases, see general_noise.py). Under the unit change,
D_bar = S_y^-1 D S_y^-1, so

    M(g_bar; W_bar) = M(g; S_y^-1 W_bar S_y^-1)     (37), (38) with S_y.

The paper prints S_v in (35a), (37) and (38); this script shows that with S_v the
invariance fails and with S_y it holds (S_y, S_u, S_v independent symbolic matrices).
It then checks (39)-(43): tr(W_bar S_gbar_gbar) = 1 for W_bar = I/n_y (unit diagonal)
and W_bar = S_gbar_gbar^-1/n_y, and that (38) turns them into (42), (43).
"""
from __future__ import annotations

import numpy as np
import sympy as sp

from _common import Checker, Result, is_zero, main, matrix_symbols, symmetric_matrix

NAME = "weights"
TITLE = "Unit-invariance weight relation W = S_y^-1 W_bar S_y^-1 (37)-(38) and weights (39)-(43)"
SOURCE = "Straka & Havlik, FUSION 2024, eqs. (18)-(21), (34)-(43)"

N_Y = 2
N_U = 2


def _transformed_moments(S_y, S_u):
    """Moments of (g_bar, u_bar) computed from those of (g, u) by the unit change (18)."""
    S_gg = symmetric_matrix("sigma_gg", N_Y)
    S_gu = matrix_symbols("sigma_gu", N_Y, N_U)
    S_uu = symmetric_matrix("sigma_uu", N_U)
    C = symmetric_matrix("c", N_Y)                      # Cov(E[g | v]); invariant under v = S_v v_bar
    D = S_gg - C - S_gu * S_uu.inv() * S_gu.T
    Syi, Sui = S_y.inv(), S_u.inv()
    bar = dict(S_gg=Syi * S_gg * Syi.T, S_gu=Syi * S_gu * Sui.T, S_uu=Sui * S_uu * Sui.T, C=Syi * C * Syi.T)
    D_bar = bar["S_gg"] - bar["C"] - bar["S_gu"] * bar["S_uu"].inv() * bar["S_gu"].T
    return D, D_bar


def check_relation(which: str = "S_y") -> Result:
    """Check M^2(g_bar; W_bar) = M^2(g; S^-1 W_bar S^-1) with S the matrix named ``which``.

    Parameters
    ----------
    which : {"S_y", "S_v"}
        "S_y" is the correct relation (38); "S_v" is what the paper prints in
        (35a), (37), (38). Both are symmetric symbolic matrices, independent of each
        other and of S_u.

    Returns
    -------
    Result
        ``passed`` is True exactly when the invariance holds identically.
    """
    if which not in ("S_y", "S_v"):
        raise ValueError(f"which must be 'S_y' or 'S_v', got {which!r}")
    ck = Checker(f"{NAME}:{which}", f"weight relation with {which}", SOURCE)
    S_y = symmetric_matrix("s_y", N_Y)
    S_v = symmetric_matrix("s_v", N_Y)                  # n_v = n_y so that the printed formula type-checks
    S_u = matrix_symbols("s_u", N_U, N_U)
    W_bar = symmetric_matrix("wbar", N_Y)
    D, D_bar = _transformed_moments(S_y, S_u)
    S = S_y if which == "S_y" else S_v
    W = S.inv() * W_bar * S.inv()
    residual = (W_bar * D_bar).trace() - (W * D).trace()
    ck.claim(f"M^2(g_bar; W_bar) = M^2(g; {which}^-1 W_bar {which}^-1)", is_zero(residual))
    return ck.result()


def check_35a(which: str = "S_y") -> bool:
    """Whether g_bar = which^-1 (g(S_u u_bar + o_u, S_v v_bar) - o) inverts (20).

    With ``which = "S_y"`` (and o = o_y) it does; the printed (35a) uses S_v and o_v.
    """
    ub = sp.Matrix(sp.symbols("ubar1:3", real=True))
    vb = sp.Matrix(sp.symbols("vbar1:3", real=True))
    S_y, S_v, S_u = symmetric_matrix("s_y", 2), symmetric_matrix("s_v", 2), matrix_symbols("s_u", 2, 2)
    o_y, o_u = matrix_symbols("o_y", 2, 1), matrix_symbols("o_u", 2, 1)
    gbar = lambda a, e: sp.Matrix([a[0] * a[1] + e[0], a[1] ** 2 + a[0] * e[1]])
    u = sp.Matrix(sp.symbols("u1:3", real=True))
    v = sp.Matrix(sp.symbols("v1:3", real=True))
    g = S_y * gbar(S_u.inv() * (u - o_u), S_v.inv() * v) + o_y              # (20)
    at = {**dict(zip(u, S_u * ub + o_u)), **dict(zip(v, S_v * vb))}
    S = S_y if which == "S_y" else S_v
    recovered = S.inv() * (g.subs(at, simultaneous=True) - o_y)               # (35a) with o_v read as o_y
    return is_zero(recovered - gbar(ub, vb))


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    good, bad = check_relation("S_y"), check_relation("S_v")
    ck.claim("(37)-(38) with S_y: invariance holds identically", good.passed)
    ck.claim("(37)-(38) as printed with S_v: invariance fails (typo confirmed)", not bad.passed)
    ck.claim("(35a) with S_y^-1, o_y inverts (20)", check_35a("S_y"))
    ck.claim("(35a) as printed with S_v^-1 does not invert (20)", not check_35a("S_v"))

    # (39), (40): tr(W_bar S_gbar_gbar) = 1 for unit-diagonal S_gbar_gbar (n_y = 3).
    n = 3
    rho = sp.symbols("rho12 rho13 rho23", real=True)
    Sbar = sp.Matrix([[1, rho[0], rho[1]], [rho[0], 1, rho[2]], [rho[1], rho[2], 1]])
    ck.claim("(39): tr(I/n_y S_gbar_gbar) = 1 when diag(S_gbar_gbar) = 1", is_zero((Sbar / n).trace() - 1))
    ck.claim("(40): tr(S_gbar_gbar^-1/n_y S_gbar_gbar) = 1", is_zero((Sbar.inv() * Sbar / n).trace() - 1))

    # (42): base units with unit variances and diagonal S_y = diag(sigma_i): S_y^-2 = diag(diag S_gg)^-1.
    S_gg = symmetric_matrix("sigma_gg", n)
    sig = sp.Matrix([sp.sqrt(S_gg[i, i]) for i in range(n)])
    S_y = sp.diag(*sig)
    Sbar_from = S_y.inv() * S_gg * S_y.inv()
    ck.claim("diagonal S_y = diag(sqrt(diag S_gg)) gives base units with unit variances",
             all(is_zero(Sbar_from[i, i] - 1) for i in range(n)))
    W_diag = S_y.inv() * (sp.eye(n) / n) * S_y.inv()
    ck.claim("(42): S_y^-1 (I/n_y) S_y^-1 = diag(diag S_gg)^-1 / n_y",
             is_zero(W_diag - sp.diag(*[1 / S_gg[i, i] for i in range(n)]) / n))
    ck.claim("(42) normalisation: tr(W^diag S_gg) = 1", is_zero((W_diag * S_gg).trace() - 1))

    # (43): holds for any invertible symmetric S_y, not only diagonal.
    S_y_full = symmetric_matrix("s_y", 2)
    S_gg2 = symmetric_matrix("sigma_gg", 2)
    Sbar2 = S_y_full.inv() * S_gg2 * S_y_full.inv()
    W_full = S_y_full.inv() * Sbar2.inv() * S_y_full.inv() / 2
    ck.claim("(43): S_y^-1 S_gbar_gbar^-1 S_y^-1 / n_y = S_gg^-1 / n_y (any symmetric S_y)",
             is_zero(W_full - S_gg2.inv() / 2))

    # (42)'s second equality needs a diagonal S_y: a counterexample with a full S_y.
    Sy = np.array([[1.0, 0.5], [0.5, 1.0]])
    Sgg = Sy @ np.eye(2) @ Sy                        # S_gbar_gbar = I has unit diagonal
    lhs = np.linalg.inv(Sy) @ np.linalg.inv(Sy) / 2
    rhs = np.diag(1 / np.diag(Sgg)) / 2
    ck.claim("(42) second equality fails for a non-diagonal S_y (the scale matrices must be diagonal)",
             not np.allclose(lhs, rhs), f"max |diff| = {np.abs(lhs - rhs).max():.3g}")

    ck.tex(r"M(\bar g; \bar W) = M(g; W) \iff", r"W = S_y^{-1}\bar W S_y^{-1}\quad(\text{not } S_v^{-1}\bar W S_v^{-1})")
    ck.tex(r"\bar g(\bar u, \bar v) =", r"S_y^{-1}\big(g(S_u\bar u + o_u, S_v\bar v) - o_y\big)")
    ck.tex(r"W^{\mathrm{diag}} =", W_diag)
    ck.tex(r"W^{\mathrm{full}} = \tfrac{1}{n_y}\Sigma_{gg}^{-1},\quad \operatorname{tr}(W^{\mathrm{full}}\Sigma_{gg}) =", sp.Integer(1))
    return ck.result()


if __name__ == "__main__":
    main(check)
