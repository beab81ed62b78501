"""Sphinx configuration of the symmon documentation.

Build: ``pip install ".[docs]"`` then ``sphinx-build -W --keep-going -b html docs docs/_build/html``;
the guide's snippets run with ``-b doctest``. Why Sphinx: see docs/index.md.
"""

from __future__ import annotations

import doctest
import inspect
import logging
import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))            # document the checkout, not an installed copy
os.environ.setdefault("MPLBACKEND", "Agg")

import symmon  # noqa: E402

# symmon logs each C build at INFO ("compiled C ready in ..."); the snippets and the gallery
# build many, which filled the build's log: the docs show symmon's warnings only.
logging.getLogger("symmon").setLevel(logging.WARNING)

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
    "sphinx-mathjax-offline",  # MathJax served from the built site: formulas render offline
    "sphinx_copybutton",
    "sphinxarg.ext",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "data", "sg_execution_times.rst", "auto_examples/sg_execution_times.rst"]  # timing pages
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

html_theme = "furo"
html_static_path = ["_static"]
html_css_files = ["wrap.css"]  # long lines of code wrap instead of being cut

# The copy button leaves the prompts out: a copied snippet runs as it is.
copybutton_prompt_text = r">>> |\.\.\. |\$ "
copybutton_prompt_is_regexp = True
copybutton_only_copy_prompt_lines = True
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
# Nothing is imported or set behind the reader's back: the first snippet of each page shows
# the page's imports, and the snippets of a page run in order in one namespace, as a reader
# runs them when copying them one after another. They run from the checkout, so that the
# paths of model files read as on the command line (examples/polar.toml).
doctest_global_setup = f"""
import os as _os
_cwd = _os.getcwd()
_os.chdir({str(ROOT)!r})
"""
doctest_global_cleanup = "_os.chdir(_cwd)"
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
    # No execution-times page: it is the one page that loads scripts from a CDN (DataTables).
    "write_computation_times": False,
}


# --------------------------------------------------------------------------------------
# The API reference page lists symmon.__all__, so that a new public name joins it by itself.
# --------------------------------------------------------------------------------------
#
# Classes and functions get one autosummary page each (reference/generated/symmon.NAME).
# The modules of sm.__all__ are public under names of the public face whose homes lie deeper
# in the tree (sm.kalman is symmon.filters.gaussian.linear, sm.weights symmon.measures.weights):
# ``import symmon.kalman`` does not work, so each module is documented under its home's
# importable name, on a page that conf.py writes (reference/modules/<home>.rst) with the
# public name in its title.  Each object is described on one page only: a name re-exported
# at the top (sm.KalmanFilter) has its own page, and a name that two module pages export
# (KalmanResult: sm.kalman and sm.filters) is described on the page of its home module, or
# else on the first page that exports it; the other pages list it in their tables and link
# to it.

_REFERENCE = Path(__file__).resolve().parent / "reference"
_TOP_LEVEL = [n for n in symmon.__all__ if not inspect.ismodule(getattr(symmon, n))]
_MODULES = {n: getattr(symmon, n) for n in sorted(symmon.__all__, key=str.lower)
            if inspect.ismodule(getattr(symmon, n))}


def _write(path: Path, text: str) -> None:
    """Write only on change: keeps rebuilds incremental."""
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def _summary(obj) -> str:
    """The first sentence of a docstring, on one line."""
    first = inspect.cleandoc(obj.__doc__ or "").split("\n\n")[0].replace("\n", " ")
    cut = first.find(".  ")
    return first if cut < 0 else first[:cut + 1]


def _absolute(text: str, module: str) -> str:
    """Relative cross-references of a module's docstring (:mod:`.nlt`) made absolute, for use
    outside the module."""
    return re.sub(r":(\w+):`\.", rf":\1:`~{module}.", text)


def _exported(mod) -> list[tuple[str, object]]:
    """The names of a module's ``__all__`` and their objects, submodules left out."""
    names = getattr(mod, "__all__", None) or [n for n in vars(mod) if not n.startswith("_")]
    return [(n, getattr(mod, n)) for n in names if not inspect.ismodule(getattr(mod, n))]


def _top_level_name(obj) -> str | None:
    return next((n for n in _TOP_LEVEL if getattr(symmon, n) is obj), None)


