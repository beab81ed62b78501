"""Where work runs, apart from the method: threads that stop together, or Dask.

An :class:`Executor` says where a stochastic transform's replicates run (threads, a
local Dask scheduler or a Dask cluster) and whether a progress bar shows; the method
(:class:`~symmon.transforms.montecarlo.MonteCarlo`) fixes the numbers, which do not depend
on it.  :func:`run_groups` runs the replicates on threads and stops them all, within a
chunk, on Ctrl-C or on the first failure; :func:`dask_compute` and :func:`connect_dask`
are the Dask side.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import queue
import sys
import threading
import time
from concurrent.futures import CancelledError, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence, TypeVar

import numpy as np
import threadpoolctl

from ..compile.compiled import cpu_count
from ..errors import SymmonError, plain_repr
from ..progress import note, progress_bar

__all__ = ["Executor", "run_groups", "stop_point", "dask_compute", "connect_dask", "one_blas_thread",
           "WORKER_TIMEOUT", "MAX_WORKER_TIMEOUT"]

J = TypeVar("J")
R = TypeVar("R")


class _Stopped(Exception):
    """A group saw the stop event: the run was interrupted, or another group failed."""


def stop_point(stop: threading.Event | None) -> None:
    """End the calling group if the run is being stopped (called once per chunk)."""
    if stop is not None and stop.is_set():
        raise _Stopped


def run_groups(fn: Callable[[J, threading.Event], R], jobs: Sequence[J], workers: int,
               desc: str = "Monte Carlo groups", progress: bool = False) -> list[R]:
    """``fn(job, stop)`` for each job on ``workers`` threads; the results in job order.

    ``fn`` calls :func:`stop_point` once per chunk.  When the calling thread is
    interrupted (Ctrl-C: KeyboardInterrupt) or a group raises, the stop event is set:
    the running groups end at their next chunk, the queued ones never start, and the
    exception propagates, within about one chunk's time instead of the remaining groups'.
    """
    stop = threading.Event()
    # Even one worker runs off the main thread: the main thread then only waits, where a
    # Ctrl-C is always seen at once (inline, a SIGINT was sometimes lost in the kernel loop).
    # The BLAS limit holds for the pool's whole life: it is restored only once no worker runs.
    with one_blas_thread():
        pool = ThreadPoolExecutor(workers)
        try:
            futures = [pool.submit(fn, j, stop) for j in jobs]
            return [f.result() for f in progress_bar(futures, desc, progress, total=len(futures))]
        except BaseException:
            stop.set()
            raise
        finally:
            # Drop the queued groups; the running ones see `stop` within a chunk.
            pool.shutdown(wait=True, cancel_futures=True)


#: The process's one BLAS limit of :func:`one_blas_thread`: the users inside it, and the
#: threadpoolctl limiter that the first one set and the last one restores.
_BLAS_LOCK = threading.Lock()
_BLAS_STATE: dict[str, Any] = {"users": 0, "limiter": None, "controller": None, "modules": -1}


def _blas_controller() -> threadpoolctl.ThreadpoolController:
    """threadpoolctl's view of the loaded BLAS libraries (under ``_BLAS_LOCK``), looked up once
    (6 ms) and again only after more modules were imported (one may have loaded another
    BLAS): a limit through it costs 20 µs, ``threadpool_limits`` 1.5–3 ms, as it looks them
    up every time (a maximum-likelihood fit of a small filter takes 4 ms)."""
    if _BLAS_STATE["modules"] != len(sys.modules):
        _BLAS_STATE["controller"], _BLAS_STATE["modules"] = threadpoolctl.ThreadpoolController(), len(sys.modules)
    return _BLAS_STATE["controller"]


def _release_openblas_control() -> None:
    """Let any thread set OpenBLAS's limit next.  threadpoolctl ≥ 3.6 lets only the thread
    that last set a process-wide (pthreads) OpenBLAS limit change it again, and silently
    ignores the others; the limit here is set by the first user's thread and restored by
    the last one's, perhaps another, so neither keeps that control (the calls are
    serialised by ``_BLAS_LOCK``).  Older threadpoolctl has no such control."""
    clear = getattr(getattr(threadpoolctl, "OpenBLASController", None), "clear_controlling_thread", None)
    if clear is not None:
        clear(force=True)


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """While symmon's own workers run, BLAS (OpenBLAS, MKL, ...) uses one thread each.

    The workers already take the cores: a multithreaded BLAS beside them oversubscribes
    them (a 20-input Monte Carlo on 2 cores took 1.6× the wall time with OpenBLAS's own
    threads, docs/compile.md).  The limit is the library's, so it holds for the whole
    process; it is therefore reference-counted: the first of overlapping users (two
    Monte Carlo calls from two Python threads) sets it, the last one restores what was
    there before the first.  Each user restoring "its" previous setting, as nested
    ``threadpool_limits`` contexts do, left BLAS at one thread for good when the calls
    ended in the order they began: the second one saw the first one's limit as the
    setting to restore.
    """
    with _BLAS_LOCK:
        if _BLAS_STATE["users"] == 0:
            _release_openblas_control()
            _BLAS_STATE["limiter"] = _blas_controller().limit(limits=1, user_api="blas")
            _release_openblas_control()
        _BLAS_STATE["users"] += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _BLAS_STATE["users"] -= 1
            if _BLAS_STATE["users"] == 0:
                limiter, _BLAS_STATE["limiter"] = _BLAS_STATE["limiter"], None
                _release_openblas_control()
                limiter.restore_original_limits()
                _release_openblas_control()


def _is_int(v: Any) -> bool:
    """An integer, numpy's included, and not a bool."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


