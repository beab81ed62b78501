"""One public API (issue 14, item 8): one default transform, one argument order,
``propagate_many`` mirroring ``propagate``, typed results."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ModelError, ShapeError, SymmonError
from symmon.compile import compiled
from symmon.measures.sweep import sweep_alpha, sweep_states
from symmon.transforms.registry import DEFAULT, default_transform, make

# Batched and one-at-a-time evaluations of the same formula differ only in the order of
# BLAS sums: rounding, relative to the largest entry.
BATCH_RTOL = 1e-12
EXACT_TOL = 1e-10

x, y, e = sp.symbols("x y e", real=True)
PLAIN = sm.Model([x, y], [x * y + sp.sin(x), y**2], name="api_plain")
NOISY = sm.Model([x, y], [x * sp.exp(e) + y, y * e], noise=[e], name="api_noisy")
US = [sm.Gaussian([0.3, -1.0], [[0.4, 0.1], [0.1, 0.2]]), sm.Gaussian([1.0, 2.0], [[0.1, 0.0], [0.0, 0.3]]),
      sm.Gaussian([-0.5, 0.5], [[1.0, -0.3], [-0.3, 0.5]])]
VS = [sm.Gaussian([0.0], [[0.05]]), sm.Gaussian([0.1], [[0.2]]), sm.Gaussian([-0.2], [[0.01]])]


def _close(a, b, what=""):
    a, b = np.asarray(a), np.asarray(b)
    np.testing.assert_allclose(a, b, rtol=0, atol=BATCH_RTOL * max(np.abs(b).max(), 1.0), err_msg=what)


# --------------------------------------------------------------------------- one default
def test_the_default_transform_is_tt2_everywhere():
    assert DEFAULT == "tt2" and default_transform() == sm.TT2() == make("tt2")
    u = US[0]
    assert sm.propagate(PLAIN, u).transform == sm.TT2()
    assert sm.nonlinearity(PLAIN, u).transform == sm.TT2()
    assert sweep_alpha(PLAIN, u, [1.0]).transform == sm.TT2()
    assert sweep_states(PLAIN, US).transform == sm.TT2()
    by_default = sm.propagate_many(PLAIN, US)
    by_name = sm.propagate_many(PLAIN, US, transform=sm.TT2())
    np.testing.assert_array_equal(by_default.cov, by_name.cov)
    assert sm.nonlinearity(PLAIN, u).value == sm.nonlinearity(PLAIN, u, transform=sm.TT2()).value


# --------------------------------------------------------------------------- one argument order
@pytest.mark.parametrize("call", [
    lambda: sm.propagate(PLAIN, US[0], None, sm.TT2()),
    lambda: sm.propagate_many(PLAIN, US, None, sm.TT2()),
    lambda: sm.nonlinearity(PLAIN, US[0], None, "full"),
    lambda: sm.compare(PLAIN, US[0], None, "full"),
    lambda: sweep_alpha(PLAIN, US[0], [1.0], None, "full"),
    lambda: sweep_states(PLAIN, US, None, "full"),
], ids=["propagate", "propagate_many", "nonlinearity", "compare", "sweep_alpha", "sweep_states"])
def test_options_after_the_noise_are_keywords(call):
    """(model, inputs, v) positionally, then weight, transform and executor by name: a
    transform passed where v goes is a clear TypeError, not a noise Gaussian."""
    with pytest.raises(TypeError, match="positional"):
        call()


# --------------------------------------------------------------------------- propagate_many
@pytest.mark.parametrize("transform", [sm.TT2(), sm.UT.ut1(), sm.GaussHermite(3)], ids=repr)
def test_propagate_many_equals_propagate_per_gaussian(transform):
    b = sm.propagate_many(PLAIN, US, transform=transform)
    arrays = sm.propagate_many(PLAIN, (np.array([u.mean for u in US]), np.array([u.cov for u in US])),
                               transform=transform)
    for k, u in enumerate(US):
        m = sm.propagate(PLAIN, u, transform=transform)
        for name in ("mean", "cov", "cross_cov", "input_cov"):
            _close(getattr(b, name)[k], getattr(m, name), f"{name}[{k}]")
            _close(getattr(arrays, name)[k], getattr(m, name), f"{name}[{k}] from arrays")
    assert b.noise_cross_cov.shape == (3, 2, 0)


@pytest.mark.parametrize("per_input", [False, True], ids=["one v", "a v per input"])
def test_propagate_many_takes_the_noise_like_propagate(per_input):
    v = VS if per_input else VS[0]
    b = sm.propagate_many(NOISY, US, v, transform=sm.UT.ut1())
    assert b.cross_cov.shape == (3, 2, 2) and b.noise_cross_cov.shape == (3, 2, 1)
    for k, u in enumerate(US):
        m = sm.propagate(NOISY, u, VS[k] if per_input else VS[0], transform=sm.UT.ut1())
        for name in ("mean", "cov", "cross_cov", "noise_cross_cov", "input_cov"):
            _close(getattr(b, name)[k], getattr(m, name), f"{name}[{k}]")


def test_propagate_many_monte_carlo_splits_its_error_bars_like_propagate():
    mc = sm.MonteCarlo(4_000, seed=3, groups=4)
    b = sm.propagate_many(NOISY, US[:1], VS[0], transform=mc)
    m = sm.propagate(NOISY, US[0], VS[0], transform=mc)
    for name in ("mean", "cov", "cross_cov"):
        _close(b.stderr[name][0], m.stderr[name], name)
    assert b.input_cov.shape == (1, 2, 2)


@pytest.mark.parametrize("u, v, err, match", [
    (US[0], None, TypeError, "one Gaussian: use propagate"),
    ([], None, ShapeError, "at least one"),
    ("means", None, TypeError, "list of K Gaussians"),
    ([US[0], sm.Gaussian([0.0], [[1.0]])], None, ShapeError, r"u\[1\] has dimension 1"),
    (US, VS[:2], TypeError, "list of 3 Gaussians"),
    (US, [sm.Gaussian([0.0, 0.0], np.eye(2))] * 3, ShapeError, r"v\[0\] has dimension 2"),
])
def test_propagate_many_bad_batches(u, v, err, match):
    with pytest.raises(err, match=match):
        sm.propagate_many(NOISY, u, v if v is not None else VS[0])


def test_propagate_many_refuses_noise_for_a_noise_free_model():
    with pytest.raises(ModelError, match="no noise"):
        sm.propagate_many(PLAIN, US, VS[0])


def test_moments_split_once():
    b = sm.propagate_many(NOISY, US, VS[0])
    with pytest.raises(ValueError, match="already split"):
        b.split(2)


def test_sweep_states_takes_gaussians_or_arrays():
    a = sweep_states(PLAIN, US, transform=sm.UT.ut1())
    b = sweep_states(PLAIN, (np.array([u.mean for u in US]), np.array([u.cov for u in US])), transform=sm.UT.ut1())
    np.testing.assert_array_equal(a.squared, b.squared)
    np.testing.assert_array_equal(a.param, [0.0, 1.0, 2.0])
    for k, u in enumerate(US):
        assert a.squared[k] == pytest.approx(sm.nonlinearity(PLAIN, u, transform=sm.UT.ut1()).squared,
                                             rel=BATCH_RTOL, abs=BATCH_RTOL)


# --------------------------------------------------------------------------- typed results
def test_mon_from_moments_is_the_measure_without_its_context():
    res = sm.nonlinearity(PLAIN, US[2], weight="diag", transform=sm.GaussHermite(4))
    m = res.moments
    parts = sm.mon_from_moments(m.cov, m.cross_cov, m.input_cov, "diag", None, m.mean)
    assert isinstance(parts, sm.MonParts) and isinstance(res, sm.MonParts)
    assert (parts.squared, parts.J_Ab, parts.J_n, parts.weight_name) == (res.squared, res.J_Ab, res.J_n, "diag")
    np.testing.assert_array_equal(parts.residual_cov, res.residual_cov)
    assert float(parts) == parts.value == pytest.approx(np.sqrt(parts.squared), rel=EXACT_TOL)
    assert repr(parts).startswith("MonParts(") and "diag" in repr(parts)


def test_a_negative_squared_mon_has_value_zero():
    parts = sm.mon_from_moments([[1.0]], [[1.0]], [[1.0 + 1e-9]], "liu-li-raw")  # M² = 1 − 1/(1 + 1e-9) > 0
    assert parts.value > 0
    neg = sm.mon_from_moments([[1.0]], [[1.0]], [[1.0 - 1e-9]], "liu-li-raw")  # M² < 0: Monte Carlo-like noise
    assert neg.squared < 0 and neg.value == 0.0


def test_quadrature_error_is_propagate_with_the_two_order_estimate():
    u, v = US[0], VS[1]
    q = sm.quadrature_error(NOISY, u, v, order=3)
    p = sm.propagate(NOISY, u, v, transform=sm.GaussHermite(3, error_estimate=True))
    assert isinstance(q, sm.JointMoments) and q.transform == p.transform
    for name in ("mean", "cov", "cross_cov"):
        np.testing.assert_array_equal(q.error[name], p.error[name])
    assert q.error["cross_cov"].shape == q.cross_cov.shape == (2, 2)
    assert sm.propagate(NOISY, u, v, transform=sm.GaussHermite(3)).error is None


def test_batched_moments_print_their_shape_not_their_arrays():
    b = sm.propagate_many(NOISY, US, VS[0], transform=sm.MonteCarlo(4_000, seed=1, groups=4))
    assert repr(b) == "Moments(K=3, n_y=2, n_u=2, n_v=1, evaluations=12000, with stderr)"
    raw = sm.TT2().moments(compiled(PLAIN), US[0].mean[None], US[0].cov[None])
    assert repr(raw) == "Moments(K=1, n_y=2, n_w=2, evaluations=1)"


# --------------------------------------------------------------------------- fuzzing the batch
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

FUZZ = dict(derandomize=True, database=None, deadline=None, max_examples=150,
            suppress_health_check=[HealthCheck.too_slow])
ODD = st.one_of(st.floats(-1e3, 1e3), st.sampled_from([np.nan, np.inf, -np.inf, 0.0, 1e300, -1e-300]))


@st.composite
def batches(draw):
    """(means, covs) pairs near and off the valid ones: wrong shapes, odd numbers,
    asymmetric or indefinite covariances, or lists of Gaussians of mixed dimension."""
    K = draw(st.integers(0, 3))
    n = draw(st.sampled_from([2, 2, 2, 1, 3]))
    kind = draw(st.sampled_from(["arrays", "gaussians"]))
    if kind == "gaussians":
        out = []
        for _ in range(K):
            d = draw(st.sampled_from([2, 2, 1]))
            A = draw(hnp.arrays(float, (d, d), elements=st.floats(-2, 2)))
            out.append(sm.Gaussian(draw(hnp.arrays(float, d, elements=st.floats(-5, 5))), A @ A.T + np.eye(d)))
        return out
    means = draw(hnp.arrays(float, (K, n), elements=ODD))
    A = draw(hnp.arrays(float, (K, n, n), elements=ODD))
    with np.errstate(all="ignore"):  # inf · 0 in the product: a NaN entry, one of the bad inputs
        covs = A @ np.swapaxes(A, 1, 2) if draw(st.booleans()) else A  # PSD, or anything
    return (means, covs)


@settings(**FUZZ)
@given(u=batches(), noise=st.sampled_from([None, "one", "per input", "wrong"]))
def test_propagate_many_refuses_a_bad_batch_clearly_or_returns_finite_moments(u, noise):
    model = NOISY if noise is not None else PLAIN
    K = len(u) if isinstance(u, list) else len(u[0])
    v = {None: None, "one": VS[0], "per input": [VS[0]] * K, "wrong": [VS[0]] * (K + 1)}[noise]
    try:
        b = sm.propagate_many(model, u, v, transform=sm.UT.ut1())
    except (SymmonError, TypeError):
        return  # a named fault: a shape, a covariance, a non-finite number, a missing noise
    assert b.mean.shape == (K, 2) and b.cov.shape == (K, 2, 2) and b.cross_cov.shape == (K, 2, 2)
    assert np.isfinite(b.mean).all() and np.isfinite(b.cov).all() and np.isfinite(b.cross_cov).all()


def test_estimators_and_filters_default_to_the_ukf_rule():
    """The moments default to TT2; the estimators and the filters keep the UKF's UT.ut1()."""
    est = sm.estimation
    lin, sq = sm.Model([x], [2 * x], name="api_lin"), sm.Model([x], [sp.sin(x) + x**2], name="api_sq")  # UT ≠ TT2 here
    prior, y1 = sm.Gaussian([0.5], [[0.4]]), sm.Gaussian([1.0], [[0.3]])
    ut = sm.UT.ut1()
    assert est.direct(sq, [y1]).fused == est.direct(sq, [y1], transform=ut).fused
    assert est.indirect(sq, prior, [[1.0]], noise=[[0.3]]).posterior == \
        est.indirect(sq, prior, [[1.0]], noise=[[0.3]], transform=ut).posterior
    assert est.predict(sq, prior, [[0.1]]) == est.predict(sq, prior, [[0.1]], transform=ut)
    assert est.update(sq, prior, [1.0], [[0.3]]) == est.update(sq, prior, [1.0], [[0.3]], transform=ut)
    assert est.predict(sq, prior, [[0.1]]) != est.predict(sq, prior, [[0.1]], transform=sm.TT2())
    assert sm.NonlinearKalmanFilter(lin, sq, [[0.1]], [[0.3]]).method == "UKF(alpha=1.0, beta=0.0, kappa=None)"


