"""Wall time and peak memory of ``symmon prove-invariance`` and of the noise-structure detection.

    python benchmarks/prove_invariance.py [--route lemmas|direct] [--numeric]

Each example (examples/*.toml) and weight runs the CLI in its own process, whose wall time
(``time.perf_counter`` around the process, including the Python and sympy imports) and peak
resident memory (``ru_maxrss`` from ``os.wait4``) are printed. The last line times
``Model.structure`` of (a+b+c+d+f+g+h+v)⁶⁴ in-process.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ("polar", "radar", "bot", "gmti", "rdcos")
WEIGHTS = ("full", "diag", "liu-li")
#: The ``symmon`` command of this checkout (run with cwd=ROOT), as ``python -m symmon.cli`` was.
CLI = [sys.executable, "-c", "import sys; from symmon.cli import main; sys.exit(main())"]


def run_one(path: Path, weight: str, extra: list[str]) -> tuple[float, float, int, str]:
    """(seconds, peak MB, exit code, verdict) of one CLI run."""
    cmd = [*CLI, "prove-invariance", str(path), "--weight", weight, *extra]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    seconds = time.perf_counter() - t0
    verdict = "holds" if "holds:" in out else "fails" if "fails:" in out else "error"
    return seconds, usage.ru_maxrss / 1024.0, proc.returncode, verdict


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--route", choices=("lemmas", "direct"), default="lemmas")
    ap.add_argument("--numeric", action="store_true")
    args = ap.parse_args(argv)
    extra = ["--route", args.route] + (["--numeric"] if args.numeric else [])
    print(f"{'model':>6} {'weight':>7} {'seconds':>8} {'peak MB':>8} {'verdict':>8}")
    for name in EXAMPLES:
        for weight in WEIGHTS:
            s, mb, code, verdict = run_one(ROOT / "examples" / f"{name}.toml", weight, extra)
            print(f"{name:>6} {weight:>7} {s:8.2f} {mb:8.0f} {verdict:>8}" + ("" if code == 0 else f"  (exit {code})"))
    sys.path.insert(0, str(ROOT))
    import sympy as sp

    import symmon as sm

    a, b, c, d, f, g, h, v = sp.symbols("a b c d f g h v", real=True)
    t0 = time.perf_counter()
    m = sm.Model([a, b, c, d, f, g, h], [(a + b + c + d + f + g + h + v) ** 64], noise=[v])
    structure = m.structure
    print(f"structure of (a+…+h+v)**64: {structure} with {m.gamma.shape[0]} γ in {time.perf_counter() - t0:.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
