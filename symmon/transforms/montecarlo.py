"""Monte Carlo moments: single-pass, chunked, compiled, with error bars.

Samples are split into G independent *groups* (shards), each with its own stream from
``numpy.random.SeedSequence(seed).spawn(G)``: symmon's xoshiro256++ and ziggurat
(:class:`~symmon.compile.rng.NormalStream`, tag :data:`MC_STREAM_TAG`) when a C compiler is
in use, NumPy's SFC64 otherwise (:func:`normals_source`).  A group draws its samples chunk
by chunk; one compiled C call per chunk (:mod:`.mc_kernel`) draws the normals, maps them to
w = m + L z, evaluates g, centres the rows and sums AᵀA, the chunk's count, sums and
cross-products.
Only these sufficient statistics are kept, merged exactly with Chan's formula.  Memory is
independent of n, the result does not depend on the chunk size (beyond rounding), and
the groups can run on threads (the kernel releases the GIL) or on a Dask cluster with the
same result.  Standard errors come from the delete-one-group jackknife; with
``qmc=True`` each group is an independently scrambled Sobol' sequence, so the same
jackknife gives randomised-QMC error bars.

References
----------
T. F. Chan, G. H. Golub, R. J. LeVeque, "Algorithms for computing the sample variance",
The American Statistician 37(3), 1983. doi:10.1080/00031305.1983.10483115
A. B. Owen, "Scrambling Sobol' and Niederreiter-Xing points", J. Complexity 14, 1998.
"""

from __future__ import annotations

import threading
import warnings
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..compile.compiled import CompiledModel, compile_model
from ..compile.rng import NormalStream
from ..core.angles import wrap_angle
from ..errors import SamplingError, SymmonError, plain_repr
from .base import Moments, Transform, batch_sqrt, pilot_angle_cut
from .executor import Executor, _is_int, dask_compute, one_blas_thread, stop_point
from .mc_kernel import sample_kernel
from .stats import Stats, _raw_stats, jackknife, merge, merge_all, moments_of

__all__ = ["MonteCarlo", "group_generator", "group_normals", "group_sizes", "MC_STREAM_TAG", "normals_source", "MC_INNER", "MAX_SAMPLES", "MAX_GROUPS", "MAX_CHUNK", "MC_CHUNK",
           "MAX_QMC_GROUP"]

#: Most samples in a run: counts and the sums of a chunk stay exact in double precision.
MAX_SAMPLES = 2**53
#: Most groups: the jackknife keeps G stacks of d×d statistics (d = n_y + n_w + 2·angles) and
#: each group costs ~0.1 ms of bookkeeping; past a few hundred groups the error bars gain
#: little (their own relative error is ~1/√(2G)), so 10⁵ keeps memory and time on the samples.
MAX_GROUPS = 10**5
#: Most samples per kernel call: a thread's normals are chunk·n_w·8 bytes (its rows too,
#: chunk·(n_w + n_y + 2·angles + 1)·8, on CasADi's VM).
MAX_CHUNK = 2**20
#: Samples per kernel call by default: the compiled kernel keeps no rows (its blocks of
#: ``mc_kernel.BLOCK`` rows stay in L1), so a chunk costs chunk·n_w·8 bytes of normals per
#: thread; 2¹⁵ makes the Python work per chunk (drawing, merging) a few per cent of the
#: chunk (gmti.toml, 4·10⁶ samples: 0.39 s of CPU at 8192, 0.34 s at 2¹⁵, 0.32 s at 2¹⁷).
MC_CHUNK = 2**15
#: Most points per group with qmc=True: SciPy's Sobol' engine draws at most 2³⁰ (30 bits).
MAX_QMC_GROUP = 2**30


def group_generator(seed: np.random.SeedSequence) -> np.random.Generator:
    """The generator of one group: SFC64, NumPy's fastest bit generator of full statistical
    quality (its normals cost ~20 % less than PCG64's, the largest single cost per sample)."""
    return np.random.Generator(np.random.SFC64(seed))


