"""Timings of mixture and particle moments against plain NumPy doing the same, in one run.

    python benchmarks/mixtures.py [--quick] [--max-exponent 6] [--out benchmarks/MIXTURES.md]

a. Gaussian mixtures, K = 1 … 64 components of the bearings-only state (n = 4, the bearing
   atan2(x, y) of (45) in Straka & Havlík 2024, with the range as a second output):
   ``sm.propagate(model, mixture, transform=UT.ut1())``, every component in one batch and
   mixed exactly, against NumPy computing the same: the ut1 sigma points of all K
   components at once (batched Cholesky), g written by hand in NumPy, the weighted moments
   per component and the same mixing.  Both give the same numbers (the largest relative
   difference is printed).
b. Particles, N = 10³ … 10⁶ (``--max-exponent 7`` adds 10⁷: 10⁷ × 4 doubles are 320 MB
   for the particles alone, and NumPy's arrays of N rows as much again): ``sm.propagate(model, sm.Empirical(X, w))``, chunked
   through the compiled model, against NumPy's ``g(X)`` and the weighted mean, covariance and
   cross-covariance in one pass of whole-array operations.  The peak of the memory
   allocated during the call beyond the particles (``tracemalloc``) shows symmon's flat
   buffers against NumPy's arrays of N rows.

Times are the best of several repeats after a warm-up call (``time.perf_counter``). The
machine may be shared: the load average is printed. Nothing here is asserted; the tests
check the numbers (tests/propagation/test_mixture_moments.py, test_particles.py).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import sympy as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import symmon as sm  # noqa: E402

x, y, vx, vy = sp.symbols("x y vx vy", real=True)
MODEL = sm.Model([x, y, vx, vy], [sp.atan2(x, y), sp.sqrt(x**2 + y**2)], name="bot_range")


def g_numpy(X: np.ndarray) -> np.ndarray:
    """The model by hand, rows of X (…, 4) to (…, 2)."""
    return np.stack([np.arctan2(X[..., 0], X[..., 1]), np.hypot(X[..., 0], X[..., 1])], axis=-1)


def mixture(K: int, rng: np.random.Generator) -> sm.GaussianMixture:
    """K components along the 45° bearing line between 200 m and 2 km (no wrap of the bearing)."""
    r = np.geomspace(200.0, 2000.0, K)
    d = np.array([np.sin(np.pi / 4), np.cos(np.pi / 4)])
    means = np.column_stack([np.outer(r, d), np.tile([5.0, 8.7], (K, 1))])
    covs = np.zeros((K, 4, 4))
    covs[:, :2, :2] = (0.1 * r)[:, None, None] ** 2 * np.outer(d, d) + (0.02 * r)[:, None, None] ** 2 * np.eye(2)
    covs[:, 2:, 2:] = np.eye(2)
    return sm.GaussianMixture(rng.dirichlet(np.ones(K)), means, covs)


def ut1_numpy(mix: sm.GaussianMixture) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ut1 moments of every component (batched) and their mixing, in NumPy."""
    w, M, P = mix.weights, mix.means, mix.covs
    K, n = M.shape
    kappa = 3.0 - n  # ut1: α = 1, β = 0, κ = 3 − n, so λ = κ
    L = np.linalg.cholesky(P) * np.sqrt(n + kappa)
    pts = np.concatenate([M[:, None], M[:, None] + np.swapaxes(L, 1, 2), M[:, None] - np.swapaxes(L, 1, 2)], axis=1)
    wm = np.full(2 * n + 1, 1 / (2 * (n + kappa)))
    wm[0] = kappa / (n + kappa)
    Y = g_numpy(pts)                                   # (K, 2n + 1, 2)
    m = np.einsum("j,kjy->ky", wm, Y)
    dY, dX = Y - m[:, None], pts - M[:, None]
    Pk = np.einsum("j,kja,kjb->kab", wm, dY, dY)
    Ck = np.einsum("j,kja,kjb->kab", wm, dY, dX)
    mean = w @ m
    d, e = m - mean, M - w @ M
    cov = np.einsum("k,kab->ab", w, Pk + d[:, :, None] * d[:, None, :])
    cross = np.einsum("k,kab->ab", w, Ck + d[:, :, None] * e[:, None, :])
    return mean, cov, cross


def weighted_numpy(X: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The weighted moments of y = g(x) over particles, in NumPy."""
    p = w / w.sum()
    Y = g_numpy(X)
    my, mx = p @ Y, p @ X
    dY, dX = Y - my, X - mx
    return my, (dY * p[:, None]).T @ dY, (dY * p[:, None]).T @ dX


def best(f, repeat: int) -> float:
    f()  # warm-up: compile, caches
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def peak_bytes(f) -> int:
    tracemalloc.start()
    f()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak


def rel_diff(a: tuple, b: tuple) -> float:
    return max(float(np.max(np.abs(np.asarray(u) - np.asarray(v)) / (np.abs(v) + 1e-300 + np.max(np.abs(v)))))
               for u, v in zip(a, b))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer sizes and repeats")
    ap.add_argument("--max-exponent", type=int, default=6, choices=range(3, 8),
                    help="the largest cloud is 10^this particles (default 6)")
    ap.add_argument("--out", type=Path, default=None, help="also write the tables to this Markdown file")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    repeat = 3 if args.quick else 7
    lines = [f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; best of {repeat}", "",
             "a. mixture moments, UT ut1, n = 4", "",
             "| K | symmon (ms) | NumPy (ms) | NumPy / symmon | max rel. diff |", "|---|---|---|---|---|"]
    ut = sm.UT.ut1()
    for K in (1, 2, 4, 8, 16, 32, 64):
        mix = mixture(K, rng)
        t_sm = best(lambda: sm.propagate(MODEL, mix, transform=ut), repeat)
        t_np = best(lambda: ut1_numpy(mix), repeat)
        m = sm.propagate(MODEL, mix, transform=ut)
        diff = rel_diff((m.mean, m.cov, m.cross_cov), ut1_numpy(mix))
        lines.append(f"| {K} | {1e3 * t_sm:.2f} | {1e3 * t_np:.2f} | {t_np / t_sm:.2f} | {diff:.1e} |")
    lines += ["", "b. particles, noise-free: weighted moments of g over the cloud", "",
              "| N | symmon (ms) | NumPy (ms) | NumPy / symmon | max rel. diff | peak extra MB symmon | NumPy |",
              "|---|---|---|---|---|---|---|"]
    sizes = [10**k for k in range(3, (5 if args.quick else args.max_exponent) + 1)]
    for N in sizes:
        X = mixture(8, rng).sample(N, rng)
        w = rng.uniform(0.5, 1.5, N)
        cloud = sm.Empirical(X, w)
        t_sm = best(lambda: sm.propagate(MODEL, cloud), repeat)
        t_np = best(lambda: weighted_numpy(X, w), repeat)
        m = sm.propagate(MODEL, cloud)
        diff = rel_diff((m.mean, m.cov, m.cross_cov), weighted_numpy(X, w))
        mem_sm = peak_bytes(lambda: sm.propagate(MODEL, cloud)) / 2**20
        mem_np = peak_bytes(lambda: weighted_numpy(X, w)) / 2**20
        lines.append(f"| {N:.0e} | {1e3 * t_sm:.1f} | {1e3 * t_np:.1f} | {t_np / t_sm:.2f} | {diff:.1e} | "
                     f"{mem_sm:.1f} | {mem_np:.1f} |")
    text = "\n".join(lines)
    print(text)
    if args.out is not None:
        args.out.write_text("# Mixture and particle moments (benchmarks/mixtures.py)\n\n" + text + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
