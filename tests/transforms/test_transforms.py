"""The transforms: the lecture's radar example, exactness, FilterPy, Monte Carlo, sparse grids."""

from __future__ import annotations

import warnings

import itertools
from math import prod

import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import symmon as sm
from symmon.compile import CompiledModel
from symmon.errors import QuadratureWarning, SamplingError
from symmon.transforms.montecarlo import group_normals
from symmon.transforms.stats import Stats, merge, merge_all
from symmon.transforms.nodes import standard_rule

from helpers import radar_model, random_spd

#: Closed-form moments against a transform that is exact for them: rounding only.
EXACT_RTOL = 1e-10
#: Two implementations of the same arithmetic (symmon vs FilterPy): rounding only.
PEER_RTOL = 1e-10
#: Two evaluation orders of the same samples (chunking, merging shards): rounding only.
REORDER_RTOL = 1e-12
#: Monte Carlo: a seeded generator, errors within 5 standard errors.
N_SE = 5.0
#: A covariance shifted by 1e8 in the mean: Chan merges keep ~16 - 8 + 1 digits.
OFFSET_RTOL = 1e-9
#: "Visibly" not exact: the error of a transform beyond its degree.
NOT_EXACT_MIN = 1e-3


def rtol_for(tr, rtol: float) -> float:
    """A UT with small α has weights of size 1/α² (ut2: 10⁶) that multiply the rounding
    errors, eps·|y|, of the transformed points: its attainable accuracy is ~10·eps/α²."""
    if isinstance(tr, sm.UT):
        return max(rtol, 10 * np.finfo(float).eps / tr.alpha**2)
    return rtol


def assert_close(actual, desired, rtol, what=""):
    """|a − d| ≤ rtol · max|d| entrywise (relative to the scale of the whole array)."""
    actual, desired = np.asarray(actual, float), np.asarray(desired, float)
    scale = max(float(np.max(np.abs(desired), initial=0.0)), 1.0)
    np.testing.assert_allclose(actual, desired, rtol=0, atol=rtol * scale, err_msg=what)


def vm(exprs, syms, name="t"):
    """A CompiledModel on CasADi's VM: no C compilation for one-off (random) models."""
    return CompiledModel(list(exprs), list(syms), name=name, compiled=False)


def batch1(tr, cm, mean, cov):
    """Moments of one Gaussian through the batch API: mean, cov, cross, stderr."""
    b = tr.moments(cm, np.asarray(mean, float)[None], np.asarray(cov, float)[None])
    se = None if b.stderr is None else {k: v[0] for k, v in b.stderr.items()}
    return b.mean[0], b.cov[0], b.cross_cov[0], se


# =========================================================================== lecture radar
@pytest.mark.parametrize("sensor", ["1", "2"])
def test_lecture_radar_ut1(sensor, lecture_radar):
    """Lecture slide 'Radar Example: direct approach with UT (2/2)': S, fS and Nhat (SigSys uteval 'ut1')."""
    ref = lecture_radar["sensors"][sensor]
    phi0 = float(sp.sympify(ref["phi_mean"]).evalf(17))
    r0 = float(sp.sympify(ref["r_mean"]).evalf(17))
    var = lecture_radar["variances"]
    u = sm.Gaussian([r0, phi0], np.diag([var["r"], var["phi"]]))
    m = sm.propagate(radar_model(tuple(ref["p"])), u, transform=sm.UT.ut1())
    S = m.info["sigma_points"][0].T  # SigSys prints one point per column
    fS = m.info["transformed_points"][0].T
    assert m.info["sigma_points"].shape == (1, 5, 2)
    # Printed with 4 decimals: agreement to half a unit in the last printed digit.
    np.testing.assert_allclose(S, ref["S"], rtol=0, atol=0.5e-4)
    np.testing.assert_allclose(fS, ref["fS"], rtol=0, atol=0.5e-4)
    # Nhat printed with 3 significant digits.
    sig3 = lambda a: np.array([float(f"{v:.3g}") for v in np.ravel(a)])  # noqa: E731
    np.testing.assert_array_equal(sig3(m.mean), ref["Nhat_mean"])
    np.testing.assert_array_equal(sig3(m.cov), np.ravel(ref["Nhat_cov"]))
    # SigSys prints N([95.1;95.1],[954,-854;-854,954]); symmon the same with Python brackets.
    assert repr(m.y) == _sigsys_to_python(ref["Nhat"])


