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
    "NonFiniteError",
    "ResourceError",
    "ArgumentError",
    "AngleWarning",
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


class NonFiniteError(SymmonError):
    """A moment or a measure would be NaN or inf: g is not finite at a point a rule
    evaluates, or the moments themselves overflow.  Never returned as a number."""


class ResourceError(SymmonError):
    """A computation would exceed a declared size limit (e.g. quadrature nodes)."""


class ArgumentError(SymmonError):
    """An argument has a value of the wrong kind (e.g. an invalid seed)."""


class AngleWarning(RuntimeWarning):
    """An output that looks like an angle (atan2) is not declared with ``angles=`` and
    its evaluated points lie on both sides of the cut at ±π: its moments are wrong."""
