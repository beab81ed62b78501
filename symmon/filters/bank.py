"""Banks of filter runs in shards: on threads, a local Dask scheduler or a Dask cluster.

A bank of R runs (``ys`` of shape (R, K, n_y)) is cut into S contiguous shards of runs;
each shard is filtered by its own task, and the shards' results are joined along the run
axis.  The runs of a bank are independent, and every filter of symmon computes run r from
run r's inputs alone (the compiled step runs row by row; the particle filter draws run r's
particles from its own stream), so the joined result is the unsharded one **bit for bit**,
and every statistic over the runs — NEES, NIS, ANEES, ANIS, RMSE — is computed from the same
per-run arrays: merging is exact, not approximate (docs/scale-out.md).

Random streams.  Run r of a bank draws from child r of ``SeedSequence(seed)``
(:func:`run_streams`; ``SeedSequence.spawn``): a shard holding runs a … b−1 spawns children
a … b−1, so the numbers of a run depend on the seed and its index only, never on the
number of shards or workers.

What travels.  A task carries the filter's constructor arguments (sympy models, arrays,
settings: no CasADi object) and its shard's slices of the per-run inputs; each worker
process rebuilds the filter once and keeps it (the compiled C is cached on disk).  Errors
of a shard, and the warnings of a worker process (raised again here), name the run by its
index in the whole bank.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import pickle
import re
import threading
import warnings
from collections import OrderedDict
from typing import Any

import numpy as np

from ..compile.compiled import cpu_count
from ..errors import ArgumentError, SymmonError, plain_repr
from ..transforms.executor import Executor, dask_compute, one_blas_thread
from .inputs import FilterCall, check_call

__all__ = ["filter_bank", "constructor_args", "run_streams", "shard_bounds", "default_shards", "MAX_SHARDS"]

#: Most shards of one bank (each is one task; more only adds scheduling).
MAX_SHARDS = 10_000
#: Filters rebuilt in this process, by the hash of their constructor arguments.
_FILTERS: OrderedDict[str, Any] = OrderedDict()
_FILTERS_LOCK = threading.Lock()
_KEEP_FILTERS = 8
_RUN = re.compile(r"\brun (\d+)\b")


def run_streams(seed: int, runs: int, first: int = 0) -> list[np.random.Generator]:
    """The random streams of runs ``first`` … ``first + runs − 1`` of a bank: child r of
    ``SeedSequence(seed)`` for run r (PCG64), the same whichever shard holds the run.

    ``SeedSequence(seed, n_children_spawned=first).spawn(runs)`` gives exactly the children
    ``first`` … of ``SeedSequence(seed).spawn(first + runs)`` (their spawn keys are the run
    indices), without making the first ones.

    Raises
    ------
    ArgumentError
        ``first`` is not a non-negative integer.
    """
    if isinstance(first, (bool, np.bool_)) or not isinstance(first, (int, np.integer)) or first < 0:
        raise ArgumentError(f"first_run must be a non-negative integer (a run's index in its bank), got {plain_repr(first)}")
    return [np.random.Generator(np.random.PCG64(s))
            for s in np.random.SeedSequence(seed, n_children_spawned=first).spawn(runs)]


def shard_bounds(runs: int, shards: int) -> list[tuple[int, int]]:
    """``shards`` contiguous ranges [a, b) of ``runs`` runs, as even as possible (sizes
    differ by at most one), in run order."""
    return [(i * runs // shards, (i + 1) * runs // shards) for i in range(shards)]


def default_shards(executor: Executor, runs: int) -> int:
    """One shard per thread of the cluster (of ``executor.client``), per CPU for a local
    Dask scheduler, per thread of ``executor.workers`` otherwise; at most ``runs``."""
    if executor.client is not None:
        try:
            slots = sum(executor.client.nthreads().values())
        except Exception:  # the cluster's failures are reported by the run's own watch
            slots = 1
    elif executor.scheduler is not None:
        slots = cpu_count()
    else:
        slots = executor.threads(runs)
    return max(1, min(runs, slots))


def _renumber(text: str, first: int) -> str:
    """A shard's message with its runs named by their index in the whole bank."""
    return _RUN.sub(lambda m: f"run {int(m[1]) + first}", text) if first else text


def _rebuilt(kind: type, init: dict, key: str) -> Any:
    """The filter ``kind(**init)``, made once per process (a task's arguments are new
    objects each time; the compiled models behind them are cached by content)."""
    with _FILTERS_LOCK:
        filt = _FILTERS.get(key)
        if filt is not None:
            _FILTERS.move_to_end(key)
            return filt
    filt = kind(**init)
    with _FILTERS_LOCK:
        _FILTERS[key] = filt
        while len(_FILTERS) > _KEEP_FILTERS:
            _FILTERS.popitem(last=False)
    return filt


