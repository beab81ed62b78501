"""How a nonlinear Kalman filter runs its steps: a strategy.

:class:`NonlinearKalmanFilter <symmon.filters.gaussian.nonlinear.NonlinearKalmanFilter>` hands a bank
of measurements to its strategy.  A transform given to the filter becomes a
:class:`RuleStrategy`: the one compiled step (:mod:`symmon.filters.gaussian.step`) of that rule for
every step of every run.  :class:`~symmon.filters.gaussian.adaptive.Adaptive` is the other built-in
strategy: it chooses a rule per step and per run.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from ...codegen.sqrtform import check_sqrt_rule
from ...errors import ArgumentTypeError, SymmonError
from ...transforms.base import Transform
from ..inputs import KEEPABLE, FilterSpec
from .step import compiled_step, filterable, check_dimensions

__all__ = ["FilterStrategy", "RuleStrategy"]


class FilterStrategy(ABC):
    """The way a :class:`~symmon.NonlinearKalmanFilter` runs its predict and update steps."""

    #: Whether :meth:`run` takes the true states (``truth=``, (R, K, n)) and returns each
    #: step's ``nees`` and ``nees_trace`` (the compiled step's NEES); otherwise the filter
    #: computes the NEES from the x and P that :meth:`run` returns.
    nees_in_step: bool = False

    @abstractmethod
    def label(self) -> str:
        """The filter's name (EKF, UKF(...), Adaptive(...)): ``NonlinearKalmanFilter.method``."""

    def check(self, kf: FilterSpec) -> None:
        """Refuse, when the filter is made, what cannot run on its dimensions (default: nothing)."""

    def stores(self, keep: frozenset[str] | None) -> frozenset[str]:
        """The arrays (of :data:`~symmon.filters.inputs.KEEPABLE`) that :meth:`run` allocates
        for a bank when the caller keeps ``keep`` (None: all), for the bound on their size."""
        return frozenset(KEEPABLE) if keep is None else frozenset(keep)

    @abstractmethod
    def run(self, kf: FilterSpec, Y: np.ndarray, x0: np.ndarray, P0: np.ndarray,
            keep: frozenset[str] | None = None) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
        """Filter the bank ``Y`` (R, K, n_y) from x0 (n,) or (R, n) and P0 (n, n) or (R, n, n).

        Returns the arrays ``x``, ``P``, ``x_pred``, ``P_pred``, ``innovation``, ``S`` and
        ``loglik``, each with the leading axes (R, K) (at least those of ``keep`` and
        ``loglik``: the filter drops the rest), and the filter chosen at each step and run
        (R, K) or ``None`` when there is no choice.  Steps after a failure may be NaN; the
        filter names the run and step.
        """


@dataclass(frozen=True)
class RuleStrategy(FilterStrategy):
    """One transform for both updates of every step: its compiled step (EKF, UKF, ...).

    Raises
    ------
    TypeError
        ``transform`` is not a symmon transform.
    SymmonError
        The rule is neither a Taylor rule nor a point rule, so no filter step can be
        compiled from it.
    """

    transform: Transform
    nees_in_step = True  # a class attribute, not a field

    def __post_init__(self) -> None:
        if not isinstance(self.transform, Transform):
            raise ArgumentTypeError(f"transform must be a symmon transform or a filter strategy, got {self.transform!r}")
        if not filterable(self.transform):
            raise SymmonError(
                f"transform must be TT1, TT2, UT or GaussHermite (a Taylor or point rule) for a Kalman filter, "
                f"got {self.transform!r}"
            )

    def label(self) -> str:
        return self.transform.filter_label()

    def check(self, kf):
        check_dimensions(self.transform, kf.dimensions)
        if kf.square_root:
            for n in sorted(set(kf.dimensions)):
                check_sqrt_rule(self.transform, n)

    def run(self, kf, Y, x0, P0, keep=None, params=None, truth=None):
        step = compiled_step(kf.f_model, kf.h_model, self.transform, kf.angle_states, kf.iterations,
                              kf.square_root)
        return step(x0, P0, Y, kf.Q, kf.R, keep=None if keep is None else keep | {"loglik"}, params=params,
                    truth=truth, check_finite=True), None
