"""E[f(x)] of a Gaussian vector x ~ N(μ, P) in closed form, in exact sympy arithmetic.

(first subset: polynomials, by the Gaussian heat operator; see :func:`expect`.)
"""

from __future__ import annotations

from typing import Any, Sequence

import sympy as sp

from ..errors import ArgumentError, ArgumentTypeError, CovarianceError, ExpectationNotClosedForm, ShapeError

__all__ = ["expect", "gaussian_polynomial_mean"]


def _as_sympy(x: Any, what: str) -> sp.Expr:
    if isinstance(x, str):
        raise ArgumentTypeError(f"{what} must be a sympy expression or a number, not a string (never parsed)")
    try:
        return sp.sympify(x, strict=True)
    except (sp.SympifyError, TypeError) as exc:
        raise ArgumentTypeError(f"{what} must be a sympy expression or a number, got {x!r}") from exc


def _symbols(over: Any) -> tuple[sp.Symbol, ...]:
    items = [over] if isinstance(over, sp.Basic) else list(over) if over is not None else []
    if not items or not all(isinstance(s, sp.Symbol) for s in items):
        raise ArgumentTypeError(f"over must be a sympy Symbol or a non-empty sequence of Symbols, got {over!r}")
    if len(set(items)) != len(items):
        raise ArgumentError(f"over lists a symbol twice: {[str(s) for s in items]}")
    return tuple(items)


def _mean_cov(mean: Any, cov: Any, over: tuple[sp.Symbol, ...]) -> tuple[sp.Matrix, sp.Matrix]:
    """μ (n × 1) and P (n × n) as sympy matrices, checked: shape, symmetry, free of ``over``."""
    n = len(over)
    if isinstance(mean, sp.MatrixBase):
        mu_items = list(mean)
    elif hasattr(mean, "__len__") and not isinstance(mean, str):
        mu_items = [m for m in (mean.ravel().tolist() if hasattr(mean, "ravel") else mean)]
    else:
        mu_items = [mean]
    if len(mu_items) != n:
        raise ShapeError(f"mean has {len(mu_items)} entries but over has {n} symbols")
    mu = sp.Matrix([_as_sympy(m, "mean") for m in mu_items])
    if isinstance(cov, sp.MatrixBase):
        rows = cov.tolist()
    elif hasattr(cov, "tolist"):
        rows = cov.tolist()
        rows = [[rows]] if not isinstance(rows, list) else rows
    elif isinstance(cov, (list, tuple)):
        rows = list(cov)
    else:
        rows = [[cov]]
    if n == 1 and rows and not isinstance(rows[0], (list, tuple)):
        rows = [list(rows)]
    if len(rows) != n or any(not isinstance(r, (list, tuple)) or len(r) != n for r in rows):
        raise ShapeError(f"cov must be {n} x {n} (over has {n} symbols)")
    P = sp.Matrix([[_as_sympy(c, "cov") for c in r] for r in rows])
    bad = (mu.free_symbols | P.free_symbols) & set(over)
    if bad:
        raise ArgumentError(f"mean and cov must not depend on the integration variables, found {sorted(map(str, bad))}")
    for i in range(n):
        for j in range(i + 1, n):
            if sp.expand(P[i, j] - P[j, i]) != 0:
                raise CovarianceError(f"cov is not symmetric: cov[{i}, {j}] = {P[i, j]} but cov[{j}, {i}] = {P[j, i]}")
    if not P.free_symbols and n:
        import numpy as np

        A = np.array(P.evalf(30).tolist(), dtype=float)
        lo = float(np.linalg.eigvalsh(A).min())
        if lo < -1e-12 * max(1.0, float(np.abs(A).max())):
            raise CovarianceError(f"cov is not positive semi-definite (smallest eigenvalue {lo:.3g})")
    return mu, P


def gaussian_polynomial_mean(p: sp.Expr, over: Sequence[sp.Symbol], mu: sp.Matrix, P: sp.Matrix) -> sp.Expr:
    """E p(x) for x ~ N(μ, P) and a polynomial p, by the heat operator.

    E p(μ + z) = Σ_k (Dᵏ p)(μ) / k!  with  D = ½ Σ_ij P_ij ∂_i ∂_j  (the Gaussian's
    generating function exp(½ tᵀPt) acting on p; the sum stops at k = ⌊deg p / 2⌋).
    μ may be complex (the tilted mean of an exponential), P symbolic.
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


def expect(expr: Any, over: Any, mean: Any, cov: Any) -> sp.Expr:
    """E[expr] for a Gaussian vector ``over`` ~ N(mean, cov), in closed form.

    Parameters
    ----------
    expr : sympy expression
    over : Symbol or sequence of Symbols
        The Gaussian vector x.
    mean : sequence (n) of numbers or sympy expressions
    cov : (n, n) sympy Matrix, array or nested sequence; symbolic entries allowed

    Returns
    -------
    sympy.Expr

    Raises
    ------
    ExpectationNotClosedForm
        expr is outside the class with a proved closed form; the message names the
        subexpression.
    """
    x = _symbols(over)
    e = _as_sympy(expr, "expr")
    mu, P = _mean_cov(mean, cov, x)
    if not e.is_polynomial(*x):
        raise ExpectationNotClosedForm(f"E[{e}] over {list(map(str, x))}: not a polynomial")
    return gaussian_polynomial_mean(e, x, mu, P)
