/* symmon: the EKF step EKF_(ekf) (TT1, or TT2 with EKF_TT2F/H, additive noise) around the
   CasADi pieces EKF_(fpart), EKF_(hpart), EKF_(xwrap) (EKF_(innov)); the linear algebra of
   symmon.filters.gaussian._ekfstep (its notes), column-major as CasADi.  ekf_c puts before this
   file the pieces' generated C and the EKF_ macros (the kernel's name EKF_NAME, its sizes and
   the sparsity patterns of the Jacobians).  EKF_(x) is the kernel's name followed by _x.
   arg: x, P, y, Q, R, mask, p; res: x+, P+, x-, P-, nu, S, loglik, nis (null: not kept; then
   scratch).  s: scratch of EKF_(ekf_scratch) reals. */
#ifndef EKF_NAME  /* checked alone: example macros, and the pieces' prototypes */
#include "../../compile/casadi_alone.h"
#define EKF_NAME model
#define EKF_N 2
#define EKF_NY 1
#define EKF_TT2F 1
#define EKF_TT2H 1
#define EKF_NS 2
#define EKF_F_COL 0, 1, 2
#define EKF_F_ROW 0, 1
#define EKF_H_COL 0, 1, 2
#define EKF_H_ROW 0, 0
#define EKF_SCRATCH 64
#define EKF_F2_COL 0, 1, 2
#define EKF_F2_ROW 0, 1
#define EKF_F2_SUP 0, 1
#define EKF_F2_OFF 0, 1, 2
#define EKF_H2_COL 0, 1, 2
#define EKF_H2_ROW 0, 1
#define EKF_H2_SUP 0, 1
#define EKF_H2_OFF 0, 1, 2
#define EKF_F_NNZ 2
#define EKF_H_NNZ 2
#define EKF_WRAP_X 1
#define EKF_ITERATIONS 1
#define EKF_LOG_2PI 1.8378770664093453
#define EKF_H2 2
#define EKF_NT 2
#define EKF_CHECK_ALONE 1
#endif
#include "ekf_names.h"
#ifdef EKF_CHECK_ALONE
EKF_PIECE(fpart);
EKF_PIECE(hpart);
EKF_PIECE(xwrap);
EKF_PIECE(innov);
#endif
#include <math.h>
#include <stdlib.h>
/* The loops below are a few KB of C: optimised even when the whole file is large enough (the
   NEES function of a large filter) for the compile policy's -O0 build.  No FMA contraction,
   as every build (the same results at any level). */
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC optimize ("O3", "fp-contract=off")
#endif
static const casadi_int EKF_(fcol)[] = {EKF_F_COL};
static const casadi_int EKF_(frow)[] = {EKF_F_ROW};
static const casadi_int EKF_(hcol)[] = {EKF_H_COL};
static const casadi_int EKF_(hrow)[] = {EKF_H_ROW};
static const casadi_int EKF_(ekf_scratch) = EKF_SCRATCH;
/* TT2: the second-order terms of f (TT2F) and h (TT2H), over the Hessian columns
   Hc = [H_1[:, S_1] ...] (CSC f2col/f2row, h2col/h2row), S concatenated (sup) at offsets off. */
static const casadi_int EKF_(f2col)[] = {EKF_F2_COL};
static const casadi_int EKF_(f2row)[] = {EKF_F2_ROW};
static const casadi_int EKF_(f2sup)[] = {EKF_F2_SUP};
static const casadi_int EKF_(f2off)[] = {EKF_F2_OFF};
static const casadi_int EKF_(h2col)[] = {EKF_H2_COL};
static const casadi_int EKF_(h2row)[] = {EKF_H2_ROW};
static const casadi_int EKF_(h2sup)[] = {EKF_H2_SUP};
static const casadi_int EKF_(h2off)[] = {EKF_H2_OFF};
#include "ekf_dense.c"

/* The lower triangle of the n x n matrix A mirrored into its upper one, in blocks. */
static void EKF_(mirror)(casadi_real* A, casadi_int n) {
  casadi_int i, j, i0, j0;
  for (j0 = 0; j0 < n; j0 += 16)
    for (i0 = j0; i0 < n; i0 += 16)
      for (j = j0; j < n && j < j0 + 16; ++j)
        for (i = i0 > j + 1 ? i0 : j + 1; i < n && i < i0 + 16; ++i) A[j + i * n] = A[i + j * n];
}

/* A (n x m) = B (n x k) Jt, Jt the transpose of the sparse J (m x k, CSC col/row/nz):
   A[:, i] += J[i, c] B[:, c] over the nonzeros, contiguous column updates. */
