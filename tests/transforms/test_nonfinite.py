"""Numerical hardening (issue 13): a NaN or inf is an error, never a number.

- g not finite at a point of a rule (UT, cubature, Gauss–Hermite): NonFiniteError naming the
  transform, the output and the point.
- Moments that overflow with g finite (|g| ≫ 1e154): the final guard of every transform.
- Gauss–Hermite grids beyond MAX_NODES are refused before they are built.
- An undeclared atan2 output whose points straddle ±π: one AngleWarning naming ``angles=``.
- A fuzz over random small models: finite moments or a SymmonError, nothing else.

The same issue's checks of a MoN that is not finite are in tests/measures/test_mon_nonfinite.py,
of conditioning near a zero posterior in tests/core/test_gaussian.py, and of the command's
exit 1 in tests/cli/test_cli.py.
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.errors import (
    AngleWarning,
    NonFiniteError,
    ResourceError,
    SamplingError,
    SymmonError,
)
from symmon.transforms import nodes
from symmon.transforms.nodes import MAX_NODES, rule_size, standard_rule

x, y = sp.symbols("x y", real=True)

#: Closed forms agree to rounding.
EXACT_RTOL = 1e-12

POINT_RULES = [sm.UT.ut1(), sm.UT.ut2(), sm.UT.cubature(), sm.GaussHermite(5)]
POINT_IDS = ["ut1", "ut2", "cubature", "gh5"]


# --------------------------------------------------------------------------- g not finite at a point
@pytest.mark.parametrize("transform", POINT_RULES, ids=POINT_IDS)
def test_sqrt_of_negative_mean_names_output_transform_and_point(transform):
    """The issue's case: sqrt(x) with mean −1 used to give E y = [nan]."""
    model = sm.Model([x], [sp.sqrt(x)])
    with pytest.raises(NonFiniteError) as exc:
        sm.propagate(model, sm.Gaussian([-1.0], [[1.0]]), transform=transform)
    msg = str(exc.value)
    assert repr(transform) in msg
    assert "output 0 (sqrt(x))" in msg
    assert "is nan at the point (x=-" in msg


def test_the_point_named_is_where_g_fails():
    """UT's point 0 is the mean: sqrt fails there first, at x = −1 exactly."""
    with pytest.raises(NonFiniteError, match=r"at the point \(x=-1\), point 0 of 3 of the rule"):
        sm.propagate(sm.Model([x], [sp.sqrt(x)]), sm.Gaussian([-1.0], [[1.0]]), transform=sm.UT.ut1())


def test_second_output_and_two_inputs_are_named():
    model = sm.Model([x, y], [x + y, sp.log(y)])
    with pytest.raises(NonFiniteError, match=r"output 1 \(log\(y\)\) is -?(nan|inf) at the point \(x=.*, y=.*\)"):
        sm.propagate(model, sm.Gaussian([0.0, 0.5], np.eye(2)), transform=sm.UT.cubature())


def test_propagate_many_and_nonlinearity_refuse_too():
    model = sm.Model([x], [sp.sqrt(x)])
    with pytest.raises(NonFiniteError, match="sqrt"):
        sm.propagate_many(model, ([[4.0], [-1.0]], [[[1.0]], [[1.0]]]), transform=sm.UT.ut1())
    with pytest.raises(NonFiniteError, match="sqrt"):
        sm.nonlinearity(model, sm.Gaussian([-1.0], [[1.0]]), transform=sm.GaussHermite(3))


def test_monte_carlo_keeps_its_sampling_error():
    with pytest.raises(SamplingError, match="NaN or inf"):
        sm.propagate(sm.Model([x], [sp.sqrt(x)]), sm.Gaussian([-1.0], [[1.0]]), transform=sm.MonteCarlo(1000, seed=0))


# --------------------------------------------------------------------------- moments that overflow
@pytest.mark.parametrize("transform", [sm.TT1(), sm.TT2(), sm.Exact()] + POINT_RULES,
                         ids=["tt1", "tt2", "exact"] + POINT_IDS)
def test_overflowing_covariance_is_refused_by_every_transform(transform):
    """g = 1e200·x is finite everywhere, but Var g = 1e400 overflows."""
    model = sm.Model([x], [sp.Float(1e200) * x])
    with pytest.raises(NonFiniteError, match=r"Cov y\[0, 0\] is inf \(output 0 .*rescale"):
        sm.propagate(model, sm.Gaussian([0.0], [[1.0]]), transform=transform)


