"""symmon's C lives in .c and .h files of the package (issue 49, item 3): each compiles alone
under the strict flags, no module holds C text, and the cache key covers a file's bytes."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
from pathlib import Path

import pytest

import symmon
from symmon.compile import ccache, csource
from symmon.compile.csource import c_defines, c_file, c_source, c_text, choose, fill

PACKAGE = Path(symmon.__file__).parent
C_FILES = sorted(PACKAGE.rglob("*.c"))
H_FILES = sorted(PACKAGE.rglob("*.h"))
#: The exported filter's templates (``.c.in``, ``.h.in``): C only once filled (csource.choose and
#: fill), so the strict check below skips them; tests/filters/test_export.py builds what they give.
TEMPLATES = sorted(PACKAGE.rglob("*.[ch].in"))
STRICT = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-fsyntax-only")
#: Lines of C a Python string constant may hold (a line ending in ``;``, ``{`` or ``}``).
MAX_C_LINES = 10
_C_LINE = re.compile(r"[;{}]\s*(//.*|/\*.*\*/)?$")


def _compiler() -> str | None:
    return shutil.which("gcc") or shutil.which("cc")


def test_the_package_ships_its_c():
    names = {p.name for p in C_FILES}
    assert {"rows.c", "rng.c", "rng_fill.c"} <= names
    assert all(p.stat().st_size > 0 for p in C_FILES + H_FILES)


@pytest.mark.parametrize("path", C_FILES + H_FILES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_each_c_file_compiles_alone_under_the_strict_flags(path):
    cc = _compiler()
    if cc is None:
        pytest.skip("no C compiler (gcc or cc) on PATH: the C files cannot be checked here")
    # the builder's -march=native where the compiler takes it: the AVX2 branches are checked too
    flags = [*STRICT, *ccache.native_target((cc,))[0]]
    if path.suffix == ".h":  # a header alone is an empty unit where it only defines macros
        src = f'#include "{path}"\ntypedef int symmon_header_check;\n'
        res = subprocess.run([cc, *flags, "-x", "c", "-"], input=src, capture_output=True, text=True, timeout=120)
    else:
        res = subprocess.run([cc, *flags, str(path)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


def _docstring_ids(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def c_lines(text: str) -> int:
    """The lines of ``text`` that end like C statements or blocks."""
    return sum(1 for line in text.splitlines() if _C_LINE.search(line.strip()))


def test_the_heuristic_sees_c_and_not_prose():
    assert c_lines("int f(void) {\n  int i;\n  return 0;\n}\n") == 4
    assert c_lines("A sentence; another one.\nA set {a, b} of names.\n") == 0


def test_no_module_holds_c_text():
    found, holding = [], set()
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        docs = _docstring_ids(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
                text = node.value
            elif isinstance(node, ast.JoinedStr):
                text = "".join(v.value for v in node.values if isinstance(v, ast.Constant))
            else:
                continue
            n = c_lines(text)
            if n > MAX_C_LINES:
                found.append(f"{path.relative_to(PACKAGE)}:{node.lineno}: {n} lines of C")
    assert not found, "C text in Python modules (move it into a .c file):\n" + "\n".join(found)


def test_the_cache_key_covers_the_c_text(monkeypatch, tmp_path):
    if ccache._compiler() is None:
        pytest.skip("no C compiler: the cache keys include the compiler's identity")
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    text = c_file("symmon.compile", "rows.c")
    changed = text.replace("return 0;\n}", "return 0;\n}\n", 1)
    assert changed != text
    one = ccache._entry(text, "rows", ccache.OPT_SYNC, lambda msg: None)
    assert ccache._entry(text, "rows", ccache.OPT_SYNC, lambda msg: None) == one
    assert ccache._entry(changed, "rows", ccache.OPT_SYNC, lambda msg: None) != one


def test_c_file_refuses_a_path():
    with pytest.raises(ValueError, match="name"):
        c_file("symmon.compile", "../compile/rows.c")


def test_c_text_is_the_file_after_its_guarded_block(monkeypatch):
    text = c_file("symmon.compile", "mtimes_dense.c")
    body = c_text("symmon.compile", "mtimes_dense.c")
    assert text.endswith(body) and body.startswith("void casadi_mtimes_dense(")
    assert "#endif" not in body and "casadi_alone.h" not in body
    monkeypatch.setattr(csource, "c_file", lambda package, name: "int f(void);\n")
    with pytest.raises(ValueError, match="f.c has no guarded block"):
        c_text("symmon.compile", "f.c")


def test_c_source_puts_the_included_files_of_the_package_in_place():
    step = c_file("symmon.filters.gaussian", "ekf_step.c")
    assert '#include "ekf_dense.c"\n' in step
    text = c_source("symmon.filters.gaussian", "ekf_step.c")
    assert '#include "ekf_dense.c"' not in text
    assert c_file("symmon.filters.gaussian", "ekf_dense.c") in text
    assert '#include "../../compile/casadi_alone.h"' in text  # a path: the guarded block's, kept


def test_c_defines_takes_numbers_and_identifiers_only():
    assert c_defines(A=3, B="name_1", C=(1, 2), D=True, E=0.5) == (
        "#define A 3\n#define B name_1\n#define C 1, 2\n#define D 1\n#define E 0.5\n")
    for bad in ("a b", "x; system()", "1abc", "a\nb", float("nan"), (), None):
        with pytest.raises(ValueError, match="A"):
            c_defines(A=bad)
    with pytest.raises(ValueError, match="macro name"):
        c_defines(**{"A B": 1})


def test_fill_replaces_checked_placeholders_and_nothing_else():
    assert fill("int @P@_n = @N@; /* a@b */", P="kf", N=2) == "int kf_n = 2; /* a@b */"
    with pytest.raises(ValueError, match="placeholders N"):
        fill("@P@ @N@", P="kf")
    with pytest.raises(ValueError, match="values Q"):
        fill("@P@", P="kf", Q=1)
    for bad in ("*/ evil /*", "a\"b", 1.5):
        with pytest.raises(ValueError, match="P"):
            fill("@P@", P=bad)


def test_the_templates_are_files_of_the_package_with_placeholders_only():
    assert {p.name for p in TEMPLATES} >= {"export_filter.c.in", "export_example.c.in", "export_api.h.in",
                                            "export_work.h.in"}
    assert not set(TEMPLATES) & set(C_FILES + H_FILES)
    for path in TEMPLATES:
        text = c_file("symmon." + ".".join(path.parent.relative_to(PACKAGE).parts), path.name)
        assert "{P}" not in text and ("@P@" in text or "@K@" in text)  # fill's placeholders, not format's


def test_c_file_reads_templates_and_no_other_name():
    assert "@P@_predict" in c_file("symmon.filters.gaussian", "export_api.h.in")
    for bad in ("export_api.in", "export_api.h.txt", "x.py"):
        with pytest.raises(ValueError, match="name"):
            c_file("symmon.filters.gaussian", bad)


def test_choose_keeps_or_drops_the_optional_parts():
    text = "f(x@?P:, p?@)@?Q:;\n  g(@N@);?@"
    assert choose(text, P=True, Q=False) == "f(x, p)"
    assert choose(text, P=False, Q=True) == "f(x);\n  g(@N@);"
    assert fill(choose(text, P=False, Q=True), N=2) == "f(x);\n  g(2);"
    with pytest.raises(ValueError, match="optional parts Q"):
        choose(text, P=True)
    with pytest.raises(ValueError, match="flags R"):
        choose(text, P=True, Q=True, R=False)
    with pytest.raises(ValueError, match="P must be a bool"):
        choose(text, P=1, Q=True)
