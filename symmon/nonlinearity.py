"""Measures of nonlinearity (MoN): Liu–Li's MSE-based MoN and the unitless normalised MoN.

With Σ_gg = Cov g, Σ_gu = Cov(g, u), Σ_uu = Cov u and Σ_c = Cov_v(E[g | v]),

    M² = tr(W (Σ_gg − Σ_c − Σ_gu Σ_uu⁻¹ Σ_ug)).

Σ_c is 0 without noise, B Σ_vv Bᵀ for additive noise g = f(u) + B v (29), and
π̄ Σ_γγ π̄ᵀ for multiplicative noise g = f(u) + π(u)γ(v) (28).  For general noise the
minimising n of (23) is n(v) = E[g | v] − E g (our derivation under the paper's assumptions
A1, A2, docs/guide/nonlinearity.md; checked in ``derivations/general_noise.py``), and Σ_c is computed by nested integration.

TT1 gives M = 0 by construction: TT1 *is* the best affine approximation at the mean, so
its residual D is exactly zero.  Use TT2 (closed form D ≈ ½[tr(H_i P H_j P)]), UT,
Gauss–Hermite or Monte Carlo.

References
----------
O. Straka, J. Havlík, "Design of unitless normalized measure of nonlinearity for state
estimation", FUSION 2024. arXiv:2410.13539
Y. Liu, X. R. Li, "Measure of nonlinearity for estimation", IEEE Trans. Signal Process.
63(9), 2015. doi:10.1109/TSP.2015.2405495
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
import sympy as sp

from . import weights as _weights
from .compile import compile_model
from .errors import NonFiniteError
from .gaussian import Gaussian
from .model import Model
from .latex import latex_number, latex_text
from .moments import JointMoments
from .propagate import compiled, propagate
from .transforms import TT2, Transform
from .transforms.montecarlo import MC_INNER, Stats, jackknife, leave_one_out, merge_all, moments_of
from .transforms.registry import compare_set

__all__ = ["NonlinearityMeasure", "nonlinearity", "compare", "format_table", "mon_from_moments"]

#: Condition number above which Σ_uu is treated as singular (pseudo-inverse on its range).
SINGULAR_COND = 1e12


@dataclass(frozen=True, eq=False)
class NonlinearityMeasure:
    """A measure of nonlinearity and its parts.

    ``float(m)`` is the value M = √max(M², 0).

    Attributes
    ----------
    value : float
    squared : float
        M² = J_Ab + J_n − E‖g‖²_W (25); may be slightly negative from Monte Carlo noise.
    J_Ab : float
        The deterministic part (26): tr(W(Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug)).
    J_n : float
        The stochastic part: E‖g‖²_W − tr(W Σ_c) (27).
    weight : ndarray
        The weight matrix W used, in the original units.
    weight_name : str
    transform : Transform
    structure : str
    stderr : float or None
        Monte Carlo standard error of the value: the delete-one-group jackknife, with
        each group left out of the moments and of Σ_c (whose Monte Carlo estimate, nested
        for general noise, has its own error).
    moments : JointMoments
    residual_cov : ndarray
        D = Σ_gg − Σ_c − Σ_gu Σ_uu⁻¹ Σ_ug.
    notes : tuple of str
        Remarks, e.g. that Σ_uu was singular and its pseudo-inverse was used.
    """

    value: float
    squared: float
    J_Ab: float
    J_n: float
    weight: np.ndarray
    weight_name: str
    transform: Transform
    structure: str
    moments: JointMoments
    residual_cov: np.ndarray
    stderr: float | None = None
    notes: tuple[str, ...] = ()
    info: Mapping[str, Any] = field(default_factory=dict)

    def __float__(self) -> float:
        return float(self.value)

    def __repr__(self) -> str:
        se = f" ± {self.stderr:.2g}" if self.stderr is not None else ""
        return f"NonlinearityMeasure({self.value:.6g}{se}, weight={self.weight_name!r}, transform={self.transform!r})"

    def _repr_latex_(self) -> str:
        se = rf" \pm {latex_number(self.stderr, 2)}" if self.stderr is not None else ""
        return (
            rf"$M_{{\text{{{latex_text(self.weight_name)}}}}} = {latex_number(self.value, 6)}{se}"
            rf"\quad\text{{({self.structure} noise, {type(self.transform).__name__})}}$"
        )


def _inv_uu(Suu: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    cond = np.linalg.cond(Suu)
    if np.isfinite(cond) and cond < SINGULAR_COND:
        return np.linalg.inv(Suu), ()
    w = np.linalg.eigvalsh(Suu)
    rank = int(np.sum(w > w[-1] * 1e-12))
    note = (
        f"Σ_uu is singular (rank {rank} of {Suu.shape[0]}): the pseudo-inverse was used, "
        "i.e. the best affine fit on the informative subspace of u"
    )
    return np.linalg.pinv(Suu, rcond=1e-12, hermitian=True), (note,)


@np.errstate(over="ignore", divide="ignore", invalid="ignore")  # a non-finite result raises below
def mon_from_moments(Sgg, Sgu, Suu, weight="full", Sc=None, mean=None):
    """The MoN from the moments (26)–(29); see :func:`nonlinearity`.

    Returns
    -------
    dict with ``squared``, ``J_Ab``, ``J_n``, ``W``, ``label``, ``D``, ``notes``.

    Raises
    ------
    NonFiniteError
        If M², J_Ab or J_n is NaN or inf (moments at the edge of the float range: the
        inverse of a subnormal Σ_uu, a weight that overflows).
    """
    Sgg = np.atleast_2d(np.asarray(Sgg, dtype=float))
    Sgu = np.atleast_2d(np.asarray(Sgu, dtype=float))
    Suu = np.atleast_2d(np.asarray(Suu, dtype=float))
    Sc = np.zeros_like(Sgg) if Sc is None else np.atleast_2d(np.asarray(Sc, dtype=float))
    Suu_inv, notes = _inv_uu(Suu)
    W, label = _weights.resolve(weight, Sgg)
    lin = Sgu @ Suu_inv @ Sgu.T
    J_Ab = float(np.trace(W @ (Sgg - lin)))
    mu = np.zeros(Sgg.shape[0]) if mean is None else np.asarray(mean, dtype=float)
    Eg2 = float(np.trace(W @ (Sgg + np.outer(mu, mu))))
    WSc = float(np.trace(W @ Sc))
    D = Sgg - Sc - lin
    # M² = J_Ab + J_n − E‖g‖²_W (25) = J_Ab − tr(W Σ_c): the E‖g‖²_W terms cancel
    # analytically; adding and subtracting them would lose every digit when |E g| ≫ σ.
    if not np.isfinite([J_Ab - WSc, J_Ab, Eg2 - WSc]).all():
        raise NonFiniteError(
            f"the MoN with weight {label!r} is not finite (M² = {J_Ab - WSc:.3g}, J_Ab = {J_Ab:.3g}, "
            f"J_n = {Eg2 - WSc:.3g}): the moments (largest |Σ_gg| {np.max(np.abs(Sgg)):.3g}, smallest "
            f"variance in Σ_uu {np.min(np.diag(Suu)):.3g}) are at the edge of the float range; rescale the units"
        )
    return {"squared": J_Ab - WSc, "J_Ab": J_Ab, "J_n": Eg2 - WSc, "W": W, "label": label, "D": D, "notes": notes}


# --------------------------------------------------------------------------- Σ_c = Cov(E[g|v])
def _aux_moments(exprs: Sequence[sp.Expr], syms: Sequence[sp.Symbol], dist: Gaussian, transform: Transform):
    cm = compile_model(list(exprs), list(syms))
    b = transform.moments(cm, dist.mean[None], dist.cov[None])
    return b.mean[0], b.cov[0]


def _cond_cov(model: Model, u: Gaussian, v: Gaussian | None, transform: Transform) -> np.ndarray:
    ny = model.n_y
    if model.n_v == 0:
        return np.zeros((ny, ny))
    if model.structure == "additive":
        B = np.array(model.pi.tolist(), dtype=float)
        return B @ v.cov @ B.T
    if model.structure == "multiplicative":
        pi = model.pi
        if pi.shape[1] == 0:
            return np.zeros((ny, ny))
        pi_mean, _ = _aux_moments(list(pi), model.inputs, u, transform)
        _, Sgam = _aux_moments(list(model.gamma), model.noise, v, transform)
        return _pi_sgam_pi(pi, pi_mean, Sgam)
    return _cond_cov_general(model, u, v, transform)


def _pi_sgam_pi(pi: sp.Matrix, pi_mean: np.ndarray, Sgam: np.ndarray) -> np.ndarray:
    """(28): Σ_c = π̄ Σ_γγ π̄ᵀ, from E π flattened as sympy flattens a matrix (row-major)."""
    pibar = pi_mean.reshape(pi.shape)
    return pibar @ Sgam @ pibar.T


def _cond_cov_general(model: Model, u: Gaussian, v: Gaussian, transform: Transform) -> np.ndarray:
    cm = compiled(model)
    nu, nv = model.n_u, model.n_v
    # Nested rule: the inner transform over u at each outer point of v (one batch).
    inner = transform.nested_inner()
    V, w = transform.outer_rule(v.mean, v.cov)
    J = V.shape[0]
    means = np.hstack([np.tile(u.mean, (J, 1)), V])
    covs = np.zeros((J, nu + nv, nu + nv))
    covs[:, :nu, :nu] = u.cov
    cond_means = inner.moments(cm, means, covs).mean  # E[g | v_j]
    m = w @ cond_means
    R = cond_means - m
    return np.einsum("j,ji,jk->ik", w, R, R)


def _sc_nested(st: Stats, var_sum: np.ndarray) -> np.ndarray:
    """Σ_c from the statistics of the inner means and the sum of the inner covariances."""
    mean_inner_cov = var_sum / st.n
    # Cov of the inner sample means overstates Cov(E[g|v]) by E[Cov(g|v)]/MC_INNER.
    return st.cov - mean_inner_cov / MC_INNER


def _cond_cov_mc(model: Model, u: Gaussian, v: Gaussian | None, tr: Transform,
                 executor: Any = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Σ_c by a stochastic transform, and its value with each replicate left out, shape
    (G, n_y, n_y), or ``None`` when Σ_c is a closed form (no sampling error).

    The leave-one-out values let the jackknife of the MoN see the error of Σ_c as well
    as that of the moments (replicate i is left out of both).  Each is the total with one
    replicate taken out (:func:`~symmon.transforms.montecarlo.leave_one_out`): O(G) in all.
    """
    exact = model.n_v == 0 or model.structure == "additive" or (
        model.structure == "multiplicative" and model.pi.shape[1] == 0)
    if exact:
        return _cond_cov(model, u, v, tr), None
    if model.structure == "multiplicative":
        pi, n_pi, n_gam = model.pi, len(model.pi), len(model.gamma)
        gp = tr.replicate_stats(compile_model(list(pi), list(model.inputs)), u.mean, u.cov, executor=executor)
        gg = tr.replicate_stats(compile_model(list(model.gamma), list(model.noise)), v.mean, v.cov, executor=executor)

        def sc(sp_: Stats, sg: Stats) -> np.ndarray:
            return _pi_sgam_pi(pi, moments_of(sp_, n_pi, model.n_u)[0], moments_of(sg, n_gam, model.n_v)[1])

        tp, tg = merge_all(gp), merge_all(gg)
        loo = [sc(a, b) for a, b in zip(leave_one_out(gp, tp), leave_one_out(gg, tg))]
        return sc(tp, tg), np.array(loo)
    nested = tr.nested_stats(compiled(model), u.mean, u.cov, v.mean, v.cov, executor)
    stats = [g[0] for g in nested]
    total, var_sum = merge_all(stats), sum(g[1] for g in nested)
    loo = [_sc_nested(s, var_sum - g[1]) for s, g in zip(leave_one_out(stats, total), nested)]
    return _sc_nested(total, var_sum), np.array(loo)


