"""Σ_c = Cov_v(E[g | v]): the part of Cov g that the noise explains, for each noise structure.

Σ_c is 0 without noise, B Σ_vv Bᵀ for additive noise g = f(u) + B v (29), and
π̄ Σ_γγ π̄ᵀ for multiplicative noise g = f(u) + π(u)γ(v) (28), with π̄ = E π(u).  For
general noise the minimising n of (23) is n(v) = E[g | v] − E g (docs/guide/nonlinearity.md;
checked in ``derivations/general_noise.py``), and Σ_c is a nested integral: the transform's
outer rule over v (:meth:`~symmon.transforms.base.Transform.outer_rule`), its inner rule
over u (:meth:`~symmon.transforms.base.Transform.nested_inner`), or for a stochastic
transform its nested replicates (:meth:`~symmon.transforms.base.Transform.nested_stats`)
with their leave-one-out values for the jackknife.

**Mixtures.**  For u ~ Σ_k w_k N(μ_k, P_k) and v ~ Σ_l ω_l N(ν_l, R_l), independent, the
conditional mean is the mixture of the components' conditional means, because
conditioning on v leaves the distribution of u unchanged:

    h(v) = E[g | v] = Σ_k w_k E_{u∼N(μ_k, P_k)}[g(u, v)],

and its covariance under the mixture of v follows from the law of total covariance over
the components of v:

    Σ_c = Cov_v h(v) = Σ_l ω_l [Cov_{N_l} h + (E_{N_l} h − E h)(E_{N_l} h − E h)ᵀ]
        = Σ_{l,j} ω_l a_lj (h(V_lj) − h̄)(h(V_lj) − h̄)ᵀ,   h̄ = Σ_{l,j} ω_l a_lj h(V_lj),

where V_lj, a_lj are the outer rule's points and weights over N(ν_l, R_l): the points of
all components of v, with the weights ω_l a_lj, are one rule for the mixture, and h at
each point is the mixture of K inner integrals, all in one batch.  The structured cases
are this formula evaluated in closed form: for additive noise h(v) = E f + B v gives
Σ_c = B Σ_vv Bᵀ (29) with Σ_vv the mixture's total covariance; for multiplicative noise
h(v) = E f + π̄ γ(v) with π̄ = Σ_k w_k E_k π gives Σ_c = π̄ Σ_γγ π̄ᵀ (28), Σ_γγ the
covariance of γ(v) under the mixture of v (the per-component moments of γ mixed by the
law of total covariance).  ``derivations/mixtures.py`` checks these identities symbolically.

References
----------
O. Straka, J. Havlík, "Design of unitless normalized measure of nonlinearity for state
estimation", FUSION 2024. arXiv:2410.13539
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import sympy as sp

from ..compile.compiled import compile_model, compiled
from ..core.gaussian import Gaussian
from ..core.mixture import Empirical, GaussianMixture, mixture_moments
from ..core.model import Model
from ..propagation.particles import group_means, jackknife_groups
from ..transforms.base import Transform
from ..transforms.montecarlo import MC_INNER
from ..transforms.stats import Stats, leave_one_out, merge_all, moments_of

__all__ = ["conditional_cov", "conditional_cov_replicates", "empirical_conditional_cov"]


def _aux_moments(exprs: Sequence[sp.Expr], syms: Sequence[sp.Symbol], dist: Gaussian | GaussianMixture,
                 transform: Transform):
    cm = compile_model(list(exprs), list(syms))
    if isinstance(dist, GaussianMixture):  # the components in one batch, mixed exactly
        b = transform.moments(cm, dist.means, dist.covs)
        return mixture_moments(dist.weights, b.mean, b.cov)
    b = transform.moments(cm, dist.mean[None], dist.cov[None])
    return b.mean[0], b.cov[0]


def conditional_cov(model: Model, u: Gaussian | GaussianMixture, v: Gaussian | GaussianMixture | None,
                    transform: Transform) -> np.ndarray:
    """Σ_c of y = g(u, v) by a deterministic transform: (28), (29) or the nested rule; for
    a mixture u or v, the mixed forms of the module notes."""
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
    if isinstance(u, GaussianMixture) or isinstance(v, GaussianMixture):
        return _general_cov_mixture(model, u, v, transform)
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
    cond_means = inner.expectation(cm, means, covs)  # E[g | v_j]: only the means are used
    m = w @ cond_means
    R = cond_means - m
    return np.einsum("j,ji,jk->ik", w, R, R)


def _components(d: Gaussian | GaussianMixture) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if isinstance(d, GaussianMixture):
        return d.weights, d.means, d.covs
    return np.ones(1), d.mean[None], d.cov[None]


def _general_cov_mixture(model: Model, u: Gaussian | GaussianMixture, v: Gaussian | GaussianMixture,
                         transform: Transform) -> np.ndarray:
    """Σ_c for general noise and a mixture u or v (module notes): the outer points of every
    component of v form one rule; at each, h is the mixture of the K inner integrals over
    the components of u, all K·J of them in one batch of the inner transform."""
    cm = compiled(model)
    nu, nv = model.n_u, model.n_v
    wu, Mu, Pu = _components(u)
    wv, Mv, Pv = _components(v)
    rules = [transform.outer_rule(m, P) for m, P in zip(Mv, Pv)]  # points only: no evaluation of g
    V = np.vstack([r[0] for r in rules])
    a = np.concatenate([wl * r[1] for wl, r in zip(wv, rules)])
    K, J = wu.size, V.shape[0]
    means = np.hstack([np.repeat(Mu, J, axis=0), np.tile(V, (K, 1))])  # row k·J + j
    covs = np.zeros((K * J, nu + nv, nu + nv))
    covs[:, :nu, :nu] = np.repeat(Pu, J, axis=0)
    cond = transform.nested_inner().expectation(cm, means, covs).reshape(K, J, model.n_y)
    h = np.einsum("k,kjy->jy", wu, cond)  # E[g | V_j] under the mixture of u
    R = h - a @ h
    return np.einsum("j,ji,jk->ik", a, R, R)


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



def _loo_ratio(sums: np.ndarray, wsum: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted means of all particles and of all but group g: (d,) and (G, d)."""
    tot, W = sums.sum(axis=0), wsum.sum()
    return tot / W, (tot - sums) / (W - wsum)[:, None]


