"""The core: models, Gaussians, angles, the problems of the papers, and the affine change
of units (docs/architecture.md).  Nothing here imports another symmon subpackage."""

from . import affine as affine
from . import angles as angles
from . import problems as problems
from .arrays import readonly as readonly
from .checks import check_gaussian as check_gaussian
from .checks import check_model as check_model
from .checks import noise_cov as noise_cov
from .gaussian import Gaussian as Gaussian
from .gaussian import as_covariance as as_covariance
from .gaussian import as_vector as as_vector
from .gaussian import fuse as fuse
from .mixture import Empirical as Empirical
from .mixture import GaussianMixture as GaussianMixture
from .model import Model as Model
from .sde import SDE as SDE
from . import discretize as discretize
from .rescale import change_units as change_units
from .rescale import changed_relation as changed_relation
from .rescale import change_gaussian as change_gaussian
from .tracing import SUPPORTED as SUPPORTED
from .tracing import trace as trace

__all__ = ["Gaussian", "GaussianMixture", "Empirical", "Model", "SDE", "discretize", "fuse", "as_covariance", "as_vector", "check_gaussian", "check_model",
           "noise_cov", "readonly", "change_units", "changed_relation", "change_gaussian", "trace",
           "SUPPORTED", "affine", "angles", "problems"]
