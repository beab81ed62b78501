"""Verify a claimed formula: proved, refuted with a counterexample, or consistent with a reference.

:func:`verify` decides a claim ``lhs = rhs`` between sympy expressions or matrices, either
side of which may be a Gaussian expectation (:class:`Expectation`, in closed form through
:func:`symmon.expect` when it has one). The verdict is one of

- **proved**: the difference simplifies to 0 in exact arithmetic (sympy's ``cancel`` for
  rational functions, else ``expand``, ``simplify``), under the stated assumptions. Never
  from numbers.
- **refuted**: a counterexample, an exact rational point of the domain where the two sides
  differ: both values in 50 digits (sympy's ``evalf`` of the exact expressions), their
  difference, the exact difference when it is short, and an independent re-check in 100
  digits (the two sides evaluated apart, by mpmath). With a numeric reference (no closed
  form), a difference beyond the reference's error bound, confirmed by an independent
  refined reference (:mod:`symmon.verify.numeric`). A near miss that agrees in 50 digits is
  refuted when the exact difference at a point is provably not 0 (a nonzero rational, or a
  number sympy's ``evalf(strict=True)`` finds nonzero), re-checked with each side apart in
  exact arithmetic or in as many digits as the difference needs.
- **consistent**: no proof was found, and the claim agrees at every random point of the
  domain within the reference's own error: 1e-35 relative for exact expressions in 50
  digits, the quadrature's error estimate, or Monte Carlo's standard errors.

No verdict (:class:`~symmon.errors.UndecidedProofError`) when the check cannot decide: no
point where both sides are defined, a re-check that does not confirm a difference, a
numeric reference that cannot bound its error (a ``DiracDelta``, a jump no sample crosses).
Every simplification runs within the claim's time ``budget`` (:func:`symmon.timelimit.deadline`);
a proof not found in time leaves the points to decide, and the certificate says so. A
variable of an :class:`Expectation` takes every real value and may carry no assumption
(``positive=True`` would make sympy turn ``Abs(x)`` into ``x``): it is refused.

Every :class:`Verification` states the claim, the method, the assumptions and the evidence,
prints as a short certificate and converts to JSON.

Numbers in a claim are exact: a float is read as its shortest decimal (0.17 → 17/100), so
write ``sp.Rational(1, 3)`` rather than ``1/3.`` for a third.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping, Sequence

import mpmath
import numpy as np
import sympy as sp
from sympy.printing.str import StrPrinter

from ..errors import (
    ArgumentError,
    ArgumentTypeError,
    ExpectationNotClosedForm,
    NonFiniteError,
    ShapeError,
    SingularMatrixError,
    UndecidedProofError,
    plain_repr,
)
from ..timelimit import OutOfTime, deadline
from .expectation import check_variables
from .numeric import Reference, gaussian_integrals

__all__ = ["Verification", "Expectation", "verify", "VERDICTS", "ASSUMPTIONS", "DEFAULT_POINTS",
           "decide", "Side", "exact_side", "numeric_side", "side_of", "prepare", "as_matrix", "domain_items", "exact_matrix"]

VERDICTS = ("proved", "refuted", "consistent")
#: Words an assumption on a symbol may use, and the sympy assumption each sets.
ASSUMPTIONS: Mapping[str, dict[str, bool]] = {
    "real": {"real": True},
    "positive": {"positive": True},
    "nonnegative": {"nonnegative": True},
    "negative": {"negative": True},
    "nonpositive": {"nonpositive": True},
    "nonzero": {"nonzero": True},
}
#: Random points of the domain checked for an exact claim (and a numeric one: NUMERIC_POINTS).
DEFAULT_POINTS = 8
NUMERIC_POINTS = 4
#: Digits of the screening evaluation and of its independent re-check.
DIGITS, RECHECK_DIGITS = 50, 100
#: Two exact sides differ at a point when |lhs − rhs| > this × max(1, |lhs|, |rhs|) in 50 digits.
EXACT_RTOL = sp.Float("1e-35")
#: sympy's simplify is tried on differences of at most this many operations.
SIMPLIFY_MAX_OPS = 600
#: Seconds the exact work on a claim may take by default (the proof's simplifications and the
#: exact differences at the points), every attempt bounded (:func:`symmon.timelimit.deadline`).
BUDGET_S = 20.0
#: The share of the budget each rewrite tried before ``simplify`` may take at most.
REWRITE_SHARE = 0.25
#: Most digits of the re-check of an exact nonzero difference far below the sides' size.
MAX_RECHECK_DIGITS = 20000
#: Points drawn per point asked for, before giving up on a domain (constraints, definiteness).
TRIES_PER_POINT = 40


# --------------------------------------------------------------------------- the result
@dataclass(frozen=True)
class Verification:
    """The verdict on a claim, with its certificate.

    Attributes
    ----------
    claim : str
        The statement checked.
    verdict : {"proved", "refuted", "consistent"}
    method : str
        How: the exact simplification, the counterexample's arithmetic, or the numeric
        reference and its error bound.
    assumptions : tuple of str
        What the verdict assumes (symbols real, positive, constraints, the Gaussian inputs).
    evidence : dict
        JSON-ready facts behind the verdict: the simplification used, the points checked,
        the largest disagreement against its bound.
    counterexample : dict or None
        For a refutation: the point (exact values by name), both sides and their difference
        in high precision, the exact difference when short, and the re-check.
    seconds : float
        Wall time.
    """

    claim: str
    verdict: str
    method: str
    assumptions: tuple[str, ...] = ()
    evidence: dict = field(default_factory=dict)
    counterexample: dict | None = None
    seconds: float = 0.0

    @property
    def passed(self) -> bool:
        """True unless refuted (proved or consistent)."""
        return self.verdict != "refuted"

    @property
    def proved(self) -> bool:
        return self.verdict == "proved"

    def to_dict(self) -> dict:
        return {"claim": self.claim, "verdict": self.verdict, "method": self.method,
                "assumptions": list(self.assumptions), "evidence": self.evidence,
                "counterexample": self.counterexample, "seconds": round(self.seconds, 3)}

    def to_json(self, indent: int | None = 2) -> str:
        """The certificate as JSON (every number as a string of its digits, exact where exact)."""
        return json.dumps(self.to_dict(), indent=indent, ensure_ascii=False)

    def __str__(self) -> str:
        lines = [f"claim:       {self.claim}", f"verdict:     {self.verdict.upper()}", f"method:      {self.method}",
                 "assumptions: " + ("; ".join(self.assumptions) if self.assumptions else "none")]
        ev = "; ".join(f"{k} = {_short(v)}" for k, v in self.evidence.items() if v not in ([], None, ""))
        lines.append(f"evidence:    {ev}")
        cex = self.counterexample
        if cex is not None:
            lines.append("counterexample: at " + ", ".join(f"{k} = {v}" for k, v in cex["point"].items())
                         + (f", entry {cex['entry']}" if cex.get("entry") else ""))
            lines.append(f"  lhs        = {cex['lhs']}")
            lines.append(f"  rhs        = {cex['rhs']}")
            lines.append(f"  lhs - rhs  = {cex['difference']}"
                         + (f"  (exactly {cex['exact_difference']})" if cex.get("exact_difference") else ""))
            lines.append(f"  re-checked: {cex['recheck']}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"Verification(verdict={self.verdict!r}, claim={self.claim!r})"


def _short(v: Any, limit: int = 160) -> str:
    text = v if isinstance(v, str) else json.dumps(v, ensure_ascii=False)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# --------------------------------------------------------------------------- Gaussian expectations
class Expectation:
    """E[expr] for the Gaussian vector ``over`` ~ N(mean, cov): one side of a claim.

    :func:`verify` takes it in closed form through :func:`symmon.expect` when the expression
    is in that class, and otherwise checks the claim against a numeric reference with its
    error bound (:mod:`symmon.verify.numeric`), which can refute or be consistent, never prove.

    Parameters
    ----------
    expr : sympy expression or matrix
    over : symbol or sequence of symbols
        The Gaussian vector x: symbols with no assumption or ``real=True`` (x takes every
        real value; a symbol declared positive, integer, ... is refused, naming it).
    mean : expression or sequence
        E x (symbols allowed).
    cov : expression or matrix
        Cov x (symbols allowed; a scalar for one variable).

    Examples
    --------
    >>> import sympy as sp
    >>> x, mu = sp.symbols("x mu", real=True)
    >>> s = sp.Symbol("sigma", positive=True)
    >>> Expectation(x**2, x, mu, s**2)
    E[x**2], (x) ~ N([mu], [[sigma**2]])
    """

    def __init__(self, expr: Any, over: Any, mean: Any, cov: Any) -> None:
        self.expr = as_matrix(expr, "expr")
        self.over = tuple(over) if isinstance(over, (list, tuple, sp.MatrixBase)) else (over,)
        if not self.over or not all(isinstance(s, sp.Symbol) for s in self.over):
            raise ArgumentTypeError(f"over must be a sympy Symbol or a sequence of them, got {over!r}")
        check_variables(self.over)
        n = len(self.over)
        self.mean = as_matrix(mean, "mean").reshape(n, 1) if _size(mean) == n else None
        if self.mean is None:
            raise ShapeError(f"mean must have {n} entries (one per variable of over), got {plain_repr(mean)}")
        self.cov = as_matrix(cov, "cov")
        if self.cov.shape != (n, n):
            raise ShapeError(f"cov must be {n}x{n}, got shape {self.cov.shape}")

    @property
    def free_symbols(self) -> set[sp.Symbol]:
        return (self.expr.free_symbols - set(self.over)) | self.mean.free_symbols | self.cov.free_symbols

    def xreplace(self, rule: Mapping) -> "Expectation":
        return Expectation(self.expr.xreplace(rule), [s.xreplace(rule) for s in self.over],
                           self.mean.xreplace(rule), self.cov.xreplace(rule))

    def closed_form(self) -> sp.Matrix:
        """E[expr] through :func:`symmon.expect`; raises ``ExpectationNotClosedForm`` outside its class."""
        from .expectation import expect

        return self.expr.applyfunc(lambda e: expect(e, list(self.over), self.mean, self.cov))

    def numeric(self, point: Mapping, refine: bool = False, seed: int = 0) -> Reference:
        """The reference value of every entry at a point of the parameters, with its error bound."""
        e = self.xreplace(point)
        return gaussian_integrals(list(e.expr), e.over, list(e.mean), e.cov, refine=refine, seed=seed)

    def __repr__(self) -> str:
        body = self.expr[0] if self.expr.shape == (1, 1) else self.expr.tolist()
        names = ", ".join(map(str, self.over))
        return f"E[{_text(body)}], ({names}) ~ N({_text(list(self.mean))}, {_text(self.cov.tolist())})"


def _size(x: Any) -> int:
    if isinstance(x, sp.MatrixBase):
        return x.rows * x.cols
    if isinstance(x, (list, tuple, np.ndarray)):
        return int(np.asarray(x, dtype=object).size)
    return 1


def as_matrix(x: Any, name: str) -> sp.Matrix:
    """A sympy Matrix of the value: a scalar is 1x1, a flat sequence a column."""
    try:
        if isinstance(x, sp.MatrixBase):
            return sp.Matrix(x)
        if isinstance(x, (list, tuple, np.ndarray)):
            arr = np.asarray(x, dtype=object)
            if arr.ndim == 1:
                return sp.Matrix([sp.sympify(v, strict=True) for v in arr])
            if arr.ndim == 2:
                return sp.Matrix(arr.shape[0], arr.shape[1], [sp.sympify(v, strict=True) for v in arr.ravel()])
            raise ShapeError(f"{name} must be a scalar, a vector or a matrix, got {arr.ndim} dimensions")
        return sp.Matrix([[sp.sympify(x, strict=True)]])
    except sp.SympifyError:
        raise ArgumentTypeError(f"{name} must hold sympy expressions or numbers, got {x!r}") from None


def exact_matrix(M: sp.Matrix) -> sp.Matrix:
    """Floats as exact rationals: the shortest decimal of a double (0.17 → 17/100)."""
    floats = M.atoms(sp.Float)
    if not floats:
        return M

    def rational(f: sp.Float) -> sp.Rational:
        if not f.is_finite:
            raise NonFiniteError(f"a claim holds a number that is not finite: {f}")
        return sp.Rational(repr(float(f))) if f._prec <= 53 else sp.Rational(f)

    return M.xreplace({f: rational(f) for f in floats})


# --------------------------------------------------------------------------- the sides of a claim
@dataclass
class Side:
    """One side of a claim: an exact matrix, or a numeric reference with error bars."""

    shape: tuple[int, int]
    exact: sp.Matrix | None = None
    reference: Callable[[Mapping, bool, int], Reference] | None = None
    symbols: set = field(default_factory=set)
    covs: list = field(default_factory=list)
    notes: list = field(default_factory=list)


def exact_side(M: Any, notes: Sequence[str] = (), covs: Sequence[sp.Matrix] = ()) -> Side:
    M = exact_matrix(as_matrix(M, "claim"))
    return Side(M.shape, exact=M, symbols=set(M.free_symbols), covs=list(covs), notes=list(notes))


def numeric_side(shape: tuple[int, int], reference: Callable[[Mapping, bool, int], Reference], symbols: set,
                 covs: Sequence[sp.Matrix], notes: Sequence[str]) -> Side:
    return Side(shape, reference=reference, symbols=set(symbols), covs=list(covs), notes=list(notes))


def side_of(x: Any) -> Side:
    """A claim's side: an :class:`Expectation` in closed form when it has one, else numeric."""
    if isinstance(x, Expectation):
        e = Expectation(exact_matrix(x.expr), x.over, exact_matrix(x.mean), exact_matrix(x.cov))
        try:
            closed = e.closed_form()
        except ExpectationNotClosedForm as exc:
            return numeric_side(e.expr.shape, e.numeric, e.free_symbols, [e.cov],
                                [f"E[...] has no closed form ({exc}): checked against a numeric reference"])
        return exact_side(closed, ["E[...] in closed form by symmon.expect"], covs=[e.cov])
    return exact_side(x)


