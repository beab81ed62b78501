"""Derivation files: a paper's appendix as claims that ``symmon verify`` checks.

A derivation file (TOML) declares symbols with their assumptions, optionally a Gaussian
vector for expectations and models, and a list of claims, each an equation between
expressions of the whitelist language of :mod:`symmon.files.expressions` (nothing in the
file is executed)::

    title = "Shin et al. (2020), Lemma 1"

    [symbols]                      # parameters, each with an assumption word (or a list)
    mu = "real"
    sigma = "positive"

    [gaussian]                     # the random vector of expect(...)
    variables = ["x"]
    mean = ["mu"]
    cov = [["sigma**2"]]

    [[claims]]
    name = "Lemma 1, eq. (8)"
    lhs = "expect(abs(x))"
    rhs = "mu*(1 - 2*Phi(-mu/sigma)) + 2*sigma*phi(mu/sigma)"

Besides the functions of model files, a claim may call ``erf``, ``erfc``, ``Phi`` (the
standard normal CDF, (1 + erf(t/√2))/2), ``phi`` (its density) and ``expect(f)``, E[f(x)]
over the ``[gaussian]`` vector. A side that is ``expect(f)`` is checked against a numeric
reference when E[f] has no closed form; ``expect`` inside a larger expression must have one.

**Tables.** ``[symbols]`` (name → ``real``, ``positive``, ``nonnegative``, ``negative``,
``nonpositive``, ``nonzero``, or a list of them); ``[gaussian]`` (``variables``, ``mean``,
``cov``: expressions in the symbols); ``[domain]`` (name → ``[low, high]``, where the random
points are drawn); ``[models.NAME]`` (``inputs``, ``outputs``, and the input Gaussian
``mean``, ``cov`` in the symbols: a model of a claim); ``[[claims]]``, each with an optional
``name`` and ``expect`` (the verdict the author expects), and by ``kind``:

==============  ===================================================================
kind            keys
==============  ===================================================================
identity        ``lhs``, ``rhs`` (the default kind); ``assumptions``: relations such
                as ``"x >= y"`` restricting the random points of this claim
moments         ``model``, ``transform`` (``exact``, ``tt1``, ``tt2``, ``ut``, ...),
                one or more of ``mean`` (a list), ``cov``, ``cross_cov`` (lists of lists)
jacobian        ``model``, ``value`` (n_y lists of n_u expressions)
hessian         ``model``, ``value`` (one n_u × n_u matrix per output)
mon             ``model``, ``weight``, ``transform``, ``value`` (the claimed M²)
weight          ``weight``, ``cov`` (Σ_gg, drawn positive definite), ``value`` (W)
estimator       ``target`` (h(x)), ``estimator``, ``bias`` (default 0), ``mse``
==============  ===================================================================

A claim passes when it is proved or consistent; with ``expect = "refuted"`` (an erratum
kept on record) it passes when refuted, and with ``expect = "proved"`` only when proved.
Limits: the model file's (size, names, expressions), and at most :data:`MAX_CLAIMS` claims.
"""

# Security note: this module does not use eval, exec, compile, sympify or parse_expr;
# file text reaches sympy only through expressions.parse_expression.

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import sympy as sp

from ..core.model import Model
from ..errors import ExpectationNotClosedForm, ModelError, ModelFileError
from ..verify.claims import verify_derivatives, verify_estimator, verify_moments, verify_mon, verify_weight
from ..verify.expectation import expect
from ..verify.verification import ASSUMPTIONS, VERDICTS, Expectation, Verification, verify
from .expressions import parse_expression
from .modelfile import _check_keys, _check_name, _Context, _names, _short, read_toml

__all__ = ["DerivationClaim", "DerivationFile", "load_derivation_file", "check_derivation_file", "MAX_CLAIMS",
           "CLAIM_KINDS", "FILE_FUNCTIONS"]

#: Most claims in one file.
MAX_CLAIMS = 200

