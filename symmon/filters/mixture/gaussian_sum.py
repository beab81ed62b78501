"""The Gaussian-sum filter, its components split where the measure of nonlinearity says so.

The posterior is a mixture p(x_k | y_1:k) ≈ Σ_i w_i N(x; m_i, P_i) (Sorenson & Alspach 1971;
Alspach & Sorenson 1972).  Each component runs the compiled step of one Gaussian filter (the
EKF, UKF, CKF, ... of :class:`~symmon.NonlinearKalmanFilter`, :mod:`symmon.filters.gaussian.step`), and
its weight is multiplied by the likelihood of its innovation, w_i ← w_i N(ν_i; 0, S_i), then
renormalised; the log-likelihood of a step is log Σ_i w_i N(ν_i; 0, S_i) with the weights
before the update.

**Splitting by the measure of nonlinearity.**  A Gaussian filter is only as good as its
component is narrow compared with the curvature of the model.  Before the prediction (for f)
and before the update (for h), the unitless MoN of each component with the full weight
W^full = Σ_yy⁻¹/n_y (Straka & Havlík 2024, eqs. (25), (29), (43)),

    M² = tr(W (Σ_gg − Σ_c − Σ_gu Σ_uu⁻¹ Σ_ug)),  Σ_gg = Cov g + R,  Σ_c = R,

(for y = g(x) + e, e ~ N(0, R); Q for the dynamics) is computed with TT2 at the component
N(m_i, P_i): for TT2, Cov g = J P Jᵀ + D and Cov(g, x) = J P, so the residual is
D_il = ½ tr(H_i P H_l P), with no inverse of P.  One compiled call gives Cov g, D and the
Hessians H_i (for the direction below) of all components of all runs.  A component whose M exceeds
``split`` is replaced by m = 3 or 5 components from a tabulated split of N(0, 1)
(:data:`symmon.core.mixture.SPLITS`, computed by ``derivations/gaussian_split.py``): along a direction d with
P = S Sᵀ and d = S a, |a| = 1,

    m_j = m + μ_j d,   P_j = P − (1 − σ²) d dᵀ,   w_j = w · ω_j,

which keeps the mixture's mean and covariance exactly (Σ ω_j μ_j = 0, σ² + Σ ω_j μ_j² = 1).

**The direction.**  For a Gaussian input, the part of the output that the best affine fit
misses is, to second order, ½ tr(H_i P H_l P) (the TT2 form of the MoN's residual D); in
whitened coordinates (x = m + S z) and with the outputs whitened by W = CᵀC, it is
½ Σ_k ‖G_k‖²_F with G_k = Σ_i C_ki Sᵀ H_i S.  Splitting along a unit a scales the variance
along a by σ² and leaves the orthogonal complement, so the split that removes most of this
residual is along the a that maximises the rank-one share ½ Σ_k (aᵀ G_k a)²: for one output
the eigenvector of G_1 with the largest |eigenvalue| (exact), for several the best among the
leading eigenvectors of every G_k and the eigen-directions of P (the axes of the whitened
coordinates).  This is the eigen-direction of the curvature in the units of the component's
own spread: splitting along the largest eigen-direction of P alone would split a bearing's
range uncertainty even when the bearing is linear in it.  Exact ties (a bearing's Hessian
has eigenvalues ±λ, so an isotropic position spread has two equally curved directions) go
to the first eigenvalue and candidate (:data:`TIE`), not to the last bits of rounding; the
sign of d (an eigenvector's sign is the eigensolver's choice, and −d lists the children in
the opposite order) is fixed: its largest entry positive.  The directions and the splits of
all components are stacked NumPy calls (:func:`split_directions`, :func:`split_components`).

**What a split does to the MoN.**  Under a fixed weight (the parent's W, or Liu–Li's raw
W = I) and a quadratic g, every child is less nonlinear than its parent along *any*
direction: D(P) = ½ tr(H P H P) is monotone in the Loewner order and P_j ⪯ P.  Each child's
*own* normalised MoN (its W^full, which for one output is also the normalised Liu–Li weight)
is not lower in general, whatever the direction or the spread: a child moving to where g is
flatter has less output variance, of which the residual is a larger share (quadratic of the
tests: 0.73 for a child against 0.42 for the parent; no direction of 24 lowers every child's
MoN by 1 %).  For a bearing even the parent's weight does not suffice: the child nearest the
sensor, where the curvature grows as 1/r², is more nonlinear (1.38 × the parent's M²); what
holds is that the children's weighted mean MoN is lower.  Splitting again the children above
the threshold does not converge either (after 5 levels a chain of children toward the
sensor or the stationary point keeps a MoN of 0.64–0.70).  docs/filters.md has the numbers.

**Merging and pruning.**  After each update, components with weight below ``prune``, and
those of weight 0 whatever ``prune`` (a merge of two would divide by their total weight), are
dropped, and while a run has more than ``max_components``, the pair with the least cost is
merged into its moment-matched Gaussian (which keeps the mixture's mean and covariance):
Runnalls' (2007) upper bound on the Kullback–Leibler discrimination,
B = ½[(w_i + w_j) log det P_ij − w_i log det P_i − w_j log det P_j], or Salmond's (1990)
distance w_i w_j/(w_i + w_j) (m_i − m_j)ᵀ P⁻¹ (m_i − m_j) with P the mixture's covariance
(:mod:`symmon.filters.mixture.merge`: the pair costs once, then only those of the merged
component, in one C call for all runs of a bank).

**Merging back.**  Splitting follows the MoN up; with ``merge_back`` the filter follows it
down too.  After each update (and the pruning and merging above), a component is *calm* when
its MoN of f and of h, at the posterior component with the next step's parameters, are below
``split``/2 (a hysteresis: a component split at ``split`` is not merged back at the next
step's small wobble of its MoN), and pairs of calm components of a run are merged, the pair
of least Runnalls cost B_ij first, while that cost is below ``merge_back``
(:func:`~symmon.filters.mixture.merge.merge_below`; each merge moment-matched, so the
mixture's mean and covariance are kept).  On a linear stretch every component is calm and the
updates draw the components' means together, so the mixture falls back to one component;
``components`` reports the count per step.  Both paths below merge back alike (the compiled
recursion in C, the stepwise filter by :func:`~symmon.filters.mixture.merge.merge_below`;
the tests hold them to 1e-12 on a scalar model), and without ``merge_back`` the numbers are
those of before, bit for bit.

**Without splitting** the number of components never grows: the components are independent
Kalman filters and run as one bank through the compiled loop of
:class:`~symmon.NonlinearKalmanFilter` (all steps of all components of all runs in one C
call), their weights following from the per-step log-likelihoods.  **With splitting** all
steps of all runs are one C call too (:mod:`symmon.filters.mixture._kernel`: the compiled stages
below, the MoN's weight, the split decision, the directions by Jacobi eigen-decompositions,
the splits, pruning and the merge, a thread per share of the runs).  Without a compiler the
steps run in Python (:meth:`GaussianSumFilter._stepwise`),
each stage (the MoN with the Hessians, the prediction, the update, the merge) one compiled
call over all components of all runs, the directions and splits stacked NumPy: the same
results to rounding (the tests hold the two to 1e-10, with the same components and splits
per step).  A call waits for a running background build of that C rather than take the
stepwise filter meanwhile, so that its numbers do not depend on the build's timing (a cold
and a warm machine agree bit for bit).

References
----------
H. W. Sorenson, D. L. Alspach, "Recursive Bayesian estimation using Gaussian sums",
Automatica 7(4), 1971. doi:10.1016/0005-1098(71)90097-5
O. Straka, J. Havlík, "Design of unitless normalized measure of nonlinearity for state
estimation", FUSION 2024. arXiv:2410.13539
K. J. DeMars, R. H. Bishop, M. K. Jah, "Entropy-based approach for uncertainty propagation of
nonlinear dynamical systems", J. Guid. Control Dyn. 36(4), 2013 (splitting libraries).
K. Tuggle, R. Zanetti, "Automated splitting Gaussian mixture nonlinear measurement update",
J. Guid. Control Dyn. 41(3), 2018.
A. R. Runnalls, "Kullback–Leibler approach to Gaussian mixture reduction", IEEE Trans.
Aerosp. Electron. Syst. 43(3), 2007. doi:10.1109/TAES.2007.4383588
D. J. Salmond, "Mixture reduction algorithms for target tracking in clutter", Proc. SPIE
1305, 1990.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from typing import Any, ClassVar

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from ...compile.compiled import batched, compiled, compiled_with_params
from ...compile.ccache import has_compiler
from ...core.angles import wrap_angle
from ...core.gaussian import Gaussian
from ...core.checks import check_gaussian
from ...core.mixture import SPLITS, GaussianMixture, split_weights
from ...core.model import Model
from ...errors import ArgumentError, ArgumentTypeError, ShapeError, SymmonError, plain_repr
from ...transforms.base import Transform
from ...transforms.taylor import TT2
from ...transforms.unscented import UT
from ..names import filter_rule
from ..base import Filter
from ._kernel import SplitKernel, bank_weights, result_arrays
from ..gaussian.nonlinear import NonlinearKalmanFilter
from .merge import MERGE_RULES, merge_below, merge_components, merge_runs
from ..inputs import FilterCall
from ..results import KalmanResult, nees_of
from ..gaussian.step import (filterable, filter_params, predict_graph, select_params, step_kind, sym,
                   update_graph)

__all__ = ["GaussianSumFilter", "GaussianSumResult", "SPLITS", "split_component", "split_components",
           "split_direction", "split_directions", "merge_components", "component_mon", "MERGE_RULES", "TIE"]


def split_component(mean: ArrayLike, cov: ArrayLike, direction: ArrayLike, m: int = 3
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split N(mean, cov) along ``direction`` d into m components with the same mean and covariance.

    m_j = mean + μ_j d, P_j = cov − (1 − σ²) d dᵀ, weights ω_j (module notes); d must be
    S a for a square root S Sᵀ = cov and a unit a (so that every P_j is positive
    semi-definite), e.g. ``split_direction``'s.  :func:`split_components` is the same for a
    stack of components.

    Returns
    -------
    weights (m,), means (m, n), covs (m, n, n)
    """
    mean, cov, d = (np.asarray(a, dtype=float) for a in (mean, cov, direction))
    w, means, covs = split_components(mean[None], cov[None], d[None], m)
    return w, means[0], covs[0]


