"""The reproduction commands of Figures 1 and 2 (small samples; the defaults are 10^6)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from helpers import ROOT
from symmon.reproduce import fig1, fig2
from symmon.reproduce.common import OKABE_ITO, figure_style, pyplot, with_angles

SAMPLES = 20_000
#: Monte Carlo bound in standard errors.
N_SE = 5
#: The α of the small runs: α = 10 puts Figure 1's bearing samples across its cut at ±π
#: (the run would raise an AngleWarning, an error under the tests' filterwarnings, if the
#: bearing were not declared).
FIG1_ALPHAS = np.array([1e-3, 0.17, 10.0])
FIG2_ALPHAS = np.array([0.1, 10.0])


@pytest.fixture(scope="module")
def fig1_paths(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig1")
    paths = fig1.run(out, samples=SAMPLES, progress=False, alphas=FIG1_ALPHAS)
    assert [p.name for p in paths] == ["fig1.png", "fig1.csv"] == list(fig1.OUTPUTS)
    assert paths[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return paths


@pytest.fixture(scope="module")
def fig1_rows(fig1_paths):
    return keyed(fig1_paths[1], fig1.COLUMNS)


def keyed(path, columns: dict[str, str]) -> list[dict[str, str]]:
    """The CSV's rows by the short keys of ``columns`` (the headers are descriptive)."""
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        assert reader.fieldnames == list(columns.values())
        by_header = {v: k for k, v in columns.items()}
        return [{by_header[h]: v for h, v in r.items()} for r in reader]


def test_fig1_claim_at_alpha_017(fig1_rows):
    """Sec. II-B: M^norm ≈ 10 % in rad and ≈ 80 % in deg at α = 0.17."""
    row = [r for r in fig1_rows if float(r["alpha"]) == 0.17][0]
    assert abs(float(row["liu_rad"]) - 0.10) < 0.01 + N_SE * float(row["liu_rad_se"])
    assert abs(float(row["liu_deg"]) - 0.80) < 0.01 + N_SE * float(row["liu_deg_se"])


def test_fig1_band_contains_both_units(fig1_rows):
    for r in fig1_rows:
        lo, hi = float(r["band_lo"]), float(r["band_hi"])
        assert lo <= float(r["liu_rad"]) + 1e-12 and float(r["liu_rad"]) <= hi + 1e-12
        assert lo <= float(r["liu_deg"]) + 1e-12 and float(r["liu_deg"]) <= hi + 1e-12
        assert 0 <= lo <= hi <= 1


