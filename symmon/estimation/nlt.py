"""Parameter estimation with nonlinear transformations (NLT): direct and indirect approaches,
sensor fusion, and nonlinear Kalman filter steps built on the same transforms.

Measurements are y_k = h(x, e_k) (additive: y_k = h(x) + e_k), e_k ~ N(0, R_k) independent.

- **Direct approach** (lecture, "Direct Approach Using NLT"): when x = h⁻¹(y − e) is available,
  one NLT per measurement gives N(x̂_k, P_k), and the sensor fusion formula combines them:
  P = (Σ_k P_k⁻¹)⁻¹, x̂ = P Σ_k P_k⁻¹ x̂_k (:func:`symmon.core.gaussian.fuse`).
- **Indirect approach** (lecture, "Indirect Approach Using NLT", steps 1–4): with a prior
  x ~ N(x̂₀, P^{xx}), the NLT of z = [x; h(x, e)] for u = [x; e] ~ N([x̂₀; 0], blkdiag(P^{xx}, R))
  gives a joint Gaussian of [x; y], and conditioning on the observed y (Lemma 7.1) gives
  x̂ = x̂₀ + P^{xy}(P^{yy})⁻¹(y − ŷ), Cov = P^{xx} − P^{xy}(P^{yy})⁻¹P^{yx}.
- **Nonlinear Kalman filters**: the time update is an NLT of the dynamics and the measurement
  update is the indirect step above, so the transform picks the filter: TT1 gives the EKF,
  TT2 the second-order EKF and the UT the UKF (Gustafsson & Hendeby, 2012).  The filter
  that runs them over a sequence, compiled to C, is :class:`symmon.filters.NonlinearKalmanFilter`.

References
----------
F. Gustafsson, G. Hendeby, *Parameter Estimation using Nonlinear Transformations*, Sensor
Fusion lecture notes (Lemma 7.1, the sensor fusion formula, the radar example); the book
F. Gustafsson, *Statistical Sensor Fusion*, Studentlitteratur, §3.4–3.5.
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ModelError, ShapeError, SingularMatrixError
from ..core.gaussian import Gaussian, as_covariance, as_vector, fuse
from ..core.checks import check_gaussian, check_model, noise_cov
from ..core.model import Model
from ..propagation.joint import JointMoments
from ..propagation.front import propagate
from ..transforms.unscented import UT
from ..transforms.base import Transform
from ..transforms.registry import resolve



def _estimator_transform(transform: Transform | None) -> Transform:
    """The estimators' default is the UKF's rule, ``UT.ut1()`` (the lecture's ``'ut1'``),
    not the moments' default TT2: an estimator's defaults follow the filters'.  A name is
    resolved as in :func:`symmon.propagate`."""
    return UT.ut1() if transform is None else resolve(transform)


__all__ = [
    "fuse",
    "DirectResult",
    "IndirectResult",
    "direct",
    "indirect",
    "predict",
    "update",
]

#: One measurement of :func:`direct`: N(y_k, R_k), or (h⁻¹_k, N(y_k, R_k)) for its own model.
DirectItem = Union[Gaussian, tuple[Model, Gaussian]]


# --------------------------------------------------------------------------- results
@dataclass(frozen=True, eq=False)
class DirectResult:
    """Result of :func:`direct`.

    Attributes
    ----------
    estimates : tuple of Gaussian
        N(x̂_k, P_k), one per measurement: the NLT of x = h⁻¹(y_k − e_k).
    fused : Gaussian
        N(x̂, P) by the sensor fusion formula.
    moments : tuple of JointMoments
        The full transform output per measurement (sigma points etc. in ``info``).
    """

    estimates: tuple[Gaussian, ...]
    fused: Gaussian
    moments: tuple[JointMoments, ...]

    def __repr__(self) -> str:
        return f"DirectResult(estimates={len(self.estimates)}, fused={self.fused!r})"


@dataclass(frozen=True, eq=False)
class IndirectResult:
    """Result of :func:`indirect`.

    Attributes
    ----------
    prior : Gaussian
        N(x̂₀, P^{xx}).
    posteriors : tuple of Gaussian
        The posterior after each measurement, in order; each is the prior of the next.
    joints : tuple of Gaussian
        The NLT approximation N([x̂; ŷ], [[P^{xx}, P^{xy}], [P^{yx}, P^{yy}]]) of [x; y]
        before each conditioning (step 3 of the indirect approach).
    """

    prior: Gaussian
    posteriors: tuple[Gaussian, ...]
    joints: tuple[Gaussian, ...]

    @property
    def posterior(self) -> Gaussian:
        """The posterior after the last measurement."""
        return self.posteriors[-1]

    def __repr__(self) -> str:
        return f"IndirectResult(measurements={len(self.posteriors)}, posterior={self.posterior!r})"


# --------------------------------------------------------------------------- helpers
@lru_cache(maxsize=256)
def _joint_model(model: Model) -> Model:
    """The model z = [x; h(x, e)] of step 3 of the indirect approach (compiled once per h)."""
    n_x = model.n_u
    angles: list = [i for i in sorted(model.angle_inputs)]  # x passes through unchanged
    angles += [n_x + j for j in sorted(model.angle_outputs)]
    angles += [model.inputs[i] for i in sorted(model.angle_inputs)]
    return Model(model.inputs, list(model.inputs) + list(model.outputs), model.noise or None,
                 f"{model.name}_joint", angles)


def _joint(model: Model, x: Gaussian, R: np.ndarray, transform: Transform | None) -> Gaussian:
    """N([x̂; ŷ], [[P^{xx}, P^{xy}], [P^{yx}, P^{yy}]]) of [x; h(x, e)] by one NLT.

    With noise symbols, the NLT runs on u = [x; e] ~ N([x̂; 0], blkdiag(P^{xx}, R)) as in the
    lecture. Without them the noise is additive, y = h(x) + e, so R is added to the y-block:
    Cov y = Cov h(x) + R and Cov(x, y) = Cov(x, h(x)) hold exactly for any transform, and the
    UT keeps its sigma points in the state space (the usual additive-noise UKF).
    """
    jm = _joint_model(model)
    n_x = model.n_u
    if model.n_v:
        m = propagate(jm, x, Gaussian(np.zeros(model.n_v), R), transform=_estimator_transform(transform))
        cov = np.array(m.cov)
    else:
        m = propagate(jm, x, transform=_estimator_transform(transform))
        cov = np.array(m.cov)
        cov[n_x:, n_x:] += R
    return Gaussian(m.mean, 0.5 * (cov + cov.T))


def _condition(model: Model, joint: Gaussian, y: np.ndarray, name: str) -> Gaussian:
    """Lemma 7.1 on the y-block of ``joint``, with wrapped innovations for angle outputs."""
    n_x, n_y = model.n_u, model.n_y
    iy = np.arange(n_x, n_x + n_y)
    # An angle 2π away from ŷ is the same measurement: Gaussian.condition wraps y − ŷ.
    angles = [n_x + j for j in sorted(model.angle_outputs)]
    try:
        return joint.condition(iy, y, angles=angles)
    except SingularMatrixError as exc:
        raise SingularMatrixError(
            f"{name}: the innovation covariance P^yy of the joint NLT is singular; give the "
            f"measurement noise a positive definite covariance ({exc})"
        ) from exc


# --------------------------------------------------------------------------- direct
def direct(
    hinv_model: Model | None,
    measurements: Sequence[DirectItem],
    transform: Transform | None = None,
) -> DirectResult:
    """Direct approach: one NLT x_k = h⁻¹(y_k − e_k) per measurement, then fusion.

    Parameters
    ----------
    hinv_model : Model or None
        x = h⁻¹(u) with inputs u = y − e (no noise symbols: the measurement noise is the
        spread of the measurement Gaussian). ``None`` if every measurement brings its own.
    measurements : sequence
        Each item is N(y_k, R_k) as a :class:`Gaussian`, or a pair ``(model_k, N(y_k, R_k))``
        when each sensor has its own h⁻¹ (e.g. its position built into the expressions).
    transform : Transform, default ``UT.ut1()``
        The NLT (TT1, TT2, UT, Gauss–Hermite, Monte Carlo, ...).

    Returns
    -------
    DirectResult
        The per-measurement N(x̂_k, P_k) and the fused N(x̂, P), P = (Σ P_k⁻¹)⁻¹,
        x̂ = P Σ P_k⁻¹ x̂_k (the sensor fusion formula).

    Raises
    ------
    ShapeError
        No measurements, a measurement of the wrong dimension, or estimates of different
        dimensions.
    ModelError
        A model with noise symbols, or a bare Gaussian without ``hinv_model``.
    SingularMatrixError
        An estimate with a singular covariance (fusion inverts each P_k).

    Examples
    --------
    >>> import numpy as np, sympy as sp, symmon as sm
    >>> r, phi = sp.symbols("r phi")
    >>> hinv = sm.Model([r, phi], [r * sp.cos(phi), r * sp.sin(phi)])
    >>> y1 = sm.Gaussian([100 * np.sqrt(2), np.pi / 4], np.diag([5, 0.1]))
    >>> direct(hinv, [y1], transform=sm.UT.ut1()).estimates[0]
    N([95.1, 95.1], [[954, -854], [-854, 954]])
    """
    if hinv_model is not None:
        check_model(hinv_model, "hinv_model")
    if isinstance(measurements, Gaussian):
        measurements = [measurements]
    items = list(measurements)
    if not items:
        raise ShapeError("measurements must hold at least one measurement Gaussian")
    estimates, moments = [], []
    for k, item in enumerate(items):
        if isinstance(item, tuple):
            if len(item) != 2:
                raise ShapeError(f"measurements[{k}] must be a Gaussian or a (model, Gaussian) pair")
            model = check_model(item[0], f"measurements[{k}][0]")
            y = check_gaussian(item[1], f"measurements[{k}][1]")
        else:
            if hinv_model is None:
                raise ModelError(
                    f"measurements[{k}] is a bare Gaussian but hinv_model is None: pass a model "
                    "or (model, Gaussian) pairs"
                )
            model, y = hinv_model, check_gaussian(item, f"measurements[{k}]")
        if model.n_v:
            raise ModelError(
                f"the inverse model {model.name!r} of measurements[{k}] declares noise symbols "
                f"{[str(s) for s in model.noise]}; in the direct approach the measurement "
                "noise is the covariance R_k of N(y_k, R_k)"
            )
        if y.dim != model.n_u:
            raise ShapeError(
                f"measurements[{k}] has dimension {y.dim} but the inverse model {model.name!r} "
                f"has {model.n_u} inputs {[str(s) for s in model.inputs]}"
            )
        m = propagate(model, y, transform=_estimator_transform(transform))
        moments.append(m)
        estimates.append(m.y)
    n = {g.dim for g in estimates}
    if len(n) != 1:
        raise ShapeError(f"the inverse models give estimates of different dimensions {sorted(n)}")
    return DirectResult(tuple(estimates), fuse(*estimates), tuple(moments))


# --------------------------------------------------------------------------- indirect
def _is_number_sequence(obj: Any) -> bool:
    if isinstance(obj, np.ndarray):
        return obj.dtype.kind in "biuf"
    if isinstance(obj, (list, tuple)):
        return all(isinstance(v, (int, float, np.integer, np.floating)) for v in obj)
    return isinstance(obj, (int, float, np.integer, np.floating))


def _indirect_steps(
    h_model: Model, measurements: Any, noise: ArrayLike | None
) -> list[tuple[Model, np.ndarray, np.ndarray]]:
    """Normalise the measurement argument of :func:`indirect` to (model, y, R) steps."""
    if isinstance(measurements, np.ndarray) and measurements.ndim == 2:
        raw = list(measurements)  # one measurement per row
    elif isinstance(measurements, Gaussian) or _is_number_sequence(measurements):
        raw = [measurements]
    else:
        raw = list(measurements)
    if not raw:
        raise ShapeError("measurements must hold at least one measurement")
    steps = []
    for k, item in enumerate(raw):
        name = f"measurements[{k}]"
        model, R = h_model, noise
        if isinstance(item, Gaussian):
            # N(y_k, R_k): condition on its mean with its covariance as the noise ("exact
            # measurement statistics" of the lecture's radar example).
            y_raw, R = item.mean, item.cov
        elif isinstance(item, tuple):
            if len(item) not in (2, 3):
                raise ShapeError(f"{name} must be y, N(y, R), (y, R) or (y, R, h_model), got {len(item)} entries")
            y_raw, R = item[0], (noise if item[1] is None else item[1])
            if len(item) == 3:
                model = check_model(item[2], f"{name}[2]")
        else:
            y_raw = item
        y = as_vector(y_raw, f"{name} y", dim=model.n_y)
        steps.append((model, y, noise_cov(model, R, f"{name} R")))
    return steps


def indirect(
    h_model: Model,
    prior: Gaussian,
    measurements: Any,
    noise: ArrayLike | None = None,
    transform: Transform | None = None,
) -> IndirectResult:
    """Indirect approach: NLT of [x; h(x, e)] from the prior, then conditioning (Lemma 7.1).

    For each measurement in turn (the previous posterior is the next prior):

    1. u = [x; e] ~ N([x̂₀; 0], blkdiag(P^{xx}, R_k));
    2. an NLT of z = [x; h(x, e)] gives N([x̂₀; ŷ], [[P^{xx}, P^{xy}], [P^{yx}, P^{yy}]]);
    3. x̂_k = x̂₀ + P^{xy}(P^{yy})⁻¹(y_k − ŷ), Cov = P^{xx} − P^{xy}(P^{yy})⁻¹P^{yx}.

    Angle outputs of h (``Model(..., angles={i})``) get a wrapped innovation.

    Parameters
    ----------
    h_model : Model
        y = h(x, e): inputs x, noise symbols e. Without noise symbols the noise is additive,
        y = h(x) + e, and R is added to P^{yy}.
    prior : Gaussian
        N(x̂₀, P^{xx}).
    measurements
        One measurement or a sequence of them. A measurement is a vector y (noise ``noise``),
        a Gaussian N(y, R) (condition on y with noise R), a tuple ``(y, R)`` or a tuple
        ``(y, R, h_model_k)`` for a sensor with its own model (R = None means ``noise``).
        A 2-D array holds one measurement per row.
    noise : array_like, optional
        The default noise covariance R: Cov e for the noise symbols, or the additive
        covariance (n_y, n_y) for a model without them.
    transform : Transform, default ``UT.ut1()``
        The NLT; TT1 is the lecture's "Gauss approximation formula".

    Returns
    -------
    IndirectResult
        Every intermediate posterior and the joint approximations.

    Raises
    ------
    ShapeError
        A measurement or covariance of the wrong dimension, or a missing R.
    SingularMatrixError
        A singular innovation covariance P^{yy}.

    Examples
    --------
    >>> import numpy as np, sympy as sp, symmon as sm
    >>> x = sp.symbols("x")
    >>> res = indirect(sm.Model([x], [2 * x]), sm.Gaussian([0.0], [[1.0]]), [[2.0]], noise=[[1.0]],
    ...                transform=sm.TT1())
    >>> res.posterior
    N([0.8], [[0.2]])
    """
    check_model(h_model, "h_model")
    check_gaussian(prior, "prior", dim=h_model.n_u)
    steps = _indirect_steps(h_model, measurements, noise)
    x = prior
    posteriors, joints = [], []
    for k, (model, y, R) in enumerate(steps):
        if model.n_u != prior.dim:
            raise ShapeError(
                f"measurements[{k}]: its model {model.name!r} has {model.n_u} inputs but the "
                f"prior has dimension {prior.dim}"
            )
        joint = _joint(model, x, R, transform)
        x = _condition(model, joint, y, f"measurements[{k}]")
        joints.append(joint)
        posteriors.append(x)
    return IndirectResult(prior, tuple(posteriors), tuple(joints))


# --------------------------------------------------------------------------- Kalman steps
def predict(model_f: Model, x: Gaussian, Q: ArrayLike, transform: Transform | None = None) -> Gaussian:
    """Time update x⁺ = f(x, w) by an NLT: N(E f, Cov f (+ Q)).

    TT1 gives the EKF prediction F P Fᵀ + Q, the UT the UKF's.

    Parameters
    ----------
    model_f : Model
        The dynamics, with as many outputs as inputs. With noise symbols w, ``Q`` is Cov w
        and the NLT runs on [x; w]; without them the noise is additive and ``Q`` is added.
    x : Gaussian
        The current estimate N(x̂, P).
    Q : array_like
        Process noise covariance.
    transform : Transform, default ``UT.ut1()``

    Returns
    -------
    Gaussian
        The predicted N(x̂⁻, P⁻).

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.symbols("x")
    >>> predict(sm.Model([x], [2 * x]), sm.Gaussian([1.0], [[1.0]]), [[0.5]], transform=sm.TT1())
    N([2], [[4.5]])
    """
    check_model(model_f, "model_f")
    if model_f.n_y != model_f.n_u:
        raise ShapeError(
            f"model_f must map the state to itself: it has {model_f.n_u} inputs and {model_f.n_y} outputs"
        )
    check_gaussian(x, "x", dim=model_f.n_u)
    dim = model_f.n_v if model_f.n_v else model_f.n_u
    Qm = as_covariance(Q, "Q", dim=dim)
    if model_f.n_v:
        m = propagate(model_f, x, Gaussian(np.zeros(dim), Qm), transform=_estimator_transform(transform))
        cov = np.array(m.cov)
    else:
        m = propagate(model_f, x, transform=_estimator_transform(transform))
        cov = m.cov + Qm
    return Gaussian(m.mean, 0.5 * (cov + cov.T))


def update(
    model_h: Model, x: Gaussian, y: ArrayLike, R: ArrayLike, transform: Transform | None = None
) -> Gaussian:
    """Measurement update: one step of the indirect approach (NLT of [x; h], Lemma 7.1).

    TT1 gives the EKF update, TT2 the second-order EKF's and the UT the UKF's.

    Parameters
    ----------
    model_h : Model
        y = h(x, e) (noise symbols e) or y = h(x) + e (none).
    x : Gaussian
        The prior N(x̂⁻, P⁻).
    y : array_like, shape (n_y,)
        The measurement.
    R : array_like
        Cov e.
    transform : Transform, default ``UT.ut1()``

    Returns
    -------
    Gaussian
        The posterior N(x̂, P).

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.symbols("x")
    >>> update(sm.Model([x], [x]), sm.Gaussian([0.0], [[1.0]]), [1.0], [[1.0]], transform=sm.TT1())
    N([0.5], [[0.5]])
    """
    check_model(model_h, "model_h")
    check_gaussian(x, "x", dim=model_h.n_u)
    yv = as_vector(y, "y", dim=model_h.n_y)
    Rm = noise_cov(model_h, R, "R")
    return _condition(model_h, _joint(model_h, x, Rm, transform), yv, "update")
