"""The EKF and EKF2 step of larger filters in hand-written C around CasADi's model pieces.

For the Taylor-1 rule (TT1) with additive noise, the step of :mod:`symmon.filters.gaussian.step` is

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
  (n² n_y / 2) and mirrored, the rule of :func:`symmon.filters.gaussian.step.sym`.

For the Taylor-2 rule (TT2, the second-order EKF) the moments gain the second-order terms
(the TT2 of Gustafsson & Hendeby 2012; :mod:`symmon.transforms.taylor`)

    x⁻_i = f_i(x) + ½ tr(Hf_i P),  P⁻ = F P Fᵀ + ½ [tr(Hf_i P Hf_j P)]_ij + Q,
    ŷ_i = h_i(x⁻) + ½ tr(Hh_i P⁻),  S = H P⁻ Hᵀ + ½ [tr(Hh_i P⁻ Hh_j P⁻)]_ij + R,  P^{xy} = P⁻ Hᵀ,

the angle entries of x⁻ and ŷ wrapped after the terms are added, as the MX step.  CasADi then
also generates the nonzeros of the Hessian columns Hc = [H_1[:, S_1] … H_m[:, S_m]] (S_i the
states on which H_i has nonzeros; the pattern a constant of the C), and the C forms
T = P Hc (n·nnz(Hc) multiply-adds, contiguous axpys), whence tr(H_i P) = Σ_{a∈S_i} T_i[a, a]
and tr(H_i P H_j P) = Σ_{a∈S_i, c∈S_j} T_i[c, a] T_j[a, c] ((Σ|S_i|)²/2 more on the lower
triangle): no work outside the Hessians' supports.  Stacked targets have a block of a few
states per output; an affine model has no Hessian nonzeros and keeps its TT1 part (its
second-order terms are zero).  The generated C grows with the Hessians' nonzeros, never with
products with P.

The results are those of the MX step to rounding: the same formulas, the same zero-pivot
rule (a zero pivot of S gives a zero column of L and a zero row and column of L⁻¹; a
negative one a NaN log-likelihood), the same masking of missing components
(:func:`symmon.filters.gaussian.step.update_graph`).

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ...codegen.symbolic import wrap_entries
from ...compile.compiled import compiled, compiled_with_params
from ...core.model import Model

#: From this many states on, a TT1 step with additive noise runs the C step of this module
#: (below, the straight-line SX step is as fast and its compile policy is unchanged).
C_EKF_FROM = 10


def _model_part(model: Model, m, p, second: bool = False):
    """g(m) and its Jacobian in m (sparse SX), with the parameters ``p`` (None: none) fixed;
    with ``second``, also the concatenated Hessian columns of :func:`_hessian_columns`."""
    n = m.shape[0]
    cm = compiled_with_params(model) if model.n_p else compiled(model)
    z = ca.vertcat(m, p) if model.n_p else m
    out = (cm.g(z), cm.jac(z)[:, :n])
    if second:
        out += _hessian_columns(cm, n, z)
    return out


def _hessian_columns(cm, n: int, z) -> tuple[ca.SX, list[int], list[int]]:
    """Hc = [H_1[:, S_1] … H_m[:, S_m]] (n × Σ|S_i|, sparse SX of z), the Hessians of the
    outputs in the first n inputs (the states: the parameters have zero variance) on the
    columns S_i where H_i has nonzeros, with S concatenated and the offsets of its blocks."""
    blocks, sup, off = [], [], [0]
    for H in cm.H_sx:
        Hx = H[:n, :n]
        starts = Hx.sparsity().colind()
        cols = [j for j in range(n) if starts[j + 1] > starts[j]]
        blocks.append(Hx[:, cols] if cols else ca.SX(n, 0))
        sup += cols
        off.append(off[-1] + len(cols))
    Hc = ca.horzcat(*blocks) if sup else ca.SX(n, 0)
    return ca.Function("hcols", [cm.w_sx], [Hc])(z), sup, off


def _pattern(J: ca.SX) -> tuple[list[int], list[int], ca.SX]:
    """The CSC pattern (column starts, rows) of J and its nonzeros as a column (one zero
    entry if J has none, so that no C array is empty)."""
    sp = J.sparsity()
    nz = J.nonzeros()
    return list(sp.colind()), list(sp.row()), ca.vertcat(*nz) if nz else ca.SX.zeros(1)


def ekf_pieces(f: Model, h: Model, angle_states: frozenset[int], p_f, p_h, x, y, p,
               name: str, order: int = 1) -> tuple[tuple[ca.Function, ...], dict]:
    """The SX pieces of the C step and the Jacobians' (and Hessians') patterns.

    ``{name}_fpart``: (x, p) ↦ (x⁻, nonzeros of F), x⁻ = f(x) with the angle states wrapped
    (twice, as the MX step: the TT1 mean, then the prediction); ``{name}_hpart``:
    (x⁻, y, p) ↦ (ν, nonzeros of H), ν = y − h(x⁻) wrapped on the angle outputs;
    ``{name}_xwrap``: x ↦ x with the angle states wrapped.  ``p_f``, ``p_h``: the entries of
    the filter's parameter symbol ``p`` that f and h use (None: none); x, y, p are SX symbols.

    ``order`` 2 (TT2): a model whose Hessians in x have nonzeros gets its second-order terms
    in the C step (:data:`_TT2`): its part returns g(x) unwrapped, the nonzeros of J and those
    of the Hessian columns Hc (:func:`_hessian_columns`), and the mean is wrapped after the
    terms ½ tr(H_i P) are added (``{name}_xwrap`` twice for f; for h ``{name}_innov``:
    (ŷ, y) ↦ y − ŷ, ŷ wrapped, then the difference, on the angle outputs).  A model without
    Hessian nonzeros (an affine one) keeps its TT1 part: its second-order terms are zero.
    """
    y_angles = frozenset(h.angle_outputs)
    fx, F, *f2 = _model_part(f, x, p_f, order == 2)
    hx, H, *h2 = _model_part(h, x, p_h, order == 2)
    tt2_f, tt2_h = bool(f2 and f2[0].nnz()), bool(h2 and h2[0].nnz())
    x_pred = fx if tt2_f else wrap_entries(wrap_entries(fx, angle_states), angle_states)
    nu = hx if tt2_h else wrap_entries(y - wrap_entries(hx, y_angles), y_angles)
    f_col, f_row, f_nz = _pattern(F)
    h_col, h_row, h_nz = _pattern(H)
    opts = {"cse": True}
    pattern = {"f_col": f_col, "f_row": f_row, "h_col": h_col, "h_row": h_row, "wrap_x": bool(angle_states),
               "tt2_f": tt2_f, "tt2_h": tt2_h}
    f_outs, h_outs = [x_pred, f_nz], [nu, h_nz]
    for tag, second, outs in (("f", f2, f_outs), ("h", h2, h_outs)):
        if second and second[0].nnz():
            col, row, nz = _pattern(second[0])
            outs.append(nz)
            pattern.update({f"{tag}2_col": col, f"{tag}2_row": row, f"{tag}2_sup": second[1],
                            f"{tag}2_off": second[2]})
    fpart = ca.Function(f"{name}_fpart", [x, p], f_outs, opts)
    hpart = ca.Function(f"{name}_hpart", [x, y, p], h_outs, opts)
    xwrap = ca.Function(f"{name}_xwrap", [x], [wrap_entries(x, angle_states)], opts)
    pieces = (fpart, hpart, xwrap)
    if tt2_h:
        v = ca.SX.sym("v", y.shape[0])
        pieces += (ca.Function(f"{name}_innov", [v, y], [wrap_entries(y - wrap_entries(v, y_angles), y_angles)],
                               opts),)
    return pieces, pattern


def _ints(values: list[int]) -> str:
    return "{" + ",".join(str(int(v)) for v in (values or [0])) + "}"


# The C step: column-major arrays (CasADi's layout), every dense product an axpy of columns.
#: Dense kernels that the C EKF step and the C RTS backward step (:mod:`symmon.filters.gaussian._ekfsmooth`)
#: share, a template in ``{name}`` (column-major, as CasADi).
DENSE_C = """
/* a[k] += sum_i c_i[k] (sg l_i) for k < len, the columns c_i = C + i ld_c (i < m) and the
   coefficients l_i = l[i * ld]: four columns a pass (one load and store of a per four
   products), each added in turn, so that it rounds as the plain loop over i.  sg = -1
   subtracts (negation is exact). */
