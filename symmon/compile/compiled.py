"""sympy → CasADi SX, exact derivatives, batched evaluation and C code generation.

Only g is converted from sympy; the Jacobian and the Hessians are built by CasADi's
automatic differentiation (exact, no finite differences).  When a C compiler is
available each function is generated as C with a row loop around it, compiled once
(whatever the batch sizes) and cached on disk (:mod:`symmon.compile.ccache`: checksums, the
compile policy, background builds for large code); otherwise, and while a background
build runs, CasADi's virtual machine evaluates ``Function.map`` through zero-copy
buffers, with a warning given once when no compiler is found.  ``docs/compile.md``
describes the cache, the policy and its measured threshold.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import os
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from pathlib import Path
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np
import sympy as sp
from sympy.functions.elementary.piecewise import ExprCondPair

from .ccache import NativeLibrary, build_shared_library, cache_dir, has_compiler, warn_no_compiler
from .ckernels import STOPPED, faster_kernels
from .cnames import c_identifier
from .csource import c_defines, c_file
from ..core.angles import circle_point
from ..core.dag import Canonical, digest, postorder
from ..core.model import Model
from ..errors import ArgumentTypeError, ModelError, ShapeError, UnsupportedFunctionError

__all__ = ["to_casadi", "CompiledModel", "compile_model", "model_key", "compiled", "compiled_with_params", "cache_dir", "has_compiler", "build_shared_library",
           "generated_c", "rows_c", "row_spans", "even_spans", "cpu_count", "MIN_ROWS_PER_THREAD", "in_threads", "run_stoppable", "WorkArrays", "padded", "address"]

log = logging.getLogger(__name__)

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
    """Convert sympy expressions to CasADi SX, each distinct node once.

    The nodes are converted in post-order (:func:`symmon.core.dag.postorder`, an explicit
    stack, no recursion), so a subexpression shared by many others (a traced loop) is one
    CasADi node and an expression hundreds of levels deep converts like a shallow one.

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
    by_symbol = {s: xs[i] for i, s in enumerate(symbols)}
    # Keyed by identity, then by structure (dag.Canonical): no lookup compares two large
    # expressions for equality, and equal nodes that sympy built twice are one CasADi node.
    # ``keep`` holds every node numbered, so no id is reused while the walk runs.
    memo: dict[int, Any] = {}
    by_class: dict[int, Any] = {}
    canon = Canonical()
    keep: list[sp.Basic] = []

    def walk(e: sp.Basic):
        hit = memo.get(id(e))
        if hit is None:
            convert([e])  # a node _convert built itself (log1p's rest): its arguments are done
            hit = memo[id(e)]
        if isinstance(hit, UnsupportedFunctionError):
            raise hit
        return hit

    def convert(roots: Sequence[sp.Basic]) -> None:
        nodes = postorder(roots, done=lambda n: id(n) in memo)
        keep.extend(nodes)
        canon.add(nodes)
        for node in nodes:
            k = canon.classes[id(node)]
            if k in by_class:
                memo[id(node)] = by_class[k]
                continue
            if node.is_Symbol and node in by_symbol:
                out = by_symbol[node]
            elif isinstance(node, ExprCondPair):
                out = _PAIR  # read through its Piecewise, never on its own
            else:
                try:
                    out = _convert(node, walk, partial)
                except UnsupportedFunctionError as exc:
                    # Raised when a node that needs it is converted: a node converted only
                    # because the walk passed it (the squares under a hypot) costs nothing.
                    out = exc
            memo[id(node)] = by_class[k] = out

    def partial(e: sp.Basic):
        """An Add or Mul converted before whose terms are terms of ``e``, and the terms
        left, or None.  sympy flattens x + h·sin(x) into one sum of all the terms so far,
        so each step of a traced loop x = x + h·f(x) is a longer sum: the sum of the step
        before, found below a term of ``e`` (f(x) holds x), is reused, and the CasADi graph
        grows by a few nodes a step, not by the length of the sum."""
        cls = canon.classes
        ids = {cls[id(a)] for a in e.args}
        found = []
        for a in e.args:
            for b in a.args:
                for c in (b, *b.args):
                    if (c.func is e.func and id(c) in memo and 1 < len(c.args) < len(e.args)
                            and not isinstance(memo[id(c)], UnsupportedFunctionError)):
                        found.append(c)
        for c in sorted(found, key=lambda c: -len(c.args)):
            inner = {cls[id(t)] for t in c.args}
            if inner <= ids and len(inner) == len(c.args):
                return memo[id(c)], [a for a in e.args if cls[id(a)] not in inner]
        return None

    roots = [sp.sympify(e) for e in exprs]
    convert(roots)
    return [walk(e) for e in roots]


