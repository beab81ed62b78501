"""The square-root form of the compiled filter step: the Cholesky factor S of P (P = S Sᵀ)
propagated through the time and the measurement update.

The standard step (:mod:`symmon.filters.gaussian.step`) forms P⁻ = Cov f + Q and P⁺ = P⁻ − K S Kᵀ;
the difference loses positive definiteness in floating point when a measurement is much
more precise than the prior (R = 1e-16 against P⁻ ≈ 1: P⁺ is rounding, of either sign), or
when a noise-free state's variance shrinks over many steps.  Here every covariance is a
Gram matrix of columns (:mod:`symmon.codegen.sqrtform`), triangularised without squaring:

    S⁻ = tria([Y₊, √Q])  (downdated by Y₋),
    S_y = tria([Y₊, √R])  (downdated by Y₋),  K = (X₊ Y₊ᵀ − X₋ Y₋ᵀ) S_y⁻ᵀ S_y⁻¹,
    S⁺ = tria([X₊ − K Y₊, −K √R])  (downdated by X₋ − K Y₋),  x⁺ = x⁻ + K ν,

with Y₊, X₊ the joint columns of the rule (Y₊ = J S⁻ and X₊ = S⁻ for TT1, the weighted
deviations of the points for a point rule, which are taken from S itself), √Q and √R the
Cholesky factors of the noises, and with general noise the rule on [x; w] with the factor
blkdiag(S, √Q) (resp. blkdiag(S⁻, √R)).  S⁺ is the factored Joseph form,
S⁺ S⁺ᵀ = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ for TT1, and P⁻ − K S Kᵀ for every rule in exact
arithmetic, so the filter is the standard one; the factors have a non-negative diagonal,
so on a positive definite P they are the Cholesky factors the standard form takes its
sigma points from.

Missing components (``mask``, as :func:`symmon.filters.gaussian.step.update_graph`): their rows of the
y columns are zero and the columns of I − D are appended to S_y's, so S_y S_yᵀ = D S D + (I − D)
and the gain's columns of the missing components are zero.
From :data:`~symmon.filters.gaussian._ekfstep.C_SQRT_EKF_FROM` states on, the TT1 step with
additive noise runs in hand-written C (:func:`symmon.filters.gaussian._ekfstep.sqrt_ekf_c`): the
products over the nonzeros of F, H and the factors, a triangularisation that skips the
columns a reflection leaves as they are, and the update as one triangularisation of the
pre-array [[D √R, I − D, D H S⁻], [0, 0, S⁻]] → [[S_y, 0], [K̄, S⁺]] (the array form: the same
S_y, K̄ and S⁺ in exact arithmetic, S⁺ from reflections of the factors rather than from the
Joseph columns; to rounding, 1e-12 relative in the tests, the MX step's).
From :data:`~symmon.filters.gaussian._ukfstep.C_SQRT_UKF_FROM` states on, a point rule with
non-negative weights and additive noise (the SR-UKF, the square-root cubature filter) likewise
runs in C (:mod:`symmon.filters.gaussian._ukfstep`): CasADi's sigma points, the same
triangularisations, the update by the array form after a rotation of each pair of points.
The iterated EKF relinearises at x_i: its residual y − h(x_i) − J_i (x⁻ − x_i) takes J_i
from the model's Jacobian (no solve with P⁻), and S⁺ is that of the last linearisation.

References
----------
M. S. Grewal, A. P. Andrews, *Kalman Filtering: Theory and Practice with MATLAB*, 4th ed.,
Wiley, 2015 (the Joseph form and square-root filters).
R. van der Merwe, E. A. Wan, "The square-root unscented Kalman filter for state and
parameter-estimation", ICASSP 2001. doi:10.1109/ICASSP.2001.940586
I. Arasaratnam, S. Haykin, "Cubature Kalman filters", IEEE Trans. Autom. Control 54(6),
2009, §V. doi:10.1109/TAC.2009.2019800
B. M. Bell, F. W. Cathey, "The iterated Kalman filter update as a Gauss–Newton method", IEEE
Trans. Autom. Control 38(2), 1993. doi:10.1109/9.250476
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from ...codegen.sqrtform import (JointColumns, chol_scaled, downdate_all, gain_factor, residual_factor, sqrt_moments,
                                tria)
from ...codegen.symbolic import tril_inverse, wrap_entries
from ...compile.compiled import compiled, compiled_with_params
from ...core.gaussian import matrix_sqrt
from ...core.model import Model
from ...transforms.base import Transform

__all__ = ["sqrt_predict_graph", "sqrt_update_graph", "sqrt_nees_graph", "noise_factor", "factor_of",
           "covariance_of"]


def noise_factor(C: np.ndarray) -> np.ndarray:
    """The lower Cholesky factor of a noise covariance (zero columns for a zero variance:
    :func:`symmon.core.gaussian.matrix_sqrt`), as the step reads it."""
    return np.tril(matrix_sqrt(np.asarray(C, dtype=float)))


def factor_of(P: np.ndarray) -> np.ndarray:
    """The lower factors of P (n, n) or (R, n, n), as the compiled loop reads them: each
    transposed (the loop is column-major), C-contiguous."""
    P = np.asarray(P, dtype=float)
    S = noise_factor(P) if P.ndim == 2 else np.stack([noise_factor(p) for p in P])
    return np.ascontiguousarray(np.swapaxes(S, -1, -2))


def covariance_of(U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, S) from the factors the compiled loop wrote (..., n, n), each Sᵀ in C order:
    S lower triangular and P = S Sᵀ = Uᵀ U."""
    S = np.ascontiguousarray(np.swapaxes(U, -1, -2))
    return np.matmul(S, U), S


