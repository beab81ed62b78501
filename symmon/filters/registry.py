"""The registry of filters by name, as :mod:`symmon.transforms.registry` is for rules.

One entry per filter: its name and aliases, a summary, the settings a scenario file's table of
that name may give (with their types), and how to build it from the models f and h and the
noise covariances Q and R.  Filter scenario files (:mod:`symmon.files.filterfile`),
``symmon filter --filters``, ``symmon export --filter``, ``symmon fit --filter`` and the CLI's
help read it, so a new filter appears everywhere by registering once (:func:`register`).  The
rule filters' names (``"ekf"`` … ``"ghkf"``) are those of :mod:`symmon.filters.names`, which
:class:`~symmon.NonlinearKalmanFilter` accepts too.

Examples
--------
>>> from symmon.filters.registry import filter_entry
>>> filter_entry("tt1").name, filter_entry("ukf").summary
('ekf', 'unscented Kalman filter, UT.ut1()')
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np
import sympy as sp

from ..core.model import Model
from ..errors import ModelError, SymmonError
from ..measures.advice import DEFAULT_TOL
from ..transforms.quadrature import GaussHermite
from .base import Filter
from .gaussian.adaptive import Adaptive
from .gaussian.continuous import ContinuousDiscreteKalmanFilter
from .gaussian.linear import KalmanFilter
from .gaussian.nonlinear import NonlinearKalmanFilter
from .ensemble.enkf import EnsembleKalmanFilter
from .mixture.gaussian_sum import GaussianSumFilter
from .mixture.imm import IMM
from .names import filter_rule
from .particle.particle_filter import ParticleFilter

__all__ = ["FilterEntry", "register", "filter_entry", "filter_names", "make_filter", "setting_fits"]

#: A builder: (f, h, Q, R, tol, settings) → the filter.
Builder = Callable[[Model, Model, np.ndarray, np.ndarray, float, dict], Filter]


@dataclass(frozen=True)
class FilterEntry:
    """One registered filter.

    Attributes
    ----------
    name : str
        The filter's name (lower case).
    summary : str
        What it is, in a few words (the CLI's help).
    kind : type
        The class it builds (a subclass of :class:`~symmon.filters.base.Filter`), whose class
        variables declare its capabilities (``has_smoother``, ``exportable``, ...).
    build : callable
        ``build(f, h, Q, R, tol, settings)`` → the filter.
    settings : mapping of str to type
        The settings a scenario file's table ``[name]`` may give, by name, with their types
        (``int``, ``float``, ``str`` or ``bool``).
    aliases : tuple of str
        Other names of the same filter (``"tt1"`` for ``"ekf"``, ``"gh"`` for ``"ghkf"``).
    scenario : bool
        Whether a filter scenario file (f, h, Q, R) is enough to build it (IMM needs modes).
    rule : callable or None
        For a Gaussian filter of one rule (or the adaptive strategy): ``rule(tol, settings)``,
        the transform (or strategy) its :class:`~symmon.NonlinearKalmanFilter` runs.
    """

    name: str
    summary: str
    kind: type
    build: Builder = field(repr=False)
    settings: Mapping[str, type] = field(default_factory=dict)
    aliases: tuple[str, ...] = ()
    scenario: bool = True
    rule: Callable[[float, dict], Any] | None = field(default=None, repr=False)

    @property
    def exportable(self) -> bool:
        """Whether the filter it builds exports standalone C (a single-rule Gaussian filter)."""
        return bool(self.kind.exportable) and self.rule is not None and self.name != "adaptive"

    @property
    def has_smoother(self) -> bool:
        """Whether the filter it builds has a smoother (the adaptive filter has no one rule to smooth with)."""
        return bool(self.kind.has_smoother) and self.name != "adaptive"


_ENTRIES: dict[str, FilterEntry] = {}
_ALIASES: dict[str, str] = {}


def register(entry: FilterEntry) -> FilterEntry:
    """Register ``entry`` under its name and aliases.

    Raises
    ------
    SymmonError
        A name or alias that another filter holds, or a kind that is not a Filter.
    """
    if not (isinstance(entry.kind, type) and issubclass(entry.kind, Filter)):
        raise SymmonError(f"filter {entry.name!r}: kind must be a subclass of symmon.filters.base.Filter")
    for name in (entry.name, *entry.aliases):
        if name != name.lower() or not name.isidentifier():
            raise SymmonError(f"filter names are lower-case identifiers, got {name!r}")
        holder = _ALIASES.get(name)
        if holder is not None and holder != entry.name:
            raise SymmonError(f"filter name {name!r} is {holder!r}'s already")
    _ENTRIES[entry.name] = entry
    for name in (entry.name, *entry.aliases):
        _ALIASES[name] = entry.name
    return entry


def filter_entry(name: str) -> FilterEntry:
    """The entry of a filter by its name or an alias (case and spaces ignored).

    Raises
    ------
    SymmonError
        For an unknown name, listing the known ones.
    """
    key = name.strip().lower() if isinstance(name, str) else name
    if key not in _ALIASES:
        raise SymmonError(f"unknown filter {name!r}; known: {', '.join(filter_names(aliases=True))}")
    return _ENTRIES[_ALIASES[key]]


def filter_names(*, aliases: bool = False, scenario: bool | None = None, exportable: bool | None = None) -> tuple[str, ...]:
    """The registered names, in the order of registration (with ``aliases``, each followed
    by its aliases); only those a scenario file can build (``scenario=True``) or that export
    C (``exportable=True``) when asked."""
    out: list[str] = []
    for e in _ENTRIES.values():
        if scenario is not None and e.scenario != scenario:
            continue
        if exportable is not None and e.exportable != exportable:
            continue
        out += [e.name, *e.aliases] if aliases else [e.name]
    return tuple(out)


def setting_fits(value: Any, want: type) -> bool:
    """Whether ``value`` is a setting of type ``want`` (:attr:`FilterEntry.settings`): a
    ``str`` or ``bool`` as itself, a ``float`` any real number but a bool, an ``int`` an
    integer but a bool."""
    if want in (str, bool):
        return isinstance(value, want)
    return not isinstance(value, bool) and isinstance(value, (int, float) if want is float else int)


def make_filter(name: str, f: Model, h: Model, Q: Any, R: Any, *, tol: float = DEFAULT_TOL,
                settings: Mapping[str, Any] | None = None) -> Filter:
    """The filter ``name`` on the models f, h with noise covariances Q, R, and ``settings``
    (those of its entry: :attr:`FilterEntry.settings`).

    Raises
    ------
    SymmonError
        An unknown name or setting, a setting of the wrong type, or a filter that the
        models cannot give (the linear ``"kf"`` of a nonlinear model, ``"imm"`` without modes).
    """
    entry = filter_entry(name)
    settings = dict(settings or {})
    unknown = sorted(set(settings) - set(entry.settings))
    if unknown:
        raise SymmonError(f"filter {entry.name!r}: unknown settings {unknown}; known: "
                          f"{', '.join(entry.settings) or 'none'}")
    for key, value in settings.items():
        want = entry.settings[key]
        if not setting_fits(value, want):
            raise SymmonError(f"filter {entry.name!r}: setting {key!r} must be {want.__name__}, got {value!r}")
    return entry.build(f, h, Q, R, tol, settings)


# ------------------------------------------------------------------------- the builders
def _gaussian(rule: Callable[[float, dict], Any], iterated: bool = False) -> Builder:
    """The builder of a NonlinearKalmanFilter running ``rule(tol, settings)``."""
    def build(f, h, Q, R, tol, settings):
        extra = {"iterations": settings.get("iterations", 5)} if iterated else {}
        return NonlinearKalmanFilter(f, h, Q, R, rule(tol, settings), **extra)
    return build


def _named(name: str) -> Callable[[float, dict], Any]:
    return lambda tol, settings: filter_rule(name)


def _gauss_hermite(tol: float, settings: dict) -> Any:
    return GaussHermite(settings.get("order", 3))


def _adaptive(tol: float, settings: dict) -> Any:
    return Adaptive(tol=settings.get("tol", tol))


def _linear_matrix(model: Model, what: str) -> np.ndarray:
    """The constant matrix M of a linear model g(x) = M x (no noise symbols, no parameters)."""
    if model.n_v or model.params:
        raise ModelError(f"'kf' needs a linear {what} without noise symbols or parameters; use 'ekf'")
    x = list(model.inputs)
    J = sp.Matrix(model.outputs).jacobian(x)
    offset = sp.Matrix(model.outputs).subs({s: 0 for s in x})
    if J.free_symbols or any(e != 0 for e in offset):
        raise ModelError(f"'kf' needs a linear {what} g(x) = M x (constant M, no offset); use 'ekf'")
    return np.array(J.tolist(), dtype=float)


def _linear(f, h, Q, R, tol, settings):
    return KalmanFilter(_linear_matrix(f, "dynamics"), Q, _linear_matrix(h, "measurement"), R)


def _gsf(f, h, Q, R, tol, settings):
    kw = dict(settings)
    if "transform" in kw:
        component = filter_entry(kw["transform"])
        if component.rule is None:
            raise SymmonError(f"gsf: transform must name a Gaussian filter (one of "
                              f"{', '.join(n for n in filter_names() if filter_entry(n).rule)}), got {kw['transform']!r}")
        kw["transform"] = component.rule(tol, {})
    return GaussianSumFilter(f, h, Q, R, **kw)


def _particle(regularise: bool | None) -> Builder:
    def build(f, h, Q, R, tol, settings):
        kw = dict(settings)
        if regularise is not None:
            kw["regularise"] = regularise
        return ParticleFilter(f, h, Q, R, **kw)
    return build


def _imm(f, h, Q, R, tol, settings):
    raise SymmonError("'imm' mixes several models: build sm.IMM([filter_1, filter_2, ...], transition, "
                      "probabilities) from one filter per mode")


_PF_SETTINGS = {"particles": int, "proposal": str, "resample": str, "ess_threshold": float, "seed": int,
                "on_collapse": str, "collapse_fraction": float}

register(FilterEntry("kf", "Kalman filter of a linear model (F, H from f and h)", KalmanFilter, _linear))
for _name, _summary, _aliases in (("ekf", "extended Kalman filter, TT1", ("tt1",)),
                                  ("ekf2", "second-order extended Kalman filter, TT2", ("tt2",)),
                                  ("ukf", "unscented Kalman filter, UT.ut1()", ("ut1",)),
                                  ("ckf", "cubature Kalman filter, UT.cubature()", ("ct",))):
    register(FilterEntry(_name, _summary, NonlinearKalmanFilter, _gaussian(_named(_name)), aliases=_aliases,
                         rule=_named(_name)))
register(FilterEntry("iekf", "iterated extended Kalman filter, TT1 with Gauss–Newton iterations",
                     NonlinearKalmanFilter, _gaussian(_named("ekf"), iterated=True), {"iterations": int},
                     rule=_named("ekf")))
register(FilterEntry("ghkf", "Gauss–Hermite Kalman filter (order 3)", NonlinearKalmanFilter,
                     _gaussian(_gauss_hermite), {"order": int}, aliases=("gh",), rule=_gauss_hermite))
register(FilterEntry("adaptive", "the rule chosen per step by its moment error (Adaptive)", NonlinearKalmanFilter,
                     _gaussian(_adaptive), {"tol": float}, rule=_adaptive))
register(FilterEntry("gsf", "Gaussian-sum filter, split by the measure of nonlinearity", GaussianSumFilter, _gsf,
                     {"transform": str, "split": float, "max_components": int, "prune": float, "merge": str,
                      "split_components": int, "merge_back": float}))
register(FilterEntry("pf", "particle filter (bootstrap or EKF/UKF proposal)", ParticleFilter, _particle(None),
                     {**_PF_SETTINGS, "regularise": bool}))
register(FilterEntry("rpf", "regularised particle filter (Musso, Oudjane & Le Gland 2001)", ParticleFilter,
                     _particle(True), _PF_SETTINGS))
def _cdkf(f, h, Q, R, tol, settings):
    raise SymmonError("'cdkf' integrates the moment equations of an SDE: build "
                      "sm.ContinuousDiscreteKalmanFilter(sde, h, R, transform) from a symmon.SDE (a scenario file's "
                      "f is already discrete)")


register(FilterEntry("enkf", "ensemble Kalman filter (perturbed observations, or the square-root ETKF)",
                     EnsembleKalmanFilter, lambda f, h, Q, R, tol, s: EnsembleKalmanFilter(f, h, Q, R, **s),
                     {"members": int, "kind": str, "inflation": float, "seed": int}))
register(FilterEntry("imm", "interacting multiple models over Gaussian filters (one per mode)", IMM, _imm,
                     scenario=False))
register(FilterEntry("cdkf", "continuous-discrete Kalman filter of an SDE (CD-EKF, CD-UKF, CD-CKF, CD-GHKF)",
                     ContinuousDiscreteKalmanFilter, _cdkf,
                     {"transform": str, "rtol": float, "atol": float, "max_evaluations": int, "square_root": bool,
                      "exact": bool}, scenario=False))