# --------------------------------------------------------------------------- assumptions and domain
@dataclass
class Prepared:
    """Symbols renamed with their assumptions, the stated assumptions and the sampling domain."""

    rule: dict
    texts: list
    constraints: list
    intervals: dict
    spd: list


def _props_text(name: str, props: Mapping[str, bool]) -> str | None:
    for word, rel in (("positive", "> 0"), ("negative", "< 0"), ("nonnegative", ">= 0"),
                      ("nonpositive", "<= 0"), ("nonzero", "!= 0")):
        if props.get(word):
            return f"{name} {rel}"
    return None


def _symbol_key(key: Any, by_name: Mapping[str, sp.Symbol], what: str) -> sp.Symbol:
    if isinstance(key, sp.Symbol):
        return key
    if isinstance(key, str) and key in by_name:
        return by_name[key]
    raise ArgumentError(f"{what}: {key!r} is not a symbol of the claim (symbols: {', '.join(sorted(by_name))})")


def prepare(objects: Iterable[Any], assumptions: Any, domain: Any) -> tuple[list[Any], Prepared]:
    """Replace every symbol of the objects by a real one carrying its assumptions.

    ``assumptions``: a mapping symbol (or name) → word of :data:`ASSUMPTIONS` (or a list of
    them), or a sequence of relations (``sigma > 0``, ``x >= y``). A relation of one symbol
    against 0 becomes a sympy assumption, used by the proof; any other relation restricts the
    random points only. ``domain``: a mapping symbol (or name) → (low, high), the interval the
    random points are drawn from, or a sympy matrix of symbols → ``"spd"``: its values are
    exact symmetric positive definite matrices.
    """
    objects = list(objects)
    syms: set[sp.Symbol] = set()
    variables: set[sp.Symbol] = set()
    for o in objects:
        if isinstance(o, Expectation):
            syms |= o.free_symbols | set(o.over)
            variables |= set(o.over)
        else:
            syms |= as_matrix(o, "claim").free_symbols
    syms = {s for s in syms if isinstance(s, sp.Symbol)}
    by_name = {s.name: s for s in syms}
    if len(by_name) != len(syms):
        raise ArgumentError("two different symbols of the claim have the same name: rename one")
    props: dict[sp.Symbol, dict[str, bool]] = {s: {} for s in syms}
    constraints: list[sp.Basic] = []
    if assumptions is None:
        pass
    elif isinstance(assumptions, Mapping):
        for key, words in assumptions.items():
            s = _symbol_key(key, by_name, "assumptions")
            _not_a_variable(s, variables, "assumptions", f"{words!r}")
            for w in [words] if isinstance(words, str) else list(words):
                if w not in ASSUMPTIONS:
                    raise ArgumentError(f"assumptions: {w!r} for {s} is not one of {', '.join(ASSUMPTIONS)}")
                props[s].update(ASSUMPTIONS[w])
    else:
        for rel in list(assumptions):
            if not isinstance(rel, sp.core.relational.Relational):
                raise ArgumentTypeError(f"assumptions must be a mapping or a sequence of sympy relations "
                                        f"(sigma > 0), got {rel!r}")
            for v in sorted(rel.free_symbols & variables, key=str):
                _not_a_variable(v, variables, "assumptions", str(rel))
            word = _sign_word(rel)
            if word is not None:
                s, w = word
                if s not in props:
                    raise ArgumentError(f"assumptions: {s} is not a symbol of the claim")
                props[s].update(ASSUMPTIONS[w])
            else:
                constraints.append(rel)
    rule: dict[sp.Symbol, sp.Symbol] = {}
    texts: list[str] = []
    for s in sorted(syms, key=lambda t: t.name):
        own = {k: v for k, v in s.assumptions0.items() if k in ASSUMPTIONS and v}
        merged = {**own, **props[s], "real": True}
        try:
            rule[s] = sp.Symbol(s.name, **merged)
        except Exception as exc:  # contradictory assumptions (positive and negative)
            raise ArgumentError(f"assumptions on {s} contradict each other: {exc}") from None
        text = _props_text(s.name, merged)
        if text:
            texts.append(text)
    texts.insert(0, "every symbol is real")
    constraints = [c.xreplace(rule) for c in constraints]
    texts += [f"{c} (restricts the random points only)" for c in constraints]
    intervals: dict[sp.Symbol, tuple[sp.Rational, sp.Rational]] = {}
    spd: list[sp.Matrix] = []
    for key, value in domain_items(domain):
        if isinstance(key, sp.MatrixBase):
            if value != "spd":
                raise ArgumentError(f"domain: a matrix key takes 'spd' (symmetric positive definite), got {value!r}")
            spd.append(sp.ImmutableMatrix(key).xreplace(rule))
            continue
        _not_a_variable(_symbol_key(key, by_name, "domain"), variables, "domain", f"{value!r}")
        s = rule[_symbol_key(key, by_name, "domain")]
        try:
            lo, hi = (sp.Rational(repr(float(v))) if isinstance(v, float) else sp.Rational(v) for v in value)
        except (TypeError, ValueError):
            raise ArgumentError(f"domain: {key} needs an interval (low, high), got {value!r}") from None
        if not lo < hi:
            raise ArgumentError(f"domain: {key}: low < high is needed, got {value!r}")
        intervals[s] = (lo, hi)
    texts += [f"{s} in [{lo}, {hi}] (random points)" for s, (lo, hi) in intervals.items()]
    texts += [f"{sp.Matrix(M).tolist()} symmetric positive definite (random points)" for M in spd]
    out = [o.xreplace(rule) if isinstance(o, Expectation) else as_matrix(o, "claim").xreplace(rule) for o in objects]
    return out, Prepared(rule, texts, constraints, intervals, spd)


