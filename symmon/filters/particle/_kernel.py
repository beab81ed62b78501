"""The compiled recursion of the bootstrap particle filter: the K steps of a run in one C call.

For the bootstrap proposal (Gordon et al. 1993, §3) a step of :class:`~symmon.ParticleFilter`
is, per particle i of a run with log-weight ℓ_i (normalised) and standard normal draws z_i,

    x'_i = f(x_i, L_Q z_i)            (or f(x_i) + L_Q z_i for additive noise; angles wrapped),
    t_i  = ℓ_i + log N(y; h(x'_i), Γ R Γᵀ)   over the measured components of y,

then the log-sum-exp of t (the step's log-likelihood increment, Doucet et al. 2000, eq. (11)),
the normalised weights W_i = exp(t_i − lse), the weighted mean Σ W_i x'_i, the effective
sample size 1 / Σ W_i², and, when the ESS is low, a resampling with the gather of the
chosen particles (and, for the regularised filter, the kernel jitter h L ε).

``NAME_run`` does all K steps of one run without returning to Python.  Per step:

1. move and weigh, by blocks of :data:`BLOCK` particles: the block's normals from the
   :data:`~symmon.compile.rng.LANES` interleaved xoshiro streams (lanes) of its chunk of
   :data:`~symmon.filters.particle._rng.CHUNK` particles, drawn column by column, LANES particles
   at a time, by the vectorised ziggurat ``symmon_normal_lanes`` of :mod:`symmon.compile.rng`
   (particle i of a block takes lane i mod LANES; each lane's numbers are the scalar
   generator's from its state), the rows [x_i, z_i] stored by columns; then the transition, the measurement and the wrapped innovation ν_i of every row, by the
   vectorised loop of :func:`symmon.compile.vecmath.vector_rows` where f and h have one
   (a row it flags recomputed by CasADi's function), else by CasADi's function per
   particle; then the whitening A ν_i by the inverse Cholesky factor A of the measured
   block of Γ R Γᵀ (embedded with zero rows and columns for the missing components, whose
   ν_i, finite or not, never enter) and the log-density, by loops over the block; writing
   x'_i, t_i and each chunk's maximum m_q of t and a flag for a non-finite particle or
   weight; then, while the chunk's x' and t are in the cache, e'_i = exp(t_i − m_q) (by
   :mod:`symmon.compile.vecmath`'s vectorised exp, within 1 ulp) and the chunk's Σ e'_i,
   Σ e'_i², Σ e'_i x'_i (sines and cosines for angle states); no exponential overflows;
2. after the barrier, with m = max t, e_i = r_q e'_i for r_q = exp(m_q − m): the chunks'
   sums scaled by r_q (r_q² for Σ e²) are added in chunk order, so the result does not
   depend on the threads, and no second pass over x' and t is needed; e itself is rescaled only
   for the covariance and the regularisation;
3. the covariance and the predicted moments when kept (a pass each);
4. on resampling: the points (systematic: u + i, not stored, u drawn by every thread
   from its copy of the resampling stream, so no barrier; stratified, or sorted uniforms
   as normalised sums of exponential spacings for multinomial: O(N), no sort), then the walk along the
   cumulative weights c_j by input chunk (points ascending: O(N), no binary search).  For
   systematic points it goes by particle: particle j takes the points from the last one's
   end to the first i with u + i >= c_j, i = ⌈c_j − u⌉ moved until the points' own
   comparisons hold (a guess off by one only within rounding), so no branch depends on the
   weights and no chain of dependences runs from one particle to the next; other schemes go point by point, each chunk finding
   its first point by bisection; both make the same picks (tested).  The regularisation's
   jitter by output chunk.
   Without regularisation the pick is kept as indices and the next move reads the moved
   particles through them (the rows are copied once, at the end of the run), which saves
   the gather's read and write of the N x n particles each step.  After a resampling the
   log-weights, all −log N, are a flag, not written.

A single run runs on T threads (pthreads made by the call, a barrier at each reduction);
the moves and the walks go by chunks that the threads claim in turn from a counter (a
thread that is ahead takes more: the two cores of a virtual machine need not run at one
speed, and a walk's chunk holds as many points as its share of the weight: fixed ranges
left threads waiting at the barriers), the other passes by fixed contiguous chunk ranges; the C of a run never waits on Python's
thread pool.  Where the other core is busy two threads are slower than one (a thread waiting
for a CPU keeps the other at the barriers), so a run takes no more threads than
``/proc/loadavg`` leaves CPUs idle at the call (``pfk_idle_cpus``), a thread that has not
started 0.2 ms after the call does not join (``pfk_join``), and the threads note the CPU time
and the span of their moves: when their efficiency so far (CPU time / (T x span)) falls below
0.6 the run goes on in one thread (``pfk_solo``).  The numbers are the same whatever the
threads.  After a step without resampling the log-weights t_i − lse are written by the
next move (which reads t_i before it overwrites it), or at the end.
The chunk's own stream draws a Gaussian prior and the regularisation's jitter.
A flag that another thread may set (a Ctrl-C of the waiting thread:
:func:`~symmon.compile.compiled.run_stoppable`) is polled before each chunk of the moves, and
every thread sees it at the barrier after them: a run stops within a chunk's move, every
thread leaving at that barrier.
``_replay`` (tests) feeds given normals and points instead of drawing them.  A Gaussian
prior is drawn in C too, x_0 = m + L z from the first normals of each chunk's stream.
"""

