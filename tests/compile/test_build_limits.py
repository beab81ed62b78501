"""The resource limits of a compiler run: CPU time and memory, inherited by cc1, set from the
environment, and a build past them fails clearly instead of running on."""

from __future__ import annotations

import sys
import warnings

import pytest

from symmon.compile import ccbuild
from symmon.compile.ccache import BUILD_MEMORY_MB, BUILD_SECONDS, NativeLibrary, build_limits, has_compiler
from symmon.errors import SymmonError

pytestmark = pytest.mark.skipif(ccbuild.resource is None, reason="no resource limits on this platform")


def test_a_compiler_past_its_cpu_limit_is_stopped(tmp_path, capfd):
    (tmp_path / "f.c").write_text("")
    spin = [sys.executable, "-I", "-c", "while True: pass"]
    assert ccbuild.main([str(tmp_path), str(tmp_path / "x.so"), "1", str(4 << 30), *spin]) == 1
    out = capfd.readouterr().out
    assert "1 s of CPU" in out and "SYMMON_BUILD_SECONDS" in out
    assert not (tmp_path / "x.so").exists()


def test_a_compiler_past_its_memory_limit_fails(tmp_path, capfd):
    (tmp_path / "f.c").write_text("")
    grab = [sys.executable, "-I", "-c", "b = bytearray(2 << 30)"]
    assert ccbuild.main([str(tmp_path), str(tmp_path / "x.so"), "60", str(512 << 20), *grab]) == 1
    out = capfd.readouterr().out
    assert "MemoryError" in out and "512 MiB of memory" in out


def test_the_limits_come_from_the_environment(monkeypatch):
    monkeypatch.delenv("SYMMON_BUILD_SECONDS", raising=False)
    monkeypatch.delenv("SYMMON_BUILD_MEMORY_MB", raising=False)
    seconds, memory = build_limits()
    assert seconds == BUILD_SECONDS and 0 < memory <= BUILD_MEMORY_MB << 20
    monkeypatch.setenv("SYMMON_BUILD_SECONDS", "30")
    monkeypatch.setenv("SYMMON_BUILD_MEMORY_MB", " 100 ")
    assert build_limits() == (30, 100 << 20)


@pytest.mark.parametrize("value", ["0", "-5", "1.5", "lots", "²"])
def test_a_bad_limit_is_refused(monkeypatch, value):
    monkeypatch.setenv("SYMMON_BUILD_SECONDS", value)
    with pytest.raises(SymmonError, match="SYMMON_BUILD_SECONDS must be a positive whole number"):
        build_limits()


@pytest.mark.skipif(not has_compiler(), reason="no C compiler")
def test_a_build_past_its_limits_leaves_the_vm_with_a_warning(monkeypatch, tmp_path):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    monkeypatch.setenv("SYMMON_COMPILE", "sync")
    monkeypatch.setenv("SYMMON_BUILD_MEMORY_MB", "1")  # not even the compiler driver starts
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lib = NativeLibrary("int f(void) { return 1; }\n", "limited", lambda p: p)
    assert lib.get() is None
    assert any("1 MiB of memory" in str(w.message) for w in caught)
    assert not list(tmp_path.glob("limited_*.so"))


def test_a_lower_ulimit_than_the_builds_is_taken(tmp_path):
    """Under ``ulimit -v`` below the build's memory limit (and ``ulimit -t`` below its CPU
    limit) the compiler runs under the lower limits (issue 38, item 14): asking for more
    than the hard limit failed in the child, before the compiler, with a raw traceback, and
    every C build fell back to the VM."""
    import ast
    import resource
    import subprocess

    own = 3 << 30  # below the build's 8 GiB, above what this Python needs

    def lower() -> None:  # the ulimit -v and -t of the process that starts the build
        resource.setrlimit(resource.RLIMIT_AS, (own, own))
        resource.setrlimit(resource.RLIMIT_CPU, (100, 100))

    build = tmp_path / "build"
    build.mkdir()
    (build / "f.c").write_text("")
    report = [sys.executable, "-I", "-c",
              "import resource; open('f.so', 'w').write(repr(resource.getrlimit(resource.RLIMIT_AS)"
              " + resource.getrlimit(resource.RLIMIT_CPU)))"]
    res = subprocess.run([sys.executable, "-I", ccbuild.__file__, str(build), str(tmp_path / "x.so"),
                          "600", str(8 << 30), *report], preexec_fn=lower, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Traceback" not in res.stdout + res.stderr
    # The compiler's limits: this process's memory, and its CPU time less the 5 s to SIGKILL.
    assert ast.literal_eval((tmp_path / "x.so").read_text()) == (own, own, 95, 100)
