"""What the benchmark scripts share: their sections of ``RESULTS.md``, times in text, and the
best of repeated calls by wall and CPU time (one copy, imported by each script from this
directory)."""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(ROOT))

from symmon.io import atomic_write_text  # noqa: E402


def write_section(path: Path, text: str, heading: str | None = None) -> None:
    """Replace the section ``heading`` (default: the first line of ``text``) of the Markdown
    file ``path`` by ``text``, or append it, leaving the other sections; written atomically."""
    heading = text.split("\n", 1)[0] if heading is None else heading
    old = path.read_text(encoding="utf-8") if path.exists() else ""
    pat = re.compile(rf"^{re.escape(heading)}\n.*?(?=^## |\Z)", re.S | re.M)
    new = pat.sub(lambda _: text.rstrip("\n") + "\n\n", old, count=1) if pat.search(old) \
        else old.rstrip("\n") + "\n\n" + text.rstrip("\n") + "\n"
    atomic_write_text(path, new.rstrip("\n") + "\n")


def fmt(t: float | None) -> str:
    """A time in µs, ms or s at a precision that fits the table; "—" for None."""
    if t is None:
        return "—"
    return f"{t * 1e6:.0f} µs" if t < 1e-3 else f"{t * 1e3:.1f} ms" if t < 1 else f"{t:.2f} s"


def best_wall_cpu(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """The least wall time and the least process CPU time (all threads) of ``repeats`` calls."""
    wall, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return min(wall), min(cpu)