def _run_shard(kind: type, init: dict, key: str, call: FilterCall, first: int,
               home: int) -> tuple[Any, list[tuple[type, str]]]:
    """Filter one shard (runs ``first`` … of the bank) with the rebuilt filter; its result
    and, in another process than the caller's (``home``), the warnings it raised."""
    filt = _rebuilt(kind, init, key)
    caught: list = []
    # A worker of another process keeps its warnings in its log: they come back with the
    # result.  In the caller's process they are the caller's already (catch_warnings is
    # not thread-safe, so it is not used there).
    away = os.getpid() != home
    with one_blas_thread(), warnings.catch_warnings(record=True) if away else contextlib.nullcontext() as rec:
        if away:
            warnings.simplefilter("always")
        try:
            res = filt._filter(call)
        except SymmonError as exc:
            message = _renumber(str(exc), first)
            if message == str(exc):
                raise
            try:
                renamed = type(exc)(message)
            except Exception:  # an error class with another signature keeps its message
                raise exc from None
            raise renamed from exc
        if away:
            caught = [(w.category, _renumber(str(w.message), first)) for w in rec]
    return res, caught


def constructor_args(filt: Any) -> dict:
    """The constructor arguments of a dataclass filter (its ``init`` fields)."""
    return {f.name: getattr(filt, f.name) for f in dataclasses.fields(filt) if f.init}


def filter_bank(filt: Any, executor: Executor, ys: Any, shards: int | None = None, **call: Any) -> Any:
    """``filt.filter(ys, **call)`` with the runs of the bank ``ys`` cut into shards, each
    filtered as one task of ``executor``; the result that the unsharded call returns, bit
    for bit.

    Parameters
    ----------
    filt : KalmanFilter, NonlinearKalmanFilter, GaussianSumFilter or ParticleFilter
        Any dataclass filter whose ``filter(ys, ...)`` filters the runs of a bank
        independently (a filter with random streams takes ``first_run=``: those of
        :func:`run_streams`).
    executor : Executor
        Where the shards run: a Dask ``client`` (a bounded wait for workers,
        ``worker_timeout``), a local Dask ``scheduler``, or else ``workers`` threads;
        ``progress`` counts the finished shards (a bar on a terminal, a line every few
        seconds otherwise).
    ys : array_like, shape (R, K, n_y) or (K, n_y)
        The measurements; one run (K, n_y) is one task.
    shards : int, optional
        Number of shards, 1 to min(R, :data:`MAX_SHARDS`) (default
        :func:`default_shards`: one per thread of the cluster).  The result does not depend
        on it.
    **call
        The other arguments of ``filt.filter``; those with one value per run (x0 (R, n),
        P0 (R, n, n), x_true (R, K, n), parameters (R, K)) are cut with the runs.

    Returns
    -------
    The filter's result (``KalmanResult``, ``ParticleResult``, ``GaussianSumResult``) for
    the whole bank, with run axis R.

    Raises
    ------
    ArgumentError
        ``executor`` is not an :class:`~symmon.Executor`, or a bad ``shards``.
    ShapeError
        A per-run argument with another number of runs than ``ys``; the filter's own errors.
    SymmonError
        The cluster had no worker for ``worker_timeout`` seconds, or a shard's workers kept
        dying; the filter's errors, naming the run by its index in the whole bank.
    """
    if not isinstance(executor, Executor):
        raise ArgumentError(f"executor must be a symmon.Executor, got {type(executor).__name__}")
    if isinstance(ys, FilterCall):
        if call:
            raise ArgumentError(f"a checked call takes no other arguments, got {sorted(call)}")
        checked = ys
    else:
        checked = check_call(filt, ys, **call)
    runs = checked.runs
    if shards is not None and (isinstance(shards, bool) or not isinstance(shards, (int, np.integer))
                               or not 1 <= shards <= min(runs or 1, MAX_SHARDS)):
        raise ArgumentError(f"shards must be an integer from 1 to {min(runs or 1, MAX_SHARDS)} "
                            f"(the runs of the bank, at most {MAX_SHARDS}), got {plain_repr(shards)}")
    if runs is None:
        bounds = [(0, 1)]
    else:
        bounds = shard_bounds(runs, int(shards) if shards is not None else default_shards(executor, runs))
    kind, init = type(filt), constructor_args(filt)
    key = hashlib.sha256(pickle.dumps((kind, init))).hexdigest()
    with _FILTERS_LOCK:  # in this process (threads, an in-process cluster): this very filter
        _FILTERS[key] = filt
        _FILTERS.move_to_end(key)
    jobs = [(checked.shard(a, b), a) for a, b in bounds]
    home = os.getpid()
    desc = f"{getattr(filt, 'method', kind.__name__)} shards of runs"
    if executor.distributed:
        import dask

        tasks = [dask.delayed(_run_shard, pure=False)(kind, init, key, job, a, home) for job, a in jobs]
        outs = dask_compute(tasks, executor.client, executor.scheduler, desc, executor.progress,
                            executor.worker_timeout)
    else:
        outs = executor.run(lambda job, stop: _run_shard(kind, init, key, job[0], job[1], home), jobs, desc)
    for _, caught in outs:
        for category, message in caught:
            warnings.warn(message, category, stacklevel=3)
    results = [r for r, _ in outs]
    if runs is None:
        return results[0]
    return type(results[0]).concat(results, checked.Y.shape[-1])
