"""The README's Figure 1 and Figure 2 numbers equal the committed CSVs to the printed digits.

``docs/data/fig1.csv`` and ``docs/data/fig2.csv`` are the outputs of ``symmon reproduce
fig1`` (10⁶ samples) and ``symmon reproduce fig2 --samples 10000000`` (seed 0). The README
quotes values read off them; each quoted value is parsed from the README text and compared
with the CSV, rounded to as many decimals as the README prints. A number edited by hand, or a
CSV regenerated with different results, fails here.
"""

from __future__ import annotations

import csv
import re

import numpy as np
import pytest

from symmon.reproduce import fig1, fig2

from helpers import ROOT

README = ROOT / "README.md"
DATA = ROOT / "docs" / "data"
#: A decimal number as the README prints it.
NUM = r"(\d+\.\d+)"
#: The range separator of the README ("a … b").
RANGE = NUM + r" … " + NUM


def readme() -> str:
    # Line breaks inside a paragraph do not matter to the sentences parsed here.
    return re.sub(r"\s+", " ", README.read_text(encoding="utf-8"))


def rows(name: str) -> list[dict[str, str]]:
    """The rows of a committed CSV, by the short keys of its module's COLUMNS."""
    columns = {"fig1.csv": fig1.COLUMNS, "fig2.csv": fig2.COLUMNS}[name]
    by_header = {v: k for k, v in columns.items()}
    with open(DATA / name, newline="", encoding="utf-8") as fh:
        return [{by_header[h]: v for h, v in r.items()} for r in csv.DictReader(fh)]


def printed(value: float, text: str) -> str:
    """``value`` rounded to the decimals of ``text``, formatted as the README would."""
    decimals = len(text.split(".")[1])
    return f"{value:.{decimals}f}"


def fig2_range(problem: str, column: str) -> list[float]:
    values = [float(r[column]) for r in rows("fig2.csv") if r["problem"] == problem]
    assert len(values) == 21, (problem, len(values))          # α ∈ [0.1, 10], 21 points
    return [min(values), max(values)]


def test_csvs_cover_the_quoted_grids():
    fig2 = rows("fig2.csv")
    assert {r["problem"] for r in fig2} == {"BOT", "GMTI", "RDCOS"}
    alphas = sorted({float(r["alpha"]) for r in fig2})
    assert alphas[0] == pytest.approx(0.1, rel=1e-12) and alphas[-1] == pytest.approx(10.0, rel=1e-12)
    assert any(float(r["alpha"]) == 0.17 for r in rows("fig1.csv"))


def test_figure1_liu_li_at_alpha_017():
    m = re.search(r"At α = 0\.17 the normalised Liu–Li MoN is " + NUM
                  + r" with the bearing in rad and " + NUM + r" in deg", readme())
    assert m, "the Figure 1 sentence was not found in README.md"
    (row,) = [r for r in rows("fig1.csv") if float(r["alpha"]) == 0.17]
    assert printed(float(row["liu_rad"]), m.group(1)) == m.group(1)
    assert printed(float(row["liu_deg"]), m.group(2)) == m.group(2)


def test_figure1_printed_block_is_what_the_command_prints():
    """The README's block of what ``symmon reproduce fig1`` prints: the headline of the
    committed run (``fig1.headline`` of docs/data/fig1.csv), then the files it wrote."""
    text = README.read_text(encoding="utf-8")
    m = re.search(r"```text\n(Figure 1 \(Sec\. II-B\).*?)```", text, re.S)
    assert m, "the block of what symmon reproduce fig1 prints was not found in README.md"
    data = rows("fig1.csv")
    c = {k: np.array([float(r[k]) for r in data]) for k in fig1.COLUMNS}
    want = fig1.headline(c, 10**6, 0) + ["wrote results/fig1.png", "wrote results/fig1.csv"]
    assert m.group(1).splitlines() == want


def test_figure1_declared_bearing_at_alpha_10():
    m = re.search(r"at α = 10 the unitless MoN is " + NUM, readme())
    assert m, "the Figure 1 sentence on the declared bearing was not found in README.md"
    (row,) = [r for r in rows("fig1.csv") if float(r["alpha"]) == pytest.approx(10.0, rel=1e-12)]
    assert printed(float(row["full"]), m.group(1)) == m.group(1)


@pytest.mark.parametrize("problem", ["BOT", "GMTI", "RDCOS"])
def test_figure2_table_ranges(problem):
    m = re.search(r"\| " + problem + r" \| " + RANGE + r" \|", readme())
    assert m, f"the Figure 2 table row of {problem} was not found in README.md"
    lo, hi = fig2_range(problem, "full")
    assert [printed(lo, m.group(1)), printed(hi, m.group(2))] == [m.group(1), m.group(2)]


def test_figure2_gmti_original_mon_in_both_unit_sets():
    m = re.search(RANGE + r" in \[m, rad, m/s\] against " + RANGE + r" in \[km, deg, km/h\]", readme())
    assert m, "the GMTI unit-set sentence was not found in README.md"
    quoted = list(m.groups())
    computed = fig2_range("GMTI", "orig") + fig2_range("GMTI", "orig_alt")
    assert [printed(v, q) for v, q in zip(computed, quoted)] == quoted


def test_printed_rounds_to_the_quoted_decimals():
    # The comparison helper itself: 0.0947 prints as 0.095 and 0.797 as 0.80, not 0.797.
    assert printed(0.09472, "0.095") == "0.095"
    assert printed(0.79716, "0.80") == "0.80"
    assert printed(0.1509, "0.154") != "0.154"
