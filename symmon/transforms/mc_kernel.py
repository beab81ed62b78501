"""The compiled sampling kernel of Monte Carlo.

For a chunk of standard normal rows z, the rows are

    a = [g(w) − s_y;  w − s_w;  1],   w = m + L z,

where s is the shift that keeps the digits (see :mod:`.montecarlo`).  Angle outputs are
first unwrapped around a reference, y_i ← r_i + wrap(y_i − r_i), and their sines and
cosines are appended before the 1 (for the circular mean).  The sufficient statistics of
a chunk are AᵀA (count, sums, cross-products): one compiled call per chunk
(:meth:`SampleKernel.stats`, ``{name}_stats``) computes the rows a block of
:data:`BLOCK` at a time, by columns, and adds the block's cross-products, so no row
leaves the L1 cache; ``{name}_draw_stats`` (:meth:`ChunkStats.draw`) draws the block's
normals too, from a stream of :mod:`symmon.compile.rng`, so no normal leaves it either.
The rows themselves are written by :meth:`SampleKernel.__call__`.
The calls go through ctypes, which releases the GIL: the groups' threads run in parallel.

The row's arithmetic is a CasADi function built from the model's SX graph.  When all its
operations that depend on the row have vector forms (:func:`symmon.compile.vecmath.vector_rows`:
arithmetic, sqrt, floor, comparisons, selects, and atan2 and hypot within 1 ulp; those of
the chunk's parameters alone run once, before the loop), the block is one
loop that gcc vectorises; otherwise (sin, exp, pow, ...) CasADi's generated C runs per
row, with libm.  Without a C compiler, and while a large kernel is compiled in the
background (docs/compile.md), the same CasADi function is evaluated by CasADi's virtual
machine and NumPy forms AᵀA.
"""

from __future__ import annotations

import ctypes
import threading
import weakref
from typing import Sequence

import casadi as ca
import numpy as np

from ..core.angles import circle_point, wrap_casadi
from ..compile.ccache import NativeLibrary
from ..compile.compiled import CompiledModel, generated_c
from ..compile.csource import c_defines, c_file
from ..compile.rng import RNG_C, NormalStream
from ..compile.vecmath import VECMATH_C, vector_rows
from ..errors import ShapeError, SymmonError

__all__ = ["SampleKernel", "ChunkStats", "sample_kernel", "FUSE_MAX_NW", "BLOCK"]

#: Largest n_w whose affine map w = m + L z is compiled into the kernel (its C grows as n_w²).
FUSE_MAX_NW = 16

#: Rows per block of the compiled chunk (mc_kernel.c).
BLOCK = 256
#: The chunk's C (mc_kernel.c, whose opening comment describes it).
_CHUNK_DRIVER = c_file(__package__, "mc_kernel.c")


