"""The compiled sampling kernel of Monte Carlo.

For a chunk of standard normal rows z, one compiled C loop writes the rows

    a = [g(w) − s_y;  w − s_w;  1],   w = m + L z,

where s is the shift that keeps the digits (see :mod:`.montecarlo`).  Angle outputs are
first unwrapped around a reference, y_i ← r_i + wrap(y_i − r_i), and their sines and
cosines are appended before the 1 (for the circular mean).  NumPy is then left
one product per chunk, AᵀA, which holds the count, the sums and the cross-products.
Fusing the affine map, the evaluation and the centring saves three passes over the
chunk, and the loop is called through ctypes, which releases the GIL, so that threads
run the evaluation in parallel (CasADi's own call holds it).

The math of the kernel is a CasADi function built from the model's SX graph, and C code
is generated from it by CasADi; only the row loop around it is written here.  Without a
C compiler, and while a large kernel is compiled in the background (docs/compile.md),
the same CasADi function is evaluated by CasADi's virtual machine.
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
from ..compile.vecmath import VECMATH_C, vector_rows
from ..errors import ShapeError, SymmonError

__all__ = ["SampleKernel", "sample_kernel", "FUSE_MAX_NW"]

#: Largest n_w whose affine map w = m + L z is compiled into the kernel (its C grows as n_w²).
FUSE_MAX_NW = 16

# The row loop: one call of CasADi's generated function per row, its arguments set by
# pointer arithmetic.  casadi_int is CasADi's default, long long.
_DRIVER = """
/* symmon: rows of z in, rows of out out; p is shared by every row. */
CASADI_SYMBOL_EXPORT int {name}_rows(const casadi_real* z, const casadi_real* p,
    casadi_real* out, casadi_int n, casadi_int* iw, casadi_real* w) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int i;
  arg[1] = p;
  for (i = 0; i < n; ++i) {{
    arg[0] = z + i * {n_in};
    res[0] = out + i * {n_out};
    if ({name}(arg, res, iw, w, 0)) return 1;
  }}
  return 0;
}}
"""


# The vectorised row loop (symmon.compile.vecmath): blocks of VEC_BLOCK rows through the
# vector loop {name}_vec; a row it flags (an atan2 or hypot argument that is zero, inf,
# NaN or beyond 2^±500) is recomputed by CasADi's function, that is, by libm.
VEC_BLOCK = 256
_VEC_DRIVER = """
/* symmon: rows of z in, rows of out out; p is shared by every row (vectorised loop). */
CASADI_SYMBOL_EXPORT int {name}_rows(const casadi_real* z, const casadi_real* p,
    casadi_real* out, casadi_int n, casadi_int* iw, casadi_real* w) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  unsigned char odd[{block}];
  casadi_int b, i, m;
  arg[1] = p;
  for (b = 0; b < n; b += {block}) {{
    m = n - b < {block} ? n - b : {block};
    if ({name}_vec(z + b * {n_in}, p, out + b * {n_out}, m, odd) == 0) continue;
    for (i = 0; i < m; ++i) {{
      if (!odd[i]) continue;
      arg[0] = z + (b + i) * {n_in};
      res[0] = out + (b + i) * {n_out};
      if ({name}(arg, res, iw, w, 0)) return 1;
    }}
  }}
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
        fmt = dict(name=name, sz_arg=max(f.sz_arg(), 2), sz_res=max(f.sz_res(), 1), n_in=self.n_w,
                   n_out=self.n_out, block=VEC_BLOCK)
        vec = vector_rows(f, f"{name}_vec", self.n_w, self.n_out)
        #: True when the rows run through the vectorised loop (every operation of g in
        #: :data:`~symmon.compile.vecmath.VECTOR_OPS`), False when through CasADi's C per row.
        self.vectorised = vec is not None
        if vec is None:
            code = generated_c(f) + _DRIVER.format(**fmt)
        else:
            code = generated_c(f) + VECMATH_C + vec + _VEC_DRIVER.format(**fmt)

        def load(so):
            rows = getattr(ctypes.CDLL(str(so)), f"{name}_rows")
            rows.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_longlong] + [ctypes.c_void_p] * 2
            rows.restype = ctypes.c_int
            return rows

        return cm.native_library(code, name, load, stacklevel=5)

    def params(self, mean: np.ndarray, L: np.ndarray, shift: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """Pack the parameters of a call."""
        return np.concatenate([mean, np.asarray(L, dtype=float).ravel(order="F"), shift, ref])

    def workspace(self) -> tuple[np.ndarray, np.ndarray]:
        """Work arrays for one thread (integer, real)."""
        return np.zeros(max(self.f.sz_iw(), 1), dtype=np.int64), np.zeros(max(self.f.sz_w(), 1))

    def __call__(self, Z: np.ndarray, p: np.ndarray, out: np.ndarray,
                 work: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Write the rows for ``Z`` (N, n_w) into ``out`` (N, ``n_out``).

        Both must be C-contiguous float64; ``p`` comes from :meth:`params`, ``work``
        from :meth:`workspace` (one per thread; made on the fly if omitted).
        """
        N = Z.shape[0]
        if Z.shape != (N, self.n_w) or out.shape != (N, self.n_out) or p.shape != (self.n_p,):
            raise ShapeError(
                f"sampling kernel: need Z (N, {self.n_w}), p ({self.n_p},) and out (N, {self.n_out}); "
                f"got Z {Z.shape}, p {p.shape}, out {out.shape}"
            )
        for name, a in (("Z", Z), ("p", p), ("out", out)):
            if a.dtype != np.float64 or not a.flags.c_contiguous or (name == "out" and not a.flags.writeable):
                raise ShapeError(f"sampling kernel: {name} must be a C-contiguous float64 array"
                                 + (" that can be written" if name == "out" else ""))
        if N == 0:
            return
        if not self.fused:
            nw = self.n_w
            L = p[nw: nw + nw * nw].reshape(nw, nw, order="F")
            Z = Z @ L.T
            Z += p[:nw]
            p = p[nw + nw * nw:]
        rows = self._native.get() if self._native is not None else None
        if rows is not None:
            iw, w = work if work is not None else self.workspace()
            if (iw.dtype != np.int64 or w.dtype != np.float64 or iw.size < self.f.sz_iw()
                    or w.size < self.f.sz_w() or not (iw.flags.c_contiguous and w.flags.c_contiguous)):
                raise ShapeError("sampling kernel: the work arrays must come from workspace()")
            if rows(Z.ctypes.data, p.ctypes.data, out.ctypes.data, N, iw.ctypes.data, w.ctypes.data):
                raise SymmonError(f"the compiled sampling kernel {self.f.name()} returned an error")
            return
        fb, ev = self._mapped(N).buffer()
        fb.set_arg(0, memoryview(Z))
        fb.set_arg(1, memoryview(p))
        fb.set_res(0, memoryview(out))
        ev()

    def _mapped(self, N: int) -> ca.Function:
        with self._lock:
            fm = self._maps.get(N)
            if fm is None:
                fm = self._maps[N] = self.f.map(f"{self.f.name()}_map{N}", "serial", N, [1], [])
            return fm


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
