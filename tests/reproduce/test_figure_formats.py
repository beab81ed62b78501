"""Figures for a journal (issue 38, item 17): ``reproduce --format png|pdf|svg`` with a
300 dpi PNG, Figure 2's unit sets and panel letters, and curves that never hide each other
(TT2 over Monte Carlo in Figure 2, ``gh`` under ``adaptive`` in the filter plots)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")
from PIL import Image  # noqa: E402 (matplotlib's own dependency)

from symmon.cli.parser import main  # noqa: E402
from symmon.errors import SymmonError  # noqa: E402
from symmon.reproduce import common, fig1, fig2  # noqa: E402


def _figure():
    plt = common.pyplot()
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    return plt, fig


@pytest.mark.parametrize("fmt", common.FORMATS)
def test_a_figure_is_saved_in_each_format(tmp_path, fmt):
    plt, fig = _figure()
    try:
        path = common.save_reproduced(fig, tmp_path / "f.png", fmt, "Title", "Caption")
    finally:
        plt.close(fig)
    assert path == tmp_path / f"f.{fmt}" and path.exists()
    head = path.read_bytes()[:200]
    if fmt == "png":
        with Image.open(path) as im:
            assert [round(d) for d in im.info["dpi"]] == [common.PNG_DPI] * 2 == [300, 300]
            assert im.info["Description"] == "Caption"
    elif fmt == "pdf":
        assert head.startswith(b"%PDF") and b"/Subtype /Image" not in path.read_bytes()  # vector: no raster image
    else:
        text = path.read_text(encoding="utf-8")
        assert "<svg" in text and "<image" not in text and "Caption" in text


def test_formats_name_the_outputs_and_a_bad_one_is_refused():
    assert common.with_format(fig1.OUTPUTS, "pdf") == ("fig1.pdf", "fig1.csv")
    with pytest.raises(SymmonError, match="png, pdf, svg"):
        common.with_format(fig1.OUTPUTS, "jpg")


def test_reproduce_takes_format(tmp_path, capsys):
    assert main(["reproduce", "fig1", "--samples", "32", "--format", "svg", "--out", str(tmp_path),
                 "--no-progress"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig1.csv", "fig1.svg"]
    assert main(["reproduce", "fig1", "--format", "jpg", "--out", str(tmp_path)]) == 2
    assert "invalid choice: 'jpg'" in capsys.readouterr().err


def _curves() -> dict:
    a = np.geomspace(0.1, 10, 21)
    c = {}
    for k, name in enumerate(fig2.PROBLEMS):
        v = {"alpha": a}
        for j, key in enumerate(("full", "diag", "orig", "orig_alt", "full_tt2", "full_ut")):
            v[key] = 0.01 * (1 + k) * a ** 0.5 * (1 + 0.01 * j)
        for key in ("full", "diag", "orig"):
            v[f"{key}_se"] = 1e-3 * a
        c[name] = v
    return c


def test_figure2_names_its_unit_sets_has_panel_letters_and_draws_tt2_above_mc():
    plt = common.pyplot()
    with common.figure_style():
        fig = fig2._plot(plt, _curves())
    try:
        texts = [t.get_text() for ax in fig.axes for t in ax.texts]
        assert [f"({x})" for x in "abcdef"] == [t for t in texts if t.startswith("(")]
        legend = " ".join(t.get_text() for t in fig.legends[0].get_texts())
        assert "km, deg, km/h" in legend and "km, –" in legend
        assert any("second unit set: km, deg, km/h" in t for t in texts)
        ax = fig.axes[0]
        mc = [ln for ln in ax.get_lines() if ln.get_linestyle() == "-" and ln.get_color() == common.OKABE_ITO["black"]]
        tt2 = [ln for ln in ax.get_lines() if ln.get_linestyle() == "--"]
        assert mc and tt2
        # TT2 above the Monte Carlo curve, in another colour, with markers of its own.
        assert tt2[0].get_zorder() > mc[0].get_zorder() and tt2[0].get_color() != mc[0].get_color()
        assert tt2[0].get_marker() not in (None, "None", "")
    finally:
        plt.close(fig)


def test_filters_on_one_axes_never_share_a_style_or_a_marker_position():
    names, points = ("ekf", "ekf2", "ukf", "ckf", "gh", "adaptive"), 40
    styles = [common.filter_style(n, points) for n in names]
    assert len({(s["color"], s["ls"], s["marker"]) for s in styles}) == len(names)
    marked = [set(range(points)[s["markevery"][0]::s["markevery"][1]]) for s in styles]
    assert all(m for m in marked)
    assert all(not (marked[i] & marked[j]) for i in range(len(names)) for j in range(i + 1, len(names)))
    # Each later filter above the earlier, thinner: a coinciding earlier one shows at its edges.
    assert all(b["zorder"] > a["zorder"] and b["lw"] < a["lw"] for a, b in zip(styles, styles[1:]))
