"""What the commands share with the parser: the names, the declared limits of the options,
the transforms by short name and the executor of ``--workers`` and ``--dask``."""

from __future__ import annotations

import argparse
import contextlib
from typing import Any, Iterator

from ..errors import SymmonError
from ..transforms.executor import Executor, connect_dask
from ..transforms.registry import make, names

__all__ = ["transform_from_name", "transform_names", "executor_of", "WEIGHT_NAMES", "FIGURES", "SH24", "DASK_LOCAL",
           "DASK_SCHEMES", "MAX_SAMPLES", "MAX_SEED", "MAX_ORDER", "MAX_GROUPS", "MAX_RUNS", "MAX_PARTICLES", "MAX_WORKERS",
           "MAX_SWEEP_POINTS", "MAX_VERIFY_POINTS", "REPRODUCE_MIN_SAMPLES", "DASK_CONNECT_TIMEOUT"]

#: The paper whose equation numbers the help cites.
SH24 = "Straka & Havlík 2024"
WEIGHT_NAMES = ("full", "diag", "liu-li", "liu-li-raw")
FIGURES = ("fig1", "fig2", "radar", "mmse", "tracking", "bot", "select")

def transform_from_name(name: str, samples: int = 10**6, seed: int = 0, order: int = 5, groups: int = 16):
    """A transform from its registered short name (:mod:`symmon.transforms.registry`).

    Parameters
    ----------
    name : str
        One of :data:`TRANSFORM_NAMES`: ``tt1``, ``tt2``, ``ut1``, ``ut2``, ``ct``, ``gh``,
        ``qmc``, ``mc`` and any rule registered since.
    samples, seed : int
        Monte Carlo sample count and seed (``mc`` and ``qmc`` only).
    order : int
        Gauss-Hermite order per dimension (``gh`` only).
    groups : int
        In how many independent groups Monte Carlo runs (``mc`` and ``qmc`` only; see
        :class:`symmon.MonteCarlo`).  Where they run is the command's executor.

    Returns
    -------
    Transform

    Raises
    ------
    SymmonError
        For an unknown name.
    """
    return make(name, samples=samples, seed=seed, order=order, groups=groups)


def transform_names() -> tuple[str, ...]:
    """The registered short names of the transforms, in the order ``compare`` lists them."""
    return names()


#: Local Dask schedulers that ``--dask`` accepts by name; anything else is an address.
DASK_LOCAL = ("threads", "processes", "synchronous")
#: Network schemes of a ``--dask`` address (besides in-process ``inproc://``).
DASK_SCHEMES = ("tcp", "tls", "ucx")

# Declared limits of the options: past them a run would not fit in memory or in a day.
#: Monte Carlo samples (``--samples``); samples are drawn in chunks, so this bounds time only.
MAX_SAMPLES = 10**12
#: Largest seed (``--seed``): numpy's SeedSequence takes non-negative integers.
MAX_SEED = 2**64 - 1
#: Gauss-Hermite points per dimension (``--order``).
MAX_ORDER = 100
#: Monte Carlo groups (``--groups``) and threads (``--workers``).
MAX_GROUPS = 1024
#: Most Monte Carlo runs of a filter study (each run keeps its whole trajectory).
MAX_RUNS = 10**5
#: Most particles per run of ``reproduce bot --particles`` (runs × particles × states are held at once).
MAX_PARTICLES = 10**6
MAX_WORKERS = 1024
#: Points of ``--alpha-sweep``: each is a full MoN computation.
MAX_SWEEP_POINTS = 1000
#: Random points per claim of ``symmon verify``: each is a 50-digit evaluation (or a quadrature).
MAX_VERIFY_POINTS = 1000
#: Fewest ``reproduce --samples``: two per Monte Carlo group of the figures (16 groups).
REPRODUCE_MIN_SAMPLES = 32
#: Seconds to wait for a Dask scheduler at ``--dask ADDRESS``.
DASK_CONNECT_TIMEOUT = 10


@contextlib.contextmanager
def executor_of(args: argparse.Namespace) -> Iterator[Any]:
    """The :class:`~symmon.Executor` of ``--workers`` and ``--dask``, with progress; a
    Client to a ``--dask`` address is connected for the command and closed after it."""
    target = args.dask
    if target is None or target in DASK_LOCAL:
        yield Executor(workers=args.workers, scheduler=target, progress=True)
        return
    # An address, checked by the parser's _dask_target when the arguments were parsed.
    try:
        client = connect_dask(target, DASK_CONNECT_TIMEOUT)  # bounds the handshake too
    except SymmonError:
        raise
    except Exception as exc:  # tls:// without a TLS configuration, ucx:// without ucx-py, ...
        raise SymmonError(f"cannot connect to the Dask scheduler at {target}: "
                          f"{type(exc).__name__}: {exc}") from exc
    try:
        yield Executor(workers=args.workers, client=client, progress=True, worker_timeout=args.dask_timeout)
    finally:
        client.close()