static void {name}_add_cols(casadi_real* restrict a, const casadi_real* restrict C, casadi_int ld_c,
    const casadi_real* l, casadi_int ld, casadi_int m, casadi_int len, casadi_real sg) {{
  casadi_int i = 0, k;
  for (; i + 4 <= m; i += 4) {{
    const casadi_real *c0 = C + i * ld_c, *c1 = c0 + ld_c, *c2 = c1 + ld_c, *c3 = c2 + ld_c;
    casadi_real l0 = sg * l[i * ld], l1 = sg * l[(i + 1) * ld], l2 = sg * l[(i + 2) * ld], l3 = sg * l[(i + 3) * ld];
    for (k = 0; k < len; ++k) {{
      casadi_real t = a[k];
      t += c0[k] * l0;
      t += c1[k] * l1;
      t += c2[k] * l2;
      t += c3[k] * l3;
      a[k] = t;
    }}
  }}
  for (; i < m; ++i) {{
    const casadi_real* c0 = C + i * ld_c;
    casadi_real l0 = sg * l[i * ld];
    for (k = 0; k < len; ++k) a[k] += c0[k] * l0;
  }}
}}

/* L L^T = A in place (L holds A's lower triangle, m x m), right-looking: column j scaled,
   then subtracted from the columns after it (contiguous updates; each entry sees the same
   subtractions in the same order as the left-looking sums); r[j] = 1 / L[j, j].  A zero,
   negative or NaN pivot gives a zero column and r[j] = 0 (a negative one NaN on the
   diagonal), and the return value 0; else 1. */
