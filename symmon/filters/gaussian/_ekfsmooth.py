"""The backward step of the extended RTS smoother in hand-written C around CasADi's model pieces.

Where the time update is TT1's closed form with additive noise — the EKF, and any rule exact
to degree 2 on an affine f without angle states (:func:`symmon.codegen.symbolic.effective_order`:
the UKF on linear dynamics) — the backward step of :mod:`symmon.filters.gaussian.smoother` reads
(Särkkä 2013, Algorithm 9.3 with the TT1 moments; F the Jacobian of f at x_k)

    x⁻ = f(x_k),  C = P_k Fᵀ,  P⁻ = F P_k Fᵀ + Q,  L Lᵀ = P⁻,  G = C L⁻ᵀ L⁻¹,
    x^s_k = x_k + G (x^s_{k+1} − x⁻),  P^s_k = P_k + G (P^s_{k+1} − P⁻) Gᵀ,

with the angle states of the difference and of x^s_k wrapped.  As in the EKF's C step
(:mod:`symmon.filters.gaussian._ekfstep`), CasADi generates the elementwise pieces (f with the angle
states wrapped and the nonzeros of F; the wrapping of a state vector) and the dense linear
algebra is C written here, on CasADi's column-major layout:

- P Fᵀ and F (P Fᵀ) run over the nonzeros of F only (its sparsity pattern a constant of the
  code): 2 n·nnz(F) multiply-adds;
- P⁻ is factored right-looking (n³/6), and G by two triangular solves in place of C
  (W Lᵀ = C forward, G L = W backward, n³/2 each), with no inverse of L formed;
- G (P^s_{k+1} − P⁻) is n³ and its product with Gᵀ is computed on the lower triangle only
  (n³/2), then mirrored (the rule of :func:`symmon.filters.gaussian.step.sym`);
- every dense loop is a contiguous column update, four columns a pass.

About 2.7 n³ multiply-adds a step, against the ~6 n³ of the MX graph's products with the
inverse factor.  The results are those of the MX step to rounding, and a prediction whose
factor has a zero, negative or NaN pivot gives an infinite gain (so x^s and P^s are inf or
NaN, which the smoother reports as a singular prediction), as the MX step's does.

References
----------
S. Särkkä, *Bayesian Filtering and Smoothing*, Cambridge University Press, 2013, ch. 8–9.
"""

from __future__ import annotations

import casadi as ca

from ...codegen.symbolic import effective_order, wrap_entries
from ...compile.compiled import compiled, compiled_with_params
from ...core.model import Model
from ...transforms.base import Transform
from ._ekfstep import C_EKF_FROM, DENSE_C, _ints, _model_part, _pattern

__all__ = ["backward_in_c", "backward_pieces", "backward_c"]


def backward_in_c(f: Model, transform: Transform, angle_states: frozenset[int], square_root: bool = False) -> bool:
    """Whether the smoother of (f, transform) runs the C backward step of this module: a time
    update that is TT1's closed form (:func:`~symmon.codegen.symbolic.effective_order` 1) with
    additive noise, in the standard form, from :data:`~symmon.filters.gaussian._ekfstep.C_EKF_FROM`
    states on (below, the straight-line SX step is as fast)."""
    n = f.n_u
    if square_root or f.n_v or n < C_EKF_FROM:
        return False
    cm = compiled_with_params(f) if f.n_p else compiled(f)
    return effective_order(cm, n, transform, angle_states) == 1


