"""The smoother's gain through the Cholesky factor of the prediction (symmon.filters.gaussian.smoother).

G = C P⁻⁻¹ is computed as (C L⁻ᵀ) L⁻¹ with P⁻ = L Lᵀ (blocked factor and inverse, loops in
C) where it was a general solve; on linear dynamics the backward pass is the textbook RTS
recursion, here in NumPy (np.linalg.solve) on the compiled filter's output: the two agree
to rounding (1e-12 relative to the largest entry) for the SX graph (n = 4) and the MX graph
(n = 10, blocked), on a bank with missing components and a missing step.  A singular
prediction is still an error, not a number.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import SymmonError


def tracker(targets: int):
    """``targets`` constant-velocity targets (n = 4 per target, + 1 bias state each when
    more than one), range and bearing of each."""
    X, rows, h = [], [], []
    for i in range(targets):
        px, py, vx, vy = s = list(sp.symbols(f"px{i} py{i} vx{i} vy{i}", real=True))
        b = [sp.Symbol(f"b{i}", real=True)] if targets > 1 else []
        X += s + b
        rows.append(len(s + b))
        h += [sp.sqrt(px**2 + py**2) + (b[0] if b else 0), sp.atan2(py, px)]
    n = len(X)
    F, Q = np.eye(n), np.zeros((n, n))
    at = 0
    for m in rows:
        F[at, at + 2] = F[at + 1, at + 3] = 1.0
        Q[at:at + 4, at:at + 4] = 0.05 * np.kron([[1 / 3, 1 / 2], [1 / 2, 1.0]], np.eye(2))
        if m == 5:
            Q[at + 4, at + 4] = 1e-4
        at += m
    f = sm.Model(X, list(sp.Matrix(F) * sp.Matrix(X)), name=f"gain_f{n}")
    hm = sm.Model(X, h, angles=list(range(1, 2 * targets, 2)), name=f"gain_h{n}")
    x0 = np.concatenate([[20.0 + 10 * i, 5.0 + 3 * i, -1.0, 0.5] + ([0.5] if targets > 1 else [])
                         for i in range(targets)])
    P0 = np.diag(np.tile([1.0, 1.0, 0.1, 0.1] + ([0.25] if targets > 1 else []), targets))
    R = np.kron(np.eye(targets), np.diag([0.5**2, 0.02**2]))
    return f, hm, F, Q, R, x0, P0


def rts(F, Q, x, P):
    """The RTS backward recursion on filtered (K, n), (K, n, n), for linear dynamics."""
    xs, Ps = x.copy(), P.copy()
    for k in range(len(x) - 2, -1, -1):
        Pp = F @ P[k] @ F.T + Q
        G = np.linalg.solve(Pp, F @ P[k]).T
        xs[k] = x[k] + G @ (xs[k + 1] - F @ x[k])
        Ps[k] = P[k] + G @ (Ps[k + 1] - Pp) @ G.T
    return xs, Ps


@pytest.mark.parametrize("targets", [1, 2])
@pytest.mark.parametrize("transform", [sm.TT1(), sm.UT.ut1()], ids=["EKF", "UKF"])
def test_the_backward_pass_is_the_textbook_recursion(targets, transform):
    f, h, F, Q, R, x0, P0 = tracker(targets)
    rng = np.random.default_rng(11)
    K, runs = 25, 3
    truth = np.broadcast_to(x0, (runs, len(x0))).copy()
    ys = np.empty((runs, K, h.n_y))
    for k in range(K):
        truth = truth @ F.T
        for r in range(runs):
            ys[r, k] = np.array([float(e) for e in sp.Matrix(h.outputs).subs(dict(zip(h.inputs, truth[r])))])
    ys += rng.standard_normal(ys.shape) * np.sqrt(np.diag(R))
    ys[0, 4, 0] = np.nan
    ys[2, 9] = np.nan
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, transform)
    res = kf.smooth(ys, x0, P0)
    for r in range(runs):
        xs, Ps = rts(F, Q, res.filtered.x[r], res.filtered.P[r])
        np.testing.assert_allclose(res.x[r], xs, rtol=0, atol=1e-12 * np.max(np.abs(xs)))
        np.testing.assert_allclose(res.P[r], Ps, rtol=0, atol=1e-12 * np.max(np.abs(Ps)))


def test_a_singular_prediction_is_still_an_error():
    f, h, _, _, R, x0, _ = tracker(1)
    for transform in (sm.TT1(), sm.UT.ut1()):
        kf = sm.NonlinearKalmanFilter(f, h, np.zeros((4, 4)), R, transform)
        ys = np.array([[20.0, 0.3], [20.5, 0.31], [21.0, 0.32]])
        with pytest.raises(SymmonError, match="smoother: NaN or inf at step 1"):
            kf.smooth(ys, x0, np.diag([1.0, 1.0, 0.0, 0.0]))
