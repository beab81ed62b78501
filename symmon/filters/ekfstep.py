"""The EKF step of larger filters in hand-written C around CasADi's model pieces.

For the Taylor-1 rule (TT1) with additive noise, the step of :mod:`symmon.filters.step` is

    x⁻ = f(x),  P⁻ = F P Fᵀ + Q,  ŷ = h(x⁻),  S = H P⁻ Hᵀ + R,  P^{xy} = P⁻ Hᵀ,
    L Lᵀ = S,  Wᵀ = P^{xy} L⁻ᵀ,  x⁺ = x⁻ + Wᵀ L⁻¹ ν,  P⁺ = P⁻ − Wᵀ W

(Gustafsson & Hendeby 2012, Lemma 7.1 with the TT1 moments; F and H the Jacobians of f and h).
CasADi generates the elementwise model pieces — f(x) with the angle states wrapped and the
nonzeros of F; the wrapped innovation y − h(x⁻) and the nonzeros of H — and the dense
linear algebra is a C function written here:

- the products with the Jacobians run over their nonzeros only (the sparsity pattern of F
  and H, compressed by columns, is a constant of the C code): n·nnz(F) and n·nnz(H)
  multiply-adds, where a block-diagonal F of stacked targets has a few nonzeros a row;
- every product with a dense matrix is a loop of contiguous axpy updates of columns
  (column-major, as CasADi), which the compiler vectorises;
- S is factored by a Cholesky factor (n_y³/6), Wᵀ = P^{xy} L⁻ᵀ and L⁻¹ ν by forward
  substitution (n n_y²/2), and P⁺ = P⁻ − Wᵀ W is computed on its lower triangle only
  (n² n_y / 2) and mirrored, the rule of :func:`symmon.filters.step.sym`.

The results are those of the MX step to rounding: the same formulas, the same zero-pivot
rule (a zero pivot of S gives a zero column of L and a zero row and column of L⁻¹; a
negative one a NaN log-likelihood), the same masking of missing components
(:func:`symmon.filters.step.update_graph`).

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..codegen.symbolic import wrap_entries
from ..compile import compiled, compiled_with_params
from ..core.model import Model

#: From this many states on, a TT1 step with additive noise runs the C step of this module
#: (below, the straight-line SX step is as fast and its compile policy is unchanged).
C_EKF_FROM = 10


def _model_part(model: Model, m, p):
    """g(m) and its Jacobian in m (sparse SX), with the parameters ``p`` (None: none) fixed."""
    n = m.shape[0]
    if model.n_p:
        cm = compiled_with_params(model)
        z = ca.vertcat(m, p)
        return cm.g(z), cm.jac(z)[:, :n]
    cm = compiled(model)
    return cm.g(m), cm.jac(m)


def _pattern(J: ca.SX) -> tuple[list[int], list[int], ca.SX]:
    """The CSC pattern (column starts, rows) of J and its nonzeros as a column (one zero
    entry if J has none, so that no C array is empty)."""
    sp = J.sparsity()
    nz = J.nonzeros()
    return list(sp.colind()), list(sp.row()), ca.vertcat(*nz) if nz else ca.SX.zeros(1)


def ekf_pieces(f: Model, h: Model, angle_states: frozenset[int], p_f, p_h, x, y, p,
               name: str) -> tuple[tuple[ca.Function, ...], dict]:
    """The SX pieces of the C step and the Jacobians' patterns.

    ``{name}_fpart``: (x, p) ↦ (x⁻, nonzeros of F), x⁻ = f(x) with the angle states wrapped
    (twice, as the MX step: the TT1 mean, then the prediction); ``{name}_hpart``:
    (x⁻, y, p) ↦ (ν, nonzeros of H), ν = y − h(x⁻) wrapped on the angle outputs;
    ``{name}_xwrap``: x ↦ x with the angle states wrapped.  ``p_f``, ``p_h``: the entries of
    the filter's parameter symbol ``p`` that f and h use (None: none); x, y, p are SX symbols.
    """
    y_angles = frozenset(h.angle_outputs)
    fx, F = _model_part(f, x, p_f)
    x_pred = wrap_entries(wrap_entries(fx, angle_states), angle_states)
    hx, H = _model_part(h, x, p_h)
    nu = wrap_entries(y - wrap_entries(hx, y_angles), y_angles)
    f_col, f_row, f_nz = _pattern(F)
    h_col, h_row, h_nz = _pattern(H)
    opts = {"cse": True}
    fpart = ca.Function(f"{name}_fpart", [x, p], [x_pred, f_nz], opts)
    hpart = ca.Function(f"{name}_hpart", [x, y, p], [nu, h_nz], opts)
    xwrap = ca.Function(f"{name}_xwrap", [x], [wrap_entries(x, angle_states)], opts)
    return (fpart, hpart, xwrap), {"f_col": f_col, "f_row": f_row, "h_col": h_col, "h_row": h_row,
                                    "wrap_x": bool(angle_states)}


def _ints(values: list[int]) -> str:
    return "{" + ",".join(str(int(v)) for v in (values or [0])) + "}"


# The C step: column-major arrays (CasADi's layout), every dense product an axpy of columns.
_STEP = """
/* symmon: the EKF step {name}_ekf (TT1, additive noise) around the CasADi pieces
   {name}_fpart, {name}_hpart, {name}_xwrap; the linear algebra of symmon.filters.ekfstep.
   arg: x, P, y, Q, R, mask, p; res: x+, P+, x-, P-, nu, S, loglik, nis (null: not kept; then
   scratch).  s: scratch of {name}_ekf_scratch reals. */
