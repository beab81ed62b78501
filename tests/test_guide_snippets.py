"""The documentation's snippets show their imports (issue 25).

``sphinx-build -b doctest`` runs the ```{doctest} blocks of each page in order, in one
namespace, as a reader runs them when copying them one after another. Nothing is set up out
of sight: ``docs/conf.py``'s ``doctest_global_setup`` binds none of the names the snippets
use, and the first snippet of each page imports every one of ``np``, ``sp`` and ``sm`` that
the page uses. (That the snippets pass is the doctest build's job; this test keeps the rule.)
"""

from __future__ import annotations

import re

import pytest

from helpers import ROOT

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
