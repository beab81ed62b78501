"""The continuous-discrete filters against cd-dynamax on its own models (stored references).

tests/reference/cd_dynamax.json was made by tests/reference/make_cd_dynamax_reference.py
(cd-dynamax with JAX and diffrax, the ``bench`` extra; the test suite does not need them):

- the linear model of cd-dynamax's ``test_cdnlgssm_filter_linear_TRegular.py`` (2 states,
  6 emissions) at 30 irregular times, through its continuous-discrete Kalman filter, CD-EKF
  and CD-UKF (α = √3, β = 2, κ = 1);
- its Van der Pol drift (μ = 1, x₁ measured) at 25 irregular times, through its CD-EKF and
  CD-UKF.

cd-dynamax conditions on the first emission before its first prediction, so symmon starts
from cd-dynamax's first filtered state at t_1 (``t0=times[0]``) and the first emission's
log-likelihood term is left out of cd-dynamax's total.

Tolerance.  Both sides integrate the same moment ODEs by adaptive Runge–Kutta 4(5)
(diffrax's Dopri5 there, scipy's RK45 here) to rtol 1e-10 and atol 1e-12 per interval, and
apply the same update.  Their controllers choose other steps, so each interval's moments
differ by their local errors, and the filter carries the differences across up to 29
intervals.  Measured: the means agree to 6e-10 and the covariances to 1.1e-8 (relative to
their largest entry), the log-likelihoods to 1.2e-9.  RTOL = 1e-6 leaves a margin of ~100
over the covariances; a wrong rule, weight, Q_c or interval moves the numbers by far more
(Q_c off by 1 %: the Van der Pol CD-UKF's means by 3.6e-4; the CD-EKF against cd-dynamax's
CD-UKF: 3e-2).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.stats
import sympy as sp

import symmon as sm
from helpers import REFERENCE_DIR, assert_close_to_scale

REF = json.loads((REFERENCE_DIR / "cd_dynamax.json").read_text())
RTOL = 1e-6
#: cd-dynamax's UKF defaults (UKFHyperParams: α = √3, β = 2, κ = 1).
UKF = sm.UT(float(np.sqrt(3.0)), 2.0, 1.0)
X1, X2 = sp.symbols("x1 x2", real=True)


def _sde(case: str, qc_scale: float = 1.0) -> tuple[sm.SDE, sm.Model]:
    d = REF[case]
    Qc = (qc_scale * np.array(d["Qc"])).tolist()
    if case == "linear":
        A = np.array(d["A"])
        drift = [sum(float(A[i, j]) * s for j, s in enumerate((X1, X2))) for i in range(2)]
        L = d["L"]
    else:
        mu = d["mu"]
        drift = [X2, mu * (1 - X1**2) * X2 - X1]
        L = np.eye(2).tolist()
    H = np.array(d["H"])
    h = sm.Model([X1, X2], [float(H[i, 0]) * X1 + float(H[i, 1]) * X2 for i in range(H.shape[0])], name=f"{case} h")
    return sm.SDE([X1, X2], drift, diffusion=L, spectral_density=Qc, name=case), h


def _run(case: str, name: str, transform, qc_scale: float = 1.0):
    d = REF[case]
    ref = d[name]
    sde, h = _sde(case, qc_scale)
    cd = sm.ContinuousDiscreteKalmanFilter(sde, h, d["R"], transform, rtol=REF["rtol"], atol=REF["atol"])
    m, P = np.array(ref["means"]), np.array(ref["covariances"])
    times, ys = np.array(d["times"]), np.array(d["emissions"])
    res = cd.filter(ys[1:], m[0], P[0], times=times[1:], t0=times[0])
    return res, ref, m, P


def _first_term(case: str) -> float:
    """The log-likelihood of the first emission under the prior (no prediction before it)."""
    d = REF[case]
    H, m0, P0 = np.array(d["H"]), np.array(d["m0"]), np.array(d["P0"])
    y0 = np.array(d["emissions"][0])
    return float(scipy.stats.multivariate_normal(H @ m0, H @ P0 @ H.T + np.array(d["R"])).logpdf(y0))


@pytest.mark.parametrize("case, name, transform", [
    ("linear", "kf", "ekf"),   # the CD Kalman filter: the EKF of a linear SDE
    ("linear", "ekf", "ekf"),
    ("linear", "ukf", UKF),
    ("vanderpol", "ekf", "ekf"),
    ("vanderpol", "ukf", UKF),
])
def test_continuous_discrete_filters_equal_cd_dynamax(case, name, transform):
    res, ref, m, P = _run(case, name, transform)
    assert_close_to_scale(res.x, m[1:], RTOL)
    assert_close_to_scale(res.P, P[1:], RTOL)
    assert res.log_likelihood == pytest.approx(ref["marginal_loglik"] - _first_term(case), rel=RTOL)


def test_the_comparison_sees_a_wrong_spectral_density():
    """The tolerance is not loose: Q_c off by 1 % moves the Van der Pol CD-UKF's means far
    beyond it."""
    res, _, m, _ = _run("vanderpol", "ukf", UKF, qc_scale=1.01)
    with pytest.raises(AssertionError):
        assert_close_to_scale(res.x, m[1:], RTOL)