#include <math.h>
#include <stdlib.h>
/* The loops below are a few KB of C: optimised even when the whole file is large enough (the
   NEES function of a large filter) for the compile policy's -O0 build.  No FMA contraction,
   as every build (the same results at any level). */
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC optimize ("O3", "fp-contract=off")
#endif
#define {name}_N {n}
#define {name}_NY {n_y}
static const casadi_int {name}_fcol[] = {f_col};
static const casadi_int {name}_frow[] = {f_row};
static const casadi_int {name}_hcol[] = {h_col};
static const casadi_int {name}_hrow[] = {h_row};
static const casadi_int {name}_ekf_scratch = {scratch};

/* The lower triangle of the n x n matrix A mirrored into its upper one, in blocks. */
static void {name}_mirror(casadi_real* A, casadi_int n) {{
  casadi_int i, j, i0, j0;
  for (j0 = 0; j0 < n; j0 += 16)
    for (i0 = j0; i0 < n; i0 += 16)
      for (j = j0; j < n && j < j0 + 16; ++j)
        for (i = i0 > j + 1 ? i0 : j + 1; i < n && i < i0 + 16; ++i) A[j + i * n] = A[i + j * n];
}}

/* A (n x m) = B (n x k) Jt, Jt the transpose of the sparse J (m x k, CSC col/row/nz):
   A[:, i] += J[i, c] B[:, c] over the nonzeros, contiguous column updates. */
static void {name}_times_jt(casadi_real* restrict A, const casadi_real* restrict B, const casadi_int* col, const casadi_int* row,
    const casadi_real* nz, casadi_int n, casadi_int m, casadi_int k) {{
  casadi_int c, e, i;
  for (i = 0; i < n * m; ++i) A[i] = 0;
  for (c = 0; c < k; ++c)
    for (e = col[c]; e < col[c + 1]; ++e) {{
      casadi_real v = nz[e];
      casadi_real* a = A + row[e] * n;
      const casadi_real* b = B + c * n;
      for (i = 0; i < n; ++i) a[i] += v * b[i];
    }}
}}

/* B (m x n) = A^T, A n x m: blocked, so that both sides stay in cache. */
static void {name}_transpose(casadi_real* restrict B, const casadi_real* restrict A, casadi_int n, casadi_int m) {{
  casadi_int i, j, i0, j0;
  for (j0 = 0; j0 < m; j0 += 16)
    for (i0 = 0; i0 < n; i0 += 16)
      for (j = j0; j < m && j < j0 + 16; ++j)
        for (i = i0; i < n && i < i0 + 16; ++i) B[j + i * m] = A[i + j * n];
}}

/* a[k] -= sum_i c_i[k] l_i for k < len, the columns c_i = C + i n (i < m) and coefficients
   l_i = l[i * ld]: four columns a pass (one load and store of a per four products), each
   subtracted in turn, so that it rounds as the plain loop over i. */
static void {name}_sub_cols(casadi_real* restrict a, const casadi_real* restrict C, casadi_int n,
    const casadi_real* l, casadi_int ld, casadi_int m, casadi_int len) {{
  casadi_int i = 0, k;
  for (; i + 4 <= m; i += 4) {{
    const casadi_real *c0 = C + i * n, *c1 = c0 + n, *c2 = c1 + n, *c3 = c2 + n;
    casadi_real l0 = l[i * ld], l1 = l[(i + 1) * ld], l2 = l[(i + 2) * ld], l3 = l[(i + 3) * ld];
    for (k = 0; k < len; ++k) {{
      casadi_real t = a[k];
      t -= c0[k] * l0;
      t -= c1[k] * l1;
      t -= c2[k] * l2;
      t -= c3[k] * l3;
      a[k] = t;
    }}
  }}
  for (; i < m; ++i) {{
    const casadi_real* c0 = C + i * n;
    casadi_real l0 = l[i * ld];
    for (k = 0; k < len; ++k) a[k] -= c0[k] * l0;
  }}
}}

