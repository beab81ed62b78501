/* symmon: the RTS backward step EKF_(bwd) (TT1 time update, additive noise) around the CasADi
   pieces EKF_(fpart) and EKF_(xwrap); the linear algebra of symmon.filters.gaussian._ekfsmooth
   (its notes), column-major as CasADi.  backward_c puts before this file the pieces' generated C
   and the macros (the kernel's name EKF_NAME, EKB_ its size and F's sparsity pattern).
   EKF_(x) is the kernel's name followed by _x.
   arg: x_k, P_k, xs_{k+1}, Ps_{k+1}, Q, p_{k+1}; res: xs_k, Ps_k.  s: scratch of EKB_SCRATCH
   reals. */
#ifndef EKF_NAME  /* checked alone: example macros, and the pieces' prototypes */
#include "../../compile/casadi_alone.h"
#define EKF_NAME model
#define EKB_N 2
#define EKB_F_COL 0, 1, 2
#define EKB_F_ROW 0, 1
#define EKB_SCRATCH 32
#define EKB_WRAP_X 1
#define EKF_CHECK_ALONE 1
#endif
#include "ekf_names.h"
#ifdef EKF_CHECK_ALONE
EKF_PIECE(fpart);
EKF_PIECE(xwrap);
#endif
#include <math.h>
static const casadi_int EKF_(fcol)[] = {EKB_F_COL};
static const casadi_int EKF_(frow)[] = {EKB_F_ROW};

#include "ekf_dense.c"

/* A (n x n) = B Ft, Ft the transpose of the sparse F (CSC EKF_(fcol)/EKF_(frow), nz):
   A[:, i] += F[i, c] B[:, c] over the nonzeros, contiguous column updates. */
static void EKF_(times_ft)(casadi_real* restrict A, const casadi_real* restrict B, const casadi_real* nz) {
  const casadi_int n = EKB_N;
  casadi_int c, e, i;
  for (i = 0; i < n * n; ++i) A[i] = 0;
  for (c = 0; c < n; ++c)
    for (e = EKF_(fcol)[c]; e < EKF_(fcol)[c + 1]; ++e) {
      casadi_real v = nz[e];
      casadi_real* a = A + EKF_(frow)[e] * n;
      const casadi_real* b = B + c * n;
      for (i = 0; i < n; ++i) a[i] += v * b[i];
    }
}

/* The lower triangle of the n x n matrix A mirrored into its upper one, in blocks. */
static void EKF_(mirror)(casadi_real* A) {
  const casadi_int n = EKB_N;
  casadi_int i, j, i0, j0;
  for (j0 = 0; j0 < n; j0 += 16)
    for (i0 = j0; i0 < n; i0 += 16)
      for (j = j0; j < n && j < j0 + 16; ++j)
        for (i = i0 > j + 1 ? i0 : j + 1; i < n && i < i0 + 16; ++i) A[j + i * n] = A[i + j * n];
}

static int EKF_(bwd)(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w,
    casadi_real* s) {
  const casadi_int n = EKB_N;
  const casadi_real *x = arg[0], *P = arg[1], *xs1 = arg[2], *Ps1 = arg[3], *Q = arg[4], *p = arg[5];
  casadi_real *xs = res[0], *Ps = res[1];
  casadi_real *xp = s, *G = xp + n, *A = G + n * n, *Pp = A + n * n, *L = Pp + n * n, *r = L + n * n;
  casadi_real *dx = r + n, *v = dx + n, *Fz = v + n;
  const casadi_real* a2[2];
  casadi_real* r2[2];
  casadi_int i, j, k, ok = 1;
  /* x- = f(x) (angle states wrapped), F's nonzeros, with the parameters of step k + 1. */
  a2[0] = x; a2[1] = p; r2[0] = xp; r2[1] = Fz;
  if (EKF_(fpart)(a2, r2, iw, w, 0)) return 1;
  /* C = P F^T (in G, solved in place below), P- = F C + Q on the lower triangle, mirrored. */
  EKF_(times_ft)(G, P, Fz);
  for (j = 0; j < n; ++j)  /* A = C^T = F P: P is symmetric */
    for (i = 0; i < n; ++i) A[j + i * n] = G[i + j * n];
  EKF_(times_ft)(Pp, A, Fz);
  for (i = 0; i < n * n; ++i) Pp[i] += Q[i];
  EKF_(mirror)(Pp);
  /* L L^T = P-, right-looking (column j scaled, then subtracted from the columns after it). */
  for (j = 0; j < n; ++j)
    for (i = 0; i < n; ++i) L[i + j * n] = i >= j ? Pp[i + j * n] : 0;
  ok = EKF_(chol)(L, n, r);  /* 0: a zero, negative or NaN pivot, P- is singular */
  /* W L^T = C: column i of W is (C[:, i] - sum_{k<i} W[:, k] L[i, k]) / L[i, i] ... */
  for (i = 0; i < n; ++i) {
    casadi_real* c = G + i * n;
    EKF_(add_cols)(c, G, n, L + i, n, i, n, -1.0);
    for (k = 0; k < n; ++k) c[k] *= r[i];
  }
  /* ... and G L = W: column j of G is (W[:, j] - sum_{i>j} G[:, i] L[i, j]) / L[j, j]. */
  for (j = n - 1; j >= 0; --j) {
    casadi_real* c = G + j * n;
    EKF_(add_cols)(c, G + (j + 1) * n, n, L + j * n + j + 1, 1, n - 1 - j, n, -1.0);
    for (k = 0; k < n; ++k) c[k] *= r[j];
  }
  if (!ok)  /* the MX step's rule: an infinite gain, so that the smoother reports the step */
    for (i = 0; i < n * n; ++i) G[i] = INFINITY;
  /* xs = x + G wrap(xs_{k+1} - x-), wrapped. */
  for (j = 0; j < n; ++j) dx[j] = xs1[j] - xp[j];
  if (EKB_WRAP_X) {
    a2[0] = dx; r2[0] = v;
    if (EKF_(xwrap)(a2, r2, iw, w, 0)) return 1;
    for (j = 0; j < n; ++j) dx[j] = v[j];
  }
  for (j = 0; j < n; ++j) v[j] = x[j];
  EKF_(add_cols)(v, G, n, dx, 1, n, n, 1.0);
  if (EKB_WRAP_X) {
    a2[0] = v; r2[0] = xs;
    if (EKF_(xwrap)(a2, r2, iw, w, 0)) return 1;
  } else {
    for (j = 0; j < n; ++j) xs[j] = v[j];
  }
  /* M = G (Ps_{k+1} - P-) (in L; A holds the difference), Ps = P + M G^T on the lower
     triangle: column j gets sum_k M[j:, k] G[j, k]. */
  for (i = 0; i < n * n; ++i) A[i] = Ps1[i] - Pp[i];
  for (j = 0; j < n; ++j) {
    casadi_real* m = L + j * n;
    for (i = 0; i < n; ++i) m[i] = 0;
    EKF_(add_cols)(m, G, n, A + j * n, 1, n, n, 1.0);
  }
  for (j = 0; j < n; ++j) {
    casadi_real* ps = Ps + j * n;
    for (i = j; i < n; ++i) ps[i] = P[i + j * n];
    EKF_(add_cols)(ps + j, L + j, n, G + j, n, n, n - j, 1.0);
  }
  EKF_(mirror)(Ps);
  return 0;
}
