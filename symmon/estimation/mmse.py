"""Closed-form MMSE estimators of distance functions of a Gaussian state.

Given the Kalman estimate :math:`\\hat x` and its error covariance :math:`P` (the first stage,
e.g. :class:`symmon.filters.gaussian.linear.KalmanFilter`), the MMSE estimate of a function :math:`f(x)` is the
conditional mean :math:`E[f(x)]` with :math:`x \\sim N(\\hat x, P)` (the second stage). For the
functions below that mean has a closed form:

============================  ========================================================================  =========
function                      MMSE estimate                                                             paper
============================  ========================================================================  =========
:func:`abs_value`             :math:`\\mu(1-2\\Phi(-\\mu/\\sigma)) + 2\\sigma\\varphi(\\mu/\\sigma)`            Lemma 1
:func:`abs_linear`            Lemma 1 with :math:`\\mu = a^T\\hat x + b,\\ \\sigma^2 = a^T P a`             Theorem 1
:func:`distance_on_line`      :math:`|x - c|`                                                           Example 1
:func:`point_line_distance`   :math:`|a x_1 + b x_2 + c| / \\sqrt{a^2 + b^2}`                            Example 2
:func:`point_plane_distance`  the same in 3-D                                                           Example 3
:func:`quadratic`             :math:`\\hat x^T A \\hat x + \\mathrm{tr}(AP) + b^T\\hat x + c`               Theorem 2
:func:`bilinear`              :math:`\\hat x^T B \\hat y + \\mathrm{tr}(B P_{yx})`                         Theorem 3
:func:`inner_product`         :math:`\\hat x^T \\hat y + \\mathrm{tr} P_{xy}`                              Example 4
:func:`squared_distance`      :math:`\\|\\hat x - \\hat y\\|^2 + \\mathrm{tr}(P_{xx}+P_{yy}-P_{xy}-P_{yx})`  Example 4
============================  ========================================================================  =========

The MSE of each estimate (its conditional variance :math:`E f^2 - (E f)^2`) is given by the
``*_mse`` companions. :func:`norm` (the paper's *range*), :func:`bearing` and :func:`cosine_angle` are the paper's
*composite* estimators (Section 6): each inner linear, bilinear or quadratic form of a composite
function is replaced by its MMSE estimate. They are not the MMSE estimates of the composite
function; they agree with it to first order in :math:`P` only.

All functions broadcast over leading axes: ``xhat`` may be ``(..., n)`` with ``P``
``(..., n, n)`` (e.g. a whole Kalman trajectory, or many Monte Carlo runs). A 0-d result is
returned as a Python ``float``.

References
----------
M. Song, W. Choi, V. Shin, "Minimum Mean Square Error Estimation of Distance Functions under
the Kalman Filtering Framework" (the distance paper): Lemma 1, Theorem 1, Examples 1-4,
Theorem 2, Lemma 2, Theorem 3, Example 7, Section 7.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import erfcx

from ..errors import ArgumentError, CovarianceError, ShapeError
from ..core.gaussian import PSD_RTOL, SYMMETRY_RTOL

__all__ = [
    "abs_value",
    "abs_value_mse",
    "abs_linear",
    "abs_linear_mse",
    "distance_on_line",
    "distance_on_line_mse",
    "point_line_distance",
    "point_line_distance_mse",
    "point_plane_distance",
    "point_plane_distance_mse",
    "quadratic",
    "quadratic_mse",
    "quadratic_mse_gap",
    "bilinear",
    "inner_product",
    "squared_distance",
    "squared_distance_mse",
    "norm",
    "bearing",
    "cosine_angle",
]

_SQRT_2_OVER_PI = math.sqrt(2.0 / math.pi)

Result = float | np.ndarray


# --------------------------------------------------------------------------- validation


def _out(a: np.ndarray) -> Result:
    a = np.asarray(a, dtype=float)
    return float(a) if a.ndim == 0 else a


def _as_array(x: ArrayLike, name: str, err: type[ValueError] = ShapeError) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} must be a real array, got {x!r}") from exc
    if not np.all(np.isfinite(arr)):
        raise err(f"{name} contains NaN or inf")
    return arr


def _as_scalar(x: ArrayLike, name: str) -> float:
    arr = _as_array(x, name)
    if arr.ndim != 0:
        raise ShapeError(f"{name} must be a scalar, got shape {arr.shape}")
    return float(arr)


def _as_vec(x: ArrayLike, name: str, n: int | None = None) -> np.ndarray:
    """A finite array of vectors, shape (..., n)."""
    arr = _as_array(x, name)
    if arr.ndim < 1:
        raise ShapeError(f"{name} must be a vector (..., n), got a scalar")
    if n is not None and arr.shape[-1] != n:
        raise ShapeError(f"{name} must have length {n} in its last axis, got shape {arr.shape}")
    if arr.shape[-1] == 0:
        raise ShapeError(f"{name} must not be empty")
    return arr


def _as_matrix(M: ArrayLike, name: str, shape: tuple[int, int]) -> np.ndarray:
    """A finite coefficient matrix of exactly the given shape."""
    arr = _as_array(M, name)
    if arr.shape != shape:
        raise ShapeError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


def _as_cross(P: ArrayLike, name: str, nx: int, ny: int) -> np.ndarray:
    """A finite array of cross-covariances, shape (..., nx, ny); no symmetry required."""
    arr = _as_array(P, name, CovarianceError)
    if arr.ndim < 2 or arr.shape[-2:] != (nx, ny):
        raise ShapeError(f"{name} must have shape (..., {nx}, {ny}), got {arr.shape}")
    return arr


def _check_psd(arr: np.ndarray, name: str) -> np.ndarray:
    """Check symmetry and PSD of a stack of square matrices; return them symmetrised."""
    scale = np.max(np.abs(arr), axis=(-2, -1), keepdims=True)
    scale = np.maximum(scale, np.finfo(float).tiny)
    asym = np.abs(arr - np.swapaxes(arr, -1, -2))
    if np.any(asym > SYMMETRY_RTOL * scale):
        worst = float(np.max(asym / scale))
        raise CovarianceError(f"{name} is not symmetric: max |P - P^T| / max |P| = {worst:.3g}")
    sym = 0.5 * (arr + np.swapaxes(arr, -1, -2))
    low = np.linalg.eigvalsh(sym)[..., 0]
    if np.any(low < -PSD_RTOL * scale[..., 0, 0]):
        raise CovarianceError(
            f"{name} is not positive semi-definite: smallest eigenvalue {float(np.min(low)):.6g}"
        )
    return sym


def _as_cov(P: ArrayLike, name: str, n: int) -> np.ndarray:
    """A stack of symmetric PSD covariances, shape (..., n, n)."""
    arr = _as_array(P, name, CovarianceError)
    if arr.ndim < 2 or arr.shape[-2:] != (n, n):
        raise ShapeError(f"{name} must have shape (..., {n}, {n}), got {arr.shape}")
    return _check_psd(arr, name)


def _as_var(v: ArrayLike, name: str) -> np.ndarray:
    arr = _as_array(v, name, CovarianceError)
    if np.any(arr < 0):
        raise CovarianceError(f"{name} must be >= 0, got minimum {float(np.min(arr)):.6g}")
    return arr


def _batch(*named: tuple[str, tuple[int, ...]]) -> tuple[int, ...]:
    """Broadcast the batch shapes of several arguments, naming them on failure."""
    try:
        return np.broadcast_shapes(*(s for _, s in named))
    except ValueError as exc:
        desc = ", ".join(f"{n} batch shape {s}" for n, s in named)
        raise ShapeError(f"incompatible batch shapes: {desc}") from exc


def _joint_cov(Pxx: np.ndarray, Pyy: np.ndarray, Pxy: np.ndarray) -> np.ndarray:
    """Check that [[Pxx, Pxy], [Pyx, Pyy]] is a valid joint covariance."""
    shape = _batch(("Pxx", Pxx.shape[:-2]), ("Pyy", Pyy.shape[:-2]), ("Pxy", Pxy.shape[:-2]))
    nx, ny = Pxx.shape[-1], Pyy.shape[-1]
    joint = np.empty(shape + (nx + ny, nx + ny))
    joint[..., :nx, :nx] = Pxx
    joint[..., nx:, nx:] = Pyy
    joint[..., :nx, nx:] = Pxy
    joint[..., nx:, :nx] = np.swapaxes(Pxy, -1, -2)
    return _check_psd(joint, "the joint covariance [[Pxx, Pxy], [Pxy^T, Pyy]]")


def _gauss(xhat: ArrayLike, P: ArrayLike, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    x = _as_vec(xhat, "xhat", n)
    Pm = _as_cov(P, "P", x.shape[-1])
    _batch(("xhat", x.shape[:-1]), ("P", Pm.shape[:-2]))
    return x, Pm


# --------------------------------------------------------------- Lemma 1, Theorem 1


def _abs_moments(mu: np.ndarray, var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E|x| and Var|x| for x ~ N(mu, var), computed without cancellation.

    Write E|x| = |mu| + d with d = E|x| - |E x| >= 0. Lemma 1 gives
    d = sigma sqrt(2/pi) exp(-t^2) - |mu| erfc(t), t = |mu| / (sigma sqrt 2); with the scaled
    erfcx(t) = exp(t^2) erfc(t) this is exp(-t^2) (sigma sqrt(2/pi) - |mu| erfcx(t)), which
    neither underflows nor cancels for |mu| >> sigma. Then
    Var|x| = mu^2 + sigma^2 - (|mu| + d)^2 = sigma^2 - d (2|mu| + d), whose terms are small when
    the subtraction E x^2 - (E|x|)^2 would cancel.
    """
    mu, var = np.broadcast_arrays(np.asarray(mu, float), np.clip(np.asarray(var, float), 0.0, None))
    amu = np.abs(mu)
    sigma = np.sqrt(var)
    pos = sigma > 0
    safe = np.where(pos, sigma, 1.0)  # avoid 0/0; the sigma = 0 branch is |mu| exactly
    with np.errstate(over="ignore", under="ignore"):
        t = amu / (safe * math.sqrt(2.0))
        d = np.exp(-t * t) * (safe * _SQRT_2_OVER_PI - amu * erfcx(t))
    d = np.where(pos, np.clip(d, 0.0, None), 0.0)
    mean = amu + d
    mse = np.clip(var - d * (2.0 * amu + d), 0.0, None)
    return mean, mse


