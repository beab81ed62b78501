/* symmon: the dense kernels that the C EKF step (ekf_step.c) and the C RTS backward step
   (ekf_backward.c) share, column-major as CasADi; they include this file (csource.c_source puts
   its text in place of the #include).  EKF_(x) is the kernel's name followed by _x. */
#ifndef EKF_NAME  /* checked alone: the name, and a use of the functions at the end */
#include "../../compile/casadi_alone.h"
#include <math.h>
#define EKF_NAME model
#define EKF_CAT2(a, b) a##_##b
#define EKF_CAT(a, b) EKF_CAT2(a, b)
#define EKF_(s) EKF_CAT(EKF_NAME, s)  /* EKF_(chol): the kernel's name, _chol */
#define EKF_DENSE_ALONE 1
#endif
/* a[k] += sum_i c_i[k] (sg l_i) for k < len, the columns c_i = C + i ld_c (i < m) and the
   coefficients l_i = l[i * ld]: four columns a pass (one load and store of a per four
   products), each added in turn, so that it rounds as the plain loop over i.  sg = -1
   subtracts (negation is exact). */
static void EKF_(add_cols)(casadi_real* restrict a, const casadi_real* restrict C, casadi_int ld_c,
    const casadi_real* l, casadi_int ld, casadi_int m, casadi_int len, casadi_real sg) {
  casadi_int i = 0, k;
  for (; i + 4 <= m; i += 4) {
    const casadi_real *c0 = C + i * ld_c, *c1 = c0 + ld_c, *c2 = c1 + ld_c, *c3 = c2 + ld_c;
    casadi_real l0 = sg * l[i * ld], l1 = sg * l[(i + 1) * ld], l2 = sg * l[(i + 2) * ld], l3 = sg * l[(i + 3) * ld];
    for (k = 0; k < len; ++k) {
      casadi_real t = a[k];
      t += c0[k] * l0;
      t += c1[k] * l1;
      t += c2[k] * l2;
      t += c3[k] * l3;
      a[k] = t;
    }
  }
  for (; i < m; ++i) {
    const casadi_real* c0 = C + i * ld_c;
    casadi_real l0 = sg * l[i * ld];
    for (k = 0; k < len; ++k) a[k] += c0[k] * l0;
  }
}

/* L L^T = A in place (L holds A's lower triangle, m x m), right-looking: column j scaled,
   then subtracted from the columns after it (contiguous updates; each entry sees the same
   subtractions in the same order as the left-looking sums); r[j] = 1 / L[j, j].  A zero,
   negative or NaN pivot gives a zero column and r[j] = 0 (a negative one NaN on the
   diagonal), and the return value 0; else 1. */
static int EKF_(chol)(casadi_real* L, casadi_int m, casadi_real* r) {
  casadi_int i, j, k;
  int ok = 1;
  for (j = 0; j < m; ++j) {
    casadi_real d = sqrt(L[j + j * m]);
    casadi_real* lj = L + j * m;
    if (!(d > 0)) ok = 0;
    for (i = j + 1; i < m; ++i) lj[i] = d > 0 ? lj[i] / d : 0;
    lj[j] = d;
    r[j] = d > 0 ? 1 / d : 0;
    for (k = j + 1; k < m; ++k) {
      casadi_real l = lj[k];
      casadi_real* lk = L + k * m;
      for (i = k; i < m; ++i) lk[i] -= lj[i] * l;
    }
  }
  return ok;
}
#ifdef EKF_DENSE_ALONE
int EKF_(use)(casadi_real* a, casadi_real* r);
int EKF_(use)(casadi_real* a, casadi_real* r) {
  EKF_(add_cols)(a, a + 4, 2, r, 1, 2, 2, 1.0);
  return EKF_(chol)(a, 2, r);
}
#endif