def test_monte_carlo_overflow_is_its_sampling_error():
    with pytest.raises(SamplingError, match="overflow"):
        sm.propagate(sm.Model([x], [sp.Float(1e200) * x]), sm.Gaussian([0.0], [[1.0]]),
                     transform=sm.MonteCarlo(1000, seed=0))


def test_std_1e154_gives_the_exact_variance_not_inf():
    """N(0, 1e308) is representable and y = x has Var y = 1e308 (the issue had [[inf]])."""
    g = sm.Gaussian.from_std([0.0], [1e154])
    m = sm.propagate(sm.Model([x], [x]), g, transform=sm.UT.ut1())
    assert m.cov[0, 0] == pytest.approx(1e308, rel=EXACT_RTOL)


# --------------------------------------------------------------------------- Gauss–Hermite size limit
def test_tensor_grid_beyond_the_limit_is_refused_before_it_is_built(monkeypatch):
    def never(*args):
        raise AssertionError("the grid was built")

    monkeypatch.setattr(nodes, "_tensor", never)
    standard_rule.cache_clear()
    assert 5**12 > MAX_NODES
    syms = sp.symbols("a0:12")
    model = sm.Model(list(syms), [sum(syms)])
    with pytest.raises(ResourceError, match=r"tensor grid of order 5 in 12 dimensions has 244140625 nodes.*"
                                            r"MAX_NODES = 1000000.*sparse=True \(at most \d+ nodes\)"):
        sm.propagate(model, sm.Gaussian(np.zeros(12), np.eye(12)), transform=sm.GaussHermite(5, sparse=False))


def test_sparse_grid_beyond_the_limit_is_refused():
    dim, order = 60, 9
    assert rule_size(dim, order, True) > MAX_NODES
    with pytest.raises(ResourceError, match=rf"sparse \(Smolyak\) grid of order 9 in 60 dimensions has "
                                            rf"{rule_size(dim, order, True)} nodes"):
        standard_rule(dim, order, True)


@pytest.mark.parametrize("dim,order", [(1, 5), (2, 5), (3, 7), (5, 5), (6, 3)])
def test_rule_size_counts_the_combination_grids(dim, order):
    """The count equals the brute-force sum of the tensor grids the combination technique
    builds, and bounds the merged node count from above."""
    level = (order + 1) // 2
    q = dim + level - 1
    brute = sum(
        int(np.prod([2 * lv - 1 for lv in levels]))
        for levels in itertools.product(range(1, level + 1), repeat=dim)
        if q - dim + 1 <= sum(levels) <= q
    )
    assert rule_size(dim, order, True) == brute
    assert standard_rule(dim, order, True)[0].shape[0] <= brute
    assert rule_size(dim, order, False) == order**dim


# --------------------------------------------------------------------------- undeclared angles across the cut
CUT = [-10.0, 0.0]  # a target behind the sensor: the bearing straddles ±π
P_XY = np.diag([1.0, 4.0])


def _bearing(angles=None, scale=1):
    return sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x) * scale], angles=angles)


@pytest.mark.parametrize("transform", POINT_RULES + [sm.MonteCarlo(2000, seed=0)], ids=POINT_IDS + ["mc"])
def test_undeclared_bearing_across_the_cut_warns_once(transform):
    u = sm.Gaussian(CUT, P_XY)
    with pytest.warns(AngleWarning, match=r"output 1 \(atan2\(y, x\)\) looks like an angle.*angles=\[1\]"):
        sm.propagate(_bearing(), u, transform=transform)
    sm.propagate(_bearing(), u, transform=transform)  # once: a second warning would be an error here


@pytest.mark.parametrize("transform", POINT_RULES + [sm.MonteCarlo(2000, seed=0)], ids=POINT_IDS + ["mc"])
def test_declared_or_away_from_the_cut_is_silent(transform):
    sm.propagate(_bearing([1]), sm.Gaussian(CUT, P_XY), transform=transform)
    # Wide, but through 0: the points span (−π/2, π/2) and beyond without crossing ±π.
    sm.propagate(_bearing(), sm.Gaussian([1.0, 0.0], np.diag([0.01, 9.0])), transform=transform)


def test_bearing_in_degrees_has_its_cut_at_180():
    with pytest.warns(AngleWarning, match=r"cut at ±180"):
        sm.propagate(_bearing(scale=180 / sp.pi), sm.Gaussian(CUT, P_XY), transform=sm.UT.ut1())