def _not_a_variable(s: sp.Symbol, variables: set, what: str, given: str) -> None:
    """Refuse an assumption or a domain on a variable of a Gaussian expectation."""
    if s in variables:
        raise ArgumentError(
            f"{what}: {s} is a variable of a Gaussian expectation, which takes every real value; "
            f"{given} cannot be assumed of it (sympy would use it, e.g. Abs({s}) -> {s}, and E|{s}| = 0 would follow). "
            f"Drop it, or rename the variable if {s} is also a parameter")


def domain_items(domain: Any) -> list[tuple[Any, Any]]:
    """The (key, value) pairs of a domain: a mapping, or a sequence of pairs (a mutable sympy
    Matrix, which cannot be a dict key, is given as ``[(P, "spd")]``)."""
    if domain is None:
        return []
    if isinstance(domain, Mapping):
        return [(sp.ImmutableMatrix(k) if isinstance(k, sp.MatrixBase) else k, v) for k, v in domain.items()]
    try:
        pairs = [tuple(p) for p in domain]
    except TypeError:
        raise ArgumentTypeError(f"domain must be a mapping or a sequence of (key, value) pairs, got {domain!r}") from None
    if not all(len(p) == 2 for p in pairs):
        raise ArgumentTypeError("domain must be a mapping or a sequence of (key, value) pairs")
    return [(sp.ImmutableMatrix(k) if isinstance(k, sp.MatrixBase) else k, v) for k, v in pairs]


