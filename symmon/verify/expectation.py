r"""E[f(x)] of a Gaussian vector x ~ N(μ, P) in closed form, in exact sympy arithmetic.

The class of f with a proved closed form (:func:`expect`) and the formula for each member:

(1) polynomials, by the Gaussian heat operator (Isserlis' theorem in operator form):
    E p(x) = Σ_{k ≥ 0} (Dᵏ p)(μ) / k!,  D = ½ Σ_ij P_ij ∂_i ∂_j,
    a finite sum (D lowers the degree by 2), exact for symbolic μ and P.

(2) a polynomial times the exponential of an affine form with a complex coefficient
    vector c (completing the square; the moment generating function M(t) = exp(tᵀμ + ½tᵀPt)
    is entire, so the identity holds for complex c by analytic continuation):
    E[p(x) exp(cᵀx + c₀)] = exp(c₀ + cᵀμ + ½cᵀPc) · E_{N(μ + Pc, P)}[p].
    sin and cos of affine forms enter as complex exponentials, cos θ = (e^{iθ} + e^{−iθ})/2,
    sinh and cosh as real ones; with μ, P real, the real and imaginary parts of (2) are
    read off formally: exp(z_r + i z_i)(A + iB) has real part e^{z_r}(A cos z_i − B sin z_i).

(3) the absolute value of an affine form L = aᵀx + a₀, L ~ N(m, s²), m = aᵀμ + a₀,
    s² = aᵀPa (Lemma 1, eq. (8), and Theorem 1, eqs. (9)–(10), of the MMSE distance paper):
    E|L| = m (1 − 2Φ(−m/s)) + 2 s φ(m/s) = m erf(m / (√2 s)) + 2 s φ(m/s);
    max and min of two affine forms through max(a, b) = (a + b)/2 + |a − b|/2 and
    min(a, b) = (a + b)/2 − |a − b|/2.

(4) |L| times a polynomial q(x): with x = μ + g (L − m) + r, g = P a / s², and
    r ~ N(0, P − P a aᵀ P / s²) independent of L (the Gaussian regression of x on L),
    E[|L| q(x)] = Σ_k h_k E[|L| Lᵏ] where Σ_k h_k ℓᵏ = E_r q(μ + g(ℓ − m) + r) by (1), and
    E[|L| Lᵏ] = E[L^{k+1}] − 2 E[L^{k+1} 1{L < 0}] with the truncated moments
    E[(m + sZ)^j 1{Z < α}] = Σ_i C(j, i) m^{j−i} sⁱ τ_i(α), α = −m/s,
    τ₀ = Φ(α), τ₁ = −φ(α), τ_i = (i − 1) τ_{i−2} − α^{i−1} φ(α) (integration by parts).
    Times a real exponential exp(cᵀx), the tilt of (2) first: the mean μ + Pc, the factor
    exp(cᵀμ + ½cᵀPc).  ``|L|² = L²`` is a polynomial; ``|L₁| |L₂|`` with L₁ = r L₂ is ``|r| L₂²``.

Sums and products of these are expanded into sums of atoms p(x) exp(cᵀx + c₀) |L|^{0 or 1}.
Everything else that depends on x is refused with :class:`~symmon.errors.ExpectationNotClosedForm`
naming the subexpression: |L| times a sine or cosine (an erf of a complex argument), a
product |L₁| |L₂| of two distinct affine forms (a bivariate normal orthant integral),
exp of a non-affine argument, negative or fractional powers, sqrt, atan2, log, ...
Nothing is ever integrated numerically or handed to sympy.stats.

References
----------
M. Song, W. Choi, V. Shin, "Minimum Mean Square Error Estimation of Distance Functions under
the Kalman Filtering Framework": Lemma 1 (8), Theorem 1 (9)–(10) and the Appendix.
L. Isserlis, "On a formula for the product-moment coefficient of any order of a normal
frequency distribution in any number of variables", Biometrika 12, 1918.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import sympy as sp

from ..errors import ArgumentError, ArgumentTypeError, CovarianceError, ExpectationNotClosedForm, ShapeError, plain_repr

__all__ = ["expect", "gaussian_polynomial_mean", "normal_cdf", "normal_pdf", "as_mean_cov", "check_variables"]

#: Longest text of a subexpression quoted in an error message.
_QUOTE = 80


def normal_cdf(a: sp.Expr) -> sp.Expr:
    """Φ(a) = (1 + erf(a/√2))/2, the standard normal distribution function."""
    return (1 + sp.erf(a / sp.sqrt(2))) / 2


def normal_pdf(a: sp.Expr) -> sp.Expr:
    """φ(a) = exp(−a²/2)/√(2π), the standard normal density."""
    return sp.exp(-a**2 / 2) / sp.sqrt(2 * sp.pi)


# --------------------------------------------------------------------------- arguments
def _as_sympy(x: Any, what: str) -> sp.Expr:
    if isinstance(x, str):
        raise ArgumentTypeError(f"{what} must be a sympy expression or a number, not a string (text is never parsed)")
    try:
        # Python and numpy ints become Integers, Rationals stay exact, floats stay Floats.
        return sp.sympify(x, strict=True)
    except (sp.SympifyError, TypeError) as exc:
        raise ArgumentTypeError(f"{what} must be a sympy expression or a number, got {x!r}") from exc


def _symbols(over: Any) -> tuple[sp.Symbol, ...]:
    if isinstance(over, sp.MatrixBase):
        over = list(over)
    items = [over] if isinstance(over, sp.Basic) else list(over) if isinstance(over, (list, tuple)) else None
    if not items or not all(isinstance(s, sp.Symbol) for s in items):
        raise ArgumentTypeError(f"over must be a sympy Symbol or a non-empty sequence of Symbols, got {over!r}")
    if len(set(items)) != len(items):
        raise ArgumentError(f"over lists a symbol twice: {[str(s) for s in items]}")
    return tuple(items)


#: The assumptions a variable's refusal names, the most telling first.
_NAMED_ASSUMPTIONS = ("positive", "negative", "zero", "nonnegative", "nonpositive", "nonzero", "integer",
                      "rational", "irrational", "imaginary")


def check_variables(over: Sequence[sp.Symbol]) -> None:
    """Refuse a Gaussian variable that carries an assumption a real Gaussian does not meet.

    A variable of a Gaussian expectation takes every real value. sympy uses a symbol's
    assumptions as soon as an expression is built (``Abs(x)`` is ``x`` for a positive x,
    ``sin(pi*x)`` is 0 for an integer x), so E|x| = 0 would follow: a variable declared
    positive, negative, nonzero, integer, ... is refused, naming it. A plain ``Symbol`` and
    ``Symbol(name, real=True)`` are accepted.

    Raises
    ------
    ArgumentError
        A variable has such an assumption.
    """
    for s in over:
        plain = sp.Symbol(s.name, real=True).assumptions0
        extra = sorted(k for k, v in s.assumptions0.items() if plain.get(k, v if k == "commutative" else None) != v)
        if extra:
            named = [k for k in _NAMED_ASSUMPTIONS if s.assumptions0.get(k) is True] or \
                [f"{k}={s.assumptions0[k]}" for k in extra[:3]]
            raise ArgumentError(
                f"over: the Gaussian variable {s} is declared {named[0]}, but a variable of a Gaussian expectation "
                f"takes every real value, and sympy has already used the assumption on the expression (Abs({s}) "
                f"becomes {s} for a positive {s}): declare it sp.Symbol({s.name!r}, real=True)")


def _entries(a: Any) -> list:
    """The rows of a matrix-like argument as nested lists (scalars stay scalars)."""
    if isinstance(a, sp.MatrixBase):
        return a.tolist()
    if isinstance(a, np.ndarray):
        return a.tolist()
    if isinstance(a, (list, tuple)):
        return [_entries(r) if isinstance(r, (list, tuple, np.ndarray, sp.MatrixBase)) else r for r in a]
    return a


def as_mean_cov(mean: Any, cov: Any, n: int, avoid: Sequence[sp.Symbol] = ()) -> tuple[sp.Matrix, sp.Matrix]:
    """μ (n × 1) and P (n × n) as sympy matrices, checked.

    Numbers become exact where they are (ints, Rationals) and stay floats where they are
    floats.  P must be symmetric (entrywise, after expansion); a numeric P must be positive
    semi-definite; neither may depend on the symbols ``avoid`` (the integration variables).

    Raises
    ------
    ShapeError, CovarianceError, ArgumentError, ArgumentTypeError
    """
    mu_items = _entries(mean)
    if not isinstance(mu_items, list):
        mu_items = [mu_items]
    if mu_items and all(isinstance(r, list) for r in mu_items):  # a column or row matrix
        mu_items = [e for r in mu_items for e in r]
    if len(mu_items) != n or any(isinstance(m, list) for m in mu_items):
        raise ShapeError(f"mean must have {n} entries (one per variable), got {plain_repr(mean)}")
    mu = sp.Matrix([_as_sympy(m, "mean") for m in mu_items])
    rows = _entries(cov)
    if not isinstance(rows, list):
        rows = [[rows]]
    if n == 1 and len(rows) == 1 and not isinstance(rows[0], list):
        rows = [rows]
    if len(rows) != n or any(not isinstance(r, list) or len(r) != n for r in rows):
        raise ShapeError(f"cov must be {n} x {n} (one row and column per variable), got {plain_repr(cov)}")
    P = sp.Matrix([[_as_sympy(c, "cov") for c in r] for r in rows])
    bad = (mu.free_symbols | P.free_symbols) & set(avoid)
    if bad:
        raise ArgumentError(f"mean and cov must not depend on the integration variables; they use {sorted(map(str, bad))}")
    for i in range(n):
        if P[i, i].is_negative:
            raise CovarianceError(f"cov[{i}, {i}] = {P[i, i]} is negative: a variance must be >= 0")
        for j in range(i + 1, n):
            if sp.expand(P[i, j] - P[j, i]) != 0:
                raise CovarianceError(f"cov is not symmetric: cov[{i}, {j}] = {P[i, j]} but cov[{j}, {i}] = {P[j, i]}")
    if not P.free_symbols:
        A = np.array(P.evalf(30).tolist(), dtype=float)
        if not np.isfinite(A).all():
            raise CovarianceError("cov has a non-finite entry")
        lo = float(np.linalg.eigvalsh(A).min())
        if lo < -1e-12 * max(1.0, float(np.abs(A).max())):
            raise CovarianceError(f"cov is not positive semi-definite (smallest eigenvalue {lo:.3g})")
    if not mu.free_symbols and not all(sp.Abs(m).evalf() < sp.oo for m in mu):
        raise ArgumentError("mean has a non-finite entry")
    return mu, P


def _quote(e: sp.Expr) -> str:
    text = str(e)
    return text if len(text) <= _QUOTE else text[: _QUOTE - 3] + "..."


def _outside(e: sp.Expr, why: str) -> ExpectationNotClosedForm:
    return ExpectationNotClosedForm(
        f"{_quote(e)} is outside the class with a closed-form Gaussian expectation ({why}); "
        "symmon.expect covers sums and products of polynomials, exp, sin, cos, sinh, cosh of affine forms, "
        "and |affine|, Max and Min of two affine forms (times polynomials and real exponentials only)")


# --------------------------------------------------------------------------- (1) polynomials
def gaussian_polynomial_mean(p: sp.Expr, over: Sequence[sp.Symbol], mu: sp.Matrix, P: sp.Matrix) -> sp.Expr:
    """E p(x) for x ~ N(μ, P) and a polynomial p in ``over``, eq. (1) of the module doc.

    E p(μ + z) = Σ_k (Dᵏ p)(μ) / k! with D = ½ Σ_ij P_ij ∂_i ∂_j; the sum stops at
    k = ⌊deg p / 2⌋.  μ may be complex (the tilted mean of (2)), P symbolic.
    """
    n = len(over)
    term, total, k = sp.expand(p), sp.Integer(0), 0
    while term != 0:
        total += term / sp.factorial(k)
        nxt = sp.Integer(0)
        for i in range(n):
            di = sp.diff(term, over[i])
            if di == 0:
                continue
            for j in range(n):
                if P[i, j] != 0:
                    nxt += P[i, j] * sp.diff(di, over[j])
        term, k = sp.expand(nxt / 2), k + 1
    return sp.expand(total.xreplace(dict(zip(over, mu))))


# --------------------------------------------------------------------------- the normal form
@dataclass(frozen=True)
class _Atom:
    """poly(x) · exp(cᵀx + c0) · |L|  (L = None: no absolute value)."""

    poly: sp.Expr
    c: tuple[sp.Expr, ...]
    c0: sp.Expr
    absl: sp.Expr | None

    @property
    def key(self) -> tuple:
        return self.c, self.c0, self.absl


def _affine(e: sp.Expr, x: tuple[sp.Symbol, ...]) -> tuple[tuple[sp.Expr, ...], sp.Expr] | None:
    """(c, c0) with e = cᵀx + c0 and c, c0 free of x, or None when e is not affine in x."""
    coef = [sp.Integer(0)] * len(x)
    const = sp.Integer(0)
    index = {s: i for i, s in enumerate(x)}
    for t in sp.Add.make_args(sp.expand(e)):
        if t == 0:
            continue
        indep, dep = t.as_independent(*x, as_Add=False)
        if dep == 1:
            const += indep
        elif dep in index:
            coef[index[dep]] += indep
        else:
            return None
    return tuple(sp.expand(c) for c in coef), sp.expand(const)


def _canonical_abs(c: tuple[sp.Expr, ...], c0: sp.Expr, x: tuple[sp.Symbol, ...]) -> sp.Expr:
    """The affine form cᵀx + c0 with the sign that sympy's Abs would pull out removed."""
    L = sp.expand(sum((ci * xi for ci, xi in zip(c, x)), c0))
    return sp.expand(-L) if L.could_extract_minus_sign() else L


