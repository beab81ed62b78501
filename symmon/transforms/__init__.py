"""The transforms: one module per family, each returns moments for a batch of Gaussians
(docs/architecture.md); :mod:`.registry` names them.  The stochastic ones keep their group
statistics with :mod:`.stats` and run where an :mod:`.executor` says."""

from .base import Moments as Moments
from .base import Transform as Transform
from .base import wrap_angle as wrap_angle
from .cubature5 import Cubature5 as Cubature5
from .exact import Exact as Exact
from .executor import Executor as Executor
from .montecarlo import MonteCarlo as MonteCarlo
from .quadrature import GaussHermite as GaussHermite
from .taylor import TT1 as TT1
from .taylor import TT2 as TT2
from .unscented import UT as UT

__all__ = ["Transform", "Moments", "TT1", "TT2", "UT", "GaussHermite", "MonteCarlo", "Exact", "Cubature5", "Executor", "wrap_angle"]
