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
smoother's backward pass) make between two steps; the loops kept in ``.c`` files (the
particle filter's, the Gaussian-sum filter's, the IMM's) make the same check, with
:data:`STOPPED` given as a macro.  An interrupt of the thread waiting for them sets the
flag (:func:`symmon.compile.compiled.in_threads`, :func:`~symmon.compile.compiled.run_stoppable`),
and each loop returns :data:`STOPPED` at its next step instead of running to its end.
"""

from __future__ import annotations

import logging

__all__ = ["faster_kernels", "faster_sparse_products", "CASADI_MTIMES_DENSE", "MTIMES_DENSE", "CASADI_MTIMES",
           "MTIMES_SPARSE", "STOP_POLL", "STOPPED"]

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


#: CasADi 3.8's ``casadi_mtimes``: z += x y (``tr``: z += xᵀ y) for sparse x, y and z in
#: compressed-column form, through a dense work column w.
CASADI_MTIMES = """\
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
      casadi_int kk;
      for (kk=colind_z[cc]; kk<colind_z[cc+1]; ++kk) {
        w[row_z[kk]] = z[kk];
      }
      for (kk=colind_y[cc]; kk<colind_y[cc+1]; ++kk) {
        casadi_int kk1;
        casadi_int rr = row_y[kk];
        for (kk1=colind_x[rr]; kk1<colind_x[rr+1]; ++kk1) {
          w[row_x[kk1]] += x[kk1]*y[kk];
        }
      }
      for (kk=colind_z[cc]; kk<colind_z[cc+1]; ++kk) {
        z[kk] = w[row_z[kk]];
      }
    }
  }
}
"""

#: The same products, with a direct loop where a column of z or of x has consecutive rows
#: (a dense block: the covariances and their tangents in a filter step), which gcc
#: vectorises, instead of the scatter through the row indices; every entry of w still
#: receives its terms in the same order, one rounding after each (no FMA), so the numbers
#: do not change.  The transposed product keeps CasADi's loop: the text is CasADi's up to its
#: untransposed branch, which :data:`_DIRECT_PRODUCT` replaces.
_DIRECT_PRODUCT = """\
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
"""
#: CasADi's sparse product with the direct loops of :data:`_DIRECT_PRODUCT`.
MTIMES_SPARSE = CASADI_MTIMES[:CASADI_MTIMES.index("  } else {\n")] + _DIRECT_PRODUCT


def faster_sparse_products(code: str) -> str:
    """``code`` (CasADi's generated C) with :data:`MTIMES_SPARSE` in place of CasADi's
    sparse product, when that is :data:`CASADI_MTIMES` word for word; otherwise ``code``
    unchanged.  Opt-in (the maximum-likelihood fit's derivatives, whose products of the
    step's covariances with sparse Jacobians took a third of their time): every library
    that uses it is new C, so a cached one is rebuilt once."""
    if CASADI_MTIMES in code:
        return code.replace(CASADI_MTIMES, MTIMES_SPARSE, 1)
    if "void casadi_mtimes(" in code:
        log.debug("symmon: this CasADi's casadi_mtimes is not the known one; kept as it is")
    return code


#: The return code of a run loop that saw its stop flag.
STOPPED = 2
#: C, between two steps of a run loop whose arguments include ``const volatile int* stop``
#: (NULL: never stopped): one load of a flag another thread may set, a few cycles a step.
STOP_POLL = "if (stop && *stop) return %d;" % STOPPED
