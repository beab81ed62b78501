"""The transform protocol and the moment computations shared by point-based rules.

Every transform works on a *batch* of K Gaussians of w = [u; v] at once: means (K, n_w)
and covariances (K, n_w, n_w).  It returns the mean (K, n_y), the covariance
(K, n_y, n_y) and the cross-covariance Cov(y, w) (K, n_y, n_w).  A single
:func:`symmon.propagate` is a batch of one.
"""

from __future__ import annotations


import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import numpy as np
import sympy as sp

from ..core import dag
from ..core.arrays import all_finite
from ..core.angles import wrap_angle  # re-exported: defined beside the other angle helpers
from ..core.gaussian import PSD_RTOL, SYMMETRY_RTOL, as_covariance, as_vector, matrix_sqrt
from ..errors import (AngleWarning, ArgumentError, ArgumentTypeError, IndefiniteCovarianceError, NonFiniteError,
                      ShapeError)
from .nodes import SPARSE_ABOVE, standard_rule
from .registry import _register

if TYPE_CHECKING:  # annotations only: a rule is handed a compiled model, it never makes one
    from ..compile.compiled import CompiledModel

__all__ = [
    "Transform", "Moments", "wrap_angle", "weighted_moments", "batch_sqrt",
    "evaluate_points", "check_moments_finite", "check_moments_definite", "check_batch", "check_shapes", "DEFINITE_RTOL", "likely_angles", "warn_angle_cut", "pilot_angle_cut",
    "reset_warnings",
]


@dataclass(frozen=True)
class Moments:
    """The moments of a batch of K Gaussians of w, the one result every transform returns.

    Attributes
    ----------
    mean : ndarray (K, n_y)
        E y.
    cov : ndarray (K, n_y, n_y)
        Cov y.
    cross_cov : ndarray (K, n_y, n_w)
        Cov(y, w).
    input_cov : ndarray (K, n_w, n_w) or None
        Cov w as the transform sees it (Monte Carlo: the sample covariance); ``None``
        means the covariances passed in.
    stderr : dict or None
        Standard errors of ``mean``, ``cov`` and ``cross_cov``, the same keys and shapes
        (stochastic transforms only).
    error : dict or None
        An error bound of a deterministic rule's ``mean``, ``cov`` and ``cross_cov``, the
        same keys and shapes (Gauss–Hermite with ``error_estimate=True``: the two-order
        estimate, :func:`symmon.quadrature_error`).
    replicates : list or None
        For each Gaussian of the batch, the independent replicates (Monte Carlo groups:
        :class:`~symmon.transforms.stats.Stats`) that the error bars come from;
        :func:`~symmon.transforms.stats.jackknife` takes one such list.
    evaluations : int
        Evaluations of g (points, samples or expansion points) for the whole batch.
    details : dict
        Rule-specific extras: ``sigma_points`` and ``transformed_points`` (UT),
        ``sparse`` and ``degree`` (Gauss–Hermite), ``n_samples`` (Monte Carlo).
    noise_cross_cov : ndarray (K, n_y, n_v) or None
        Set by :meth:`split`: Cov(y, v), the noise block of Cov(y, w).
    cov_scale : ndarray (K, n_y) or None
        The magnitude each output's variance was summed from, the scale of the rounding
        in Cov y: Σ abs(wᶜᵢ) rᵢ² over the points of a rule with negative weights, the same
        bound for the Taylor rules and exact moments; ``None``: the diagonal of ``cov``
        (a rule with non-negative weights sums non-negative terms).  The template
        :meth:`Transform.moments` tests definiteness against it
        (:func:`check_moments_definite`).
    """

    mean: np.ndarray
    cov: np.ndarray
    cross_cov: np.ndarray
    input_cov: np.ndarray | None = None
    stderr: dict | None = None
    replicates: list | None = None
    evaluations: int = 0
    details: dict = field(default_factory=dict)
    error: dict | None = None
    noise_cross_cov: np.ndarray | None = None
    cov_scale: np.ndarray | None = None

    @property
    def info(self) -> dict:
        """A read-only compatibility view: ``details`` with ``evaluations``, for
        replicates ``groups`` (one list per Gaussian) and ``error_estimate`` (``error``)."""
        out = dict(self.details)
        out["evaluations"] = self.evaluations
        if self.replicates is not None:
            out["groups"] = self.replicates
        if self.error is not None:
            out["error_estimate"] = self.error
        return out

    def __repr__(self) -> str:
        K, n_y = self.mean.shape
        n_x = self.cross_cov.shape[2]
        inputs = f"n_u={n_x}, n_v={self.noise_cross_cov.shape[2]}" if self.noise_cross_cov is not None else f"n_w={n_x}"
        extras = [name for name in ("stderr", "error") if getattr(self, name) is not None]
        return (f"Moments(K={K}, n_y={n_y}, {inputs}, evaluations={self.evaluations}"
                + "".join(f", with {e}" for e in extras) + ")")

    def split(self, n_u: int) -> "Moments":
        """The moments of y with u = w[:n_u] as the input: ``cross_cov``, its standard
        error and error bound become Cov(y, u), ``input_cov`` Cov u, and the rest of
        Cov(y, w) goes to ``noise_cross_cov`` (as :class:`~symmon.JointMoments` holds them)."""
        def u_block(d: dict | None) -> dict | None:
            return None if d is None else {**d, "cross_cov": d["cross_cov"][:, :, :n_u]}

        if self.noise_cross_cov is not None:
            raise ArgumentError("these moments are already split")
        return replace(
            self, cross_cov=self.cross_cov[:, :, :n_u], noise_cross_cov=self.cross_cov[:, :, n_u:],
            input_cov=None if self.input_cov is None else self.input_cov[:, :n_u, :n_u],
            stderr=u_block(self.stderr), error=u_block(self.error),
        )


