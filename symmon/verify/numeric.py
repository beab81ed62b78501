"""Numeric references for a claim that has no closed form: Gaussian integrals with error bars.

When :func:`symmon.expect` cannot give E[f(x)] in closed form (``ExpectationNotClosedForm``),
a claim about it can still be checked at points, against a reference whose error is known:

- one dimension: mpmath's adaptive quadrature in 30 digits, split at the kinks of f (the zeros
  of the arguments of ``Abs``, ``Max``, ``Min``, ``sign``, ``Heaviside``), with its own error
  estimate;
- two or three dimensions: tensor Gauss–Hermite rules of two orders, the error the
  difference of the two times :data:`GH_SAFETY` (the estimate of
  :class:`symmon.GaussHermite`'s ``error_estimate``);
- more dimensions: Monte Carlo with a seeded ``numpy.random.Generator``, the error
  :data:`MC_SIGMAS` standard errors.

Every result is a value and an error bound per function; a reference is never a proof, and
:mod:`symmon.verify.verification` says "consistent", never "proved", from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import mpmath
import numpy as np
import sympy as sp

from ..errors import NonFiniteError, SingularMatrixError
from ..transforms.nodes import standard_rule

__all__ = ["Reference", "gaussian_integrals", "GH_ORDERS", "GH_SAFETY", "MC_SAMPLES", "MC_SIGMAS", "QUAD_DPS"]

#: Digits of the one-dimensional quadrature.
QUAD_DPS = 30
#: Gauss–Hermite orders per dimension (the pair whose difference is the error estimate).
GH_ORDERS = {2: (40, 48), 3: (16, 20)}
#: The orders of the independent re-check in two dimensions.
GH_REFINED = (64, 80)
#: The difference of the two Gauss–Hermite orders, times this, is the error bound.
GH_SAFETY = 10.0
#: Monte Carlo samples of the reference above three dimensions (and of its re-check, times 4).
MC_SAMPLES = 2**18
#: Standard errors a Monte Carlo reference may be off.
MC_SIGMAS = 5.0
#: Relative rounding of a double-precision sum of many terms, added to the GH and MC bounds.
DOUBLE_RTOL = 1e-13

_KINKS = (sp.Abs, sp.Max, sp.Min, sp.sign, sp.Heaviside)


@dataclass(frozen=True)
class Reference:
    """Values of E[f_k(x)] and their error bounds (same length, mpmath numbers: the 1-D
    quadrature's carry its 30 digits), and how they were computed."""

    values: tuple[mpmath.mpf, ...]
    errors: tuple[mpmath.mpf, ...]
    method: str


def _kink_points(funcs: Sequence[sp.Expr], x: sp.Symbol) -> list[sp.Expr]:
    """Real zeros in x of the arguments of the kinks of the functions (1-D breakpoints)."""
    args: list[sp.Expr] = []
    for f in funcs:
        for atom in f.atoms(*_KINKS):
            if isinstance(atom, (sp.Max, sp.Min)):
                a = list(atom.args)
                args += [a[i] - a[j] for i in range(len(a)) for j in range(i + 1, len(a))]
            else:
                args.append(atom.args[0])
    zeros: list[sp.Expr] = []
    for a in args:
        if not a.has(x):
            continue
        try:
            poly = sp.Poly(a, x)
        except sp.PolynomialError:
            continue
        if poly.degree() > 4:
            continue
        zeros += [r for r in sp.roots(poly, filter="R")]
    return zeros


def _quad_1d(funcs: Sequence[sp.Expr], x: sp.Symbol, m: sp.Expr, var: sp.Expr, dps: int) -> Reference:
    with mpmath.workdps(dps):
        mm, sd = mpmath.mpf(sp.N(m, dps + 5)), mpmath.sqrt(mpmath.mpf(sp.N(var, dps + 5)))
        if sd == 0:
            raise SingularMatrixError("the variance of the expectation is 0: no Gaussian integral to take")
        breaks = sorted({float(sp.N((z - m), 20)) / float(sd) for z in _kink_points(funcs, x)})
        pts = [-mpmath.inf, *[mpmath.mpf(b) for b in breaks], mpmath.inf]
        vals, errs = [], []
        norm = 1 / mpmath.sqrt(2 * mpmath.pi)
        for f in funcs:
            fn = sp.lambdify([x], f, modules="mpmath")

            def integrand(z, fn=fn):
                return fn(mm + sd * z) * mpmath.exp(-z * z / 2) * norm

            v, e = mpmath.quad(integrand, pts, error=True, maxdegree=10)
            if not (mpmath.isfinite(v) and mpmath.im(v) == 0):
                raise NonFiniteError(f"E[{f}] is not a finite real number at this point ({v})")
            # the quadrature's estimate, and the last digits of the working precision
            bound = 10 * abs(e) + mpmath.mpf(10) ** (-(dps - 5)) * max(1, abs(v))
            vals.append(+v)
            errs.append(+bound)
    return Reference(tuple(vals), tuple(errs), f"mpmath quadrature in {dps} digits (split at the kinks)")


def _evaluate(funcs: Sequence[sp.Expr], over: Sequence[sp.Symbol], X: np.ndarray) -> np.ndarray:
    """The functions at the rows of X, shape (len(funcs), len(X)); non-finite values refused."""
    fn = sp.lambdify(list(over), list(funcs), modules="numpy")
    with np.errstate(all="ignore"):
        out = fn(*[X[:, i] for i in range(X.shape[1])])
    vals = np.array([np.broadcast_to(np.asarray(v, dtype=complex), (X.shape[0],)) for v in out])
    if not np.all(np.isfinite(vals)) or np.any(np.abs(vals.imag) > 0):
        raise NonFiniteError("the integrand is not a finite real number at some node of the reference rule")
    return vals.real


def _gauss_hermite(funcs: Sequence[sp.Expr], over: Sequence[sp.Symbol], m: np.ndarray, L: np.ndarray,
                   orders: tuple[int, int]) -> Reference:
    lo, hi = orders
    res = []
    for order in (lo, hi):
        Z, w = standard_rule(len(over), order, sparse=False)
        F = _evaluate(funcs, over, m + Z @ L.T)
        res.append((F @ w, np.abs(F) @ w))
    (a, scale), (b, _) = res
    err = GH_SAFETY * np.abs(a - b) + DOUBLE_RTOL * scale
    return Reference(tuple(mpmath.mpf(float(v)) for v in b), tuple(mpmath.mpf(float(e)) for e in err),
                     f"tensor Gauss-Hermite of orders {lo} and {hi} (error: {GH_SAFETY:g} x their difference)")


def _monte_carlo(funcs: Sequence[sp.Expr], over: Sequence[sp.Symbol], m: np.ndarray, L: np.ndarray,
                 samples: int, seed: int) -> Reference:
    rng = np.random.default_rng(seed)
    Z = rng.standard_normal((samples, len(over)))
    F = _evaluate(funcs, over, m + Z @ L.T)
    mean = F.mean(axis=1)
    se = F.std(axis=1, ddof=1) / np.sqrt(samples)
    err = MC_SIGMAS * se + DOUBLE_RTOL * np.abs(F).mean(axis=1)
    return Reference(tuple(mpmath.mpf(float(v)) for v in mean), tuple(mpmath.mpf(float(e)) for e in err),
                     f"Monte Carlo, {samples} samples, seed {seed} (error: {MC_SIGMAS:g} standard errors)")


def gaussian_integrals(funcs: Sequence[sp.Expr], over: Sequence[sp.Symbol], mean: Sequence[sp.Expr],
                       cov: sp.Matrix, *, refine: bool = False, seed: int = 0) -> Reference:
    """E[f_k(x)] for x ~ N(mean, cov), numbers (the functions' other symbols substituted).

    Parameters
    ----------
    funcs : sequence of sympy.Expr
        Functions of the symbols ``over`` only.
    over : sequence of sympy.Symbol
    mean, cov
        Numeric (exact or float) mean and covariance.
    refine : bool
        The independent re-check of a disagreement: 1-D quadrature in twice the digits,
        Gauss–Hermite of higher orders, Monte Carlo with 4 times the samples and another seed.
    seed : int
        Seed of a Monte Carlo reference.

    Returns
    -------
    Reference
    """
    over = list(over)
    n = len(over)
    cov = sp.Matrix(cov)
    for f in funcs:
        extra = f.free_symbols - set(over)
        if extra:
            raise SingularMatrixError(f"E[{f}]: symbols {sorted(map(str, extra))} have no value at this point")
    if n == 1:
        return _quad_1d(funcs, over[0], sp.sympify(mean[0]), cov[0, 0], 2 * QUAD_DPS if refine else QUAD_DPS)
    m = np.array([float(sp.N(v, 20)) for v in mean])
    P = np.array(cov.evalf(20).tolist(), dtype=float)
    try:
        L = np.linalg.cholesky(P + 0.0)
    except np.linalg.LinAlgError:
        raise SingularMatrixError(f"the covariance of the expectation is not positive definite: {P.tolist()}") from None
    if n in GH_ORDERS and not refine:
        return _gauss_hermite(funcs, over, m, L, GH_ORDERS[n])
    if n == 2:  # the re-check in 2-D: higher orders
        return _gauss_hermite(funcs, over, m, L, GH_REFINED)
    samples = MC_SAMPLES * (4 if refine else 1)
    return _monte_carlo(funcs, over, m, L, samples, seed + (1 if refine else 0))
