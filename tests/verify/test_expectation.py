"""sm.expect: closed-form Gaussian expectations (issue 37, item 1).

Each closed form of the class (symmon/verify/expectation.py, eqs. (1)–(4)) is checked against
mpmath's tanh-sinh quadrature, in one and two dimensions, at random exact parameters (fixed
seeds), to 1e-12 relative.  In 1-D the quadrature runs at 30 digits; in 2-D mpmath integrates
across the kinks (breakpoints) of a 64-node Gauss–Hermite sum along them in double precision,
good to ~1e-15 (measured: 1e-17 to 1e-15 against the closed forms).  The integrands are
smooth between the kinks, so a miss at 1e-12 is a wrong formula, not rounding.  Polynomials
are also checked against the Exact transform.
"""

from __future__ import annotations

import mpmath as mp
import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import (ArgumentError, ArgumentTypeError, CovarianceError, ExpectationNotClosedForm,
                           ShapeError)
from symmon.verify.expectation import normal_cdf, normal_pdf

#: Closed form against a 30-digit quadrature: the formulas are exact, the reference good to
#: ~25 digits, so 1e-12 leaves room only for an evaluation at double precision somewhere.
RTOL = 1e-12

x, y = sp.symbols("x y", real=True)
m, s = sp.symbols("m s", positive=True)


def _rational(v: float) -> sp.Rational:
    return sp.Rational(v).limit_denominator(10**6)


def _random_gaussian(rng: np.random.Generator, n: int) -> tuple[list, list]:
    """An exact (Rational) mean and positive definite covariance."""
    mu = [_rational(v) for v in rng.uniform(-1, 1, n)]
    A = rng.uniform(-1, 1, (n, n))
    P = A @ A.T + 0.3 * np.eye(n)
    Pr = [[_rational(P[i, j]) for j in range(n)] for i in range(n)]
    for i in range(n):
        for j in range(i):
            Pr[i][j] = Pr[j][i]
    return mu, Pr


def _kinks(expr: sp.Expr, over) -> list[tuple[list, sp.Expr]]:
    """The affine forms (a, a0) whose sign changes are kinks of expr (Abs, Max, Min)."""
    out = []
    for node in sp.preorder_traversal(expr):
        args = None
        if isinstance(node, sp.Abs):
            args = node.args[0]
        elif isinstance(node, (sp.Max, sp.Min)):
            args = node.args[0] - node.args[1]
        if args is not None:
            poly = sp.Poly(args, *over)
            out.append(([poly.coeff_monomial(v) for v in over], poly.coeff_monomial(1)))
    return out


def _mp(v) -> mp.mpf:
    r = sp.Rational(v)
    return mp.mpf(r.p) / r.q


#: Probabilists' Gauss–Hermite rule for the smooth direction of a 2-D integral: 64 nodes
#: integrate the entire integrands here (polynomials of degree ≤ 6 times exponentials and
#: sines of frequency ≤ 4 in whitened units) to far below 1e-14 relative.
_GH_Z, _GH_W = np.polynomial.hermite_e.hermegauss(64)