def _sign_word(rel: sp.Basic) -> tuple[sp.Symbol, str] | None:
    """``s > 0`` → (s, "positive"), ``0 < s`` likewise, ..., else None."""
    lhs, rhs = rel.lhs, rel.rhs
    table = {sp.StrictGreaterThan: "positive", sp.GreaterThan: "nonnegative",
             sp.StrictLessThan: "negative", sp.LessThan: "nonpositive", sp.Unequality: "nonzero"}
    flip = {"positive": "negative", "negative": "positive", "nonnegative": "nonpositive",
            "nonpositive": "nonnegative", "nonzero": "nonzero"}
    word = table.get(type(rel))
    if word is None:
        return None
    if isinstance(lhs, sp.Symbol) and rhs == 0:
        return lhs, word
    if isinstance(rhs, sp.Symbol) and lhs == 0:
        return rhs, flip[word]
    return None


def _rational(rng: np.random.Generator, lo: sp.Rational, hi: sp.Rational) -> sp.Rational:
    q = int(rng.integers(1, 9))
    a, b = int(sp.ceiling(lo * q)), int(sp.floor(hi * q))
    if a > b:
        return (lo + hi) / 2
    return sp.Rational(int(rng.integers(a, b + 1)), q)


def _default_interval(s: sp.Symbol) -> tuple[sp.Rational, sp.Rational]:
    four = sp.Integer(4)
    if s.is_positive:
        return sp.Rational(1, 4), four
    if s.is_negative:
        return -four, -sp.Rational(1, 4)
    if s.is_nonnegative:
        return sp.Integer(0), four
    if s.is_nonpositive:
        return -four, sp.Integer(0)
    return -four, four


def _spd(rng: np.random.Generator, n: int) -> sp.Matrix:
    """An exact symmetric positive definite matrix: B Bᵀ + diag(d) with small integers over q."""
    B = sp.Matrix(n, n, [int(v) for v in rng.integers(-2, 3, size=n * n)])
    d = sp.diag(*[int(v) for v in rng.integers(1, 4, size=n)])
    return (B * B.T + d) / int(rng.integers(1, 5))


