"""Assertions for a user's own test suite: derivations, moments and unit invariance.

Each function returns its evidence when the check passes and raises :class:`AssertionError`
with the certificate when it does not, so that pytest (or unittest) prints why::

    import sympy as sp
    import symmon as sm
    from symmon.testing import assert_derivation, assert_moments_close, assert_unit_invariant

    def test_second_moment():
        x, mu = sp.symbols("x mu", real=True)
        s = sp.Symbol("sigma", positive=True)
        assert_derivation(sm.Expectation(x**2, x, mu, s**2), mu**2 + s**2, require="proved")

- :func:`assert_derivation`: a claim ``lhs = rhs`` (:func:`symmon.verify`), a
  :class:`~symmon.Verification` already made, or every claim of a derivation file
  (``symmon verify``'s format, docs/reference/derivationfile.md);
- :func:`assert_moments_close`: two sets of moments agree within the error bars of
  whichever side has them (Monte Carlo standard errors, Gauss–Hermite error estimates);
- :func:`assert_unit_invariant`: the unit-invariance proof of the measure of nonlinearity,
  :func:`symmon.units.prove_invariance` (Straka & Havlík 2024, (21), (34)).
"""

from __future__ import annotations

import os
from typing import Any, Mapping

import numpy as np

from .errors import ArgumentError, UndecidedProofError, plain_repr
from .verify.verification import Verification, verify

__all__ = ["assert_derivation", "assert_moments_close", "assert_unit_invariant", "MOMENT_PARTS"]

#: The moments :func:`assert_moments_close` compares, when both sides have them.
MOMENT_PARTS = ("mean", "cov", "cross_cov")
_LEVELS = ("consistent", "proved")


def assert_derivation(lhs: Any, rhs: Any = None, assumptions: Any = None, domain: Any = None, *,
                      require: str = "consistent", points: int = 8, seed: int = 0) -> Verification | list[Verification]:
    """Assert that a derivation holds: not refuted, or proved with ``require="proved"``.

    Parameters
    ----------
    lhs : expression, matrix, Expectation, Verification, or path of a derivation file
        A claim's left side (with ``rhs``); a :class:`~symmon.Verification` to assert on;
        or a derivation file (``.toml``), whose every claim must meet its own ``expect``
        (default: not refuted).
    rhs : optional
        The right side of the claim.
    assumptions, domain, points, seed
        As :func:`symmon.verify`.
    require : {"consistent", "proved"}
        "consistent" accepts a proof or agreement within the reference's error; "proved"
        only a proof.

    Returns
    -------
    Verification, or a list of them for a file

    Raises
    ------
    AssertionError
        With the certificate(s) of the claims that fail.

    Examples
    --------
    >>> import sympy as sp
    >>> x = sp.Symbol("x")
    >>> assert_derivation(sp.cos(2 * x), 1 - 2 * sp.sin(x)**2, require="proved").verdict
    'proved'
    >>> assert_derivation(sp.cos(2 * x), 1 - sp.sin(x)**2)
    Traceback (most recent call last):
        ...
    AssertionError: the derivation does not hold:
    claim:       cos(2*x) = 1 - sin(x)**2
    verdict:     REFUTED
    ...
    """
    if require not in _LEVELS:
        raise ArgumentError(f"require must be 'consistent' or 'proved', got {require!r}")
    if isinstance(lhs, (str, os.PathLike)) and rhs is None:
        return _assert_file(lhs, points, seed)
    v = lhs if isinstance(lhs, Verification) else verify(lhs, rhs, assumptions, domain, points=points, seed=seed)
    if v.verdict == "refuted" or (require == "proved" and not v.proved):
        why = "does not hold" if v.verdict == "refuted" else "is not proved (only consistent with a reference)"
        raise AssertionError(f"the derivation {why}:\n{v}")
    return v


