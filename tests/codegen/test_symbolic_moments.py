"""The CasADi moment formulas of symmon.codegen.symbolic, in SX and in MX.

The Cholesky factor against NumPy's (positive definite, semidefinite with a zero variance,
indefinite, a non-symmetric input), built four ways: in SX, in MX, MX expanded to SX, and
an MX function called on SX symbols (the two ways an MX graph reaches a filter's SX step).
The moments against the NumPy transforms of symmon.transforms, and the filter names that
the transforms declare.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import SymmonError
from symmon.core.gaussian import matrix_sqrt
from symmon.compile import compiled
from symmon.codegen.symbolic import (_tt2_derivatives, affine_in, chol_lower, chol_node, jacobian_products,
                                     moments, tril_inverse, unit_rule)
from symmon.transforms.cubature5 import Cubature5

#: Two implementations of the same Cholesky algorithm in double precision that sum in a
#: different order: each entry differs by rounding, about n·ε·κ(P) relative to max |L|
#: (≈ 10 · 2.2e-16 · 6 for the matrices below, whose eigenvalues lie in [n, ~6n]);
#: 1e-12 leaves a margin of about 50× over that bound (observed: ≤ 1e-15).
CHOL_RTOL = 1e-12
#: The same closed forms (TT1, TT2, weighted sums over the same points) evaluated by a
#: CasADi graph and by batched NumPy in a different order of operations: rounding,
#: relative to each array's scale.
MOMENT_RTOL = 1e-10

BUILDS = ["sx", "mx", "mx-expanded", "mx-called-on-sx", "blocked-mx", "blocked-sx"]
#: Sizes of the factor tests: the blocked factor unrolls blocks of CHOL_BLOCK = 8.
SIZES = [*range(1, 11), 17, 20]


def chol_function(n: int, build: str) -> ca.Function:
    """P ↦ chol_lower(P) (or the blocked chol_node) as a CasADi function, built one of the ways."""
    if build.startswith("blocked"):
        kind = ca.MX if build == "blocked-mx" else ca.SX
        P = kind.sym("P", n, n)
        return ca.Function("chol_blocked", [P], [chol_node(P)])
    if build == "sx":
        P = ca.SX.sym("P", n, n)
        return ca.Function("chol", [P], [chol_lower(P)])
    P = ca.MX.sym("P", n, n)
    f = ca.Function("chol", [P], [chol_lower(P)])
    if build == "mx-expanded":
        return f.expand()
    if build == "mx-called-on-sx":
        Ps = ca.SX.sym("P", n, n)
        return ca.Function("chol_sx", [Ps], [f(Ps)], {"cse": True})  # as the filter step: CSE on
    return f


def spd(n: int, rng: np.random.Generator) -> np.ndarray:
    """A random symmetric positive definite matrix with eigenvalues in [n, ~6n]."""
    A = rng.standard_normal((n, n))
    return A @ A.T + n * np.eye(n)


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


# --------------------------------------------------------------------------- Cholesky
@pytest.mark.parametrize("build", BUILDS)
@pytest.mark.parametrize("n", SIZES)
def test_cholesky_equals_numpy(n, build):
    rng = np.random.default_rng(100 + n)
    f = chol_function(n, build)
    for _ in range(3):
        P = spd(n, rng)
        assert rel(f(P).full(), np.linalg.cholesky(P)) <= CHOL_RTOL


@pytest.mark.parametrize("build", BUILDS)
@pytest.mark.parametrize("n", SIZES)
def test_cholesky_of_a_zero_variance_has_a_zero_row_and_column(n, build):
    """A positive semidefinite P with P[z, z] = 0 (and its row and column): the factor of
    the other entries, with zeros at z, as matrix_sqrt continues a singular Cholesky."""
    rng = np.random.default_rng(200 + n)
    f = chol_function(n, build)
    P = spd(n, rng)
    z = int(rng.integers(n))
    P[z, :] = P[:, z] = 0.0
    L = f(P).full()
    assert np.all(L[z, :] == 0) and np.all(L[:, z] == 0)
    if n > 1:
        keep = np.delete(np.arange(n), z)
        assert rel(L[np.ix_(keep, keep)], np.linalg.cholesky(P[np.ix_(keep, keep)])) <= CHOL_RTOL
        assert rel(L, matrix_sqrt(P)) <= CHOL_RTOL


@pytest.mark.parametrize("build", BUILDS)
def test_cholesky_of_an_indefinite_matrix_is_nan(build):
    """The negative pivot of column 1 gives NaN there (in MX the dense update L + c e_jᵀ
    spreads it over row 1, 0·NaN; SX folds the product with the constant e_j)."""
    L = chol_function(2, build)(np.array([[1.0, 2.0], [2.0, 1.0]])).full()
    assert L[0, 0] == 1.0 and L[0, 1] == 0.0 and np.isnan(L[1, 1])


@pytest.mark.parametrize("kind", [ca.SX, ca.MX])
@pytest.mark.parametrize("n", SIZES)
def test_the_triangular_inverse_equals_numpy(n, kind):
    rng = np.random.default_rng(300 + n)
    P = kind.sym("P", n, n)
    f = ca.Function("inv", [P], [tril_inverse(chol_node(P))])
    for _ in range(2):
        A = spd(n, rng)
        want = np.linalg.inv(np.linalg.cholesky(A))
        got = f(A).full()
        assert np.all(np.triu(got, 1) == 0)
        # Substitution and NumPy's LAPACK inverse: rounding of order n·ε·κ(L).
        assert rel(got, want) <= CHOL_RTOL


@pytest.mark.parametrize("n", [3, 9, 17])
def test_the_triangular_inverse_of_a_zero_pivot_has_a_zero_row_and_column(n):
    rng = np.random.default_rng(400 + n)
    A = spd(n, rng)
    z = n // 2
    A[z, :] = A[:, z] = 0.0
    P = ca.MX.sym("P", n, n)
    got = ca.Function("inv", [P], [tril_inverse(chol_node(P))])(A).full()
    assert np.all(got[z, :] == 0) and np.all(got[:, z] == 0)
    keep = np.delete(np.arange(n), z)
    assert rel(got[np.ix_(keep, keep)], np.linalg.inv(np.linalg.cholesky(A[np.ix_(keep, keep)]))) <= CHOL_RTOL


@pytest.mark.parametrize("density", ["sparse", "dense"])
def test_the_jacobian_products_equal_numpy_sparse_or_dense(density):
    rng = np.random.default_rng(5)
    n, n_y = 12, 7
    pattern = rng.random((n_y, n)) < (0.2 if density == "sparse" else 0.9)
    x, P = ca.MX.sym("x", n), ca.MX.sym("P", n, n)
    J = ca.mtimes(ca.sparsify(ca.DM(pattern.astype(float))), ca.diag(x))  # J's pattern is the mask
    assert (J.nnz() <= 0.5 * J.numel()) == (density == "sparse")
    JP, cov = jacobian_products(J, P)
    f = ca.Function("jp", [x, P], [JP, cov])
    xv, Pv = rng.normal(size=n), spd(n, rng)
    Jv = pattern * xv
    got_JP, got_cov = (a.full() for a in f(xv, Pv))
    assert rel(got_JP, Jv @ Pv) <= MOMENT_RTOL
    assert rel(got_cov, Jv @ Pv @ Jv.T) <= MOMENT_RTOL


def affine_model(angle: bool) -> sm.Model:
    x = sp.symbols("a0:5", real=True)
    out = [x[0] + 2 * x[1] - x[4], 3 * x[2] + 0.5, x[3] - x[0]]
    return sm.Model(list(x), out, name=f"affine5{'_angle' if angle else ''}", angles=[2] if angle else [])


@pytest.mark.parametrize("transform", [sm.UT(1, 2, 0), sm.UT.ut2(), sm.UT.cubature(), sm.GaussHermite(3, sparse=False)])
def test_a_rule_on_an_affine_model_builds_the_exact_closed_forms(transform):
    """On an affine g with no angle outputs, a rule exact to degree 2 gives g(m), J P Jᵀ, J P:
    TT1's graph to the bit (no points), and the NumPy rule's moments to rounding."""
    model = affine_model(angle=False)
    cm = compiled(model)
    assert affine_in(cm, 5) and not affine_in(compiled(blocks_model()), 5)
    m, P = ca.MX.sym("m", 5), ca.MX.sym("P", 5, 5)
    f = ca.Function("mom", [m, P], list(moments(cm, m, P, transform)))
    tt1 = ca.Function("tt1", [m, P], list(moments(cm, m, P, sm.TT1())))
    rng = np.random.default_rng(11)
    mv, Pv = rng.normal(size=5), spd(5, rng)
    got = [a.full() for a in f(mv, Pv)]
    assert all(np.array_equal(a, b.full()) for a, b in zip(got, tt1(mv, Pv)))
    ref = sm.propagate(model, sm.Gaussian(mv, Pv), transform=transform)
    assert rel(got[0].ravel(), ref.mean) <= MOMENT_RTOL
    assert rel(got[1], ref.cov) <= MOMENT_RTOL


def test_an_affine_model_with_an_angle_output_keeps_the_points():
    """A declared angle output has a circular mean, which no closed form gives: the points stay."""
    model = affine_model(angle=True)
    cm = compiled(model)
    m, P = ca.MX.sym("m", 5), ca.MX.sym("P", 5, 5)
    f = ca.Function("mom", [m, P], list(moments(cm, m, P, sm.UT(1, 2, 0), angles=[2])))
    mv, Pv = np.array([0.0, 0.0, 1.0, 0.0, 0.0]), np.eye(5)  # output 2 = 3 a2 + 0.5 spreads over the cut
    ref = sm.propagate(model, sm.Gaussian(mv, Pv), transform=sm.UT(1, 2, 0))
    got = [a.full() for a in f(mv, Pv)]
    assert rel(got[0].ravel(), ref.mean) <= MOMENT_RTOL
    assert abs(got[0][2, 0] - 3.5) > 0.1  # the circular mean, not g(m)


@pytest.mark.parametrize("build", BUILDS)
def test_cholesky_reads_the_lower_triangle(build):
    rng = np.random.default_rng(7)
    P = spd(5, rng)
    garbled = np.tril(P) + np.triu(rng.standard_normal((5, 5)), 1)
    assert rel(chol_function(5, build)(garbled).full(), np.linalg.cholesky(P)) <= CHOL_RTOL


# --------------------------------------------------------------------------- moments
def blocks_model() -> sm.Model:
    """Ten inputs, Hessians on two inputs each: TT2 takes the Hessian blocks."""
    x = sp.symbols("x0:10", real=True)
    return sm.Model(list(x), [sp.atan2(x[1], x[0]), sp.sqrt(x[2] ** 2 + x[3] ** 2 + 1), x[4] * x[5],
                              sp.sin(x[6]) * x[7]], name="symmom_blocks", angles=[0])


def dense_model() -> sm.Model:
    """Three inputs, Hessians on all of them: TT2 takes H_i P per output."""
    x, y, z = sp.symbols("x y z", real=True)
    return sm.Model([x, y, z], [sp.atan2(y, x) + z**2 / 10, x * y * z], name="symmom_dense", angles=[0])


def gaussian(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    m = rng.uniform(0.5, 1.5, n)
    m[:2] = [1.0, 0.7]  # the angle output atan2(·, ·) stays far from its cut at ±π
    A = rng.standard_normal((n, n)) / np.sqrt(n)
    return m, 0.05 * (A @ A.T) + 0.01 * np.eye(n)


TRANSFORMS = [sm.TT1(), sm.TT2(), sm.UT.ut1(), sm.UT(1.0, 2.0, 0.0), sm.UT.cubature(), sm.GaussHermite(3, sparse=True),
              Cubature5()]


@pytest.mark.parametrize("kind", [ca.SX, ca.MX], ids=["sx", "mx"])
@pytest.mark.parametrize("transform", TRANSFORMS, ids=repr)
@pytest.mark.parametrize("factory", [blocks_model, dense_model], ids=["blocks", "dense"])
def test_moments_equal_the_numpy_transforms(factory, transform, kind):
    model = factory()
    cm = compiled(model)
    angles = frozenset(model.angle_outputs)
    m, P = gaussian(cm.n_w, 3)
    ms, Ps = kind.sym("m", cm.n_w), kind.sym("P", cm.n_w, cm.n_w)
    f = ca.Function("moments", [ms, Ps], list(moments(cm, ms, Ps, transform, angles)))
    ref = transform.moments(cm, m[None], P[None], angles)
    for got, want in zip(f(m, P), (ref.mean[0], ref.cov[0], ref.cross_cov[0])):
        got = np.array(ca.densify(got)).reshape(want.shape)
        np.testing.assert_allclose(got, want, rtol=MOMENT_RTOL, atol=MOMENT_RTOL * np.abs(want).max())


def test_both_tt2_paths_are_exercised():
    assert _tt2_derivatives(compiled(blocks_model()))[1] is True
    assert _tt2_derivatives(compiled(dense_model()))[1] is False


def test_the_circular_mean_crosses_the_cut():
    """An angle output near ±π: the weighted circular mean and wrapped residuals (SX, MX)
    equal the UT's, where a plain weighted mean would be near 0."""
    x, y = sp.symbols("x y", real=True)
    model = sm.Model([x, y], [sp.atan2(y, x)], name="symmom_cut", angles=[0])
    cm = compiled(model)
    m, P = np.array([-1.0, 1e-3]), np.diag([0.01, 0.04])
    ref = sm.UT.ut1().moments(cm, m[None], P[None], frozenset({0}))
    assert abs(ref.mean[0, 0]) > 3.0  # the mean sits at the cut
    for kind in (ca.SX, ca.MX):
        ms, Ps = kind.sym("m", 2), kind.sym("P", 2, 2)
        f = ca.Function("ut", [ms, Ps], list(moments(cm, ms, Ps, sm.UT.ut1(), [0])))
        mean, cov, _ = (np.array(ca.densify(a)) for a in f(m, P))
        np.testing.assert_allclose(mean.ravel(), ref.mean[0], rtol=MOMENT_RTOL)
        np.testing.assert_allclose(cov, ref.cov[0], rtol=MOMENT_RTOL)