def _points(symbols: set, prep: Prepared, covs: Sequence[sp.Matrix], count: int, seed: int) -> tuple[list[dict], int]:
    """``count`` exact random points of the domain (and the number of draws refused)."""
    rng = np.random.default_rng(seed)
    symbols = sorted(symbols, key=lambda s: s.name)
    points, refused = [], 0
    for _ in range(count * TRIES_PER_POINT):
        if len(points) == count:
            break
        pt: dict[sp.Symbol, sp.Expr] = {}
        for M in prep.spd:
            S = _spd(rng, M.rows)
            for i in range(M.rows):
                for j in range(M.cols):
                    if isinstance(M[i, j], sp.Symbol):
                        pt[M[i, j]] = S[i, j]
        for s in symbols:
            if s not in pt:
                v = _rational(rng, *prep.intervals.get(s, _default_interval(s)))
                if s.is_nonzero and v == 0:
                    v = sp.Rational(1, 2)
                pt[s] = v
        if not _admissible(pt, prep, covs):
            refused += 1
            continue
        points.append(pt)
    return points, refused


def _admissible(pt: Mapping, prep: Prepared, covs: Sequence[sp.Matrix]) -> bool:
    for c in prep.constraints:
        if c.xreplace(pt) is not sp.true:
            return False
    for P in covs:
        Pn = sp.Matrix(P).xreplace(pt)
        if Pn.free_symbols or not Pn.rows:
            continue
        try:
            A = np.array(Pn.evalf(20).tolist(), dtype=float)
            np.linalg.cholesky(A)
        except (np.linalg.LinAlgError, TypeError):
            return False
    return True


