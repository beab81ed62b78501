"""The documentation's snippets show their imports (issue 25).

``sphinx-build -b doctest`` runs the ```{doctest} blocks of each page in order, in one
namespace, as a reader runs them when copying them one after another. Nothing is set up out
of sight: ``docs/conf.py``'s ``doctest_global_setup`` binds none of the names the snippets
use, and the first snippet of each page imports every one of ``np``, ``sp`` and ``sm`` that
the page uses. (That the snippets pass is the doctest build's job; this test keeps the rule.)

The plain ```python blocks of every page under docs/ (issue 47, item 16) run here, page by
page: the blocks of one page in order, in one namespace, in a fresh interpreter whose working
directory is an empty temporary one, with warnings as errors. So a fragment that uses a name
no block of its page defines fails with its NameError, at the page's own line number.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import ROOT, checkout_environment

DOCS = ROOT / "docs"
#: The conventional names of the snippets and the module each stands for.
NAMES = {"np": "numpy", "sp": "sympy", "sm": "symmon"}


def snippets(text: str) -> list[list[str]]:
    """The code lines (after ``>>>`` or ``...``) of each ```{doctest} block of a page."""
    out = []
    for body in re.findall(r"^```\{doctest\}\n(.*?)^```", text, re.S | re.M):
        out.append([m.group(1) for m in re.finditer(r"^(?:>>>|\.\.\.) ?(.*)$", body, re.M)])
    return out


PAGES = sorted(p for p in DOCS.rglob("*.md") if snippets(p.read_text(encoding="utf-8")))


def imported(line: str) -> set[str]:
    """The names of :data:`NAMES` that an ``import a as b, c as d`` line binds."""
    m = re.fullmatch(r"import (.*?)\s*(#.*)?", line)
    if not m:
        return set()
    pairs = (re.fullmatch(r"(\w+) as (\w+)", part.strip()) for part in m.group(1).split(","))
    return {p.group(2) for p in pairs if p and NAMES.get(p.group(2)) == p.group(1)}


def test_the_guide_has_snippets():
    assert {p.stem for p in PAGES} >= {"getting-started", "models", "transforms", "nonlinearity",
                                       "units", "estimation", "mmse"}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(DOCS)))
def test_first_snippet_imports_what_the_page_uses(page):
    blocks = snippets(page.read_text(encoding="utf-8"))
    code = "\n".join(line for block in blocks for line in block)
    used = {name for name in NAMES if re.search(rf"\b{name}\.", code)}
    bound = set().union(*(imported(line) for line in blocks[0]))
    assert used <= bound, f"{page.relative_to(ROOT)}: its first snippet does not import {sorted(used - bound)}"


def test_doctest_setup_binds_none_of_the_names():
    conf = (DOCS / "conf.py").read_text(encoding="utf-8")
    m = re.search(r'^doctest_global_setup = f?"""(.*?)"""', conf, re.S | re.M)
    assert m, "doctest_global_setup not found in docs/conf.py"
    for name, module in NAMES.items():
        assert not re.search(rf"\b(import {module}\b|{name}\s*=)", m.group(1)), (name, m.group(1))
    assert not re.search(r"\bROOT\s*=", m.group(1))          # the pages read files by relative paths


def test_imported_reads_an_import_line():
    assert imported("import numpy as np, sympy as sp, symmon as sm") == {"np", "sp", "sm"}
    assert imported("import symmon as sm   # the package") == {"sm"}
    assert imported("import numpy") == set() and imported("x = np.eye(2)") == set()


def test_the_docs_build_shows_symmons_warnings_only():
    """Issue 38, item 16: the docs build's log was full of symmon's INFO lines (``compiled C
    ready in ...``, one per C build of the snippets and the gallery): conf.py sets symmon's
    logger to WARNING, which this runs as conf.py does, after ``import symmon``."""
    import logging

    conf = (DOCS / "conf.py").read_text(encoding="utf-8")
    line = 'logging.getLogger("symmon").setLevel(logging.WARNING)'
    assert line in conf and conf.index(line) > conf.index("import symmon")
    before = logging.getLogger("symmon").level
    try:
        exec(line, {"logging": logging})
        assert not logging.getLogger("symmon.compile.ccache").isEnabledFor(logging.INFO)
    finally:
        logging.getLogger("symmon").setLevel(before)


# --------------------------------------------------------------------------- ```python blocks
#: The info strings of a fence whose block is Python to run (MyST's directives included).
PYTHON_FENCES = re.compile(r"(python3?|py|\{code-block\}\s+python3?|\{code\}\s+python3?)")
#: Generous wall-clock bound per page, so that a hang fails (not a timing test).
HANG_TIMEOUT_S = 600
# The runner: each block compiled with the page's name and its own line numbers, all the
# blocks of the page in one namespace, in order.
RUNNER = """
import json, pathlib, sys
page, blocks = sys.argv[1], json.loads(pathlib.Path(sys.argv[2]).read_text(encoding="utf-8"))
namespace = {"__name__": "__main__"}
for line, code in blocks:
    exec(compile("\\n" * (line - 1) + code, page, "exec"), namespace)
"""


