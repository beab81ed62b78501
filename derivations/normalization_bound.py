"""Normalization of the unitless MoN: the bounds (30)-(33).

(30) J_{A,b} <= E||g - E g||_W^2 = tr(W S_gg)   (take A = 0, b = E g)
(31) E||g - n||_W^2 = E||g||_W^2 + E||n||_W^2 - 2 E[g^T W n]
(32) J_n <= E||g||_W^2                             (take n independent of v, or n = 0)
(33) M^2 = J_{A,b} + J_n - E||g||_W^2 <= tr(W S_gg)

Checked symbolically (2 x 2, every moment a symbol) and on random joint covariances.
The script also tests the sentence after (33), which says the bound is attained for
S_fu = 0 in the additive case and for S_fu = 0 and E[pi~ S pi~^T] = 0 in the
multiplicative case. From (28), tr(W S_gg) - M^2 = tr(W S_gu S_uu^-1 S_ug) +
tr(W pi_bar S_gamgam pi_bar^T), so the bound is attained exactly when S_gu = 0 *and*
tr(W pi_bar S_gamgam pi_bar^T) = 0; E[pi~ S pi~^T] plays no role. In the additive case
(pi = I) this means no noise at all. Both counterexamples are computed exactly.
"""
from __future__ import annotations

import numpy as np
import sympy as sp

from _common import Checker, Result, gaussian_expectation, is_zero, lower_triangular, main, matrix_symbols, symmetric_matrix

NAME = "normalization_bound"
TITLE = "Upper bound M^2 <= tr(W S_gg) and normalization (30)-(33)"
SOURCE = "Straka & Havlik, FUSION 2024, eqs. (25), (28)-(33) and the remark after (33)"