_TOP_KEYS = ("title", "source", "symbols", "gaussian", "domain", "models", "claims")
_MODEL_KEYS = ("inputs", "outputs", "mean", "cov")
#: Keys of a claim by kind (besides name, kind, expect).
CLAIM_KINDS: Mapping[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # kind: (required, optional)
    "identity": (("lhs", "rhs"), ("assumptions",)),
    "moments": (("model",), ("transform", "mean", "cov", "cross_cov")),
    "jacobian": (("model", "value"), ()),
    "hessian": (("model", "value"), ()),
    "mon": (("model", "value"), ("weight", "transform")),
    "weight": (("weight", "cov", "value"), ()),
    "estimator": (("target", "estimator"), ("bias", "mse")),
}

_EXPECT = sp.Function("expect")


def _phi(t: sp.Expr) -> sp.Expr:
    return sp.exp(-t**2 / 2) / sp.sqrt(2 * sp.pi)


def _Phi(t: sp.Expr) -> sp.Expr:
    return (1 + sp.erf(t / sp.sqrt(2))) / 2


#: The functions a derivation file adds to the expression language: name -> (builder, arity).
FILE_FUNCTIONS: Mapping[str, tuple[Callable[..., sp.Expr], int, int]] = {
    "erf": (sp.erf, 1, 1),
    "erfc": (sp.erfc, 1, 1),
    "Phi": (_Phi, 1, 1),
    "phi": (_phi, 1, 1),
    "expect": (_EXPECT, 1, 1),
}


@dataclass(frozen=True)
class DerivationClaim:
    """One claim of a derivation file: its name, kind, the verdict expected, and how to check it."""

    name: str
    kind: str
    expected: str | None
    check: Callable[[int, int], Verification]

    def passes(self, v: Verification) -> bool:
        """Whether a verdict meets the claim's expectation (default: not refuted)."""
        if self.expected is None or self.expected == "consistent":
            return v.passed
        return v.verdict == self.expected


@dataclass(frozen=True)
class DerivationFile:
    """A derivation file read: its title, source, and claims."""

    title: str
    source: str
    claims: tuple[DerivationClaim, ...]
    path: Path