def _sigsys_to_python(s: str) -> str:
    """'N([95.1;95.1],[954,-854;-854,954])' → 'N([95.1, 95.1], [[954, -854], [-854, 954]])'."""
    mean, cov = s[len("N(["):-len("])")].split("],[")
    m = ", ".join(mean.split(";"))
    rows = ", ".join("[" + ", ".join(r.split(",")) + "]" for r in cov.split(";"))
    return f"N([{m}], [{rows}])"


def test_lecture_radar_repr_sensor1_literal():
    r0, phi0 = 100 * np.sqrt(2), np.pi / 4
    m = sm.propagate(radar_model((0.0, 0.0)), sm.Gaussian([r0, phi0], np.diag([5.0, 0.1])), transform=sm.UT.ut1())
    assert repr(m.y) == "N([95.1, 95.1], [[954, -854], [-854, 954]])"


# =========================================================================== TT1 / TT2 closed forms
X3 = sp.symbols("x0:3", real=True)


def _quadratic_case(seed: int):
    r = np.random.default_rng(seed)
    A = [(lambda M: (M + M.T) / 2)(r.normal(size=(3, 3))) for _ in range(2)]
    b = [r.normal(size=3) for _ in range(2)]
    c = r.normal(size=2)
    mu = r.normal(size=3)
    P = random_spd(r, 3)
    xs = sp.Matrix(X3)
    exprs = [
        sp.expand((xs.T * sp.Matrix(A[i]) * xs)[0] + (sp.Matrix(b[i]).T * xs)[0] + c[i]) for i in range(2)
    ]
    return A, b, c, mu, P, exprs


def _quadratic_moments(A, b, c, mu, P):
    """Gaussian moments of y_i = xᵀA_i x + b_iᵀx + c_i, A_i symmetric.

    E y_i = μᵀA_iμ + tr(A_iP) + b_iᵀμ + c_i,
    Cov(y_i, y_j) = 2 tr(A_iPA_jP) + 4 (A_iμ + b_i/2)ᵀP(A_jμ + b_j/2),
    Cov(y_i, x) = (2A_iμ + b_i)ᵀP.
    """
    k = len(A)
    mean = np.array([mu @ A[i] @ mu + np.trace(A[i] @ P) + b[i] @ mu + c[i] for i in range(k)])
    g = [A[i] @ mu + b[i] / 2 for i in range(k)]
    cov = np.array([[2 * np.trace(A[i] @ P @ A[j] @ P) + 4 * g[i] @ P @ g[j] for j in range(k)] for i in range(k)])
    cross = np.array([2 * g[i] @ P for i in range(k)])
    return mean, cov, cross


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tt2_exact_for_quadratic_models(seed):
    A, b, c, mu, P, exprs = _quadratic_case(seed)
    mean, cov, cross = _quadratic_moments(A, b, c, mu, P)
    model = sm.Model(list(X3), exprs)
    m = sm.propagate(model, sm.Gaussian(mu, P), transform=sm.TT2())
    assert_close(m.mean, mean, EXACT_RTOL, "mean")
    assert_close(m.cov, cov, EXACT_RTOL, "cov")
    assert_close(m.cross_cov, cross, EXACT_RTOL, "cross_cov")
    e = sm.propagate(model, sm.Gaussian(mu, P), transform=sm.Exact())
    for name in ("mean", "cov", "cross_cov"):
        assert_close(getattr(m, name), getattr(e, name), EXACT_RTOL, f"{name} vs Exact")