SEED = 7
N_RANDOM = 200


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    n = 2
    W = symmetric_matrix("w", n)
    S_gg = symmetric_matrix("sigma_gg", n)
    S_gu = matrix_symbols("sigma_gu", n, n)
    Lu = lower_triangular("l", n)
    S_uu = Lu * Lu.T
    m_g = matrix_symbols("m_g", n, 1)
    m_u = matrix_symbols("m_u", n, 1)

    # (30): the cost at A = 0, b = E g.
    A0, b0 = sp.zeros(n, n), m_g
    cov_e = S_gg - A0 * S_gu.T - S_gu * A0.T + A0 * S_uu * A0.T
    mean_e = m_g - A0 * m_u - b0
    cost0 = (W * cov_e).trace() + (mean_e.T * W * mean_e)[0]
    ck.claim("(30): E||g - E g||_W^2 = tr(W S_gg)", is_zero(cost0 - (W * S_gg).trace()))

    # J_{A,b} = tr(W S_gg) - tr(W S_gu S_uu^-1 S_ug) and the subtracted term is a sum of squares.
    R = lower_triangular("r", n).T                      # W = R^T R (Cholesky, upper factor)
    Wc = R.T * R
    term = (Wc * S_gu * S_uu.inv() * S_gu.T).trace()
    K = R * S_gu * Lu.T.inv()
    ck.claim("tr(W S_gu S_uu^-1 S_ug) = ||R S_gu L^-T||_F^2 >= 0 (W = R^T R, S_uu = L L^T), hence (30)",
             is_zero(term - sum(k ** 2 for k in K)))

    # (31): expansion of the weighted norm.
    gv, nv = matrix_symbols("g", n, 1), matrix_symbols("n", n, 1)
    lhs = ((gv - nv).T * W * (gv - nv))[0]
    rhs = (gv.T * W * gv)[0] + (nv.T * W * nv)[0] - 2 * (gv.T * W * nv)[0]
    ck.claim("(31): ||g - n||_W^2 = ||g||_W^2 + ||n||_W^2 - 2 g^T W n", is_zero(lhs - rhs))

    # (32): n independent of (u, v) with E n = 0: E[g^T W n] = (E g)^T W E n = 0, so
    # E||g - n||_W^2 = E||g||_W^2 + E||n||_W^2 >= E||g||_W^2, equality at n = 0.
    Sn = symmetric_matrix("sigma_n", n)
    m_n = matrix_symbols("m_n", n, 1)
    Egg = S_gg + m_g * m_g.T
    Enn = Sn + m_n * m_n.T
    Egn = m_g * m_n.T                                     # independence: E[g n^T] = E g E n^T
    second = Egg - Egn - Egn.T + Enn                      # E[(g - n)(g - n)^T]
    excess = ((W * second).trace() - (W * Egg).trace()).subs(dict(zip(m_n, [0] * n)))
    ck.claim("(32): for independent zero-mean n, E||g - n||_W^2 - E||g||_W^2 = tr(W S_nn) >= 0",
             is_zero(excess - (W * Sn).trace()))
    ck.claim("(32) needs E n = 0: with E n != 0 the cross term -2 (E g)^T W E n remains",
             not is_zero((W * second).trace() - (W * Egg).trace() - (W * Enn).trace()))

    # (33) and 0 <= J_{A,b} <= tr(W S_gg) on random joint covariances of [g; u].
    rng = np.random.default_rng(SEED)
    ok = True
    for _ in range(N_RANDOM):
        X = rng.standard_normal((5, 5))
        S = X @ X.T
        Sgg, Sgu, Suu = S[:2, :2], S[:2, 2:], S[2:, 2:]
        Y = rng.standard_normal((2, 2))
        Wn = Y @ Y.T + 1e-3 * np.eye(2)
        J = np.trace(Wn @ (Sgg - Sgu @ np.linalg.solve(Suu, Sgu.T)))
        ok &= -1e-10 <= J <= np.trace(Wn @ Sgg) + 1e-10
        # normalised with W^full: value in [0, 1]
        Jf = np.trace(np.linalg.solve(Sgg, Sgg - Sgu @ np.linalg.solve(Suu, Sgu.T))) / 2
        ok &= -1e-10 <= Jf <= 1 + 1e-10
    ck.claim(f"(33): 0 <= J_Ab <= tr(W S_gg) and W^full MoN^2 in [0, 1] on {N_RANDOM} random cases", ok)

    # The remark after (33) on when the bound is attained.
    z, v = sp.symbols("z v", real=True)
    w = sp.Symbol("w", positive=True)
    E = lambda e: gaussian_expectation(e, [z, v])

    def scalar_mon(f, pi, gamma):
        """(28) for scalar u = z ~ N(0,1) and M^2 vs the bound tr(W S_gg)."""
        g = f + pi * gamma
        Eg = E(g)
        var_g, cov_gu = E((g - Eg) ** 2), E((g - Eg) * z)
        pi_bar = E(pi)
        M2 = w * (var_g - cov_gu ** 2 - pi_bar ** 2 * E(gamma ** 2))
        return sp.simplify(M2), sp.simplify(w * var_g), sp.simplify(cov_gu)

    M2, bound, cov = scalar_mon(z ** 2, sp.Integer(1), v)      # additive: g = u^2 + v
    ck.claim("additive g = u^2 + v, S_fu = 0: bound NOT attained (M^2 = 2w < 3w = tr(W S_gg))",
             cov == 0 and is_zero(M2 - 2 * w) and is_zero(bound - 3 * w))
    ck.tex(r"g = u^2 + v:\ M^2 = ", M2)
    M2b, boundb, covb = scalar_mon(z ** 2, z, v)               # g = u^2 + u v: pi_bar = 0, E[pi~ S pi~] = 1
    ck.claim("multiplicative g = u^2 + u v with E[pi~ S pi~^T] = 1 != 0: bound attained (M^2 = 3w = tr(W S_gg))",
             covb == 0 and is_zero(M2b - boundb))
    ck.tex(r"g = u^2 + u v:\ M^2 = \operatorname{tr}(W\Sigma_{gg}) = ", M2b)
    ck.tex(r"\operatorname{tr}(W\Sigma_{gg}) - M^2 =",
           r"\operatorname{tr}(W\Sigma_{gu}\Sigma_{uu}^{-1}\Sigma_{ug}) + \operatorname{tr}(W\bar\pi\Sigma_{\gamma\gamma}\bar\pi^\top) \ge 0")
    return ck.result()


if __name__ == "__main__":
    main(check)