class _Normaliser:
    """Writes an expression as a sum of atoms (module doc), or raises naming what is outside."""

    def __init__(self, x: tuple[sp.Symbol, ...]) -> None:
        self.x = x
        self.xset = set(x)
        self.zero = tuple(sp.Integer(0) for _ in x)
        self.memo: dict[sp.Expr, list[_Atom]] = {}

    def const(self, e: sp.Expr) -> list[_Atom]:
        return [_Atom(e, self.zero, sp.Integer(0), None)]

    def exp_atom(self, arg: sp.Expr, where: sp.Expr, scale: sp.Expr = sp.Integer(1)) -> _Atom:
        aff = _affine(arg, self.x)
        if aff is None:
            raise _outside(where, "the exponent is not affine in the variables")
        return _Atom(scale, aff[0], aff[1], None)

    def of(self, e: sp.Expr) -> list[_Atom]:
        if e in self.memo:
            return self.memo[e]
        out = self._of(e)
        self.memo[e] = out
        return out

    def _of(self, e: sp.Expr) -> list[_Atom]:
        if not (e.free_symbols & self.xset):
            return self.const(e)
        if e in self.xset:
            return [_Atom(e, self.zero, sp.Integer(0), None)]
        if e.is_Add:
            return _merge([a for t in e.args for a in self.of(t)])
        if e.is_Mul:
            acc = self.const(sp.Integer(1))
            for f in e.args:
                acc = self.times(acc, self.of(f), e)
            return acc
        if e.is_Pow:
            base, n = e.args
            if not (base.free_symbols & self.xset):
                if base.is_positive:  # b^(affine) = exp(affine · log b)
                    return [self.exp_atom(n * sp.log(base), e)]
                raise _outside(e, "a power with a variable exponent needs a positive base")
            if n.is_Integer and n > 0:
                return self.power(self.of(base), int(n), e)
            raise _outside(e, "a negative or fractional power of the variables")
        if isinstance(e, sp.exp):
            return [self.exp_atom(e.args[0], e)]
        if isinstance(e, (sp.cos, sp.sin, sp.cosh, sp.sinh)):
            arg = e.args[0]
            k = sp.I if isinstance(e, (sp.cos, sp.sin)) else sp.Integer(1)
            sign = 1 if isinstance(e, (sp.cos, sp.cosh)) else -1
            half = sp.Rational(1, 2) / (sp.I if isinstance(e, sp.sin) else 1)
            # cos θ = (e^{iθ} + e^{-iθ})/2, sin θ = (e^{iθ} - e^{-iθ})/(2i), and the hyperbolic ones.
            return _merge([self.exp_atom(k * arg, e, half), self.exp_atom(-k * arg, e, sign * half)])
        if isinstance(e, sp.Abs):
            aff = _affine(e.args[0], self.x)
            if aff is None:
                raise _outside(e, "an absolute value of a non-affine argument")
            return [_Atom(sp.Integer(1), self.zero, sp.Integer(0), _canonical_abs(*aff, self.x))]
        if isinstance(e, (sp.Max, sp.Min)):
            if len(e.args) != 2:
                raise _outside(e, f"{type(e).__name__} of {len(e.args)} arguments (two affine forms have a closed form)")
            a, b = e.args
            fa, fb = _affine(a, self.x), _affine(b, self.x)
            if fa is None or fb is None:
                raise _outside(e, f"{type(e).__name__} of a non-affine argument")
            # max(a, b) = (a + b)/2 + |a - b|/2, min(a, b) = (a + b)/2 - |a - b|/2
            d = _canonical_abs(tuple(p - q for p, q in zip(fa[0], fb[0])), fa[1] - fb[1], self.x)
            half = sp.Rational(1, 2) if isinstance(e, sp.Max) else -sp.Rational(1, 2)
            return _merge([_Atom(sp.expand((a + b) / 2), self.zero, sp.Integer(0), None)]
                          + ([_Atom(half, self.zero, sp.Integer(0), d)] if d != 0 else []))
        raise _outside(e, f"{type(e).__name__} of the variables has no closed form here")

    def power(self, f: list[_Atom], n: int, where: sp.Expr) -> list[_Atom]:
        out, base = self.const(sp.Integer(1)), f
        while n:
            if n & 1:
                out = self.times(out, base, where)
            n >>= 1
            if n:
                base = self.times(base, base, where)
        return out

    def times(self, f: list[_Atom], g: list[_Atom], where: sp.Expr) -> list[_Atom]:
        out = []
        for a in f:
            for b in g:
                out.append(self.product(a, b, where))
        return _merge(out)

    def product(self, a: _Atom, b: _Atom, where: sp.Expr) -> _Atom:
        c = tuple(sp.expand(p + q) for p, q in zip(a.c, b.c))
        c0 = sp.expand(a.c0 + b.c0)
        poly = a.poly * b.poly
        if a.absl is None or b.absl is None:
            return _Atom(poly, c, c0, a.absl if b.absl is None else b.absl)
        r = sp.cancel(a.absl / b.absl)
        if r.free_symbols & self.xset:
            raise _outside(where, f"a product of the absolute values of two different affine forms, "
                                  f"|{_quote(a.absl)}| |{_quote(b.absl)}| (a bivariate normal orthant integral)")
        # |L1| |L2| = |r| L2² when L1 = r L2
        return _Atom(poly * sp.Abs(r) * b.absl**2, c, c0, None)