def test_bearing_with_additive_noise_warns():
    e = sp.Symbol("e")
    model = sm.Model([x, y], [sp.atan2(y, x) + e], noise=[e])
    with pytest.warns(AngleWarning, match=r"output 0"):
        sm.propagate(model, sm.Gaussian(CUT, P_XY), v=sm.Gaussian([0.0], [[1e-4]]), transform=sm.UT.cubature())


def test_output_mixing_bearing_with_its_own_arguments_is_not_guessed():
    """range + bearing (a full S_y of a unit change): the jump is not at ±π, so no warning."""
    model = sm.Model([x, y], [sp.sqrt(x**2 + y**2) + 0.5 * sp.atan2(y, x)])
    sm.propagate(model, sm.Gaussian(CUT, P_XY), transform=sm.UT.ut1())


def test_angle_warning_is_a_runtime_warning():
    assert issubclass(AngleWarning, RuntimeWarning)


# --------------------------------------------------------------------------- fuzz: finite or a SymmonError
_LEAVES = st.sampled_from([x, y, sp.Integer(1), sp.Integer(2), sp.Rational(1, 2), sp.Float(1e160)])
_UNARY = [sp.sqrt, sp.log, sp.exp, sp.sin, sp.Abs, lambda a: 1 / a, lambda a: a**3]
_BINARY = [lambda a, b: a + b, lambda a, b: a * b, lambda a, b: a / b, sp.atan2]


def _apply(f, *args):
    """f(*args), or the first argument when sympy cannot even build it (exp(exp(1e160))) or
    builds a number beyond the float range: mpmath's exponents are unbounded, so exp(1e160)
    is a number, and sin of it would ask sympy for 10^160 digits of π (a hang, not a test)."""
    try:
        r = f(*args)
    except (OverflowError, ValueError):
        return args[0]
    if r.is_number and not r.free_symbols:
        try:
            if not np.isfinite(complex(r)):
                return args[0]
        except (TypeError, OverflowError):
            return args[0]
    return r


def _expr(depth: int):
    if depth == 0:
        return _LEAVES
    sub = _expr(depth - 1)
    return st.one_of(
        sub,
        st.tuples(st.sampled_from(_UNARY), sub).map(lambda t: _apply(*t)),
        st.tuples(st.sampled_from(_BINARY), sub, sub).map(lambda t: _apply(*t)),
    )


_TRANSFORMS = [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.UT.ut2(), sm.UT.cubature(), sm.GaussHermite(3),
               sm.MonteCarlo(512, seed=0, groups=2)]
_MAGNITUDE = st.sampled_from([0.0, 1e-300, 1e-3, 1.0, 10.0, 1e150, 1e300])


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(
    out=_expr(2).filter(lambda e: e.free_symbols and not e.has(sp.zoo, sp.nan, sp.oo, -sp.oo)),
    mean=st.tuples(st.floats(-5, 5), st.floats(-5, 5)),
    std=st.tuples(_MAGNITUDE, _MAGNITUDE),
    rho=st.floats(-0.99, 0.99),
    transform=st.sampled_from(_TRANSFORMS),
    weight=st.sampled_from(["full", "diag", "liu-li", "liu-li-raw"]),
)
def test_fuzz_moments_are_finite_or_a_symmon_error(out, mean, std, rho, transform, weight):
    """Moments, then the MoN: each is finite or a SymmonError (never NaN, inf, or another
    exception or RuntimeWarning, which filterwarnings=error turns into a failure)."""
    s = np.array(std)
    with np.errstate(over="ignore"):  # a variance of 1e600 is inf: the Gaussian must refuse it
        P = np.array([[s[0] ** 2, rho * s[0] * s[1]], [rho * s[0] * s[1], s[1] ** 2]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AngleWarning)  # the property here is finiteness
        try:
            u = sm.Gaussian(mean, P)
            model = sm.Model([x, y], [out])
            m = sm.propagate(model, u, transform=transform)
        except SymmonError:
            return
        assert np.isfinite(m.mean).all() and np.isfinite(m.cov).all() and np.isfinite(m.cross_cov).all()
        try:
            mon = sm.nonlinearity(model, u, weight=weight, transform=transform)
        except SymmonError:
            return
    assert np.isfinite(mon.value) and np.isfinite(mon.squared)
