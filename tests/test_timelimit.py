"""The wall-clock limit on symbolic work (symmon.timelimit)."""

from __future__ import annotations

import threading
import time

import pytest
import sympy as sp

from symmon.timelimit import OutOfTime, deadline


def test_alarm_spares_foreign_code_and_interrupts_sympy():
    # Raised in foreign code (a gc callback, say) the alarm would be ignored and lost: it waits.
    spin_until = time.perf_counter() + 0.3
    with deadline(0.05) as check:
        while time.perf_counter() < spin_until:
            pass
        with pytest.raises(OutOfTime):
            check()
    # Inside sympy it interrupts (the timer repeats until it lands there).
    x = sp.Symbol("x")
    with pytest.raises(OutOfTime):
        with deadline(0.05):
            while True:
                sp.expand((x + 1) ** 3)


def test_outside_the_main_thread_only_the_check_stops():
    seen = []

    def work():
        with deadline(0.01) as check:
            time.sleep(0.05)
            try:
                check()
            except OutOfTime:
                seen.append("out of time")

    t = threading.Thread(target=work)
    t.start()
    t.join()
    assert seen == ["out of time"]


@pytest.mark.parametrize("seconds", [0, -1, True, "5"])
def test_a_budget_must_be_a_positive_number(seconds):
    with pytest.raises(ValueError, match="seconds must be a positive number"):
        with deadline(seconds):
            pass
