"""The EKF and the UKF from 4 to 200 states against dynamax (and a NumPy EKF bank): first
call, warm, peak memory, growth exponents.

    python benchmarks/large_filters.py [--ekf-sizes 4,10,20,30,65,100,130,200]
        [--ukf-sizes 20,65,100,130,200] [--timeout 300] [--out benchmarks/RESULTS.md]

The trackers of ``benchmarks/peers.py`` (n = 5k: k range–bearing targets with a range bias
each, stacked; n = 4: one target).  Each (filter, side, n) runs in its own subprocess, so that
its first call is a first call (symmon: a fresh cache, the step built and its C compiled,
or the VM while the C builds; dynamax: ``jax.jit`` trace and XLA compile) and its peak memory
its own: VmHWM, reset after the imports and the problem's set-up, minus the resident set at
that point (a compiler that symmon runs is a child process and not counted).  symmon and
dynamax alternate per size, so that both see the same load.

- one run: K steps of one run, ``filter(ys[0], x0, keep=("x", "P"))`` (dynamax: ``jax.jit``);
- bank: R runs in one call (dynamax: ``jax.jit(jax.vmap(...))``; NumPy: every run at once,
  ``peers.numpy_ekf_bank``), keeping every step's x and P (all sides alike).

K = 100 steps and R = 50 runs up to 65 states, K = 50 and R = 20 from 100 on (the kept
covariances of a bank are R K n² doubles).  A subprocess that exceeds ``--timeout`` seconds
is reported as such.  Ratios are peer time / symmon time; growth exponents are least-squares
fits of log time on log n over n ≥ 10.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
HEADING = "## Filters at 4–200 states"


def sizes_of(n: int) -> tuple[int, int]:
    """(K, R) at n states."""
    return (100, 50) if n < 100 else (50, 20)


def _peak_reset() -> float:
    """Reset VmHWM to the current resident set; return that set (MiB)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass
    return _status("VmRSS")


