/* symmon: the continuous-discrete Gaussian filter of a bank in C (symmon.filters.gaussian.continuous,
   whose _CompiledCD puts before this file the generated C of the drift pieces and of the update,
   and the CDK_ macros: the kernel's name CDK_NAME, the sizes, the rule and the form).

   Between two measurements each run integrates the moment equations (eqs. (1)-(3) and (6) of
   the module notes) by the Dormand-Prince 5(4) pair with the step-size control of
   scipy.integrate.solve_ivp's RK45, step for step (its initial step, error norm, safety factor
   and bounds), so that the two integrators take the same steps up to rounding; then the
   measurement update (CDK_UPD).  Each run has its own adaptive steps.  A run whose interval
   stops (more than max_eval evaluations, moments or rates NaN or inf, a factor that is no
   longer one, a step below the spacing of the numbers) or whose update is not finite ends
   there: failed[r] is that step (else -1), and the caller goes on with that run in Python,
   which either continues it or names the failure.

   Layout: matrices are row-major n x n except the update's, which are CasADi's column-major
   (the same for a symmetric P; a factor is handed over transposed).  The ODE state is
   z = [m; P (n*n)] or [m; the lower triangle of S, row by row], then with `transition` the
   transition Phi (n*n) and, in the square-root form, the effective noise Qt (n*n). */
