/* symmon: an IMM over the filter steps of its modes (symmon.filters.mixture.imm, _FusedLoop):
   for each run, K steps of the IMM recursion, each calling the modes' steps.  outs[0..6] are
   the modes' x, P, x-, P-, nu, S, log Lambda (run, step, mode, ...), outs[7] mu and outs[8]
   cbar.  A mode's previous x and P are its outputs of the step before.  _FusedLoop puts
   before this file the generated C of the modes' steps (IMM_STEP_0 ... IMM_STEP_<M-1>, at most
   IMM_MAX_MODES) and the IMM_ macros.  Before each step it polls stop (NULL: never), a flag
   another thread may set (a Ctrl-C of the waiting thread), and returns IMM_STOPPED. */
#ifndef IMM_M  /* checked alone: example macros (_FusedLoop defines them), and what comes before */
#include "../../compile/casadi_alone.h"
#define IMM_BAD imm_model_bad
#define IMM_WRAP imm_model_wrap
#define IMM_STEP imm_model_step
#define IMM_RUN imm_model_run
#define IMM_STEP_0 imm_cv
#define IMM_STEP_1 imm_ct
#define IMM_M 2
#define IMM_N 3
#define IMM_NY 1
#define IMM_N_ANG 1
#define IMM_ANGLES 2
#define IMM_SZ_ARG 7
#define IMM_SZ_RES 8
#define IMM_STOPPED 2
int IMM_STEP_0(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int IMM_STEP_1(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
#endif
#define IMM_MAX_MODES 16
#if IMM_M > IMM_MAX_MODES
#error "the fused IMM loop takes at most IMM_MAX_MODES modes"
#endif
#include <math.h>
#include <string.h>
#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif
static int IMM_BAD(const casadi_real* a, casadi_int n) {
  unsigned long long u, bad = 0;
  casadi_int j;
  for (j = 0; j < n; ++j) {
    memcpy(&u, a + j, sizeof u);
    bad |= (u & 0x7ff0000000000000ULL) == 0x7ff0000000000000ULL;
  }
  return bad != 0;
}
static casadi_real IMM_WRAP(casadi_real a) {
  casadi_real r = fmod(a + M_PI, 2 * M_PI);
  if (r < 0) r += 2 * M_PI;
  r -= M_PI;
  return r == -M_PI ? M_PI : r;
}
static int IMM_STEP(casadi_int j, const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w) {
  switch (j) {
#if IMM_M > 0
    case 0: return IMM_STEP_0(arg, res, iw, w, 0);
#endif
#if IMM_M > 1
    case 1: return IMM_STEP_1(arg, res, iw, w, 0);
#endif
#if IMM_M > 2
    case 2: return IMM_STEP_2(arg, res, iw, w, 0);
#endif
#if IMM_M > 3
    case 3: return IMM_STEP_3(arg, res, iw, w, 0);
#endif
#if IMM_M > 4
    case 4: return IMM_STEP_4(arg, res, iw, w, 0);
#endif
#if IMM_M > 5
    case 5: return IMM_STEP_5(arg, res, iw, w, 0);
#endif
#if IMM_M > 6
    case 6: return IMM_STEP_6(arg, res, iw, w, 0);
#endif
#if IMM_M > 7
    case 7: return IMM_STEP_7(arg, res, iw, w, 0);
#endif
#if IMM_M > 8
    case 8: return IMM_STEP_8(arg, res, iw, w, 0);
#endif
#if IMM_M > 9
    case 9: return IMM_STEP_9(arg, res, iw, w, 0);
#endif
#if IMM_M > 10
    case 10: return IMM_STEP_10(arg, res, iw, w, 0);
#endif
#if IMM_M > 11
    case 11: return IMM_STEP_11(arg, res, iw, w, 0);
#endif
#if IMM_M > 12
    case 12: return IMM_STEP_12(arg, res, iw, w, 0);
#endif
#if IMM_M > 13
    case 13: return IMM_STEP_13(arg, res, iw, w, 0);
#endif
#if IMM_M > 14
    case 14: return IMM_STEP_14(arg, res, iw, w, 0);
#endif
#if IMM_M > 15
    case 15: return IMM_STEP_15(arg, res, iw, w, 0);
#endif
  }
  return 1;
}

CASADI_SYMBOL_EXPORT int IMM_RUN(const casadi_real* x0, casadi_int x0_step, const casadi_real* P0,
    casadi_int P0_step, const casadi_real* y, const casadi_real* mask, const casadi_real* const* Qs,
    const casadi_real* const* Rs, const casadi_real* const* ps, const casadi_int* p_sizes, const casadi_real* T,
    const casadi_real* mu0, casadi_real* const* outs, casadi_int runs, casadi_int K, casadi_int* iw,
    casadi_real* w, casadi_int* failed, const volatile int* stop) {
  const casadi_real* arg[IMM_SZ_ARG];
  casadi_real* res[IMM_SZ_RES];
  const casadi_real* xprev[IMM_M];
  const casadi_real* Pprev[IMM_M];
  casadi_real mu[IMM_M], cbar[IMM_M], wm[IMM_M * IMM_M], xmix[IMM_M * IMM_N], Pmix[IMM_M * IMM_N * IMM_N], d[IMM_N], nis, top, tot, s, c;
  casadi_int r, k, i, j, a, b, t;
  static const casadi_int angles[] = {IMM_ANGLES};
  for (r = 0; r < runs; ++r) {
    failed[2 * r] = -1;
    failed[2 * r + 1] = -1;
    for (j = 0; j < IMM_M; ++j) mu[j] = mu0[j];
    for (k = 0; k < K; ++k) {
      if (stop && *stop) return IMM_STOPPED;
      t = r * K + k;
      for (i = 0; i < IMM_M; ++i) {
        xprev[i] = k ? outs[0] + ((t - 1) * IMM_M + i) * IMM_N : x0 + r * x0_step;
        Pprev[i] = k ? outs[1] + ((t - 1) * IMM_M + i) * IMM_N * IMM_N : P0 + r * P0_step;
      }
      /* 1: c̄_j = Σ_i p_ij μ_i, μ_(i|j) = p_ij μ_i / c̄_j (a mode nothing reaches keeps its own) */
      for (j = 0; j < IMM_M; ++j) {
        cbar[j] = 0;
        for (i = 0; i < IMM_M; ++i) cbar[j] += mu[i] * T[i * IMM_M + j];
        for (i = 0; i < IMM_M; ++i) wm[i * IMM_M + j] = cbar[j] > 0 ? mu[i] * T[i * IMM_M + j] / cbar[j] : (i == j);
      }
      /* 2: the mixed Gaussians, angle states by circular means and wrapped deviations */
      for (j = 0; j < IMM_M; ++j) {
        casadi_real* xj = xmix + j * IMM_N;
        casadi_real* Pj = Pmix + j * IMM_N * IMM_N;
        for (a = 0; a < IMM_N; ++a) {
          xj[a] = 0;
          for (i = 0; i < IMM_M; ++i) xj[a] += wm[i * IMM_M + j] * xprev[i][a];
        }
        for (b = 0; b < IMM_N_ANG; ++b) {
          a = angles[b];
          s = c = 0;
          for (i = 0; i < IMM_M; ++i) {
            s += wm[i * IMM_M + j] * sin(xprev[i][a]);
            c += wm[i * IMM_M + j] * cos(xprev[i][a]);
          }
          xj[a] = atan2(s, c);
        }
        for (a = 0; a < IMM_N * IMM_N; ++a) Pj[a] = 0;
        for (i = 0; i < IMM_M; ++i) {
          casadi_real wi = wm[i * IMM_M + j];
          for (a = 0; a < IMM_N; ++a) d[a] = xprev[i][a] - xj[a];
          for (b = 0; b < IMM_N_ANG; ++b) d[angles[b]] = IMM_WRAP(d[angles[b]]);
          for (b = 0; b < IMM_N; ++b)
            for (a = 0; a < IMM_N; ++a) Pj[a + b * IMM_N] += wi * (Pprev[i][a + b * IMM_N] + d[a] * d[b]);
        }
        for (b = 0; b < IMM_N; ++b)
          for (a = 0; a < b; ++a) Pj[a + b * IMM_N] = Pj[b + a * IMM_N] = 0.5 * (Pj[a + b * IMM_N] + Pj[b + a * IMM_N]);
      }
      /* 3: each mode's predict + update step from its mixed Gaussian */
      for (j = 0; j < IMM_M; ++j) {
        casadi_int o = t * IMM_M + j;
        arg[0] = xmix + j * IMM_N; arg[1] = Pmix + j * IMM_N * IMM_N; arg[2] = y + t * IMM_NY; arg[3] = Qs[j]; arg[4] = Rs[j];
        arg[5] = mask + t * IMM_NY; arg[6] = ps[j] + t * p_sizes[j];
        res[0] = outs[0] + o * IMM_N; res[1] = outs[1] + o * IMM_N * IMM_N; res[2] = outs[2] + o * IMM_N;
        res[3] = outs[3] + o * IMM_N * IMM_N; res[4] = outs[4] + o * IMM_NY; res[5] = outs[5] + o * IMM_NY * IMM_NY;
        res[6] = outs[6] + o; res[7] = &nis;
        if (IMM_STEP(j, arg, res, iw, w)) return 1;
        if (IMM_BAD(res[6], 1) || IMM_BAD(res[0], IMM_N) || IMM_BAD(res[1], IMM_N * IMM_N)) {
          failed[2 * r] = k;
          failed[2 * r + 1] = j;
          break;
        }
      }
      if (failed[2 * r] >= 0) break;
      /* 4: μ_j ∝ c̄_j Λ_j, the Λ_j scaled by the largest */
      top = outs[6][t * IMM_M];
      for (j = 1; j < IMM_M; ++j) if (outs[6][t * IMM_M + j] > top) top = outs[6][t * IMM_M + j];
      tot = 0;
      for (j = 0; j < IMM_M; ++j) {
        mu[j] = cbar[j] * exp(outs[6][t * IMM_M + j] - top);
        tot += mu[j];
      }
      for (j = 0; j < IMM_M; ++j) {
        mu[j] /= tot;
        outs[7][t * IMM_M + j] = mu[j];
        outs[8][t * IMM_M + j] = cbar[j];
      }
    }
  }
  return 0;
}
