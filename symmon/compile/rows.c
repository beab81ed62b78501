/* symmon: the row loop around CasADi's generated function ROWS_F: row i of x in, row i of
   each output out (outputs are dense, so output k of row i is at out[k] + i * nnz_k).
   symmon.compile.compiled.rows_c defines the macros below and puts CasADi's C first. */
#ifndef ROWS_F  /* checked alone: example sizes, and what CasADi's C declares */
#include "casadi_alone.h"
#define ROWS_F model_f
#define ROWS_RUN model_f_rows
#define ROWS_SZ_ARG 1
#define ROWS_SZ_RES 2
#define ROWS_N_IN 3
#define ROWS_N_OUT 2
#define ROWS_NNZ_OUT 3, 9
int ROWS_F(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
#endif

CASADI_SYMBOL_EXPORT int ROWS_RUN(const casadi_real* x, casadi_real** out, casadi_int n,
    casadi_int* iw, casadi_real* w) {
  static const casadi_int nnz[ROWS_N_OUT] = {ROWS_NNZ_OUT};
  const casadi_real* arg[ROWS_SZ_ARG];
  casadi_real* res[ROWS_SZ_RES];
  casadi_int i, k;
  for (i = 0; i < n; ++i) {
    arg[0] = x + i * ROWS_N_IN;
    for (k = 0; k < ROWS_N_OUT; ++k) res[k] = out[k] + i * nnz[k];
    if (ROWS_F(arg, res, iw, w, 0)) return 1;
  }
  return 0;
}
