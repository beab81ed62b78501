"""The compiled step of the bootstrap particle filter: three C row loops over the particles.

For the bootstrap proposal (Gordon et al. 1993, §3) a step of :class:`~symmon.ParticleFilter`
is, per particle i of a run with log-weight ℓ_i (normalised) and standard normal draws z_i,

    x'_i = f(x_i, L_Q z_i)            (or f(x_i) + L_Q z_i for additive noise; angles wrapped),
    t_i  = ℓ_i + log N(y; h(x'_i), Γ R Γᵀ)   over the measured components of y,

then the log-sum-exp of t (the step's log-likelihood increment, Doucet et al. 2000, eq. (11)),
the normalised weights W_i = exp(t_i − lse), the weighted mean Σ W_i x'_i, the effective
sample size 1 / Σ W_i², and, when the ESS is low, a resampling with the gather of the
chosen particles.  NumPy does this in about a dozen passes over the particle array; here it
is three:

1. ``NAME_prop``: one call of CasADi's generated function per row (the transition, the
   measurement, the wrapped innovation, its whitening by the inverse Cholesky factor A of
   the measured block of Γ R Γᵀ, embedded with zero rows and columns for the missing
   components, and the log-density), writing x'_i and t_i, the running maximum of t and a
   flag for a non-finite particle or weight;
2. ``NAME_sums``: e_i = exp(t_i − max t), Σ e_i, Σ e_i² and Σ e_i x'_i (one pass, with
   the maximum found in pass 1, so no exponential overflows);
3. ``NAME_resample``: the walk of the resampling points along the cumulative weights
   (points ascending: O(N), no binary search), copying each chosen row to the new array.

Passes 1 and 2 run on row spans in threads (ctypes releases the GIL); the partial sums of
the spans are merged in NumPy (a few numbers each).  The draws are NumPy's, in the order
of the NumPy path (:mod:`symmon.filters.particle`), so a seed gives the same particles to
rounding.

The covariance, the predicted moments and the innovation moments, when asked for, stay
NumPy passes over the particles (the last needs h(x'_i), which pass 1 then writes).
"""

from __future__ import annotations

import ctypes
import math
import threading
from typing import Sequence

import casadi as ca
import numpy as np

from ..compile import NativeLibrary, compiled_with_params
from ..compile.compiled import WorkArrays, generated_c
from ..core.angles import wrap_casadi
from ..core.model import Model

__all__ = ["BootstrapKernel", "bootstrap_kernel"]

_LOG_2PI = math.log(2 * math.pi)

# The three loops.  casadi_int is long long (CasADi's default).
_DRIVER = """
#include <math.h>
#include <string.h>
/* symmon: pass 1 of the bootstrap particle filter (symmon.filters.pf_kernel). */
CASADI_SYMBOL_EXPORT int {name}_prop(const casadi_real* x, const casadi_real* z, const casadi_real* p,
    const casadi_real* lw, casadi_real* xn, casadi_real* t, casadi_real* hx, casadi_int n,
    casadi_real* mx, casadi_int* iw, casadi_real* w) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_real ll, ti, m = -INFINITY;
  casadi_int i, j, bad = 0;
  arg[2] = p;
  res[1] = &ll;
  for (i = 0; i < n; ++i) {{
    arg[0] = x + i * {nx};
    arg[1] = z + i * {nq};
    res[0] = xn + i * {nx};
    res[2] = hx ? hx + i * {ny} : 0;
    if ({name}(arg, res, iw, w, 0)) return 1;
    ti = lw[i] + ll;
    t[i] = ti;
    if (ti != ti || ti == INFINITY) bad = 1;
    for (j = 0; j < {nx}; ++j) if (!isfinite(res[0][j])) bad = 1;
    if (ti > m) m = ti;
  }}
  *mx = m;
  return bad ? 2 : 0;
}}

/* symmon: pass 2: e = exp(t - m); acc += [sum e, sum e^2, sum e x]. */
CASADI_SYMBOL_EXPORT void {name}_sums(const casadi_real* xn, const casadi_real* t, casadi_real m,
    casadi_real* e, casadi_int n, casadi_real* acc) {{
  casadi_real s = 0, s2 = 0, sx[{nx}], ei;
  casadi_int i, j;
  const casadi_real* xi;
  for (j = 0; j < {nx}; ++j) sx[j] = 0;
  for (i = 0; i < n; ++i) {{
    ei = exp(t[i] - m);
    e[i] = ei;
    s += ei;
    s2 += ei * ei;
    xi = xn + i * {nx};
    for (j = 0; j < {nx}; ++j) sx[j] += ei * xi[j];
  }}
  acc[0] = s;
  acc[1] = s2;
  for (j = 0; j < {nx}; ++j) acc[2 + j] = sx[j];
}}

/* symmon: pass 3: row i of out is the row of x whose cumulative weight interval, on the
   scale N / total, holds point i (pts ascending; NULL: the systematic points u + i). */
CASADI_SYMBOL_EXPORT void {name}_resample(const casadi_real* e, casadi_real total, const casadi_real* pts,
    casadi_real u, casadi_int n, const casadi_real* x, casadi_real* out) {{
  casadi_real scale = (casadi_real) n / total, cum = e[0] * scale, pt;
  casadi_int i, j = 0;
  for (i = 0; i < n; ++i) {{
    pt = pts ? pts[i] : u + (casadi_real) i;
    while (cum <= pt && j < n - 1) cum += e[++j] * scale;
    memcpy(out + i * {nx}, x + j * {nx}, {nx} * sizeof(casadi_real));
  }}
}}
"""


