"""A wall-clock limit on symbolic work: SIGALRM in the main thread, a check between steps elsewhere.

sympy has no time limit of its own, and one call (``expand_trig`` of ``sin(1000 x)``, the
``simplify`` of a large difference) can run for minutes. :func:`deadline` bounds such a call:
in the main thread a repeating ``SIGALRM`` raises :class:`OutOfTime` inside the running
code (only inside sympy, mpmath and symmon: raised in foreign code, a garbage-collector
callback say, the exception would be ignored and the alarm lost, so it waits for the next
tick); in any thread the ``check`` it yields raises it between steps. Both the direct
unit-invariance proof (:mod:`symmon.units.direct`) and :func:`symmon.verify` use it.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterator, Sequence

import mpmath
import sympy as sp

__all__ = ["OutOfTime", "deadline", "INTERRUPTIBLE"]

#: The code the alarm may interrupt: sympy, mpmath and symmon itself (directories).
INTERRUPTIBLE: tuple[str, ...] = tuple(os.path.dirname(m.__file__) + os.sep for m in (sp, mpmath)) + (
    os.path.dirname(os.path.abspath(__file__)) + os.sep,)
#: Seconds between two alarms once the first has rung: a skipped one comes again.
REPEAT_S = 0.1


class OutOfTime(BaseException):
    """The time is spent. A BaseException: sympy catches Exception in places, and must not
    swallow the alarm."""


@contextmanager
def deadline(seconds: float, interruptible: Sequence[str] = INTERRUPTIBLE) -> Iterator[Callable[[], None]]:
    """A wall-clock limit of ``seconds`` on the ``with`` block.

    Parameters
    ----------
    seconds : float
        The budget; positive.
    interruptible : sequence of str
        Directories whose code the alarm may interrupt (default: sympy, mpmath, symmon).

    Yields
    ------
    callable
        ``check()``: raises :class:`OutOfTime` once the budget is spent (for loops between
        steps, and the only limit outside the main thread, where no signal can be used).

    Raises
    ------
    OutOfTime
        The budget is spent (raised inside the block).
    ValueError
        ``seconds`` is not a positive number.
    """
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not seconds > 0:
        raise ValueError(f"seconds must be a positive number, got {seconds!r}")
    end = time.perf_counter() + seconds
    prefixes = tuple(interruptible)

    def check() -> None:
        if time.perf_counter() > end:
            raise OutOfTime

    use_alarm = (threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer")
                 and signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0))
    if not use_alarm:  # another thread, or an alarm already running (an outer deadline): checks only
        yield check
        return

    def handler(signum, frame):  # noqa: ARG001 - the signal handler signature
        if frame is not None and frame.f_code.co_filename.startswith(prefixes):
            raise OutOfTime

    old = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, seconds, REPEAT_S)
    try:
        yield check
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