#: Seconds a Dask run waits for a worker: for the first one to join, and after the last
#: one is lost, for another (``Executor(worker_timeout=...)``, ``--dask-timeout``).
WORKER_TIMEOUT = 60.0
#: Longest ``worker_timeout`` accepted (a day): a run waits, bounded, for workers to come.
MAX_WORKER_TIMEOUT = 86400.0


class _WorkerWatch:
    """Whether a Dask cluster has had a worker lately: a run with no worker for
    ``timeout`` seconds (none joined, or the last one died) ends with a SymmonError
    instead of waiting forever; the wait is announced on stderr with ``progress``."""

    def __init__(self, client: Any, timeout: float, desc: str, progress: bool) -> None:
        self.client, self.timeout, self.desc, self.progress = client, timeout, desc, progress
        self.poll = min(1.0, timeout / 4)  # seconds between two looks when nothing finishes
        self.seen = False  # a worker was there at some point
        self.since: float | None = None  # when the cluster was last seen without a worker

    def where(self) -> str:
        return f"the Dask cluster at {getattr(getattr(self.client, 'scheduler', None), 'address', '?')}"

    def check(self, futures: list) -> None:
        """Raise SymmonError when the cluster has had no worker for ``timeout`` s
        (``futures``: the run's, for the count of the unfinished)."""
        total = len(futures)
        unfinished = sum(f.status != "finished" for f in futures)
        try:
            workers = len(self.client.nthreads())
        except Exception as exc:  # CommClosedError, OSError, ...: the scheduler went away
            raise SymmonError(f"lost {self.where()} with {unfinished} of {total} {self.desc} "
                              f"unfinished: {type(exc).__name__}: {exc}") from exc
        now = time.monotonic()
        if workers:
            if self.since is not None:
                note(f"{self.desc}: {workers} Dask worker(s) now; going on", self.progress)
            self.seen, self.since = True, None
            return
        if self.since is None:
            self.since = now
            what = "lost its last worker" if self.seen else "has no worker"
            note(f"{self.desc}: {self.where()} {what}; waiting up to {self.timeout:g} s for one "
                 f"({unfinished} of {total} unfinished)", self.progress)
        elif now - self.since >= self.timeout:
            what = ("lost its workers and none came back" if self.seen else "had no worker")
            raise SymmonError(
                f"{self.where()} {what} for {self.timeout:g} s, with {unfinished} of {total} "
                f"{self.desc} unfinished: start workers for it (dask worker ADDRESS), or wait "
                f"longer with Executor(worker_timeout=...) / --dask-timeout")


