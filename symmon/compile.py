"""sympy → CasADi SX, exact derivatives, batched evaluation and C code generation.

Only g is converted from sympy; the Jacobian and the Hessians are built by CasADi's
automatic differentiation (exact, no finite differences).  Batches are evaluated
with ``Function.map`` through zero-copy buffers.  When a C compiler is available the
mapped functions are generated as C, compiled with ``-O2`` and cached on disk under a
content hash; otherwise CasADi's virtual machine is used, with a warning given once.
"""

from __future__ import annotations

import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Callable, Sequence

import casadi as ca
import numpy as np
import sympy as sp

from .errors import ShapeError, UnsupportedFunctionError

__all__ = ["to_casadi", "CompiledModel", "compile_model", "cache_dir", "has_compiler", "build_shared_library"]

#: Rows per batched call of a mapped function; memory per call stays flat.
CHUNK = 8192

_UNARY = {
    sp.sin: ca.sin, sp.cos: ca.cos, sp.tan: ca.tan,
    sp.asin: ca.asin, sp.acos: ca.acos, sp.atan: ca.atan,
    sp.sinh: ca.sinh, sp.cosh: ca.cosh, sp.tanh: ca.tanh,
    sp.asinh: ca.asinh, sp.acosh: ca.acosh, sp.atanh: ca.atanh,
    sp.exp: ca.exp, sp.Abs: ca.fabs, sp.sign: ca.sign,
    sp.floor: ca.floor, sp.ceiling: ca.ceil, sp.erf: ca.erf,
}


_UNARY_EXTRA = {sp.cot: lambda a: 1 / ca.tan(a), sp.sec: lambda a: 1 / ca.cos(a), sp.csc: lambda a: 1 / ca.sin(a)}

#: n-ary sympy heads folded left to right with a binary CasADi operation.
_NARY = {
    sp.Add: lambda a, b: a + b, sp.Mul: lambda a, b: a * b,
    sp.Max: ca.fmax, sp.Min: ca.fmin, sp.And: ca.logic_and, sp.Or: ca.logic_or,
}


def to_casadi(exprs: Sequence[sp.Expr], symbols: Sequence[sp.Symbol], xs: ca.SX) -> list[ca.SX]:
    """Convert sympy expressions to CasADi SX by a memoised tree walk.

    Parameters
    ----------
    exprs : sequence of sympy.Expr
    symbols : sequence of sympy.Symbol
        The symbols, in the order of the entries of ``xs``.
    xs : casadi.SX
        A column of SX symbols, one per entry of ``symbols``.

    Raises
    ------
    UnsupportedFunctionError
        Naming the sympy function that has no CasADi counterpart.
    """
    memo: dict[sp.Basic, ca.SX] = {s: xs[i] for i, s in enumerate(symbols)}

    def walk(e: sp.Basic):
        hit = memo.get(e)
        if hit is not None:
            return hit
        out = _convert(e, walk)
        memo[e] = out
        return out

    return [walk(sp.sympify(e)) for e in exprs]