# --------------------------------------------------------------------------- deciding
class _Clock:
    """The budget of a claim's exact work: each attempt runs within what is left of it."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.end = time.perf_counter() + seconds
        self.stopped: list[str] = []

    def left(self) -> float:
        return self.end - time.perf_counter()

    def run(self, name: str, f: Callable[[], Any], share: float = 1.0) -> Any:
        """``f()`` within ``share`` of the budget (and what is left of it), or None when it ran
        out of time (noted) or sympy failed."""
        seconds = min(self.left(), share * self.seconds)
        if seconds <= 0:
            self.stopped.append(name)
            return None
        try:
            with deadline(seconds):
                return f()
        except OutOfTime:
            self.stopped.append(name)
            return None
        except (TypeError, ValueError, ArithmeticError, RecursionError, sp.PolynomialError):
            return None


def _zero_by(e: sp.Expr, clock: _Clock) -> str | None:
    """The exact simplification that takes ``e`` to 0, or None when none does (in the time left)."""
    if e == 0:
        return "identical"
    syms = list(e.free_symbols)
    if e.is_rational_function(*syms):
        return "cancel" if clock.run("cancel", lambda: sp.cancel(sp.together(e))) == 0 else None
    ex = clock.run("expand", lambda: sp.expand(e), REWRITE_SHARE)
    if ex is None:
        ex = e
    elif ex == 0:
        return "expand"
    for name, f in (("rewrite(erf), expand", lambda t: sp.expand(t.rewrite(sp.erf))),
                    ("expand_trig", lambda t: sp.expand(sp.expand_trig(t))),
                    ("powsimp, cancel", lambda t: sp.cancel(sp.powsimp(sp.expand(t), force=False)))):
        if clock.run(name, lambda f=f: f(ex), REWRITE_SHARE) == 0:
            return name
    if sp.count_ops(ex) <= SIMPLIFY_MAX_OPS and clock.run("simplify", lambda: sp.simplify(ex)) == 0:
        return "simplify"
    return None


def _value(e: sp.Expr, pt: Mapping) -> sp.Expr | None:
    """``e`` at an exact point in DIGITS digits, or None when it is not a finite real number."""
    v = sp.N(e.xreplace(pt), DIGITS)
    if not (v.is_number and v.is_real and v.is_finite) or v.has(sp.nan, sp.zoo):
        return None
    return v


def _n(v: Any, digits: int) -> str:
    return mpmath.nstr(v, digits)


def _fmt(v: Any, digits: int = 30) -> str:
    return str(sp.N(v, digits)) if isinstance(v, sp.Basic) else mpmath.nstr(v, digits)


def _recheck(le: sp.Expr, re_: sp.Expr, pt: Mapping, d50: sp.Expr, scale: sp.Expr) -> tuple[bool, str]:
    """The two sides evaluated apart, by mpmath in RECHECK_DIGITS digits (another code path)."""
    syms = sorted(pt, key=lambda s: s.name)
    with mpmath.workdps(RECHECK_DIGITS):
        args = [mpmath.mpf(pt[s].p) / pt[s].q if pt[s].is_Rational else mpmath.mpf(sp.N(pt[s], RECHECK_DIGITS + 10))
                for s in syms]
        try:
            lv = mpmath.mpmathify(sp.lambdify(syms, le, modules="mpmath")(*args))
            rv = mpmath.mpmathify(sp.lambdify(syms, re_, modules="mpmath")(*args))
        except (TypeError, ValueError, ZeroDivisionError, NameError) as exc:
            return False, f"mpmath could not evaluate the sides: {exc}"
        d = lv - rv
        tol = mpmath.mpf(str(EXACT_RTOL)) * mpmath.mpf(str(scale))
        agree = abs(d - mpmath.mpf(str(d50))) <= mpmath.mpf("1e-30") * mpmath.mpf(str(scale))
        ok = bool(abs(d) > tol and agree)
        return ok, (f"in {RECHECK_DIGITS} digits by mpmath, each side apart: lhs = {mpmath.nstr(lv, 30)}, "
                    f"rhs = {mpmath.nstr(rv, 30)}, difference = {mpmath.nstr(d, 20)}")


def _exact_text(value: sp.Expr, clock: _Clock) -> str | None:
    """The exact difference at a point, simplified (within the budget), when it is short and holds no float."""
    if value.free_symbols or value.atoms(sp.Float) or sp.count_ops(value) > 60:
        return None
    if sp.count_ops(value) > 1:
        value = clock.run("the exact difference's text", lambda: sp.radsimp(sp.simplify(value)), REWRITE_SHARE)
        if value is None:
            return None
    text = _text(value)
    return text if len(text) <= 120 and not value.atoms(sp.Float) else None


class _Printer(StrPrinter):
    """sympy's str printer, with integers too long for Python's text conversion (4300 digits
    by default) shown by their first and last digits and their length."""

    def _print_Integer(self, expr: sp.Integer) -> str:
        return _int_text(int(expr.p))

    def _print_int(self, expr: int) -> str:
        return _int_text(expr)

    def _print_Rational(self, expr: sp.Rational) -> str:
        if expr.q == 1:
            return _int_text(int(expr.p))
        return f"{_int_text(int(expr.p))}/{_int_text(int(expr.q))}"


#: Integers of at most this many bits are printed in full (Python converts up to 4300 digits).
_FULL_INT_BITS = 14000


def _int_text(n: int) -> str:
    if abs(n).bit_length() <= _FULL_INT_BITS:
        return str(n)
    a = abs(n)
    digits = int(a.bit_length() * 0.30102999566398120) + 1
    while digits > 1 and 10 ** (digits - 1) > a:
        digits -= 1
    while 10 ** digits <= a:
        digits += 1
    head, tail = a // 10 ** (digits - 20), a % 10 ** 6
    return f"{'-' if n < 0 else ''}{head}...{tail:06d} ({digits} digits)"


def _text(e: Any, limit: int | None = None) -> str:
    """``str(e)`` that never fails on a long integer; cut to ``limit`` characters."""
    text = _Printer().doprint(e)
    return text if limit is None or len(text) <= limit else text[: limit - 3] + "..."


def _entry(M: sp.Matrix, i: int) -> str | None:
    if M.shape == (1, 1):
        return None
    r, c = divmod(i, M.cols)
    return f"[{r}, {c}]" if M.cols > 1 else f"[{r}]"


def _point_text(pt: Mapping) -> dict:
    return {s.name: str(v) for s, v in sorted(pt.items(), key=lambda kv: kv[0].name)}


def _exact_nonzero(le: sp.Expr, re_: sp.Expr, d: sp.Expr, clock: _Clock) -> tuple[sp.Expr, str] | None:
    """The exact difference ``d = le - re_`` at a point when it is provably nonzero, with its
    independent re-check (the sides apart: in exact rational arithmetic when both are rational,
    else by mpmath in as many digits as the difference needs), or None.

    Nonzero is proved by a rational value, or by sympy's ``evalf`` with ``strict=True`` (its
    error control: a nonzero value with all its digits correct); 0 and undecided numbers
    return None, so a near miss is refuted only when its difference is certain."""
    if d.free_symbols or d.atoms(sp.Float):
        return None
    if d.is_Rational:
        if d == 0:
            return None
        value = d
    else:
        value = clock.run("the exact difference at a point", lambda: sp.N(d, 20, strict=True, maxn=MAX_RECHECK_DIGITS),
                          REWRITE_SHARE)
        if value is None or value == 0 or not value.is_real:
            return None
    lx, rx = le, re_
    if lx.is_Rational and rx.is_Rational:
        if lx - rx != d:
            return None
        return d, (f"exact rational arithmetic, each side apart: lhs = {_fmt(lx)}, rhs = {_fmt(rx)}, "
                   f"lhs - rhs = {_text(lx - rx, 120)}")
    scale = max(abs(sp.N(lx, 15)), abs(sp.N(rx, 15)), 1)
    digits = int(sp.ceiling(sp.log(scale / abs(sp.N(value, 15)), 10))) + 40
    if digits > MAX_RECHECK_DIGITS:
        return None
    digits = max(digits, RECHECK_DIGITS)
    with mpmath.workdps(digits):
        try:
            lv, rv = (mpmath.mpmathify(sp.N(x, digits)._to_mpmath(mpmath.mp.prec)) for x in (lx, rx))
        except (TypeError, ValueError, AttributeError):
            return None
        diff = lv - rv
        if not abs(diff - mpmath.mpf(str(sp.N(value, 20)))) <= abs(diff) * mpmath.mpf("1e-10"):
            return None
        return d, (f"in {digits} digits, each side apart: lhs = {mpmath.nstr(lv, 30)}, rhs = {mpmath.nstr(rv, 30)}, "
                   f"difference = {mpmath.nstr(diff, 20)}")


def decide(claim: str, lhs: Side, rhs: Side, prep: Prepared, *, points: int = DEFAULT_POINTS, seed: int = 0,
           notes: Sequence[str] = (), t0: float | None = None, labels: Sequence[str] | None = None,
           budget: float = BUDGET_S) -> Verification:
    """The verdict on ``lhs = rhs`` (sides of the same shape) over the prepared domain; ``labels``
    name the entries (in row-major order) in a counterexample; ``budget`` bounds the seconds of
    the exact work (each simplification attempt within what is left of it)."""
    if isinstance(budget, bool) or not isinstance(budget, (int, float)) or not budget > 0:
        raise ArgumentError(f"budget must be a positive number of seconds, got {budget!r}")
    t0 = time.perf_counter() if t0 is None else t0
    if lhs.shape != rhs.shape:
        raise ShapeError(f"the two sides of the claim have different shapes: {lhs.shape} and {rhs.shape}")
    notes = [*lhs.notes, *rhs.notes, *notes]
    texts = list(prep.texts)
    if lhs.exact is not None and rhs.exact is not None:
        return _decide_exact(claim, lhs, rhs, prep, points, seed, notes, texts, t0, labels, _Clock(float(budget)))
    return _decide_numeric(claim, lhs, rhs, prep, min(points, NUMERIC_POINTS), seed, notes, texts, t0, labels)


def _decide_exact(claim, lhs, rhs, prep, count, seed, notes, texts, t0, labels, clock) -> Verification:
    L, R = lhs.exact, rhs.exact
    D = L - R
    symbols = L.free_symbols | R.free_symbols | lhs.symbols | rhs.symbols
    pts, refused = _points(symbols, prep, lhs.covs + rhs.covs, count, seed) if symbols else ([{}], 0)
    checked, skipped, worst = 0, 0, sp.Integer(0)
    defined = []
    for pt in pts:
        vals = []
        for i in range(len(D)):
            lv, rv = _value(L[i], pt), _value(R[i], pt)
            if lv is None or rv is None:
                vals = None
                break
            vals.append((lv, rv))
        if vals is None:  # a side is undefined there (a pole, a log of a negative): not in the domain
            skipped += 1
            continue
        checked += 1
        defined.append((pt, vals))
        for i, (lv, rv) in enumerate(vals):
            scale = sp.Max(1, abs(lv), abs(rv))
            diff = lv - rv
            worst = sp.Max(worst, abs(diff) / scale)
            if abs(diff) > EXACT_RTOL * scale:
                ok, recheck = _recheck(L[i], R[i], pt, diff, scale)
                if not ok:
                    raise UndecidedProofError(
                        f"{claim}: the sides differ by {_fmt(diff, 10)} at {_point_text(pt)} in {DIGITS} digits, "
                        f"but the re-check does not confirm it ({recheck})")
                exact_text = _exact_text(D[i].xreplace(pt), clock)
                cex = {"point": _point_text(pt), "entry": labels[i] if labels else _entry(D, i), "lhs": _fmt(lv), "rhs": _fmt(rv),
                       "difference": _fmt(diff, 20), "exact_difference": exact_text, "recheck": recheck}
                return Verification(
                    claim, "refuted",
                    f"counterexample at an exact rational point: both sides in {DIGITS} digits (sympy evalf of the "
                    "exact expressions), re-checked apart in mpmath",
                    tuple(texts), {"notes": notes, "points_checked_before": checked - 1}, cex,
                    time.perf_counter() - t0)
    how = [_zero_by(e, clock) for e in D]
    if all(h is not None for h in how):
        return Verification(
            claim, "proved", "exact: lhs - rhs simplifies to 0 (sympy: " + ", ".join(sorted(set(how))) + ")",
            tuple(texts), {"difference": "0", "notes": notes,
                           "also_zero_at_random_points": checked, "digits": DIGITS}, None, time.perf_counter() - t0)
    # A near miss: equal in 50 digits, but the exact difference at a point is not 0.
    for k, (pt, vals) in enumerate(defined):
        for i, (lv, rv) in enumerate(vals):
            if how[i] is not None:
                continue
            le, re_ = L[i].xreplace(pt), R[i].xreplace(pt)
            found = _exact_nonzero(le, re_, D[i].xreplace(pt), clock)
            if found is None:
                continue
            d, recheck = found
            cex = {"point": _point_text(pt), "entry": labels[i] if labels else _entry(D, i), "lhs": _fmt(lv),
                   "rhs": _fmt(rv), "difference": _fmt(sp.N(d, DIGITS), 20), "exact_difference": _text(d, 120),
                   "recheck": recheck}
            return Verification(
                claim, "refuted",
                f"counterexample at an exact rational point: the sides agree to {DIGITS} digits, but their exact "
                "difference there is not 0 (exact arithmetic), re-checked with each side apart",
                tuple(texts), {"notes": notes, "points_checked_before": k}, cex, time.perf_counter() - t0)
    if checked == 0:
        raise UndecidedProofError(f"{claim}: no proof found, and no random point of the domain where both sides are "
                                  f"defined ({skipped} undefined, {refused} refused): give a domain")
    evidence = {"points": checked, "max_relative_difference": _fmt(worst, 5), "notes": notes,
                "unsimplified_entries": sum(h is None for h in how)}
    if clock.stopped:
        evidence["out_of_time"] = (f"stopped within the budget of {clock.seconds:g} s: "
                                   + ", ".join(sorted(set(clock.stopped))))
    return Verification(
        claim, "consistent",
        f"no exact proof found; equal at {checked} random exact points within {EXACT_RTOL} relative "
        f"({DIGITS}-digit evaluation)" + (f"; the proof search stopped at its budget of {clock.seconds:g} s"
                                          if clock.stopped else ""),
        tuple(texts), evidence, None, time.perf_counter() - t0)


def _side_values(side: Side, pt: Mapping, refine: bool, seed: int) -> tuple[list, list, str] | None:
    """The side's values and error bounds at a point, as mpmath numbers in DIGITS digits."""
    if side.exact is not None:
        out = [_value(e, pt) for e in side.exact]
        if any(v is None for v in out):
            return None
        vals = [mpmath.mpf(v._to_mpmath(mpmath.mp.prec)) for v in out]
        return vals, [mpmath.mpf(str(EXACT_RTOL)) * max(1, abs(v)) for v in vals], "exact"
    try:
        ref = side.reference(pt, refine, seed)
    except (NonFiniteError, SingularMatrixError):
        return None
    return [mpmath.mpf(v) for v in ref.values], [mpmath.mpf(e) for e in ref.errors], ref.method


