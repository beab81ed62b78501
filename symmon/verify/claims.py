"""Claims about a model or an estimator, each decided by :func:`symmon.verify.verification.decide`.

- :func:`verify_moments`: a claimed E y, Cov y or Cov(y, u) of a model under a transform
  (TT1, TT2, the UT family, through :func:`symmon.symbolic_moments`) or exactly (through
  :func:`symmon.expect`, or against a numeric reference when E[g] has no closed form);
- :func:`verify_derivatives`: a claimed Jacobian or Hessians (against sympy's exact derivatives);
- :func:`verify_mon`: a claimed squared measure of nonlinearity M² = tr(W D) (29) of
  Straka & Havlík (2024), D = Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug, with a named weight (42), (43), (6), (8);
- :func:`verify_weight`: a claimed weight W(Σ_gg) against the named rule;
- :func:`verify_estimator`: a claimed estimator of h(x) given x ~ N(x̂, P) (the second stage
  of Shin et al. (2020)): its bias E[h(x) − ĥ] and its MSE E[(h(x) − ĥ)²].

Each returns a :class:`~symmon.verify.verification.Verification`.
"""

from __future__ import annotations

import time
from typing import Any, Sequence

import mpmath
import sympy as sp

from ..core.gaussian import Gaussian
from ..core.model import Model
from ..errors import ArgumentError, ArgumentTypeError, ExpectationNotClosedForm, ShapeError
from ..measures.weights import NAMED_WEIGHTS
from .moments import symbolic_moments
from .numeric import Reference, gaussian_integrals
from .verification import (
    DEFAULT_POINTS,
    Expectation,
    Verification,
    as_matrix,
    decide,
    domain_items,
    exact_matrix,
    exact_side,
    numeric_side,
    prepare,
    side_of,
)

__all__ = ["verify_moments", "verify_derivatives", "verify_mon", "verify_weight", "verify_estimator"]


def _model(model: Any) -> Model:
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    return model


def _input(model: Model, u: Any, n: int | None = None, what: str = "u") -> tuple[sp.Matrix, sp.Matrix]:
    """μ and P of the input (or of the noise): a Gaussian (its numbers made exact) or a pair (mean, cov)."""
    n = model.n_u if n is None else n
    if isinstance(u, Gaussian):
        mu, P = sp.Matrix(list(u.mean)), sp.Matrix(u.cov.tolist())
    elif isinstance(u, (tuple, list)) and len(u) == 2:
        mu, P = sp.Matrix(u[0]), sp.Matrix(u[1])
    else:
        raise ArgumentTypeError(f"{what} must be a symmon.Gaussian or a pair (mean, cov), got {type(u).__name__}")
    if mu.shape not in ((n, 1), (1, n)) or P.shape != (n, n):
        raise ShapeError(f"{what}: the model has {n} of them, got a mean of shape {mu.shape} and a cov of shape {P.shape}")
    # numbers exact before any moment is computed from them (0.17 -> 17/100)
    return exact_matrix(mu.reshape(n, 1)), exact_matrix(P)


def _transform_name(transform: Any) -> str:
    return transform if isinstance(transform, str) else type(transform).__name__


def _stack(parts: Sequence[tuple[str, sp.Matrix | None]]) -> tuple[sp.Matrix, list[str]]:
    """The given parts as one column, with a label per entry ("Cov y[0, 1]")."""
    entries, labels = [], []
    for name, M in parts:
        if M is None:
            continue
        for i in range(M.rows):
            for j in range(M.cols):
                entries.append(M[i, j])
                labels.append(f"{name}[{i}]" if M.cols == 1 else f"{name}[{i}, {j}]")
    return sp.Matrix(entries), labels


def _claimed(value: Any, shape: tuple[int, int], name: str) -> sp.Matrix | None:
    if value is None:
        return None
    M = as_matrix(value, name)
    if M.shape != shape and M.shape == (shape[1], shape[0]) and 1 in shape:
        M = M.reshape(*shape)
    if M.shape != shape:
        raise ShapeError(f"{name} must have shape {shape}, got {M.shape}")
    return M


