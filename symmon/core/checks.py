"""Checks of arguments shared by the estimators and the filters: a model, a Gaussian of
the right dimension, a noise covariance that fits a model; and read-only result arrays."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ArgumentTypeError, ShapeError
from .gaussian import Gaussian, as_covariance
from .model import Model

__all__ = ["all_finite", "check_model", "check_gaussian", "noise_cov", "readonly"]


#: Entries from which :func:`all_finite` sums an array instead of a dot product:
#: OpenBLAS runs a longer dot product on its own threads (from 10⁴ entries), which then
#: spin for a while and take the cores from the threads of symmon's next compiled call
#: (a 10⁴-Gaussian batch kernel ran 1.6 times slower after one).
DOT_MAX = 8192


def all_finite(*arrays: np.ndarray) -> bool:
    """Whether every entry of the float arrays is finite.

    Σ a² (or, for arrays of more than :data:`DOT_MAX` entries, Σ a) is finite exactly
    when every entry is, unless it overflows (entries beyond about 1e154), which the
    entry-by-entry test then decides: one dot product per small array, a quarter of the
    cost of ``np.isfinite(a).all()`` on the small arrays of one Gaussian."""
    return all(math.isfinite(np.vdot(a, a) if a.size <= DOT_MAX else _sum(a)) or bool(np.isfinite(a).all())
               for a in arrays)


def _sum(a: np.ndarray) -> float:
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow or inf − inf: the entry test decides
        return a.sum()


def readonly(a: ArrayLike) -> np.ndarray:
    """A read-only float copy of ``a`` (results expose their arrays; freezing a copy cannot
    affect the caller's array)."""
    arr = np.array(a, dtype=float)  # own copy: freezing it cannot affect the caller
    arr.setflags(write=False)
    return arr


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