static void EKF_(times_jt)(casadi_real* restrict A, const casadi_real* restrict B, const casadi_int* col, const casadi_int* row,
    const casadi_real* nz, casadi_int n, casadi_int m, casadi_int k) {
  casadi_int c, e, i;
  for (i = 0; i < n * m; ++i) A[i] = 0;
  for (c = 0; c < k; ++c)
    for (e = col[c]; e < col[c + 1]; ++e) {
      casadi_real v = nz[e];
      casadi_real* a = A + row[e] * n;
      const casadi_real* b = B + c * n;
      for (i = 0; i < n; ++i) a[i] += v * b[i];
    }
}

/* B (m x n) = A^T, A n x m: blocked, so that both sides stay in cache. */
static void EKF_(transpose)(casadi_real* restrict B, const casadi_real* restrict A, casadi_int n, casadi_int m) {
  casadi_int i, j, i0, j0;
  for (j0 = 0; j0 < m; j0 += 16)
    for (i0 = 0; i0 < n; i0 += 16)
      for (j = j0; j < m && j < j0 + 16; ++j)
        for (i = i0; i < n && i < i0 + 16; ++i) B[j + i * m] = A[i + j * n];
}

/* The TT2 terms of m outputs at the covariance P (n x n): T = P Hc (n x ns, Hc sparse CSC
   col/row/nz, one contiguous axpy per nonzero), then with T_i = P H_i[:, S_i] =
   ((H_i P)[S_i, :])^T, t_i = 1/2 tr(H_i P) = 1/2 sum_{a in S_i} T_i[a, a] and, on the lower
   triangle of G (m x m), G_ij = 1/2 tr(H_i P H_j P) = 1/2 sum_{a in S_i, c in S_j} T_i[c, a] T_j[a, c]:
   nnz(Hc) n + (sum_i |S_i|)^2 / 2 multiply-adds, nothing outside the Hessians' supports. */
static void EKF_(tt2)(const casadi_real* restrict P, const casadi_int* col, const casadi_int* row,
    const casadi_real* nz, const casadi_int* sup, const casadi_int* off, casadi_int n, casadi_int m,
    casadi_real* restrict T, casadi_real* t, casadi_real* G) {
  casadi_int c, e, i, j, a, b, k;
  for (i = 0; i < n * off[m]; ++i) T[i] = 0;
  for (c = 0; c < off[m]; ++c)
    for (e = col[c]; e < col[c + 1]; ++e) {
      casadi_real v = nz[e];
      casadi_real* tc = T + c * n;
      const casadi_real* pr = P + row[e] * n;
      for (k = 0; k < n; ++k) tc[k] += v * pr[k];
    }
  for (i = 0; i < m; ++i) {
    casadi_real v = 0;
    for (a = off[i]; a < off[i + 1]; ++a) v += T[sup[a] + a * n];
    t[i] = 0.5 * v;
    for (j = 0; j <= i; ++j) {
      casadi_real g = 0;
      for (a = off[i]; a < off[i + 1]; ++a)
        for (b = off[j]; b < off[j + 1]; ++b) g += T[sup[b] + a * n] * T[sup[a] + b * n];
      G[i + j * m] = 0.5 * g;
    }
  }
}

/* The linearised update at xl (xl = x-: the EKF's; else an iteration of the IEKF, whose
   residual is y - h(xl) - H (x- - xl)): nu (masked), Ct -> W^T = P^xy L^-T, S (masked), L,
   r (reciprocal pivots), wh = L^-1 nu; adds |wh|^2, sum log L_ii and the measured count
   into acc[0..2].  dx: n reals of scratch; s2: the TT2 terms' (EKF_(ekf)). */