static int {name}_chol(casadi_real* L, casadi_int m, casadi_real* r) {{
  casadi_int i, j, k;
  int ok = 1;
  for (j = 0; j < m; ++j) {{
    casadi_real d = sqrt(L[j + j * m]);
    casadi_real* lj = L + j * m;
    if (!(d > 0)) ok = 0;
    for (i = j + 1; i < m; ++i) lj[i] = d > 0 ? lj[i] / d : 0;
    lj[j] = d;
    r[j] = d > 0 ? 1 / d : 0;
    for (k = j + 1; k < m; ++k) {{
      casadi_real l = lj[k];
      casadi_real* lk = L + k * m;
      for (i = k; i < m; ++i) lk[i] -= lj[i] * l;
    }}
  }}
  return ok;
}}
"""

_STEP = """
/* symmon: the EKF step {name}_ekf (TT1, or TT2 with {name}_TT2F/H, additive noise) around the
   CasADi pieces {name}_fpart, {name}_hpart, {name}_xwrap ({name}_innov); the linear algebra
   of symmon.filters.gaussian._ekfstep.
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
/* TT2: the second-order terms of f (TT2F) and h (TT2H), over the Hessian columns
   Hc = [H_1[:, S_1] ...] (CSC f2col/f2row, h2col/h2row), S concatenated (sup) at offsets off. */
#define {name}_TT2F {tt2_f}
#define {name}_TT2H {tt2_h}
#define {name}_NS {ns}
static const casadi_int {name}_f2col[] = {f2_col};
static const casadi_int {name}_f2row[] = {f2_row};
static const casadi_int {name}_f2sup[] = {f2_sup};
static const casadi_int {name}_f2off[] = {f2_off};
static const casadi_int {name}_h2col[] = {h2_col};
static const casadi_int {name}_h2row[] = {h2_row};
static const casadi_int {name}_h2sup[] = {h2_sup};
static const casadi_int {name}_h2off[] = {h2_off};
""" + DENSE_C + """
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

