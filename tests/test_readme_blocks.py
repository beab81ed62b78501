"""Every code block of README.md runs as written (issue 25).

The rule, which the README states above its first Python block: **each ```python block runs
on its own**, top to bottom, with its imports visible, in a fresh interpreter; no block
continues another. Each block runs here as a subprocess with warnings as errors, in a
temporary working directory, with ``MPLBACKEND=Agg``. Its traceback names the README's own
line numbers (the block is compiled with the README as its file name), and a failure names
the block's first line.

A comment ``# -> TEXT`` on a line of a block (after an optional explanation:
``# E|x| -> 0.7979``) shows what that line prints. The lines of the block's output must
contain every such TEXT as a whole line, in the order of the comments, so that a number
shown in the README is the one the code prints.

The ```bash blocks' ``symmon`` commands run too (from the temporary directory, with
``examples/`` linked into it), except the long ones of :data:`LONG_COMMANDS`; the
```text block that shows a ``$ symmon ...`` command and its output is compared with what
the command prints now.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from helpers import ROOT, checkout_environment

README = ROOT / "README.md"
#: Generous wall-clock bound per block or command, so that a hang fails (not a timing test).
HANG_TIMEOUT_S = 300
#: ``# -> TEXT`` at the end of a line, after an optional explanation.
SHOWN = re.compile(r"#(?:.*\s)?-> (.*\S)\s*$")
#: Commands of the README's bash blocks that take minutes (or a cluster), with the reason;
#: every other ``symmon`` command of a bash block runs. Each must still be in the README.
LONG_COMMANDS = {
    "symmon reproduce fig1": "10⁶ samples at every α of Figure 1 (CI runs it on 10⁵)",
    "symmon reproduce fig2 --samples 1e7": "10⁷ samples at 21 α for three problems",
    "symmon propagate examples/gmti.toml --transform mc --samples 1e9 --groups 64 --dask processes":
        "10⁹ samples on a local Dask cluster",
    "symmon reproduce tracking": "the tracking study: banks of filters over many scenarios",
}


@dataclass(frozen=True)
class Block:
    """A fenced block of the README: its language, first line of code (1-based) and text."""

    lang: str
    line: int
    code: str

    @property
    def id(self) -> str:
        return f"{self.lang}-line-{self.line}"


def blocks(lang: str) -> list[Block]:
    out, current, start, body = [], None, 0, []
    for number, line in enumerate(README.read_text(encoding="utf-8").splitlines(), start=1):
        if current is None:
            m = re.fullmatch(r"```(\w+)\s*", line)
            if m:
                current, start, body = m.group(1), number + 1, []
        elif line.strip() == "```":
            if current == lang:
                out.append(Block(current, start, "\n".join(body) + "\n"))
            current = None
        else:
            body.append(line)
    assert current is None, f"README.md: the block opened at line {start - 1} is not closed"
    return out


def shown(block: Block) -> list[tuple[int, str]]:
    """(README line, TEXT) of each ``# -> TEXT`` comment of a block."""
    out = []
    for offset, line in enumerate(block.code.splitlines()):
        m = SHOWN.search(line)
        if m:
            out.append((block.line + offset, m.group(1)))
    return out


def missing(expected: list[tuple[int, str]], stdout: str) -> list[tuple[int, str]]:
    """The expected lines that the output does not contain as whole lines, in order."""
    lines = iter(line.rstrip() for line in stdout.splitlines())
    return [(n, text) for n, text in expected if not any(line == text for line in lines)]


PYTHON_BLOCKS = blocks("python")
# The runner: the block, compiled as README.md with its own line numbers, in a fresh module.
RUNNER = ("import sys, pathlib; code = pathlib.Path(sys.argv[1]).read_text(encoding='utf-8'); "
          "exec(compile(code, sys.argv[2], 'exec'), {'__name__': '__main__'})")


def test_the_readme_has_its_python_blocks():
    assert len(PYTHON_BLOCKS) >= 5
    assert all(b.code.startswith("import ") for b in PYTHON_BLOCKS), \
        [b.line for b in PYTHON_BLOCKS if not b.code.startswith("import ")]


@pytest.mark.parametrize("block", PYTHON_BLOCKS, ids=lambda b: b.id)
def test_python_block_runs_on_its_own(block, tmp_path):
    source = tmp_path / "block.py"
    source.write_text("\n" * (block.line - 1) + block.code, encoding="utf-8")
    run = tmp_path / "cwd"
    run.mkdir()
    proc = subprocess.run([sys.executable, "-W", "error", "-c", RUNNER, str(source), str(README)],
                          cwd=run, env=checkout_environment(), capture_output=True, text=True,
                          timeout=HANG_TIMEOUT_S, check=False)
    if proc.returncode != 0:
        pytest.fail(f"README.md, the Python block at line {block.line} fails:\n{proc.stderr[-3000:]}",
                    pytrace=False)
    lost = missing(shown(block), proc.stdout)
    if lost:
        pytest.fail(f"README.md, the Python block at line {block.line}: the output shown "
                    + "; ".join(f"at line {n} ({text!r})" for n, text in lost)
                    + f" is not what it prints:\n{proc.stdout[-3000:]}", pytrace=False)