def _client_results(futures: list, watch: _WorkerWatch, desc: str, progress: bool) -> list:
    """The results of the Dask ``futures`` in order, counting them as they finish, and
    watching the cluster's workers whenever nothing finishes for a while."""
    from distributed import TimeoutError as DaskTimeout

    total = len(futures)
    finished: queue.SimpleQueue = queue.SimpleQueue()
    for f in futures:
        f.add_done_callback(finished.put)

    def completions() -> Iterator[Any]:
        for _ in range(total):
            while True:
                try:
                    f = finished.get(timeout=watch.poll)
                    break
                except queue.Empty:
                    watch.check(futures)
            if f.status == "error":
                f.result()  # raises the task's exception now, not after the tasks before it
            yield f

    watch.check(futures)
    for _ in progress_bar(completions(), desc, progress, total=total):
        pass
    results = []
    for f in futures:
        while True:  # a result held by a worker that died is computed again, elsewhere
            try:
                results.append(f.result(timeout=watch.poll))
                break
            except (DaskTimeout, TimeoutError):
                watch.check(futures)
    return results


def _dask_failure(exc: BaseException, where: str, desc: str) -> SymmonError | None:
    """The SymmonError of the cluster's own failures (a task whose workers kept dying,
    cancelled tasks), None for the task's own exception."""
    from distributed import KilledWorker

    if isinstance(exc, KilledWorker):
        return SymmonError(f"{where}: the workers running one of the {desc} died each time it ran "
                           f"(out of memory, or killed?): {exc}")
    if isinstance(exc, CancelledError):  # distributed's FutureCancelledError too
        return SymmonError(f"{where}: the {desc} were cancelled on the cluster (another client, "
                           f"or the scheduler restarted): {exc}")
    return None


def dask_compute(tasks: Sequence[Any], client: Any = None, scheduler: str | None = None,
                 desc: str = "Dask tasks", progress: bool = False,
                 worker_timeout: float = WORKER_TIMEOUT) -> list:
    """The results of Dask delayed ``tasks``, in order, on ``client`` or else on the local
    ``scheduler``.  On a client, an interrupt (or any error) cancels the tasks still
    pending, so the cluster does not go on with a run nobody waits for.

    With ``progress`` each finished task is counted as the thread pool counts its groups
    (:func:`symmon.progress.progress_bar`: a bar on a terminal, a line every few seconds
    otherwise), in the order the tasks finish.

    On a client, a cluster without a worker (none joined, or the last one died) is
    waited for at most ``worker_timeout`` seconds (a line on stderr with ``progress``
    says so), then the run ends with a SymmonError; so does a task whose workers died
    every time it ran (distributed's KilledWorker) or that was cancelled on the cluster.
    """
    if client is not None:
        watch = _WorkerWatch(client, worker_timeout, desc, progress)
        futures = client.compute(list(tasks))
        try:
            return _client_results(futures, watch, desc, progress)
        except BaseException as exc:
            client.cancel(futures)
            failure = _dask_failure(exc, watch.where(), desc)
            if failure is not None:
                raise failure from exc
            raise
    import dask
    from dask.callbacks import Callback

    keys = {t.key for t in tasks}
    finished: queue.SimpleQueue = queue.SimpleQueue()

    def count(key, result, dsk, state, worker_id):
        if key in keys:
            finished.put(key)

    # The scheduler runs in this thread: a second one reports while it works, in this
    # thread's context (where progress.silenced() may hold).
    reporter = threading.Thread(target=contextvars.copy_context().run,
                                args=(_drain, finished, desc, progress, len(keys)), daemon=True)
    reporter.start()
    try:
        with Callback(posttask=count):
            return list(dask.compute(*tasks, scheduler=scheduler))
    finally:
        finished.put(None)
        reporter.join()


def _drain(finished: queue.SimpleQueue, desc: str, progress: bool, total: int) -> None:
    """Count the finished tasks of :func:`dask_compute` until its end mark (None)."""
    for _ in progress_bar(iter(finished.get, None), desc, progress, total=total):
        pass