def _convert(e: sp.Basic, walk: Callable):
    if e.is_Number:
        if e.is_real is False or not e.is_finite:
            if e in (sp.oo, -sp.oo):
                return ca.SX(float(e))
            raise UnsupportedFunctionError(f"cannot compile the number {e}")
        return ca.SX(float(e))
    if e is sp.pi or e == sp.pi:
        return ca.SX(np.pi)
    if e == sp.E:
        return ca.SX(np.e)
    if e.is_Symbol:
        raise UnsupportedFunctionError(f"unknown symbol {e} in expression")
    op = _NARY.get(e.func)
    if op is not None:
        return functools.reduce(op, [walk(a) for a in e.args])
    if isinstance(e, sp.Pow):
        base, ex = e.args
        b = walk(base)
        if ex == sp.Rational(1, 2):
            return ca.sqrt(b)
        if ex == -sp.Rational(1, 2):
            return 1 / ca.sqrt(b)
        if ex.is_Integer:
            k = int(ex)
            if k == -1:
                return 1 / b
            return ca.constpow(b, k) if k >= 0 else 1 / ca.constpow(b, -k)
        if ex.is_Number:
            return ca.constpow(b, float(ex))
        return ca.power(b, walk(ex))
    if isinstance(e, sp.log):
        if len(e.args) == 2:
            return ca.log(walk(e.args[0])) / ca.log(walk(e.args[1]))
        return ca.log(walk(e.args[0]))
    if isinstance(e, sp.atan2):
        return ca.atan2(walk(e.args[0]), walk(e.args[1]))
    if isinstance(e, sp.Piecewise):
        # Build from the last branch backwards; if_else is short-circuit-free in SX,
        # but derivatives of the branch not taken do not leak (CASADI-NOTES).
        out = None
        for expr, cond in reversed(e.args):
            val = walk(expr)
            if cond == sp.true:
                out = val
            else:
                if out is None:
                    out = ca.SX(np.nan)
                out = ca.if_else(walk(cond), val, out)
        return out
    if isinstance(e, sp.Heaviside):
        x = walk(e.args[0])
        return ca.if_else(x > 0, 1, ca.if_else(x < 0, 0, 0.5))
    if isinstance(e, sp.Mod):
        a, b = walk(e.args[0]), walk(e.args[1])
        return a - b * ca.floor(a / b)
    if isinstance(e, sp.core.relational.Relational):
        a, b = walk(e.lhs), walk(e.rhs)
        ops = {"<": a < b, "<=": a <= b, ">": a > b, ">=": a >= b, "==": a == b, "!=": a != b}
        return ops[e.rel_op]
    if isinstance(e, sp.Not):
        return ca.logic_not(walk(e.args[0]))
    if e == sp.true:
        return ca.SX(1)
    if e == sp.false:
        return ca.SX(0)
    fn = _UNARY.get(e.func) or _UNARY_EXTRA.get(e.func)
    if fn is not None and len(e.args) == 1:
        return fn(walk(e.args[0]))
    name = getattr(e.func, "__name__", type(e).__name__)
    raise UnsupportedFunctionError(
        f"cannot compile function {name!r} in {e}: supported are + - * / **, sqrt, exp, log, "
        "trig and inverse trig, atan2, hyperbolic, Abs, sign, floor, ceiling, erf, Min/Max, "
        "Mod, Heaviside and Piecewise"
    )


# --------------------------------------------------------------------------- C cache
def cache_dir() -> Path:
    """Directory of the compiled-function cache (``$SYMMON_CACHE`` or ~/.cache/symmon)."""
    d = os.environ.get("SYMMON_CACHE")
    path = Path(d) if d else Path.home() / ".cache" / "symmon"
    return path


@lru_cache(maxsize=1)
def _compiler() -> str | None:
    if os.environ.get("SYMMON_NO_COMPILE"):
        return None
    return os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")


def has_compiler() -> bool:
    """True when a C compiler is found and compilation is not disabled."""
    return _compiler() is not None


_warned_no_compiler = False
_lock = threading.Lock()
CFLAGS = ("-O2", "-fPIC", "-shared", "-fno-fast-math")


def _warn_no_compiler(stacklevel: int) -> None:
    """Warn, once per process, that the CasADi VM is used instead of compiled C."""
    global _warned_no_compiler
    with _lock:
        if not _warned_no_compiler:
            _warned_no_compiler = True
            warnings.warn(
                "symmon: no C compiler found (or SYMMON_NO_COMPILE set); using CasADi's "
                "virtual machine, which is several times slower",
                RuntimeWarning,
                stacklevel=stacklevel + 1,
            )


