"""sm.advise: the error of each candidate transform against a reference, and the choice."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.measures.advice import CANDIDATES, DEFAULT_TOL, MAX_REFERENCE_NODES, _explicit, moment_error
from symmon.errors import SymmonError

#: The unitless error of an exact transform is rounding only.
EXACT_ATOL = 1e-12
#: Invariance of the unitless error under a change of units: rounding of the rescaling.
INVARIANCE_RTOL = 1e-10
#: An identity between two quadrature results that are both exact (degree ≤ 4): rounding.
IDENTITY_RTOL = 1e-9

x, y = sp.symbols("x y", real=True)


def test_affine_model_chooses_tt1():
    a = sm.advise(sm.Model([x, y], [3 * x - y + 1, x + 2 * y]), sm.Gaussian([1.0, -2.0], [[0.5, 0.1], [0.1, 2.0]]))
    assert a.choice_name == "TT1" and isinstance(a.choice, sm.TT1)
    assert a.reference == "Gauss-Hermite 7" and a.reference_error < EXACT_ATOL
    by = {r["name"]: r for r in a.rows}
    assert by["TT1"]["error"] < EXACT_ATOL and by["TT1"]["within_tol"]


def test_quadratic_model_chooses_tt2_which_is_exact():
    a = sm.advise(sm.Model([x], [x**2]), sm.Gaussian([1.0], [[0.3]]))
    by = {r["name"]: r for r in a.rows}
    assert by["TT2"]["error"] < EXACT_ATOL
    assert not by["TT1"]["within_tol"]  # TT1 misses ½ tr(H P) in the mean
    assert a.choice_name == "TT2"


def test_strongly_nonlinear_case_rejects_the_taylor_transforms():
    """Polar example at α = 1 (Figure 1): the MoN is large and TT1, TT2 fail."""
    p = sm.problems.polar(1.0, "rad")
    a = sm.advise(p.model, p.u, tol=1e-2, samples=200_000)
    by = {r["name"]: r for r in a.rows}
    assert a.reference_mon > 0.5
    assert not by["TT1"]["within_tol"] and not by["TT2"]["within_tol"]
    assert a.choice_name not in ("TT1", "TT2")
    assert "Monte Carlo" in a.reference  # Gauss-Hermite 7 does not converge here
    assert any("did not converge" in n for n in a.notes)


def test_error_is_unitless():
    p = sm.problems.gmti(1.0)
    ref = sm.propagate(p.model, p.u, transform=sm.GaussHermite(7))
    m = sm.propagate(p.model, p.u, transform=sm.TT2())
    S = np.diag([1e3, np.pi / 180, 3.6])  # km → m, rad → deg-ish, m/s → km/h scalings
    scaled = sm.Model(p.model.inputs, [s * g for s, g in zip(np.diag(S), p.model.outputs)])
    ref_s = sm.propagate(scaled, p.u, transform=sm.GaussHermite(7))
    m_s = sm.propagate(scaled, p.u, transform=sm.TT2())
    assert moment_error(m_s, ref_s) == pytest.approx(moment_error(m, ref), rel=INVARIANCE_RTOL)


def test_table_and_print():
    a = sm.advise(sm.Model([x], [sp.sin(x)]), sm.Gaussian([0.3], [[0.01]]))
    text = str(a)
    assert "choice:" in text and "<- choice" in a.table
    assert len(a.table.splitlines()) == len(CANDIDATES) + 1
    assert repr(a).startswith("Advice(choice=")


def test_the_one_mon_is_the_reference_s():
    """The table has no MoN per candidate (TT1's own is 0 by construction): the printed MoN
    is the reference's; each row keeps its own estimate under ``mon`` (the old field)."""
    a = sm.advise(sm.Model([x], [sp.sin(x)]), sm.Gaussian([0.3], [[0.01]]))
    assert "MoN" not in a.table.splitlines()[0]
    ref = sm.nonlinearity(sm.Model([x], [sp.sin(x)]), sm.Gaussian([0.3], [[0.01]]), transform=sm.GaussHermite(7))
    assert a.reference_mon == pytest.approx(ref.value, rel=EXACT_ATOL)
    assert f"by the reference: {a.reference_mon:.4f}" in str(a)
    assert a.reference_mon_stderr is None  # a quadrature reference has no standard error
    by = {r["name"]: r for r in a.rows}
    assert by["TT1"]["mon"] == 0.0 and by["TT2"]["mon"] > 0


def test_monte_carlo_reference_reports_the_standard_error_of_its_mon():
    p = sm.problems.polar(1.0, "rad")
    a = sm.advise(p.model, p.u, samples=200_000, candidates=[("TT1", sm.TT1())])
    assert "Monte Carlo" in a.reference and a.reference_mon_stderr > 0
    assert "(2 SE)" in str(a)


def test_first_call_and_warm_times_are_reported_apart():
    """Both times are in each row and in the table; ``seconds`` is the warm time. Only their
    presence is tested: no test asserts a timing."""
    a = sm.advise(sm.Model([x], [sp.exp(x)]), sm.Gaussian([0.0], [[0.1]]))
    header = a.table.splitlines()[0]
    assert "first call" in header and "warm" in header
    for r in a.rows:
        assert np.isfinite(r["first_call"]) and np.isfinite(r["warm"]) and r["seconds"] == r["warm"]


def test_tt1_error_on_a_quadratic_is_the_mon_over_root_two():
    """For g = a u + b u², u ~ N(m, σ²), TT1 misses the mean by b σ², which is M/√2 standard
    deviations of y, with M the W^full MoN (43), and its variance by M² relative: the link of
    the tolerance to the MoN (docs/guide/advise.md). Gauss–Hermite 7 is exact here."""
    a = sm.advise(sm.Model([x], [2 * x + 0.3 * x**2]), sm.Gaussian([0.5], [[0.4]]))
    tt1 = next(r for r in a.rows if r["name"] == "TT1")
    assert tt1["error"] == pytest.approx(a.reference_mon / np.sqrt(2), rel=IDENTITY_RTOL)


def test_one_default_tolerance_for_advise_and_the_adaptive_filter():
    """One constant (the CLI's defaults: tests/cli/test_cli.py)."""
    assert sm.Adaptive().tol == DEFAULT_TOL == 0.01
    assert sm.advise(sm.Model([x], [x]), sm.Gaussian([0.0], [[1.0]])).tol == DEFAULT_TOL


@pytest.mark.parametrize("n_w, sparse", [(4, False), (6, False), (12, True)])
def test_gauss_hermite_candidates_run_on_an_explicit_grid(n_w, sparse):
    """GaussHermite(3) with ``sparse=None`` becomes the tensor grid while 3**n_w nodes are
    affordable and the sparse grid beyond, named so (and without the fallback's warning)."""
    name, t = _explicit("Gauss-Hermite 3", sm.GaussHermite(3), n_w)
    assert t.sparse is sparse and (3**n_w > MAX_REFERENCE_NODES) is sparse
    assert name == "Gauss-Hermite 3" + (" (sparse)" if sparse else "")
    assert _explicit("TT1", sm.TT1(), n_w) == ("TT1", sm.TT1())


@pytest.mark.parametrize("tol", [0, 1, -1e-3, "0.1", True])
def test_bad_tol(tol):
    with pytest.raises(SymmonError, match="tol"):
        sm.advise(sm.Model([x], [x]), sm.Gaussian([0.0], [[1.0]]), tol=tol)


def test_bad_model():
    with pytest.raises(TypeError, match="symmon.Model"):
        sm.advise("x**2", sm.Gaussian([0.0], [[1.0]]))


def test_candidates_by_name_transform_or_pair():
    """Issue 47, item 9: ``candidates=["ut1"]`` ended in an AttributeError (or a failed
    unpacking); a registered name (the CLI's), a Transform and a (name, Transform) pair are
    all candidates, named in the table by the name, the repr and the given name."""
    a = sm.advise(sm.Model([x, y], [x * y]), sm.Gaussian([1.0, 2.0], [[0.5, 0.1], [0.1, 1.0]]),
                  candidates=["ut1", "gh5", sm.TT2(), ("cubature", sm.UT.cubature())])
    assert [r["name"] for r in a.rows] == ["ut1", "gh5", "TT2()", "cubature"]
    assert [r["transform"] for r in a.rows] == [sm.UT.ut1(), sm.GaussHermite(5, sparse=False), sm.TT2(), sm.UT.cubature()]
    assert a.choice_name == "TT2()" and a.choice == sm.TT2()     # exact on x y, the cheapest


def test_unknown_candidate_name_lists_the_names():
    from symmon.transforms.registry import names

    with pytest.raises(SymmonError, match=r"candidates\[1\]: unknown transform name 'ukf'") as info:
        sm.advise(sm.Model([x], [x**2]), sm.Gaussian([1.0], [[0.3]]), candidates=["tt1", "ukf"])
    assert all(name in str(info.value) for name in names())


@pytest.mark.parametrize("bad", [3, ("TT1",), ("TT1", "tt1"), None])
def test_bad_candidate(bad):
    with pytest.raises(TypeError, match=r"candidates\[0\] must be a transform name"):
        sm.advise(sm.Model([x], [x**2]), sm.Gaussian([1.0], [[0.3]]), candidates=[bad])


# --------------------------------------------------------------------------- advise and Adaptive
# A constant-velocity target seen by a range–bearing sensor at the origin. The filter adds R
# to Cov h; advise sees the same noise as noise symbols, so that Cov y = Cov h + R is the
# innovation covariance S by which Adaptive measures its errors too.
PX, PY, VX, VY, ER, EB = sp.symbols("px py vx vy e_r e_b", real=True)
STATES = [PX, PY, VX, VY]
CV = sm.Model(STATES, [PX + VX, PY + VY, VX, VY], name="advise_cv")
RB = sm.Model(STATES, [sp.sqrt(PX**2 + PY**2), sp.atan2(PY, PX)], angles=[1], name="advise_rb")
RB_NOISY = sm.Model(STATES, [sp.sqrt(PX**2 + PY**2) + ER, sp.atan2(PY, PX) + EB], noise=[ER, EB], angles=[1],
                    name="advise_rb_noisy")
Q_CV, R_RB = 0.01 * np.eye(4), np.diag([0.25, 1e-4])
#: Adaptive's own candidates, named by their filter labels (EKF, EKF2, CKF, GHKF).
ADAPTIVE = [(t.filter_label(), t) for t in sm.Adaptive().candidates]


def rb_measurements(x0: sm.Gaussian, steps: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x, ys = rng.multivariate_normal(x0.mean, x0.cov), []
    for _ in range(steps):
        x = np.array([x[0] + x[2], x[1] + x[3], x[2], x[3]]) + rng.multivariate_normal(np.zeros(4), Q_CV)
        ys.append([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])] + rng.multivariate_normal(np.zeros(2), R_RB))
    return np.array(ys)


