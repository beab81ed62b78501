"""Timings of symmon's particle filter against a hand-vectorised NumPy bootstrap filter and
Stone Soup's particle filter, in one run.

    python benchmarks/particle.py [--quick] [--sections table growth threads] [--out benchmarks/RESULTS.md]

Three sections, each its own heading in RESULTS.md (``--sections`` picks; all by default):
``table``, the table below; ``growth``, the one-state growth model against the NumPy
filter (:func:`run_growth`); ``threads``, one thread against two at 4 and 20 states
(:func:`run_threads`).  The last two give medians over interleaved repeats, wall and CPU
time, and the load average before and after; rerun them on an idle machine with
``python benchmarks/particle.py --sections growth threads --out benchmarks/RESULTS.md``.

The model, the same in the three: m targets with constant velocity (n = 4m states ordered
[x, vx, y, vy] per target, as Stone Soup's ``ConstantVelocity``, dt = 1, noise intensity
q = 0.05), measured in bearing and range of the first target (additive noise, the bearing
an angle: wrapped innovation).  n = 4 (m = 1) and n = 20 (m = 5); N = 10³, 10⁴, 10⁵
particles; K steps from a Gaussian prior; the bootstrap proposal with systematic resampling
at every step (``ess_threshold=1``; Stone Soup's ``SystematicResampler``).  symmon keeps only
``x`` (``keep=("x",)``); the NumPy filter computes the same weighted mean.  Times per step,
best of the repeats after a warm-up (symmon and NumPy 5, 3 at N = 10⁵; Stone Soup 3, 2, 1 at
N = 10³, 10⁴, 10⁵; the peers on one OpenBLAS thread, see PEER_BLAS_THREADS), symmon and NumPy interleaved (wall time and process CPU time, all threads); symmon's first call apart (after ``sm.simulate``
compiled f and h into a fresh cache; ``SYMMON_COMPILE=sync``, so that it includes the C build of the compiled step).  Ratios: peer / symmon (> 1: symmon faster).  The load average is recorded: the
machine may be shared.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
os.environ.setdefault("SYMMON_CACHE", tempfile.mkdtemp(prefix="symmon-bench-particle-"))
# The first call waits for the C (else a step larger than BACKGROUND_BYTES, n = 20 here, is
# built in the background and the timed calls may run the NumPy path meanwhile).
os.environ.setdefault("SYMMON_COMPILE", "sync")

import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402

import symmon as sm  # noqa: E402
from report import best_wall_cpu, fmt, write_section  # noqa: E402

HEADING = "## Particle filter"
# The NumPy and Stone Soup filters run on one OpenBLAS thread (threadpoolctl): their products
# of N x n by n x n matrices are no slower on one (measured equal or faster, e.g. Stone Soup
# at n = 20, N = 10⁴: 14.5 against 17–19 ms a step), and OpenBLAS's threads spin for about
# 0.1 s after a product, sharing the cores with the next timed call (symmon's 10⁵-particle
# step measured 4.0–4.8 ms right after a NumPy call on its threads, 2.4–2.9 ms 0.3 s later).
PEER_BLAS_THREADS = 1
Q_INTENSITY = 0.05
NOISE = (0.02, 0.5)  # bearing (rad), range


def scenario(m: int):
    """symmon's models, Q, R, prior and the measurements of one simulated run."""
    X = sp.symbols(" ".join(f"x{i} vx{i} y{i} vy{i}" for i in range(m)), real=True)
    f_out = []
    for i in range(m):
        x, vx, y, vy = X[4 * i:4 * i + 4]
        f_out += [x + vx, vx, y + vy, vy]
    f = sm.Model(X, f_out, name=f"pf_bench_cv{m}")
    h = sm.Model(X, [sp.atan2(X[2], X[0]), sp.sqrt(X[0] ** 2 + X[2] ** 2)], angles=[0], name=f"pf_bench_br{m}")
    q = Q_INTENSITY * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    Q = np.kron(np.eye(2 * m), q)
    R = np.diag(np.square(NOISE))
    mean = np.tile([20.0, -1.0, 5.0, 0.5], m)
    x0 = sm.Gaussian(mean, np.diag(np.tile([1.0, 0.1, 1.0, 0.1], m)))
    return f, h, Q, R, x0