def _status(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def worker(side: str, label: str, n: int, repeat: int) -> dict:
    """One (side, filter, n) measurement, in this process."""
    os.environ["SYMMON_CACHE"] = tempfile.mkdtemp(prefix="symmon-bench-large-")
    sys.path.insert(0, str(HERE))
    import peers  # noqa: F401  (its imports: symmon, numpy, sympy)
    from filters import best

    p = peers.problem(n)
    K, R = sizes_of(n)
    _, ys = p.simulate(K, R, seed=0)
    if side == "dynamax":
        import jax  # noqa: F401
    base = _peak_reset()
    if side == "symmon":
        out = peers.symmon_filters(p, ys, repeat, labels=(label,), wait=None)[label]
    elif side == "dynamax":
        got = peers.dynamax_filters(p, ys, repeat, labels=(label,))
        if got is None:
            return {"missing": True}
        out = got[label]
    else:
        t0 = time.perf_counter()
        peers.numpy_ekf_bank(p, ys)
        out = {"first": time.perf_counter() - t0, "bank": best(lambda: peers.numpy_ekf_bank(p, ys), repeat)}
    out.pop("x", None)
    out.update(n=p.n, K=K, R=R, peak_mib=_status("VmHWM") - base)
    return out


def run_worker(side: str, label: str, n: int, repeat: int, timeout: float) -> dict:
    from filters import run_json_worker

    return run_json_worker([__file__, "--worker", side, label, str(n), str(repeat)], timeout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--ekf-sizes", default="4,10,20,30,65,100,130,200")
    ap.add_argument("--ukf-sizes", default="20,65,100,130,200")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per subprocess")
    ap.add_argument("--out", type=Path, default=None, help="write the section into this Markdown file")
    ap.add_argument("--logs", nargs="*", type=Path, default=None,
                    help="build the section from the result lines that earlier runs printed (no measurement)")
    a = ap.parse_args()
    if a.worker:
        side, label, n, repeat = a.worker
        print(json.dumps(worker(side, label, int(n), int(repeat))))
        return
    sys.path.insert(0, str(HERE))
    import numpy as np
    from peers import exponent
    from smoothers import fmt, ratio
    from filters import publish

    load0 = os.getloadavg()[0]
    res: dict[tuple[str, str, int], dict] = {}
    if a.logs is not None:
        import ast

        loads = []
        for path in a.logs:  # later files override earlier ones
            for line in path.read_text().splitlines():
                parts = line.split(" ", 3)
                if len(parts) == 4 and parts[0] in ("symmon", "dynamax", "numpy") and parts[3].startswith("{"):
                    res[parts[0], parts[1], int(parts[2])] = ast.literal_eval(parts[3])
                elif line.startswith("load "):
                    loads += [float(v) for v in line.split()[1:]]
        load0, load1 = (min(loads), max(loads)) if loads else (float("nan"), float("nan"))
    else:
        print("load", load0, flush=True)
        plan = [("ekf", int(n), ("symmon", "dynamax", "numpy")) for n in a.ekf_sizes.split(",") if n]
        plan += [("ukf", int(n), ("symmon", "dynamax")) for n in a.ukf_sizes.split(",") if n]
        for label, n, sides in plan:
            for side in sides:
                res[side, label, n] = r = run_worker(side, label, n, a.repeat, a.timeout)
                print(side, label, n, r, flush=True)
        load1 = os.getloadavg()[0]
        print("load", load1, flush=True)

    def cell(r: dict, key: str) -> str:
        if "timeout" in r:
            return f"> {r['timeout']:.0f} s"
        return "error" if "error" in r else fmt(r.get(key))

    lines = [HEADING, "",
             f"Generated by `python benchmarks/large_filters.py` (its docstring says what each column runs): each "
             f"measurement in its own subprocess, symmon and dynamax alternating; K = 100 steps and banks of R = 50 runs "
             f"below 100 states, K = 50 and R = 20 from 100 on. Ratios: peer / symmon (> 1: symmon faster). First: "
             f"symmon into a fresh cache (in parentheses, until the C is in), dynamax its jit trace and compile. Peak: "
             f"VmHWM above the process after its imports (MiB), over all its calls. {platform.machine()}, "
             f"{os.cpu_count()} cores, Python {platform.python_version()}, NumPy {np.__version__}; load average "
             f"(1 min) {'min / max over the runs' if a.logs is not None else 'before / after'}: {load0:.2f} / {load1:.2f}.", ""]
    for label, peers_ in (("ekf", ("dynamax", "numpy")), ("ukf", ("dynamax",))):
        ns = sorted({n for (s, lab, n) in res if lab == label})
        if not ns:
            continue
        lines += [f"### {label.upper()}", "",
                  "| n | symmon first (C in) / dynamax first | one run: symmon / dynamax | bank: symmon / dynamax"
                  + (" / NumPy" if "numpy" in peers_ else "") + " | dynamax / symmon: one, bank"
                  + (" | NumPy / symmon (bank)" if "numpy" in peers_ else "") + " | peak MiB: symmon / dynamax |",
                  "|---|---|---|---|---|" + ("---|" if "numpy" in peers_ else "") + "---|"]
        cols: dict[str, list] = {}
        for n in ns:
            s, d = res["symmon", label, n], res["dynamax", label, n]
            npy = res.get(("numpy", label, n), {})
            nn = s.get("n", d.get("n", n))
            row = (f"| {nn} | {cell(s, 'first')} ({cell(s, 'built')}) / {cell(d, 'first')} "
                   f"| {cell(s, 'one')} / {cell(d, 'one')} | {cell(s, 'bank')} / {cell(d, 'bank')}"
                   + (f" / {cell(npy, 'bank')}" if "numpy" in peers_ else "")
                   + f" | {ratio(d.get('one'), s.get('one'))}, {ratio(d.get('bank'), s.get('bank'))}"
                   + (f" | {ratio(npy.get('bank'), s.get('bank'))}" if "numpy" in peers_ else "")
                   + f" | {s.get('peak_mib', float('nan')):.0f} / {d.get('peak_mib', float('nan')):.0f} |")
            lines.append(row)
            for side, r in (("symmon", s), ("dynamax", d), ("NumPy", npy)):
                for key in ("one", "bank"):
                    if r.get(key):
                        # Per run-step, so that the two bank sizes fit one line.
                        K, R = sizes_of(n)
                        cols.setdefault(f"{side} {key}", []).append((nn, r[key] / (K * (R if key == "bank" else 1))))
        lines += ["", "Growth exponent p of the cost per step ∝ nᵖ (n ≥ 10): "
                  + "; ".join(f"{k} {exponent([a for a, _ in v], [b for _, b in v])}" for k, v in cols.items()) + ".", ""]
    publish(lines, a.out, HEADING)


if __name__ == "__main__":
    main()