def test_shown_output_is_parsed():
    block = Block("python", 10, 'print(1)   # -> 1\nx = 2  # x, Lemma 1 -> 2\n# plain comment\n')
    assert shown(block) == [(10, "1"), (11, "2")]
    assert missing([(1, "a"), (2, "b")], "a\nb\n") == []
    assert missing([(1, "b"), (2, "a")], "a\nb\n") == [(2, "a")]      # in order
    assert missing([(1, "a")], "ab\n") == [(1, "a")]                  # whole lines


# --------------------------------------------------------------------------- the shell
def commands() -> list[tuple[int, str]]:
    """(README line, command) of each ``symmon`` command of the bash blocks; a line may
    hold several commands joined by ``&&``."""
    out = []
    for block in blocks("bash"):
        for offset, line in enumerate(block.code.splitlines()):
            for part in " ".join(shlex.split(line, comments=True)).split(" && "):
                if part.startswith("symmon "):
                    out.append((block.line + offset, part))
    return out


def made_directories() -> set[str]:
    """The directories that ``mkdir -p DIR && symmon ...`` lines of the bash blocks make."""
    out = set()
    for block in blocks("bash"):
        for line in block.code.splitlines():
            for part in " ".join(shlex.split(line, comments=True)).split(" && "):
                if part.startswith("mkdir -p "):
                    out.update(part.split()[2:])
    return out


#: Options of the README's commands that name a file or directory they write.
OUTPUT_OPTIONS = ("--csv", "--plot", "--out")


def test_readme_commands_write_under_results_not_the_checkout_root():
    """Issue 38, item 16: the README's commands wrote mon.csv, mon.png and nees.png into the
    checkout's root; they go under results/ (as `symmon reproduce` writes), and the C export
    does not use pip's build/ directory."""
    for line, command in commands():
        words = shlex.split(command)
        for opt, value in zip(words, words[1:]):
            if opt in OUTPUT_OPTIONS:
                assert "/" in value and value.split("/")[0] in {"results", "docs", "c_export"}, \
                    f"README.md line {line}: {opt} {value} writes into the checkout's root"
    text = README.read_text(encoding="utf-8")
    assert "results" in made_directories()
    assert not re.search(r"export_c\([^)]*[\"']build[\"']|--out build\b", text), "the C export writes into build/"


def symmon(command: str, cwd: Path) -> subprocess.CompletedProcess:
    (cwd / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    for d in made_directories():  # what `mkdir -p results && symmon ...` makes first
        (cwd / d).mkdir(parents=True, exist_ok=True)
    argv = [sys.executable, "-W", "error", "-m", "symmon.cli", *shlex.split(command)[1:]]
    return subprocess.run(argv, cwd=cwd, env=checkout_environment(), capture_output=True, text=True,
                          timeout=HANG_TIMEOUT_S, check=False)


SHELL = [(n, c) for n, c in commands() if c not in LONG_COMMANDS]


def test_long_commands_are_still_in_the_readme():
    assert set(LONG_COMMANDS) <= {c for _, c in commands()}
    assert len(SHELL) >= 5


@pytest.mark.parametrize("line, command", SHELL, ids=[f"line-{n}" for n, _ in SHELL])
def test_shell_command_runs(line, command, tmp_path):
    proc = symmon(command, tmp_path)
    if proc.returncode != 0:
        pytest.fail(f"README.md line {line}: `{command}` fails:\n{proc.stderr[-3000:]}", pytrace=False)


def transcripts() -> list[tuple[int, str, str]]:
    """(README line, command, output) of each ```text block that starts with ``$ symmon``."""
    out = []
    for block in blocks("text"):
        first, _, rest = block.code.partition("\n")
        if first.startswith("$ symmon "):
            out.append((block.line, first[2:], rest))
    return out


def test_the_readme_has_a_transcript():
    assert transcripts()


@pytest.mark.parametrize("line, command, output", transcripts(), ids=[f"line-{t[0]}" for t in transcripts()])
def test_transcript_is_what_the_command_prints(line, command, output, tmp_path):
    proc = symmon(command, tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert [ln.rstrip() for ln in proc.stdout.splitlines()] == output.rstrip("\n").splitlines(), \
        f"README.md line {line}: `{command}` prints now:\n{proc.stdout}"