class _Reader:
    def __init__(self, path: Path, ctx: _Context, doc: dict) -> None:
        self.path, self.ctx, self.doc = path, ctx, doc
        self.seen: dict[str, str] = {}
        self.symbols: dict[str, sp.Symbol] = {}
        self.gaussian: tuple[list[sp.Symbol], sp.Matrix, sp.Matrix] | None = None
        self.models: dict[str, tuple[Model, sp.Matrix, sp.Matrix]] = {}
        self.domain: dict[sp.Symbol, tuple] = {}

    def error(self, where: str, message: str) -> ModelFileError:
        return self.ctx.error(where, message)

    def expr(self, text: Any, where: str, names: Mapping[str, sp.Expr] | None = None) -> sp.Expr:
        if isinstance(text, bool) or not isinstance(text, (str, int, float)):
            raise self.error(where, f"must be an expression (a string or a number), got {_short(text)}")
        if not isinstance(text, str):
            text = repr(text)
        return parse_expression(text, dict(names if names is not None else self.names()),
                                source=f"{self.path}: {where}", functions=FILE_FUNCTIONS)

    def names(self) -> dict[str, sp.Expr]:
        out: dict[str, sp.Expr] = dict(self.symbols)
        if self.gaussian is not None:
            out.update({s.name: s for s in self.gaussian[0]})
        return out

    def vector(self, value: Any, where: str, n: int | None = None, names=None) -> sp.Matrix:
        if not isinstance(value, list) or (n is not None and len(value) != n):
            raise self.error(where, f"must be a list of {n if n is not None else 'some'} expressions, got {_short(value)}")
        return sp.Matrix([self.expr(v, f"{where}[{i}]", names) for i, v in enumerate(value)])

    def matrix(self, value: Any, where: str, rows: int | None = None, cols: int | None = None, names=None) -> sp.Matrix:
        if not isinstance(value, list) or not value or not all(isinstance(r, list) for r in value):
            raise self.error(where, f"must be a matrix (a list of lists of expressions), got {_short(value)}")
        if (rows is not None and len(value) != rows) or len({len(r) for r in value}) != 1 or (
                cols is not None and len(value[0]) != cols):
            raise self.error(where, f"must be a {rows or '?'} x {cols or '?'} matrix, got {_short(value)}")
        return sp.Matrix([[self.expr(v, f"{where}[{i}][{j}]", names) for j, v in enumerate(r)]
                          for i, r in enumerate(value)])

    # -- tables --------------------------------------------------------------------------
    def read_symbols(self) -> None:
        table = self.doc.get("symbols", {})
        if not isinstance(table, dict):
            raise self.error("symbols", f"must be a table name = assumption, got {_short(table)}")
        for name, words in table.items():
            self._name(name, "[symbols]")
            words = [words] if isinstance(words, str) else words
            if not isinstance(words, list) or not all(isinstance(w, str) and w in ASSUMPTIONS for w in words):
                raise self.error(f"[symbols].{name}", f"must be one of {', '.join(ASSUMPTIONS)} (or a list of them), "
                                 f"got {_short(words)}")
            props = {k: v for w in words for k, v in ASSUMPTIONS[w].items()}
            try:
                self.symbols[name] = sp.Symbol(name, **{"real": True, **props})
            except Exception:  # contradictory words
                raise self.error(f"[symbols].{name}", f"the assumptions {words} contradict each other") from None

    def _name(self, name: Any, where: str) -> None:
        if not isinstance(name, str):
            raise self.error(where, f"names must be strings, got {_short(name)}")
        if name in FILE_FUNCTIONS:
            raise self.error(where, f"{name!r} is reserved (a function of derivation files)")
        _check_name(self.ctx, name, where, self.seen)

    def read_gaussian(self) -> None:
        if "gaussian" not in self.doc:
            return
        table = self.doc["gaussian"]
        if not isinstance(table, dict):
            raise self.error("gaussian", f"must be a table, got {_short(table)}")
        _check_keys(self.ctx, table, ("variables", "mean", "cov"), ("variables", "mean", "cov"), "[gaussian]")
        names = _names(self.ctx, table["variables"], "[gaussian].variables", self.seen)
        if not names or any(n in FILE_FUNCTIONS for n in names):
            raise self.error("[gaussian].variables", "must name at least one variable, none of "
                             + ", ".join(FILE_FUNCTIONS))
        xs = [sp.Symbol(n, real=True) for n in names]
        mean = self.vector(table["mean"], "[gaussian].mean", len(xs), self.symbols)
        cov = self.matrix(table["cov"], "[gaussian].cov", len(xs), len(xs), self.symbols)
        self.gaussian = (xs, mean, cov)

    def read_domain(self) -> None:
        table = self.doc.get("domain", {})
        if not isinstance(table, dict):
            raise self.error("domain", f"must be a table name = [low, high], got {_short(table)}")
        for name, value in table.items():
            if name not in self.symbols:
                raise self.error(f"[domain].{name}", f"is not a symbol of [symbols] ({', '.join(self.symbols)})")
            if (not isinstance(value, list) or len(value) != 2
                    or not all(isinstance(v, (int, float, str)) and not isinstance(v, bool) for v in value)):
                raise self.error(f"[domain].{name}", f"must be [low, high], got {_short(value)}")
            lo, hi = (self.expr(v, f"[domain].{name}", {}) for v in value)
            if not (lo.is_Rational or lo.is_Float) or not (hi.is_Rational or hi.is_Float) or not lo < hi:
                raise self.error(f"[domain].{name}", f"must be two numbers low < high, got {_short(value)}")
            self.domain[self.symbols[name]] = (lo, hi)

    def read_models(self) -> None:
        table = self.doc.get("models", {})
        if not isinstance(table, dict):
            raise self.error("models", f"must be a table of models, got {_short(table)}")
        for mname, spec in table.items():
            where = f"[models.{_short(mname, 60)}]"
            if len(mname) > 100 or not mname.isprintable():
                raise self.error("models", f"{_short(mname)}: a model's name has at most 100 printable characters")
            if not isinstance(spec, dict):
                raise self.error(where, f"must be a table, got {_short(spec)}")
            _check_keys(self.ctx, spec, _MODEL_KEYS, _MODEL_KEYS, where)
            inputs = _names(self.ctx, spec["inputs"], f"{where}.inputs", self.seen)
            if not inputs:
                raise self.error(f"{where}.inputs", "at least one input is required")
            us = [sp.Symbol(n, real=True) for n in inputs]
            env = {**self.symbols, **{s.name: s for s in us}}
            outputs = spec["outputs"]
            if not isinstance(outputs, list) or not outputs:
                raise self.error(f"{where}.outputs", f"must be a non-empty list of expressions, got {_short(outputs)}")
            g = [self.expr(o, f"{where}.outputs[{i}]", env) for i, o in enumerate(outputs)]
            try:
                model = Model(us, g, name=mname)
            except ModelError as exc:
                raise self.error(where, str(exc)) from None
            mean = self.vector(spec["mean"], f"{where}.mean", len(us), self.symbols)
            cov = self.matrix(spec["cov"], f"{where}.cov", len(us), len(us), self.symbols)
            self.models[mname] = (model, mean, cov)

    # -- claims --------------------------------------------------------------------------
    def claims(self) -> list[DerivationClaim]:
        raw = self.doc.get("claims", [])
        if not isinstance(raw, list) or not raw or not all(isinstance(c, dict) for c in raw):
            raise self.error("claims", "must be a non-empty array of tables [[claims]]")
        if len(raw) > MAX_CLAIMS:
            raise self.error("claims", f"{len(raw)} claims: at most {MAX_CLAIMS} are accepted")
        return [self.claim(c, i) for i, c in enumerate(raw)]

    def claim(self, c: dict, i: int) -> DerivationClaim:
        where = f"claims[{i}]"
        kind = c.get("kind", "identity")
        if kind not in CLAIM_KINDS:
            raise self.error(f"{where}.kind", f"must be one of {', '.join(CLAIM_KINDS)}, got {_short(kind)}")
        required, optional = CLAIM_KINDS[kind]
        _check_keys(self.ctx, c, ("name", "kind", "expect", *required, *optional), required, where)
        name = c.get("name", f"claim {i + 1}")
        if not isinstance(name, str) or len(name) > 200 or not name.isprintable():
            raise self.error(f"{where}.name", "must be at most 200 printable characters")
        expected = c.get("expect")
        if expected is not None and expected not in VERDICTS:
            raise self.error(f"{where}.expect", f"must be one of {', '.join(VERDICTS)}, got {_short(expected)}")
        handlers = {"identity": self._identity, "moments": self._moments, "jacobian": self._jacobian,
                    "hessian": self._hessian, "mon": self._mon, "weight": self._weight_claim,
                    "estimator": self._estimator}
        check = handlers[kind](c, where)
        return DerivationClaim(name, kind, expected, check)

    def _model(self, c: dict, where: str) -> tuple[Model, sp.Matrix, sp.Matrix]:
        m = c["model"]
        if not isinstance(m, str) or m not in self.models:
            raise self.error(f"{where}.model", f"must name a [models.NAME] table ({', '.join(self.models) or 'none'}), "
                             f"got {_short(m)}")
        return self.models[m]

    def _side(self, e: sp.Expr, where: str) -> Any:
        """A parsed side: expect(f) alone becomes an Expectation; inside, each expect must close."""
        calls = e.atoms(_EXPECT)
        if not calls:
            return e
        if self.gaussian is None:
            raise self.error(where, "expect(...) needs a [gaussian] table (its variables, mean and cov)")
        xs, mean, cov = self.gaussian
        if isinstance(e, _EXPECT):
            return Expectation(e.args[0], xs, mean, cov)
        closed = {}
        for call in calls:
            try:
                closed[call] = expect(call.args[0], xs, mean, cov)
            except ExpectationNotClosedForm as exc:
                raise self.error(where, f"{call} inside a larger expression has no closed form ({exc}); write the "
                                 "claim as expect(...) = ... to check it against a numeric reference") from None
        return e.xreplace(closed)

    def _relations(self, c: dict, where: str) -> list:
        texts = c.get("assumptions", [])
        if not isinstance(texts, list) or not all(isinstance(t, str) for t in texts):
            raise self.error(f"{where}.assumptions", f"must be a list of relations such as 'x >= y', got {_short(texts)}")
        out = []
        for k, t in enumerate(texts):
            m = re.fullmatch(r"\s*(.+?)\s*(<=|>=|<|>)\s*(.+?)\s*", t)
            if m is None:
                raise self.error(f"{where}.assumptions[{k}]", f"must be 'a < b', 'a <= b', 'a > b' or 'a >= b', got {_short(t)}")
            a, b = (self.expr(s, f"{where}.assumptions[{k}]", self.symbols) for s in (m.group(1), m.group(3)))
            out.append({"<": sp.Lt, "<=": sp.Le, ">": sp.Gt, ">=": sp.Ge}[m.group(2)](a, b))
        return out

    def _identity(self, c: dict, where: str) -> Callable[[int, int], Verification]:
        lhs = self._side(self.expr(c["lhs"], f"{where}.lhs"), f"{where}.lhs")
        rhs = self._side(self.expr(c["rhs"], f"{where}.rhs"), f"{where}.rhs")
        rel = self._relations(c, where)
        text = f"{c['lhs']} = {c['rhs']}"
        return lambda points, seed: verify(lhs, rhs, rel or None, self.domain or None, points=points, seed=seed,
                                           claim=text)

    def _moments(self, c: dict, where: str) -> Callable[[int, int], Verification]:
        model, mean, cov = self._model(c, where)
        env = {**self.symbols, **{s.name: s for s in model.inputs}}
        ny, nu = model.n_y, model.n_u
        claimed = {}
        if "mean" in c:
            claimed["mean"] = self.vector(c["mean"], f"{where}.mean", ny, env)
        if "cov" in c:
            claimed["cov"] = self.matrix(c["cov"], f"{where}.cov", ny, ny, env)
        if "cross_cov" in c:
            claimed["cross_cov"] = self.matrix(c["cross_cov"], f"{where}.cross_cov", ny, nu, env)
        if not claimed:
            raise self.error(where, "a moments claim needs mean, cov and/or cross_cov")
        transform = self._transform(c, where, "exact")
        return lambda points, seed: verify_moments(model, (mean, cov), transform=transform, domain=self.domain or None,
                                                   points=points, seed=seed, **claimed)

    def _transform(self, c: dict, where: str, default: str) -> str:
        t = c.get("transform", default)
        if not isinstance(t, str) or not re.fullmatch(r"[a-z0-9_\-]{1,20}", t):
            raise self.error(f"{where}.transform", f"must be a transform name (exact, tt1, tt2, ut, ...), got {_short(t)}")
        return t

    def _jacobian(self, c: dict, where: str) -> Callable[[int, int], Verification]:
        model, _, _ = self._model(c, where)
        env = {**self.symbols, **{s.name: s for s in model.inputs}}
        J = self.matrix(c["value"], f"{where}.value", model.n_y, model.n_u, env)
        return lambda points, seed: verify_derivatives(model, jacobian=J, domain=self.domain or None, points=points,
                                                       seed=seed)

    def _hessian(self, c: dict, where: str) -> Callable[[int, int], Verification]:
        model, _, _ = self._model(c, where)
        env = {**self.symbols, **{s.name: s for s in model.inputs}}
        value = c["value"]
        if not isinstance(value, list) or len(value) != model.n_y:
            raise self.error(f"{where}.value", f"must be a list of {model.n_y} matrices (one per output)")
        H = [self.matrix(h, f"{where}.value[{i}]", model.n_u, model.n_u, env) for i, h in enumerate(value)]
        return lambda points, seed: verify_derivatives(model, hessians=H, domain=self.domain or None, points=points,
                                                       seed=seed)

    def _mon(self, c: dict, where: str) -> Callable[[int, int], Verification]:
        model, mean, cov = self._model(c, where)
        value = self.expr(c["value"], f"{where}.value", self.symbols)
        weight = self._weight(c, where)
        transform = self._transform(c, where, "tt2")
        return lambda points, seed: verify_mon(model, (mean, cov), value, weight, transform,
                                               domain=self.domain or None, points=points, seed=seed)

    def _weight(self, c: dict, where: str) -> str:
        w = c.get("weight", "full")
        if w not in ("full", "diag", "liu-li", "liu-li-raw"):
            raise self.error(f"{where}.weight", f"must be full, diag, liu-li or liu-li-raw, got {_short(w)}")
        return w

    def _weight_claim(self, c: dict, where: str) -> Callable[[int, int], Verification]:
        S = self.matrix(c["cov"], f"{where}.cov", names=self.symbols)
        W = self.matrix(c["value"], f"{where}.value", S.rows, S.cols, self.symbols)
        weight = self._weight(c, where)
        return lambda points, seed: verify_weight(weight, S, W, points=points, seed=seed)

    def _estimator(self, c: dict, where: str) -> Callable[[int, int], Verification]:
        if self.gaussian is None:
            raise self.error(where, "an estimator claim needs a [gaussian] table (the x of h(x))")
        xs, mean, cov = self.gaussian
        target = self.expr(c["target"], f"{where}.target")
        est = self.expr(c["estimator"], f"{where}.estimator", self.symbols)
        bias = self.expr(c.get("bias", 0), f"{where}.bias", self.symbols)
        mse = self.expr(c["mse"], f"{where}.mse", self.symbols) if "mse" in c else None
        return lambda points, seed: verify_estimator(target, est, xs, mean, cov, bias=bias, mse=mse,
                                                     domain=self.domain or None, points=points, seed=seed)