#: The memo's entry of a Piecewise's (expression, condition) pair.
_PAIR = object()


def _squares(e: sp.Basic) -> list[sp.Expr] | None:
    """The a_i of e = Σ a_i² (at least two terms), else None."""
    if not e.is_Add or len(e.args) < 2:
        return None
    if all(isinstance(t, sp.Pow) and t.exp == 2 for t in e.args):
        return [t.base for t in e.args]
    return None


def _careful(e: sp.Basic, walk: Callable):
    """The numerically careful C99 functions for the forms that sympy writes out: sqrt(Σ a_i²)
    as nested hypot (no underflow of tiny, no overflow of huge a_i), exp(a) − 1 as expm1(a) and
    log(1 + a) as log1p(a) (no loss of every digit near a = 0).  The same functions, so the
    derivatives (CasADi's own) and the NaN of an undefined point are unchanged; None when
    ``e`` is none of these forms."""
    if isinstance(e, sp.Pow) and e.exp in (sp.Rational(1, 2), -sp.Rational(1, 2)):
        terms = _squares(e.base)
        if terms is not None:
            r = functools.reduce(ca.hypot, [walk(a) for a in terms])
            return r if e.exp > 0 else 1 / r
    if e.is_Add and sp.S.NegativeOne in e.args:
        exps = [t for t in e.args if isinstance(t, sp.exp)]
        if exps:
            rest = [t for t in e.args if t is not exps[0] and t != sp.S.NegativeOne]
            out = ca.expm1(walk(exps[0].args[0]))
            return functools.reduce(lambda a, b: a + b, [walk(t) for t in rest], out)
    if isinstance(e, sp.log) and len(e.args) == 1 and e.args[0].is_Add and sp.S.One in e.args[0].args:
        rest = sp.Add(*[t for t in e.args[0].args if t != sp.S.One])
        return ca.log1p(walk(rest))
    return None


def _convert(e: sp.Basic, walk: Callable, partial: Callable | None = None):
    if e.is_Number:
        if e is sp.nan:
            # A NaN branch of a traced np.maximum / np.minimum (NaN in, NaN out, as NumPy).
            return ca.SX(np.nan)
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
    careful = _careful(e, walk)
    if careful is not None:
        return careful
    op = _NARY.get(e.func)
    if op is not None:
        reused = partial(e) if partial is not None and e.func in (sp.Add, sp.Mul) else None
        if reused is not None:
            return functools.reduce(op, [walk(a) for a in reused[1]], reused[0])
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
        # but derivatives of the branch not taken do not leak into the result.
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
    if isinstance(e, sp.ITE):  # sympy's form of a comparison of a Piecewise
        return ca.if_else(walk(e.args[0]), walk(e.args[1]), walk(e.args[2]))
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


# --------------------------------------------------------------------------- C code
def generated_c(f: ca.Function, *more: ca.Function) -> str:
    """CasADi's C source of ``f`` (and of the functions ``more``, in one file that shares
    their helpers; no header, no main), with symmon's faster dense product
    (:func:`symmon.compile.ckernels.faster_kernels`: the same results to the bit)."""
    gen = ca.CodeGenerator(f.name() + ".c", {"with_header": False})
    for g in (f,) + more:
        gen.add(g)
    return faster_kernels(gen.dump())


def rows_c(f: ca.Function) -> str:
    """C source of ``f`` plus ``NAME_rows``, which evaluates f on each row of a batch
    (``rows.c``: row i of x in, row i of each output out)."""
    return generated_c(f) + c_defines(
        ROWS_F=f.name(), ROWS_RUN=f"{f.name()}_rows", ROWS_SZ_ARG=max(f.sz_arg(), 1),
        ROWS_SZ_RES=max(f.sz_res(), f.n_out()), ROWS_N_IN=f.nnz_in(0), ROWS_N_OUT=f.n_out(),
        ROWS_NNZ_OUT=[f.nnz_out(k) for k in range(f.n_out())]) + c_file(__package__, "rows.c")


