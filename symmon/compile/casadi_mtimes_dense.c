/* CasADi 3.6-3.8's casadi_mtimes_dense, as its generated C holds it word for word (the
   text after the block below): symmon.compile.ckernels.faster_kernels looks for it and puts
   mtimes_dense.c in its place.  CasADi's C, not symmon's: kept here only to be matched. */
#ifndef casadi_real  /* checked alone: what CasADi's C defines before it */
#include "casadi_alone.h"
#endif
void casadi_mtimes_dense(const casadi_real* x, casadi_int nrow_x, casadi_int ncol_x,
    const casadi_real* y, casadi_int ncol_y, casadi_real* z, casadi_int tr) {
  casadi_int i, j, k;
  if (tr) {
    for (i=0; i<ncol_y; ++i) {
      for (j=0; j<ncol_x; ++j) {
        for (k=0; k<nrow_x; ++k) {
          z[j + i*ncol_x] += x[k + j*nrow_x] * y[k + i*nrow_x];
        }
      }
    }
  } else {
    for (i=0; i<ncol_y; ++i) {
      for (j=0; j<nrow_x; ++j) {
        for (k=0; k<ncol_x; ++k) {
          z[j + i*nrow_x] += x[j + k*nrow_x] * y[k + i*ncol_x];
        }
      }
    }
  }
}
