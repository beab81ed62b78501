"""The moment formulas as CasADi graphs: one construction for the C export and the filters.

Each function takes the mean m and covariance P as CasADi symbols and returns
(E y, Cov y, Cov(y, w)) as expressions of the same type, SX or MX:

- :func:`export_c <symmon.codegen.export_c>` builds them in **MX**: the products with P,
  the Cholesky factor and the map over the points are matrix nodes, so the C code has
  loops and grows with the nonzeros of the derivatives, not with n_y² n²;
- the compiled filter step (:mod:`symmon.filters.gaussian.step`) builds them in **SX** for small
  filters: the same helper functions are then inlined, the constant one-hot selections
  fold away, and the whole predict + update step is one straight-line SX function; from
  ``MX_FROM`` variables on it builds them in MX too, with the blocked factor
  :func:`chol_node` (its code grows with n², not n³).

The formulas (docs/guide/transforms.md):

- **TT1**: E y ≈ g(m), Cov y ≈ J P Jᵀ, Cov(y, w) ≈ J P;
- **TT2** (Gustafsson & Hendeby 2012): E y_i ≈ g_i(m) + ½ tr(H_i P),
  Cov(y_i, y_j) ≈ J_i P J_jᵀ + ½ tr(H_i P H_j P), Cov(y, w) ≈ J P;
- **point rules** (any transform with :meth:`~symmon.transforms.base.Transform.unit_rule`:
  the UT family, Gauss–Hermite, the fifth-degree cubature): points m + L z_k with L the
  lower Cholesky factor of P (:func:`chol_lower`), E y = Σ wᵐ_k g(m + L z_k), Cov y and
  Cov(y, w) the wᶜ-weighted sums of the residual products, as
  :func:`symmon.transforms.base.weighted_moments` computes them in NumPy.

Outputs declared as angles get a wrapped mean (TT1, TT2), or the weighted circular mean
atan2(Σ wᵐ_k sin y_k, Σ wᵐ_k cos y_k) and wrapped residuals (point rules; Crouse 2015).

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman
filters", IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
D. F. Crouse, "Cubature/unscented/sigma point Kalman filtering with angular measurement
models", FUSION 2015.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Iterable, Union

import casadi as ca
import numpy as np

from ..compile.vecmath import split_parameters
from ..core.angles import wrap_casadi
from ..errors import SymmonError
from ..transforms.base import Transform

if TYPE_CHECKING:  # annotations only: the graphs are built from a compiled model handed in, never one made here
    from ..compile.compiled import CompiledModel

__all__ = ["MX_FROM", "MAX_SX_POINTS", "graph_kind", "chol_lower", "chol_function", "tril_inverse_function", "chol_node", "tril_inverse", "jacobian_products", "affine_in", "effective_order", "tt1_moments", "tt2_moments", "point_values", "point_moments", "moments", "wrap_entries", "unit_rule"]

#: A symbolic matrix: SX (inlined, straight-line code) or MX (matrix nodes, loops in C).
Sym = Union[ca.SX, ca.MX]


def chol_lower(P: Sym) -> Sym:
    """Lower Cholesky factor L (L Lᵀ = P) of a symbolic matrix, reading its lower triangle.

    Column j is one call of a step function of (L, P, j) that subtracts the projections
    on the columns before j: in MX, n calls of one piece of C, each O(n²) work, instead of
    the n³/6 scalar operations of an unrolled factor (j is an argument, so that no
    per-column constant is folded into the code); in SX the calls are inlined with j a
    constant, and the one-hot selections fold to the unrolled factor.

    A zero pivot gives a zero column, so a positive *semi*definite P with an exactly zero
    variance still works (the limit of chol(P + εI), as
    :func:`symmon.core.gaussian.matrix_sqrt`); a negative pivot gives NaN (the square root of
    a negative number), which reaches the outputs rather than a silently wrong factor.
    """
    kind = type(P)
    n = P.shape[0]
    L, Pj, j = kind.sym("L", n, n), kind.sym("P", n, n), kind.sym("j")
    idx = ca.DM(np.arange(n, dtype=float))
    e = ca.if_else(idx == j, 1, 0)  # e_j
    below = ca.if_else(idx > j, 1, 0)  # rows i > j
    v = ca.mtimes(Pj, e) - ca.mtimes(L, ca.mtimes(e.T, L).T)  # P[:, j] − L L[j, :]ᵀ
    d = ca.sqrt(ca.dot(e, v))
    # if_else: the 0/0 of the branch not taken (a zero pivot) does not reach L.
    col = ca.if_else(d > 0, below * v / d, 0) + d * e
    step = ca.Function("chol_step", [L, Pj, j], [L + ca.mtimes(col, e.T)])
    out = kind.zeros(n, n)
    for k in range(n):
        out = step(out, P, k)
    return out


@functools.lru_cache(maxsize=64)
def chol_function(n: int) -> ca.Function:
    """The lower Cholesky factor of an n × n matrix as one SX function, unrolled.

    The column-by-column factor of :func:`chol_lower` in MX repeats O(n²) work per column
    (the column index is an argument): about 5 n³ operations, against n³/6 here.  Called
    as one node of an MX graph (the compiled filter step) it keeps the C loops of the other
    matrix nodes while the factor itself is straight-line code of n³/6 multiply-adds.
    The same zero-pivot rule: a zero pivot gives a zero column, a negative one NaN.
    """
    P = ca.SX.sym("P", n, n)
    L = [[ca.SX(0)] * n for _ in range(n)]
    for j in range(n):
        d = ca.sqrt(P[j, j] - sum((L[j][k] * L[j][k] for k in range(j)), ca.SX(0)))
        L[j][j] = d
        for i in range(j + 1, n):
            v = P[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), ca.SX(0))
            L[i][j] = ca.if_else(d > 0, v / d, 0)
    out = ca.vertcat(*[ca.horzcat(*row) for row in L])
    return ca.Function(f"chol{n}", [P], [out], ["P"], ["L"], {"cse": True})


@functools.lru_cache(maxsize=64)
def tril_inverse_function(n: int) -> ca.Function:
    """The inverse of an n × n lower triangular L as one SX function, unrolled (n³/6
    multiply-adds); a zero diagonal entry gives a zero row and column, the rule of
    :func:`chol_function` for a zero pivot."""
    L = ca.SX.sym("L", n, n)
    X = [[ca.SX(0)] * n for _ in range(n)]
    for i in range(n):
        r = ca.if_else(L[i, i] > 0, 1 / L[i, i], 0)
        X[i][i] = r
        for j in range(i):
            X[i][j] = -r * sum((L[i, k] * X[k][j] for k in range(j, i)), ca.SX(0))
    out = ca.vertcat(*[ca.horzcat(*row) for row in X])
    return ca.Function(f"trilinv{n}", [L], [out], ["L"], ["Linv"], {"cse": True})


#: The block size of :func:`chol_node`: its diagonal blocks are unrolled (b³/6 operations
#: of straight-line code each), the rest are matrix products (loops in C).
CHOL_BLOCK = 8


def chol_node(P: Sym, block: int = CHOL_BLOCK) -> Sym:
    """The lower Cholesky factor of P, blocked: O(n³/3) operations and O(n²/b²) nodes.

    The right-looking block factor: L_kk = chol(A_kk − Σ_m L_km L_kmᵀ) by the unrolled
    :func:`chol_function`, L_ik = (A_ik − Σ_m L_im L_kmᵀ) L_kk⁻ᵀ with the unrolled
    :func:`tril_inverse_function`; every product is one matrix node.  In MX the C code has
    loops and grows with n², where :func:`chol_lower` costs about 5 n³ operations and an
    unrolled factor n³/6 lines of C.  A zero pivot gives a zero column, as
    :func:`chol_lower`.
    """
    n = P.shape[0]
    if n <= block:
        return chol_function(n)(P)
    edges = list(range(0, n, block)) + [n]
    spans = [(a, b) for a, b in zip(edges[:-1], edges[1:])]
    L: dict[tuple[int, int], Sym] = {}
    for k, (a, b) in enumerate(spans):
        Akk = P[a:b, a:b]
        for m in range(k):
            Akk = Akk - ca.mtimes(L[k, m], L[k, m].T)
        L[k, k] = chol_function(b - a)(Akk)
        inv_t = tril_inverse_function(b - a)(L[k, k]).T
        for i in range(k + 1, len(spans)):
            c, d = spans[i]
            Aik = P[c:d, a:b]
            for m in range(k):
                Aik = Aik - ca.mtimes(L[i, m], L[k, m].T)
            L[i, k] = ca.mtimes(Aik, inv_t)
    kind = type(P)
    rows = [ca.horzcat(*[L[i, j] if j <= i else kind.zeros(spans[i][1] - spans[i][0], spans[j][1] - spans[j][0])
                         for j in range(len(spans))]) for i in range(len(spans))]
    return ca.vertcat(*rows)


def tril_inverse(L: Sym, block: int = CHOL_BLOCK) -> Sym:
    """The inverse of a lower triangular L (the factor of :func:`chol_node` or
    :func:`chol_lower`), blocked as :func:`chol_node`: the diagonal blocks by the unrolled
    :func:`tril_inverse_function`, and X_ij = −X_ii Σ_{j ≤ m < i} L_im X_mj below them as
    matrix products.  A zero diagonal entry gives a zero row and column, as
    :func:`tril_inverse_function`."""
    n = L.shape[0]
    if n <= block:
        return tril_inverse_function(n)(L)
    edges = list(range(0, n, block)) + [n]
    spans = list(zip(edges[:-1], edges[1:]))
    X: dict[tuple[int, int], Sym] = {}
    for i, (a, b) in enumerate(spans):
        X[i, i] = tril_inverse_function(b - a)(L[a:b, a:b])
        for j in range(i):
            acc = sum((ca.mtimes(L[a:b, spans[m][0]:spans[m][1]], X[m, j]) for m in range(j, i)), 0)
            X[i, j] = -ca.mtimes(X[i, i], acc)
    kind = type(L)
    rows = [ca.horzcat(*[X[i, j] if j <= i else kind.zeros(spans[i][1] - spans[i][0], spans[j][1] - spans[j][0])
                         for j in range(len(spans))]) for i in range(len(spans))]
    return ca.vertcat(*rows)


def wrap_entries(v: Sym, idx: Iterable[int]) -> Sym:
    """``v`` with the rows ``idx`` wrapped to (−π, π] (:func:`symmon.core.angles.wrap_casadi`)."""
    rows = sorted(idx)
    if not rows:
        return v
    out = v[:, :]  # a copy: the slice assignment below must not change the caller's v
    out[rows, :] = wrap_casadi(v[rows, :])
    return out


#: A Jacobian with at most this fraction of nonzeros enters its products with P sparse.
SPARSE_JACOBIAN = 0.5


def jacobian_products(J: Sym, P: Sym) -> tuple[Sym, Sym]:
    """(J P, J P Jᵀ) for a symmetric P, with J's nonzeros only when J is sparse.

    A sparse J (at most :data:`SPARSE_JACOBIAN` of its entries nonzero, as a motion model of
    stacked targets) enters as the right factor of dense × sparse products, J P = (P Jᵀ)ᵀ
    (P = Pᵀ: no transpose of P) and (J P) Jᵀ, which CasADi writes as loops over J's nonzeros (``casadi_mtimes_dense_sparse``):
    the work is n·nnz(J) rather than n_y n², and each entry adds its terms in the order of the
    dense product, less the zero ones.  A dense J is densified, so that the products are the
    dense loops with no sparsity pattern in the C code.
    """
    if J.nnz() <= SPARSE_JACOBIAN * J.numel():
        JP = ca.mtimes(P, J.T).T
    else:
        J = ca.densify(J)
        JP = ca.mtimes(J, P)
    return JP, ca.mtimes(JP, J.T)


def tt1_moments(cm: CompiledModel, m: Sym, P: Sym, angles: Iterable[int] = ()) -> tuple[Sym, Sym, Sym]:
    """TT1 moments of g at (m, P): g(m) (angle outputs wrapped), J P Jᵀ and J P."""
    JP, cov = jacobian_products(cm.jac(m), P)
    return wrap_entries(cm.g(m), angles), cov, JP


@functools.lru_cache(maxsize=64)
def _tt2_derivatives(cm: CompiledModel) -> tuple[ca.Function, bool, np.ndarray]:
    """w ↦ (g, J, Hessian blocks or stacked Hessians), whether blocks, the supports S.

    Hessians supported on few inputs are kept as their s × s blocks B_i = H_i[S_i, S_i]
    (zero-padded to s, concatenated: s × n_y s), dense ones stacked (n_y n × n):
    whichever has fewer entries, (n_y s)² against n_y n².
    """
    w, y = cm.w_sx, cm.y_sx
    n, n_y = cm.n_w, cm.n_y
    H = cm.H_sx
    S = cm.hess_support
    s = S.shape[1]
    blocks = (n_y * s) ** 2 <= n_y * n * n
    if blocks:
        sizes = [int(k) for k in cm.hess_support_size]
        sel = [[int(a) for a in S[i, :k]] for i, k in enumerate(sizes)]
        B = ca.horzcat(*[ca.densify(ca.diagcat(H[i][sel[i], sel[i]], ca.SX(s - k, s - k)))
                         for i, k in enumerate(sizes)])
    else:
        B = ca.vertcat(*H)
    return ca.Function("derivs", [w], [y, cm.J_sx, B]), blocks, S


def _block_terms(kind: type, n: int, n_y: int, s: int) -> ca.Function:
    """(B, P, sel, ids) ↦ (½ tr(H_i P), ½ tr(H_i P H_j P)) from the s × s Hessian blocks.

    B = [B_1 … B_{n_y}] (s × n_y s) holds the blocks and sel (1 × n_y s) the inputs S_i.
    With E the one-hot selection of sel, Q = Eᵀ P E has the blocks Q_ij = P[S_i, S_j],
    and with Rᵀ = [Q_{:,1} B_1 … Q_{:,n_y} B_{n_y}] (one map over the outputs),
    tr(H_i P H_j P) = tr(R_ij R_ji) is the sum over block (j, i) of Rᵀ ∘ R.  In MX every
    step is a dense loop: no sparsity pattern or index list longer than n_y·s is written
    into the C code (sel and ids = 0…n−1 are arguments, so the selection is computed at
    run time rather than folded into a stored matrix); in SX they are constants and fold.
    """
    m = n_y * s
    B, P, sel, ids = kind.sym("B", s, m), kind.sym("P", n, n), kind.sym("sel", 1, m), kind.sym("ids", n)
    E = ca.if_else(ca.repmat(ids, 1, m) == ca.repmat(sel, n, 1), 1, 0)
    Q = ca.mtimes(ca.mtimes(P, E).T, E)
    X, Bi = kind.sym("X", m, s), kind.sym("Bi", s, s)
    Rt = ca.Function("block_times", [X, Bi], [ca.mtimes(X, Bi)]).map(n_y)(Q, B)

    def block_sums(Z: Sym, rows: int) -> Sym:
        """(n_y s × rows) ↦ (n_y × rows): sums over the s rows of each block."""
        return ca.reshape(ca.sum1(ca.reshape(Z, s, n_y * rows)), n_y, rows)

    half_tr = 0.5 * block_sums(ca.diag(Rt), 1)  # tr(Q_ii B_i)
    half_tr2 = 0.5 * block_sums(block_sums(Rt * Rt.T, m).T, n_y)
    return ca.Function("tt2_blocks", [B, P, sel, ids], [half_tr, half_tr2])


def tt2_moments(cm: CompiledModel, m: Sym, P: Sym, angles: Iterable[int] = ()) -> tuple[Sym, Sym, Sym]:
    """TT2 moments of g at (m, P) (Gustafsson & Hendeby 2012).

    g, J and the Hessians come from one SX function of w; the second-order terms go
    through the Hessian blocks (:func:`_block_terms`, (n_y s)² entries) or through H_i P
    per output (n_y n² entries), whichever is smaller.
    """
    kind = type(P)
    n, n_y = cm.n_w, cm.n_y
    derivs, blocks, S = _tt2_derivatives(cm)
    s = S.shape[1]
    y_m, J, Hm = derivs(m)
    JP, cov = jacobian_products(J, P)
    if s == 0:  # affine g
        half_tr, half_tr2 = kind(n_y, 1), kind(n_y, n_y)
    elif blocks:
        half_tr, half_tr2 = _block_terms(kind, n, n_y, s)(
            Hm, P, ca.DM(S.reshape(1, -1).astype(float)), ca.DM(np.arange(n, dtype=float)))
    else:
        HP = [ca.mtimes(ca.densify(Hm[i * n:(i + 1) * n, :]), P) for i in range(n_y)]
        half_tr = 0.5 * ca.vertcat(*[ca.trace(a) for a in HP])
        F = ca.horzcat(*[ca.vec(a) for a in HP])
        Ft = ca.horzcat(*[ca.vec(a.T) for a in HP])
        half_tr2 = 0.5 * ca.mtimes(F.T, Ft)  # ⟨H_i P, (H_j P)ᵀ⟩ = tr(H_i P H_j P)
    return wrap_entries(y_m + half_tr, angles), cov + half_tr2, JP


#: From this many variables (states plus noise symbols) on, a filter step or a batch's
#: moment function is built in MX.  The SX step is straight-line code that grows about n^2.8
#: (245 KB of C and 4-12 s of gcc at n = 10, 1.85 MB and a minute at 20); the MX step keeps
#: the matrix products, the map over the points and the solve as loops (tens of KB at any
#: n, about a second of gcc) and is as fast from about 10 states on (docs/compile.md,
#: "Filter steps").
MX_FROM = 10
#: A point rule with more points than this is built in MX at any size: unrolled, each point
#: copies g and its products with P (Gauss–Hermite of order 10 on 4 states has 10⁴ points,
#: and its SX step ran gcc for minutes); in MX the points are one map.
MAX_SX_POINTS = 64


def graph_kind(n: int, points: int = 0):
    """SX or MX for a graph of n variables and a rule of ``points`` points (0: a Taylor
    rule), and the Cholesky factor that goes with it: :func:`chol_lower` unrolled in SX,
    the blocked :func:`chol_node` in MX."""
    kind = ca.MX if n >= MX_FROM or points > MAX_SX_POINTS else ca.SX
    return kind, chol_node if kind is ca.MX else chol_lower  # unrolled factor: n³/6 operations


def unit_rule(transform: Transform, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points z (N, n) for N(0, I_n), mean and covariance weights of a point rule.

    Raises
    ------
    SymmonError
        If ``transform`` declares no points (:meth:`Transform.unit_rule` is None).
    """
    rule = transform.unit_rule(n) if isinstance(transform, Transform) else None
    if rule is None:
        raise SymmonError(f"{transform!r} is not a point rule (it declares no unit_rule): "
                          "its moments cannot be compiled as weighted sums over points")
    return rule


