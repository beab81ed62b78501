"""Covariance safeguards and degenerate cases (issue 8): explicit, never silent.

- The UT's negative weights: a covariance that is not PSD is refused
  (tests/transforms/test_definiteness.py).
- Monte Carlo's shifted sums: a large offset in y costs no digits.
- Singular Σ_uu (pseudo-inverse, said in ``.notes``) and singular Σ_gg (W^full refused
  with the null combination named).
- TT1/TT2 refuse NaN derivatives, naming the output and the point.

``Gaussian(psd=...)`` (raise, clip with the clipped mass, or jitter with ε) is tested in
tests/core/test_gaussian.py.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import CovarianceError, DerivativeError, SingularMatrixError
from symmon.core.gaussian import matrix_sqrt

#: Closed forms and exact identities agree to rounding.
EXACT_TOL = 1e-12
#: The issue's bound for Monte Carlo with an offset of 1e8 in y (same seed): the offset
#: output is rounded to ulp(1e8) ≈ 1.5e-8 per sample, i.e. 1.5e-10 relative to σ = 100.
OFFSET_RTOL = 1e-9
#: Rotations/reductions that map rule points onto rule points: rounding only.
REDUCTION_TOL = 1e-9
#: Monte Carlo bound: 5 standard errors (seeded generator).
N_SE = 5

x, y, z = sp.symbols("x y z", real=True)


# --------------------------------------------------------------------------- MC offsets
R = sp.sqrt(x**2 + y**2)
U_FAR = sm.Gaussian([1e4, 0.0], np.diag([100.0**2, 100.0**2]))  # a range of about 1e4, σ = 100
MC_OFFSET = sm.MonteCarlo(40_000, seed=7, groups=4, chunk=1024)  # many chunks: Chan merges


@pytest.fixture(scope="module")
def offset_moments():
    return {
        off: sm.propagate(sm.Model([x, y], [R + off, x * y / 1e4 + off]), U_FAR, transform=MC_OFFSET)
        for off in (0.0, -1e4, 1e8)
    }


@pytest.mark.parametrize("offset, rtol", [(1e8, OFFSET_RTOL), (-1e4, EXACT_TOL * 100)])
def test_mc_offset_loses_no_digits(offset_moments, offset, rtol):
    """Same seed: y + 1e8 gives Cov y and Cov(y, u) unchanged to 1e-9 relative, and the
    range (about 1e4) agrees with range − 1e4 to rounding: no digits are lost to E y."""
    a, b = offset_moments[0.0], offset_moments[offset]
    assert np.abs(b.cov - a.cov).max() < rtol * np.abs(a.cov).max()
    assert np.abs(b.cross_cov - a.cross_cov).max() < rtol * np.abs(a.cross_cov).max()
    assert np.abs((b.mean - offset) - a.mean).max() < rtol * max(abs(offset), 1e4)


def test_naive_sums_would_lose_the_digits():
    """The check above can fail: E y² − (E y)² in double precision at y ≈ 1e8 with σ = 100
    has an error of about ulp(1e16) ≈ 2 per sample, far beyond 1e-9 relative of σ² = 1e4."""
    gen = np.random.default_rng(0)
    w = U_FAR.sample(40_000, gen)
    yv = np.hypot(w[:, 0], w[:, 1]) + 1e8
    naive = np.mean(yv**2) - np.mean(yv) ** 2
    good = np.var(yv)
    assert abs(naive - good) > OFFSET_RTOL * good * 1e3


# --------------------------------------------------------------------------- singular Σ_uu
Z_VALUE = 2.0
P_XY = np.array([[0.5, 0.1], [0.1, 0.3]])
FULL = sm.Model([x, y, z], [x * y + z * x, sp.sqrt(x**2 + y**2) + z**2])
REDUCED = sm.Model([x, y], [e.subs(z, Z_VALUE) for e in FULL.outputs])
U_SING = sm.Gaussian([1.0, 2.0, Z_VALUE], np.block([[P_XY, np.zeros((2, 1))], [np.zeros((1, 3))]]))
U_RED = sm.Gaussian([1.0, 2.0], P_XY)

#: Perfectly correlated inputs: y = x + 1 almost surely; the reduced model is g(x, x + 1).
CORR = sm.Model([x, y], [x * y, sp.exp(y / 4) + x**2])
CORR_RED = sm.Model([x], [e.subs(y, x + 1) for e in CORR.outputs])
U_CORR = sm.Gaussian([1.0, 2.0], 0.3 * np.ones((2, 2)))
U_CORR_RED = sm.Gaussian([1.0], [[0.3]])

# The rules whose points on the informative subspace are those of the reduced problem:
# TT2 (derivatives), Gauss–Hermite (a zero column of the square root collapses its axis),
# and ut1 (its spread √(n + λ) = √3 does not depend on n, and the collapsed points add
# their weights 1/6 each to the centre's, which is what w₀ = (3 − n)/3 does for n − 1).
REDUCIBLE = [pytest.param(sm.TT2(), id="tt2"), pytest.param(sm.GaussHermite(5), id="gh5"),
             pytest.param(sm.UT.ut1(), id="ut1")]
CASES = {
    "zero-variance": (FULL, U_SING, REDUCED, U_RED, "rank 2 of 3"),
    "correlated": (CORR, U_CORR, CORR_RED, U_CORR_RED, "rank 1 of 2"),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("transform", REDUCIBLE)
@pytest.mark.parametrize("weight", ["full", "diag", "liu-li"])
def test_singular_input_cov_uses_the_pseudo_inverse(case, transform, weight):
    """Σ_uu singular: M² uses Σ_gu Σ_uu⁺ Σ_ug, the best affine fit on the informative
    subspace, says so in ``.notes``, and equals the MoN of the reduced model."""
    model, u, red_model, u_red, rank = CASES[case]
    a = sm.nonlinearity(model, u, weight=weight, transform=transform)
    b = sm.nonlinearity(red_model, u_red, weight=weight, transform=transform)
    assert a.value == pytest.approx(b.value, abs=REDUCTION_TOL)
    assert a.residual_cov == pytest.approx(b.residual_cov, abs=REDUCTION_TOL * np.abs(b.moments.cov).max())
    assert any("Σ_uu is singular" in n and "pseudo-inverse" in n and rank in n for n in a.notes)
    assert b.notes == ()


@pytest.mark.parametrize("transform", REDUCIBLE)
def test_zero_variance_input_cross_cov(transform):
    """Cov(y, z) = 0 for the constant input, and Cov(y, [x, y]) is the reduced model's."""
    a = sm.propagate(FULL, U_SING, transform=transform)
    b = sm.propagate(REDUCED, U_RED, transform=transform)
    assert np.array_equal(a.cross_cov[:, 2], np.zeros(2))
    assert a.cross_cov[:, :2] == pytest.approx(b.cross_cov, rel=REDUCTION_TOL)