def _exact_moments_reference(model: Model, mu: sp.Matrix, P: sp.Matrix, which: Sequence[str],
                             mv: sp.Matrix, R: sp.Matrix):
    """A numeric reference of the exact E y, Cov y, Cov(y, u) at a point, with propagated errors
    (the noise v ~ N(mv, R), independent of u, integrated with it)."""
    g = list(model.outputs)
    u = list(model.inputs)
    w = u + list(model.noise)
    ny, nu = len(g), len(u)

    def reference(pt, refine, seed) -> Reference:
        m = mu.xreplace(pt)
        mw = list(m) + list(mv.xreplace(pt))
        C = sp.diag(P.xreplace(pt), R.xreplace(pt)) if model.n_v else P.xreplace(pt)
        funcs = g + [g[i] * g[j] for i in range(ny) for j in range(ny)] + [g[i] * s for i in range(ny) for s in u]
        r = gaussian_integrals(funcs, w, mw, C, refine=refine, seed=seed)
        v, e = list(r.values), list(r.errors)
        Eg, eg = v[:ny], e[:ny]
        vals, errs = [], []
        if "mean" in which:
            vals += Eg
            errs += eg
        if "cov" in which:
            for i in range(ny):
                for j in range(ny):
                    k = ny + i * ny + j
                    vals.append(v[k] - Eg[i] * Eg[j])
                    errs.append(e[k] + abs(Eg[i]) * eg[j] + abs(Eg[j]) * eg[i] + eg[i] * eg[j])
        if "cross_cov" in which:
            for i in range(ny):
                for j in range(nu):
                    k = ny + ny * ny + i * nu + j
                    mj = mpmath.mpf(sp.N(m[j], 40)._to_mpmath(mpmath.mp.prec))
                    vals.append(v[k] - Eg[i] * mj)
                    errs.append(e[k] + abs(mj) * eg[i])
        return Reference(tuple(vals), tuple(errs), r.method)

    return reference


def verify_moments(model: Model, u: Any, mean: Any = None, cov: Any = None, cross_cov: Any = None,
                   transform: Any = "exact", assumptions: Any = None, domain: Any = None, *,
                   v: Any = None, points: int = DEFAULT_POINTS, seed: int = 0) -> Verification:
    """Verify a claimed E y, Cov y and/or Cov(y, u) of y = g(u, v), u ~ N(μ, P), v ~ N(μ_v, R).

    The reference is :func:`symmon.symbolic_moments` with the same transform: TT1, TT2 and
    the UT family are closed forms, so the claim is proved or refuted exactly; the exact
    moments (``transform="exact"``) are closed forms when every entry is in the class of
    :func:`symmon.expect`, and otherwise a numeric reference with error bars (1-D quadrature,
    Gauss–Hermite, Monte Carlo), which can refute or be consistent, never prove.

    Parameters
    ----------
    model : Model
    u : Gaussian or (mean, cov)
        The input: numbers (made exact, 0.17 → 17/100) or sympy symbols.
    mean, cov, cross_cov : optional
        The claimed E y (n_y), Cov y (n_y × n_y), Cov(y, u) (n_y × n_u); at least one.
    transform : "exact" or a transform of :func:`symmon.symbolic_moments` ("tt1", "tt2", "ut", ...)
    assumptions, domain, points, seed
        As :func:`symmon.verify`; the input covariance must be positive definite at every
        random point (other points are refused).
    v : Gaussian or (mean, cov), keyword-only
        The noise of a model with noise symbols (required then), independent of u.

    Returns
    -------
    Verification

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x", real=True)
    >>> m, p = sp.Symbol("m", real=True), sp.Symbol("p", positive=True)
    >>> sq = sm.Model([x], [x**2])
    >>> u = (sp.Matrix([m]), sp.Matrix([[p]]))
    >>> sm.verify_moments(sq, u, mean=[m**2], cov=[[4*m**2*p]], transform="tt1").verdict
    'proved'
    >>> sm.verify_moments(sq, u, mean=[m**2 + p / 2], transform="tt1").counterexample["entry"]
    'E y[0]'
    """
    t0 = time.perf_counter()
    model = _model(model)
    mu, P = _input(model, u)
    if model.n_v and v is None:
        raise ArgumentError(f"the model has noise {list(map(str, model.noise))}: pass its Gaussian, v=(mean, cov)")
    if not model.n_v and v is not None:
        raise ArgumentError("v is given but the model has no noise symbols")
    mv, R = _input(model, v, model.n_v, "v") if model.n_v else (sp.zeros(0, 1), sp.zeros(0, 0))
    ny, nu = model.n_y, model.n_u
    claimed = [("E y", _claimed(mean, (ny, 1), "mean")), ("Cov y", _claimed(cov, (ny, ny), "cov")),
               ("Cov(y, u)", _claimed(cross_cov, (ny, nu), "cross_cov"))]
    if all(c is None for _, c in claimed):
        raise ArgumentError("verify_moments needs a claim: mean, cov and/or cross_cov")
    which = [k for k, (_, c) in zip(("mean", "cov", "cross_cov"), claimed) if c is not None]
    C, labels = _stack(claimed)
    (C, mu, P, mv, R), prep = prepare([C, mu, P, mv, R], assumptions, domain)
    tname = _transform_name(transform)
    noise = dict(noise_mean=mv, noise_cov=R) if model.n_v else {}
    try:
        ref = symbolic_moments(model, transform, mean=mu, cov=P, **noise)
        reference, _ = _stack([("E y", ref.mean if "mean" in which else None),
                               ("Cov y", ref.cov if "cov" in which else None),
                               ("Cov(y, u)", ref.cross_cov if "cross_cov" in which else None)])
        rhs = exact_side(reference, [f"reference: symmon.symbolic_moments(model, {tname!r}) in closed form"],
                         covs=[P, R])
    except ExpectationNotClosedForm as exc:
        rhs = numeric_side(C.shape, _exact_moments_reference(model, mu, P, which, mv, R),
                           mu.free_symbols | P.free_symbols | mv.free_symbols | R.free_symbols,
                           [P, R], [f"the exact moments have no closed form ({exc}): numeric reference"])
    parts = ", ".join(f"{n} = {_short(c)}" for n, c in claimed if c is not None)
    text = f"{parts} for y = {list(model.outputs)}, u ~ N({list(mu)}, {P.tolist()})"
    text += f", v ~ N({list(mv)}, {R.tolist()}), {tname}" if model.n_v else f", {tname}"
    lhs = exact_side(C, covs=[P, R])
    lhs.symbols |= mu.free_symbols | P.free_symbols | mv.free_symbols | R.free_symbols
    return decide(text, lhs, rhs, prep, points=points, seed=seed, t0=t0, labels=labels)


