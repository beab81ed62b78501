"""A Ctrl-C while a filter bank (or its smoother) runs stops the bank's C loops (issue 38,
item 13): the waiting thread sets a flag that the loops poll between steps, and waits for
them before the KeyboardInterrupt propagates, so nothing keeps running in the shared pool.

The interrupt is a real SIGINT sent to the thread that waits (pytest's main thread) once
every chunk's part has started.  Each part then holds its C loop back until the stop flag
is set (it reads the flag the loop is given), so that the order is fixed whatever the load
of the machine: the loops start only after the interrupt, and must see the flag at their
first step and return, before the KeyboardInterrupt reaches the test.  Without the flag the
interrupt propagated at once, the loops still to run in the shared pool."""

from __future__ import annotations

import ctypes
import signal
import threading
import time

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile.ckernels import STOPPED
from symmon.filters.gaussian import smoother, step

x = sp.Symbol("x", real=True)
F = sm.Model([x], [0.9 * x + 0.1 * sp.sin(x)], name="f_interrupt")
H = sm.Model([x], [x + 0.1 * x**2], name="h_interrupt")
Q, R = np.array([[0.1]]), np.array([[0.2]])
RUNS, K = 2, 1000


@pytest.fixture(scope="module")
def compiled_step():
    kf = sm.NonlinearKalmanFilter(F, H, Q, R, sm.TT1())
    st = step.compiled_step(F, H, kf.transform, kf.angle_states)
    if not (st._lib.wait(600) and st.is_compiled):
        pytest.skip("no C compiler: the bank runs on CasADi's VM, step by step in Python")
    return st


def interrupted(loop, monkeypatch, call) -> list[int]:
    """Run ``call()`` with the loop's C function wrapped: once every chunk has entered its
    C loop, SIGINT goes to this (the waiting) thread.  Returns the loops' return codes
    as they stood when the KeyboardInterrupt arrived here."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    monkeypatch.setattr(step, "chunk_runs", lambda runs, K, n: [(0, 1), (1, 2)])  # one run per thread
    monkeypatch.setattr(smoother, "chunk_runs", lambda runs, K, n: [(0, 1), (1, 2)])
    real = loop._lib.get()
    started, codes = threading.Semaphore(0), []
    main = threading.get_ident()

    def wrapped(*args):
        started.release()
        flag = args[-1]
        for _ in range(10_000):  # at most 10 s: the flag set by the interrupted caller
            if isinstance(flag, int) and ctypes.c_int.from_address(flag).value:
                break
            time.sleep(0.001)
        code = real(*args)
        codes.append(code)
        return code

    def send() -> None:
        for _ in range(2):
            started.acquire(timeout=60)
        signal.pthread_kill(main, signal.SIGINT)

    loop._lib.get = lambda: wrapped  # an instance attribute over the method: removed below
    sender = threading.Thread(target=send)
    sender.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            call()
        seen = list(codes)
    finally:
        sender.join()
        del loop._lib.get
        signal.signal(signal.SIGINT, old)
    return seen


def test_ctrl_c_stops_the_filter_banks_c_loops(compiled_step, monkeypatch):
    Y = np.zeros((RUNS, K, 1))
    seen = interrupted(compiled_step, monkeypatch,
                       lambda: compiled_step(np.zeros(1), np.eye(1), Y, Q, R, keep=frozenset({"loglik"})))
    # Both loops had returned when the interrupt reached the caller, each at the flag.
    assert seen == [STOPPED, STOPPED]
    # The pool is free: the next bank runs in full.
    out = compiled_step(np.zeros(1), np.eye(1), Y[:, :50], Q, R)
    assert np.all(np.isfinite(out["loglik"]))


def test_ctrl_c_stops_the_smoothers_c_loops(monkeypatch):
    kf = sm.NonlinearKalmanFilter(F, H, Q, R, sm.TT1())
    sm_step = smoother.compiled_smoother(F, kf.transform, kf.angle_states)
    if not (sm_step._lib.wait(600) and sm_step.is_compiled):
        pytest.skip("no C compiler")
    xs, Ps = np.zeros((RUNS, K, 1)), np.ones((RUNS, K, 1, 1))
    seen = interrupted(sm_step, monkeypatch, lambda: sm_step(xs, Ps, Q))
    assert seen == [STOPPED, STOPPED]