/* The linearised update at xl (xl = x-: the EKF's; else an iteration of the IEKF, whose
   residual is y - h(xl) - H (x- - xl)): nu (masked), Ct -> W^T = P^xy L^-T, S (masked), L,
   r (reciprocal pivots), wh = L^-1 nu; adds |wh|^2, sum log L_ii and the measured count
   into acc[0..2].  dx: n reals of scratch. */
static int {name}_linearised(const casadi_real* xl, const casadi_real* xp, const casadi_real* Pp,
    const casadi_real* y, const casadi_real* R, const casadi_real* mask, const casadi_real* p,
    casadi_int* iw, casadi_real* w, casadi_real* nu, casadi_real* Hz, casadi_real* Ct, casadi_real* A,
    casadi_real* S, casadi_real* L, casadi_real* r, casadi_real* wh, casadi_real* dx, casadi_real* acc) {{
  const casadi_int n = {name}_N, ny = {name}_NY;
  const casadi_real* a2[3];
  casadi_real* r2[2];
  casadi_int i, j, k, e;
  /* nu = y - h(xl) (angle outputs wrapped), H's nonzeros at xl. */
  a2[0] = xl; a2[1] = y; a2[2] = p; r2[0] = nu; r2[1] = Hz;
  if ({name}_hpart(a2, r2, iw, w, 0)) return 1;
  if (xl != xp) {{
    for (j = 0; j < n; ++j) dx[j] = xp[j] - xl[j];
    for (j = 0; j < n; ++j)
      for (e = {name}_hcol[j]; e < {name}_hcol[j + 1]; ++e) nu[{name}_hrow[e]] -= Hz[e] * dx[j];
  }}
  /* Ct = P- H^T (the cross-covariance P^xy, n x ny), S = H Ct + R, lower mirrored. */
  {name}_times_jt(Ct, Pp, {name}_hcol, {name}_hrow, Hz, n, ny, n);
  {name}_transpose(A, Ct, n, ny);  /* H P- = Ct^T */
  {name}_times_jt(S, A, {name}_hcol, {name}_hrow, Hz, ny, ny, n);
  for (i = 0; i < ny * ny; ++i) S[i] += R[i];
  {name}_mirror(S, ny);
  /* The measured block: D nu, D S D + (I - D), P^xy D (update_graph's masking). */
  for (i = 0; i < ny; ++i) {{
    casadi_real m = mask[i];
    acc[2] += m;
    nu[i] *= m;
    for (j = 0; j < ny; ++j) S[i + j * ny] *= m * mask[j];
    S[i + i * ny] += 1 - m;
    for (k = 0; k < n; ++k) Ct[k + i * n] *= m;
  }}
  /* L L^T = S, right-looking: column j scaled, then subtracted from the columns after it
     (contiguous updates; each entry sees the same subtractions in the same order as the
     left-looking sums).  A zero pivot gives a zero column, a negative one NaN on the diagonal. */
  for (j = 0; j < ny; ++j)
    for (i = 0; i < ny; ++i) L[i + j * ny] = i >= j ? S[i + j * ny] : 0;
  for (j = 0; j < ny; ++j) {{
    casadi_real d = sqrt(L[j + j * ny]);
    casadi_real* lj = L + j * ny;
    for (i = j + 1; i < ny; ++i) lj[i] = d > 0 ? lj[i] / d : 0;
    lj[j] = d;
    r[j] = d > 0 ? 1 / d : 0;  /* a zero (or NaN) pivot: a zero row of the inverse */
    for (k = j + 1; k < ny; ++k) {{
      casadi_real l = lj[k];
      casadi_real* lk = L + k * ny;
      for (i = k; i < ny; ++i) lk[i] -= lj[i] * l;
    }}
  }}
  /* W^T = Ct L^-T and L^-1 nu, by forward substitution, column by column. */
  for (i = 0; i < ny; ++i) {{
    casadi_real* c = Ct + i * n;
    casadi_real v = nu[i];
    {name}_sub_cols(c, Ct, n, L + i, ny, i, n);
    for (k = 0; k < i; ++k) v -= L[i + k * ny] * wh[k];
    for (j = 0; j < n; ++j) c[j] *= r[i];
    wh[i] = r[i] * v;
    acc[0] += wh[i] * wh[i];
    acc[1] += log(L[i + i * ny]);
  }}
  return 0;
}}