def _load_rows(name: str) -> Callable[[Path], Callable]:
    """Loader of ``NAME_rows`` from a library (for :class:`NativeLibrary`)."""
    def load(path: Path):
        rows = getattr(ctypes.CDLL(str(path)), f"{name}_rows")
        rows.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p, ctypes.c_void_p]
        rows.restype = ctypes.c_int
        return rows
    return load


#: Rows of a compiled evaluation per thread, at least: below 2 × this a batch runs on the
#: calling thread (a thread costs about 50 µs; a row of a small model well under 1 µs).
MIN_ROWS_PER_THREAD = 4096


_cpu_count: list = [None, 1]  # (os.cpu_count, os.sched_getaffinity) and their count


def cpu_count() -> int:
    """The CPUs this process may run on: ``os.cpu_count()``, at most the CPUs of its affinity
    mask where the system has one (``os.sched_getaffinity``: a container's or a batch job's
    share of a larger machine, where ``os.cpu_count()`` counts the machine's), so that a
    compiled loop starts no more threads than can run at once.  Read once (``os.cpu_count``
    reads a file, about 10 µs a call), and again when either function is replaced (a test's
    monkeypatch); a change of the affinity after the first call is not seen."""
    fns = (os.cpu_count, getattr(os, "sched_getaffinity", None))
    if _cpu_count[0] != fns:
        n = fns[0]() or 1
        if fns[1] is not None:
            n = min(n, len(fns[1](0)) or 1)
        _cpu_count[:] = [fns, n]
    return _cpu_count[1]


