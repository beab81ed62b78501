"""The checks of a filter call's inputs, in one module: the measurements, ``keep``, the size of
a bank's results, the true states, the initial state and the models' parameter values.

:func:`check_call` runs them all, in the order a caller meets them, for every filter's
:meth:`~symmon.filters.base.Filter.filter` (a :class:`FilterCall`), and for the nonlinear
filter's smoother and fit; the filter files use the single checks.  It is the bottom of
:mod:`symmon.filters`: the results, the filter, its strategies, its fit and its export import
it, and it imports none of them.  :class:`FilterSpec` is what they read from a filter, so that
none of them needs the filter's class (nor imports :mod:`symmon.filters.gaussian.nonlinear`, which
imports them).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from decimal import Decimal
from typing import Any, Iterable, Protocol

import numpy as np
from numpy.typing import ArrayLike

from ..core.checks import check_gaussian, check_model
from ..core.gaussian import Gaussian, as_covariance, float_array
from ..core.model import Model
from ..core.sde import SDE
from ..errors import ArgumentError, ArgumentTypeError, CovarianceError, ModelError, ResourceError, ShapeError, plain_repr

__all__ = ["FilterSpec", "FilterCall", "check_call", "KEEPABLE", "check_keep", "real_measurements",
           "check_t0", "measurement_times", "time_intervals",
           "check_truth", "check_state_models", "measurement_bank", "refuse_inf", "MAX_BANK_NUMBERS",
           "check_bank_size", "kept_numbers", "initial_state", "param_values"]


class FilterSpec(Protocol):
    """A nonlinear filter as its strategies, fit, export and input checks read it
    (:class:`~symmon.NonlinearKalmanFilter` is the one implementation)."""

    f_model: Model
    h_model: Model
    Q: np.ndarray
    R: np.ndarray
    transform: Any
    iterations: int
    square_root: bool
    strategy: Any  # a FilterStrategy (symmon.filters.gaussian.strategy imports this module)

    @property
    def params(self) -> tuple: ...

    @property
    def angle_states(self) -> frozenset[int]: ...

    @property
    def dimensions(self) -> tuple[int, int]: ...

    @property
    def method(self) -> str: ...


#: The arrays a filter can keep (``filter(..., keep=...)``).
KEEPABLE = ("x", "P", "x_pred", "P_pred", "innovation", "S", "nis")


def check_state_models(f_model: Model, h_model: Model) -> tuple[Model, Model]:
    """The checked models of a state space: f maps the state to itself, h reads the state.

    Raises
    ------
    ArgumentTypeError
        f is an :class:`~symmon.SDE` (the message points to its discretisation and to the
        continuous-discrete filter).
    ShapeError
        f's outputs are not its inputs in number, or h's inputs are not f's states.
    """
    if isinstance(f_model, SDE):
        raise ArgumentTypeError(
            f"f_model is an SDE ({f_model.name!r}): a discrete filter needs its transition, "
            "sde.discretize('exact' or 'taylor1.5', ...) with Q = I and dt a parameter, or filter the SDE "
            "itself with sm.ContinuousDiscreteKalmanFilter(sde, h, R, transform)")
    f = check_model(f_model, "f_model")
    h = check_model(h_model, "h_model")
    if f.n_y != f.n_u:
        raise ShapeError(f"f_model must map the state to itself: {f.n_u} inputs, {f.n_y} outputs")
    if h.n_u != f.n_u:
        raise ShapeError(f"h_model has {h.n_u} inputs but f_model has {f.n_u} states")
    return f, h


def measurement_bank(ys: ArrayLike, n_y: int) -> tuple[np.ndarray, int | None]:
    """``ys`` as real measurements of shape (K, n_y) for one run or (R, K, n_y) for a bank of
    R runs (:func:`real_measurements`), and R (None for one run).

    Raises
    ------
    ShapeError
        Another shape, no step or no run, or what :func:`real_measurements` refuses.
    """
    Y = real_measurements(ys)
    if Y.ndim not in (2, 3) or Y.shape[-1] != n_y or Y.shape[-2] == 0 or Y.shape[0] == 0:
        raise ShapeError(f"ys must have shape (K, {n_y}) or (R, K, {n_y}) with K >= 1, got {Y.shape}")
    return Y, (Y.shape[0] if Y.ndim == 3 else None)


def refuse_inf(Y: np.ndarray) -> None:
    """Refuse an infinite measurement, naming its index: a missing one is NaN. Called after
    the bank's size is checked, since it reads ``Y`` whole (a broadcast bank may be larger
    than memory)."""
    if np.isinf(Y).any():
        where = tuple(int(i) for i in np.argwhere(np.isinf(Y))[0])
        raise ShapeError(f"ys contains inf (at index {where}); a missing measurement is NaN")


def check_keep(keep: Iterable[str] | str | None, allowed: Iterable[str] = KEEPABLE) -> frozenset[str] | None:
    """``keep`` of a filter call as a set of names of ``allowed`` (None: all); a string is
    one name.

    Raises
    ------
    ArgumentError
        For an unknown name, or a ``keep`` that is not a name or a collection of names.
    """
    if keep is None:
        return None
    allowed = tuple(allowed)
    if isinstance(keep, str):
        keep = (keep,)
    try:
        names = frozenset(keep)
    except TypeError:
        raise ArgumentError(f"keep must be a name or a collection of names among {list(allowed)}, "
                            f"got {keep!r}") from None
    unknown = sorted(names - set(allowed), key=repr)
    if unknown:
        raise ArgumentError(f"keep names {unknown} are not results of this filter; use some of {list(allowed)}")
    return names


def _first_none(x: Any, depth: int = 3) -> tuple[int, ...] | None:
    """The index of the first ``None`` in nested lists/tuples (or an object array) of ``x``."""
    if x is None:
        return ()
    if depth == 0 or not (isinstance(x, (list, tuple)) or (isinstance(x, np.ndarray) and x.dtype == object)):
        return None
    for i, item in enumerate(x):
        below = _first_none(item, depth - 1)
        if below is not None:
            return (i, *below)
    return None


def real_measurements(ys: ArrayLike) -> np.ndarray:
    """``ys`` as a float array; complex, non-numeric or text measurements are refused, not cast.

    Raises
    ------
    ShapeError
        For complex values, values that are not numbers, strings (``ys.astype(str)``: even
        numeric text is refused, as the docs say, since a parser's choice of decimal mark or
        a stray unit would pass unseen) or ``None`` (FilterPy's missing measurement: symmon's
        is NaN).
    """
    where = _first_none(ys)
    if where is not None:
        raise ShapeError(f"ys holds None at index {where}: a missing measurement is NaN in symmon (FilterPy's "
                         "update(None)): write np.nan for it, a row of NaN for a missing row")
    try:
        raw = ys if isinstance(ys, np.ndarray) else np.asarray(ys)
    except (TypeError, ValueError):
        raw = ys  # ragged or not numbers: float_array says what is wrong
    if isinstance(raw, np.ndarray) and (raw.dtype.kind in "US" or (
            raw.dtype == object and any(isinstance(v, (str, bytes)) for v in raw.flat))):
        raise ShapeError("ys holds text, not real numbers: convert it explicitly (np.asarray(ys, dtype=float) once "
                         "you know its format), so that a number is never read from a string unseen")
    return float_array(raw, "ys", ShapeError)


def check_t0(t0: Any) -> float:
    """``t0``, the time of the prior x_0, as a float.

    Raises
    ------
    ArgumentError
        ``t0`` is not a finite real number.
    """
    if isinstance(t0, (bool, np.bool_)) or not isinstance(t0, (int, float, np.integer, np.floating)) \
            or not np.isfinite(t0):
        raise ArgumentError(f"t0 must be a finite number (the time of x_0), got {plain_repr(t0)}")
    return float(t0)


def measurement_times(times: ArrayLike, t0: float = 0.0, runs: int | None = None, steps: int | None = None,
                      name: str = "times") -> np.ndarray:
    """Measurement times, checked: a 1-D array of strictly increasing finite times after
    ``t0`` (shape (K,) when ``steps`` = K is given), or for a bank of ``runs`` runs one row
    of them per run, shape (R, K).

    Raises
    ------
    ArgumentError
        Times that are not real numbers, of another shape, not finite, not after ``t0`` or
        not strictly increasing, naming the first bad index; a bad ``t0``.
    """
    t0 = check_t0(t0)
    try:
        t = np.asarray(times, dtype=float)
    except (TypeError, ValueError):
        raise ArgumentError(f"{name} must be a 1-D sequence of numbers, got {plain_repr(times)}") from None
    shapes = ["(K,)" if steps is None else f"({steps},)"]
    if runs is not None:
        shapes.append(f"({runs}, {'K' if steps is None else steps})")
    ok_1d = t.ndim == 1 and t.size > 0 and (steps is None or t.shape[0] == steps)
    ok_2d = runs is not None and t.ndim == 2 and t.shape[0] == runs and t.shape[1] > 0 and (
        steps is None or t.shape[1] == steps)
    if not (ok_1d or ok_2d):
        raise ArgumentError(f"{name} must be a non-empty 1-D array of one time per measurement, shape {shapes[0]}"
                            + (f", or one row of them per run, shape {shapes[1]}" if runs is not None else "")
                            + f"; got shape {t.shape}")
    rows = t.reshape(-1, t.shape[-1])

    def at(r: int, k: int) -> str:
        return f"{name}[{k}]" if t.ndim == 1 else f"{name}[{r}, {k}]"

    bad = np.argwhere(~np.isfinite(rows))
    if bad.size:
        r, k = (int(i) for i in bad[0])
        raise ArgumentError(f"{name} must be finite: {at(r, k)} = {float(rows[r, k])!r}")
    dt = time_intervals(rows, t0)
    bad = np.argwhere(~(dt > 0))
    if bad.size:
        r, k = (int(i) for i in bad[0])
        if k == 0:
            raise ArgumentError(f"{name} must be after t0 = {t0:g} (the time of x_0): {at(r, 0)} = {rows[r, 0]:g}")
        raise ArgumentError(f"{name} must be strictly increasing: {at(r, k)} = {rows[r, k]:g} follows "
                            f"{at(r, k - 1)} = {rows[r, k - 1]:g}")
    return t


def time_intervals(times: np.ndarray, t0: float = 0.0) -> np.ndarray:
    """The intervals t_k − t_{k−1} (t_{−1} = ``t0``) of times (K,) or (R, K), along the last
    axis (the shape of ``times``)."""
    t = np.asarray(times, dtype=float)
    start = np.full(t.shape[:-1] + (1,), float(t0))
    return np.diff(np.concatenate([start, t], axis=-1), axis=-1)


def check_truth(x_true: ArrayLike, shape: tuple[int, ...]) -> np.ndarray:
    """The true states ``x_true`` as a finite float array of ``shape`` ((K, n) or (R, K, n)).

    Raises
    ------
    ShapeError
        For another shape, or NaN or inf (complex values are refused by ``float_array``).
    """
    X = float_array(x_true, "x_true")
    if X.shape != tuple(shape):
        raise ShapeError(f"x_true must have the shape of x, {tuple(shape)}, got {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ShapeError("x_true contains NaN or inf")
    return X


#: The most numbers (8 bytes each: 1.5 GiB) that the arrays of one filter bank may hold: a
#: filter call's results (R × K × the numbers per step of the arrays kept), a smoother's,
#: or a simulated bank's states and measurements.  Beyond it the allocation would end in a
#: MemoryError, or in the system's out-of-memory killer half-way through the run: the size
#: is checked before anything is computed.
MAX_BANK_NUMBERS = 2 * 10**8


def check_bank_size(runs: int, steps: int, per_step: int, what: str, advice: str, shared: int = 0) -> None:
    """Refuse a bank whose arrays would hold more than :data:`MAX_BANK_NUMBERS` numbers.

    ``per_step`` is the count of numbers per run and step, ``shared`` per step for all
    runs (the linear filter's covariances); ``what`` names the arrays and ``advice`` says
    how to make them smaller.

    Raises
    ------
    ResourceError
        When runs × steps × per_step (+ steps × shared) exceeds the limit.
    """
    total = int(runs) * int(steps) * int(per_step) + int(steps) * int(shared)  # Python ints: no overflow
    if total > MAX_BANK_NUMBERS:
        gib = Decimal(8 * total) / 2**30  # a float would overflow for 400-digit counts
        raise ResourceError(
            f"{what}: runs × steps × numbers per step = {runs} × {steps} × {per_step}"
            + (f" (+ {shared} per step)" if shared else "")
            + f" = {Decimal(total):.3g} numbers ({gib:.3g} GiB), which exceeds the limit of "
            f"{MAX_BANK_NUMBERS:.0e} ({8 * MAX_BANK_NUMBERS / 2**30:.1f} GiB): {advice}")


def kept_numbers(n: int, n_y: int, names: Iterable[str]) -> int:
    """Numbers per run and step of the filter arrays ``names`` (and the log-likelihood)."""
    size = {"x": n, "P": n * n, "x_pred": n, "P_pred": n * n, "innovation": n_y, "S": n_y * n_y, "nis": 1}
    return 1 + sum(size[k] for k in set(names) if k in size)


def initial_state(n: int, x0: Gaussian | ArrayLike, P0: ArrayLike | None,
                  runs: int | None) -> tuple[np.ndarray, np.ndarray]:
    """The initial mean(s) and covariance(s) of a filter of state dimension ``n``: from a
    Gaussian, or a mean (n,) or (R, n) with ``P0`` (n, n) or (R, n, n).

    Raises
    ------
    ShapeError, CovarianceError, ArgumentTypeError
        A bad shape, NaN or inf, a covariance that is not one, or neither form given.
    """
    if isinstance(x0, Gaussian):
        if P0 is not None:
            raise ShapeError("P0 must not be given with a Gaussian x0 (it carries its covariance)")
        check_gaussian(x0, "x0", dim=n)
        return np.asarray(x0.mean, dtype=float), np.asarray(x0.cov, dtype=float)
    if P0 is None:
        raise ArgumentTypeError("x0 must be a symmon.Gaussian, or a mean given together with P0")
    m = float_array(x0, "x0")
    if not (m.shape == (n,) or (runs is not None and m.shape == (runs, n))):
        want = f"({n},)" + ("" if runs is None else f" or ({runs}, {n})")
        raise ShapeError(f"x0 must have shape {want}, got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ShapeError("x0 contains NaN or inf")
    C = float_array(P0, "P0", CovarianceError)
    if runs is not None and C.shape == (runs, n, n):  # one covariance per run, each made symmetric
        return m, np.stack([as_covariance(C[r], f"P0[{r}]", dim=n) for r in range(runs)])
    return m, as_covariance(P0, "P0", dim=n)


def param_values(names: tuple, params: dict | None, runs: int | None, K: int,
                 who: str = "the filter's models") -> np.ndarray | None:
    """The values of the parameters ``names`` (sympy symbols) as (R, K, n_p): for each, a
    scalar, one per step (K,), or one per run and step (R, K); None without parameters.

    Raises
    ------
    ModelError
        ``params`` is not a dict, or misses or adds a parameter (``who`` names the models).
    ShapeError
        A value of another shape, or NaN or inf.
    """
    if not names:
        if params:
            raise ModelError(f"{who} declare no parameters, got params {sorted(map(str, params))}")
        return None
    names = [str(s) for s in names]
    if not isinstance(params, dict):
        raise ModelError(f"{who} have parameters {names}: give params={{name: value}}, "
                         f"got {type(params).__name__}")
    given = {str(k): v for k, v in params.items()}
    unknown = sorted(set(given) - set(names))
    missing = [n for n in names if n not in given]
    if unknown or missing:
        raise ModelError(f"params must give each of {names}" + (f"; unknown {unknown}" if unknown else "")
                         + (f"; missing {missing}" if missing else ""))
    R = runs or 1
    out = np.empty((R, K, len(names)))
    for j, n in enumerate(names):
        v = float_array(given[n], f"parameter {n!r}")
        shapes = [(), (K,)] + ([(runs, K)] if runs is not None else [])
        if v.shape not in shapes:
            raise ShapeError(f"parameter {n!r} must be a number, one per step ({K},)"
                             + (f" or one per run and step ({runs}, {K})" if runs is not None else "")
                             + f", got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ShapeError(f"parameter {n!r} contains NaN or inf")
        out[..., j] = v
    return out


def filter_params(f: Model, h: Model) -> tuple:
    """The parameters of a filter: f's, then h's whose names f does not have.

    One name is one parameter: a ``b`` of h declared as another sympy symbol than f's ``b``
    (other assumptions, or made apart) is the same parameter, as ``filter(params={"b": …})``
    sets it, so that a fit varies the one value both models use."""
    names = {str(s) for s in f.params}
    return tuple(f.params) + tuple(s for s in h.params if str(s) not in names)


@dataclass(frozen=True)
class FilterCall:
    """The checked inputs of one call of :meth:`Filter.filter`.

    Attributes
    ----------
    Y : ndarray, shape (R, K, n_y)
        The measurements as a bank (R = 1 for a single run); NaN marks a missing one.
    runs : int or None
        R for a bank, None for a single run (the results then have no run axis).
    keep : frozenset of str, or None
        The arrays to keep (None: all).
    x0 : object
        The prior as the filter's :meth:`Filter._check_prior` returned it: a mean (n,) or
        (R, n) and a covariance (n, n) or (R, n, n) for the Gaussian filters
        (``x0`` and ``P0``), a distribution for the particle and Gaussian-sum filters.
    P0 : ndarray or None
        The covariance(s) of a Gaussian filter's prior (None for the others).
    params : dict or None
        The parameter values as given (the shards of a bank slice their per-run values).
    pv : object
        The parameter values as the filter's :meth:`Filter._check_params` returned them
        (for one set of models: (R, K, n_p), or None without parameters).
    truth : ndarray, shape (R, K, n), or None
        The true states, when given: each step's NEES is computed against them.
    first_run : int
        The index of the first run in a larger bank (a random filter draws run r from the
        stream of run ``first_run + r``).
    times : ndarray, shape (K,) or (R, K), or None
        The measurement times of a continuous-time filter (``filter(times=...)``), checked:
        strictly increasing after ``t0``; one row per run for a bank with its own times
        (the shards of a bank cut them).  None without times.
    t0 : float
        The time of the prior x_0 (0 unless given with ``times``).
    """

    Y: np.ndarray
    runs: int | None
    keep: frozenset[str] | None
    x0: Any
    P0: np.ndarray | None
    params: dict | None
    pv: Any
    truth: np.ndarray | None
    first_run: int = 0
    times: np.ndarray | None = None
    t0: float = 0.0

    @property
    def steps(self) -> int:
        """K, the number of steps."""
        return int(self.Y.shape[1])

    @property
    def intervals(self) -> np.ndarray | None:
        """The intervals t_k − t_{k−1} before each measurement (t_{−1} = ``t0``), of the shape of
        ``times`` ((K,), or (R, K) per run); None without times."""
        return None if self.times is None else time_intervals(self.times, self.t0)

    @property
    def measurements(self) -> np.ndarray:
        """The measurements as given: (K, n_y) for one run, (R, K, n_y) for a bank."""
        return self.Y if self.runs is not None else self.Y[0]

    def shard(self, a: int, b: int) -> FilterCall:
        """The runs ``a`` … ``b - 1`` of a bank, as a call of their own (a shard of
        :func:`~symmon.filters.bank.filter_bank`)."""
        if self.runs is None:
            if (a, b) != (0, 1):
                raise ArgumentError(f"a single run has no runs {a} … {b - 1}")
            return self
        if not 0 <= a < b <= self.runs:
            raise ArgumentError(f"runs {a} … {b - 1} are not runs of a bank of {self.runs}")

        def cut(v: Any, ndim: int) -> Any:
            return v[a:b] if isinstance(v, np.ndarray) and v.ndim == ndim else v

        params = self.params
        if isinstance(params, dict):
            params = {k: (np.asarray(v)[a:b] if np.ndim(v) == 2 else v) for k, v in params.items()}
        return dataclasses.replace(
            self, Y=self.Y[a:b], runs=b - a, x0=cut(self.x0, 2) if self.P0 is not None else self.x0,
            P0=cut(self.P0, 3), params=params, pv=_cut_values(self.pv, a, b),
            truth=None if self.truth is None else self.truth[a:b], first_run=self.first_run + a,
            times=cut(self.times, 2))


def _cut_values(pv: Any, a: int, b: int) -> Any:
    """Parameter values (R, K, n_p), or a list of them (one per mode), cut to runs a … b − 1."""
    if isinstance(pv, np.ndarray):
        return pv[a:b]
    if isinstance(pv, (list, tuple)):
        return type(pv)(_cut_values(v, a, b) for v in pv)
    return pv


def _check_runs(runs: int, **values: tuple[Any, int]) -> None:
    """Refuse a per-run value (an array of its ``ndim`` whose leading axis is the runs') with
    another number of runs than the bank's."""
    for name, (value, ndim) in values.items():
        if isinstance(value, (np.ndarray, list, tuple)) and np.ndim(value) == ndim and len(value) != runs:
            raise ShapeError(f"{name} has {len(value)} runs (its leading axis) but ys has {runs}")


def check_call(filt: Any, ys: ArrayLike, x0: Any, P0: ArrayLike | None = None, *,
               keep: Iterable[str] | str | None = None, params: dict | None = None,
               x_true: ArrayLike | None = None, first_run: int = 0, times: ArrayLike | None = None,
               t0: float = 0.0, extra_per_step: int = 0, what: str = "results",
               advice: str = "keep fewer arrays, or filter the runs in smaller banks") -> FilterCall:
    """Every check of a filter call's inputs, in the order a caller meets them.

    ``times`` (and ``t0``) are for a filter that declares ``continuous_time``: K measurement
    times (K,), or (R, K) per run for a bank (:func:`measurement_times`); its
    ``_check_params`` hook then receives their intervals (``intervals=``; None without times).
    ``extra_per_step`` numbers per run and step are added to those the filter keeps (a
    smoother's x and P), ``what`` names them, and ``advice`` ends the size bound's message.

    Raises
    ------
    ShapeError
        ``ys`` not (K, n_y) or (R, K, n_y), not real, or holding inf; a bad ``x_true``.
    ArgumentError
        A bad ``keep``, ``first_run``, ``times`` or ``t0``; ``P0`` given to a filter whose prior
        is a distribution; ``times`` (or ``t0``) given to a discrete-time filter, or ``t0``
        without ``times``.
    ArgumentTypeError, CovarianceError, ModelError
        A bad prior or parameters.
    """
    default_t0 = not isinstance(t0, (bool, np.bool_)) and isinstance(t0, (int, float, np.integer, np.floating)) \
        and t0 == 0
    if not filt.continuous_time and (times is not None or not default_t0):
        given = "times" if times is not None else "t0"
        raise ArgumentError(
            f"{filt.method} is a discrete-time filter: it takes no {given} (its steps are its model's "
            "transitions); filter an SDE at irregular times with sm.ContinuousDiscreteKalmanFilter(sde, h, R, ...) "
            "and times=..., or give a discretised model (sde.discretize(...)) a per-step dt in params")
    if times is None and not default_t0:
        raise ArgumentError(f"t0 (the time of x_0) applies only with times; got t0 = {plain_repr(t0)} without times")
    n, n_y = filt.sizes
    kept = check_keep(keep, filt.keepable)
    if isinstance(first_run, bool) or not isinstance(first_run, (int, np.integer)) or first_run < 0:
        raise ArgumentError(f"first_run must be a non-negative integer, got {plain_repr(first_run)}")
    if first_run and not filt.random:
        raise ArgumentError(f"first_run is for a filter that draws random numbers; {filt.method} draws none")
    Y, runs = measurement_bank(ys, n_y)
    Yb = Y.reshape((runs or 1,) + Y.shape[-2:])
    if runs is not None:
        _check_runs(runs, x0=(x0, 2), P0=(P0, 3), x_true=(x_true, 3))
        if isinstance(params, dict):
            _check_runs(runs, **{f"parameter {str(k)!r}": (v, 2) for k, v in params.items()})
    per_step, shared = filt._numbers(kept)
    check_bank_size(runs or 1, Yb.shape[1], per_step + extra_per_step, f"{filt.method} {what}", advice, shared=shared)
    refuse_inf(Y)
    T = None if times is None else measurement_times(times, t0, runs, Yb.shape[1])
    if filt.takes_covariance:
        m0, C0 = filt._check_prior(x0, P0, runs)
    else:
        if P0 is not None:
            raise ArgumentError(f"{filt.method} takes a distribution as x0 (a Gaussian or a mixture), not P0")
        m0, C0 = filt._check_prior(x0, None, runs)
    truth = None
    if x_true is not None:
        truth = check_truth(x_true, Y.shape[:-1] + (n,)).reshape(Yb.shape[:2] + (n,))
    if filt.continuous_time:
        pv = filt._check_params(params, runs, Y.shape[-2], intervals=None if T is None else time_intervals(T, t0))
    else:
        pv = filt._check_params(params, runs, Y.shape[-2])
    return FilterCall(Y=Yb, runs=runs, keep=kept, x0=m0, P0=C0, params=params, pv=pv, truth=truth,
                      first_run=int(first_run), times=T, t0=0.0 if T is None else float(t0))
