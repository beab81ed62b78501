"""The direct route of :func:`symmon.units.prove_invariance`, guarded by size and time.

M² of the TT2 closed form is built symbolically in both unit systems (derivatives from
sympy) and the difference simplified: stage 1 checks that the TT2 moments of ḡ are those of
g mapped by S_y⁻¹, stage 2 that the weight's M² = tr(W D) (29) is unchanged under that map.
Its cost grows without bound with the model (the GMTI model of the paper took more than
20 minutes and 2.5 GB), so a model larger than :data:`DIRECT_MAX_SIZE` is refused, and a
wall-clock deadline (SIGALRM in the main thread) stops it after its budget; the message
points to the lemma route (:mod:`symmon.units.proofs`).

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV, eqs. (18)–(21), (29), (34)–(43).
"""

from __future__ import annotations

import time
from dataclasses import replace
from functools import lru_cache
from typing import Any, Callable

import numpy as np
import sympy as sp

from ..errors import NonSmoothModelError, SymmonError, UndecidedProofError, plain_repr
from ..timelimit import OutOfTime, deadline
from .check import SCALE_SETS, _numeric_check
from .kinks import UNDIFFERENTIATED, kink_text, localize, nonsmooth_atoms
from .proof import InvarianceProof, _say
from .lemmas import _m2, _sym_matrix, _tt2_moments
from ..core.model import Model
from ..core.affine import changed_parts, inverse, Relation
from ..measures.weights import NAMED as WEIGHTS

#: Differences larger than this (sympy operation count) are not put over a common
#: denominator: the counterexample alone decides them.
_CANCEL_MAX_OPS = 20000
#: Default wall-clock budget of the direct route, seconds.
DIRECT_BUDGET_S = 10.0
#: The direct route refuses models whose Σ count_ops(g_i) · n_w² exceeds this: their TT2
#: moments, differentiated and put over a common denominator, do not fit the budget.
DIRECT_MAX_SIZE = 2000


@lru_cache(maxsize=32)
def _stage1(model, g_bar, mu, P, R, mu_bar, P_bar, R_bar, Sy):
    """TT2 moments in both unit systems and whether Σ_ḡḡ, D̄ = S_y⁻¹ (Σ_gg, D) S_y⁻¹ (cached:
    the weights share it)."""
    Sgg, D = _tt2_moments(model, sp.Matrix(mu), sp.Matrix(P), sp.Matrix(R))
    Sgg_b, D_b = _tt2_moments(g_bar, sp.Matrix(mu_bar), sp.Matrix(P_bar), sp.Matrix(R_bar))
    Sy_inv = inverse(sp.Matrix(Sy))
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
    kinky = nonsmooth_atoms([d])
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
        if kinky:
            try:  # a point on a kink of g (x = y for Max(x, y)) is no admissible mean
                localize(kinky, point)
            except NonSmoothModelError:
                continue
        val = d.xreplace(point)
        num = sp.N(val, 50)
        if num.is_finite and abs(num) > sp.Float("1e-30"):
            point["difference"] = val if val.is_Rational else num
            return d, False, point
    raise UndecidedProofError(
        "could not decide the invariance: the difference did not simplify to 0 and no point "
        f"where it is nonzero was found ({sp.count_ops(d)} operations)"
    )

def direct_size(model: Model) -> int:
    """Σ count_ops(g_i) · n_w²: how much the direct route has to differentiate and simplify."""
    nw = model.n_u + model.n_v
    return int(sum(sp.count_ops(e) for e in model.outputs)) * nw * nw


