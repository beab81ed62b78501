"""JointMoments: the result of a nonlinear transformation of a Gaussian, the single-point
view of a transform's batched :class:`~symmon.transforms.base.Moments`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import ArgumentError, ShapeError
from ..core.gaussian import Gaussian
from ..latex import latex_number, latex_text

__all__ = ["JointMoments"]


def _fmt_arr(a: np.ndarray) -> str:
    return np.array2string(np.asarray(a), precision=4, suppress_small=False)


@dataclass(frozen=True, eq=False)
class JointMoments:
    """E y, Cov y and Cov(y, u) of y = g(u, v), with what produced them.

    Attributes
    ----------
    mean : ndarray, shape (n_y,)
        E y.
    cov : ndarray, shape (n_y, n_y)
        Cov y.
    cross_cov : ndarray, shape (n_y, n_u)
        Cov(y, u); for a model with noise, the u-block of Cov(y, [u; v]).
    input : Gaussian or GaussianMixture
        The distribution of u (:attr:`joint` and :meth:`condition` use its mean and
        covariance: the Gaussian approximation of [u; y]).
    transform : object
        The transform settings that produced the moments.
    noise_cross_cov : ndarray, shape (n_y, n_v)
        Cov(y, v) (empty for a noise-free model).
    stderr : mapping or None
        Standard errors of ``mean``, ``cov`` and ``cross_cov`` (stochastic transforms only).
    error : mapping or None
        An error bound of ``mean``, ``cov`` and ``cross_cov`` (Gauss–Hermite with
        ``error_estimate=True``, :func:`symmon.quadrature_error`).
    info : mapping
        A read-only view of the details: ``evaluations``, ``evaluator``, ``groups`` (the
        replicates) and the rule's own (``sigma_points``, ``error_estimate``, ...).
    replicates : list or None
        The independent replicates behind ``stderr`` (Monte Carlo groups: their
        statistics of [y; w]), for :func:`~symmon.transforms.stats.jackknife`.
    evaluations : int
        Evaluations of g.
    input_cov : ndarray, shape (n_u, n_u)
        Cov u as the transform sees it: ``input.cov`` for the deterministic rules, the
        sample covariance for Monte Carlo (regressions must use it, or the sampling
        error of Σ_gu does not cancel and biases the residual).
    angles, input_angles : frozenset of int
        The model's angle outputs and angle inputs (``Model(..., angles=...)``); see
        :attr:`joint_angles` and :meth:`condition`.
    """

    mean: np.ndarray
    cov: np.ndarray
    cross_cov: np.ndarray
    input: Gaussian
    transform: Any
    noise_cross_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    stderr: Mapping[str, np.ndarray] | None = None
    error: Mapping[str, np.ndarray] | None = None
    info: Mapping[str, Any] = field(default_factory=dict)
    input_cov: np.ndarray | None = None
    angles: frozenset[int] = frozenset()
    input_angles: frozenset[int] = frozenset()
    replicates: Sequence[Any] | None = None
    evaluations: int = 0

    @classmethod
    def of(cls, b: Any, u: Gaussian, n_u: int, transform: Any, angles: frozenset[int] = frozenset(),
           input_angles: frozenset[int] = frozenset(), **details: Any) -> "JointMoments":
        """The first Gaussian of a batch result ``b`` (:class:`~symmon.transforms.base.Moments`)
        of w = [u; v], with Cov(y, w) split into its u- and v-blocks."""
        if b.noise_cross_cov is not None:
            raise ArgumentError("these moments are already split")

        def first(d: Mapping[str, np.ndarray] | None) -> dict | None:  # u-block of Cov(y, w), as Moments.split
            return None if d is None else {"mean": d["mean"][0], "cov": d["cov"][0], "cross_cov": d["cross_cov"][0, :, :n_u]}

        # Moments.split of the first Gaussian only: a dataclasses.replace of the batch costs 6 µs a call.
        cross = b.cross_cov[0]
        replicates = None if b.replicates is None else b.replicates[0]
        info = {**b.info, **details}
        if b.error is not None:
            info["error_estimate"] = {**b.error, "cross_cov": b.error["cross_cov"][:, :, :n_u]}
        if replicates is not None:
            info["groups"] = replicates
        return cls(
            mean=b.mean[0], cov=b.cov[0], cross_cov=cross[:, :n_u], input=u, transform=transform,
            noise_cross_cov=cross[:, n_u:], stderr=first(b.stderr), error=first(b.error), info=info,
            input_cov=None if b.input_cov is None else b.input_cov[0, :n_u, :n_u],
            angles=angles, input_angles=input_angles, replicates=replicates, evaluations=b.evaluations,
        )

    def __post_init__(self) -> None:
        for name in ("angles", "input_angles"):
            a = getattr(self, name)
            if a or type(a) is not frozenset:  # the common empty frozenset is kept as it is
                object.__setattr__(self, name, frozenset(map(int, a)))
        names = ("mean", "cov", "cross_cov", "noise_cross_cov", "input_cov")
        if self.input_cov is None:  # the input's own read-only array: a Gaussian is immutable
            object.__setattr__(self, "input_cov", self.input.cov)
            names = names[:-1]
        for name in names:
            arr = np.array(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def y(self) -> Gaussian:
        """The Gaussian approximation N(E y, Cov y)."""
        return Gaussian(self.mean, self.cov)

    @property
    def joint(self) -> Gaussian:
        """The Gaussian approximation of [u; y] (noise v is not part of it).

        For a mixture or particles with a declared angle input, E u and Cov u are those
        the moments were mixed with (on the circle, ``info["input_mean"]`` and
        :attr:`input_cov`), not the input's linear ones.
        """
        u = self.input
        mu, Puu = u.mean, u.cov
        if self.input_angles and "input_mean" in self.info:
            mu, Puu = np.asarray(self.info["input_mean"])[0, :u.dim], self.input_cov
        mean = np.concatenate([mu, self.mean])
        cov = np.block([[Puu, self.cross_cov.T], [self.cross_cov, self.cov]])
        return Gaussian(mean, cov)

    @property
    def joint_angles(self) -> list[int]:
        """The components of :attr:`joint`, [u; y], that are angles, for
        ``joint.condition(..., angles=...)`` and ``sm.fuse(..., angles=...)``."""
        n_u = self.input.dim
        return sorted(self.input_angles) + [n_u + i for i in sorted(self.angles)]

    def condition(self, y_observed) -> Gaussian:
        """The Gaussian of u given an observed y (Lemma 7.1 on :attr:`joint`).

        x̂ = E u + Cov(u, y) (Cov y)⁻¹ (y − E y), Cov = Cov u − Cov(u, y) (Cov y)⁻¹ Cov(y, u),
        with the innovation of an angle output wrapped to (−π, π] and an angle input's
        mean returned wrapped.  This is the update step of the indirect approach.

        Parameters
        ----------
        y_observed : array_like, shape (n_y,)

        Raises
        ------
        ShapeError
            If ``y_observed`` does not have n_y components.
        SingularMatrixError
            If Cov y is singular.

        Examples
        --------
        >>> import numpy as np, sympy as sp, symmon as sm
        >>> x = sp.Symbol("x")
        >>> m = sm.propagate(sm.Model([x], [2 * x]), sm.Gaussian([0.0], [[1.0]]), transform=sm.TT1())
        >>> m.condition([2.0]).mean.tolist()   # y = 2x is exact: x = 1, with no variance left
        [1.0]
        """
        n_u, n_y = self.input.dim, self.mean.shape[0]
        y = np.asarray(y_observed, dtype=float)
        if y.shape != (n_y,):
            raise ShapeError(f"y_observed must have shape ({n_y},) (one value per output), got {y.shape}")
        return self.joint.condition(list(range(n_u, n_u + n_y)), y, angles=self.joint_angles)

    def __repr__(self) -> str:
        s = f"JointMoments(by {self.transform!r},\n  mean={_fmt_arr(self.mean)},\n  cov={_fmt_arr(self.cov)},\n  cross_cov={_fmt_arr(self.cross_cov)}"
        if self.stderr is not None:
            s += f",\n  stderr(mean)={_fmt_arr(self.stderr['mean'])}"
        return s + ")"

    def _repr_latex_(self) -> str:
        def mat(a: np.ndarray) -> str:
            a = np.atleast_2d(a)
            return r"\begin{bmatrix}" + r" \\ ".join(
                " & ".join(latex_number(x) for x in row) for row in a
            ) + r"\end{bmatrix}"

        return (
            r"$\mathsf{E}\,y = " + mat(self.mean[:, None]) + r",\ \operatorname{Cov} y = "
            + mat(self.cov) + r",\ \operatorname{Cov}(y, u) = " + mat(self.cross_cov)
            + r"\quad\text{(" + latex_text(repr(self.transform)) + r")}$"
        )
