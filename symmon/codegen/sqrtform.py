"""Square-root forms of the moment formulas as CasADi graphs: factors instead of covariances.

A covariance P is carried as its lower Cholesky factor S (P = S Sᵀ, diagonal ≥ 0), and
every covariance a filter step forms is a Gram matrix A Aᵀ − B Bᵀ of *columns* it never
squares:

- :func:`tria` is the lower triangular factor of A Aᵀ by Householder reflections of the
  columns of A (a QR of Aᵀ, R = Sᵀ; Golub & Van Loan 2013, Alg. 5.2.1), with the signs chosen
  so that the diagonal is ≥ 0: the factor is then *the* Cholesky factor when A Aᵀ is
  positive definite, and the sigma points taken from it are those of the standard form;
- :func:`chol_downdate` removes one column b (S' S'ᵀ = S Sᵀ − b bᵀ, Golub & Van Loan 2013
  §6.5.4), for the points of negative weight (the UT's centre, a sparse grid): a result
  that is not positive semidefinite gives NaN, never a factor of a wrong matrix;
- :func:`sqrt_moments` gives, for y = g(w), w ~ N(m, A Aᵀ), E y and the joint columns
  (Y₊, W₊; Y₋, W₋) with Cov [y; w] = [Y₊; W₊][Y₊; W₊]ᵀ − [Y₋; W₋][Y₋; W₋]ᵀ: for TT1
  Y₊ = J A, W₊ = A (Gustafsson & Hendeby 2012, eq. (10)); for TT2 also the columns of the
  second-order term, ½ tr(H_i P H_j P) = Σ_{a≤b} G_ia G_jb with G the entries of Aᵀ H_i A
  (the diagonal ones scaled by 1/√2); for a point rule √|wᶜ_k| (y_k − ȳ) and √|wᶜ_k| A z_k
  (Arasaratnam & Haykin 2009, eqs. (48)–(52) for the cubature rule; van der Merwe & Wan
  2001 for the UT with its centre weight);
- :func:`gain_factor` and :func:`residual_factor` are the measurement update: S_y = tria(Y)
  (S_y S_yᵀ = Cov y, + R with its columns), K = P^{xy} S_y⁻ᵀ S_y⁻¹ by triangular inverses,
  and S⁺ = tria(X − K Y): the Joseph form (X − K Y)(X − K Y)ᵀ = P − K S Kᵀ in factored
  form (Arasaratnam & Haykin 2009, §V; Grewal & Andrews 2015), a sum of squares that
  stays positive semidefinite in floating point, where P − K S Kᵀ is a difference that
  need not.

The same functions build SX (straight-line code, the column index a constant that folds) or
MX graphs (one step function per column called n times: loops in C, code O(1) in n), as
:func:`symmon.codegen.symbolic.chol_lower`.

References
----------
G. H. Golub, C. F. Van Loan, *Matrix Computations*, 4th ed., Johns Hopkins, 2013, §5.2
(Householder QR), §6.5.4 (Cholesky updating and downdating).
M. S. Grewal, A. P. Andrews, *Kalman Filtering: Theory and Practice with MATLAB*, 4th ed.,
Wiley, 2015 (the Joseph form and square-root filters).
R. van der Merwe, E. A. Wan, "The square-root unscented Kalman filter for state and
parameter-estimation", ICASSP 2001. doi:10.1109/ICASSP.2001.940586
I. Arasaratnam, S. Haykin, "Cubature Kalman filters", IEEE Trans. Autom. Control 54(6),
2009, §V (the square-root cubature Kalman filter). doi:10.1109/TAC.2009.2019800
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, Iterable, NamedTuple

import casadi as ca
import numpy as np

from ..errors import SymmonError
from ..transforms.base import Transform
from .symbolic import Sym, effective_order, point_values, tril_inverse, wrap_entries

if TYPE_CHECKING:  # annotations only: the graphs are built from a compiled model handed in, never one made here
    from ..compile.compiled import CompiledModel

__all__ = ["tria", "chol_downdate", "JointColumns", "sqrt_moments", "gain_factor", "residual_factor", "check_sqrt_rule",
           "chol_scaled"]

#: A rule's points reproduce the covariance when Σ wᶜ_k z_k z_kᵀ = I to this (absolute) tolerance.
UNIT_COV_TOL = 1e-10


def tria(A: Sym) -> Sym:
    """The lower triangular L with L Lᵀ = A Aᵀ and diag L ≥ 0 (n × n, A n × m).

    Householder reflections of the columns of A, row by row (a QR factorisation of Aᵀ; Golub
    & Van Loan 2013, Alg. 5.2.1): row j of the trailing block is reflected onto σ e_j (σ its
    norm), the same reflection applied to the rows below, and the sign of column j chosen so
    that σ ≥ 0 sits on the diagonal.  With A Aᵀ positive definite, L is its Cholesky factor;
    a zero row j (a direction with no variance) needs no reflection and gives a zero row of
    L, one of the factors of the singular A Aᵀ (its column j below the diagonal need not be
    zero, as that of :func:`symmon.codegen.symbolic.chol_lower` is).  Each step works on the
    trailing block only (slices, a matrix-vector product and a rank-1 update: loops in MX,
    2 n² m operations in all, O(n) nodes).
    """
    kind = type(A)
    n, m = A.shape
    if m < n:  # fewer columns than rows: zero columns change nothing
        A = ca.horzcat(A, kind.zeros(n, n - m))
        m = n
    T = ca.densify(A)
    if kind is not ca.MX:
        return _reflect(T, n)[0]
    # MX: the rows in parts of at most TRIA_PART, each one function of the generated C, so
    # that a large step's functions stay small enough for an optimised build
    # (symmon.compile.ccache.background_level); the same operations in the same order.
    parts, j = [], 0
    while j < n:
        k = min(TRIA_PART, n - j)
        outs = _tria_part(n - j, m - j, k).call([T])
        parts.append(ca.vertcat(kind.zeros(j, k), outs[0]) if j else outs[0])
        T = outs[1] if k < n - j else None
        j += k
    return ca.horzcat(*parts)


#: Rows of a part of an MX :func:`tria` (one function of the generated C each).
TRIA_PART = 24


@functools.lru_cache(maxsize=128)
def _tria_part(n: int, m: int, k: int) -> ca.Function:
    """The first k reflections of :func:`tria` on an n × m MX block: (the k columns of L,
    n × k; the trailing block after them, (n − k) × (m − k), when k < n)."""
    T = ca.MX.sym("T", n, m)
    L, rest = _reflect(T, k)
    return ca.Function(f"tria{n}x{m}p{k}", [T], [L] + ([rest] if k < n else []))


def _reflect(T: Sym, k: int) -> tuple[Sym, Sym | None]:
    """The first k reflections of :func:`tria` on the dense n × m block T (m ≥ n): the k
    columns of L (n × k), and the trailing block after them (None when k = n)."""
    kind = type(T)
    n = T.shape[0]
    cols = []
    for j in range(k):
        x = T[0, :].T
        sigma = ca.norm_2(x)
        s = ca.if_else(x[0] >= 0, 1, -1)
        v = ca.vertcat(x[0] + s * sigma, x[1:, :])
        vv = ca.dot(v, v)  # 2σ(σ + |x₀|): zero only for a zero row, which needs no reflection
        beta = ca.if_else(vv > 0, 2 / vv, 0)
        if j == n - 1:
            cols.append(ca.vertcat(kind.zeros(j, 1), sigma))
            return ca.horzcat(*cols), None
        # The rows below: w = T v (without row 0), column 0 is their new column j, and the
        # trailing block T[1:, 1:] − β w v[1:]ᵀ accumulates into the copy of its slice.
        w = beta * ca.mtimes(T, v)[1:, :]
        cols.append(ca.vertcat(kind.zeros(j, 1), sigma, -s * (T[1:, 0] - w * v[0])))
        T = ca.mac(-w, v[1:, :].T, T[1:, 1:])
    return ca.horzcat(*cols), T


def chol_downdate(L: Sym, b: Sym) -> Sym:
    """The lower factor L' of L Lᵀ − b bᵀ (diag ≥ 0): a hyperbolic rotation of each column of
    L against b (Golub & Van Loan 2013, §6.5.4), O(n²).

    A result that is not positive semidefinite gives a negative r² and NaN, which reaches
    the outputs (the filter names the step), as a negative pivot of
    :func:`symmon.codegen.symbolic.chol_lower` does.
    """
    kind = type(L)
    n = L.shape[0]
    cols = []
    for k in range(n):
        col = L[k:, k]
        lkk, bk = col[0], b[0]
        r = ca.sqrt((lkk - bk) * (lkk + bk))  # l² − b² without the cancellation of the squares
        ok = r > 0
        c = ca.if_else(ok, r / lkk, 0)
        s = ca.if_else(ok, bk / lkk, 0)
        if k == n - 1:
            cols.append(ca.vertcat(kind.zeros(k, 1), r))
            break
        below = ca.if_else(ok, (col[1:, :] - s * b[1:, :]) / c, 0)
        cols.append(ca.vertcat(kind.zeros(k, 1), r, below))
        # r = 0 from a positive pivot: the column equals ±b below it, and both vanish; a zero
        # pivot (with b_k = 0): the column stays zero and b passes unchanged.
        b = ca.if_else(ok, c * b[1:, :] - s * below, ca.if_else(lkk > 0, 0, 1) * b[1:, :])
    return ca.horzcat(*cols)


class JointColumns(NamedTuple):
    """Columns of the joint factor of [y; w]: Cov [y; w] = [Y; W][Y; W]ᵀ − [Yn; Wn][Yn; Wn]ᵀ
    (``Yn``, ``Wn`` None when no weight is negative)."""

    Y: Sym
    W: Sym
    Yn: Sym | None = None
    Wn: Sym | None = None


def check_sqrt_rule(transform: Transform, n: int) -> None:
    """Refuse a point rule whose points do not reproduce the covariance (Σ wᶜ z zᵀ ≠ I in
    n dimensions): the square-root update reads P⁻ from the points.

    Raises
    ------
    SymmonError
        Naming the rule and the dimension.
    """
    if not transform.point_rule:
        return
    Z, _, wc = transform.unit_rule(n)
    Z = np.asarray(Z, dtype=float)
    err = float(np.abs(Z.T @ (np.asarray(wc, dtype=float)[:, None] * Z) - np.eye(n)).max()) if n else 0.0
    if not err <= UNIT_COV_TOL:
        raise SymmonError(f"square_root=True: the points of {transform!r} in {n} dimensions do not reproduce "
                          f"the covariance (|Σ wc z zᵀ − I| = {err:.3g}), which the square-root update reads "
                          "from them; use a rule exact to degree 2 (UT, cubature, Gauss–Hermite of order ≥ 2)")


def _split(cols: Sym, weights: np.ndarray) -> tuple[Sym, Sym | None]:
    """(cols[:, w > 0] √w, cols[:, w < 0] √|w|): zero weights drop."""
    pos, neg = np.flatnonzero(weights > 0), np.flatnonzero(weights < 0)
    scaled = [ca.mtimes(cols[:, idx.tolist()], ca.diag(ca.DM(np.sqrt(np.abs(weights[idx]))))) if idx.size else None
              for idx in (pos, neg)]
    if scaled[0] is None:
        scaled[0] = type(cols).zeros(cols.shape[0], 1)
    return scaled[0], scaled[1]


@functools.lru_cache(maxsize=64)
def _taylor_derivatives(cm: CompiledModel, order: int) -> ca.Function:
    """w ↦ (g, J) for TT1, (g, J, H_1; …; H_{n_y}) stacked (n_y n × n) for TT2."""
    outs = [cm.y_sx, cm.J_sx] + ([ca.vertcat(*cm.H_sx)] if order == 2 else [])
    return ca.Function("derivs", [cm.w_sx], outs)


def sqrt_moments(cm: CompiledModel, m: Sym, A: Sym, transform: Transform, angles: Iterable[int] = (),
                 p: Sym | None = None) -> tuple[Sym, JointColumns]:
    """E g and the joint columns (module notes) of y = g(w), w ~ N(m, A Aᵀ), by ``transform``.

    ``A`` (n × n) is a square root of the covariance; a point rule takes its points
    m + A z_k, so A must be the lower Cholesky factor for the points of the standard form.
    With parameters ``p``, ``cm`` is compiled with respect to [w; p] and p is fixed (its
    rows of the factor are zero).
    """
    kind = type(A)
    n = m.shape[0]
    angles = sorted(angles)
    order = effective_order(cm, n, transform, angles)
    if order in (1, 2):
        z = m if p is None else ca.vertcat(m, p)
        outs = _taylor_derivatives(cm, order)(z)
        y, J = outs[0], outs[1][:, :n]
        JA = ca.mtimes(J, A)
        if order == 1:
            return wrap_entries(y, angles), JointColumns(JA, A)
        nz = z.shape[0]
        # Aᵀ H_i A per output (the w block of H_i); its entries a ≤ b are the columns of the
        # second-order term, the diagonal ones over √2: ½ ⟨Aᵀ H_i A, Aᵀ H_j A⟩ = G_i G_jᵀ.
        T = [ca.mtimes(ca.mtimes(A.T, outs[2][i * nz:i * nz + n, :n]), A) for i in range(cm.n_y)]
        half_tr = 0.5 * ca.vertcat(*[ca.trace(t) for t in T])
        upper = [(a, b) for b in range(n) for a in range(b + 1)]
        idx = [a + b * n for a, b in upper]  # column-major positions in vec
        scale = ca.DM([1 / math.sqrt(2) if a == b else 1.0 for a, b in upper])
        G = ca.horzcat(*[ca.vec(t)[idx] * scale for t in T]).T
        return (wrap_entries(y + half_tr, angles),
                JointColumns(ca.horzcat(JA, G), ca.horzcat(A, kind.zeros(n, G.shape[1]))))
    if angles:
        g = cm.circle_function(angles)
    else:
        g = cm.g
    _, _, wc, D, mean, R = point_values(g, m, A, transform, angles, p, circle=bool(angles))
    wc = np.asarray(wc, dtype=float)
    Y, Yn = _split(R, wc)
    W, Wn = _split(D, wc)
    return mean, JointColumns(Y, W, Yn, Wn)


def downdate_all(L: Sym, cols: Sym | None) -> Sym:
    """L after a rank-1 downdate by each column of ``cols`` (None: L)."""
    if cols is not None:
        for k in range(cols.shape[1]):
            L = chol_downdate(L, cols[:, k])
    return L


def gain_factor(Y: Sym, X: Sym, Yn: Sym | None = None, Xn: Sym | None = None,
                extra: Sym | None = None) -> tuple[Sym, Sym, Sym]:
    """(S_y, K̄, K) of the joint columns: S_y = tria([Y, extra]) downdated by Yn (S_y S_yᵀ =
    Cov y, the ``extra`` columns' Gram added), K̄ = P^{xy} S_y⁻ᵀ with P^{xy} = X Yᵀ − Xn Ynᵀ,
    and the gain K = K̄ S_y⁻¹ = P^{xy} (S_y S_yᵀ)⁻¹ (triangular inverses only)."""
    Sy = downdate_all(tria(Y if extra is None else ca.horzcat(Y, extra)), Yn)
    cross = ca.mtimes(X, Y.T)
    if Yn is not None:
        cross = cross - ca.mtimes(Xn, Yn.T)
    inv = tril_inverse(Sy)
    Kbar = ca.mtimes(cross, inv.T)
    return Sy, Kbar, ca.mtimes(Kbar, inv)


def residual_factor(X: Sym, Y: Sym, K: Sym, Xn: Sym | None = None, Yn: Sym | None = None,
                    extra: Sym | None = None) -> Sym:
    """tria([X − K Y, extra]) downdated by Xn − K Yn: the factor of the Joseph form
    (X − K Y)(X − K Y)ᵀ − (Xn − K Yn)(Xn − K Yn)ᵀ + extra extraᵀ, which is
    P − K P^{yx} − P^{xy} Kᵀ + K Cov y Kᵀ (+ extra extraᵀ) = P − K Cov y Kᵀ for the gain of
    :func:`gain_factor` (Arasaratnam & Haykin 2009, §V): a sum of squares, first-order
    insensitive to an error in K."""
    A = X - ca.mtimes(K, Y)
    L = tria(A if extra is None else ca.horzcat(A, extra))
    return downdate_all(L, None if Xn is None else Xn - ca.mtimes(K, Yn))


def chol_scaled(S: Sym) -> tuple[Sym, Sym]:
    """(diag(r) S, r) with r = 1/√diag(S Sᵀ): the Cholesky factor of the correlation matrix
    of P = S Sᵀ, read off the factor (no second factorisation)."""
    r = 1 / ca.sqrt(ca.sum2(S * S))
    return S * ca.repmat(r, 1, S.shape[1]), r

