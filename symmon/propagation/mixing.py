"""Moments of y = g(u, v) for a Gaussian-mixture u and/or v: the exact mixing of the
moments of each pair of components, computed in one batch.

With u ~ Σ_k w_k N(μ_k, P_k) and v ~ Σ_l ω_l N(ν_l, R_l) independent, w = [u; v] is the
mixture Σ_{k,l} w_k ω_l N([μ_k; ν_l], blkdiag(P_k, R_l)): component j = (k, l) with weight
π_j = w_k ω_l and mean μ_j^w.  If a transform gives, for component j, m_j = E_j y,
P_j = Cov_j y and C_j = Cov_j(y, w), then by the laws of total expectation and covariance

    E y        = Σ_j π_j m_j =: m,
    Cov y      = Σ_j π_j (P_j + (m_j − m)(m_j − m)ᵀ),
    Cov(y, w)  = Σ_j π_j (C_j + (m_j − m)(μ_j^w − μ^w)ᵀ),

whose u- and v-blocks are Cov(y, u) and Cov(y, v).  These identities are exact: the
mixture's moments carry only the error of the per-component rule, so a linear model has
exact moments under every transform (``derivations/mixtures.py`` checks the identities
symbolically).  All components of all inputs go through the rule's
batched :meth:`~symmon.transforms.base.Transform.moments` in one call.

An angle output's component means, and a declared angle input's (``Model(...,
angles=[θ])``), are moved to within π of the heaviest component's mean
(:func:`~symmon.core.angles.unwrap_near`) before they are mixed, and the mixed mean is
wrapped to (−π, π]: the mixture's spread about its mean, not about the cut.  Components of
a bearing at +3.0 and −3.0 rad are 0.28 rad apart, not 6 (a linear average would put the
mixture's mean at 0 and its variance near 9, and the MoN's affine fit across the cut).
The component moments themselves need no change: g is 2π-periodic in an angle input.

For a stochastic rule the standard errors come from the delete-one-group jackknife
(:func:`~symmon.transforms.stats.jackknife_se`): group g is left out of every component at
once, the leave-one-out moments are mixed, and their spread is the error bar.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..core.angles import unwrap_near, wrap_components
from ..core.gaussian import Gaussian
from ..core.mixture import GaussianMixture
from ..core.model import Model
from ..errors import ArgumentTypeError, ShapeError
from ..transforms.base import Moments
from ..transforms.stats import jackknife_se, leave_one_out_stack, moments_of

__all__ = ["ComponentBatch", "component_batch", "mix", "mix_batch", "mixed_leave_one_out", "mixed_error", "mixed_input_mean",
           "is_mixture", "parts"]


def is_mixture(d: Any) -> bool:
    """True for a :class:`~symmon.core.mixture.GaussianMixture`."""
    return isinstance(d, GaussianMixture)


def parts(d: Any, name: str, dim: int, what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weights (K,), means (K, dim) and covariances (K, dim, dim) of a Gaussian (K = 1) or
    a mixture, checked against the model's dimension ``dim`` of ``what``."""
    if isinstance(d, Gaussian):
        w, M, P = np.ones(1), d.mean[None], d.cov[None]
    elif isinstance(d, GaussianMixture):
        w, M, P = d.weights, d.means, d.covs
    else:
        raise ArgumentTypeError(f"{name} must be a symmon.Gaussian or GaussianMixture, got {type(d).__name__}")
    if M.shape[1] != dim:
        raise ShapeError(f"{name} has dimension {M.shape[1]} but the model has {dim} {what}")
    return w, M, P


@dataclass(frozen=True)
class ComponentBatch:
    """The components of w = [u; v] of several inputs, in one batch.

    Attributes
    ----------
    weights : ndarray (J,)
        π_j = w_k ω_l; within each input they sum to 1.
    means : ndarray (J, n_w)
    covs : ndarray (J, n_w, n_w)
        Block-diagonal: u and v are independent.
    starts : ndarray (n_items,)
        Index of the first component of each input (the components of an input are
        consecutive).
    input_angles : tuple of int
        The components of w that are angles (the model's angle inputs): mixed on the
        circle.
    """

    weights: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    starts: np.ndarray
    input_angles: tuple[int, ...] = ()

    @property
    def owner(self) -> np.ndarray:
        """For each component, the index of its input."""
        counts = np.diff(np.append(self.starts, self.weights.shape[0]))
        return np.repeat(np.arange(self.starts.shape[0]), counts)