class Transform(ABC):
    """An abstract moment transform: immutable settings, a batched kernel and declared
    capabilities.

    Subclasses are frozen dataclasses that implement the hook :meth:`_moments` (the
    template :meth:`moments` checks its input and output) and declare what
    the rest of symmon needs to know about them, so that no caller tests for a concrete
    class (docs/architecture.md):

    - ``exact_degree``: the polynomial degree of g up to which the mean is exact for a
      Gaussian input (the covariance is exact to half of it);
    - ``taylor_order``: 1 or 2 for a Taylor rule (the filters build its closed forms);
    - ``stochastic``: the result is random, with ``replicates`` for the error bars
      (then :meth:`replicate_stats` and :meth:`nested_stats` are implemented);
    - :meth:`outer_rule`: points and weights over a Gaussian for the outer integral of
      a conditional expectation (nested integration);
    - :meth:`nested_inner`: the transform used inside a nested rule, where a rule that
      cannot see curvature (TT1) would give Cov E[g | v] no inner part;
    - :meth:`cost`: evaluations of g for one Gaussian of dimension n_w;
    - :meth:`unit_rule`: for a point rule, its points and weights for N(0, I) (the
      filters compile them into their steps);
    - :meth:`check_angles`: the undeclared-angle check for rules that keep no points.
    - :meth:`filter_label`: the name of the Kalman filter built on the rule (EKF, UKF, ...);
    - :meth:`settings`: the rule's settings in words for a dimension (generated-code headers).

    A rule that evaluates g at points does so through :func:`evaluate_points`, so a
    NaN or inf of g is reported with the point; the front ends
    (:func:`symmon.propagate`, :func:`symmon.propagate_many`) then refuse any moment
    that is not finite (:func:`check_moments_finite`).
    """

    exact_degree: ClassVar[float] = 0
    name: ClassVar[str] = "transform"
    stochastic: ClassVar[bool] = False
    #: The order of a Taylor rule (1: TT1, 2: TT2), whose moments are closed forms in
    #: J and H at the mean; ``None`` for other rules.
    taylor_order: ClassVar[int | None] = None
    #: True for a point rule: its moments are weighted sums over points m + L z whose unit
    #: points and weights :meth:`unit_rule` gives (the filters and ``export_c`` compile
    #: them).  Declared, so that no caller builds a rule to learn what kind it is.
    point_rule: ClassVar[bool] = False
    #: The rule's registered short names: ``{name: (summary, factory)}``, where
    #: ``factory(**options)`` builds the rule from the options of
    #: :func:`~symmon.transforms.registry.make` (samples, seed, order, groups), taking only
    #: those it needs.  Registered when the class is created (:meth:`__init_subclass__`).
    presets: ClassVar[dict[str, tuple[str, Callable[..., "Transform"]]]] = {}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Check a concrete rule's declarations and register its presets.

        A rule is concrete when it implements :meth:`_moments`; it must then declare
        :meth:`cost` (the cost model of ``advise`` and the adaptive filter), and a
        ``stochastic`` rule also :meth:`replicate_stats` and :meth:`nested_stats` (its
        error bars and the nested Σ_c).  A missing declaration is a TypeError here, when
        the class is created, not at the first call.
        """
        super().__init_subclass__(**kwargs)
        for final in ("moments", "expectation", "_checked"):
            if final in cls.__dict__:
                raise ArgumentTypeError(f"{cls.__name__} overrides {final}(): implement the hook _moments() instead, "
                                        "so that the checks of Transform.moments always run")
        if getattr(cls, "_moments") is Transform._moments:  # abstract: an intermediate base
            return
        missing = [m for m in ("cost",) if getattr(cls, m) is getattr(Transform, m)]
        if cls.point_rule and cls.unit_rule is Transform.unit_rule:
            missing.append("unit_rule (it declares point_rule)")
        if not cls.point_rule and cls.unit_rule is not Transform.unit_rule:
            missing.append("point_rule = True (it defines unit_rule)")
        if cls.stochastic:
            missing += [m for m in ("replicate_stats", "nested_stats") if getattr(cls, m) is getattr(Transform, m)]
        if missing:
            raise ArgumentTypeError(f"the transform {cls.__name__} does not declare {', '.join(missing)} "
                            "(docs/architecture.md, the Transform contract)")
        for key, (summary, factory) in cls.__dict__.get("presets", {}).items():
            _register(key, summary, factory)

    def moments(self, cm: CompiledModel, means: np.ndarray, covs: np.ndarray,
                angles: frozenset[int] = frozenset(), executor: Any = None, *, validated: bool = False) -> Moments:
        """The moments of y = g(w) for the K Gaussians N(means[k], covs[k]).

        The template of every rule: it checks the batch (shapes against ``cm``, finite
        entries, symmetric positive semi-definite covariances), runs the rule's
        undeclared-angle check, calls the rule's :meth:`_moments`, and refuses any NaN or
        inf moment and any Cov y that is indefinite beyond rounding (a rule with negative
        weights can give one: :func:`check_moments_definite`; a rule that is
        :meth:`semidefinite` by construction needs no test), so that no caller can skip
        the checks.

        Parameters
        ----------
        cm : CompiledModel
            The compiled g of w.
        means : ndarray (K, n_w)
        covs : ndarray (K, n_w, n_w)
        angles : frozenset of int
            The outputs that are angles (circular means, wrapped residuals).
        executor : Executor, optional
            Where stochastic work runs (:class:`~symmon.transforms.executor.Executor`);
            deterministic rules ignore it.
        validated : bool
            The batch was built from :class:`~symmon.Gaussian` objects, which checked their
            covariances when they were made (symmetric, positive semi-definite): only its
            shapes are checked again (:func:`symmon.propagate` of one Gaussian).

        Raises
        ------
        ShapeError, CovarianceError
            A batch that does not fit ``cm`` or is not a batch of Gaussians.
        NonFiniteError
            A moment is NaN or inf.
        IndefiniteCovarianceError
            Cov y of some Gaussian has a negative eigenvalue beyond rounding.
        """
        result = self._checked(cm, means, covs, angles, executor, validated)
        if not self.semidefinite(cm.n_w):
            check_moments_definite(cm, result, means, self)
        return result

    def expectation(self, cm: CompiledModel, means: np.ndarray, covs: np.ndarray,
                    angles: frozenset[int] = frozenset(), executor: Any = None) -> np.ndarray:
        """E y (K, n_y) alone, for a caller that reads nothing else (the inner integral
        of a nested rule, E[g | v]): the checks of :meth:`moments` except the definiteness
        of a Cov y that is not returned.

        Raises
        ------
        ShapeError, CovarianceError, NonFiniteError
            As :meth:`moments`.
        """
        return self._checked(cm, means, covs, angles, executor).mean

    def _checked(self, cm: CompiledModel, means: np.ndarray, covs: np.ndarray,
                 angles: frozenset[int], executor: Any, validated: bool = False) -> Moments:
        """The checked batch through the rule, its moments refused unless finite."""
        means, covs = check_shapes(cm, means, covs) if validated else check_batch(cm, means, covs)
        if type(angles) is not frozenset:
            angles = frozenset(angles)
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported just below
            self.check_angles(cm, means, covs, angles)
            result = self._moments(cm, means, covs, angles, executor)
        check_moments_finite(cm, result, means, self)
        return result

    @abstractmethod
    def _moments(self, cm: CompiledModel, means: np.ndarray, covs: np.ndarray,
                 angles: frozenset[int], executor: Any) -> Moments:
        """The rule itself, on a checked batch (called by :meth:`moments` only)."""

    def degree(self, n: int) -> float:
        """The degree of exactness for Gaussians of dimension ``n`` (default
        :attr:`exact_degree`; a rule whose grid depends on n says so)."""
        return self.exact_degree

    def semidefinite(self, n: int) -> bool:
        """Whether the rule's Cov y is positive semi-definite by construction for Gaussians
        of dimension ``n``: a sum of positive semi-definite terms, which rounding moves by
        n_y·N·eps relative at most, far inside :data:`DEFINITE_RTOL`, so that
        :meth:`moments` need not test it.  Default: a point rule whose covariance weights
        are all non-negative (a rule with a negative one, the UT with κ < 0 or a sparse
        grid, is tested); TT1, TT2 and Monte Carlo say so themselves."""
        return _nonnegative_weights(self, n) if self.point_rule else False

    def for_dimension(self, n: int, max_nodes: int) -> tuple["Transform", str]:
        """This rule with its dimension-dependent choices made for Gaussians of dimension ``n``
        (a grid left to the dimension takes the richer grid while it has at most ``max_nodes``
        nodes), and a word naming the choice ("" when none): what :func:`symmon.advise` times
        and reports is then the rule that runs.  Default: the rule itself and ""."""
        return self, ""

    def cost(self, n_w: int) -> int:
        """Evaluations of g for one Gaussian of dimension ``n_w``."""
        raise NotImplementedError(f"{type(self).__name__} declares no cost model")

    def unit_rule(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Points z (N, n) for N(0, I_n), mean weights and covariance weights, for a rule
        whose moments are weighted sums over the points m + L z; ``None`` otherwise."""
        return None

    def symbolic_unit_rule(self, n: int) -> tuple[sp.Matrix, list, list] | None:
        """:meth:`unit_rule` in exact sympy arithmetic (points as the rows of a matrix, mean
        and covariance weights as lists), for :func:`symmon.symbolic_moments`; ``None``
        when the rule declares none (the floats of :meth:`unit_rule` are then used)."""
        return None

    def filter_label(self) -> str:
        """The name of the Kalman filter whose time and measurement updates use this rule
        (:class:`symmon.NonlinearKalmanFilter`); default ``KF(<repr>)``."""
        return f"KF({self!r})"

    def settings(self, n: int) -> str:
        """The rule's settings in words for dimension ``n``, with any dimension-dependent
        default resolved (the header of :func:`symmon.codegen.export_c`); default: repr."""
        return repr(self)

    def outer_rule(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points (J, n) and weights (J,) of the outer integral over N(mean, cov) in a
        nested rule.  Default: the Gauss–Hermite rule of order 5 (tensor up to 4
        dimensions, sparse above), exact to degree 9 per coordinate."""
        n = mean.shape[0]
        Z, w = standard_rule(n, 5, n > SPARSE_ABOVE)
        return mean + Z @ batch_sqrt(cov[None])[0].T, w

    def nested_inner(self) -> "Transform":
        """The transform for the inner integral of a nested rule (default: itself)."""
        return self

    def check_angles(self, cm: CompiledModel, means: np.ndarray, covs: np.ndarray, angles: frozenset[int]) -> None:
        """Warn about undeclared angles straddling their cut.  Point rules check their
        points in :func:`evaluate_points`; nothing more to do by default."""

    def replicate_stats(self, cm: CompiledModel, mean: np.ndarray, cov: np.ndarray,
                        angles: frozenset[int] = frozenset(), executor: Any = None) -> list:
        """Independent replicates of the statistics of [y; w] (stochastic transforms)."""
        raise NotImplementedError(f"{type(self).__name__} is not stochastic")

    def nested_stats(self, cm: CompiledModel, u_mean: np.ndarray, u_cov: np.ndarray, v_mean: np.ndarray,
                     v_cov: np.ndarray, executor: Any = None) -> list:
        """Replicates of a nested estimate of Cov_v E[g | v] (stochastic transforms)."""
        raise NotImplementedError(f"{type(self).__name__} is not stochastic")


def batch_sqrt(covs: np.ndarray) -> np.ndarray:
    """Square roots L_k L_kᵀ = P_k: batched Cholesky, eigh for singular ones."""
    try:
        return np.linalg.cholesky(covs)
    except np.linalg.LinAlgError:
        return np.stack([matrix_sqrt(P) for P in covs])


def weighted_moments(Y: np.ndarray, X: np.ndarray, mx: np.ndarray, wm: np.ndarray, wc: np.ndarray,
                     angles: frozenset[int], negative: bool | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Moments of weighted points, and the scale of Cov y's rounding.

    Parameters
    ----------
    Y : (K, N, n_y) transformed points
    X : (K, N, n_w) points
    mx : (K, n_w) the input means
    wm, wc : (N,) mean and covariance weights
    angles : output indices that are angles: circular mean, wrapped residuals
    negative : whether some weight of wc is negative, when the rule knows (else tested)

    Returns
    -------
    mean (K, n_y), cov (K, n_y, n_y), cross (K, n_y, n_w)
    cov_scale : (K, n_y) or None
        Σ |wcᵢ| rᵢ² per output when some weight is negative (``Moments.cov_scale``); None
        when none is, where it is the diagonal of ``cov``.
    """
    # Weights sum to 1: centring on the first point keeps digits when the weights are
    # large and of both signs (ut2's are about ±1e6), so a constant output stays exact.
    # Products, then their sum: a matmul's fused multiply-adds would leave ut2's ±1e6-weighted
    # sums of opposite points inexact (|w y| eps), where separate products cancel to zero.
    Y0 = Y[:, :1, :]
    mean = Y0[:, 0] + (wm[:, None] * (Y - Y0)).sum(axis=1)
    if angles:
        idx = sorted(angles)
        s = np.einsum("n,kni->ki", wm, np.sin(Y[..., idx]))
        c = np.einsum("n,kni->ki", wm, np.cos(Y[..., idx]))
        mean[:, idx] = np.arctan2(s, c)
    R = Y - mean[:, None, :]
    if angles:
        R[..., idx] = wrap_angle(R[..., idx])
    D = X - mx[:, None, :]
    # Matrix products (BLAS), not a three-operand einsum: 5x faster at n_w = 128.
    RW = (R * wc[:, None]).transpose(0, 2, 1)
    cov = RW @ R
    half = cov * 0.5
    cov = half + half.transpose(0, 2, 1)  # exactly symmetric, as the einsum was; no overflow
    cross = RW @ D
    if negative is None:
        negative = bool(wc.min() < 0)
    scale = np.abs(wc) @ (R * R) if negative else None
    return mean, cov, cross, scale



def _point_str(cm: CompiledModel, w: np.ndarray) -> str:
    return ", ".join(f"{sym}={x:.6g}" for sym, x in zip(cm.symbols, w))


def _output_str(cm: CompiledModel, i: int) -> str:
    return f"output {i} ({cm.source_exprs[i]})" if i < len(cm.source_exprs) else f"output {i}"


def evaluate_points(cm: CompiledModel, X: np.ndarray, transform: "Transform",
                    angles: frozenset[int] = frozenset()) -> np.ndarray:
    """g at the points X (K, N, n_w) of a rule, shape (K, N, n_y): finite, or an error.

    A single NaN or inf among the transformed points makes every moment NaN or inf,
    so the first point where g is not finite is reported instead (the sampling
    counterpart is Monte Carlo's :class:`~symmon.errors.SamplingError`).  Outputs that
    look like undeclared angles are checked for points on both sides of their cut
    (:func:`warn_angle_cut`).

    Raises
    ------
    NonFiniteError
        Naming the transform, the output and the point.
    """
    K, N, n = X.shape
    if not all_finite(X):
        k, j = np.argwhere(~np.isfinite(X).all(axis=2))[0]
        raise NonFiniteError(
            f"{transform!r}: point {j} of the rule, ({_point_str(cm, X[k, j])}), overflows: the input "
            "mean and spread put it beyond 1.8e308; rescale the units of the inputs"
        )
    Y = cm.eval_g(X.reshape(K * N, n)).reshape(K, N, -1)
    if not all_finite(Y):
        bad = ~np.isfinite(Y)
        k, j, i = np.argwhere(bad)[0]
        raise NonFiniteError(
            f"{transform!r}: {_output_str(cm, i)} is {Y[k, j, i]} at the point "
            f"({_point_str(cm, X[k, j])}), point {j} of {N} of the rule, at {int(bad[k].any(axis=1).sum())} "
            "of its points in all: E y and Cov y would be NaN or inf.  The input distribution "
            "reaches where g is not defined (e.g. sqrt of a negative number): move the mean, "
            "shrink the covariance or change the model"
        )
    warn_angle_cut(cm, Y, angles, transform)
    return Y


@lru_cache(maxsize=256)
def _nonnegative_weights(transform: "Transform", n: int) -> bool:
    rule = transform.unit_rule(n)
    return rule is not None and bool(np.all(np.asarray(rule[2]) >= 0))


def check_shapes(cm: CompiledModel, means: Any, covs: Any) -> tuple[np.ndarray, np.ndarray]:
    """``means`` (K, n_w) and ``covs`` (K, n_w, n_w) as float arrays for ``cm``, their shapes
    checked (for a batch of validated Gaussians; :func:`check_batch` checks the values too).

    Raises
    ------
    ShapeError
    """
    M = np.asarray(means, dtype=float)
    P = np.asarray(covs, dtype=float)
    n = cm.n_w
    if M.ndim != 2 or M.shape[1] != n or P.shape != (M.shape[0], n, n):
        raise ShapeError(f"a batch of Gaussians of {n} variables needs means (K, {n}) and covs (K, {n}, {n}), "
                         f"got {M.shape} and {P.shape}")
    if M.shape[0] == 0:
        raise ShapeError("means must hold at least one state")
    return M, P


def check_batch(cm: CompiledModel, means: Any, covs: Any) -> tuple[np.ndarray, np.ndarray]:
    """``means`` (K, n_w) and ``covs`` (K, n_w, n_w) as float arrays for ``cm``, checked in
    one batched pass: K ≥ 1, finite, symmetric and positive semi-definite within the
    tolerances of :class:`~symmon.Gaussian`.  A bad batch is re-checked state by state only
    to name the first culprit.

    Raises
    ------
    ShapeError, CovarianceError
    """
    M, P = check_shapes(cm, means, covs)
    finite = np.isfinite(M).all() and np.isfinite(P).all()
    scale = np.maximum(np.abs(P).max(axis=(1, 2)), np.finfo(float).tiny)
    with np.errstate(over="ignore", invalid="ignore"):  # entries near 1.8e308: the slow path names them
        asym = np.abs(P - P.transpose(0, 2, 1)).max(axis=(1, 2))
        ok = finite and np.all(asym <= SYMMETRY_RTOL * scale)
        if ok:
            sym = 0.5 * P + 0.5 * P.transpose(0, 2, 1)
            try:
                # A Cholesky factor exists only for a positive definite batch: 6x cheaper than
                # the eigenvalues, which decide a semidefinite or indefinite one.
                np.linalg.cholesky(sym)
            except np.linalg.LinAlgError:
                try:
                    ok = bool(np.all(np.linalg.eigvalsh(sym)[:, 0] >= -PSD_RTOL * scale))
                except np.linalg.LinAlgError:
                    ok = False
    if not ok:
        for k in range(M.shape[0]):  # slow path: find and name the first bad state
            as_vector(M[k], f"means[{k}]")
            as_covariance(P[k], f"covs[{k}]")
    return M, P


def check_moments_finite(cm: CompiledModel, b: Moments, means: np.ndarray, transform: "Transform") -> None:
    """Raise if any moment of a batch is NaN or inf (every transform's final guard).

    With g finite at every point the moments can still overflow: |g| beyond ~1e154
    makes its square, and Cov y, inf.

    Raises
    ------
    NonFiniteError
        Naming the transform, the moment, the output and the input mean.
    """
    if all_finite(b.mean, b.cov, b.cross_cov):
        return
    for label, arr in (("E y", b.mean), ("Cov y", b.cov), ("Cov(y, w)", b.cross_cov)):
        bad = ~np.isfinite(arr)
        if bad.any():
            idx = np.argwhere(bad)[0]
            k, i = idx[0], idx[1]
            entry = ", ".join(str(int(j)) for j in idx[1:])
            raise NonFiniteError(
                f"{transform!r}: {label}[{entry}] is {arr[tuple(idx)]} ({_output_str(cm, i)}) for the input "
                f"mean ({_point_str(cm, means[k])}): the moments overflow (|g| beyond ~1e154 has an "
                "infinite square, or g is not finite where the rule looks): rescale the units"
            )


#: The rounding allowed below zero in the eigenvalues of Cov y scaled by the magnitudes it
#: was summed from (``Moments.cov_scale``: C = D^-1/2 Cov y D^-1/2, D its diagonal).  An entry
#: of a weighted sum over N points carries a rounding error of at most N·eps·√(aⱼ aₖ)
#: (Higham's bound of a dot product, with Cauchy–Schwarz), so C's eigenvalues move by at most
#: n_y·N·eps: 2e-12 for ten outputs and a thousand points, where an indefiniteness due to
#: negative weights is of order 0.1 to 1 (the sum of squares under ut1 in four dimensions:
#: -0.6).  1e-10, the tolerance of an input covariance (``PSD_RTOL``), keeps a PSD but
#: rank-deficient Cov y (two equal outputs, a linear g of rank below n_y) from being refused.
DEFINITE_RTOL = PSD_RTOL


def check_moments_definite(cm: CompiledModel, b: Moments, means: np.ndarray, transform: "Transform") -> None:
    """Raise if the Cov y of some Gaussian of a batch is indefinite beyond rounding.

    The test is scale-invariant: Cov y scaled to C = D^-1/2 Cov y D^-1/2 by D, the
    magnitudes its entries were summed from (``b.cov_scale``, or the diagonal of Cov y),
    must have no eigenvalue below −``DEFINITE_RTOL``, so that changing the units of an
    output changes nothing.  A PSD rule (non-negative weights, Taylor, Monte Carlo) passes
    by construction up to rounding; a rule with negative weights can fail (the UT with
    κ < 0, Gauss–Hermite's sparse grid, the fifth-degree cubature above 4 dimensions), and
    then the covariance is refused rather than returned: no Gaussian, filter or measure
    of nonlinearity can use it.

    Raises
    ------
    IndefiniteCovarianceError
        Naming the transform, the Gaussian, the negative eigenvalue (of Cov y and scaled),
        the direction, and rules with non-negative weights.
    """
    cov = b.cov
    a = np.abs(np.diagonal(cov, axis1=1, axis2=2)) if b.cov_scale is None else b.cov_scale
    # A zero scale holds only zeros (no term was summed); tiny keeps 1/√a finite there, and a
    # nonzero entry beside it is then enormous against it: indefinite, as it must be.
    inv = 1.0 / np.sqrt(np.maximum(a, np.finfo(float).tiny))
    with np.errstate(over="ignore", invalid="ignore"):
        C = cov * inv[:, :, None] * inv[:, None, :]
    n_y = cov.shape[1]
    finite = np.isfinite(C).all(axis=(1, 2))
    try:  # the common case in one batched factorisation: C + tol·I is positive definite
        if finite.all():
            np.linalg.cholesky(C + DEFINITE_RTOL * np.eye(n_y))
            return
    except np.linalg.LinAlgError:
        pass
    lam = np.full(cov.shape[0], -np.inf)
    lam[finite] = np.linalg.eigvalsh(C[finite])[:, 0]
    bad = np.flatnonzero(lam < -DEFINITE_RTOL)
    if bad.size == 0:
        return
    k = int(bad[0])
    ev, vec = np.linalg.eigh(cov[k])
    direction = vec[:, 0] / vec[np.argmax(np.abs(vec[:, 0])), 0]  # its largest component +1
    along = ", ".join(f"{c:+.3g}·y{i}" for i, c in enumerate(direction) if abs(c) > 1e-3)
    weights = ""
    if transform.point_rule:
        wc = transform.unit_rule(means.shape[1])[2]
        if (wc < 0).any():
            weights = f" Its covariance weights in {means.shape[1]} dimensions go down to {wc.min():.3g}."
    raise IndefiniteCovarianceError(
        f"{transform!r}: Cov y of Gaussian {k} of {cov.shape[0]} (input mean {_point_str(cm, means[k])}) is "
        f"indefinite: its smallest eigenvalue is {ev[0]:.6g}, along {along}, {lam[k]:.3g} relative to the "
        f"magnitudes it was summed from (rounding allows {DEFINITE_RTOL:g}).{weights}  A rule with negative "
        "weights does not give a covariance here; use one whose weights are all non-negative: "
        "UT.cubature() or UT(kappa >= 0), GaussHermite(order, sparse=False), TT2(), MonteCarlo(...)"
    )


# --------------------------------------------------------------------------- undeclared angles
#: The once-only warnings already given: ("angle", outputs, symbols, output index) for an
#: AngleWarning (one per model and output), and the rules' own keys (a Gauss–Hermite
#: grid's QuadratureWarning, one per order and dimension).
_WARNED: set[tuple] = set()


def reset_warnings() -> None:
    """Forget which once-only warnings were given (undeclared angles, a rule's fall to
    another grid), so that each is given again: for a fresh start in a notebook or a test."""
    _WARNED.clear()


def likely_angles(cm: CompiledModel, declared: frozenset[int]) -> dict[int, float]:
    """Outputs that look like angles but are not declared: index → half-period of the cut.

    An output looks like an angle when its expression is atan2(·, ·), possibly times a
    number c (a unit change, e.g. to degrees: the cut is then at ±|c|π) and possibly
    plus terms without atan2 (additive noise).
    """
    return _likely_angles(tuple(cm.source_exprs), frozenset(declared))


@lru_cache(maxsize=256)  # a filter calls this at every step with the same model
def _likely_angles(exprs: tuple, declared: frozenset[int]) -> dict[int, float]:
    out = {}
    for i, e in enumerate(exprs):
        if i in declared or not isinstance(e, sp.Basic):
            continue
        # DAG walks (symmon.core.dag): sympy's has() walks the tree, exponential on a traced loop.
        terms = [t for t in sp.Add.make_args(e) if dag.contains(t, sp.atan2)]
        if len(terms) != 1:
            continue
        # c·atan2(·, ·) with c a number: the factors but one atan2 have no symbols.
        factors = sp.Mul.make_args(terms[0])
        angles = [f for f in factors if isinstance(f, sp.atan2)]
        c = sp.Mul(*[f for f in factors if not isinstance(f, sp.atan2)])
        if (len(angles) == 1 and not dag.free_symbols(c) and c.is_number and c != 0
                and _additive_rest(e - terms[0], terms[0])):
            out[i] = float(abs(c)) * np.pi
    return out


def _additive_rest(others: sp.Expr, angle: sp.Expr) -> bool:
    """True when ``others`` is a constant or affine in symbols the angle does not use.

    Additive noise shifts the cut only a little; a term in the angle's own arguments (a
    unit change mixing range and bearing, say) moves it anywhere, and then no cut is guessed.
    """
    syms = dag.free_symbols(others)
    if not syms:
        return True
    if syms & dag.free_symbols(angle) or not dag.is_small([others]):
        return False  # a rest too large for sympy's diff: no cut guessed (this is a hint only)
    return all(sp.diff(others, a, b) == 0 for a in syms for b in syms)


def warn_angle_cut(cm: CompiledModel, Y: np.ndarray, angles: frozenset[int], transform: object) -> None:
    """Warn once per model and output when an undeclared angle's points straddle its cut.

    The points of state k straddle the cut at ±π when some lie above π/2, some below
    −π/2, and the widest gap between them on the circle is not the one across ±π:
    they form one cluster through ±π, which as real numbers has a mean near 0 and a
    variance near π², both wrong.

    Parameters
    ----------
    Y : (K, N, n_y)
        Transformed points (or samples) of each state.
    """
    for i, half in likely_angles(cm, angles).items():
        key = ("angle", cm.source_exprs, cm.symbols, i)
        if key in _WARNED:
            continue
        th = wrap_angle(Y[:, :, i] * (np.pi / half))
        both = (th.max(axis=1) > np.pi / 2) & (th.min(axis=1) < -np.pi / 2)
        if not both.any():
            continue  # the common case, decided without sorting
        th = np.sort(th[both], axis=1)
        inner = np.diff(th, axis=1).max(axis=1)
        across = 2 * np.pi - (th[:, -1] - th[:, 0])
        hit = inner > across
        if hit.any():
            _WARNED.add(key)
            k = int(np.argmax(hit))
            above = int(np.sum(th[k] > np.pi / 2))
            below = int(np.sum(th[k] < -np.pi / 2))
            warnings.warn(
                f"{_output_str(cm, i)} looks like an angle but is not declared, and the points of "
                f"{transform!r} lie on both sides of its cut at ±{half:.6g} ({above} above, {below} "
                "below): its mean and covariance mix values a full turn apart.  Declare it with "
                f"Model(..., angles=[{i}]) to get circular moments",
                AngleWarning, stacklevel=6,
            )


#: Pilot samples per Gaussian for :func:`pilot_angle_cut`.
ANGLE_PILOT = 1000


def pilot_angle_cut(cm: CompiledModel, means: np.ndarray, covs: np.ndarray, angles: frozenset[int],
                    transform: object) -> None:
    """:func:`warn_angle_cut` on ANGLE_PILOT samples of each Gaussian, for a rule that
    keeps statistics only (Monte Carlo).  The pilot has its own fixed seed, apart from
    the rule's streams, so the rule's numbers do not change; it costs nothing for a model
    without undeclared atan2 outputs."""
    if not likely_angles(cm, angles):
        return
    Z = np.random.default_rng(0).standard_normal((ANGLE_PILOT, means.shape[1]))
    X = means[:, None, :] + Z @ batch_sqrt(covs).transpose(0, 2, 1)
    Y = cm.eval_g(X.reshape(-1, X.shape[2])).reshape(X.shape[0], ANGLE_PILOT, -1)
    warn_angle_cut(cm, Y, angles, transform)
