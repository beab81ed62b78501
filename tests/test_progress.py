"""Progress: a bar on a terminal, a line every few seconds otherwise, and never a changed result."""

from __future__ import annotations

import io
import itertools

import numpy as np
import sympy as sp

import symmon as sm
from symmon import progress
from symmon.progress import progress_bar, silenced


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_bar_only_on_a_terminal(monkeypatch):
    items = [1, 2, 3]
    from tqdm import tqdm

    assert not isinstance(progress_bar(items, "x"), tqdm)  # pytest's stderr is not a terminal
    monkeypatch.setattr("sys.stderr", _Tty())
    bar = progress_bar(items, "x")
    assert isinstance(bar, tqdm) and list(bar) == items
    assert progress_bar(items, "x", enabled=False) is items
    with silenced():
        assert progress_bar(items, "x") is items
    assert isinstance(progress_bar(items, "x"), tqdm)  # silenced only inside the block


def test_lines_when_stderr_is_not_a_terminal(capsys):
    ticks = itertools.count(0.0, 2.0)  # a clock that advances 2 s per item
    out = list(progress.progress_lines(range(7), "fig2: sweep", 7, 5.0, clock=lambda: next(ticks)))
    assert out == list(range(7))
    # Start at t=0; items end at t=2, 4, ...: a line once 5 s have passed since the last one.
    assert capsys.readouterr().err.splitlines() == ["fig2: sweep: 3/7 done after 6 s",
                                                     "fig2: sweep: 6/7 done after 12 s"]


def test_a_quick_loop_prints_nothing(capsys):
    assert list(progress_bar(range(5), "quick")) == list(range(5))
    assert capsys.readouterr().err == ""


def test_monte_carlo_progress_does_not_change_the_result(monkeypatch):
    x = sp.Symbol("x", real=True)
    model = sm.Model([x], [sp.sin(x)], name="progress_mc")
    u = sm.Gaussian([0.3], [[0.5]])
    quiet = sm.propagate(model, u, transform=sm.MonteCarlo(4000, seed=2))
    monkeypatch.setattr("sys.stderr", _Tty())
    shown = sm.propagate(model, u, transform=sm.MonteCarlo(4000, seed=2), executor=sm.Executor(progress=True))
    assert np.array_equal(quiet.mean, shown.mean) and np.array_equal(quiet.cov, shown.cov)
