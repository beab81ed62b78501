"""Sweeps: the MoN and the moments over an α grid or along a trajectory, local or on Dask.

Straka & Havlík (2024) plot each MoN against a covariance scale α (Figures 1 and 2: the input
covariance is α·P, (14) and (44)), and a filter asks for it at every state of a trajectory.
Both are a list of K input Gaussians N(m_k, P_k) with one model, so both go through one
kernel here:

* a deterministic transform (TT2, UT, Gauss–Hermite, Exact) on a noise-free model evaluates
  all K Gaussians in a single batched call (:func:`symmon.propagate_many`), then the MoN
  (26)–(29) of each from its moments;
* Monte Carlo (and any model with noise) runs one :func:`symmon.nonlinearity` per Gaussian,
  on Dask when the executor names a ``client`` or a ``scheduler``.  Every task recompiles the
  model on its worker (sympy expressions travel, CasADi functions never do) and returns
  plain arrays.

**Common random numbers.**  Monte Carlo draws standard normals z from the seed and maps them
to w = m + L z with L Lᵀ = P.  With the same seed for every k (``crn=True``, the default)
the K estimates share their z: at α the samples are m + √α L₁ z, so the Monte Carlo error
is a smooth function of α and differences between adjacent grid points are far more
accurate than each value.  ``crn=False`` gives each k its own stream
(``SeedSequence(seed).spawn(K)``): independent errors, e.g. to average over the grid.

A distributed sweep returns the same numbers as the local one, bit for bit: each task is
the same computation on the same seed, and the results are collected in grid order.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ArgumentTypeError, ShapeError, SymmonError
from ..core.gaussian import Gaussian
from ..core.mixture import GaussianMixture
from ..core.model import Model
from .mon import mon_from_moments, nonlinearity
from ..propagation.front import check_transform, input_batch, propagate_many
from ..transforms.base import Transform
from ..transforms.executor import Executor, dask_compute

__all__ = ["SweepResult", "sweep_alpha", "sweep_states"]


@dataclass(frozen=True, eq=False)
class SweepResult:
    """The MoN and the moments at each point of a sweep.

    Attributes
    ----------
    param : ndarray (K,)
        The α values (:func:`sweep_alpha`) or the state indices (:func:`sweep_states`).
    value : ndarray (K,)
        The MoN M = √max(M², 0).
    squared : ndarray (K,)
        M² (25); Monte Carlo noise can make it slightly negative.
    stderr : ndarray (K,) or None
        Monte Carlo standard error of ``value`` (delete-one-group jackknife); ``None`` for
        deterministic transforms.
    mean : ndarray (K, n_y)
    cov : ndarray (K, n_y, n_y)
    cross_cov : ndarray (K, n_y, n_u)
        E y, Cov y and Cov(y, u) at each point.
    moment_stderr : dict or None
        Monte Carlo standard errors ``"mean"``, ``"cov"``, ``"cross_cov"`` with the shapes
        above; ``None`` for deterministic transforms.
    weight_name : str
    transform : Transform
        The transform as given (with its client, if any).
    """

    param: np.ndarray
    value: np.ndarray
    squared: np.ndarray
    stderr: np.ndarray | None
    mean: np.ndarray
    cov: np.ndarray
    cross_cov: np.ndarray
    moment_stderr: dict[str, np.ndarray] | None
    weight_name: str
    transform: Transform

    def __len__(self) -> int:
        return int(self.param.shape[0])

    def __repr__(self) -> str:
        return (f"SweepResult(K={len(self)}, weight={self.weight_name!r}, transform={self.transform!r}, "
                f"value=[{self.value.min():.4g} … {self.value.max():.4g}])")


# --------------------------------------------------------------------------- validation
def _check_model(model: Any) -> Model:
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    return model


def _check_executor(executor: Any) -> Executor | None:
    if executor is not None and not isinstance(executor, Executor):
        raise ArgumentTypeError(f"executor must be a symmon.Executor, got {executor!r}")
    return executor


def _check_alphas(alphas: ArrayLike) -> np.ndarray:
    a = np.asarray(alphas, dtype=float)
    if a.ndim != 1 or a.size == 0:
        raise ShapeError(f"alphas must be a non-empty 1-D array, got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise SymmonError(f"alphas must be finite and positive, got {a.tolist()}")
    return a


# --------------------------------------------------------------------------- one point
def _point(model: Model, mean: np.ndarray, cov: np.ndarray, v: Gaussian | None, weight: Any,
           transform: Transform, executor: Executor | None) -> dict[str, Any]:
    """The MoN and moments of one input Gaussian, as plain arrays (cheap to ship back)."""
    res = nonlinearity(model, Gaussian(mean, cov), v, weight=weight, transform=transform, executor=executor)
    m = res.moments
    return {
        "value": res.value, "squared": res.squared, "stderr": res.stderr, "weight_name": res.weight_name,
        "mean": m.mean, "cov": m.cov, "cross_cov": m.cross_cov, "moment_stderr": m.stderr,
    }


def _run_points(model: Model, means: np.ndarray, covs: np.ndarray, v: Gaussian | None, weight: Any,
                transforms: Sequence[Transform], executor: Executor | None) -> list[dict[str, Any]]:
    if executor is None or not executor.distributed:
        return [_point(model, m, P, v, weight, t, executor) for m, P, t in zip(means, covs, transforms)]
    try:
        import dask
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise SymmonError("a distributed sweep needs the 'dask' extra: pip install symmon[dask]") from exc
    # The model travels as sympy (it pickles); each worker compiles it once and caches it.
    # A task on a cluster runs its replicates on one thread: the cluster supplies the
    # parallelism, and the result does not depend on the thread count (groups merge in a
    # fixed order).
    tasks = [dask.delayed(_point, pure=False)(model, m, P, v, weight, t, Executor(workers=1))
             for m, P, t in zip(means, covs, transforms)]
    # An interrupt cancels the pending points.
    return dask_compute(tasks, executor.client, executor.scheduler, "sweep points", executor.progress,
                        executor.worker_timeout)


def _sweep(model: Model, param: np.ndarray | None, u: Any, v: Gaussian | None, weight: Any,
           transform: Any, executor: Any, crn: bool) -> SweepResult:
    """The sweep over the K input Gaussians ``u`` (:func:`~symmon.propagation.front.input_batch`);
    ``param`` defaults to their indices."""
    model = _check_model(model)
    transform = check_transform(transform)
    executor = _check_executor(executor)
    if v is not None and not isinstance(v, Gaussian):
        raise ArgumentTypeError(f"v must be a symmon.Gaussian (the same noise at every point), got {type(v).__name__}")
    is_mc = transform.stochastic
    if not is_mc and model.n_v == 0:
        return _batched(model, param, u, v, weight, transform)
    W, Pw = input_batch(model, u, v)
    means, covs = W[:, :model.n_u], Pw[:, :model.n_u, :model.n_u]
    K = means.shape[0]
    param = np.arange(K, dtype=float) if param is None else param
    if is_mc and not crn:
        # Independent streams, one per point, reproducible from the one seed.
        seeds = [int(s.generate_state(1, np.uint64)[0]) for s in np.random.SeedSequence(transform.seed).spawn(K)]
        transforms = [dataclasses.replace(transform, seed=s) for s in seeds]
    else:
        transforms = [transform] * K
    pts = _run_points(model, means, covs, v, weight, transforms, executor)
    mse = None
    if is_mc:
        mse = {k: np.stack([p["moment_stderr"][k] for p in pts]) for k in ("mean", "cov", "cross_cov")}
    return SweepResult(
        param=param,
        value=np.array([p["value"] for p in pts]),
        squared=np.array([p["squared"] for p in pts]),
        stderr=np.array([p["stderr"] for p in pts], dtype=float) if is_mc else None,
        mean=np.stack([p["mean"] for p in pts]),
        cov=np.stack([p["cov"] for p in pts]),
        cross_cov=np.stack([p["cross_cov"] for p in pts]),
        moment_stderr=mse, weight_name=pts[0]["weight_name"], transform=transform,
    )


def _batched(model: Model, param: np.ndarray | None, u: Any, v: Gaussian | None, weight: Any,
             transform: Transform) -> SweepResult:
    """A deterministic transform on a noise-free model: one batched evaluation of all points
    (:func:`~symmon.propagate_many` validates the batch)."""
    b = propagate_many(model, u, v, transform=transform)
    K = b.mean.shape[0]
    param = np.arange(K, dtype=float) if param is None else param
    parts = [mon_from_moments(b.cov[k], b.cross_cov[k], b.input_cov[k], weight, None, b.mean[k]) for k in range(K)]
    sq = np.array([p.squared for p in parts])
    return SweepResult(
        param=param, value=np.sqrt(np.maximum(sq, 0.0)), squared=sq, stderr=None,
        mean=b.mean, cov=b.cov, cross_cov=b.cross_cov, moment_stderr=None,
        weight_name=parts[0].weight_name, transform=transform,
    )


# --------------------------------------------------------------------------- public API
def sweep_alpha(model: Model, u: Gaussian, alphas: ArrayLike, v: Gaussian | None = None, *,
                weight: Any = "full", transform: Transform | None = None, executor: Executor | None = None,
                crn: bool = True) -> SweepResult:
    """The MoN and the moments of y = g(u, v) with u ~ N(ū, α P) over a grid of α.

    The scaling of the input covariance by α is that of (14) and (44) in Straka & Havlík
    (2024); the noise v is not scaled.

    Parameters
    ----------
    model : Model
    u : Gaussian or GaussianMixture
        N(ū, P): the distribution at α = 1.  A mixture is scaled about its mean, each
        component's mean offset by √α and its covariance by α (so Cov u scales by α); as
        for mixtures in :func:`sweep_states`, with a deterministic transform on a
        noise-free model.
    alphas : array_like (K,)
        Positive covariance scales.
    v : Gaussian, optional
        The noise, required when the model has noise symbols.
    weight : str, ndarray or weights.GeneralWeight
        As in :func:`symmon.nonlinearity` (default ``"full"``, W = Σ_gg⁻¹/n_y (43)).
    transform : Transform, default ``TT2()``
        As in :func:`symmon.nonlinearity`.  With :class:`~symmon.MonteCarlo`, every α uses
        the transform's seed (common random numbers) unless ``crn=False``.
    executor : Executor, optional
        Where the points run: with a Dask ``client`` or ``scheduler``, one task per α
        (Monte Carlo, or models with noise; each task runs its groups on one thread);
        otherwise locally, with the executor's threads for the Monte Carlo groups.
    crn : bool, default True
        Common random numbers across α; ``False``: independent streams per α.

    Returns
    -------
    SweepResult
        ``param`` holds the α values.

    Examples
    --------
    >>> import numpy as np, sympy as sp, symmon as sm
    >>> from symmon.measures.sweep import sweep_alpha
    >>> x = sp.Symbol("x")
    >>> r = sweep_alpha(sm.Model([x], [x**2]), sm.Gaussian([1.0], [[1.0]]), [0.5, 1.0, 2.0])
    >>> np.round(r.squared, 12)  # M² = 2α / (4 + 2α) for x² with x ~ N(1, α)
    array([0.2       , 0.33333333, 0.5       ])
    """
    model = _check_model(model)
    if isinstance(u, GaussianMixture):
        if u.dim != model.n_u:
            raise ShapeError(f"u has dimension {u.dim} but the model has {model.n_u} inputs")
        a = _check_alphas(alphas)
        # The mixture scaled about its mean: each component's offset by √α and its
        # covariance by α, so the whole mixture's covariance is α Cov u, as (14) for a Gaussian.
        scaled = [GaussianMixture(u.weights, u.mean + np.sqrt(s) * (u.means - u.mean), s * u.covs) for s in a]
        try:
            res = sweep_states(model, scaled, v, weight=weight, transform=transform, executor=executor, crn=crn)
        except ArgumentTypeError as exc:
            raise ArgumentTypeError(f"sweep_alpha takes a GaussianMixture with a deterministic transform on a "
                                    f"noise-free model only, as sweep_states ({exc})") from None
        return dataclasses.replace(res, param=a)
    if not isinstance(u, Gaussian):
        raise ArgumentTypeError(f"u must be a symmon.Gaussian or GaussianMixture, got {type(u).__name__}")
    if u.dim != model.n_u:
        raise ShapeError(f"u has dimension {u.dim} but the model has {model.n_u} inputs")
    a = _check_alphas(alphas)
    means = np.tile(u.mean, (a.size, 1))
    covs = a[:, None, None] * u.cov[None]
    return _sweep(model, a, (means, covs), v, weight, transform, executor, crn)


def sweep_states(model: Model, u: Any, v: Gaussian | None = None, *, weight: Any = "full",
                 transform: Transform | None = None, executor: Executor | None = None,
                 crn: bool = True) -> SweepResult:
    """The MoN and the moments at each state N(m_k, P_k) of a trajectory.

    Parameters
    ----------
    model : Model
    u : list of Gaussian, or (means, covs)
        The K states, as in :func:`symmon.propagate_many`: Gaussians, or their means
        (K, n_u) and covariances (K, n_u, n_u).  A deterministic transform on a noise-free
        model also takes GaussianMixtures in the list (their mixed moments, one batch);
        otherwise a mixture is refused.
    v : Gaussian, optional
        The noise, the same at every state.
    weight, transform, executor, crn
        As in :func:`sweep_alpha`.  A deterministic transform on a noise-free model
        evaluates all K states in one batched call, always locally (it is cheaper than
        shipping them).

    Returns
    -------
    SweepResult
        ``param`` holds the state indices 0, …, K − 1.
    """
    return _sweep(model, None, u, v, weight, transform, executor, crn)
