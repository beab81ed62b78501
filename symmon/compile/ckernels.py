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

from .csource import c_text

__all__ = ["faster_kernels", "faster_sparse_products", "CASADI_MTIMES_DENSE", "MTIMES_DENSE", "CASADI_MTIMES",
           "MTIMES_SPARSE", "STOP_POLL", "STOPPED"]

log = logging.getLogger(__name__)

#: CasADi 3.6–3.8's ``casadi_mtimes_dense``: z += x y (x nrow_x × ncol_x, y ncol_x × ncol_y),
#: or z += xᵀ y with ``tr`` (x nrow_x × ncol_x, y nrow_x × ncol_y), all column-major
#: (``casadi_mtimes_dense.c``: CasADi's text, to be matched).
CASADI_MTIMES_DENSE = c_text(__package__, "casadi_mtimes_dense.c")

#: The same products, loops reordered: each z entry adds x[j, k] y[k, i] for k = 0, 1, …
#: in turn, as above.  z is never one of the operands (CasADi computes a product in place
#: only into its accumulator), which is what lets the sum of a tr column stay in a register
#: (``mtimes_dense.c``).
MTIMES_DENSE = c_text(__package__, "mtimes_dense.c")


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
#: compressed-column form, through a dense work column w (``casadi_mtimes.c``: CasADi's text,
#: to be matched).
CASADI_MTIMES = c_text(__package__, "casadi_mtimes.c")

#: The same products, with a direct loop where a column of z or of x has consecutive rows
#: (a dense block: the covariances and their tangents in a filter step), which gcc
#: vectorises, instead of the scatter through the row indices; every entry of w still
#: receives its terms in the same order, one rounding after each (no FMA), so the numbers
#: do not change.  The transposed product keeps CasADi's loop: the text is CasADi's up to its
#: untransposed branch (``mtimes_sparse.c``).
MTIMES_SPARSE = c_text(__package__, "mtimes_sparse.c")


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
