"""The model-independent lemmas of the unit-invariance proofs, proved once with sympy.

Each lemma is a statement about every model of a size (matrix symbols), cross-checked on
explicit generic matrices; :func:`symmon.units.prove_invariance` combines them with a
cheap per-model check (:mod:`symmon.units.check`):

- :func:`lemma_tt2`: the TT2 moments map under the change of units (18) by A = S_y⁻¹;
- :func:`lemma_cholesky`, :func:`lemma_point_rule`: the points of the UT family,
  Gauss–Hermite and Monte Carlo map affinely, and so do their weighted moments;
- :func:`lemma_weight`: M² = tr(W D) (29) of a weight rule is unchanged under
  (Σ_gg, D) → (A Σ_gg Aᵀ, A D Aᵀ), or it is not (Liu–Li's (6), (8)).

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV, eqs. (18)–(21), (29), (34)–(43).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Sequence

import sympy as sp

from ..errors import ShapeError, SymmonError
from ..core.model import Model
from ..core.affine import Relation
from ..measures.weights import NAMED as WEIGHTS
from ..measures.weights import weighted_trace

__all__ = ["Lemma", "lemma_tt2", "lemma_cholesky", "lemma_point_rule", "lemma_weight"]


@dataclass(frozen=True)
class Lemma:
    """A model-independent statement proved with sympy.

    Attributes
    ----------
    name : str
    statement : str
    assumptions : str
    claims : tuple of (str, bool)
        Each identity checked and whether it reduced to 0.
    seconds : float
    """

    name: str
    statement: str
    assumptions: str
    claims: tuple[tuple[str, bool], ...]
    seconds: float = 0.0

    @property
    def holds(self) -> bool:
        return all(ok for _, ok in self.claims)

    def __repr__(self) -> str:
        return f"Lemma({self.name!r}, holds={self.holds})"

    def __str__(self) -> str:
        lines = [f"Lemma {self.name}: {self.statement} (assuming {self.assumptions})"]
        lines += [f"  [{'PASS' if ok else 'FAIL'}] {what}" for what, ok in self.claims]
        return "\n".join(lines)


def _sym_matrix(n: int, name: str) -> sp.Matrix:
    return sp.Matrix(n, n, lambda i, j: sp.Symbol(f"{name}_{min(i, j) + 1}{max(i, j) + 1}", real=True))


def _cancel_matrix(M: sp.Matrix) -> sp.Matrix:
    return M.applyfunc(sp.cancel)


def _half_trace_products(H: list[sp.Matrix], P: sp.Matrix) -> sp.Matrix:
    """½ [tr(H_i P H_j P)]_ij: the second-order covariance term of TT2."""
    HP = [h * P for h in H]
    n = len(H)
    return sp.Matrix(n, n, lambda i, j: sp.Rational(1, 2) * (HP[i] * HP[j]).trace())


def _tt2_moments(model: Model | Relation, mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix) -> tuple[sp.Matrix, sp.Matrix]:
    """Σ_gg and the residual covariance D of the MoN under the TT2 closed form.

    w = [u; v] ~ N([μ; 0], blkdiag(P, R)). TT2 gives Σ_gg ≈ J P_w Jᵀ + ½[tr(H_i P_w H_j P_w)]
    and Σ_gu ≈ J_u P. The residual is D = Σ_gg − Cov(E[g | v]) − Σ_gu Σ_uu⁻¹ Σ_ug
    (Straka & Havlík 2024, Sec. III, with n(v) = E[g | v] − E g for general noise: see
    docs/guide/nonlinearity.md); Cov(E[g | v]) is TT2 of g(μ, ·) in v, which vanishes for
    a noise-free model, so that D = Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug and, for additive noise,
    D = ½[tr(H_i P H_j P)] (29).
    """
    u, v = model.inputs, model.noise
    nu = len(u)
    w = list(u) + list(v)
    point = dict(zip(u, mu))
    point.update({s: sp.Integer(0) for s in v})
    g = sp.Matrix(model.outputs)
    J = g.jacobian(w).xreplace(point)
    H = [sp.hessian(gi, w).xreplace(point) for gi in g]
    Pw = sp.diag(P, R) if v else P
    Sgg = J * Pw * J.T + _half_trace_products(H, Pw)
    Sgu = J[:, :nu] * P
    D = Sgg - Sgu * _cancel_matrix(P.LUsolve(Sgu.T))
    if v:
        Jv = J[:, nu:]
        Hv = [h[nu:, nu:] for h in H]
        D = D - (Jv * R * Jv.T + _half_trace_products(Hv, R))
    return _cancel_matrix(Sgg), _cancel_matrix(D)


def _weight_label(weight: Any) -> str:
    if isinstance(weight, str):
        if weight not in WEIGHTS:
            raise SymmonError(f"unknown weight {weight!r}: use one of {WEIGHTS}, a sympy Matrix W̄ or a callable")
        return weight
    if isinstance(weight, sp.MatrixBase):
        if weight.rows != weight.cols or (weight - weight.T).applyfunc(sp.simplify) != sp.zeros(*weight.shape):
            raise SymmonError(f"weight W̄ must be a symmetric matrix, got {weight.tolist()}")
        if not weight.free_symbols and not weight.is_positive_definite:
            raise SymmonError("weight W̄ must be positive definite (41)")
        return "matrix W̄ (38)"
    if callable(weight):
        return "callable W̄ (38), (41)"
    raise SymmonError(f"weight must be one of {WEIGHTS}, a sympy Matrix W̄ or a callable, got {type(weight).__name__}")


def _general_weight(weight: Any, Sgg: sp.Matrix, sigma: Sequence[sp.Expr]) -> sp.Matrix:
    """W = S_b⁻¹ W̄ S_b⁻¹ (38) with the base-unit scale S_b = diag(σ), σ_i = √Σ_gg,ii."""
    n = Sgg.rows
    corr = sp.Matrix(n, n, lambda i, j: sp.Integer(1) if i == j else Sgg[i, j] / (sigma[i] * sigma[j]))
    Wb = weight(corr) if callable(weight) and not isinstance(weight, sp.MatrixBase) else weight
    if not isinstance(Wb, sp.MatrixBase):
        raise SymmonError(f"the weight callable must return a sympy Matrix, got {type(Wb).__name__}")
    if Wb.shape != (n, n):
        raise ShapeError(f"weight W̄ must be {n}x{n}, got {Wb.rows}x{Wb.cols}")
    Sbinv = sp.diag(*[1 / s for s in sigma])
    return Sbinv * Wb * Sbinv


def _m2(weight: Any, Sgg: sp.Matrix, D: sp.Matrix, sigma: Sequence[sp.Expr] | None = None) -> sp.Expr:
    """M² = tr(W D) for the weight rule evaluated on Σ_gg, (29) with (6), (8), (42), (43), (38)."""
    if isinstance(weight, str):
        return sp.cancel(weighted_trace(weight, Sgg, D))
    W = _general_weight(weight, Sgg, sigma)
    return sp.cancel((W * D).trace())


def _is_zero_matrix(M: Any) -> bool:
    """An explicit matrix whose entries expand to 0, or a matrix expression that reduces to 0."""
    if isinstance(M, sp.MatrixBase):
        return all(sp.cancel(e) == 0 for e in M)
    r = _reduce(M)
    return r == 0 or (isinstance(r, sp.MatrixExpr) and r.is_ZeroMatrix) or bool(getattr(r, "is_zero_matrix", False))


def _generic(name: str, rows: int, cols: int) -> sp.Matrix:
    return sp.Matrix(rows, cols, lambda i, j: sp.Symbol(f"{name}_{i + 1}{j + 1}", real=True))


@lru_cache(maxsize=None)
def lemma_tt2() -> Lemma:
    """TT2 moments are equivariant under the change of units (18).

    For ḡ(w̄) = A(g(S_w w̄ + o_w) − o_y) with A = S_y⁻¹, S_w = blkdiag(S_u, S_v),
    o_w = [o_u; 0] and w̄ ~ N(S_w⁻¹(μ_w − o_w), S_w⁻¹ P_w S_w⁻ᵀ), the TT2 closed form gives
    E ḡ = A(E g − o_y), Σ_ḡḡ = A Σ_gg Aᵀ, Σ_ḡū = A Σ_gu S_u⁻ᵀ, Σ_ūū = S_u⁻¹ P S_u⁻ᵀ,
    Cov(E[ḡ | v̄]) = A Cov(E[g | v]) Aᵀ and hence D̄ = A D Aᵀ.

    Proof (each step checked here):

    1. Chain rule. The first and second derivatives of g ∘ φ at w̄₀ depend only on the 2-jet
       of g at φ(w̄₀), so it is enough to check J̄ = A J S_w, H̄_i = Σ_k A_ik S_wᵀ H_k S_w on
       the generic quadratic g(w) = c + J(w − w₀) + ½[(w − w₀)ᵀ H_k (w − w₀)]_k; this is done
       with explicit symbolic matrices (n_u = 2, n_v = 1, n_y = 2, full S_u and A).
    2. Moments, for every size (matrix symbols): (A J S)(S⁻¹ P S⁻ᵀ)(A J S)ᵀ = A J P Jᵀ Aᵀ;
       tr(Sᵀ H_k S · S⁻¹ P S⁻ᵀ · Sᵀ H_l S · S⁻¹ P S⁻ᵀ) = tr(H_k P H_l P), so by bilinearity
       [½ tr(H̄_i P̄ H̄_j P̄)] = A [½ tr(H_k P H_l P)] Aᵀ; tr(Sᵀ H S S⁻¹ P S⁻ᵀ) = tr(H P) for the
       mean; (A J_u S_u)(S_u⁻¹ P S_u⁻ᵀ) = A Σ_gu S_u⁻ᵀ and Σ̄_gu Σ̄_uu⁻¹ Σ̄_ug = A Σ_gu P⁻¹ Σ_ug Aᵀ.
       Cov(E[g | v]) is TT2 of g(μ, ·) in v: the same identities with S_v, R.
    """
    t0 = time.perf_counter()
    claims: list[tuple[str, bool]] = []
    # 1. Chain rule on the generic 2-jet.
    nu, nv, ny = 2, 1, 2
    nw = nu + nv
    wb = sp.Matrix(sp.symbols(f"wbar1:{nw + 1}", real=True))
    wb0 = sp.Matrix(sp.symbols(f"wbar0_1:{nw + 1}", real=True))
    Su, Sv = _generic("a", nu, nu), sp.Matrix([[sp.Symbol("c", positive=True)]])
    S = sp.diag(Su, Sv)
    o = sp.Matrix(list(sp.symbols(f"o1:{nu + 1}", real=True)) + [0] * nv)
    A, oy = _generic("A", ny, ny), sp.Matrix(sp.symbols(f"oy1:{ny + 1}", real=True))
    c, J = sp.Matrix(sp.symbols(f"c1:{ny + 1}", real=True)), _generic("J", ny, nw)
    H = [_sym_matrix(nw, f"H{k + 1}") for k in range(ny)]
    w0 = S * wb0 + o  # the point, parametrised by its new-unit value (no inverse needed)

    def g(w: sp.Matrix) -> sp.Matrix:
        d = w - w0
        return c + J * d + sp.Matrix([(d.T * Hk * d)[0] / 2 for Hk in H])

    gb = A * (g(S * wb + o) - oy)
    at = dict(zip(wb, wb0))
    Jb = gb.jacobian(wb).xreplace(at)
    claims.append(("chain rule: J̄ = S_y⁻¹ J S_w (explicit, n_u=2, n_v=1, n_y=2)", _is_zero_matrix(Jb - A * J * S)))
    ok = all(
        _is_zero_matrix(sp.hessian(gb[i], wb).xreplace(at) - sum((A[i, k] * S.T * H[k] * S for k in range(ny)), sp.zeros(nw, nw)))
        for i in range(ny)
    )
    claims.append(("chain rule: H̄_i = Σ_k (S_y⁻¹)_ik S_wᵀ H_k S_w (explicit)", ok))
    # 2. The moment identities for every size.
    n, m, p = 3, 2, 4  # sizes are placeholders: the reductions never look at entries
    Am, Sm = sp.MatrixSymbol("A", n, n), sp.MatrixSymbol("S", p, p)
    Jm, Hk, Hl = sp.MatrixSymbol("J", n, p), sp.MatrixSymbol("H_k", p, p), sp.MatrixSymbol("H_l", p, p)
    Pm = sp.MatrixSymbol("P", p, p)
    Pb = Sm.I * Pm * Sm.I.T
    Jbm = Am * Jm * Sm
    claims.append(("first-order term: J̄ P̄ J̄ᵀ = A J P Jᵀ Aᵀ (any size)",
                   _is_zero_matrix(Jbm * Pb * Jbm.T - Am * Jm * Pm * Jm.T * Am.T)))
    hk, hl = Sm.T * Hk * Sm, Sm.T * Hl * Sm
    claims.append(("second-order term: tr(H̄_k P̄ H̄_l P̄) = tr(H_k P H_l P) (any size)",
                   _reduce(sp.Trace(hk * Pb * hl * Pb) - sp.Trace(Hk * Pm * Hl * Pm)) == 0))
    claims.append(("mean term: tr(H̄_k P̄) = tr(H_k P) (any size)", _reduce(sp.Trace(hk * Pb) - sp.Trace(Hk * Pm)) == 0))
    Ju, Sum_, Pu = sp.MatrixSymbol("J_u", n, m), sp.MatrixSymbol("S_u", m, m), sp.MatrixSymbol("P_u", m, m)
    Sgu_b = Am * Ju * Sum_ * (Sum_.I * Pu * Sum_.I.T)
    claims.append(("cross-covariance: Σ̄_gu = A Σ_gu S_u⁻ᵀ (any size)", _is_zero_matrix(Sgu_b - Am * Ju * Pu * Sum_.I.T)))
    Suu_b = Sum_.I * Pu * Sum_.I.T
    proj_b = Sgu_b * Suu_b.I * Sgu_b.T
    claims.append(("projection: Σ̄_gu Σ̄_uu⁻¹ Σ̄_ug = A Σ_gu P⁻¹ Σ_ug Aᵀ (any size)",
                   _is_zero_matrix(proj_b - Am * (Ju * Pu) * Pu.I * (Ju * Pu).T * Am.T)))
    return Lemma(
        "tt2-equivariance",
        "the TT2 moments of ḡ are those of g mapped by S_y⁻¹ (and S_u⁻¹): Σ_ḡḡ = S_y⁻¹ Σ_gg S_y⁻ᵀ, D̄ = S_y⁻¹ D S_y⁻ᵀ",
        "S_u, S_v, S_y invertible; g twice differentiable at the mean; P (and R) positive definite",
        tuple(claims), time.perf_counter() - t0,
    )


@lru_cache(maxsize=None)
def lemma_cholesky() -> Lemma:
    """chol(S⁻¹ P S⁻ᵀ) = S⁻¹ chol(P) for a lower-triangular S with a positive diagonal.

    L̄ = S⁻¹ L is lower triangular with the positive diagonal l_ii / s_ii (checked on explicit
    3×3 matrices; the inverse and the product of lower-triangular matrices are lower
    triangular for every size) and L̄ L̄ᵀ = S⁻¹ L Lᵀ S⁻ᵀ (any size); the Cholesky factor is
    unique, so L̄ is it. A full S rotates the sigma points: the lemma needs the triangle.
    """
    t0 = time.perf_counter()
    n = 3
    S = sp.Matrix(n, n, lambda i, j: sp.Symbol(f"s_{i + 1}{j + 1}", real=True, positive=(i == j) or None) if j <= i else 0)
    L = sp.Matrix(n, n, lambda i, j: sp.Symbol(f"l_{i + 1}{j + 1}", real=True, positive=(i == j) or None) if j <= i else 0)
    Lb = (S.inv() * L).applyfunc(sp.cancel)
    tri = all(Lb[i, j] == 0 for i in range(n) for j in range(i + 1, n))
    pos = all(Lb[i, i].is_positive for i in range(n))
    Sm, Lm = sp.MatrixSymbol("S", n, n), sp.MatrixSymbol("L", n, n)
    prod = _is_zero_matrix((Sm.I * Lm) * (Sm.I * Lm).T - Sm.I * (Lm * Lm.T) * Sm.I.T)
    return Lemma(
        "cholesky-equivariance",
        "chol(S⁻¹ P S⁻ᵀ) = S⁻¹ chol(P)",
        "S lower triangular with a positive diagonal (e.g. a positive diagonal scale); P positive definite",
        (("S⁻¹L is lower triangular (explicit 3×3)", tri), ("its diagonal l_ii/s_ii is positive", pos),
         ("(S⁻¹L)(S⁻¹L)ᵀ = S⁻¹ P S⁻ᵀ (any size)", prod)),
        time.perf_counter() - t0,
    )


@lru_cache(maxsize=None)
def lemma_point_rule() -> Lemma:
    """Moments of a point rule map affinely when its points do.

    A rule with points χ_i = μ + L z_i (fixed standardised nodes z_i: sigma points, Gauss–Hermite
    nodes, or the same seeded Monte Carlo draws), mean weights w_i with Σ w_i = 1 and any
    covariance weights c_i, gives m = Σ w_i g(χ_i), Σ_gg = Σ c_i (Y_i − m)(Y_i − m)ᵀ,
    Σ_gu = Σ c_i (Y_i − m)(χ_i − μ)ᵀ. With L̄ = S⁻¹L (:func:`lemma_cholesky`) the new points
    are χ̄_i = S⁻¹(χ_i − o) (any size), the new values Ȳ_i = ḡ(χ̄_i) = A(Y_i − o_y) by the
    definition of ḡ, and then m̄ = A(m − o_y), Σ_ḡḡ = A Σ_gg Aᵀ, Σ_ḡū = A Σ_gu S⁻ᵀ (explicit:
    three points, n = n_y = 2, generic A and S).
    """
    t0 = time.perf_counter()
    claims: list[tuple[str, bool]] = []
    n = 3
    Sm, Lm = sp.MatrixSymbol("S", n, n), sp.MatrixSymbol("L", n, n)
    mu, o, z = sp.MatrixSymbol("mu", n, 1), sp.MatrixSymbol("o", n, 1), sp.MatrixSymbol("z", n, 1)
    chi_b = Sm.I * (mu - o) + (Sm.I * Lm) * z
    claims.append(("points: μ̄ + L̄ z = S⁻¹(μ + L z − o) (any size)", _is_zero_matrix(chi_b - Sm.I * (mu + Lm * z - o))))
    N, k = 3, 2
    A, S = _generic("A", k, k), _generic("S", k, k)
    oy = sp.Matrix(sp.symbols(f"oy1:{k + 1}", real=True))
    w = list(sp.symbols(f"w1:{N}", real=True))
    w.append(1 - sum(w))  # Σ w_i = 1
    cw = sp.symbols(f"c1:{N + 1}", real=True)
    Y = [_generic(f"Y{i + 1}", k, 1) for i in range(N)]
    X = [_generic(f"X{i + 1}", k, 1) for i in range(N)]
    mx = sp.Matrix(sp.symbols(f"mu1:{k + 1}", real=True))
    Sinv = S.adjugate()  # S⁻¹ up to the factor 1/det S, which a linear identity carries through
    det = S.det()

    def moments(Ys: list, Xs: list, mxs: sp.Matrix) -> tuple:
        m = sum((wi * Yi for wi, Yi in zip(w, Ys)), sp.zeros(k, 1))
        cyy = sum((ci * (Yi - m) * (Yi - m).T for ci, Yi in zip(cw, Ys)), sp.zeros(k, k))
        cyx = sum((ci * (Yi - m) * (Xi - mxs).T for ci, Yi, Xi in zip(cw, Ys, Xs)), sp.zeros(k, k))
        return m, cyy, cyx

    m, cyy, cyx = moments(Y, X, mx)
    # New units: X̄ = S⁻¹(X − o) = adj(S)(X − o)/det S; the offset o cancels in X − μ.
    ou = sp.Matrix(sp.symbols(f"ou1:{k + 1}", real=True))
    mb, cyyb, cyxb = moments([A * (Yi - oy) for Yi in Y], [Sinv * (Xi - ou) / det for Xi in X], Sinv * (mx - ou) / det)
    claims.append(("mean: m̄ = A(m − o_y) (explicit)", _is_zero_matrix(mb - A * (m - oy))))
    claims.append(("covariance: Σ̄_gg = A Σ_gg Aᵀ (explicit)", _is_zero_matrix(cyyb - A * cyy * A.T)))
    claims.append(("cross-covariance: Σ̄_gu = A Σ_gu S⁻ᵀ (explicit)", _is_zero_matrix(cyxb - A * cyx * Sinv.T / det)))
    return Lemma(
        "point-rule-equivariance",
        "the moments of a point rule (UT, Gauss–Hermite, Monte Carlo) of ḡ are those of g mapped by S_y⁻¹ and S_u⁻¹",
        "points μ + L z_i with L = chol(P) and fixed nodes z_i (same seed for Monte Carlo); Σ w_i = 1; "
        "outputs not wrapped as angles",
        tuple(claims), time.perf_counter() - t0,
    )


@dataclass(frozen=True)
class _WeightPart:
    lemma: Lemma
    lhs: sp.Expr
    rhs: sp.Expr
    difference: sp.Expr
    G: sp.Matrix
    E: sp.Matrix
    s_y: tuple[sp.Symbol, ...]
    sigma: tuple[sp.Symbol, ...] | None


def lemma_weight(weight: Any, n_y: int) -> Lemma:
    """M² = tr(W D) of the weight rule is unchanged under (Σ_gg, D) → (A Σ_gg Aᵀ, A D Aᵀ).

    A = S_y⁻¹ is a symbolic positive diagonal matrix and Σ_gg, D are generic symmetric
    n_y×n_y matrices; the lemma fails (with the nonzero difference) for Liu–Li's (6), (8).
    """
    return _weight_part(weight, n_y).lemma


def _weight_part(weight: Any, n_y: int) -> _WeightPart:
    if isinstance(weight, str):
        return _weight_part_cached(weight, n_y)
    return _weight_part_uncached(weight, n_y)


@lru_cache(maxsize=None)
def _weight_part_cached(weight: str, n_y: int) -> _WeightPart:
    return _weight_part_uncached(weight, n_y)


def _weight_part_uncached(weight: Any, n_y: int) -> _WeightPart:
    t0 = time.perf_counter()
    label = _weight_label(weight)
    s_y = tuple(sp.Symbol(f"s_y{i + 1}", positive=True) for i in range(n_y))
    if label == "full":
        # (43) for every size and any invertible S_y, by matrix algebra alone: explicit
        # symbolic inverses of 3×3 matrices take minutes.
        G, E = sp.MatrixSymbol("Sigma_gg", n_y, n_y), sp.MatrixSymbol("D", n_y, n_y)
        A = sp.MatrixSymbol("A", n_y, n_y)
        lhs, rhs = sp.Trace(G.I * E) / n_y, sp.Trace((A * G * A.T).I * (A * E * A.T)) / n_y
        d = _reduce(lhs - rhs)
        lemma = Lemma(
            "weight-full", "tr(Σ_gg⁻¹ D)/n_y (43) is unchanged when Σ_gg, D → A Σ_gg Aᵀ, A D Aᵀ (A = S_y⁻¹, any size)",
            "S_y invertible (any, not only diagonal); Σ_gg nonsingular",
            ((f"tr((AΣAᵀ)⁻¹ A D Aᵀ) − tr(Σ⁻¹ D) = {d}", d == 0),), time.perf_counter() - t0,
        )
        return _WeightPart(lemma, lhs, rhs, d, G, E, s_y, None)
    Ainv = sp.diag(*[1 / s for s in s_y])
    G, E = _sym_matrix(n_y, "Sigma"), _sym_matrix(n_y, "D")
    G_b, E_b = Ainv * G * Ainv, Ainv * E * Ainv
    sigma = sigma_b = None
    if label not in WEIGHTS:
        # Base units have unit variances: S_b = diag(σ), σ_i = √Σ_gg,ii > 0. In the new units
        # σ̄_i = √Σ_ḡḡ,ii = σ_i √(Σ_ḡḡ,ii / Σ_gg,ii), exact because both roots are positive.
        sigma = tuple(sp.Symbol(f"sigma_y{i + 1}", positive=True) for i in range(n_y))
        sigma_b = [sigma[i] * sp.sqrt(sp.cancel(G_b[i, i] / G[i, i])) for i in range(n_y)]
    lhs = _m2(weight, G, E, sigma)
    rhs = _m2(weight, G_b, E_b, sigma_b)
    d = sp.cancel(sp.together(lhs - rhs))
    lemma = Lemma(
        f"weight-{label if label in WEIGHTS else 'general'} (n_y={n_y})",
        f"M² with weight {label!r} is unchanged when Σ_gg, D → S_y⁻¹ Σ_gg S_y⁻¹, S_y⁻¹ D S_y⁻¹",
        "S_y positive diagonal; Σ_gg nonsingular (full) or with positive diagonal (diag, W̄)",
        ((f"M²(Σ_gg, D) − M²(S_y⁻¹Σ_gg S_y⁻¹, S_y⁻¹D S_y⁻¹) = {'0' if d == 0 else 'a nonzero expression'}", d == 0),),
        time.perf_counter() - t0,
    )
    return _WeightPart(lemma, lhs, rhs, d, G, E, s_y, sigma)


def _best_rotation(tr: sp.Trace) -> sp.Expr:
    """tr(A₁⋯A_k) = tr(A_j⋯A_k A₁⋯A_{j−1}): the rotation after which most factors cancel."""
    arg = tr.arg
    if not isinstance(arg, sp.MatMul):
        return tr
    coeff, mats = arg.as_coeff_matrices()
    best = arg
    for k in range(1, len(mats)):
        cand = sp.MatMul(*(mats[k:] + mats[:k])).doit()
        n_c = len(cand.args) if isinstance(cand, sp.MatMul) else 1
        n_b = len(best.as_coeff_matrices()[1]) if isinstance(best, sp.MatMul) else 1
        if n_c < n_b:
            best = cand
    return coeff * sp.Trace(best)


def _reduce(expr: sp.Expr) -> sp.Expr:
    """Matrix-algebra simplification: (ABC)⁻¹ = C⁻¹B⁻¹A⁻¹, X X⁻¹ = I, linearity and cyclicity of tr."""
    e = sp.expand(expr.doit())
    e = e.replace(lambda x: isinstance(x, sp.Trace), _best_rotation)
    return sp.expand(e.doit())
