"""Derivation verification: symbolic Gaussian expectations and symbolic moments.

The room above propagation and code generation where a user's own derivation is checked:
:func:`expect` gives E[f(x)] of a Gaussian vector in closed form (or says it has none),
:func:`symbolic_moments` the moments of a model under a transform as sympy matrices in the
symbols of the input's mean and covariance.
"""

from .expectation import expect
from .moments import SymbolicMoments, symbolic_moments
from .verification import Expectation, Verification, verify
from .claims import verify_derivatives, verify_estimator, verify_moments, verify_mon, verify_weight

__all__ = ["expect", "symbolic_moments", "SymbolicMoments", "verify", "Verification", "Expectation",
           "verify_moments", "verify_derivatives", "verify_mon", "verify_weight", "verify_estimator"]