def _assert_file(path: str | os.PathLike, points: int, seed: int) -> list[Verification]:
    from .files.derivationfile import load_derivation_file

    spec = load_derivation_file(path)
    out, failed = [], []
    for claim in spec.claims:
        v = claim.check(points, seed)
        out.append(v)
        if not claim.passes(v):
            wanted = f" (expected {claim.expected})" if claim.expected else ""
            failed.append(f"{claim.name}: {v.verdict}{wanted}\n{v}")
    if failed:
        raise AssertionError(f"{len(failed)} of {len(out)} claims of {spec.path} fail:\n\n" + "\n\n".join(failed))
    return out


def _part(obj: Any, name: str) -> Any:
    return obj.get(name) if isinstance(obj, Mapping) else getattr(obj, name, None)


def _bars(obj: Any, name: str, kind: str) -> np.ndarray | None:
    bars = _part(obj, kind)
    if bars is None:
        return None
    b = bars.get(name) if isinstance(bars, Mapping) else None
    return None if b is None else np.abs(np.asarray(b, dtype=float))


def _numbers(x: Any, what: str) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise ArgumentError(f"{what} must be numbers (evaluate symbolic moments at a point first), got {plain_repr(x)}") from None
    if not np.all(np.isfinite(arr)):
        raise ArgumentError(f"{what} is not finite: {arr.tolist()}")
    return arr


def assert_moments_close(a: Any, b: Any, *, sigmas: float = 5.0, rtol: float = 1e-12, atol: float = 0.0,
                         parts: tuple[str, ...] = MOMENT_PARTS) -> Verification:
    """Assert that two sets of moments agree within the error bars of whichever side has them.

    Entry by entry, ``abs(a − b) ≤ sigmas · √(se_a² + se_b²) + err_a + err_b + rtol · max(abs(a), abs(b)) + atol``,
    where se are standard errors (``stderr``: Monte Carlo, particles)
    and err error bounds (``error``: Gauss–Hermite's ``error_estimate``, :func:`symmon.quadrature_error`);
    a side without them contributes 0, so two closed forms are compared to ``rtol``.

    Parameters
    ----------
    a, b : JointMoments, Moments, SymbolicMoments at numbers, or a mapping
        Anything with ``mean``, ``cov``, ``cross_cov`` (and optionally ``stderr`` and
        ``error`` mappings under the same keys); a missing part is skipped.
    sigmas : float, default 5
        Standard errors allowed (5: a false alarm about once in 3.5 million entries).
    rtol, atol : float
        Rounding allowed on top of the error bars.
    parts : tuple of str
        Which of mean, cov, cross_cov to compare.

    Returns
    -------
    Verification
        Verdict "consistent", with the largest ``abs(a − b)`` over its tolerance.

    Raises
    ------
    AssertionError
        With the entry that differs, both values, the difference and the tolerance and
        where it came from.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x", real=True)
    >>> model, u = sm.Model([x], [x**2], name="square_doc"), sm.Gaussian([1.0], [[0.5]])
    >>> exact = sm.propagate(model, u, transform=sm.Exact())
    >>> mc = sm.propagate(model, u, transform=sm.MonteCarlo(20000, seed=1))
    >>> assert_moments_close(mc, exact).verdict
    'consistent'
    >>> assert_moments_close(sm.propagate(model, u, transform=sm.TT1()), exact)
    Traceback (most recent call last):
        ...
    AssertionError: the moments differ beyond their error bars:
    ...
    """
    if not sigmas >= 0 or not rtol >= 0 or not atol >= 0:
        raise ArgumentError(f"sigmas, rtol and atol must be >= 0, got {sigmas}, {rtol}, {atol}")
    compared, worst, sources = [], (0.0, None), set()
    for name in parts:
        if name not in MOMENT_PARTS:
            raise ArgumentError(f"parts must be among {MOMENT_PARTS}, got {name!r}")
        pa, pb = _part(a, name), _part(b, name)
        if pa is None or pb is None:
            continue
        A, B = _numbers(pa, f"a.{name}"), _numbers(pb, f"b.{name}")
        A, B = np.squeeze(A), np.squeeze(B)
        if A.shape != B.shape:
            raise ArgumentError(f"{name}: shapes differ, {A.shape} and {B.shape}")
        se2 = np.zeros(A.shape)
        err = np.zeros(A.shape)
        for side, label in ((a, "a"), (b, "b")):
            se = _bars(side, name, "stderr")
            if se is not None:
                se2 = se2 + np.squeeze(se) ** 2
                sources.add(f"{sigmas:g} standard errors of {label}")
            e = _bars(side, name, "error")
            if e is not None:
                err = err + np.squeeze(e)
                sources.add(f"the error bound of {label}")
        tol = sigmas * np.sqrt(se2) + err + rtol * np.maximum(np.abs(A), np.abs(B)) + atol
        diff = np.abs(A - B)
        compared.append(name)
        ratio = np.where(tol > 0, diff / np.where(tol > 0, tol, 1), np.where(diff > 0, np.inf, 0.0))
        k = int(np.argmax(ratio)) if ratio.size else 0
        r = float(np.ravel(ratio)[k]) if ratio.size else 0.0
        if r > worst[0] or worst[1] is None:
            idx = np.unravel_index(k, A.shape) if A.ndim else ()
            worst = (r, (name, idx, float(np.ravel(A)[k]), float(np.ravel(B)[k]), float(np.ravel(tol)[k])))
    if not compared:
        raise ArgumentError(f"no moments to compare: neither side has both of {parts}")
    how = ("entrywise |a - b| <= " + " + ".join(sorted(sources) + [f"rtol {rtol:g} x max(|a|, |b|)"]
                                                 + ([f"atol {atol:g}"] if atol else [])))
    ratio, (name, idx, va, vb, tol) = worst
    entry = f"{name}[{', '.join(map(str, idx))}]" if idx else name
    evidence = {"compared": compared, "max_difference_over_tolerance": f"{ratio:.4g}", "worst_entry": entry}
    if ratio > 1:
        v = Verification(f"moments a = moments b ({', '.join(compared)})", "refuted", how, (), evidence,
                         {"point": {}, "entry": entry, "lhs": f"{va:.17g}", "rhs": f"{vb:.17g}",
                          "difference": f"{va - vb:.6g}", "exact_difference": None,
                          "recheck": f"tolerance of this entry {tol:.6g}"})
        raise AssertionError(f"the moments differ beyond their error bars:\n{v}")
    return Verification(f"moments a = moments b ({', '.join(compared)})", "consistent", how, (), evidence)


