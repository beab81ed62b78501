/* symmon: the square-root EKF step EKF_(sqrt_ekf) (TT1, additive noise) around the CasADi
   pieces EKF_(fpart), EKF_(hpart), EKF_(xwrap) of the C EKF step (ekf_step.c); the factor
   arithmetic of symmon.filters.gaussian._sqrtstep (its notes), column-major as CasADi.
   _ekfstep.sqrt_ekf_c puts before this file the pieces' generated C and the EKF_ macros (the
   kernel's name EKF_NAME, its sizes and the sparsity patterns of the Jacobians).
   arg: x, S, y, sqrt Q, sqrt R, mask, p (S, sqrt Q, sqrt R lower factors); res: x+, S+, x-, S-,
   nu, S_y S_y^T, loglik, nis (null: not kept; then scratch).  s: scratch of EKF_SCRATCH reals. */
#ifndef EKF_NAME  /* checked alone: example macros, and the pieces' prototypes */
#include "../../compile/casadi_alone.h"
#define EKF_NAME model
#define EKF_N 2
#define EKF_NY 1
#define EKF_F_COL 0, 1, 2
#define EKF_F_ROW 0, 1
#define EKF_H_COL 0, 1, 2
#define EKF_H_ROW 0, 0
#define EKF_F_NNZ 2
#define EKF_H_NNZ 2
#define EKF_WRAP_X 1
#define EKF_ITERATIONS 1
#define EKF_LOG_2PI 1.8378770664093453
#define EKF_SCRATCH 64
#define EKF_MA 4
#define EKF_MV 4
#define EKF_CHECK_ALONE 1
#endif
#include "ekf_names.h"
#ifdef EKF_CHECK_ALONE
EKF_PIECE(fpart);
EKF_PIECE(hpart);
EKF_PIECE(xwrap);
#endif
#include <math.h>
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

#include "sqrt_tria.c"

/* B (m x n) = J S, J sparse (m x k, CSC col/row/nz), S lower triangular (k x n, column-major;
   its upper triangle is not read): one scatter of each S[a, c] through column a of J, from
   the diagonal down to the last nonzero of the column (found first: a test of each entry
   would mispredict at every nonzero of a block-diagonal factor). */
static void EKF_(times_lower)(casadi_real* restrict B, const casadi_int* col, const casadi_int* row,
    const casadi_real* nz, const casadi_real* restrict S, casadi_int m, casadi_int n) {
  casadi_int c, a, e, i, hi;
  for (i = 0; i < m * n; ++i) B[i] = 0;
  for (c = 0; c < n; ++c) {
    casadi_real* b = B + c * m;
    const casadi_real* sc = S + c * n;
    for (hi = n - 1; hi > c && sc[hi] == 0; --hi) {}
    for (a = c; a <= hi; ++a) {
      casadi_real s = sc[a];
      for (e = col[a]; e < col[a + 1]; ++e) b[row[e]] += nz[e] * s;
    }
  }
}

/* The update at xl (xl = x-: the EKF's; else an iteration of the IEKF, whose residual is
   y - h(xl) - H (x- - xl)) by one triangularisation of the pre-array (rows y, then x)

       [ D sqrt R   I - D   D H S- ]        [ Sy   0  ]
       [    0         0       S-   ]   ->   [ Kb   S+ ]   (L, (ny + n) x (ny + n)),

   whose Gram matrices agree: Sy Sy^T = D H P- H^T D + D R D + (I - D) (the masked innovation
   covariance of sqrt_update_graph), Kb Sy^T = P- H^T D = P^xy and Kb Kb^T + S+ S+^T = P-, so
   that Kb = P^xy Sy^-T and S+ S+^T = P- - P^xy S^-1 P^yx: the gain factor and the updated
   factor of sqrt_update_graph, both from orthogonal reflections (the array form of the
   square-root covariance filter; equal to the MX step's Joseph-form factor in exact
   arithmetic).  nu (masked) and wh = Sy^-1 nu (0 for a zero pivot: the zero row of the
   inverse); adds |wh|^2, sum log Sy_ii and the measured count into acc[0..2]. */
