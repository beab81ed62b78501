"""JointMoments: the result of a nonlinear transformation of a Gaussian."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from .gaussian import Gaussian
from .latex import latex_number, latex_text

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
    input : Gaussian
        The distribution of u.
    transform : object
        The transform settings that produced the moments.
    noise_cross_cov : ndarray, shape (n_y, n_v)
        Cov(y, v) (empty for a noise-free model).
    stderr : mapping or None
        Standard errors of ``mean``, ``cov`` and ``cross_cov`` (Monte Carlo only).
    info : mapping
        Transform-specific details (number of evaluations, samples, warnings).
    input_cov : ndarray, shape (n_u, n_u)
        Cov u as the transform sees it: ``input.cov`` for the deterministic rules, the
        sample covariance for Monte Carlo (regressions must use it, or the sampling
        error of Σ_gu does not cancel and biases the residual).
    """

    mean: np.ndarray
    cov: np.ndarray
    cross_cov: np.ndarray
    input: Gaussian
    transform: Any
    noise_cross_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    stderr: Mapping[str, np.ndarray] | None = None
    info: Mapping[str, Any] = field(default_factory=dict)
    input_cov: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.input_cov is None:
            object.__setattr__(self, "input_cov", self.input.cov)
        for name in ("mean", "cov", "cross_cov", "noise_cross_cov", "input_cov"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def y(self) -> Gaussian:
        """The Gaussian approximation N(E y, Cov y)."""
        return Gaussian(self.mean, self.cov)

    @property
    def joint(self) -> Gaussian:
        """The Gaussian approximation of [u; y] (noise v is not part of it)."""
        u = self.input
        mean = np.concatenate([u.mean, self.mean])
        cov = np.block([[u.cov, self.cross_cov.T], [self.cross_cov, self.cov]])
        return Gaussian(mean, cov)

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