def _short(M: sp.Matrix) -> str:
    return str(M[0]) if M.shape == (1, 1) else str(M.tolist() if M.cols > 1 else list(M))


def verify_derivatives(model: Model, jacobian: Any = None, hessians: Any = None, assumptions: Any = None,
                       domain: Any = None, *, points: int = DEFAULT_POINTS, seed: int = 0) -> Verification:
    """Verify a claimed Jacobian ∂g/∂w and/or Hessians ∂²g_i/∂w² of a model, w = [u; v].

    The reference is sympy's exact derivative of the model's outputs.

    Parameters
    ----------
    model : Model
    jacobian : matrix, optional
        n_y × n_w.
    hessians : sequence of matrices (one per output) or one matrix (one output), optional
        n_w × n_w each.
    assumptions, domain, points, seed
        As :func:`symmon.verify` (the random points are points w of the model).

    Returns
    -------
    Verification

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x, y = sp.symbols("x y", real=True)
    >>> polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2)])
    >>> r = sp.sqrt(x**2 + y**2)
    >>> sm.verify_derivatives(polar, jacobian=[[x / r, y / r]]).verdict
    'proved'
    """
    t0 = time.perf_counter()
    model = _model(model)
    w = list(model.inputs) + list(model.noise)
    g = sp.Matrix(model.outputs)
    nw, ny = len(w), model.n_y
    parts_c, parts_r = [], []
    if jacobian is not None:
        parts_c.append(("J", _claimed(jacobian, (ny, nw), "jacobian")))
        parts_r.append(("J", g.jacobian(w)))
    if hessians is not None:
        hs = [hessians] if isinstance(hessians, sp.MatrixBase) or (ny == 1 and _is_matrix_like(hessians)) else list(hessians)
        if len(hs) != ny:
            raise ShapeError(f"hessians: one matrix per output ({ny}), got {len(hs)}")
        for i, h in enumerate(hs):
            parts_c.append((f"H_{i}", _claimed(h, (nw, nw), f"hessians[{i}]")))
            parts_r.append((f"H_{i}", sp.hessian(g[i], w)))
    if not parts_c:
        raise ArgumentError("verify_derivatives needs a claim: jacobian and/or hessians")
    C, labels = _stack(parts_c)
    R, _ = _stack(parts_r)
    (C, R), prep = prepare([C, R], assumptions, domain)
    text = ", ".join(f"{n} = {_short(c)}" for n, c in parts_c) + f" for g = {list(model.outputs)}"
    return decide(text, exact_side(C), exact_side(R, ["reference: sympy's exact derivatives of g"]), prep,
                  points=points, seed=seed, t0=t0, labels=labels)


