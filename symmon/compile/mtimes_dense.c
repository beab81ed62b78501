/* symmon: CasADi's dense product z += x y (tr: z += x' y), the inner loop contiguous and
   four terms per pass over a column of z, each entry's terms in CasADi's order
   (symmon.compile.ckernels.faster_kernels puts the text after the block below in place of
   casadi_mtimes_dense.c in generated C). */
#ifndef casadi_real  /* checked alone: what CasADi's C defines before it */
#include "casadi_alone.h"
#endif
void casadi_mtimes_dense(const casadi_real* x, casadi_int nrow_x, casadi_int ncol_x,
    const casadi_real* y, casadi_int ncol_y, casadi_real* z, casadi_int tr) {
  /* symmon: CasADi's dense product, the inner loop contiguous and four terms per pass over
     a column of z; each entry adds its terms in CasADi's order (symmon.compile.ckernels). */
  casadi_int i, j, k;
  if (tr) {
    for (i=0; i<ncol_y; ++i) {
      const casadi_real* yi = y + i*nrow_x;
      for (j=0; j<ncol_x; ++j) {
        const casadi_real* xj = x + j*nrow_x;
        casadi_real s = z[j + i*ncol_x];
        for (k=0; k<nrow_x; ++k) s += xj[k] * yi[k];
        z[j + i*ncol_x] = s;
      }
    }
  } else {
    for (i=0; i<ncol_y; ++i) {
      casadi_real* zi = z + i*nrow_x;
      const casadi_real* yi = y + i*ncol_x;
      for (k=0; k+4<=ncol_x; k+=4) {
        const casadi_real *x0 = x + k*nrow_x, *x1 = x0 + nrow_x, *x2 = x1 + nrow_x, *x3 = x2 + nrow_x;
        casadi_real y0 = yi[k], y1 = yi[k+1], y2 = yi[k+2], y3 = yi[k+3];
        for (j=0; j<nrow_x; ++j) zi[j] = (((zi[j] + x0[j]*y0) + x1[j]*y1) + x2[j]*y2) + x3[j]*y3;
      }
      for (; k<ncol_x; ++k) {
        const casadi_real* xk = x + k*nrow_x;
        casadi_real yk = yi[k];
        for (j=0; j<nrow_x; ++j) zi[j] += xk[j] * yk;
      }
    }
  }
}