@pytest.mark.parametrize("transform", [sm.TT2(), sm.MonteCarlo(n=100, seed=0), "ut1"], ids=repr)
def test_a_rule_without_points_is_refused(transform):
    with pytest.raises(SymmonError, match="not a point rule"):
        unit_rule(transform, 2)


# --------------------------------------------------------------------------- filter names
@pytest.mark.parametrize("transform, label", [
    (sm.TT1(), "EKF"), (sm.TT2(), "EKF2"), (sm.UT.cubature(), "CKF"),
    (sm.UT(1.0, 2.0, 0.0), "UKF(alpha=1.0, beta=2.0, kappa=0.0)"), (sm.UT.ut1(), "UKF(alpha=1.0, beta=0.0, kappa=None)"),
    (sm.GaussHermite(3), "GHKF(order=3)"), (Cubature5(), "KF(Cubature5())"),
])
def test_each_rule_declares_its_filter_name(transform, label):
    assert transform.filter_label() == label
    x = sp.Symbol("x", real=True)
    kf = sm.NonlinearKalmanFilter(sm.Model([x], [x], name="symmom_f"), sm.Model([x], [x], name="symmom_h"),
                                  [[1.0]], [[1.0]], transform)
    assert kf.method == label


def test_the_circle_function_gives_g_and_the_sines_and_cosines_of_its_angles():
    """[g; sin y_A; cos y_A] for A = sorted angles: a bearing's by a / r, b / r, an atan2
    plus noise by sin and cos; equal to NumPy's sin and cos of g to a few ulps, made once
    per angle set."""
    cm = compiled(dense_model())  # y0 = atan2(y, x) + z²/10: not a bare bearing
    x, y = sp.symbols("x y", real=True)
    bearing = compiled(sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="symmom_circle", angles=[1]))
    rng = np.random.default_rng(7)
    for model, angles in ((cm, [0]), (bearing, [1]), (bearing, [])):
        f = model.circle_function(angles)
        assert f is model.circle_function(list(reversed(angles)))  # cached by the sorted rows
        for w in [*rng.standard_normal((20, model.n_w)) * 3, np.zeros(model.n_w)]:
            out = np.array(f(w)).ravel()
            g = np.array(model.g(w)).ravel()
            k = len(angles)
            assert out.shape == (model.n_y + 2 * k,)
            np.testing.assert_array_equal(out[:model.n_y], g)
            ya = g[angles]
            np.testing.assert_allclose(out[model.n_y:model.n_y + k], np.sin(ya), rtol=0, atol=4e-16)
            np.testing.assert_allclose(out[model.n_y + k:], np.cos(ya), rtol=0, atol=4e-16)


