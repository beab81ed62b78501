/* symmon: the log-likelihood of a bank and its derivatives in the fitted rows of the step's
   data, in reverse mode (symmon.filters.gaussian.fit, whose _CompiledLoglik puts before this
   file the generated C of the step FIT_(f), its vector-Jacobian product FIT_(vjp) and, with
   FIT_HESSIAN 1, its Jacobian-vector product FIT_(jvp) and the derivative FIT_(hvp) of the
   vjp, and the FIT_ macros: the library's name FIT_NAME, the sizes FIT_NS (the step's state
   [x; vec(P)]), FIT_ND (its data) and FIT_NZ = FIT_NS + FIT_ND, FIT_SZ_ARG and FIT_SZ_RES).
   One reverse sweep gives the gradient, a forward-over-reverse sweep per fitted parameter
   the Hessian (FIT_HESSIAN 1: the second library only).

   D (runs*K*FIT_ND): the step's data per step; S0 (runs*FIT_NS): [x0; vec(P0)] per run;
   rows (m): the fitted rows of the data; order 0: the value, 1: + gradient, 2: + Hessian,
   added into out = [l, g (m), H (m*m, row-major)]; l and g only when j0 = 0, and of H only
   the columns j0 <= j < j1 (so that calls on parts of the columns add up to one call's out).
   Z (K*FIT_NZ) and T (K*FIT_NS): work. */
#ifndef FIT_NAME  /* checked alone: example macros, and the prototypes of the functions called */
#include "../../compile/casadi_alone.h"
#define FIT_NAME model
#define FIT_HESSIAN 1
#define FIT_NS 6
#define FIT_ND 5
#define FIT_NZ 11
#define FIT_SZ_ARG 6
#define FIT_SZ_RES 2
#define FIT_ALONE
#endif
#include "fit_driver.h"
FIT_PROTOTYPE;
#ifdef FIT_ALONE
FIT_FUNCTION(f);
FIT_FUNCTION(vjp);
FIT_FUNCTION(jvp);
FIT_FUNCTION(hvp);
#endif
FIT_SIGNATURE
  casadi_real o[FIT_NS + 1], lam[FIT_NS + 1], lamd[FIT_NS + 1], a[FIT_NZ], ad[FIT_NZ], zd[FIT_NZ];
  casadi_int r, k, i, j;
  for (r = 0; r < runs; ++r) {
    /* forward: z_k = [s_k; d_k], s_{k+1}, l_k = step(z_k) */
    for (i = 0; i < FIT_NS; ++i) Z[i] = S0[r * FIT_NS + i];
    for (k = 0; k < K; ++k) {
      for (i = 0; i < FIT_ND; ++i) Z[k * FIT_NZ + FIT_NS + i] = D[(r * K + k) * FIT_ND + i];
      arg[0] = Z + k * FIT_NZ; arg[1] = Q; arg[2] = R; res[0] = o;
      if (FIT_(f)(arg, res, iw, w, 0)) return 1;
      if (j0 == 0) out[0] += o[FIT_NS];
      if (k + 1 < K) for (i = 0; i < FIT_NS; ++i) Z[(k + 1) * FIT_NZ + i] = o[i];
    }
    if (order < 1) continue;
    /* reverse (j0 = 0 only): the adjoint [lambda_{k+1}; 1] of (s_{k+1}, l_k) gives that of z_k */
    for (i = 0; i < FIT_NS; ++i) lam[i] = 0.0;
    lam[FIT_NS] = 1.0;
    for (k = K - 1; k >= 0 && j0 == 0; --k) {
      arg[0] = Z + k * FIT_NZ; arg[1] = Q; arg[2] = R; arg[3] = lam; res[0] = a;
      if (FIT_(vjp)(arg, res, iw, w, 0)) return 1;
      for (j = 0; j < m; ++j) out[1 + j] += a[FIT_NS + rows[j]];
      for (i = 0; i < FIT_NS; ++i) lam[i] = a[i];
    }
#if FIT_HESSIAN
    if (order < 2) continue;
    for (j = j0; j < j1 && j < m; ++j) {
      /* forward tangent of the states along parameter j (T_k = ds_k/dtheta_j), then the
         reverse sweep of the adjoint and its tangent: column j of the Hessian */
      for (i = 0; i < FIT_NZ; ++i) zd[i] = 0.0;
      zd[FIT_NS + rows[j]] = 1.0;
      for (i = 0; i < FIT_NS; ++i) T[i] = 0.0;
      for (k = 0; k + 1 < K; ++k) {
        for (i = 0; i < FIT_NS; ++i) zd[i] = T[k * FIT_NS + i];
        arg[0] = Z + k * FIT_NZ; arg[1] = Q; arg[2] = R; arg[3] = zd; res[0] = o;
        if (FIT_(jvp)(arg, res, iw, w, 0)) return 1;
        for (i = 0; i < FIT_NS; ++i) T[(k + 1) * FIT_NS + i] = o[i];
      }
      for (i = 0; i <= FIT_NS; ++i) lam[i] = lamd[i] = 0.0;
      lam[FIT_NS] = 1.0;
      for (k = K - 1; k >= 0; --k) {
        for (i = 0; i < FIT_NS; ++i) zd[i] = T[k * FIT_NS + i];
        arg[0] = Z + k * FIT_NZ; arg[1] = Q; arg[2] = R; arg[3] = zd; arg[4] = lam; arg[5] = lamd;
        res[0] = a; res[1] = ad;
        if (FIT_(hvp)(arg, res, iw, w, 0)) return 1;
        for (i = 0; i < m; ++i) out[1 + m + i * m + j] += ad[FIT_NS + rows[i]];
        for (i = 0; i < FIT_NS; ++i) { lam[i] = a[i]; lamd[i] = ad[i]; }
      }
    }
#endif
  }
  return 0;
}
