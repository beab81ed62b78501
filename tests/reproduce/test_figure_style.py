"""One figure style for every figure the package draws (issue 47, items 14 and 15).

Figure 1 prints its headline numbers beside the paper's and has panel letters; the tracking
figures keep one colour and marker per filter across panels, put their legends outside the
data, label log axes with plain numbers and are saved at 300 dpi without a title.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

pytest.importorskip("matplotlib")
from PIL import Image  # noqa: E402 (matplotlib's own dependency)

from symmon.reproduce import common, fig1, tracking  # noqa: E402

SAMPLES = 4000
ALPHAS = np.array([1e-3, 0.17, 10.0])


# --------------------------------------------------------------------------- helpers
def tick_texts(fig) -> list[str]:
    """The texts of every tick label of ``fig``, after drawing it (labels are set at draw)."""
    fig.canvas.draw()
    out = []
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            out += [t.get_text() for t in axis.get_majorticklabels() + axis.get_minorticklabels()]
    return [t for t in out if t]


def outside_data(fig, legend, ax) -> bool:
    """True when the drawn ``legend`` does not overlap the data area of ``ax``."""
    fig.canvas.draw()
    e, box = legend.get_window_extent(), ax.get_window_extent()
    return e.x0 >= box.x1 or e.x1 <= box.x0 or e.y0 >= box.y1 or e.y1 <= box.y0


def legends_of(fig) -> list:
    return [a for ax in fig.axes for a in ax.get_children() if type(a).__name__ == "Legend"] + list(fig.legends)


# --------------------------------------------------------------------------- Figure 1
@pytest.fixture(scope="module")
def fig1_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig1")
    lines: list[str] = []
    paths = fig1.run(out, samples=SAMPLES, progress=False, alphas=ALPHAS, report=lines.append)
    return paths, lines


def test_fig1_prints_its_numbers_beside_the_papers(fig1_run):
    paths, lines = fig1_run
    text = "\n".join(lines)
    c = fig1.curves(ALPHAS, samples=SAMPLES, progress=False)  # the same seed: the same numbers
    i = int(np.flatnonzero(ALPHAS == 0.17)[0])
    assert "alpha = 0.17" in lines[0] and f"{SAMPLES:,} samples" in lines[0]
    rad = next(ln for ln in lines if "bearing in rad" in ln)
    deg = next(ln for ln in lines if "bearing in deg" in ln)
    assert f"{c['liu_rad'][i]:.3f} ± {2 * c['liu_rad_se'][i]:.3f}" in rad and "paper: 10 %" in rad
    assert f"{c['liu_deg'][i]:.3f} ± {2 * c['liu_deg_se'][i]:.3f}" in deg and "paper: 80 %" in deg
    assert f"{c['band_lo'][i]:.3f} to {c['band_hi'][i]:.3f}" in text
    unitless = next(ln for ln in lines if ln.startswith("unitless MoN"))
    assert f"{c['full'].min():.3f} to {c['full'].max():.3f}" in unitless and "the same in every unit" in unitless
    assert fig1.PAPER_LIU_LI == {"rad": 0.10, "deg": 0.80} and fig1.PAPER_ALPHA == 0.17


def test_fig1_headline_names_the_nearest_alpha_when_017_is_off_the_grid():
    c = fig1.curves(np.array([0.1, 1.0]), samples=500, progress=False)
    first = fig1.headline(c, 500)[0]
    assert "alpha = 0.1 (the grid's nearest to the paper's 0.17)" in first


def test_reproduce_fig1_prints_the_headline_before_the_files(tmp_path, capsys):
    from symmon.cli.parser import main

    assert main(["reproduce", "fig1", "--samples", "500", "--out", str(tmp_path), "--no-progress"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert re.search(r"bearing in rad: \d\.\d{3} ± \d\.\d{3} \(2 SE\); paper: 10 %", "\n".join(out))
    assert re.search(r"bearing in deg: \d\.\d{3} ± \d\.\d{3} \(2 SE\); paper: 80 %", "\n".join(out))
    assert out[-2:] == [f"wrote {tmp_path / 'fig1.png'}", f"wrote {tmp_path / 'fig1.csv'}"]


@pytest.fixture(scope="module")
def fig1_figure():
    plt = common.pyplot()
    c = fig1.curves(ALPHAS, samples=SAMPLES, progress=False)
    with common.figure_style():
        fig = fig1._plot(plt, c)
    yield fig
    plt.close(fig)


def test_fig1_has_panel_letters(fig1_figure):
    letters = [[t.get_text() for t in ax.texts if t.get_text().startswith("(")] for ax in fig1_figure.axes]
    assert letters == [["(a)"], ["(b)"]]
    assert all(ax.get_title() == "" for ax in fig1_figure.axes) and fig1_figure.get_suptitle() == ""


def test_fig1_legends_are_outside_the_data(fig1_figure):
    legends = legends_of(fig1_figure)
    assert legends
    for leg in legends:
        for ax in fig1_figure.axes:
            assert outside_data(fig1_figure, leg, ax)


def test_fig1_log_axes_have_plain_tick_labels(fig1_figure):
    texts = tick_texts(fig1_figure)
    assert "0.01" in texts and "1" in texts
    assert not [t for t in texts if "times" in t or "×" in t or "^" in t]


# --------------------------------------------------------------------------- the shared style
def test_each_filter_has_one_look_and_labels_map_to_it():
    looks = {name: (c, m) for name, (c, m, _) in common.FILTER_STYLES.items()}
    # The same filter under two names (symmon filter's gsf is bot's MoN-split GSF), else distinct.
    assert looks["gsf"] == looks["mon_gsf"]
    distinct = [v for k, v in looks.items() if k != "mon_gsf"]
    assert len(set(distinct)) == len(distinct)
    assert all(c in common.OKABE_ITO for c, _, _ in common.FILTER_STYLES.values())
    for label, name in (("EKF", "ekf"), ("EKF2", "ekf2"), ("CKF", "ckf"), ("GHKF(order=3)", "gh"),
                        ("UKF(alpha=1.0, beta=0.0, kappa=None)", "ukf"), ("adaptive", "adaptive")):
        assert common.filter_key(label) == name
        a, b = common.filter_style(label, 40), common.filter_style(name, 40)
        assert (a["color"], a["marker"], a["ls"]) == (b["color"], b["marker"], b["ls"])
    assert common.filter_key("KF(MonteCarlo())") is None
    assert common.filter_style("KF(MonteCarlo())", 40)["color"] == "grey"


def test_plain_log_ticks_replaces_the_scientific_labels():
    plt = common.pyplot()
    fig, (before, after) = plt.subplots(1, 2)
    try:
        for ax in (before, after):
            ax.semilogy([1, 2, 3], [1.5, 2.5, 4.0])  # less than a decade: matplotlib labels 2×10⁰
        common.plain_log_ticks(after)
        fig.canvas.draw()
        old = [t.get_text() for t in before.yaxis.get_minorticklabels() if t.get_text()]
        new = [t.get_text() for t in after.yaxis.get_minorticklabels() if t.get_text()]
        assert any("times" in t for t in old)  # the default that the issue reports
        assert new and set(new) <= {"2", "3", "4", "5", "6", "7", "8", "9"}
    finally:
        plt.close(fig)


# --------------------------------------------------------------------------- tracking figures
@pytest.fixture(scope="module")
def tracking_figure():
    sc = tracking.scenarios()[1]
    st = tracking.study(sc, 8, 0, progress=False)
    with common.figure_style():
        fig = tracking._figure(sc, st)
    return sc, st, fig


def test_tracking_filter_looks_are_the_same_in_every_panel(tracking_figure):
    sc, st, fig = tracking_figure
    looks: dict[str, set] = {}
    for ax in fig.axes:
        for ln in ax.get_lines():
            marker = ln.get_marker()
            if marker in (None, "None", ""):
                continue  # the smoothers, the step markers: no filter's look
            looks.setdefault(ln.get_color(), set()).add(marker)
    filters = list(st["filters"])
    assert len(filters) == 6
    for name in filters:
        style = common.filter_style(name, sc.steps)
        drawn = [(ax, ln) for ax in fig.axes[:3] for ln in ax.get_lines()
                 if ln.get_color() == style["color"] and ln.get_marker() == style["marker"]]
        assert len(drawn) == 3, name  # NEES, NIS, RMSE: one curve each, one look
        assert {ln.get_linestyle() for _, ln in drawn} == {drawn[0][1].get_linestyle()}
    # The adaptive filter's choices (panel e) in the looks of the filters chosen.
    for ln in fig.axes[4].get_lines():
        if ln.get_label().startswith("_"):
            continue
        style = common.filter_style(ln.get_label(), sc.steps)
        assert (ln.get_color(), ln.get_marker()) == (style["color"], style["marker"])
    # Every colour is one filter's marker alone, in every panel: never red and green alone.
    palette = {common.OKABE_ITO[c] for c, _, _ in common.FILTER_STYLES.values()}
    for colour, markers in looks.items():
        if colour in palette:
            assert len(markers) == 1, (colour, markers)


def test_tracking_legends_outside_no_title_plain_ticks(tracking_figure):
    _, _, fig = tracking_figure
    legends = legends_of(fig)
    assert len(legends) == 5
    for leg in legends:
        for ax in fig.axes:
            assert outside_data(fig, leg, ax)
    assert [t.get_text() for ax in fig.axes for t in ax.texts] == [f"({x})" for x in "abcde"]
    assert all(ax.get_title() == "" for ax in fig.axes) and fig.get_suptitle() == ""
    texts = tick_texts(fig)
    assert not [t for t in texts if "×10" in t or "times10" in t.replace(" ", "")]


def test_tracking_png_is_300_dpi_with_its_caption(tracking_figure, tmp_path):
    sc, st, _ = tracking_figure
    path = tracking._plot(sc, st, 8, tmp_path / "t.png")
    with Image.open(path) as im:
        assert [round(d) for d in im.info["dpi"]] == [300, 300]
        assert im.info["Description"] == tracking.caption(sc, 8)
