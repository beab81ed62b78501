"""Every bad input of DESIGN.md's conventions raises a clear error that names the argument."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import (
    ArgumentError,
    CovarianceError,
    DerivativeError,
    ModelError,
    SamplingError,
    ShapeError,
    SymmonError,
)

x, y = sp.symbols("x y", real=True)
e1, e2 = sp.symbols("e1 e2", real=True)

PRODUCT = sm.Model([x, y], [x * y, x + y], name="bad_product")
NOISY = sm.Model([x, y], [x * y + e1, y + e2], noise=[e1, e2], name="bad_noisy")
U = sm.Gaussian([1.0, 2.0], np.eye(2))


# --------------------------------------------------------------------------- shapes
def test_u_dimension_must_match_the_model():
    with pytest.raises(ShapeError, match=r"u has dimension 3 but the model has 2 inputs \['x', 'y'\]"):
        sm.propagate(PRODUCT, sm.Gaussian([0.0, 0.0, 0.0], np.eye(3)))


def test_u_must_be_a_gaussian():
    with pytest.raises(TypeError, match="u must be a symmon.Gaussian"):
        sm.propagate(PRODUCT, ([1.0, 2.0], np.eye(2)))


def test_v_missing():
    with pytest.raises(ModelError, match=r"noise symbols \['e1', 'e2'\]: pass v="):
        sm.propagate(NOISY, U)


def test_v_given_for_a_noise_free_model():
    with pytest.raises(ModelError, match="v was given but the model declares no noise"):
        sm.propagate(PRODUCT, U, v=sm.Gaussian([0.0], [[1.0]]))


def test_v_dimension():
    with pytest.raises(ShapeError, match="v has dimension 1 but the model has 2 noise symbols"):
        sm.propagate(NOISY, U, v=sm.Gaussian([0.0], [[1.0]]))


@pytest.mark.parametrize(
    ("means", "covs", "match"),
    [
        (np.zeros((3, 3)), np.tile(np.eye(2), (3, 1, 1)), r"means must have shape \(K, 2\)"),
        (np.zeros(2), np.eye(2)[None], r"means must have shape \(K, 2\)"),
        (np.zeros((3, 2)), np.tile(np.eye(2), (2, 1, 1)), r"covs must have shape \(3, 2, 2\)"),
        (np.zeros((3, 2)), np.tile(np.eye(3), (3, 1, 1)), r"covs must have shape \(3, 2, 2\)"),
    ],
)
def test_propagate_many_shapes(means, covs, match):
    with pytest.raises(ShapeError, match=match):
        sm.propagate_many(PRODUCT, (means, covs), transform=sm.TT1())


def test_propagate_many_names_the_bad_entry():
    covs = np.tile(np.eye(2), (3, 1, 1))
    covs[1] = [[1.0, 0.5], [0.2, 1.0]]
    with pytest.raises(CovarianceError, match=r"covs\[1\] is not symmetric"):
        sm.propagate_many(PRODUCT, (np.zeros((3, 2)), covs), transform=sm.TT1())
    covs[1] = [[1.0, 2.0], [2.0, 1.0]]
    with pytest.raises(CovarianceError, match=r"covs\[1\] is not positive semi-definite"):
        sm.propagate_many(PRODUCT, (np.zeros((3, 2)), covs), transform=sm.TT1())
    means = np.zeros((3, 2))
    means[2, 0] = np.nan
    with pytest.raises(ShapeError, match=r"means\[2\] contains NaN"):
        sm.propagate_many(PRODUCT, (means, np.tile(np.eye(2), (3, 1, 1))), transform=sm.TT1())


def test_propagate_many_needs_the_noise_of_a_noisy_model():
    with pytest.raises(ModelError, match="pass v="):
        sm.propagate_many(NOISY, (np.zeros((1, 2)), np.eye(2)[None]), transform=sm.TT1())


# --------------------------------------------------------------------------- covariances
@pytest.mark.parametrize(
    ("cov", "match"),
    [
        ([[1.0, 0.3], [0.1, 1.0]], "cov is not symmetric"),
        ([[1.0, 3.0], [3.0, 1.0]], "cov is not positive semi-definite: smallest eigenvalue -2"),
        ([[1.0, np.nan], [np.nan, 1.0]], "cov contains NaN"),
    ],
)
def test_bad_covariances(cov, match):
    with pytest.raises(CovarianceError, match=match):
        sm.Gaussian([0.0, 0.0], cov)


# --------------------------------------------------------------------------- symbols
def test_unknown_symbols():
    z = sp.Symbol("z")
    with pytest.raises(ModelError, match=r"unknown symbols \['z'\]"):
        sm.Model([x, y], [x * z])


# --------------------------------------------------------------------------- sampling
def test_nan_while_sampling_reports_the_count():
    m = sm.Model([x], [sp.log(x)], name="bad_log")
    with pytest.raises(SamplingError, match=r"g is NaN or inf at \d+ of \d+ samples") as info:
        sm.propagate(m, sm.Gaussian([0.05], [[1.0]]), transform=sm.MonteCarlo(n=2000, seed=1))
    count = int(str(info.value).split(" at ")[1].split(" of ")[0])
    assert count > 0


# --------------------------------------------------------------------------- transforms
@pytest.mark.parametrize("cls", [sm.TT1, sm.TT2, sm.UT, sm.GaussHermite, sm.MonteCarlo, sm.Exact])
def test_transform_class_instead_of_instance(cls):
    with pytest.raises(TypeError, match=rf"pass a transform instance, e.g. {cls.__name__}\(\), not the class"):
        sm.propagate(PRODUCT, U, transform=cls)


def test_not_a_transform():
    with pytest.raises(TypeError, match="transform must be a symmon transform"):
        sm.propagate(PRODUCT, U, transform=object())
    with pytest.raises(SymmonError, match="unknown transform 'ut'"):
        sm.propagate(PRODUCT, U, transform="ut")  # a name, but not a registered one


@pytest.mark.parametrize("alpha", [0.0, -1.0])
def test_ut_alpha_must_be_positive(alpha):
    with pytest.raises(SymmonError, match="UT alpha must be positive"):
        sm.UT(alpha=alpha)


@pytest.mark.parametrize("kw", [dict(alpha=np.nan), dict(beta=np.inf), dict(kappa=np.nan)])
def test_ut_parameters_must_be_finite(kw):
    with pytest.raises(SymmonError, match="must be finite"):
        sm.UT(**kw)


def test_ut_n_plus_lambda_must_be_positive():
    # n = 2, α = 1, κ = −2: n + λ = α²(n + κ) = 0.
    with pytest.raises(SymmonError, match=r"n \+ lambda = 0 <= 0 for n = 2"):
        sm.propagate(PRODUCT, U, transform=sm.UT(alpha=1.0, kappa=-2.0))


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        (dict(n=10), "n = 10 is too small for 16 groups"),
        (dict(n=0), "n must be a positive integer"),
        (dict(n=1000, groups=1), "groups >= 2"),
        (dict(n=1000, chunk=0), "chunk must be a positive integer"),
        (dict(n=1000.5), "n must be a positive integer"),
    ],
)
def test_monte_carlo_settings(kw, match):
    with pytest.raises(SymmonError, match=match):
        sm.MonteCarlo(**kw)


@pytest.mark.parametrize("order", [0, -2, 2.5])
def test_gauss_hermite_order(order):
    with pytest.raises(SymmonError, match="GaussHermite order must be a positive integer"):
        sm.GaussHermite(order)


def test_exact_needs_a_polynomial():
    with pytest.raises(ModelError, match=r"output 0 .* is not polynomial"):
        sm.propagate(sm.Model([x, y], [sp.sin(x)], name="bad_sin"), U, transform=sm.Exact())


# --------------------------------------------------------------------------- derivatives
ORIGIN = sm.Gaussian([0.0, 0.0], np.eye(2))


@pytest.mark.parametrize("tr", [sm.TT1(), sm.TT2()], ids=["tt1", "tt2"])
@pytest.mark.parametrize(
    ("outputs", "i"),
    [([sp.sqrt(x**2 + y**2)], 0), ([x + y, sp.atan2(y, x)], 1)],
    ids=["range", "atan2"],
)
def test_derivative_error_names_output_and_point(tr, outputs, i):
    m = sm.Model([x, y], outputs, name="bad_singular")
    with pytest.raises(DerivativeError, match=rf"Jacobian of output {i} \(.+\) is NaN or inf at the point \(x=0, y=0\)"):
        sm.propagate(m, ORIGIN, transform=tr)


# --------------------------------------------------------------------------- tracebacks that escaped (issue 13)
BIG = 10**400  # a Python int no float can hold


@pytest.mark.parametrize(
    ("mean", "cov", "err", "match"),
    [
        ([BIG], [[1.0]], ShapeError, r"mean holds a number too large for a float"),
        ([0.0], [[BIG]], CovarianceError, r"cov holds a number too large for a float"),
        (["a"], [[1.0]], ShapeError, r"mean must hold real numbers"),
        ([0.0], [["a"]], CovarianceError, r"cov must hold real numbers"),
        ([], [], ShapeError, r"mean is empty: a Gaussian needs at least one component"),
        ([], [[]], ShapeError, r"mean is empty"),
    ],
)
def test_gaussian_refuses_what_numpy_and_python_raised(mean, cov, err, match):
    with pytest.raises(err, match=match):
        sm.Gaussian(mean, cov)


@pytest.mark.parametrize("rng", [-1, 1.5, "seed", True])
def test_sample_refuses_a_bad_seed(rng):
    with pytest.raises(ArgumentError, match=r"rng must be a numpy Generator, a non-negative integer seed or None"):
        U.sample(3, rng=rng)


@pytest.mark.parametrize("n", [0, -1, 2.0, True])
def test_sample_refuses_a_bad_count(n):
    with pytest.raises(ArgumentError, match="n must be a positive integer"):
        U.sample(n, rng=0)


def test_sample_accepts_a_seed_and_a_generator_alike():
    a = U.sample(4, rng=7)
    b = U.sample(4, rng=np.random.default_rng(7))
    assert np.array_equal(a, b)


def test_from_std_refuses_a_variance_that_overflows():
    with pytest.raises(CovarianceError, match=r"std\[1\] = 1e\+160: its square, the variance, overflows"):
        sm.Gaussian.from_std([0.0, 0.0], [1.0, 1e160])


def test_covariance_near_the_float_maximum_is_symmetrised_without_overflow():
    """(P + Pᵀ)/2 overflowed to inf for 1e308; halving first keeps the entry."""
    assert sm.Gaussian([0.0], [[1e308]]).cov[0, 0] == 1e308


@pytest.mark.parametrize("v", [1e308, 1.7e308])
def test_covariance_whose_eigen_decomposition_fails_is_refused(v):
    """A rank-one matrix of entries near the float maximum: LAPACK's eigenvalues overflow."""
    with pytest.raises(CovarianceError, match=r"cov: the eigen-decomposition failed .* rescale the units"):
        sm.Gaussian([0.0, 0.0], [[v, v], [v, v]])


