"""The contract of every filter: :class:`Filter` (its checked call is
:class:`~symmon.filters.inputs.FilterCall`), and the filter classes.

A filter subclasses :class:`Filter`, declares its capabilities as class variables and
implements one hook, :meth:`Filter._filter`, which receives a :class:`FilterCall` whose inputs
:func:`check_call` has already checked.  The public method :meth:`Filter.filter` is the same
template for every filter and final: it checks the inputs once (one function assembles every
check, so that no filter can skip one), hands a bank to an executor once
(:func:`symmon.filters.bank.filter_bank`), and calls the family's hook.  Nothing reads a
filter's capabilities from its signature or its class: what a caller needs, the class
declares (docs/architecture.md, "Adding a filter").
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, Callable, ClassVar, Iterable

import numpy as np
from numpy.typing import ArrayLike

from ..core.sde import SDE
from ..transforms.executor import Executor
from .bank import constructor_args, filter_bank
from .inputs import KEEPABLE, FilterCall, check_call, initial_state, kept_numbers, param_values

__all__ = ["Filter", "filter_classes", "register_sde_builder"]

#: Every concrete filter class, by its name, in the order they were defined.
_CLASSES: dict[str, type] = {}
#: What a filter class's constructor builds when its first argument is an SDE (by class name,
#: as :func:`filter_classes` names the classes).
_SDE_BUILDERS: dict[str, Callable[..., Any]] = {}


def register_sde_builder(kind: str, builder: Callable[..., Any]) -> None:
    """Make the filter class named ``kind`` return ``builder(sde, ...)`` when its first argument
    (positional or by its first field's name) is an :class:`~symmon.SDE`: the discrete filters'
    spelling of the continuous-discrete filter (:mod:`symmon.filters.gaussian.continuous`
    registers ``NonlinearKalmanFilter`` and ``KalmanFilter``; it builds on the first, so
    neither names it)."""
    _SDE_BUILDERS[kind] = builder


def filter_classes() -> dict[str, type]:
    """Every concrete subclass of :class:`Filter`, by class name (a copy)."""
    return dict(_CLASSES)


class Filter(abc.ABC):
    """The contract of every filter of symmon.

    A filter is a frozen dataclass of its settings that subclasses :class:`Filter`, declares
    the capabilities below and implements :meth:`_filter`.  :meth:`filter` is final.

    Capabilities (class variables)
    ------------------------------
    random : bool
        The filter draws random numbers: run r of a bank draws from the stream of run
        ``first_run + r`` (:func:`~symmon.filters.bank.run_streams`), so that a bank filtered
        in shards gives the numbers of the whole bank.
    keepable : tuple of str
        The arrays ``keep=`` may name.
    has_smoother : bool
        The filter has a ``smooth`` method (a Rauch–Tung–Striebel or ensemble smoother).
    exportable : bool
        The filter has an ``export_c`` method (standalone C99).
    gaussian_mode : bool
        The filter is a Gaussian filter that :class:`~symmon.IMM` may mix as a mode; it
        then implements :meth:`as_gaussian_mode`.
    takes_covariance : bool
        ``x0`` may be a mean given with ``P0`` (the Gaussian filters); otherwise ``x0`` is a
        distribution and ``P0`` is refused.
    continuous_time : bool
        The filter's model runs in continuous time: :meth:`filter` takes the measurement
        ``times`` (and ``t0``, the time of ``x0``), and :meth:`_check_params` receives their
        intervals (``intervals=``).  A discrete-time filter (the default) refuses ``times``:
        its steps are its model's transitions.
    """

    random: ClassVar[bool] = False
    keepable: ClassVar[tuple[str, ...]] = KEEPABLE
    has_smoother: ClassVar[bool] = False
    exportable: ClassVar[bool] = False
    gaussian_mode: ClassVar[bool] = False
    takes_covariance: ClassVar[bool] = True
    continuous_time: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "filter" in cls.__dict__:
            raise TypeError(f"{cls.__name__} overrides Filter.filter; a filter implements the hook _filter, "
                            "and Filter.filter checks the inputs and hands banks to executors for it")
        for name, kind in (("random", bool), ("has_smoother", bool), ("exportable", bool),
                           ("gaussian_mode", bool), ("takes_covariance", bool), ("continuous_time", bool),
                           ("keepable", tuple)):
            if not isinstance(getattr(cls, name), kind):
                raise TypeError(f"{cls.__name__}.{name} must be a {kind.__name__}")
        if cls.has_smoother and not callable(getattr(cls, "smooth", None)):
            raise TypeError(f"{cls.__name__} declares has_smoother but has no smooth method")
        if cls.exportable and not callable(getattr(cls, "export_c", None)):
            raise TypeError(f"{cls.__name__} declares exportable but has no export_c method")
        if not getattr(cls, "__abstractmethods__", None) and not getattr(_filter_hook(cls), "__isabstractmethod__",
                                                                          False):
            _CLASSES[cls.__name__] = cls

    def __new__(cls, *args: Any, **kwargs: Any) -> Any:
        """The filter; or, for a class with a registered builder (:func:`register_sde_builder`)
        given an SDE as its first argument, what the builder returns."""
        builder = _SDE_BUILDERS.get(cls.__name__) if _CLASSES.get(cls.__name__) is cls else None
        if builder is not None:
            name = dataclasses.fields(cls)[0].name
            first = args[0] if args else kwargs.get(name)
            if isinstance(first, SDE):  # the builder takes it first, whatever the class calls it
                return builder(first, *args[1:], **{k: v for k, v in kwargs.items() if k != name})
        return super().__new__(cls)

    def __reduce__(self) -> tuple:
        """A filter pickles as its class and constructor arguments: it is rebuilt, and its
        compiled code comes back from the cache on disk (no compiled object travels)."""
        if not dataclasses.is_dataclass(self):
            return super().__reduce__()
        return _rebuild, (type(self), constructor_args(self))

    # -------------------------------------------------------------- what the template reads
    @property
    @abc.abstractmethod
    def sizes(self) -> tuple[int, int]:
        """(n, n_y): the dimensions of the state and of the measurement."""

    @abc.abstractmethod
    def step_cost(self) -> int:
        """Evaluations of the models per step of one run, as :func:`symmon.advise` counts a
        rule's (its declared ``cost``), times the components, particles or members: the
        deterministic cost by which a choice between filters compares them
        (:func:`~symmon.filters.selection.advise_filter`)."""

    @property
    def params(self) -> tuple:
        """The models' parameters (sympy symbols), whose values ``filter(params=...)`` gives."""
        return ()

    @property
    def method(self) -> str:
        """The name the filter prints (EKF, UKF(…), PF(N=…), GSF(…), IMM(…))."""
        return type(self).__name__

    def as_gaussian_mode(self) -> Any:
        """The filter as a mode of :class:`~symmon.IMM` (a ``NonlinearKalmanFilter``); only
        for a class that declares ``gaussian_mode``."""
        raise TypeError(f"{type(self).__name__} is not a Gaussian filter that IMM can mix")

    # ------------------------------------------------------------------ the template
    def filter(self, ys: ArrayLike, x0: Any, P0: ArrayLike | None = None, *, keep: Iterable[str] | str | None = None,
               params: dict | None = None, x_true: ArrayLike | None = None, executor: Executor | None = None,
               first_run: int = 0, times: ArrayLike | None = None, t0: float = 0.0) -> Any:
        """Filter the measurements ``ys`` from the prior ``x0``: for each measurement,
        predict, then update (``ys[k]`` is y_{k+1}).

        Parameters
        ----------
        ys : array_like, shape (K, n_y) or (R, K, n_y)
            Measurements y_1 … y_K; a leading axis filters R independent runs (a bank).  NaN
            means "not measured": a row of NaN skips the update (the step only predicts), a
            row with some NaN updates on the measured components.
        x0 : Gaussian, array_like, GaussianMixture or Empirical
            The prior of x_0 (before the first prediction): a Gaussian, or its mean (n,) or
            (R, n) together with ``P0`` for the Gaussian filters; the particle filter also
            takes a ``GaussianMixture`` or an ``Empirical``, the Gaussian-sum filter a
            ``GaussianMixture``.
        P0 : array_like, shape (n, n) or (R, n, n), optional
            The covariance of x_0 when ``x0`` is a mean (Gaussian filters only).
        keep : str or iterable of str, optional
            The arrays to return, among the class's :attr:`keepable` (a string is one name);
            default all.  The log-likelihood is always kept.
        params : dict, optional
            The models' parameter values by name: a number, one per step (K,), or one per run
            and step (R, K).
        x_true : array_like, shape (K, n) or (R, K, n), optional
            The true states: each step's NEES is computed against them.
        executor : Executor, optional
            Filter the runs of a bank in shards on threads, a local Dask scheduler or a Dask
            cluster (:func:`~symmon.filters.bank.filter_bank`): the same result bit for bit.
        first_run : int, default 0
            For a random filter: the index of the first run of ``ys`` in a larger bank, so
            that a bank filtered in pieces gives the numbers of the whole bank.
        times : array_like, shape (K,) or (R, K), optional
            For a continuous-time filter (``continuous_time``, e.g.
            :class:`~symmon.ContinuousDiscreteKalmanFilter`): the times t_1 < … < t_K of the
            measurements, after ``t0``, in the model's time unit; irregular allowed, and one
            row per run for a bank whose runs have their own times.  A discrete-time filter
            refuses them (its steps are its model's transitions).
        t0 : float, default 0
            The time of the prior ``x0`` (with ``times`` only).

        Returns
        -------
        KalmanResult
            The family's result (``KalmanResult``, ``ParticleResult``, ``GaussianSumResult``,
            ``IMMResult``, ``EnsembleResult``), with a leading run axis for a bank.

        Raises
        ------
        ShapeError, ArgumentError, ArgumentTypeError, CovarianceError, ModelError
            Bad inputs (:func:`check_call`), among them ``times`` given to a discrete-time
            filter, or times that are not strictly increasing after ``t0`` (naming the first
            bad index).
        ResourceError
            The results would exceed :data:`~symmon.filters.inputs.MAX_BANK_NUMBERS` numbers.
        SymmonError
            The filter produced NaN or inf, naming the step (and run).
        """
        call = check_call(self, ys, x0, P0, keep=keep, params=params, x_true=x_true, first_run=first_run,
                          times=times, t0=t0)
        if executor is not None:
            return filter_bank(self, executor, call)
        return self._filter(call)

    @abc.abstractmethod
    def _filter(self, call: FilterCall) -> Any:
        """The family's recursion over the checked ``call``; its result."""

    # -------------------------------------------------------- hooks of the checks
    def _check_prior(self, x0: Any, P0: ArrayLike | None, runs: int | None) -> tuple[Any, np.ndarray | None]:
        """The prior, checked: (mean, covariance) for a Gaussian filter
        (:func:`~symmon.filters.inputs.initial_state`)."""
        return initial_state(self.sizes[0], x0, P0, runs)

    def _numbers(self, keep: frozenset[str] | None) -> tuple[int, int]:
        """The numbers a call stores per run and step, and those its runs share, for the
        bound :data:`~symmon.filters.inputs.MAX_BANK_NUMBERS` (checked before any work)."""
        n, n_y = self.sizes
        return kept_numbers(n, n_y, self.keepable if keep is None else keep), 0

    def _check_params(self, params: dict | None, runs: int | None, steps: int) -> Any:
        """The parameter values, checked (:func:`~symmon.filters.inputs.param_values`).  A
        ``continuous_time`` filter's hook takes a keyword ``intervals`` too: the intervals
        t_k − t_{k−1} of ``times``, (K,) or (R, K), or None without times."""
        return param_values(self.params, params, runs, steps)


def _rebuild(kind: type, init: dict) -> Filter:
    """``kind(**init)``: a pickled filter, rebuilt."""
    return kind(**init)


def _filter_hook(cls: type) -> Any:
    return getattr(cls, "_filter", None)