def _merge(atoms: list[_Atom]) -> list[_Atom]:
    """Atoms with the same exponential and absolute value, their polynomials added."""
    by: dict[tuple, sp.Expr] = {}
    for a in atoms:
        by[a.key] = by.get(a.key, sp.Integer(0)) + a.poly
    return [_Atom(p, *k) for k, p in by.items() if p != 0]


# --------------------------------------------------------------------------- the expectations
def _split_i(e: sp.Expr) -> tuple[sp.Expr, sp.Expr] | None:
    """(A, B) with e = A + iB read off formally (every symbol a real parameter), or None."""
    e = sp.expand(e)
    if not e.has(sp.I):
        return e, sp.Integer(0)
    im = sp.expand(e.coeff(sp.I))
    re = sp.expand(e - sp.I * im)
    if re.has(sp.I) or im.has(sp.I):
        return None
    return re, im


def _tilt(atom: _Atom, mu: sp.Matrix, P: sp.Matrix) -> tuple[sp.Expr, sp.Matrix]:
    """z = c0 + cᵀμ + ½cᵀPc and the tilted mean μ + Pc of eq. (2)."""
    c = sp.Matrix(atom.c)
    Pc = P * c
    z = sp.expand(atom.c0 + (c.T * mu)[0] + (c.T * Pc)[0] / 2)
    return z, mu + Pc