def quadrature(expr: sp.Expr, over, mu, P, dps: int = 30) -> mp.mpf:
    """E[expr] over x = μ + L z, z ~ N(0, I): mpmath's tanh-sinh quadrature with the kinks
    (Abs, Max, Min) as breakpoints.  In 2-D the whitened plane is rotated so that the first
    coordinate t is normal to the kinks (they must be parallel lines): mpmath.quad over t,
    with the breakpoints, of a Gauss–Hermite sum over the smooth direction r."""
    n = len(over)
    with mp.workdps(dps):
        f = sp.lambdify(over, expr, "mpmath")
        L = mp.cholesky(mp.matrix([[_mp(P[i][j]) for j in range(n)] for i in range(n)]))
        mv = [_mp(v) for v in mu]
        # a kink aᵀ(μ + L z) + a0 = 0 is the line b0 + bᵀz = 0
        lines = [(sum(_mp(a[i]) * mv[i] for i in range(n)) + _mp(a0),
                  [sum(_mp(a[i]) * L[i, j] for i in range(n)) for j in range(n)]) for a, a0 in _kinks(expr, over)]
        g = lambda t: mp.exp(-t * t / 2) / mp.sqrt(2 * mp.pi)
        if n == 1:
            pts = sorted({-b0 / b[0] for b0, b in lines if b[0] != 0})
            return mp.quad(lambda z: f(mv[0] + L[0, 0] * z) * g(z), [-mp.inf, *pts, mp.inf])
        assert n == 2
        normal = [mp.mpf(1), mp.mpf(0)]
        if lines:
            b = lines[0][1]
            normal = [b[0] / mp.norm(b), b[1] / mp.norm(b)]
        along = [-normal[1], normal[0]]
        pts = set()
        for b0, b in lines:
            assert abs(b[0] * along[0] + b[1] * along[1]) < mp.mpf(10) ** (5 - dps), "kinks not parallel"
            pts.add(-b0 / (b[0] * normal[0] + b[1] * normal[1]))
        fn = sp.lambdify(over, expr, "numpy")
        L00, L10, L11 = (float(L[0, 0]), float(L[1, 0]), float(L[1, 1]))
        m0, m1 = float(mv[0]), float(mv[1])
        nr, ar = [float(v) for v in normal], [float(v) for v in along]
        w = _GH_W / np.sqrt(2 * np.pi)

        def inner(t):
            # the smooth direction in double precision (vectorised): 1e-16 relative, far
            # inside the 1e-12 of the test; the outer integral carries the kinks.
            t = float(t)
            z1, z2 = t * nr[0] + _GH_Z * ar[0], t * nr[1] + _GH_Z * ar[1]
            vals = np.broadcast_to(fn(m0 + L00 * z1, m1 + L10 * z1 + L11 * z2), _GH_Z.shape)
            return mp.mpf(float(w @ vals)) * g(t)

        # |t| <= 40: the Gaussian factor e^{-800} is beyond every digit, and float g stays finite
        # and the peak of the Gaussian and its shoulders as breakpoints too
        return mp.quad(inner, sorted({-40, -6, 0, 6, 40} | {p for p in pts if abs(p) < 40}))


def _check(expr, over, mu, P, dps: int = 30):
    closed = sm.expect(expr, over, mu, P)
    assert not closed.free_symbols, closed
    value = sp.N(closed, 30)
    ref = quadrature(expr, over, mu, P, dps)
    assert abs(complex(value) - complex(ref)) <= RTOL * max(abs(complex(ref)), 1e-300), (expr, value, ref)
    return closed


# --------------------------------------------------------------------------- 1-D, every form
ONE_D = {
    "polynomial (1)": x**5 - 3 * x**2 + 2,
    "exp times polynomial (2)": x**2 * sp.exp(sp.Rational(3, 4) * x - 1),
    "sin times polynomial (2)": x * sp.sin(2 * x + 1),
    "cos cubed (2)": sp.cos(x) ** 3,
    "sin cos exp (2)": sp.sin(x) * sp.cos(3 * x - 2) * sp.exp(-x / 2),
    "sinh cosh (2)": sp.sinh(x / 3) + x * sp.cosh(x - 1),
    "positive base power (2)": 2**x,
    "abs (3), Lemma 1": sp.Abs(x - sp.Rational(1, 3)),
    "abs times polynomial (4)": sp.Abs(x + 1) * (x**3 - x),
    "abs times exp (4)": sp.Abs(2 * x - 1) * sp.exp(x / 2),
    "abs cubed (4)": sp.Abs(x - 1) ** 3,
    "abs squared is a polynomial": sp.Abs(x - 1) ** 2 * sp.cos(x),
    "max (3)": sp.Max(x, 1 - x),
    "min times polynomial (4)": sp.Min(x, 0) * x,
    "sum of forms": sp.exp(x) + sp.Abs(x) + sp.cos(x) ** 2 - x**2,
}


@pytest.mark.parametrize("name", list(ONE_D))
def test_one_dimensional_closed_forms_match_quadrature(name):
    rng = np.random.default_rng(37 + list(ONE_D).index(name))
    mu, P = _random_gaussian(rng, 1)
    _check(ONE_D[name], [x], mu, P)