def component_batch(model: Model, us: Sequence[Any], vs: Sequence[Any] | None) -> ComponentBatch:
    """The batch of components of w = [u_i; v_i] for each input i: the product of the
    components of u_i and of v_i (``vs`` is ``None`` for a model without noise)."""
    n_u, n_v = model.n_u, model.n_v
    W, M, P, starts, J = [], [], [], [], 0
    for i, u in enumerate(us):
        wu, Mu, Pu = parts(u, "u" if len(us) == 1 else f"u[{i}]", n_u, "inputs")
        if vs is None:
            w, Mw, Pw = wu, Mu, Pu
        else:
            wv, Mv, Pv = parts(vs[i], "v" if len(us) == 1 else f"v[{i}]", n_v, "noise symbols")
            Ku, Kv = wu.size, wv.size
            w = np.outer(wu, wv).ravel()  # j = k·Kv + l
            Mw = np.hstack([np.repeat(Mu, Kv, axis=0), np.tile(Mv, (Ku, 1))])
            Pw = np.zeros((Ku * Kv, n_u + n_v, n_u + n_v))
            Pw[:, :n_u, :n_u] = np.repeat(Pu, Kv, axis=0)
            Pw[:, n_u:, n_u:] = np.tile(Pv, (Ku, 1, 1))
        starts.append(J)
        J += w.size
        W.append(w), M.append(Mw), P.append(Pw)
    return ComponentBatch(np.concatenate(W), np.concatenate(M), np.concatenate(P), np.array(starts, dtype=np.intp),
                          tuple(sorted(model.angle_inputs)))


def _expand(pi: np.ndarray, x: np.ndarray) -> np.ndarray:
    return pi.reshape(pi.shape + (1,) * (x.ndim - 1)) * x


def _on_branch(pi: np.ndarray, starts: np.ndarray, x: np.ndarray, idx: Sequence[int]) -> np.ndarray:
    """``x`` (J, ...) with its angle components ``idx`` moved to within π of those of the
    heaviest component of the same input: one branch per input, so that a linear
    mixing is the mixing on the circle."""
    if not len(idx):
        return x
    ends = np.append(starts[1:], pi.size)
    heaviest = np.array([s + int(np.argmax(pi[s:e])) for s, e in zip(starts, ends)])
    owner = np.repeat(np.arange(starts.size), ends - starts)
    return unwrap_near(x, x[heaviest][owner], list(idx))


def mixed_input_mean(cb: ComponentBatch) -> np.ndarray:
    """The mean of w of each input (n_items, n_w): Σ_j π_j μ_j^w, with the angle inputs'
    component means on one branch and the result wrapped to (−π, π]."""
    mu = _on_branch(cb.weights, cb.starts, cb.means, cb.input_angles)
    return wrap_components(np.add.reduceat(_expand(cb.weights, mu), cb.starts, axis=0), cb.input_angles)


