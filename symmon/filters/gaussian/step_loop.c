/* symmon: a bank of runs of the filter step KFL_STEP (symmon.filters.gaussian.step, whose
   _CompiledStep puts before this file the step's generated C, the C EKF step when it runs one,
   and the KFL_ macros: the kernel's name KFL_NAME, the sizes, the step KFL_STEP and its scratch
   argument KFL_S (s, or 0), the NEES function KFL_NEES).  KFL_(x) is the name followed by _x.
   outs[j] is output j's block and
   strides[j] its size per step; a stride of 0 means "not kept": the step does not write it
   (a null result), but x and P, which the next step reads, go to two slots, alternately,
   so that a step never writes what it reads.  With the true states (truth, not null), each
   step's NEES and its singularity test go to outs[8] and outs[9] (KFL_NEES).  With
   failed (not null), failed[r] is the first step of run r whose x, P or log-likelihood is
   not finite (the run stops there), or -1.  Before each step it polls stop (not null): set
   by the thread that waits for the bank when that is interrupted, it ends the loop. */
#ifndef KFL_NAME  /* checked alone: example macros, and the prototypes of the functions called */
#include "../../compile/casadi_alone.h"
#define KFL_NAME model
#define KFL_STEP model_ekf
#define KFL_S s
#define KFL_NEES modelnees_of
#define KFL_SZ_ARG 7
#define KFL_SZ_RES 8
#define KFL_N 2
#define KFL_NN 4
#define KFL_N_Y 1
#define KFL_N_P 0
#define KFL_SCRATCH 16
#define KFL_STOPPED 2
int KFL_STEP(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, casadi_real* s);
int KFL_NEES(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
#endif
#define KFL_CAT2(a, b) a##_##b
#define KFL_CAT(a, b) KFL_CAT2(a, b)
#define KFL_(s) KFL_CAT(KFL_NAME, s)  /* KFL_(run): the kernel's name, _run */
#include <stdlib.h>
#include <string.h>
static int KFL_(nonfinite)(const casadi_real* a, casadi_int n) {
  /* An exponent of all ones is inf or NaN; an integer test, so that the loop vectorises. */
  unsigned long long u, bad = 0;
  casadi_int j;
  for (j = 0; j < n; ++j) {
    memcpy(&u, a + j, sizeof u);
    bad |= (u & 0x7ff0000000000000ULL) == 0x7ff0000000000000ULL;
  }
  return bad != 0;
}

static int KFL_(loop)(const casadi_real* x0, casadi_int x0_step,
    const casadi_real* P0, casadi_int P0_step, const casadi_real* y,
    const casadi_real* Q, const casadi_real* R, const casadi_real* mask, const casadi_real* p,
    const casadi_real* truth, casadi_real* const* outs, const casadi_int* strides, casadi_int runs,
    casadi_int K, casadi_int* iw, casadi_real* w, casadi_int* failed, const volatile int* stop,
    casadi_real* s) {
  const casadi_real* arg[KFL_SZ_ARG];
  casadi_real* res[KFL_SZ_RES];
  casadi_real* res2[KFL_SZ_RES];
  casadi_real ll;
  casadi_int r, k, i, j;
  for (r = 0; r < runs; ++r) {
    if (failed) failed[r] = -1;
    const casadi_real* x = x0 + r * x0_step;
    const casadi_real* P = P0 + r * P0_step;
    for (k = 0; k < K; ++k) {
      if (stop && *stop) return KFL_STOPPED;
      i = r * K + k;
      arg[0] = x; arg[1] = P; arg[2] = y + i * KFL_N_Y; arg[3] = Q; arg[4] = R; arg[5] = mask + i * KFL_N_Y;
      arg[6] = p + i * KFL_N_P;
      for (j = 0; j < 8; ++j) res[j] = strides[j] ? outs[j] + i * strides[j] : 0;
      if (!strides[0]) res[0] = outs[0] + (k & 1) * KFL_N;
      if (!strides[1]) res[1] = outs[1] + (k & 1) * KFL_NN;
      if (failed && !res[6]) res[6] = &ll;
      if (KFL_STEP(arg, res, iw, w, KFL_S)) return 1;
      x = res[0];
      P = res[1];
      if (failed && (KFL_(nonfinite)(res[6], 1) || KFL_(nonfinite)(x, KFL_N) || KFL_(nonfinite)(P, KFL_NN))) {
        failed[r] = k;
        break;
      }
      if (truth) {
        arg[0] = x; arg[1] = P; arg[2] = truth + i * KFL_N;
        res2[0] = outs[8] + i; res2[1] = outs[9] + i;
        if (KFL_NEES(arg, res2, iw, w, 0)) return 1;
      }
    }
  }
  return 0;
}

/* The loop with its scratch (KFL_SCRATCH reals: the C EKF step's work, one block per call). */
CASADI_SYMBOL_EXPORT int KFL_(run)(const casadi_real* x0, casadi_int x0_step,
    const casadi_real* P0, casadi_int P0_step, const casadi_real* y,
    const casadi_real* Q, const casadi_real* R, const casadi_real* mask, const casadi_real* p,
    const casadi_real* truth, casadi_real* const* outs, const casadi_int* strides, casadi_int runs,
    casadi_int K, casadi_int* iw, casadi_real* w, casadi_int* failed, const volatile int* stop) {
  casadi_real* s = 0;
  int code;
  if (KFL_SCRATCH && !(s = (casadi_real*)malloc(KFL_SCRATCH * sizeof(casadi_real)))) return 1;
  code = KFL_(loop)(x0, x0_step, P0, P0_step, y, Q, R, mask, p, truth, outs, strides, runs, K, iw, w,
                     failed, stop, s);
  free(s);
  return code;
}