def test_tt1_exact_for_affine_and_biased_for_quadratic():
    A, b, c, mu, P, exprs = _quadratic_case(5)
    mean, _, _ = _quadratic_moments(A, b, c, mu, P)
    m = sm.propagate(sm.Model(list(X3), exprs), sm.Gaussian(mu, P), transform=sm.TT1())
    # TT1 misses exactly the tr(A P) term of the mean.
    assert_close(mean - m.mean, [np.trace(A[i] @ P) for i in range(2)], EXACT_RTOL)


# =========================================================================== affine: every transform
ALL_TRANSFORMS = {
    "tt1": sm.TT1(),
    "tt2": sm.TT2(),
    "ut1": sm.UT.ut1(),
    "ut2": sm.UT.ut2(),
    "cubature": sm.UT.cubature(),
    "ut_custom": sm.UT(alpha=0.7, beta=2.0, kappa=1.5),
    "gh_tensor": sm.GaussHermite(3, sparse=False),
    "gh_sparse": sm.GaussHermite(3, sparse=True),
    "exact": sm.Exact(),
}
MC = sm.MonteCarlo(n=64 * 64, seed=3, groups=64)


@st.composite
def affine_problems(draw):
    n = draw(st.integers(1, 3))
    ny = draw(st.integers(1, 3))
    el = st.floats(-3, 3, allow_nan=False, allow_subnormal=False)
    A = draw(arrays(float, (ny, n), elements=el))
    b = draw(arrays(float, (ny,), elements=st.floats(-5, 5, allow_nan=False, allow_subnormal=False)))
    mu = draw(arrays(float, (n,), elements=st.floats(-5, 5, allow_nan=False, allow_subnormal=False)))
    M = draw(arrays(float, (n, n), elements=st.floats(-2, 2, allow_nan=False, allow_subnormal=False)))
    P = M @ M.T + 0.1 * np.eye(n)  # SPD by construction
    return A, b, mu, P


@settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(affine_problems())
def test_every_transform_is_exact_for_affine_models(problem):
    A, b, mu, P = problem
    n = len(mu)
    xs = sp.symbols(f"x0:{n}", real=True)
    exprs = [sum((sp.Float(A[i, j]) * xs[j] for j in range(n)), sp.Float(b[i])) for i in range(A.shape[0])]
    cm = vm(exprs, xs, "affine")
    mean, cov, cross = A @ mu + b, A @ P @ A.T, A @ P
    for name, tr in ALL_TRANSFORMS.items():
        m, C, X, _ = batch1(tr, cm, mu, P)
        tol = rtol_for(tr, EXACT_RTOL)
        assert_close(m, mean, tol, f"{name} mean")
        assert_close(C, cov, tol, f"{name} cov")
        assert_close(X, cross, tol, f"{name} cross")
    m, C, X, se = batch1(MC, cm, mu, P)
    # Rounding floor on the standard error: a zero row of A has zero sampling error.
    floor = 1e-12 * max(1.0, float(np.abs(cov).max()), float(np.abs(mean).max()))
    np.testing.assert_array_less(np.abs(m - mean), N_SE * se["mean"] + floor)
    np.testing.assert_array_less(np.abs(C - cov), N_SE * se["cov"] + floor)
    np.testing.assert_array_less(np.abs(X - cross), N_SE * se["cross_cov"] + floor)


# =========================================================================== declared degree
U2 = sp.symbols("u0:2", real=True)
U5 = sp.symbols("u0:5", real=True)
MU2, P2 = np.array([0.7, -0.4]), np.array([[0.5, 0.1], [0.1, 0.3]])
MU5 = np.array([0.3, -0.5, 0.8, 0.2, -0.1])
P5 = random_spd(np.random.default_rng(4), 5) + 0.2 * np.eye(5)