def _truncated_moments(j: int, m: sp.Expr, s: sp.Expr, Phi: sp.Symbol, phi: sp.Symbol) -> sp.Expr:
    """E[Lʲ 1{L < 0}] for L ~ N(m, s²), in the placeholders Φ = Φ(−m/s), φ = φ(m/s), eq. (4)."""
    alpha = -m / s
    tau = [Phi, -phi]
    for i in range(2, j + 1):
        tau.append((i - 1) * tau[i - 2] - alpha ** (i - 1) * phi)
    return sum((sp.binomial(j, i) * m ** (j - i) * s**i * tau[i] for i in range(j + 1)), sp.Integer(0))


def _abs_poly_mean(L: sp.Expr, q: sp.Expr, x: tuple[sp.Symbol, ...], mu: sp.Matrix, P: sp.Matrix) -> sp.Expr:
    """E[|L| q(x)] for x ~ N(μ, P), L affine and q a polynomial, eqs. (3)–(4)."""
    a, a0 = _affine(L, x)
    av = sp.Matrix(a)
    m = sp.expand((av.T * mu)[0] + a0)
    var = sp.expand((av.T * P * av)[0])
    if var == 0:  # L is the constant m almost surely
        return sp.Abs(m) * gaussian_polynomial_mean(q, x, mu, P)
    s = sp.sqrt(var)
    Pa = P * av
    ell = sp.Dummy("ell")
    # x = μ + g (L − m) + r: the regression on L, r independent of L with Cov P − Pa aᵀP / s²
    cond_mean = mu + Pa * (ell - m) / var
    cond_cov = P - Pa * Pa.T / var
    h = sp.Poly(gaussian_polynomial_mean(q, x, cond_mean, cond_cov), ell)
    Phi, phi = sp.Dummy("Phi"), sp.Dummy("phi")
    ell_mean = sp.Matrix([m])
    total = sp.Integer(0)
    for (k,), hk in h.terms():
        raw = gaussian_polynomial_mean(ell ** (k + 1), (ell,), ell_mean, sp.Matrix([[var]]))
        total += hk * (raw - 2 * _truncated_moments(k + 1, m, s, Phi, phi))
    # Φ(−m/s) = (1 − erf(m/(√2 s)))/2: the form of Lemma 1 (8), m erf(m/(√2 s)) + 2 s φ(m/s) for q = 1.
    erf = sp.Dummy("erf")
    total = sp.expand(total.xreplace({Phi: (1 - erf) / 2}))
    # A + B erf + C φ with each coefficient over one denominator (the regression divides by s²).
    parts = sp.collect(total, [erf, phi], evaluate=False)
    out = sum((sp.factor(sp.cancel(coef)) * k for k, coef in parts.items()), sp.Integer(0))
    return out.xreplace({erf: sp.erf(m / (sp.sqrt(2) * s)), phi: normal_pdf(m / s)})