def test_singular_input_cov_monte_carlo():
    mc = sm.MonteCarlo(10**5, seed=11)
    a = sm.nonlinearity(FULL, U_SING, transform=mc)
    b = sm.nonlinearity(REDUCED, U_RED, transform=mc)
    assert abs(a.value - b.value) < N_SE * np.hypot(a.stderr, b.stderr)
    assert any("pseudo-inverse" in n for n in a.notes)


def test_singular_sqrt_is_the_limit_of_cholesky():
    """The square root of a singular PSD matrix continues Cholesky (zero columns), so a
    rule does not jump when a variance reaches 0."""
    P = U_SING.cov
    L = matrix_sqrt(P)
    assert L @ L.T == pytest.approx(P, abs=EXACT_TOL)
    assert L[:2, :2] == pytest.approx(np.linalg.cholesky(P_XY), abs=EXACT_TOL)
    assert np.array_equal(L[2], np.zeros(3)) and np.array_equal(L[:, 2], np.zeros(3))
    eps = 1e-14
    assert L == pytest.approx(np.linalg.cholesky(P + eps * np.eye(3)), abs=1e-6)


def test_indefinite_sqrt_falls_back_to_clipped_eigen():
    L = matrix_sqrt(np.array([[1.0, 2.0], [2.0, 1.0]]))
    assert L @ L.T == pytest.approx(1.5 * np.ones((2, 2)), abs=EXACT_TOL)


# --------------------------------------------------------------------------- singular Σ_gg
@pytest.mark.parametrize("transform", [sm.TT2(), sm.UT.ut1(), sm.MonteCarlo(20_000, seed=2)],
                         ids=["tt2", "ut1", "mc"])
def test_singular_output_cov_full_weight_names_the_combination(transform):
    """y = (x, y, x + y): y₀ + y₁ − y₂ has no variance, so W^full = Σ_gg⁻¹/n_y (43) does
    not exist; the error names that combination (up to sign and normalisation)."""
    model = sm.Model([x, y], [x, y, x + y])
    u = sm.Gaussian([1.0, 2.0], [[1.0, 0.2], [0.2, 0.5]])
    with pytest.raises(SingularMatrixError, match="has no variance") as exc:
        sm.nonlinearity(model, u, weight="full", transform=transform)
    terms = dict((int(i), float(c)) for c, i in re.findall(r"([-0-9.e+]+)\*y(\d)", str(exc.value)))
    v = np.array([terms.get(i, 0.0) for i in range(3)])
    expected = np.array([1.0, 1.0, -1.0]) / np.sqrt(3)
    assert min(np.abs(v - expected).max(), np.abs(v + expected).max()) < 1e-3  # printed to 3 digits
    # the diagonal weight needs only the variances and works
    assert float(sm.nonlinearity(model, u, weight="diag", transform=transform)) >= 0


# --------------------------------------------------------------------------- NaN derivatives
@pytest.mark.parametrize("transform", [sm.TT1(), sm.TT2()], ids=["tt1", "tt2"])
@pytest.mark.parametrize(
    "outputs, index, text",
    [([sp.sqrt(x**2 + y**2)], 0, r"sqrt\(x\*\*2 \+ y\*\*2\)"), ([x + y, sp.atan2(y, x)], 1, r"atan2\(y, x\)")],
    ids=["sqrt", "atan2"],
)
def test_nan_derivative_names_output_and_point(transform, outputs, index, text):
    model = sm.Model([x, y], outputs)
    u = sm.Gaussian([0.0, 0.0], np.eye(2))
    with pytest.raises(DerivativeError, match=rf"output {index} \({text}\) is NaN or inf at the point \(x=0, y=0\)"):
        sm.propagate(model, u, transform=transform)
    with pytest.raises(DerivativeError, match=rf"output {index}"):
        sm.nonlinearity(model, u, transform=transform)


def test_sampling_rules_work_at_the_singular_point():
    """The remedy the error suggests: the UT never differentiates."""
    m = sm.propagate(sm.Model([x, y], [sp.sqrt(x**2 + y**2)]), sm.Gaussian([0.0, 0.0], np.eye(2)),
                     transform=sm.UT.cubature())
    assert m.mean[0] == pytest.approx(np.sqrt(2.0), rel=EXACT_TOL)  # all four points at radius √2
