/* symmon: what the two drivers of the fit's log-likelihood share (fit_reverse.c and
   fit_forward.c, symmon.filters.gaussian.fit): the name pasting FIT_(x) (the library's name
   FIT_NAME followed by _x) and their one signature, FIT_SIGNATURE.  A call computes the
   columns of the ranks j0 <= j < j1 of the fitted parameters (a part of them on each thread);
   arg and res hold FIT_SZ_ARG and FIT_SZ_RES pointers, for the calls of CasADi's functions.
   FIT_PROTOTYPE is the driver's prototype; FIT_FUNCTION(s) that of the generated function
   FIT_(s), declared by a driver compiled alone (FIT_ALONE, with example FIT_ macros). */
#define FIT_CAT2(a, b) a##_##b
#define FIT_CAT(a, b) FIT_CAT2(a, b)
#define FIT_(s) FIT_CAT(FIT_NAME, s)  /* FIT_(f): the library's name, _f */
#define FIT_FUNCTION(s) \
int FIT_(s)(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem)
#define FIT_PROTOTYPE \
CASADI_SYMBOL_EXPORT int FIT_(fit)(const casadi_real* D, const casadi_real* S0, const casadi_real* Q, \
    const casadi_real* R, casadi_int runs, casadi_int K, casadi_int m, const casadi_int* rows, \
    casadi_int order, casadi_int j0, casadi_int j1, casadi_real* Z, casadi_real* T, casadi_real* out, \
    casadi_int* iw, casadi_real* w)
#define FIT_SIGNATURE \
FIT_PROTOTYPE { \
  const casadi_real* arg[FIT_SZ_ARG]; \
  casadi_real* res[FIT_SZ_RES];