def _is_matrix_like(x: Any) -> bool:
    return isinstance(x, (list, tuple)) and bool(x) and isinstance(x[0], (list, tuple)) and not (
        x[0] and isinstance(x[0][0], (list, tuple, sp.MatrixBase)))


def weight_matrix(weight: str, Sgg: sp.Matrix) -> sp.Matrix:
    """The named weight W(Σ_gg) of Straka & Havlík (2024) as a sympy matrix: "full" (43),
    "diag" (42), "liu-li" (the square of (8)), "liu-li-raw" (6)."""
    n = Sgg.rows
    if weight == "full":
        return Sgg.inv() / n
    if weight == "diag":
        return sp.diag(*[1 / Sgg[i, i] for i in range(n)]) / n
    if weight == "liu-li":
        return sp.eye(n) / Sgg.trace()
    if weight == "liu-li-raw":
        return sp.eye(n)
    raise ArgumentError(f"weight must be one of {', '.join(NAMED_WEIGHTS)}, got {weight!r}")


def verify_weight(weight: str, cov: Any, claimed: Any, assumptions: Any = None, domain: Any = None, *,
                  points: int = DEFAULT_POINTS, seed: int = 0) -> Verification:
    """Verify a claimed weight matrix W(Σ_gg) against a named rule of Straka & Havlík (2024).

    Parameters
    ----------
    weight : {"full", "diag", "liu-li", "liu-li-raw"}
    cov : matrix
        Σ_gg, usually a symmetric matrix of symbols; it is drawn symmetric positive
        definite at the random points.
    claimed : matrix
        The claimed W.

    Returns
    -------
    Verification

    Examples
    --------
    Remark 2 of the paper prints W = I/√tr Σ_gg for the normalised measure (8), whose weight
    is I/tr Σ_gg (derivations/ERRATA.md, entry 5):

    >>> import sympy as sp, symmon as sm
    >>> a, b, c = sp.symbols("a b c", real=True)
    >>> S = sp.Matrix([[a, b], [b, c]])
    >>> sm.verify_weight("liu-li", S, sp.eye(2) / sp.sqrt(S.trace())).verdict
    'refuted'
    """
    t0 = time.perf_counter()
    S = sp.Matrix(cov)
    if S.rows != S.cols:
        raise ShapeError(f"cov must be square, got shape {S.shape}")
    if weight not in NAMED_WEIGHTS:
        raise ArgumentError(f"weight must be one of {', '.join(NAMED_WEIGHTS)}, got {weight!r}")
    C = _claimed(claimed, S.shape, "claimed")
    dom = dict(domain_items(domain))
    if S.free_symbols and not any(isinstance(k, sp.MatrixBase) for k in dom):
        dom[sp.ImmutableMatrix(S)] = "spd"
    (C, S), prep = prepare([C, S], assumptions, dom)
    R = weight_matrix(weight, S)
    eq = NAMED_WEIGHTS[weight].equation
    return decide(f"W = {_short(C)} is the weight {weight!r} {eq} of Sigma_gg = {S.tolist()}", exact_side(C, covs=[S]),
                  exact_side(R, [f"reference: {NAMED_WEIGHTS[weight].formula}"], covs=[S]), prep,
                  points=points, seed=seed, t0=t0)