# transform, inputs, (mean, cov), monomials of degree exact_degree, of degree exact_degree + 1,
# and the moment that is off at degree + 1.  TT2's *mean* is exact for cubics as well (the
# third central moments of a Gaussian vanish), so beyond degree 2 it is its covariance that fails.
DEGREE_CASES = {
    "tt1": (sm.TT1(), U2, (MU2, P2), [U2[0], U2[1]], [U2[0] * U2[1], U2[0] ** 2], "mean"),
    "tt2": (sm.TT2(), U2, (MU2, P2), [U2[0] * U2[1], U2[1] ** 2], [U2[0] ** 3, U2[0] ** 2 * U2[1]], "cov"),
    "ut1": (sm.UT.ut1(), U2, (MU2, P2), [U2[0] ** 3, U2[0] * U2[1] ** 2], [U2[0] ** 2 * U2[1] ** 2], "mean"),
    "ut2": (sm.UT.ut2(), U2, (MU2, P2), [U2[0] ** 3, U2[0] ** 2 * U2[1]], [U2[0] ** 2 * U2[1] ** 2, U2[0] ** 4], "mean"),
    "cubature": (sm.UT.cubature(), U2, (MU2, P2), [U2[0] ** 3, U2[0] * U2[1] ** 2], [U2[0] ** 2 * U2[1] ** 2, U2[1] ** 4], "mean"),
    "gh2": (sm.GaussHermite(2, sparse=False), U2, (MU2, P2), [U2[0] ** 3, U2[0] ** 2 * U2[1]], [U2[0] ** 4], "mean"),
    "gh3": (sm.GaussHermite(3, sparse=False), U2, (MU2, P2), [U2[0] ** 5, U2[0] ** 3 * U2[1] ** 2], [U2[1] ** 6], "mean"),
    "ct5": (sm.transforms.Cubature5(), U2, (MU2, P2), [U2[0] ** 5, U2[0] ** 3 * U2[1] ** 2],
            [U2[0] ** 6, U2[0] ** 2 * U2[1] ** 4], "mean"),
    "gh5_sparse": (
        sm.GaussHermite(5, sparse=True), U5, (MU5, P5),
        [U5[0] * U5[1] * U5[2] * U5[3] * U5[4], U5[0] ** 3 * U5[1] * U5[4]],
        [U5[0] ** 2 * U5[1] ** 2 * U5[2] ** 2],
        "mean",
    ),
}


def _degree(e, syms):
    return sp.Poly(e, *syms).total_degree()


@pytest.mark.parametrize("case", sorted(DEGREE_CASES))
def test_declared_exact_degree(case):
    tr, syms, (mu, P), exact_monos, broken_monos, broken = DEGREE_CASES[case]
    d = tr.exact_degree
    assert all(_degree(e, syms) == d for e in exact_monos)
    assert all(_degree(e, syms) == d + 1 for e in broken_monos)
    cm_ok = vm(exact_monos, syms, f"deg_ok_{case}")
    got, ref = batch1(tr, cm_ok, mu, P), batch1(sm.Exact(), cm_ok, mu, P)
    assert_close(got[0], ref[0], EXACT_RTOL, f"{case}: mean at degree {d}")
    cm_bad = vm(broken_monos, syms, f"deg_bad_{case}")
    got, ref = batch1(tr, cm_bad, mu, P), batch1(sm.Exact(), cm_bad, mu, P)
    k = {"mean": 0, "cov": 1}[broken]
    err = np.abs(got[k] - ref[k])
    assert np.all(err.reshape(len(broken_monos), -1).max(axis=1) > NOT_EXACT_MIN), f"{case}: {broken} exact at degree {d + 1}"


def test_declared_degrees():
    assert (sm.TT1().exact_degree, sm.TT2().exact_degree, sm.UT.ut1().exact_degree) == (1, 2, 3)
    assert [sm.GaussHermite(p, sparse=False).exact_degree for p in (1, 2, 5)] == [1, 3, 9]
    assert sm.GaussHermite(5, sparse=True).exact_degree == 5


# =========================================================================== FilterPy
def _random_smooth_model(seed: int, syms):
    """A random smooth model: sums of products of elementary functions of linear forms."""
    r = np.random.default_rng(seed)
    funcs = [sp.sin, sp.cos, sp.tanh, lambda a: sp.exp(a / 10), lambda a: sp.sqrt(1 + a**2), lambda a: a]
    out = []
    for _ in range(2):
        terms = []
        for _ in range(2):
            f1, f2 = (funcs[i] for i in r.integers(0, len(funcs), 2))
            lin1 = sum(sp.Float(round(c, 3)) * s for c, s in zip(r.normal(size=len(syms)), syms))
            lin2 = sum(sp.Float(round(c, 3)) * s for c, s in zip(r.normal(size=len(syms)), syms))
            terms.append(f1(lin1) * f2(lin2))
        out.append(sum(terms))
    return out


