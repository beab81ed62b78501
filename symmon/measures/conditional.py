"""Σ_c = Cov_v(E[g | v]): the part of Cov g that the noise explains, for each noise structure.

Σ_c is 0 without noise, B Σ_vv Bᵀ for additive noise g = f(u) + B v (29), and
π̄ Σ_γγ π̄ᵀ for multiplicative noise g = f(u) + π(u)γ(v) (28), with π̄ = E π(u).  For
general noise the minimising n of (23) is n(v) = E[g | v] − E g (docs/guide/nonlinearity.md;
checked in ``derivations/general_noise.py``), and Σ_c is a nested integral: the transform's
outer rule over v (:meth:`~symmon.transforms.base.Transform.outer_rule`), its inner rule
over u (:meth:`~symmon.transforms.base.Transform.nested_inner`), or for a stochastic
transform its nested replicates (:meth:`~symmon.transforms.base.Transform.nested_stats`)
with their leave-one-out values for the jackknife.

References
----------
O. Straka, J. Havlík, "Design of unitless normalized measure of nonlinearity for state
estimation", FUSION 2024. arXiv:2410.13539
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import sympy as sp

from ..compile.compiled import compile_model
from ..core.gaussian import Gaussian
from ..core.model import Model
from ..compile import compiled
from ..transforms import Transform
from ..transforms.montecarlo import MC_INNER
from ..transforms.stats import Stats, leave_one_out, merge_all, moments_of

__all__ = ["conditional_cov", "conditional_cov_replicates"]


def _aux_moments(exprs: Sequence[sp.Expr], syms: Sequence[sp.Symbol], dist: Gaussian, transform: Transform):
    cm = compile_model(list(exprs), list(syms))
    b = transform.moments(cm, dist.mean[None], dist.cov[None])
    return b.mean[0], b.cov[0]


def conditional_cov(model: Model, u: Gaussian, v: Gaussian | None, transform: Transform) -> np.ndarray:
    """Σ_c of y = g(u, v) by a deterministic transform: (28), (29) or the nested rule."""
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
    return _general_cov(model, u, v, transform)


def _pi_sgam_pi(pi: sp.Matrix, pi_mean: np.ndarray, Sgam: np.ndarray) -> np.ndarray:
    """(28): Σ_c = π̄ Σ_γγ π̄ᵀ, from E π flattened as sympy flattens a matrix (row-major)."""
    pibar = pi_mean.reshape(pi.shape)
    return pibar @ Sgam @ pibar.T


def _general_cov(model: Model, u: Gaussian, v: Gaussian, transform: Transform) -> np.ndarray:
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


def conditional_cov_replicates(model: Model, u: Gaussian, v: Gaussian | None, tr: Transform,
                 executor: Any = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Σ_c by a stochastic transform, and its value with each replicate left out, shape
    (G, n_y, n_y), or ``None`` when Σ_c is a closed form (no sampling error).

    The leave-one-out values let the jackknife of the MoN see the error of Σ_c as well
    as that of the moments (replicate i is left out of both).  Each is the total with one
    replicate taken out (:func:`~symmon.transforms.stats.leave_one_out`): O(G) in all.
    """
    exact = model.n_v == 0 or model.structure == "additive" or (
        model.structure == "multiplicative" and model.pi.shape[1] == 0)
    if exact:
        return conditional_cov(model, u, v, tr), None
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