TWO_D = {
    "polynomial with cross-covariance (1)": x**2 * y**3 - x * y + 1,
    "exp times polynomial (2)": x * y * sp.exp(x - 2 * y),
    "sin cos of two affine forms (2)": x * sp.sin(x + y) * sp.cos(x - 2 * y),
    "abs of an affine form (3), Theorem 1": sp.Abs(x - 2 * y + 1),
    "abs times polynomial (4)": sp.Abs(x + y) * x * y,
    "abs times exp (4)": sp.Abs(x - y) * sp.exp(y / 2),
    "max of two affine forms (3)": sp.Max(x, 2 * y + 1),
    "min squared (3), (4)": sp.Min(x, y) ** 2,
    "max times polynomial (4)": sp.Max(x, y) * x,
    "abs times abs of a multiple": sp.Abs(x - y) * sp.Abs(2 * y - 2 * x),
}


@pytest.mark.parametrize("name", list(TWO_D))
def test_two_dimensional_closed_forms_match_quadrature(name):
    rng = np.random.default_rng(101 + list(TWO_D).index(name))
    mu, P = _random_gaussian(rng, 2)
    _check(TWO_D[name], [x, y], mu, P, dps=15)


# --------------------------------------------------------------------------- symbolic forms
def test_lemma_1_of_the_mmse_paper_symbolically():
    """E|x| = m(1 − 2Φ(−m/s)) + 2sφ(m/s), eq. (8), for symbolic m and s."""
    lemma = m * (1 - 2 * normal_cdf(-m / s)) + 2 * s * normal_pdf(m / s)
    assert sp.simplify(sm.expect(sp.Abs(x), x, [m], [[s**2]]) - lemma) == 0


def test_symbolic_cross_covariance():
    mx, my, a, b = sp.symbols("mu_x mu_y P_x_x P_y_y", real=True)
    c = sp.Symbol("P_x_y", real=True)
    P = sp.Matrix([[a, c], [c, b]])
    assert sp.expand(sm.expect(x * y, [x, y], [mx, my], P) - (mx * my + c)) == 0
    # Isserlis: E x²y² = (μx² + a)(μy² + b) + 2c² + 4 μx μy c
    want = (mx**2 + a) * (my**2 + b) + 2 * c**2 + 4 * mx * my * c
    assert sp.expand(sm.expect(x**2 * y**2, [x, y], [mx, my], P) - want) == 0
    # the characteristic function of x − y
    got = sm.expect(sp.cos(x - y), [x, y], [mx, my], P)
    assert sp.simplify(got - sp.exp(-(a + b - 2 * c) / 2) * sp.cos(mx - my)) == 0
    # Theorem 1 with L = x − y: m = μx − μy, s² = a + b − 2c
    d, v = mx - my, a + b - 2 * c
    theorem = d * (1 - 2 * normal_cdf(-d / sp.sqrt(v))) + 2 * sp.sqrt(v) * normal_pdf(d / sp.sqrt(v))
    assert sp.simplify(sm.expect(sp.Abs(x - y), [x, y], [mx, my], P) - theorem) == 0


def test_characteristic_function_is_complex():
    t = sp.Symbol("t", real=True)
    got = sm.expect(sp.exp(sp.I * t * x), x, [m], [[s**2]])
    assert sp.simplify(got - sp.exp(sp.I * t * m - t**2 * s**2 / 2)) == 0


def test_degenerate_variance_of_an_abs_is_the_abs_of_its_mean():
    """x = y almost surely: |x − y| = 0 and |x − y + 2| = 2."""
    assert sm.expect(sp.Abs(x - y + 2) * x, [x, y], [1, 1], [[1, 1], [1, 1]]) == 2


