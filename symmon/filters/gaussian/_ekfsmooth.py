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
from ...compile.csource import c_defines, c_source
from ...core.model import Model
from ...transforms.base import Transform
from ._ekfstep import C_EKF_FROM, _ints, _model_part, _pattern

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


def backward_c(name: str, n: int, pattern: dict) -> tuple[str, int]:
    """The C of ``{name}_bwd`` (after the pieces' generated C) and its scratch size in reals."""
    f_nnz = max(len(pattern["f_row"]), 1)
    scratch = 4 * n + 4 * n * n + f_nnz
    defines = c_defines(EKF_NAME=name, EKB_N=n, EKB_F_COL=_ints(pattern["f_col"]),
                        EKB_F_ROW=_ints(pattern["f_row"]), EKB_SCRATCH=scratch, EKB_WRAP_X=bool(pattern["wrap_x"]))
    return defines + c_source(__package__, "ekf_backward.c"), scratch
