"""Sphinx configuration of the symmon documentation.

Build: ``pip install ".[docs]"`` then ``sphinx-build -W --keep-going -b html docs docs/_build/html``;
the guide's snippets run with ``-b doctest``. Why Sphinx: see docs/index.md.
"""

from __future__ import annotations

import doctest
import inspect
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))            # document the checkout, not an installed copy
os.environ.setdefault("MPLBACKEND", "Agg")

import symmon  # noqa: E402

project = "symmon"
author = "symmon developers"
copyright = "symmon developers"
release = version = symmon.__version__

extensions = [
    "myst_parser",
    "numpydoc",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.doctest",
    "sphinx.ext.mathjax",
    "sphinxarg.ext",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "data", "sg_execution_times.rst"]   # the gallery's timing page
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

html_theme = "furo"
html_title = f"symmon {release}"

# API reference: one page per public name of symmon.__all__ (docs/reference/api.rst, written below).
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "undoc-members": True, "show-inheritance": True}
autodoc_typehints = "none"               # numpydoc's Parameters sections carry the types
numpydoc_show_class_members = False      # autosummary lists members; avoid duplicate stubs
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# The guide's ```{doctest} blocks run with `sphinx-build -b doctest docs docs/_build/doctest`.
doctest_global_setup = f"""
from pathlib import Path
ROOT = Path({str(ROOT)!r})  # the checkout: examples/ and docs/ files are read from here
import numpy as np
import sympy as sp
import symmon as sm
np.set_printoptions(precision=4, suppress=True)
"""
# The docstrings' own examples run under pytest --doctest-modules; here only the guide's.
doctest_test_doctest_blocks = ""
doctest_default_flags = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE

# Gallery: examples/gallery/*.py run at build time on small samples (a few seconds each).
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples" / "gallery"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "within_subsection_order": "FileNameSortKey",
}


# --------------------------------------------------------------------------------------
# The API reference page lists symmon.__all__, so that a new public name joins it by itself.
# --------------------------------------------------------------------------------------

def _api_page() -> str:


    kinds: dict[str, list[str]] = {"Classes": [], "Functions": [], "Modules": []}
    for name in symmon.__all__:
        obj = getattr(symmon, name)
        kind = "Modules" if inspect.ismodule(obj) else "Classes" if inspect.isclass(obj) else "Functions"
        kinds[kind].append(name)
    intro = {
        "Classes": "The model, the Gaussian, the transforms and the result types.",
        "Functions": "Propagation, measures of nonlinearity, fusion, model files and C export.",
        "Modules": "Each module's page documents the names of its ``__all__``.",
    }
    lines = [
        ".. This file is written by docs/conf.py from symmon.__all__; do not edit.",
        "",
        "API reference",
        "=============",
        "",
        "Every public name of the package, as ``import symmon as sm`` exposes it "
        "(``symmon.__all__``). The pages are generated from the numpydoc docstrings; "
        "equation numbers refer to the :doc:`papers <references>`.",
        "",
        ".. currentmodule:: symmon",
    ]
    for kind, names in kinds.items():
        lines += ["", kind, "-" * len(kind), "", intro[kind], "", ".. autosummary::",
                  "   :toctree: generated", "   :nosignatures:", ""]
        lines += [f"   {n}" for n in sorted(names, key=str.lower)]
    return "\n".join(lines) + "\n"


_api = Path(__file__).resolve().parent / "reference" / "api.rst"
if not _api.exists() or _api.read_text(encoding="utf-8") != _api_page():
    _api.write_text(_api_page(), encoding="utf-8")   # rewrite only on change: keeps rebuilds incremental


def _skip_reexports(app, what, name, obj, skip, options):
    """In a module's page, skip what the package exports at the top: it has its own page.

    ``symmon.filters.linear.KalmanFilter`` is ``symmon.KalmanFilter``; documenting it twice gives
    Sphinx two descriptions of one object.
    """
    if what == "module" and any(obj is getattr(symmon, n) for n in _TOP_LEVEL):
        return True
    return None


_TOP_LEVEL = [n for n in symmon.__all__ if not inspect.ismodule(getattr(symmon, n))]


def setup(app):
    app.connect("autodoc-skip-member", _skip_reexports)
