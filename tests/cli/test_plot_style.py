"""The figures of ``--plot`` in the package's one style (issue 47, item 15): 300 dpi, no
title, legends outside the data, plain log ticks, one look per filter, ±2 SE error bars
where the numbers have them."""

from __future__ import annotations

import pytest

pytest.importorskip("matplotlib")
from PIL import Image  # noqa: E402 (matplotlib's own dependency)

from symmon.cli import parser as cli  # noqa: E402
from symmon.reproduce import common  # noqa: E402

from helpers import EXAMPLES  # noqa: E402


@pytest.fixture
def saved(monkeypatch):
    """The figures the commands save, kept open for inspection (drawn, as when saved)."""
    figures = []
    real = common.save_plot

    def keep(fig, path):
        figures.append(fig)
        out = real(fig, path)
        fig.canvas.draw()
        return out

    monkeypatch.setattr(common, "save_plot", keep)
    return figures


def dpi(path) -> list[int]:
    with Image.open(path) as im:
        return [round(d) for d in im.info["dpi"]]


def check_common_style(fig) -> None:
    assert fig.get_suptitle() == "" and all(ax.get_title() == "" for ax in fig.axes)
    for ax in fig.axes:
        box = ax.get_window_extent()
        leg = ax.get_legend()
        if leg is not None:
            e = leg.get_window_extent()
            assert e.x0 >= box.x1 or e.y1 <= box.y0 or e.y0 >= box.y1 or e.x1 <= box.x0  # outside the data
        for axis in (ax.xaxis, ax.yaxis):
            labels = [t.get_text() for t in axis.get_majorticklabels() + axis.get_minorticklabels()]
            assert not [t for t in labels if "times" in t or "×" in t], labels


@pytest.mark.parametrize("transform, bars", [("mc", True), ("tt2", False)])
def test_nonlinearity_sweep_plot(tmp_path, capsys, saved, transform, bars):
    png = tmp_path / "mon.png"
    argv = ["nonlinearity", str(EXAMPLES / "polar.toml"), "--alpha-sweep", "0.01:100:5", "--transform", transform,
            "--plot", str(png), "--no-progress"]
    if transform == "mc":
        argv += ["--samples", "2000"]
    assert cli.main(argv) == 0
    assert dpi(png) == [300, 300]
    (fig,) = saved
    check_common_style(fig)
    (ax,) = fig.axes
    (container,) = ax.containers  # the errorbar's
    assert container.has_yerr is bars
    assert ax.get_legend() is not None and ("±2 SE" in ax.get_legend().get_texts()[0].get_text()) is bars


def test_filter_plot_one_look_per_filter_in_every_panel(tmp_path, capsys, saved):
    png = tmp_path / "nees.png"
    assert cli.main(["filter", str(EXAMPLES / "rb_close.toml"), "--runs", "5", "--filters", "ekf,ukf,adaptive",
                     "--smooth", "--plot", str(png)]) == 0
    assert dpi(png) == [300, 300]
    (fig,) = saved
    check_common_style(fig)
    for name in ("ekf", "ukf", "adaptive"):
        st = common.filter_style(name, 10)
        per_panel = [[ln for ln in ax.get_lines() if ln.get_color() == st["color"] and ln.get_marker() == st["marker"]]
                     for ax in fig.axes]
        assert all(len(lines) == 1 for lines in per_panel), name  # NEES, NIS and each RMSE panel
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels[:3] == ["ekf", "ukf", "adaptive"]
    assert [t.get_text() for ax in fig.axes for t in ax.texts] == [f"({x})" for x in "abcd"[:len(fig.axes)]]