def _ut_scale(Z: np.ndarray) -> float:
    """c when the points Z (N, n) are the UT's 0, +c eᵢ, −c eᵢ (in that order), else 0."""
    N, n = Z.shape
    c = Z[1, 0] if N == 2 * n + 1 else 0.0
    return c if c > 0 and np.array_equal(Z, np.vstack([np.zeros(n), c * np.eye(n), -c * np.eye(n)])) else 0.0


def _offsets(L: Sym, Z: np.ndarray, c: float) -> Sym:
    """D = L Zᵀ (n × N), the offsets of the points from the mean; c = :func:`_ut_scale` of Z."""
    kind = type(L)
    N, n = Z.shape
    if c:
        # The UT's points 0, ±c eᵢ: a concatenation, no n × N constant in the C code.
        return c * ca.horzcat(kind.zeros(n, 1), L, -L)
    # Zᵀ without its zeros, added into a dense zero: the C code holds no sparsity
    # pattern of the n × N product.
    return ca.mac(L, ca.sparsify(ca.DM(Z.T)), kind.zeros(n, N))


def point_values(g: ca.Function, m: Sym, L: Sym, transform: Transform, angles: Iterable[int] = (),
                 p: Sym | None = None, circle: bool = False):
    """The parts of a point rule's moments at N(m, L Lᵀ): (Z, wᵐ, wᶜ, D, E g, R), with D = L Zᵀ
    the offsets of the points and R the residuals g(m + L z_k) − E g (angle rows wrapped).

    g is mapped over the N points m + L z_k (one loop in MX).  The mean is centred on the
    first point, as :func:`symmon.transforms.base.weighted_moments`: that keeps digits when
    the weights are large and of both signs (ut2's are about ±1e6).  With ``circle``, g is
    :meth:`~symmon.compile.CompiledModel.circle_function` of the angles: it also gives the
    sines and cosines of the angle outputs for their circular mean (a bearing's without a
    sine or a cosine).
    """
    Z, wm_a, wc_a = unit_rule(transform, m.shape[0])
    N, n = Z.shape
    Z = np.asarray(Z, dtype=float)
    c = _ut_scale(Z)
    D = _offsets(L, Z, c)
    W = ca.repmat(m, 1, N) + D
    # With parameters p, g is a function of [w; p]: the same p at every point.  In MX (a loop
    # over the points) the libm functions of p alone run once, not once per point
    # (split_parameters: the same numbers); SX straight-line code already shares them.
    split = split_parameters(g, n) if p is not None and isinstance(W, ca.MX) else None
    if split is not None:
        pre, row = split
        Y = row.map(N)(W, p, pre(p))
    else:
        Y = g.map(N)(W if p is None else ca.vertcat(W, ca.repmat(p, 1, N)))
    rows = sorted(angles)
    if circle and rows:
        k = len(rows)
        n_y = Y.shape[0] - 2 * k
        Y, sines, cosines = Y[:n_y, :], Y[n_y:n_y + k, :], Y[n_y + k:, :]
    elif rows:
        sines, cosines = ca.sin(Y[rows, :]), ca.cos(Y[rows, :])
    wm = ca.DM(np.asarray(wm_a, dtype=float))
    Y0 = Y[:, 0]
    mean = Y0 + ca.mtimes(Y - ca.repmat(Y0, 1, N), wm)
    if rows:
        mean[rows] = ca.atan2(ca.mtimes(sines, wm), ca.mtimes(cosines, wm))
    R = wrap_entries(Y - ca.repmat(mean, 1, N), rows)
    return Z, wm_a, wc_a, D, mean, R


