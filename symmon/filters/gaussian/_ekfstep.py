"""The EKF and EKF2 step of larger filters in hand-written C around CasADi's model pieces.

For the Taylor-1 rule (TT1) with additive noise, the step of :mod:`symmon.filters.gaussian.step` is

    x⁻ = f(x),  P⁻ = F P Fᵀ + Q,  ŷ = h(x⁻),  S = H P⁻ Hᵀ + R,  P^{xy} = P⁻ Hᵀ,
    L Lᵀ = S,  Wᵀ = P^{xy} L⁻ᵀ,  x⁺ = x⁻ + Wᵀ L⁻¹ ν,  P⁺ = P⁻ − Wᵀ W

(Gustafsson & Hendeby 2012, Lemma 7.1 with the TT1 moments; F and H the Jacobians of f and h).
CasADi generates the elementwise model pieces — f(x) with the angle states wrapped and the
nonzeros of F; the wrapped innovation y − h(x⁻) and the nonzeros of H — and the dense
linear algebra is a C function written here:

- the products with the Jacobians run over their nonzeros only (the sparsity pattern of F
  and H, compressed by columns, is a constant of the C code): n·nnz(F) and n·nnz(H)
  multiply-adds, where a block-diagonal F of stacked targets has a few nonzeros a row;
- every product with a dense matrix is a loop of contiguous axpy updates of columns
  (column-major, as CasADi), which the compiler vectorises;
- S is factored by a Cholesky factor (n_y³/6), Wᵀ = P^{xy} L⁻ᵀ and L⁻¹ ν by forward
  substitution (n n_y²/2), and P⁺ = P⁻ − Wᵀ W is computed on its lower triangle only
  (n² n_y / 2) and mirrored, the rule of :func:`symmon.filters.gaussian.step.sym`.

For the Taylor-2 rule (TT2, the second-order EKF) the moments gain the second-order terms
(the TT2 of Gustafsson & Hendeby 2012; :mod:`symmon.transforms.taylor`)

    x⁻_i = f_i(x) + ½ tr(Hf_i P),  P⁻ = F P Fᵀ + ½ [tr(Hf_i P Hf_j P)]_ij + Q,
    ŷ_i = h_i(x⁻) + ½ tr(Hh_i P⁻),  S = H P⁻ Hᵀ + ½ [tr(Hh_i P⁻ Hh_j P⁻)]_ij + R,  P^{xy} = P⁻ Hᵀ,

the angle entries of x⁻ and ŷ wrapped after the terms are added, as the MX step.  CasADi then
also generates the nonzeros of the Hessian columns Hc = [H_1[:, S_1] … H_m[:, S_m]] (S_i the
states on which H_i has nonzeros; the pattern a constant of the C), and the C forms
T = P Hc (n·nnz(Hc) multiply-adds, contiguous axpys), whence tr(H_i P) = Σ_{a∈S_i} T_i[a, a]
and tr(H_i P H_j P) = Σ_{a∈S_i, c∈S_j} T_i[c, a] T_j[a, c] ((Σ|S_i|)²/2 more on the lower
triangle): no work outside the Hessians' supports.  Stacked targets have a block of a few
states per output; an affine model has no Hessian nonzeros and keeps its TT1 part (its
second-order terms are zero).  The generated C grows with the Hessians' nonzeros, never with
products with P.

The results are those of the MX step to rounding: the same formulas, the same zero-pivot
rule (a zero pivot of S gives a zero column of L and a zero row and column of L⁻¹; a
negative one a NaN log-likelihood), the same masking of missing components
(:func:`symmon.filters.gaussian.step.update_graph`).

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ...codegen.symbolic import wrap_entries
from ...compile.compiled import compiled, compiled_with_params
from ...compile.csource import c_defines, c_source
from ...core.model import Model

#: From this many states on, a TT1 step with additive noise runs the C step of this module
#: (below, the straight-line SX step is as fast and its compile policy is unchanged).
C_EKF_FROM = 10

#: From this many states on, a square-root TT1 step with additive noise runs the C step of
#: :func:`sqrt_ekf_c` (below, the straight-line SX step).
C_SQRT_EKF_FROM = 10


def _model_part(model: Model, m, p, second: bool = False):
    """g(m) and its Jacobian in m (sparse SX), with the parameters ``p`` (None: none) fixed;
    with ``second``, also the concatenated Hessian columns of :func:`_hessian_columns`."""
    n = m.shape[0]
    cm = compiled_with_params(model) if model.n_p else compiled(model)
    z = ca.vertcat(m, p) if model.n_p else m
    out = (cm.g(z), cm.jac(z)[:, :n])
    if second:
        out += _hessian_columns(cm, n, z)
    return out


def _hessian_columns(cm, n: int, z) -> tuple[ca.SX, list[int], list[int]]:
    """Hc = [H_1[:, S_1] … H_m[:, S_m]] (n × Σ|S_i|, sparse SX of z), the Hessians of the
    outputs in the first n inputs (the states: the parameters have zero variance) on the
    columns S_i where H_i has nonzeros, with S concatenated and the offsets of its blocks."""
    blocks, sup, off = [], [], [0]
    for H in cm.H_sx:
        Hx = H[:n, :n]
        starts = Hx.sparsity().colind()
        cols = [j for j in range(n) if starts[j + 1] > starts[j]]
        blocks.append(Hx[:, cols] if cols else ca.SX(n, 0))
        sup += cols
        off.append(off[-1] + len(cols))
    Hc = ca.horzcat(*blocks) if sup else ca.SX(n, 0)
    return ca.Function("hcols", [cm.w_sx], [Hc])(z), sup, off


def _pattern(J: ca.SX) -> tuple[list[int], list[int], ca.SX]:
    """The CSC pattern (column starts, rows) of J and its nonzeros as a column (one zero
    entry if J has none, so that no C array is empty)."""
    sp = J.sparsity()
    nz = J.nonzeros()
    return list(sp.colind()), list(sp.row()), ca.vertcat(*nz) if nz else ca.SX.zeros(1)


def ekf_pieces(f: Model, h: Model, angle_states: frozenset[int], p_f, p_h, x, y, p,
               name: str, order: int = 1) -> tuple[tuple[ca.Function, ...], dict]:
    """The SX pieces of the C step and the Jacobians' (and Hessians') patterns.

    ``{name}_fpart``: (x, p) ↦ (x⁻, nonzeros of F), x⁻ = f(x) with the angle states wrapped
    (twice, as the MX step: the TT1 mean, then the prediction); ``{name}_hpart``:
    (x⁻, y, p) ↦ (ν, nonzeros of H), ν = y − h(x⁻) wrapped on the angle outputs;
    ``{name}_xwrap``: x ↦ x with the angle states wrapped.  ``p_f``, ``p_h``: the entries of
    the filter's parameter symbol ``p`` that f and h use (None: none); x, y, p are SX symbols.

    ``order`` 2 (TT2): a model whose Hessians in x have nonzeros gets its second-order terms
    in the C step (:data:`_TT2`): its part returns g(x) unwrapped, the nonzeros of J and those
    of the Hessian columns Hc (:func:`_hessian_columns`), and the mean is wrapped after the
    terms ½ tr(H_i P) are added (``{name}_xwrap`` twice for f; for h ``{name}_innov``:
    (ŷ, y) ↦ y − ŷ, ŷ wrapped, then the difference, on the angle outputs).  A model without
    Hessian nonzeros (an affine one) keeps its TT1 part: its second-order terms are zero.
    """
    y_angles = frozenset(h.angle_outputs)
    fx, F, *f2 = _model_part(f, x, p_f, order == 2)
    hx, H, *h2 = _model_part(h, x, p_h, order == 2)
    tt2_f, tt2_h = bool(f2 and f2[0].nnz()), bool(h2 and h2[0].nnz())
    x_pred = fx if tt2_f else wrap_entries(wrap_entries(fx, angle_states), angle_states)
    nu = hx if tt2_h else wrap_entries(y - wrap_entries(hx, y_angles), y_angles)
    f_col, f_row, f_nz = _pattern(F)
    h_col, h_row, h_nz = _pattern(H)
    opts = {"cse": True}
    pattern = {"f_col": f_col, "f_row": f_row, "h_col": h_col, "h_row": h_row, "wrap_x": bool(angle_states),
               "tt2_f": tt2_f, "tt2_h": tt2_h}
    f_outs, h_outs = [x_pred, f_nz], [nu, h_nz]
    for tag, second, outs in (("f", f2, f_outs), ("h", h2, h_outs)):
        if second and second[0].nnz():
            col, row, nz = _pattern(second[0])
            outs.append(nz)
            pattern.update({f"{tag}2_col": col, f"{tag}2_row": row, f"{tag}2_sup": second[1],
                            f"{tag}2_off": second[2]})
    fpart = ca.Function(f"{name}_fpart", [x, p], f_outs, opts)
    hpart = ca.Function(f"{name}_hpart", [x, y, p], h_outs, opts)
    xwrap = ca.Function(f"{name}_xwrap", [x], [wrap_entries(x, angle_states)], opts)
    pieces = (fpart, hpart, xwrap)
    if tt2_h:
        v = ca.SX.sym("v", y.shape[0])
        pieces += (ca.Function(f"{name}_innov", [v, y], [wrap_entries(y - wrap_entries(v, y_angles), y_angles)],
                               opts),)
    return pieces, pattern


def _ints(values: list[int]) -> list[int]:
    """The entries of a sparsity pattern's array (an array of one 0 for none: C has no empty array)."""
    return [int(v) for v in (values or [0])]


