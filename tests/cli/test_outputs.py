"""Every output option of every subcommand goes through one check before any work (issue 26, item 4).

The parser registers each output option (``output_opt``); ``symmon.cli.commands.check_outputs``
checks them all before the command runs: an output that is an input file, a read-only
file (which the atomic rename would replace), a path in a missing directory, a directory
where a file is wanted or a file where a directory is wanted is exit 1, and nothing runs.
"""

from __future__ import annotations

import argparse

import pytest

from symmon.cli import commands
from symmon.cli import parser as cli

from helpers import ROOT

EXAMPLES = ROOT / "examples"
MODEL = EXAMPLES / "polar.toml"
SCENARIO = EXAMPLES / "rb_close.toml"

#: What each command needs besides the output option, and the file it reads.
BASE = {
    "nonlinearity": ([str(MODEL), "--alpha-sweep", "0.1:1:2"], MODEL),
    "prove-invariance": ([str(MODEL)], MODEL),
    "reproduce": (["fig1"], None),
    "derive": ([], None),
    "codegen": ([str(MODEL)], MODEL),
    "export": ([str(SCENARIO)], SCENARIO),
    "filter": ([str(SCENARIO), "--runs", "2"], SCENARIO),
}


def subparsers() -> dict[str, argparse.ArgumentParser]:
    p = cli._parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def registered() -> list[tuple[str, str, str]]:
    """(command, kind, flag) of every registered output option."""
    return [(name, kind, flag) for name, sp in subparsers().items() for _, kind, flag in sp.get_default("outputs") or ()]


def test_every_output_option_is_registered_and_tested():
    """An option whose value is a path to write is registered, so the check sees it; and
    this file has the arguments of every command with one."""
    for name, sp in subparsers().items():
        writes = {a.option_strings[-1] for a in sp._actions if a.type in (cli._output_path, cli._plot_path)}
        assert writes == {flag for _, _, flag in sp.get_default("outputs") or ()}, name
    assert {name for name, _, _ in registered()} == set(BASE)
    assert len(registered()) == 8


@pytest.fixture
def nothing_runs(monkeypatch):
    """Every command replaced by a recorder: the check must refuse before any of them."""
    ran: list[str] = []
    for attr in dir(commands):
        if attr.startswith("cmd_"):
            monkeypatch.setattr(commands, attr, lambda args, attr=attr: ran.append(attr) or 0)
    return ran


FAULTS = ("the input file", "read-only", "in a missing directory", "of the wrong kind")


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("command, kind, flag", registered(), ids=lambda v: str(v))
def test_a_bad_output_is_refused_before_the_command_runs(capsys, tmp_path, nothing_runs, command, kind, flag, fault):
    argv, source = BASE[command]
    suffix = ".png" if flag == "--plot" else ".md"
    if fault == "the input file":
        if source is None:
            pytest.skip(f"{command} reads no input file")
        target, expect = source, "is the input file" if kind == "file" else "is a file, not a directory"
        if flag == "--plot":  # a .toml figure: refused as a format already, when parsed (exit 2)
            code = cli.main([command, *argv, flag, str(target)])
            assert (code, nothing_runs) == (2, []) and "cannot write a figure as 'toml'" in capsys.readouterr().err
            return
    elif fault == "read-only":
        if kind == "dir":
            pytest.skip("a directory output is checked for being a directory (its files by check_output_set)")
        target = tmp_path / f"locked{suffix}"
        target.write_text("keep me\n")
        target.chmod(0o444)
        expect = "is read-only"
    elif fault == "in a missing directory":
        blocker = tmp_path / "a-file"
        blocker.write_text("x")
        target = (tmp_path / "missing" / f"out{suffix}") if kind == "file" else blocker / "sub"
        expect = "output directory does not exist" if kind == "file" else "is not a directory"
    else:
        if kind == "file":
            target, expect = tmp_path, "is a directory; only regular files are written"
        else:
            target = tmp_path / "plain"
            target.write_text("x")
            expect = "is a file, not a directory"
    before = target.read_bytes() if target.is_file() else None
    code = cli.main([command, *argv, flag, str(target)])
    err = capsys.readouterr().err
    assert (code, nothing_runs) == (1, []), err
    assert expect in err
    assert before is None or target.read_bytes() == before


def test_two_options_naming_one_file_is_a_usage_error(capsys, tmp_path, nothing_runs):
    target = tmp_path / "out.png"
    code = cli.main(["nonlinearity", str(MODEL), "--alpha-sweep", "0.1:1:2", "--csv", str(target), "--plot", str(target)])
    assert (code, nothing_runs) == (2, [])
    assert "--csv and --plot name the same file" in capsys.readouterr().err


def test_derive_out_may_not_name_a_derivation_script(capsys, nothing_runs):
    from symmon import derive

    script = sorted(derive.derivations_dir().glob("*.py"))[0]
    before = script.read_bytes()
    assert cli.main(["derive", "--out", str(script)]) == 1 and nothing_runs == []
    assert "is the input file" in capsys.readouterr().err and script.read_bytes() == before


def test_valid_outputs_reach_the_command(tmp_path, nothing_runs):
    assert cli.main(["nonlinearity", str(MODEL), "--alpha-sweep", "0.1:1:2", "--csv", str(tmp_path / "a.csv")]) == 0
    assert cli.main(["codegen", str(MODEL), "-o", str(tmp_path / "new" / "dir")]) == 0
    assert cli.main(["derive", "--list"]) == 0  # writes nothing: its default --out is not checked
    assert nothing_runs == ["cmd_nonlinearity", "cmd_codegen", "cmd_derive"]


@pytest.mark.parametrize("which", ["c", "h"])
def test_codegen_set_with_one_read_only_file_writes_none(tmp_path, which):
    """NAME.c and NAME.h are checked together before anything is generated: a read-only
    header no longer leaves a new .c beside an old .h."""
    import sympy as sp

    import symmon as sm
    from symmon.codegen import export_c
    from symmon.errors import OutputPathError

    a = sp.Symbol("a")
    model = sm.Model([a], [a * a], name="set_model")
    for ext in ("c", "h"):
        (tmp_path / f"set_model.{ext}").write_text(f"old {ext}\n")
    (tmp_path / f"set_model.{which}").chmod(0o444)
    with pytest.raises(OutputPathError, match="is read-only"):
        export_c(model, tmp_path)
    assert [(tmp_path / f"set_model.{e}").read_text() for e in ("c", "h")] == ["old c\n", "old h\n"]


def test_filter_export_set_with_a_read_only_readme_writes_none(tmp_path):
    import sympy as sp

    import symmon as sm
    from symmon.errors import OutputPathError

    x = sp.Symbol("x", real=True)
    kf = sm.NonlinearKalmanFilter(sm.Model([x], [x], name="set_f"), sm.Model([x], [x], name="set_h"),
                                  [[1.0]], [[1.0]], sm.TT1())
    kf.export_c(tmp_path, "set_ekf")
    readme = tmp_path / "set_ekf_README.md"
    readme.chmod(0o444)   # a set that symmon wrote, with one member read-only: nothing is replaced
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    kf2 = sm.NonlinearKalmanFilter(sm.Model([x], [2 * x], name="set_f"), sm.Model([x], [x], name="set_h"),
                                   [[1.0]], [[1.0]], sm.TT1())
    with pytest.raises(OutputPathError, match="set_ekf_README.md .*is read-only"):
        kf2.export_c(tmp_path, "set_ekf")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
