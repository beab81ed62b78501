"""The second-order EKF's C step against the MX step it replaces, and the EKF's C step: CPU
time per step and first call.

    python benchmarks/ekf2_step.py [--sizes 10,20,30,65] [--repeat 7] [--out benchmarks/RESULTS.md]

The trackers of ``benchmarks/peers.py`` (n = 5k: k range–bearing targets with a range bias
each, stacked; a linear f, so the EKF2's second-order terms are h's: a 2 × 2 Hessian block per
output).  Each (step, n) runs in its own subprocess with a fresh cache (``SYMMON_CACHE`` a new
temporary directory), so that its first call is a first call:

- ``ekf2 C``: ``NonlinearKalmanFilter(..., sm.TT2())``, the C step of
  ``symmon.filters.gaussian._ekfstep`` (from ``C_EKF_FROM`` states on);
- ``ekf2 MX``: the same filter with ``symmon.filters.gaussian.step.C_EKF_FROM`` raised above n, so that
  its step is the MX graph's C (the step before the C EKF2 step existed);
- ``ekf C``: the EKF (``sm.TT1()``), for the cost of the second-order terms.

Per step, after the C is in: the best of ``--repeat`` CPU times (``time.process_time``, all
threads of the process; one run is one thread), divided by the steps, of the step alone in its
C loop (the compiled step of one run of K_LOOP = 2000 steps, keeping x) and of
``filter(ys[0], x0, keep=("x", "P"))`` over K = 100 steps (with the call's own cost).  First:
the wall time of the first call into the fresh cache (in parentheses, until the C is in: a
large step starts on CasADi's VM while it builds).
The load average is printed before and after, as the sides alternate per size.
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
HEADING = "## EKF2 C step"
SIDES = ("ekf2 C", "ekf2 MX", "ekf C")
K = 100
K_LOOP = 2000


def worker(side: str, n: int, repeat: int) -> dict:
    """One (side, n) measurement in this process."""
    os.environ["SYMMON_CACHE"] = tempfile.mkdtemp(prefix="symmon-bench-ekf2-")
    sys.path.insert(0, str(HERE))
    import numpy as np

    import peers
    import symmon as sm
    import symmon.filters.gaussian.step as step_module

    if side == "ekf2 MX":
        step_module.C_EKF_FROM = 10**9  # the MX graph's step, as before the C EKF2 step
    p = peers.problem(n)
    _, ys = p.simulate(K_LOOP, 1, seed=0)
    x0 = sm.Gaussian(p.x0, p.P0)
    transform = sm.TT1() if side == "ekf C" else sm.TT2()
    kf = sm.NonlinearKalmanFilter(p.f_model, p.h_model, p.Q, p.R, transform)
    t0 = time.perf_counter()
    kf.filter(ys[0, :K], x0, keep=("x", "P"))
    first = time.perf_counter() - t0
    step = step_module.compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states)
    step._lib.wait(None)
    built = time.perf_counter() - t0
    times, loop = [], []
    for _ in range(repeat):
        c0 = time.process_time()
        res = kf.filter(ys[0, :K], x0, keep=("x", "P"))
        times.append(time.process_time() - c0)
        c0 = time.process_time()
        step(p.x0, p.P0, ys, p.Q, p.R, keep=frozenset(("x",)))
        loop.append(time.process_time() - c0)
    return {"n": p.n, "c_step": bool(step.c_ekf), "first": first, "built": built, "cpu_step": min(times) / K,
            "cpu_loop": min(loop) / K_LOOP,
            "x": np.asarray(res.x).tolist()}


def run_worker(side: str, n: int, repeat: int, timeout: float) -> dict:
    from filters import run_json_worker

    return run_json_worker([__file__, "--worker", side, str(n), str(repeat)], timeout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--sizes", default="10,20,30,65")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per subprocess")
    ap.add_argument("--out", type=Path, default=None, help="write the section into this Markdown file")
    a = ap.parse_args()
    if a.worker:
        side, n, repeat = a.worker
        print(json.dumps(worker(side, int(n), int(repeat))))
        return
    sys.path.insert(0, str(HERE))
    import numpy as np
    from filters import publish

    load0 = os.getloadavg()[0]
    print("load", load0, flush=True)
    res = {}
    for n in (int(v) for v in a.sizes.split(",") if v):
        for side in SIDES:
            res[side, n] = r = run_worker(side, n, a.repeat, a.timeout)
            print(side, n, {k: v for k, v in r.items() if k != "x"}, flush=True)
    load1 = os.getloadavg()[0]
    print("load", load1, flush=True)

    def us(r: dict, key: str = "cpu_step") -> str:
        return f"{1e6 * r[key]:.1f}" if key in r else ("timeout" if "timeout" in r else "error")

    def first(r: dict) -> str:
        return f"{r['first']:.2f} s ({r['built']:.1f} s)" if "first" in r else "–"

    def diff(r: dict, ref: dict) -> str:
        if "x" not in r or "x" not in ref:
            return "–"
        x, y = np.asarray(r["x"]), np.asarray(ref["x"])
        return f"{np.abs(x - y).max() / np.abs(y).max():.1e}"

    lines = [HEADING, "",
             "Generated by `python benchmarks/ekf2_step.py` (its docstring says what each column runs): the "
             "second-order EKF (TT2) on the trackers of `benchmarks/peers.py`, its C step "
             "(`symmon.filters.gaussian._ekfstep`) against the MX step it replaced and against the EKF's C step; CPU time "
             "per step (best of the repeats, `time.process_time`: the step alone in its C loop, one run of 2000 steps; "
             "in parentheses `filter` of one run of K = 100 steps, with the call's cost) and first call into "
             f"a fresh cache (until the C is in). {platform.machine()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}; load average (1 min) before / after: {load0:.2f} / {load1:.2f}.", "",
             "| n | EKF2 C step µs | EKF2 MX step µs | MX / C | EKF C step µs | first call: EKF2 C / EKF2 MX "
             "| max rel. diff of x, C vs MX |",
             "|---|---|---|---|---|---|---|"]
    for n in sorted({n for _, n in res}):
        c, mx, e = res["ekf2 C", n], res["ekf2 MX", n], res["ekf C", n]
        ratio = (f"{mx['cpu_loop'] / c['cpu_loop']:.1f} ({mx['cpu_step'] / c['cpu_step']:.1f})"
                 if "cpu_step" in c and "cpu_step" in mx else "–")
        lines.append(f"| {c.get('n', n)} | {us(c, 'cpu_loop')} ({us(c)}) | {us(mx, 'cpu_loop')} ({us(mx)}) | {ratio} "
                     f"| {us(e, 'cpu_loop')} ({us(e)}) | {first(c)} / {first(mx)} "
                     f"| {diff(c, mx)} |")
    publish(lines, a.out, HEADING)


if __name__ == "__main__":
    main()