from __future__ import annotations

import ctypes
import math
import re
import threading
from typing import Sequence

import casadi as ca
import numpy as np

from ...compile.ccache import NativeLibrary
from ...compile.ckernels import STOPPED
from ...compile.compiled import compiled_with_params
from ...compile.compiled import WorkArrays, generated_c
from ...compile.csource import c_defines, c_file
from ...compile.vecmath import VECMATH_C, vector_rows
from ...core.model import Model
from ...compile.rng import LANES, RNG_C
from ._rng import CHUNK

__all__ = ["BootstrapKernel", "bootstrap_kernel", "BLOCK", "MIN_THREAD_NUMBERS"]

_LOG_2PI = math.log(2 * math.pi)



def _compact(code: str) -> str:
    """C without its comments and indentation: they are for its reader, and the library's
    size, which decides a background build (a gcc time), is the code's."""
    return re.sub(r"^[ \t]+", "", re.sub(r"/\*.*?\*/", "", code, flags=re.S), flags=re.M)


# The recursion of one run (pf_kernel.c).
_DRIVER_C = c_file(__package__, "pf_kernel.c")

#: Particles per block of the move and weigh (the rows of a block by columns fit in L2).
BLOCK = 256
#: A run takes several threads (over its chunks) only from N (n + n_q) numbers drawn and
#: moved a step on: below, a step is tens of microseconds, and the barriers and the
#: threads' start would take a good part of what a second core saves.
MIN_THREAD_NUMBERS = 1 << 15
#: The column stride of a block's buffers: not a power of two, so that the columns of a row
#: (written one after another by the rows' loop) do not all fall in one set of the L1 cache;
#: at least BLOCK rounded up to LANES (the normals' last group of a block fills spare rows).
LD = BLOCK + 8
assert LD >= -(-BLOCK // LANES) * LANES
class BootstrapKernel:
    """The three compiled loops of a bootstrap step for the models f and h (module notes).

    Parameters
    ----------
    f_model, h_model : Model
    params : the filter's parameter names (f's, then h's that f does not have)
    Lq_pattern : bool (d, n_q), the structural nonzeros of L_Q (d: f's noise symbols, or n),
        n_q the draws per particle
    angle_states, angle_outputs : wrapped components
    vectorise : bool, default True
        Move and weigh through :func:`~symmon.compile.vecmath.vector_rows`'s loop where f
        and h have one (False: CasADi's function per particle, for comparisons)

    Notes
    -----
    The parameters of a call (one run) are packed by :meth:`pack`:
    p = [θ (the filter's parameters), the nonzeros of L_Q (column-major), y (missing: 0), mask (1: measured),
    vec(A) (column-major), c], with A the inverse Cholesky factor of the measured block of
    Γ R Γᵀ embedded with zeros and c = −(log det + m log 2π)/2 for the m measured components.
    """

    def __init__(self, f_model: Model, h_model: Model, params: Sequence, Lq_pattern: np.ndarray,
                 angle_states: Sequence[int], angle_outputs: Sequence[int], vectorise: bool = True) -> None:
        cf, ch = compiled_with_params(f_model), compiled_with_params(h_model)
        n, ny, npar = f_model.n_u, h_model.n_y, len(params)
        self.n, self.n_y, self.n_par = n, ny, npar
        # L_Q enters by its structural nonzeros only (a block-diagonal Q of 5 targets: 40 of
        # 400 products per particle), as parameters, so one C serves every Q of that pattern.
        self.Lq_pattern = pattern = np.asarray(Lq_pattern, dtype=bool)
        d, n_q = pattern.shape  # d: f's noise symbols, or n for additive noise
        self.n_q, nnz = n_q, int(pattern.sum())
        x, z = ca.SX.sym("x", n), ca.SX.sym("z", n_q)
        p = ca.SX.sym("p", npar + nnz + 2 * ny + ny * ny + 1)
        theta = p[:npar]
        col, row = np.nonzero(pattern.T)  # the nonzeros in column-major order, as CasADi stores them
        Lq = ca.SX(ca.Sparsity.triplet(d, n_q, row.tolist(), col.tolist()), p[npar:npar + nnz])
        o = npar + nnz
        y = p[o:o + ny]  # then the mask, vec(A) and c, which the C reads (pack's notes)
        self._o_mask, self._o_A = o + ny, o + 2 * ny

        def of(model: Model, cm, state, noise):
            th = [theta[list(params).index(s)] for s in model.params]
            return ca.substitute(cm.y_sx, cm.w_sx, ca.vertcat(state, *noise, *th))

        noise = ca.mtimes(Lq, z)
        xn = of(f_model, cf, x, [noise]) if f_model.n_v else of(f_model, cf, x, []) + noise
        xn = ca.vertcat(*[_wrap(xn[i]) if i in angle_states else xn[i] for i in range(n)])
        hx = of(h_model, ch, xn, [ca.SX.zeros(h_model.n_v)] if h_model.n_v else [])
        hx = ca.vertcat(*[_wrap(hx[i]) if i in angle_outputs else hx[i] for i in range(ny)])
        # the innovation, wrapped; the C whitens its measured components (a select on the
        # mask here would keep gcc from vectorising the row loop)
        nu = y - hx
        nu = ca.vertcat(*[_wrap(nu[i]) if i in angle_outputs else nu[i] for i in range(ny)])
        name = f"{cf.tag}_{ch.tag}_pfb" + "".join(f"_s{i}" for i in angle_states) + "".join(
            f"_o{i}" for i in angle_outputs)
        self.f = ca.Function(name, [x, z, p], [ca.densify(xn), ca.densify(nu), ca.densify(hx)], ["x", "z", "p"],
                             ["xn", "nu", "hx"], {"cse": True})
        self.n_p = p.numel()
        self._work = WorkArrays(self.f)
        self.angle_states = tuple(angle_states)
        # The same map as one output [x', ν, h(x')] of the rows [x, z] of a block
        # stored by columns, for the vectorised loop (None: an operation without a vector
        # form, e.g. sin): vector_rows reads input j of row i at z[i * n_in + j], so the
        # row's input is a vector whose entry j * LD is the row's entry j, with n_in = 1.
        cols = ca.SX.sym("r", (n + n_q - 1) * LD + 1)
        at = ca.vertcat(*[cols[j * LD] for j in range(n + n_q)])
        out = ca.substitute(ca.vertcat(xn, nu, hx), ca.vertcat(x, z), at)
        row = ca.Function(f"{name}_row", [cols, p], [out], {"cse": True})
        vec = vector_rows(row, f"{name}_vec", 1, LD) if vectorise else None
        #: True when the move and weigh run through the vectorised loop (module notes).
        self.vectorised = vec is not None
        flags = lambda idx, d: [int(i in idx) for i in range(d)]  # noqa: E731
        # The move of a block of nb rows [x_i, z_i] (by columns: x'_i, the wrapped innovation
        # ν_i, h(x'_i)): by the vectorised loop PFK_VEC when f and h have one, a row it flags
        # (an atan2 or hypot argument that is zero, inf, NaN or beyond 2^±500) recomputed by
        # CasADi's function (libm); else by CasADi's function row by row.  The weighted sums of
        # a particle's states: sines and cosines for angle states (PFK_ANGLES), else a loop
        # without a branch, which gcc vectorises.
        defines = c_defines(
            PFK_F=name, PFK_VEC=f"{name}_vec", PFK_NORMALS=f"{name}_normals", PFK_LANES=f"{name}_lanes",
            PFK_RUN=f"{name}_run", PFK_PICK=f"{name}_pick", PFK_SOLO=f"{name}_solo", PFK_VECTORISED=self.vectorised,
            PFK_ANGLES=bool(angle_states), PFK_NX=n, PFK_NQ=max(n_q, 1), PFK_NY=ny, PFK_N_P=self.n_p,
            PFK_DM=max(n, ny), PFK_CHUNK=CHUNK, PFK_AX=flags(angle_states, n), PFK_AY=flags(angle_outputs, ny),
            PFK_BLOCK=BLOCK, PFK_LD=LD, PFK_NR=n + max(n_q, 1), PFK_NO=n + 2 * ny, PFK_O_MASK=self._o_mask,
            PFK_O_A=self._o_A, PFK_SZ_ARG=max(self.f.sz_arg(), 3), PFK_SZ_RES=max(self.f.sz_res(), 3),
            PFK_STOPPED=STOPPED)
        code = _compact(RNG_C + generated_c(self.f) + VECMATH_C + (vec or "") + defines + _DRIVER_C)

        def load(so):
            lib = ctypes.CDLL(str(so))
            run = getattr(lib, f"{name}_run")
            run.argtypes = ([ctypes.c_void_p, ctypes.c_longlong, ctypes.c_longlong] + [ctypes.c_void_p] * 27
                            + [ctypes.c_longlong] * 3 + [ctypes.c_void_p] * 2)
            run.restype = ctypes.c_int
            normals = getattr(lib, f"{name}_normals")
            normals.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p]
            normals.restype = None
            lanes = getattr(lib, f"{name}_lanes")
            lanes.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p]
            lanes.restype = None
            pick = getattr(lib, f"{name}_pick")
            pick.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p]
            pick.restype = ctypes.c_int
            solo = getattr(lib, f"{name}_solo")
            solo.argtypes = [ctypes.c_double, ctypes.c_double, ctypes.c_int]
            solo.restype = ctypes.c_double
            return run, normals, lanes, pick, solo

        self._native: NativeLibrary = cf.native_library(code, name, load, stacklevel=4)
        self._Lq_size = nnz

    def loops(self):
        """The ctypes functions (run, normals, lanes, pick, solo), or None while the C is not there (no
        compiler, or a background build running: the caller takes the NumPy path)."""
        return self._native.get()

    def built_loops(self):
        """:meth:`loops` after a running build has ended: the NumPy path draws other numbers
        than the C (its own streams), so a seed's particles must not depend on whether the
        build had finished at the call; None only without compiled code (no compiler, the
        ``never`` policy, a failed build)."""
        self._native.wait()
        return self.loops()

    def pack(self, theta: np.ndarray | None, Lq: np.ndarray, Y: np.ndarray, white) -> np.ndarray:
        """The parameter vectors (R, K, n_p) of every run and step (class notes): θ (R, K,
        n_par) or None, L_Q, the measurements Y (R, K, n_y) with NaN for missing, and
        ``white(mask)`` → (A, c), the whitening of the measured components ``mask``."""
        R, K, ny = Y.shape
        p = np.zeros((R, K, self.n_p))
        o = self.n_par
        if o:
            p[..., :o] = theta
        p[..., o:o + self._Lq_size] = Lq.T[self.Lq_pattern.T]
        o += self._Lq_size
        measured = ~np.isnan(Y)
        p[..., o:o + ny] = np.where(measured, Y, 0.0)
        p[..., o + ny:o + 2 * ny] = measured
        o += 2 * ny
        flat = p.reshape(-1, self.n_p)
        if measured.all():  # the common case: one pattern
            A, c = white(np.ones(ny, dtype=bool))
            flat[:, o:o + ny * ny] = A.ravel(order="F")
            flat[:, -1] = c
            return p
        codes = np.packbits(measured.reshape(-1, ny), axis=1, bitorder="little")
        codes = codes.view(np.dtype((np.void, codes.shape[1]))).ravel()
        for code in np.unique(codes):
            rows = codes == code
            A, c = white(measured.reshape(-1, ny)[np.argmax(rows)])
            flat[rows, o:o + ny * ny] = A.ravel(order="F")
            flat[rows, -1] = c
        return p

    def work(self) -> tuple[int, int]:
        """This thread's work arrays (addresses)."""
        return self._work.addresses()


