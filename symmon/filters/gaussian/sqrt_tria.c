/* symmon: the Householder triangularisation EKF_(tria) of the square-root steps in C
   (sqrt_ekf_step.c, sqrt_ukf_step.c include it), and what both read from an update's
   triangularised pre-array (EKF_(array_s), EKF_(array_x), EKF_(array_sp)): the kernel's name
   EKF_NAME and the longest row EKF_MV are defined before it. */
#ifndef EKF_NAME  /* checked alone: example macros */
#include "../../compile/casadi_alone.h"
#include <math.h>
#define EKF_NAME model
#define EKF_MV 4
#include "ekf_names.h"
void EKF_(tria_check)(casadi_real* A, casadi_real* L, casadi_real* v, casadi_real* w);
#endif
/* L (n x n, lower, diag >= 0) with L L^T = A A^T, A (n x m, n <= m <= EKF_MV) overwritten:
   the Householder triangularisation of codegen.sqrtform.tria, row j of the trailing columns
   j..m-1 reflected onto column j.  A column whose entry in row j is zero has a zero entry in
   the reflection's vector, so the reflection leaves it as it is: it is skipped; and the rows
   below the last nonzero of every column the reflection touches are zero in all of them, so
   they are skipped too (last[c]: the last row where column c may be nonzero).  Row j then
   costs 4 (rows it reaches) times (its nonzeros): block-diagonal factors and Jacobians stay
   sparse through the steps, and a dense A costs the 2 n^2 m of the MX step.  v: m reals,
   w: n reals of scratch. */
static void EKF_(tria)(casadi_real* restrict A, casadi_int n, casadi_int m, casadi_real* restrict L,
    casadi_real* restrict v, casadi_real* restrict w) {
  casadi_int i, j, c, t, cnt, top, last[EKF_MV], idx[EKF_MV];
  /* The last nonzero of each column: a pass without an early exit (no mispredicted branch). */
  for (c = 0; c < m; ++c) {
    const casadi_real* a = A + c * n;
    casadi_int l = -1;
    for (i = 0; i < n; ++i) l = a[i] != 0 ? i : l;
    last[c] = l;
  }
  for (i = 0; i < n * n; ++i) L[i] = 0;
  for (j = 0; j < n; ++j) {
    casadi_real sum, vv, sigma, x0, sg, beta, vj;
    casadi_real* lj = L + j * n;
    const casadi_real* aj = A + j * n;
    casadi_int hi = j;
    /* Row j: the pivot x0, then the nonzeros of the other columns (idx, their values v),
       the list appended to without a branch; the sums over the nonzeros only (a zero adds
       nothing), in the columns' order. */
    x0 = aj[j];
    cnt = 0;
    for (c = j + 1; c < m; ++c) {
      casadi_real x = A[j + c * n];
      idx[cnt] = c;
      v[cnt] = x;
      cnt += x != 0;
    }
    sum = x0 * x0;
    for (t = 0; t < cnt; ++t) sum += v[t] * v[t];
    sigma = sqrt(sum);
    sg = x0 >= 0 ? 1 : -1;
    vj = x0 + sg * sigma;
    vv = vj * vj;
    if (vj != 0 && last[j] > hi) hi = last[j];
    for (t = 0; t < cnt; ++t) {
      vv += v[t] * v[t];
      if (last[idx[t]] > hi) hi = last[idx[t]];
    }
    /* vv = 2 sigma (sigma + |x0|): zero only for a zero row, which needs no reflection. */
    beta = vv > 0 ? 2 / vv : 0;
    lj[j] = sigma;
    if (j == n - 1) break;
    for (i = j + 1; i <= hi; ++i) w[i] = aj[i] * vj;
    for (t = 0; t < cnt; ++t) {
      casadi_real vc = v[t];
      const casadi_real* a = A + idx[t] * n;
      for (i = j + 1; i <= hi; ++i) w[i] += a[i] * vc;
    }
    for (i = j + 1; i <= hi; ++i) {
      w[i] *= beta;
      lj[i] = -sg * (aj[i] - w[i] * vj);
    }
    /* Below hi, w is zero: the pivot column as it is (nonzero there only for a zero row). */
    top = last[j] > hi ? last[j] : hi;
    for (i = hi + 1; i <= top; ++i) lj[i] = -sg * aj[i];
    for (t = 0; t < cnt; ++t) {
      casadi_real vc = v[t];
      casadi_real* a = A + idx[t] * n;
      c = idx[t];
      for (i = j + 1; i <= hi; ++i) a[i] -= w[i] * vc;
      if (hi > last[c]) last[c] = hi;
    }
  }
}

/* The update's pre-array triangularised, L (N2 = ny + n rows, lower): [[Sy, 0], [Kb, S+]].
   S = Sy Sy^T, both triangles (ny x ny). */
static void EKF_(array_s)(const casadi_real* L, casadi_int N2, casadi_int ny, casadi_real* S) {
  casadi_int i, j, k;
  for (j = 0; j < ny; ++j)
    for (i = j; i < ny; ++i) {
      casadi_real v = 0;
      for (k = 0; k <= j; ++k) v += L[i + k * N2] * L[j + k * N2];
      S[i + j * ny] = v;
      S[j + i * ny] = v;
    }
}

/* x+ = x- + Kb wh (wh = Sy^-1 nu), into xn (n). */
static void EKF_(array_x)(const casadi_real* L, casadi_int N2, casadi_int n, casadi_int ny,
    const casadi_real* xp, const casadi_real* wh, casadi_real* xn) {
  casadi_int i, j;
  for (j = 0; j < n; ++j) xn[j] = xp[j];
  for (i = 0; i < ny; ++i) {
    const casadi_real* c = L + ny + i * N2;
    for (j = 0; j < n; ++j) xn[j] += c[j] * wh[i];
  }
}

/* S+ (n x n), the trailing block of L. */
static void EKF_(array_sp)(const casadi_real* L, casadi_int N2, casadi_int n, casadi_int ny, casadi_real* Sn) {
  casadi_int i, j;
  for (j = 0; j < n; ++j)
    for (i = 0; i < n; ++i) Sn[i + j * n] = L[ny + i + (ny + j) * N2];
}

#ifndef EKF_N  /* checked alone: the kernel used */
void EKF_(tria_check)(casadi_real* A, casadi_real* L, casadi_real* v, casadi_real* w) {
  EKF_(tria)(A, 2, 4, L, v, w);
  EKF_(array_s)(L, 2, 1, v);
  EKF_(array_x)(L, 2, 1, 1, v, v + 1, w);
  EKF_(array_sp)(L, 2, 1, 1, w);
}
#endif