static int EKF_(linearised)(const casadi_real* xl, const casadi_real* xp, const casadi_real* Pp,
    const casadi_real* y, const casadi_real* R, const casadi_real* mask, const casadi_real* p,
    casadi_int* iw, casadi_real* w, casadi_real* nu, casadi_real* Hz, casadi_real* Ct, casadi_real* A,
    casadi_real* S, casadi_real* L, casadi_real* r, casadi_real* wh, casadi_real* dx, casadi_real* acc,
    casadi_real* s2) {
  const casadi_int n = EKF_N, ny = EKF_NY;
  const casadi_real* a2[3];
  casadi_real* r2[3];
  casadi_int i, j, k, e;
  /* nu = y - h(xl) (angle outputs wrapped), H's nonzeros at xl; TT2: h(xl) and the Hessian
     columns' nonzeros Hh, then nu = y - (h(xl) + t) with t_i = 1/2 tr(H_i P-) (wrapped as the
     TT2 mean), and G_ij = 1/2 tr(H_i P- H_j P-) for S. */
  a2[0] = xl; a2[1] = y; a2[2] = p; r2[0] = nu; r2[1] = Hz; r2[2] = s2;
  if (EKF_(hpart)(a2, r2, iw, w, 0)) return 1;
#if EKF_TT2H
  {
    casadi_real *Hh = s2, *T = Hh + EKF_H2, *t = T + n * EKF_NS, *G = t + EKF_NT, *v = G + EKF_NT * EKF_NT;
    EKF_(tt2)(Pp, EKF_(h2col), EKF_(h2row), Hh, EKF_(h2sup), EKF_(h2off), n, ny, T, t, G);
    for (i = 0; i < ny; ++i) v[i] = nu[i] + t[i];
    a2[0] = v; a2[1] = y; r2[0] = nu;
    if (EKF_(innov)(a2, r2, iw, w, 0)) return 1;
  }
#endif
  if (xl != xp) {
    for (j = 0; j < n; ++j) dx[j] = xp[j] - xl[j];
    for (j = 0; j < n; ++j)
      for (e = EKF_(hcol)[j]; e < EKF_(hcol)[j + 1]; ++e) nu[EKF_(hrow)[e]] -= Hz[e] * dx[j];
  }
  /* Ct = P- H^T (the cross-covariance P^xy, n x ny), S = H Ct + R, lower mirrored. */
  EKF_(times_jt)(Ct, Pp, EKF_(hcol), EKF_(hrow), Hz, n, ny, n);
  EKF_(transpose)(A, Ct, n, ny);  /* H P- = Ct^T */
  EKF_(times_jt)(S, A, EKF_(hcol), EKF_(hrow), Hz, ny, ny, n);
#if EKF_TT2H
  {
    const casadi_real* G = s2 + EKF_H2 + n * EKF_NS + EKF_NT;
    for (j = 0; j < ny; ++j)
      for (i = j; i < ny; ++i) S[i + j * ny] += G[i + j * ny];  /* the lower triangle: mirrored below */
  }
#endif
  for (i = 0; i < ny * ny; ++i) S[i] += R[i];
  EKF_(mirror)(S, ny);
  /* The measured block: D nu, D S D + (I - D), P^xy D (update_graph's masking). */
  for (i = 0; i < ny; ++i) {
    casadi_real m = mask[i];
    acc[2] += m;
    nu[i] *= m;
    for (j = 0; j < ny; ++j) S[i + j * ny] *= m * mask[j];
    S[i + i * ny] += 1 - m;
    for (k = 0; k < n; ++k) Ct[k + i * n] *= m;
  }
  /* L L^T = S, right-looking: column j scaled, then subtracted from the columns after it
     (contiguous updates; each entry sees the same subtractions in the same order as the
     left-looking sums).  A zero pivot gives a zero column, a negative one NaN on the diagonal. */
  for (j = 0; j < ny; ++j)
    for (i = 0; i < ny; ++i) L[i + j * ny] = i >= j ? S[i + j * ny] : 0;
  EKF_(chol)(L, ny, r);  /* a zero (or NaN) pivot: a zero row of the inverse */
  /* W^T = Ct L^-T and L^-1 nu, by forward substitution, column by column. */
  for (i = 0; i < ny; ++i) {
    casadi_real* c = Ct + i * n;
    casadi_real v = nu[i];
    EKF_(add_cols)(c, Ct, n, L + i, ny, i, n, -1.0);
    for (k = 0; k < i; ++k) v -= L[i + k * ny] * wh[k];
    for (j = 0; j < n; ++j) c[j] *= r[i];
    wh[i] = r[i] * v;
    acc[0] += wh[i] * wh[i];
    acc[1] += log(L[i + i * ny]);
  }
  return 0;
}