# --------------------------------------------------------------------------- public API
def nonlinearity(model: Model, u: Gaussian, v: Gaussian | None = None, weight="full",
                 transform: Transform | None = None, executor: Any = None) -> NonlinearityMeasure:
    """The measure of nonlinearity of y = g(u, v).

    Parameters
    ----------
    model : Model
    u : Gaussian
    v : Gaussian, optional
        Required when the model has noise symbols.
    weight : {"full", "diag", "liu-li", "liu-li-raw"}, ndarray or weights.GeneralWeight
        ``"full"``: W = Σ_gg⁻¹/n_y (43); ``"diag"``: W = diag(diag Σ_gg)⁻¹/n_y (42);
        ``"liu-li"``: W = I/tr Σ_gg, the normalised MoN (8); ``"liu-li-raw"``: W = I, the
        raw MSE MoN (6) (it has units); a matrix W̄ in base units, checked against the
        set (41); or :func:`symmon.weights.general`.  The first two and the last two
        options are unitless and lie in [0, 1].
    transform : Transform, default ``TT2()``
        TT1 gives 0 by construction (see the module notes).
    executor : Executor, optional
        Where a stochastic transform's replicates run (:func:`symmon.propagate`).

    Returns
    -------
    NonlinearityMeasure

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> round(float(sm.nonlinearity(sm.Model([x], [x**2]), sm.Gaussian([0.0], [[1.0]]))), 12)
    1.0
    """
    tr = transform if transform is not None else TT2()
    m = propagate(model, u, v, tr, executor)
    stderr = None
    if tr.stochastic:
        Sc, Sc_loo = _cond_cov_mc(model, u, v, tr, executor)
        stderr = _mc_stderr(m, model, weight, Sc, Sc_loo)
    else:
        Sc = _cond_cov(model, u, v, tr)
    try:
        parts = mon_from_moments(m.cov, m.cross_cov, m.input_cov, weight, Sc, m.mean)
    except NonFiniteError as exc:
        raise NonFiniteError(f"{tr!r}: {exc}") from None
    if stderr is not None and not np.isfinite(stderr):
        raise NonFiniteError(f"{tr!r}: the standard error of the MoN is {stderr}")
    sq = parts["squared"]
    return NonlinearityMeasure(
        value=float(np.sqrt(max(sq, 0.0))), squared=sq, J_Ab=parts["J_Ab"], J_n=parts["J_n"],
        weight=parts["W"], weight_name=parts["label"], transform=tr, structure=model.structure,
        moments=m, residual_cov=parts["D"], stderr=stderr, notes=parts["notes"],
    )