def backward_pieces(f: Model, angle_states: frozenset[int], p_f, x, p, name: str) -> tuple[tuple[ca.Function, ...], dict]:
    """The SX pieces of the C backward step and F's pattern.

    ``{name}_fpart``: (x, p) ↦ (x⁻, nonzeros of F), x⁻ = f(x) with the angle states wrapped
    (twice, as the MX graph: the TT1 mean, then the prediction); ``{name}_xwrap``: v ↦ v with
    the angle states wrapped.  ``p_f``: the entries of the filter's parameter symbol ``p``
    that f uses (None: none); x, p are SX symbols."""
    fx, F = _model_part(f, x, p_f)
    x_pred = wrap_entries(wrap_entries(fx, angle_states), angle_states)
    f_col, f_row, f_nz = _pattern(F)
    opts = {"cse": True}
    fpart = ca.Function(f"{name}_fpart", [x, p], [x_pred, f_nz], opts)
    xwrap = ca.Function(f"{name}_xwrap", [x], [wrap_entries(x, angle_states)], opts)
    return (fpart, xwrap), {"f_col": f_col, "f_row": f_row, "wrap_x": bool(angle_states)}


# The backward step: column-major arrays (CasADi's layout), every dense product an axpy of columns.
_BACKWARD = """
/* symmon: the RTS backward step {name}_bwd (TT1 time update, additive noise) around the CasADi
   pieces {name}_fpart and {name}_xwrap; the linear algebra of symmon.filters.gaussian._ekfsmooth.
   arg: x_k, P_k, xs_{{k+1}}, Ps_{{k+1}}, Q, p_{{k+1}}; res: xs_k, Ps_k.  s: scratch of
   {scratch} reals. */
#include <math.h>
#define {name}_N {n}
static const casadi_int {name}_fcol[] = {f_col};
static const casadi_int {name}_frow[] = {f_row};

""" + DENSE_C + """
/* A (n x n) = B Ft, Ft the transpose of the sparse F (CSC {name}_fcol/{name}_frow, nz):
   A[:, i] += F[i, c] B[:, c] over the nonzeros, contiguous column updates. */
static void {name}_times_ft(casadi_real* restrict A, const casadi_real* restrict B, const casadi_real* nz) {{
  const casadi_int n = {name}_N;
  casadi_int c, e, i;
  for (i = 0; i < n * n; ++i) A[i] = 0;
  for (c = 0; c < n; ++c)
    for (e = {name}_fcol[c]; e < {name}_fcol[c + 1]; ++e) {{
      casadi_real v = nz[e];
      casadi_real* a = A + {name}_frow[e] * n;
      const casadi_real* b = B + c * n;
      for (i = 0; i < n; ++i) a[i] += v * b[i];
    }}
}}

/* The lower triangle of the n x n matrix A mirrored into its upper one, in blocks. */
static void {name}_mirror(casadi_real* A) {{
  const casadi_int n = {name}_N;
  casadi_int i, j, i0, j0;
  for (j0 = 0; j0 < n; j0 += 16)
    for (i0 = j0; i0 < n; i0 += 16)
      for (j = j0; j < n && j < j0 + 16; ++j)
        for (i = i0 > j + 1 ? i0 : j + 1; i < n && i < i0 + 16; ++i) A[j + i * n] = A[i + j * n];
}}

static int {name}_bwd(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w,
    casadi_real* s) {{
  const casadi_int n = {name}_N;
  const casadi_real *x = arg[0], *P = arg[1], *xs1 = arg[2], *Ps1 = arg[3], *Q = arg[4], *p = arg[5];
  casadi_real *xs = res[0], *Ps = res[1];
  casadi_real *xp = s, *G = xp + n, *A = G + n * n, *Pp = A + n * n, *L = Pp + n * n, *r = L + n * n;
  casadi_real *dx = r + n, *v = dx + n, *Fz = v + n;
  const casadi_real* a2[2];
  casadi_real* r2[2];
  casadi_int i, j, k, ok = 1;
  /* x- = f(x) (angle states wrapped), F's nonzeros, with the parameters of step k + 1. */
  a2[0] = x; a2[1] = p; r2[0] = xp; r2[1] = Fz;
  if ({name}_fpart(a2, r2, iw, w, 0)) return 1;
  /* C = P F^T (in G, solved in place below), P- = F C + Q on the lower triangle, mirrored. */
  {name}_times_ft(G, P, Fz);
  for (j = 0; j < n; ++j)  /* A = C^T = F P: P is symmetric */
    for (i = 0; i < n; ++i) A[j + i * n] = G[i + j * n];
  {name}_times_ft(Pp, A, Fz);
  for (i = 0; i < n * n; ++i) Pp[i] += Q[i];
  {name}_mirror(Pp);
  /* L L^T = P-, right-looking (column j scaled, then subtracted from the columns after it). */
  for (j = 0; j < n; ++j)
    for (i = 0; i < n; ++i) L[i + j * n] = i >= j ? Pp[i + j * n] : 0;
  ok = {name}_chol(L, n, r);  /* 0: a zero, negative or NaN pivot, P- is singular */
  /* W L^T = C: column i of W is (C[:, i] - sum_{{k<i}} W[:, k] L[i, k]) / L[i, i] ... */
  for (i = 0; i < n; ++i) {{
    casadi_real* c = G + i * n;
    {name}_add_cols(c, G, n, L + i, n, i, n, -1.0);
    for (k = 0; k < n; ++k) c[k] *= r[i];
  }}
  /* ... and G L = W: column j of G is (W[:, j] - sum_{{i>j}} G[:, i] L[i, j]) / L[j, j]. */
  for (j = n - 1; j >= 0; --j) {{
    casadi_real* c = G + j * n;
    {name}_add_cols(c, G + (j + 1) * n, n, L + j * n + j + 1, 1, n - 1 - j, n, -1.0);
    for (k = 0; k < n; ++k) c[k] *= r[j];
  }}
  if (!ok)  /* the MX step's rule: an infinite gain, so that the smoother reports the step */
    for (i = 0; i < n * n; ++i) G[i] = INFINITY;
  /* xs = x + G wrap(xs_{{k+1}} - x-), wrapped. */
  for (j = 0; j < n; ++j) dx[j] = xs1[j] - xp[j];
  if ({wrap_x}) {{
    a2[0] = dx; r2[0] = v;
    if ({name}_xwrap(a2, r2, iw, w, 0)) return 1;
    for (j = 0; j < n; ++j) dx[j] = v[j];
  }}
  for (j = 0; j < n; ++j) v[j] = x[j];
  {name}_add_cols(v, G, n, dx, 1, n, n, 1.0);
  if ({wrap_x}) {{
    a2[0] = v; r2[0] = xs;
    if ({name}_xwrap(a2, r2, iw, w, 0)) return 1;
  }} else {{
    for (j = 0; j < n; ++j) xs[j] = v[j];
  }}
  /* M = G (Ps_{{k+1}} - P-) (in L; A holds the difference), Ps = P + M G^T on the lower
     triangle: column j gets sum_k M[j:, k] G[j, k]. */
  for (i = 0; i < n * n; ++i) A[i] = Ps1[i] - Pp[i];
  for (j = 0; j < n; ++j) {{
    casadi_real* m = L + j * n;
    for (i = 0; i < n; ++i) m[i] = 0;
    {name}_add_cols(m, G, n, A + j * n, 1, n, n, 1.0);
  }}
  for (j = 0; j < n; ++j) {{
    casadi_real* ps = Ps + j * n;
    for (i = j; i < n; ++i) ps[i] = P[i + j * n];
    {name}_add_cols(ps + j, L + j, n, G + j, n, n, n - j, 1.0);
  }}
  {name}_mirror(Ps);
  return 0;
}}
"""


def backward_c(name: str, n: int, pattern: dict) -> tuple[str, int]:
    """The C of ``{name}_bwd`` (after the pieces' generated C) and its scratch size in reals."""
    f_nnz = max(len(pattern["f_row"]), 1)
    scratch = 4 * n + 4 * n * n + f_nnz
    code = _BACKWARD.format(name=name, n=n, f_col=_ints(pattern["f_col"]), f_row=_ints(pattern["f_row"]),
                            scratch=scratch, wrap_x=int(pattern["wrap_x"]))
    return code, scratch
