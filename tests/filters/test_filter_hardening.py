"""Filter runs that used to end in an internal error or a silent wrong answer (issue 26, item 3).

(a) the adaptive filter after an early stop; (b) banks whose results exceed memory; (c)
NEES and NIS on a singular or underflowed covariance, and their scale invariance; (d) the
linear filter's overflow and singular S; (g) an angle state measured by an output not
declared an angle.  The fuzzing of the API is in test_filter_api_fuzz.py.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import AngleWarning, NonFiniteError, ResourceError, SingularMatrixError, SymmonError
from symmon.filters import inputs, results
from symmon.filters.gaussian.adaptive import _adaptive_run
from symmon.filters.inputs import MAX_BANK_NUMBERS
from symmon.filters.results import quadratic_forms

#: A quadratic form computed two ways (scaled and unscaled) in double precision.
FORM_RTOL = 1e-12


def line_filter(transform=None) -> sm.NonlinearKalmanFilter:
    x = sp.Symbol("x", real=True)
    m = sm.Model([x], [x], name="hard_line")
    return sm.NonlinearKalmanFilter(m, m, [[0.01]], [[0.01]], transform or sm.Adaptive())


# --------------------------------------------------------------------------- (a) adaptive early stop
def diverging_bank() -> tuple[np.ndarray, np.ndarray]:
    """Three runs; run 1's innovation overflows at step 0 (its measurement is 1.7e308 and its
    prior mean -1.7e308): its state is inf, and the adaptive filter stops there."""
    Y = np.ones((3, 40, 1))
    Y[1, 0, 0] = 1.7e308
    x0 = np.array([[4.0], [-1.7e308], [4.0]])
    return Y, x0


def test_adaptive_choices_after_an_early_stop_are_empty_not_garbage():
    """The choice array was np.empty: after the stop its entries were whatever memory held,
    and names[chosen] an IndexError whose index changed from run to run."""
    kf = line_filter()
    Y, x0 = diverging_bank()
    out, choices = _adaptive_run(kf.strategy, kf, Y, x0, np.array([[0.1]]))
    assert choices.shape == (3, 40)
    assert (choices[:, 0] != "").all() and (choices[:, 1:] == "").all()
    assert not np.isfinite(out["x"][1, 0]).all() and np.isnan(out["x"][:, 1:]).all()


def test_adaptive_filter_that_stops_early_names_the_run_and_step():
    Y, x0 = diverging_bank()
    with pytest.raises(SymmonError, match=r"Adaptive\(.*\): the filter produced NaN or inf at run 1, step 0"):
        line_filter().filter(Y, x0, [[0.1]])


# --------------------------------------------------------------------------- (b) memory
def huge_bank(runs: int, steps: int, n_y: int = 1) -> np.ndarray:
    """A bank of measurements that takes no memory (one number, broadcast)."""
    return np.broadcast_to(np.ones(n_y), (runs, steps, n_y))


@pytest.mark.parametrize("transform", [sm.TT1(), sm.Adaptive()], ids=["ekf", "adaptive"])
def test_results_beyond_the_limit_are_refused_before_any_work(transform):
    kf = line_filter(transform)
    ys = huge_bank(10**5, 10**5)  # 10^10 run-steps: 80 GB for x alone
    with pytest.raises(ResourceError, match=r"results: runs × steps × numbers per step = 100000 × 100000 × \d+ .* "
                                            r"exceeds the limit of 2e\+08 \(1\.5 GiB\): keep fewer arrays"):
        kf.filter(ys, sm.Gaussian([0.0], [[1.0]]))
    with pytest.raises(ResourceError, match="smoother results"):
        line_filter(sm.TT1()).smooth(ys, sm.Gaussian([0.0], [[1.0]]))


def test_the_bound_counts_the_arrays_kept(monkeypatch):
    """x and P with loglik are 1 + 1 + 1 numbers per step for n = 1; all arrays are 8
    (x, P, x_pred, P_pred, innovation, S, nis, loglik): a limit between the two separates them."""
    kf = line_filter(sm.TT1())
    ys = np.ones((10, 10, 1))
    monkeypatch.setattr(inputs, "MAX_BANK_NUMBERS", 100 * 5)
    assert kf.filter(ys, sm.Gaussian([0.0], [[1.0]]), keep=("x", "P")).x.shape == (10, 10, 1)
    with pytest.raises(ResourceError, match=r"10 × 10 × 8 = 800 numbers"):
        kf.filter(ys, sm.Gaussian([0.0], [[1.0]]))
    with pytest.raises(ResourceError, match=r"10 × 10 × 8 = 800 numbers"):  # the adaptive filter keeps all
        line_filter().filter(ys, sm.Gaussian([0.0], [[1.0]]), keep=("x",))


def test_linear_filter_and_its_simulation_are_bounded_too():
    kf = sm.KalmanFilter(np.eye(2), 0.1 * np.eye(2), np.eye(2), np.eye(2))
    with pytest.raises(ResourceError, match="KF results"):
        kf.filter(huge_bank(10**5, 10**5, 2), np.zeros(2), np.eye(2))
    with pytest.raises(ResourceError, match="KalmanFilter.simulate: .* simulate fewer runs or steps"):
        kf.simulate(10**9, np.zeros(2), np.random.default_rng(0), runs=1000)
    with pytest.raises(ResourceError, match="exceeds the limit"):  # a 400-digit count is formatted, not overflowed
        kf.simulate(10**400, np.zeros(2), np.random.default_rng(0))
    assert MAX_BANK_NUMBERS == 2 * 10**8


# --------------------------------------------------------------------------- (c) NEES / NIS
@pytest.mark.parametrize("scale", [1e-150, 1e-100, 1e-6, 1.0, 1e6, 1e100, 1e150])
def test_normalised_errors_are_the_same_in_any_units(scale):
    """(e/σ)ᵀ Ρ⁻¹ (e/σ) on the correlation matrix: a state in units `scale` times smaller
    (its standard deviation 1e-150 beside one of 1) gives the same NEES."""
    rng = np.random.default_rng(3)
    A = rng.standard_normal((5, 3, 3))
    C = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    e = rng.standard_normal((5, 3))
    s = np.array([scale, 1.0, 1.0 / scale])
    plain = np.einsum("ki,ki->k", e, np.linalg.solve(C, e[..., None])[..., 0])
    scaled = quadratic_forms(e * s, s[:, None] * C * s[None, :])
    np.testing.assert_allclose(scaled, plain, rtol=FORM_RTOL)


@pytest.mark.parametrize("variance, message", [
    (0.0, "has variance 0 in component 0"),
    (1e-200**2, "has variance 0 in component 0"),  # a standard deviation of 1e-200 underflows
    (1e-320, "has variance 1e-320 in component 0 .* below 2.23e-308"),  # subnormal: digits lost
    (np.nan, "holds NaN or inf"),
])
def test_nees_on_an_underflowed_variance_is_a_named_error(variance, message):
    P = np.array([np.diag([variance, 1.0])] * 3)
    res = results.KalmanResult(x=np.zeros((3, 2)), P=P, loglik=np.zeros(3))
    with pytest.raises(SymmonError, match=message):
        res.nees(np.ones((3, 2)))


def test_nees_on_a_singular_correlation_is_a_named_error():
    """Two components that are the same number (correlation 1): P is singular in any units,
    and np.linalg.solve did not always notice (rounding hides the zero pivot)."""
    P = np.array([[[1.0, 1.0], [1.0, 1.0 + 1e-16]]] * 2) * np.array([1e-3, 1e3])[:, None, None]
    res = results.KalmanResult(x=np.zeros((2, 2, 2)), P=np.broadcast_to(P, (2, 2, 2, 2)), loglik=np.zeros((2, 2)))
    with pytest.raises(SingularMatrixError, match=r"state covariance P at run 0, step 0 is singular \(smallest "
                                                  r"eigenvalue of its correlation matrix"):
        res.nees(np.ones((2, 2, 2)))


def test_nis_on_a_singular_s_is_a_named_error():
    res = results.KalmanResult(x=np.zeros((2, 1)), innovation=np.ones((2, 2)), S=np.array([np.ones((2, 2))] * 2),
                          loglik=np.zeros(2))
    with pytest.raises(SingularMatrixError, match="innovation covariance S at step 0 is singular"):
        res.nis()


def test_a_nees_that_overflows_is_refused():
    res = results.KalmanResult(x=np.zeros((1, 1)), P=np.array([[[1e-300]]]), loglik=np.zeros(1))
    with pytest.raises(NonFiniteError, match="overflows"):
        res.nees(np.array([[1e300]]))


# --------------------------------------------------------------------------- (d) the linear filter's numerics
def test_linear_filter_overflow_is_a_named_error_not_inf():
    kf = sm.KalmanFilter([[1e200]], [[1.0]], [[1.0]], [[1.0]])
    with pytest.raises(NonFiniteError, match="the predicted covariance overflows at step 0"):
        kf.filter(np.ones((3, 1)), [1.0], [[1.0]])
    with pytest.raises(NonFiniteError, match="KalmanFilter.simulate: the simulated state overflows at run 0, step 1"):
        kf.simulate(3, [1.0], np.random.default_rng(0), runs=2)
    # Huge measurements with sane covariances: the state itself overflows.
    with pytest.raises(NonFiniteError, match="KF: the filter produced NaN or inf at run 0, step 0"):
        sm.KalmanFilter([[1.0]], [[1.0]], [[1.0]], [[1.0]]).filter(np.full((2, 2, 1), 1.7e308), [-1.7e308], [[1.0]])


def test_linear_filter_with_s_singular_in_double_precision_is_a_named_error():
    """R is positive definite but 1e-17 of H P Hᵀ: S rounds to a singular matrix."""
    kf = sm.KalmanFilter(np.eye(2), np.zeros((2, 2)), np.ones((2, 2)), 1e-17 * np.eye(2))
    with pytest.raises(SingularMatrixError, match="innovation covariance S at step 0"):
        kf.filter(np.ones((2, 2)), np.zeros(2), np.eye(2))


# --------------------------------------------------------------------------- (g) undeclared angle outputs
th, om = sp.symbols("theta omega", real=True)
ROTATION = sm.Model([th, om], [th + 0.1 * om, om], angles=[0], name="hard_rotation")


@pytest.mark.parametrize("output, warned", [
    (th, True), (th + sp.Symbol("b0"), True), (2 * th, True), (th * sp.cos(th), True),
    (sp.sin(th), False), (sp.cos(2 * th), False), (om, False), (th + om, False),
])
def test_an_output_that_measures_an_angle_state_must_be_declared(output, warned):
    params = [p for p in output.free_symbols if str(p) == "b0"]
    h = sm.Model([th, om], [output], params=params or None, name="hard_direct")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sm.NonlinearKalmanFilter(ROTATION, h.with_params({"b0": 0.1}) if h.params else h,
                                 np.diag([1e-4, 1e-4]), [[0.01]], sm.UT.ut1())
    angle = [w for w in caught if issubclass(w.category, AngleWarning)]
    assert bool(angle) is warned
    if warned:
        assert "output 0" in str(angle[0].message) and "declare it with Model(..., angles=[0])" in str(angle[0].message)
        assert angle[0].filename == __file__  # it points at the caller's line


def test_the_undeclared_angle_makes_the_filter_inconsistent_and_declaring_it_fixes_it():
    """Why the warning: a rotating angle measured directly, true values crossing ±π."""
    from symmon.files.filterfile import simulate

    declared = sm.Model([th, om], [th], angles=[0], name="hard_direct_a")
    Q, R, x0 = np.diag([1e-4, 1e-4]), np.array([[0.01]]), sm.Gaussian([3.0, 0.5], np.diag([0.01, 0.01]))
    xs, ys = simulate(ROTATION, declared, Q, R, x0, 60, 40, seed=1)
    with pytest.warns(AngleWarning):
        bad = sm.NonlinearKalmanFilter(ROTATION, sm.Model([th, om], [th], name="hard_direct_u"), Q, R, sm.UT.ut1())
    good = sm.NonlinearKalmanFilter(ROTATION, declared, Q, R, sm.UT.ut1())
    a_bad, a_good = (float(np.mean(k.filter(ys, x0).anees(xs).value)) for k in (bad, good))
    assert a_bad > 100 and a_good < 4  # n = 2 for a consistent filter
