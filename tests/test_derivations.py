"""The derivation scripts in ``derivations/`` and their runner ``symmon.derive``.

Every script is run as a program (``sys.executable script``) and must exit 0; the
runner is tested on a fast subset, on an overriding directory, and with a deliberately
wrong claim so that the checks are seen to be able to fail.
"""

from __future__ import annotations

import ast
import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from symmon import derive
from symmon.errors import SymmonError

from helpers import DERIVATIONS

SCRIPTS = sorted(p for p in DERIVATIONS.glob("*.py") if not p.stem.startswith("_"))
SCRIPT_TIMEOUT_S = 300          # generous: a loaded CI machine; each script takes seconds
FAST = ["mmse_lemma2", "remarks"]


def test_scripts_found() -> None:
    assert len(SCRIPTS) >= 15
    assert derive.available() == [p.stem for p in SCRIPTS]


@pytest.mark.parametrize("script", SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_script_passes(script: Path) -> None:
    proc = subprocess.run([sys.executable, str(script)], cwd=DERIVATIONS, capture_output=True,
                          text=True, timeout=SCRIPT_TIMEOUT_S)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "[PASSED]" in proc.stdout


@pytest.mark.parametrize("script", SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_script_declares_its_interface(script: Path) -> None:
    tree = ast.parse(script.read_text())
    assigned = {t.id: node.value for node in tree.body if isinstance(node, ast.Assign)
                for t in node.targets if isinstance(t, ast.Name)}
    functions = {node.name for node in tree.body if isinstance(node, ast.FunctionDef)}
    assert {"NAME", "TITLE", "SOURCE"} <= set(assigned)
    assert ast.literal_eval(assigned["NAME"]) == script.stem
    assert "check" in functions
    assert ast.get_docstring(tree)


def test_unknown_name_lists_available() -> None:
    with pytest.raises(ValueError, match="unknown derivation") as info:
        derive.run(["no_such_derivation"])
    for name in derive.available():
        assert name in str(info.value)


def test_report_contains_titles_and_latex() -> None:
    results = derive.run(FAST)
    assert [r.name for r in results] == FAST
    assert all(r.passed for r in results)
    report = derive.report_markdown(results)
    assert f"{len(FAST)} of {len(FAST)} checks passed" in report
    for r in results:
        assert r.title in report
        assert r.latex
        for tex in r.latex:
            assert f"$$\n{tex}\n$$" in report


def _load_weights():
    spec = importlib.util.spec_from_file_location("derivation_weights_under_test", DERIVATIONS / "weights.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_wrong_claim_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    """The paper's printed S_v in (37)-(38) must make the check fail; S_y must pass."""
    monkeypatch.syspath_prepend(str(DERIVATIONS))
    weights = _load_weights()
    assert weights.check_relation("S_y").passed
    wrong = weights.check_relation("S_v")
    assert not wrong.passed
    assert any(line.startswith("FAIL") for line in wrong.details)
    assert not weights.check_35a("S_v")


def test_directory_override_and_failures(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    shutil.copy(DERIVATIONS / "_common.py", tmp_path / "_common.py")
    (tmp_path / "false_claim.py").write_text(
        '"""A deliberately wrong claim."""\n'
        "import sympy as sp\n"
        "from _common import Checker, is_zero, main\n"
        'NAME = "false_claim"\nTITLE = "x + 1 = x"\nSOURCE = "nowhere"\n'
        "def check():\n"
        "    ck = Checker(NAME, TITLE, SOURCE)\n"
        '    x = sp.Symbol("x")\n'
        '    ck.claim("x + 1 - x is zero", is_zero(x + 1 - x))\n'
        "    return ck.result()\n"
        'if __name__ == "__main__":\n    main(check)\n'
    )
    (tmp_path / "crashes.py").write_text(
        '"""Raises."""\nNAME = "crashes"\nTITLE = "t"\nSOURCE = "s"\n'
        "def check():\n    raise RuntimeError('boom')\n"
    )
    monkeypatch.setenv(derive.ENV_VAR, str(tmp_path))
    assert derive.available() == ["crashes", "false_claim"]
    crashed, false = derive.run()
    assert not false.passed and "FAIL: x + 1 - x is zero" in false.details
    assert not crashed.passed and any("boom" in d for d in crashed.details)
    assert "0 of 2 checks passed" in derive.report_markdown([crashed, false])
    proc = subprocess.run([sys.executable, str(tmp_path / "false_claim.py")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=SCRIPT_TIMEOUT_S)
    assert proc.returncode == 1 and "[FAILED]" in proc.stdout


def test_no_scripts_found_is_a_clear_error(tmp_path, monkeypatch):
    from symmon import derive
    from symmon.errors import SymmonError

    monkeypatch.setenv(derive.ENV_VAR, str(tmp_path))
    with pytest.raises(SymmonError, match="no derivation scripts found"):
        derive.run(None)


def test_list_without_scripts_is_an_error_naming_the_places(tmp_path, monkeypatch, capsys):
    """Outside a checkout `symmon derive --list` says where it looked and exits 1."""
    from symmon.cli import parser as cli

    monkeypatch.setenv("SYMMON_DERIVATIONS", str(tmp_path))
    assert cli.main(["derive", "--list"]) == 1
    assert f"no derivation scripts found in $SYMMON_DERIVATIONS = {tmp_path}" in capsys.readouterr().err
    monkeypatch.delenv("SYMMON_DERIVATIONS")
    monkeypatch.setattr(derive, "available", lambda: [])
    with pytest.raises(SymmonError, match=r"beside the package.*the current directory"):
        derive.require_available()
