"""Numeric references for a claim that has no closed form: Gaussian integrals with error bars.

When :func:`symmon.expect` cannot give E[f(x)] in closed form (``ExpectationNotClosedForm``),
a claim about it can still be checked at points, against a reference whose error is known:

- one dimension: mpmath's adaptive quadrature in 30 digits, split at every kink and jump of f
  (the real zeros of the arguments of ``Abs``, ``sign``, ``Heaviside``, of the differences
  of the arguments of ``Max`` and ``Min``, of the two sides of each relation of a
  ``Piecewise``), with its own error estimate;
- two or three dimensions, f smooth: tensor Gauss–Hermite rules of two orders, the error the
  difference of the two times :data:`GH_SAFETY` (the estimate of
  :class:`symmon.GaussHermite`'s ``error_estimate``);
- more dimensions, and f not smooth (:data:`NONSMOOTH`) where the quadrature cannot be split
  at all its jumps (two or more dimensions, ``floor``, a kink of a non-polynomial argument):
  Monte Carlo with a seeded ``numpy.random.Generator``. Its error is :data:`MC_SIGMAS`
  standard errors plus the second term of the empirical Bernstein bound (Maurer & Pontil
  2009), (7/3) ln(2/δ) R/(N − 1) with ln(2/δ) = MC_SIGMAS²/2 and R the range of f over the
  samples and over probe points out to 12 standard deviations along each axis: a jump that
  the samples rarely cross is not hidden by a small sample variance. When f took one value
  at every sample and probe though it has jumps, the reference cannot tell where they are,
  and no verdict is given (:class:`~symmon.errors.UndecidedProofError`); so is it for
  ``DiracDelta``, which no numeric rule integrates.

A Gauss–Hermite rule's two orders agree on a jump they do not straddle (E sign(x₁x₂) with no
node where sign(x₁) changes is 0 to 1e-13 by both), so its "error" is no bound there and it is
never used for a function with a kink or a jump. A Monte Carlo reference, like any sampling,
cannot see a feature of f of probability much below 1/N that no sample or probe meets.

Every result is a value and an error bound per function; a reference is never a proof, and
:mod:`symmon.verify.verification` says "consistent", never "proved", from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import mpmath
import numpy as np
import sympy as sp

from ..errors import NonFiniteError, SingularMatrixError, UndecidedProofError
from ..transforms.nodes import standard_rule
from ..units.kinks import NONSMOOTH as KINKS

__all__ = ["Reference", "gaussian_integrals", "nonsmooth", "GH_ORDERS", "GH_SAFETY", "MC_SAMPLES", "MC_SIGMAS",
           "QUAD_DPS", "NONSMOOTH"]

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

#: Standard deviations out to which the probe points of a Monte Carlo reference go along each axis.
PROBE_SIGMAS = 12
#: Highest degree of a polynomial kink argument whose real zeros split the 1-D quadrature.
MAX_KINK_DEGREE = 20
#: The functions with a kink or a jump: sympy's (``Abs``, ``sign``, ``Max``, ``Min``,
#: ``Heaviside``, ``DiracDelta``, ``floor``, ``ceiling``, ``frac``, ``Mod``, ``Piecewise``), and
#: ``atan2`` and ``arg``, which jump across a half-line.
NONSMOOTH = (*KINKS, sp.atan2, sp.arg)


@dataclass(frozen=True)
class Reference:
    """Values of E[f_k(x)] and their error bounds (same length, mpmath numbers: the 1-D
    quadrature's carry its 30 digits), and how they were computed."""

    values: tuple[mpmath.mpf, ...]
    errors: tuple[mpmath.mpf, ...]
    method: str


def nonsmooth(funcs: Sequence[sp.Expr]) -> list[sp.Expr]:
    """The calls of :data:`NONSMOOTH` functions in ``funcs`` (their kinks and jumps), no repeats."""
    found: list[sp.Expr] = []
    for f in funcs:
        for node in sp.preorder_traversal(sp.sympify(f)):
            if isinstance(node, NONSMOOTH) and node not in found:
                found.append(node)
    return found


def _kink_arguments(atom: sp.Expr) -> list[sp.Expr] | None:
    """Expressions whose real zeros hold every kink and jump of ``atom``, or None for a function
    whose jumps are not the zeros of finitely many expressions (``floor``, ...)."""
    if isinstance(atom, (sp.Abs, sp.sign, sp.Heaviside, sp.arg)):
        return [atom.args[0]]
    if isinstance(atom, (sp.Max, sp.Min)):
        a = list(atom.args)
        return [a[i] - a[j] for i in range(len(a)) for j in range(i + 1, len(a))]
    if isinstance(atom, sp.atan2):
        return list(atom.args)
    if isinstance(atom, sp.Piecewise):
        out = []
        for _, cond in atom.args:
            rels = cond.atoms(sp.core.relational.Relational)
            # only relations joined by and, or, not: anything else (Contains, ...) is refused
            if not isinstance(cond.xreplace({r: sp.true for r in rels}), sp.logic.boolalg.BooleanAtom):
                return None
            out += [r.lhs - r.rhs for r in rels]
        return out
    return None


def _kink_points(funcs: Sequence[sp.Expr], x: sp.Symbol) -> list[float] | None:
    """Every real point where a function of x alone has a kink or a jump (a superset: the real
    parts of nearly real roots too), or None when they cannot all be found: a jump of ``floor``,
    an argument that is no polynomial in x (or of degree above :data:`MAX_KINK_DEGREE`)."""
    args: list[sp.Expr] = []
    for atom in nonsmooth(funcs):
        a = _kink_arguments(atom)
        if a is None:
            return None
        args += a
    zeros: list[float] = []
    for a in args:
        a = sp.sympify(a)
        if not a.has(x):
            continue
        try:
            poly = sp.Poly(a, x)
        except sp.PolynomialError:
            return None
        if poly.degree() > MAX_KINK_DEGREE or poly.free_symbols - {x}:
            return None
        try:
            coeffs = [complex(sp.N(c, 30)) for c in poly.all_coeffs()]
        except TypeError:
            return None
        if poly.degree() < 1:
            continue
        for r in np.roots(coeffs):
            if abs(r.imag) <= 1e-4 * (1 + abs(r.real)):
                zeros.append(float(r.real))
    return zeros


def _quad_1d(funcs: Sequence[sp.Expr], x: sp.Symbol, m: sp.Expr, var: sp.Expr, dps: int,
             kinks: Sequence[float]) -> Reference:
    with mpmath.workdps(dps):
        mm, sd = mpmath.mpf(sp.N(m, dps + 5)), mpmath.sqrt(mpmath.mpf(sp.N(var, dps + 5)))
        if sd == 0:
            raise SingularMatrixError("the variance of the expectation is 0: no Gaussian integral to take")
        breaks = sorted({(z - float(sp.N(m, 20))) / float(sd) for z in kinks})
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
                 samples: int, seed: int, jumps: bool = False) -> Reference:
    rng = np.random.default_rng(seed)
    n = len(over)
    Z = rng.standard_normal((samples, n))
    F = _evaluate(funcs, over, m + Z @ L.T)
    mean = F.mean(axis=1)
    se = F.std(axis=1, ddof=1) / np.sqrt(samples)
    # the range of f: the samples, and probes out to PROBE_SIGMAS along each axis of z
    t = np.arange(1, PROBE_SIGMAS + 1, dtype=float)
    probes = np.concatenate([np.outer(sgn * t, np.eye(n)[i]) for i in range(n) for sgn in (-1, 1)])
    G = _evaluate(funcs, over, m + probes @ L.T)
    R = np.maximum(F.max(axis=1), G.max(axis=1)) - np.minimum(F.min(axis=1), G.min(axis=1))
    if jumps and np.any(R == 0):
        k = int(np.argmax(R == 0))
        raise UndecidedProofError(
            f"E[{funcs[k]}]: the function has kinks or jumps ({', '.join(map(str, nonsmooth([funcs[k]])))}) but took "
            f"one value at all {samples} samples and {len(probes)} probe points, so no numeric reference can bound "
            "where it changes: no verdict")
    err = (MC_SIGMAS * se + (7 / 3) * (MC_SIGMAS**2 / 2) * R / (samples - 1)
           + DOUBLE_RTOL * np.abs(F).mean(axis=1))
    return Reference(tuple(mpmath.mpf(float(v)) for v in mean), tuple(mpmath.mpf(float(e)) for e in err),
                     f"Monte Carlo, {samples} samples, seed {seed} (error: {MC_SIGMAS:g} standard errors and the "
                     "empirical Bernstein range term)")


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
    atoms = nonsmooth(funcs)
    deltas = [a for a in atoms if isinstance(a, sp.DiracDelta)] + [d for f in funcs for d in f.atoms(sp.Derivative)]
    if deltas:
        raise UndecidedProofError(f"E[...] of {deltas[0]}: a point mass (or an unevaluated derivative) has no numeric "
                                  "reference: no verdict")
    if n == 1:
        kinks = _kink_points(funcs, over[0]) if atoms else []
        if kinks is not None:
            return _quad_1d(funcs, over[0], sp.sympify(mean[0]), cov[0, 0], 2 * QUAD_DPS if refine else QUAD_DPS,
                            kinks)
    m = np.array([float(sp.N(v, 20)) for v in mean])
    P = np.array(cov.evalf(20).tolist(), dtype=float)
    try:
        L = np.linalg.cholesky(P + 0.0)
    except np.linalg.LinAlgError:
        raise SingularMatrixError(f"the covariance of the expectation is not positive definite: {P.tolist()}") from None
    if not atoms and n in GH_ORDERS and not refine:
        return _gauss_hermite(funcs, over, m, L, GH_ORDERS[n])
    if not atoms and n == 2:  # the re-check in 2-D: higher orders
        return _gauss_hermite(funcs, over, m, L, GH_REFINED)
    samples = MC_SAMPLES * (4 if refine else 1)
    return _monte_carlo(funcs, over, m, L, samples, seed + (1 if refine else 0), jumps=bool(atoms))