def row_spans(N: int, least: int = MIN_ROWS_PER_THREAD) -> list[tuple[int, int]]:
    """The rows [a, b) of each thread for a compiled evaluation of N rows: one per CPU with
    at least ``least`` each, and one span off the main thread (inside a thread pool of
    symmon's, or of the caller's, the pool already uses the cores)."""
    if N < 2 * least:  # the common small batch
        return [(0, N)]
    threads = 1
    if threading.current_thread() is threading.main_thread():
        threads = min(cpu_count(), N // least)
    return even_spans(N, threads)


def even_spans(N: int, parts: int) -> list[tuple[int, int]]:
    """[0, N) as ``parts`` contiguous spans [a, b) of near-equal length (the rows, runs or
    columns of each thread)."""
    if parts <= 1:
        return [(0, N)]
    edges = np.linspace(0, N, parts + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


_pool: tuple[int, ThreadPoolExecutor] | None = None  # (the pid that made it, the pool)
_pool_lock = threading.Lock()


def _thread_pool() -> ThreadPoolExecutor:
    """One pool of one thread per CPU for every compiled loop, kept for the process, so that a
    call starts no thread and each thread keeps its work arrays (:class:`WorkArrays`); a
    forked child, which has the pool but not its threads, makes its own."""
    global _pool
    with _pool_lock:
        if _pool is None or _pool[0] != os.getpid():
            _pool = (os.getpid(), ThreadPoolExecutor(cpu_count(), thread_name_prefix="symmon-c"))
        return _pool[1]


#: Seconds between two looks of a waiting thread at its pending signals: a Ctrl-C that
#: arrives just before the thread blocks on a future is otherwise handled only when the
#: future is done (CPython runs the handler when the wait returns).
SIGNAL_POLL = 0.1


def _result(f: Future) -> Any:
    """``f.result()``, waiting in slices of :data:`SIGNAL_POLL` seconds."""
    while True:
        try:
            return f.result(timeout=SIGNAL_POLL)
        except FutureTimeout:
            continue


def in_threads(part: Callable[[Any], int], items: Sequence[Any], stop: np.ndarray | None = None,
               offload: bool = False) -> list[int]:
    """``part(item)`` for each item, on the threads of one pool when there are several (a
    ctypes call into compiled C releases the GIL, so they run in parallel); the return
    codes, in order.  A part must not itself wait on the pool.

    When the waiting thread is interrupted (Ctrl-C: KeyboardInterrupt, or any exception),
    the parts not started are cancelled and, with ``stop`` (a one-entry int array that the
    parts' C loops poll between steps, :data:`~symmon.compile.ckernels.STOP_POLL`), it is
    set to 1 and the running parts are waited for, which end at their next step: the
    interrupt leaves no loop running in the shared pool for the next call to queue
    behind.  A part that starts after that returns :data:`~symmon.compile.ckernels.STOPPED`
    at once.  The parts are counted as they start, not by their futures, so that an
    interrupt arriving while they are being submitted still waits for every one that runs.
    Without ``stop`` the running parts end on their own (short batches).

    A single item runs on the calling thread, except with ``stop`` and ``offload`` (the
    caller expects a long loop: tens of milliseconds and more) on the main thread: there it
    runs on the pool, so that a Ctrl-C, which only the main thread receives (and handles only
    between two bytecodes, never during a C call), reaches the waiting thread at once and
    stops the loop.  A short one stays: the hand-over to a pool thread and back costs a few
    hundred microseconds on a loaded virtual machine (measured: 0.4 ms a call).
    """
    if len(items) == 1 and not (stop is not None and offload and threading.current_thread() is threading.main_thread()):
        return [part(items[0])]
    running = [0]
    idle = threading.Condition()

    def task(item: Any) -> int:
        with idle:
            if stop is not None and stop[0]:
                return STOPPED
            running[0] += 1
        try:
            return part(item)
        finally:
            with idle:
                running[0] -= 1
                idle.notify_all()

    futures: list = []
    try:
        pool = _thread_pool()
        for item in items:
            futures.append(pool.submit(task, item))
        return [_result(f) for f in futures]
    except BaseException:
        for f in futures:
            f.cancel()
        if stop is not None:
            with idle:
                stop[...] = 1
                idle.wait_for(lambda: running[0] == 0)
        raise


def run_stoppable(part: Callable[[Any, int], int], items: Sequence[Any], long: bool = False) -> list[int]:
    """``part(item, stop)`` for each item by :func:`in_threads`, ``stop`` the address of a
    fresh flag (a C ``int``) that the parts' C loops poll between their steps and, where a
    step is long, within it (:data:`~symmon.compile.ckernels.STOP_POLL`); the return codes,
    in order.  ``long``: the caller expects the loops to run long (tens of milliseconds and
    more), and a single item on the main thread goes to the pool too, so that a Ctrl-C
    stops it (:func:`in_threads`).

    Raises
    ------
    KeyboardInterrupt
        On a Ctrl-C of the waiting thread, once every running loop has seen the flag and
        returned; or when a loop returned :data:`~symmon.compile.ckernels.STOPPED` (its flag
        set by another thread): the loops stopped part way, so there is no result.
    """
    stop = np.zeros(1, dtype=np.intc)
    codes = in_threads(lambda item: part(item, stop.ctypes.data), items, stop=stop, offload=long)
    if STOPPED in codes:
        raise KeyboardInterrupt("a compiled loop was stopped before its end")
    return codes


def address(a: np.ndarray) -> int:
    """The address of the data of a C-contiguous array: ``ctypes.addressof`` of its buffer,
    a third of the cost of ``a.ctypes.data`` (1.2 µs), which a read-only or empty array takes."""
    try:
        return ctypes.addressof(ctypes.c_char.from_buffer(a))
    except (TypeError, ValueError):
        return a.ctypes.data


#: Bytes of a cache line: work arrays of two threads never share one.
CACHE_LINE = 64


def padded(n: int, dtype=np.float64) -> np.ndarray:
    """A zeroed array of n items that starts on a cache line and owns the rest of its last
    one, so that two threads writing two of them never write the same line."""
    item = np.dtype(dtype).itemsize
    per_line = CACHE_LINE // item
    raw = np.zeros(n + 2 * per_line, dtype=dtype)
    start = (-raw.ctypes.data % CACHE_LINE) // item
    return raw[start:start + n]


class WorkArrays:
    """The integer and real work arrays of compiled CasADi functions, one pair per thread,
    made on first use in that thread (each on its own cache lines) and large enough for
    every function given."""

    def __init__(self, *functions: ca.Function) -> None:
        self.sizes = (max(max(f.sz_iw() for f in functions), 1), max(max(f.sz_w() for f in functions), 1))
        self._local = threading.local()

    def addresses(self) -> tuple[int, int]:
        """The addresses of this thread's arrays (integer, real)."""
        ws = getattr(self._local, "ws", None)
        if ws is None:
            arrays = (padded(self.sizes[0], np.int64), padded(self.sizes[1]))
            # The arrays with their addresses: reading .ctypes.data costs a microsecond a call.
            ws = self._local.ws = (arrays, arrays[0].ctypes.data, arrays[1].ctypes.data)
        return ws[1], ws[2]


# --------------------------------------------------------------------------- compiled model
class _Batched:
    """Evaluate a Function of one (n_in,) input on batches of rows, through buffers.

    Compiled: one C library per function whatever the batch sizes (a row loop called
    through ctypes, which releases the GIL).  On CasADi's VM: maps of power-of-two
    sizes up to CHUNK, at most 14 per function, so no batch is padded.
    """

    def __init__(self, f: ca.Function, compiled: bool) -> None:
        self._f = f
        self._compiled = compiled
        self.n_in = f.size1_in(0)
        self.out_nnz = [f.nnz_out(i) for i in range(f.n_out())]
        self._maps: dict[int, ca.Function] = {}
        self._lock = threading.Lock()
        self._work = WorkArrays(f)
        self._pointers = ctypes.c_void_p * len(self.out_nnz)  # the type of the outputs' address array
        self.native: NativeLibrary | None = None
        self.used = False

    def _native(self) -> NativeLibrary | None:
        """The compiled library, started on first use (stack: __call__ ← eval_* ← caller)."""
        if self._compiled and self.native is None:
            with self._lock:
                if self.native is None:
                    self.native = NativeLibrary(rows_c(self._f), self._f.name(), _load_rows(self._f.name()),
                                                stacklevel=5)
        return self.native

    def _vm_map(self, n: int) -> ca.Function:
        with self._lock:
            fm = self._maps.get(n)
            if fm is None:
                fm = self._maps[n] = self._f.map(f"{self._f.name()}_map{n}", "serial", n, [], [])
            return fm

    @property
    def evaluator(self) -> str:
        """The evaluator of the latest call (see :attr:`CompiledModel.evaluator`)."""
        return "vm" if self.native is None else self.native.evaluator

    def __call__(self, X: np.ndarray) -> list[np.ndarray]:
        X = np.ascontiguousarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != self.n_in:
            raise ShapeError(f"batch must have shape (N, {self.n_in}), got {X.shape}")
        N = X.shape[0]
        outs = [np.empty((N, k)) for k in self.out_nnz]
        if N == 0:
            return outs
        if not self.used and not self._compiled:
            log.info("symmon: %s: evaluating on CasADi's VM (no compiled C wanted or available)", self._f.name())
        self.used = True
        native = self._native()
        rows = native.get() if native is not None else None
        if rows is not None:
            spans = row_spans(N)
            if len(spans) == 1:  # the common small batch: one call, no slices (a few µs of a propagate)
                iw, w = self._work.addresses()
                if rows(address(X), self._pointers(*[address(o) for o in outs]), N, iw, w):
                    raise RuntimeError(f"the compiled function {self._f.name()} returned an error")
                return outs

            def part(ab: tuple[int, int]) -> int:
                a, b = ab
                iw, w = self._work.addresses()
                return rows(X[a:].ctypes.data, self._pointers(*[o[a:].ctypes.data for o in outs]), b - a, iw, w)

            if any(in_threads(part, spans)):
                raise RuntimeError(f"the compiled function {self._f.name()} returned an error")
            return outs
        start = 0
        while start < N:
            size = min(CHUNK, 1 << ((N - start).bit_length() - 1))
            fb, ev = self._vm_map(size).buffer()
            fb.set_arg(0, memoryview(X[start:start + size]))
            for i, o in enumerate(outs):
                fb.set_res(i, memoryview(o[start:start + size]))
            ev()
            start += size
        return outs


def batched(f: ca.Function, compiled: bool | None = None) -> _Batched:
    """An evaluator of ``f`` (one dense (n_in,) input) on batches of rows: ``ev(X)`` with X
    (N, n_in) returns each output's nonzeros as (N, nnz).  Compiled C with a row loop (through
    the compile policy, docs/compile.md) when a compiler is there (``compiled=None``) or
    asked for, else CasADi's VM; the evaluator of :class:`CompiledModel`'s g and derivatives,
    for other generated functions (the Gaussian-sum filter's component steps)."""
    return _Batched(f, has_compiler() if compiled is None else compiled)


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
    w_sx, y_sx, J_sx, H_sx : casadi.SX
        The symbols w, and g, J and the full Hessians (a list) as expressions of them,
        for graphs built on the model (:mod:`symmon.codegen.symbolic`).
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
    hess_support_size : (n_y,) int array
        |S_i|, the unpadded length of row i of ``hess_support``.
    name : str
        The name as given (any text); ``tag`` is the C identifier made of it
        (:func:`symmon.compile.cnames.c_identifier`) that prefixes every function name.
    compiled : bool
        Whether compiled C is wanted (and a compiler available); :attr:`evaluator` says
        what actually ran.
    """

    def __init__(self, outputs: Sequence[sp.Expr], symbols: Sequence[sp.Symbol], name: str = "g",
                 compiled: bool | None = None) -> None:
        self.symbols = tuple(symbols)
        self.source_exprs = tuple(outputs)
        self.n_w = len(self.symbols)
        self.n_y = len(outputs)
        self.name = name
        self.tag = tag = "sm_" + c_identifier(name)
        w = ca.SX.sym("w", self.n_w)
        y = ca.densify(ca.vertcat(*to_casadi(outputs, self.symbols, w)))
        self.w_sx, self.y_sx = w, y
        # J and the Hessians as SX of w, built once: the evaluators below and the symbolic
        # moments of the filter step and export_c (symmon.codegen.symbolic) use them.
        self.J_sx = J = ca.jacobian(y, w)
        self.H_sx = [ca.hessian(y[i], w)[0] for i in range(self.n_y)]
        # Hessians are symmetric: evaluate the lower triangle of each.
        H = [ca.tril(h) for h in self.H_sx]
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
        self._circle: dict[tuple[int, ...], ca.Function] = {}
        self.jac = ca.Function(f"{tag}_J", [w], [J], ["w"], ["J"])
        # Buffers carry nonzeros only: the outputs are dense columns of nonzeros.
        H_nz = ca.vertcat(ca.SX(0, 1), *[_nonzeros(h) for h in H])
        # CSE merges the subexpressions that g, J and the Hessians share (~15% less C).
        self.derivs = ca.Function(f"{tag}_gJH", [w], [y, _nonzeros(J), H_nz],
                                  ["w"], ["y", "J_nz", "H_nz"], {"cse": True})
        self.compiled = has_compiler() if compiled is None else compiled
        if compiled is None and not self.compiled:
            # The default asked for C but none is available: say so (once per process).
            warn_no_compiler(stacklevel=2)
        self._batch_g = _Batched(self.g, self.compiled)
        self._batch_derivs = _Batched(self.derivs, self.compiled)
        self._kernels: list[NativeLibrary] = []

    def native_library(self, code: str, stem: str, load: Callable[[Path], Any], stacklevel: int = 2) -> NativeLibrary:
        """A :class:`~symmon.compile.ccache.NativeLibrary` of extra C code for this model (e.g.
        the Monte Carlo kernel), built by the compile policy and counted in
        :attr:`evaluator`."""
        lib = NativeLibrary(code, stem, load, stacklevel=stacklevel + 1)
        with _cache_lock:
            self._kernels.append(lib)
        return lib

    @property
    def evaluator(self) -> str:
        """Which evaluator the model's functions used in their latest calls.

        ``"compiled"`` when all ran as compiled C, ``"vm (C build running)"`` when one
        ran on CasADi's virtual machine while its C is built in the background,
        ``"vm"`` when one ran on the VM for good (no compiler, ``SYMMON_COMPILE=never``
        or a failed build), and ``"none"`` before any evaluation.
        """
        with _cache_lock:
            states = {b.evaluator for b in (self._batch_g, self._batch_derivs) if b.used}
            states |= {lib.evaluator for lib in self._kernels}
        for s in ("vm (C build running)", "vm", "compiled"):
            if s in states:
                return s
        return "none"

    def wait_compiled(self, timeout: float | None = None) -> str:
        """Wait for the background C builds started so far; return :attr:`evaluator`."""
        libs = [b.native for b in (self._batch_g, self._batch_derivs) if b.native is not None] + self._kernels
        for lib in libs:
            lib.wait(timeout)
        return self.evaluator

    def _hess_layout(self) -> None:
        """Supports S_i of the Hessians and where each nonzero goes in the blocks H_i[S_i, S_i]."""
        out, rows, cols = self.hess_index
        supports = [np.union1d(rows[out == i], cols[out == i]) for i in range(self.n_y)]
        self.hess_support_size = np.array([len(S) for S in supports], dtype=np.intp)
        s = max(self.hess_support_size, default=0)
        self.hess_support = np.zeros((self.n_y, s), dtype=np.intp)
        pos = np.zeros((self.n_w, self.n_y), dtype=np.intp)  # pos[a, i]: place of a in S_i
        for i, S in enumerate(supports):
            self.hess_support[i, : len(S)] = S
            pos[S, i] = np.arange(len(S))
        a, b = pos[rows, out], pos[cols, out]
        # Flat positions in an (n_y, s, s) array of blocks, and of the mirrored entries.
        self._block_at = (out * s + a) * s + b
        self._block_at_t = (out * s + b) * s + a

    def circle_function(self, angles: Sequence[int]) -> ca.Function:
        """w ↦ [g(w); sin y_A; cos y_A] for the angle outputs A = sorted(angles) (all sines,
        then all cosines), for the circular mean of a point rule: a bearing atan2(a, b) has
        them as a / r and b / r (:func:`~symmon.core.angles.circle_point`), computed with g
        in one function so that a and b are shared.  Made once per A."""
        rows = tuple(sorted(angles))
        with _cache_lock:
            f = self._circle.get(rows)
            if f is None:
                y = self.y_sx
                sines, cosines = zip(*[circle_point(y[i]) for i in rows]) if rows else ((), ())
                f = self._circle[rows] = ca.Function(f"{self.tag}_gcs", [self.w_sx],
                                                     [ca.vertcat(y, *sines, *cosines)], ["w"], ["y_sc"],
                                                     {"cse": True})
            return f

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


_cache: dict[str, CompiledModel] = {}
_cache_lock = threading.Lock()


def model_key(outputs: Sequence[sp.Expr], symbols: Sequence[sp.Symbol]) -> str:
    """The key of the compiled functions of ``outputs`` in the variables ``symbols``: the
    structural hash of both, in order (:func:`symmon.core.dag.digest`).

    Its cost is linear in the distinct nodes of the outputs (printing them, as an earlier
    key did, takes exponential time on a traced loop), and it is the same in every process.
    """
    return digest([sp.Tuple(*outputs), sp.Tuple(*symbols)])


def compile_model(outputs: Sequence[sp.Expr], symbols: Sequence[sp.Symbol], name: str = "g") -> CompiledModel:
    """A :class:`CompiledModel`, cached per (outputs, symbols) in this process
    (:func:`model_key`)."""
    key = model_key(outputs, symbols)
    with _cache_lock:
        cm = _cache.get(key)
        if cm is None:
            cm = CompiledModel(outputs, symbols, name=f"{name}_{key[:10]}")
            _cache[key] = cm
    return cm


def compiled(model: Model) -> CompiledModel:
    """The compiled CasADi functions of ``model`` with respect to w = [u; v] (cached).

    Raises
    ------
    ModelError
        If the model declares parameters: their values come first
        (:meth:`Model.with_params`), except in the filters, which take them as inputs
        (:func:`compiled_with_params`).
    """
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"expected a symmon.Model, got {type(model).__name__}")
    if model.params:
        raise ModelError(
            f"model {model.name!r} has parameters {[str(s) for s in model.params]}: give their values, "
            "model.with_params({...}) (the filters take params= at each call)")
    return _of_model(model, False)


#: CompiledModel of each model by its structural key (``Model.key``, computed once per Model
#: object), so that a call with the same model costs one lookup, not a walk of its outputs.
_by_model: dict[tuple[str, bool], CompiledModel] = {}


def _of_model(model: Model, with_params: bool) -> CompiledModel:
    cm = _by_model.get((model.key, with_params))
    if cm is None:
        symbols = model.inputs + model.noise + (model.params if with_params else ())
        cm = _by_model[(model.key, with_params)] = compile_model(model.outputs, symbols, model.name)
    return cm


def compiled_with_params(model: Model) -> CompiledModel:
    """The compiled functions of ``model`` with respect to z = [u; v; p], its parameters p
    appended to the inputs (cached): the graphs of the filter steps slice z, so that the
    parameters are inputs of the compiled steps and their derivatives are exact."""
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"expected a symmon.Model, got {type(model).__name__}")
    return _of_model(model, True)
