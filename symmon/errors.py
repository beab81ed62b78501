"""Exception types of symmon, and :func:`plain_repr`, how their messages show a value.

Every error symmon raises on bad input is a :class:`SymmonError`, which is also a
:class:`ValueError`, so ``except ValueError`` keeps working for callers that do not
know symmon's types.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "plain_repr",
    "SymmonError",
    "ShapeError",
    "CovarianceError",
    "IndefiniteCovarianceError",
    "ModelError",
    "UnsupportedFunctionError",
    "DiscretizationError",
    "NonSmoothModelError",
    "UndecidedProofError",
    "ExpectationNotClosedForm",
    "SamplingError",
    "SingularMatrixError",
    "DerivativeError",
    "NonFiniteError",
    "InconsistentMomentsError",
    "ResourceError",
    "ArgumentError",
    "ArgumentTypeError",
    "ModelFileError",
    "UnitError",
    "OutputPathError",
    "UsageError",
    "BuildError",
    "WeightError",
    "AngleWarning",
    "QuadratureWarning",
    "SampleSizeWarning",
    "IdentifiabilityWarning",
    "DegeneracyWarning",
]

#: An array of more entries is shown by its shape only in a message.
PLAIN_MAX_ENTRIES = 12


def plain_repr(value: Any) -> str:
    """``value`` as an error message shows it: its ``repr``, with NumPy numbers plain.

    Under NumPy ≥ 2 the ``repr`` of a NumPy scalar is ``np.float64(0.9)`` and that of an
    array ``array([...])``; a message shows the number ``0.9`` and the list ``[0.5, 0.4]``
    instead (an array of more than :data:`PLAIN_MAX_ENTRIES` entries by its shape).  Any
    other value is shown by its ``repr`` (a string with its quotes, ``None``, a tuple).

    Examples
    --------
    >>> import numpy as np
    >>> plain_repr(np.float64(0.9)), plain_repr(np.int64(-1)), plain_repr(np.array([0.5, 0.4]))
    ('0.9', '-1', '[0.5, 0.4]')
    >>> plain_repr("ukf"), plain_repr(2.5), plain_repr(np.zeros((20, 3)))
    ("'ukf'", '2.5', 'an array of shape (20, 3)')
    """
    tolist = getattr(value, "tolist", None)
    if callable(tolist) and hasattr(value, "dtype") and hasattr(value, "shape"):   # NumPy, without importing it
        if getattr(value, "size", 1) > PLAIN_MAX_ENTRIES:
            return f"an array of shape {tuple(value.shape)}"
        return repr(tolist())
    if isinstance(value, (tuple, list)):
        inner = ", ".join(plain_repr(v) for v in value)
        return f"[{inner}]" if isinstance(value, list) else f"({inner}{',' * (len(value) == 1)})"
    return repr(value)


class SymmonError(ValueError):
    """Base class of the errors symmon raises on bad input."""


class ShapeError(SymmonError):
    """An array has the wrong shape or dimension."""


class CovarianceError(SymmonError):
    """A covariance is not symmetric, not positive semi-definite, or not finite."""


class IndefiniteCovarianceError(CovarianceError):
    """A transform's Cov y is indefinite beyond rounding: a rule with negative weights (the
    UT with a negative centre weight, Gauss–Hermite's sparse grid, the fifth-degree cubature
    rule above 4 dimensions) gave a covariance with a negative eigenvalue.  Never returned
    as a number; use a rule whose weights are all non-negative."""


class SingularMatrixError(SymmonError):
    """A matrix that must be inverted is singular."""


class ModelError(SymmonError):
    """A model is ill-formed: unknown, duplicate or missing symbols."""


class DiscretizationError(ModelError):
    """A stochastic differential equation cannot be discretised by the method asked for: a
    nonlinear drift or a state-dependent diffusion for ``"exact"``, a state-dependent
    diffusion for ``"taylor1.5"`` or ``"local_linear"``, or a matrix exponential or Van Loan
    integral that sympy cannot give in closed form within the time limit."""


class UnsupportedFunctionError(ModelError):
    """An expression uses a function that symmon cannot compile."""


class NonSmoothModelError(ModelError):
    """g is not differentiable where a computation needs its derivatives: the mean lies on
    a kink or jump of ``Abs``, ``sign``, ``Max``, ``Min``, ``Heaviside``, ``floor``,
    ``ceiling``, ``Mod`` or a ``Piecewise`` boundary (TT2 and its proofs need the Hessian
    at the mean), or a symbolic route cannot differentiate the function at all.  The
    message names the function and the kink, and what to do instead."""


class UndecidedProofError(SymmonError):
    """A unit-invariance proof reached no verdict: the difference did not reduce to 0 and
    no point where the two values of M² differ was found, or the numeric check of the
    change of units contradicts the symbolic verdict.  Never reported as "holds"."""


class ExpectationNotClosedForm(SymmonError):
    """A Gaussian expectation E[f(x)] asked of :func:`symmon.expect` (or of the exact
    symbolic moments built on it) lies outside the class that has a proved closed form:
    sums and products of polynomials, exponentials of affine forms, sines and cosines of
    affine forms, and ``|affine|`` and max/min of two affine forms (an absolute value times
    polynomials and real exponentials only).  The message names the subexpression that
    is outside; nothing unproven (no numeric integral, no sympy.stats fallback) is
    returned instead."""


class SamplingError(SymmonError):
    """Monte Carlo sampling produced NaN or inf values."""


class DerivativeError(SymmonError):
    """A derivative is NaN or inf at the expansion point."""


class NonFiniteError(SymmonError):
    """A moment or a measure would be NaN or inf: g is not finite at a point a rule
    evaluates, or the moments themselves overflow.  Never returned as a number."""


class InconsistentMomentsError(SymmonError):
    """A deterministic transform's moments that no distribution has: a residual covariance
    of the MoN, Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug − Σ_c, clearly negative where it is a variance.  The
    approximation has failed for this model and prior, and its MoN is no number (clamped at
    0 it would read as "linear")."""


class ResourceError(SymmonError):
    """A computation would exceed a declared size limit (e.g. quadrature nodes)."""


class ArgumentError(SymmonError):
    """An argument has a value of the wrong kind (e.g. an invalid seed)."""


class WeightError(ArgumentError):
    """Mixture or particle weights are negative, not finite, all zero, or (for a
    mixture) do not sum to 1 beyond rounding."""


class ArgumentTypeError(ArgumentError, TypeError):
    """An argument has the wrong type (e.g. a string where a Model is expected).

    Also a :class:`TypeError`, so ``except TypeError`` keeps working."""


class ModelFileError(ModelError):
    """A model file or an expression text is invalid or refused.

    Parameters
    ----------
    message : str
        The full message; it names the file or source and, for expressions, the line
        and column.
    source, line, column, reason : optional
        The parts of the message, kept as attributes for programs.
    """

    def __init__(
        self,
        message: str,
        *,
        source: str | None = None,
        line: int | None = None,
        column: int | None = None,
        reason: str | None = None,
    ) -> None:
        super().__init__(message)
        self.source = source
        self.line = line
        self.column = column
        self.reason = reason

    def __reduce__(self):
        # Keep the keyword-only attributes when the error is pickled (multiprocessing).
        return (_rebuild_error, (self.args[0], self.__dict__))


def _rebuild_error(message: str, state: dict) -> ModelFileError:
    err = ModelFileError(message)
    err.__dict__.update(state)
    return err


class UnitError(ModelError):
    """An unknown unit, incompatible dimensions, or a unit declaration that does not fit the model."""


class OutputPathError(SymmonError):
    """An output path is empty or names something that is not a regular file, or a file
    that symmon would replace but did not write (an export's README beside a user's)."""


class UsageError(SymmonError):
    """A combination of command-line options that argparse cannot check by itself (exit code 2)."""


class BuildError(RuntimeError):
    """The C compiler failed (its message holds the end of the compiler's output).

    Not a :class:`SymmonError`: the input was fine, the build environment was not."""


class AngleWarning(RuntimeWarning):
    """An output that looks like an angle (atan2) is not declared with ``angles=`` and
    its evaluated points lie on both sides of the cut at ±π: its moments are wrong."""


class QuadratureWarning(UserWarning):
    """A quadrature rule chose a grid the caller did not ask for (Gauss–Hermite with
    ``sparse=None`` falls to the sparse grid above 4 dimensions): its degree of exactness
    and its weights differ from the tensor grid's."""


class IdentifiabilityWarning(UserWarning):
    """A fitted parameter has a standard error larger than its estimate: the data hardly
    constrain it (a bias confounded with an uncertain initial state), and the estimate is
    little more than its starting value moved by noise."""


class SampleSizeWarning(UserWarning):
    """A weighted sample (``Empirical``) has a small effective sample size
    (Σ w)² / Σ w²: its moments and measures are those of a few particles, and their
    error bars are themselves unreliable."""


class DegeneracyWarning(RuntimeWarning):
    """A particle filter's weights collapsed: at some step the effective sample size
    1 / Σ w_i² fell to about one particle, so its estimate is that particle's state and its
    covariance and log-likelihood are unreliable.  More particles, a proposal that uses the
    measurement (``proposal="ekf"`` or ``"ukf"``) or a larger process noise help."""
