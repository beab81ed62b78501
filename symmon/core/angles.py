"""Angles: wrapping, circular means, and the angle-aware steps of conditioning and fusion.

An angle is defined modulo 2π, so a bearing whose distribution straddles ±π (a target
behind the sensor) has samples near +π *and* near −π.  Treated as real numbers they
have a mean near 0 and a variance near π², both meaningless.  A model declares its
angles (``Model(..., angles={i})``, output indices or input symbols) and then:

- every transform takes the *circular* mean of an angle output, either
  atan2(Σ wₖ sin θₖ, Σ wₖ cos θₖ) (UT, Gauss–Hermite) or, with respect to a reference
  point r, r + Σ wₖ wrap(θₖ − r) (Monte Carlo, with r = g(E u)); for a distribution
  symmetric about its mean direction the two coincide, in general they differ by
  O(E e³) in the residual e;
- it wraps the residuals θ − E θ to (−π, π] before it forms Cov y and Cov(y, u);
- it returns the mean wrapped to (−π, π];
- conditioning (Lemma 7.1) and fusion wrap the innovation: a measurement 2π away from
  its prediction is the same measurement (:meth:`symmon.Gaussian.condition`,
  :func:`symmon.fuse`, both with ``angles=...``).

An output that looks like an angle (atan2, possibly scaled or plus noise) but is not
declared is checked: when the points of UT or Gauss–Hermite, or a pilot sample under
Monte Carlo, lie on both sides of its cut, an :class:`~symmon.errors.AngleWarning` names
the output and ``angles=`` (once per model and output; see
:func:`symmon.transforms.base.warn_angle_cut`).

This module holds the numerical pieces; it depends only on numpy so that the Gaussian
and the transforms can both use it.

References
----------
K. V. Mardia, P. E. Jupp, *Directional Statistics*, Wiley, 2000, Sec. 2.2 (the mean
direction). doi:10.1002/9780470316979
D. F. Crouse, "Cubature/unscented/sigma point Kalman filtering with angular measurement
models", FUSION 2015 (wrapped residuals in sigma-point filters).
"""

from __future__ import annotations

from typing import Iterable

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from ..errors import ShapeError, SymmonError

__all__ = [
    "wrap_casadi",
    "circle_point",
    "wrap_angle",
    "angle_diff",
    "circular_mean",
    "angle_indices",
    "wrap_components",
    "unwrap_near",
    "innovation",
]

#: Mean resultant length (relative to Σ|w|) below which the circular mean is undefined:
#: the weighted unit vectors cancel to rounding, e.g. angles spread evenly on the circle.
RESULTANT_RTOL = 1e-12


def wrap_angle(a: ArrayLike) -> np.ndarray:
    """Wrap angles to (−π, π].

    Examples
    --------
    >>> wrap_angle([3 * np.pi / 2, -np.pi, np.pi]).round(6).tolist()
    [-1.570796, 3.141593, 3.141593]
    """
    out = np.mod(np.asarray(a, dtype=float) + np.pi, 2 * np.pi) - np.pi
    # np.mod maps +π to −π; keep +π, which is the closed end of (−π, π].
    return np.where(out == -np.pi, np.pi, out)


def wrap_casadi(a: ca.SX | ca.MX) -> ca.SX | ca.MX:
    """:func:`wrap_angle` in a CasADi graph (generated C, compiled kernels and filter steps).

    A floor-based mod, as ``np.mod``: (a + π) − 2π ⌊(a + π)/2π⌋ − π, with −π mapped to +π,
    the closed end of (−π, π].
    """
    two_pi = 2 * np.pi
    s = a + np.pi
    out = s - two_pi * ca.floor(s / two_pi) - np.pi
    return ca.if_else(out == -np.pi, np.pi, out)


def circle_point(y: ca.SX) -> tuple[ca.SX, ca.SX]:
    """(sin y, cos y) of an angle output y, for its circular mean.

    An output that is atan2(a, b) itself (a bearing) has them as a / r and b / r with
    r = hypot(a, b): two divisions instead of a sine and a cosine, which cost as much as
    the atan2 and the rest of the model together (perf on the GMTI kernel), equal to
    within an ulp or two.  At a = b = 0, where atan2 gives 0, they are 0 and 1, as
    sin 0 and cos 0.  Any other output (an atan2 plus noise, a scaled one) keeps sin and cos.
    """
    if y.is_symbolic() or y.op() != ca.OP_ATAN2:
        return ca.sin(y), ca.cos(y)
    a, b = y.dep(0), y.dep(1)
    r = ca.hypot(a, b)
    return ca.if_else(r > 0, a / r, 0), ca.if_else(r > 0, b / r, 1)