def connect_dask(address: str, timeout: float = 10.0) -> Any:
    """A ``dask.distributed.Client`` to the scheduler at ``address``, or a clear error
    within about ``timeout`` seconds.

    ``Client(address, timeout=...)`` bounds the TCP connection but not distributed's
    handshake after it: a server that accepts the connection and never answers (a wrong
    port, a hung scheduler) would hold it forever.  So the handshake is tried first, in
    its own event loop on a helper thread: ``timeout`` for the connection (as a closed
    port gets), then as long again for the answer.

    Raises
    ------
    SymmonError
        The 'dask' extra is missing, or no scheduler answered at ``address`` in time.
    """
    try:
        from distributed import Client
        from distributed.comm import connect
        from distributed.security import Security
    except ImportError as exc:
        raise SymmonError(f"a Dask scheduler address ({address}) needs the 'dask' extra: "
                          "pip install 'symmon[dask]'") from exc

    async def handshake() -> None:
        comm = await connect(address, timeout=timeout, **Security().get_connection_args("client"))
        await comm.close()

    def probe() -> None:
        # A refused or unresolvable address fails inside connect() after `timeout`, first.
        asyncio.run(asyncio.wait_for(handshake(), 2 * timeout))

    reach = f"cannot reach the Dask scheduler at {address} within {timeout:g} s"
    with ThreadPoolExecutor(1) as pool:  # a thread: the caller may be inside an event loop
        try:
            pool.submit(probe).result()
        except asyncio.TimeoutError as exc:
            raise SymmonError(f"{reach}: the connection was accepted but nothing answered in "
                              f"another {timeout:g} s (is a Dask scheduler listening there?)") from exc
        except (OSError, ValueError) as exc:  # refused, unresolvable, malformed address
            raise SymmonError(f"{reach}: {exc}") from exc
    try:
        return Client(address, timeout=timeout)
    except OSError as exc:
        raise SymmonError(f"{reach}: {exc}") from exc


@dataclass(frozen=True)
class Executor:
    """Where a stochastic transform's replicates run: apart from the method, so that
    the same ``MonteCarlo`` gives the same numbers wherever it runs.

    Parameters
    ----------
    workers : int or None
        Threads (``None``: the number of CPUs, at most the number of replicates).
    client : dask.distributed.Client, optional
        Run the replicates on a Dask cluster.
    scheduler : str, optional
        A local Dask scheduler name (``"threads"``, ``"processes"``, ``"synchronous"``).
    progress : bool
        Show a progress bar over the replicates (on a terminal only).
    worker_timeout : float
        On a ``client``: seconds to wait for a worker when the cluster has none, at the
        start or after the last one died, before the run ends with a SymmonError
        (default :data:`WORKER_TIMEOUT`, 60 s; at most a day).
    """

    workers: int | None = None
    client: Any = field(default=None, repr=False)
    scheduler: str | None = None
    progress: bool = False
    worker_timeout: float = WORKER_TIMEOUT

    def __post_init__(self) -> None:
        if self.workers is not None and (not _is_int(self.workers) or self.workers < 1):
            raise SymmonError(f"workers must be >= 1, got {plain_repr(self.workers)}")
        if self.client is not None and self.scheduler is not None:
            raise SymmonError("pass either client or scheduler, not both")
        t = self.worker_timeout
        if not (isinstance(t, (int, float, np.integer, np.floating)) and not isinstance(t, (bool, np.bool_))
                and 0 < t <= MAX_WORKER_TIMEOUT):
            raise SymmonError(f"worker_timeout must be seconds, > 0 and at most {MAX_WORKER_TIMEOUT:g}, "
                              f"got {plain_repr(t)}")
        if self.scheduler is not None and not isinstance(self.scheduler, str):
            raise SymmonError(f"scheduler must be a Dask scheduler name such as 'processes', got {self.scheduler!r}")

    @property
    def distributed(self) -> bool:
        """True when the work goes to Dask."""
        return self.client is not None or self.scheduler is not None

    def threads(self, jobs: int) -> int:
        """Threads for ``jobs`` replicates: ``workers``, or the number of CPUs, at most ``jobs``."""
        return self.workers or min(cpu_count(), int(jobs))

    def run(self, fn: Callable[[J, threading.Event], R], jobs: Sequence[J], desc: str) -> list[R]:
        """``fn(job, stop)`` for each job on this executor's threads (:func:`run_groups`)."""
        return run_groups(fn, jobs, self.threads(len(jobs)), desc, self.progress)