FP_MODELS = {
    "brief": [sp.sin(X3[0]) * X3[1] + sp.exp(sp.Float(0.1) * X3[2]), X3[0] * X3[2] - sp.cos(X3[1])],
    "random0": _random_smooth_model(10, X3),
    "random1": _random_smooth_model(11, X3),
}
FP_PARAMS = [(1.0, 0.0, None), (1.0, 0.0, 0.0), (0.5, 2.0, 1.0), (1e-3, 2.0, 0.0), (2.0, 1.0, -1.0)]


@pytest.mark.parametrize(("alpha", "beta", "kappa"), FP_PARAMS)
@pytest.mark.parametrize("name", sorted(FP_MODELS))
def test_ut_agrees_with_filterpy(name, alpha, beta, kappa):
    from filterpy.kalman import MerweScaledSigmaPoints, unscented_transform

    r = np.random.default_rng(sorted(FP_MODELS).index(name))
    mu = r.normal(size=3)
    P = random_spd(r, 3, scale=0.5)
    exprs = FP_MODELS[name]
    cm = vm(exprs, X3, f"fp_{name}")
    n = 3
    tr = sm.UT(alpha=alpha, beta=beta, kappa=kappa)
    m, C, X, _ = batch1(tr, cm, mu, P)
    # FilterPy's kappa is explicit: ut1's kappa = 3 - n.
    pts = MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=3.0 - n if kappa is None else kappa)
    sig = pts.sigma_points(mu, P)
    Ysig = cm.eval_g(sig)
    fm, fC = unscented_transform(Ysig, pts.Wm, pts.Wc)
    fX = np.einsum("k,ki,kj->ij", pts.Wc, Ysig - fm, sig - mu)
    # FilterPy sums Σ w·Y directly; with α = 1e-3 its weights are ~1e6 and it rounds at
    # ~eps/α² relative, while symmon centres on the middle point first.
    rtol = max(PEER_RTOL, 10 * np.finfo(float).eps / alpha**2)
    assert_close(m, fm, rtol, "mean")
    assert_close(C, fC, rtol, "cov")
    assert_close(X, fX, rtol, "cross")


# =========================================================================== Monte Carlo
POLY = [X3[0] * X3[1] + X3[2] ** 2, X3[0] ** 3 - X3[1]]
POLY_MU = np.array([0.5, -1.0, 0.3])
POLY_P = np.array([[0.4, 0.1, 0.0], [0.1, 0.3, -0.05], [0.0, -0.05, 0.2]])


@pytest.fixture(scope="module")
def poly_model():
    return sm.Model(list(X3), POLY, name="mc_poly")


@pytest.fixture(scope="module")
def poly_exact(poly_model):
    return sm.propagate(poly_model, sm.Gaussian(POLY_MU, POLY_P), transform=sm.Exact())


@pytest.mark.parametrize(
    "tr",
    [sm.MonteCarlo(n=40_000, seed=1, groups=32), sm.MonteCarlo(n=2**15, seed=2, groups=32, qmc=True)],
    ids=["plain", "qmc"],
)
def test_monte_carlo_within_5_se_of_exact(tr, poly_model, poly_exact):
    m = sm.propagate(poly_model, sm.Gaussian(POLY_MU, POLY_P), transform=tr)
    assert m.info["n_samples"] == (40_000 if not tr.qmc else 2**15)
    for name in ("mean", "cov", "cross_cov"):
        err = np.abs(getattr(m, name) - getattr(poly_exact, name))
        se = m.stderr[name]
        assert np.all(se > 0)
        np.testing.assert_array_less(err, N_SE * se, err_msg=name)


