"""Exception types of symmon.

Every error symmon raises on bad input is a :class:`SymmonError`, which is also a
:class:`ValueError`, so ``except ValueError`` keeps working for callers that do not
know symmon's types.
"""

from __future__ import annotations

__all__ = [
    "SymmonError",
    "ShapeError",
    "CovarianceError",
    "ModelError",
    "UnsupportedFunctionError",
    "SamplingError",
    "SingularMatrixError",
    "DerivativeError",
]


class SymmonError(ValueError):
    """Base class of the errors symmon raises on bad input."""


class ShapeError(SymmonError):
    """An array has the wrong shape or dimension."""


class CovarianceError(SymmonError):
    """A covariance is not symmetric, not positive semi-definite, or not finite."""


class SingularMatrixError(SymmonError):
    """A matrix that must be inverted is singular."""


class ModelError(SymmonError):
    """A model is ill-formed: unknown, duplicate or missing symbols."""


class UnsupportedFunctionError(ModelError):
    """An expression uses a function that symmon cannot compile."""


class SamplingError(SymmonError):
    """Monte Carlo sampling produced NaN or inf values."""


class DerivativeError(SymmonError):
    """A derivative is NaN or inf at the expansion point."""
