"""Code generation: the moment formulas as CasADi graphs (:mod:`.symbolic`, shared with the
compiled filter step) and :func:`export_c`, standalone C of g, its Jacobian and its moments."""

from .export import export_c as export_c
from .export import moment_functions as moment_functions

__all__ = ["export_c", "moment_functions"]
