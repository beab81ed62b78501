"""
A test file for your own derivation
===================================

A researcher derives the TT2 moments of a new measurement model, a closed-form MMSE estimate,
and a measure of nonlinearity that should not depend on the units; this is the test file that
keeps those derivations true, with :mod:`symmon.testing`. Save it as ``test_my_model.py`` and
run ``pytest``: each assertion passes, or fails with the certificate (the claim, the method,
the assumptions and the counterexample).

The model is a range-only sensor at (1, 0) seeing a point (x, y): g = √((x − 1)² + y²).
"""

import sympy as sp

import symmon as sm
from symmon.testing import assert_derivation, assert_moments_close, assert_unit_invariant

x, y, mx, my, p12 = sp.symbols("x y m_x m_y p12", real=True)
p11, p22, sigma = sp.symbols("p11 p22 sigma", positive=True)
rng = sm.Model([x, y], [sp.sqrt((x - 1)**2 + y**2)], name="range_at_1_0")


def test_my_jacobian():
    """∂g/∂(x, y) = ((x − 1)/r, y/r), written by hand in the paper's appendix."""
    r = sp.sqrt((x - 1)**2 + y**2)
    v = sm.verify_derivatives(rng, jacobian=[[(x - 1) / r, y / r]])
    assert_derivation(v, require="proved")


def test_my_tt2_mean():
    """E r ≈ r(μ) + ((P11 b² − 2 P12 a b + P22 a²) / (2 r³)), a = m_x − 1, b = m_y (TT2)."""
    a, b = mx - 1, my
    r = sp.sqrt(a**2 + b**2)
    claimed = [r + (p11 * b**2 - 2 * p12 * a * b + p22 * a**2) / (2 * r**3)]
    P = sp.Matrix([[p11, p12], [p12, p22]])
    v = sm.verify_moments(rng, (sp.Matrix([mx, my]), P), mean=claimed, transform="tt2")
    assert_derivation(v, require="proved")


def test_my_mmse_estimate_of_a_squared_range():
    """E[(x − 1)²] = (m − 1)² + σ² for x ~ N(m, σ²): the MMSE estimate of a squared distance."""
    lhs = sm.Expectation((x - 1)**2, x, mx, sigma**2)
    assert_derivation(lhs, (mx - 1)**2 + sigma**2, require="proved")


def test_monte_carlo_agrees_with_gauss_hermite():
    """Two numeric routes to the moments agree within their own error bars."""
    u = sm.Gaussian([3.0, 1.0], [[0.2, 0.05], [0.05, 0.1]])
    mc = sm.propagate(rng, u, transform=sm.MonteCarlo(20000, seed=0))
    gh = sm.propagate(rng, u, transform=sm.GaussHermite(7, error_estimate=True))
    assert_moments_close(mc, gh)


def test_my_measure_is_unit_invariant():
    """The full-weight MoN (43) of the model does not depend on the units (Straka & Havlík 2024)."""
    assert_unit_invariant(rng, weight="full", transform="tt2")


# %%
# pytest finds and runs the ``test_*`` functions; here they are called by hand.
for test in (test_my_jacobian, test_my_tt2_mean, test_my_mmse_estimate_of_a_squared_range,
             test_monte_carlo_agrees_with_gauss_hermite, test_my_measure_is_unit_invariant):
    test()
    print(f"passed: {test.__name__}")

# %%
# A wrong claim fails with its certificate: here E[(x − 1)²] with the wrong sign of σ².
try:
    assert_derivation(sm.Expectation((x - 1)**2, x, mx, sigma**2), (mx - 1)**2 - sigma**2)
except AssertionError as failure:
    print(failure)