@pytest.fixture(scope="module")
def fig2_paths(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig2")
    paths = fig2.run(out, samples=SAMPLES, progress=False, alphas=FIG2_ALPHAS)
    assert [p.name for p in paths] == list(fig2.OUTPUTS)  # the files checked before the work
    return paths


@pytest.fixture(scope="module")
def fig2_rows(fig2_paths):
    return keyed(fig2_paths[1], fig2.COLUMNS)


def test_csv_headers_say_what_each_column_holds():
    for columns in (fig1.COLUMNS, fig2.COLUMNS):
        assert len(set(columns.values())) == len(columns)
        for key, header in columns.items():
            assert "," not in header and len(header) > len(key)
            if key.endswith("_se"):
                assert header.endswith("standard error")


def test_fig2_bot_mons_coincide(fig2_rows):
    for r in (r for r in fig2_rows if r["problem"] == "BOT"):
        assert float(r["full"]) == pytest.approx(float(r["diag"]), rel=1e-10)
        assert float(r["full"]) == pytest.approx(float(r["orig"]), rel=1e-10)


def test_fig2_has_every_problem_and_sane_values(fig2_rows):
    assert {r["problem"] for r in fig2_rows} == {"BOT", "GMTI", "RDCOS"}
    for r in fig2_rows:
        for k in ("full", "diag", "orig", "orig_alt", "full_tt2", "full_ut"):
            assert 0 <= float(r[k]) <= 1


def test_fig2_mon_grows_with_alpha(fig2_rows):
    for name in ("BOT", "GMTI", "RDCOS"):
        lo, hi = [float(r["full"]) for r in fig2_rows if r["problem"] == name]
        assert hi > lo


# --------------------------------------------------------------------------- as a journal prints them
def test_fig1_grid_has_20_points_per_decade_around_the_peak():
    """The deg curve of the committed run (docs/data/fig1.csv) rises to a local peak inside
    [1e-2, 1], where the grid has at least 20 points per decade; the α = 0.17 of Sec. II-B is
    on it."""
    rows = keyed(ROOT / "docs" / "data" / "fig1.csv", fig1.COLUMNS)
    alphas = np.array([float(r["alpha"]) for r in rows])
    np.testing.assert_allclose(alphas, fig1.ALPHAS, rtol=1e-12)
    window = (alphas >= 1e-2) & (alphas <= 1)
    deg = np.array([float(r["liu_deg"]) for r in rows])[window]
    assert 0 < int(np.argmax(deg)) < deg.size - 1  # a peak, not the window's edge
    near = fig1.ALPHAS[(fig1.ALPHAS >= 1e-2) & (fig1.ALPHAS <= 1)]
    assert np.diff(np.log10(near)).max() <= 1 / 20
    assert 0.17 in fig1.ALPHAS


def test_the_bearings_are_declared_angles():
    """Figure 1's bearing, and in Figure 2 exactly the outputs that are atan2 bearings."""
    import sympy as sp

    assert fig1.MODEL.angle_outputs == frozenset({1}) and isinstance(fig1.MODEL.outputs[1], sp.atan2)
    for name, (factory, _) in fig2.PROBLEMS.items():
        model = factory().model
        bearings = [i for i, g in enumerate(model.outputs) if isinstance(g, sp.atan2)]
        assert fig2.ANGLES[name] == bearings
        assert sorted(with_angles(model, fig2.ANGLES[name]).angle_outputs) == bearings


@pytest.mark.parametrize("module, paths", [(fig1, "fig1_paths"), (fig2, "fig2_paths")])
def test_the_caption_is_in_the_png_not_in_a_title(module, paths, request):
    from PIL import Image  # matplotlib's own dependency

    png = request.getfixturevalue(paths)[0]
    with Image.open(png) as im:
        text = dict(im.text)
    assert text["Description"] == module.caption(SAMPLES, 0)
    assert f"{SAMPLES:,} samples" in text["Description"] and "declared" in text["Description"]
    assert text["Title"].startswith(f"Figure {module.__name__[-1]}")


def drawn(module, alphas):
    """The figure of ``module`` from a small run, drawn (so that legends have their extents)."""
    plt = pyplot()
    c = module.curves(alphas, samples=SAMPLES, progress=False)
    with figure_style():  # as run() draws it
        fig = module._plot(plt, c)
        fig.canvas.draw()
    return plt, fig


def is_grey(color) -> bool:
    from matplotlib.colors import to_rgb

    r, g, b = to_rgb(color)
    return r == g == b


@pytest.mark.parametrize("module, alphas", [(fig1, FIG1_ALPHAS), (fig2, np.array([0.1, 1.0, 10.0]))])
def test_okabe_ito_colours_and_never_colour_alone(module, alphas):
    """Every curve is Okabe–Ito or grey, and two curves of different colours differ also by
    line style, marker or width: the distinction survives a colour-vision deficiency."""
    from matplotlib.colors import to_hex

    plt, fig = drawn(module, alphas)
    palette = {c.lower() for c in OKABE_ITO.values()}
    try:
        for ax in fig.axes:
            curves = [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 2]  # not the α = 0.17 marker
            assert curves
            for ln in curves:
                assert to_hex(ln.get_color()) in palette or is_grey(ln.get_color())
            looks = {}
            for ln in curves:
                looks.setdefault(to_hex(ln.get_color()), set()).add((ln.get_linestyle(), ln.get_marker(),
                                                                     ln.get_linewidth()))
            colours = list(looks)
            for i, a in enumerate(colours):
                for b in colours[i + 1:]:
                    assert not looks[a] & looks[b], (module.__name__, a, b)
            assert fig.get_suptitle() == "" and ax.get_title() in ("", "BOT (45)", "GMTI (46)", "RDCOS (47)")
    finally:
        plt.close(fig)


def test_fig1_legend_is_below_the_axes():
    plt, fig = drawn(fig1, FIG1_ALPHAS)
    try:
        (leg,) = fig.legends
        e = leg.get_window_extent()
        assert e.y1 <= min(ax.get_window_extent().y0 for ax in fig.axes)
        assert 0 <= e.x0 and e.x1 <= fig.bbox.x1 and e.y0 >= 0
        assert not [a for ax in fig.axes for a in ax.get_children() if type(a).__name__ == "Legend"]
    finally:
        plt.close(fig)


def test_fig2_legend_is_below_the_axes():
    plt, fig = drawn(fig2, FIG2_ALPHAS)
    try:
        (leg,) = fig.legends
        e = leg.get_window_extent()
        assert e.y1 <= min(ax.get_window_extent().y0 for ax in fig.axes)
        assert 0 <= e.x0 and e.x1 <= fig.bbox.x1 and e.y0 >= 0
    finally:
        plt.close(fig)
