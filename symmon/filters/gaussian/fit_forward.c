/* symmon: the log-likelihood of a bank and its derivatives in the fitted rows of the step's
   data, in forward mode (symmon.filters.gaussian.fit, whose _CompiledLoglik puts before this
   file the generated C of the step's functions and the FIT_ macros: the library's name
   FIT_NAME, the sizes FIT_NS (the step's state [x; vec(P)]), FIT_ND (its data),
   FIT_NZ = FIT_NS + FIT_ND, FIT_NO = FIT_NS + 1 (the step's output), FIT_M (the tangents: one
   per parameter of the filter) and FIT_MM = FIT_M * FIT_M, FIT_MAX_ORDER, FIT_SZ_ARG and
   FIT_SZ_RES).  With FIT_HESSIAN 0 (the first library) the calls are the step FIT_(f), its
   Jacobian times all the tangents FIT_(jvp), or (a part of them on a thread) times one
   tangent per call, FIT_(jvp1); with FIT_HESSIAN 1 (the second library) FIT_(hess), the
   forward derivative of the jvp along one tangent, once per fitted parameter.

   D (runs*K*FIT_ND): the step's data per step; S0 (runs*FIT_NS): [x0; vec(P0)] per run;
   rows (m <= FIT_M): the fitted rows of the data; order 0: the value, 1: + gradient,
   2: + Hessian, added into out = [l, g (m), H (m*m, row-major)]; l only when j0 = 0, of g
   only the entries j0 <= j < j1, of H only the entries (i, j) with j0 <= max(i, j) < j1, the
   tangents computed (so that calls on parts add up to one call's out).
   Z ((1 + FIT_M + FIT_MM) * (FIT_NZ + FIT_NO)): work; T: unused.  Column j < m of zd is
   dz/dtheta_j = [T_j; e_{rows[j]}], column i + FIT_M j of zdd is d2z/dtheta_i dtheta_j =
   [T_ij; 0] (columns of i or j >= m: zero, and those of j >= m neither computed nor read);
   od and odd the same of o. */
#ifndef FIT_NAME  /* checked alone: example macros, and the prototypes of the functions called */
#include "../../compile/casadi_alone.h"
#define FIT_NAME model
#define FIT_HESSIAN 0
#define FIT_NS 6
#define FIT_ND 5
#define FIT_NZ 11
#define FIT_NO 7
#define FIT_M 2
#define FIT_MM 4
#define FIT_MAX_ORDER 1
#define FIT_SZ_ARG 6
#define FIT_SZ_RES 3
#define FIT_ALONE
#endif
#include "fit_driver.h"
FIT_PROTOTYPE;
#ifdef FIT_ALONE
FIT_FUNCTION(f);
FIT_FUNCTION(jvp);
FIT_FUNCTION(jvp1);
FIT_FUNCTION(hess);
#endif
FIT_SIGNATURE
  /* zd: M first-order tangents, then M*M second-order ones; od, odd: those of o */
  casadi_real *z = Z, *zd = z + FIT_NZ, *o = zd + FIT_NZ * (FIT_M + FIT_MM), *od = o + FIT_NO, *odd = od + FIT_NO * FIT_M;
  casadi_int r, k, i, j;
  (void)T;
  if (m > FIT_M || order > FIT_MAX_ORDER || (order > 1 && m < 1)) return 1;
  for (r = 0; r < runs; ++r) {
    for (i = 0; i < FIT_NS; ++i) z[i] = S0[r * FIT_NS + i];
    for (i = 0; i < FIT_NZ * (FIT_M + FIT_MM); ++i) zd[i] = 0.0;
    for (j = 0; j < m; ++j) zd[j * FIT_NZ + FIT_NS + rows[j]] = 1.0;
    for (k = 0; k < K; ++k) {
      for (i = 0; i < FIT_ND; ++i) z[FIT_NS + i] = D[(r * K + k) * FIT_ND + i];
      arg[0] = z; arg[1] = Q; arg[2] = R; arg[3] = zd; res[0] = o; res[1] = od;
#if FIT_HESSIAN
      /* one call per fitted parameter j, each giving the columns i + M j (i < M) of the
         second-order tangents (and the first-order ones, again) */
      for (j = j0; j < j1 && j < m; ++j) {
        arg[4] = zd + j * FIT_NZ; arg[5] = zd + FIT_NZ * (FIT_M + j * FIT_M); res[2] = od + FIT_NO * (FIT_M + j * FIT_M);
        if (FIT_(hess)(arg, res, iw, w, 0)) return 1;
      }
#else
      /* the step, its Jacobian times all the tangents, or (a part j0 <= j < j1 of them, on a
         thread) times one tangent per call */
      if (order == 0) {
        if (FIT_(f)(arg, res, iw, w, 0)) return 1;
      } else if (j0 == 0 && j1 >= m) {
        if (FIT_(jvp)(arg, res, iw, w, 0)) return 1;
      } else {
        for (j = j0; j < j1 && j < m; ++j) {
          arg[3] = zd + j * FIT_NZ; res[1] = od + j * FIT_NO;
          if (FIT_(jvp1)(arg, res, iw, w, 0)) return 1;
        }
      }
#endif
      if (j0 == 0) out[0] += o[FIT_NS];
      for (j = j0; j < j1 && j < m && order > 0; ++j) out[1 + j] += od[j * FIT_NO + FIT_NS];
      /* H_ij = H_ji from the column min(i, j) + M max(i, j): symmetric to the bit */
      for (i = 0; i < m * m && order > 1; ++i) {
        casadi_int lo = i / m < i % m ? i / m : i % m, hi = i / m < i % m ? i % m : i / m;
        if (hi >= j0 && hi < j1) out[1 + m + i] += odd[(lo + FIT_M * hi) * FIT_NO + FIT_NS];
      }
      if (k + 1 == K) break;
      /* s_{k+1} and its tangents: the first FIT_NS rows of each output column */
      for (i = 0; i < FIT_NS; ++i) z[i] = o[i];
      for (j = 0; j < FIT_M * (order > 0) + FIT_M * m * (order > 1); ++j)
        for (i = 0; i < FIT_NS; ++i) zd[j * FIT_NZ + i] = od[j * FIT_NO + i];
    }
  }
  return 0;
}