def test_functions_of_the_parameters_run_once_per_batch_of_points_in_mx(monkeypatch):
    """In MX the points are one map; a libm function of the parameters alone (the growth
    model's cos 1.2k) is split out of it (symmon.compile.vecmath.split_parameters) and
    evaluated once: the moments are the unsplit graph's, bit for bit, on 10 states."""
    import symmon.codegen.symbolic as symbolic
    from symmon.compile.compiled import compiled_with_params
    from symmon.compile.vecmath import split_parameters

    n = 10
    xs = sp.symbols(f"x0:{n}", real=True)
    k, a = sp.symbols("k a", real=True)
    outs = [x / 2 + 25 * x / (1 + x**2) + 8 * sp.cos(sp.Rational(6, 5) * k) + sp.exp(a) * xs[(i + 1) % n]
            for i, x in enumerate(xs)] + [sp.atan2(xs[0], xs[1] + a)]
    model = sm.Model(list(xs), outs, params=[k, a], name="sym_split")
    cm = compiled_with_params(model)
    assert split_parameters(cm.g, n) is not None and split_parameters(compiled_with_params(
        sm.Model(list(xs), list(xs), params=[k], name="sym_nosplit")).g, n) is None
    m, P, p = ca.MX.sym("m", n), ca.MX.sym("P", n, n), ca.MX.sym("p", 2)
    built = {}
    for name, fn in (("split", split_parameters), ("whole", lambda g, n_row: None)):
        monkeypatch.setattr(symbolic, "split_parameters", fn)
        out = moments(cm, m, P, sm.transforms.UT(), (), chol_node, p)
        built[name] = ca.Function(f"mom_{name}", [m, P, p], list(out))
    rng = np.random.default_rng(4)
    A = rng.standard_normal((n, n))
    args = [rng.standard_normal(n) * 2, A @ A.T + n * np.eye(n), np.array([7.0, 0.3])]
    got, want = built["split"](*args), built["whole"](*args)
    assert [str(f) for f in built.values()] and built["split"].n_nodes() != built["whole"].n_nodes()
    for g_, w_ in zip(got, want):
        np.testing.assert_array_equal(np.array(g_), np.array(w_))