def _wrap(a: ca.SX) -> ca.SX:
    """:func:`symmon.core.angles.wrap_casadi` without its select, the same number to the bit.

    o = (a + π) − 2π ⌊(a + π)/2π⌋ − π lies in [−π, π] up to rounding (a little below −π
    for large |a|); d = o + π is exact near −π (Sterbenz), so d = 0 exactly where o = −π,
    and else 0 < |d| < 8, where ⌈|d|/8⌉ = 1.  Hence o + (1 − ⌈|d|/8⌉) 2π is o (o is never
    −0: x − π is +0 at zero, so o + 0 = o) or −π + 2π = π exactly (2π is π doubled); a NaN
    stays NaN.  gcc vectorises a loop with this form, not one with a select on a
    comparison (symmon.compile.vecmath's row loop).
    """
    two_pi = 2 * np.pi
    s = a + np.pi
    out = s - two_pi * ca.floor(s / two_pi) - np.pi
    return out + (1 - ca.ceil(ca.fabs(out + np.pi) / 8)) * two_pi


_kernels: dict[tuple, BootstrapKernel] = {}
_lock = threading.Lock()


def bootstrap_kernel(f_model: Model, h_model: Model, params: Sequence, Lq: np.ndarray,
                     angle_states: Sequence[int], angle_outputs: Sequence[int]) -> BootstrapKernel:
    """The kernel of these models for the nonzero pattern of ``Lq``, built once per process
    (by the models' structural keys and the pattern)."""
    pattern = np.asarray(Lq) != 0
    key = (f_model.key, h_model.key, tuple(str(s) for s in params), pattern.shape, pattern.tobytes(),
           tuple(angle_states), tuple(angle_outputs))
    with _lock:
        k = _kernels.get(key)
        if k is None:
            k = _kernels[key] = BootstrapKernel(f_model, h_model, params, pattern, angle_states, angle_outputs)
        return k


def whitening(S: np.ndarray, measured: np.ndarray) -> tuple[np.ndarray, float]:
    """A (n_y, n_y): the inverse Cholesky factor of S's measured block embedded with zeros,
    and c = −(log det S_m + m log 2π) / 2; S_m must be positive definite (checked by the
    filter when it is built)."""
    m = np.flatnonzero(measured)
    A = np.zeros_like(S)
    if m.size == 0:
        return A, 0.0
    L = np.linalg.cholesky(S[np.ix_(m, m)])
    A[np.ix_(m, m)] = np.linalg.inv(L)
    return A, float(-0.5 * (2 * np.log(np.diag(L)).sum() + m.size * _LOG_2PI))
