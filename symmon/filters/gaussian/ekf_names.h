/* symmon: the names of the EKF family's C kernels (ekf_step.c, ekf_backward.c, sqrt_ekf_step.c,
   sqrt_ukf_step.c and the files they include): EKF_(x) is the kernel's name EKF_NAME followed
   by _x, and EKF_PIECE(x) the prototype of CasADi's generated function EKF_(x), which a file
   checked alone declares. */
#ifndef EKF_NAMES_H
#define EKF_NAMES_H
#define EKF_CAT2(a, b) a##_##b
#define EKF_CAT(a, b) EKF_CAT2(a, b)
#define EKF_(s) EKF_CAT(EKF_NAME, s)  /* EKF_(chol): the kernel's name, _chol */
#define EKF_PIECE(s) int EKF_(s)(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem)
#endif
