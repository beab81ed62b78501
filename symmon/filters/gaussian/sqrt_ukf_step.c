/* symmon: the square-root step EKF_(sqrt_ukf) of a point rule with non-negative weights (the
   UKF, the cubature rule; additive noise) around the CasADi pieces EKF_(upred), EKF_(uupd),
   EKF_(xwrap); the factor arithmetic of symmon.filters.gaussian._sqrtstep (its notes),
   column-major as CasADi.  _ukfstep.sqrt_ukf_c puts before this file the pieces' generated C
   and the EKF_ macros (the kernel's name EKF_NAME, its sizes, EKF_KF, EKF_K0, EKF_KD the
   columns of f's and h's deviations, EKF_M2 those of the second pre-array,
   EKF_SZ_ARG and EKF_SZ_RES the pieces' argument and result arrays (MX: their calls' scratch)).
   arg: x, S, y, sqrt Q, sqrt R, mask, p (S, sqrt Q, sqrt R lower factors); res: x+, S+, x-, S-,
   nu, S_y S_y^T, loglik, nis (null: not kept; then scratch).  s: scratch of EKF_SCRATCH reals. */
#ifndef EKF_NAME  /* checked alone: example macros, and the pieces' prototypes */
#include "../../compile/casadi_alone.h"
#define EKF_NAME model
#define EKF_N 2
#define EKF_NY 1
#define EKF_KF 2
#define EKF_K0 1
#define EKF_KD 2
#define EKF_M2 3
#define EKF_SZ_ARG 4
#define EKF_SZ_RES 4
#define EKF_WRAP_X 1
#define EKF_LOG_2PI 1.8378770664093453
#define EKF_SCRATCH 160
#define EKF_MA 24
#define EKF_MV 8
#define EKF_CHECK_ALONE 1
#endif
#include "ekf_names.h"
#ifdef EKF_CHECK_ALONE
EKF_PIECE(upred);
EKF_PIECE(uupd);
EKF_PIECE(xwrap);
#endif
#include <math.h>
/* A few KB of C: optimised whatever the size of the file around it; no FMA contraction. */
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC optimize ("O3", "fp-contract=off")
#endif

#include "sqrt_tria.c"

/* The step: x- and the points' weighted deviations Yp (n x KF) from EKF_(upred), S- =
   tria([sqrt Q, Yp]) (the noise's triangle first: its reflections skip its zeros); then nu
   and the joint columns of h's points at N(x-, S- S-^T) from EKF_(uupd), the pairs of points
   +-z rotated (_ukfstep._paired): Y0 (ny x K0) over a zero X part, Yd (ny x KD) over Xd
   (n x KD).  The update is the triangularisation of the pre-array (rows y, then x)

       [ D sqrt R   I - D   D Y0   D Yd ]        [ Sy   0  ]
       [    0         0      0      Xd  ]   ->   [ Kb   S+ ]

   (the array form of sqrt_ekf_step.c: Sy Sy^T = D Y Y^T D + D R D + (I - D), Kb Sy^T =
   X Y^T D = P^xy, Kb Kb^T + S+ S+^T = X X^T = P-), in two parts: the columns with a zero x
   part first, on the y rows alone (Ly, ny x ny), then [Ly, D Yd; 0, Xd]; x+ = x- + Kb Sy^-1 nu. */
