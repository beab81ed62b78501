/* symmon (symmon.propagation.kernel): PBK_F on each of K Gaussians: m (K, n) and P (K, n, n) in, the moments out, and
   per Gaussian three checks (check[3k], check[3k + 1], check[3k + 2]): its smallest pivot,
   its asymmetry max |P - P'| / max(max |P|, DBL_MIN) (the test of symmon.Gaussian, here in
   plain C: in the graph, each max was a call of libm's fmax, 8 % of the batch) and 1 when
   every input and output of that Gaussian is finite, else 0 (x - x == 0 exactly when x is
   finite; in C, not by a NumPy pass whose dot product would wake BLAS's threads). */
#include <float.h>
#ifndef PBK_F  /* checked alone: example macros (BatchKernel defines them), and CasADi's C before */
#include "../compile/casadi_alone.h"
#include <math.h>
#define PBK_F pbk_model
#define PBK_FINITE pbk_model_finite
#define PBK_BATCH pbk_model_batch
#define PBK_SZ_ARG 2
#define PBK_SZ_RES 4
#define PBK_N 2
#define PBK_NN 4
#define PBK_N_Y 3
#define PBK_NYY 9
#define PBK_NNY 6
int PBK_F(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
#endif
static int PBK_FINITE(const casadi_real* a, casadi_int n) {
  int ok = 1;
  casadi_int i;
  for (i = 0; i < n; ++i) ok &= (a[i] - a[i] == 0);
  return ok;
}
CASADI_SYMBOL_EXPORT int PBK_BATCH(const casadi_real* m, const casadi_real* P, casadi_real* mean,
    casadi_real* cov, casadi_real* cross, casadi_real* check, casadi_int K, casadi_int* iw, casadi_real* w) {
  const casadi_real* arg[PBK_SZ_ARG];
  casadi_real* res[PBK_SZ_RES];
  const casadi_real* Pk;
  casadi_real big, asym, a;
  casadi_int k, i, j;
  int ok;
  for (k = 0; k < K; ++k) {
    arg[0] = m + k * PBK_N; arg[1] = Pk = P + k * PBK_NN;
    res[0] = mean + k * PBK_N_Y; res[1] = cov + k * PBK_NYY; res[2] = cross + k * PBK_NNY; res[3] = check + 3 * k;
    if (PBK_F(arg, res, iw, w, 0)) return 1;
    big = DBL_MIN;
    asym = 0;
    for (i = 0; i < PBK_NN; ++i) {
      a = fabs(Pk[i]);
      if (a > big) big = a;
    }
    for (j = 0; j < PBK_N; ++j)
      for (i = j + 1; i < PBK_N; ++i) {
        a = fabs(Pk[i + j * PBK_N] - Pk[j + i * PBK_N]);
        if (a > asym) asym = a;
      }
    check[3 * k + 1] = asym / big;
    ok = PBK_FINITE(arg[0], PBK_N) & PBK_FINITE(Pk, PBK_NN) & PBK_FINITE(res[0], PBK_N_Y)
        & PBK_FINITE(res[1], PBK_NYY) & PBK_FINITE(res[2], PBK_NNY);
    check[3 * k + 2] = ok;
  }
  return 0;
}
