"""Run the derivation scripts of ``derivations/`` and report on them.

Each script in the directory checks one formula of the papers (symbolically with
sympy where it can decide, otherwise against an independent numeric method) and
defines ``NAME``, ``TITLE``, ``SOURCE`` and ``check() -> Result``. This module finds
the scripts, imports them by path (never through a subprocess, never by evaluating
text) and collects their results.

The directory is ``derivations/`` beside the package, or the one named by the
``SYMMON_DERIVATIONS`` environment variable.

Examples
--------
>>> from symmon import derive
>>> "weights" in derive.available()          # doctest: +SKIP
True
>>> results = derive.run(["remarks"])         # doctest: +SKIP
>>> print(derive.report_markdown(results))    # doctest: +SKIP
"""

from __future__ import annotations

import importlib.util
import os
import sys
import traceback
from pathlib import Path
from types import ModuleType
from typing import Any, Sequence

from .errors import SymmonError

__all__ = ["available", "run", "report_markdown", "derivations_dir"]

#: Environment variable that overrides the location of the derivation scripts.
ENV_VAR = "SYMMON_DERIVATIONS"
_COMMON = "_common"


def derivations_dir() -> Path:
    """The directory holding the derivation scripts.

    Returns
    -------
    pathlib.Path
        ``$SYMMON_DERIVATIONS`` if set, else ``derivations/`` next to the package (a
        source checkout or an editable install), else ``./derivations``.
    """
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).expanduser().resolve()
    beside = Path(__file__).resolve().parent.parent / "derivations"
    if beside.is_dir():
        return beside
    # An installed (non-editable) package has no scripts beside it: use a checkout's.
    return Path.cwd() / "derivations"


def available() -> list[str]:
    """Names of the derivation scripts (file stems, sorted; helpers starting with ``_`` excluded).

    Returns
    -------
    list of str
        Empty if the directory does not exist.
    """
    directory = derivations_dir()
    if not directory.is_dir():
        return []
    return sorted(p.stem for p in directory.glob("*.py") if not p.stem.startswith("_"))


def require_available() -> list[str]:
    """Like :func:`available`, but an empty list is an error that says where scripts were looked for.

    Raises
    ------
    SymmonError
        When no derivation script is found.
    """
    known = available()
    if not known:
        here = Path(__file__).resolve().parent.parent / "derivations"
        raise SymmonError(
            f"no derivation scripts found: looked in ${ENV_VAR} (unset), {here} (beside the "
            f"package) and {Path.cwd() / 'derivations'} (the current directory). Run from a "
            f"symmon source checkout or set ${ENV_VAR} to its derivations/ directory"
            if not os.environ.get(ENV_VAR) else
            f"no derivation scripts found in ${ENV_VAR} = {derivations_dir()}"
        )
    return known


def _load_module(unique_name: str, path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(unique_name, path)
    if spec is None or spec.loader is None:  # pragma: no cover - only for unreadable files
        raise SymmonError(f"cannot import derivation file {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[unique_name] = module      # dataclasses look their module up while it executes
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(unique_name, None)
        raise
    return module


def _run_one(name: str, directory: Path, common: ModuleType) -> Any:
    """Import ``name`` with ``_common`` bound to this directory's helper, call ``check()``."""
    previous = sys.modules.get(_COMMON)
    sys.modules[_COMMON] = common
    try:
        try:
            unique = f"symmon_derivation_{name}"
            try:
                result = _load_module(unique, directory / f"{name}.py").check()
            finally:
                sys.modules.pop(unique, None)
        except Exception as exc:  # a crashing script is a failed check, not a crash of the report
            return common.Result(
                name=name, title=f"{name} (crashed)", source=str(directory / f"{name}.py"), passed=False,
                details=[f"ERROR: {type(exc).__name__}: {exc}",
                         *traceback.format_exception_only(type(exc), exc)[-1:]],
                latex=[],
            )
    finally:
        if previous is None:
            sys.modules.pop(_COMMON, None)
        else:
            sys.modules[_COMMON] = previous
    return result


def run(names: Sequence[str] | None = None) -> list[Any]:
    """Run derivation checks and return their results.

    Parameters
    ----------
    names : sequence of str, optional
        Script names as listed by :func:`available`; all of them when omitted.

    Returns
    -------
    list of Result
        One ``Result`` (dataclass of ``derivations/_common.py``: ``name``, ``title``,
        ``source``, ``passed``, ``details``, ``latex``) per name, in the given order. A
        script that raises gives a failed result carrying the error message.

    Raises
    ------
    ValueError
        (a :class:`symmon.SymmonError`) for a name that is not an available script.
    """
    known = require_available()
    if isinstance(names, str):
        names = [names]
    selected = list(known if names is None else names)
    unknown = [n for n in selected if n not in known]
    if unknown:
        listing = ", ".join(known) if known else "(none)"
        raise SymmonError(
            f"unknown derivation name(s) {unknown!r} in {derivations_dir()}; available: {listing}"
        )
    directory = derivations_dir()
    common = _load_module("symmon_derivations_common", directory / f"{_COMMON}.py")
    return [_run_one(name, directory, common) for name in selected]


def report_markdown(results: Sequence[Any]) -> str:
    """A Markdown report: a summary line, then per result its status, source, details
    and LaTeX in ``$$ ... $$`` blocks.

    Parameters
    ----------
    results : sequence of Result-like
        Objects with ``name``, ``title``, ``source``, ``passed``, ``details``, ``latex``.

    Returns
    -------
    str
    """
    passed = sum(bool(r.passed) for r in results)
    lines = ["# symmon derivations", "", f"{passed} of {len(results)} checks passed.", ""]
    for r in results:
        status = "PASS" if r.passed else "FAIL"
        lines += [f"## {status} `{r.name}`: {r.title}", "", f"*Source:* {r.source}", ""]
        lines += [f"- {d}" for d in r.details]
        for tex in r.latex:
            lines += ["", "$$", tex, "$$"]
        lines.append("")
    return "\n".join(lines)