def _decide_numeric(claim, lhs, rhs, prep, count, seed, notes, texts, t0, labels) -> Verification:
    symbols = lhs.symbols | rhs.symbols | (lhs.exact.free_symbols if lhs.exact is not None else set()) \
        | (rhs.exact.free_symbols if rhs.exact is not None else set())
    pts, refused = _points(symbols, prep, lhs.covs + rhs.covs, count, seed) if symbols else ([{}], 0)
    with mpmath.workdps(DIGITS):
        return _numeric_points(claim, lhs, rhs, pts, refused, seed, notes, texts, t0, labels)


def _numeric_points(claim, lhs, rhs, pts, refused, seed, notes, texts, t0, labels) -> Verification:
    checked, worst, methods, resolved = 0, mpmath.mpf(0), set(), 0
    for k, pt in enumerate(pts):
        a, b = _side_values(lhs, pt, False, seed + k), _side_values(rhs, pt, False, seed + k)
        if a is None or b is None:
            continue
        checked += 1
        methods |= {a[2], b[2]} - {"exact"}
        for i in range(len(a[0])):
            diff, bound = abs(a[0][i] - b[0][i]), a[1][i] + b[1][i]
            worst = max(worst, diff / bound if bound > 0 else (mpmath.mpf(0) if diff == 0 else mpmath.inf))
            if diff <= bound:
                continue
            a2, b2 = _side_values(lhs, pt, True, seed + k), _side_values(rhs, pt, True, seed + k)
            if a2 is None or b2 is None:
                continue
            diff2, bound2 = abs(a2[0][i] - b2[0][i]), a2[1][i] + b2[1][i]
            if diff2 <= bound2:
                resolved += 1
                continue
            cex = {"point": _point_text(pt), "entry": labels[i] if labels else _entry(sp.zeros(*lhs.shape), i),
                   "lhs": f"{_n(a[0][i], 20)} ± {_n(a[1][i], 3)}", "rhs": f"{_n(b[0][i], 20)} ± {_n(b[1][i], 3)}",
                   "difference": f"{_n(a[0][i] - b[0][i], 10)} (bound {_n(bound, 3)})", "exact_difference": None,
                   "recheck": (f"refined reference ({a2[2] if a2[2] != 'exact' else b2[2]}): lhs = {_n(a2[0][i], 20)}, "
                               f"rhs = {_n(b2[0][i], 20)}, |difference| = {_n(diff2, 10)} > bound {_n(bound2, 3)}")}
            return Verification(claim, "refuted",
                                f"numeric reference beyond its error bound, confirmed by a refined reference "
                                f"({'; '.join(sorted(methods))})", tuple(texts), {"notes": notes}, cex,
                                time.perf_counter() - t0)
    if checked == 0:
        raise UndecidedProofError(f"{claim}: no random point of the domain where both sides are defined "
                                  f"({refused} refused): give a domain")
    return Verification(
        claim, "consistent",
        f"no closed form, so no proof; agrees at {checked} random points within the reference's error bound "
        f"({'; '.join(sorted(methods))})",
        tuple(texts), {"points": checked, "max_difference_over_bound": _n(worst, 4),
                       "disagreements_resolved_by_refinement": resolved, "notes": notes},
        None, time.perf_counter() - t0)