@pytest.mark.parametrize("qmc", [False, True], ids=["plain", "qmc"])
def test_monte_carlo_chunking_and_workers_do_not_change_the_result(qmc, poly_model):
    u = sm.Gaussian(POLY_MU, POLY_P)
    base = dict(n=2**14, seed=5, groups=4, qmc=qmc)
    one_shot = sm.propagate(poly_model, u, transform=sm.MonteCarlo(**base, chunk=2**14), executor=sm.Executor(1))
    for kw in (dict(chunk=100, workers=1), dict(chunk=1000, workers=2), dict(chunk=2**14, workers=4)):
        other = sm.propagate(poly_model, u, transform=sm.MonteCarlo(**base, chunk=kw["chunk"]),
                             executor=sm.Executor(kw["workers"]))
        for name in ("mean", "cov", "cross_cov"):
            assert_close(getattr(other, name), getattr(one_shot, name), REORDER_RTOL, f"{name} {kw}")


def test_monte_carlo_is_reproducible_and_seed_dependent(poly_model):
    u = sm.Gaussian(POLY_MU, POLY_P)
    a = sm.propagate(poly_model, u, transform=sm.MonteCarlo(n=4096, seed=9))
    b = sm.propagate(poly_model, u, transform=sm.MonteCarlo(n=4096, seed=9))
    c = sm.propagate(poly_model, u, transform=sm.MonteCarlo(n=4096, seed=10))
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.cov, b.cov)
    assert not np.array_equal(a.mean, c.mean)


@pytest.mark.parametrize("sizes", [[1000], [1, 999], [300, 1, 250, 449], [17] * 10])
def test_merged_shards_equal_concatenated_statistics(sizes, rng):
    # Moderate offsets: with |mean| ≫ std even the one-pass reference Stats.of loses digits.
    Z = rng.normal(size=(sum(sizes), 4)) * [1.0, 10.0, 1e-3, 5.0] + [3.0, -30.0, 0.0, 2.0]
    cuts = np.cumsum(sizes)[:-1]
    shards = [Stats.of(s) for s in np.split(Z, cuts)]
    merged = merge_all(shards)
    whole = Stats.of(Z)
    assert merged.n == whole.n
    assert_close(merged.mean, whole.mean, REORDER_RTOL, "mean")
    assert_close(merged.m2, whole.m2, REORDER_RTOL, "m2")
    np.testing.assert_allclose(whole.cov, np.cov(Z.T), rtol=REORDER_RTOL)
    # merge is symmetric up to rounding.
    if len(shards) >= 2:
        ab, ba = merge(shards[0], shards[1]), merge(shards[1], shards[0])
        assert_close(ab.m2, ba.m2, REORDER_RTOL)


def test_monte_carlo_offset_keeps_the_covariance():
    x, y = sp.symbols("x y", real=True)
    u = sm.Gaussian([1.0, -0.5], [[0.3, 0.1], [0.1, 0.2]])
    tr = sm.MonteCarlo(n=20_000, seed=4, groups=8)
    plain = sm.propagate(sm.Model([x, y], [x * y, x**2 + y]), u, transform=tr)
    shifted = sm.propagate(sm.Model([x, y], [x * y + 10**8, x**2 + y + 10**8]), u, transform=tr)
    assert_close(shifted.cov, plain.cov, OFFSET_RTOL, "cov")
    assert_close(shifted.cross_cov, plain.cross_cov, OFFSET_RTOL, "cross_cov")
    assert_close(shifted.mean - 1e8, plain.mean, OFFSET_RTOL * 1e8 / max(1.0, float(np.abs(plain.mean).max())))


def test_monte_carlo_nan_raises_with_the_count():
    x = sp.Symbol("x", real=True)
    n_group = 1600
    tr = sm.MonteCarlo(n=2 * n_group, seed=3, groups=2, chunk=n_group)
    mean, sd = 0.5, 1.0
    # The count the first group must report: its samples are reproducible from the seed.
    z = group_normals(np.random.SeedSequence(3).spawn(2)[0], n_group, 1)
    expected = int(np.sum(mean + sd * z[:, 0] <= 0.0))
    assert expected > 0
    with pytest.raises(SamplingError, match=rf"NaN or inf at {expected} of {n_group} samples"):
        sm.propagate(sm.Model([x], [sp.log(x)], name="mc_log"), sm.Gaussian([mean], [[sd**2]]), transform=tr)


