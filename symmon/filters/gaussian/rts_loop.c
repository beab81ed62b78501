/* symmon: the RTS backward pass of RTL_STEP over a bank (symmon.filters.gaussian.smoother, whose
   _CompiledSmoother puts before this file the step's generated C, the C backward step when it
   runs one, and the RTL_ macros: the kernel's name RTL_NAME, the sizes, the step RTL_STEP and
   its scratch argument RTL_S (s, or 0)).  RTL_(x) is the name followed by _x.
   x (runs*K*n), P (runs*K*n*n) filtered; xs, Ps smoothed, the same layout; stop (not null) is
   polled before each step, as in the filter's loop.  s: the scratch of a C backward step
   (RTL_SCRATCH reals), one block per call. */
#ifndef RTL_NAME  /* checked alone: example macros, and the prototype of the step */
#include "../../compile/casadi_alone.h"
#define RTL_NAME model
#define RTL_STEP model_bwd
#define RTL_S s
#define RTL_SZ_ARG 6
#define RTL_SZ_RES 2
#define RTL_N 2
#define RTL_NN 4
#define RTL_N_P 0
#define RTL_SCRATCH 16
#define RTL_STOPPED 2
int RTL_STEP(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, casadi_real* s);
#endif
#define RTL_CAT2(a, b) a##_##b
#define RTL_CAT(a, b) RTL_CAT2(a, b)
#define RTL_(s) RTL_CAT(RTL_NAME, s)  /* RTL_(run): the kernel's name, _run */
#include <stdlib.h>
static int RTL_(loop)(const casadi_real* x, const casadi_real* P, const casadi_real* Q,
    const casadi_real* p, casadi_real* xs, casadi_real* Ps, casadi_int runs, casadi_int K, casadi_int* iw,
    casadi_real* w, const volatile int* stop, casadi_real* s) {
  const casadi_real* arg[RTL_SZ_ARG];
  casadi_real* res[RTL_SZ_RES];
  casadi_int r, k, i;
  for (r = 0; r < runs; ++r) {
    i = r * K + K - 1;
    for (k = 0; k < RTL_N; ++k) xs[i * RTL_N + k] = x[i * RTL_N + k];
    for (k = 0; k < RTL_NN; ++k) Ps[i * RTL_NN + k] = P[i * RTL_NN + k];
    for (k = K - 2; k >= 0; --k) {
      if (stop && *stop) return RTL_STOPPED;
      i = r * K + k;
      arg[0] = x + i * RTL_N; arg[1] = P + i * RTL_NN; arg[2] = xs + (i + 1) * RTL_N;
      arg[3] = Ps + (i + 1) * RTL_NN; arg[4] = Q; arg[5] = p + (i + 1) * RTL_N_P;
      res[0] = xs + i * RTL_N; res[1] = Ps + i * RTL_NN;
      if (RTL_STEP(arg, res, iw, w, RTL_S)) return 1;
    }
  }
  return 0;
}

CASADI_SYMBOL_EXPORT int RTL_(run)(const casadi_real* x, const casadi_real* P, const casadi_real* Q,
    const casadi_real* p, casadi_real* xs, casadi_real* Ps, casadi_int runs, casadi_int K, casadi_int* iw,
    casadi_real* w, const volatile int* stop) {
  casadi_real* s = 0;
  int code;
  if (RTL_SCRATCH && !(s = (casadi_real*)malloc(RTL_SCRATCH * sizeof(casadi_real)))) return 1;
  code = RTL_(loop)(x, P, Q, p, xs, Ps, runs, K, iw, w, stop, s);
  free(s);
  return code;
}
