"""Kalman filters: the linear filter (:mod:`.linear`) and the nonlinear family compiled to C
(:mod:`.nonlinear`: EKF, second-order EKF, UKF, CKF, Gauss–Hermite), the continuous-discrete
filters of an SDE (:mod:`.gaussian.continuous`), their compiled step
(:mod:`.step`), their RTS smoothers (:mod:`.smoother`), their export as standalone C
(:mod:`.export`), the truth of a filter study (:func:`.simulation.simulate`), the particle filter
(:mod:`.particle`), results with NEES/NIS (:mod:`.results`), the strategies that run the steps
(:mod:`.strategy`: one rule, or :class:`Adaptive`, :mod:`.adaptive`), the Gaussian-sum filter
(:mod:`.gaussian_sum`), the ensemble Kalman filters (:mod:`.ensemble`), interacting multiple models over them (:mod:`.imm`), and the checks of a
filter call's inputs (:mod:`.inputs`, which the others import and which imports none of them)."""

from .gaussian.adaptive import Adaptive as Adaptive
from .gaussian.linear import KalmanFilter as KalmanFilter
from .gaussian.nonlinear import NonlinearKalmanFilter as NonlinearKalmanFilter
from .gaussian.continuous import ContinuousDiscreteKalmanFilter as ContinuousDiscreteKalmanFilter
from .results import ConsistencyTest as ConsistencyTest
from .results import KalmanResult as KalmanResult
from .results import NonlinearKalmanResult as NonlinearKalmanResult
from .results import SmootherResult as SmootherResult
from .gaussian.fit import FitResult as FitResult
from .mixture.gaussian_sum import GaussianSumFilter as GaussianSumFilter
from .mixture.gaussian_sum import GaussianSumResult as GaussianSumResult
from .mixture.imm import IMM as IMM
from .mixture.imm import IMMResult as IMMResult
from .gaussian.strategy import FilterStrategy as FilterStrategy
from .simulation import simulate as simulate
from .particle.particle_filter import ParticleFilter as ParticleFilter
from .particle.particle_filter import ParticleResult as ParticleResult
from .results import Credibility as Credibility
from .selection import FilterAdvice as FilterAdvice
from .selection import FilterCandidate as FilterCandidate
from .selection import advise_filter as advise_filter
from .gaussian.strategy import RuleStrategy as RuleStrategy
from .ensemble.enkf import EnsembleKalmanFilter as EnsembleKalmanFilter
from .ensemble.enkf import EnsembleResult as EnsembleResult

__all__ = ["KalmanFilter", "KalmanResult", "NonlinearKalmanFilter", "ContinuousDiscreteKalmanFilter", "NonlinearKalmanResult", "SmootherResult", "FitResult", "ConsistencyTest",
           "Adaptive", "FilterStrategy", "RuleStrategy", "simulate", "IMM", "IMMResult",
           "ParticleFilter", "ParticleResult", "EnsembleKalmanFilter", "EnsembleResult", "GaussianSumFilter", "GaussianSumResult",
           "Credibility", "FilterAdvice", "FilterCandidate", "advise_filter"]