class BootstrapKernel:
    """The three compiled loops of a bootstrap step for the models f and h (module notes).

    Parameters
    ----------
    f_model, h_model : Model
    params : the filter's parameter names (f's, then h's that f does not have)
    Lq_pattern : bool (d, n_q), the structural nonzeros of L_Q (d: f's noise symbols, or n),
        n_q the draws per particle
    angle_states, angle_outputs : wrapped components

    Notes
    -----
    The parameters of a call (one run) are packed by :meth:`pack`:
    p = [θ (the filter's parameters), the nonzeros of L_Q (column-major), y (missing: 0), mask (1: measured),
    vec(A) (column-major), c], with A the inverse Cholesky factor of the measured block of
    Γ R Γᵀ embedded with zeros and c = −(log det + m log 2π)/2 for the m measured components.
    """

    def __init__(self, f_model: Model, h_model: Model, params: Sequence, Lq_pattern: np.ndarray,
                 angle_states: Sequence[int], angle_outputs: Sequence[int]) -> None:
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
        y, mask = p[o:o + ny], p[o + ny:o + 2 * ny]
        o += 2 * ny
        A = ca.reshape(p[o:o + ny * ny], ny, ny)
        c = p[o + ny * ny]

        def of(model: Model, cm, state, noise):
            th = [theta[list(params).index(s)] for s in model.params]
            return ca.substitute(cm.y_sx, cm.w_sx, ca.vertcat(state, *noise, *th))

        noise = ca.mtimes(Lq, z)
        xn = of(f_model, cf, x, [noise]) if f_model.n_v else of(f_model, cf, x, []) + noise
        xn = ca.vertcat(*[wrap_casadi(xn[i]) if i in angle_states else xn[i] for i in range(n)])
        hx = of(h_model, ch, xn, [ca.SX.zeros(h_model.n_v)] if h_model.n_v else [])
        hx = ca.vertcat(*[wrap_casadi(hx[i]) if i in angle_outputs else hx[i] for i in range(ny)])
        nu = y - hx
        nu = ca.vertcat(*[ca.if_else(mask[i], wrap_casadi(nu[i]) if i in angle_outputs else nu[i], 0)
                          for i in range(ny)])
        wz = ca.mtimes(A, nu)
        ll = -0.5 * ca.dot(wz, wz) + c
        name = f"{cf.tag}_{ch.tag}_pfb" + "".join(f"_s{i}" for i in angle_states) + "".join(
            f"_o{i}" for i in angle_outputs)
        self.f = ca.Function(name, [x, z, p], [ca.densify(xn), ll, ca.densify(hx)], ["x", "z", "p"],
                             ["xn", "ll", "hx"], {"cse": True})
        self.n_p = p.numel()
        self._work = WorkArrays(self.f)
        code = generated_c(self.f) + _DRIVER.format(name=name, sz_arg=max(self.f.sz_arg(), 3),
                                                    sz_res=max(self.f.sz_res(), 3), nx=n, nq=n_q, ny=ny)

        def load(so):
            lib = ctypes.CDLL(str(so))
            prop = getattr(lib, f"{name}_prop")
            prop.argtypes = [ctypes.c_void_p] * 7 + [ctypes.c_longlong] + [ctypes.c_void_p] * 3
            prop.restype = ctypes.c_int
            sums = getattr(lib, f"{name}_sums")
            sums.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p,
                             ctypes.c_longlong, ctypes.c_void_p]
            sums.restype = None
            res = getattr(lib, f"{name}_resample")
            res.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p, ctypes.c_double,
                            ctypes.c_longlong, ctypes.c_void_p, ctypes.c_void_p]
            res.restype = None
            return prop, sums, res

        self._native: NativeLibrary = cf.native_library(code, name, load, stacklevel=4)
        self._Lq_size = nnz

    def loops(self):
        """The three ctypes functions (prop, sums, resample), or None while the C is not there
        (no compiler, or a background build running: the caller takes the NumPy path)."""
        return self._native.get()

    def pack(self, theta: np.ndarray | None, Lq: np.ndarray, y: np.ndarray, A: np.ndarray, c: float) -> np.ndarray:
        """The parameter vector of one run's call (class notes); y with NaN for missing."""
        p = np.zeros(self.n_p)
        o = self.n_par
        if o:
            p[:o] = theta
        p[o:o + self._Lq_size] = Lq.T[self.Lq_pattern.T]
        o += self._Lq_size
        measured = ~np.isnan(y)
        p[o:o + self.n_y] = np.where(measured, y, 0.0)
        p[o + self.n_y:o + 2 * self.n_y] = measured
        o += 2 * self.n_y
        p[o:o + A.size] = A.ravel(order="F")
        p[-1] = c
        return p

    def work(self) -> tuple[int, int]:
        """This thread's work arrays (addresses)."""
        return self._work.addresses()


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