def _atom_mean(atom: _Atom, x: tuple[sp.Symbol, ...], mu: sp.Matrix, P: sp.Matrix, real: bool,
               expr: sp.Expr) -> tuple[sp.Expr, sp.Expr]:
    """(real part, imaginary part) of E[atom], or (value, 0) when ``real`` is False."""
    z, tilted = _tilt(atom, mu, P)
    if atom.absl is None:
        Q = gaussian_polynomial_mean(atom.poly, x, tilted, P)
    elif any(ci.has(sp.I) for ci in atom.c):
        raise _outside(expr, f"the absolute value |{_quote(atom.absl)}| times a sine or cosine "
                             "(its expectation needs erf of a complex argument)")
    else:
        Q = _abs_poly_mean(atom.absl, atom.poly, x, tilted, P)
    if not real:
        return sp.exp(z) * Q, sp.Integer(0)
    zs, Qs = _split_i(z), _split_i(Q)
    if zs is None or Qs is None:
        raise _outside(expr, "an imaginary part that cannot be separated formally")
    (zr, zi), (A, B) = zs, Qs
    if zi == 0:
        return sp.exp(zr) * A, sp.exp(zr) * B
    return (sp.exp(zr) * (A * sp.cos(zi) - B * sp.sin(zi)),
            sp.exp(zr) * (A * sp.sin(zi) + B * sp.cos(zi)))


