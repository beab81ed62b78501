"""Kalman filters: the linear filter (:mod:`.linear`) and the nonlinear family compiled to C
(:mod:`.nonlinear`: EKF, second-order EKF, UKF, CKF, Gauss–Hermite), their compiled step
(:mod:`.step`), their RTS smoothers (:mod:`.smoother`), their export as standalone C
(:mod:`.export`), results with NEES/NIS (:mod:`.results`), and the strategies that run the steps
(:mod:`.strategy`: one rule, or :class:`Adaptive`, :mod:`.adaptive`), and interacting multiple
models over them (:mod:`.imm`)."""

from .adaptive import Adaptive as Adaptive
from .linear import KalmanFilter as KalmanFilter
from .nonlinear import NonlinearKalmanFilter as NonlinearKalmanFilter
from .results import ConsistencyTest as ConsistencyTest
from .results import KalmanResult as KalmanResult
from .results import NonlinearKalmanResult as NonlinearKalmanResult
from .results import SmootherResult as SmootherResult
from .fit import FitResult as FitResult
from .imm import IMM as IMM
from .imm import IMMResult as IMMResult
from .strategy import FilterStrategy as FilterStrategy
from .strategy import RuleStrategy as RuleStrategy

__all__ = ["KalmanFilter", "KalmanResult", "NonlinearKalmanFilter", "NonlinearKalmanResult", "SmootherResult", "FitResult", "ConsistencyTest",
           "Adaptive", "FilterStrategy", "RuleStrategy", "IMM", "IMMResult"]