def numpy_pf(ys, x0, Q, R, N, seed=0):
    """The hand-vectorised NumPy bootstrap filter: the weighted mean of each step."""
    rng = np.random.default_rng(seed)
    n = x0.dim
    F = np.kron(np.eye(n // 4), np.kron(np.eye(2), [[1.0, 1.0], [0.0, 1.0]]))
    Lq = np.linalg.cholesky(Q)
    Rinv = np.linalg.inv(R)
    X = x0.mean + rng.standard_normal((N, n)) @ x0.sqrt_cov().T
    out = np.empty((len(ys), n))
    for k, y in enumerate(ys):
        X = X @ F.T + rng.standard_normal((N, n)) @ Lq.T
        nu = np.column_stack([np.arctan2(X[:, 2], X[:, 0]), np.hypot(X[:, 0], X[:, 2])])
        nu = y - nu
        nu[:, 0] = np.mod(nu[:, 0] + np.pi, 2 * np.pi) - np.pi
        logw = -0.5 * np.einsum("ni,ij,nj->n", nu, Rinv, nu)
        w = np.exp(logw - logw.max())
        w /= w.sum()
        out[k] = w @ X
        u = (rng.random() + np.arange(N)) / N
        idx = np.minimum(np.searchsorted(np.cumsum(w), u), N - 1)
        X = X[idx]
    return out


def ungm_scenario(K: int):
    """The univariate nonstationary growth model (issue 51; ``symmon.reproduce.select``'s
    ``ungm``): x' = x/2 + 25x/(1 + x²) + 8 cos 1.2k + w, y = x²/20 + e, Q = 10, R = 1,
    x_0 ~ N(0, 5), k a per-step parameter; the measurements of one simulated run."""
    x, k = sp.symbols("x k", real=True)
    f = sm.Model([x], [x / 2 + 25 * x / (1 + x**2) + 8 * sp.cos(sp.Rational(6, 5) * k)], params=[k],
                 name="pf_bench_ungm_f")
    h = sm.Model([x], [x**2 / 20], name="pf_bench_ungm_h")
    x0 = sm.Gaussian([0.0], [[5.0]])
    params = {"k": np.arange(1, K + 1, dtype=float)}
    _, ys = sm.simulate(f, h, [[10.0]], [[1.0]], x0, K, params=params, seed=1)
    return f, h, x0, params, ys


def numpy_ungm(ys, N, seed=0):
    """The hand-vectorised NumPy bootstrap filter of the growth model (systematic resampling
    at every step): the weighted mean of each step."""
    rng = np.random.default_rng(seed)
    X = np.sqrt(5.0) * rng.standard_normal(N)
    sq = np.sqrt(10.0)
    out = np.empty(len(ys))
    ar = np.arange(N)
    for k, y in enumerate(ys[:, 0], start=1):
        X = X / 2 + 25 * X / (1 + X * X) + 8 * np.cos(1.2 * k) + sq * rng.standard_normal(N)
        nu = y - X * X / 20
        logw = -0.5 * nu * nu
        w = np.exp(logw - logw.max())
        w /= w.sum()
        out[k - 1] = w @ X
        idx = np.minimum(np.searchsorted(np.cumsum(w), (rng.random() + ar) / N), N - 1)
        X = X[idx]
    return out


def timed(fn) -> tuple[float, float]:
    """Wall and process CPU time (all threads) of one call."""
    t, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t, time.process_time() - c


def med(xs) -> float:
    return float(np.median(xs))


def run_growth(quick: bool) -> str:
    """The one-state particle filter (issue 51, item 1): symmon against the NumPy filter
    on the growth model, interleaved, N = 10⁴ and 10⁵, K = 50 steps, resampling at every
    step; medians (and least) of the repeats' per-step times, wall and CPU."""
    K = 10 if quick else 50
    f, h, x0, params, ys = ungm_scenario(K)
    rows = []
    load0 = os.getloadavg()
    for N in ((10**4,) if quick else (10**4, 10**5)):
        pf = sm.ParticleFilter(f, h, [[10.0]], [[1.0]], particles=N, ess_threshold=1.0)
        call = lambda: pf.filter(ys, x0, params=params, keep=("x",))  # noqa: E731
        call()
        numpy_ungm(ys, N)
        reps = 5 if quick else (21 if N < 10**5 else 11)
        a, b = [], []
        for _ in range(reps):  # interleaved: both see the same load
            a.append(timed(call))
            b.append(timed(lambda: numpy_ungm(ys, N)))
        a, b = np.array(a) / K, np.array(b) / K
        diff = float(np.abs(call().x[:, 0] - numpy_ungm(ys, N)).max())
        rows.append((N, a, b, diff, pf._bootstrap_kernel.vectorised))
        print(N, med(a[:, 0]), med(b[:, 0]), os.getloadavg(), flush=True)
    load1 = os.getloadavg()
    lines = ["## Particle filter: one state (growth model)", "",
             "Generated by `python benchmarks/particle.py --sections growth` (`run_growth`): the growth model "
             "x' = x/2 + 25x/(1 + x²) + 8 cos 1.2k + w, y = x²/20 + e (Q = 10, R = 1, x₀ ~ N(0, 5), k a per-step "
             f"parameter), K = {K} steps, systematic resampling at every step, symmon keeping `x`, against the "
             "hand-vectorised NumPy bootstrap filter (`numpy_ungm`), the two interleaved in one process; per-step "
             "times, median (least) of the repeats; CPU: the process's, all threads. Ratios NumPy / symmon. "
             f"Target (issue 51): ≥ 3× at N = 10⁴ and 10⁵. x86_64, {os.cpu_count()} cores; load average (1, 5, 15 "
             f"min) before: {load0[0]:.2f}, {load0[1]:.2f}, {load0[2]:.2f}; after: {load1[0]:.2f}, {load1[1]:.2f}, "
             f"{load1[2]:.2f}.", "",
             "| N | symmon wall / step | NumPy wall / step | NumPy / symmon (wall) | symmon CPU / step | NumPy CPU / step "
             "| NumPy / symmon (CPU) | symmon ns per particle-step (CPU) | vector loop | max |x̂ − x̂_NumPy| |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for N, a, b, diff, vec in rows:
        lines.append(f"| {N:.0e} | {fmt(med(a[:, 0]))} ({fmt(a[:, 0].min())}) | {fmt(med(b[:, 0]))} ({fmt(b[:, 0].min())}) "
                     f"| {med(b[:, 0]) / med(a[:, 0]):.2f}× | {fmt(med(a[:, 1]))} | {fmt(med(b[:, 1]))} "
                     f"| {med(b[:, 1]) / med(a[:, 1]):.2f}× | {med(a[:, 1]) / N * 1e9:.1f} | {'yes' if vec else 'no'} "
                     f"| {diff:.2g} |")
    return "\n".join(lines) + "\n"


def run_threads(quick: bool) -> str:
    """The PF's second thread (issue 51, item 2): one run on one thread (the threshold
    ``MIN_THREAD_NUMBERS`` raised) against two (the default, with the fallback to one when
    the other core is busy) and two without the fallback, interleaved, n = 4 and 20,
    N = 10⁴ and 10⁵, K = 20; medians of the per-step times."""
    import symmon.filters.particle.particle_filter as pfm

    K = 5 if quick else 20
    orig = pfm.MIN_THREAD_NUMBERS
    rows = []
    load0 = os.getloadavg()
    for m in (1, 5):
        f, h, Q, R, x0 = scenario(m)
        _, ys = sm.simulate(f, h, Q, R, x0, K, seed=1)
        for N in ((10**4,) if quick else (10**4, 10**5)):
            pf = sm.ParticleFilter(f, h, Q, R, particles=N, ess_threshold=1.0)
            pf.filter(ys, x0, keep=("x",))
            solo = pf._bootstrap_kernel.built_loops()[4]
            reps = 5 if quick else (15 if N < 10**5 else 9)
            got = {"one": [], "two": [], "two, no fallback": []}
            for _ in range(reps):
                for key in got:
                    pfm.MIN_THREAD_NUMBERS = 1 << 62 if key == "one" else orig
                    was = solo(0.0, 1e10, 0) if key == "two, no fallback" else None
                    try:
                        got[key].append(timed(lambda: pf.filter(ys, x0, keep=("x",))))
                    finally:
                        pfm.MIN_THREAD_NUMBERS = orig
                        if was is not None:
                            solo(was, 2e5, 1)
            rows.append((4 * m, N, {k: np.array(v) / K for k, v in got.items()}, os.getloadavg()[0]))
            print(rows[-1][:2], {k: med(v[:, 0]) for k, v in rows[-1][2].items()}, rows[-1][3], flush=True)
    load1 = os.getloadavg()
    lines = ["## Particle filter: two threads", "",
             "Generated by `python benchmarks/particle.py --sections threads` (`run_threads`): the model of the "
             f"table above (n = 4 and 20), K = {K} steps, resampling at every step, one run on one thread (`one`), "
             "on two as by default (`two`: no second thread when /proc/loadavg counts no idle CPU at the call; a thread "
             "that has not started 0.2 ms after the call does not join the run; "
             "and the run falls back to one thread when the threads' CPU time in the moves falls below 0.6 × 2 × "
             "their span; pf_kernel.c's `pfk_idle_cpus`, `pfk_join`, `pfk_solo`), and on two without these (as before "
             "issue 51), "
             "interleaved; per-step times, "
             "medians. Targets (issue 51): two threads ≥ 1.5× one at n = 20, N ≥ 10⁴ on an idle machine (load "
             "below 0.5); never slower than one, loaded or not. "
             f"x86_64, {os.cpu_count()} cores; load average (1, 5, 15 min) before: {load0[0]:.2f}, {load0[1]:.2f}, "
             f"{load0[2]:.2f}; after: {load1[0]:.2f}, {load1[1]:.2f}, {load1[2]:.2f}.", "",
             "| n | N | one: wall (CPU) / step | two: wall (CPU) / step | two, no fallback: wall (CPU) / step "
             "| one / two (wall) | one / two, no fallback (wall) | load (1 min) after the row |",
             "|---|---|---|---|---|---|---|---|"]
    for n, N, got, load in rows:
        one, two, raw = (got[k] for k in ("one", "two", "two, no fallback"))
        lines.append(f"| {n} | {N:.0e} | {fmt(med(one[:, 0]))} ({fmt(med(one[:, 1]))}) | {fmt(med(two[:, 0]))} "
                     f"({fmt(med(two[:, 1]))}) | {fmt(med(raw[:, 0]))} ({fmt(med(raw[:, 1]))}) "
                     f"| {med(one[:, 0]) / med(two[:, 0]):.2f}× | {med(one[:, 0]) / med(raw[:, 0]):.2f}× | {load:.2f} |")
    return "\n".join(lines) + "\n"


def stonesoup_pf(ys, x0, m, N, seed=0):
    """Stone Soup's predictor, updater and systematic resampler on the same model."""
    from stonesoup.models.measurement.nonlinear import CartesianToBearingRange
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.particle import ParticlePredictor
    from stonesoup.resampler.particle import SystematicResampler
    from stonesoup.types.array import StateVectors
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import ParticleState
    from stonesoup.updater.particle import ParticleUpdater

    np.random.seed(seed)  # Stone Soup draws from NumPy's global generator
    n = 4 * m
    tm = CombinedLinearGaussianTransitionModel([ConstantVelocity(Q_INTENSITY) for _ in range(2 * m)])
    mm = CartesianToBearingRange(ndim_state=n, mapping=(0, 2), noise_covar=np.diag(np.square(NOISE)))
    predictor = ParticlePredictor(tm)
    updater = ParticleUpdater(mm, resampler=SystematicResampler())
    t = datetime.datetime(2024, 1, 1)
    X = x0.sample(N, np.random.default_rng(seed))
    state = ParticleState(StateVectors(X.T), weight=np.full(N, 1.0 / N), timestamp=t)
    out = np.empty((len(ys), n))
    for k, y in enumerate(ys):
        t = t + datetime.timedelta(seconds=1)
        pred = predictor.predict(state, timestamp=t)
        det = Detection(np.array([[y[0]], [y[1]]]), timestamp=t, measurement_model=mm)
        state = updater.update(SingleHypothesis(pred, det))
        out[k] = np.asarray(state.mean, dtype=float).ravel()
    return out


def best(fn, repeats: int) -> float:
    return best_wall_cpu(fn, repeats)[0]






def run(quick: bool) -> str:
    try:
        import stonesoup  # noqa: F401
        have_ss = True
    except ImportError:
        have_ss = False
    K = 5 if quick else 20
    sizes = (10**3, 10**4) if quick else (10**3, 10**4, 10**5)
    load0 = os.getloadavg()[0]
    rows = []
    for m in (1, 5):
        f, h, Q, R, x0 = scenario(m)
        _, ys = sm.simulate(f, h, Q, R, x0, K, seed=1)
        for N in sizes:
            pf = sm.ParticleFilter(f, h, Q, R, particles=N, ess_threshold=1.0)
            t = time.perf_counter()
            pf.filter(ys, x0, keep=("x",))
            first = time.perf_counter() - t
            reps = 5 if N < 10**5 else 3
            t_sm, c_sm, t_np, c_np = np.inf, np.inf, np.inf, np.inf
            for _ in range(reps):  # interleaved: both see the same load
                w, c = best_wall_cpu(lambda: pf.filter(ys, x0, keep=("x",)), 1)
                t_sm, c_sm = min(t_sm, w / K), min(c_sm, c / K)
                w, c = best_wall_cpu(lambda: numpy_pf(ys, x0, Q, R, N), 1)
                t_np, c_np = min(t_np, w / K), min(c_np, c / K)
            t_ss = None
            if have_ss and N <= 10**4 * (1 if quick else 10):
                stonesoup_pf(ys[:2], x0, m, N)  # warm-up (imports)
                t_ss = best(lambda: stonesoup_pf(ys, x0, m, N), {10**3: 3, 10**4: 2}.get(N, 1)) / K
            # agreement: the three are Monte Carlo estimates with their own draws
            a = pf.filter(ys, x0, keep=("x",)).x
            b = numpy_pf(ys, x0, Q, R, N)
            rows.append((4 * m, N, first, t_sm, t_np, t_ss, float(np.abs(a - b)[:, 0].max()), c_sm, c_np))
            print(rows[-1], flush=True)
    load1 = os.getloadavg()[0]
    lines = [HEADING, "",
             "Generated by `python benchmarks/particle.py` (its docstring gives the model): the bootstrap particle "
             f"filter, systematic resampling at every step, K = {K} steps, per-step times (best of the repeats, warm: symmon and NumPy 5, 3 at N = 10⁵; Stone Soup 3, 2, 1 at N = 10³, 10⁴, 10⁵); NumPy and Stone Soup on one OpenBLAS thread (no slower on one here; its threads would otherwise spin beside the next timed call). "
             "symmon's first call is its first filter call, after `sm.simulate` compiled f and h into a fresh cache (it "
             "includes the C build of the PF's compiled step, once per model: the first N of each n). Ratios: peer / symmon (> 1: symmon faster). "
             "Targets (issue 35): NumPy / symmon ≥ 3 and Stone Soup / symmon ≥ 30 at every size. "
             f"x86_64, {os.cpu_count()} cores; load average before / after: "
             f"{load0:.2f} / {load1:.2f}.", "",
             "| n | N | symmon first call | symmon / step | NumPy / step | Stone Soup / step | NumPy / symmon | "
             "Stone Soup / symmon | CPU / step: symmon, NumPy (ratio) | |x̂_symmon − x̂_NumPy| (px, max over steps) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for n, N, first, a, b, c, d, ca, cb in rows:
        ss = "not run" if c is None else fmt(c)
        ratio = "—" if c is None else f"{c / a:.1f}×"
        cpu = f"{fmt(ca)}, {fmt(cb)} ({cb / ca:.2f}×)"
        lines.append(f"| {n} | {N:.0e} | {fmt(first)} | {fmt(a)} | {fmt(b)} | {ss} | {b / a:.2f}× | {ratio} | {cpu} | "
                     f"{d:.2g} |")
    return "\n".join(lines) + "\n"




def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="K = 5, N ≤ 1e4")
    parser.add_argument("--sections", nargs="+", choices=("table", "growth", "threads"),
                        default=["table", "growth", "threads"], help="the sections to run (default: all)")
    parser.add_argument("--out", type=Path, help="write the sections into this Markdown file")
    args = parser.parse_args()
    from threadpoolctl import threadpool_limits
    runs = {"table": run, "growth": run_growth, "threads": run_threads}
    for name in args.sections:
        with threadpool_limits(PEER_BLAS_THREADS):  # the peers' products (symmon's PF calls no BLAS)
            text = runs[name](args.quick)
        print(text)
        if args.out:
            write_section(args.out, text)


if __name__ == "__main__":
    main()