def abs_value(mean: ArrayLike, var: ArrayLike) -> Result:
    """MMSE estimate :math:`E|x|` for :math:`x \\sim N(\\mu, \\sigma^2)` (Lemma 1, eq. (8)).

    .. math:: E|x| = \\mu\\,(1 - 2\\Phi(-\\mu/\\sigma)) + 2\\sigma\\varphi(\\mu/\\sigma)

    Parameters
    ----------
    mean : array_like
        :math:`\\mu`, the estimate of x.
    var : array_like
        :math:`\\sigma^2 \\ge 0`, broadcast against ``mean``. ``var = 0`` gives :math:`|\\mu|`.

    Returns
    -------
    float or ndarray

    Raises
    ------
    ShapeError
        ``mean`` and ``var`` do not broadcast, or ``mean`` is not finite.
    CovarianceError
        ``var`` is negative or not finite.

    Examples
    --------
    >>> round(abs_value(0.0, 1.0), 12)  # sqrt(2/pi)
    0.797884560803
    >>> abs_value(-3.0, 0.0)
    3.0
    """
    mu = _as_array(mean, "mean")
    v = _as_var(var, "var")
    _batch(("mean", mu.shape), ("var", v.shape))
    return _out(_abs_moments(mu, v)[0])


def abs_value_mse(mean: ArrayLike, var: ArrayLike) -> Result:
    """MSE of :func:`abs_value`: :math:`E x^2 - (E|x|)^2 = \\mu^2 + \\sigma^2 - (E|x|)^2`.

    Computed as :math:`\\sigma^2 - d(2|\\mu| + d)` with :math:`d = E|x| - |\\mu|`, which does not
    cancel when :math:`|\\mu| \\gg \\sigma`. Parameters and errors as in :func:`abs_value`.

    Examples
    --------
    >>> round(abs_value_mse(0.0, 1.0), 12)  # 1 - 2/pi
    0.363380227632
    """
    mu = _as_array(mean, "mean")
    v = _as_var(var, "var")
    _batch(("mean", mu.shape), ("var", v.shape))
    return _out(_abs_moments(mu, v)[1])