def _model_sqrt_moments(model: Model, m, A, transform: Transform, angles, p=None):
    if model.n_p:
        return sqrt_moments(compiled_with_params(model), m, A, transform, angles, p)
    return sqrt_moments(compiled(model), m, A, transform, angles)


def _columns(model: Model, transform: Transform, angles, x, S, noise_sqrt, p) -> tuple:
    """E g and the joint columns of [g; x] (the x rows only), the noise's columns included:
    the rule on [x; w] with blkdiag(S, √Q) for general noise, [Y₊, √Q] over [X₊, 0] for
    additive noise."""
    kind, n = type(x), x.shape[0]
    if model.n_v:
        mean, cols = _model_sqrt_moments(model, ca.vertcat(x, kind.zeros(model.n_v)), ca.diagcat(S, noise_sqrt),
                                         transform, angles, p)
        return mean, JointColumns(cols.Y, cols.W[:n, :], cols.Yn, None if cols.Wn is None else cols.Wn[:n, :])
    mean, cols = _model_sqrt_moments(model, x, S, transform, angles, p)
    k = noise_sqrt.shape[1]
    return mean, JointColumns(ca.horzcat(cols.Y, noise_sqrt), ca.horzcat(cols.W, kind.zeros(n, k)), cols.Yn, cols.Wn)


def sqrt_predict_graph(f: Model, transform: Transform, angle_states: frozenset[int], x, S, Q_sqrt, p=None,
                       joint: bool = False):
    """The time update in square-root form: (x⁻, S⁻), S⁻ = tria of the columns of f (and √Q),
    downdated by those of negative weight; with ``joint``, (x⁻, the joint columns of
    [x⁻; x]) instead (the smoother's, :func:`symmon.codegen.sqrtform.gain_factor`)."""
    mean, cols = _columns(f, transform, angle_states, x, S, Q_sqrt, p)
    x_pred = wrap_entries(mean, angle_states)
    if joint:
        return x_pred, cols
    return x_pred, downdate_all(tria(cols.Y), cols.Yn)


def _jacobian_x(h: Model, m, p):
    """J_x of h at the state m (the noise at 0, the parameters p): the iterated EKF's
    linearisation."""
    n, kind = m.shape[0], type(m)
    w = ca.vertcat(m, kind.zeros(h.n_v)) if h.n_v else m
    if h.n_p:
        return compiled_with_params(h).jac(ca.vertcat(w, p))[:, :n]
    return compiled(h).jac(w)[:, :n]


def sqrt_update_graph(h: Model, transform: Transform, angle_states: frozenset[int], x_pred, S_pred, y, R_sqrt,
                      mask=None, p=None, iterations: int = 1):
    """The measurement update in square-root form: (x⁺, S⁺, ν, S_y, log N(ν; 0, S), NIS), with
    S = S_y S_yᵀ the innovation covariance (module notes; the mask and the iterations as
    :func:`symmon.filters.gaussian.step.update_graph`)."""
    n_y = h.n_y
    y_angles = frozenset(h.angle_outputs)

    # I − D appended to S_y's columns: S_y S_yᵀ = D S D + (I − D).
    extra = None if mask is None else ca.diag(1 - mask)

    def columns(m):
        y_hat, cols = _columns(h, transform, y_angles, m, S_pred, R_sqrt, p)
        if mask is None:
            return y_hat, cols
        # D Y: the rows of the missing components zero.
        def rows(Z):
            return None if Z is None else Z * ca.repmat(mask, 1, Z.shape[1])

        return y_hat, JointColumns(rows(cols.Y), cols.W, rows(cols.Yn), cols.Wn)

    def masked(r):
        return r if mask is None else mask * r

    y_hat, cols = columns(x_pred)
    nu = masked(wrap_entries(y - y_hat, y_angles))
    Sy, Kbar, K = gain_factor(*cols, extra=extra)
    # A zero pivot: a zero row of S_y⁻¹, and log det S = −inf below.
    white = ca.mtimes(tril_inverse(Sy), nu)
    x_i = x_pred + ca.mtimes(Kbar, white)
    for _ in range(iterations - 1):
        y_hat_i, cols = columns(x_i)
        r_i = masked(wrap_entries(y - y_hat_i, y_angles) - ca.mtimes(_jacobian_x(h, x_i, p), x_pred - x_i))
        _, _, K = gain_factor(*cols, extra=extra)
        x_i = x_pred + ca.mtimes(K, r_i)
    S_new = residual_factor(cols.W, cols.Y, K, cols.Wn, cols.Yn)
    measured = n_y if mask is None else ca.sum1(mask)
    nis = ca.dot(white, white)
    log_det = 2 * ca.sum1(ca.log(ca.diag(Sy)))
    loglik = -0.5 * (nis + log_det + measured * math.log(2 * math.pi))
    return wrap_entries(x_i, angle_states), S_new, nu, Sy, loglik, nis


def sqrt_nees_graph(x, S, truth, angle_states):
    """(ε, t) of :func:`symmon.filters.gaussian.step.nees_graph` from the factor S: the correlation
    matrix's factor is diag(r) S (:func:`symmon.codegen.sqrtform.chol_scaled`), so no second
    factorisation."""
    e = wrap_entries(truth - x, angle_states)
    L, r = chol_scaled(S)
    inv = tril_inverse(L)
    z = ca.mtimes(inv, e * r)
    return ca.dot(z, z), ca.sumsqr(inv) / ca.mmin(ca.diag(L) > 0)
