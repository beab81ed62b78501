"""symmon: nonlinear transformations of random variables.

Models are declared with sympy, compiled with CasADi (exact derivatives, batched
evaluation, C code), and their moments computed by TT1, TT2, the unscented family,
Gauss–Hermite, Monte Carlo and exact polynomial moments.
"""

from . import angles as angles
from . import errors as errors
from . import estimation as estimation
from . import kalman as kalman
from . import modelfile as modelfile
from . import mmse as mmse
from . import problems as problems
from . import sweep as sweep
from . import units as units
from . import weights as weights
from . import codegen as codegen
from . import filters as filters
from . import transforms as transforms
from .advise import Advice as Advice
from .advise import advise as advise
from .codegen import export_c as export_c
from .errors import SymmonError as SymmonError
from .gaussian import Gaussian as Gaussian
from .gaussian import fuse as fuse
from .kalman import KalmanFilter as KalmanFilter
from .filters import NonlinearKalmanFilter as NonlinearKalmanFilter
from .filters import Adaptive as Adaptive
from .model import Model as Model
from .modelfile import load_model_file as load_model_file
from .moments import JointMoments as JointMoments
from .measure import MonParts as MonParts
from .measure import NonlinearityMeasure as NonlinearityMeasure
from .measure import mon_from_moments as mon_from_moments
from .nonlinearity import compare as compare
from .nonlinearity import nonlinearity as nonlinearity
from .propagate import propagate as propagate
from .propagate import propagate_many as propagate_many
from .transforms import TT1 as TT1
from .transforms import TT2 as TT2
from .transforms import UT as UT
from .transforms import Exact as Exact
from .transforms import GaussHermite as GaussHermite
from .transforms import MonteCarlo as MonteCarlo
from .transforms import Transform as Transform
from .transforms import Moments as Moments
from .transforms import Cubature5 as Cubature5
from .transforms import Executor as Executor
from .transforms.quadrature import quadrature_error as quadrature_error

__version__ = "0.1.0"

__all__ = [
    "angles", "errors", "estimation", "filters", "sweep", "units", "quadrature_error", "kalman",
    "modelfile", "mmse", "problems", "transforms", "weights", "codegen", "export_c",
    "load_model_file",
    "SymmonError", "Gaussian", "fuse", "KalmanFilter", "Model", "JointMoments",
    "NonlinearityMeasure", "MonParts", "mon_from_moments", "nonlinearity", "compare",
    "propagate", "propagate_many", "advise", "Advice",
    "TT1", "TT2", "UT", "GaussHermite", "MonteCarlo", "Exact", "Cubature5", "Transform", "Moments", "Executor",
    "NonlinearKalmanFilter", "Adaptive",
]


def __dir__() -> list[str]:
    # The public names only: implementation modules (compile, io, latex, progress, ...) stay
    # importable as symmon.compile etc. but are not listed (PEP 562).
    return sorted([*__all__, "__version__"])