/* The TT2 terms of m outputs at the covariance P (n x n): T = P Hc (n x ns, Hc sparse CSC
   col/row/nz, one contiguous axpy per nonzero), then with T_i = P H_i[:, S_i] =
   ((H_i P)[S_i, :])^T, t_i = 1/2 tr(H_i P) = 1/2 sum_{{a in S_i}} T_i[a, a] and, on the lower
   triangle of G (m x m), G_ij = 1/2 tr(H_i P H_j P) = 1/2 sum_{{a in S_i, c in S_j}} T_i[c, a] T_j[a, c]:
   nnz(Hc) n + (sum_i |S_i|)^2 / 2 multiply-adds, nothing outside the Hessians' supports. */
static void {name}_tt2(const casadi_real* restrict P, const casadi_int* col, const casadi_int* row,
    const casadi_real* nz, const casadi_int* sup, const casadi_int* off, casadi_int n, casadi_int m,
    casadi_real* restrict T, casadi_real* t, casadi_real* G) {{
  casadi_int c, e, i, j, a, b, k;
  for (i = 0; i < n * off[m]; ++i) T[i] = 0;
  for (c = 0; c < off[m]; ++c)
    for (e = col[c]; e < col[c + 1]; ++e) {{
      casadi_real v = nz[e];
      casadi_real* tc = T + c * n;
      const casadi_real* pr = P + row[e] * n;
      for (k = 0; k < n; ++k) tc[k] += v * pr[k];
    }}
  for (i = 0; i < m; ++i) {{
    casadi_real v = 0;
    for (a = off[i]; a < off[i + 1]; ++a) v += T[sup[a] + a * n];
    t[i] = 0.5 * v;
    for (j = 0; j <= i; ++j) {{
      casadi_real g = 0;
      for (a = off[i]; a < off[i + 1]; ++a)
        for (b = off[j]; b < off[j + 1]; ++b) g += T[sup[b] + a * n] * T[sup[a] + b * n];
      G[i + j * m] = 0.5 * g;
    }}
  }}
}}

/* The linearised update at xl (xl = x-: the EKF's; else an iteration of the IEKF, whose
   residual is y - h(xl) - H (x- - xl)): nu (masked), Ct -> W^T = P^xy L^-T, S (masked), L,
   r (reciprocal pivots), wh = L^-1 nu; adds |wh|^2, sum log L_ii and the measured count
   into acc[0..2].  dx: n reals of scratch; s2: the TT2 terms' ({name}_ekf). */