def angle_diff(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """The signed angle a − b wrapped to (−π, π]: the shortest way from b to a.

    Examples
    --------
    >>> round(float(angle_diff(3.1, -3.1)), 6)   # not 6.2
    -0.083185
    """
    return wrap_angle(np.asarray(a, dtype=float) - np.asarray(b, dtype=float))


def circular_mean(angles: ArrayLike, weights: ArrayLike | None = None,
                  reference: ArrayLike | None = None, axis: int = 0) -> np.ndarray:
    """The weighted circular mean of angles, wrapped to (−π, π].

    Without a reference it is the mean direction atan2(Σ wₖ sin θₖ, Σ wₖ cos θₖ)
    (Mardia & Jupp, Sec. 2.2.1); with a reference r it is the mean of the angles
    unwrapped next to r, r + Σ wₖ wrap(θₖ − r) / Σ wₖ, which is what a single-pass
    (Monte Carlo) accumulation computes.  Both are invariant to adding 2π to any θₖ.

    Parameters
    ----------
    angles : array_like
        The angles in radians; the samples lie along ``axis``.
    weights : array_like, shape (N,), optional
        Weights of the N samples (equal when omitted).  They may be negative (the
        unscented transform's) but must not sum to zero; they are normalised by their sum.
    reference : array_like, optional
        A reference angle (broadcast against the result) for the reference form.
    axis : int, default 0
        The sample axis of ``angles``.

    Returns
    -------
    ndarray
        ``angles`` reduced along ``axis``.

    Raises
    ------
    ShapeError
        If ``weights`` does not match the length of ``axis`` or is not finite.
    SymmonError
        If the weights sum to zero, or (without a reference) if the mean resultant
        vector vanishes, so that the mean direction is undefined.

    Examples
    --------
    >>> float(circular_mean([np.pi - 0.1, -np.pi + 0.1]))   # not 0
    3.141592653589793
    >>> round(float(circular_mean([3.0, -3.0, 3.1], [0.25, 0.25, 0.5], reference=np.pi)), 6)
    3.120796
    """
    th = np.asarray(angles, dtype=float)
    if th.ndim == 0:
        th = th.reshape(1)
    ax = axis % th.ndim
    n = th.shape[ax]
    if n == 0:
        raise ShapeError("angles must not be empty")
    w = np.full(n, 1.0 / n) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (n,):
        raise ShapeError(f"weights must have shape ({n},) to match angles along axis {axis}, got {w.shape}")
    if not np.all(np.isfinite(w)) or not np.all(np.isfinite(th)):
        raise ShapeError("angles and weights must be finite")
    total = float(w.sum())
    if abs(total) <= RESULTANT_RTOL * float(np.abs(w).sum()):
        raise SymmonError(f"weights sum to {total:.3g}: the weighted mean is undefined")
    w = w / total
    shape = [1] * th.ndim
    shape[ax] = n
    wb = w.reshape(shape)
    if reference is not None:
        r = np.asarray(reference, dtype=float)
        rb = np.expand_dims(r, ax) if r.ndim == th.ndim - 1 and r.ndim > 0 else r
        return wrap_angle(r + np.sum(wb * wrap_angle(th - rb), axis=ax))
    s = np.sum(wb * np.sin(th), axis=ax)
    c = np.sum(wb * np.cos(th), axis=ax)
    if np.any(np.hypot(s, c) <= RESULTANT_RTOL * float(np.abs(w).sum())):
        raise SymmonError(
            "the circular mean is undefined: the weighted unit vectors cancel (mean resultant "
            "length 0, e.g. angles spread evenly around the circle); pass a reference angle"
        )
    return np.arctan2(s, c)


def angle_indices(angles: Iterable[int] | int | None, dim: int, name: str = "angles") -> tuple[int, ...]:
    """Validate component indices that are angles: sorted, unique, non-negative.

    Negative indices count from the end, as in numpy.

    Raises
    ------
    ShapeError
        On a non-integer, an index out of range for ``dim``, or a duplicate, naming ``name``.
    """
    if angles is None:
        return ()
    arr = np.atleast_1d(np.asarray(list(angles) if not np.isscalar(angles) else angles))
    if arr.size == 0:
        return ()
    if arr.dtype.kind not in "iu":
        raise ShapeError(f"{name} must hold integer component indices, got {arr.tolist()}")
    if np.any(arr < -dim) or np.any(arr >= dim):
        raise ShapeError(f"{name} {arr.tolist()} out of range for dimension {dim}")
    arr = np.where(arr < 0, arr + dim, arr)
    if len(set(arr.tolist())) != arr.size:
        raise ShapeError(f"{name} has duplicate indices: {arr.tolist()}")
    return tuple(sorted(int(i) for i in arr))


def wrap_components(x: ArrayLike, idx: Iterable[int]) -> np.ndarray:
    """A copy of the vector ``x`` with the components ``idx`` wrapped to (−π, π]."""
    out = np.array(x, dtype=float)
    ix = list(idx)
    if ix:
        out[..., ix] = wrap_angle(out[..., ix])
    return out


def unwrap_near(x: ArrayLike, reference: ArrayLike, idx: Iterable[int]) -> np.ndarray:
    """A copy of ``x`` whose angle components ``idx`` are moved by multiples of 2π to
    within π of the same components of ``reference``: r + wrap(x − r).

    This puts estimates of an angle on one branch before a linear operation (fusion).
    """
    out = np.array(x, dtype=float)
    ref = np.asarray(reference, dtype=float)
    ix = list(idx)
    if ix:
        out[..., ix] = ref[..., ix] + wrap_angle(out[..., ix] - ref[..., ix])
    return out


def innovation(value: ArrayLike, predicted: ArrayLike, idx: Iterable[int]) -> np.ndarray:
    """The innovation value − predicted with the angle components ``idx`` wrapped.

    Examples
    --------
    >>> innovation([10.0, 3.1], [9.0, -3.1], [1]).round(6).tolist()
    [1.0, -0.083185]
    """
    d = np.asarray(value, dtype=float) - np.asarray(predicted, dtype=float)
    return wrap_components(d, idx)