def _linear_form(a: ArrayLike, b: ArrayLike, xhat: ArrayLike, P: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of aᵀx + b (eq. (9))."""
    av = _as_vec(a, "a")
    if av.ndim != 1:
        raise ShapeError(f"a must be a 1-D coefficient vector, got shape {av.shape}")
    bs = _as_scalar(b, "b")
    x, Pm = _gauss(xhat, P, av.shape[0])
    mu = x @ av + bs
    var = np.einsum("...ij,i,j->...", Pm, av, av)
    mu, var = np.broadcast_arrays(mu, var)
    return mu, var


def abs_linear(a: ArrayLike, b: ArrayLike, xhat: ArrayLike, P: ArrayLike) -> Result:
    """MMSE estimate of :math:`|a^T x + b|`, :math:`x \\sim N(\\hat x, P)` (Theorem 1, eq. (10)).

    Lemma 1 with :math:`\\mu = a^T \\hat x + b` and :math:`\\sigma^2 = a^T P a` (eq. (9)).

    Parameters
    ----------
    a : array_like, shape (n,)
    b : float
    xhat : array_like, shape (..., n)
    P : array_like, shape (..., n, n)
        Symmetric PSD error covariance.

    Returns
    -------
    float or ndarray, shape (...)

    Raises
    ------
    ShapeError, CovarianceError

    Examples
    --------
    >>> abs_linear([1.0, -1.0], 0.0, [2.0, 2.0], [[0.5, 0.0], [0.0, 0.5]]) == abs_value(0.0, 1.0)
    True
    """
    return _out(_abs_moments(*_linear_form(a, b, xhat, P))[0])


def abs_linear_mse(a: ArrayLike, b: ArrayLike, xhat: ArrayLike, P: ArrayLike) -> Result:
    """MSE of :func:`abs_linear` (:func:`abs_value_mse` of the linear form, Theorem 1)."""
    return _out(_abs_moments(*_linear_form(a, b, xhat, P))[1])


def _line_moments(xhat: ArrayLike, P: ArrayLike, c: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    x = _as_array(xhat, "xhat")
    v = _as_var(P, "P")
    cc = _as_array(c, "c")
    _batch(("xhat", x.shape), ("P", v.shape), ("c", cc.shape))
    return _abs_moments(x - cc, v)


def distance_on_line(xhat: ArrayLike, P: ArrayLike, c: ArrayLike = 0.0) -> Result:
    """MMSE estimate of the distance :math:`|x - c|` on a line (Example 1, eq. (11)).

    Parameters
    ----------
    xhat : array_like
        Estimate of the scalar position x (any shape, e.g. a trajectory ``(K,)``).
    P : array_like
        Its error variance (>= 0), broadcast against ``xhat``.
    c : array_like, default 0
        The given point (or sequence of points), broadcast against ``xhat``.

    Returns
    -------
    float or ndarray

    Examples
    --------
    >>> distance_on_line(5.0, 0.0, c=2.0)
    3.0
    """
    return _out(_line_moments(xhat, P, c)[0])


def distance_on_line_mse(xhat: ArrayLike, P: ArrayLike, c: ArrayLike = 0.0) -> Result:
    """MSE of :func:`distance_on_line` (Example 1)."""
    return _out(_line_moments(xhat, P, c)[1])


def _normalised_plane(coefs: tuple[ArrayLike, ...], names: str) -> tuple[np.ndarray, float]:
    """Unit normal and offset of a line / plane sum(coef_i x_i) + offset = 0."""
    *normal, offset = (_as_scalar(v, name) for v, name in zip(coefs, names))
    norm = math.hypot(*normal)
    if norm == 0.0:
        lead = ", ".join(names[:-1])
        raise ArgumentError(f"the coefficients {lead} must not all be zero (no line or plane)")
    return np.asarray(normal) / norm, offset / norm


def point_line_distance(
    xhat: ArrayLike, P: ArrayLike, a: ArrayLike, b: ArrayLike, c: ArrayLike
) -> Result:
    """MMSE estimate of the distance :math:`|a x_1 + b x_2 + c| / \\sqrt{a^2 + b^2}` from a point
    to the line :math:`a x_1 + b x_2 + c = 0` (Example 2, eqs. (12)-(14)).

    Parameters
    ----------
    xhat : array_like, shape (..., 2)
    P : array_like, shape (..., 2, 2)
    a, b, c : float
        Line coefficients; ``a`` and ``b`` not both zero.

    Returns
    -------
    float or ndarray, shape (...)

    Examples
    --------
    >>> point_line_distance([3.0, 4.0], [[0.0, 0.0], [0.0, 0.0]], 1.0, 0.0, 0.0)
    3.0
    """
    normal, offset = _normalised_plane((a, b, c), ("a", "b", "c"))
    return abs_linear(normal, offset, xhat, P)


def point_line_distance_mse(
    xhat: ArrayLike, P: ArrayLike, a: ArrayLike, b: ArrayLike, c: ArrayLike
) -> Result:
    """MSE of :func:`point_line_distance` (Example 2)."""
    normal, offset = _normalised_plane((a, b, c), ("a", "b", "c"))
    return abs_linear_mse(normal, offset, xhat, P)


def point_plane_distance(
    xhat: ArrayLike, P: ArrayLike, a: ArrayLike, b: ArrayLike, c: ArrayLike, d: ArrayLike
) -> Result:
    """MMSE estimate of the distance :math:`|a x_1 + b x_2 + c x_3 + d| / \\sqrt{a^2+b^2+c^2}`
    from a point to a plane (Example 3, eqs. (15)-(17)).

    Parameters
    ----------
    xhat : array_like, shape (..., 3)
    P : array_like, shape (..., 3, 3)
    a, b, c, d : float
        Plane coefficients; ``a``, ``b``, ``c`` not all zero.

    Returns
    -------
    float or ndarray, shape (...)
    """
    normal, offset = _normalised_plane((a, b, c, d), ("a", "b", "c", "d"))
    return abs_linear(normal, offset, xhat, P)


def point_plane_distance_mse(
    xhat: ArrayLike, P: ArrayLike, a: ArrayLike, b: ArrayLike, c: ArrayLike, d: ArrayLike
) -> Result:
    """MSE of :func:`point_plane_distance` (Example 3)."""
    normal, offset = _normalised_plane((a, b, c, d), ("a", "b", "c", "d"))
    return abs_linear_mse(normal, offset, xhat, P)


# ------------------------------------------------------------- Theorems 2, 3, Lemma 2


def _quadratic_args(
    A: ArrayLike, xhat: ArrayLike, P: ArrayLike, b: ArrayLike | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    x, Pm = _gauss(xhat, P)
    n = x.shape[-1]
    Am = _as_matrix(A, "A", (n, n))
    bv = np.zeros(n) if b is None else _as_vec(b, "b", n)
    if bv.ndim != 1:
        raise ShapeError(f"b must be a 1-D vector of length {n}, got shape {bv.shape}")
    return Am, x, Pm, bv


def quadratic(
    A: ArrayLike, xhat: ArrayLike, P: ArrayLike, b: ArrayLike | None = None, c: ArrayLike = 0.0
) -> Result:
    """MMSE estimate of the quadratic form :math:`x^T A x + b^T x + c` (Theorem 2, eq. (26)).

    .. math:: E[x^T A x + b^T x + c] = \\hat x^T A \\hat x + \\mathrm{tr}(AP) + b^T \\hat x + c

    Parameters
    ----------
    A : array_like, shape (n, n)
        Any square matrix (only its symmetric part matters).
    xhat : array_like, shape (..., n)
    P : array_like, shape (..., n, n)
    b : array_like, shape (n,), optional
    c : float, default 0

    Returns
    -------
    float or ndarray, shape (...)

    Examples
    --------
    >>> quadratic(np.eye(2), [1.0, 2.0], np.eye(2))  # E||x||^2 = ||xhat||^2 + tr P
    7.0
    """
    Am, x, Pm, bv = _quadratic_args(A, xhat, P, b)
    cs = _as_scalar(c, "c")
    value = np.einsum("...i,ij,...j->...", x, Am, x) + np.einsum("ij,...ji->...", Am, Pm)
    return _out(value + x @ bv + cs)


def quadratic_mse(A: ArrayLike, xhat: ArrayLike, P: ArrayLike, b: ArrayLike | None = None) -> Result:
    """MSE of :func:`quadratic`, i.e. :math:`\\mathrm{Var}(x^T A x + b^T x)` (Theorem 2).

    .. math:: 2\\,\\mathrm{tr}(A_s P A_s P) + 4\\,g^T P g,
        \\qquad A_s = (A + A^T)/2,\\quad g = A_s \\hat x + b/2.

    With :math:`x = \\hat x + e`, the form is :math:`e^T A_s e + (2A_s\\hat x + b)^T e` plus a
    constant; the two terms are uncorrelated (odd Gaussian moments vanish), the first has variance
    :math:`2\\,\\mathrm{tr}((A_s P)^2)` and the second :math:`(2g)^T P (2g)`. The constant ``c``
    does not change the MSE. Parameters as in :func:`quadratic`.
    """
    Am, x, Pm, bv = _quadratic_args(A, xhat, P, b)
    As = 0.5 * (Am + Am.T)
    AP = np.einsum("ij,...jk->...ik", As, Pm)
    g = x @ As.T + 0.5 * bv
    return _out(2.0 * np.einsum("...ij,...ji->...", AP, AP) + 4.0 * np.einsum("...i,...ij,...j->...", g, Pm, g))


def quadratic_mse_gap(A: ArrayLike, xhat: ArrayLike, P: ArrayLike) -> Result:
    """MSE of the plug-in :math:`\\hat x^T A \\hat x` minus MSE of :func:`quadratic` (Lemma 2, eq. (29)).

    The plug-in estimate is biased by :math:`-\\mathrm{tr}(AP)`; since the MMSE estimate is the
    conditional mean, the MSE gap is the squared bias :math:`(\\mathrm{tr}\\,AP)^2`. The same holds
    with a linear term and a constant, which both estimators share.

    Parameters
    ----------
    A : array_like, shape (n, n)
    xhat : array_like, shape (..., n)
        Only its shape is used (the gap does not depend on the estimate).
    P : array_like, shape (..., n, n)

    Returns
    -------
    float or ndarray, shape (...)
    """
    Am, x, Pm, _ = _quadratic_args(A, xhat, P, None)
    shape = _batch(("xhat", x.shape[:-1]), ("P", Pm.shape[:-2]))
    tr = np.einsum("ij,...ji->...", Am, Pm)
    return _out(np.broadcast_to(tr * tr, shape))


def bilinear(B: ArrayLike, xhat: ArrayLike, yhat: ArrayLike, Pxy: ArrayLike) -> Result:
    """MMSE estimate of the bilinear form :math:`x^T B y` (Theorem 3, eq. (34)).

    .. math:: E[x^T B y] = \\hat x^T B \\hat y + \\mathrm{tr}(B P_{yx}),
        \\qquad P_{xy} = E[(x - \\hat x)(y - \\hat y)^T],\\ P_{yx} = P_{xy}^T.

    Parameters
    ----------
    B : array_like, shape (n_x, n_y)
    xhat : array_like, shape (..., n_x)
    yhat : array_like, shape (..., n_y)
    Pxy : array_like, shape (..., n_x, n_y)
        Error cross-covariance (e.g. :meth:`symmon.filters.gaussian.linear.KalmanResult.cross_cov`).

    Returns
    -------
    float or ndarray, shape (...)

    Examples
    --------
    >>> bilinear([[1.0, 0.0], [0.0, 1.0]], [1.0, 0.0], [0.0, 1.0], [[0.5, 0.0], [0.0, 0.25]])
    0.75
    """
    x = _as_vec(xhat, "xhat")
    y = _as_vec(yhat, "yhat")
    Bm = _as_matrix(B, "B", (x.shape[-1], y.shape[-1]))
    Pc = _as_cross(Pxy, "Pxy", x.shape[-1], y.shape[-1])
    _batch(("xhat", x.shape[:-1]), ("yhat", y.shape[:-1]), ("Pxy", Pc.shape[:-2]))
    # tr(B P_yx) = sum_ij B_ij (P_xy)_ij
    return _out(np.einsum("...i,ij,...j->...", x, Bm, y) + np.einsum("ij,...ij->...", Bm, Pc))


def inner_product(xhat: ArrayLike, yhat: ArrayLike, Pxy: ArrayLike) -> Result:
    """MMSE estimate of the inner product :math:`x^T y` (Example 4, eq. (35)):
    :math:`\\hat x^T \\hat y + \\mathrm{tr}\\,P_{xy}`.

    Parameters
    ----------
    xhat, yhat : array_like, shape (..., n)
    Pxy : array_like, shape (..., n, n)

    Returns
    -------
    float or ndarray, shape (...)
    """
    x = _as_vec(xhat, "xhat")
    y = _as_vec(yhat, "yhat", x.shape[-1])
    return bilinear(np.eye(x.shape[-1]), x, y, Pxy)


def _joint_pair(
    xhat: ArrayLike, yhat: ArrayLike, Pxx: ArrayLike, Pyy: ArrayLike, Pxy: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Validated estimates and covariances of two jointly Gaussian vectors of one dimension."""
    x = _as_vec(xhat, "xhat")
    n = x.shape[-1]
    y = _as_vec(yhat, "yhat", n)
    Px = _as_cov(Pxx, "Pxx", n)
    Py = _as_cov(Pyy, "Pyy", n)
    Pc = _as_cross(Pxy, "Pxy", n, n)
    _joint_cov(Px, Py, Pc)
    _batch(
        ("xhat", x.shape[:-1]), ("yhat", y.shape[:-1]),
        ("Pxx", Px.shape[:-2]), ("Pyy", Py.shape[:-2]), ("Pxy", Pc.shape[:-2]),
    )
    return x, y, Px, Py, Pc


def _difference(
    xhat: ArrayLike, yhat: ArrayLike, Pxx: ArrayLike, Pyy: ArrayLike, Pxy: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """Estimate and error covariance of x - y (eq. (36)), after checking the joint covariance."""
    x, y, Px, Py, Pc = _joint_pair(xhat, yhat, Pxx, Pyy, Pxy)
    Pd = Px + Py - Pc - np.swapaxes(Pc, -1, -2)
    return x - y, Pd


def squared_distance(
    xhat: ArrayLike, yhat: ArrayLike, Pxx: ArrayLike, Pyy: ArrayLike, Pxy: ArrayLike
) -> Result:
    """MMSE estimate of the squared Euclidean distance :math:`\\|x - y\\|^2` (Example 4, eq. (37)).

    .. math:: \\|\\hat x - \\hat y\\|^2 + \\mathrm{tr}(P_{xx} + P_{yy} - P_{xy} - P_{yx})

    Parameters
    ----------
    xhat, yhat : array_like, shape (..., n)
    Pxx, Pyy : array_like, shape (..., n, n)
        Error covariances of x and y.
    Pxy : array_like, shape (..., n, n)
        Error cross-covariance; the joint covariance must be PSD.

    Returns
    -------
    float or ndarray, shape (...)
    """
    d, Pd = _difference(xhat, yhat, Pxx, Pyy, Pxy)
    return _out(np.sum(d * d, axis=-1) + np.trace(Pd, axis1=-2, axis2=-1))


def squared_distance_mse(
    xhat: ArrayLike, yhat: ArrayLike, Pxx: ArrayLike, Pyy: ArrayLike, Pxy: ArrayLike
) -> Result:
    """MSE of :func:`squared_distance`: :func:`quadratic_mse` with A = I applied to
    :math:`x - y \\sim N(\\hat x - \\hat y, P_{xx} + P_{yy} - P_{xy} - P_{yx})` (eqs. (31), (36))."""
    d, Pd = _difference(xhat, yhat, Pxx, Pyy, Pxy)
    return quadratic_mse(np.eye(d.shape[-1]), d, Pd)


# ------------------------------------------------------- composite estimators (Section 6)


def norm(xhat: ArrayLike, P: ArrayLike) -> Result:
    """Composite estimate of the norm :math:`\\|x\\|`, the paper's *range* (Section 6.2, eq. (53)):
    :math:`\\sqrt{\\hat x^T \\hat x + \\mathrm{tr}\\,P}`.

    The squared norm inside the root is replaced by its MMSE estimate (Theorem 2 with A = I).
    By Jensen's inequality it over-estimates :math:`E\\|x\\|`, while the plug-in
    :math:`\\|\\hat x\\|` under-estimates it. (It is not called ``range``, which would
    shadow the builtin.)

    Parameters
    ----------
    xhat : array_like, shape (..., n)
    P : array_like, shape (..., n, n)

    Returns
    -------
    float or ndarray, shape (...)

    Examples
    --------
    >>> norm([3.0, 4.0], np.zeros((2, 2)))
    5.0
    """
    x, Pm = _gauss(xhat, P)
    return _out(np.sqrt(np.sum(x * x, axis=-1) + np.trace(Pm, axis1=-2, axis2=-1)))


def bearing(xhat: ArrayLike, P: ArrayLike) -> Result:
    """Composite estimate of the bearing angle :math:`\\theta = \\operatorname{atan2}(x_2, x_1)`
    (Section 7, eq. (53)).

    The paper estimates :math:`\\tan\\theta = x_2 / x_1`, a composite of two *linear* forms whose
    MMSE estimates are :math:`\\hat x_2` and :math:`\\hat x_1`; the composite estimate of the
    tangent is therefore :math:`\\hat x_2 / \\hat x_1`, identical to the plug-in (as the paper
    notes). We return the angle :math:`\\operatorname{atan2}(\\hat x_2, \\hat x_1) \\in (-\\pi, \\pi]`
    instead of the tangent, because the tangent loses the quadrant and is infinite at
    :math:`\\hat x_1 = 0`. ``P`` does not change the value; it is validated so that the
    signature matches the other composite estimators.

    Parameters
    ----------
    xhat : array_like, shape (..., 2)
    P : array_like, shape (..., 2, 2)

    Returns
    -------
    float or ndarray, shape (...)
        Angle in radians.

    Raises
    ------
    ValueError
        If some :math:`\\hat x = 0`, where the bearing is undefined.

    Examples
    --------
    >>> round(bearing([1.0, 1.0], np.eye(2)), 12)
    0.785398163397
    """
    x, _ = _gauss(xhat, P, 2)
    if np.any(np.all(x == 0.0, axis=-1)):
        raise ArgumentError("xhat must not be the origin: the bearing is undefined there")
    return _out(np.arctan2(x[..., 1], x[..., 0]))


def cosine_angle(
    xhat: ArrayLike, yhat: ArrayLike, Pxx: ArrayLike, Pyy: ArrayLike, Pxy: ArrayLike
) -> Result:
    """Composite estimate of the cosine of the angle between x and y (Example 7, eq. (51)).

    .. math:: \\frac{\\hat x^T \\hat y + \\mathrm{tr}\\,P_{xy}}
        {\\sqrt{(\\|\\hat x\\|^2 + \\mathrm{tr}\\,P_{xx})(\\|\\hat y\\|^2 + \\mathrm{tr}\\,P_{yy})}}

    The inner product and both squared norms are replaced by their MMSE estimates (Theorems 2,
    3). By the Cauchy-Schwarz inequality :math:`E[x^T y]^2 \\le E\\|x\\|^2 E\\|y\\|^2`, so the value
    lies in [-1, 1] whenever the joint covariance is valid.

    Parameters
    ----------
    xhat, yhat : array_like, shape (..., n)
    Pxx, Pyy : array_like, shape (..., n, n)
    Pxy : array_like, shape (..., n, n)
        Error cross-covariance; the joint covariance must be PSD.

    Returns
    -------
    float or ndarray, shape (...)

    Raises
    ------
    ShapeError, CovarianceError
    ValueError
        If a denominator is zero (x or y is the origin with certainty).
    """
    x, y, Px, Py, Pc = _joint_pair(xhat, yhat, Pxx, Pyy, Pxy)
    num = np.sum(x * y, axis=-1) + np.trace(Pc, axis1=-2, axis2=-1)
    den2 = (np.sum(x * x, axis=-1) + np.trace(Px, axis1=-2, axis2=-1)) * (
        np.sum(y * y, axis=-1) + np.trace(Py, axis1=-2, axis2=-1)
    )
    if np.any(den2 <= 0.0):
        raise ArgumentError("the angle is undefined: E||x||^2 or E||y||^2 is zero")
    # Clip only rounding beyond Cauchy-Schwarz, never a real excess (the joint cov is checked).
    return _out(np.clip(num / np.sqrt(den2), -1.0, 1.0))
