/* symmon: CasADi's sparse product (casadi_mtimes.c) with direct, vectorisable loops in its
   untransposed branch where a column of z or of x has consecutive rows
   (symmon.compile.ckernels.faster_sparse_products puts the text after the block below in
   place of casadi_mtimes.c in generated C). */
#ifndef casadi_real  /* checked alone: what CasADi's C defines before it */
#include "casadi_alone.h"
#endif
void casadi_mtimes(const casadi_real* x, const casadi_int* sp_x, const casadi_real* y, const casadi_int* sp_y, casadi_real* z, const casadi_int* sp_z, casadi_real* w, casadi_int tr) {
  casadi_int ncol_x, ncol_y, ncol_z, cc;
  const casadi_int *colind_x, *row_x, *colind_y, *row_y, *colind_z, *row_z;
  ncol_x = sp_x[1];
  colind_x = sp_x+2; row_x = sp_x + 2 + ncol_x+1;
  ncol_y = sp_y[1];
  colind_y = sp_y+2; row_y = sp_y + 2 + ncol_y+1;
  ncol_z = sp_z[1];
  colind_z = sp_z+2; row_z = sp_z + 2 + ncol_z+1;
  if (tr) {
    for (cc=0; cc<ncol_z; ++cc) {
      casadi_int kk;
      for (kk=colind_y[cc]; kk<colind_y[cc+1]; ++kk) {
        w[row_y[kk]] = y[kk];
      }
      for (kk=colind_z[cc]; kk<colind_z[cc+1]; ++kk) {
        casadi_int kk1;
        casadi_int rr = row_z[kk];
        for (kk1=colind_x[rr]; kk1<colind_x[rr+1]; ++kk1) {
          z[kk] += x[kk1] * w[row_x[kk1]];
        }
      }
    }
  } else {
    for (cc=0; cc<ncol_y; ++cc) {
      casadi_int kk, z0 = colind_z[cc], nz = colind_z[cc+1] - z0;
      /* symmon: a column of z (or of x) whose rows are consecutive is copied (or added)
         with a direct, vectorisable loop; the same terms in the same order otherwise. */
      int zc = nz > 0 && row_z[z0 + nz - 1] - row_z[z0] == nz - 1;
      if (zc) {
        casadi_real* wz = w + row_z[z0];
        for (kk=0; kk<nz; ++kk) wz[kk] = z[z0 + kk];
      } else {
        for (kk=z0; kk<z0 + nz; ++kk) w[row_z[kk]] = z[kk];
      }
      for (kk=colind_y[cc]; kk<colind_y[cc+1]; ++kk) {
        casadi_int kk1;
        casadi_int rr = row_y[kk], x0 = colind_x[rr], nx = colind_x[rr+1] - x0;
        casadi_real yk = y[kk];
        if (nx > 0 && row_x[x0 + nx - 1] - row_x[x0] == nx - 1) {
          casadi_real* wx = w + row_x[x0];
          const casadi_real* xx = x + x0;
          for (kk1=0; kk1<nx; ++kk1) wx[kk1] += xx[kk1]*yk;
        } else {
          for (kk1=x0; kk1<x0 + nx; ++kk1) w[row_x[kk1]] += x[kk1]*yk;
        }
      }
      if (zc) {
        const casadi_real* wz = w + row_z[z0];
        for (kk=0; kk<nz; ++kk) z[z0 + kk] = wz[kk];
      } else {
        for (kk=z0; kk<z0 + nz; ++kk) z[kk] = w[row_z[kk]];
      }
    }
  }
}