# --------------------------------------------------------------------------- exact arithmetic
def test_exact_numbers_stay_exact_and_floats_stay_floats():
    got = sm.expect(x**4 + sp.Abs(x), x, [1], [[sp.Rational(1, 3)]])
    assert not got.atoms(sp.Float)
    assert sm.expect(x**2, x, [1], [[sp.Rational(1, 3)]]) == sp.Rational(4, 3)
    assert sm.expect(x**2, x, np.array([2]), np.array([[3]])) == 7  # numpy ints are exact too
    f = sm.expect(x**2, x, [1.5], [[0.5]])
    assert f.atoms(sp.Float) and float(f) == pytest.approx(2.75, rel=1e-15)


def test_polynomials_agree_with_the_exact_transform():
    model = sm.Model([x, y], [x**3 * y - 2 * y**2, x * y + x**4])
    u = sm.Gaussian([0.4, -1.2], [[0.5, 0.2], [0.2, 0.8]])
    exact = sm.propagate(model, u, transform=sm.Exact())
    g = model.outputs
    mean = [sm.expect(gi, [x, y], u.mean, u.cov) for gi in g]
    np.testing.assert_allclose([float(v) for v in mean], exact.mean, rtol=1e-12)
    cov = [[float(sm.expect(gi * gj, [x, y], u.mean, u.cov) - mean[i] * mean[j]) for j, gj in enumerate(g)]
           for i, gi in enumerate(g)]
    np.testing.assert_allclose(cov, exact.cov, rtol=1e-11, atol=1e-12 * np.abs(exact.cov).max())


# --------------------------------------------------------------------------- outside the class
OUTSIDE = {
    "sqrt": (sp.sqrt(x**2 + y**2), "sqrt"),
    "atan2": (sp.atan2(y, x), "atan2"),
    "exp of a square": (sp.exp(x**2), "exp(x**2)"),
    "a reciprocal": (1 / (1 + x**2), "1/(x**2 + 1)"),
    "two different absolute values": (sp.Abs(x) * sp.Abs(y), "Abs(x)*Abs(y)"),
    "abs times sine": (sp.Abs(x) * sp.sin(y), "sine or cosine"),
    "max of three": (sp.Max(x, y, 0), "Max of 3 arguments"),
    "abs of a square minus one": (sp.Abs(x**2 - 1), "Abs(x**2 - 1)"),
    "log": (sp.log(1 + x**2), "log"),
    "sign": (sp.sign(x), "sign"),
    "a negative base": ((-2) ** x, "positive base"),
}


@pytest.mark.parametrize("name", list(OUTSIDE))
def test_outside_the_class_is_refused_naming_the_subexpression(name):
    expr, said = OUTSIDE[name]
    with pytest.raises(ExpectationNotClosedForm, match="outside the class") as info:
        sm.expect(expr * x + 1, [x, y], [0, 1], [[1, 0], [0, 1]])
    assert said in str(info.value)


# --------------------------------------------------------------------------- bad arguments
@pytest.mark.parametrize("call, error, said", [
    (lambda: sm.expect("x**2", x, [0], [[1]]), ArgumentTypeError, "string"),
    (lambda: sm.expect(x, "x", [0], [[1]]), ArgumentTypeError, "over"),
    (lambda: sm.expect(x, [x, x], [0, 0], np.eye(2)), ArgumentError, "twice"),
    (lambda: sm.expect(x, [x, y], [0], np.eye(2)), ShapeError, "mean"),
    (lambda: sm.expect(x, [x, y], [0, 0], [[1, 0]]), ShapeError, "cov"),
    (lambda: sm.expect(x, [x, y], [0, 0], [[1, 1], [0, 1]]), CovarianceError, "symmetric"),
    (lambda: sm.expect(x, [x, y], [0, 0], [[1, 2], [2, 1]]), CovarianceError, "semi-definite"),
    (lambda: sm.expect(x, [x], [x], [[1]]), ArgumentError, "integration variables"),
    (lambda: sm.expect(x, [x], [0], [[-1]]), CovarianceError, "negative"),
])
def test_bad_arguments_are_clear_errors(call, error, said):
    with pytest.raises(error, match=said):
        call()


def test_a_scalar_mean_and_variance_for_one_variable():
    assert sm.expect(x**2, x, 1, 2) == 3
