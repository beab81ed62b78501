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
operations have vector forms (:func:`symmon.compile.vecmath.vector_rows`: arithmetic,
sqrt, floor, comparisons, selects, and atan2 and hypot within 1 ulp), the block is one
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
from ..compile.rng import RNG_C, NormalStream
from ..compile.vecmath import VECMATH_C, vector_rows
from ..errors import ShapeError, SymmonError

__all__ = ["SampleKernel", "ChunkStats", "sample_kernel", "FUSE_MAX_NW", "BLOCK"]

#: Largest n_w whose affine map w = m + L z is compiled into the kernel (its C grows as n_w²).
FUSE_MAX_NW = 16

# The compiled chunk: blocks of BLOCK rows, each computed into a block by columns (blk,
# BLOCK × n_out, after CasADi's work array w), by the vectorised loop {name}_vec when g has
# one (symmon.compile.vecmath; a row it flags, an atan2 or hypot argument that is zero, inf,
# NaN or beyond 2^±500, is recomputed by CasADi's function, that is, by libm) or else by
# CasADi's function row by row.  {name}_rows writes the rows out; {name}_stats sums the
# blocks' cross-products into S (n_out × n_out, symmetric): per entry, sixteen
# partial sums over the rows i ≡ 0, 1, …, 15 (mod 16) added in a fixed order (four
# vectors of AVX2: their additions do not wait for each other), so the numbers
# do not depend on the vector width, and gcc vectorises them.  Rows with a value that is
# not finite are counted (bad[0]) and the first is named (bad[1]).
BLOCK = 256
_BLOCK_FILL = {
    True: """
  if ({name}_vec(z, p, blk, m, odd) == 0) return 0;
  for (i = 0; i < m; ++i) {{
    if (!odd[i]) continue;
    arg[0] = z + i * {n_in}; res[0] = row;
    if ({name}(arg, res, iw, w, 0)) return 1;
    for (k = 0; k < {n_out}; ++k) blk[k * {block} + i] = row[k];
  }}""",
    False: """
  for (i = 0; i < m; ++i) {{
    arg[0] = z + i * {n_in}; res[0] = row;
    if ({name}(arg, res, iw, w, 0)) return 1;
    for (k = 0; k < {n_out}; ++k) blk[k * {block} + i] = row[k];
  }}""",
}
_CHUNK_DRIVER = """
/* symmon: the rows of m <= {block} samples z into blk (by columns); p is shared by every row. */
static int {name}_block(const casadi_real* z, const casadi_real* p, casadi_int m, casadi_real* blk,
    casadi_int* iw, casadi_real* w) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_real* row = blk + {block} * {n_out};
  unsigned char odd[{block}];
  casadi_int i, k;
  (void) odd;
  arg[1] = p;
  {fill}
  return 0;
}}
/* symmon: the rows of n samples z (n × {n_in}) into out (n × {n_out}). */
CASADI_SYMBOL_EXPORT int {name}_rows(const casadi_real* z, const casadi_real* p,
    casadi_real* out, casadi_int n, casadi_int* iw, casadi_real* w) {{
  casadi_real* blk = w + {sz_w};
  casadi_int b, i, k, m;
  for (b = 0; b < n; b += {block}) {{
    m = n - b < {block} ? n - b : {block};
    if ({name}_block(z + b * {n_in}, p, m, blk, iw, w)) return 1;
    for (i = 0; i < m; ++i)
      for (k = 0; k < {n_out}; ++k) out[(b + i) * {n_out} + k] = blk[k * {block} + i];
  }}
  return 0;
}}
/* symmon: add the cross-products of the rows of m <= {block} samples z (rows b, b + 1, ...) to S
   (upper triangle); count the rows with a value that is not finite in bad, and copy the first
   one's z to zbad (x - x == 0 exactly when x is finite). */
static int {name}_sums(const casadi_real* z, const casadi_real* p, casadi_int m, casadi_int b,
    casadi_real* S, long long* bad, casadi_real* zbad, casadi_int* iw, casadi_real* w) {{
  casadi_real* blk = w + {sz_w};
  unsigned char fin[{block}];
  casadi_int i, j, k, r;
  if ({name}_block(z, p, m, blk, iw, w)) return 1;
  for (r = 0; r < m; ++r) fin[r] = 1;
  for (k = 0; k < {n_out}; ++k) {{
    const casadi_real* c = blk + k * {block};
    for (r = 0; r < m; ++r) fin[r] &= (c[r] - c[r] == 0);
  }}
  for (r = 0; r < m; ++r)
    if (!fin[r]) {{
      if (bad[1] < 0) {{ bad[1] = b + r; for (k = 0; k < {n_in}; ++k) zbad[k] = z[r * {n_in} + k]; }}
      bad[0]++;
    }}
  for (r = m; r < (m + 15) / 16 * 16; ++r)  /* pad the last block to 16 rows with zeros */
    for (k = 0; k < {n_out}; ++k) blk[k * {block} + r] = 0;
  for (i = 0; i < {n_out}; ++i) {{
    const casadi_real* ci = blk + i * {block};
    for (j = i; j < {n_out}; ++j) {{
      const casadi_real* cj = blk + j * {block};
      casadi_real s[16] = {{0}}, t[8];
      for (r = 0; r < m; r += 16)
        for (k = 0; k < 16; ++k) s[k] += ci[r + k] * cj[r + k];
      for (k = 0; k < 8; ++k) t[k] = s[k] + s[k + 8];
      S[i * {n_out} + j] += ((t[0] + t[4]) + (t[2] + t[6])) + ((t[1] + t[5]) + (t[3] + t[7]));
    }}
  }}
  return 0;
}}
static void {name}_start(casadi_real* S, long long* bad) {{
  casadi_int i;
  bad[0] = 0; bad[1] = -1;
  for (i = 0; i < {n_out} * {n_out}; ++i) S[i] = 0;
}}
static void {name}_symmetric(casadi_real* S) {{
  casadi_int i, j;
  for (i = 0; i < {n_out}; ++i)
    for (j = 0; j < i; ++j) S[i * {n_out} + j] = S[j * {n_out} + i];
}}
/* symmon: S = the cross-products of the rows of n samples z (n_out × n_out); bad = (count, first
   index) of the rows with a value that is not finite, zbad the first one's z. */
CASADI_SYMBOL_EXPORT int {name}_stats(const casadi_real* z, const casadi_real* p, casadi_int n,
    casadi_real* S, long long* bad, casadi_real* zbad, casadi_int* iw, casadi_real* w) {{
  casadi_int b, m;
  {name}_start(S, bad);
  for (b = 0; b < n; b += {block}) {{
    m = n - b < {block} ? n - b : {block};
    if ({name}_sums(z + b * {n_in}, p, m, b, S, bad, zbad, iw, w)) return 1;
  }}
  {name}_symmetric(S);
  return 0;
}}
/* symmon: {name}_stats of n samples drawn here, a block at a time, from the xoshiro256++ stream
   s (symmon.compile.rng, advanced in place): the normals of a row in order, row after row,
   as NormalStream.fill writes them; no normal leaves the L1 cache. */
CASADI_SYMBOL_EXPORT int {name}_draw_stats(uint64_t* s, const casadi_real* p, casadi_int n,
    casadi_real* S, long long* bad, casadi_real* zbad, casadi_int* iw, casadi_real* w) {{
  casadi_real* z = w + {sz_w} + ({block} + 1) * {n_out};
  casadi_int b, i, m;
  {name}_start(S, bad);
  for (b = 0; b < n; b += {block}) {{
    m = n - b < {block} ? n - b : {block};
    for (i = 0; i < m * {n_in}; ++i) z[i] = symmon_normal(s);
    if ({name}_sums(z, p, m, b, S, bad, zbad, iw, w)) return 1;
  }}
  {name}_symmetric(S);
  return 0;
}}
"""


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
        fmt = dict(name=name, sz_arg=max(f.sz_arg(), 2), sz_res=max(f.sz_res(), 1), n_in=self.n_w,
                   n_out=self.n_out, block=BLOCK, sz_w=f.sz_w())
        fmt["fill"] = _BLOCK_FILL[self.vectorised].format(**fmt)
        code = RNG_C + generated_c(f) + (VECMATH_C + vec if vec else "") + _CHUNK_DRIVER.format(**fmt)

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
