"""Symbolic proofs of unit invariance that scale: lemmas proved once, then a cheap per-model part.

The lemmas are in :mod:`symmon.lemmas` (re-exported here); this module holds the proofs.

The measure of nonlinearity (MoN) is unit invariant (21), (34) of Straka & Havlík (2024) when
M²(g, u) = M²(ḡ, ū) for every change of units (18)::

    u = S_u ū + o_u,    v = S_v v̄,    y = S_y ȳ + o_y,    ḡ(ū, v̄) = S_y⁻¹(g(S_u ū + o_u, S_v v̄) − o_y).

Expanding M² of a model symbolically in both unit systems (the *direct* route) grows without
bound: the GMTI model of the paper took more than 20 minutes and 2.5 GB. The *lemma* route
splits the proof into parts that do not depend on the model, proved once with sympy for
every size (matrix symbols) and cross-checked on explicit generic matrices:

- ``tt2-equivariance``: the TT2 moments of ḡ at ū ~ N(S_u⁻¹(μ − o_u), S_u⁻¹ P S_u⁻ᵀ),
  v̄ ~ N(0, S_v⁻¹ R S_v⁻ᵀ) are those of g mapped by A = S_y⁻¹: Σ_ḡḡ = A Σ_gg Aᵀ,
  Σ_ḡū = A Σ_gu S_u⁻ᵀ, D̄ = A D Aᵀ, by the chain rule J̄ = A J S_w,
  H̄_i = Σ_k A_ik S_wᵀ H_k S_w (S_w = blkdiag(S_u, S_v)).
- ``cholesky-equivariance`` and ``point-rule-equivariance``: for the UT family, Gauss–Hermite and
  Monte Carlo, whose points are μ + L z_i with L = chol(P): chol(S⁻¹ P S⁻ᵀ) = S⁻¹ chol(P) for a
  lower-triangular S with a positive diagonal (a diagonal scale is one), so the points map
  affinely, χ̄_i = S⁻¹(χ_i − o), and the weighted moments map as above.
- ``weight-<name>``: the weight rule's M² = tr(W D) (29) is unchanged under
  (Σ_gg, D) → (A Σ_gg Aᵀ, A D Aᵀ) with A = S_y⁻¹ diagonal positive, for generic symmetric
  n_y×n_y matrices; or it is not (Liu–Li's (6), (8)).

What is specific to a model is checked per model and is cheap: that ḡ is the composition
above (its derivatives, or values, at an exact rational point against the chain rule), and
that the moments the weight needs are regular at the point (Σ_gg nonsingular for (43),
positive variances for (42)). A refutation is a concrete point: the model's mean and
covariance (from the caller or a rational point), rational scales, and the two values of M²,
each computed from its own model's TT2 moments.

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV, eqs. (18)–(21), (29), (34)–(43).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable, Iterator, Sequence

import mpmath
import numpy as np
import sympy as sp

from .errors import ModelError, ShapeError, SingularMatrixError, SymmonError
from .gaussian import Gaussian
from .lemmas import (Lemma, _m2, _reduce, _sym_matrix, _tt2_moments, _weight_label,
                     _weight_part, _WeightPart, lemma_cholesky, lemma_point_rule,
                     lemma_tt2, lemma_weight)
from .model import Model
from .units import _changed_parts, _inverse, _Relation, _sympify_entry
from .weights import NAMED as WEIGHTS

__all__ = [
    "InvarianceProof",
    "Lemma",
    "lemma_tt2",
    "lemma_cholesky",
    "lemma_point_rule",
    "lemma_weight",
    "prove_invariance",
    "prove_matrix_invariance",
]

#: Differences larger than this (sympy operation count) are not put over a common
#: denominator: the counterexample alone decides them.
_CANCEL_MAX_OPS = 20000
#: Digits of the numeric evaluations (composition check, regularity, counterexamples).
_DPS = 40
#: Relative agreement demanded of two 40-digit evaluations of the same exact quantity.
_AGREE_RTOL = mpmath.mpf("1e-25")
#: Default wall-clock budget of the direct route, seconds.
DIRECT_BUDGET_S = 10.0
#: The direct route refuses models whose Σ count_ops(g_i) · n_w² exceeds this: their TT2
#: moments, differentiated and put over a common denominator, do not fit the budget.
DIRECT_MAX_SIZE = 2000


@dataclass(frozen=True)
class InvarianceProof:
    """The outcome of a symbolic unit-invariance check (21), (34).

    Attributes
    ----------
    holds : bool
        True when M²(g, u) − M²(ḡ, ū) is 0 identically in the scales, offsets and moments;
        False when it is provably nonzero (see ``counterexample``).
    difference : sympy.Expr
        The simplified M²(g, u) − M²(ḡ, ū). On the lemma route it is written in generic
        moments (``Sigma_ij`` for Σ_gg, ``D_ij`` for D) and scales (``s_yi``).
    lhs, rhs : sympy.Expr
        M² in the old units and in the new units (same variables as ``difference``).
    weight : str
    transform : str
        ``"tt2"``, ``"ut"``, ``"gh"``, ``"mc"`` for :func:`prove_invariance`, ``"exact"`` for
        :func:`prove_matrix_invariance`.
    statement : str
    symbols : dict
        The symbols of the statement: scales, offsets, moments.
    counterexample : dict or None
        For a failed proof: values of the symbols of ``difference`` at which it is nonzero
        (its value under ``"difference"``), and the model point: ``"mean"``, ``"cov"``, the
        scales ``"S_u"``, ``"o_u"``, ``"S_y"``, ``"o_y"`` and M² computed independently in the
        old (``"lhs"``) and in the new (``"rhs"``) units.
    seconds : float
        Wall time of the proof.
    lemmas : tuple of str
        Names of the lemmas the proof rests on (empty for the direct route).
    assumptions : tuple of str
        Conditions under which the statement is proved.
    """

    holds: bool
    difference: sp.Expr
    lhs: sp.Expr
    rhs: sp.Expr
    weight: str
    transform: str
    statement: str
    symbols: dict = field(repr=False, default_factory=dict)
    counterexample: dict | None = field(repr=False, default=None)
    seconds: float = 0.0
    lemmas: tuple[str, ...] = ()
    assumptions: tuple[str, ...] = ()

    def __bool__(self) -> bool:
        return self.holds

    @property
    def latex(self) -> str:
        """The result as a LaTeX equation (without $ delimiters)."""
        verdict = r"\quad\text{(invariant)}" if self.holds else r"\quad\text{(not invariant)}"
        return (
            r"M^2(\mathbf{g}, \mathbf{u}) - M^2(\bar{\mathbf{g}}, \bar{\mathbf{u}}) = "
            + sp.latex(self.difference) + verdict
        )

    def _repr_latex_(self) -> str:
        return "$" + self.latex + "$"

    def __str__(self) -> str:
        if self.holds:
            tail = "holds: M²(g, u) − M²(ḡ, ū) = 0"
        else:
            d = self.difference
            shown = str(d) if sp.count_ops(d) <= 40 else f"a nonzero expression ({sp.count_ops(d)} operations, see .difference)"
            tail = f"fails: M²(g, u) − M²(ḡ, ū) = {shown}"
            cex = self.counterexample
            if cex is not None and "lhs" in cex:
                tail += (f"; counterexample: M² = {float(cex['lhs']):.10g} in the old units, "
                         f"{float(cex['rhs']):.10g} in the new units with {_show_point(cex)}")
            elif cex is not None:
                tail += f"; e.g. {float(cex['difference']):.6g} at a rational point"
        text = f"{self.statement} with weight {self.weight!r} ({self.transform}): {tail} [{self.seconds:.2f} s]"
        if self.lemmas:
            text += "\n  by the lemmas: " + ", ".join(self.lemmas)
        if self.assumptions:
            text += "\n  assuming: " + "; ".join(self.assumptions)
        return text

    def __repr__(self) -> str:
        return f"InvarianceProof(weight={self.weight!r}, transform={self.transform!r}, holds={self.holds})"


def _show_point(cex: dict) -> str:
    def fmt(M: Any) -> str:
        M = sp.Matrix(M)
        if M.cols > 1 and M.is_diagonal():
            return "diag(" + ", ".join(str(M[i, i]) for i in range(M.rows)) + ")"
        return "[" + ", ".join(str(x) for x in M) + "]"

    keys = ("S_u", "o_u", "S_y", "o_y", "S_v", "mean", "cov", "noise_cov")
    return ", ".join(f"{k} = {fmt(cex[k])}" for k in keys if k in cex and sp.Matrix(cex[k]).rows)


def _exact(x: Any, name: str) -> sp.Expr:
    """Numbers to exact sympy numbers (0.17 → 17/100) so that the proof stays exact."""
    if isinstance(x, sp.Basic):
        return x
    if isinstance(x, (bool, np.bool_)):
        raise ShapeError(f"{name}: booleans are not numbers")
    if isinstance(x, (int, np.integer)):
        return sp.Integer(int(x))
    if isinstance(x, (float, np.floating)):
        if not np.isfinite(x):
            raise ShapeError(f"{name} contains NaN or inf")
        return sp.Rational(repr(float(x)))
    return _sympify_entry(x, name)


def _exact_vector(x: Any, n: int, name: str) -> sp.Matrix:
    items = list(x) if isinstance(x, sp.MatrixBase) else list(np.asarray(x, dtype=object).reshape(-1))
    if len(items) != n:
        raise ShapeError(f"{name} must have length {n}, got {len(items)}")
    return sp.Matrix([_exact(e, name) for e in items])


def _exact_cov(P: Any, n: int, name: str) -> sp.Matrix:
    if isinstance(P, sp.MatrixBase):
        M = sp.Matrix(P).applyfunc(lambda e: _exact(e, name))
    else:
        arr = np.asarray(P, dtype=object)
        if arr.ndim == 0 and n == 1:
            arr = arr.reshape(1, 1)
        if arr.ndim != 2:
            raise ShapeError(f"{name} must be a square matrix, got shape {arr.shape}")
        M = sp.Matrix(arr.shape[0], arr.shape[1], [_exact(e, name) for e in arr.ravel()])
    if M.shape != (n, n):
        raise ShapeError(f"{name} must be {n}x{n}, got {M.rows}x{M.cols}")
    if any(sp.simplify(M[i, j] - M[j, i]) != 0 for i in range(n) for j in range(i)):
        raise ShapeError(f"{name} must be symmetric")
    if not M.free_symbols:
        A = np.array(M.evalf(), dtype=float)
        if np.linalg.eigvalsh(A)[0] <= 0:
            raise SingularMatrixError(f"{name} must be positive definite (its inverse enters D)")
    return M


@lru_cache(maxsize=32)
def _stage1(model, g_bar, mu, P, R, mu_bar, P_bar, R_bar, Sy):
    """TT2 moments in both unit systems and whether Σ_ḡḡ, D̄ = S_y⁻¹ (Σ_gg, D) S_y⁻¹ (cached:
    the weights share it)."""
    Sgg, D = _tt2_moments(model, sp.Matrix(mu), sp.Matrix(P), sp.Matrix(R))
    Sgg_b, D_b = _tt2_moments(g_bar, sp.Matrix(mu_bar), sp.Matrix(P_bar), sp.Matrix(R_bar))
    Sy_inv = _inverse(sp.Matrix(Sy))
    ny = Sgg.rows
    covariant = all(
        sp.cancel(X_b[i, j] - (Sy_inv * X * Sy_inv)[i, j]) == 0
        for X, X_b in ((Sgg, Sgg_b), (D, D_b)) for i in range(ny) for j in range(ny)
    )
    return Sgg, D, Sgg_b, D_b, covariant


def _decide(diff: sp.Expr, seed: int = 0) -> tuple[sp.Expr, bool, dict | None]:
    """Simplify a difference; if it is not 0, find an exact rational point where it is not.

    A nonzero value at one admissible point (positive scales, diagonally dominant
    covariances) is a rigorous disproof, whatever the simplifier managed.
    """
    d = sp.cancel(sp.together(diff)) if sp.count_ops(diff) < _CANCEL_MAX_OPS else diff
    if d == 0:
        return sp.Integer(0), True, None
    rng = np.random.default_rng(seed)
    syms = sorted(d.free_symbols, key=str)
    for _ in range(20):
        point = {}
        for s in syms:
            val = sp.Rational(int(rng.integers(1, 20)), int(rng.integers(1, 7)))
            if not s.is_positive and rng.random() < 0.5:
                val = -val
            # Diagonal entries of covariance symbols (P_11, R_22, ...) dominate their row.
            idx = s.name.rsplit("_", 1)[-1]
            if len(idx) == 2 and idx.isdigit() and idx[0] == idx[1]:
                val = abs(val) + 60
            point[s] = val
        val = d.xreplace(point)
        num = sp.N(val, 50)
        if num.is_finite and abs(num) > sp.Float("1e-30"):
            point["difference"] = val if val.is_Rational else num
            return d, False, point
    raise SymmonError(
        "could not decide the invariance: the difference did not simplify to 0 and no point "
        f"where it is nonzero was found ({sp.count_ops(d)} operations)"
    )


# --------------------------------------------------------------------------------------
# The per-model part: composition, regularity, counterexample
# --------------------------------------------------------------------------------------
def _mp(x: Any) -> mpmath.mpf:
    return sp.N(sp.sympify(x), _DPS + 5)._to_mpmath(mpmath.mp.prec)


def _jets(inputs: Sequence[sp.Symbol], noise: Sequence[sp.Symbol], outputs: Sequence[sp.Expr]) -> Callable:
    """Values, Jacobian and Hessians of g in w = [u; v] as one mpmath function of the point."""
    w = list(inputs) + list(noise)
    g = sp.Matrix(list(outputs))
    J = g.jacobian(w)
    H = [sp.hessian(gi, w) for gi in g]
    f = sp.lambdify(w, [list(g), J.tolist(), [h.tolist() for h in H]], modules="mpmath")

    def at(point: Sequence[Any]) -> tuple[mpmath.matrix, mpmath.matrix, list[mpmath.matrix]]:
        vals, Jv, Hv = f(*[_mp(x) for x in point])
        out = mpmath.matrix([[mpmath.mpmathify(x)] for x in vals]), mpmath.matrix(Jv), [mpmath.matrix(h) for h in Hv]
        if not all(mpmath.isfinite(x) for M in (out[0], out[1], *out[2]) for x in M):
            raise SymmonError(
                f"g or its derivatives are not finite at {[str(x) for x in point]}: TT2 needs g twice "
                "differentiable at the mean"
            )
        return out

    return at


def _mp_matrix(M: sp.Matrix) -> mpmath.matrix:
    return mpmath.matrix(M.rows, M.cols) if M.rows == 0 else mpmath.matrix([[_mp(x) for x in row] for row in M.tolist()])


def _half_traces(H: list[mpmath.matrix], P: mpmath.matrix) -> mpmath.matrix:
    HP = [h * P for h in H]
    n = len(H)
    T = mpmath.matrix(n, n)
    for i in range(n):
        for j in range(n):
            T[i, j] = sum((HP[i] * HP[j])[k, k] for k in range(P.rows)) / 2
    return T


def _tt2_numeric(jets: Callable, nu: int, nv: int, mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix
                 ) -> tuple[mpmath.matrix, mpmath.matrix]:
    """Σ_gg and D of the TT2 closed form at a point, in 40 digits (the formulas of _tt2_moments)."""
    _, J, H = jets(list(mu) + [0] * nv)
    Pm = _mp_matrix(P)
    nw = nu + nv
    Pw = mpmath.matrix(nw, nw)
    for i in range(nu):
        for j in range(nu):
            Pw[i, j] = Pm[i, j]
    Rm = _mp_matrix(R) if nv else None
    for i in range(nv):
        for j in range(nv):
            Pw[nu + i, nu + j] = Rm[i, j]
    Sgg = J * Pw * J.T + _half_traces(H, Pw)
    Ju = J[:, :nu] if nv else J
    Sgu = Ju * Pm
    D = Sgg - Sgu * mpmath.inverse(Pm) * Sgu.T
    if nv:
        Jv = J[:, nu:nw]
        Hv = [h[nu:nw, nu:nw] for h in H]
        D = D - (Jv * Rm * Jv.T + _half_traces(Hv, Rm))
    return Sgg, D


def _rational_point(model: Model, seed: int = 0, tries: int = 20) -> tuple[sp.Matrix, sp.Matrix, sp.Matrix]:
    """An exact rational mean and diagonally dominant covariances where g is differentiable."""
    rng = np.random.default_rng(seed)
    jets = _jets(model.inputs, model.noise, model.outputs)
    for _ in range(tries):
        mu = sp.Matrix([sp.Rational(int(rng.integers(1, 20)), int(rng.integers(1, 7))) for _ in range(model.n_u)])

        def cov(n: int) -> sp.Matrix:
            A = sp.Matrix(n, n, lambda i, j: sp.Rational(int(rng.integers(-3, 4)), int(rng.integers(2, 6))))
            return (A + A.T) / 4 + (n + 1) * sp.eye(n)

        P, R = cov(model.n_u), cov(model.n_v) if model.n_v else sp.zeros(0, 0)
        try:
            jets(list(mu) + [0] * model.n_v)
        except SymmonError:
            continue
        return mu, P, R
    raise SymmonError(f"found no rational point where {model.name!r} is twice differentiable")


def _scales(model: Model) -> dict[str, sp.Matrix]:
    """Rational positive diagonal scales and offsets, distinct per component (one fixed choice)."""
    primes = (2, 3, 5, 7, 11, 13, 17, 19)

    def diag(n: int, k: int) -> sp.Matrix:
        # Alternately large and small, so that a unit-dependent M² visibly changes.
        return sp.diag(*[sp.Rational(primes[(i + k) % 8]) ** (-1 if i % 2 else 1) for i in range(n)])

    def off(n: int, k: int) -> sp.Matrix:
        return sp.Matrix([sp.Rational(i + k + 1, 3) for i in range(n)])

    return {"S_u": diag(model.n_u, 0), "o_u": off(model.n_u, 1), "S_y": diag(model.n_y, 2),
            "o_y": off(model.n_y, 2), "S_v": diag(model.n_v, 5) if model.n_v else sp.zeros(0, 0)}


def _close(a: mpmath.matrix, b: mpmath.matrix) -> bool:
    scale = max([mpmath.mpf(1)] + [abs(x) for x in a] + [abs(x) for x in b])
    return all(abs(x - y) <= _AGREE_RTOL * scale for x, y in zip(a, b))


def _check_composition(model: Model, point: sp.Matrix, tname: str) -> None:
    """ḡ built by change_units is g composed with the unit change: check it at one point.

    At rational scales, offsets and point (the model's mean mapped to the new units), the
    values, Jacobian and Hessians of ḡ, differentiated on their own, must equal
    A(g − o_y), A J S_w and Σ_k A_ik S_wᵀ H_k S_w from g (the chain rule; values only for a
    point rule). 40-digit evaluation; the two sides agree to 1e-25 or this raises.
    """
    sc = _scales(model)
    Sw = sp.diag(sc["S_u"], sc["S_v"]) if model.n_v else sc["S_u"]
    ow = sp.Matrix(list(sc["o_u"]) + [0] * model.n_v)
    ub, vb, gb = _changed_parts(model, sc["S_u"], sc["o_u"], sc["S_y"], sc["o_y"], sc["S_v"], "_bar")
    w = sp.Matrix(list(point) + [0] * model.n_v)
    wb = _inverse(Sw) * (w - ow)
    with mpmath.workdps(_DPS):
        val, J, H = _jets(model.inputs, model.noise, model.outputs)(list(w))
        val_b, J_b, H_b = _jets(ub, vb, list(gb))(list(wb))
        A, S = _mp_matrix(_inverse(sc["S_y"])), _mp_matrix(Sw)
        ok = _close(val_b, A * (val - _mp_matrix(sc["o_y"])))
        if tname == "tt2":
            ok = ok and _close(J_b, A * J * S)
            for i in range(model.n_y):
                mixed = sum((A[i, k] * (S.T * H[k] * S) for k in range(model.n_y)), mpmath.zeros(Sw.rows))
                ok = ok and _close(H_b[i], mixed)
    if not ok:
        raise SymmonError(f"the changed model of {model.name!r} is not g composed with the unit change (18)")


def _regular(weight: Any, label: str, Sgg: mpmath.matrix) -> None:
    """The weight needs Σ_gg⁻¹ (43) or positive variances (42), (38), (8): check at the point."""
    n = Sgg.rows
    if label == "full":
        ev = mpmath.eigsy(Sgg)[0]
        if min(ev) <= _AGREE_RTOL * max(abs(x) for x in ev):
            raise SingularMatrixError(
                f"Σ_gg of TT2 is singular at the given mean (eigenvalues {[mpmath.nstr(x, 5) for x in ev]}): "
                "the weight 'full' (43) needs its inverse"
            )
    elif label != "liu-li-raw":
        if any(Sgg[i, i] <= 0 for i in range(n)):
            raise SingularMatrixError(
                f"an output variance of TT2 is zero at the given mean: the weight {label!r} divides by it"
            )


def _values(wp: _WeightPart, Sgg: mpmath.matrix, D: mpmath.matrix, S_y: sp.Matrix) -> dict:
    """Values of the symbols of the generic difference: Σ_gg, D of the model, the scale s_y."""
    n = S_y.rows
    point: dict = {}
    for i in range(n):
        for j in range(i, n):
            point[wp.G[i, j]] = sp.Float(Sgg[i, j], _DPS)
            point[wp.E[i, j]] = sp.Float(D[i, j], _DPS)
        point[wp.s_y[i]] = S_y[i, i]
        if wp.sigma is not None:
            point[wp.sigma[i]] = sp.Float(mpmath.sqrt(Sgg[i, i]), _DPS)
    return point


def _m2_at(weight: Any, label: str, Sgg: mpmath.matrix, D: mpmath.matrix) -> sp.Expr:
    G = sp.Matrix(Sgg.rows, Sgg.cols, lambda i, j: sp.Float(Sgg[i, j], _DPS))
    E = sp.Matrix(D.rows, D.cols, lambda i, j: sp.Float(D[i, j], _DPS))
    sigma = None if label in WEIGHTS else [sp.sqrt(G[i, i]) for i in range(G.rows)]
    return sp.N(_m2(weight, G, E, sigma), _DPS)


def _counterexample_tt2(model: Model, weight: Any, label: str, wp: _WeightPart,
                        mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix) -> dict:
    """M² of g at (μ, P, R) and of ḡ at the mapped point, each from its own TT2 moments."""
    sc = _scales(model)
    ub, vb, gb = _changed_parts(model, sc["S_u"], sc["o_u"], sc["S_y"], sc["o_y"], sc["S_v"], "_bar")
    Su_inv = _inverse(sc["S_u"])
    mu_b, P_b = Su_inv * (mu - sc["o_u"]), Su_inv * P * Su_inv.T
    R_b = _inverse(sc["S_v"]) * R * _inverse(sc["S_v"]).T if model.n_v else R
    with mpmath.workdps(_DPS):
        Sgg, D = _tt2_numeric(_jets(model.inputs, model.noise, model.outputs), model.n_u, model.n_v, mu, P, R)
        Sgg_b, D_b = _tt2_numeric(_jets(ub, vb, list(gb)), model.n_u, model.n_v, mu_b, P_b, R_b)
        lhs, rhs = _m2_at(weight, label, Sgg, D), _m2_at(weight, label, Sgg_b, D_b)
    point = _values(wp, Sgg, D, sc["S_y"])
    diff = sp.N(wp.difference.xreplace(point), _DPS)
    if abs(diff - (lhs - rhs)) > 1e-20 * max(1, abs(lhs)):
        raise SymmonError(f"internal: the lemma's difference {diff} and the direct {lhs - rhs} disagree")
    point.update(sc)
    point.update({"mean": mu, "cov": P, "noise_cov": R, "lhs": lhs, "rhs": rhs, "difference": diff})
    return point


def _counterexample_rule(model: Model, weight: Any, label: str, wp: _WeightPart, transform: Any,
                         mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix) -> dict:
    """The same with the moments of a point rule, computed by :func:`symmon.nonlinearity` (double precision)."""
    from .nonlinearity import nonlinearity
    from .transforms import UT, GaussHermite, MonteCarlo
    from .units import change_gaussian, change_units

    if isinstance(transform, str):  # a name: the family's default rule
        transform = {"ut": UT.ut1(), "gh": GaussHermite(), "mc": MonteCarlo(n=10**5, seed=0)}[transform]
    sc = _scales(model)
    plain = model.with_angles([])  # the lemma assumes outputs that are not wrapped
    f = lambda M: np.array(M.evalf(), dtype=float)  # noqa: E731 - a one-line conversion
    u = Gaussian(f(mu).ravel(), f(P))
    v = Gaussian(np.zeros(model.n_v), f(R)) if model.n_v else None
    g_b = change_units(plain, sc["S_u"], sc["o_u"], sc["S_y"], sc["o_y"], sc["S_v"] if model.n_v else None)
    u_b = change_gaussian(u, f(sc["S_u"]), f(sc["o_u"]).ravel())
    v_b = change_gaussian(v, f(sc["S_v"])) if v is not None else None
    old = nonlinearity(plain, u, v, weight=weight, transform=transform)
    new = nonlinearity(g_b, u_b, v_b, weight=weight, transform=transform)
    to_mp = lambda a: mpmath.matrix(a.tolist())  # noqa: E731
    point = _values(wp, to_mp(old.moments.cov), to_mp(old.residual_cov), sc["S_y"])
    point.update(sc)
    lhs, rhs = sp.Float(old.squared), sp.Float(new.squared)
    point.update({"mean": mu, "cov": P, "noise_cov": R, "lhs": lhs, "rhs": rhs,
                  "difference": sp.N(wp.difference.xreplace(point), _DPS)})
    return point


# --------------------------------------------------------------------------------------
# prove_invariance
# --------------------------------------------------------------------------------------
_RULES = {"ut": "UT family", "gh": "Gauss–Hermite", "mc": "Monte Carlo"}


def _as_transform_name(transform: Any) -> str:
    name = transform if isinstance(transform, str) else getattr(transform, "name", None)
    if name not in ("tt2", *_RULES):
        raise SymmonError(
            f"prove_invariance covers TT2 and the point rules (transform in 'tt2', 'ut', 'gh', 'mc' or "
            f"such a Transform), got {transform!r}; prove_matrix_invariance states the exact result"
        )
    return name


def _say(progress: bool, message: str) -> None:
    if progress:
        print(f"prove-invariance: {message}", file=sys.stderr, flush=True)


def prove_invariance(
    model: Model,
    weight: Any = "full",
    transform: Any = "tt2",
    mean: Any = None,
    cov: Any = None,
    noise_cov: Any = None,
    *,
    route: str = "lemmas",
    budget: float = DIRECT_BUDGET_S,
    progress: bool = False,
    at: tuple[Gaussian, ...] | None = None,
) -> InvarianceProof:
    """Prove (or disprove) the unit invariance (21), (34) of the MoN of ``model``.

    The change of units is u = S_u ū + o_u, y = S_y ȳ + o_y, v = S_v v̄ (18) with positive
    diagonal S and any offsets, ū ~ N(S_u⁻¹(μ − o_u), S_u⁻¹ P S_u⁻¹), v̄ ~ N(0, S_v⁻¹ R S_v⁻¹)
    (35b), (35c); M² = tr(W D) (29) with W from its own Σ_gg.

    ``route="lemmas"`` (default) proves it from :func:`lemma_tt2` (or, for a point rule,
    :func:`lemma_cholesky` and :func:`lemma_point_rule`) and :func:`lemma_weight`, which do not
    depend on the model, plus a check of what does: ḡ is g composed with the unit change
    (at an exact point) and, for a numeric mean and covariance, the weight's Σ_gg is regular
    there. It takes seconds for any model. When the weight lemma fails (Liu–Li), the
    counterexample is a concrete point (the given mean and covariance, or a rational one) with
    rational scales, and M² computed from the moments of g and of ḡ independently.

    ``route="direct"`` (TT2 only) builds M² symbolically in both unit systems, differentiating
    the model and simplifying the difference; it is stopped with a :class:`SymmonError` when
    the model is too large or after ``budget`` seconds.

    Parameters
    ----------
    model : Model
    weight : {"full", "diag", "liu-li", "liu-li-raw"}, sympy Matrix or callable
        ``"full"``: W = Σ_gg⁻¹/n_y (43); ``"diag"``: W = diag(diag Σ_gg)⁻¹/n_y (42);
        ``"liu-li"``: W = I/tr Σ_gg (the square of (8)); ``"liu-li-raw"``: W = I (6).
        A matrix W̄ (in base units, where every output has unit variance) or a callable
        ``corr -> W̄`` of the base-unit covariance Σ_ḡḡ (a correlation matrix) gives
        W = S_b⁻¹ W̄ S_b⁻¹ with S_b = diag(√diag Σ_gg), (38) and (41).
    transform : "tt2", "ut", "gh", "mc" or such a Transform
        The point rules (UT family, Gauss–Hermite, Monte Carlo) take models without noise or
        with additive noise, and the lemma route only.
    mean, cov : optional
        Numeric or symbolic mean and covariance of u (a Gaussian may be passed as ``mean``).
        Default: symbols μ and a symmetric P. Numbers are made exact (0.17 → 17/100).
    noise_cov : optional
        Covariance R of v (default: symbols), for a model with noise.
    route : {"lemmas", "direct"}
    budget : float
        Seconds allowed to the direct route.
    progress : bool
        Print what is being done to stderr.
    at : (Gaussian,) or (Gaussian, Gaussian), optional
        u (and v) at which a symbolic proof checks the composition and, when it fails, gives
        its counterexample (default: a rational point). Ignored when ``mean`` is numeric.

    Returns
    -------
    InvarianceProof
        With the names of the lemmas used in ``lemmas`` and the conditions in ``assumptions``.

    Raises
    ------
    SymmonError
        The direct route is out of size or time (the message suggests ``route="lemmas"``), or a
        lemma did not reduce (the proof cannot be made).
    SingularMatrixError
        A numeric covariance is not positive definite, or Σ_gg is singular at the given mean
        for a weight that needs its inverse.

    Examples
    --------
    >>> import sympy as sp
    >>> x, y = sp.symbols("x y", real=True)
    >>> polar = Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)])
    >>> prove_invariance(polar, "full").holds, prove_invariance(polar, "liu-li-raw").holds
    (True, False)
    >>> prove_invariance(polar, "full").lemmas
    ('tt2-equivariance', 'weight-full')
    """
    t0 = time.perf_counter()
    if not isinstance(model, Model):
        raise TypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    label = _weight_label(weight)
    tname = _as_transform_name(transform)
    if route not in ("lemmas", "direct"):
        raise SymmonError(f"route must be 'lemmas' or 'direct', got {route!r}")
    mu, P, R = _moments_args(model, mean, cov, noise_cov)
    if route == "direct":
        if tname != "tt2":
            raise SymmonError(f"the direct route works on the TT2 closed form only, got transform {tname!r}")
        return _prove_direct(model, weight, label, mu, P, R, budget, progress, t0)
    if tname != "tt2" and model.n_v and model.structure != "additive":
        raise SymmonError(
            f"no lemma covers {_RULES[tname]} moments of a model with {model.structure} noise "
            "(its conditional covariance is computed by nested rules); use transform='tt2'"
        )
    _say(progress, "lemmas (model-independent, proved once per session)")
    lemmas = [lemma_tt2()] if tname == "tt2" else [lemma_cholesky(), lemma_point_rule()]
    wp = _weight_part(weight, model.n_y)
    for lem in lemmas:
        if not lem.holds:
            raise SymmonError(f"lemma {lem.name} did not reduce: the proof cannot be made\n{lem}")
    numeric = not (mu.free_symbols or P.free_symbols or R.free_symbols)
    _say(progress, f"per-model checks of {model.name!r}: composition" + (" and regularity at the given mean" if numeric else ""))
    if numeric:
        point = (mu, P, R)
    else:
        point = _rational_point(model)
        if at is not None:
            if not (isinstance(at, tuple) and at and all(isinstance(d, Gaussian) or d is None for d in at)
                    and isinstance(at[0], Gaussian)):
                raise SymmonError(f"at must be a tuple (u,) or (u, v) of Gaussians, got {at!r}")
            given = _moments_args(model, at[0].mean, at[0].cov, at[1].cov if len(at) > 1 and at[1] is not None else None)
            if not any(M.free_symbols for M in given):  # a model with noise needs v too
                point = given
    _check_composition(model, point[0], tname)
    # The TT2 and 'full' lemmas hold for any invertible scales; (42), W̄ and the Cholesky
    # factor of the point rules need positive diagonal ones.
    scales = "any invertible" if tname == "tt2" and label == "full" else "positive diagonal"
    assumptions = [f"{scales} S_u, S_v, S_y; any offsets o_u, o_y"]
    if numeric and tname == "tt2":
        with mpmath.workdps(_DPS):
            Sgg, _ = _tt2_numeric(_jets(model.inputs, model.noise, model.outputs), model.n_u, model.n_v, mu, P, R)
            _regular(weight, label, Sgg)
    elif not numeric:
        assumptions.append("g twice differentiable at μ and Σ_gg regular there "
                           "(nonsingular for 'full', positive variances for 'diag' and W̄)")
    if tname != "tt2":
        assumptions.append("outputs not wrapped as angles; P positive definite (Cholesky); the same nodes "
                           "(and Monte Carlo seed) in both unit systems")
    if wp.lemma.holds:
        holds, diff, cex = True, sp.Integer(0), None
    else:
        _say(progress, "the weight lemma fails: counterexample at " + ("the given distribution" if numeric or at is not None else "a rational point"))
        holds, diff = False, wp.difference
        cex = (_counterexample_tt2(model, weight, label, wp, *point) if tname == "tt2"
               else _counterexample_rule(model, weight, label, wp, transform, *point))
    symbols = {"S_y": sp.diag(*wp.s_y), "Sigma_gg": wp.G, "D": wp.E, "mean": mu, "cov": P, "noise_cov": R}
    if wp.sigma is not None:
        symbols["sigma"] = sp.Matrix(wp.sigma)
    return InvarianceProof(
        holds, diff, wp.lhs, wp.rhs, label, tname,
        f"unit invariance of the MoN of {model.name!r} under u = S_u ū + o_u, y = S_y ȳ + o_y, v = S_v v̄ (18)",
        symbols, cex, time.perf_counter() - t0,
        tuple(lem.name for lem in lemmas) + (wp.lemma.name,), tuple(assumptions),
    )


def _moments_args(model: Model, mean: Any, cov: Any, noise_cov: Any) -> tuple[sp.Matrix, sp.Matrix, sp.Matrix]:
    nu, nv = model.n_u, model.n_v
    if isinstance(mean, Gaussian):
        if cov is None:
            cov = mean.cov
        mean = mean.mean
    mu = (sp.Matrix([sp.Symbol(f"mu_{s.name}", real=True) for s in model.inputs])
          if mean is None else _exact_vector(mean, nu, "mean"))
    P = _sym_matrix(nu, "P") if cov is None else _exact_cov(cov, nu, "cov")
    if nv:
        R = _sym_matrix(nv, "R") if noise_cov is None else _exact_cov(noise_cov, nv, "noise_cov")
    else:
        if noise_cov is not None:
            raise ModelError("noise_cov was given but the model declares no noise symbols")
        R = sp.zeros(0, 0)
    return mu, P, R


# --------------------------------------------------------------------------------------
# The direct route, guarded
# --------------------------------------------------------------------------------------
#: Code the direct route's alarm may interrupt: sympy, mpmath and symmon itself.
_INTERRUPTIBLE = tuple(os.path.dirname(m.__file__) + os.sep for m in (sp, mpmath, sys.modules[__package__]))


class _OutOfTime(BaseException):
    """The budget is spent. A BaseException: sympy catches Exception in places, and must
    not swallow the alarm."""


@contextmanager
def _deadline(seconds: float) -> Iterator[Callable[[], None]]:
    """A wall-clock limit: SIGALRM in the main thread (it interrupts a long sympy call), and
    a check between steps everywhere."""
    end = time.perf_counter() + seconds

    def check() -> None:
        if time.perf_counter() > end:
            raise _OutOfTime

    use_alarm = threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer")
    if not use_alarm:
        yield check
        return

    def handler(signum, frame):  # noqa: ARG001 - the signal handler signature
        # Interrupt only the proof's own code: raised elsewhere (e.g. in a garbage-collector
        # callback) the exception would be ignored and the alarm lost.
        if frame is not None and frame.f_code.co_filename.startswith(_INTERRUPTIBLE):
            raise _OutOfTime

    old = signal.signal(signal.SIGALRM, handler)
    # Repeat the alarm every 0.1 s until it is cleared: a skipped one comes again.
    signal.setitimer(signal.ITIMER_REAL, seconds, 0.1)
    try:
        yield check
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def direct_size(model: Model) -> int:
    """Σ count_ops(g_i) · n_w²: how much the direct route has to differentiate and simplify."""
    nw = model.n_u + model.n_v
    return int(sum(sp.count_ops(e) for e in model.outputs)) * nw * nw


def _prove_direct(model: Model, weight: Any, label: str, mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix,
                  budget: float, progress: bool, t0: float) -> InvarianceProof:
    size = direct_size(model)
    hint = ("use the lemma route (route='lemmas'; on the command line drop --route direct), which "
            "proves the same statement from model-independent lemmas in seconds")
    if size > DIRECT_MAX_SIZE:
        raise SymmonError(
            f"the direct symbolic proof of {model.name!r} is too large (size Σ count_ops(g_i)·n_w² = {size} "
            f"> {DIRECT_MAX_SIZE}): {hint}"
        )
    if not (isinstance(budget, (int, float)) and budget > 0):
        raise SymmonError(f"budget must be a positive number of seconds, got {budget!r}")
    try:
        with _deadline(float(budget)) as check:
            return _direct(model, weight, label, mu, P, R, progress, check, t0)
    except _OutOfTime:
        raise SymmonError(
            f"the direct symbolic proof of {model.name!r} did not finish in {budget:g} s (size {size}): "
            f"{hint}; or raise the budget (--budget SECONDS)"
        ) from None


def _direct(model: Model, weight: Any, label: str, mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix,
            progress: bool, check: Callable[[], None], t0: float) -> InvarianceProof:
    """M² built symbolically twice (TT2 closed form, derivatives from sympy) and subtracted."""
    nu, ny, nv = model.n_u, model.n_y, model.n_v
    s_u = [sp.Symbol(f"s_{s.name}", positive=True) for s in model.inputs]
    o_u = [sp.Symbol(f"o_{s.name}", real=True) for s in model.inputs]
    s_y = [sp.Symbol(f"s_y{i + 1}", positive=True) for i in range(ny)]
    o_y = [sp.Symbol(f"o_y{i + 1}", real=True) for i in range(ny)]
    s_v = [sp.Symbol(f"s_{s.name}", positive=True) for s in model.noise]
    Su, Sy, Sv = sp.diag(*s_u), sp.diag(*s_y), sp.diag(*s_v) if nv else sp.zeros(0, 0)
    ou, oy = sp.Matrix(o_u), sp.Matrix(o_y)

    ub, vb, gb = _changed_parts(model, Su, ou, Sy, oy, Sv, "_bar")
    g_bar = _Relation(tuple(ub), tuple(vb), tuple(gb), model.name)
    Su_inv = _inverse(Su)
    mu_bar = Su_inv * (mu - ou)
    P_bar = Su_inv * P * Su_inv
    R_bar = (_inverse(Sv) * R * _inverse(Sv)) if nv else R

    # Stage 1: the TT2 moments of ḡ are those of g mapped by the unit change,
    # Σ_ḡḡ = S_y⁻¹ Σ_gg S_y⁻¹ and D̄ = S_y⁻¹ D S_y⁻¹, checked entrywise on the actual
    # expressions (derivatives of ḡ from sympy, evaluated at the mapped mean).
    _say(progress, f"direct route, step 1/3: TT2 moments of {model.name!r} in both unit systems")
    Sgg, D, Sgg_b, D_b, covariant = _stage1(
        model, g_bar, sp.ImmutableMatrix(mu), sp.ImmutableMatrix(P), sp.ImmutableMatrix(R),
        sp.ImmutableMatrix(mu_bar), sp.ImmutableMatrix(P_bar), sp.ImmutableMatrix(R_bar),
        sp.ImmutableMatrix(Sy),
    )
    check()
    Sy_inv = _inverse(Sy)
    # Stage 2: M² of the weight rule, for generic symmetric Σ_gg and D, is (or is not)
    # invariant under that map. Both stages are exact, so together they decide (21).
    _say(progress, "direct route, step 2/3: M² of the weight rule")
    G = _sym_matrix(ny, "Sigma")
    E = _sym_matrix(ny, "D")
    if covariant:
        G_b, E_b = Sy_inv * G * Sy_inv, Sy_inv * E * Sy_inv
    else:  # cannot happen for an affine change; decide on the actual expressions instead
        G, E, G_b, E_b = Sgg, D, Sgg_b, D_b
    sigma = sigma_b = None
    if label not in WEIGHTS:
        sigma = [sp.Symbol(f"sigma_y{i + 1}", positive=True) for i in range(ny)]
        sigma_b = [sigma[i] * sp.sqrt(sp.cancel(G_b[i, i] / G[i, i])) for i in range(ny)]
    lhs_g = _m2(weight, G, E, sigma)
    rhs_g = _m2(weight, G_b, E_b, sigma_b)
    actual = {G[i, j]: Sgg[i, j] for i in range(ny) for j in range(ny)}
    actual.update({E[i, j]: D[i, j] for i in range(ny) for j in range(ny)})
    check()
    _say(progress, "direct route, step 3/3: simplifying the difference")
    d = sp.cancel(sp.together(lhs_g - rhs_g))
    if d == 0:
        diff, holds, cex = sp.Integer(0), True, None
    else:
        diff, holds, cex = _decide(d.xreplace(actual) if covariant else d)
    lhs, rhs = (lhs_g.xreplace(actual), rhs_g.xreplace(actual)) if covariant else (lhs_g, rhs_g)
    symbols = {"S_u": Su, "o_u": ou, "S_y": Sy, "o_y": oy, "S_v": Sv, "mean": mu, "cov": P, "noise_cov": R}
    if sigma is not None:
        symbols["sigma"] = sp.Matrix(sigma)
    return InvarianceProof(
        holds, diff, lhs, rhs, label, "tt2",
        f"unit invariance of the MoN of {model.name!r} under u = S_u ū + o_u, y = S_y ȳ + o_y, v = S_v v̄ (18)",
        symbols, cex, time.perf_counter() - t0, (), ("positive diagonal S_u, S_v, S_y; any offsets o_u, o_y",),
    )


# --------------------------------------------------------------------------------------
# The exact, transform-free statement in matrix form
# --------------------------------------------------------------------------------------


def _matrix_counterexample(d: sp.Expr, explicit: dict, scales: str, seed: int = 0) -> dict:
    """An exact rational point (moments positive definite, scales invertible) where d ≠ 0."""
    rng = np.random.default_rng(seed)
    for _ in range(20):
        point = {}
        for M, X in explicit.items():
            n, m = X.shape
            A = sp.Matrix(n, m, lambda i, j: sp.Rational(int(rng.integers(-9, 10)), int(rng.integers(1, 5))))
            if M.name in ("Sigma_gg", "Sigma_uu"):
                A = A * A.T + 3 * sp.eye(n)  # symmetric positive definite
            elif M.name in ("S_y", "S_u"):
                A = (A * A.T + sp.eye(n)) if scales == "full" else sp.diag(*[abs(A[i, i]) + 1 for i in range(n)])
            point[M] = sp.ImmutableMatrix(A)
        entries = {X[i, j]: point[M][i, j] for M, X in explicit.items()
                   for i in range(X.rows) for j in range(X.cols) if X[i, j].is_Symbol}
        val = sp.nsimplify(sp.sympify(d.subs(point).doit()).xreplace(entries))
        if val.is_Rational and val != 0:
            out = {str(k): v for k, v in point.items()}
            out["difference"] = val
            return out
    raise SymmonError(f"could not decide: {d} did not simplify to 0 but vanished at every test point")


def prove_matrix_invariance(n_u: int, n_y: int, weight: str = "full", scales: str | None = None) -> InvarianceProof:
    """The exact unit invariance of tr(W D) in matrix form, for any transform.

    Under the change (18) the moments map as Σ_gg → S_y Σ_gg S_yᵀ, Σ_gu → S_y Σ_gu S_uᵀ,
    Σ_uu → S_u Σ_uu S_uᵀ (exactly, without any approximation), so
    D = Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug → S_y D S_yᵀ. This function proves that M² = tr(W D),
    with W computed by the weight rule from the mapped Σ_gg, is unchanged: for
    ``"full"`` (43) with full invertible S_y, S_u; for ``"diag"`` (42) with positive diagonal
    scales; and it shows the failure of ``"liu-li"`` (8) and ``"liu-li-raw"`` (6).

    The base moments are full symbolic n×n matrices (symmetric where they must be) and the
    scales full symbolic matrices (or positive diagonal ones). The proof first reduces the
    mapped expression with exact matrix algebra ((ABC)⁻¹ = C⁻¹B⁻¹A⁻¹, X X⁻¹ = I, and the
    linearity and cyclicity of the trace), which is valid for every size, then evaluates the
    weights that act entrywise (42), (8), (6) on the explicit n×n entries. A failure is
    certified by an exact rational point at which the difference is nonzero.

    Parameters
    ----------
    n_u, n_y : int
        Sizes of u and y (1 to 4: the explicit entries grow quickly).
    weight : {"full", "diag", "liu-li", "liu-li-raw"}
    scales : {"full", "diagonal"}, optional
        Default: ``"full"`` for ``"full"`` and the Liu–Li weights, ``"diagonal"`` for ``"diag"``
        (which is not invariant under a full S_y: it ignores correlations).

    Returns
    -------
    InvarianceProof

    Examples
    --------
    >>> prove_matrix_invariance(2, 2, "full").holds
    True
    """
    t0 = time.perf_counter()
    for n, name in ((n_u, "n_u"), (n_y, "n_y")):
        if not isinstance(n, (int, np.integer)) or not 1 <= n <= 4:
            raise ShapeError(f"{name} must be an integer from 1 to 4, got {n!r}")
    if weight not in WEIGHTS:
        raise SymmonError(f"weight must be one of {WEIGHTS}, got {weight!r}")
    if scales is None:
        scales = "diagonal" if weight == "diag" else "full"
    if scales not in ("full", "diagonal"):
        raise SymmonError(f"scales must be 'full' or 'diagonal', got {scales!r}")
    n_u, n_y = int(n_u), int(n_y)
    # Explicit entries of the base-unit moments and of the scales.
    Gx = _sym_matrix(n_y, "G")
    Ux = _sym_matrix(n_u, "U")
    Cx = sp.Matrix(n_y, n_u, lambda i, j: sp.Symbol(f"C_{i + 1}{j + 1}", real=True))
    if scales == "full":
        Syx = sp.Matrix(n_y, n_y, lambda i, j: sp.Symbol(f"a_{i + 1}{j + 1}", real=True))
        Sux = sp.Matrix(n_u, n_u, lambda i, j: sp.Symbol(f"b_{i + 1}{j + 1}", real=True))
    else:
        Syx = sp.diag(*[sp.Symbol(f"s_y{i + 1}", positive=True) for i in range(n_y)])
        Sux = sp.diag(*[sp.Symbol(f"s_u{i + 1}", positive=True) for i in range(n_u)])
    # The same as matrix symbols, for the dimension-free reduction.
    G = sp.MatrixSymbol("Sigma_gg", n_y, n_y)
    U = sp.MatrixSymbol("Sigma_uu", n_u, n_u)
    C = sp.MatrixSymbol("Sigma_gu", n_y, n_u)
    Sy = sp.MatrixSymbol("S_y", n_y, n_y)
    Su = sp.MatrixSymbol("S_u", n_u, n_u)
    explicit = {G: sp.ImmutableMatrix(Gx), U: sp.ImmutableMatrix(Ux), C: sp.ImmutableMatrix(Cx),
                Sy: sp.ImmutableMatrix(Syx), Su: sp.ImmutableMatrix(Sux)}

    def m2(Gm, Cm, Um):
        D = _reduce(Gm - Cm * Um.I * Cm.T)
        if weight == "full":
            return _reduce(sp.Trace(Gm.I * D) / n_y)  # (43)
        if weight == "liu-li":
            return _reduce(sp.Trace(D)) / _reduce(sp.Trace(Gm))  # (8)
        if weight == "liu-li-raw":
            return _reduce(sp.Trace(D))  # (6)
        # (42) acts on the entries: evaluate them explicitly, term by term.
        Ge = sp.Matrix(Gm.subs(explicit).doit())
        De = sp.Matrix(D.subs(explicit).doit())
        return [sp.cancel(De[i, i] / Ge[i, i] / n_y) for i in range(n_y)]

    lhs = m2(Sy * G * Sy.T, Sy * C * Su.T, Su * U * Su.T)  # old units: mapped moments
    rhs = m2(G, C, U)  # base units
    if weight == "diag":
        d = sp.cancel(sp.together(sum(a - b for a, b in zip(lhs, rhs))))
        lhs, rhs = sp.Add(*lhs), sp.Add(*rhs)
    else:
        d = _reduce(lhs - rhs)
        if d != 0:
            d = sp.simplify(d)
    if d == 0:
        diff, holds, cex = sp.Integer(0), True, None
    else:
        diff, holds = d, False
        cex = _matrix_counterexample(d, explicit, scales)
    symbols = {"Sigma_gg": Gx, "Sigma_gu": Cx, "Sigma_uu": Ux, "S_y": Syx, "S_u": Sux}
    return InvarianceProof(
        holds, diff, lhs, rhs, weight, "exact",
        f"unit invariance of tr(W D) under Σ_gg → S_y Σ_gg S_yᵀ, Σ_gu → S_y Σ_gu S_uᵀ, "
        f"Σ_uu → S_u Σ_uu S_uᵀ ({scales} S, n_u={n_u}, n_y={n_y})",
        symbols, cex, time.perf_counter() - t0,
    )