static int {name}_linearised(const casadi_real* xl, const casadi_real* xp, const casadi_real* Pp,
    const casadi_real* y, const casadi_real* R, const casadi_real* mask, const casadi_real* p,
    casadi_int* iw, casadi_real* w, casadi_real* nu, casadi_real* Hz, casadi_real* Ct, casadi_real* A,
    casadi_real* S, casadi_real* L, casadi_real* r, casadi_real* wh, casadi_real* dx, casadi_real* acc,
    casadi_real* s2) {{
  const casadi_int n = {name}_N, ny = {name}_NY;
  const casadi_real* a2[3];
  casadi_real* r2[3];
  casadi_int i, j, k, e;
  /* nu = y - h(xl) (angle outputs wrapped), H's nonzeros at xl; TT2: h(xl) and the Hessian
     columns' nonzeros Hh, then nu = y - (h(xl) + t) with t_i = 1/2 tr(H_i P-) (wrapped as the
     TT2 mean), and G_ij = 1/2 tr(H_i P- H_j P-) for S. */
  a2[0] = xl; a2[1] = y; a2[2] = p; r2[0] = nu; r2[1] = Hz; r2[2] = s2;
  if ({name}_hpart(a2, r2, iw, w, 0)) return 1;
#if {name}_TT2H
  {{
    casadi_real *Hh = s2, *T = Hh + {H2}, *t = T + n * {name}_NS, *G = t + {NT}, *v = G + {NT} * {NT};
    {name}_tt2(Pp, {name}_h2col, {name}_h2row, Hh, {name}_h2sup, {name}_h2off, n, ny, T, t, G);
    for (i = 0; i < ny; ++i) v[i] = nu[i] + t[i];
    a2[0] = v; a2[1] = y; r2[0] = nu;
    if ({name}_innov(a2, r2, iw, w, 0)) return 1;
  }}
#endif
  if (xl != xp) {{
    for (j = 0; j < n; ++j) dx[j] = xp[j] - xl[j];
    for (j = 0; j < n; ++j)
      for (e = {name}_hcol[j]; e < {name}_hcol[j + 1]; ++e) nu[{name}_hrow[e]] -= Hz[e] * dx[j];
  }}
  /* Ct = P- H^T (the cross-covariance P^xy, n x ny), S = H Ct + R, lower mirrored. */
  {name}_times_jt(Ct, Pp, {name}_hcol, {name}_hrow, Hz, n, ny, n);
  {name}_transpose(A, Ct, n, ny);  /* H P- = Ct^T */
  {name}_times_jt(S, A, {name}_hcol, {name}_hrow, Hz, ny, ny, n);
#if {name}_TT2H
  {{
    const casadi_real* G = s2 + {H2} + n * {name}_NS + {NT};
    for (j = 0; j < ny; ++j)
      for (i = j; i < ny; ++i) S[i + j * ny] += G[i + j * ny];  /* the lower triangle: mirrored below */
  }}
#endif
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
  {name}_chol(L, ny, r);  /* a zero (or NaN) pivot: a zero row of the inverse */
  /* W^T = Ct L^-T and L^-1 nu, by forward substitution, column by column. */
  for (i = 0; i < ny; ++i) {{
    casadi_real* c = Ct + i * n;
    casadi_real v = nu[i];
    {name}_add_cols(c, Ct, n, L + i, ny, i, n, -1.0);
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
  casadi_real *nu2 = dx + n, *S2 = nu2 + ny, *wh2 = S2 + ny * ny, *wx = wh, *s2 = wh2 + ny;
  casadi_real *Pn = res[1], acc[3] = {{0, 0, 0}}, acc2[3] = {{0, 0, 0}};
  const casadi_real* a2[2];
  casadi_real* r2[3];
  casadi_int i, j, k, it;
  /* x- = f(x) (angle states wrapped), F's nonzeros.  TT2: f(x) and the Hessian columns'
     nonzeros Hf, then x- = f(x) + t with t_i = 1/2 tr(H_i P), wrapped twice as the MX step (the
     TT2 mean, then the prediction), and G_ij = 1/2 tr(H_i P H_j P) for P-. */
  a2[0] = x; a2[1] = p; r2[0] = xp; r2[1] = Fz; r2[2] = s2;
  if ({name}_fpart(a2, r2, iw, w, 0)) return 1;
#if {name}_TT2F
  {{
    casadi_real *T = s2 + {H2}, *t = T + n * {name}_NS, *G = t + {NT}, *v = G + {NT} * {NT}, *u = v + {NT};
    {name}_tt2(P, {name}_f2col, {name}_f2row, s2, {name}_f2sup, {name}_f2off, n, n, T, t, G);
    for (i = 0; i < n; ++i) v[i] = xp[i] + t[i];
    if ({wrap_x}) {{
      a2[0] = v; r2[0] = u;
      if ({name}_xwrap(a2, r2, iw, w, 0)) return 1;
      a2[0] = u; r2[0] = xp;
      if ({name}_xwrap(a2, r2, iw, w, 0)) return 1;
    }} else {{
      for (i = 0; i < n; ++i) xp[i] = v[i];
    }}
  }}
#endif
  /* P- = F (P F^T) + Q, lower triangle mirrored. */
  {name}_times_jt(Pp, P, {name}_fcol, {name}_frow, Fz, n, n, n);
  {name}_transpose(A, Pp, n, n);  /* F P = (P F^T)^T: P is symmetric */
  {name}_times_jt(Pp, A, {name}_fcol, {name}_frow, Fz, n, n, n);
#if {name}_TT2F
  {{
    const casadi_real* G = s2 + {H2} + n * {name}_NS + {NT};
    for (j = 0; j < n; ++j)
      for (i = j; i < n; ++i) Pp[i + j * n] += G[i + j * n];  /* the lower triangle: mirrored below */
  }}
#endif
  for (i = 0; i < n * n; ++i) Pp[i] += Q[i];
  {name}_mirror(Pp, n);
  /* The update at x-: its nu, S, NIS and log-likelihood are the step's. */
  if ({name}_linearised(xp, xp, Pp, y, R, mask, p, iw, w, nu, Hz, Ct, A, S, L, r, wh, dx, acc, s2)) return 1;
  /* x+ = x- + W^T (L^-1 nu); the IEKF's Gauss-Newton steps relinearise h at x+. */
  for (it = 0; it < {iterations}; ++it) {{
    if (it) {{
      for (j = 0; j < n; ++j) xl[j] = xn[j];
      if ({name}_linearised(xl, xp, Pp, y, R, mask, p, iw, w, nu2, Hz, Ct, A, S2, L, r, wh2, dx, acc2, s2)) return 1;
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
    {name}_add_cols(pn + j, Ct + j, n, Ct + j, n, ny, n - j, -1.0);
  }}
  {name}_mirror(Pn, n);
  if (res[6]) res[6][0] = -0.5 * (acc[0] + 2 * acc[1] + acc[2] * {log_2pi});
  if (res[7]) res[7][0] = acc[0];
  return 0;
}}
"""


def ekf_c(name: str, n: int, n_y: int, pattern: dict, iterations: int = 1) -> tuple[str, int]:
    """The C of ``{name}_ekf`` (after the pieces' generated C) and its scratch size in reals;
    ``iterations`` > 1: the iterated EKF's update (:func:`symmon.filters.gaussian.step.update_graph`);
    ``pattern`` with ``tt2_f`` or ``tt2_h`` (:func:`ekf_pieces` of order 2): the TT2 terms of
    f or h in the step."""
    f_nnz, h_nnz = max(len(pattern["f_row"]), 1), max(len(pattern["h_row"]), 1)
    scratch = n + 2 * n * n + f_nnz + h_nnz + n_y + n * n_y + 2 * n_y * n_y + 2 * n_y + 3 * n + 2 * n_y + n_y * n_y
    second = {tag: {key: pattern.get(f"{tag}2_{key}", []) for key in ("col", "row", "sup", "off")}
              for tag in "fh"}
    tt2 = {tag: bool(pattern.get(f"tt2_{tag}")) for tag in "fh"}
    # The TT2 scratch (after the TT1 step's): the Hessian columns' nonzeros, T = P Hc, t, G,
    # and two vectors, shared by the prediction and the update.
    ns = max([len(second[tag]["sup"]) for tag in "fh" if tt2[tag]] + [1])
    h2 = max([len(second[tag]["row"]) for tag in "fh" if tt2[tag]] + [1])
    nt = max(n, n_y)
    if tt2["f"] or tt2["h"]:
        scratch += h2 + n * ns + nt + nt * nt + 2 * nt
    code = _STEP.format(name=name, n=n, n_y=n_y, f_col=_ints(pattern["f_col"]), f_row=_ints(pattern["f_row"]),
                        h_col=_ints(pattern["h_col"]), h_row=_ints(pattern["h_row"]), f_nnz=f_nnz, h_nnz=h_nnz,
                        scratch=scratch, wrap_x=int(pattern["wrap_x"]), iterations=int(iterations),
                        log_2pi=repr(float(np.log(2 * np.pi))),
                        tt2_f=int(tt2["f"]), tt2_h=int(tt2["h"]), ns=ns, H2=h2, NT=nt,
                        **{f"{tag}2_{key}": _ints(v) for tag in "fh" for key, v in second[tag].items()})
    return code, scratch