def mix(pi: np.ndarray, starts: np.ndarray, m: np.ndarray, P: np.ndarray, C: np.ndarray, mu: np.ndarray,
        Pw: np.ndarray, angles: Sequence[int] = (), input_angles: Sequence[int] = ()
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The mixed moments of each input from the moments of its components (the module's
    identities), centred on the mixed means so that no digits are lost to |m| ≫ σ.

    Parameters
    ----------
    pi : (J,) component weights, summing to 1 within each input
    starts : (n_items,) first component of each input
    m, P, C : (J, ..., n_y), (J, ..., n_y, n_y), (J, ..., n_y, n_w)
        E_j y, Cov_j y and Cov_j(y, w); any axes between the first and the last ones are
        carried along (the jackknife's G leave-one-out sets).
    mu, Pw : (J, n_w), (J, n_w, n_w)
        The component means and covariances of w.
    angles : sequence of int
        The angle outputs.
    input_angles : sequence of int
        The components of w that are angles: their component means are put on one branch
        before Cov w and Cov(y, w) are formed.

    Returns
    -------
    mean (n_items, ..., n_y), cov, cross_cov, input_cov
    """
    owner = np.repeat(np.arange(starts.size), np.diff(np.append(starts, pi.size)))
    A = list(angles)
    # The heaviest component of each input is the reference of its angles.
    m = _on_branch(pi, starts, m, A)
    mu = _on_branch(pi, starts, mu, input_angles)
    mean = np.add.reduceat(_expand(pi, m), starts, axis=0)
    mu_bar = np.add.reduceat(_expand(pi, mu), starts, axis=0)
    d = m - mean[owner]
    e = mu - mu_bar[owner]
    e_b = e.reshape((e.shape[0],) + (1,) * (m.ndim - 2) + e.shape[1:])  # over the carried axes
    ee = e_b[..., :, None] * e_b[..., None, :]
    cov = np.add.reduceat(_expand(pi, P + d[..., :, None] * d[..., None, :]), starts, axis=0)
    cross = np.add.reduceat(_expand(pi, C + d[..., :, None] * e_b[..., None, :]), starts, axis=0)
    in_cov = np.add.reduceat(_expand(pi, Pw + ee), starts, axis=0)
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    return wrap_components(mean, A), cov, cross, 0.5 * (in_cov + np.swapaxes(in_cov, -1, -2))


def mixed_leave_one_out(b: Moments, cb: ComponentBatch, n_y: int, angles: Sequence[int]
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The mixed moments with replicate g left out of every component, for each g: arrays
    with the axis G second, (n_items, G, ...), for the jackknife."""
    n_w = cb.means.shape[1]
    loo = [moments_of(leave_one_out_stack(reps), n_y, n_w, sorted(angles)) for reps in b.replicates]
    G = {r[0].shape[0] for r in loo}
    if len(G) != 1:
        raise ShapeError(f"the components have different numbers of replicates: {sorted(G)}")
    m, P, C, Pw = (np.stack([r[i] for r in loo]) for i in range(4))  # (J, G, ...)
    # Pw: each component's sample Cov w, as JointMoments.input_cov holds it for Monte Carlo.
    return mix(cb.weights, cb.starts, m, P, C, cb.means, Pw, angles, cb.input_angles)


def mix_batch(b: Moments, cb: ComponentBatch, angles: Sequence[int]) -> Moments:
    """The moments of each input (unsplit: ``cross_cov`` is Cov(y, w)) from the batch
    result ``b`` of its components; for a stochastic rule with standard errors by the
    jackknife over its replicates."""
    Pw = cb.covs if b.input_cov is None else b.input_cov
    mean, cov, cross, in_cov = mix(cb.weights, cb.starts, b.mean, b.cov, b.cross_cov, cb.means, Pw, angles,
                                   cb.input_angles)
    stderr = None
    if b.replicates is not None:
        lm, lP, lC, _ = mixed_leave_one_out(b, cb, b.mean.shape[1], angles)
        stderr = {k: jackknife_se(np.moveaxis(x, 1, 0))
                  for k, x in (("mean", lm), ("cov", lP), ("cross_cov", lC))}
    counts = np.diff(np.append(cb.starts, cb.weights.size))
    error = None if b.error is None else mixed_error(b, cb, mean, angles)
    return Moments(mean=mean, cov=cov, cross_cov=cross, input_cov=in_cov, stderr=stderr, error=error,
                   evaluations=b.evaluations, details={"components": counts.tolist(), "input_mean": mixed_input_mean(cb)})


def mixed_error(b: Moments, cb: ComponentBatch, mean: np.ndarray, angles: Sequence[int]) -> dict:
    """A first-order bound of the error of the mixed moments from the components' bounds
    ``b.error`` (Gauss–Hermite's two-order estimate).

    With |δm_j| ≤ ε_j, the mixed mean errs by at most ε = Σ_j π_j ε_j, each deviation
    d_j = m_j − m by at most ε_j + ε, so (to first order in the errors)
    |δ Cov y| ≤ Σ_j π_j (|δP_j| + |δd_j||d_j|ᵀ + |d_j||δd_j|ᵀ) and
    |δ Cov(y, w)| ≤ Σ_j π_j (|δC_j| + |δd_j||μ_j^w − μ^w|ᵀ), entrywise.
    """
    pi, starts, owner = cb.weights, cb.starts, cb.owner
    m = unwrap_near(b.mean, mean[owner], list(angles))
    d = np.abs(m - mean[owner])
    mu = _on_branch(pi, starts, cb.means, cb.input_angles)
    e = np.abs(mu - np.add.reduceat(_expand(pi, mu), starts, axis=0)[owner])
    eps_m = np.add.reduceat(_expand(pi, b.error["mean"]), starts, axis=0)
    dd = b.error["mean"] + eps_m[owner]
    cov = np.add.reduceat(_expand(pi, b.error["cov"] + dd[:, :, None] * d[:, None, :] + d[:, :, None] * dd[:, None, :]),
                          starts, axis=0)
    cross = np.add.reduceat(_expand(pi, b.error["cross_cov"] + dd[:, :, None] * e[:, None, :]), starts, axis=0)
    return {"mean": eps_m, "cov": cov, "cross_cov": cross}
