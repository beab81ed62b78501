"""The Gaussian distribution: validated mean and covariance, sampling, marginals,
conditioning (Lemma 7.1 of the lecture) and sensor fusion.

References
----------
F. Gustafsson, G. Hendeby, *Parameter Estimation using Nonlinear Transformations*,
Sensor Fusion lecture notes (Lemma 7.1 and the sensor fusion formula).
"""

from __future__ import annotations

import warnings
from typing import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from .angles import angle_indices, innovation, unwrap_near, wrap_components
from ..errors import (
    ArgumentError,
    ArgumentTypeError,
    CovarianceError,
    ShapeError,
    SingularMatrixError,
    SymmonError,
    plain_repr,
)
from ..latex import latex_number

__all__ = ["Gaussian", "fuse", "as_covariance", "as_vector", "check_indices", "float_array"]

#: Relative tolerance of the symmetry and positive-semi-definiteness checks.
SYMMETRY_RTOL = 1e-10
PSD_RTOL = 1e-10

_PSD_MODES = ("raise", "clip", "jitter")


def float_array(x: ArrayLike, name: str, error: type[SymmonError] = ShapeError) -> np.ndarray:
    """``x`` as a float array, or ``error`` naming ``name``: for a value that is not a
    number (a string, None, a ragged list), a complex number (refused, not cast to its
    real part) or a number that overflows a float (a 400-digit integer), instead of
    numpy's TypeError, ValueError or ComplexWarning and Python's OverflowError."""
    try:
        if np.iscomplexobj(x):
            raise error(f"{name} holds complex numbers: it must be real")
        return np.asarray(x, dtype=float)
    except OverflowError as exc:
        raise error(f"{name} holds a number too large for a float (|x| > {np.finfo(float).max:.3g}): {exc}") from None
    except SymmonError:
        raise
    except (TypeError, ValueError) as exc:
        raise error(f"{name} must hold real numbers: {exc}") from None