#ifndef CDK_NAME  /* checked alone: example macros, and the prototypes of the functions called */
#include "../../compile/casadi_alone.h"
#define CDK_NAME model
#define CDK_N 2
#define CDK_NY 1
#define CDK_NTH 1
#define CDK_NP 1
#define CDK_TV 0
#define CDK_POINTS 5
#define CDK_SQRT 0
#define CDK_DX 0
#define CDK_JNNZ 2
#define CDK_A model_a
#define CDK_AJ model_aj
#define CDK_D model_d
#define CDK_UPD model_upd
#define CDK_SZ_ARG 6
#define CDK_SZ_RES 7
#define CDK_STOPPED 2
int CDK_A(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int CDK_AJ(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int CDK_D(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int CDK_UPD(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
#endif
#define CDK_CAT2(a, b) a##_##b
#define CDK_CAT(a, b) CDK_CAT2(a, b)
#define CDK_(s) CDK_CAT(CDK_NAME, s)
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define CDK_NN (CDK_N * CDK_N)
#define CDK_NCOV (CDK_SQRT ? CDK_N * (CDK_N + 1) / 2 : CDK_NN)
#define CDK_NPT (CDK_POINTS ? CDK_POINTS : 1)
/* Why an interval stopped (0: it did not). */
#define CDK_OVER 1
#define CDK_BAD 2

typedef struct {
  const casadi_real *Z, *wm, *wc;  /* unit points (CDK_POINTS x n), mean and covariance weights */
  const casadi_int *jcol, *jrow;   /* the CSC pattern of the drift's Jacobian */
  casadi_int *iw;
  casadi_real *w, *th;             /* CasADi's work; the drift's parameters, the time last (CDK_TV) */
  casadi_real *P, *S, *Si, *A, *D, *Dp, *T1, *T2, *T3, *Ah, *a, *X, *AY, *jnz;
  casadi_int nz, evals, max_evals;
  int transition;
} CDK_(ctx);

static int CDK_(nonfinite)(const casadi_real* a, casadi_int n) {
  unsigned long long u, bad = 0;
  casadi_int j;
  for (j = 0; j < n; ++j) {
    memcpy(&u, a + j, sizeof u);
    bad |= (u & 0x7ff0000000000000ULL) == 0x7ff0000000000000ULL;
  }
  return bad != 0;
}

/* C = A B, n x n row-major. */
static void CDK_(mm)(const casadi_real* A, const casadi_real* B, casadi_real* C) {
  casadi_int i, j, k;
  for (i = 0; i < CDK_N; ++i) {
    casadi_real* c = C + i * CDK_N;
    for (j = 0; j < CDK_N; ++j) c[j] = 0;
    for (k = 0; k < CDK_N; ++k) {
      const casadi_real aik = A[i * CDK_N + k];
      const casadi_real* b = B + k * CDK_N;
      if (aik == 0) continue;
      for (j = 0; j < CDK_N; ++j) c[j] += aik * b[j];
    }
  }
}

/* C = A Bt^T (Bt row-major: C_ij = sum_k A_ik Bt_jk). */
static void CDK_(mmt)(const casadi_real* A, const casadi_real* Bt, casadi_real* C) {
  casadi_int i, j, k;
  for (i = 0; i < CDK_N; ++i)
    for (j = 0; j < CDK_N; ++j) {
      casadi_real s = 0;
      for (k = 0; k < CDK_N; ++k) s += A[i * CDK_N + k] * Bt[j * CDK_N + k];
      C[i * CDK_N + j] = s;
    }
}

/* The lower Cholesky factor L of the symmetric P (row-major); 1 where P is not positive definite. */
static int CDK_(chol)(const casadi_real* P, casadi_real* L) {
  casadi_int i, j, k;
  memset(L, 0, CDK_NN * sizeof(casadi_real));
  for (j = 0; j < CDK_N; ++j) {
    casadi_real d = P[j * CDK_N + j];
    for (k = 0; k < j; ++k) d -= L[j * CDK_N + k] * L[j * CDK_N + k];
    if (!(d > 0)) return 1;
    d = sqrt(d);
    L[j * CDK_N + j] = d;
    for (i = j + 1; i < CDK_N; ++i) {
      casadi_real s = P[i * CDK_N + j];
      for (k = 0; k < j; ++k) s -= L[i * CDK_N + k] * L[j * CDK_N + k];
      L[i * CDK_N + j] = s / d;
    }
  }
  return 0;
}

/* The inverse of the lower triangular L with a positive diagonal (lower, row-major). */
static void CDK_(trinv)(const casadi_real* L, casadi_real* Li) {
  casadi_int i, j, k;
  memset(Li, 0, CDK_NN * sizeof(casadi_real));
  for (j = 0; j < CDK_N; ++j) {
    Li[j * CDK_N + j] = 1 / L[j * CDK_N + j];
    for (i = j + 1; i < CDK_N; ++i) {
      casadi_real s = 0;
      for (k = j; k < i; ++k) s += L[i * CDK_N + k] * Li[k * CDK_N + j];
      Li[i * CDK_N + j] = -s / L[i * CDK_N + i];
    }
  }
}

/* dS = S Phi(N): N symmetric, Phi its lower triangle with half the diagonal; the lower
   triangle of the product, row by row, to out (eq. (2)). */
static void CDK_(factor_rate)(const casadi_real* S, casadi_real* N, casadi_real* out) {
  casadi_int i, j, k, q = 0;
  for (i = 0; i < CDK_N; ++i) {
    N[i * CDK_N + i] *= 0.5;
    for (j = i + 1; j < CDK_N; ++j) N[i * CDK_N + j] = 0;
  }
  for (i = 0; i < CDK_N; ++i)
    for (j = 0; j <= i; ++j) {
      casadi_real s = 0;
      for (k = j; k <= i; ++k) s += S[i * CDK_N + k] * N[k * CDK_N + j];
      out[q++] = s;
    }
}

/* The right-hand side of the moment equations at (t, z): dz; 0, or why it stopped. */
static int CDK_(rhs)(CDK_(ctx)* c, casadi_real t, const casadi_real* z, casadi_real* dz) {
  const casadi_real* arg[CDK_SZ_ARG];
  casadi_real* res[CDK_SZ_RES];
  const casadi_real* m = z;
  casadi_real *dm = dz, *P = c->P, *S = c->S, *Si = c->Si, *A = c->A, *D = c->D;
  casadi_real *T1 = c->T1, *T2 = c->T2, *T3 = c->T3, *Ah = c->A;
  casadi_int i, j, k, q;
  if (++c->evals > c->max_evals) return CDK_OVER;
  if (CDK_(nonfinite)(z, c->nz)) return CDK_BAD;
  if (CDK_TV) c->th[CDK_NTH - 1] = t;
  if (CDK_SQRT) {
    memset(S, 0, CDK_NN * sizeof(casadi_real));
    for (i = 0, q = CDK_N; i < CDK_N; ++i)
      for (j = 0; j <= i; ++j) S[i * CDK_N + j] = z[q++];
    for (i = 0; i < CDK_N; ++i)
      if (!(S[i * CDK_N + i] > 0)) return CDK_BAD;
  } else {
    for (i = 0; i < CDK_N; ++i)
      for (j = 0; j < CDK_N; ++j) P[i * CDK_N + j] = 0.5 * (z[CDK_N + i * CDK_N + j] + z[CDK_N + j * CDK_N + i]);
    if (CDK_POINTS && CDK_(chol)(P, S)) return CDK_BAD;
  }
  if (!CDK_POINTS) {  /* TT1: a, A = da/dx and D at m */
    arg[0] = m; arg[1] = c->th; res[0] = dm; res[1] = c->jnz;
    if (CDK_AJ(arg, res, c->iw, c->w, 0)) return CDK_BAD;
    memset(A, 0, CDK_NN * sizeof(casadi_real));
    for (j = 0; j < CDK_N; ++j)
      for (k = c->jcol[j]; k < c->jcol[j + 1]; ++k) A[c->jrow[k] * CDK_N + j] = c->jnz[k];
    res[0] = D;
    if (CDK_D(arg, res, c->iw, c->w, 0)) return CDK_BAD;
    if (!CDK_SQRT) {  /* dP = A P + (A P)^T + D */
      CDK_(mm)(A, P, T1);
      for (i = 0; i < CDK_N; ++i)
        for (j = 0; j < CDK_N; ++j)
          dz[CDK_N + i * CDK_N + j] = T1[i * CDK_N + j] + T1[j * CDK_N + i] + D[i * CDK_N + j];
    } else {  /* N = S^-1 A S + its transpose + S^-1 D S^-T */
      CDK_(trinv)(S, Si);
      CDK_(mm)(Si, A, T1);
      CDK_(mm)(T1, S, T2);
    }
  } else {  /* a point rule: chi_i = m + S z_i */
    casadi_real* X = c->X;
    casadi_real* AY = c->AY;
    casadi_int p;
    arg[1] = c->th;
    if (CDK_DX) memset(D, 0, CDK_NN * sizeof(casadi_real));
    for (p = 0; p < CDK_POINTS; ++p) {
      const casadi_real* zp = c->Z + p * CDK_N;
      /* X = m + S z_p by the nonzeros of z_p: a column of S for the UKF's and CKF's points
         (+-c e_j), so 2n points cost O(n^2), not O(n^3) (at 128 states a third of the time) */
      for (i = 0; i < CDK_N; ++i) X[i] = m[i];
      for (k = 0; k < CDK_N; ++k) {
        const casadi_real zk = zp[k];
        if (zk == 0) continue;
        for (i = k; i < CDK_N; ++i) X[i] += S[i * CDK_N + k] * zk;
      }
      arg[0] = X; res[0] = AY + p * CDK_N;
      if (CDK_A(arg, res, c->iw, c->w, 0)) return CDK_BAD;
      if (CDK_DX) {
        res[0] = c->Dp;
        if (CDK_D(arg, res, c->iw, c->w, 0)) return CDK_BAD;
        for (i = 0; i < CDK_NN; ++i) D[i] += c->wm[p] * c->Dp[i];
      }
    }
    if (!CDK_DX) {
      arg[0] = m; res[0] = D;
      if (CDK_D(arg, res, c->iw, c->w, 0)) return CDK_BAD;
    }
    for (i = 0; i < CDK_N; ++i) dm[i] = 0;
    for (p = 0; p < CDK_POINTS; ++p)
      for (i = 0; i < CDK_N; ++i) dm[i] += c->wm[p] * AY[p * CDK_N + i];
    for (p = 0; p < CDK_POINTS; ++p)
      for (i = 0; i < CDK_N; ++i) AY[p * CDK_N + i] = c->wc[p] * (AY[p * CDK_N + i] - dm[i]);
    /* T3 = Z^T Y: C = E[(x - m)(a - dm)^T] = S T3, and the linearised drift A^ = T3^T S^-1 */
    memset(T3, 0, CDK_NN * sizeof(casadi_real));
    for (p = 0; p < CDK_POINTS; ++p)
      for (i = 0; i < CDK_N; ++i) {
        const casadi_real zi = c->Z[p * CDK_N + i];
        if (zi == 0) continue;
        for (j = 0; j < CDK_N; ++j) T3[i * CDK_N + j] += zi * AY[p * CDK_N + j];
      }
    if (CDK_SQRT || c->transition) CDK_(trinv)(S, Si);
    if (!CDK_SQRT) {
      CDK_(mm)(S, T3, T1);
      for (i = 0; i < CDK_N; ++i)
        for (j = 0; j < CDK_N; ++j)
          dz[CDK_N + i * CDK_N + j] = T1[i * CDK_N + j] + T1[j * CDK_N + i] + D[i * CDK_N + j];
    } else {
      CDK_(mmt)(T3, Si, T2);  /* S^-1 C S^-T = Z^T Y S^-T */
    }
    if (c->transition) {  /* A^ = T3^T S^-1 */
      Ah = c->Ah;
      for (i = 0; i < CDK_N; ++i)
        for (j = 0; j < CDK_N; ++j) {
          casadi_real s = 0;
          for (k = j; k < CDK_N; ++k) s += T3[k * CDK_N + i] * Si[k * CDK_N + j];
          Ah[i * CDK_N + j] = s;
        }
    }
  }
  if (CDK_SQRT) {  /* T2 = S^-1 C S^-T; N = T2 + T2^T + sym(S^-1 D S^-T) */
    CDK_(mm)(Si, D, T1);
    CDK_(mmt)(T1, Si, T3);
    for (i = 0; i < CDK_N; ++i)
      for (j = 0; j < CDK_N; ++j)
        T1[i * CDK_N + j] = T2[i * CDK_N + j] + T2[j * CDK_N + i] + 0.5 * (T3[i * CDK_N + j] + T3[j * CDK_N + i]);
    CDK_(factor_rate)(S, T1, dz + CDK_N);
  }
  if (c->transition) {  /* dPhi = A^ Phi; dQt = A^ Qt + Qt A^T + D */
    const casadi_real* Phi = z + CDK_N + CDK_NCOV;
    CDK_(mm)(Ah, Phi, dz + CDK_N + CDK_NCOV);
    if (CDK_SQRT) {
      const casadi_real* Qt = Phi + CDK_NN;
      casadi_real* dQ = dz + CDK_N + CDK_NCOV + CDK_NN;
      CDK_(mm)(Ah, Qt, T1);
      for (i = 0; i < CDK_N; ++i)
        for (j = 0; j < CDK_N; ++j) dQ[i * CDK_N + j] = T1[i * CDK_N + j] + T1[j * CDK_N + i] + D[i * CDK_N + j];
    }
  }
  if (CDK_(nonfinite)(dz, c->nz)) return CDK_BAD;
  return 0;
}

/* The RMS norm of x / scale. */
static casadi_real CDK_(rms)(const casadi_real* x, const casadi_real* scale, casadi_int n) {
  casadi_real s = 0;
  casadi_int i;
  for (i = 0; i < n; ++i) s += (x[i] / scale[i]) * (x[i] / scale[i]);
  return sqrt(s) / sqrt((casadi_real)n);
}

/* Dormand-Prince 5(4) as solve_ivp's RK45 (scipy.integrate._ivp.rk). */
static const casadi_real CDK_(C)[6] = {0, 1.0 / 5, 3.0 / 10, 4.0 / 5, 8.0 / 9, 1};
static const casadi_real CDK_(Ab)[6][5] = {
  {0, 0, 0, 0, 0},
  {1.0 / 5, 0, 0, 0, 0},
  {3.0 / 40, 9.0 / 40, 0, 0, 0},
  {44.0 / 45, -56.0 / 15, 32.0 / 9, 0, 0},
  {19372.0 / 6561, -25360.0 / 2187, 64448.0 / 6561, -212.0 / 729, 0},
  {9017.0 / 3168, -355.0 / 33, 46732.0 / 5247, 49.0 / 176, -5103.0 / 18656}};
static const casadi_real CDK_(B)[6] = {35.0 / 384, 0, 500.0 / 1113, 125.0 / 192, -2187.0 / 6784, 11.0 / 84};
static const casadi_real CDK_(E)[7] = {-71.0 / 57600, 0, 71.0 / 16695, -71.0 / 1920, 17253.0 / 339200,
                                       -22.0 / 525, 1.0 / 40};

/* z over [t0, t0 + dt]: 0, or why it stopped.  K: 7 nz reals of stages, y: 3 nz of scratch. */
static int CDK_(interval)(CDK_(ctx)* c, casadi_real t0, casadi_real dt, casadi_real* z, const casadi_real* tol,
                          casadi_real* K, casadi_real* y) {
  const casadi_int nz = c->nz;
  const casadi_real rtol = tol[0], atol = tol[1], max_step = tol[2];
  const casadi_real tb = t0 + dt, length = fabs(tb - t0);
  casadi_real *ynew = y, *scale = y + nz, *tmp = y + 2 * nz;
  casadi_real t = t0, h_abs, h0, h1, d0, d1, d2;
  casadi_int i, s, j;
  int code;
  c->evals = 0;
  if ((code = CDK_(rhs)(c, t, z, K))) return code;
  /* the initial step (scipy.integrate._ivp.common.select_initial_step, order 4) */
  for (i = 0; i < nz; ++i) scale[i] = atol + fabs(z[i]) * rtol;
  d0 = CDK_(rms)(z, scale, nz);
  d1 = CDK_(rms)(K, scale, nz);
  h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
  if (h0 > length) h0 = length;
  for (i = 0; i < nz; ++i) tmp[i] = z[i] + h0 * K[i];
  if ((code = CDK_(rhs)(c, t + h0, tmp, K + nz))) return code;
  for (i = 0; i < nz; ++i) tmp[i] = K[nz + i] - K[i];
  d2 = CDK_(rms)(tmp, scale, nz) / h0;
  if (d1 <= 1e-15 && d2 <= 1e-15) h1 = h0 * 1e-3 > 1e-6 ? h0 * 1e-3 : 1e-6;
  else h1 = pow(0.01 / (d1 > d2 ? d1 : d2), 1.0 / 5);
  h_abs = 100 * h0;
  if (h1 < h_abs) h_abs = h1;
  if (length < h_abs) h_abs = length;
  if (max_step < h_abs) h_abs = max_step;
  while (t != tb) {
    const casadi_real min_step = 10 * fabs(nextafter(t, INFINITY) - t);
    int rejected = 0;
    casadi_real t_new, h;
    if (h_abs > max_step) h_abs = max_step;
    else if (h_abs < min_step) h_abs = min_step;
    for (;;) {
      casadi_real err, factor;
      if (h_abs < min_step) return CDK_BAD;
      t_new = t + h_abs;
      if (t_new - tb > 0) t_new = tb;
      h = t_new - t;
      h_abs = fabs(h);
      for (s = 1; s < 6; ++s) {
        for (i = 0; i < nz; ++i) {
          casadi_real d = 0;
          for (j = 0; j < s; ++j) d += K[j * nz + i] * CDK_(Ab)[s][j];
          tmp[i] = z[i] + d * h;
        }
        if ((code = CDK_(rhs)(c, t + CDK_(C)[s] * h, tmp, K + s * nz))) return code;
      }
      for (i = 0; i < nz; ++i) {
        casadi_real d = 0;
        for (j = 0; j < 6; ++j) d += K[j * nz + i] * CDK_(B)[j];
        ynew[i] = z[i] + h * d;
      }
      if ((code = CDK_(rhs)(c, t + h, ynew, K + 6 * nz))) return code;
      for (i = 0; i < nz; ++i) {
        casadi_real e = 0, a = fabs(z[i]), b = fabs(ynew[i]);
        for (j = 0; j < 7; ++j) e += K[j * nz + i] * CDK_(E)[j];
        tmp[i] = e * h;
        scale[i] = atol + (a > b ? a : b) * rtol;
      }
      err = CDK_(rms)(tmp, scale, nz);
      if (err < 1) {
        factor = err == 0 ? 10 : 0.9 * pow(err, -0.2);
        if (factor > 10) factor = 10;
        if (rejected && factor > 1) factor = 1;
        h_abs *= factor;
        break;
      }
      factor = 0.9 * pow(err, -0.2);
      h_abs *= factor > 0.2 ? factor : 0.2;
      rejected = 1;
    }
    t = t_new;
    memcpy(z, ynew, nz * sizeof(casadi_real));
    memcpy(K, K + 6 * nz, nz * sizeof(casadi_real));
    if (t - tb >= 0) break;
  }
  return 0;
}

/* The bank: runs x K steps.  x0 (runs x n, step x0_step), P0 (covariances, or lower factors
   S0 row-major, step P0_step); per run and step: y and mask (n_y), p (CDK_NP, the update's
   parameters), th (CDK_NTH, the drift's, the time's entry written here), dt and start (the
   interval and its start time).  outs: x, P, x_pred, P_pred, innovation, S, nis, loglik,
   P_chol, P_pred_chol, Phi, Qt (null: not written), each (runs, K, ...); a factor row-major.
   tol: rtol, atol, max_step.  Rf: the update's R (its factor, column-major, in the square-root
   form). */
CASADI_SYMBOL_EXPORT int CDK_(run)(const casadi_real* x0, casadi_int x0_step, const casadi_real* P0,
    casadi_int P0_step, const casadi_real* yv, const casadi_real* mask, const casadi_real* pv,
    const casadi_real* thv, const casadi_real* dts, const casadi_real* starts, const casadi_real* Rf,
    const casadi_real* Z, const casadi_real* wm, const casadi_real* wc, const casadi_int* jcol,
    const casadi_int* jrow, const casadi_real* tol, casadi_int max_eval, casadi_int transition,
    casadi_real* const* outs, casadi_int runs, casadi_int K, casadi_int* iw, casadi_real* w,
    casadi_int* failed, const volatile int* stop) {
  CDK_(ctx) c;
  const casadi_real* arg[CDK_SZ_ARG];
  casadi_real* res[CDK_SZ_RES];
  casadi_int nz = CDK_N + CDK_NCOV + (transition ? (CDK_SQRT ? 2 : 1) * CDK_NN : 0);
  casadi_int r, k, i, j, q;
  casadi_real *buf, *z, *stages, *ys, *U, *Unew, *upd_x, *ll;
  int code = 0;
  size_t total = 12 * CDK_NN + 3 * CDK_N + CDK_NPT * CDK_N + CDK_JNNZ + CDK_NTH + 11 * nz + 1;
  buf = (casadi_real*)malloc(total * sizeof(casadi_real));
  if (!buf) return 1;
  c.Z = Z; c.wm = wm; c.wc = wc; c.jcol = jcol; c.jrow = jrow; c.iw = iw; c.w = w;
  c.nz = nz; c.max_evals = max_eval; c.transition = (int)transition;
  q = 0;
  c.P = buf + q; q += CDK_NN; c.S = buf + q; q += CDK_NN; c.Si = buf + q; q += CDK_NN;
  c.A = buf + q; q += CDK_NN; c.D = buf + q; q += CDK_NN; c.Dp = buf + q; q += CDK_NN;
  c.T1 = buf + q; q += CDK_NN; c.T2 = buf + q; q += CDK_NN; c.T3 = buf + q; q += CDK_NN;
  c.Ah = buf + q; q += CDK_NN; c.a = buf + q; q += CDK_N; c.X = buf + q; q += CDK_N;
  c.AY = buf + q; q += CDK_NPT * CDK_N; c.jnz = buf + q; q += CDK_JNNZ; c.th = buf + q; q += CDK_NTH;
  z = buf + q; q += nz; stages = buf + q; q += 7 * nz; ys = buf + q; q += 3 * nz;
  U = buf + q; q += CDK_NN; Unew = buf + q; q += CDK_NN; upd_x = buf + q; q += CDK_N; ll = buf + q;
  for (r = 0; r < runs && !code; ++r) {
    failed[r] = -1;
    /* the state before the first interval */
    memcpy(z, x0 + r * x0_step, CDK_N * sizeof(casadi_real));
    if (CDK_SQRT) {
      for (i = 0, q = CDK_N; i < CDK_N; ++i)
        for (j = 0; j <= i; ++j) z[q++] = P0[r * P0_step + i * CDK_N + j];
    } else {
      memcpy(z + CDK_N, P0 + r * P0_step, CDK_NN * sizeof(casadi_real));
    }
    for (k = 0; k < K; ++k) {
      const casadi_int at = r * K + k;
      casadi_real* Pk;
      if (stop && *stop) { code = CDK_STOPPED; break; }
      if (transition) {  /* Phi = I, Qt = 0 at the interval's start */
        casadi_real* Phi = z + CDK_N + CDK_NCOV;
        memset(Phi, 0, (nz - CDK_N - CDK_NCOV) * sizeof(casadi_real));
        for (i = 0; i < CDK_N; ++i) Phi[i * CDK_N + i] = 1;
      }
      memcpy(c.th, thv + at * CDK_NTH, CDK_NTH * sizeof(casadi_real));
      if (CDK_(interval)(&c, starts[at], dts[at], z, tol, stages, ys)) { failed[r] = k; break; }
      /* the prediction: P symmetrised, or the factor (column-major for the update) */
      if (CDK_SQRT) {
        memset(U, 0, CDK_NN * sizeof(casadi_real));
        for (i = 0, q = CDK_N; i < CDK_N; ++i)
          for (j = 0; j <= i; ++j) U[j * CDK_N + i] = z[q++];  /* U: S column-major */
        for (i = 0; i < CDK_N; ++i)
          if (!(U[i * CDK_N + i] > 0)) break;
        if (i < CDK_N) { failed[r] = k; break; }
        Pk = U;
      } else {
        Pk = z + CDK_N;
        for (i = 0; i < CDK_N; ++i)
          for (j = 0; j < i; ++j)
            Pk[i * CDK_N + j] = Pk[j * CDK_N + i] = 0.5 * (Pk[i * CDK_N + j] + Pk[j * CDK_N + i]);
      }
      if (outs[3]) memcpy(outs[3] + at * CDK_NN, Pk, CDK_NN * sizeof(casadi_real));
      if (outs[9])  /* the predicted factor, row-major */
        for (i = 0; i < CDK_N; ++i)
          for (j = 0; j < CDK_N; ++j) outs[9][at * CDK_NN + i * CDK_N + j] = U[j * CDK_N + i];
      if (transition) {
        const casadi_real* Phi = z + CDK_N + CDK_NCOV;
        memcpy(outs[10] + at * CDK_NN, Phi, CDK_NN * sizeof(casadi_real));
        if (CDK_SQRT)
          for (i = 0; i < CDK_N; ++i)
            for (j = 0; j < CDK_N; ++j)
              outs[11][at * CDK_NN + i * CDK_N + j] = 0.5 * (Phi[CDK_NN + i * CDK_N + j] + Phi[CDK_NN + j * CDK_N + i]);
      }
      /* the update */
      arg[0] = z; arg[1] = Pk; arg[2] = yv + at * CDK_NY; arg[3] = Rf; arg[4] = mask + at * CDK_NY;
      arg[5] = pv + at * CDK_NP;
      res[0] = upd_x; res[1] = Unew; res[2] = outs[2] + at * CDK_N; res[3] = outs[4] + at * CDK_NY;
      res[4] = outs[5] + at * CDK_NY * CDK_NY; res[5] = ll; res[6] = outs[6] + at;
      if (CDK_UPD(arg, res, iw, w, 0)) { code = 1; break; }
      outs[7][at] = *ll;
      if (CDK_(nonfinite)(ll, 1) || CDK_(nonfinite)(upd_x, CDK_N) || CDK_(nonfinite)(Unew, CDK_NN)) {
        failed[r] = k;
        break;
      }
      memcpy(outs[0] + at * CDK_N, upd_x, CDK_N * sizeof(casadi_real));
      memcpy(z, upd_x, CDK_N * sizeof(casadi_real));
      if (CDK_SQRT) {
        for (i = 0, q = CDK_N; i < CDK_N; ++i)
          for (j = 0; j <= i; ++j) z[q++] = Unew[j * CDK_N + i];
        for (i = 0; i < CDK_N; ++i)
          for (j = 0; j < CDK_N; ++j) outs[8][at * CDK_NN + i * CDK_N + j] = Unew[j * CDK_N + i];
      } else {
        memcpy(z + CDK_N, Unew, CDK_NN * sizeof(casadi_real));
        memcpy(outs[1] + at * CDK_NN, Unew, CDK_NN * sizeof(casadi_real));
      }
    }
  }
  free(buf);
  return code;
}