def ekf_c(name: str, n: int, n_y: int, pattern: dict, iterations: int = 1) -> tuple[str, int]:
    """The C of ``{name}_ekf`` (after the pieces' generated C) and its scratch size in reals;
    ``iterations`` > 1: the iterated EKF's update (:func:`symmon.filters.gaussian.step.update_graph`);
    ``pattern`` with ``tt2_f`` or ``tt2_h`` (:func:`ekf_pieces` of order 2): the TT2 terms of
    f or h in the step."""
    f_nnz, h_nnz = max(len(pattern["f_row"]), 1), max(len(pattern["h_row"]), 1)
    scratch = n + 2 * n * n + f_nnz + h_nnz + n_y + n * n_y + 2 * n_y * n_y + 2 * n_y + 3 * n + 2 * n_y + n_y * n_y
    second = {tag: {key: pattern.get(f"{tag}2_{key}", []) for key in ("col", "row", "sup", "off")}
              for tag in "fh"}
    tt2 = {tag: bool(pattern.get(f"tt2_{tag}")) for tag in "fh"}
    # The TT2 scratch (after the TT1 step's): the Hessian columns' nonzeros, T = P Hc, t, G,
    # and two vectors, shared by the prediction and the update.
    ns = max([len(second[tag]["sup"]) for tag in "fh" if tt2[tag]] + [1])
    h2 = max([len(second[tag]["row"]) for tag in "fh" if tt2[tag]] + [1])
    nt = max(n, n_y)
    if tt2["f"] or tt2["h"]:
        scratch += h2 + n * ns + nt + nt * nt + 2 * nt
    defines = c_defines(
        EKF_NAME=name, EKF_N=n, EKF_NY=n_y, EKF_TT2F=tt2["f"], EKF_TT2H=tt2["h"], EKF_NS=ns,
        EKF_F_COL=_ints(pattern["f_col"]), EKF_F_ROW=_ints(pattern["f_row"]), EKF_H_COL=_ints(pattern["h_col"]),
        EKF_H_ROW=_ints(pattern["h_row"]), EKF_SCRATCH=scratch,
        **{f"EKF_{tag.upper()}2_{key.upper()}": _ints(v) for tag in "fh" for key, v in second[tag].items()},
        EKF_F_NNZ=f_nnz, EKF_H_NNZ=h_nnz, EKF_WRAP_X=bool(pattern["wrap_x"]), EKF_ITERATIONS=int(iterations),
        EKF_LOG_2PI=float(np.log(2 * np.pi)), EKF_H2=h2, EKF_NT=nt)
    return defines + c_source(__package__, "ekf_step.c"), scratch


