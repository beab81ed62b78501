"""Measurements behind the compile policy (docs/compile.md, "Threshold").

For models of growing size, the C of g, J and the Hessians (``CompiledModel.gjh`` with
its row loop) is compiled with gcc at -O0, -O1 and -O2; the table gives the size of the
C, CasADi's instruction count, the compile time, and the evaluation time per row of the
compiled code and of CasADi's virtual machine.

Run: ``python benchmarks/compile_policy.py`` (a few minutes; prints a Markdown table).
"""

from __future__ import annotations

import ctypes
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import sympy as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from symmon.compile.compiled import CompiledModel, _load_rows, rows_c  # noqa: E402

ROWS = 2000


def model(n: int) -> tuple[list[sp.Expr], list[sp.Symbol]]:
    """n sensors at distinct places, each measuring range and bearing of an n-state target."""
    xs = sp.symbols(f"x0:{n}", real=True)
    outs = []
    for i in range(n):
        dx = xs[0] - (i + 1) * 100 + sum(xs[k] * sp.Rational(1, k + 2) for k in range(2, n))
        dy = xs[1] - (i % 3) * 50 + sum(xs[k] * sp.Rational(1, k + 3) for k in range(2, n))
        outs += [sp.sqrt(dx**2 + dy**2 + 1), sp.atan2(dy, dx)]
    return outs, list(xs)


def best_of(f, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    print("| n_w | n_y | C bytes | SX instructions | gcc -O0 s | -O1 s | -O2 s | "
          "µs/row -O0 | -O1 | -O2 | VM µs/row |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    for n in (2, 4, 6, 8, 10, 12, 16):
        outs, xs = model(n)
        cm = CompiledModel(outs, xs, name=f"bench{n}", compiled=False)
        f = cm.gjh
        code = rows_c(f)
        W = rng.uniform(1, 50, (ROWS, n))
        vm = best_of(lambda: cm.eval_gjh(W)) / ROWS * 1e6
        outs_buf = [np.empty((ROWS, f.nnz_out(k))) for k in range(f.n_out())]
        ptrs = (ctypes.c_void_p * len(outs_buf))(*[o.ctypes.data for o in outs_buf])
        iw = np.empty(max(f.sz_iw(), 1), np.int64)
        w = np.empty(max(f.sz_w(), 1))
        row = [n, 2 * n, len(code), f.n_instructions()]
        per_row = []
        with tempfile.TemporaryDirectory() as tmp:
            (Path(tmp) / "f.c").write_text(code)
            for opt in ("-O0", "-O1", "-O2"):
                so = Path(tmp) / f"f{opt}.so"
                t0 = time.perf_counter()
                subprocess.run(["gcc", opt, "-fPIC", "-shared", "-fno-fast-math", "-ffp-contract=off",
                                "f.c", "-o", so.name, "-lm"], cwd=tmp, check=True)
                row.append(round(time.perf_counter() - t0, 2))
                rows = _load_rows(f.name())(so)
                X = np.ascontiguousarray(W)
                per_row.append(best_of(lambda: rows(X.ctypes.data, ptrs, ROWS, iw.ctypes.data, w.ctypes.data))
                               / ROWS * 1e6)
        row += [round(t, 2) for t in per_row] + [round(vm, 2)]
        print("| " + " | ".join(map(str, row)) + " |", flush=True)


if __name__ == "__main__":
    main()