def expect(expr: Any, over: Any, mean: Any, cov: Any) -> sp.Expr:
    r"""E[expr] for a Gaussian vector ``over`` ~ N(mean, cov), in closed form.

    The class (module :mod:`symmon.verify.expectation`, eqs. (1)–(4)): sums and products of
    polynomials, exponentials of affine forms, sin, cos, sinh and cosh of affine forms, the
    absolute value of an affine form and max / min of two affine forms (the last three times
    polynomials and real exponentials; ``|L|²`` and ``|L| |rL|`` reduce to polynomials).  The
    expectation of an absolute value is that of Lemma 1, eq. (8), and Theorem 1, eq. (10), of
    the MMSE distance paper, E|L| = m(1 − 2Φ(−m/s)) + 2sφ(m/s), written with erf.

    Parameters
    ----------
    expr : sympy expression
        f(x); symbols other than ``over`` are parameters.  A string is refused (never parsed).
    over : Symbol or sequence of Symbols
        The Gaussian vector x.
    mean : sequence of n numbers or sympy expressions (or a scalar for n = 1)
        μ.  ints and Rationals stay exact, floats stay floats.
    cov : (n, n) sympy Matrix, array or nested sequence (or a scalar for n = 1)
        P, symbolic entries (and symbolic cross-covariances) allowed; it must be symmetric,
        and a numeric one positive semi-definite.  Symbols in μ and P are taken as real, and
        for an absolute value of L = aᵀx + a₀ the variance aᵀPa as positive unless it is 0.

    Returns
    -------
    sympy.Expr
        The exact expectation, free of ``over``: real for a real ``expr`` (the imaginary
        parts of the complex exponentials of sin and cos cancel and are dropped), complex
        for an ``expr`` with ``I`` (e.g. the characteristic function ``exp(I*t*x)``).

    Raises
    ------
    ExpectationNotClosedForm
        expr is outside the class; the message names the subexpression that is.
    ShapeError, CovarianceError, ArgumentError, ArgumentTypeError
        Bad ``over``, ``mean`` or ``cov``.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x", real=True)
    >>> m, s = sp.symbols("m s", positive=True)
    >>> sm.expect(x**2, x, [m], [[s**2]])
    m**2 + s**2
    >>> sp.simplify(sm.expect(sp.cos(x), x, [0], [[s**2]]))
    exp(-s**2/2)
    >>> sm.expect(sp.Abs(x), x, [0], [[1]])
    sqrt(2)/sqrt(pi)
    """
    x = _symbols(over)
    check_variables(x)
    e = _as_sympy(expr, "expr")
    if not isinstance(e, sp.Expr):
        raise ArgumentTypeError(f"expr must be a scalar sympy expression, got {type(e).__name__}")
    mu, P = as_mean_cov(mean, cov, len(x), x)
    real = not e.has(sp.I)
    atoms = _Normaliser(x).of(e)
    re, im = sp.Integer(0), sp.Integer(0)
    for atom in atoms:
        a, b = _atom_mean(atom, x, mu, P, real, e)
        re += a
        im += b
    # For a real expr the imaginary parts cancel (the integrand is real; μ, P are real).
    return re if real else re + sp.I * im
