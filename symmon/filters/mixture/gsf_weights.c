#include <math.h>
/* symmon: for each run r, prev = logw0; per step k: a_m = prev_m + ll[r, m, k],
   lse = max a + log sum exp(a - max a) (the step's log-likelihood), prev = a - lse.
   A NaN in a propagates to the max, as numpy's max does. */
int sm_gsf_weights(long long R, long long M, long long K, const double* logw0, const double* ll,
                   double* logw, double* step_ll) {
  long long r, k, m;
  for (r = 0; r < R; ++r) {
    const double* l = ll + r * M * K;
    double* out = logw + r * K * M;
    const double* prev = logw0;
    for (k = 0; k < K; ++k) {
      double* a = out + k * M;
      double top, sum = 0.0, lse;
      for (m = 0; m < M; ++m) a[m] = prev[m] + l[m * K + k];
      top = a[0];
      for (m = 1; m < M; ++m) if (a[m] > top || isnan(a[m])) top = a[m];
      for (m = 0; m < M; ++m) sum += exp(a[m] - top);
      lse = top + log(sum);
      step_ll[r * K + k] = lse;
      for (m = 0; m < M; ++m) a[m] -= lse;
      prev = a;
    }
  }
  return 0;
}
