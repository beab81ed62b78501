"""Checks of plain arrays, below every other check of :mod:`symmon.core`: whether float
arrays are finite (the transforms' and filters' test of every batch and result) and a
read-only copy for a result to expose.  They need no model and no Gaussian, so the
transforms' base reads them without the models' module (:mod:`symmon.core.checks` has
the checks of models and Gaussians)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["all_finite", "readonly"]


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
