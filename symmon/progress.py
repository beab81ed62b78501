"""Progress of long runs on stderr: a tqdm bar on a terminal, a line every few seconds otherwise.

When stderr is a file or a pipe (a batch job, ``2> log``), a bar's carriage returns would
make a mess, and nothing at all leaves the user guessing whether a 46-second run is alive:
there, one short line is written every :data:`LINE_INTERVAL` seconds instead. The command
line's ``--quiet`` (or ``--no-progress``) runs inside :func:`silenced`, which hides both.
Progress output never changes a result.
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
import time
from typing import Callable, Iterable, Iterator, TypeVar

__all__ = ["progress_bar", "progress_lines", "note", "silenced", "LINE_INTERVAL"]

T = TypeVar("T")

#: Seconds between two progress lines when stderr is not a terminal.
LINE_INTERVAL = 5.0

_silenced: contextvars.ContextVar[bool] = contextvars.ContextVar("symmon_progress_silenced", default=False)


@contextlib.contextmanager
def silenced() -> Iterator[None]:
    """Hide every progress bar and progress line inside the ``with`` block."""
    token = _silenced.set(True)
    try:
        yield
    finally:
        _silenced.reset(token)


def progress_bar(items: Iterable[T], desc: str, enabled: bool = True, total: int | None = None) -> Iterable[T]:
    """``items``, reporting progress on stderr while they are consumed.

    Parameters
    ----------
    items : iterable
        What the loop runs over; returned unchanged when progress is off.
    desc : str
        What the loop does, the start of every bar or line.
    enabled : bool
        False: no progress (also inside :func:`silenced`).
    total : int, optional
        The number of items, when ``len(items)`` does not tell it.

    Returns
    -------
    iterable
        A tqdm bar on a terminal; otherwise a generator writing a line every
        :data:`LINE_INTERVAL` seconds.
    """
    if not enabled or _silenced.get():
        return items
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    if not sys.stderr.isatty():
        return progress_lines(items, desc, total, LINE_INTERVAL)
    try:
        from tqdm import tqdm
    except ImportError:  # the bar is a convenience; the run does not need it
        return progress_lines(items, desc, total, LINE_INTERVAL)
    return tqdm(items, desc=desc, total=total, leave=False)


def progress_lines(items: Iterable[T], desc: str, total: int | None, interval: float,
                   clock: Callable[[], float] = time.monotonic) -> Iterator[T]:
    """``items``, writing ``desc: done/total after t s`` to stderr at most every ``interval`` s.

    What :func:`progress_bar` returns when stderr is not a terminal; ``clock`` (seconds)
    is there for a test to control the time.
    """
    start = last = clock()
    done = 0
    for item in items:
        yield item
        done += 1
        now = clock()
        if now - last >= interval:
            last = now
            of = f"/{total}" if total else ""
            print(f"{desc}: {done}{of} done after {now - start:.0f} s", file=sys.stderr, flush=True)


def note(message: str, enabled: bool = True) -> None:
    """Write one line about a long run's state (``symmon: message``) to stderr, as the
    progress bars do: not when ``enabled`` is False nor inside :func:`silenced`."""
    if enabled and not _silenced.get():
        print(f"symmon: {message}", file=sys.stderr, flush=True)
