"""Checks of arguments shared by the estimators and the filters: a model, a Gaussian of
the right dimension, a noise covariance that fits a model (the checks of plain arrays, which
need neither, are :mod:`symmon.core.arrays`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ArgumentTypeError, ShapeError
from .gaussian import Gaussian, as_covariance
from .model import Model

__all__ = ["check_model", "check_gaussian", "noise_cov"]


def check_model(model: Any, name: str) -> Model:
    """``model`` if it is a :class:`Model`, else a TypeError naming ``name``."""
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"{name} must be a symmon.Model, got {type(model).__name__}")
    return model


def check_gaussian(g: Any, name: str, dim: int | None = None) -> Gaussian:
    """``g`` if it is a :class:`Gaussian` (of dimension ``dim``, if given), else a named error."""
    if not isinstance(g, Gaussian):
        raise ArgumentTypeError(f"{name} must be a symmon.Gaussian, got {type(g).__name__}")
    if dim is not None and g.dim != dim:
        raise ShapeError(f"{name} has dimension {g.dim}, expected {dim}")
    return g


def noise_cov(model: Model, R: ArrayLike | None, name: str) -> np.ndarray:
    """R validated against the model: Cov e for its noise symbols, else the additive Cov(e)."""
    if R is None:
        raise ShapeError(f"{name}: the measurement noise covariance is missing")
    dim = model.n_v if model.n_v else model.n_y
    what = "noise symbols" if model.n_v else "outputs (additive noise)"
    try:
        return as_covariance(R, name, dim=dim)
    except ShapeError as exc:
        raise ShapeError(f"{exc}; the model {model.name!r} has {dim} {what}") from exc