def _mc_stderr(m: JointMoments, model: Model, weight, Sc: np.ndarray, Sc_loo: np.ndarray | None) -> float:
    """Jackknife standard error of the MoN: replicate i is left out of the moments and of
    Σ_c (``Sc_loo``; ``None``: Σ_c has no sampling error)."""
    ny, nu = model.n_y, model.n_u
    nw = model.n_u + model.n_v
    if Sc_loo is None:
        Sc_loo = np.repeat(Sc[None], len(m.replicates), axis=0)

    def values(loo: Stats) -> np.ndarray:
        _, cyy, cyw, cww = moments_of(loo, ny, nw, sorted(model.angle_outputs))
        return np.array([np.sqrt(max(mon_from_moments(cyy[i], cyw[i, :, :nu], cww[i, :nu, :nu], weight, S)["squared"], 0.0))
                         for i, S in enumerate(Sc_loo)])

    return float(jackknife(m.replicates, values))


def compare(model: Model, u: Gaussian, v: Gaussian | None = None, weight="full",
            transforms: Sequence[Transform] | None = None) -> list[dict]:
    """The MoN by every transform, as rows of a table.

    Returns
    -------
    list of dict
        Keys ``transform``, ``value``, ``stderr`` (Monte Carlo only) and ``evaluations``.
    """
    if transforms is None:
        transforms = compare_set()
    rows = []
    for t in transforms:
        res = nonlinearity(model, u, v, weight, t)
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

