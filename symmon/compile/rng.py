"""symmon's C random numbers: xoshiro256++ streams and a ziggurat for normals.

Compiled kernels draw their own numbers in C, inside the loop that uses them, instead of
reading normals that NumPy drew in a separate pass: the particle filter's bootstrap
recursion (:mod:`symmon.filters.particle._kernel`) and Monte Carlo's fused chunk
(:mod:`symmon.transforms.mc_kernel`).

* **uniforms**: xoshiro256++ (Blackman & Vigna 2021, §4: a 256-bit state, period 2²⁵⁶ − 1),
  a double in [0, 1) from the top 53 bits;
* **normals**: the ziggurat of Marsaglia & Tsang (2000) with 256 layers of equal area
  v = r f(r) + ∫_r^∞ f, f(x) = exp(−x²/2), r = 3.6541528853610088 (the layers' edges
  x_{i+1} = f⁻¹(f(x_i) + v / x_i) of their §2, here computed in double precision at import
  and checked to close at x_256 = 0), one 64-bit word per draw (8 bits pick the layer, 1
  the sign, 52 the abscissa), the wedges by rejection against f, the tail beyond r by
  Marsaglia's (1964) method (their §3);
* **lanes**: ``symmon_normal_lanes`` draws a column of normals from :data:`LANES`
  interleaved streams, one from each lane in turn (the particle filter's moves): with AVX2,
  the lanes' states stay in registers for the column, the xoshiro steps and the layer's
  core test run four lanes per instruction, and a layer's k and w come in one 16-byte load;
  a lane whose word falls outside its layer's core (about 1.5 %) finishes alone by the
  scalar code.  Lane l
  gives exactly the numbers ``symmon_normal`` draws from its state (tested), so the
  vector width changes nothing.

**Streams.**  A stream's state is four words of ``SeedSequence(entropy, spawn_key=key +
(tag,))`` for the SeedSequence (entropy, key) of its owner and a tag naming the user
(:func:`xoshiro_states`; O'Neill's hashing of the seed into well-mixed, distinct words; a
xoshiro256++ state seeded that way starts a stream that overlaps no other in practice:
2²⁵⁶ period).  :class:`NormalStream` draws a stream's normals into NumPy arrays through a
small compiled library (the same C as the kernels), so that the numbers of a stream are
the same whether a kernel or this library draws them.

References
----------
D. Blackman, S. Vigna, "Scrambled linear pseudorandom number generators", ACM Trans. Math.
Softw. 47(4), 2021. doi:10.1145/3460772
G. Marsaglia, W. W. Tsang, "The ziggurat method for generating random variables", J. Stat.
Softw. 5(8), 2000. doi:10.18637/jss.v005.i08
G. Marsaglia, "Generating a variable from the tail of the normal distribution",
Technometrics 6(1), 1964.
"""

from __future__ import annotations

import ctypes
import math
import threading

import numpy as np

from ..errors import ShapeError, SymmonError
from .ccache import NativeLibrary, compile_mode
from .csource import c_defines, c_file

__all__ = ["LANES", "RNG_C", "NormalStream", "xoshiro_states", "ziggurat_edges"]

#: The interleaved streams of :c:func:`symmon_normal_lanes` (one AVX2 register holds 4).
LANES = 8
_R = 3.6541528853610088  # the base layer's edge for 256 layers (Marsaglia & Tsang 2000, §2)
_LAYERS = 256


def ziggurat_edges() -> tuple[np.ndarray, float]:
    """The edges x_0 … x_256 of the 256 layers (x_0 = v / f(r) the base layer's virtual
    width, x_1 = r, x_256 = 0) and the common area v (module notes)."""
    f = lambda x: math.exp(-0.5 * x * x)  # noqa: E731
    v = _R * f(_R) + math.sqrt(math.pi / 2) * math.erfc(_R / math.sqrt(2))
    x = [v / f(_R), _R]
    for i in range(1, _LAYERS):
        y = f(x[i]) + v / x[i]
        x.append(math.sqrt(-2 * math.log(y)) if y < 1 else 0.0)
    if abs(f(x[-2]) + v / x[-2] - 1) > 1e-12:  # the layers must close at the top
        raise AssertionError("the ziggurat's layers do not close")  # pragma: no cover
    return np.array(x), v