def empirical_conditional_cov(model: Model, u: Empirical, v: Gaussian | GaussianMixture | None,
                              transform: Transform) -> tuple[np.ndarray, np.ndarray]:
    """Σ_c for particles u, and its value with each jackknife group left out (G, n_y, n_y).

    No noise: 0; additive: B Σ_vv Bᵀ (29), no sampling error; multiplicative: π̄ Σ_γγ π̄ᵀ
    (28) with π̄ = Σ_i w_i π(x_i) and Σ_γγ by the transform over v; general: the outer
    rule of the transform over (each component of) v, h(V_j) = Σ_i w_i g(x_i, V_j) at each
    point (module notes).  Groups are those of :func:`~symmon.propagation.particles.group_means`.
    """
    ny = model.n_y
    G = jackknife_groups(u)
    zero = np.zeros((ny, ny))
    if model.n_v == 0:
        return zero, np.repeat(zero[None], G, axis=0)
    if model.structure == "additive" or (model.structure == "multiplicative" and model.pi.shape[1] == 0):
        Sc = conditional_cov(model, u, v, transform)  # uses v only (u.cov is not read)
        return Sc, np.repeat(Sc[None], G, axis=0)
    if model.structure == "multiplicative":
        pi = model.pi
        cm = compile_model(list(pi), list(model.inputs))
        pbar, pbar_loo = _loo_ratio(*group_means(u, cm.eval_g))
        _, Sgam = _aux_moments(list(model.gamma), model.noise, v, transform)
        return _pi_sgam_pi(pi, pbar, Sgam), np.array([_pi_sgam_pi(pi, p, Sgam) for p in pbar_loo])
    cm = compiled(model)
    wv, Mv, Pv = _components(v)
    rules = [transform.outer_rule(m, P) for m, P in zip(Mv, Pv)]
    V = np.vstack([r[0] for r in rules])
    a = np.concatenate([wl * r[1] for wl, r in zip(wv, rules)])
    J = V.shape[0]

    def at_points(X: np.ndarray) -> np.ndarray:  # g(x_i, V_j) for every particle and point: (n, J·n_y)
        W = np.hstack([np.repeat(X, J, axis=0), np.tile(V, (X.shape[0], 1))])
        return cm.eval_g(W).reshape(X.shape[0], J * ny)

    h, h_loo = _loo_ratio(*group_means(u, at_points))

    def cov_of(hj: np.ndarray) -> np.ndarray:
        R = hj.reshape(J, ny) - a @ hj.reshape(J, ny)
        return np.einsum("j,ji,jk->ik", a, R, R)

    return cov_of(h), np.array([cov_of(x) for x in h_loo])