def test_asymmetry_that_overflows_is_still_asymmetry():
    with pytest.raises(CovarianceError, match="not symmetric"):
        sm.Gaussian([0.0, 0.0], [[1e308, -1e308], [1e308, 1e308]])


def _no_convergence(*args, **kwargs):
    raise np.linalg.LinAlgError("Eigenvalues did not converge")


def test_lapack_failure_in_validation_is_a_covariance_error(monkeypatch):
    """LAPACK's own failure (seen for extreme std) becomes a CovarianceError naming cov."""
    monkeypatch.setattr(np.linalg, "eigvalsh", _no_convergence)
    with pytest.raises(CovarianceError, match=r"cov: the eigen-decomposition failed \(Eigenvalues did not converge\)"):
        sm.Gaussian([0.0, 0.0], [[1e300, 0.0], [0.0, 1e-300]])


def test_lapack_failure_in_the_square_root_is_a_covariance_error(monkeypatch):
    """Cholesky fails on a singular P, the semidefinite Cholesky on an indefinite one: the
    last resort, eigh, failing too is reported, not raised as LinAlgError."""
    from symmon.core.gaussian import matrix_sqrt

    monkeypatch.setattr(np.linalg, "eigh", _no_convergence)
    with pytest.raises(CovarianceError, match=r"no square root of the covariance.*did not converge"):
        matrix_sqrt(np.array([[1.0, 2.0], [2.0, 1.0]]))