def verify_mon(model: Model, u: Any, claimed: Any, weight: str = "full", transform: Any = "tt2",
               assumptions: Any = None, domain: Any = None, *, points: int = DEFAULT_POINTS, seed: int = 0
               ) -> Verification:
    """Verify a claimed squared measure of nonlinearity M² = tr(W D) (29), D = Σ_gg − Σ_gu P⁻¹ Σ_ug.

    The moments are :func:`symmon.symbolic_moments` under ``transform`` (closed forms);
    the weight is the named rule on their Σ_gg (:func:`weight_matrix`).

    Parameters
    ----------
    model : Model
        Without noise symbols.
    u : Gaussian or (mean, cov)
    claimed : expression
        The claimed M² (the square of the measure).
    weight : {"full", "diag", "liu-li", "liu-li-raw"}
    transform : a transform of :func:`symmon.symbolic_moments`

    Returns
    -------
    Verification
    """
    t0 = time.perf_counter()
    model = _model(model)
    if model.n_v:
        raise ArgumentError("verify_mon takes a model without noise symbols")
    mu, P = _input(model, u)
    C = _claimed(claimed, (1, 1), "claimed")
    (C, mu, P), prep = prepare([C, mu, P], assumptions, domain)
    ref = symbolic_moments(model, transform, mean=mu, cov=P)
    D = ref.cov - ref.cross_cov * P.inv() * ref.cross_cov.T
    M2 = (weight_matrix(weight, ref.cov) * D).trace()
    lhs = exact_side(C, covs=[P])
    lhs.symbols |= mu.free_symbols | P.free_symbols
    return decide(f"M^2 = {C[0]} with weight {weight!r} for y = {list(model.outputs)}, u ~ N({list(mu)}, {P.tolist()}), "
                  f"{_transform_name(transform)}", lhs,
                  exact_side(sp.Matrix([[M2]]), ["reference: tr(W D), Straka & Havlik (2024) eq. (29), from "
                                                 "symmon.symbolic_moments"], covs=[P]),
                  prep, points=points, seed=seed, t0=t0)


def verify_estimator(target: Any, estimator: Any, over: Any, mean: Any, cov: Any, *, bias: Any = 0,
                     mse: Any = None, assumptions: Any = None, domain: Any = None, points: int = DEFAULT_POINTS,
                     seed: int = 0) -> Verification:
    """Verify the bias (and the MSE) of an estimator ĥ of h(x), x ~ N(mean, cov).

    The claims are E[h(x) − ĥ] = ``bias`` (0 by default: ĥ is the MMSE estimate, the
    conditional mean of Shin et al. (2020), Section 2) and, if given, E[(h(x) − ĥ)²] = ``mse``.

    Parameters
    ----------
    target : expression
        h(x), in the symbols ``over``.
    estimator : expression
        ĥ, in the symbols of mean and cov (not of ``over``).
    over, mean, cov
        The Gaussian x, as :class:`symmon.Expectation`.
    bias, mse : expression, optional

    Returns
    -------
    Verification

    Examples
    --------
    The MMSE estimate of x² is μ² + σ², with MSE 4μ²σ² + 2σ⁴:

    >>> import sympy as sp, symmon as sm
    >>> x, mu = sp.symbols("x mu", real=True)
    >>> s = sp.Symbol("sigma", positive=True)
    >>> sm.verify_estimator(x**2, mu**2 + s**2, x, mu, s**2, mse=4*mu**2*s**2 + 2*s**4).verdict
    'proved'
    """
    t0 = time.perf_counter()
    h, est = sp.sympify(target, strict=True), sp.sympify(estimator, strict=True)
    syms = set(over) if isinstance(over, (list, tuple)) else {over}
    if est.free_symbols & syms:
        raise ArgumentError(f"the estimator {est} may not depend on the random variables {sorted(map(str, syms))}")
    err = h - est
    exprs = [err] + ([err**2] if mse is not None else [])
    claimed = [bias] + ([mse] if mse is not None else [])
    E = Expectation(sp.Matrix(exprs), over, mean, cov)
    (E, C), prep = prepare([E, sp.Matrix(claimed)], assumptions, domain)
    labels = ["bias E[h - est]"] + (["MSE E[(h - est)^2]"] if mse is not None else [])
    text = (f"the estimator {est} of {h} has bias {claimed[0]}" + (f" and MSE {claimed[1]}" if mse is not None else "")
            + f", {list(E.over)} ~ N({list(E.mean)}, {E.cov.tolist()})")
    return decide(text, side_of(E), exact_side(C, covs=[E.cov]), prep, points=points, seed=seed, t0=t0,
                  labels=labels)
