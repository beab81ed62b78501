"""symmon.testing (issue 37, item 5): assertions for a user's own test suite."""

from __future__ import annotations

import pytest
import sympy as sp

import symmon as sm
from symmon.testing import assert_derivation, assert_moments_close, assert_unit_invariant

x, y, mu = sp.symbols("x y mu", real=True)
s = sp.Symbol("sigma", positive=True)


def test_assert_derivation_passes_a_proof_and_fails_with_the_certificate():
    v = assert_derivation(sm.Expectation(x**2, x, mu, s**2), mu**2 + s**2, require="proved")
    assert v.proved
    with pytest.raises(AssertionError) as info:
        assert_derivation(sm.Expectation(x**2, x, mu, s**2), mu**2 + s**2 + sp.Rational(1, 10**13))
    text = str(info.value)
    assert "REFUTED" in text and "counterexample: at" in text and "lhs - rhs" in text


def test_assert_derivation_require_proved_refuses_a_numeric_agreement():
    claim = (sm.Expectation(sp.atan(x), x, 0, s**2), 0)
    assert assert_derivation(*claim).verdict == "consistent"
    with pytest.raises(AssertionError, match="is not proved"):
        assert_derivation(*claim, require="proved")
    with pytest.raises(sm.errors.ArgumentError, match="require"):
        assert_derivation(x, x, require="surely")


def test_assert_derivation_takes_a_verification_and_a_file(tmp_path):
    assert assert_derivation(sm.verify(x + x, 2 * x)).proved
    path = tmp_path / "d.toml"
    path.write_text('[symbols]\nmu = "real"\n[[claims]]\nlhs = "(mu + 1)**2"\nrhs = "mu**2 + 2*mu + 1"\n'
                    '[[claims]]\nname = "typo"\nlhs = "(mu + 1)**2"\nrhs = "mu**2 + 1"\n', encoding="utf-8")
    with pytest.raises(AssertionError, match="1 of 2 claims") as info:
        assert_derivation(path)
    assert "typo: refuted" in str(info.value)


@pytest.fixture(scope="module")
def square():
    model = sm.Model([x], [x**2], name="testing_square")
    u = sm.Gaussian([1.0], [[0.5]])
    return model, u, sm.propagate(model, u, transform=sm.Exact())


def test_assert_moments_close_uses_the_monte_carlo_standard_errors(square):
    model, u, exact = square
    mc = sm.propagate(model, u, transform=sm.MonteCarlo(20000, seed=2))
    v = assert_moments_close(mc, exact)
    assert v.verdict == "consistent" and "standard errors of a" in v.method
    assert float(v.evidence["max_difference_over_tolerance"]) <= 1
    with pytest.raises(AssertionError, match="differ beyond their error bars"):
        assert_moments_close(mc, exact, sigmas=0.0)  # no error bars left: the sampling error shows


def test_assert_moments_close_of_two_closed_forms_is_to_rounding(square):
    model, u, exact = square
    assert assert_moments_close(exact, {"mean": exact.mean, "cov": exact.cov}).verdict == "consistent"
    with pytest.raises(AssertionError) as info:
        assert_moments_close(sm.propagate(model, u, transform=sm.TT1()), exact)
    assert "entry" in str(info.value) or "mean" in str(info.value)
    with pytest.raises(sm.errors.ArgumentError, match="no moments"):
        assert_moments_close({"mean": None}, exact)


def test_assert_moments_close_reads_gauss_hermite_error_bounds(square):
    model, u, exact = square
    gh = sm.propagate(model, u, transform=sm.GaussHermite(3, error_estimate=True))
    v = assert_moments_close(gh, exact, rtol=1e-10)
    assert "error bound of a" in v.method


def test_assert_unit_invariant():
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="testing_polar")
    assert assert_unit_invariant(polar, weight="full").holds
    with pytest.raises(AssertionError, match="not unit invariant") as info:
        assert_unit_invariant(polar, weight="liu-li-raw")
    assert "counterexample" in str(info.value) or "fails" in str(info.value)


def test_the_public_module_is_symmon_testing():
    import importlib

    assert sm.testing is importlib.import_module("symmon.testing")
    assert set(sm.testing.__all__) >= {"assert_derivation", "assert_moments_close", "assert_unit_invariant"}