class SampleKernel:
    """z ↦ a = [g(w) − s_y; w − s_w; sin y_A − s_sin; cos y_A − s_cos; 1], w = m + L z,
    on the rows of a chunk.

    Parameters
    ----------
    cm : CompiledModel
    angles : indices A of the outputs that are angles.  They are unwrapped around
        ``ref``, and their sines and cosines are appended (all sines, then all cosines),
        so that the sample statistics give the circular mean as well.

    Notes
    -----
    The parameters of a call are packed as p = [m, vec(L) (column-major), s, ref], with
    s of length ``n_z`` = n_y + n_w + 2|A|; rows have ``n_out`` = n_z + 1 columns.  Above
    :data:`FUSE_MAX_NW` inputs the map w = m + L z is a NumPy (BLAS) product per call and
    the compiled function takes w and [s, ref], so its code grows with g, not with n_w².
    """

    def __init__(self, cm: CompiledModel, angles: Sequence[int] = ()) -> None:
        nw, ny = cm.n_w, cm.n_y
        angles = tuple(sorted(angles))
        self.n_w, self.n_y, self.angles = nw, ny, angles
        self.n_z = ny + nw + 2 * len(angles)
        self.n_out = self.n_z + 1
        self.n_p = nw + nw * nw + self.n_z + ny
        # Small models fuse the affine map into the kernel (one pass over the chunk); above
        # FUSE_MAX_NW its n_w² terms would dominate the generated C, so w = m + L z is one
        # BLAS product per chunk instead and the kernel starts at w.
        self.fused = nw <= FUSE_MAX_NW
        z = ca.SX.sym("z", nw)
        p = ca.SX.sym("p", self.n_p if self.fused else self.n_z + ny)
        if self.fused:
            m = p[:nw]
            L = ca.reshape(p[nw: nw + nw * nw], nw, nw)
            q = p[nw + nw * nw:]
            w = m + ca.mtimes(L, z)
        else:
            q, w = p, z
        s = q[: self.n_z]
        ref = q[self.n_z:]
        y = ca.substitute(cm.y_sx, cm.w_sx, w)
        sines, cosines = zip(*[circle_point(y[i]) for i in angles]) if angles else ((), ())
        if angles:
            y = ca.vertcat(*[ref[i] + wrap_casadi(y[i] - ref[i]) if i in angles else y[i] for i in range(ny)])
        zfull = ca.vertcat(y, w, *sines, *cosines)
        out = ca.densify(ca.vertcat(zfull - s, 1))
        tag = "_".join(["mc", *map(str, angles)])
        self.f = ca.Function(f"{cm.tag}_{tag}", [z, p], [out], ["z", "p"], ["a"])
        self.vectorised = False
        self._native = self._start(cm) if cm.compiled else None
        self._maps: dict[int, ca.Function] = {}
        self._lock = threading.Lock()

    @property
    def compiled(self) -> bool:
        """True when the kernel runs as compiled C now (else CasADi's virtual machine,
        for good or while its C is built in the background)."""
        return self._native is not None and self._native.get() is not None

    def _start(self, cm: CompiledModel) -> NativeLibrary:
        """The kernel's C library, built (now or in the background) by the compile policy."""
        f = self.f
        name = f.name()
        vec = vector_rows(f, f"{name}_vec", self.n_w, BLOCK)
        #: True when the rows run through the vectorised loop (every operation of g in
        #: :data:`~symmon.compile.vecmath.VECTOR_OPS`), False when through CasADi's C per row.
        self.vectorised = vec is not None
        defines = c_defines(
            MCK_F=name, MCK_VEC=f"{name}_vec", MCK_BLOCK_FN=f"{name}_block", MCK_ROWS=f"{name}_rows",
            MCK_SUMS=f"{name}_sums", MCK_START=f"{name}_start", MCK_SYMMETRIC=f"{name}_symmetric",
            MCK_STATS=f"{name}_stats", MCK_DRAW_STATS=f"{name}_draw_stats", MCK_VECTORISED=self.vectorised,
            MCK_BLOCK=BLOCK, MCK_N_IN=self.n_w, MCK_N_OUT=self.n_out, MCK_SZ_ARG=max(f.sz_arg(), 2),
            MCK_SZ_RES=max(f.sz_res(), 1), MCK_SZ_W=f.sz_w())
        code = RNG_C + generated_c(f) + (VECMATH_C + vec if vec else "") + defines + _CHUNK_DRIVER

        def load(so):
            lib = ctypes.CDLL(str(so))
            rows, stats = getattr(lib, f"{name}_rows"), getattr(lib, f"{name}_stats")
            draw = getattr(lib, f"{name}_draw_stats")
            rows.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_longlong] + [ctypes.c_void_p] * 2
            stats.argtypes = draw.argtypes = [ctypes.c_void_p] * 2 + [ctypes.c_longlong] + [ctypes.c_void_p] * 5
            rows.restype = stats.restype = draw.restype = ctypes.c_int
            return rows, stats, draw

        return cm.native_library(code, name, load, stacklevel=5)

    def params(self, mean: np.ndarray, L: np.ndarray, shift: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """Pack the parameters of a call."""
        return np.concatenate([mean, np.asarray(L, dtype=float).ravel(order="F"), shift, ref])

    def _work_size(self) -> int:
        # CasADi's work, a block of rows and one row, a block of normals (drawn in C).
        return self.f.sz_w() + (BLOCK + 1) * self.n_out + BLOCK * self.n_w

    def workspace(self) -> tuple[np.ndarray, np.ndarray]:
        """Work arrays for one thread (integer, real): CasADi's, then a block of rows and
        a block of normals."""
        return (np.zeros(max(self.f.sz_iw(), 1), dtype=np.int64), np.zeros(self._work_size()))

    def _checked(self, Z: np.ndarray, p: np.ndarray, out: np.ndarray | None, work) -> tuple:
        """Z and p as the compiled loop takes them (the map w = m + L z done here above
        :data:`FUSE_MAX_NW`), the loaded functions (or None) and the work arrays."""
        N = Z.shape[0]
        if (Z.shape != (N, self.n_w) or p.shape != (self.n_p,)
                or (out is not None and out.shape != (N, self.n_out))):
            raise ShapeError(
                f"sampling kernel: need Z (N, {self.n_w}), p ({self.n_p},) and out (N, {self.n_out}); "
                f"got Z {Z.shape}, p {p.shape}, out {None if out is None else out.shape}"
            )
        for name, a in (("Z", Z), ("p", p), ("out", out)):
            if a is None:
                continue
            if a.dtype != np.float64 or not a.flags.c_contiguous or (name == "out" and not a.flags.writeable):
                raise ShapeError(f"sampling kernel: {name} must be a C-contiguous float64 array"
                                 + (" that can be written" if name == "out" else ""))
        if not self.fused:
            nw = self.n_w
            L = p[nw: nw + nw * nw].reshape(nw, nw, order="F")
            Z = Z @ L.T
            Z += p[:nw]
            p = p[nw + nw * nw:]
        native = self._native.get() if self._native is not None else None
        if native is not None:
            iw, w = work if work is not None else self.workspace()
            if (iw.dtype != np.int64 or w.dtype != np.float64 or iw.size < self.f.sz_iw()
                    or w.size < self._work_size()
                    or not (iw.flags.c_contiguous and w.flags.c_contiguous)):
                raise ShapeError("sampling kernel: the work arrays must come from workspace()")
            work = (iw, w)
        return Z, p, native, work

    def __call__(self, Z: np.ndarray, p: np.ndarray, out: np.ndarray,
                 work: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Write the rows for ``Z`` (N, n_w) into ``out`` (N, ``n_out``).

        Both must be C-contiguous float64; ``p`` comes from :meth:`params`, ``work``
        from :meth:`workspace` (one per thread; made on the fly if omitted).
        """
        N = Z.shape[0]
        Z, p, native, work = self._checked(Z, p, out, work)
        if N == 0:
            return
        if native is not None:
            iw, w = work
            if native[0](Z.ctypes.data, p.ctypes.data, out.ctypes.data, N, iw.ctypes.data, w.ctypes.data):
                raise SymmonError(f"the compiled sampling kernel {self.f.name()} returned an error")
            return
        fb, ev = self._mapped(N).buffer()
        fb.set_arg(0, memoryview(Z))
        fb.set_arg(1, memoryview(p))
        fb.set_res(0, memoryview(out))
        ev()

    def stats(self, Z: np.ndarray, p: np.ndarray, work: tuple[np.ndarray, np.ndarray] | None = None
              ) -> tuple[np.ndarray, int, int, np.ndarray] | None:
        """S = AᵀA of the rows A for ``Z`` (as :meth:`__call__` writes them) in one compiled
        call that keeps no rows, the number of rows with a value that is not finite, the
        index of the first (-1: none) and its z; None while the kernel is not compiled.

        The sums are in a fixed order (``_CHUNK_DRIVER``): the same numbers on any CPU
        whose C compiler gives IEEE double arithmetic, whatever its vector width.
        """
        Z, p, native, work = self._checked(Z, p, None, work)
        if native is None:
            return None
        return ChunkStats(native[1:], self.n_out, self.n_w, work)(Z, p)

    def chunk_stats(self, work: tuple[np.ndarray, np.ndarray]) -> "ChunkStats | None":
        """:meth:`stats` for the chunks of one thread, with its arguments checked once (the
        fused map only: ``self.fused``), or None while the kernel is not compiled."""
        native = self._native.get() if self._native is not None else None
        if native is None or not self.fused:
            return None
        self._checked(np.zeros((0, self.n_w)), np.zeros(self.n_p), None, work)
        return ChunkStats(native[1:], self.n_out, self.n_w, work)

    def _mapped(self, N: int) -> ca.Function:
        with self._lock:
            fm = self._maps.get(N)
            if fm is None:
                fm = self._maps[N] = self.f.map(f"{self.f.name()}_map{N}", "serial", N, [1], [])
            return fm


class ChunkStats:
    """The compiled ``{name}_stats`` and ``{name}_draw_stats`` of one thread: (S, bad rows,
    first bad, its z) of a chunk, for given normals or for normals drawn in the kernel.

    The work arrays' addresses are taken once: per chunk, the Python cost is one ctypes
    call (NumPy's ``.ctypes`` of an array costs microseconds each).  Z and p must be
    C-contiguous float64 of the kernel's shapes (``SampleKernel._checked``)."""

    def __init__(self, fns, n_out: int, n_in: int, work: tuple[np.ndarray, np.ndarray]) -> None:
        self._stats, self._draw = fns
        self._work = work  # the pointers below are into these arrays: keep them alive
        self._S = np.zeros((n_out, n_out))
        self._bad = np.zeros(2, dtype=np.int64)
        self._zbad = np.zeros(n_in)
        self._ptrs = (self._S.ctypes.data, self._bad.ctypes.data, self._zbad.ctypes.data,
                      work[0].ctypes.data, work[1].ctypes.data)

    def _result(self, status: int) -> tuple[np.ndarray, int, int, np.ndarray]:
        if status:
            raise SymmonError("the compiled sampling kernel returned an error")
        return self._S.copy(), int(self._bad[0]), int(self._bad[1]), self._zbad.copy()

    def __call__(self, Z: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, int, int, np.ndarray]:
        return self._result(self._stats(Z.ctypes.data, p.ctypes.data, Z.shape[0], *self._ptrs))

    def draw(self, stream: NormalStream, p: np.ndarray, n: int) -> tuple[np.ndarray, int, int, np.ndarray]:
        """The same for the next n samples of ``stream`` (n·n_w normals, drawn in the kernel
        in the order :meth:`NormalStream.fill` writes them; the stream advances)."""
        return self._result(self._draw(stream.state.ctypes.data, p.ctypes.data, n, *self._ptrs))


_kernels: "weakref.WeakKeyDictionary[CompiledModel, dict[tuple[int, ...], SampleKernel]]" = weakref.WeakKeyDictionary()
_kernels_lock = threading.Lock()


def sample_kernel(cm: CompiledModel, angles: Sequence[int] = ()) -> SampleKernel:
    """The kernel of ``cm`` for these angle outputs, built once per model and angle set."""
    key = tuple(sorted(angles))
    with _kernels_lock:
        per_model = _kernels.setdefault(cm, {})
        k = per_model.get(key)
        if k is None:
            k = per_model[key] = SampleKernel(cm, key)
        return k
