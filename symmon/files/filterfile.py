"""Filter scenario files: a state-space model, its noises and a prior, in TOML.

A scenario declares the dynamics f and the measurement h of a filtering problem with
additive noise, x_k = f(x_{k−1}) + w_k, y_k = h(x_k) + e_k, w_k ~ N(0, Q),
e_k ~ N(0, R), the prior N(x̄_0, P_0) and the number of steps::

    # A constant-velocity target seen by a range-bearing sensor at the origin.
    name = "rb-cv"
    states = ["px", "py", "vx", "vy"]
    dynamics = ["px + T*vx", "py + T*vy", "vx", "vy"]      # f
    measurements = ["hypot(px, py)", "atan2(py, px)"]       # h
    angles = [1]                  # optional: measurement indices that are angles
    state_angles = []             # optional: state names that are angles (e.g. a heading)
    steps = 40

    [params]                      # optional: named constants
    T = 1.0

    [Q]                           # process noise: cov (a matrix) or std (a vector)
    std = [0.1, 0.1, 0.05, 0.05]

    [R]
    std = [1.0, 0.01]

    [x0]                          # the prior of the filters; each run's true x_0 is drawn from it
    mean = [-20, 50, 0, -2]
    std = [2, 2, 0.2, 0.2]

**Non-additive noise.**  ``process_noise`` and ``measurement_noise`` name noise symbols
that the dynamics and the measurements may use: then x_k = f(x_{k−1}, w_k) and
y_k = h(x_k, e_k), and ``[Q]`` and ``[R]`` are the covariances of those symbols, so a noise
may enter nonlinearly or with fewer components than the states::

    states = ["x", "v"]
    process_noise = ["a"]                                   # one acceleration noise
    dynamics = ["x + T*v + T**2/2*a", "v + T*a"]
    measurement_noise = ["r"]
    measurements = ["hypot(x, 10) * exp(r)"]                # a multiplicative range error
    [Q]
    std = [0.5]
    [R]
    std = [0.01]

**Gaussian-sum and particle filters.**  ``symmon filter --filters ekf,gsf,pf`` runs them beside
the Gaussian filters; optional ``[gsf]`` and ``[pf]`` tables hold their settings (the
keyword arguments of :class:`symmon.GaussianSumFilter` and :class:`symmon.ParticleFilter`; a
component filter by its short name)::

    [gsf]
    transform = "ukf"             # the filter of each component (a name of symmon.filters.registry)
    split = 0.05                  # split where a component's MoN (W^full) exceeds this
    max_components = 16
    [pf]
    particles = 2000
    proposal = "bootstrap"
    seed = 1
    regularise = true             # the regularised PF (kernel jitter after resampling)

**Units.**  An optional ``[units]`` table gives pint unit strings of states (by name) and
measurements (``"measurements[i]"``); ``symmon filter`` prints them and its plot shows
the RMSE of the states of each unit on its own axis.

**Continuous-time dynamics.**  An ``[sde]`` table declares the dynamics as a stochastic
differential equation dx = a(x) dt + L dβ, E[dβ dβᵀ] = Q_c dt (:class:`symmon.SDE`), and the
file's ``dynamics`` and ``[Q]`` are then derived from it by discretisation over the step
``dt`` (:meth:`symmon.SDE.discretize`: f(x, w) with w ~ N(0, I), so Q is the identity);
``dynamics``, ``process_noise`` and ``[Q]`` must then be absent::

    name = "wna"
    states = ["p", "v"]
    measurements = ["p"]
    steps = 50
    [params]
    q = 0.5                       # the acceleration noise density, in (m/s²)²/(1/s) = m²/s³
    [sde]
    drift = ["v", "0"]            # a(x), one expression per state
    diffusion = [["0"], ["1"]]    # L, one row per state (a flat list is one column); default I
    spectral_density = "q"        # Q_c: a scalar (times I) or rows of a matrix; default I
    method = "exact"              # a discretisation method (default "exact")
    dt = 1.0                      # the step, in the time unit
    substeps = 1                  # optional: sub-steps of the approximate methods
    time_unit = "s"               # optional: the unit of dt (Q_c is a density per time unit)

Irregular sampling: instead of one ``dt``, ``times = [t_1, ..., t_K]`` (strictly increasing,
after ``t0``, the time of x_0, default 0) or ``dt = [dt_1, ..., dt_K]`` (one positive interval
per step).  The derived ``dynamics`` then keep ``dt`` as a parameter whose per-step values,
the intervals t_k − t_{k−1}, are :attr:`FilterScenario.step_params`; ``symmon filter`` and
``symmon fit`` simulate and filter with them, and ``steps`` may be left out (it is K).

A time-varying SDE names its time symbol, ``time = "t"``, which the drift and the diffusion
may use (not Q_c); ``method`` must then be an approximate one (not ``"exact"``), and the
derived ``dynamics`` keep the time as a parameter whose per-step values, the start time of
each step (``t0`` and the times before each, or the sums of the steps from 0), are in
:attr:`FilterScenario.step_params`.

The ``[params]`` stay symbols in the SDE (``symmon discretize`` prints F and Q(dt) in them)
and take their values in the derived ``dynamics``; the drift, L and Q_c may use the states
and ``[params]`` (Q_c only ``[params]``), and Q_c must be symmetric positive semi-definite.

Every expression and number is read by the same whitelist parser as a model file
(:func:`symmon.files.modelfile.parse_expression`): nothing in the file is executed.  Keys:
``name``, ``states``, ``dynamics``, ``measurements``, ``steps``, ``[Q]``, ``[R]`` and
``[x0]`` are required (with ``[sde]`` instead of ``dynamics`` and ``[Q]``); ``angles``,
``state_angles``, ``process_noise``, ``measurement_noise``, ``[params]``, ``[units]``,
``[gsf]`` and ``[pf]`` are optional.

:func:`simulate` draws the true states and the measurements of a bank of runs with a
seed, and the filters that ``symmon filter`` runs are those of :mod:`symmon.filters.registry`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import sympy as sp

from ..core.angles import wrap_angle
from ..errors import SymmonError
from ..filters.registry import filter_entry, filter_names, setting_fits
from ..filters.registry import make_filter as make_registered
from ..filters.inputs import KEEPABLE, MAX_BANK_NUMBERS, check_bank_size, kept_numbers
from ..filters.simulation import check_times, simulate as simulate_models
from ..measures.advice import DEFAULT_TOL
from ..core.gaussian import Gaussian
from ..core.model import Model
from ..core import dag
from ..core.sde import SDE
from ..core.discretize import METHODS as SDE_METHODS
from .modelfile import (
    _check_name,
    ModelFileError,
    _check_keys,
    _number,
    _Context,
    _gaussian,
    _names,
    _params,
    _units,
    read_toml,
    parse_expression,
)
from ..transforms.executor import Executor

__all__ = ["FilterScenario", "ScenarioSDE", "FilterSpec", "load_filter_file", "simulate_scenario", "simulate", "check_bank",
           "filter_transform", "run_bank", "BankSummary", "make_filter", "settings_tables"]

def settings_tables() -> tuple[str, ...]:
    """The filters whose settings a scenario may give in a table of their name (``[gsf]``,
    ``[pf]``, ...): every registered filter that a scenario can build and that has settings."""
    return tuple(n for n in filter_names(scenario=True) if filter_entry(n).settings)
#: Largest number of steps of a scenario (the bank holds runs × steps × n² numbers).
MAX_STEPS = 100_000
#: The most numbers :func:`simulate` holds (truth and measurements of every run and step):
#: 2·10⁸, 1.5 GiB, so that runs × steps is bounded jointly before any memory is taken; the
#: same bound as a filter bank's results (:data:`symmon.filters.inputs.MAX_BANK_NUMBERS`).
MAX_SIMULATED = MAX_BANK_NUMBERS
#: Most sub-steps of an ``[sde]`` table: the composed model's nodes and its compile time grow
#: linearly with them (:func:`symmon.core.discretize.compose`), and each sub-step adds its
#: noise symbols to the filters' noise (n_v grows with the sub-steps).
MAX_SUBSTEPS = 256

_KEYS = ("name", "states", "dynamics", "measurements", "angles", "state_angles", "steps", "params", "Q", "R", "x0",
         "process_noise", "measurement_noise", "units")
_REQUIRED = ("name", "states", "dynamics", "measurements", "steps", "Q", "R", "x0")
#: The keys of an ``[sde]`` table, and those it requires.
_SDE_KEYS = ("drift", "diffusion", "spectral_density", "method", "dt", "times", "t0", "substeps", "time_unit", "time")
_SDE_REQUIRED = ("drift",)
#: Keys that an ``[sde]`` table replaces.
_SDE_DERIVED = ("dynamics", "process_noise", "Q")


def filter_transform(name: str, tol: float = DEFAULT_TOL):
    """The transform (or strategy) of a Gaussian filter by a registered name
    (:mod:`symmon.filters.registry`: ``"ekf"`` or ``"tt1"``, ``"ukf"``, ``"gh"``, ``"adaptive"``, ...).

    Raises
    ------
    ModelFileError
        For an unknown name, or a filter that is not one Gaussian filter of a rule.
    """
    try:
        entry = filter_entry(name)
    except SymmonError as exc:
        raise ModelFileError(str(exc)) from None
    if entry.rule is None:
        raise ModelFileError(f"{name!r} is not a Gaussian filter of one rule; use one of "
                             f"{', '.join(n for n in filter_names() if filter_entry(n).rule)}")
    return entry.rule(tol, {})


@dataclass(frozen=True)
class ScenarioSDE:
    """The ``[sde]`` table of a scenario (module notes).

    Attributes
    ----------
    sde : SDE
        The equation, its ``[params]`` kept as symbols.
    method : str
        The discretisation method of the scenario's dynamics.
    dt : float
        The step, in ``time_unit``: the regular one, or with irregular intervals the
        longest (where ``symmon discretize`` evaluates F and Q).
    substeps : int
    time_unit : str or None
        The unit of dt, if declared.
    intervals : tuple of float or None
        Irregular sampling: the interval before each measurement, t_k − t_{k−1} (from
        ``times`` and ``t0``, or a list ``dt``); None for a regular step.
    t0 : float
        The time of x_0 (with ``times``; default 0).
    """

    sde: SDE
    method: str
    dt: float
    substeps: int = 1
    time_unit: str | None = None
    intervals: tuple[float, ...] | None = None
    t0: float = 0.0


@dataclass(frozen=True)
class FilterScenario:
    """A filter scenario read by :func:`load_filter_file`.

    Attributes
    ----------
    name : str
    f, h : Model
        The dynamics (states → states) and the measurement (states → measurements), with
        their noise symbols when the file names them.
    Q, R : ndarray
        Process and measurement noise covariances: of the additive noises, or of the
        noise symbols of ``f`` and ``h``.
    x0 : Gaussian
        The prior of the filters and the distribution of the true x_0.
    steps : int
    path : Path
    units : dict of str to str
        Unit strings by state name or ``"measurements[i]"`` (empty: none declared).
    params : dict of str to float
        The values of the ``[params]`` table (those kept free are model parameters of ``f``
        and ``h``, :func:`load_filter_file`).
    settings : dict
        The filters' tables by filter name (:func:`settings_tables`: ``{"gsf": {...}, "pf": {...}}``;
        empty: defaults).
    sde : ScenarioSDE or None
        The ``[sde]`` table, from which ``f`` and ``Q`` were derived (None: none).
    step_params : dict of str to ndarray
        Per-step parameter values that simulation and every filter take (``params=``):
        ``{"dt": intervals}`` for an ``[sde]`` table with irregular times, whose ``f`` keeps
        ``dt`` as a parameter; empty otherwise.
    """

    name: str
    f: Model
    h: Model
    Q: np.ndarray
    R: np.ndarray
    x0: Gaussian
    steps: int
    path: Path = Path("<memory>")
    units: dict[str, str] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    settings: dict[str, dict] = field(default_factory=dict)
    sde: ScenarioSDE | None = None
    step_params: dict[str, np.ndarray] = field(default_factory=dict)

    def unit(self, key: str) -> str | None:
        """The unit of a state name or of ``"measurements[i]"``, if declared."""
        return self.units.get(key)


def _expressions(ctx: _Context, doc: dict, key: str, env: dict, path: Path) -> list[sp.Expr]:
    raw = doc[key]
    if not isinstance(raw, list) or not raw or not all(isinstance(o, str) for o in raw):
        raise ctx.error(key, f"must be a non-empty list of expression strings, got {raw!r}")
    out = []
    for i, text in enumerate(raw):
        line_off, col_off = ctx.locate(text, rf"^\s*{key}\s*=")
        out.append(parse_expression(text, env, source=f"{path}: {key}[{i}]", line_offset=line_off, col_offset=col_off))
    return out


def _noise(ctx: _Context, doc: dict, key: str, dim: int, params: dict) -> np.ndarray:
    table = doc[key]
    if isinstance(table, dict) and "mean" in table:
        raise ctx.error(f"[{key}]", "a noise covariance takes cov or std, not a mean (the noise has mean 0)")
    with_mean = {**table, "mean": [0] * dim} if isinstance(table, dict) else table
    return _gaussian(ctx, with_mean, key, dim, params, "components").cov


def _uses(table: Any, name: str) -> bool:
    """Whether an expression string anywhere in a TOML value mentions the identifier ``name``."""
    if isinstance(table, str):
        return re.search(rf"(?<![A-Za-z0-9_]){re.escape(name)}(?![A-Za-z0-9_])", table) is not None
    if isinstance(table, dict):
        return any(_uses(v, name) for v in table.values())
    if isinstance(table, list):
        return any(_uses(v, name) for v in table)
    return False


def load_filter_file(path: str | os.PathLike, free: Iterable[str] = ()) -> FilterScenario:
    """Read a filter scenario (module notes).

    Parameters
    ----------
    path : str or PathLike
    free : iterable of str
        Names of ``[params]`` entries to keep as model parameters of f and h
        (``Model(params=...)``, for :meth:`symmon.NonlinearKalmanFilter.fit`) instead of
        substituting their values.

    Raises
    ------
    ModelFileError
        With the file name, for the same faults as :func:`symmon.files.modelfile.load_model_file`,
        for a dynamics whose length is not the number of states, or a bad ``steps``; and for a
        free parameter that the file does not declare, or that ``[Q]``, ``[R]`` or ``[x0]``
        use (they are numbers).
    """
    path, ctx, doc = read_toml(path, "scenario files")
    with_sde = "sde" in doc
    # Irregular times give the number of steps: steps may be left out.
    irregular = with_sde and isinstance(doc["sde"], dict) and ("times" in doc["sde"]
                                                               or isinstance(doc["sde"].get("dt"), list))
    required = tuple(k for k in _REQUIRED if not (with_sde and k in _SDE_DERIVED) and not (irregular and k == "steps"))
    _check_keys(ctx, doc, _KEYS + ("sde",) + settings_tables(), required, "")
    if with_sde:
        for key in _SDE_DERIVED:
            if key in doc:
                raise ctx.error(key, "must be absent with an [sde] table: the dynamics and their noise are "
                                     "derived from the SDE by discretisation")
    name = doc["name"]
    if not isinstance(name, str) or not name.strip():
        raise ctx.error("name", f"must be a non-empty string, got {name!r}")
    seen: dict[str, str] = {}
    state_names = _names(ctx, doc["states"], "states", seen)
    if not state_names:
        raise ctx.error("states", "at least one state is required")
    W = [sp.Symbol(s, real=True) for s in _names(ctx, doc.get("process_noise", []), "process_noise", seen)]
    E = [sp.Symbol(s, real=True) for s in _names(ctx, doc.get("measurement_noise", []), "measurement_noise", seen)]
    params = _params(ctx, doc.get("params", {}), seen)
    free = list(dict.fromkeys(str(n) for n in free))
    for n in free:
        if n not in params:
            raise ctx.error("params", f"{n!r} is not in [params] (it has {', '.join(params) or 'nothing'}): "
                                      "only a declared parameter can be fitted")
        for key in ("Q", "R", "x0"):
            if _uses(doc.get(key), n):
                raise ctx.error(f"[{key}]", f"uses the parameter {n!r}, which is kept free: [{key}] must be "
                                            "numbers; put the parameter in the dynamics or the measurements "
                                            "(e.g. a noise intensity times a noise symbol)")
    free_syms = {n: sp.Symbol(n, real=True) for n in free}
    X = [sp.Symbol(s, real=True) for s in state_names]
    env: dict[str, Any] = {**params, **free_syms, **{s.name: s for s in X}}
    # Each noise is visible only where it belongs: w in the dynamics, e in the measurements.
    sde = None
    if with_sde:
        sde = _sde_table(ctx, doc["sde"], X, params, free_syms, [a for a in doc.get("state_angles", [])
                                                                 if a in state_names], name, seen)
        model = sde.sde.discretize(sde.method, substeps=sde.substeps)
        # A regular step is substituted; irregular intervals keep dt a per-step parameter, and a
        # time-varying SDE its time (the start of each step).
        time_name = None if sde.sde.is_time_invariant else str(sde.sde.time)
        per_step = {"dt"} if sde.intervals else set()
        per_step |= {time_name} if time_name else set()
        values = {s: (sp.Float(sde.dt) if str(s) == "dt" else params[str(s)])
                  for s in model.params if str(s) not in free_syms and str(s) not in per_step}
        step_symbols = [s for s in model.params if str(s) in per_step]
        # Composed sub-steps are a DAG: substituted node by node, not as a tree.
        dyn = (list(dag.substitute(model.outputs, values)) if not dag.is_small(model.outputs)
               else [e.xreplace(values) for e in model.outputs])
        W = list(model.noise)
    else:
        dyn = _expressions(ctx, doc, "dynamics", {**env, **{s.name: s for s in W}}, path)
    if len(dyn) != len(X):
        raise ctx.error("dynamics", f"must have one expression per state ({len(X)}), got {len(dyn)}")
    meas = _expressions(ctx, doc, "measurements", {**env, **{s.name: s for s in E}}, path)
    steps = doc.get("steps", len(sde.intervals) if sde is not None and sde.intervals else None)
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= MAX_STEPS:
        raise ctx.error("steps", f"must be an integer in [1, {MAX_STEPS}], got {steps!r}")
    step_params: dict[str, np.ndarray] = {}
    if sde is not None and sde.intervals:
        if steps != len(sde.intervals):
            raise ctx.error("steps", f"must be the number of measurement times of [sde] ({len(sde.intervals)}), "
                                     f"got {steps!r} (or leave it out)")
        step_params = {"dt": np.array(sde.intervals)}
    if sde is not None and not sde.sde.is_time_invariant:
        # The start time of each step: t0 and the times before each, or the sums of the steps.
        dts = np.array(sde.intervals) if sde.intervals else np.full(steps, sde.dt)
        step_params[str(sde.sde.time)] = sde.t0 + np.concatenate([[0.0], np.cumsum(dts)[:-1]])
    angles = doc.get("angles", [])
    if not isinstance(angles, list) or not all(isinstance(a, int) and not isinstance(a, bool)
                                               and 0 <= a < len(meas) for a in angles):
        raise ctx.error("angles", f"must be a list of measurement indices in [0, {len(meas)}), got {angles!r}")
    state_angles = doc.get("state_angles", [])
    if not isinstance(state_angles, list) or not all(a in state_names for a in state_angles):
        raise ctx.error("state_angles", f"must be a list of state names ({', '.join(state_names)}), got {state_angles!r}")
    by_name = dict(zip(state_names, X))
    def used(exprs):
        syms = dag.free_symbols(exprs)  # a DAG walk: composed sub-steps are a tree of billions of nodes
        return [s for s in free_syms.values() if s in syms] or None

    f_params = (used(dyn) or []) + (step_symbols if with_sde else [])
    f = Model(X, dyn, noise=W or None, name=f"{name}_f", angles=[by_name[a] for a in state_angles] or None,
              params=f_params or None)
    h = Model(X, meas, noise=E or None, name=f"{name}_h", angles=list(angles) or None, params=used(meas))
    unused = [n for n in free if free_syms[n] not in set(f.params) | set(h.params)]
    if unused:
        raise ctx.error("params", f"{unused} appear in neither the dynamics nor the measurements: nothing to fit")
    if with_sde:
        Q = np.eye(len(W)) if W else np.zeros((len(X), len(X)))
    else:
        Q = _noise(ctx, doc, "Q", len(W) or len(X), params)
    R = _noise(ctx, doc, "R", len(E) or len(meas), params)
    x0 = _gaussian(ctx, doc["x0"], "x0", len(X), params, "states")
    units = _units(ctx, doc.get("units", {}), len(meas), state_names, indexed="measurements", named="state names")
    settings = {kind: _filter_settings(ctx, doc[kind], kind) for kind in settings_tables() if kind in doc}
    for kind, table in settings.items():  # the filters' own checks, with the file's name
        try:
            make_filter(kind, f, h, Q, R, settings=settings)
        except SymmonError as exc:
            raise ctx.error(f"[{kind}]", str(exc)) from None
    return FilterScenario(name, f, h, Q, R, x0, int(steps), path, units, {k: float(v) for k, v in params.items()},
                          settings, sde, step_params)


def _matrix_entries(ctx: _Context, value: Any, key: str, env: dict, what: str) -> list:
    """A scalar, a flat list (a column) or a list of rows of numbers and expression strings,
    parsed (nested lists kept)."""
    where = f"[sde].{key}"

    def entry(v: Any, label: str) -> sp.Expr:
        if isinstance(v, bool) or not isinstance(v, (int, float, str)):
            raise ctx.error(where, f"{label} must be a number or an expression string, got {v!r}")
        if isinstance(v, str):
            line_off, col_off = ctx.locate(v, rf"^\s*{key}\s*=")
            return parse_expression(v, env, source=f"{ctx.path}: {where}{label}", line_offset=line_off,
                                    col_offset=col_off)
        if isinstance(v, float) and not np.isfinite(v):
            raise ctx.error(where, f"{label} must be finite, got {v!r}")
        return sp.Integer(v) if isinstance(v, int) else sp.Float(v)

    if not isinstance(value, list):
        return entry(value, "")
    if not value:
        raise ctx.error(where, f"must be {what}, got an empty list")
    if all(isinstance(r, list) for r in value):
        widths = {len(r) for r in value}
        if len(widths) != 1 or 0 in widths:
            raise ctx.error(where, f"must be {what}: rows of one non-zero length, got lengths {[len(r) for r in value]}")
        return [[entry(v, f"[{i}][{j}]") for j, v in enumerate(r)] for i, r in enumerate(value)]
    if any(isinstance(r, list) for r in value):
        raise ctx.error(where, f"must be {what}: a list of rows (lists) or of entries, not both")
    return [entry(v, f"[{i}]") for i, v in enumerate(value)]


def _sde_table(ctx: _Context, table: Any, X: list, params: dict, free_syms: dict, angles: list,
               name: str, seen: dict[str, str]) -> ScenarioSDE:
    """The ``[sde]`` table as a :class:`ScenarioSDE`: its expressions through the whitelist
    parser, the SDE's own checks reported with the file's name and the key."""
    if not isinstance(table, dict):
        raise ctx.error("[sde]", f"must be a table, got {table!r}")
    _check_keys(ctx, table, _SDE_KEYS, _SDE_REQUIRED, "[sde]")
    # The [params] stay symbols (positive where their value is): F and Q(dt) print in them.
    syms = {n: free_syms[n] if n in free_syms else sp.Symbol(n, positive=True) if float(v) > 0
            else sp.Symbol(n, real=True) for n, v in params.items()}
    env = {**syms, **{s.name: s for s in X}}
    if "dt" in env:
        raise ctx.error("[sde]", "'dt' is the step of the discretisation: a state or a [params] entry cannot "
                                 "have that name")
    time = None
    if "time" in table:  # the time symbol of a time-varying drift or diffusion
        if not isinstance(table["time"], str):
            raise ctx.error("[sde].time", f"must be a name (a string), got {table['time']!r}")
        if table["time"] == "dt":
            raise ctx.error("[sde].time", "'dt' is the step of the discretisation, not the time")
        _check_name(ctx, table["time"], "[sde].time", seen)
        time = sp.Symbol(table["time"], real=True)
        env = {**env, time.name: time}
    drift = table["drift"]
    if not isinstance(drift, list) or not drift or isinstance(drift[0], list):
        raise ctx.error("[sde].drift", f"must be a list of expressions, one per state, got {drift!r}")
    a = _matrix_entries(ctx, drift, "drift", env, "one expression per state")
    L = _matrix_entries(ctx, table["diffusion"], "diffusion", env, "a matrix L (rows)") if "diffusion" in table else None
    Qc = (_matrix_entries(ctx, table["spectral_density"], "spectral_density", syms, "a scalar or a matrix Q_c (rows)")
          if "spectral_density" in table else None)
    method = table.get("method", "exact")
    if method not in SDE_METHODS:
        raise ctx.error("[sde].method", f"must be one of {', '.join(SDE_METHODS)}, got {method!r}")
    dt, intervals, t0 = _sde_steps(ctx, table, params)
    substeps = table.get("substeps", 1)
    if isinstance(substeps, bool) or not isinstance(substeps, int) or not 1 <= substeps <= MAX_SUBSTEPS:
        raise ctx.error("[sde].substeps", f"must be an integer in [1, {MAX_SUBSTEPS}], got {substeps!r}")
    if method == "exact" and substeps != 1:
        raise ctx.error("[sde].substeps", "does not apply to the 'exact' method (it is exact for any dt)")
    unit = table.get("time_unit")
    if unit is not None and (not isinstance(unit, str) or not unit.strip()):
        raise ctx.error("[sde].time_unit", f"must be a non-empty unit string, got {unit!r}")
    if isinstance(Qc, list) and not isinstance(Qc[0], list):
        raise ctx.error("[sde].spectral_density", "must be a scalar or a list of rows (a matrix), not a flat list")
    try:
        sde = SDE(X, a, diffusion=L, spectral_density=Qc, params=list(syms.values()),
                  angles=[s for s in X if s.name in angles], name=name, time=time)
    except SymmonError as exc:
        text = str(exc)
        key = next((k for k in ("spectral_density", "diffusion", "drift") if k in text.split(":")[0]), None)
        raise ctx.error(f"[sde].{key}" if key else "[sde]", text) from None
    if method == "exact" and not sde.is_linear:
        raise ctx.error("[sde].method", "'exact' needs a linear drift and a constant diffusion; this SDE is "
                                        "nonlinear: use 'taylor1.5' or 'local_linear' with substeps")
    if method == "exact" and not sde.is_time_invariant:
        raise ctx.error("[sde].method", f"'exact' needs a time-invariant SDE; this one depends on {time} (no single "
                                        "e^(A dt)): use 'rk4', 'taylor1.5' or 'local_linear' with substeps")
    if method in ("taylor1.5", "local_linear") and not sde.additive:
        raise ctx.error("[sde].method", f"{method!r} needs a diffusion free of the states: use 'euler' or 'rk4'")
    return ScenarioSDE(sde, method, dt, substeps, unit, intervals, t0)


def _sde_steps(ctx: _Context, table: dict, params: dict) -> tuple[float, tuple[float, ...] | None, float]:
    """(dt, intervals, t0) of an ``[sde]`` table: one regular ``dt``, a list ``dt`` (one
    interval per step) or measurement ``times`` after ``t0``, exactly one of them."""
    if ("dt" in table) == ("times" in table):
        raise ctx.error("[sde]", "give the step dt (a number, or a list: one interval per step) or the measurement "
                                 "times, exactly one of them")
    if "t0" in table and "times" not in table:
        raise ctx.error("[sde].t0", "applies only with times (the time of x0)")
    t0 = _number(ctx, table["t0"], "[sde].t0", params, r"^\s*t0\s*=") if "t0" in table else 0.0
    raw = table.get("dt", table.get("times"))
    key = "dt" if "dt" in table else "times"
    if key == "dt" and not isinstance(raw, list):
        dt = _number(ctx, raw, "[sde].dt", params, r"^\s*dt\s*=")
        if dt <= 0:
            raise ctx.error("[sde].dt", f"must be positive (the step), got {raw!r}")
        return dt, None, 0.0
    if not isinstance(raw, list) or not raw or len(raw) > MAX_STEPS:
        raise ctx.error(f"[sde].{key}", f"must be a non-empty list of at most {MAX_STEPS} numbers, got {raw!r}")
    values = [_number(ctx, v, f"[sde].{key}[{i}]", params, rf"^\s*{key}\s*=") for i, v in enumerate(raw)]
    if key == "dt":
        bad = next((i for i, v in enumerate(values) if v <= 0), None)
        if bad is not None:
            raise ctx.error(f"[sde].dt[{bad}]", f"must be positive (the interval before measurement {bad}), "
                                                f"got {raw[bad]!r}")
        intervals = np.array(values)
    else:
        try:
            intervals = check_times(values, t0, name="times")
        except SymmonError as exc:
            raise ctx.error("[sde].times", str(exc)) from None
    return float(intervals.max()), tuple(float(d) for d in intervals), t0


def _filter_settings(ctx: _Context, table: Any, kind: str) -> dict:
    """A filter's table (``[gsf]``, ``[pf]``, ...): known keys of the right types
    (:attr:`symmon.filters.registry.FilterEntry.settings`)."""
    if not isinstance(table, dict):
        raise ctx.error(f"[{kind}]", f"must be a table, got {table!r}")
    known = filter_entry(kind).settings
    out = {}
    for key, value in table.items():
        if key not in known:
            raise ctx.error(f"[{kind}]", f"unknown setting {key!r}; known: {', '.join(known)}")
        want = known[key]
        if not setting_fits(value, want):
            what = {str: "a string", bool: "true or false", float: "a number"}.get(want, "an integer")
            raise ctx.error(f"[{kind}].{key}", f"must be {what}, got {value!r}")
        out[key] = value
    return out


def make_filter(name: str, f: Model, h: Model, Q: np.ndarray, R: np.ndarray, tol: float = DEFAULT_TOL,
                settings: dict | None = None):
    """The registered filter ``name`` (:func:`symmon.filters.registry.make_filter`) with the
    scenario's table of its name from ``settings`` (a component ``transform`` by its name)."""
    entry = filter_entry(name)
    return make_registered(name, f, h, Q, R, tol=tol, settings=(settings or {}).get(entry.name))


