"""Measures of nonlinearity (MoN): Liu–Li's MSE-based MoN and the unitless normalised MoN.

With Σ_gg = Cov g, Σ_gu = Cov(g, u), Σ_uu = Cov u and Σ_c = Cov_v(E[g | v]),

    M² = tr(W (Σ_gg − Σ_c − Σ_gu Σ_uu⁻¹ Σ_ug)).

This module is the front end: it gets the moments from :func:`symmon.propagate`, Σ_c
from :mod:`symmon.measures.conditional` (0 without noise, (29) for additive, (28) for
multiplicative, a nested integral for general noise), evaluates the formula in
:mod:`symmon.measures.formula`, and for Monte Carlo the jackknife error bar.

TT1 gives M = 0 by construction: TT1 *is* the best affine approximation at the mean, so
its residual D is exactly zero.  Use TT2 (closed form D ≈ ½[tr(H_i P H_j P)]), UT,
Gauss–Hermite or Monte Carlo.

The papers are those of :mod:`symmon.measures.formula` (Straka & Havlík 2024; Liu & Li 2015).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, Sequence

import numpy as np

from .conditional import conditional_cov, conditional_cov_replicates, empirical_conditional_cov
from ..errors import ArgumentError, InconsistentMomentsError, NonFiniteError
from ..core.gaussian import Gaussian
from ..core.mixture import Empirical, GaussianMixture
from .formula import MonParts, NonlinearityMeasure, mon_from_moments
from ..core.model import Model, with_param_values
from ..core.sde import SDE
from ..propagation.joint import JointMoments
from ..propagation.front import check_noise_given, check_transform, propagate, propagate_mixture
from ..propagation.mixing import is_mixture, mixed_leave_one_out
from ..propagation.particles import propagate_empirical
from ..transforms.base import Transform
from ..transforms.stats import Stats, jackknife, jackknife_se, moments_of
from ..transforms.registry import compare_set

__all__ = ["NonlinearityMeasure", "MonParts", "nonlinearity", "flow_model", "FLOW_SUBSTEPS", "compare", "format_table",
           "mon_from_moments", "choose_substeps", "MAX_CHOSEN_SUBSTEPS"]


# --------------------------------------------------------------------------- public API
def nonlinearity(model: Model | SDE, u: Gaussian | GaussianMixture, v: Gaussian | GaussianMixture | None = None, *,
                 weight: Any = "full", transform: Transform | None = None, executor: Any = None,
                 params: dict | None = None, dt: float | None = None, method: str | None = None,
                 substeps: int | None = None, t: float | None = None) -> NonlinearityMeasure:
    """The measure of nonlinearity of y = g(u, v).

    Parameters
    ----------
    model : Model or SDE
        For an :class:`~symmon.SDE`, the MoN of its flow map over a step ``dt``, x(t) ↦ x(t + dt)
        with its noise: of the discretisation :func:`flow_model` (``u`` is the law of x(t),
        ``v`` is not given: the noise is the SDE's Brownian motion).
    u : Gaussian, GaussianMixture or Empirical
        For particles (:class:`~symmon.Empirical`) the MoN of the empirical measure,
        from the weighted sample moments of :func:`symmon.propagate` and Σ_c with the
        inner integral over u a weighted sum over the particles
        (:func:`~symmon.measures.conditional.empirical_conditional_cov`); its ``stderr`` is
        the delete-one-group jackknife over 20 interleaved groups of particles, and a
        ``SampleSizeWarning`` comes when the effective sample size is below 100.  The
        transform only integrates noise that is neither absent nor additive.
    v : Gaussian or GaussianMixture, optional
        Required when the model has noise symbols.  With a mixture, the MoN (25)–(29) is
        formed from the mixture's joint moments (:func:`symmon.propagate`: the exact
        mixing of the per-component moments): Σ_uu is the mixture's covariance, so the
        affine part is the best affine fit over the whole mixture, and Σ_c the mixed form
        of :mod:`symmon.measures.conditional`.  A stochastic transform takes its error bar
        from the jackknife with each group left out of every component; it is refused for
        multiplicative and general noise with a mixture (their Σ_c would need nested
        replicates per component): use a deterministic rule there.
    weight : {"full", "diag", "liu-li", "liu-li-raw"}, ndarray or weights.GeneralWeight
        ``"full"``: W = Σ_gg⁻¹/n_y (43); ``"diag"``: W = diag(diag Σ_gg)⁻¹/n_y (42);
        ``"liu-li"``: W = I/tr Σ_gg, the normalised MoN (8); ``"liu-li-raw"``: W = I, the
        raw MSE MoN (6) (it has units); a matrix W̄ in base units, checked against the
        set (41); or :func:`symmon.measures.weights.general`.  The first two and the last two
        options are unitless and lie in [0, 1].
    transform : Transform, default ``TT2()``
        As in :func:`symmon.propagate` (the same default).  TT1 gives 0 by construction
        (see the module notes).
    executor : Executor, optional
        Where a stochastic transform's replicates run (:func:`symmon.propagate`).

    params : dict, optional
        Values of the model's parameters (``Model(params=...)``), substituted before the
        model is compiled (:meth:`symmon.Model.with_params`).
    dt, method, substeps, t
        For an SDE only: the step (a positive number, in the SDE's time unit), and the
        discretisation of the flow (:func:`flow_model`: by default the order-1.5
        Itô–Taylor scheme for additive noise, Euler–Maruyama otherwise, on
        :data:`FLOW_SUBSTEPS` sub-steps); ``t``, the step's start time, which a
        time-varying SDE needs (x(t) ↦ x(t + dt) depends on it).

    Returns
    -------
    NonlinearityMeasure

    Raises
    ------
    InconsistentMomentsError
        A deterministic transform whose moments give M² clearly below 0 (beyond
        :data:`NEGATIVE_MON_RTOL`): no distribution has them, the approximation has failed,
        and a MoN clamped at 0 would read as "linear".  A Monte Carlo M² below 0 is noise,
        and is clamped.
    NonFiniteError
        Moments or a MoN that are NaN or inf.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> round(float(sm.nonlinearity(sm.Model([x], [x**2]), sm.Gaussian([0.0], [[1.0]]))), 12)
    1.0
    """
    if isinstance(model, SDE):
        if v is not None:
            raise ArgumentError("v must not be given for an SDE: the noise of its flow is its Brownian motion")
        model, params = flow_model(model, dt, params, method=method, substeps=substeps, t=t)
        v = Gaussian(np.zeros(model.n_v), np.eye(model.n_v))
    elif dt is not None or method is not None or substeps is not None or t is not None:
        raise ArgumentError("dt, method, substeps and t are for the flow of an SDE; a Model is one step already")
    model = with_param_values(model, params)
    tr = check_transform(transform)
    if isinstance(u, Empirical):
        return _empirical_nonlinearity(model, u, v, weight, tr, executor)
    if is_mixture(u) or is_mixture(v):
        return _mixture_nonlinearity(model, u, v, weight, tr, executor)
    m = propagate(model, u, v, transform=tr, executor=executor)
    stderr = None
    if tr.stochastic:
        Sc, Sc_loo = conditional_cov_replicates(model, u, v, tr, executor)
        stderr = _mc_stderr(m, model, weight, Sc, Sc_loo)
    else:
        Sc = conditional_cov(model, u, v, tr)
    try:
        parts = mon_from_moments(m.cov, m.cross_cov, m.input_cov, weight, Sc, m.mean)
    except NonFiniteError as exc:
        raise NonFiniteError(f"{tr!r}: {exc}") from None
    if not tr.stochastic:
        _check_consistent(parts, m.cov, tr)
    if stderr is not None and not np.isfinite(stderr):
        raise NonFiniteError(f"{tr!r}: the standard error of the MoN is {stderr}")
    return NonlinearityMeasure.of(parts, transform=tr, structure=model.structure, moments=m, stderr=stderr)


#: A deterministic transform's M² below −this × (|tr(W Σ_gg)| + |tr(W Σ_c)|), the terms it is
#: the difference of, is no rounding (M² is a weighted residual variance, never negative for
#: a distribution's moments).
NEGATIVE_MON_RTOL = 1e-8


def _check_consistent(parts: MonParts, Sgg: np.ndarray, tr: Transform) -> None:
    """Refuse a clearly negative M² of a deterministic transform (:class:`InconsistentMomentsError`)."""
    WSc = parts.J_Ab - parts.squared
    scale = abs(float(np.trace(parts.weight @ np.atleast_2d(Sgg)))) + abs(WSc)
    if parts.squared < -NEGATIVE_MON_RTOL * scale:
        raise InconsistentMomentsError(
            f"{tr!r}: its moments give M² = {parts.squared:.3g} < 0 (J_Ab = {parts.J_Ab:.3g}, tr(W Σ_c) = "
            f"{WSc:.3g}), which no distribution has: the approximation fails for this model and prior, and "
            "its MoN would read as 0 (linear). Use a rule of higher degree (UT, GaussHermite) or Monte Carlo, "
            "or a smaller prior spread (for an SDE, a shorter dt or more sub-steps)")


#: The sub-steps of the discretisation of an SDE's flow in :func:`nonlinearity`.
FLOW_SUBSTEPS = 4


@lru_cache(maxsize=32)
def _discretized(sde: SDE, method: str, substeps: int) -> Model:
    return sde.discretize(method, substeps=substeps)


def flow_model(sde: SDE, dt: float, params: dict | None = None, *, method: str | None = None,
               substeps: int | None = None, t: float | None = None) -> tuple[Model, dict]:
    """The flow of ``sde`` over a step ``dt`` as a model x(t + dt) = f(x(t), w), w ~ N(0, I),
    and the parameter values (``params`` with ``dt``, and ``t`` for a time-varying SDE)
    that make it one step.

    Parameters
    ----------
    sde : SDE
    dt : float
        The step, positive, in the SDE's time unit.
    params : dict, optional
        The values of the SDE's parameters.
    method : str, optional
        The discretisation (:meth:`SDE.discretize`): default ``"taylor1.5"`` (strong order 1.5)
        for additive noise, ``"euler"`` otherwise.
    substeps : int, optional
        Sub-steps of the discretisation, default :data:`FLOW_SUBSTEPS`.
    t : float, optional
        The step's start time: required for a time-varying SDE (:attr:`SDE.is_time_invariant`
        false), whose flow depends on it; not read for a time-invariant one.

    Raises
    ------
    ArgumentError
        A ``dt`` that is not a positive finite number, ``params`` naming ``dt`` or the time,
        or a time-varying SDE without a finite ``t``.
    """
    if isinstance(dt, (bool, np.bool_)) or not isinstance(dt, (int, float, np.integer, np.floating)) \
            or not np.isfinite(dt) or dt <= 0:
        raise ArgumentError(f"dt (the step of the SDE's flow) must be a positive finite number, got {dt!r}")
    if method is None:
        method = "taylor1.5" if sde.additive else "euler"
    model = _discretized(sde, method, FLOW_SUBSTEPS if substeps is None else substeps)
    given = dict(params or {})
    if "dt" in {str(k) for k in given}:
        raise ArgumentError("params must not give 'dt': the step is the argument dt")
    if sde.is_time_invariant:
        return model, {**given, "dt": float(dt)}
    name = str(sde.time)
    if name in {str(k) for k in given}:
        raise ArgumentError(f"params must not give {name!r}: the start time is the argument t")
    if isinstance(t, (bool, np.bool_)) or not isinstance(t, (int, float, np.integer, np.floating)) \
            or not np.isfinite(t):
        raise ArgumentError(f"the SDE {sde.name!r} is time-varying (its drift or diffusion uses {name}), so its flow "
                            f"over dt depends on when the step starts: give t=... (a finite number), got {t!r}")
    return model, {**given, name: float(t), "dt": float(dt)}


#: The most sub-steps :func:`choose_substeps` gives (and so the shortest sub-step, dt/256).
MAX_CHOSEN_SUBSTEPS = 256


def choose_substeps(sde: SDE, prior: Gaussian, dt: float, tol: float = 0.01, params: dict | None = None, *,
                    transform: Transform | None = None, max_substeps: int = MAX_CHOSEN_SUBSTEPS,
                    t: float | None = None) -> int:
    """The fewest sub-steps N (a power of two) whose sub-step's flow is nearly affine: the MoN
    of the flow map over dt/N (:func:`nonlinearity` of the SDE from ``prior``) at most ``tol``.

    A discretisation that linearises the drift on each sub-step (``"local_linear"``, the
    noise of ``"rk4"``), and a Gaussian filter of it, are then accurate to about ``tol`` on
    each sub-step.  N doubles from 1 until the MoN is within ``tol``.  The sub-step's flow is
    one step of :func:`flow_model`'s scheme (order-1.5 Itô–Taylor for additive noise,
    Euler–Maruyama otherwise: one compiled model per N tried); the MoN is taken from
    ``prior``, the law of x at the step's start (the later sub-steps start from the
    propagated law: for a long step whose spread grows much, take the prior of the largest
    spread).

    Parameters
    ----------
    sde : SDE
    prior : Gaussian
        The law of x(t) at the step's start.
    dt : float
        The step, positive, in the SDE's time unit.
    tol : float, default 0.01
        The MoN (unitless, in [0, 1]) one sub-step may have: :func:`symmon.advise`'s
        tolerance (:data:`symmon.measures.advice.DEFAULT_TOL`).
    params : dict, optional
        The SDE's parameter values.
    transform : Transform, optional
        The rule of the MoN (:func:`nonlinearity`'s default, TT2).
    max_substeps : int, default :data:`MAX_CHOSEN_SUBSTEPS`
        The most sub-steps to try.
    t : float, optional
        The step's start time, which a time-varying SDE needs (:func:`flow_model`); its
        sub-step's flow is taken from there.

    Returns
    -------
    int
        N ≥ 1; 1 for a linear SDE (its flow is affine: MoN 0).

    Raises
    ------
    ArgumentError
        A bad ``tol`` or ``max_substeps``, or a ``dt`` that is not a positive finite number.
    SymmonError
        No N up to ``max_substeps`` brings the MoN within ``tol``, naming the MoN reached.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x", real=True)
    >>> well = sm.SDE([x], [x - x**3], diffusion=[0.5])
    >>> choose_substeps(well, sm.Gaussian([0.5], [[0.1]]), 1.0, tol=0.1)
    16
    """
    from ..errors import SymmonError

    if isinstance(tol, (bool, np.bool_)) or not isinstance(tol, (int, float, np.integer, np.floating)) \
            or not np.isfinite(tol) or tol <= 0:
        raise ArgumentError(f"tol must be a positive finite number, got {tol!r}")
    if isinstance(max_substeps, (bool, np.bool_)) or not isinstance(max_substeps, (int, np.integer)) or max_substeps < 1:
        raise ArgumentError(f"max_substeps must be a positive integer, got {max_substeps!r}")
    flow_model(sde, dt, t=t)  # checks dt (and t)
    if sde.is_linear:
        return 1
    N, mon = 1, float("nan")
    while N <= max_substeps:
        mon = float(nonlinearity(sde, prior, dt=float(dt) / N, params=params, transform=transform, substeps=1, t=t))
        if mon <= tol:
            return N
        N *= 2
    raise SymmonError(f"the MoN of {sde.name!r}'s flow over dt/{N // 2} = {float(dt) / (N // 2):.6g} is {mon:.3g}, "
                      f"above tol = {tol:g} at max_substeps = {max_substeps}: the flow is nonlinear at every "
                      "sub-step (a larger tol, or a narrower prior)")


def _empirical_nonlinearity(model: Model, u: Empirical, v: Any, weight: Any, tr: Transform, executor: Any
                            ) -> NonlinearityMeasure:
    """The MoN of particles with its jackknife error bar (see :func:`nonlinearity`)."""
    check_noise_given(model, v)
    m, sums = propagate_empirical(model, u, v, tr, executor)
    Sc, Sc_loo = empirical_conditional_cov(model, u, v, tr)
    try:
        parts = mon_from_moments(m.cov, m.cross_cov, m.input_cov, weight, Sc, m.mean)
    except NonFiniteError as exc:
        raise NonFiniteError(f"particles: {exc}") from None
    stderr = None
    if sums.w.shape[0] >= 2:
        # Group g left out of the moments and of Σ_c at once, as for Monte Carlo.
        _, cov, cross, in_cov = sums.leave_one_out().moments()
        nu = model.n_u
        stderr = float(jackknife_se(np.array([
            mon_from_moments(cov[g], cross[g][:, :nu], in_cov[g][:nu, :nu], weight, Sc_loo[g]).value
            for g in range(cov.shape[0])])))
    return NonlinearityMeasure.of(parts, transform=tr, structure=model.structure, moments=m, stderr=stderr)


def _mixture_nonlinearity(model: Model, u: Any, v: Any, weight: Any, tr: Transform, executor: Any
                          ) -> NonlinearityMeasure:
    """The MoN of a mixture u and/or v from the mixed joint moments (see :func:`nonlinearity`)."""
    exact_sc = model.n_v == 0 or model.structure == "additive" or (
        model.structure == "multiplicative" and model.pi.shape[1] == 0)
    if tr.stochastic and not exact_sc:
        raise ArgumentError(
            f"{tr!r} with a GaussianMixture and {model.structure} noise: the conditional term Cov_v E[g | v] "
            "would need nested replicates for every component; use a deterministic transform "
            "(GaussHermite, UT, TT2) or an Empirical sample of the mixture")
    m, raw, cb = propagate_mixture(model, u, v, tr, executor)
    Sc = conditional_cov(model, u, v, tr)
    try:
        parts = mon_from_moments(m.cov, m.cross_cov, m.input_cov, weight, Sc, m.mean)
    except NonFiniteError as exc:
        raise NonFiniteError(f"{tr!r}: {exc}") from None
    if not tr.stochastic:
        _check_consistent(parts, m.cov, tr)
    stderr = None
    if tr.stochastic:
        # Group g left out of every component at once, mixed, and the MoN of each.
        _, cov, cross, in_cov = mixed_leave_one_out(raw, cb, model.n_y, sorted(model.angle_outputs))
        nu = model.n_u
        stderr = float(jackknife_se(np.array([
            mon_from_moments(cov[0, g], cross[0, g][:, :nu], in_cov[0, g][:nu, :nu], weight, Sc).value
            for g in range(cov.shape[1])])))
        if not np.isfinite(stderr):
            raise NonFiniteError(f"{tr!r}: the standard error of the MoN is {stderr}")
    return NonlinearityMeasure.of(parts, transform=tr, structure=model.structure, moments=m, stderr=stderr)


def _mc_stderr(m: JointMoments, model: Model, weight, Sc: np.ndarray, Sc_loo: np.ndarray | None) -> float:
    """Jackknife standard error of the MoN: replicate i is left out of the moments and of
    Σ_c (``Sc_loo``; ``None``: Σ_c has no sampling error)."""
    ny, nu = model.n_y, model.n_u
    nw = model.n_u + model.n_v
    if Sc_loo is None:
        Sc_loo = np.repeat(Sc[None], len(m.replicates), axis=0)

    def values(loo: Stats) -> np.ndarray:
        _, cyy, cyw, cww = moments_of(loo, ny, nw, sorted(model.angle_outputs))
        return np.array([mon_from_moments(cyy[i], cyw[i, :, :nu], cww[i, :nu, :nu], weight, S).value
                         for i, S in enumerate(Sc_loo)])

    return float(jackknife(m.replicates, values))


def compare(model: Model, u: Gaussian | GaussianMixture, v: Gaussian | GaussianMixture | None = None, *,
            weight: Any = "full",
            transforms: Sequence[Transform] | None = None, executor: Any = None,
            params: dict | None = None) -> list[dict]:
    """The MoN by every transform, as rows of a table.

    Parameters
    ----------
    model, u, v, weight, executor
        As in :func:`nonlinearity` (a mixture u or v included: each row is the MoN
        of the mixture by that transform).
    transforms : sequence of Transform, optional
        Default: the registry's comparison set
        (:func:`~symmon.transforms.registry.compare_set`).

    params : dict, optional
        Values of the model's parameters (``Model(params=...)``), substituted before the
        model is compiled (:meth:`symmon.Model.with_params`).

    Returns
    -------
    list of dict
        Keys ``transform``, ``value``, ``stderr`` (Monte Carlo only) and ``evaluations``.
    """
    model = with_param_values(model, params)
    if transforms is None:
        transforms = compare_set()
    rows = []
    for t in transforms:
        res = nonlinearity(model, u, v, weight=weight, transform=t, executor=executor)
        rows.append({
            "transform": repr(t), "value": res.value, "stderr": res.stderr,
            "evaluations": res.moments.evaluations,
        })
    return rows


def format_table(rows: list[dict]) -> str:
    """A plain-text table of :func:`compare` rows."""
    lines = [f"{'transform':<60} {'MoN':>12} {'MC s.e.':>10}"]
    for r in rows:
        se = f"{r['stderr']:.2g}" if r["stderr"] is not None else "-"
        lines.append(f"{r['transform'][:60]:<60} {r['value']:>12.6g} {se:>10}")
    return "\n".join(lines)