def test_monte_carlo_sqrt_of_negative_raises():
    x = sp.Symbol("x", real=True)
    with pytest.raises(SamplingError, match=r"NaN or inf at \d+ of"):
        sm.propagate(sm.Model([x], [sp.sqrt(x)], name="mc_sqrt"), sm.Gaussian([0.1], [[1.0]]), transform=sm.MonteCarlo(n=1000, seed=0))


# =========================================================================== Gauss–Hermite sparse grid
def _gauss_moment(alpha) -> float:
    """E Π z_k^{a_k} for z ~ N(0, I): Π (a_k − 1)!! for even a_k, else 0."""
    def dfact(a):
        return prod(range(a - 1, 0, -2)) if a % 2 == 0 else 0
    return float(prod(dfact(a) for a in alpha))


def _monomials(dim: int, degree: int):
    return [a for a in itertools.product(range(degree + 1), repeat=dim) if sum(a) == degree]


@pytest.mark.parametrize(("dim", "order"), [(5, 5), (3, 3), (6, 4)])
def test_sparse_grid_weights_sum_to_one_and_exact_to_total_degree(dim, order):
    Z, w = standard_rule(dim, order, True)
    assert abs(w.sum() - 1.0) < EXACT_RTOL
    level = (order + 1) // 2
    for deg in range(2 * level):  # total degree up to 2·level − 1
        for a in _monomials(dim, deg):
            got = float(w @ np.prod(Z ** np.array(a), axis=1))
            assert abs(got - _gauss_moment(a)) < EXACT_RTOL * max(1.0, _gauss_moment(a)), (a, got)


def test_sparse_grid_is_smaller_than_the_tensor_grid():
    Z, _ = standard_rule(5, 5, True)
    assert len(Z) < 5**5 // 10


def test_sparse_grid_polynomial_model_against_exact():
    # dim 5, order 5 → level 3 → total degree 5 for the mean.
    expr = [U5[0] * U5[1] * U5[2] ** 3 + U5[3] ** 4 * U5[4] - 2 * U5[1] ** 2 + U5[4]]
    cm = vm(expr, U5, "sparse_model")
    got, ref = batch1(sm.GaussHermite(5, sparse=True), cm, MU5, P5), batch1(sm.Exact(), cm, MU5, P5)
    assert_close(got[0], ref[0], EXACT_RTOL, "mean")


def test_gauss_hermite_default_grid_switches_to_sparse_above_four_dims():
    """The fall to the sparse grid is announced once, with the grid's size and degree."""
    cm = vm([sum(U5)], U5, "sum5")
    with pytest.warns(QuadratureWarning, match=r"GaussHermite\(order=3\) in 5 dimensions uses the Smolyak sparse "
                                               r"grid \(11 nodes.*total degree 3 only.*3\^5 = 243 nodes, degree 5"):
        b = sm.GaussHermite(3).moments(cm, MU5[None], P5[None])
    assert b.info["sparse"] is True
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert sm.GaussHermite(3).moments(cm, MU5[None], P5[None]).info["sparse"] is True  # once
        assert sm.GaussHermite(3, sparse=True).moments(cm, MU5[None], P5[None]).info["sparse"] is True
    assert (sm.GaussHermite(3).degree(4), sm.GaussHermite(3).degree(5), sm.GaussHermite(3).exact_degree) == (5, 3, 3)
    b = sm.GaussHermite(3).moments(vm([U2[0] + U2[1]], U2, "sum2"), MU2[None], P2[None])
    assert b.info["sparse"] is False


# =========================================================================== UT presets
@pytest.mark.parametrize(("tr", "params"), [(sm.UT.ut1(), (1.0, 0.0, None)), (sm.UT.ut2(), (1e-3, 2.0, 0.0)), (sm.UT.cubature(), (1.0, 0.0, 0.0))])
def test_ut_presets(tr, params):
    assert (tr.alpha, tr.beta, tr.kappa) == params


