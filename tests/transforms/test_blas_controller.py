"""one_blas_thread's threadpoolctl controller (symmon.transforms.executor._blas_controller):
looked up once, and again after more modules were imported (one may load another BLAS)."""

from __future__ import annotations

import sys
import types

import threadpoolctl

from symmon.transforms import executor


def test_the_controller_is_kept_until_a_module_is_imported(monkeypatch):
    with executor._BLAS_LOCK:
        first = executor._blas_controller()
        assert executor._blas_controller() is first
        monkeypatch.setitem(sys.modules, "symmon_test_new_module", types.ModuleType("symmon_test_new_module"))
        again = executor._blas_controller()
    assert again is not first and isinstance(again, threadpoolctl.ThreadpoolController)


def test_one_blas_thread_limits_and_restores():
    blas = [i for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
    before = [i["num_threads"] for i in blas]
    with executor.one_blas_thread():
        inside = [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
    assert inside == [1] * len(blas)
    assert [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"] == before