def load_derivation_file(path: str | os.PathLike) -> DerivationFile:
    """Read a derivation file (TOML) into its claims, without checking them.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    DerivationFile

    Raises
    ------
    ModelFileError
        With the file name and the key (and, for an expression, the line and column): a
        missing or unreadable file, invalid TOML, unknown or missing keys, refused
        expressions, unknown names, wrong shapes.
    """
    path, ctx, doc = read_toml(path, "derivation files")
    _check_keys(ctx, doc, _TOP_KEYS, ("claims",), "")
    title, source = doc.get("title", path.stem), doc.get("source", "")
    for key, value in (("title", title), ("source", source)):
        if not isinstance(value, str) or len(value) > 500 or not value.isprintable():
            raise ctx.error(key, "must be a string of at most 500 printable characters")
    r = _Reader(path, ctx, doc)
    r.read_symbols()
    r.read_gaussian()
    r.read_domain()
    r.read_models()
    return DerivationFile(title, source, tuple(r.claims()), path)


def check_derivation_file(path: str | os.PathLike, *, points: int = 8, seed: int = 0
                          ) -> tuple[DerivationFile, list[Verification]]:
    """Read a derivation file and check each claim (:func:`symmon.verify` and its kin).

    Returns
    -------
    (DerivationFile, list of Verification)
        One verdict per claim, in the file's order.
    """
    spec = load_derivation_file(path)
    return spec, [c.check(points, seed) for c in spec.claims]