@lru_cache(maxsize=None)
def _split_table(m: int) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`~symmon.core.mixture.split_weights` of m, computed once (read-only arrays)."""
    if m not in SPLITS:
        raise ArgumentError(f"a split has {sorted(SPLITS)} components, got {plain_repr(m)}")
    w, mu, sigma = split_weights(m)
    w.flags.writeable = mu.flags.writeable = False
    return w, mu, sigma


def split_components(means: np.ndarray, covs: np.ndarray, directions: np.ndarray, m: int = 3
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`split_component` of N components at once: means (N, n), covs (N, n, n) and
    directions (N, n) give the weights ω (m,) and the children's means (N, m, n) and
    covariances (N, m, n, n)."""
    w, mu, sigma = _split_table(m)
    d = directions
    children = means[:, None, :] + mu[None, :, None] * d[:, None, :]
    P = covs - (1.0 - sigma**2) * (d[:, :, None] * d[:, None, :])
    P = 0.5 * (P + np.swapaxes(P, 1, 2))
    return w, children, np.broadcast_to(P[:, None], (len(P), m) + P.shape[1:]).copy()


def split_direction(cov: np.ndarray, hessians: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The direction d = S a to split N(·, cov) along, for Hessians H_i (n_y, n, n) of g at its
    mean and the MoN's weight W (n_y, n_y): the unit a maximising ½ Σ_k (aᵀ G_k a)²,
    G_k = Σ_i C_ki Sᵀ H_i S, W = CᵀC (module notes), among the leading eigenvectors of the
    G_k and the axes; S from the eigen-decomposition of cov (ties within :data:`TIE`: the first
    eigenvalue, the first candidate).  :func:`split_directions` is the same for a stack of
    components."""
    cov, hessians, weight = (np.asarray(a, dtype=float) for a in (cov, hessians, weight))
    return split_directions(cov[None], hessians[None], weight[None])[0]


#: Relative margin within which two candidate directions (or eigenvalues) count as tied: a
#: bearing's Hessian has eigenvalues ±λ (atan2 is harmonic), so with an isotropic position
#: spread its two curvature directions are exactly as good, and rounding alone would pick one.
TIE = 1e-9


def _first_max(a: np.ndarray, axis: int) -> np.ndarray:
    """The index of the first entry of the non-negative ``a`` along ``axis`` within :data:`TIE`
    of the largest: a tie is broken by the order, not by the last bits."""
    return np.argmax(a >= (1.0 - TIE) * a.max(axis=axis, keepdims=True), axis=axis)


def split_directions(covs: np.ndarray, hessians: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """:func:`split_direction` of N components at once, every step one stacked NumPy call:
    covs (N, n, n), hessians (N, n_y, n, n), weights (N, n_y, n_y) ↦ directions (N, n)."""
    N, n = covs.shape[:2]
    lam, V = np.linalg.eigh(covs)
    S = V * np.sqrt(np.maximum(lam, 0.0))[:, None, :]
    SHS = np.swapaxes(S, 1, 2)[:, None] @ hessians @ S[:, None]
    if weights.shape[1] == 1:
        # One output: W = C² > 0 and the leading eigenvector a of G_1 maximises (aᵀ G_1 a)²
        # exactly, so no axis can beat it (the general path below picks it too).
        G = np.sqrt(np.maximum(weights[:, 0, 0], 0.0))[:, None, None] * SHS[:, 0]
        gl, gv = np.linalg.eigh(0.5 * (G + np.swapaxes(G, 1, 2)))
        lead = gv[np.arange(N), :, _first_max(np.abs(gl), axis=1)]
        return _signed((S @ lead[:, :, None])[:, :, 0])
    wl, wv = np.linalg.eigh(0.5 * (weights + np.swapaxes(weights, 1, 2)))
    C = np.swapaxes(wv * np.sqrt(np.clip(wl, 0.0, None))[:, None, :], 1, 2)
    # G_k = Σ_i C_ki Sᵀ H_i S for every component: (N, n_y, n, n).
    G = np.einsum("Nki,Nibd->Nkbd", C, SHS)
    G = 0.5 * (G + np.swapaxes(G, 2, 3))
    gl, gv = np.linalg.eigh(G)
    top = _first_max(np.abs(gl), axis=2)  # (N, n_y)
    lead = np.take_along_axis(gv, top[:, :, None, None], axis=3)[..., 0]  # (N, n_y, n): leading eigenvectors
    cands = np.concatenate([lead, np.broadcast_to(np.eye(n), (N, n, n))], axis=1)  # (N, n_y + n, n)
    quad = np.einsum("Nca,Nkab,Ncb->Nck", cands, G, cands)
    best = _first_max((quad**2).sum(axis=2), axis=1)
    return _signed(np.einsum("Nab,Nb->Na", S, cands[np.arange(N), best]))


def _signed(d: np.ndarray) -> np.ndarray:
    """The directions d (N, n) with their largest entry (the first within :data:`TIE`) positive:
    an eigenvector's sign is LAPACK's choice, and −d orders the children of a split the other
    way round (the merges that follow take the first of tied pairs), so the sign is fixed here
    as in the compiled recursion (:mod:`symmon.filters.mixture._kernel`)."""
    lead = d[np.arange(len(d)), _first_max(np.abs(d), axis=1)]
    return np.where((lead < 0)[:, None], -d, d)


def _corr_inverse(A: np.ndarray) -> np.ndarray:
    """Batched inverses of positive definite A (N, d, d), through the correlation matrices
    (so that a state in mm beside one in rad is not called singular); pseudo-inverse on the
    correlation scale where one is singular."""
    r = 1.0 / np.sqrt(np.einsum("nii->ni", A))
    if A.shape[1] == 1:  # a variance: its correlation matrix is [1]
        return r[:, :, None] * r[:, None, :]
    corr = r[:, :, None] * A * r[:, None, :]
    return r[:, :, None] * np.linalg.pinv(corr, rcond=1e-12, hermitian=True) * r[:, None, :]


def component_mon(cov_g: np.ndarray, residual: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unitless MoN M (N,) of y = g(x) + e, e ~ N(0, noise), at N components, and their
    weights W = Σ_yy⁻¹/n_y (N, n_y, n_y), from Cov g (N, n_y, n_y) and the residual
    D = Σ_gg − Σ_c − Σ_gu Σ_uu⁻¹ Σ_ug (N, n_y, n_y) of each component.

    M² = tr(W D) with Σ_gg = Cov g + noise, Σ_c = noise (eqs. (25), (29), (43) of Straka &
    Havlík 2024): the batched form of :func:`symmon.measures.formula.mon_from_moments`.  The
    filter takes D from TT2, D_ij = ½ tr(H_i P H_j P) (no inverse of P, and none of the
    cancellation of Cov g − J P Jᵀ), in the same compiled call as Cov g.
    """
    n_y = cov_g.shape[-1]
    W = _corr_inverse(cov_g + noise) / n_y
    M2 = np.einsum("nij,nji->n", W, residual)
    return np.sqrt(np.maximum(M2, 0.0)), W


def _rows(z, shapes: list[tuple[int, int]]) -> list:
    """The packed row z cut into matrices of the given shapes (column-major, as CasADi's)."""
    out, a = [], 0
    for r, c in shapes:
        out.append(ca.reshape(z[a:a + r * c], r, c))
        a += r * c
    return out


def _model_cm(model: Model):
    """The compiled model with its parameters as inputs after [u; v] (none: the plain one)."""
    return compiled_with_params(model) if model.n_p else compiled(model)


class _ComponentSteps:
    """The three compiled batches of the stepwise filter, each a function of one packed row:
    the prediction (x, P, Q, p) ↦ (x⁻, P⁻); the update (x⁻, P⁻, y, R, mask, p) ↦ (x, P,
    log N(ν; 0, S)); and the TT2 moments of f and of h for the MoN, (x, P, p) ↦ (Cov g, Cov(g, x))."""

    def __init__(self, f: Model, h: Model, transform: Transform, angle_states: frozenset[int]) -> None:
        n, n_y = f.n_u, h.n_y
        names = filter_params(f, h)
        self.n_p = n_p = len(names)
        key = repr((f.key, h.key, transform, sorted(angle_states), sorted(h.angle_outputs)))
        tag = "sm_gsf_" + hashlib.sha1(key.encode()).hexdigest()[:12]
        kind, chol = step_kind(f, h, transform)
        z = kind.sym("z", n + n * n + n * n + n_p)
        x, P, Q, p = _rows(z, [(n, 1), (n, n), (n, n), (n_p, 1)])
        xp, Pp = predict_graph(f, transform, angle_states, x, P, Q, chol, select_params(f, names, p))
        fp = ca.Function(tag + "_p", [z], [ca.densify(xp), ca.densify(Pp)], {"cse": True})
        self.predict = batched(fp)
        z = kind.sym("z", n + n * n + n_y + n_y * n_y + n_y + n_p)
        x, P, y, R, mask, p = _rows(z, [(n, 1), (n, n), (n_y, 1), (n_y, n_y), (n_y, 1), (n_p, 1)])
        xn, Pn, _, _, ll, _ = update_graph(h, transform, angle_states, x, P, y, R, chol, mask,
                                           select_params(h, names, p))
        fu = ca.Function(tag + "_u", [z], [ca.densify(a) for a in (xn, Pn, ll)], {"cse": True})
        self.update = batched(fu)
        self.mon, fm = {}, {}
        mon_kind = step_kind(f, h, TT2())[0]
        for which, mdl in (("f", f), ("h", h)):
            z = mon_kind.sym("z", n + n * n + n_p)
            x, P, p = _rows(z, [(n, 1), (n, n), (n_p, 1)])
            fm[which] = ca.Function(f"{tag}_m{which}", [z], _mon_graph(mdl, x, P, select_params(mdl, names, p)),
                                    {"cse": True})
            self.mon[which] = batched(fm[which])
        self._graphs = (fp, fu, fm["f"], fm["h"], n, n_y, n_p, tag + "_run")
        self._kernel: SplitKernel | None = None
        self._kernel_lock = threading.Lock()

    def kernel(self) -> SplitKernel | None:
        """The compiled recursion of these steps (:mod:`symmon.filters.mixture._kernel`), built on
        first use under the compile policy; None when compiled C is not wanted or there is no compiler."""
        if not has_compiler():
            return None
        with self._kernel_lock:
            if self._kernel is None:
                self._kernel = SplitKernel(*self._graphs)
            return self._kernel


def _mon_graph(model: Model, x, P, p) -> list:
    """(Cov g, D, the Hessians H_i) of g = ``model`` (additive noise) at N(x, P) by TT2: the
    MoN's moments and the split direction's curvature of one component, one graph.

    With J and H_i the Jacobian and Hessians in the state at x (p fixed), TT2 gives
    Cov g = J P Jᵀ + D and Cov(g, x) = J P, so the MoN's residual
    D = Σ_gg − Σ_c − Σ_gu Σ_uu⁻¹ Σ_ug = Cov g − J P Jᵀ (Straka & Havlík 2024, eqs. (25), (29))
    is D_ij = ½ tr(H_i P H_j P) (Gustafsson & Hendeby 2012): no inverse of P, and none of the
    cancellation of the difference when the MoN is small."""
    cm = _model_cm(model)
    n = x.shape[0]
    w = ca.vertcat(x, p) if model.n_p else x
    J, *H = ca.Function("jh", [cm.w_sx], [cm.J_sx, *cm.H_sx])(w)
    J = J[:, :n]
    H = [ca.densify(a[:n, :n]) for a in H]
    HP = [ca.mtimes(a, P) for a in H]
    F = ca.horzcat(*[ca.vec(a) for a in HP])
    Ft = ca.horzcat(*[ca.vec(a.T) for a in HP])
    D = 0.5 * ca.mtimes(F.T, Ft)  # ⟨H_i P, (H_j P)ᵀ⟩ = tr(H_i P H_j P)
    D = 0.5 * (D + D.T)
    cov = ca.mtimes(ca.mtimes(J, P), J.T) + D
    return [ca.densify(sym(cov)), ca.densify(D), ca.vertcat(*[ca.vec(a) for a in H])]


_steps: dict[tuple, _ComponentSteps] = {}
_steps_lock = threading.Lock()


def _component_steps(f: Model, h: Model, transform: Transform, angle_states: frozenset[int]) -> _ComponentSteps:
    key = (f, h, transform, angle_states)
    with _steps_lock:
        if key not in _steps:
            _steps[key] = _ComponentSteps(f, h, transform, angle_states)
        return _steps[key]


@dataclass(frozen=True, eq=False)
class GaussianSumResult(KalmanResult):
    """The result of :meth:`GaussianSumFilter.filter`: a :class:`KalmanResult` whose ``x`` and
    ``P`` are the moment-matched mean and covariance of each step's mixture (so NEES, ANEES,
    ``estimate`` and ``log_likelihood`` work as for every filter), with the mixtures.

    Attributes
    ----------
    weights : ndarray, shape (K, M) or (R, K, M), or None
        The components' weights at each step, zero beyond ``components`` (M: the most
        components of any step).
    means : ndarray, shape (K, M, n) or (R, K, M, n), or None
    covs : ndarray, shape (K, M, n, n) or (R, K, M, n, n), or None
    components : ndarray of int, shape (K,) or (R, K)
        Components after each step (after merging and pruning).
    splits : ndarray of int, shape (K,) or (R, K)
        Components split during each step (before its prediction and its update).
    """

    weights: np.ndarray | None = None
    means: np.ndarray | None = None
    covs: np.ndarray | None = None
    components: np.ndarray | None = None
    splits: np.ndarray | None = None

    component_fields: ClassVar[tuple[str, ...]] = ("weights", "means", "covs")

    def mixture(self, k: int, run: int | None = None) -> GaussianMixture:
        """The posterior mixture at step k (0-based), of run ``run`` for a bank."""
        if (run is None) != (self.runs is None):
            raise ShapeError("give run= for a bank of runs, and only then")
        self._need("weights", "means", "covs")
        sel = (k,) if run is None else (run, k)
        c = int(self.components[sel])
        return GaussianMixture(self.weights[sel][:c], self.means[sel][:c], self.covs[sel][:c], psd="clip")

    def __repr__(self) -> str:
        runs = "" if self.runs is None else f"runs={self.runs}, "
        return (f"GaussianSumResult({self.method}, {runs}steps={self.steps}, n={self.n}, "
                f"components={int(self.components.min())}–{int(self.components.max())})")


#: What :meth:`GaussianSumFilter.filter` can keep.
GSF_KEEPABLE = ("x", "P", "mixture")


@dataclass(frozen=True, eq=False)
class GaussianSumFilter(Filter):
    """A Gaussian-sum filter whose components run a compiled Gaussian filter, split by the MoN.

    x_{k+1} = f(x_k) + w_k, y_k = h(x_k) + e_k (or with noise symbols, as
    :class:`~symmon.NonlinearKalmanFilter`); module notes for the algorithm.

    Parameters
    ----------
    f_model, h_model, Q, R
        As for :class:`~symmon.NonlinearKalmanFilter`.
    transform : TT1, TT2, UT, GaussHermite or a registered name, default ``UT.ut1()``
        The Gaussian filter each component runs (``TT1()``: a bank of EKFs).
    split : float or None, default None
        Split a component before a prediction (by the MoN of f) or an update (by the MoN of
        h, at the predicted component) whose unitless MoN (W^full, TT2) exceeds this; None:
        never split.  Splitting needs additive noises (no noise symbols).
    max_components : int, default 16
        Components kept per run after each step (merging beyond); splits during a step are
        limited to ``max_components`` × ``split_components`` components.
    prune : float, default 1e-6
        Components whose weight falls below this after an update are dropped (the heaviest
        is always kept).  A component of weight 0 is dropped with ``prune=0`` too, and a
        prior's components of weight 0 before the first step: it carries nothing, and two
        of them would merge to a NaN.
    merge : {"runnalls", "salmond"}, default "runnalls"
        The cost by which pairs are merged (module notes).
    split_components : {3, 5}, default 3
        Components per split (:data:`SPLITS`).
    merge_back : float or None, default None
        Merge back, after each update, pairs of *calm* components (whose MoN of f and of h
        at the posterior component, with the next step's parameters, are below ``split``/2:
        a hysteresis below the split level) while their least Runnalls (2007) cost is below
        this (module notes, "Merging back"); needs ``split``.  None: never (the default,
        whose numbers do not change).  ``components`` of the result counts them per step.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.symbols("x")
    >>> gsf = sm.GaussianSumFilter(sm.Model([x], [x]), sm.Model([x], [x]), [[1.0]], [[1.0]], sm.TT1())
    >>> prior = sm.GaussianMixture([0.5, 0.5], [[-1.0], [1.0]], [[[1.0]], [[1.0]]])
    >>> res = gsf.filter([[1.0]], prior)
    >>> res.mixture(0).n_components, round(float(res.x[0, 0]), 6)
    (2, 0.773838)
    """

    f_model: Model
    h_model: Model
    Q: np.ndarray
    R: np.ndarray
    transform: Transform | None = None
    split: float | None = None
    max_components: int = 16
    prune: float = 1e-6
    merge: str = "runnalls"
    split_components: int = 3
    merge_back: float | None = None
    kf: NonlinearKalmanFilter = field(init=False, repr=False)

    def __post_init__(self) -> None:
        transform = UT.ut1() if self.transform is None else filter_rule(self.transform)
        if not filterable(transform):
            raise ArgumentTypeError(f"transform must be TT1, TT2, UT or GaussHermite (one rule for every component), "
                                    f"got {self.transform!r}")
        kf = NonlinearKalmanFilter(self.f_model, self.h_model, self.Q, self.R, transform)
        object.__setattr__(self, "kf", kf)
        object.__setattr__(self, "transform", transform)
        object.__setattr__(self, "Q", kf.Q)
        object.__setattr__(self, "R", kf.R)
        s = self.split
        if s is not None and (isinstance(s, bool) or not isinstance(s, (int, float)) or not 0 < s < 1):
            raise ArgumentError(f"split must be None or a MoN level in (0, 1) (W^full's MoN lies in [0, 1]), got {plain_repr(s)}")
        if s is not None and (kf.f_model.n_v or kf.h_model.n_v):
            raise ArgumentError("split needs additive noises: the models have noise symbols, whose MoN needs "
                                "nested integration per component; use split=None")
        mc = self.max_components
        if isinstance(mc, bool) or not isinstance(mc, (int, np.integer)) or mc < 1:
            raise ArgumentError(f"max_components must be a positive integer, got {plain_repr(mc)}")
        p = self.prune
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not 0 <= p < 1:
            raise ArgumentError(f"prune must be a weight in [0, 1), got {plain_repr(p)}")
        if self.merge not in MERGE_RULES:
            raise ArgumentError(f"merge must be one of {MERGE_RULES}, got {self.merge!r}")
        if self.split_components not in SPLITS:
            raise ArgumentError(f"split_components must be one of {sorted(SPLITS)}, got {self.split_components!r}")
        b = self.merge_back
        if b is not None:
            if isinstance(b, bool) or not isinstance(b, (int, float)) or not (np.isfinite(b) and b > 0):
                raise ArgumentError(f"merge_back must be None or a positive Runnalls cost, got {plain_repr(b)}")
            if s is None:
                raise ArgumentError("merge_back needs split: components merge back when their MoN falls below split/2")

    @property
    def f(self) -> Model:
        return self.kf.f_model

    @property
    def h(self) -> Model:
        return self.kf.h_model

    @cached_property
    def method(self) -> str:
        """``GSF(<component filter>, split=...)``."""
        s = "" if self.split is None else f", split={self.split:g}"
        b = "" if self.merge_back is None else f", merge_back={self.merge_back:g}"
        return f"GSF({self.kf.method}{s}{b})"

    @cached_property
    def _curved(self) -> tuple[bool, bool]:
        """Whether f and h have a structurally nonzero second derivative in the state (an
        affine model's MoN is 0: it is never split)."""
        def curved(model: Model) -> bool:
            _, rows, cols = _model_cm(model).hess_index
            return bool(((rows < model.n_u) & (cols < model.n_u)).any())
        return curved(self.f), curved(self.h)

    def _prior(self, x0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self.f.n_u
        if isinstance(x0, GaussianMixture):
            if x0.dim != n:
                raise ShapeError(f"x0 has dimension {x0.dim} but the state has {n}")
            some = np.asarray(x0.weights) > 0  # a component of weight 0 is dropped (class notes)
            return np.array(x0.weights[some]), np.array(x0.means[some]), np.array(x0.covs[some])
        if isinstance(x0, Gaussian):
            check_gaussian(x0, "x0", dim=n)
            return np.ones(1), np.asarray(x0.mean, dtype=float)[None], np.asarray(x0.cov, dtype=float)[None]
        raise ArgumentTypeError(f"x0 must be a symmon.Gaussian or GaussianMixture, got {type(x0).__name__}")

    keepable: ClassVar[tuple[str, ...]] = GSF_KEEPABLE
    takes_covariance: ClassVar[bool] = False

    @property
    def sizes(self) -> tuple[int, int]:
        """(n, n_y): the state's and the measurement's dimensions."""
        return self.f.n_u, self.h.n_y

    def step_cost(self) -> int:
        """The component filter's cost at each of at most ``max_components`` components, and
        with ``split`` the MoN's (TT2 on f and h) that decides the splits."""
        mon = 0 if self.split is None else TT2().cost(self.f.n_u + self.f.n_v) + TT2().cost(self.h.n_u + self.h.n_v)
        return self.max_components * self.kf.step_cost() + mon

    @property
    def params(self) -> tuple:
        """The parameters of the component filter's models."""
        return self.kf.params

    def _check_prior(self, x0: Any, P0: None, runs: int | None) -> tuple[tuple, None]:
        return self._prior(x0), None

    def _numbers(self, keep: frozenset[str] | None) -> tuple[int, int]:
        n = self.f.n_u
        kept = set(self.keepable) if keep is None else keep
        mixture_numbers = self.max_components * (1 + n + n * n) if "mixture" in kept else 0
        return 2 + n + n * n + mixture_numbers, 0

    def _filter(self, call: FilterCall) -> GaussianSumResult:
        """Predict, then update, for each measurement, every component, over the checked
        ``call`` (:meth:`filter`).  The prior is a Gaussian or a GaussianMixture (e.g. a
        range-parameterised prior); ``keep`` names some of ``"x"``, ``"P"`` and ``"mixture"``
        (the weights, means and covariances of every step); the per-step log-likelihood is
        always kept.

        Raises
        ------
        SymmonError
            A component's step produced NaN or inf (naming the step and run).
        """
        kept = set(self.keepable) if call.keep is None else set(call.keep)
        inner = kept | ({"x", "P"} if call.truth is not None else set())  # the NEES reads x and P
        w0, m0, P0 = call.x0
        if len(w0) > self.max_components:
            w0, m0, P0 = merge_components(w0, m0, P0, self.max_components, self.merge)
        n, n_y = self.sizes
        runs, Yb, pv = call.runs, call.Y, call.pv
        if self.split is None:
            out = self._bank(Yb, w0, m0, P0, call.params, runs, inner)
        else:
            # a running build of the recursion is waited for: the stepwise filter agrees with it
            # to rounding, not to the bit, so a call's numbers must not depend on the build's timing
            out = self._recursion(Yb, w0, m0, P0, pv, inner, wait=True)
            if out is None:  # no compiled code (no compiler, the never policy, a failed build)
                out = self._stepwise(Yb, w0, m0, P0, pv, inner)
        if call.truth is not None:
            out["nees_values"] = nees_of(out["x"], out["P"], call.truth, sorted(self.kf.angle_states))
            out = {k: v for k, v in out.items() if k not in ("x", "P") or k in kept}
        arrays = {k: (v if runs is not None else v[0]) for k, v in out.items()}
        for v in arrays.values():
            v.flags.writeable = False
        return GaussianSumResult(**arrays, n_y=n_y, n_x=n, angle_states=tuple(sorted(self.kf.angle_states)),
                                 method=self.method)

    def _bank(self, Y, w0, m0, P0, params, runs, kept) -> dict[str, np.ndarray]:
        """Without splitting: every component of every run as one bank of the compiled filter."""
        R, K = Y.shape[:2]
        M = len(w0)
        Yr = np.repeat(Y, M, axis=0)
        bank_params = None
        if params:
            bank_params = {}
            for k, v in params.items():
                a = np.asarray(v, dtype=float)
                bank_params[k] = np.repeat(a, M, axis=0) if runs is not None and a.shape == (R, K) else a
        res = self.kf.filter(Yr, np.tile(m0, (R, 1)), np.tile(P0, (R, 1, 1)), keep=("x", "P"), params=bank_params)
        ll = res.loglik.reshape(R, M, K)
        x, P = res.x.reshape(R, M, K, n := self.f.n_u), res.P.reshape(R, M, K, n, n)
        logw, step_ll = bank_weights(np.log(w0), ll)  # log of the normalised weights
        w = np.exp(logw)
        w /= w.sum(axis=-1, keepdims=True)
        means, covs = np.moveaxis(x, 1, 2), np.moveaxis(P, 1, 2)  # (R, K, M, ...)
        out = {"loglik": step_ll, "components": np.full((R, K), M), "splits": np.zeros((R, K), dtype=int)}
        xm = np.einsum("rkm,rkma->rka", w, means)
        if "x" in kept:
            out["x"] = xm
        if "P" in kept:
            d = means - xm[:, :, None]
            Pm = np.einsum("rkm,rkmab->rkab", w, covs) + np.einsum("rkm,rkma,rkmb->rkab", w, d, d)
            out["P"] = 0.5 * (Pm + np.swapaxes(Pm, -1, -2))
        if "mixture" in kept:
            out.update(weights=w, means=means, covs=covs)
        return out

    # ------------------------------------------------------------------ the stepwise filter
    def _mons(self, which: str, steps: _ComponentSteps, x, P, p, noise):
        """The MoN M (N,), its weights W (N, n_y, n_y) and the Hessians (N, n_y, n, n) of f or h
        at every component: one compiled call, then the stacked weights."""
        N, n = x.shape
        n_y = noise.shape[0]
        cov_g, D, H = steps.mon[which](np.hstack([x, P.reshape(N, n * n), p]))
        mon, W = component_mon(cov_g.reshape(N, n_y, n_y), D.reshape(N, n_y, n_y), noise)
        # CasADi's vec is column-major: H_i's columns are the rows of its transpose (H_i is symmetric).
        return mon, W, H.reshape(N, n_y, n, n)

    def _split(self, which: str, steps, run, w, x, P, p, noise, cap: int):
        """Split the components whose MoN of ``which`` exceeds ``split`` (the largest first,
        while the run has room below ``cap``); returns the new arrays and the splits per run."""
        R = int(run.max()) + 1 if len(run) else 0
        mon, W, H = self._mons(which, steps, x, P, p, noise)
        over = np.flatnonzero(mon > self.split)
        splits = np.zeros(R, dtype=int)
        if not len(over):
            return run, w, x, P, p, splits
        m = self.split_components
        order = over[np.argsort(-mon[over], kind="stable")]
        # The largest MoN first, while the run has room: the k-th split of a run (in that
        # order) brings it to count + k (m − 1) components.
        count = np.bincount(run, minlength=R)
        if (count + np.bincount(run[over], minlength=R) * (m - 1) <= cap).all():
            chosen = over  # room for every split (the usual case)
        else:
            rank = np.empty(len(order), dtype=int)
            ro = run[order]
            by_run = np.argsort(ro, kind="stable")
            firsts = np.searchsorted(ro[by_run], np.arange(R))
            rank[by_run] = np.arange(len(order)) - firsts[ro[by_run]]
            chosen = np.sort(order[count[ro] + (rank + 1) * (m - 1) <= cap])
        if not len(chosen):
            return run, w, x, P, p, splits
        splits += np.bincount(run[chosen], minlength=R)
        d = split_directions(P[chosen], H[chosen], W[chosen])
        pw, pm, pP = split_components(x[chosen], P[chosen], d, m)
        # Each chosen component becomes m, in place (the runs stay contiguous and in order).
        reps = np.ones(len(w), dtype=int)
        reps[chosen] = m
        idx = np.repeat(np.arange(len(w)), reps)
        run, w, x, P, p = run[idx], w[idx].copy(), x[idx].copy(), P[idx].copy(), p[idx]
        slots = ((np.cumsum(reps) - reps)[chosen][:, None] + np.arange(m)).ravel()
        w[slots] = w[slots] * np.tile(pw, len(chosen))
        x[slots], P[slots] = pm.reshape(-1, x.shape[1]), pP.reshape((-1,) + P.shape[1:])
        if self.kf.angle_states:
            a = sorted(self.kf.angle_states)
            x[:, a] = wrap_angle(x[:, a])
        return run, w, x, P, p, splits

    def _nonfinite(self, k: int, r: int, R: int) -> SymmonError:
        where = f"step {k}" if R == 1 else f"run {r}, step {k}"
        return SymmonError(f"{self.method}: a component's step produced NaN or inf at {where} (its "
                           "innovation covariance is singular or a covariance lost positive definiteness)")

    def _recursion(self, Y, w0, m0, P0, pv, kept, wait: bool = False) -> dict[str, np.ndarray] | None:
        """With splitting: all steps of all runs in one compiled call
        (:mod:`symmon.filters.mixture._kernel`), the same results as :meth:`_stepwise` to rounding;
        None when that C is not available (``wait``: wait for a background build)."""
        steps = _component_steps(self.f, self.h, self.transform, self.kf.angle_states)
        kernel = steps.kernel()
        if kernel is None:
            return None
        if wait:
            kernel.native.wait()
        fn = kernel.loop()
        if fn is None:
            return None
        R, K, _ = Y.shape
        n_p = steps.n_p
        params = np.zeros((R, K, n_p)) if pv is None else np.broadcast_to(pv, (R, K, n_p))
        out, fail = kernel.run(fn, Y, w0, m0, P0, params, np.asarray(self.Q), np.asarray(self.R), split=self.split,
                               prune=self.prune, max_components=self.max_components, m=self.split_components,
                               salmond=self.merge == "salmond", curved=self._curved,
                               table=_split_table(self.split_components),
                               angle_states=tuple(sorted(self.kf.angle_states)), kept=kept,
                               merge_back=self.merge_back)
        if (fail >= 0).any():
            k = int(fail[fail >= 0].min())
            raise self._nonfinite(k, int(np.argmax(fail == k)), R)
        if "mixture" in kept:
            M = max(int(out["components"].max()), 1)
            for name in ("weights", "means", "covs"):
                out[name] = np.ascontiguousarray(out[name][:, :, :M])
        return out

    def _stepwise(self, Y, w0, m0, P0, pv, kept) -> dict[str, np.ndarray]:
        R, K, n_y = Y.shape
        n = self.f.n_u
        steps = _component_steps(self.f, self.h, self.transform, self.kf.angle_states)
        M0 = len(w0)
        run = np.repeat(np.arange(R), M0)
        w = np.tile(w0, R)
        x, P = np.tile(m0, (R, 1)), np.tile(P0, (R, 1, 1))
        n_p = steps.n_p
        params = np.zeros((R, K, max(n_p, 1)))[..., :n_p] if pv is None else pv
        measured = ~np.isnan(Y)
        Yz = np.where(measured, Y, 0.0)
        cap = self.max_components * self.split_components
        out = result_arrays(R, K, n, self.max_components, kept)
        curved_f, curved_h = self._curved
        Q, Rn = np.asarray(self.Q), np.asarray(self.R)
        for k in range(K):
            p = params[run, k]
            if curved_f:
                run, w, x, P, p, s = self._split("f", steps, run, w, x, P, p, Q, cap)
                out["splits"][:, k] += s
            N = len(w)
            xp, Pp = steps.predict(np.hstack([x, P.reshape(N, n * n), np.broadcast_to(Q.ravel(), (N, n * n)), p]))
            Pp = Pp.reshape(N, n, n)
            if curved_h:
                run, w, xp, Pp, p, s = self._split("h", steps, run, w, xp, Pp, p, Rn, cap)
                out["splits"][:, k] += s
            N = len(w)
            rows = np.hstack([xp, Pp.reshape(N, n * n), Yz[run, k], np.broadcast_to(Rn.ravel(), (N, n_y * n_y)),
                              measured[run, k].astype(float), p])
            x, P, ll = steps.update(rows)
            P = P.reshape(N, n, n)
            ll = ll[:, 0]
            bad = ~(np.isfinite(ll) & np.isfinite(x).all(axis=1) & np.isfinite(P).all(axis=(1, 2)))
            if bad.any():
                raise self._nonfinite(k, int(run[np.argmax(bad)]), R)
            # log Σ_i w_i N(ν_i; 0, S_i) per run, in log space; then the normalised weights.
            # Every run keeps at least one component and its components are contiguous: the
            # per-run reductions are reduceat over the runs' first rows.
            with np.errstate(divide="ignore"):  # a child's weight that underflowed: -inf, as in C
                a = np.log(w) + ll
            first = np.searchsorted(run, np.arange(R))
            top = np.maximum.reduceat(a, first)
            tot = top + np.log(np.add.reduceat(np.exp(a - top[run]), first))
            out["loglik"][:, k] = tot
            w = np.exp(a - tot[run])
            run, w, x, P = self._reduce(run, w, x, P)
            if self.merge_back is not None:
                run, w, x, P = self._merge_back(steps, run, w, x, P, params[run, min(k + 1, K - 1)], Q, Rn)
            starts = np.searchsorted(run, np.arange(R))
            out["components"][:, k] = np.diff(starts, append=len(run))
            xm = np.add.reduceat(w[:, None] * x, starts, axis=0)
            if "x" in kept:
                out["x"][:, k] = xm
            if "P" in kept:
                d = x - xm[run]
                Pm = np.add.reduceat(w[:, None, None] * (P + d[:, :, None] * d[:, None, :]), starts, axis=0)
                out["P"][:, k] = 0.5 * (Pm + np.swapaxes(Pm, 1, 2))
            if "mixture" in kept:
                slot = np.arange(len(w)) - starts[run]
                out["weights"][run, k, slot] = w
                out["means"][run, k, slot] = x
                out["covs"][run, k, slot] = P
        if "mixture" in kept:
            M = max(int(out["components"].max()), 1)
            for name in ("weights", "means", "covs"):
                out[name] = np.ascontiguousarray(out[name][:, :, :M])
        return out

    def _merge_back(self, steps: _ComponentSteps, run, w, x, P, p, Q, Rn):
        """Merge back the calm components of each run (``merge_back``; module notes)."""
        calm = np.ones(len(w), dtype=bool)
        for which, noise, curved in (("f", Q, self._curved[0]), ("h", Rn, self._curved[1])):
            if curved:
                calm &= self._mons(which, steps, x, P, p, noise)[0] < 0.5 * self.split
        R = int(run[-1]) + 1
        starts = np.searchsorted(run, np.arange(R + 1))
        parts = []
        for r in range(R):
            a, b = starts[r], starts[r + 1]
            if np.count_nonzero(calm[a:b]) < 2:
                parts.append((np.full(b - a, r), w[a:b], x[a:b], P[a:b]))
                continue
            wr, xr, Pr, _ = merge_below(w[a:b], x[a:b], P[a:b], self.merge_back, calm[a:b])
            parts.append((np.full(len(wr), r), wr, xr, Pr))
        run, w, x, P = (np.concatenate([q[i] for q in parts]) for i in range(4))
        if self.kf.angle_states:
            ang = sorted(self.kf.angle_states)
            x[:, ang] = wrap_angle(x[:, ang])
        return run, w, x, P

    def _reduce(self, run, w, x, P):
        """Prune below ``prune`` (keeping each run's heaviest) and merge each run down to
        ``max_components``; weights renormalised per run."""
        R = int(run[-1]) + 1
        top = np.maximum.reduceat(w, np.searchsorted(run, np.arange(R)))
        keep = ((w >= self.prune) & (w > 0)) | (w == top[run])  # weight 0: dropped, even at prune=0
        run, w, x, P = run[keep], w[keep], x[keep], P[keep]
        if (np.bincount(run, minlength=R) > self.max_components).any():
            w, x, P = (np.ascontiguousarray(a, dtype=float) for a in (w, x, P))
            left = merge_runs(run, w, x, P, self.max_components, self.merge)
            run, w, x, P = run[left], w[left], x[left], P[left]
        tot = np.bincount(run, w, minlength=R)
        return run, w / tot[run], x, P
