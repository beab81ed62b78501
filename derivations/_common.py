"""Shared pieces of the derivation scripts.

Every script in ``derivations/`` defines ``NAME``, ``TITLE``, ``SOURCE`` and a
function ``check() -> Result``; run as a program it calls :func:`main`, which prints
the report and exits with status 0 when the check passed and 1 otherwise.

Only sympy, numpy and scipy are used here, so that a derivation never depends on
the package whose formulas it is meant to check.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import sympy as sp

__all__ = [
    "Result",
    "Checker",
    "main",
    "is_zero",
    "gaussian_expectation",
    "standard_normal_moment",
    "symmetric_matrix",
    "lower_triangular",
    "matrix_symbols",
    "mc_within",
]

#: Number of standard errors a Monte Carlo estimate may deviate from its target.
MC_SIGMAS = 5.0


@dataclass
class Result:
    """Outcome of one derivation check.

    Attributes
    ----------
    name, title, source : str
        Script name, one-line title, and paper with equation numbers.
    passed : bool
        True when every claim of the script was confirmed.
    details : list of str
        One line per claim: ``PASS``/``FAIL`` and what was compared.
    latex : list of str
        LaTeX (``sympy.latex``) of each derived result.
    """

    name: str
    title: str
    source: str
    passed: bool
    details: list[str] = field(default_factory=list)
    latex: list[str] = field(default_factory=list)


class Checker:
    """Collects the claims of one script into a :class:`Result`.

    Each call of :meth:`claim` records one statement and whether it held; the
    result passes only if all of them held and there was at least one.
    """

    def __init__(self, name: str, title: str, source: str) -> None:
        self.name, self.title, self.source = name, title, source
        self.details: list[str] = []
        self.latex: list[str] = []
        self._oks: list[bool] = []

    def claim(self, label: str, ok: bool, note: str = "") -> bool:
        """Record that the statement ``label`` held (``ok``) or not."""
        ok = bool(ok)
        self._oks.append(ok)
        line = f"{'PASS' if ok else 'FAIL'}: {label}"
        if note:
            line += f" ({note})"
        self.details.append(line)
        return ok

    def note(self, text: str) -> None:
        """Record an informative line that is not a claim."""
        self.details.append(f"NOTE: {text}")

    def tex(self, label: str, expr: object) -> None:
        """Record the LaTeX of a derived result, prefixed by ``label``."""
        body = expr if isinstance(expr, str) else sp.latex(expr)
        self.latex.append(f"{label} {body}".strip())

    def result(self) -> Result:
        passed = bool(self._oks) and all(self._oks)
        return Result(self.name, self.title, self.source, passed,
                      list(self.details), list(self.latex))


def main(check: Callable[[], Result]) -> None:
    """Run ``check``, print its report and exit 0 (passed) or 1 (failed)."""
    try:
        res = check()
    except Exception as exc:  # a crash is a failed check, reported as such
        print(f"ERROR: {type(exc).__name__}: {exc}")
        sys.exit(1)
    status = "PASSED" if res.passed else "FAILED"
    print(f"[{status}] {res.name}: {res.title}")
    print(f"  source: {res.source}")
    for line in res.details:
        print(f"  {line}")
    for line in res.latex:
        print(f"  $$ {line} $$")
    sys.exit(0 if res.passed else 1)


def is_zero(expr: object) -> bool:
    """Decide with sympy whether a scalar or matrix expression is identically zero.

    Rational functions of the symbols are decided by ``cancel`` (exact polynomial
    arithmetic, fast and conclusive); anything else falls back to ``simplify``.
    """
    if isinstance(expr, sp.MatrixBase):
        return all(is_zero(e) for e in expr)
    e = sp.sympify(expr)
    if e == 0:
        return True
    if e.is_rational_function(*e.free_symbols):
        return sp.cancel(sp.together(e)) == 0
    e = sp.expand(e)
    if e == 0:
        return True
    return sp.simplify(e) == 0


def standard_normal_moment(k: int) -> int:
    """E[z**k] for z ~ N(0, 1): 0 for odd k, (k-1)!! for even k."""
    if k % 2:
        return 0
    return int(sp.factorial2(k - 1)) if k > 0 else 1


def gaussian_expectation(expr: sp.Expr, zs: Sequence[sp.Symbol]) -> sp.Expr:
    """Exact expectation of a polynomial in independent standard normals ``zs``.

    The monomial z_1^{k_1}...z_n^{k_n} is replaced by the product of the moments
    (k_i - 1)!!, which is Isserlis' theorem for independent standard normals; other
    symbols in ``expr`` are treated as constants.
    """
    poly = sp.Poly(sp.expand(expr), *zs)
    total = sp.Integer(0)
    for powers, coeff in poly.terms():
        weight = 1
        for k in powers:
            weight *= standard_normal_moment(k)
            if weight == 0:
                break
        if weight:
            total += coeff * weight
    return sp.expand(total)


def matrix_symbols(prefix: str, rows: int, cols: int, **assumptions) -> sp.Matrix:
    """A ``rows`` x ``cols`` matrix of independent symbols ``prefix_ij``."""
    return sp.Matrix(rows, cols, lambda i, j: sp.Symbol(f"{prefix}_{i + 1}{j + 1}", **assumptions))


def symmetric_matrix(prefix: str, n: int) -> sp.Matrix:
    """A symmetric ``n`` x ``n`` matrix of symbols (positive diagonal)."""
    def entry(i: int, j: int) -> sp.Symbol:
        a, b = min(i, j), max(i, j)
        return sp.Symbol(f"{prefix}_{a + 1}{b + 1}", real=True, positive=(a == b) or None)
    return sp.Matrix(n, n, entry)


def lower_triangular(prefix: str, n: int) -> sp.Matrix:
    """A lower-triangular ``n`` x ``n`` matrix of symbols with a positive diagonal
    (a generic Cholesky factor)."""
    def entry(i: int, j: int) -> sp.Expr:
        if j > i:
            return sp.Integer(0)
        return sp.Symbol(f"{prefix}_{i + 1}{j + 1}", real=True, positive=(i == j) or None)
    return sp.Matrix(n, n, entry)


def mc_within(samples: np.ndarray, target: float, extra: float = 0.0,
              sigmas: float = MC_SIGMAS) -> tuple[bool, str]:
    """Whether the sample mean of ``samples`` is within ``sigmas`` standard errors
    (plus a stated deterministic allowance ``extra``) of ``target``."""
    samples = np.asarray(samples, dtype=float)
    mean = float(samples.mean())
    se = float(samples.std(ddof=1) / np.sqrt(samples.size))
    ok = abs(mean - target) <= sigmas * se + extra
    return ok, f"MC {mean:.6g} vs {target:.6g}, |diff| = {abs(mean - target):.3g}, {sigmas:g} SE = {sigmas * se:.3g}"
