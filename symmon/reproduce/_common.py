"""Shared pieces of the reproduction commands: progress bars and the plotting backend."""

from __future__ import annotations

from ..progress import progress_bar as progress_bar


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (a clear error if missing)."""
    try:
        import matplotlib
    except ImportError as exc:
        raise RuntimeError("plots need matplotlib: pip install 'symmon[plot]'") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
