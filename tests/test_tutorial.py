"""The tutorial notebook (examples/tutorial.py, jupytext percent format) runs end to end.

The script checks its own results with ``assert``; here it runs as a subprocess with
warnings as errors, and its cell structure is checked so that jupytext reads it as a
notebook.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

from helpers import EXAMPLES

TUTORIAL = EXAMPLES / "tutorial.py"
#: Generous wall-clock bound so that a hang fails instead of blocking CI (not a timing test).
HANG_TIMEOUT_S = 600


def cells() -> list[tuple[str, list[str]]]:
    """(kind, lines) per cell: kind is "code" or "markdown"; the header comment is skipped."""
    out: list[tuple[str, list[str]]] = []
    for line in TUTORIAL.read_text(encoding="utf-8").splitlines():
        m = re.fullmatch(r"# %%( \[markdown\])?", line)
        if m:
            out.append(("markdown" if m.group(1) else "code", []))
        elif out:
            out[-1][1].append(line)
    return out


def test_tutorial_runs_end_to_end(tmp_path):
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.run([sys.executable, "-W", "error", str(TUTORIAL)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=HANG_TIMEOUT_S, check=False)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert proc.stdout.rstrip().endswith("tutorial: all checks passed")
    assert list(tmp_path.iterdir()) == []          # it cleans up after itself


def test_tutorial_is_a_percent_format_notebook():
    text = TUTORIAL.read_text(encoding="utf-8")
    assert text.startswith("# ---\n# jupyter:\n#   jupytext:\n")
    assert "format_name: percent" in text
    kinds = [k for k, _ in cells()]
    assert kinds.count("markdown") >= 8 and kinds.count("code") >= 8
    for kind, lines in cells():
        if kind == "markdown":                    # markdown cells are comment lines only
            assert all(ln.startswith("#") or not ln.strip() for ln in lines), lines


def test_tutorial_checks_instead_of_printing():
    asserts = sum(ln.lstrip().startswith("assert ") for _, lines in cells() for ln in lines)
    assert asserts >= 25