static int EKF_(update)(const casadi_real* xl, const casadi_real* xp, const casadi_real* Sp,
    const casadi_real* y, const casadi_real* Rs, const casadi_real* mask, const casadi_real* p,
    casadi_int* iw, casadi_real* w, casadi_real* nu, casadi_real* Hz, casadi_real* Y, casadi_real* A,
    casadi_real* L, casadi_real* wh, casadi_real* dx, casadi_real* vt, casadi_real* wt, casadi_real* acc) {
  const casadi_int n = EKF_N, ny = EKF_NY, N2 = EKF_N + EKF_NY;
  const casadi_real* a2[3];
  casadi_real* r2[2];
  casadi_int i, j, k, e;
  a2[0] = xl; a2[1] = y; a2[2] = p; r2[0] = nu; r2[1] = Hz;
  if (EKF_(hpart)(a2, r2, iw, w, 0)) return 1;
  if (xl != xp) {
    for (j = 0; j < n; ++j) dx[j] = xp[j] - xl[j];
    for (j = 0; j < n; ++j)
      for (e = EKF_(hcol)[j]; e < EKF_(hcol)[j + 1]; ++e) nu[EKF_(hrow)[e]] -= Hz[e] * dx[j];
  }
  EKF_(times_lower)(Y, EKF_(hcol), EKF_(hrow), Hz, Sp, ny, n);
  for (i = 0; i < ny; ++i) {
    acc[2] += mask[i];
    nu[i] *= mask[i];
  }
  /* The pre-array, column-major (N2 rows): the noise's triangle first, so that row j's
     reflection pivots on a column of its own block. */
  for (j = 0; j < ny; ++j) {
    casadi_real* a = A + j * N2;
    casadi_real* d = A + (ny + j) * N2;
    for (i = 0; i < N2; ++i) {
      a[i] = i >= j && i < ny ? mask[i] * Rs[i + j * ny] : 0;
      d[i] = i == j ? 1 - mask[i] : 0;
    }
  }
  for (j = 0; j < n; ++j) {
    casadi_real* a = A + (2 * ny + j) * N2;
    const casadi_real* sp = Sp + j * n;
    for (i = 0; i < ny; ++i) a[i] = mask[i] * Y[i + j * ny];
    for (k = 0; k < n; ++k) a[ny + k] = k >= j ? sp[k] : 0;
  }
  EKF_(tria)(A, N2, 2 * ny + n, L, vt, wt);
  for (i = 0; i < ny; ++i) {
    casadi_real d = L[i + i * N2], v = nu[i];
    for (k = 0; k < i; ++k) v -= L[i + k * N2] * wh[k];
    wh[i] = d > 0 ? v / d : 0;
    acc[0] += wh[i] * wh[i];
    acc[1] += log(d);
  }
  return 0;
}

static int EKF_(sqrt_ekf)(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w,
    casadi_real* s) {
  const casadi_int n = EKF_N, ny = EKF_NY, N2 = EKF_N + EKF_NY;
  const casadi_real *x = arg[0], *S = arg[1], *y = arg[2], *Qs = arg[3], *Rs = arg[4], *mask = arg[5];
  const casadi_real* p = arg[6];
  casadi_real *xp = res[2] ? res[2] : s, *Sp = res[3] ? res[3] : s + n;
  casadi_real *A = s + n + n * n, *Fz = A + EKF_MA, *Hz = Fz + EKF_F_NNZ, *Y = Hz + EKF_H_NNZ;
  casadi_real *L = Y + ny * n, *wh = L + N2 * N2, *wh2 = wh + ny, *nu2 = wh2 + ny, *xn = nu2 + ny;
  casadi_real *xl = xn + n, *dx = xl + n, *vt = dx + n, *wt = vt + EKF_MV, *nus = wt + EKF_MV;
  casadi_real *nu = res[4] ? res[4] : nus, *wx = wh, acc[3] = {0, 0, 0}, acc2[3] = {0, 0, 0};
  const casadi_real* a2[2];
  casadi_real* r2[2];
  casadi_int i, j, it;
  /* x- = f(x) (angle states wrapped), F's nonzeros; S- = tria([F S, sqrt Q]). */
  a2[0] = x; a2[1] = p; r2[0] = xp; r2[1] = Fz;
  if (EKF_(fpart)(a2, r2, iw, w, 0)) return 1;
  EKF_(times_lower)(A, EKF_(fcol), EKF_(frow), Fz, S, n, n);
  for (j = 0; j < n; ++j)
    for (i = 0; i < n; ++i) A[n * n + i + j * n] = i >= j ? Qs[i + j * n] : 0;
  EKF_(tria)(A, n, 2 * n, Sp, vt, wt);
  /* The update at x-: its nu, S = Sy Sy^T, NIS and log-likelihood are the step's. */
  if (EKF_(update)(xp, xp, Sp, y, Rs, mask, p, iw, w, nu, Hz, Y, A, L, wh, dx, vt, wt, acc)) return 1;
  if (res[5]) EKF_(array_s)(L, N2, ny, res[5]);
  /* x+ = x- + Kb (Sy^-1 nu); the IEKF's Gauss-Newton steps relinearise h at x+. */
  for (it = 0; it < EKF_ITERATIONS; ++it) {
    if (it) {
      for (j = 0; j < n; ++j) xl[j] = xn[j];
      if (EKF_(update)(xl, xp, Sp, y, Rs, mask, p, iw, w, nu2, Hz, Y, A, L, wh2, dx, vt, wt, acc2)) return 1;
      wx = wh2;
    }
    EKF_(array_x)(L, N2, n, ny, xp, wx, xn);
  }
  if (EKF_WRAP_X) {
    a2[0] = xn; r2[0] = res[0];
    if (EKF_(xwrap)(a2, r2, iw, w, 0)) return 1;
  } else {
    for (j = 0; j < n; ++j) res[0][j] = xn[j];
  }
  /* S+: the last linearisation's. */
  EKF_(array_sp)(L, N2, n, ny, res[1]);
  if (res[6]) res[6][0] = -0.5 * (acc[0] + 2 * acc[1] + acc[2] * EKF_LOG_2PI);
  if (res[7]) res[7][0] = acc[0];
  return 0;
}
