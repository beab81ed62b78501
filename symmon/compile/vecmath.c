/* symmon.compile.vecmath: atan2, hypot and exp within 1 ulp, branch-free for vectorised loops
   (the module notes describe them).  The module puts its numbers before this file, the SM_
   macros: the table of atan(k/8) and pi/2, pi as double-doubles, the Taylor coefficients,
   the split of ln 2 and the ranges of the ordinary arguments. */
#ifndef SM_SMALL  /* checked alone: the macros the module writes, their values */
#define SM_SMALL 0x1.0000000000000p-500
#define SM_BIG 0x1.0000000000000p+500
#define SM_ATAN_HI0 0x0.0p+0
#define SM_ATAN_HI1 0x1.fd5ba9aac2f6ep-4
#define SM_ATAN_HI2 0x1.f5b75f92c80ddp-3
#define SM_ATAN_HI3 0x1.6f61941e4def1p-2
#define SM_ATAN_HI4 0x1.dac670561bb4fp-2
#define SM_ATAN_HI5 0x1.1e00babdefeb4p-1
#define SM_ATAN_HI6 0x1.4978fa3269ee1p-1
#define SM_ATAN_HI7 0x1.700a7c5784634p-1
#define SM_ATAN_HI8 0x1.921fb54442d18p-1
#define SM_ATAN_LO0 0x0.0p+0
#define SM_ATAN_LO1 -0x1.cd37686760c17p-59
#define SM_ATAN_LO2 0x1.8ab6e3cf7afbdp-57
#define SM_ATAN_LO3 -0x1.c63aae6f6e918p-56
#define SM_ATAN_LO4 0x1.a2b7f222f65e2p-56
#define SM_ATAN_LO5 -0x1.928df287a668fp-58
#define SM_ATAN_LO6 0x1.2419a87f2a458p-56
#define SM_ATAN_LO7 -0x1.8c34d25aadef6p-56
#define SM_ATAN_LO8 0x1.1a62633145c07p-55
#define SM_ATAN_C3 -0x1.5555555555555p-2
#define SM_ATAN_C5 0x1.999999999999ap-3
#define SM_ATAN_C7 -0x1.2492492492492p-3
#define SM_ATAN_C9 0x1.c71c71c71c71cp-4
#define SM_ATAN_C11 -0x1.745d1745d1746p-4
#define SM_ATAN_C13 0x1.3b13b13b13b14p-4
#define SM_ATAN_C15 -0x1.1111111111111p-4
#define SM_PI2_HI 0x1.921fb54442d18p+0
#define SM_PI2_LO 0x1.1a62633145c07p-54
#define SM_PI_HI 0x1.921fb54442d18p+1
#define SM_PI_LO 0x1.1a62633145c07p-53
#define SM_EXP_MIN -0x1.6200000000000p+9
#define SM_EXP_MAX 0x1.6280000000000p+9
#define SM_LOG2E 0x1.71547652b82fep+0
#define SM_LN2_HI 0x1.62e42fee00000p-1
#define SM_LN2_LO 0x1.a39ef35793c76p-33
#define SM_EXP_C2 0x1.0000000000000p-1
#define SM_EXP_C3 0x1.5555555555555p-3
#define SM_EXP_C4 0x1.5555555555555p-5
#define SM_EXP_C5 0x1.1111111111111p-7
#define SM_EXP_C6 0x1.6c16c16c16c17p-10
#define SM_EXP_C7 0x1.a01a01a01a01ap-13
#define SM_EXP_C8 0x1.a01a01a01a01ap-16
#define SM_EXP_C9 0x1.71de3a556c734p-19
#define SM_EXP_C10 0x1.27e4fb7789f5cp-22
#define SM_EXP_C11 0x1.ae64567f544e4p-26
#define SM_EXP_C12 0x1.1eed8eff8d898p-29
#define SM_EXP_C13 0x1.6124613a86d09p-33
#endif
#include <math.h>
#include <string.h>
static inline int sm_ordinary(double a) { a = fabs(a); return (a >= SM_SMALL) & (a <= SM_BIG); }
static inline double sm_atan2(double y, double x) {
  double ax = fabs(x), ay = fabs(y);
  int swap = ay > ax;
  double n = swap ? ax : ay, d = swap ? ay : ax;
  /* Two divisions, by reciprocals: the residuals (fma, exact) carry each quotient's error. */
  double rd = 1.0 / d, t = n * rd, tl = fma(-t, d, n) * rd;
  /* t is NaN or outside [0, 1] only where the arguments are not ordinary: index 0 there. */
  double kd = floor((((t >= 0.0) & (t <= 1.0)) ? t : 0.0) * 8.0 + 0.5);
  double c = kd * 0.125;
  /* t - c is exact (Sterbenz: c/2 <= t <= 2c when k >= 1). */
  double nh = t - c, numh = nh + tl, bv = numh - nh;
  double numl = (nh - (numh - bv)) + (tl - bv);
  double pr = t * c, pe = fma(t, c, -pr);
  double dh = 1.0 + pr, dl = ((1.0 - dh) + pr) + (pe + tl * c);
  double rdh = 1.0 / dh, uh = numh * rdh, ul = ((fma(-uh, dh, numh) + numl) - uh * dl) * rdh;
  double u2 = uh * uh;
  double tail = ul + uh * (u2 * (SM_ATAN_C3 + u2 * (SM_ATAN_C5 + u2 * (SM_ATAN_C7 + u2 * (SM_ATAN_C9 + u2 * (SM_ATAN_C11 + u2 * (SM_ATAN_C13 + u2 * SM_ATAN_C15)))))));
  /* atan(k/8) by selects, not a table: gcc does not vectorise the table's load. */
  double ch = SM_ATAN_HI8;
  ch = kd < 7.5 ? SM_ATAN_HI7 : ch;
  ch = kd < 6.5 ? SM_ATAN_HI6 : ch;
  ch = kd < 5.5 ? SM_ATAN_HI5 : ch;
  ch = kd < 4.5 ? SM_ATAN_HI4 : ch;
  ch = kd < 3.5 ? SM_ATAN_HI3 : ch;
  ch = kd < 2.5 ? SM_ATAN_HI2 : ch;
  ch = kd < 1.5 ? SM_ATAN_HI1 : ch;
  ch = kd < 0.5 ? SM_ATAN_HI0 : ch;
  double cl = SM_ATAN_LO8;
  cl = kd < 7.5 ? SM_ATAN_LO7 : cl;
  cl = kd < 6.5 ? SM_ATAN_LO6 : cl;
  cl = kd < 5.5 ? SM_ATAN_LO5 : cl;
  cl = kd < 4.5 ? SM_ATAN_LO4 : cl;
  cl = kd < 3.5 ? SM_ATAN_LO3 : cl;
  cl = kd < 2.5 ? SM_ATAN_LO2 : cl;
  cl = kd < 1.5 ? SM_ATAN_LO1 : cl;
  cl = kd < 0.5 ? SM_ATAN_LO0 : cl;
  double rh = ch + uh, b2 = rh - ch;
  double rl = ((ch - (rh - b2)) + (uh - b2)) + (cl + tail);
  /* pi/2 - r when |y| > |x|, then pi - r when x < 0; the head differences are exact. */
  double sh = SM_PI2_HI - rh, sl = ((SM_PI2_HI - sh) - rh) + (SM_PI2_LO - rl);
  rh = swap ? sh : rh; rl = swap ? sl : rl;
  sh = SM_PI_HI - rh; sl = ((SM_PI_HI - sh) - rh) + (SM_PI_LO - rl);
  int neg = x < 0;
  rh = neg ? sh : rh; rl = neg ? sl : rl;
  return copysign(rh + rl, y);
}
/* exp(x) for x in [SM_EXP_MIN, SM_EXP_MAX] (a normal result; sm_exp_ordinary): x = k ln 2 + r,
   |r| <= ln2/2 + tiny, r as a double-double (Cody and Waite: k ln2_hi exact), then
   exp r = 1 + r + r^2 (1/2! + ... + r^11/13!) (the next term is below 2^-60 of the result),
   1 + r_h summed exactly, and the scale 2^k made from the bits of the rounding constant. */
