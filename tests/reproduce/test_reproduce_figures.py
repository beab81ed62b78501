"""The reproduction commands of Figures 1 and 2 (small samples; the defaults are 10^6)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from symmon.reproduce import fig1, fig2

SAMPLES = 20_000
#: Monte Carlo bound in standard errors.
N_SE = 5


@pytest.fixture(scope="module")
def fig1_rows(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig1")
    paths = fig1.run(out, samples=SAMPLES, progress=False, alphas=np.array([1e-3, 0.17, 10.0]))
    assert [p.name for p in paths] == ["fig1.png", "fig1.csv"]
    assert paths[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return keyed(paths[1], fig1.COLUMNS)


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
def fig2_rows(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig2")
    paths = fig2.run(out, samples=SAMPLES, progress=False, alphas=np.array([0.1, 10.0]))
    return keyed(paths[1], fig2.COLUMNS)


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