def sqrt_ekf_c(name: str, n: int, n_y: int, pattern: dict, iterations: int = 1) -> tuple[str, int]:
    """The C of ``{name}_sqrt_ekf``, the square-root EKF step (TT1, additive noise; after the
    pieces' generated C, :func:`ekf_pieces` of order 1), and its scratch size in reals;
    ``iterations`` > 1: the iterated EKF's update.

    The factor arithmetic of :mod:`symmon.filters.gaussian._sqrtstep`: S⁻ = tria([F S, √Q]),
    S_y = tria([D √R, I − D, D H S⁻]), K̄ = S⁻ (D H S⁻)ᵀ S_y⁻ᵀ, x⁺ = x⁻ + K̄ S_y⁻¹ ν and
    S⁺ = tria([S⁻ − K D H S⁻, −K D √R]) with K = K̄ S_y⁻¹.  The products with F and H run over
    their nonzeros and over those of the factors, and the Householder triangularisation skips
    the columns whose entry in the reflected row is zero (the reflection leaves them as they
    are), so a factor that stays sparse (block-diagonal for independent targets) keeps its
    cost low; a dense factor costs the O(n³) of the dense reflections.
    """
    f_nnz, h_nnz = max(len(pattern["f_row"]), 1), max(len(pattern["h_row"]), 1)
    m_a = max(2 * n * n, (n + n_y) * (n + 2 * n_y))  # the time update's and the update's pre-arrays
    m_v = max(2 * n, n + 2 * n_y)  # a row of either (and a column: n + n_y ≤ that)
    scratch = (n + n * n + m_a + f_nnz + h_nnz + n_y * n + (n + n_y) ** 2 + 3 * n_y + 3 * n + 2 * m_v + n_y)
    defines = c_defines(
        EKF_NAME=name, EKF_N=n, EKF_NY=n_y, EKF_F_COL=_ints(pattern["f_col"]), EKF_F_ROW=_ints(pattern["f_row"]),
        EKF_H_COL=_ints(pattern["h_col"]), EKF_H_ROW=_ints(pattern["h_row"]), EKF_F_NNZ=f_nnz, EKF_H_NNZ=h_nnz,
        EKF_WRAP_X=bool(pattern["wrap_x"]), EKF_ITERATIONS=int(iterations), EKF_LOG_2PI=float(np.log(2 * np.pi)),
        EKF_SCRATCH=scratch, EKF_MA=m_a, EKF_MV=m_v)
    return defines + c_source(__package__, "sqrt_ekf_step.c"), scratch
