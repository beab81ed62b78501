"""Symbolic proofs of unit invariance that scale: lemmas proved once, then a cheap per-model part.

This module is the front end, :func:`prove_invariance`; the parts are in their own modules:

- :mod:`symmon.units.lemmas`: the model-independent lemmas (re-exported here);
- :mod:`symmon.units.check`: the per-model checks at an exact rational point
  (composition, regularity) and the counterexamples;
- :mod:`symmon.units.direct`: the direct symbolic route, guarded by size and time;
- :mod:`symmon.units.kinks`: where g is not smooth, and its smooth branch near a point;
- :mod:`symmon.units.matrix`: :func:`prove_matrix_invariance`, the exact statement in
  matrix form (re-exported here);
- :mod:`symmon.units.proof`: the result type :class:`InvarianceProof` (re-exported here).

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

import time
from typing import Any

import mpmath
import numpy as np
import sympy as sp

from ..errors import (
    ArgumentTypeError,
    ModelError,
    NonSmoothModelError,
    ShapeError,
    SingularMatrixError,
    SymmonError,
    UndecidedProofError,
)
from ..core.gaussian import Gaussian
from .check import (
    _DPS,
    SCALE_SETS,
    _check_composition,
    _jets,
    _numeric_check,
    _rational_point,
    _refutation,
    _regular,
    _residual_zero,
    _tt2_numeric,
)
from .kinks import kink_text, localize, nonsmooth_atoms
from .direct import DIRECT_BUDGET_S, DIRECT_MAX_SIZE, _prove_direct
from .matrix import prove_matrix_invariance
from .proof import InvarianceProof, _say
from .lemmas import (
    Lemma,
    _sym_matrix,
    _weight_label,
    _weight_part,
    lemma_cholesky,
    lemma_point_rule,
    lemma_tt2,
    lemma_weight,
)
from ..core.model import Model
from ..core.affine import changed_parts, sympify_entry

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
    return sympify_entry(x, name)


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


#: Rational points a refutation tries when the caller gave none.
_POINTS = 5

_RULES = {"ut": "UT family", "gh": "Gauss–Hermite", "mc": "Monte Carlo"}


def _as_transform_name(transform: Any) -> str:
    name = transform if isinstance(transform, str) else getattr(transform, "name", None)
    if name not in ("tt2", *_RULES):
        raise SymmonError(
            f"prove_invariance covers TT2 and the point rules (transform in 'tt2', 'ut', 'gh', 'mc' or "
            f"such a Transform), got {transform!r}; prove_matrix_invariance states the exact result"
        )
    return name


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

    A refutation always shows two values of M² that differ (beyond rounding, relative to
    tr(W Σ_gg)): when the weight lemma fails but the model has D = 0 (∂²g/∂u∂w = 0: g affine
    in u, at the mean for a numeric TT2 proof, everywhere otherwise), M² = tr(W D) = 0 in
    every unit system and the proof holds by ``residual-zero`` (a linear model's Liu–Li MoN);
    when no tried point and scales separate the two values, :class:`UndecidedProofError`.

    **Kinks.** A model with ``Abs``, ``sign``, ``Max``, ``Min``, ``Heaviside``, ``floor``,
    ``ceiling``, ``frac``, ``Mod`` or ``Piecewise`` is smooth except on its kinks (an argument of
    ``Abs`` at 0, a tie of ``Max``, ...; :mod:`symmon.units.kinks`). TT2 needs the Hessian at
    the mean, so its proofs take g's smooth branch there, which has the same TT2 moments: a
    symbolic proof holds for every mean off the kinks (listed in ``assumptions``), and a
    numeric mean on a kink is refused with :class:`NonSmoothModelError` by both routes (the
    symbolic direct route also refuses ``floor``, ``ceiling``, ``frac`` and ``Mod``, which
    sympy cannot differentiate). The point rules (``transform="ut"``, ``"gh"``, ``"mc"``)
    evaluate g only, so their lemmas hold for such models exactly, kinks included.

    **Numeric check.** Before a numeric route (a numeric mean, or a point rule) says "holds"
    for a named weight, the MoN of :func:`symmon.nonlinearity` (the same transform) is compared in the original
    units and in four changes of units (scales ×2^±10 and small primes, with offsets); if
    they differ by more than 1e-6 of tr(W Σ_gg) (double-precision rounding is ~1e-13 of
    it), :class:`UndecidedProofError`: e.g. a point of the rule on a jump of g, which the
    rounding of the change of units moves to the other side. The exact symbolic TT2 proof
    (symbolic mean) has no numbers to compare.

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
        with additive noise, and the lemma route only; they need no derivative of g.
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
    NonSmoothModelError
        TT2 at a numeric mean on a kink of g (naming the function and the kink), or the
        symbolic direct route on a function sympy cannot differentiate.
    UndecidedProofError
        No verdict: the weight lemma fails but the two values of M² agree at every point and
        scales tried, or the numeric check of a "holds" disagrees.

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
        raise ArgumentTypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    label = _weight_label(weight)
    tname = _as_transform_name(transform)
    if route not in ("lemmas", "direct"):
        raise SymmonError(f"route must be 'lemmas' or 'direct', got {route!r}")
    mu, P, R = _moments_args(model, mean, cov, noise_cov)
    if route == "direct":
        if tname != "tt2":
            raise SymmonError(f"the direct route works on the TT2 closed form only, got transform {tname!r}")
        # The size limit is read here: symmon.units.proofs.DIRECT_MAX_SIZE is the setting users know.
        return _prove_direct(model, weight, label, mu, P, R, budget, progress, t0, DIRECT_MAX_SIZE)
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
    kinks = nonsmooth_atoms(model.outputs)
    _say(progress, f"per-model checks of {model.name!r}: composition" + (" and regularity at the given mean" if numeric else ""))
    given_point = numeric  # the counterexample is at the caller's distribution
    if numeric:
        point = (mu, P, R)
    else:
        point = _rational_point(model)  # off the kinks of g
        if at is not None:
            if not (isinstance(at, tuple) and at and all(isinstance(d, Gaussian) or d is None for d in at)
                    and isinstance(at[0], Gaussian)):
                raise SymmonError(f"at must be a tuple (u,) or (u, v) of Gaussians, got {at!r}")
            given = _moments_args(model, at[0].mean, at[0].cov, at[1].cov if len(at) > 1 and at[1] is not None else None)
            if not any(M.free_symbols for M in given):  # a model with noise needs v too
                if tname == "tt2" and kinks and not _smooth_at(model, given[0]):
                    # A symbolic proof is of every mean off the kinks: check it at one of those.
                    _say(progress, "the given mean lies on a kink of g: checking at a rational point instead")
                else:
                    point, given_point = given, True
    # The builder of ḡ this module imports is the one checked (a test replaces it here).
    # At a numeric mean on a kink, TT2's check refuses here (NonSmoothModelError), before any other work.
    _check_composition(model, point[0], tname, changed_parts)
    # The TT2 and 'full' lemmas hold for any invertible scales; (42), W̄ and the Cholesky
    # factor of the point rules need positive diagonal ones.
    scales = "any invertible" if tname == "tt2" and label == "full" else "positive diagonal"
    assumptions = [f"{scales} S_u, S_v, S_y; any offsets o_u, o_y"]
    if numeric and tname == "tt2":
        with mpmath.workdps(_DPS):
            Sgg, _ = _tt2_numeric(_jets(model.inputs, model.noise, model.outputs), model.n_u, model.n_v, mu, P, R)
            _regular(weight, label, Sgg)
    elif not numeric:
        assumptions.append(("g twice differentiable at μ and " if tname == "tt2" else "")
                           + "Σ_gg regular at μ (nonsingular for 'full', positive variances for 'diag' and W̄)")
        if tname == "tt2" and kinks:
            assumptions.append("μ off the kinks of g: " + "; ".join(f"{k} where {kink_text(k)}" for k in kinks))
    if tname != "tt2":
        assumptions.append("outputs not wrapped as angles; P positive definite (Cholesky); the same nodes "
                           "(and Monte Carlo seed) in both unit systems")
    used = tuple(lem.name for lem in lemmas)
    lhs, rhs = wp.lhs, wp.rhs
    if wp.lemma.holds:
        holds, diff, cex = True, sp.Integer(0), None
        used += (wp.lemma.name,)
    elif _residual_zero(model, tname, mu if numeric else None):
        # The weight is not invariant for generic moments, but this model has D = 0, so
        # M² = tr(W D) = 0 in every unit system: invariant, and no counterexample exists.
        holds, diff, cex = True, sp.Integer(0), None
        used += ("residual-zero",)
        lhs = rhs = sp.Integer(0)
        assumptions.append("D = 0, so M² = 0 in every unit system: ∂²g/∂u∂w = 0 "
                           + ("at the mean" if numeric and tname == "tt2" else "everywhere (g affine in u)"))
    else:
        where = "the given distribution" if given_point else "a rational point"
        _say(progress, f"the weight lemma fails: counterexample at {where}")
        holds, diff = False, wp.difference
        used += (wp.lemma.name,)
        rule = tname if tname == "tt2" else transform
        cex = _refutation(model, weight, label, wp, rule, *point)
        # A rational point may be special (two outputs equal there): try others.
        for seed in range(1, _POINTS) if not given_point else ():
            if cex is not None:
                break
            cex = _refutation(model, weight, label, wp, rule, *_rational_point(model, seed=seed))
        if cex is None:  # never a "counterexample" of two equal values
            raise UndecidedProofError(
                f"cannot decide the unit invariance of the MoN of {model.name!r} with weight {label!r}: its "
                f"lemma {wp.lemma.name} fails for generic moments, but at {where if given_point else f'{_POINTS} rational points'} "
                f"M² is the same in all {SCALE_SETS} sets of scales tried; try another mean (a file's [u] with --numeric)"
            )
    if holds and isinstance(weight, str) and (numeric or tname != "tt2"):
        # A numeric route: the numbers of symmon itself must agree before "holds" is said.
        _say(progress, "numeric check: the MoN in the original and in changed units")
        _numeric_check(model, weight, tname if tname == "tt2" else transform, *point)
        assumptions.append(f"checked numerically: the MoN is the same in {SCALE_SETS} changes of units")
    symbols = {"S_y": sp.diag(*wp.s_y), "Sigma_gg": wp.G, "D": wp.E, "mean": mu, "cov": P, "noise_cov": R}
    if wp.sigma is not None:
        symbols["sigma"] = sp.Matrix(wp.sigma)
    return InvarianceProof(
        holds, diff, lhs, rhs, label, tname,
        f"unit invariance of the MoN of {model.name!r} under u = S_u ū + o_u, y = S_y ȳ + o_y, v = S_v v̄ (18)",
        symbols, cex, time.perf_counter() - t0, used, tuple(assumptions),
    )


def _smooth_at(model: Model, mean: sp.Matrix) -> bool:
    """g is off its kinks at ``mean`` (v = 0), so TT2 can be taken there."""
    try:
        localize(model.outputs, dict(zip(list(model.inputs) + list(model.noise), list(mean) + [0] * model.n_v)))
    except NonSmoothModelError:
        return False
    return True


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