# --------------------------------------------------------------------------- transforms by name
def test_a_transform_can_be_named_wherever_one_is_given(tmp_path):
    """The command line's names work in Python too: the same rule as the instance, bit for bit."""
    x, y = sp.symbols("x y", real=True)
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="named_polar")
    u = sm.Gaussian([1.0, 10.0], np.diag([0.17, 17.0]))
    for name, rule in (("ut1", sm.UT.ut1()), ("tt1", sm.TT1()), ("gh5", sm.GaussHermite(5)), ("ct", sm.UT.cubature())):
        np.testing.assert_array_equal(sm.propagate(polar, u, transform=name).cov, sm.propagate(polar, u, transform=rule).cov)
    assert float(sm.nonlinearity(polar, u, transform="GH3")) == float(sm.nonlinearity(polar, u, transform=sm.GaussHermite(3)))
    m = sm.propagate_many(polar, [u, u], transform="tt2")
    np.testing.assert_array_equal(m.mean[0], sm.propagate(polar, u, transform=sm.TT2()).mean)
    assert sm.NonlinearKalmanFilter(polar.with_angles([]), polar, np.eye(2), np.eye(2), "ut1").method == \
        sm.UT.ut1().filter_label()
    assert sm.Adaptive(candidates=("tt1", "ct"), reference="gh5").candidates == (sm.TT1(), sm.UT.cubature())
    pred = sm.estimation.predict(polar.with_angles([]), u, np.eye(2), transform="tt1")
    assert pred == sm.estimation.predict(polar.with_angles([]), u, np.eye(2), transform=sm.TT1())
    c_named, _ = sm.export_c(polar, tmp_path / "a", name="named", ut="ct")
    c_rule, _ = sm.export_c(polar, tmp_path / "b", name="named", ut=sm.UT.cubature())
    assert c_named.read_text() == c_rule.read_text()


@pytest.mark.parametrize("bad, error, match", [
    ("nope", SymmonError, "unknown transform 'nope'"),
    ("gh", None, None),  # the registry's own gh: order 5
    (3, TypeError, "symmon transform"),
])
def test_a_bad_transform_name_is_a_clear_error(bad, error, match):
    x = sp.Symbol("x", real=True)
    model, u = sm.Model([x], [x**2], name="named_bad"), sm.Gaussian([0.0], [[1.0]])
    if error is None:
        assert sm.propagate(model, u, transform=bad).mean[0] == pytest.approx(1.0, abs=1e-12)
        return
    with pytest.raises(error, match=match):
        sm.propagate(model, u, transform=bad)