static int EKF_(sqrt_ukf)(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w,
    casadi_real* s) {
  const casadi_int n = EKF_N, ny = EKF_NY, kf = EKF_KF, k0 = EKF_K0, kd = EKF_KD, m2 = EKF_M2;
  const casadi_int N2 = EKF_N + EKF_NY;
  const casadi_real *x = arg[0], *S = arg[1], *y = arg[2], *Qs = arg[3], *Rs = arg[4], *mask = arg[5];
  const casadi_real* p = arg[6];
  casadi_real *xp = res[2] ? res[2] : s, *Sp = res[3] ? res[3] : s + n;
  casadi_real *A = s + n + n * n, *Y0 = A + EKF_MA, *Yd = Y0 + ny * k0, *Xd = Yd + ny * kd, *L = Xd + n * kd;
  casadi_real *Ly = L + N2 * N2, *wh = Ly + ny * ny, *xn = wh + ny, *vt = xn + n, *wt = vt + EKF_MV;
  casadi_real *nus = wt + EKF_MV, *nu = res[4] ? res[4] : nus, nis = 0, logdet = 0, measured = 0;
  const casadi_real* a4[EKF_SZ_ARG];
  casadi_real* r4[EKF_SZ_RES];
  casadi_int i, j, k;
  a4[0] = x; a4[1] = S; a4[2] = p; r4[0] = xp; r4[1] = A + n * n;
  if (EKF_(upred)(a4, r4, iw, w, 0)) return 1;
  for (j = 0; j < n; ++j)
    for (i = 0; i < n; ++i) A[i + j * n] = i >= j ? Qs[i + j * n] : 0;
  EKF_(tria)(A, n, n + kf, Sp, vt, wt);
  a4[0] = xp; a4[1] = Sp; a4[2] = y; a4[3] = p; r4[0] = nu; r4[1] = Y0; r4[2] = Yd; r4[3] = Xd;
  if (EKF_(uupd)(a4, r4, iw, w, 0)) return 1;
  for (i = 0; i < ny; ++i) {
    measured += mask[i];
    nu[i] *= mask[i];
  }
  /* [D sqrt R, I - D, D Y0] (ny rows) -> Ly. */
  for (j = 0; j < ny; ++j) {
    casadi_real* a = A + j * ny;
    casadi_real* d = A + (ny + j) * ny;
    for (i = 0; i < ny; ++i) {
      a[i] = i >= j ? mask[i] * Rs[i + j * ny] : 0;
      d[i] = i == j ? 1 - mask[i] : 0;
    }
  }
  for (j = 0; j < k0; ++j)
    for (i = 0; i < ny; ++i) A[i + (2 * ny + j) * ny] = mask[i] * Y0[i + j * ny];
  EKF_(tria)(A, ny, 2 * ny + k0, Ly, vt, wt);
  /* [Ly, D Yd; 0, Xd] (N2 rows, zero columns up to m2) -> L. */
  for (j = 0; j < m2; ++j) {
    casadi_real* a = A + j * N2;
    if (j < ny) {
      for (i = 0; i < ny; ++i) a[i] = Ly[i + j * ny];
      for (k = 0; k < n; ++k) a[ny + k] = 0;
    } else if (j < ny + kd) {
      for (i = 0; i < ny; ++i) a[i] = mask[i] * Yd[i + (j - ny) * ny];
      for (k = 0; k < n; ++k) a[ny + k] = Xd[k + (j - ny) * n];
    } else {
      for (i = 0; i < N2; ++i) a[i] = 0;
    }
  }
  EKF_(tria)(A, N2, m2, L, vt, wt);
  for (i = 0; i < ny; ++i) {
    casadi_real d = L[i + i * N2], v = nu[i];
    for (k = 0; k < i; ++k) v -= L[i + k * N2] * wh[k];
    wh[i] = d > 0 ? v / d : 0;
    nis += wh[i] * wh[i];
    logdet += log(d);
  }
  if (res[5]) EKF_(array_s)(L, N2, ny, res[5]);
  EKF_(array_x)(L, N2, n, ny, xp, wh, xn);
  if (EKF_WRAP_X) {
    a4[0] = xn; r4[0] = res[0];
    if (EKF_(xwrap)(a4, r4, iw, w, 0)) return 1;
  } else {
    for (j = 0; j < n; ++j) res[0][j] = xn[j];
  }
  EKF_(array_sp)(L, N2, n, ny, res[1]);
  if (res[6]) res[6][0] = -0.5 * (nis + 2 * logdet + measured * EKF_LOG_2PI);
  if (res[7]) res[7][0] = nis;
  return 0;
}