def _owner(name: str, obj) -> str:
    """The home (``__name__``) of the module page that describes ``obj``."""
    homes = {mod.__name__ for mod in _MODULES.values()}
    home = getattr(obj, "__module__", None)
    if (inspect.isclass(obj) or inspect.isroutine(obj)) and home in homes:
        return home
    return next(mod.__name__ for mod in _MODULES.values()
                if any(n == name and o is obj for n, o in _exported(mod)))


def _module_page(public: str, mod) -> str:
    """The page of ``sm.<public>``: the module's docstring, tables of all its classes,
    exceptions and functions (each linked to its description), and the descriptions of the
    names this page owns.

    The members are listed one directive each: an explicit ``:members:`` list of
    ``automodule`` would be replaced by ``autodoc_default_options["members"]``.
    """
    title = f"sm.{public} ({mod.__name__})"
    own, tables = [], {"Classes": [], "Exceptions": [], "Functions": []}
    for name, obj in _exported(mod):
        top = _top_level_name(obj)
        where = "symmon" if top else _owner(name, obj)
        if inspect.isclass(obj):
            kind = "Exceptions" if issubclass(obj, BaseException) else "Classes"
        elif inspect.isroutine(obj):
            kind = "Functions"
        else:
            kind = None                  # data: described below, not tabulated
        if not top and where == mod.__name__:
            directive = {"Classes": "autoclass", "Exceptions": "autoexception", "Functions": "autofunction"}
            own.append(f".. {directive.get(kind, 'autodata')}:: {mod.__name__}.{name}")
        if kind and where == mod.__name__:
            tables[kind].append(name)
        elif kind:                       # autosummary wants the names below the current module relative
            where = where.removeprefix(f"{mod.__name__}.")
            tables[kind].append(f"~{where}.{top or name}")
    lines = [
        ".. This file is written by docs/conf.py from symmon.__all__; do not edit.",
        "",
        title,
        "=" * len(title),
        "",
        f"``sm.{public}`` is the module :mod:`{mod.__name__}`.",
        "",
        f".. automodule:: {mod.__name__}",
        "   :no-members:",
    ]
    for kind, entries in tables.items():
        if entries:
            lines += ["", f"   .. rubric:: {kind}", "", "   .. autosummary::", ""]
            lines += [f"      {e}" for e in entries]
    for directive in own:
        lines += ["", directive]
    return "\n".join(lines) + "\n"


def _api_page() -> str:
    kinds: dict[str, list[str]] = {"Classes": [], "Functions": []}
    for name in _TOP_LEVEL:
        kinds["Classes" if inspect.isclass(getattr(symmon, name)) else "Functions"].append(name)
    intro = {
        "Classes": "The model, the Gaussian, the transforms and the result types.",
        "Functions": "Propagation, measures of nonlinearity, fusion, model files and C export.",
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
    lines += ["", "Modules", "-------", "",
              "Each module's page documents the names of its ``__all__``. A module's public name "
              "(``sm.kalman``) is that of the public face; the module itself lives in a "
              "subpackage (:doc:`../architecture`), under the name that ``import`` takes.",
              "", ".. list-table::", "   :header-rows: 1", "   :widths: 15 25 60", "",
              "   * - name", "     - module", "     - what it holds"]
    for public, mod in _MODULES.items():
        lines += [f"   * - :doc:`sm.{public} <modules/{mod.__name__}>`", f"     - :mod:`{mod.__name__}`",
                  f"     - {_absolute(_summary(mod), mod.__name__)}"]
    lines += ["", ".. toctree::", "   :hidden:", ""]
    lines += [f"   modules/{mod.__name__}" for mod in _MODULES.values()]
    return "\n".join(lines) + "\n"


_write(_REFERENCE / "api.rst", _api_page())
_pages = {f"{mod.__name__}.rst": _module_page(public, mod) for public, mod in _MODULES.items()}
for _name, _text in _pages.items():
    _write(_REFERENCE / "modules" / _name, _text)
# Pages of names that left sm.__all__ would be documents outside every toctree (a warning).
for _old in [*(_REFERENCE / "modules").glob("*.rst"), *(_REFERENCE / "generated").glob("symmon.*.rst")]:
    if _old.parent.name == "modules" and _old.name not in _pages \
            or _old.parent.name == "generated" and _old.stem.split(".")[1] not in _TOP_LEVEL:
        _old.unlink()
