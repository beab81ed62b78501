"""The transforms: one module per family, each returns moments for a batch of Gaussians
(docs/architecture.md); :mod:`.registry` names them.  The stochastic ones keep their group
statistics with :mod:`.stats` and run where an :mod:`.executor` says."""

from .base import Moments as Moments
from .base import Transform as Transform
from .base import wrap_angle as wrap_angle
from .executor import Executor as Executor

# The rules register their presets as their classes are created: this order is the order
# of registry.names(), the rows of ``symmon compare``.
from .taylor import TT1 as TT1  # noqa: E402, I001
from .taylor import TT2 as TT2  # noqa: E402
from .unscented import UT as UT  # noqa: E402
from .quadrature import GaussHermite as GaussHermite  # noqa: E402
from .montecarlo import MonteCarlo as MonteCarlo  # noqa: E402
from .exact import Exact as Exact  # noqa: E402
from .cubature5 import Cubature5 as Cubature5  # noqa: E402

__all__ = ["Transform", "Moments", "TT1", "TT2", "UT", "GaussHermite", "MonteCarlo", "Exact", "Cubature5", "Executor", "wrap_angle"]