def advice_at(res, k: int) -> sm.Advice:
    """advise on the prior N(x⁻, P⁻) of step k, which Adaptive's measurement update decided on
    (the dynamics are linear, so the measurement update makes the step's choice)."""
    prior = sm.Gaussian(res.x_pred[k], res.P_pred[k])
    return sm.advise(RB_NOISY, prior, sm.Gaussian([0.0, 0.0], R_RB), candidates=ADAPTIVE)


def test_advise_agrees_with_adaptive_where_the_ekf_suffices():
    """A target 20 m away with 1 m of position uncertainty (the README's tracker): Adaptive
    uses the EKF at most steps, and at every step advise says TT1 exactly where Adaptive
    used the EKF, with the same tolerance. (At the first, widest prior both leave the EKF,
    for rules that may differ: advise integrates over the noise as inputs, where the CKF's
    points spread by √6 instead of √4.)"""
    x0 = sm.Gaussian([20.0, 5.0, -1.0, 0.5], np.diag([1.0, 1.0, 0.1, 0.1]))
    ys = rb_measurements(x0, steps=12, seed=0)
    res = sm.NonlinearKalmanFilter(CV, RB, Q_CV, R_RB, sm.Adaptive()).filter(ys, x0)
    assert np.mean(res.choices == "EKF") > 0.5
    for k, chosen in enumerate(res.choices):
        a = advice_at(res, k)
        assert (a.choice_name == "EKF") == (chosen == "EKF"), (k, chosen, str(a))


@pytest.mark.parametrize("mean, sd", [([20.0, 0.0, 0.0, 0.0], 3.0), ([50.0, 0.0, 0.0, 0.0], 8.0)])
def test_advise_agrees_with_adaptive_on_a_strongly_nonlinear_prior(mean, sd):
    """A position uncertainty of 15 % of the range: the MoN is above 0.1, neither Taylor
    rule is within tol, and both pick Gauss–Hermite 3 (the tensor grid, which on additive
    noise gives exactly the filter's moments)."""
    x0 = sm.Gaussian(mean, np.diag([sd**2, sd**2, 0.1, 0.1]))
    res = sm.NonlinearKalmanFilter(CV, RB, Q_CV, R_RB, sm.Adaptive()).filter([[mean[0], 0.0]], x0)
    a = advice_at(res, 0)
    assert a.reference_mon > 0.1
    by = {r["name"]: r for r in a.rows}
    assert not by["EKF"]["within_tol"] and not by["EKF2"]["within_tol"]
    assert res.choices[0] == a.choice_name == "GHKF(order=3)"