def _prove_direct(model: Model, weight: Any, label: str, mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix,
                  budget: float, progress: bool, t0: float,
                  max_size: int = DIRECT_MAX_SIZE) -> InvarianceProof:
    """The direct route within ``budget`` seconds, for models of size at most ``max_size``."""
    size = direct_size(model)
    hint = ("use the lemma route (route='lemmas'; on the command line drop --route direct), which "
            "proves the same statement from model-independent lemmas in seconds")
    if size > max_size:
        raise SymmonError(
            f"the direct symbolic proof of {model.name!r} is too large (size Σ count_ops(g_i)·n_w² = {size} "
            f"> {max_size}): {hint}"
        )
    if not (isinstance(budget, (int, float)) and budget > 0):
        raise SymmonError(f"budget must be a positive number of seconds, got {plain_repr(budget)}")
    numeric = not (mu.free_symbols or P.free_symbols or R.free_symbols)
    smooth, extra = _smooth_model(model, mu, numeric)
    try:
        with deadline(float(budget)) as check:
            proof = _direct(smooth, weight, label, mu, P, R, progress, check, t0)
    except OutOfTime:
        raise SymmonError(
            f"the direct symbolic proof of {model.name!r} did not finish in {budget:g} s (size {size}): "
            f"{hint}; or raise the budget (--budget SECONDS)"
        ) from None
    if proof.holds and numeric and isinstance(weight, str):
        # A numeric route: the numbers of symmon itself must agree before "holds" is said.
        _say(progress, "numeric check: the MoN in the original and in changed units")
        _numeric_check(model, weight, "tt2", mu, P, R)
        extra += (f"checked numerically: the MoN is the same in {SCALE_SETS} changes of units",)
    return replace(proof, assumptions=proof.assumptions + extra)


def _smooth_model(model: Model, mu: sp.Matrix, numeric: bool) -> tuple[Model, tuple[str, ...]]:
    """The model the direct route differentiates, and what that adds to the assumptions.

    At a numeric mean, g's smooth branch there (:func:`symmon.units.kinks.localize`: the
    same TT2 moments; a mean on a kink is refused). At a symbolic one, g itself: sympy
    differentiates ``Abs``, ``Max``, ... into ``sign``, ``Heaviside`` and ``DiracDelta``,
    which vanish off the kinks, so the proof is of every mean off them; ``floor``,
    ``ceiling``, ``frac`` and ``Mod`` it cannot differentiate at all.
    """
    kinks = nonsmooth_atoms(model.outputs)
    if not kinks:
        return model, ()
    if numeric:
        w = list(model.inputs) + list(model.noise)
        hint = ("the direct route differentiates g at the mean: move the mean off the kink, or use a point rule "
                "with the lemma route (transform='ut'; on the command line --transform ut)")
        loc = localize(model.outputs, dict(zip(w, list(mu) + [0] * model.n_v)), hint)
        return Model(model.inputs, loc, list(model.noise) or None, model.name), ()
    flat = [k for k in kinks if isinstance(k, UNDIFFERENTIATED)]
    if flat:
        raise NonSmoothModelError(
            f"the direct route differentiates g symbolically, and sympy cannot differentiate {flat[0]} (a jump "
            f"where {kink_text(flat[0])}): use the lemma route (route='lemmas'; on the command line drop "
            "--route direct), or give a numeric mean (--numeric)"
        )
    return model, ("μ off the kinks of g: " + "; ".join(f"{k} where {kink_text(k)}" for k in kinks),)


def _direct(model: Model, weight: Any, label: str, mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix,
            progress: bool, check: Callable[[], None], t0: float) -> InvarianceProof:
    """M² built symbolically twice (TT2 closed form, derivatives from sympy) and subtracted."""
    ny, nv = model.n_y, model.n_v
    s_u = [sp.Symbol(f"s_{s.name}", positive=True) for s in model.inputs]
    o_u = [sp.Symbol(f"o_{s.name}", real=True) for s in model.inputs]
    s_y = [sp.Symbol(f"s_y{i + 1}", positive=True) for i in range(ny)]
    o_y = [sp.Symbol(f"o_y{i + 1}", real=True) for i in range(ny)]
    s_v = [sp.Symbol(f"s_{s.name}", positive=True) for s in model.noise]
    Su, Sy, Sv = sp.diag(*s_u), sp.diag(*s_y), sp.diag(*s_v) if nv else sp.zeros(0, 0)
    ou, oy = sp.Matrix(o_u), sp.Matrix(o_y)

    ub, vb, gb = changed_parts(model, Su, ou, Sy, oy, Sv, "_bar")
    g_bar = Relation(tuple(ub), tuple(vb), tuple(gb), model.name)
    Su_inv = inverse(Su)
    mu_bar = Su_inv * (mu - ou)
    P_bar = Su_inv * P * Su_inv
    R_bar = (inverse(Sv) * R * inverse(Sv)) if nv else R

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
    Sy_inv = inverse(Sy)
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
