"""A Dask cluster without workers ends a run with a SymmonError in bounded time (issue 26, item 2).

A scheduler with no worker, or whose only worker dies, used to make symmon wait forever
with nothing on stderr: the watch in ``dask_compute`` waits at most ``worker_timeout``
seconds for a worker, says so on stderr, and stops with an error naming the cluster.
The clusters here run in this process (``processes=False``): they start in a fraction of
a second and their worker can be closed from a task.
"""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

import symmon as sm
from symmon.core.problems import gmti
from symmon.errors import SymmonError
from symmon.transforms import executor
from symmon.transforms.executor import MAX_WORKER_TIMEOUT, WORKER_TIMEOUT, _dask_failure, dask_compute

distributed = pytest.importorskip("dask.distributed")
dask = pytest.importorskip("dask")

#: Short waits for a worker: the point is that they end, not how long they take.
SHORT = 0.5
#: Long enough that a worker started by the test arrives well within it.
PATIENT = 60.0


@pytest.fixture
def cluster():
    """An in-process scheduler with no worker, and its client; extra workers closed after."""
    c = distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0")
    client = distributed.Client(c)
    extra: list = []
    yield c, client, extra
    for w in extra:
        client.sync(w.close)
    client.close()
    c.close()


def start_worker(client) -> object:
    async def start():
        return await distributed.Worker(client.scheduler.address, nthreads=1)
    return client.sync(start)


def test_no_worker_is_an_error_not_a_hang(cluster, capsys):
    _, client, _ = cluster
    p = gmti(1.0)
    ex = sm.Executor(client=client, worker_timeout=SHORT, progress=True)
    with pytest.raises(SymmonError, match=rf"had no worker for {SHORT:g} s, with 4 of 4 Monte Carlo groups "
                                          r"unfinished: start workers .* --dask-timeout"):
        sm.propagate(p.model, p.u, transform=sm.MonteCarlo(10**4, seed=1, groups=4), executor=ex)
    err = capsys.readouterr().err
    assert f"has no worker; waiting up to {SHORT:g} s for one (4 of 4 unfinished)" in err
    assert not client.futures  # the tasks were cancelled, not left on the scheduler


_closed_once = threading.Event()


def _closes_its_worker_once(i: int) -> int:
    """Task 0 closes the worker running it, the first time only; the others take a while."""
    if i == 0 and not _closed_once.is_set():
        _closed_once.set()
        w = distributed.get_worker()
        w.loop.add_callback(w.close, executor_wait=False)
        return 0
    time.sleep(0.05)
    return i * i


def _tasks(tag: str, n: int = 4) -> list:
    return [dask.delayed(_closes_its_worker_once)(i, dask_key_name=f"{tag}-{i}") for i in range(n)]


def test_losing_the_only_worker_is_an_error(cluster, capsys):
    _, client, extra = cluster
    _closed_once.clear()
    start_worker(client)  # closed by the first task
    with pytest.raises(SymmonError, match=rf"lost its workers and none came back for {SHORT:g} s"):
        dask_compute(_tasks("lost"), client, desc="test tasks", progress=True, worker_timeout=SHORT)
    assert f"lost its last worker; waiting up to {SHORT:g} s for one" in capsys.readouterr().err
    assert not client.futures


def test_a_worker_that_comes_back_in_time_finishes_the_run(cluster, monkeypatch):
    """The wait is for *a* worker: one that joins while the run waits takes over its tasks."""
    _, client, extra = cluster
    _closed_once.clear()
    notes: list[str] = []
    waiting = threading.Event()

    def record(message: str, enabled: bool = True) -> None:
        notes.append(message)
        if "lost its last worker" in message:
            waiting.set()

    monkeypatch.setattr(executor, "note", record)
    start_worker(client)

    def revive():  # once the run says it waits
        if waiting.wait(PATIENT):
            extra.append(start_worker(client))

    helper = threading.Thread(target=revive)
    helper.start()
    try:
        got = dask_compute(_tasks("back"), client, desc="test tasks", progress=True, worker_timeout=PATIENT)
    finally:
        waiting.set()
        helper.join()
    assert got == [0, 1, 4, 9]
    # It did wait: the worker came only after the run had said so.
    assert any("lost its last worker; waiting up to" in n for n in notes), notes


def test_cluster_failures_are_symmon_errors():
    killed = distributed.KilledWorker("task-1", SimpleNamespace(address="tcp://w:1"), allowed_failures=3)
    assert "died each time it ran" in str(_dask_failure(killed, "the Dask cluster at tcp://s:1", "tasks"))
    cancelled = distributed.client.FutureCancelledError("task-1", reason="scheduler-restart")
    assert "were cancelled on the cluster" in str(_dask_failure(cancelled, "here", "tasks"))
    assert _dask_failure(ZeroDivisionError("the task's own"), "here", "tasks") is None


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), MAX_WORKER_TIMEOUT * 2, "60", True, None])
def test_worker_timeout_is_checked(bad):
    with pytest.raises(SymmonError, match="worker_timeout must be seconds"):
        sm.Executor(worker_timeout=bad)


def test_worker_timeout_default():
    assert sm.Executor().worker_timeout == WORKER_TIMEOUT == 60.0 and np.isfinite(MAX_WORKER_TIMEOUT)