def assert_unit_invariant(model: Any, weight: Any = "full", transform: Any = "tt2", **kwargs: Any) -> Any:
    """Assert that the measure of nonlinearity of ``model`` is unit invariant (21), (34).

    The proof is :func:`symmon.units.prove_invariance` (lemmas proved once, then an exact
    per-model check; Straka & Havlík 2024, Sections III–IV).

    Parameters
    ----------
    model : Model
    weight : {"full", "diag", "liu-li", "liu-li-raw"}, matrix or callable
    transform : "tt2", "ut", "gh", "mc" or such a Transform
    **kwargs
        Passed to :func:`symmon.units.prove_invariance` (mean, cov, noise_cov, route, ...).

    Returns
    -------
    InvarianceProof

    Raises
    ------
    AssertionError
        The measure is not invariant (with the counterexample: two values of M² in two
        systems of units), or the proof reached no verdict.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x, y = sp.symbols("x y", real=True)
    >>> polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)])
    >>> assert_unit_invariant(polar, weight="full").holds
    True
    >>> assert_unit_invariant(polar, weight="liu-li")
    Traceback (most recent call last):
        ...
    AssertionError: the measure of nonlinearity is not unit invariant:
    ...
    """
    from .units.proofs import prove_invariance

    try:
        proof = prove_invariance(model, weight, transform, **kwargs)
    except UndecidedProofError as exc:
        raise AssertionError(f"the unit-invariance proof reached no verdict: {exc}") from None
    if not proof.holds:
        raise AssertionError(f"the measure of nonlinearity is not unit invariant:\n{proof}")
    return proof