def check_bank(spec: FilterSpec, runs: int, filters: Iterable[str], smooth: bool = False) -> None:
    """Refuse, before anything is simulated, a bank whose arrays would not fit: the
    simulated truth and measurements, and every filter's results (:func:`run_bank` keeps
    each filter's, all arrays, and with ``smooth`` its smoothed means and covariances).

    Raises
    ------
    ResourceError
        Beyond :data:`~symmon.filters.inputs.MAX_BANK_NUMBERS` numbers.
    """
    n, n_y = spec.f.n_u, spec.h.n_y
    names = list(filters)
    smoothed = sum(smooth and filter_entry(name).has_smoother for name in names)
    per_step = n + n_y + len(names) * kept_numbers(n, n_y, KEEPABLE) + smoothed * (n + n * n)
    check_bank_size(runs, spec.steps, per_step, f"a bank of {len(names)} filter(s) on {spec.name!r}",
                    "use fewer runs, steps or filters")


def simulate_scenario(f: Model, h: Model, Q: np.ndarray, R: np.ndarray, x0: Gaussian, steps: int, runs: int,
                      seed: int = 0, params: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """True states and measurements of ``runs`` independent runs: :func:`symmon.simulate`
    with a bank of ``runs`` (shapes (runs, steps, n) and (runs, steps, n_y)).

    x_0 ~ x0, x_k = f(x_{k−1}) + w_k, y_k = h(x_k) + e_k for k = 1 … ``steps``, with
    w_k ~ N(0, Q) and e_k ~ N(0, R); for a model with noise symbols the noise is its
    argument instead, x_k = f(x_{k−1}, w_k) and y_k = h(x_k, e_k).  Angle states and
    angle measurements are wrapped to (−π, π].  ``params`` are the models' parameter values
    (a scenario's :attr:`FilterScenario.step_params`: the intervals of irregular times).

    Raises
    ------
    SymmonError
        If runs × steps × (n + n_y) exceeds :data:`MAX_SIMULATED`, or the truth diverges (a
        non-finite state or measurement, naming the run and step).
    """
    return simulate_models(f, h, Q, R, x0, steps, runs, params=params or None, seed=seed)


@dataclass(frozen=True)
class BankSummary:
    """One filter on a bank of runs: the per-step consistency statistics and RMSE.

    Attributes
    ----------
    name : str
    result : NonlinearKalmanResult or None
        None when the filter failed (``error`` says why).
    anees, anis : ConsistencyTest or None
        Averages over the runs at each step, with their χ² intervals.
    rmse : ndarray, shape (K, n)
        Root mean square error of each state component over the runs, per step.
    error : str or None
    smoothed : SmootherResult or None
        With ``smooth=True``: the RTS smoother of the filter (None for the adaptive filter,
        which has no one transform to smooth with).
    smoothed_anees : ConsistencyTest or None
    smoothed_rmse : ndarray, shape (K, n), or None
    """

    name: str
    result: Any
    anees: Any
    anis: Any
    rmse: np.ndarray | None
    error: str | None = None
    smoothed: Any = None
    smoothed_anees: Any = None
    smoothed_rmse: np.ndarray | None = None


def _rmse(xs: np.ndarray, x: np.ndarray, angle_states) -> np.ndarray:
    """RMSE over the runs per step and component, angle errors wrapped."""
    e = xs - x
    if angle_states:
        idx = list(angle_states)
        e[..., idx] = wrap_angle(e[..., idx])
    return np.sqrt(np.mean(e**2, axis=0))


def run_bank(f: Model, h: Model, Q: np.ndarray, R: np.ndarray, x0: Gaussian, xs: np.ndarray, ys: np.ndarray,
             names: list[str], tol: float = DEFAULT_TOL, confidence: float = 0.95,
             smooth: bool = False, settings: dict | None = None,
             executor: Executor | None = None, params: dict | None = None) -> list[BankSummary]:
    """Run the named filters (:func:`filter_transform`) on the bank ``ys`` with truth ``xs``.

    With ``smooth``, each filter's RTS smoother runs too (:meth:`NonlinearKalmanFilter.smooth`),
    except the adaptive filter's, the Gaussian-sum filter's and the particle filter's (made by
    :func:`make_filter` with ``settings``, the scenario's ``[gsf]`` and ``[pf]`` tables; the
    Gaussian-sum filter has no ANIS, its ``anis`` is None).  A filter that fails (NaN: it diverged), or whose
    statistics do (a state known exactly has no NEES), is reported with its error instead of
    stopping the others.  With ``executor`` each filter's bank runs in shards there
    (:func:`symmon.filters.bank.filter_bank`: the same numbers); the smoothers'
    backward passes run here.  ``params`` go to every filter (a scenario's
    :attr:`FilterScenario.step_params`).
    """
    out = []
    for name in names:
        smoothed = None
        try:
            entry = filter_entry(name)
            kf = make_filter(name, f, h, Q, R, tol, settings)
            if smooth and entry.has_smoother:
                smoothed = kf.smooth(ys, x0, params=params or None)
                res = smoothed.filtered
            else:
                res = kf.filter(ys, x0, executor=executor, params=params or None)
            # Its statistics may fail too (a state known exactly has no NEES): the same report.
            extra = {}
            if smoothed is not None:
                extra = {"smoothed": smoothed, "smoothed_anees": smoothed.anees(xs, confidence),
                         "smoothed_rmse": _rmse(xs, smoothed.x, res.angle_states)}
            # A mixture's innovation has no one covariance: no NIS, no ANIS.
            anis = res.anis(confidence) if res.nis_values is not None else None
            summary = BankSummary(name, res, res.anees(xs, confidence), anis, _rmse(xs, res.x, res.angle_states),
                                  **extra)
        except SymmonError as exc:
            summary = BankSummary(name, None, None, None, None, str(exc))
        out.append(summary)
    return out


#: The scenario's former names, kept: :class:`FilterScenario` (not the filters' ``FilterSpec``
#: protocol) and :func:`simulate_scenario` (not :func:`symmon.simulate`).
FilterSpec = FilterScenario
simulate = simulate_scenario