# --------------------------------------------------------------------------- the front end
def verify(lhs: Any, rhs: Any, assumptions: Any = None, domain: Any = None, *, points: int = DEFAULT_POINTS,
           seed: int = 0, claim: str | None = None, budget: float = BUDGET_S) -> Verification:
    """Verify the claim ``lhs = rhs``: proved, refuted (with a counterexample) or consistent.

    Parameters
    ----------
    lhs, rhs : sympy expression or matrix, number, or :class:`Expectation`
        The two sides, of the same shape. An :class:`Expectation` (a Gaussian expectation,
        e.g. of a distance as in Lemma 1 of Shin et al. (2020), eq. (8)) is taken in closed
        form by :func:`symmon.expect` when it has one; otherwise the claim is checked against
        a numeric reference with error bars and can only be refuted or consistent.
    assumptions : mapping or sequence, optional
        ``{sigma: "positive"}`` (words: real, positive, nonnegative, negative, nonpositive,
        nonzero) or relations ``[sigma > 0, x >= y]``. A relation of a symbol against 0 is a
        sympy assumption the proof may use; any other relation restricts the random points.
        Every symbol is real.
    domain : mapping or sequence of pairs, optional
        Where the random points are drawn: ``{x: (-1, 1)}``, and ``(P, "spd")`` for a sympy
        matrix of symbols that is a covariance (exact symmetric positive definite values; a
        mutable Matrix is no dict key: pass ``[(P, "spd")]`` or ``sp.ImmutableMatrix(P)``).
        Default: [-4, 4] for a real symbol, [1/4, 4] for a positive one.
    points : int, default 8
        Random points of the screening (4 at most with a numeric reference).
    seed : int, default 0
        Seed of the random points (``numpy.random.default_rng``).
    claim : str, optional
        The statement as printed in the certificate (default: ``lhs = rhs``).
    budget : float, default 20
        Seconds the exact work may take: every simplification attempt of the proof (and of
        an exact difference at a point) stops within what is left of it (each rewrite before
        ``simplify`` within a quarter of it). A proof not found in time leaves the points to
        decide: refuted or consistent, and the certificate says the search stopped.

    Returns
    -------
    Verification

    Raises
    ------
    ShapeError
        The sides have different shapes.
    UndecidedProofError
        No random point of the domain has both sides defined, a difference is not
        confirmed by its re-check, or a numeric reference cannot bound its error (an
        expectation of a ``DiracDelta``, a function whose jumps no sample crosses, a
        number too long for Python's conversion of integers to text).
    ArgumentError
        An assumption or a domain on a variable of an :class:`Expectation` (it takes every
        real value), or a budget that is not a positive number.

    Examples
    --------
    >>> import sympy as sp
    >>> x = sp.Symbol("x")
    >>> verify(sp.sin(x)**2 + sp.cos(x)**2, 1).verdict
    'proved'
    >>> v = verify(sp.sqrt(x**2), x)
    >>> v.verdict, v.counterexample["point"]["x"].startswith("-")
    ('refuted', True)
    >>> verify(sp.sqrt(x**2), x, assumptions=[x >= 0]).verdict
    'proved'
    """
    t0 = time.perf_counter()
    if not isinstance(points, int) or isinstance(points, bool) or points < 1:
        raise ArgumentError(f"points must be a positive integer, got {plain_repr(points)}")
    (lhs_p, rhs_p), prep = prepare([lhs, rhs], assumptions, domain)
    text = claim if claim is not None else f"{_show(lhs_p)} = {_show(rhs_p)}"
    try:
        return decide(text, side_of(lhs_p), side_of(rhs_p), prep, points=points, seed=seed, t0=t0, budget=budget)
    except ValueError as exc:
        if "string conversion" not in str(exc):
            raise
        raise UndecidedProofError(
            f"{_text(text, 200)}: a number of the claim is too long for Python's conversion of integers to text "
            f"({exc}), which a step of the check needs: no verdict") from None


def _show(x: Any) -> str:
    if isinstance(x, Expectation):
        return repr(x)
    M = as_matrix(x, "claim")
    return _text(M[0]) if M.shape == (1, 1) else _text(M.tolist())