def build_shared_library(code: str, stem: str, stacklevel: int = 2) -> Path | None:
    """Compile C source to a shared library, cached on disk by content hash.

    Returns the path of the library, or None (after a warning) when no compiler is
    available or the compilation fails (``stacklevel`` as in ``warnings.warn``, counted
    from this function).  The cache key covers the source, the flags,
    the CasADi version and the compiler, and the library is moved into place atomically,
    so concurrent processes see all of it or nothing.
    """
    cc = _compiler()
    if cc is None:
        _warn_no_compiler(stacklevel=stacklevel)
        return None
    key = hashlib.sha256(
        (code + " ".join(CFLAGS) + ca.__version__ + cc).encode()
    ).hexdigest()[:24]
    d = cache_dir()
    so = d / f"{stem}_{key}.so"
    if not so.exists():
        d.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=d) as tmp:
            src = Path(tmp) / "f.c"
            src.write_text(code)
            out = Path(tmp) / "f.so"
            res = subprocess.run(
                [cc, *CFLAGS, str(src), "-o", str(out), "-lm"],
                capture_output=True, text=True,
            )
            if res.returncode != 0:
                warnings.warn(
                    f"symmon: compiling {stem} failed, using the CasADi VM:\n{res.stderr[-2000:]}",
                    RuntimeWarning, stacklevel=stacklevel,
                )
                return None
            os.replace(out, so)
    return so


def generated_c(f: ca.Function) -> str:
    """CasADi's C source of ``f`` (no header, no main)."""
    gen = ca.CodeGenerator(f.name() + ".c", {"with_header": False})
    gen.add(f)
    return gen.dump()


def _compile_function(f: ca.Function) -> ca.Function:
    """Compile ``f`` to a shared library (cached by content hash); fall back to ``f``."""
    so = build_shared_library(generated_c(f), f.name(), stacklevel=4)
    return f if so is None else ca.external(f.name(), str(so))


# --------------------------------------------------------------------------- compiled model
class _Batched:
    """Evaluate a Function of one (n_in,) input on batches of rows, through buffers."""

    def __init__(self, f: ca.Function, compiled: bool) -> None:
        self._f = f
        self._compiled = compiled
        self.n_in = f.size1_in(0)
        self.out_shapes = [f.size_out(i) for i in range(f.n_out())]
        self._maps: dict[int, ca.Function] = {}

    def _mapped(self, n: int) -> ca.Function:
        fm = self._maps.get(n)
        if fm is None:
            fm = self._f.map(f"{self._f.name()}_map{n}", "serial", n, [], [])
            if self._compiled:
                fm = _compile_function(fm)
            self._maps[n] = fm
        return fm

    def __call__(self, X: np.ndarray) -> list[np.ndarray]:
        X = np.ascontiguousarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != self.n_in:
            raise ShapeError(f"batch must have shape (N, {self.n_in}), got {X.shape}")
        N = X.shape[0]
        outs = [np.empty((N, r * c)) for r, c in self.out_shapes]
        if N == 0:
            return outs
        # Small batches get an exact-size map (cached); large ones go in fixed chunks.
        size = N if N <= CHUNK else CHUNK
        fm = self._mapped(size)
        fb, ev = fm.buffer()
        start = 0
        pad_in = None
        while start < N:
            stop = min(start + size, N)
            if stop - start == size:
                fb.set_arg(0, memoryview(X[start:stop]))
                res = [o[start:stop] for o in outs]
                for i, r in enumerate(res):
                    fb.set_res(i, memoryview(r))
                ev()
            else:
                pad_in = np.zeros((size, self.n_in))
                pad_in[: stop - start] = X[start:stop]
                pad_out = [np.empty((size, o.shape[1])) for o in outs]
                fb.set_arg(0, memoryview(pad_in))
                for i, r in enumerate(pad_out):
                    fb.set_res(i, memoryview(r))
                ev()
                for o, p in zip(outs, pad_out):
                    o[start:stop] = p[: stop - start]
            start = stop
        return outs