def point_moments(g: ca.Function, m: Sym, P: Sym, transform: Transform,
                  angles: Iterable[int] = (), chol=chol_lower, p: Sym | None = None,
                  circle: bool = False) -> tuple[Sym, Sym, Sym]:
    """E g, Cov g and Cov(g, w) of w ~ N(m, P) by a point rule.

    The points and residuals are :func:`point_values` at the factor L = ``chol(P)``, and
    the weighted sums are matrix products.  ``chol`` builds the factor:
    :func:`chol_lower` (code O(n²)) or :func:`chol_node` (code O(n³), fewer operations).
    """
    L = chol(P)
    Z, _, wc_a, D, mean, R = point_values(g, m, L, transform, angles, p, circle)
    N, n = Z.shape
    c = _ut_scale(Z)
    RW = ca.mtimes(R, ca.diag(ca.DM(np.asarray(wc_a, dtype=float))))
    if c:  # D = c [0, L, −L]: RW Dᵀ = c (RW₊ − RW₋) Lᵀ, half the products
        cross = ca.mtimes(c * (RW[:, 1:n + 1] - RW[:, n + 1:]), L.T)
    else:
        cross = ca.mtimes(RW, D.T)
    return mean, ca.mtimes(RW, R.T), cross


def affine_in(cm: CompiledModel, n: int) -> bool:
    """Whether g is affine in its first n inputs: its Jacobian in them does not depend on them."""
    return not ca.depends_on(ca.vec(cm.J_sx[:, :n]), cm.w_sx[:n])


