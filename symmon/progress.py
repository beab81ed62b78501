"""Progress bars for long runs: shown on a terminal, hidden otherwise."""

from __future__ import annotations

import sys
from typing import Iterable, TypeVar

__all__ = ["progress_bar"]

T = TypeVar("T")


def progress_bar(items: Iterable[T], desc: str, enabled: bool = True, total: int | None = None) -> Iterable[T]:
    """Wrap ``items`` in a tqdm bar, hidden when disabled or when stderr is not a terminal."""
    if not enabled or not sys.stderr.isatty():
        return items
    try:
        from tqdm import tqdm
    except ImportError:  # the bar is a convenience; the run does not need it
        return items
    return tqdm(items, desc=desc, total=total, leave=False)