def _tables() -> str:
    x, _ = ziggurat_edges()
    k = [int(math.floor(2.0 ** 52 * x[i + 1] / x[i])) for i in range(_LAYERS)]
    w = [x[i] / 2.0 ** 52 for i in range(_LAYERS)]
    fv = [math.exp(-0.5 * xi * xi) for xi in x]
    num = lambda a: ", ".join(repr(float(v)) for v in a)  # noqa: E731
    kw = ", ".join(f"{{{a}ULL, {b!r}}}" for a, b in zip(k, map(float, w)))
    # a layer's k and w side by side: one 16-byte load gives both (the lanes' table reads)
    return ("typedef struct { unsigned long long k; double w; } symmon_zig_layer;\n"
            f"static const symmon_zig_layer symmon_zig_kw[{_LAYERS}] __attribute__((aligned(16))) = {{{kw}}};\n"
            f"static const double symmon_zig_f[{_LAYERS + 1}] = {{{num(fv)}}};\n")


#: The C of the generator (static functions; included once in each kernel's source): the
#: ziggurat's tables, the base layer's edge and the lanes, then ``rng.c``.
RNG_C = _tables() + c_defines(SYMMON_ZIG_R=_R, SYMMON_LANES=LANES) + c_file(__package__, "rng.c")


def xoshiro_states(seq: np.random.SeedSequence, streams: int, tag: int) -> np.ndarray:
    """The xoshiro256++ states (streams, 4) of the owner of ``seq`` for the user ``tag``:
    the words of ``SeedSequence(entropy, spawn_key=key + (tag,))``, four per stream (a
    SeedSequence's words do not depend on how many are asked for, so stream c is the same
    for every count that has it)."""
    child = np.random.SeedSequence(seq.entropy, spawn_key=tuple(seq.spawn_key) + (int(tag),))
    out = child.generate_state(4 * streams, np.uint64).reshape(streams, 4)
    out[~out.any(axis=1), 0] = 1  # the one state xoshiro must not have (probability 2⁻²⁵⁶)
    return out


#: The library of :class:`NormalStream`: n normals of a stream into an array (``rng_fill.c``).
_FILL_C = RNG_C + c_file(__package__, "rng_fill.c")
_library: NativeLibrary | None = None
_library_lock = threading.Lock()


def _normals_fn():
    """The compiled ``symmon_rng_normals``, or None (no compiler, ``SYMMON_COMPILE=never``:
    the policy of the moment, even when the library was loaded before)."""
    global _library
    if compile_mode() == "never":
        return None
    with _library_lock:
        if _library is None:
            def load(so):
                fn = ctypes.CDLL(str(so)).symmon_rng_normals
                fn.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p]
                fn.restype = None
                return fn
            _library = NativeLibrary(_FILL_C, "symmon_rng", load, stacklevel=4)
        lib = _library
    lib.wait()  # a few kB of C: never a background build, but a caller may race one
    fn = lib.get()
    if fn is None:
        with _library_lock:  # not kept: a later call under another compile policy tries again
            _library = None
    return fn


class NormalStream:
    """One xoshiro256++ stream of standard normals (the ziggurat of :data:`RNG_C`).

    Parameters
    ----------
    seq : numpy.random.SeedSequence
        The owner's seed sequence.
    tag : int
        The spawn-key entry naming the user (:func:`xoshiro_states`).

    The state (``state``, 4 words) advances by one word per normal, more on a rejection;
    a compiled kernel that includes :data:`RNG_C` may draw from ``state`` too, and the
    stream continues where it left off.  Raises :class:`~symmon.errors.SymmonError` when
    there is no compiled generator (:meth:`available`).
    """

    def __init__(self, seq: np.random.SeedSequence, tag: int) -> None:
        self._fn = _normals_fn()
        if self._fn is None:
            raise SymmonError("symmon's C normals need a C compiler (see docs/compile.md); "
                              "none is in use (SYMMON_COMPILE=never, or no compiler found)")
        self.state = xoshiro_states(seq, 1, tag)[0].copy()

    @staticmethod
    def available() -> bool:
        """True when the generator is compiled (a C compiler is in use)."""
        return _normals_fn() is not None

    def fill(self, out: np.ndarray) -> np.ndarray:
        """Fill the C-contiguous float64 array ``out`` with the stream's next normals (in
        the array's memory order) and return it."""
        if out.dtype != np.float64 or not out.flags.c_contiguous or not out.flags.writeable:
            raise ShapeError("NormalStream.fill needs a writeable C-contiguous float64 array")
        self._fn(self.state.ctypes.data, out.size, out.ctypes.data)
        return out

    def peek(self, out: np.ndarray) -> np.ndarray:
        """:meth:`fill` without advancing the stream (the next ``out.size`` normals)."""
        state = self.state.copy()
        try:
            return self.fill(out)
        finally:
            self.state[:] = state