class CompiledModel:
    """CasADi functions of a model, with respect to w = [u; v].

    The derivatives are kept sparse: the compiled function returns only the structural
    nonzeros of J and of the lower triangles of the Hessians, so the generated code grows
    with those nonzeros, not with n_y·n_w².  Products with a covariance are left to
    batched NumPy (:mod:`symmon.transforms.taylor`).

    Attributes
    ----------
    g : casadi.Function
        w ↦ g(w), shape (n_y,).
    jac : casadi.Function
        w ↦ ∂g/∂w, a sparse (n_y, n_w) matrix.
    derivs : casadi.Function
        w ↦ (g(w), the nonzeros of J, the nonzeros of the Hessians' lower triangles),
        laid out by ``jac_index`` and ``hess_index``.
    jac_index : (rows, cols)
        Output and input index of each Jacobian nonzero.
    hess_index : (outputs, rows, cols)
        Output i and entry (a, b), a ≥ b, of H_i = ∂²g_i/∂w² for each Hessian nonzero.
    hess_support : (n_y, s) int array
        Row i lists S_i, the inputs on which H_i is supported (padded with 0 to the
        largest size s; padded entries carry zero blocks).
    """

    def __init__(self, outputs: Sequence[sp.Expr], symbols: Sequence[sp.Symbol], name: str = "g",
                 compiled: bool | None = None) -> None:
        self.symbols = tuple(symbols)
        self.source_exprs = tuple(outputs)
        self.n_w = len(self.symbols)
        self.n_y = len(outputs)
        self.tag = tag = _c_name(name)
        w = ca.SX.sym("w", self.n_w)
        y = ca.densify(ca.vertcat(*to_casadi(outputs, self.symbols, w)))
        self.w_sx, self.y_sx = w, y
        J = ca.jacobian(y, w)
        # Hessians are symmetric: keep the lower triangle of each.
        H = [ca.tril(ca.hessian(y[i], w)[0]) for i in range(self.n_y)]
        jr, jc = J.sparsity().get_triplet()
        self.jac_index = (np.array(jr, dtype=np.intp), np.array(jc, dtype=np.intp))
        trip = [h.sparsity().get_triplet() for h in H]
        self.hess_index = (
            np.array([i for i, (r, _) in enumerate(trip) for _ in r], dtype=np.intp),
            np.array([a for r, _ in trip for a in r], dtype=np.intp),
            np.array([b for _, c in trip for b in c], dtype=np.intp),
        )
        self._hess_layout()
        self.g = ca.Function(f"{tag}_g", [w], [y], ["w"], ["y"])
        self.jac = ca.Function(f"{tag}_J", [w], [J], ["w"], ["J"])
        # Buffers carry nonzeros only: the outputs are dense columns of nonzeros.
        H_nz = ca.vertcat(ca.SX(0, 1), *[_nonzeros(h) for h in H])
        # CSE merges the subexpressions that g, J and the Hessians share (~15% less C).
        self.derivs = ca.Function(f"{tag}_gJH", [w], [y, _nonzeros(J), H_nz],
                                  ["w"], ["y", "J_nz", "H_nz"], {"cse": True})
        self.compiled = has_compiler() if compiled is None else compiled
        if compiled is None and not self.compiled:
            # The default asked for C but none is available: say so (once per process).
            _warn_no_compiler(stacklevel=2)
        self._batch_g = _Batched(self.g, self.compiled)
        self._batch_derivs = _Batched(self.derivs, self.compiled)

    def _hess_layout(self) -> None:
        """Supports S_i of the Hessians and where each nonzero goes in the blocks H_i[S_i, S_i]."""
        out, rows, cols = self.hess_index
        supports = [np.union1d(rows[out == i], cols[out == i]) for i in range(self.n_y)]
        s = max((len(S) for S in supports), default=0)
        self.hess_support = np.zeros((self.n_y, s), dtype=np.intp)
        pos = np.zeros((self.n_w, self.n_y), dtype=np.intp)  # pos[a, i]: place of a in S_i
        for i, S in enumerate(supports):
            self.hess_support[i, : len(S)] = S
            pos[S, i] = np.arange(len(S))
        a, b = pos[rows, out], pos[cols, out]
        # Flat positions in an (n_y, s, s) array of blocks, and of the mirrored entries.
        self._block_at = (out * s + a) * s + b
        self._block_at_t = (out * s + b) * s + a

    # ------------------------------------------------------------------ evaluation
    def eval_g(self, W: np.ndarray) -> np.ndarray:
        """g at each row of W (N, n_w) → (N, n_y)."""
        return self._batch_g(W)[0]

    def eval_derivatives(self, W: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """g and the structural nonzeros of J and of the Hessians at each row of W.

        Returns
        -------
        y : (N, n_y); J_nz : (N, nnz J) laid out by ``jac_index``;
        H_nz : (N, nnz tril H) laid out by ``hess_index``
        """
        y, J_nz, H_nz = self._batch_derivs(W)
        return y, J_nz, H_nz

    def dense_jacobian(self, J_nz: np.ndarray) -> np.ndarray:
        """(N, n_y, n_w) Jacobians from their nonzeros (N, nnz J)."""
        J = np.zeros((J_nz.shape[0], self.n_y, self.n_w))
        J[:, self.jac_index[0], self.jac_index[1]] = J_nz
        return J

    def dense_hessians(self, H_nz: np.ndarray) -> np.ndarray:
        """(N, n_y, n_w, n_w) Hessians from their lower-triangle nonzeros (N, nnz)."""
        out, rows, cols = self.hess_index
        H = np.zeros((H_nz.shape[0], self.n_y, self.n_w, self.n_w))
        H[:, out, rows, cols] = H_nz
        H[:, out, cols, rows] = H_nz
        return H

    def hessian_blocks(self, H_nz: np.ndarray) -> np.ndarray:
        """(N, n_y, s, s) blocks H_i[S_i, S_i], S_i the rows of ``hess_support``."""
        s = self.hess_support.shape[1]
        B = np.zeros((H_nz.shape[0], self.n_y * s * s))
        B[:, self._block_at] = H_nz
        B[:, self._block_at_t] = H_nz
        return B.reshape(-1, self.n_y, s, s)

    def eval_gjh(self, W: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """g, J and the Hessians at each row of W, dense (for small models and checks).

        Returns
        -------
        y : (N, n_y); J : (N, n_y, n_w); H : (N, n_y, n_w, n_w)
        """
        y, J_nz, H_nz = self.eval_derivatives(W)
        return y, self.dense_jacobian(J_nz), self.dense_hessians(H_nz)


def _nonzeros(x: ca.SX) -> ca.SX:
    """The structural nonzeros of ``x`` as a column (column-major order, as ``get_triplet``)."""
    # A fully dense matrix's ``nz[:]`` keeps its shape: reshape to a column.
    return ca.reshape(x.nz[:], -1, 1)


def _c_name(name: str) -> str:
    safe = "".join(ch if ch.isalnum() else "_" for ch in name)
    return "sm_" + safe[:40]


_cache: dict[tuple, CompiledModel] = {}
_cache_lock = threading.Lock()


def compile_model(outputs: Sequence[sp.Expr], symbols: Sequence[sp.Symbol], name: str = "g") -> CompiledModel:
    """A :class:`CompiledModel`, cached per (outputs, symbols) in this process."""
    key = (tuple(outputs), tuple(symbols))
    with _cache_lock:
        cm = _cache.get(key)
        if cm is None:
            digest = hashlib.sha1(repr(key).encode()).hexdigest()[:10]
            cm = CompiledModel(outputs, symbols, name=f"{name}_{digest}")
            _cache[key] = cm
    return cm
