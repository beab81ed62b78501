"""The single entry point: moments of y = g(u, v) for a Gaussian u (and v)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from scipy.linalg import block_diag

from ..compile.compiled import compiled
from ..errors import ArgumentTypeError, ModelError, ShapeError
from ..core.gaussian import Gaussian
from ..core.mixture import Empirical, GaussianMixture
from ..core.model import Model, with_param_values
from .joint import JointMoments
from .particles import propagate_empirical
from .mixing import ComponentBatch, component_batch, is_mixture, mix_batch
from ..transforms.base import Moments, Transform
from .kernel import batch_kernel, kernel_moments
from ..transforms.registry import default_transform, resolve

__all__ = ["propagate", "propagate_many", "propagate_mixture", "check_noise_given", "joint_input", "input_batch",
           "check_transform"]


def check_transform(transform: Any) -> Transform:
    """``transform``, or the default (TT2, :func:`~symmon.transforms.registry.default_transform`)
    for ``None``, or the transform of a registered name (``"ut1"``, ``"gh5"``:
    :func:`~symmon.transforms.registry.resolve`); a class or a non-transform is a TypeError."""
    if transform is None:
        return default_transform()
    transform = resolve(transform)
    if isinstance(transform, type) and issubclass(transform, Transform):
        raise ArgumentTypeError(f"pass a transform instance, e.g. {transform.__name__}(), not the class")
    if not isinstance(transform, Transform):
        raise ArgumentTypeError(f"transform must be a symmon transform (TT1, TT2, UT, ...), got {transform!r}")
    return transform


def check_noise_given(model: Model, v: Any) -> None:
    """v is given exactly when the model has noise symbols, else a ModelError."""
    if model.n_v == 0 and v is not None:
        raise ModelError("v was given but the model declares no noise symbols")
    if model.n_v and v is None:
        raise ModelError(f"the model has noise symbols {list(map(str, model.noise))}: pass v=Gaussian(...)")


def joint_input(model: Model, u: Gaussian, v: Gaussian | None) -> tuple[np.ndarray, np.ndarray]:
    """Mean and block-diagonal covariance of w = [u; v], validated against the model."""
    if not isinstance(u, Gaussian):
        raise ArgumentTypeError(f"u must be a symmon.Gaussian, got {type(u).__name__}")
    if u.dim != model.n_u:
        raise ShapeError(f"u has dimension {u.dim} but the model has {model.n_u} inputs {list(map(str, model.inputs))}")
    check_noise_given(model, v)
    if model.n_v == 0:
        return u.mean, u.cov  # read-only: a Gaussian is immutable, and no rule writes into its input
    if not isinstance(v, Gaussian):
        raise ArgumentTypeError(f"v must be a symmon.Gaussian, got {type(v).__name__}")
    if v.dim != model.n_v:
        raise ShapeError(f"v has dimension {v.dim} but the model has {model.n_v} noise symbols")
    return np.concatenate([u.mean, v.mean]), block_diag(u.cov, v.cov)


def propagate(model: Model, u: Gaussian | GaussianMixture | Empirical,
              v: Gaussian | GaussianMixture | None = None, *, transform: Transform | None = None,
              executor: Any = None, params: dict | None = None) -> JointMoments:
    """E y, Cov y and Cov(y, u) of y = g(u, v) by a transform.

    Parameters
    ----------
    model : Model
    u : Gaussian, GaussianMixture or Empirical
        The input distribution.  For particles (:class:`~symmon.Empirical`), the weighted
        moments of y = g(x_i, v), exact for the empirical measure without noise and with
        additive noise (the transform integrates any other noise at each particle), with
        jackknife standard errors over interleaved groups of particles
        (:mod:`symmon.propagation.particles`); a ``SampleSizeWarning`` when the
        effective sample size is below 100.
    v : Gaussian or GaussianMixture, optional
        The noise distribution (required when the model has noise symbols).  With a
        mixture for u or v, every pair of components goes through the transform in one
        batch and their moments are mixed exactly (:mod:`symmon.propagation.mixing`):
        E y = Σ_j π_j m_j, Cov y = Σ_j π_j (P_j + (m_j − m)(m_j − m)ᵀ), and the
        cross-covariances likewise.
    transform : Transform, default ``TT2()``
        TT1(), TT2(), UT(...), GaussHermite(...), MonteCarlo(...), Exact() or any
        registered rule (docs/architecture.md).  The default is the same for
        :func:`propagate_many`, :func:`symmon.nonlinearity` and the sweeps; docs/guide/transforms.md
        says why it is TT2.
        With noise, the transform is applied to w = [u; v] with a block-diagonal
        covariance and ``cross_cov`` is the u-block of Cov(y, w).
    executor : Executor, optional
        Where a stochastic transform's replicates run (threads, Dask, progress);
        default: the transform's own.  It never changes the numbers.
    params : dict, optional
        Values of the model's parameters (``Model(params=...)``), substituted before the
        model is compiled (:meth:`symmon.Model.with_params`; the filters take them as
        inputs of their compiled step instead).

    Returns
    -------
    JointMoments

    Raises
    ------
    NonFiniteError
        If g is NaN or inf at a point the transform evaluates (naming the output and the
        point), or a moment overflows: a non-finite moment is never returned.  TT1/TT2
        raise a DerivativeError and Monte Carlo a SamplingError in the same cases.

    Warns
    -----
    AngleWarning
        Once per model and output, for an atan2 output not declared in ``angles=`` whose
        points (or, for Monte Carlo, pilot samples) lie on both sides of its cut at ±π.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x, y = sp.symbols("x y")
    >>> m = sm.propagate(sm.Model([x, y], [x * y]), sm.Gaussian([1, 2], [[1, 0], [0, 1]]), transform=sm.TT2())
    >>> float(m.mean[0]), float(m.cov[0, 0])
    (2.0, 6.0)
    """
    model = with_param_values(model, params)
    tr = check_transform(transform)
    if isinstance(u, Empirical):
        check_noise_given(model, v)
        return propagate_empirical(model, u, v, tr, executor)[0]
    if is_mixture(u) or is_mixture(v):
        return propagate_mixture(model, u, v, tr, executor)[0]
    mw, Pw = joint_input(model, u, v)
    b = _checked_batch(model, tr, mw[None], Pw[None], executor, validated=True)  # Gaussians, checked when made
    # "compiled", "vm" or "vm (C build running)": CompiledModel.evaluator, docs/compile.md.
    return JointMoments.of(b, u, model.n_u, tr, model.angle_outputs, model.angle_inputs,
                           evaluator=compiled(model).evaluator)


def propagate_mixture(model: Model, u: Any, v: Any, transform: Transform, executor: Any = None
                      ) -> tuple[JointMoments, Moments, ComponentBatch]:
    """:func:`propagate` for a mixture u and/or v, with what the mixing came from: the
    moments, the transform's batch result of the components and the
    :class:`~symmon.propagation.mixing.ComponentBatch` (for the jackknife of a measure:
    :func:`~symmon.propagation.mixing.mixed_leave_one_out`).

    Every pair of components of u and v goes through the transform in one batch, and
    their moments are mixed exactly (:mod:`symmon.propagation.mixing`).
    """
    check_noise_given(model, v)
    cb = component_batch(model, [u], None if model.n_v == 0 else [v])
    raw = _checked_batch(model, transform, cb.means, cb.covs, executor)
    b = mix_batch(raw, cb, sorted(model.angle_outputs))
    m = JointMoments.of(b, u, model.n_u, transform, model.angle_outputs, model.angle_inputs,
                        evaluator=compiled(model).evaluator)
    return m, raw, cb


def input_batch(model: Model, u: Any, v: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """Means (K, n_w) and block-diagonal covariances (K, n_w, n_w) of K Gaussians of
    w = [u; v], validated against the model (the batch of :func:`propagate_many`)."""
    if isinstance(u, Gaussian):
        raise ArgumentTypeError("u is one Gaussian: use propagate, or pass a list of Gaussians")
    if isinstance(u, list) and not u:
        raise ShapeError("u must hold at least one Gaussian")
    if isinstance(u, (list, tuple)) and u and all(isinstance(g, Gaussian) for g in u):
        for k, g in enumerate(u):
            if g.dim != model.n_u:
                raise ShapeError(f"u[{k}] has dimension {g.dim} but the model has {model.n_u} inputs")
        M = np.array([g.mean for g in u])
        P = np.array([g.cov for g in u])
    elif isinstance(u, tuple) and len(u) == 2:
        M = np.asarray(u[0], dtype=float)
        P = np.asarray(u[1], dtype=float)
        if M.ndim != 2 or M.shape[1] != model.n_u:
            raise ShapeError(f"means must have shape (K, {model.n_u}), got {M.shape}")
        if P.shape != (M.shape[0], model.n_u, model.n_u):
            raise ShapeError(f"covs must have shape {(M.shape[0], model.n_u, model.n_u)}, got {P.shape}")
        if M.shape[0] == 0:
            raise ShapeError("means must hold at least one state")
    else:
        raise ArgumentTypeError("u must be a list of K Gaussians or a pair (means (K, n_u), covs (K, n_u, n_u)), "
                        f"got {type(u).__name__}")
    K = M.shape[0]
    check_noise_given(model, v)
    if model.n_v == 0:
        return M, P
    vs = [v] * K if isinstance(v, Gaussian) else list(v) if isinstance(v, (list, tuple)) else None
    if vs is None or len(vs) != K or not all(isinstance(g, Gaussian) for g in vs):
        raise ArgumentTypeError(f"v must be a Gaussian or a list of {K} Gaussians, one per input")
    for k, g in enumerate(vs):
        if g.dim != model.n_v:
            raise ShapeError(f"v[{k}] has dimension {g.dim} but the model has {model.n_v} noise symbols")
    n_u, n_w = model.n_u, model.n_u + model.n_v
    Mw = np.hstack([M, np.array([g.mean for g in vs])])
    Pw = np.zeros((K, n_w, n_w))
    Pw[:, :n_u, :n_u] = P
    Pw[:, n_u:, n_u:] = np.array([g.cov for g in vs])
    return Mw, Pw


def propagate_many(model: Model, u: Any, v: Any = None, *, transform: Transform | None = None,
                   executor: Any = None, params: dict | None = None) -> Moments:
    """:func:`propagate` for K input Gaussians at once (one batched evaluation).

    Parameters
    ----------
    model : Model
    u : list of Gaussian or GaussianMixture, or (means, covs)
        K input distributions, or the means (K, n_u) and covariances (K, n_u, n_u) of K
        Gaussians (checked with array operations: the fast way to pass many).
    v : Gaussian, GaussianMixture or a list of them, optional
        The noise: one distribution for every input, or one per input (required when the
        model has noise symbols).  With any mixture, the components of every input go
        through the transform in one batch and are mixed per input, as in :func:`propagate`.
    transform : Transform, default ``TT2()``
        As in :func:`propagate`.
    executor : Executor, optional
        As in :func:`propagate`.

    params : dict, optional
        Values of the model's parameters (``Model(params=...)``), substituted before the
        model is compiled (:meth:`symmon.Model.with_params`).

    Returns
    -------
    Moments
        ``mean`` (K, n_y), ``cov`` (K, n_y, n_y), ``cross_cov`` Cov(y, u) (K, n_y, n_u),
        ``noise_cross_cov`` Cov(y, v) (K, n_y, n_v) and ``input_cov`` as
        :class:`~symmon.JointMoments` holds them, batched.

    Examples
    --------
    >>> import numpy as np, sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> b = sm.propagate_many(sm.Model([x], [x**2]), [sm.Gaussian([0.0], [[1.0]]), sm.Gaussian([1.0], [[2.0]])])
    >>> b.mean[:, 0]  # E x² = m² + P
    array([1., 3.])
    """
    model = with_param_values(model, params)
    tr = check_transform(transform)
    if _has_mixture(u, v):
        us, vs = _mixture_items(model, u, v)
        cb = component_batch(model, us, vs)
        b = _checked_batch(model, tr, cb.means, cb.covs, executor)
        return mix_batch(b, cb, sorted(model.angle_outputs)).split(model.n_u)
    M, P = input_batch(model, u, v)
    b = _checked_batch(model, tr, M, P, executor)
    if b.input_cov is None:  # as JointMoments: always Cov u, here the covariances passed in
        b = replace(b, input_cov=P)
    return b.split(model.n_u)


def _has_mixture(u: Any, v: Any) -> bool:
    items = list(u) if isinstance(u, list) else [u]
    noise = list(v) if isinstance(v, (list, tuple)) else [v]
    if any(isinstance(d, Empirical) for d in items + noise):
        raise ArgumentTypeError("propagate_many takes Gaussians and GaussianMixtures; pass an Empirical "
                                "(particles) to propagate, one cloud at a time")
    return any(is_mixture(d) for d in items + noise)


def _mixture_items(model: Model, u: Any, v: Any) -> tuple[list, list | None]:
    """The inputs and noises of :func:`propagate_many` as lists when one is a mixture."""
    if is_mixture(u):
        raise ArgumentTypeError("u is one GaussianMixture: use propagate, or pass a list of distributions")
    if not isinstance(u, list) or not u:
        raise ArgumentTypeError("with a GaussianMixture, u must be a non-empty list of Gaussian or "
                                f"GaussianMixture, got {type(u).__name__}")
    check_noise_given(model, v)
    if model.n_v == 0:
        return u, None
    vs = list(v) if isinstance(v, (list, tuple)) else [v] * len(u)
    if len(vs) != len(u):
        raise ArgumentTypeError(f"v must be one distribution or a list of {len(u)}, one per input")
    return u, vs


def _checked_batch(model: Model, tr: Transform, means: np.ndarray, covs: np.ndarray, executor,
                   validated: bool = False) -> Moments:
    """``tr.moments`` on the compiled model (the template checks the batch and the result;
    ``validated``: a batch of checked Gaussians, as :meth:`Transform.moments`), or, for a
    large batch and a point rule, the compiled batch kernel (:mod:`.kernel`), whose own
    Cholesky factor tests definiteness: any doubt goes to ``tr.moments``."""
    cm = compiled(model)
    angles = frozenset(model.angle_outputs)
    M, P = np.asarray(means, dtype=float), np.asarray(covs, dtype=float)
    fits = M.ndim == 2 and P.shape == (M.shape[0], cm.n_w, cm.n_w)  # else tr.moments says what is wrong
    kernel = batch_kernel(cm, tr, angles, M.shape[0]) if fits else None
    if kernel is not None:
        b = kernel_moments(kernel, cm, tr, M, P)
        if b is not None:
            return b
    return tr.moments(cm, M, P, model.angle_outputs, executor, validated=validated)
