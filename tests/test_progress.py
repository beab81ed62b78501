"""Progress bars: shown on a terminal, hidden otherwise, and never change a result."""

from __future__ import annotations

import io

import numpy as np
import sympy as sp

import symmon as sm
from symmon.progress import progress_bar


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_bar_only_on_a_terminal(monkeypatch):
    items = [1, 2, 3]
    assert progress_bar(items, "x") is items  # pytest's stderr is not a terminal
    monkeypatch.setattr("sys.stderr", _Tty())
    from tqdm import tqdm

    bar = progress_bar(items, "x")
    assert isinstance(bar, tqdm) and list(bar) == items
    assert progress_bar(items, "x", enabled=False) is items


def test_monte_carlo_progress_does_not_change_the_result(monkeypatch):
    x = sp.Symbol("x", real=True)
    model = sm.Model([x], [sp.sin(x)], name="progress_mc")
    u = sm.Gaussian([0.3], [[0.5]])
    quiet = sm.propagate(model, u, transform=sm.MonteCarlo(4000, seed=2))
    monkeypatch.setattr("sys.stderr", _Tty())
    shown = sm.propagate(model, u, transform=sm.MonteCarlo(4000, seed=2, progress=True))
    assert np.array_equal(quiet.mean, shown.mean) and np.array_equal(quiet.cov, shown.cov)
    assert sm.MonteCarlo(10, seed=1, groups=2, progress=True) == sm.MonteCarlo(10, seed=1, groups=2)