static int EKF_(ekf)(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w,
    casadi_real* s) {
  const casadi_int n = EKF_N, ny = EKF_NY;
  const casadi_real *x = arg[0], *P = arg[1], *y = arg[2], *Q = arg[3], *R = arg[4], *mask = arg[5], *p = arg[6];
  casadi_real *xp = res[2] ? res[2] : s, *Pp = res[3] ? res[3] : s + n;
  casadi_real *A = s + n + n * n, *Fz = A + n * n, *Hz = Fz + EKF_F_NNZ, *nu = res[4] ? res[4] : Hz + EKF_H_NNZ;
  casadi_real *Ct = Hz + EKF_H_NNZ + ny, *S = res[5] ? res[5] : Ct + n * ny, *L = Ct + n * ny + ny * ny;
  casadi_real *wh = L + ny * ny, *r = wh + ny, *xn = r + ny, *xl = xn + n, *dx = xl + n;
  casadi_real *nu2 = dx + n, *S2 = nu2 + ny, *wh2 = S2 + ny * ny, *wx = wh, *s2 = wh2 + ny;
  casadi_real *Pn = res[1], acc[3] = {0, 0, 0}, acc2[3] = {0, 0, 0};
  const casadi_real* a2[2];
  casadi_real* r2[3];
  casadi_int i, j, k, it;
  /* x- = f(x) (angle states wrapped), F's nonzeros.  TT2: f(x) and the Hessian columns'
     nonzeros Hf, then x- = f(x) + t with t_i = 1/2 tr(H_i P), wrapped twice as the MX step (the
     TT2 mean, then the prediction), and G_ij = 1/2 tr(H_i P H_j P) for P-. */
  a2[0] = x; a2[1] = p; r2[0] = xp; r2[1] = Fz; r2[2] = s2;
  if (EKF_(fpart)(a2, r2, iw, w, 0)) return 1;
#if EKF_TT2F
  {
    casadi_real *T = s2 + EKF_H2, *t = T + n * EKF_NS, *G = t + EKF_NT, *v = G + EKF_NT * EKF_NT, *u = v + EKF_NT;
    EKF_(tt2)(P, EKF_(f2col), EKF_(f2row), s2, EKF_(f2sup), EKF_(f2off), n, n, T, t, G);
    for (i = 0; i < n; ++i) v[i] = xp[i] + t[i];
    if (EKF_WRAP_X) {
      a2[0] = v; r2[0] = u;
      if (EKF_(xwrap)(a2, r2, iw, w, 0)) return 1;
      a2[0] = u; r2[0] = xp;
      if (EKF_(xwrap)(a2, r2, iw, w, 0)) return 1;
    } else {
      for (i = 0; i < n; ++i) xp[i] = v[i];
    }
  }
#endif
  /* P- = F (P F^T) + Q, lower triangle mirrored. */
  EKF_(times_jt)(Pp, P, EKF_(fcol), EKF_(frow), Fz, n, n, n);
  EKF_(transpose)(A, Pp, n, n);  /* F P = (P F^T)^T: P is symmetric */
  EKF_(times_jt)(Pp, A, EKF_(fcol), EKF_(frow), Fz, n, n, n);
#if EKF_TT2F
  {
    const casadi_real* G = s2 + EKF_H2 + n * EKF_NS + EKF_NT;
    for (j = 0; j < n; ++j)
      for (i = j; i < n; ++i) Pp[i + j * n] += G[i + j * n];  /* the lower triangle: mirrored below */
  }
#endif
  for (i = 0; i < n * n; ++i) Pp[i] += Q[i];
  EKF_(mirror)(Pp, n);
  /* The update at x-: its nu, S, NIS and log-likelihood are the step's. */
  if (EKF_(linearised)(xp, xp, Pp, y, R, mask, p, iw, w, nu, Hz, Ct, A, S, L, r, wh, dx, acc, s2)) return 1;
  /* x+ = x- + W^T (L^-1 nu); the IEKF's Gauss-Newton steps relinearise h at x+. */
  for (it = 0; it < EKF_ITERATIONS; ++it) {
    if (it) {
      for (j = 0; j < n; ++j) xl[j] = xn[j];
      if (EKF_(linearised)(xl, xp, Pp, y, R, mask, p, iw, w, nu2, Hz, Ct, A, S2, L, r, wh2, dx, acc2, s2)) return 1;
      wx = wh2;
    }
    for (j = 0; j < n; ++j) xn[j] = xp[j];
    for (i = 0; i < ny; ++i) {
      const casadi_real* c = Ct + i * n;
      for (j = 0; j < n; ++j) xn[j] += c[j] * wx[i];
    }
  }
  if (EKF_WRAP_X) {
    a2[0] = xn; r2[0] = res[0];
    if (EKF_(xwrap)(a2, r2, iw, w, 0)) return 1;
  } else {
    for (j = 0; j < n; ++j) res[0][j] = xn[j];
  }
  /* P+ = P- - W^T W (the last linearisation's W) on the lower triangle, mirrored. */
  for (j = 0; j < n; ++j) {
    casadi_real* pn = Pn + j * n;
    const casadi_real* pp = Pp + j * n;
    for (k = j; k < n; ++k) pn[k] = pp[k];
    EKF_(add_cols)(pn + j, Ct + j, n, Ct + j, n, ny, n - j, -1.0);
  }
  EKF_(mirror)(Pn, n);
  if (res[6]) res[6][0] = -0.5 * (acc[0] + 2 * acc[1] + acc[2] * EKF_LOG_2PI);
  if (res[7]) res[7][0] = acc[0];
  return 0;
}