@pytest.mark.parametrize("n", [1, 2, 4])
def test_ut1_weights_use_kappa_3_minus_n(n):
    wm, wc, c = sm.UT.ut1().weights(n)
    # κ = 3 − n → n + λ = 3: the points sit at ±√3 standard deviations.
    assert c == pytest.approx(np.sqrt(3.0), rel=1e-15)
    assert wm.sum() == pytest.approx(1.0, rel=1e-15)
    np.testing.assert_array_equal(wm, wc)


# --------------------------------------------------------------------------- extreme settings (issue 13)
@pytest.mark.parametrize(("alpha", "kappa"), [(1e160, None), (1e300, 0.0), (1e100, 1e300)])
def test_ut_whose_weights_overflow_is_refused(alpha, kappa):
    """α² (n + κ) overflowed: Python's OverflowError, or inf weights and NaN moments."""
    x = sp.Symbol("x")
    with pytest.raises(sm.SymmonError, match=r"UT with alpha=.* gives lambda = .* = inf .*overflow"):
        sm.propagate(sm.Model([x], [x**2]), sm.Gaussian([1.0], [[1.0]]), transform=sm.UT(alpha=alpha, kappa=kappa))


def test_propagate_many_refuses_covariances_that_overflow_the_checks():
    """|P − Pᵀ| = inf for ±1e308: refused as asymmetric, with no RuntimeWarning on the way."""
    x, y = sp.symbols("x y")
    P = np.array([[[1e308, -1e308], [1e308, 1e308]]])
    with pytest.raises(sm.SymmonError, match=r"covs\[0\] is not symmetric"):
        sm.propagate_many(sm.Model([x, y], [x * y]), (np.zeros((1, 2)), P), transform=sm.UT.ut1())


# =========================================================================== declared degrees
def _random_monomials(n: int, degree: int, rng: np.random.Generator, count: int = 4) -> list[tuple[int, ...]]:
    """``count`` random exponent vectors of total degree exactly ``degree`` in n variables."""
    out = []
    for _ in range(count):
        e = np.zeros(n, dtype=int)
        for i in rng.integers(0, n, size=degree):
            e[i] += 1
        out.append(tuple(int(k) for k in e))
    return out


DIMENSION_CASES = [(rule, n) for rule in (sm.GaussHermite(2), sm.GaussHermite(3), sm.GaussHermite(3, sparse=True),
                                         sm.GaussHermite(2, sparse=False), sm.UT.ut1()) for n in range(1, 9)]
DIMENSION_CASES += [(sm.Cubature5(), n) for n in range(1, 6)]  # the exact degree-5 reference is slow beyond


@pytest.mark.parametrize("rule, n", DIMENSION_CASES, ids=lambda c: repr(c) if not isinstance(c, int) else f"n={c}")
def test_the_declared_degree_holds_in_every_dimension(rule, n):
    """rule.degree(n) is what the grid used in n dimensions achieves: the mean of random
    monomials of that total degree equals the exact Gaussian moment (closed form), for a
    random mean and covariance."""
    deg = int(rule.degree(n))
    rng = np.random.default_rng(1000 * n + deg)
    z = sp.symbols(f"z0:{n}", real=True)
    monos = [sp.Mul(*[s**k for s, k in zip(z, e)]) for d in {max(deg - 1, 0), deg} for e in _random_monomials(n, d, rng, 2)]
    cm = vm(monos, list(z), f"deg_{n}_{deg}")
    A = rng.standard_normal((n, n))
    mu, P = 0.3 * rng.standard_normal(n), 0.2 * (A @ A.T) / n + 0.3 * np.eye(n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QuadratureWarning)  # the fall to the sparse grid, tested above
        got = rule.moments(cm, mu[None], P[None])
    ref = sm.Exact().moments(cm, mu[None], P[None])
    assert_close(got.mean[0], ref.mean[0], EXACT_RTOL, "mean")
    assert rule.exact_degree <= rule.degree(n)  # the dimension-free declaration is the safe one
