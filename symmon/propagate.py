"""The single entry point: moments of y = g(u, v) for a Gaussian u (and v)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import block_diag

from .compile import CompiledModel, compile_model
from .errors import ModelError, ShapeError
from .gaussian import PSD_RTOL, SYMMETRY_RTOL, Gaussian, as_covariance, as_vector
from .model import Model
from .moments import JointMoments
from .transforms import UT, Transform
from .transforms.base import Moments, check_moments_finite

__all__ = ["propagate", "propagate_many", "compiled", "joint_input"]


def compiled(model: Model) -> CompiledModel:
    """The compiled CasADi functions of ``model`` with respect to w = [u; v] (cached)."""
    if not isinstance(model, Model):
        raise TypeError(f"expected a symmon.Model, got {type(model).__name__}")
    return compile_model(model.outputs, model.inputs + model.noise, model.name)


def _check_transform(transform) -> Transform:
    if transform is None:
        return UT.ut1()
    if isinstance(transform, type) and issubclass(transform, Transform):
        raise TypeError(f"pass a transform instance, e.g. {transform.__name__}(), not the class")
    if not isinstance(transform, Transform):
        raise TypeError(f"transform must be a symmon transform (TT1, TT2, UT, ...), got {transform!r}")
    return transform


def joint_input(model: Model, u: Gaussian, v: Gaussian | None) -> tuple[np.ndarray, np.ndarray]:
    """Mean and block-diagonal covariance of w = [u; v], validated against the model."""
    if not isinstance(u, Gaussian):
        raise TypeError(f"u must be a symmon.Gaussian, got {type(u).__name__}")
    if u.dim != model.n_u:
        raise ShapeError(f"u has dimension {u.dim} but the model has {model.n_u} inputs {list(map(str, model.inputs))}")
    if model.n_v == 0:
        if v is not None:
            raise ModelError("v was given but the model declares no noise symbols")
        return u.mean.copy(), u.cov.copy()
    if v is None:
        raise ModelError(f"the model has noise symbols {list(map(str, model.noise))}: pass v=Gaussian(...)")
    if not isinstance(v, Gaussian):
        raise TypeError(f"v must be a symmon.Gaussian, got {type(v).__name__}")
    if v.dim != model.n_v:
        raise ShapeError(f"v has dimension {v.dim} but the model has {model.n_v} noise symbols")
    return np.concatenate([u.mean, v.mean]), block_diag(u.cov, v.cov)


def propagate(model: Model, u: Gaussian, v: Gaussian | None = None, transform: Transform | None = None,
              executor=None) -> JointMoments:
    """E y, Cov y and Cov(y, u) of y = g(u, v) by a transform.

    Parameters
    ----------
    model : Model
    u : Gaussian
        The input distribution.
    v : Gaussian, optional
        The noise distribution (required when the model has noise symbols).
    transform : Transform, default ``UT.ut1()``
        TT1(), TT2(), UT(...), GaussHermite(...), MonteCarlo(...) or Exact().
        With noise, the transform is applied to w = [u; v] with a block-diagonal
        covariance and ``cross_cov`` is the u-block of Cov(y, w).
    executor : Executor, optional
        Where a stochastic transform's replicates run (threads, Dask, progress);
        default: the transform's own.  It never changes the numbers.

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
    tr = _check_transform(transform)
    mw, Pw = joint_input(model, u, v)
    b = _checked_batch(model, tr, mw[None], Pw[None], executor)
    # "compiled", "vm" or "vm (C build running)": CompiledModel.evaluator, docs/compile.md.
    return JointMoments.of(b, u, model.n_u, tr, model.angle_outputs, model.angle_inputs,
                           evaluator=compiled(model).evaluator)


def propagate_many(model: Model, means: ArrayLike, covs: ArrayLike, transform: Transform | None = None,
                   executor=None) -> Moments:
    """Moments for K noise-free input Gaussians at once (one batched evaluation).

    Parameters
    ----------
    means : (K, n_u)
    covs : (K, n_u, n_u)

    executor : Executor, optional
        As in :func:`propagate`.

    Returns
    -------
    Moments
        ``mean`` (K, n_y), ``cov`` (K, n_y, n_y), ``cross_cov`` (K, n_y, n_u).
    """
    tr = _check_transform(transform)
    if model.n_v:
        raise ModelError("propagate_many takes noise-free models; stack the noise into the inputs")
    M = np.asarray(means, dtype=float)
    P = np.asarray(covs, dtype=float)
    if M.ndim != 2 or M.shape[1] != model.n_u:
        raise ShapeError(f"means must have shape (K, {model.n_u}), got {M.shape}")
    if P.shape != (M.shape[0], model.n_u, model.n_u):
        raise ShapeError(f"covs must have shape {(M.shape[0], model.n_u, model.n_u)}, got {P.shape}")
    _validate_batch(M, P)
    return _checked_batch(model, tr, M, P, executor)


def _checked_batch(model: Model, tr: Transform, means: np.ndarray, covs: np.ndarray, executor) -> Moments:
    """``tr.moments`` with the final guard: a NaN or inf moment is an error, never a number."""
    cm = compiled(model)
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported just below
        tr.check_angles(cm, means, covs, model.angle_outputs)
        b = tr.moments(cm, means, covs, model.angle_outputs, executor)
    check_moments_finite(cm, b, means, tr)
    return b


def _validate_batch(M: np.ndarray, P: np.ndarray) -> None:
    """Batched checks of K means and covariances; the per-state checks only name the culprit."""
    if M.shape[0] == 0:
        raise ShapeError("means must hold at least one state")
    finite = np.isfinite(M).all() and np.isfinite(P).all()
    scale = np.maximum(np.abs(P).max(axis=(1, 2)), np.finfo(float).tiny)
    with np.errstate(over="ignore", invalid="ignore"):  # entries near 1.8e308: the slow path names them
        asym = np.abs(P - P.transpose(0, 2, 1)).max(axis=(1, 2))
        ok = finite and np.all(asym <= SYMMETRY_RTOL * scale)
        if ok:
            try:
                eig_min = np.linalg.eigvalsh(0.5 * P + 0.5 * P.transpose(0, 2, 1))[:, 0]
                ok = bool(np.all(eig_min >= -PSD_RTOL * scale))
            except np.linalg.LinAlgError:
                ok = False
    if ok:
        return
    for k in range(M.shape[0]):  # slow path: find and name the first bad state
        as_vector(M[k], f"means[{k}]")
        as_covariance(P[k], f"covs[{k}]")
