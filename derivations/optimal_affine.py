"""Optimal affine part of the MSE-based MoN: (9), (10) and (26).

The deterministic part of the unitless MoN (23)-(25) is

    J_{A,b} = min_{A,b} E ||g - A u - b||_W^2 ,

where ||a||_W^2 = a^T W a. Written with first and second moments,

    E ||e||_W^2 = tr(W Cov e) + (E e)^T W (E e),   e = g - A u - b,
    Cov e = S_gg - A S_ug - S_gu A^T + A S_uu A^T .

The script shows with sympy (n_y = n_u = 2, every moment a symbol) that

* the gradient in A and b vanishes at A = S_gu S_uu^{-1} (9) and
  b = E g - A E u (10);
* the cost equals J* + tr(W dA S_uu dA^T) + ||E e||_W^2 with dA = A - A*, so the
  stationary point is the global minimum for W > 0, S_uu > 0 (completing the square);
* J* = tr(W (S_gg - S_gu S_uu^{-1} S_ug)) (26).

It also shows why ||.||_W must be read as the *squared* weighted norm (the paper
writes ||a||_W = (a) W (a)^T, with no square root): with a true norm the value is
not (26), e.g. for a scalar Gaussian error E sqrt(w e^2) = sqrt(w) sigma sqrt(2/pi).
"""
from __future__ import annotations

import sympy as sp
from sympy.stats import E as Expect, Normal

from _common import Checker, Result, is_zero, main, matrix_symbols, symmetric_matrix

NAME = "optimal_affine"
TITLE = "Optimal A, b of the affine fit and J_{A,b} (9), (10), (26)"
SOURCE = "Straka & Havlik, FUSION 2024, eqs. (9), (10), (23)-(26)"

N_Y = 2
N_U = 2


def affine_cost(A: sp.Matrix, b: sp.Matrix, W: sp.Matrix, m_g: sp.Matrix, m_u: sp.Matrix,
                S_gg: sp.Matrix, S_gu: sp.Matrix, S_uu: sp.Matrix) -> sp.Expr:
    """E ||g - A u - b||_W^2 expressed with the first and second moments of (g, u)."""
    cov_e = S_gg - A * S_gu.T - S_gu * A.T + A * S_uu * A.T
    mean_e = m_g - A * m_u - b
    return (W * cov_e).trace() + (mean_e.T * W * mean_e)[0]


def check() -> Result:
    """Stationarity, global minimality and value of the affine fit."""
    ck = Checker(NAME, TITLE, SOURCE)
    A = matrix_symbols("a", N_Y, N_U)
    b = matrix_symbols("b", N_Y, 1)
    W = symmetric_matrix("w", N_Y)
    S_gg = symmetric_matrix("sigma_gg", N_Y)
    S_uu = symmetric_matrix("sigma_uu", N_U)
    S_gu = matrix_symbols("sigma_gu", N_Y, N_U)
    m_g = matrix_symbols("m_g", N_Y, 1)
    m_u = matrix_symbols("m_u", N_U, 1)

    cost = affine_cost(A, b, W, m_g, m_u, S_gg, S_gu, S_uu)
    A_opt = S_gu * S_uu.inv()                      # (9)
    b_opt = m_g - A_opt * m_u                      # (10)
    at_opt = {**dict(zip(A, A_opt)), **dict(zip(b, b_opt))}

    grad = sp.Matrix([sp.diff(cost, s) for s in list(A) + list(b)])
    ck.claim("gradient of E||g - Au - b||_W^2 vanishes at A = S_gu S_uu^-1 (9), b = E g - A E u (10)",
             is_zero(grad.subs(at_opt)))

    J_opt = (W * (S_gg - S_gu * S_uu.inv() * S_gu.T)).trace()   # (26)
    ck.claim("J_{A,b} = tr(W (S_gg - S_gu S_uu^-1 S_ug)) (26)", is_zero(cost.subs(at_opt) - J_opt))

    dA = A - A_opt
    mean_e = m_g - A * m_u - b
    square = J_opt + (W * dA * S_uu * dA.T).trace() + (mean_e.T * W * mean_e)[0]
    ck.claim("cost = J* + tr(W dA S_uu dA^T) + ||E e||_W^2 (so (9), (10) is the global minimum)",
             is_zero(cost - square))

    # A wrong candidate must fail: the 'regression of u on g' slope is not optimal.
    wrong = {**dict(zip(A, S_uu * S_gu.T.inv())), **dict(zip(b, b_opt))}
    ck.claim("a wrong slope (S_uu S_ug^-1) is not stationary", not is_zero(grad.subs(wrong)))

    # Notation: (23) needs the squared norm a^T W a. With the square root the value changes.
    sigma, w = sp.symbols("sigma w", positive=True)
    e = Normal("e", 0, sigma)
    rooted = sp.simplify(Expect(sp.sqrt(w) * sp.Abs(e)))
    squared = sp.simplify(Expect(w * e ** 2))
    ck.claim("E sqrt(w e^2) = sqrt(w) sigma sqrt(2/pi) differs from E[w e^2] = w sigma^2 "
             "(||a||_W in (23)-(33) is the squared norm)",
             is_zero(rooted - sp.sqrt(w) * sigma * sp.sqrt(2 / sp.pi)) and is_zero(squared - w * sigma ** 2)
             and not is_zero(rooted - squared))

    ck.tex(r"A^\ast =", r"\Sigma_{gu}\Sigma_{uu}^{-1},\quad b^\ast = \mathrm{E}\,g - A^\ast\,\mathrm{E}\,u")
    ck.tex(r"J_{A,b} =", r"\operatorname{tr}\big(W(\Sigma_{gg} - \Sigma_{gu}\Sigma_{uu}^{-1}\Sigma_{ug})\big)")
    ck.tex(r"\mathrm{E}\|g - Au - b\|_W^2 - J_{A,b} =",
           r"\operatorname{tr}\big(W (A - A^\ast)\Sigma_{uu}(A - A^\ast)^\top\big) + \|\mathrm{E}\,g - A\,\mathrm{E}\,u - b\|_W^2")
    ck.tex(r"\mathrm{E}\sqrt{w e^2} =", rooted)
    return ck.result()


if __name__ == "__main__":
    main(check)
