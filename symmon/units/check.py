"""The per-model part of the lemma route: checks of one model at an exact rational point.

The lemmas (:mod:`symmon.units.lemmas`) do not depend on the model; what does is checked here, in
40-digit mpmath arithmetic at exact rational points:

- :func:`_check_composition`: ḡ built by the change of units is g composed with (18): its
  values, Jacobian and Hessians equal A(g − o_y), A J S_w and Σ_k A_ik S_wᵀ H_k S_w (the
  chain rule, A = S_y⁻¹, S_w = blkdiag(S_u, S_v));
- :func:`_regular`: the moments the weight needs are regular at the point (Σ_gg
  nonsingular for (43), positive variances for (42), (38), (8));
- :func:`_counterexample_tt2`, :func:`_counterexample_rule`: when the weight lemma fails, a
  concrete refutation: M² of g at (μ, P, R) and of ḡ at the mapped point, each from its own
  moments (the TT2 closed form in 40 digits, or a point rule through
  :func:`symmon.nonlinearity`).

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV, eqs. (18)–(21), (29), (34)–(43).
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import mpmath
import numpy as np
import sympy as sp

from ..errors import SingularMatrixError, SymmonError, UndecidedProofError
from ..core.gaussian import Gaussian
from .kinks import localize, nonsmooth_atoms
from .lemmas import _m2, _WeightPart
from ..core.model import Model
from ..core.affine import changed_parts, inverse
from ..core.rescale import change_gaussian, change_units
from ..measures.mon import nonlinearity
from ..measures.weights import NAMED as WEIGHTS
from ..transforms.taylor import TT2
from ..transforms.unscented import UT
from ..transforms.quadrature import GaussHermite
from ..transforms.montecarlo import MonteCarlo

#: Digits of the numeric evaluations (composition check, regularity, counterexamples).
_DPS = 40
#: Relative agreement demanded of two 40-digit evaluations of the same exact quantity.
_AGREE_RTOL = mpmath.mpf("1e-25")


def _mp(x: Any) -> mpmath.mpf:
    return sp.N(sp.sympify(x), _DPS + 5)._to_mpmath(mpmath.mp.prec)


#: What to do when the TT2 route meets a kink of g at the mean (appended to the refusal).
TT2_KINK_HINT = ("TT2 and its proof need g twice differentiable at the mean: move the mean off the kink, or use "
                 "a point rule, which does not differentiate g (transform='ut' or 'gh'; on the command line --transform ut)")


def _jets(inputs: Sequence[sp.Symbol], noise: Sequence[sp.Symbol], outputs: Sequence[sp.Expr],
          hint: str = TT2_KINK_HINT) -> Callable:
    """Values, Jacobian and Hessians of g in w = [u; v] as one mpmath function of the point.

    A g with kinks (``Abs``, ``Max``, ..., :mod:`symmon.units.kinks`) is differentiated as its
    smooth branch at the point, which has the same value and derivatives there; a point on a
    kink raises :class:`NonSmoothModelError` (with ``hint``) instead of evaluating a
    ``DiracDelta``.
    """
    w = list(inputs) + list(noise)
    outputs = list(outputs)
    smooth = not nonsmooth_atoms(outputs)
    built: dict[tuple, Callable] = {}

    def build(exprs: list[sp.Expr]) -> Callable:
        g = sp.Matrix(exprs)
        J = g.jacobian(w)
        H = [sp.hessian(gi, w) for gi in g]
        return sp.lambdify(w, [list(g), J.tolist(), [h.tolist() for h in H]], modules="mpmath")

    def at(point: Sequence[Any]) -> tuple[mpmath.matrix, mpmath.matrix, list[mpmath.matrix]]:
        exprs = outputs if smooth else localize(outputs, dict(zip(w, [sp.sympify(x) for x in point])), hint)
        key = tuple(exprs)
        if key not in built:  # one branch per region of g, built once
            built[key] = build(exprs)
        vals, Jv, Hv = built[key](*[_mp(x) for x in point])
        out = mpmath.matrix([[mpmath.mpmathify(x)] for x in vals]), mpmath.matrix(Jv), [mpmath.matrix(h) for h in Hv]
        if not all(mpmath.isfinite(x) for M in (out[0], out[1], *out[2]) for x in M):
            raise SymmonError(
                f"g or its derivatives are not finite at {[str(x) for x in point]}: TT2 needs g twice "
                "differentiable at the mean"
            )
        return out

    return at


def _g_values(exprs: Sequence[sp.Expr], syms: Sequence[sp.Symbol], point: Sequence[Any]) -> mpmath.matrix:
    """g at a point, in 40 digits, by sympy itself: defined on the kinks too (a point rule needs no
    derivative, and ``Max(1, 1)`` or ``Abs(0)`` have values)."""
    sub = dict(zip(syms, [sp.sympify(x) for x in point]))
    return mpmath.matrix([[_mp(sp.sympify(e).xreplace(sub))] for e in exprs])


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


#: How many sets of scales a refutation (and the numeric check of a "holds") tries.
SCALE_SETS = 4


def _scales(model: Model, k: int = 0) -> dict[str, sp.Matrix]:
    """Rational positive diagonal scales and offsets, distinct per component: set ``k`` of
    :data:`SCALE_SETS`.

    Set 0 alternates small primes and their inverses (a unit-dependent M² visibly changes);
    sets 1 and 2 alternate 2¹⁰ and 2⁻¹⁰ (about ×1e3 and ×1e-3, and exact in binary floating
    point, so the numeric check compares M² without rounding from the scales themselves);
    set 3 is set 0 with the output scales inverted.
    """
    primes = (2, 3, 5, 7, 11, 13, 17, 19)

    def factor(i: int, j: int) -> sp.Rational:
        if k in (1, 2):
            return sp.Integer(2) ** (10 if (i + k) % 2 else -10)
        sgn = -1 if (i % 2) else 1
        return sp.Rational(primes[(i + j) % 8]) ** (-sgn if k == 3 and j == 2 else sgn)

    def diag(n: int, j: int) -> sp.Matrix:
        return sp.diag(*[factor(i, j) for i in range(n)])

    def off(n: int, j: int) -> sp.Matrix:
        return sp.Matrix([sp.Rational(i + j + 1, 3) * (1 + 9 * k) for i in range(n)])

    return {"S_u": diag(model.n_u, 0), "o_u": off(model.n_u, 1), "S_y": diag(model.n_y, 2),
            "o_y": off(model.n_y, 2), "S_v": diag(model.n_v, 5) if model.n_v else sp.zeros(0, 0)}


def _close(a: mpmath.matrix, b: mpmath.matrix) -> bool:
    scale = max([mpmath.mpf(1)] + [abs(x) for x in a] + [abs(x) for x in b])
    return all(abs(x - y) <= _AGREE_RTOL * scale for x, y in zip(a, b))


def _check_composition(model: Model, point: sp.Matrix, tname: str,
                       changed_parts: Callable = changed_parts) -> None:
    """ḡ built by change_units is g composed with the unit change: check it at one point.

    At rational scales, offsets and point (the model's mean mapped to the new units), the
    values, Jacobian and Hessians of ḡ, differentiated on their own, must equal
    A(g − o_y), A J S_w and Σ_k A_ik S_wᵀ H_k S_w from g (the chain rule; values only for a
    point rule). 40-digit evaluation; the two sides agree to 1e-25 or this raises.
    ``changed_parts`` builds ḡ (the caller passes the builder it relies on, so that the
    check is of that builder).
    """
    sc = _scales(model)
    Sw = sp.diag(sc["S_u"], sc["S_v"]) if model.n_v else sc["S_u"]
    ow = sp.Matrix(list(sc["o_u"]) + [0] * model.n_v)
    ub, vb, gb = changed_parts(model, sc["S_u"], sc["o_u"], sc["S_y"], sc["o_y"], sc["S_v"], "_bar")
    w = sp.Matrix(list(point) + [0] * model.n_v)
    wb = inverse(Sw) * (w - ow)
    with mpmath.workdps(_DPS):
        if tname == "tt2":
            val, J, H = _jets(model.inputs, model.noise, model.outputs)(list(w))
            val_b, J_b, H_b = _jets(ub, vb, list(gb))(list(wb))
        else:  # a point rule evaluates g only: values, defined on the kinks too
            val = _g_values(model.outputs, list(model.inputs) + list(model.noise), list(w))
            val_b = _g_values(list(gb), list(ub) + list(vb), list(wb))
        A, S = _mp_matrix(inverse(sc["S_y"])), _mp_matrix(Sw)
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
                        mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix, k: int = 0) -> tuple[dict, Any]:
    """M² of g at (μ, P, R) and of ḡ at the mapped point, each from its own TT2 moments (scale
    set ``k``); and tr(W Σ_gg), the size M² = tr(W D) is summed from."""
    sc = _scales(model, k)
    ub, vb, gb = changed_parts(model, sc["S_u"], sc["o_u"], sc["S_y"], sc["o_y"], sc["S_v"], "_bar")
    Su_inv = inverse(sc["S_u"])
    mu_b, P_b = Su_inv * (mu - sc["o_u"]), Su_inv * P * Su_inv.T
    R_b = inverse(sc["S_v"]) * R * inverse(sc["S_v"]).T if model.n_v else R
    with mpmath.workdps(_DPS):
        Sgg, D = _tt2_numeric(_jets(model.inputs, model.noise, model.outputs), model.n_u, model.n_v, mu, P, R)
        Sgg_b, D_b = _tt2_numeric(_jets(ub, vb, list(gb)), model.n_u, model.n_v, mu_b, P_b, R_b)
        lhs, rhs = _m2_at(weight, label, Sgg, D), _m2_at(weight, label, Sgg_b, D_b)
        size = max(abs(_m2_at(weight, label, Sgg, Sgg)), abs(_m2_at(weight, label, Sgg_b, Sgg_b)))
    point = _values(wp, Sgg, D, sc["S_y"])
    diff = sp.N(wp.difference.xreplace(point), _DPS)
    if abs(diff - (lhs - rhs)) > 1e-20 * max(1, abs(lhs)):
        raise SymmonError(f"internal: the lemma's difference {diff} and the direct {lhs - rhs} disagree")
    point.update(sc)
    point.update({"mean": mu, "cov": P, "noise_cov": R, "lhs": lhs, "rhs": rhs, "difference": diff})
    return point, size


def _rule(transform: Any) -> Any:
    """The Transform of a name of :func:`prove_invariance` (the family's default rule), or itself."""
    if isinstance(transform, str):
        return {"tt2": TT2(), "ut": UT.ut1(), "gh": GaussHermite(), "mc": MonteCarlo(n=10**5, seed=0)}[transform]
    return transform


def _float(M: sp.Matrix) -> np.ndarray:
    return np.array(sp.Matrix(M).evalf(), dtype=float)


def _both_units(model: Model, weight: Any, transform: Any, mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix,
                sc: dict[str, sp.Matrix]) -> tuple[Any, Any]:
    """:func:`symmon.nonlinearity` of g at (μ, P, R) and of ḡ at the mapped point (double precision)."""
    plain = model.with_angles([])  # the lemmas assume outputs that are not wrapped
    u = Gaussian(_float(mu).ravel(), _float(P))
    v = Gaussian(np.zeros(model.n_v), _float(R)) if model.n_v else None
    g_b = change_units(plain, sc["S_u"], sc["o_u"], sc["S_y"], sc["o_y"], sc["S_v"] if model.n_v else None)
    u_b = change_gaussian(u, _float(sc["S_u"]), _float(sc["o_u"]).ravel())
    v_b = change_gaussian(v, _float(sc["S_v"])) if v is not None else None
    rule = _rule(transform)
    return (nonlinearity(plain, u, v, weight=weight, transform=rule),
            nonlinearity(g_b, u_b, v_b, weight=weight, transform=rule))


def _size(m: Any) -> float:
    """tr(W Σ_gg): M² = tr(W D) with D a difference of terms of the size of Σ_gg, so its rounding
    is relative to this (1 for the weights (43), (42) and (8))."""
    return abs(float(np.trace(m.weight @ m.moments.cov)))


def _counterexample_rule(model: Model, weight: Any, label: str, wp: _WeightPart, transform: Any,
                         mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix, k: int = 0) -> tuple[dict, float]:
    """The same with the moments of a point rule, computed by :func:`symmon.nonlinearity` (double
    precision), and tr(W Σ_gg)."""
    sc = _scales(model, k)
    old, new = _both_units(model, weight, transform, mu, P, R, sc)
    to_mp = lambda a: mpmath.matrix(a.tolist())  # noqa: E731
    point = _values(wp, to_mp(old.moments.cov), to_mp(old.residual_cov), sc["S_y"])
    point.update(sc)
    lhs, rhs = sp.Float(old.squared), sp.Float(new.squared)
    point.update({"mean": mu, "cov": P, "noise_cov": R, "lhs": lhs, "rhs": rhs,
                  "difference": sp.N(wp.difference.xreplace(point), _DPS)})
    return point, max(_size(old), _size(new))


#: Relative to tr(W Σ_gg): below this, two values of M² are the same.  TT2 is evaluated in 40
#: digits (agreement to 1e-25 elsewhere in this module); a point rule in double precision,
#: where M² = tr(W D) rounds to about 1e-13 of tr(W Σ_gg) at these scales (powers of two are
#: exact in binary): a difference of 1e-6 of it is not rounding.
_REFUTE_RTOL = {"tt2": sp.Float("1e-20", _DPS), "rule": 1e-6}


def _differs(lhs: Any, rhs: Any, size: Any, rtol: Any) -> bool:
    """Two values of M² differ beyond rounding (so 0 and 0, or two roundings of 0, do not)."""
    return abs(lhs - rhs) > rtol * size


def _refutation(model: Model, weight: Any, label: str, wp: _WeightPart, transform: Any,
                mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix) -> dict | None:
    """A counterexample whose two values of M² differ, from the first of :data:`SCALE_SETS` sets
    of scales that gives one; None if none does (the weight lemma fails for generic moments,
    yet not at this point: a refutation is never two equal numbers)."""
    tname = transform if isinstance(transform, str) else transform.name
    for k in range(SCALE_SETS):
        if tname == "tt2":
            cex, size = _counterexample_tt2(model, weight, label, wp, mu, P, R, k)
        else:
            cex, size = _counterexample_rule(model, weight, label, wp, transform, mu, P, R, k)
        if _differs(cex["lhs"], cex["rhs"], size, _REFUTE_RTOL["tt2" if tname == "tt2" else "rule"]):
            return cex
    return None


def _residual_zero(model: Model, tname: str, mu: sp.Matrix | None) -> bool:
    """D = 0 for this model, so M² = tr(W D) = 0 in every unit system, whatever the weight.

    TT2: D_ii = ½‖P^½ H_uu,i P^½‖² + ‖P^½ H_uv,i R^½‖² (the v–v block of the Hessian cancels
    against Σ_c), so D = 0 exactly when the second derivatives ∂²g/∂u∂w vanish at the mean
    (``mu``; for every mean when ``mu`` is None). A point rule evaluates g away from the mean,
    so it needs them to vanish everywhere: g affine in u, whose points the rule maps exactly
    (D = 0 up to rounding, for the UT family, Gauss–Hermite and Monte Carlo alike).
    """
    w = list(model.inputs) + list(model.noise)
    exprs = list(model.outputs)
    at_mean = tname == "tt2" and mu is not None
    if at_mean and nonsmooth_atoms(exprs):
        exprs = localize(exprs, dict(zip(w, list(mu) + [0] * model.n_v)), TT2_KINK_HINT)
    sub = dict(zip(w, list(mu) + [0] * model.n_v)) if at_mean else {}
    # A rational probe point tells most nonzero derivatives apart at once; simplify confirms the rest.
    probe = {s: sp.Rational(7 + 4 * i, 5 + 2 * i) for i, s in enumerate(w)}
    for g in exprs:
        for a in model.inputs:
            da = sp.diff(g, a)
            for b in w:
                h = sp.diff(da, b).xreplace(sub)
                if h == 0:
                    continue
                at = sp.N(h.xreplace(probe), 30)
                if at.is_number and at.is_finite and abs(at) > 1e-20:
                    return False
                if sp.simplify(h) != 0:
                    return False
    return True


def _numeric_check(model: Model, weight: Any, transform: Any, mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix) -> None:
    """Before a "holds": M² by :func:`symmon.nonlinearity` is the same in the original units and
    in every set of :data:`SCALE_SETS` (scales ×2^±10 and small primes, offsets), within
    ``_REFUTE_RTOL["rule"]`` of tr(W Σ_gg).

    Raises
    ------
    UndecidedProofError
        Naming the two values and the scales: the proof is not reported as holding where the
        numbers say otherwise (g discontinuous at a point the rule evaluates, or rounding
        that takes another branch of a kink).
    """
    for k in range(SCALE_SETS):
        sc = _scales(model, k)
        old, new = _both_units(model, weight, transform, mu, P, R, sc)
        if _differs(old.squared, new.squared, max(_size(old), _size(new)), _REFUTE_RTOL["rule"]):
            kinks = nonsmooth_atoms(model.outputs)
            why = (f"g has kinks or jumps ({', '.join(map(str, kinks[:3]))}) that rounding or a point of the rule meets"
                   if kinks else "the symbolic verdict and the numbers disagree")
            def fmt(n: str) -> str:
                a = _float(sc[n])
                vals = ", ".join(f"{v:.6g}" for v in (a.diagonal() if n.startswith("S") else a.ravel()))
                return f"{n} = " + (f"diag({vals})" if n.startswith("S") else f"[{vals}]")

            shown = ", ".join(fmt(n) for n in ("S_u", "o_u", "S_y", "o_y", "S_v") if sc[n].rows)
            raise UndecidedProofError(
                f"not reporting invariance of {model.name!r}: symmon's numeric MoN ({_rule(transform)}) is "
                f"{old.value:.6g} in the original units and {new.value:.6g} with {shown}; {why}. Move the "
                "mean off the kinks, or check the model"
            )
