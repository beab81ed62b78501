"""symmon: nonlinear transformations of random variables.

Models are declared with sympy, compiled with CasADi (exact derivatives, batched
evaluation, C code), and their moments computed by TT1, TT2, the unscented family,
Gauss–Hermite, Monte Carlo and exact polynomial moments.

This module is the package's one face: every public name is re-exported here from its
home subpackage (docs/architecture.md lists the layers and where new code goes).
"""

from . import errors as errors
from . import transforms as transforms
from . import codegen as codegen
from . import estimation as estimation
from . import filters as filters
from . import units as units
from . import testing as testing
from .core import angles as angles
from .core import problems as problems
from .estimation import mmse as mmse
from .files import modelfile as modelfile
from .filters.gaussian import linear as kalman
from .measures import sweep as sweep
from .measures import weights as weights
from .codegen import export_c as export_c
from .core import Empirical as Empirical
from .core import Gaussian as Gaussian
from .core import GaussianMixture as GaussianMixture
from .core import Model as Model
from .core import SDE as SDE
from .core import fuse as fuse
from .errors import SymmonError as SymmonError
from .files import load_model_file as load_model_file
from .files import load_samples_file as load_samples_file
from .filters import IMM as IMM
from .filters import Adaptive as Adaptive
from .filters import GaussianSumFilter as GaussianSumFilter
from .filters import GaussianSumResult as GaussianSumResult
from .filters import KalmanFilter as KalmanFilter
from .filters import NonlinearKalmanFilter as NonlinearKalmanFilter
from .filters import ContinuousDiscreteKalmanFilter as ContinuousDiscreteKalmanFilter
from .filters import ParticleFilter as ParticleFilter
from .filters import EnsembleKalmanFilter as EnsembleKalmanFilter
from .filters import EnsembleResult as EnsembleResult
from .filters import simulate as simulate
from .filters import FilterAdvice as FilterAdvice
from .filters import advise_filter as advise_filter
from .measures import Advice as Advice
from .measures import MonParts as MonParts
from .measures import NonlinearityMeasure as NonlinearityMeasure
from .measures import advise as advise
from .measures import compare as compare
from .measures import mon_from_moments as mon_from_moments
from .measures import nonlinearity as nonlinearity
from .propagation import JointMoments as JointMoments
from .propagation import propagate as propagate
from .propagation import propagate_many as propagate_many
from .propagation import quadrature_error as quadrature_error
from .transforms import TT1 as TT1
from .transforms import TT2 as TT2
from .transforms import UT as UT
from .transforms import Cubature5 as Cubature5
from .transforms import Exact as Exact
from .transforms import Executor as Executor
from .transforms import GaussHermite as GaussHermite
from .transforms import Moments as Moments
from .transforms import MonteCarlo as MonteCarlo
from .transforms import Transform as Transform
from .verify import SymbolicMoments as SymbolicMoments
from .verify import expect as expect
from .verify import symbolic_moments as symbolic_moments
from .verify import Expectation as Expectation
from .verify import Verification as Verification
from .verify import verify as verify
from .verify import verify_derivatives as verify_derivatives
from .verify import verify_estimator as verify_estimator
from .verify import verify_moments as verify_moments
from .verify import verify_mon as verify_mon
from .verify import verify_weight as verify_weight

from .version import __version__ as __version__

__all__ = [
    "angles", "errors", "estimation", "filters", "sweep", "units", "quadrature_error", "kalman",
    "modelfile", "mmse", "problems", "transforms", "weights", "codegen", "export_c",
    "load_model_file", "load_samples_file",
    "SymmonError", "Gaussian", "GaussianMixture", "Empirical", "fuse", "KalmanFilter", "Model", "SDE", "JointMoments",
    "NonlinearityMeasure", "MonParts", "mon_from_moments", "nonlinearity", "compare",
    "propagate", "propagate_many", "advise", "Advice", "advise_filter", "FilterAdvice",
    "TT1", "TT2", "UT", "GaussHermite", "MonteCarlo", "Exact", "Cubature5", "Transform", "Moments", "Executor",
    "NonlinearKalmanFilter", "ContinuousDiscreteKalmanFilter", "Adaptive", "IMM", "simulate", "ParticleFilter", "EnsembleKalmanFilter", "EnsembleResult", "GaussianSumFilter", "GaussianSumResult",
    "expect", "symbolic_moments", "SymbolicMoments",
    "testing", "verify", "Verification", "Expectation", "verify_moments", "verify_derivatives", "verify_mon",
    "verify_weight", "verify_estimator",
]


def __dir__() -> list[str]:
    # The public names only: the subpackages (core, compile, propagation, ...) stay importable
    # as symmon.core etc. but are not listed (PEP 562).
    return sorted([*__all__, "__version__"])
