"""Every file ``symmon reproduce`` writes is checked before the work (issue 26).

Each figure module declares the files it writes (``OUTPUTS``); ``run`` checks them with
``symmon.io.check_output_set`` and the command line with its other outputs
(``symmon.cli.commands.check_outputs``), so a read-only ``fig1.png`` refuses the run at once,
not after minutes of Monte Carlo. The output directory is created when missing, as before.
"""

from __future__ import annotations

import importlib

import pytest

from symmon.cli import commands
from symmon.cli import parser as cli
from symmon.cli.options import FIGURES
from symmon.errors import OutputPathError

#: The first expensive step of each module's run: replaced by one that fails the test.
HEAVY = {"fig1": "curves", "fig2": "curves", "radar": "measurement", "mmse": "_sec431", "tracking": "study",
         "bot": "study", "select": "study"}


@pytest.fixture
def no_work(monkeypatch):
    """Every figure's expensive step raises: a refusal must come before it."""
    def forbidden(*args, **kwargs):
        raise AssertionError("the heavy computation ran before the outputs were checked")

    for name, attr in HEAVY.items():
        monkeypatch.setattr(importlib.import_module(f"symmon.reproduce.{name}"), attr, forbidden)


def _lock(directory, name):
    target = directory / name
    target.write_text("keep me\n")
    target.chmod(0o444)
    return target


@pytest.mark.parametrize("figure", FIGURES)
def test_a_read_only_output_refuses_the_command_before_any_work(capsys, tmp_path, no_work, figure):
    mod = importlib.import_module(f"symmon.reproduce.{figure}")
    for name in mod.OUTPUTS:
        target = _lock(tmp_path, name)
        code = cli.main(["reproduce", figure, "--out", str(tmp_path), "--no-progress"])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 1 and len(err) == 1 and "is read-only" in err[0] and name in err[0]
        assert target.read_text() == "keep me\n"
        target.chmod(0o644)
        target.unlink()


@pytest.mark.parametrize("figure", FIGURES)
def test_run_itself_checks_its_files_first(tmp_path, no_work, figure):
    mod = importlib.import_module(f"symmon.reproduce.{figure}")
    target = _lock(tmp_path, mod.OUTPUTS[-1])
    with pytest.raises(OutputPathError, match="is read-only"):
        mod.run(tmp_path, progress=False)
    assert target.read_text() == "keep me\n"


def test_reproduce_all_checks_every_figure_before_the_first(capsys, tmp_path, no_work):
    _lock(tmp_path, "bot_steps.csv")  # the last file of the last figure
    assert cli.main(["reproduce", "all", "--out", str(tmp_path), "--no-progress"]) == 1
    assert "bot_steps.csv" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bot_steps.csv"]


def test_an_output_file_that_is_a_directory_is_refused(capsys, tmp_path, no_work):
    (tmp_path / "fig1.csv").mkdir()
    assert cli.main(["reproduce", "fig1", "--out", str(tmp_path), "--no-progress"]) == 1
    assert "is a directory; only regular files are written" in capsys.readouterr().err


def test_a_missing_directory_is_still_created(tmp_path, monkeypatch):
    ran = []
    monkeypatch.setattr(commands, "cmd_reproduce", lambda args: ran.append(args.out) or 0)
    out = tmp_path / "new" / "results"
    assert cli.main(["reproduce", "fig1", "--out", str(out), "--no-progress"]) == 0 and ran == [str(out)]
    # and run creates it, after the check (a new directory holds no read-only file)
    from symmon.reproduce import fig1

    def stop(*args, **kwargs):
        raise RuntimeError("stop after the check")

    monkeypatch.setattr(fig1, "curves", stop)
    with pytest.raises(RuntimeError, match="stop after the check"):
        fig1.run(out, progress=False)
    assert out.is_dir()
