"""Moments of y = g(u, v) for a weighted sample of u (:class:`~symmon.core.mixture.Empirical`).

Each particle x_i with weight w_i is a point mass: the sample is the mixture
Σ_i w_i N(x_i, 0) of degenerate components, and its moments are the mixing identities of
:mod:`symmon.propagation.mixing` with P_i = Cov(y | x_i) and C_i = Cov(y, w | x_i):

- without noise, y_i = g(x_i), P_i = C_i = 0: the weighted sample moments, exact for the
  empirical measure, by direct batched evaluation of the compiled model;
- with additive noise g = f(u) + B v, E[y | x_i] = g(x_i, ν), P_i = B R Bᵀ and
  Cov(y, v | x_i) = B R, exact without any rule (for each component (ν, R) of v);
- with other noise, the transform integrates v at each particle: the components
  N([x_i; ν_l], blkdiag(0, R_l)), one batch per chunk of particles (every rule accepts the
  zero block; a stochastic rule is refused, since the particles are already a sample).

The particles are processed in chunks of :data:`CHUNK` and accumulated as weighted sums
about a reference (the first chunk's weighted mean), so that memory beyond the particles
is flat in their number and a mean far from 0 costs no digits.  The particles of zero
weight add nothing and are left out (:func:`support`); of the others, the i-th belongs to
group i mod G (:data:`GROUPS`), so that every group holds weight (were the groups formed
over all particles, a cloud whose weighted particles all fall in one group, every 20th,
would leave a group of zero weight and no leave-one-out moments); the group sums give the delete-one-group jackknife
(:func:`~symmon.transforms.stats.jackknife_se`) of every moment and measure: the error of the
particles as a sample of the distribution they stand for.  Interleaved groups keep
neighbouring particles apart; the duplicates of a resampled cloud are still correlated
across groups, which makes the error bar optimistic for such a cloud.

A declared angle input (``Model(..., angles=[θ])``) is summed on the circle: its
reference is the circular mean of the first chunk, its deviations are wrapped to
(−π, π], so a cloud on both sides of ±π has its spread about its mean direction, not about
0 (Mardia & Jupp 2000, Sec. 2.2; :mod:`symmon.core.angles`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..compile.compiled import compiled
from ..core.angles import unwrap_near, wrap_components, wrap_angle
from ..core.mixture import Empirical
from ..core.model import Model
from ..errors import ArgumentError, ArgumentTypeError, NonFiniteError, SampleSizeWarning, ShapeError
from ..transforms.base import Moments, Transform
from ..transforms.stats import jackknife_se
from .joint import JointMoments
from .mixing import parts

__all__ = ["GroupSums", "particle_sums", "group_means", "propagate_empirical", "check_ess", "support",
           "jackknife_groups", "CHUNK", "GROUPS", "SMALL_ESS"]

#: Particles per evaluation batch (a multiple of :data:`GROUPS`): the buffers of a chunk
#: are CHUNK·(n_y·n_w + n_y²)·8 bytes, a few MB.
CHUNK = 2**15 - 2**15 % 20
#: Jackknife groups: 20 leave-one-out estimates give the error bar to about ±16 %
#: (1/√(2(G−1))), at 20 evaluations of the measure from the sums (no evaluation of g).
GROUPS = 20
#: Below this effective sample size a SampleSizeWarning: with under 100 effective
#: particles a variance (hence a MoN) is uncertain by more than ±14 % (√(2/ESS)).
SMALL_ESS = 100.0


def check_ess(u: Empirical, stacklevel: int = 3) -> None:
    """Warn (:class:`~symmon.errors.SampleSizeWarning`) when the ESS is below :data:`SMALL_ESS`."""
    if u.ess < SMALL_ESS:
        warnings.warn(f"the particles' effective sample size is {u.ess:.3g} (of {u.n_samples} particles), below "
                      f"{SMALL_ESS:g}: their moments and measures are those of a few particles",
                      SampleSizeWarning, stacklevel=stacklevel)


def support(u: Empirical) -> tuple[np.ndarray, np.ndarray]:
    """The particles of ``u`` with a positive weight and their weights (``u``'s own arrays,
    uncopied, when none is zero): what every sum of this module runs over."""
    w = u.weights
    keep = w > 0
    if keep.all():
        return u.samples, w
    return u.samples[keep], w[keep]


def jackknife_groups(u: Empirical) -> int:
    """The number G of jackknife groups of ``u``: :data:`GROUPS`, or fewer when fewer
    particles have a positive weight (each group holds at least one of them)."""
    return min(GROUPS, int(np.count_nonzero(u.weights > 0)))


def _by_group(a: np.ndarray, G: int, L: int = 1) -> np.ndarray:
    """Rows of a chunk (n·L rows: L per particle, n a multiple of G) regrouped as
    (G, n/G·L, ...): particle start + r·G + g is in group g, the chunk starting at a
    multiple of G."""
    n = a.shape[0] // L
    return np.swapaxes(a.reshape((n // G, G, L) + a.shape[1:]), 0, 1).reshape((G, (n // G) * L) + a.shape[1:])


def _pad(a: np.ndarray, rows: int) -> np.ndarray:
    """``a`` with zero rows appended up to ``rows`` (zero weight: nothing is added)."""
    if a.shape[0] == rows:
        return a
    return np.concatenate([a, np.zeros((rows - a.shape[0],) + a.shape[1:])])


def group_means(u: Empirical, fn: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per group, Σ_i w_i fn(x_i) (G, d) and Σ_i w_i (G,), with fn evaluated on chunks of
    particles (rows) returning (chunk, d)."""
    G = jackknife_groups(u)
    Xs, ws = support(u)
    sums, wsum = 0.0, 0.0
    for start in range(0, ws.size, CHUNK):
        X, w = Xs[start:start + CHUNK], ws[start:start + CHUNK]
        rows = -(-X.shape[0] // G) * G
        F, wp = _by_group(_pad(np.asarray(fn(X), dtype=float), rows), G), _by_group(_pad(w, rows), G)
        sums = sums + np.einsum("gk,gkd->gd", wp, F)
        wsum = wsum + wp.sum(axis=1)
    return sums, wsum


@dataclass(frozen=True)
class GroupSums:
    """Weighted sums of the particles' conditional moments, per group, about a reference.

    With d_i = m_i − c_y and e_i = μ_i − c_w (angles wrapped), each group holds
    w = Σ w_i, m = Σ w_i d_i, mm = Σ w_i (P_i + d_i d_iᵀ), my = Σ w_i (C_i + d_i e_iᵀ),
    mu = Σ w_i e_i and uu = Σ w_i (Pw_i + e_i e_iᵀ), the leading axis the G groups.
    """

    w: np.ndarray
    m: np.ndarray
    mm: np.ndarray
    my: np.ndarray
    mu: np.ndarray
    uu: np.ndarray
    c_y: np.ndarray
    c_w: np.ndarray
    angles: tuple[int, ...]
    evaluations: int
    input_angles: tuple[int, ...] = ()

    def total(self) -> "GroupSums":
        """The sums over all groups (a leading axis of 1)."""
        return self._with(lambda a: a.sum(axis=0, keepdims=True))

    def leave_one_out(self) -> "GroupSums":
        """For each group g, the sums over the other groups (leading axis G)."""
        return self._with(lambda a: a.sum(axis=0, keepdims=True) - a)

    def _with(self, f: Callable[[np.ndarray], np.ndarray]) -> "GroupSums":
        return GroupSums(*(f(getattr(self, k)) for k in ("w", "m", "mm", "my", "mu", "uu")),
                         self.c_y, self.c_w, self.angles, self.evaluations, self.input_angles)

    def input_mean(self) -> np.ndarray:
        """E w for each set of sums (leading axis), the angle inputs wrapped to (−π, π]."""
        return wrap_components(self.c_w + self.mu / self.w[:, None], self.input_angles)

    def moments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """E y, Cov y, Cov(y, w) and Cov w for each set of sums (leading axis)."""
        W = self.w[:, None]
        dm, du = self.m / W, self.mu / W
        mean = wrap_components(self.c_y + dm, self.angles)
        cov = self.mm / W[..., None] - dm[:, :, None] * dm[:, None, :]
        cross = self.my / W[..., None] - dm[:, :, None] * du[:, None, :]
        in_cov = self.uu / W[..., None] - du[:, :, None] * du[:, None, :]
        return mean, 0.5 * (cov + np.swapaxes(cov, 1, 2)), cross, 0.5 * (in_cov + np.swapaxes(in_cov, 1, 2))


def _conditional(model: Model, tr: Transform, X: np.ndarray, wv: np.ndarray, Mv: np.ndarray, Pv: np.ndarray,
                 executor: Any) -> tuple[np.ndarray, ...]:
    """For the particles X (n, n_u) and each component l of v: the weight factor (n·L,),
    means of w (n·L, n_w), Cov w, and E[y | x_i, l], Cov(y | x_i, l), Cov(y, w | x_i, l),
    and the evaluations of g; without noise the covariances are ``None`` (all zero)."""
    cm = compiled(model)
    n, nu = X.shape
    if model.n_v == 0:  # point masses: no conditional (co)variances (None: not summed)
        return np.ones(n), X, None, cm.eval_g(X), None, None, n
    L, nv = wv.size, model.n_v
    Mw = np.hstack([np.repeat(X, L, axis=0), np.tile(Mv, (n, 1))])  # row i·L + l
    Pw = np.zeros((n * L, nu + nv, nu + nv))
    Pw[:, nu:, nu:] = np.tile(Pv, (n, 1, 1))
    fac = np.tile(wv, n)
    if model.structure == "additive":
        # g = f(u) + B v: exact at every particle, without a rule.
        Bm = np.array(model.pi.tolist(), dtype=float)
        Y = cm.eval_g(Mw)
        P = np.einsum("ij,kjl,ml->kim", Bm, Pw[:, nu:, nu:], Bm)
        C = np.zeros((n * L, Y.shape[1], nu + nv))
        C[:, :, nu:] = np.einsum("ij,kjl->kil", Bm, Pw[:, nu:, nu:])
        return fac, Mw, Pw, Y, P, C, n * L
    b = tr.moments(cm, Mw, Pw, model.angle_outputs, executor)
    return fac, Mw, Pw if b.input_cov is None else b.input_cov, b.mean, b.cov, b.cross_cov, b.evaluations


def particle_sums(model: Model, u: Empirical, v: Any, tr: Transform, executor: Any = None) -> GroupSums:
    """The :class:`GroupSums` of the particles of ``u`` (and the noise ``v``, a Gaussian or
    mixture) through ``model``, chunk by chunk."""
    if u.dim != model.n_u:
        raise ShapeError(f"u has dimension {u.dim} but the model has {model.n_u} inputs {list(map(str, model.inputs))}")
    if model.n_v:
        if isinstance(v, Empirical):
            raise ArgumentTypeError("v as an Empirical is not supported: give the noise as a Gaussian or "
                                    "GaussianMixture, or put the noise symbols among the inputs")
        wv, Mv, Pv = parts(v, "v", model.n_v, "noise symbols")
        if model.structure != "additive" and tr.stochastic:
            raise ArgumentError(f"{tr!r} with an Empirical: the particles are already a sample; integrate the "
                                "noise with a deterministic transform (GaussHermite, UT, TT2)")
    else:
        wv = Mv = Pv = None
    A = tuple(sorted(model.angle_outputs))
    W = tuple(sorted(model.angle_inputs))  # u leads w: an input's index is its index in w
    G = jackknife_groups(u)
    Xs, ws = support(u)
    conditional = model.n_v > 0  # without noise P_i = C_i = Pw_i = 0: skip their sums
    acc: list[np.ndarray] | None = None
    c_y = c_w = None
    evaluations = 0
    for start in range(0, ws.size, CHUNK):
        X, wx = Xs[start:start + CHUNK], ws[start:start + CHUNK]
        fac, Mw, Pw, m, P, C, ev = _conditional(model, tr, X, wv, Mv, Pv, executor)
        evaluations += int(ev)
        L = fac.size // X.shape[0]
        pi = np.repeat(wx, L) * fac
        if c_y is None:  # the reference: this first chunk's weighted mean (circular for angles)
            s = max(float(pi.sum()), np.finfo(float).tiny)
            c_y, c_w = pi @ m / s, pi @ Mw / s
            for ref, x, idx in ((c_y, m, A), (c_w, Mw, W)):
                if idx:
                    ref[list(idx)] = np.arctan2(pi @ np.sin(x[:, idx]), pi @ np.cos(x[:, idx]))
        d = unwrap_near(m, c_y, A) - c_y
        e = unwrap_near(Mw, c_w, W) - c_w
        # Regroup the rows (L per particle, the last chunk padded with zero weights) and
        # take the weighted sums and Gram matrices of z = [d; e] per group, one BLAS call.
        rows = -(-X.shape[0] // G) * G * L
        pg = _by_group(_pad(pi, rows), G, L)
        Zg = _by_group(_pad(np.hstack([d, e]), rows), G, L)
        S1 = np.einsum("gk,gka->ga", pg, Zg)
        S2 = np.matmul(np.swapaxes(Zg * pg[..., None], 1, 2), Zg)
        ny = m.shape[1]
        sums = [pg.sum(axis=1), S1[:, :ny], S2[:, :ny, :ny], S2[:, :ny, ny:], S1[:, ny:], S2[:, ny:, ny:]]
        if conditional:  # the noise's own (co)variances at each particle: Σ π P, Σ π C, Σ π Pw
            for k, t in ((2, P), (3, C), (5, Pw)):
                sums[k] = sums[k] + np.einsum("gk,gkab->gab", pg, _by_group(_pad(t, rows), G, L))
        acc = sums if acc is None else [a + s_ for a, s_ in zip(acc, sums)]
    return GroupSums(*acc, c_y=c_y, c_w=c_w, angles=A, evaluations=evaluations, input_angles=W)


def propagate_empirical(model: Model, u: Empirical, v: Any, tr: Transform, executor: Any = None
                        ) -> tuple[JointMoments, GroupSums]:
    """:func:`~symmon.propagate` for particles: the moments of the empirical measure (exact
    without noise or with additive noise), their jackknife standard errors, and the group
    sums they came from (for the measures' error bars)."""
    check_ess(u, stacklevel=4)
    sums = particle_sums(model, u, v, tr, executor)
    mean, cov, cross, in_cov = sums.total().moments()
    stderr = None
    if sums.w.shape[0] >= 2:
        lm, lP, lC, _ = sums.leave_one_out().moments()
        if A := list(sums.angles):  # leave-one-out means of an angle: their spread about the total
            lm[:, A] = mean[0, A] + wrap_angle(lm[:, A] - mean[0, A])
        stderr = {"mean": jackknife_se(lm)[None], "cov": jackknife_se(lP)[None], "cross_cov": jackknife_se(lC)[None]}
        if not all(np.all(np.isfinite(a)) for a in stderr.values()):
            raise NonFiniteError(
                f"particles: the jackknife standard errors over {sums.w.shape[0]} groups are not finite (group "
                f"weights {np.array2string(sums.w, precision=3)}); the moments are {mean[0].tolist()}: check the "
                "weights, or rescale the units if the moments are near the float range")
    b = Moments(mean=mean, cov=cov, cross_cov=cross, input_cov=in_cov, stderr=stderr, evaluations=sums.evaluations,
                details={"particles": u.n_samples, "ess": u.ess, "jackknife_groups": int(sums.w.shape[0]),
                         "input_mean": sums.total().input_mean()})
    m = JointMoments.of(b, u, model.n_u, tr, model.angle_outputs, model.angle_inputs,
                        evaluator=compiled(model).evaluator)
    return m, sums

