"""The state-space model of the filters as drawn by sampling: validated (f, h, Q, R) and their
compiled evaluation over batches of states (simulated runs, particles).

x_{k+1} = f(x_k, w_k), y_k = h(x_k, e_k), w_k ~ N(0, Q), e_k ~ N(0, R); without noise symbols
the noises are additive, x_{k+1} = f(x_k) + w_k and y_k = h(x_k) + e_k (the convention of
:class:`~symmon.filters.gaussian.nonlinear.NonlinearKalmanFilter`).  Noise is drawn as L z with L Lᵀ
the covariance and z standard normal rows, so that a caller fixes the order of the draws.
f and h are evaluated on all rows of a batch at once by their compiled C
(:func:`~symmon.compile.compiled_with_params`, threads over row spans for large batches),
the parameters appended to each row; angle states and angle measurements are wrapped to
(−π, π].
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

from ..compile.compiled import compiled_with_params
from ..core.angles import wrap_angle
from ..core.arrays import readonly
from ..core.checks import noise_cov
from ..core.gaussian import as_covariance, matrix_sqrt
from ..core.model import Model
from .inputs import check_state_models, filter_params

__all__ = ["StateSpace", "rows_times"]


def rows_times(Z: np.ndarray, L: np.ndarray) -> np.ndarray:
    """The rows of Z times Lᵀ, (N, m) × (m, m)ᵀ, without BLAS: OpenBLAS splits a product of
    many rows and few columns over its threads, which then spin against the compiled
    evaluation's threads (30 ms where this takes 1 ms for 40000 × 4 on a loaded machine)."""
    return np.einsum("ij,nj->ni", L, Z)


@dataclass(frozen=True, eq=False)
class StateSpace:
    """Validated models and noise covariances, and their batched compiled evaluation.

    Parameters
    ----------
    f_model, h_model : Model
        The dynamics (n inputs, n outputs) and the measurement (n inputs, n_y outputs).
    Q, R : array_like
        Covariances of the noise symbols of f and h, or of the additive noises.

    Raises
    ------
    ArgumentTypeError
        For a model that is not a :class:`~symmon.Model`.
    ShapeError, CovarianceError
        For models that do not fit together, or a covariance of the wrong size or not PSD.
    """

    f_model: Model
    h_model: Model
    Q: np.ndarray
    R: np.ndarray

    def __post_init__(self) -> None:
        f, h = check_state_models(self.f_model, self.h_model)
        object.__setattr__(self, "Q", readonly(as_covariance(self.Q, "Q", dim=f.n_v or f.n_u)))
        object.__setattr__(self, "R", readonly(noise_cov(h, self.R, "R")))

    @property
    def n(self) -> int:
        """The state dimension."""
        return self.f_model.n_u

    @property
    def n_y(self) -> int:
        """The measurement dimension."""
        return self.h_model.n_y

    @cached_property
    def params(self) -> tuple:
        """The parameters: those of f, then those of h that f does not have (as the filters)."""
        return filter_params(self.f_model, self.h_model)

    @cached_property
    def angle_states(self) -> tuple[int, ...]:
        """State components that are angles: f's angle outputs and f's or h's angle inputs."""
        f, h = self.f_model, self.h_model
        return tuple(sorted(f.angle_outputs | f.angle_inputs | h.angle_inputs))

    @cached_property
    def angle_outputs(self) -> tuple[int, ...]:
        """Measurement components that are angles."""
        return tuple(sorted(self.h_model.angle_outputs))

    @cached_property
    def Lq(self) -> np.ndarray:
        """L with L Lᵀ = Q (a singular PSD Q allowed)."""
        return matrix_sqrt(np.asarray(self.Q))

    @cached_property
    def Lr(self) -> np.ndarray:
        """L with L Lᵀ = R."""
        return matrix_sqrt(np.asarray(self.R))

    def _columns(self, model: Model) -> np.ndarray:
        """Where each of ``model``'s parameters sits in the filter's parameter vector."""
        return np.array([self.params.index(s) for s in model.params], dtype=np.intp)

    def evaluate(self, model: Model, X: np.ndarray, noise: np.ndarray | None, p: ArrayLike | None) -> np.ndarray:
        """``model`` (f or h) at each row of X (N, n): g(x, v) with the noise rows as its
        noise symbols, or g(x) + noise for additive noise (``noise`` None: g(x) with the
        noise symbols at 0, or without noise); ``p`` the values of every filter parameter,
        (n_p,) shared or (N, n_p) per row."""
        cm = compiled_with_params(model)
        parts = [X]
        if model.n_v:
            parts.append(np.zeros((X.shape[0], model.n_v)) if noise is None else noise)
        if model.n_p:
            P = np.asarray(p, dtype=float)[..., self._columns(model)]
            parts.append(np.broadcast_to(P, (X.shape[0], model.n_p)))
        W = parts[0] if len(parts) == 1 else np.hstack(parts)
        out = cm.eval_g(W)
        if noise is not None and not model.n_v:
            out += noise
        return out

    def transition(self, X: np.ndarray, Z: np.ndarray | None, p: ArrayLike | None) -> np.ndarray:
        """x' = f(x, L_Q z) (or f(x) + L_Q z) for each row, angle states wrapped; Z (N, n_q)
        standard normal rows, None for no noise."""
        out = self.evaluate(self.f_model, X, None if Z is None else rows_times(Z, self.Lq), p)
        return self.wrap_states(out)

    def measure(self, X: np.ndarray, Z: np.ndarray | None, p: ArrayLike | None) -> np.ndarray:
        """y = h(x, L_R z) (or h(x) + L_R z) for each row, angle outputs wrapped."""
        out = self.evaluate(self.h_model, X, None if Z is None else rows_times(Z, self.Lr), p)
        if self.angle_outputs:
            idx = list(self.angle_outputs)
            out[:, idx] = wrap_angle(out[:, idx])
        return out

    def wrap_states(self, X: np.ndarray) -> np.ndarray:
        """X with its angle states wrapped to (−π, π] (in place)."""
        if self.angle_states:
            idx = list(self.angle_states)
            X[..., idx] = wrap_angle(X[..., idx])
        return X
