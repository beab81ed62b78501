"""Faster C for CasADi's runtime kernels in generated code, with the same results to the bit.

CasADi's C for an MX matrix product of dense operands calls ``casadi_mtimes_dense``, a
triple loop whose innermost index runs along a row of a column-major matrix: a strided
load, and a read-modify-write of the same entry of z on every term, so gcc can neither
vectorise it nor keep the sum in a register.  In the compiled filter step at 30 states the
products took 70 % of the time (perf, docs/compile.md "Filter steps").

:func:`faster_kernels` swaps that definition for one whose inner loop is contiguous and
adds four terms per pass over a column of z.  Every entry of z still receives its terms in
the same order, one rounding after each, as in CasADi's loop and its virtual machine
(no FMA: the builds use ``-ffp-contract=off``), so the numbers do not change.  The swap is
made only when CasADi's definition is the one this was written against (its text is
compared in full): any other CasADi keeps its own kernel.

:data:`STOP_POLL` is the check that symmon's own run loops (the filter bank's steps, the
smoother's backward pass) make between two steps: an interrupt of the thread waiting for
them sets the flag (:func:`symmon.compile.compiled.in_threads`), and each loop returns
:data:`STOPPED` at its next step instead of running to its end.
"""

from __future__ import annotations

import logging

__all__ = ["faster_kernels", "CASADI_MTIMES_DENSE", "MTIMES_DENSE", "STOP_POLL", "STOPPED"]

log = logging.getLogger(__name__)

#: CasADi 3.6–3.8's ``casadi_mtimes_dense``: z += x y (x nrow_x × ncol_x, y ncol_x × ncol_y),
#: or z += xᵀ y with ``tr`` (x nrow_x × ncol_x, y nrow_x × ncol_y), all column-major.
CASADI_MTIMES_DENSE = """\
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
"""

#: The same products, loops reordered: each z entry adds x[j, k] y[k, i] for k = 0, 1, …
#: in turn, as above.  z is never one of the operands (CasADi computes a product in place
#: only into its accumulator), which is what lets the sum of a tr column stay in a register.
MTIMES_DENSE = """\
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
"""


def faster_kernels(code: str) -> str:
    """``code`` (CasADi's generated C) with :data:`MTIMES_DENSE` in place of CasADi's
    dense product, when that is :data:`CASADI_MTIMES_DENSE` word for word; otherwise
    ``code`` unchanged."""
    if CASADI_MTIMES_DENSE in code:
        return code.replace(CASADI_MTIMES_DENSE, MTIMES_DENSE, 1)
    if "void casadi_mtimes_dense(" in code:
        log.debug("symmon: this CasADi's casadi_mtimes_dense is not the known one; kept as it is")
    return code


#: The return code of a run loop that saw its stop flag.
STOPPED = 2
#: C, between two steps of a run loop whose arguments include ``const volatile int* stop``
#: (NULL: never stopped): one load of a flag another thread may set, a few cycles a step.
STOP_POLL = "if (stop && *stop) return %d;" % STOPPED