static int {name}_ekf(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w,
    casadi_real* s) {{
  const casadi_int n = {name}_N, ny = {name}_NY;
  const casadi_real *x = arg[0], *P = arg[1], *y = arg[2], *Q = arg[3], *R = arg[4], *mask = arg[5], *p = arg[6];
  casadi_real *xp = res[2] ? res[2] : s, *Pp = res[3] ? res[3] : s + n;
  casadi_real *A = s + n + n * n, *Fz = A + n * n, *Hz = Fz + {f_nnz}, *nu = res[4] ? res[4] : Hz + {h_nnz};
  casadi_real *Ct = Hz + {h_nnz} + ny, *S = res[5] ? res[5] : Ct + n * ny, *L = Ct + n * ny + ny * ny;
  casadi_real *wh = L + ny * ny, *r = wh + ny, *xn = r + ny, *xl = xn + n, *dx = xl + n;
  casadi_real *nu2 = dx + n, *S2 = nu2 + ny, *wh2 = S2 + ny * ny, *wx = wh;
  casadi_real *Pn = res[1], acc[3] = {{0, 0, 0}}, acc2[3] = {{0, 0, 0}};
  const casadi_real* a2[2];
  casadi_real* r2[2];
  casadi_int i, j, k, it;
  /* x- = f(x) (angle states wrapped), F's nonzeros. */
  a2[0] = x; a2[1] = p; r2[0] = xp; r2[1] = Fz;
  if ({name}_fpart(a2, r2, iw, w, 0)) return 1;
  /* P- = F (P F^T) + Q, lower triangle mirrored. */
  {name}_times_jt(Pp, P, {name}_fcol, {name}_frow, Fz, n, n, n);
  {name}_transpose(A, Pp, n, n);  /* F P = (P F^T)^T: P is symmetric */
  {name}_times_jt(Pp, A, {name}_fcol, {name}_frow, Fz, n, n, n);
  for (i = 0; i < n * n; ++i) Pp[i] += Q[i];
  {name}_mirror(Pp, n);
  /* The update at x-: its nu, S, NIS and log-likelihood are the step's. */
  if ({name}_linearised(xp, xp, Pp, y, R, mask, p, iw, w, nu, Hz, Ct, A, S, L, r, wh, dx, acc)) return 1;
  /* x+ = x- + W^T (L^-1 nu); the IEKF's Gauss-Newton steps relinearise h at x+. */
  for (it = 0; it < {iterations}; ++it) {{
    if (it) {{
      for (j = 0; j < n; ++j) xl[j] = xn[j];
      if ({name}_linearised(xl, xp, Pp, y, R, mask, p, iw, w, nu2, Hz, Ct, A, S2, L, r, wh2, dx, acc2)) return 1;
      wx = wh2;
    }}
    for (j = 0; j < n; ++j) xn[j] = xp[j];
    for (i = 0; i < ny; ++i) {{
      const casadi_real* c = Ct + i * n;
      for (j = 0; j < n; ++j) xn[j] += c[j] * wx[i];
    }}
  }}
  if ({wrap_x}) {{
    a2[0] = xn; r2[0] = res[0];
    if ({name}_xwrap(a2, r2, iw, w, 0)) return 1;
  }} else {{
    for (j = 0; j < n; ++j) res[0][j] = xn[j];
  }}
  /* P+ = P- - W^T W (the last linearisation's W) on the lower triangle, mirrored. */
  for (j = 0; j < n; ++j) {{
    casadi_real* pn = Pn + j * n;
    const casadi_real* pp = Pp + j * n;
    for (k = j; k < n; ++k) pn[k] = pp[k];
    {name}_sub_cols(pn + j, Ct + j, n, Ct + j, n, ny, n - j);
  }}
  {name}_mirror(Pn, n);
  if (res[6]) res[6][0] = -0.5 * (acc[0] + 2 * acc[1] + acc[2] * {log_2pi});
  if (res[7]) res[7][0] = acc[0];
  return 0;
}}
"""


def ekf_c(name: str, n: int, n_y: int, pattern: dict, iterations: int = 1) -> tuple[str, int]:
    """The C of ``{name}_ekf`` (after the pieces' generated C) and its scratch size in reals;
    ``iterations`` > 1: the iterated EKF's update (:func:`symmon.filters.step.update_graph`)."""
    f_nnz, h_nnz = max(len(pattern["f_row"]), 1), max(len(pattern["h_row"]), 1)
    scratch = n + 2 * n * n + f_nnz + h_nnz + n_y + n * n_y + 2 * n_y * n_y + 2 * n_y + 3 * n + 2 * n_y + n_y * n_y
    code = _STEP.format(name=name, n=n, n_y=n_y, f_col=_ints(pattern["f_col"]), f_row=_ints(pattern["f_row"]),
                        h_col=_ints(pattern["h_col"]), h_row=_ints(pattern["h_row"]), f_nnz=f_nnz, h_nnz=h_nnz,
                        scratch=scratch, wrap_x=int(pattern["wrap_x"]), iterations=int(iterations), log_2pi=repr(float(np.log(2 * np.pi))))
    return code, scratch