static inline int sm_exp_ordinary(double x) { return (x >= SM_EXP_MIN) & (x <= SM_EXP_MAX); }
static inline double sm_exp(double x) {
  double kd = x * SM_LOG2E + 0x1.8p52;  /* k = round(x / ln 2) in kd's low bits */
  double k = kd - 0x1.8p52;
  double r0 = x - k * SM_LN2_HI, kl = k * SM_LN2_LO;  /* r0 exact */
  double rh = r0 - kl, rl = (r0 - rh) - kl;
  double q = rh * rh * (SM_EXP_C2 + rh * (SM_EXP_C3 + rh * (SM_EXP_C4 + rh * (SM_EXP_C5 + rh * (SM_EXP_C6 + rh * (SM_EXP_C7 + rh * (SM_EXP_C8 + rh * (SM_EXP_C9 + rh * (SM_EXP_C10 + rh * (SM_EXP_C11 + rh * (SM_EXP_C12 + rh * SM_EXP_C13))))))))))) + rl * (1.0 + rh);
  double sh = 1.0 + rh, se = (1.0 - sh) + rh;  /* exact: |rh| < 1 */
  unsigned long long bits;
  double scale;
  memcpy(&bits, &kd, sizeof bits);
  bits = (bits + 1023ULL) << 52;  /* kd's low 12 bits hold k + 2^51: the exponent k + 1023 */
  memcpy(&scale, &bits, sizeof scale);
  return (sh + (se + q)) * scale;
}
static inline double sm_hypot(double x, double y) {
  double ax = fabs(x), ay = fabs(y);
  double x2 = ax * ax, x2e = fma(ax, ax, -x2), y2 = ay * ay, y2e = fma(ay, ay, -y2);
  double s = x2 + y2, bv = s - x2, se = (x2 - (s - bv)) + (y2 - bv);
  double h = sqrt(s), hh = h * h, he = fma(h, h, -hh);
  /* s - hh is exact (Sterbenz); the residual x^2 + y^2 - h^2 to about 2^-104 relative. */
  double r = (s - hh) + ((se + x2e + y2e) - he);
  return h + r / (2.0 * h);
}