#: The spawn-key entry that marks a Monte Carlo group's C normals among its seed's children.
MC_STREAM_TAG = 0x4D43524E  # "MCRN"


def normals_source(qmc: bool = False) -> str:
    """Where a run's normals come from: ``"qmc"``; ``"c"``, symmon's C stream of each group
    (:class:`~symmon.compile.rng.NormalStream`), when a C compiler is in use; else
    ``"numpy"``, the group's SFC64 generator (:func:`group_generator`)."""
    return "qmc" if qmc else ("c" if NormalStream.available() else "numpy")


def group_normals(seed: np.random.SeedSequence, n: int, d: int) -> np.ndarray:
    """The n × d normals that the group of ``seed`` draws with ``MonteCarlo(qmc=False)``, in
    order: its xoshiro256++ stream (tag :data:`MC_STREAM_TAG`, drawn by the compiled
    chunk itself) when a C compiler is in use, else its SFC64 generator.  For checks
    that replay a run."""
    if normals_source() == "c":
        return NormalStream(seed, MC_STREAM_TAG).fill(np.empty((n, d)))
    return group_generator(seed).standard_normal((n, d))


def group_sizes(n: int, G: int) -> list[int]:
    """n split over G groups as evenly as possible (the first n mod G get one more)."""
    return [n // G + (1 if g < n % G else 0) for g in range(G)]


@dataclass(frozen=True)
class _Job:
    mean: np.ndarray
    L: np.ndarray
    n: int
    seed: Any  # a SeedSequence
    qmc: bool
    chunk: int
    ref: np.ndarray  # reference output for angle unwrapping
    angles: tuple[int, ...]
    normals: str  # "c": symmon's C stream (group_normals); "numpy": SFC64 (no compiler); "qmc"


def _sampling_error_count(n_bad: int, w_bad: np.ndarray | None, m: int, done: int) -> SamplingError:
    """The error of a chunk of m samples ({done} drawn before it) with n_bad rows that are
    not finite, the first at input w_bad (None: no such row, the sums overflow)."""
    if w_bad is None:
        return SamplingError(
            f"Monte Carlo: the second moments of g overflow in a chunk of {m} samples "
            f"({done + m} drawn so far in this group): |y| is beyond ~1e154"
        )
    return SamplingError(
        f"Monte Carlo: g is NaN or inf at {n_bad} of {m} samples in a chunk "
        f"({done + m} drawn so far in this group); first bad sample w = {w_bad.tolist()}"
    )


def _sampling_error(A: np.ndarray, shift: np.ndarray, ny: int, nw: int, m: int, done: int) -> SamplingError:
    """:func:`_sampling_error_count` of the rows A (shifted by ``shift``) of a chunk."""
    bad = ~np.isfinite(A).all(axis=1)
    first = A[np.argmax(bad), ny: ny + nw] + shift[ny: ny + nw] if bad.any() else None
    return _sampling_error_count(int(bad.sum()), first, m, done)


def _run_group(cm: CompiledModel, job: _Job, stop: threading.Event | None = None) -> Stats:
    """One group: draw, evaluate with the compiled kernel, accumulate (count, mean, M2).

    Each chunk is centred on a shift s: the first chunk on its first sample, the later
    ones on the first chunk's mean.  A large offset (|E y| ≫ std) would otherwise cost its
    digits, and with the centred rows the raw cross-products AᵀA of a chunk lose nothing
    in M2 = Σ zzᵀ − n z̄z̄ᵀ (|z̄| ≈ σ·√(2/chunk): σ/64 at the default chunk).
    Chunks are merged with Chan's formula.  ``stop`` (see :func:`~.executor.run_groups`) is checked
    before each chunk.  With symmon's C normals (``job.normals == "c"``) the compiled
    chunk draws them itself (no normal is written to memory); on CasADi's VM, or above
    :data:`~.mc_kernel.FUSE_MAX_NW` inputs, the same stream fills a NumPy array first.
    """
    d = job.mean.shape[0]
    ny = cm.n_y
    kernel = sample_kernel(cm, job.angles)
    work = kernel.workspace()
    stream = None
    if job.qmc:
        from scipy.special import ndtri
        from scipy.stats import qmc

        engine = qmc.Sobol(d, scramble=True, seed=np.random.default_rng(job.seed))
    elif job.normals == "c":
        stream = NormalStream(job.seed, MC_STREAM_TAG)
    else:
        gen = group_generator(job.seed)
    rows = min(job.chunk, job.n)  # a group smaller than a chunk needs no more
    Zbuf: np.ndarray | None = None  # the normals, kept only when the kernel does not draw them
    Abuf: np.ndarray | None = None  # rows are kept only on CasADi's VM (no compiled kernel)
    fused = None
    shift = np.zeros(kernel.n_z)
    p = kernel.params(job.mean, job.L, shift, job.ref)
    acc: Stats | None = None
    done = 0
    while done < job.n:
        stop_point(stop)
        m = min(job.chunk, job.n - done)
        if fused is None:
            fused = kernel.chunk_stats(work)
        in_kernel = fused is not None and stream is not None  # the chunk draws its normals
        if not in_kernel:
            if Zbuf is None:
                Zbuf = np.empty((rows, d))
            Z = Zbuf[:m]
            if job.qmc:
                with warnings.catch_warnings():
                    # Chunks are powers of two and the total is one: the balance holds.
                    warnings.filterwarnings("ignore", message="The balance properties")
                    U = engine.random(m)
                eps = np.finfo(float).eps
                # ndtri is what norm.ppf evaluates (bit for bit), without its ~2x argument-checking overhead.
                ndtri(np.clip(U, eps, 1 - eps, out=U), out=Z)
            elif stream is not None:
                stream.fill(Z)
            else:
                gen.standard_normal(out=Z)
        if acc is None:
            # The first chunk is centred on its first sample (not drawn yet when the kernel draws).
            first = np.empty((1, kernel.n_out))
            kernel(stream.peek(np.empty((1, d))) if in_kernel else Z[:1], p, first, work)
            shift = first[0, :-1].copy()
            if not np.isfinite(shift).all():
                shift[:] = 0.0  # g fails at the first sample: leave the rows for the error count
            p = kernel.params(job.mean, job.L, shift, job.ref)
        if fused is None:  # CasADi's VM (or the map w = m + L z in NumPy): the rows, then one product
            if Abuf is None:
                Abuf = np.empty((rows, kernel.n_out))
            A = Abuf[:m]
            kernel(Z, p, A, work)
            with np.errstate(over="ignore", invalid="ignore"):  # reported just below, with the count
                S = A.T @ A
            if not np.isfinite(S).all():
                raise _sampling_error(A, shift, ny, d, m, done)
        else:  # one compiled call: the rows and their sums, no rows kept
            S, n_bad, _, z_bad = fused.draw(stream, p, m) if in_kernel else fused(Z, p)
            if n_bad or not np.isfinite(S).all():
                w_bad = None if n_bad == 0 else job.mean + job.L @ z_bad
                raise _sampling_error_count(n_bad, w_bad, m, done)
        s = _raw_stats(S)
        if acc is None:
            # Later chunks are centred on this chunk's mean: re-express it on that shift.
            new_shift = shift + s.mean
            acc = Stats(s.n, s.mean - (new_shift - shift), s.m2)
            shift = new_shift
            p = kernel.params(job.mean, job.L, shift, job.ref)
        else:
            acc = merge(acc, s)
        done += m
    assert acc is not None
    return Stats(acc.n, acc.mean + shift, acc.m2)


def _run_group_remote(outputs, symbols, job: _Job) -> Stats:
    # Workers compile the model themselves: CasADi functions are not shipped.  A Dask
    # worker runs several tasks at once on its threads: one BLAS thread each, as ours.
    with one_blas_thread():
        return _run_group(compile_model(outputs, symbols), job)

#: Inner samples per outer noise sample in the nested Monte Carlo of Cov_v E[g | v].
MC_INNER = 64


@dataclass(frozen=True)
class MonteCarlo(Transform):
    """Monte Carlo moments with standard errors.

    Parameters
    ----------
    n : int
        Number of samples (an integral float such as 1e6 is accepted), 2·groups to 2⁵³ (with ``qmc=True``, rounded to ``groups`` times
        a power of 2, at most 2³⁰ per group).
    seed : int or None
        Seed of ``numpy.random.SeedSequence``, a non-negative integer; the same seed gives
        the same result whatever the chunk size, the number of threads, or a Dask
        cluster (its normals: :func:`group_normals`; without a C compiler another draw,
        docs/compile.md).  ``None`` draws a fresh seed from the OS, kept in ``seed`` (and shown by
        ``repr``) so the run can be repeated.
    qmc : bool
        Scrambled Sobol' points through the inverse normal CDF instead of pseudo-random.
    groups : int
        Independent shards, 2 to 10⁵; the jackknife over them gives the error bars.
    chunk : int
        Samples per compiled kernel call, at most 2²⁰ (memory per thread ~ chunk · n_w · 8
        bytes; on CasADi's VM ~ chunk · (2 n_w + n_y + 1) · 8 bytes).

    Where the groups run (threads, Dask, progress) is not part of the method: pass an
    :class:`~symmon.Executor` to :func:`symmon.propagate` (``executor=``); the numbers do not
    depend on it.
    """

    n: int = 100_000
    seed: int | None = 0
    qmc: bool = False
    groups: int = 16
    chunk: int = MC_CHUNK

    exact_degree: ClassVar[float] = 0
    name: ClassVar[str] = "mc"
    presets: ClassVar[dict] = {
        "qmc": ("randomised quasi-Monte Carlo (scrambled Sobol' groups)",
                lambda samples, seed, groups, **_: MonteCarlo(samples, seed=seed, qmc=True, groups=groups)),
        "mc": ("Monte Carlo with jackknife standard errors",
               lambda samples, seed, groups, **_: MonteCarlo(samples, seed=seed, qmc=False, groups=groups)),
    }
    stochastic: ClassVar[bool] = True

    def __post_init__(self) -> None:
        limits = (
            ("n", MAX_SAMPLES, "2**53, where sample counts stop being exact in double precision"),
            ("groups", MAX_GROUPS, "10**5: more groups only add bookkeeping, not better error bars"),
            ("chunk", MAX_CHUNK, "2**20 samples per kernel call (a thread's buffers grow with it)"),
        )
        for k, most, why in limits:
            v = getattr(self, k)
            if isinstance(v, float) and v.is_integer():  # 1e6 is a count too
                v = int(v)
                object.__setattr__(self, k, v)
            if not _is_int(v) or v < 1:
                raise SymmonError(f"MonteCarlo {k} must be a positive integer, got {plain_repr(v)}")
            if v > most:
                raise SymmonError(f"MonteCarlo {k} = {v} is above the limit {why}")
        if self.groups < 2:
            raise SymmonError("MonteCarlo needs groups >= 2 for its error bars")
        if self.n < 2 * self.groups:
            raise SymmonError(f"MonteCarlo n = {self.n} is too small for {self.groups} groups (need >= {2 * self.groups})")
        if self.qmc and self.sizes()[0] > MAX_QMC_GROUP:
            raise SymmonError(f"MonteCarlo with qmc=True draws at most 2**30 points per group, "
                              f"but n = {self.n} over {self.groups} groups needs {self.sizes()[0]}: use more groups")
        if self.seed is None:
            # Fresh entropy, kept: the run can be repeated with the seed that repr shows.
            object.__setattr__(self, "seed", int(np.random.SeedSequence().entropy))
        elif not _is_int(self.seed) or self.seed < 0:
            raise SymmonError(f"MonteCarlo seed must be a non-negative integer or None, got {plain_repr(self.seed)}")
        else:
            object.__setattr__(self, "seed", int(self.seed))  # numpy integers too: one repr, one hash

    def sizes(self) -> list[int]:
        """Samples per group (QMC: a power of two each)."""
        if self.qmc:
            m = max(1, int(round(np.log2(self.n / self.groups))))
            return [2**m] * self.groups
        return group_sizes(int(self.n), int(self.groups))

    def cost(self, n_w: int) -> int:
        """The samples drawn (``n``, rounded with ``qmc=True``), whatever the dimension."""
        return sum(self.sizes())

    def check_angles(self, cm, means, covs, angles):
        """The kernel keeps no samples: check a pilot sample (:func:`pilot_angle_cut`)."""
        pilot_angle_cut(cm, means, covs, angles, self)

    def group_stats(self, cm: CompiledModel, mean: np.ndarray, cov: np.ndarray,
                    angles: frozenset[int] = frozenset(), executor: Executor | None = None) -> list[Stats]:
        """The statistics of z = [y; w; sin y_A; cos y_A] for each group, in group order
        (A: the angle outputs, unwrapped around g(E w); see :func:`~.stats.moments_of`)."""
        ex = executor or Executor()
        L = batch_sqrt(cov[None])[0]
        ref = cm.eval_g(mean[None])[0] if angles else np.zeros(cm.n_y)
        seeds = np.random.SeedSequence(self.seed).spawn(self.groups)
        chunk = int(self.chunk)
        if self.qmc:
            chunk = 1 << max(0, int(np.floor(np.log2(chunk))))  # powers of two keep Sobol' balanced
        normals = normals_source(self.qmc)  # one source for every group, local or remote
        jobs = [
            _Job(mean, L, n_g, s, self.qmc, chunk, ref, tuple(sorted(angles)), normals)
            for n_g, s in zip(self.sizes(), seeds)
        ]
        if ex.distributed:
            return self._dask(cm, jobs, ex)
        return ex.run(lambda j, stop: _run_group(cm, j, stop), jobs, "Monte Carlo groups")

    replicate_stats = group_stats

    def _dask(self, cm: CompiledModel, jobs: list[_Job], ex: Executor) -> list[Stats]:
        try:
            import dask
        except ImportError as exc:  # pragma: no cover - depends on the environment
            raise SymmonError("the Dask path needs the 'dask' extra: pip install symmon[dask]") from exc
        tasks = [dask.delayed(_run_group_remote)(cm.source_exprs, cm.symbols, j) for j in jobs]
        return dask_compute(tasks, ex.client, ex.scheduler, "Monte Carlo groups", ex.progress,
                            ex.worker_timeout)

    def semidefinite(self, n: int) -> bool:
        """True: a sample covariance (merged exactly over groups and chunks) is a sum of
        positive semi-definite terms."""
        return True

    def _moments(self, cm, means, covs, angles, executor):
        outs = [self._single(cm, m, P, angles, executor) for m, P in zip(means, covs)]
        return Moments(
            np.stack([o.mean for o in outs]), np.stack([o.cov for o in outs]),
            np.stack([o.cross_cov for o in outs]),
            input_cov=np.stack([o.input_cov for o in outs]),
            stderr={k: np.stack([o.stderr[k] for o in outs]) for k in outs[0].stderr},
            replicates=[o.replicates[0] for o in outs],
            evaluations=sum(o.evaluations for o in outs),
            details={"n_samples": outs[0].details["n_samples"]},
        )

    def _single(self, cm, mean, cov, angles, executor) -> Moments:
        groups = self.group_stats(cm, mean, cov, angles, executor)
        total = merge_all(groups)
        ny, nw, A = cm.n_y, cm.n_w, sorted(angles)
        mu, Cyy, Cyw, Cww = moments_of(total, ny, nw, A)

        def flat(loo: Stats) -> np.ndarray:
            # (E y, Cov y, Cov(y, w)) of every left-out set, as rows.
            m, c, x, _ = moments_of(loo, ny, nw, A)
            # An angle's mean near ±π must not jump by 2π between the left-out groups.
            m[:, A] = wrap_angle(m[:, A] - mu[A])
            G = m.shape[0]
            return np.concatenate([m, c.reshape(G, -1), x.reshape(G, -1)], axis=1)

        se = jackknife(groups, flat, total)
        stderr = {
            "mean": se[:ny],
            "cov": se[ny: ny + ny * ny].reshape(ny, ny),
            "cross_cov": se[ny + ny * ny:].reshape(ny, nw),
        }
        return Moments(mu, Cyy, Cyw, input_cov=Cww, stderr=stderr, replicates=[groups],
                       evaluations=total.n, details={"n_samples": total.n})

    def nested_stats(self, cm, u_mean, u_cov, v_mean, v_cov, executor=None) -> list[tuple[Stats, np.ndarray]]:
        """Nested Monte Carlo for Σ_c = Cov_v E[g | v], in ``groups`` independent groups.

        Each outer sample of v gets MC_INNER samples of u.  A group keeps the statistics
        of the inner means and the sum of the inner covariances; its streams are the
        children of the one ``SeedSequence(seed)`` child that the moments do not use.
        The groups run on the executor's threads (:func:`~.executor.run_groups`): the same result
        for any thread count, and Ctrl-C stops them within a chunk.

        Returns
        -------
        list of (Stats, ndarray)
            Per group: the statistics of the inner means and the sum of the inner
            sample covariances.
        """
        ex = executor or Executor()
        G = self.groups
        n_outer = max(2 * G, self.n // MC_INNER)
        seeds = np.random.SeedSequence(self.seed).spawn(G + 1)[-1].spawn(G)
        Lu, Lv = batch_sqrt(u_cov[None])[0], batch_sqrt(v_cov[None])[0]

        def group(job: tuple[int, np.random.SeedSequence], stop: threading.Event) -> tuple[Stats, np.ndarray]:
            return _nested_group(cm, u_mean, Lu, v_mean, Lv, *job, stop)

        return ex.run(group, list(zip(group_sizes(n_outer, G), seeds)), "nested Monte Carlo groups")


def _nested_group(cm: CompiledModel, u_mean: np.ndarray, Lu: np.ndarray, v_mean: np.ndarray, Lv: np.ndarray,
                  n_g: int, seed: np.random.SeedSequence, stop: threading.Event | None) -> tuple[Stats, np.ndarray]:
    """One group of :meth:`MonteCarlo.nested_stats`: n_g outer samples, in chunks."""
    gen = group_generator(seed)
    step = max(1, 65536 // MC_INNER)
    stats, var_sum = [], 0.0
    n_u, n_v = u_mean.shape[0], v_mean.shape[0]
    for start in range(0, n_g, step):
        stop_point(stop)
        k = min(step, n_g - start)
        V = v_mean + gen.standard_normal((k, n_v)) @ Lv.T
        U = u_mean + gen.standard_normal((k, MC_INNER, n_u)) @ Lu.T
        W = np.concatenate([U, np.repeat(V[:, None, :], MC_INNER, axis=1)], axis=2)
        Y = cm.eval_g(W.reshape(-1, W.shape[2])).reshape(k, MC_INNER, -1)
        mean_v = Y.mean(axis=1)
        R = Y - mean_v[:, None]
        var_sum = var_sum + np.einsum("kmi,kmj->ij", R, R) / (MC_INNER - 1)
        stats.append(Stats.of(mean_v))
    return merge_all(stats), var_sum