def python_blocks(text: str) -> list[tuple[int, str]]:
    """(first code line, 1-based; code) of each fenced Python block of a Markdown page.

    A fence is three or more backticks or tildes, closed by a line of the same character at
    least as long (CommonMark); blocks inside another fence (a ````` ````markdown ````` example)
    are not code to run.
    """
    out, fence, start, body, is_python = [], None, 0, [], False
    for number, line in enumerate(text.splitlines(), start=1):
        if fence is None:
            m = re.fullmatch(r"\s{0,3}(`{3,}|~{3,})\s*(.*?)\s*", line)
            if m:
                fence, start, body = m.group(1), number + 1, []
                is_python = bool(PYTHON_FENCES.fullmatch(m.group(2)))
        elif re.fullmatch(rf"\s{{0,3}}{fence[0]}{{{len(fence)},}}\s*", line):
            if is_python:
                out.append((start, "\n".join(body) + "\n"))
            fence = None
        else:
            body.append(line)
    assert fence is None, f"the fence opened at line {start - 1} is not closed"
    return out


def run_blocks(page: Path, blocks: list[tuple[int, str]], cwd: Path) -> subprocess.CompletedProcess:
    """Run the blocks of ``page`` in one fresh interpreter, from ``cwd``, warnings as errors."""
    import json

    listing = cwd.parent / f"{cwd.name}-blocks.json"
    listing.write_text(json.dumps(blocks), encoding="utf-8")
    return subprocess.run([sys.executable, "-W", "error", "-c", RUNNER, str(page), str(listing)],
                          cwd=cwd, env=checkout_environment(), capture_output=True, text=True,
                          timeout=HANG_TIMEOUT_S, check=False)


CODE_PAGES = sorted(p for p in DOCS.rglob("*.md")
                    if "_build" not in p.parts and python_blocks(p.read_text(encoding="utf-8")))


def test_every_python_block_is_found():
    text = "a\n```python\nx = 1\n```\n~~~py\ny = 2\n~~~\n````markdown\n```python\nz\n```\n````\n" \
           "```text\nw\n```\n```{code-block} python\nv = 3\n```\n"
    assert python_blocks(text) == [(3, "x = 1\n"), (6, "y = 2\n"), (17, "v = 3\n")]
    assert CODE_PAGES


def test_a_fragment_fails(tmp_path):
    """The runner reports a block that uses a name no earlier block of its page defines,
    with the page's line number, and shares the namespace of a page's blocks."""
    page = tmp_path / "page.md"
    page.write_text("intro\n```python\nx = 1\n```\ntext\n```python\nprint(x + 1)\nprint(y)\n```\n",
                    encoding="utf-8")
    (tmp_path / "cwd").mkdir()
    proc = run_blocks(page, python_blocks(page.read_text(encoding="utf-8")), tmp_path / "cwd")
    assert proc.returncode != 0 and proc.stdout == "2\n"
    assert "NameError: name 'y' is not defined" in proc.stderr and f'"{page}", line 8' in proc.stderr


@pytest.mark.parametrize("page", CODE_PAGES, ids=lambda p: str(p.relative_to(DOCS)))
def test_python_blocks_of_a_page_run(page, tmp_path):
    """Issue 47, item 16: every ```python block of docs/ runs as written."""
    run = tmp_path / "cwd"
    run.mkdir()
    proc = run_blocks(page, python_blocks(page.read_text(encoding="utf-8")), run)
    if proc.returncode != 0:
        pytest.fail(f"{page.relative_to(ROOT)}: a Python block fails:\n{proc.stderr[-3000:]}", pytrace=False)