def as_vector(x: ArrayLike, name: str, dim: int | None = None) -> np.ndarray:
    """Return ``x`` as a finite 1-D float array, or raise a :class:`ShapeError` naming ``name``."""
    arr = float_array(x, name, ShapeError)
    if arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim != 1:
        raise ShapeError(f"{name} must be a vector (1-D), got shape {arr.shape}")
    if dim is not None and arr.shape[0] != dim:
        raise ShapeError(f"{name} must have length {dim}, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ShapeError(f"{name} contains NaN or inf: {arr}")
    return arr


def as_covariance(
    P: ArrayLike, name: str, dim: int | None = None, psd: str = "raise"
) -> np.ndarray:
    """Validate a covariance matrix and return it as a float array.

    Parameters
    ----------
    P : array_like
        A scalar (for dimension 1) or a square matrix.
    name : str
        The argument name used in error messages.
    dim : int, optional
        The required dimension.
    psd : {"raise", "clip", "jitter"}
        What to do with a matrix that is not positive semi-definite: raise a
        :class:`CovarianceError`; clip negative eigenvalues to zero (with a warning
        that gives the clipped mass); or add ``eps * I`` (with a warning that gives eps).

    Notes
    -----
    Asymmetry up to ``SYMMETRY_RTOL`` times the largest entry (rounding) is removed by
    P ← (P + Pᵀ)/2; anything larger raises, so a covariance is never symmetrized beyond
    rounding without an error.  The repairs ``"clip"`` and ``"jitter"`` always warn.

    Raises
    ------
    ShapeError, CovarianceError
    """
    if psd not in _PSD_MODES:
        raise ArgumentError(f"psd must be one of {_PSD_MODES}, got {psd!r}")
    arr = float_array(P, name, CovarianceError)
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ShapeError(f"{name} must be a square matrix, got shape {arr.shape}")
    if dim is not None and arr.shape[0] != dim:
        raise ShapeError(f"{name} must be {dim}x{dim}, got {arr.shape[0]}x{arr.shape[1]}")
    if not np.all(np.isfinite(arr)):
        raise CovarianceError(f"{name} contains NaN or inf")
    scale = max(float(np.max(np.abs(arr))), np.finfo(float).tiny)
    with np.errstate(over="ignore"):  # |P - Pᵀ| = inf for entries ±1e308: asymmetric all the same
        asym = float(np.max(np.abs(arr - arr.T)))
    if asym > SYMMETRY_RTOL * scale:
        raise CovarianceError(
            f"{name} is not symmetric: max |P - P^T| = {asym:.3g} (scale {scale:.3g})"
        )
    # Remove rounding-level asymmetry only (checked above).  Halving first cannot
    # overflow (P + Pᵀ is inf for entries near 1.8e308) and gives the same bits, subnormals aside.
    arr = 0.5 * arr + 0.5 * arr.T
    eig = _eigvalsh(arr, name)
    tol = PSD_RTOL * scale
    if eig.size and eig[0] < -tol:
        if psd == "raise":
            raise CovarianceError(
                f"{name} is not positive semi-definite: smallest eigenvalue {eig[0]:.6g}"
                " (use psd='clip' or psd='jitter' to repair it explicitly)"
            )
        if psd == "clip":
            w, V = np.linalg.eigh(arr)
            clipped = float(-np.sum(w[w < 0]))
            w = np.clip(w, 0.0, None)
            arr = (V * w) @ V.T
            arr = 0.5 * arr + 0.5 * arr.T
            warnings.warn(
                f"{name}: clipped negative eigenvalues to 0 (clipped mass {clipped:.3g})",
                RuntimeWarning,
                stacklevel=3,
            )
        else:
            eps = float(-eig[0] + tol)
            arr = arr + eps * np.eye(arr.shape[0])
            warnings.warn(f"{name}: added jitter eps = {eps:.3g} times I", RuntimeWarning, stacklevel=3)
    return arr


def _eigvalsh(P: np.ndarray, name: str) -> np.ndarray:
    """Eigenvalues of a symmetric P, or a :class:`CovarianceError` naming ``name`` when
    LAPACK fails ("Eigenvalues did not converge") or overflows on extreme entries."""
    if not P.size:
        return np.zeros(0)
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            eig = np.linalg.eigvalsh(P)
    except np.linalg.LinAlgError as exc:
        eig = np.array([np.nan])
        reason = str(exc)
    else:
        reason = "non-finite eigenvalues"
    if not np.all(np.isfinite(eig)):
        mag = np.abs(P[P != 0])
        span = f"{mag.min():.3g} to {mag.max():.3g}" if mag.size else "0"
        raise CovarianceError(
            f"{name}: the eigen-decomposition failed ({reason}); its entries range over "
            f"{span} in magnitude, beyond what double precision can decompose: rescale the units"
        )
    return eig


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def _frozen_reduce(obj: object) -> tuple:
    """``__reduce__`` of an immutable ``__slots__`` object: its slots, restored as they are
    (no validation again, the same bits), so that it pickles (e.g. to a Dask worker)."""
    names = [s for c in type(obj).__mro__ for s in getattr(c, "__slots__", ())]
    return _frozen_restore, (type(obj), {s: getattr(obj, s) for s in names if hasattr(obj, s)})


def _frozen_restore(cls: type, state: dict) -> object:
    """The object of :func:`_frozen_reduce`, its arrays read-only again."""
    obj = cls.__new__(cls)
    for name, value in state.items():
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
        object.__setattr__(obj, name, value)
    return obj


class Gaussian:
    """A multivariate Gaussian N(mean, cov), immutable and validated.

    Parameters
    ----------
    mean : array_like, shape (n,)
    cov : array_like, shape (n, n)
        Symmetric positive semi-definite covariance (a scalar is accepted for n = 1).
    psd : {"raise", "clip", "jitter"}, default "raise"
        Repair policy for a covariance that is not PSD; see :func:`as_covariance`.

    Raises
    ------
    ShapeError
        For an empty, non-numeric or non-finite mean (a 400-digit integer included).
    CovarianceError
        For a covariance that is not numeric, finite, symmetric or PSD, or whose
        eigen-decomposition fails (entries at the ends of the float range).

    Examples
    --------
    >>> Gaussian([95.1, 95.1], [[954, -854], [-854, 954]])
    N([95.1, 95.1], [[954, -854], [-854, 954]])
    """

    __slots__ = ("_mean", "_cov")

    def __init__(self, mean: ArrayLike, cov: ArrayLike, psd: str = "raise") -> None:
        # Copy: freezing below must not make the caller's array read-only.
        m = as_vector(mean, "mean").copy()
        if m.size == 0:
            raise ShapeError("mean is empty: a Gaussian needs at least one component")
        P = as_covariance(cov, "cov", dim=m.shape[0], psd=psd).copy()
        m.setflags(write=False)
        P.setflags(write=False)
        object.__setattr__(self, "_mean", m)
        object.__setattr__(self, "_cov", P)

    def __setattr__(self, key, value):  # immutable
        raise AttributeError("Gaussian is immutable")

    __reduce__ = _frozen_reduce  # pickles: __setattr__ refuses the default restore

    @classmethod
    def from_std(cls, mean: ArrayLike, std: ArrayLike) -> "Gaussian":
        """Build N(mean, diag(std**2)) from standard deviations."""
        s = as_vector(std, "std")
        if np.any(s < 0):
            raise CovarianceError(f"std must be non-negative, got {s}")
        with np.errstate(over="ignore"):
            var = s**2
        if not np.all(np.isfinite(var)):
            i = int(np.argmax(~np.isfinite(var)))
            raise CovarianceError(f"std[{i}] = {s[i]:.3g}: its square, the variance, overflows a float")
        return cls(mean, np.diag(var))

    @property
    def mean(self) -> np.ndarray:
        """The mean vector, shape (n,)."""
        return self._mean

    @property
    def cov(self) -> np.ndarray:
        """The covariance matrix, shape (n, n)."""
        return self._cov

    @property
    def dim(self) -> int:
        """The dimension n."""
        return int(self._mean.shape[0])

    def sqrt_cov(self) -> np.ndarray:
        """A square root L with L Lᵀ = cov: Cholesky, or eigh for a singular PSD cov."""
        return matrix_sqrt(self._cov)

    def sample(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """Draw ``n`` samples, shape (n, dim), from a seeded generator."""
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ArgumentError(f"n must be a positive integer, got {plain_repr(n)}")
        gen = as_generator(rng)
        z = gen.standard_normal((int(n), self.dim))
        return self._mean + z @ self.sqrt_cov().T

    def _index(self, idx: Iterable[int] | int, name: str = "idx") -> np.ndarray:
        return check_indices(idx, self.dim, name)

    def marginal(self, idx: Sequence[int] | int) -> "Gaussian":
        """The marginal distribution of the components ``idx``."""
        ix = self._index(idx)
        return Gaussian(self._mean[ix], self._cov[np.ix_(ix, ix)])

    @np.errstate(over="ignore", invalid="ignore")  # an overflowing mean is refused by Gaussian()
    def condition(self, idx: Sequence[int] | int, value: ArrayLike,
                  angles: Iterable[int] | None = None) -> "Gaussian":
        """Condition on observed components (Lemma 7.1).

        With x the components not in ``idx`` and y those in ``idx``,
        x̂ = x̂₀ + P^{xy}(P^{yy})⁻¹(y − ŷ), Cov = P^{xx} − P^{xy}(P^{yy})⁻¹P^{yx}.

        Parameters
        ----------
        idx : int or sequence of int
            The observed components.
        value : array_like, shape (len(idx),)
            Their observed values.
        angles : iterable of int, optional
            Components (indices into this Gaussian, observed or not) that are angles.
            The innovation y − ŷ of an observed angle is wrapped to (−π, π] (an angle
            measured at +3.1 with a prediction at −3.1 is 0.083 rad away, not 6.2), and
            the conditional mean of an unobserved angle is returned wrapped.

        Returns
        -------
        Gaussian
            The distribution of the remaining components, in their original order.

        Raises
        ------
        SingularMatrixError
            If P^{yy} is singular.
        """
        iy = self._index(idx)
        ix = np.setdiff1d(np.arange(self.dim), iy)
        if ix.size == 0:
            raise ShapeError("condition: idx covers every component; nothing is left")
        y = as_vector(value, "value", dim=iy.size)
        ang = set(angle_indices(angles, self.dim, "angles"))
        Pyy = self._cov[np.ix_(iy, iy)]
        Pxy = self._cov[np.ix_(ix, iy)]
        K = solve_psd(Pyy, Pxy.T, "P^yy").T
        nu = innovation(y, self._mean[iy], [k for k, i in enumerate(iy) if i in ang])
        mean = wrap_components(self._mean[ix] + K @ nu, [k for k, i in enumerate(ix) if i in ang])
        return Gaussian(mean, _schur_complement(self._cov[np.ix_(ix, ix)], K @ Pxy.T))

    def __repr__(self) -> str:
        m = ", ".join(_fmt(x) for x in self._mean)
        rows = ", ".join("[" + ", ".join(_fmt(x) for x in r) + "]" for r in self._cov)
        return f"N([{m}], [{rows}])"

    def _repr_latex_(self) -> str:
        m = r" \\ ".join(latex_number(x, 3) for x in self._mean)
        P = r" \\ ".join(" & ".join(latex_number(x, 3) for x in r) for r in self._cov)
        return (
            r"$\mathcal{N}\left(\begin{bmatrix}" + m + r"\end{bmatrix},\ "
            r"\begin{bmatrix}" + P + r"\end{bmatrix}\right)$"
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Gaussian):
            return NotImplemented
        return bool(np.array_equal(self._mean, other._mean) and np.array_equal(self._cov, other._cov))

    def __hash__(self) -> int:
        return hash((self._mean.tobytes(), self._cov.tobytes()))


def check_indices(idx: Iterable[int] | int, dim: int, name: str = "idx") -> np.ndarray:
    """``idx`` as distinct non-negative indices into a vector of length ``dim`` (negative
    ones count from the end), or a :class:`ShapeError` naming ``name``."""
    ix = np.atleast_1d(np.asarray(idx))
    if ix.size == 0:  # before the dtype check: np.asarray([]) is float
        raise ShapeError(f"{name} must not be empty")
    if ix.dtype.kind not in "iu":
        raise ShapeError(f"{name} must hold integer indices, got {ix}")
    if np.any(ix < -dim) or np.any(ix >= dim):
        raise ShapeError(f"{name} {ix.tolist()} out of range for dimension {dim}")
    ix = np.where(ix < 0, ix + dim, ix)
    if len(set(ix.tolist())) != ix.size:
        raise ShapeError(f"{name} has duplicate indices: {ix.tolist()}")
    return ix


def as_generator(rng: np.random.Generator | int | None, name: str = "rng") -> np.random.Generator:
    """A ``numpy.random.Generator`` from a generator, a non-negative integer seed or None.

    Raises
    ------
    ArgumentError
        For anything else (a negative seed, a float, a string), naming ``name``.
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is not None and (isinstance(rng, (bool, np.bool_)) or not isinstance(rng, (int, np.integer)) or rng < 0):
        raise ArgumentError(f"{name} must be a numpy Generator, a non-negative integer seed or None, got {plain_repr(rng)}")
    return np.random.default_rng(rng)


#: Negative eigenvalues of a Schur complement P_xx − P_xy P_yy⁻¹ P_yx down to −SCHUR_RTOL
#: times the size of the terms it subtracts are rounding, and are set to 0.
SCHUR_RTOL = 1e-8


def _schur_complement(Pxx: np.ndarray, sub: np.ndarray) -> np.ndarray:
    """P_xx − sub with sub = P_xy P_yy⁻¹ P_yx, symmetric and PSD up to rounding.

    The difference of two nearly equal matrices (an observation that pins the state
    down: a posterior near 0) carries the rounding of its *terms*, not of its tiny
    result.  That rounding is the relative error of P_yy (moments from a transform are
    accurate to ~1e-12, the ut2 weights of ±1e6 cost six digits) amplified by
    cond(P_yy) ≤ 1e13 (:func:`solve_psd`), so eigenvalues down to
    −SCHUR_RTOL · max(‖P_xx‖, ‖sub‖) are rounding and clipped to 0; anything more
    negative means the joint covariance was not PSD, and raises.

    Raises
    ------
    CovarianceError
        If the complement has an eigenvalue below −SCHUR_RTOL times its terms' scale.
    """
    cov = Pxx - sub
    cov = 0.5 * cov + 0.5 * cov.T
    w, V = np.linalg.eigh(cov)
    if w[0] >= -PSD_RTOL * max(float(np.max(np.abs(cov))), np.finfo(float).tiny):
        return cov  # PSD as it stands (within the Gaussian's own tolerance)
    scale = max(float(np.max(np.abs(Pxx))), float(np.max(np.abs(sub))), np.finfo(float).tiny)
    if w[0] < -SCHUR_RTOL * scale:
        raise CovarianceError(
            f"the conditional covariance P_xx - P_xy P_yy^-1 P_yx is not positive semi-definite: "
            f"smallest eigenvalue {w[0]:.3g}, beyond rounding of its terms (scale {scale:.3g}); "
            "the joint covariance is not PSD"
        )
    cov = (V * np.clip(w, 0.0, None)) @ V.T
    return 0.5 * cov + 0.5 * cov.T


def matrix_sqrt(P: np.ndarray) -> np.ndarray:
    """A square root L of a PSD matrix with L Lᵀ = P.

    Cholesky when P is positive definite.  For a singular PSD P (an input with zero
    variance, perfectly correlated inputs) the Cholesky recursion is continued with zero
    columns where the pivot vanishes: the limit of the Cholesky factors of P + εI as
    ε → 0, so the points of UT, Gauss–Hermite and Monte Carlo do not jump when a variance
    reaches 0, and the rule on the informative subspace is the rule of the reduced
    problem.  If that fails (P indefinite beyond rounding), the symmetric
    eigen-decomposition with negative eigenvalues clipped to 0 is used.
    """
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    with np.errstate(over="ignore", invalid="ignore"):  # extreme entries: checked below
        L = _semidefinite_cholesky(P)
        if L is not None:
            return L
        try:
            w, V = np.linalg.eigh(P)
        except np.linalg.LinAlgError as exc:
            raise CovarianceError(f"no square root of the covariance: the eigen-decomposition failed ({exc})") from None
        L = V * np.sqrt(np.clip(w, 0.0, None))
    if not np.all(np.isfinite(L)):
        raise CovarianceError("no square root of the covariance: its eigen-decomposition is not finite")
    return L


def _semidefinite_cholesky(P: np.ndarray) -> np.ndarray | None:
    """Cholesky with zero pivots allowed, or None when L Lᵀ does not reproduce P."""
    n = P.shape[0]
    scale = max(float(np.max(np.abs(np.diag(P)))), np.finfo(float).tiny) if n else 1.0
    tol = 10 * n * np.finfo(float).eps * scale  # a pivot at rounding level is a zero
    L = np.zeros_like(P, dtype=float)
    for j in range(n):
        d = P[j, j] - L[j, :j] @ L[j, :j]
        if d <= tol:
            continue  # no variance left in this coordinate: a zero column
        L[j, j] = np.sqrt(d)
        L[j + 1:, j] = (P[j + 1:, j] - L[j + 1:, :j] @ L[j, :j]) / L[j, j]
    if np.max(np.abs(L @ L.T - P), initial=0.0) > 1e3 * tol:
        return None
    return L


def solve_psd(A: np.ndarray, B: np.ndarray, name: str) -> np.ndarray:
    """Solve A X = B for a symmetric positive definite A, or raise naming ``name``."""
    scale = max(float(np.max(np.abs(A))), np.finfo(float).tiny) if A.size else 1.0
    cond = np.linalg.cond(A) if A.size else 1.0
    if not np.isfinite(cond) or cond > 1e13:
        raise SingularMatrixError(f"{name} is singular (condition number {cond:.3g}, scale {scale:.3g})")
    return np.linalg.solve(A, B)


def fuse(*gaussians: Gaussian, angles: Iterable[int] | None = None) -> Gaussian:
    """Fuse independent estimates of the same quantity (the sensor fusion formula).

    P = (Σ_k P_k⁻¹)⁻¹,  x̂ = P Σ_k P_k⁻¹ x̂_k.

    Parameters
    ----------
    *gaussians : Gaussian
        The estimates, all of the same dimension.
    angles : iterable of int, optional
        Components that are angles.  Each estimate's angles are first moved by multiples
        of 2π to within π of the first estimate's (x̂₁ + wrap(x̂_k − x̂₁): the innovation
        is wrapped), and the fused angles are returned wrapped to (−π, π].

    Raises
    ------
    ShapeError
        If fewer than one estimate is given or the dimensions differ.
    SingularMatrixError
        If a covariance is singular.

    Examples
    --------
    >>> g = fuse(Gaussian([3.1], [[0.01]]), Gaussian([-3.1], [[0.01]]), angles=[0])
    >>> round(abs(float(g.mean[0])), 6)   # π, not 0
    3.141593
    """
    if len(gaussians) == 0:
        raise ShapeError("fuse needs at least one Gaussian")
    if not all(isinstance(g, Gaussian) for g in gaussians):
        raise ArgumentTypeError("fuse takes Gaussian arguments")
    n = gaussians[0].dim
    if any(g.dim != n for g in gaussians):
        raise ShapeError(f"fuse: dimensions differ: {[g.dim for g in gaussians]}")
    ang = angle_indices(angles, n, "angles")
    ref = gaussians[0].mean
    info = np.zeros((n, n))
    vec = np.zeros(n)
    with np.errstate(over="ignore", invalid="ignore"):  # a covariance near 1e-308: checked below
        for k, g in enumerate(gaussians):
            Pinv = solve_psd(g.cov, np.eye(n), f"covariance of estimate {k}")
            info += Pinv
            vec += Pinv @ unwrap_near(g.mean, ref, ang)
    if not (np.all(np.isfinite(info)) and np.all(np.isfinite(vec))):
        smallest = min(float(np.min(np.diag(g.cov))) for g in gaussians)
        raise CovarianceError(
            f"fuse: the information sum of P_k^-1 overflows (smallest variance {smallest:.3g}): rescale the units"
        )
    P = np.linalg.inv(info)
    P = 0.5 * P + 0.5 * P.T
    return Gaussian(wrap_components(P @ vec, ang), P)
