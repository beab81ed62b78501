"""The square-root step of a point rule (the UKF, the cubature rule) in hand-written C around
CasADi's sigma-point pieces.

CasADi generates what depends on the model (straight-line SX below :data:`MX_PIECES_FROM` states,
MX with the points one loop from it on): the points of N(x, S Sᵀ),
f (resp. h) at them, the weighted mean (angle rows by their circular mean, wrapped) and the
weighted deviations √wᶜ_k (g(χ_k) − ḡ), √wᶜ_k (χ_k − x) (:func:`symmon.codegen.sqrtform.sqrt_moments`);
the factor arithmetic is the C of ``sqrt_ukf_step.c``, which shares the Householder
triangularisation of the square-root EKF (``sqrt_tria.c``): S⁻ = tria([√Q, Y₊]) with the noise's
triangle first (its reflections skip the triangle's zeros), and the update as the
triangularisation of the pre-array [[D √R, I − D, D Y], [0, 0, X]] → [[S_y, 0], [K̄, S⁺]] (the
array form: the same S_y, K̄ and S⁺ as the MX step in exact arithmetic, S⁺ from reflections of
the points rather than from the Joseph columns; to rounding, 1e-12 relative in the tests, the
MX step's).  Each pair of points ±z (the UT's, the cubature rule's) is first rotated,
(a, b) ↦ ((a + b)/√2, (a − b)/√2), which leaves the Gram matrix as it is and makes the x part of
the sums exactly zero (the offsets ±S z are exact negatives): those columns are triangularised
on the y rows alone, then the n differences with the result, about half the flops of the whole
pre-array.  With the reflections in place (no copies of trailing blocks), the square-root UKF
costs 1.7–1.9× the standard one at 16–64 states (benchmarks/RESULTS.md, "Square-root
filters"), where the MX step cost 2.8–3.9×.

Only rules with non-negative covariance weights run it (a negative weight needs a downdate, which
the MX step does), and only the plain update (no iterations).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ...codegen.sqrtform import sqrt_moments
from ...codegen.symbolic import effective_order, unit_rule, wrap_entries
from ...compile.compiled import compiled, compiled_with_params
from ...compile.csource import c_defines, c_source
from ...core.model import Model
from ...transforms.base import Transform

#: From this many states on, a square-root point-rule step with additive noise and non-negative
#: weights runs the C step of :func:`sqrt_ukf_c` (below, the straight-line SX step: at 4 states it is as fast).
C_SQRT_UKF_FROM = 8

#: From this many states on, the sigma-point pieces are MX (the points one loop: C small enough
#: for an optimised build); below, straight-line SX (as fast, and no loop overhead).
MX_PIECES_FROM = 16


def sqrt_ukf_kind(n: int) -> type:
    """``ca.SX`` or ``ca.MX``: the kind of the symbols of :func:`sqrt_ukf_pieces` for n states."""
    return ca.MX if n >= MX_PIECES_FROM else ca.SX


def c_sqrt_ukf_applies(f: Model, h: Model, transform: Transform, iterations: int) -> bool:
    """Whether the square-root step of (f, h, transform) runs the C step of this module: a
    point rule with non-negative covariance weights in n = f.n_u dimensions, additive noise,
    no iterations, n ≥ :data:`C_SQRT_UKF_FROM`."""
    n = f.n_u
    if not transform.point_rule or f.n_v or h.n_v or iterations != 1 or n < C_SQRT_UKF_FROM:
        return False
    return bool(np.all(np.asarray(unit_rule(transform, n)[2], dtype=float) >= 0))


def _moments(model: Model, m, S, transform: Transform, angles, p):
    cm = compiled_with_params(model) if model.n_p else compiled(model)
    return sqrt_moments(cm, m, S, transform, angles, p if model.n_p else None)


def sqrt_ukf_pieces(f: Model, h: Model, transform: Transform, angle_states: frozenset[int], p_f, p_h,
                    x, y, p, name: str) -> tuple[tuple[ca.Function, ...], tuple[int, int, int]]:
    """The pieces of the C step (SX or MX, the kind of ``x``) and the numbers of columns (k_f, k_0, k_d) of f's and h's
    deviations (k_f: the points', or n for a model the rule takes exactly by its Jacobian, an affine f).

    ``{name}_upred``: (x, S, p) ↦ (x⁻, Y₊ (n × k_f)), x⁻ the rule's mean of f with the angle
    states wrapped; ``{name}_uupd``: (x⁻, S⁻, y, p) ↦ (ν, Y₀ (n_y × k_0), Y_d (n_y × k_d), X_d
    (n × k_d)), ν = y − ŷ wrapped on the angle outputs and the columns of :func:`_paired`; ``{name}_xwrap``: x ↦ x with the angle states wrapped.
    ``p_f``, ``p_h``: the entries of the filter's parameter symbol ``p`` that f and h use (None:
    none); x, y, p are symbols of the kind :func:`sqrt_ukf_kind` (MX: the points' evaluations one
    loop, C small enough for an optimised build, where straight-line SX of 2n + 1 points at 64
    states is not), S and S⁻ lower triangular (their upper triangles not read).
    """
    n = x.shape[0]
    S = type(x).sym("S", n, n)  # dense, as the C passes it; the products read its lower triangle
    mean, cols = _moments(f, x, ca.tril(S), transform, angle_states, p_f)
    x_pred = wrap_entries(mean, angle_states)
    y_hat, hcols = _moments(h, x, ca.tril(S), transform, frozenset(h.angle_outputs), p_h)
    y_angles = frozenset(h.angle_outputs)
    nu = wrap_entries(y - y_hat, y_angles)
    if cols.Yn is not None or hcols.Yn is not None:
        raise ValueError(f"transform: {transform!r} has negative weights in {n} dimensions; the C square-root "
                         "step needs none (c_sqrt_ukf_applies)")
    Y0, Yd, Xd = _paired(hcols, h, n, transform, y_angles)
    opts = {"cse": True}
    upred = ca.Function(f"{name}_upred", [x, S, p], [x_pred, ca.densify(cols.Y)], opts)
    uupd = ca.Function(f"{name}_uupd", [x, S, y, p], [nu, ca.densify(Y0), ca.densify(Yd), ca.densify(Xd)], opts)
    xwrap = ca.Function(f"{name}_xwrap", [x], [wrap_entries(x, angle_states)], opts)
    return (upred, uupd, xwrap), (cols.Y.shape[1], Y0.shape[1], Yd.shape[1])


def _paired(cols, h: Model, n: int, transform: Transform, y_angles) -> tuple:
    """(Y₀, Y_d, X_d): the joint columns [Y; X] of h's points after an orthogonal rotation of
    each pair of points ±z of equal weight, (a, b) ↦ ((a + b)/√2, (a − b)/√2): the pair's X
    deviations are exact negatives (the offsets ±S z), so the sum's X part is zero, and the
    columns whose X part is zero (those, and the centre's) are Y₀ (with X₀ = 0); the others
    Y_d over X_d.  The Gram matrix of the columns is unchanged; the C update triangularises Y₀
    alone first (rows y only), then the rest (module notes)."""
    cm = compiled_with_params(h) if h.n_p else compiled(h)
    k = cols.Y.shape[1]
    kind = type(cols.Y)
    if effective_order(cm, n, transform, y_angles) in (1, 2):  # the Jacobian's columns: none paired
        return kind.zeros(cols.Y.shape[0], 0), cols.Y, cols.W
    Z, _, wc = unit_rule(transform, n)
    Z, wc = np.asarray(Z, dtype=float), np.asarray(wc, dtype=float)
    pos = np.flatnonzero(wc > 0).tolist()
    where = {pt: i for i, pt in enumerate(pos)}
    zero, pairs, single, used = [], [], [], set()
    for a in pos:
        if a in used:
            continue
        if not np.any(Z[a]):
            zero.append(where[a])
            continue
        b = next((b for b in pos if b > a and b not in used and wc[b] == wc[a] and np.array_equal(Z[b], -Z[a])),
                 None)
        if b is None:
            single.append(where[a])
        else:
            used.add(b)
            pairs.append((where[a], where[b]))
    assert len(zero) + 2 * len(pairs) + len(single) == k
    # The rotation as sparse constant products (MX: one product each, no slices).
    r = 1 / np.sqrt(2.0)
    rot0, rotd = np.zeros((k, len(zero) + len(pairs))), np.zeros((k, len(pairs) + len(single)))
    for c, i in enumerate(zero):
        rot0[i, c] = 1.0
    for c, (a, b) in enumerate(pairs):
        rot0[a, len(zero) + c] = rot0[b, len(zero) + c] = r
        rotd[a, c], rotd[b, c] = r, -r
    for c, i in enumerate(single):
        rotd[i, len(pairs) + c] = 1.0
    rot0, rotd = ca.sparsify(ca.DM(rot0)), ca.sparsify(ca.DM(rotd))
    return ca.mtimes(cols.Y, rot0), ca.mtimes(cols.Y, rotd), ca.mtimes(cols.W, rotd)


def sqrt_ukf_c(name: str, n: int, n_y: int, k: tuple[int, int, int], wrap_x: bool,
               pieces: tuple[ca.Function, ...]) -> tuple[str, int]:
    """The C of ``{name}_sqrt_ukf`` (after the pieces' generated C, :func:`sqrt_ukf_pieces`
    with (k_f, k_0, k_d) columns of deviations) and its scratch size in reals; ``wrap_x``: the step wraps angle
    states; ``pieces``: the functions it calls (the sizes of their argument arrays)."""
    n2, (kf, k0, kd) = n + n_y, k
    m2 = max(n_y + kd, n2)  # the update's second pre-array's columns (zeros beyond n_y + k_d)
    m_a = max(n * (n + kf), n_y * (2 * n_y + k0), n2 * m2)  # the time update's and the update's pre-arrays
    m_v = max(n + kf, 2 * n_y + k0, m2)  # a row of any, and a column
    scratch = n + n * n + m_a + n_y * (k0 + kd) + n * kd + n2 * n2 + n_y * n_y + n_y + n + 2 * m_v + n_y
    defines = c_defines(EKF_NAME=name, EKF_N=n, EKF_NY=n_y, EKF_KF=kf, EKF_K0=k0, EKF_KD=kd, EKF_M2=m2,
                        EKF_SZ_ARG=max(max(g.sz_arg() for g in pieces), 4),
                        EKF_SZ_RES=max(max(g.sz_res() for g in pieces), 4), EKF_WRAP_X=bool(wrap_x),
                        EKF_LOG_2PI=float(np.log(2 * np.pi)), EKF_SCRATCH=scratch, EKF_MA=m_a, EKF_MV=m_v)
    return defines + c_source(__package__, "sqrt_ukf_step.c"), scratch