def effective_order(cm: CompiledModel, n: int, transform: Transform, angles: Iterable[int]) -> int | None:
    """The Taylor order the moments use: the rule's own (None for a point rule), or 1 for a
    rule exact to degree 2 on a g affine in its first n inputs without angle outputs, where
    TT1's closed forms are exact (:func:`moments`)."""
    order = transform.taylor_order
    if order != 1 and not angles and transform.degree(n) >= 2 and affine_in(cm, n):
        return 1
    return order


def moments(cm: CompiledModel, m: Sym, P: Sym, transform: Transform,
            angles: Iterable[int] = (), chol=chol_lower, p: Sym | None = None) -> tuple[Sym, Sym, Sym]:
    """E g, Cov g and Cov(g, w) of w ~ N(m, P) by ``transform``, chosen by its declared
    capabilities: a Taylor rule (``taylor_order`` 1 or 2) or a point rule (``unit_rule``,
    its factor built by ``chol``).

    With parameters ``p`` (a symbol of the enclosing graph), ``cm`` is the model compiled
    with respect to z = [w; p] (:func:`symmon.compile.compiled_with_params`) and p is fixed:
    the Taylor rules run at z = [m; p] with covariance blkdiag(P, 0), which gives their
    moments in w exactly (J_w P J_wᵀ, tr(H_ww P), …), and the point rules put their points
    in w only.  Cov(g, w) is returned either way.

    On a g that is affine in w, with no angle outputs, any rule whose mean is exact to
    degree 2 (:meth:`~symmon.transforms.base.Transform.degree`) gives g(m), J P Jᵀ and J P
    exactly, which are TT1's closed forms: those are built instead of the points (a linear
    motion model's time update then costs n·nnz(J), not the 2n + 1 points' n³)."""
    order = effective_order(cm, m.shape[0], transform, angles)
    if p is not None and order in (1, 2):
        kind, n_p = type(P), p.shape[0]
        mz, Pz = ca.vertcat(m, p), ca.diagcat(P, kind.zeros(n_p, n_p))
        mean, cov, cross = (tt1_moments if order == 1 else tt2_moments)(cm, mz, Pz, angles)
        return mean, cov, cross[:, :m.shape[0]]
    if order == 1:
        return tt1_moments(cm, m, P, angles)
    if order == 2:
        return tt2_moments(cm, m, P, angles)
    if angles:
        return point_moments(cm.circle_function(angles), m, P, transform, angles, chol, p, circle=True)
    return point_moments(cm.g, m, P, transform, angles, chol, p)
