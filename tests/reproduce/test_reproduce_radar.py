"""The reproduction of the lecture's radar example writes its files, and its numbers are the
lecture's (tests/reference/lecture_estimation.json)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

import symmon as sm
from symmon.reproduce import radar

from helpers import REFERENCE_DIR

#: Closed forms in double precision.
CLOSED_FORM_RTOL = 1e-10
#: Monte Carlo checks: a seeded generator and 5 standard errors.
N_SE = 5.0
#: Small but enough for the Monte Carlo check; keeps the test fast.
SAMPLES = 2000
PRINTED_DIGITS = 3
FILES = ["radar_mc.png", "radar_direct_ut.png", "radar_indirect_tt1.png", "radar_estimates.csv"]

REFERENCE = json.loads((REFERENCE_DIR / "lecture_estimation.json").read_text())


def printed(x) -> np.ndarray:
    return np.vectorize(lambda v: float(f"{v:.{PRINTED_DIGITS}g}"))(np.asarray(x, dtype=float))


@pytest.fixture(scope="module")
def outdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("radar") / "out"  # missing: run must create it


@pytest.fixture(scope="module")
def written(outdir) -> list[Path]:
    return radar.run(outdir, samples=SAMPLES, seed=5, progress=False)


@pytest.fixture(scope="module")
def table(written) -> dict[str, sm.Gaussian]:
    path = next(p for p in written if p.suffix == ".csv")
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {r["name"]: sm.Gaussian([float(r["x1"]), float(r["x2"])],
                                   [[float(r["P11"]), float(r["P12"])], [float(r["P12"]), float(r["P22"])]])
            for r in rows}


def test_run_writes_its_files(written, outdir):
    assert [p.name for p in written] == FILES == list(radar.OUTPUTS)
    for p in written:
        assert p.parent == outdir and p.stat().st_size > 0
    for p in written[:3]:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(("name", "section"), [("Nhat1", "direct_ut"), ("Nhat2", "direct_ut"),
                                               ("Xhat0", "indirect_tt1"), ("Xhat1", "indirect_tt1")])
def test_csv_numbers_match_the_lecture(table, name, section):
    ref = REFERENCE[section][name]
    np.testing.assert_array_equal(printed(table[name].mean), ref["mean"])
    np.testing.assert_array_equal(printed(table[name].cov), ref["cov"])


def test_csv_xhat2_matches_the_reproduced_digits(table):
    ref = REFERENCE["indirect_tt1"]["Xhat2"]
    ok_m, ok_c = np.array(ref["reproduced"]["mean"]), np.array(ref["reproduced"]["cov"])
    np.testing.assert_array_equal(printed(table["Xhat2"].mean)[ok_m], np.array(ref["mean"])[ok_m])
    np.testing.assert_array_equal(printed(table["Xhat2"].cov)[ok_c], np.array(ref["cov"])[ok_c])


def test_csv_fused_is_the_fusion_of_the_csv_estimates(table):
    f = sm.fuse(table["Nhat1"], table["Nhat2"])  # the CSV keeps full precision (repr)
    np.testing.assert_allclose(table["fused"].mean, f.mean, rtol=CLOSED_FORM_RTOL)
    np.testing.assert_allclose(table["fused"].cov, f.cov, rtol=CLOSED_FORM_RTOL,
                               atol=CLOSED_FORM_RTOL * np.abs(f.cov).max())


@pytest.mark.parametrize(("name", "phi"), [("MC1", np.pi / 4), ("MC2", 3 * np.pi / 4)])
def test_csv_monte_carlo_mean_is_the_exact_mean(table, name, phi):
    """E[p + r(cos φ, sin φ)] = p + E r · e^{−σ²/2} (cos μ, sin μ) for independent Gaussian r, φ."""
    p = np.array(radar.SENSORS[int(name[-1]) - 1])
    exact = p + 100 * np.sqrt(2) * np.exp(-radar.BEARING_VAR / 2) * np.array([np.cos(phi), np.sin(phi)])
    g = table[name]
    se = np.sqrt(np.diag(g.cov) / SAMPLES)
    assert np.all(np.abs(g.mean - exact) < N_SE * se)


def test_run_is_reproducible_for_a_seed(written, tmp_path):
    again = radar.run(tmp_path, samples=SAMPLES, seed=5, progress=False)
    assert again[-1].read_bytes() == written[-1].read_bytes()


@pytest.mark.parametrize(("kwargs", "match"), [({"samples": 1}, "samples must be"), ({"seed": -1}, "seed must be"),
                                               ({"samples": 2.5}, "samples must be")])
def test_run_rejects_bad_arguments(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        radar.run(tmp_path, progress=False, **kwargs)
