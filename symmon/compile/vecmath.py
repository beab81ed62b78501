"""Vectorised elementary functions accurate to 1 ulp, and a row loop gcc vectorises.

The Monte Carlo kernel (:mod:`symmon.transforms.mc_kernel`) evaluates one compiled row
per sample.  CasADi's generated C calls its function once per row, and libm's ``atan2``
and ``hypot`` are scalar calls, so the loop runs one sample at a time.  Here:

- :data:`VECMATH_C`: ``sm_atan2`` and ``sm_hypot`` in plain C without branches
  (``vecmath.c``, its numbers computed here as ``SM_`` macros), written for this package
  (no vendored library), so that gcc vectorises a loop that calls them.
  Both work in double-double arithmetic with explicit ``fma`` (an exact operation, not
  a contraction: the builds keep ``-ffp-contract=off``), and their results are the
  exact value rounded once more, within 1 ulp of the true value (measured against
  mpmath in tests/test_vecmath.py).  Every lane computes the same IEEE operations in
  the same order whatever the vector width, so the numbers do not depend on the CPU's
  vector instructions: they are those of the scalar C.  Arguments outside the ordinary
  range (zero, subnormal or beyond 2^±500, inf, NaN) set a flag, and the row loop
  recomputes those rows with CasADi's C (libm's functions).
- :func:`vector_rows`: the C of a loop over the rows of a chunk, the row's arithmetic
  written out from the instructions of a CasADi SX function (one C statement per
  instruction, as CasADi's own generator writes them), with ``restrict`` pointers and
  no calls left but the ones above, so that gcc -O3 vectorises it.  A function with any
  other operation (sin, exp, pow, ...) gets no vector loop (``None``): libm's scalar
  functions keep it as it is.

Why not a library: glibc's vector math library (libmvec) documents errors up to 4 ulp
(measured: atan2 2.35 ulp, hypot 1.16 ulp; docs/compile.md) and gcc calls it only under
``-ffast-math``; SLEEF has no wheel on the package index, and its build needs CMake.

atan2 (y, x): with n = min(|x|, |y|), d = max(|x|, |y|), t = n / d in [0, 1] is kept as a
double-double t + t_l (t_l = fma(−t, d, n) / d), reduced around c = k/8 (k = round 8t) by
atan t = atan c + atan u, u = (t − c)/(1 + t c), |u| ≤ 1/16, with u also a double-double
and atan u = u − u³/3 + … + u¹⁵/15 (the next term is below 2⁻⁶⁴ u); atan c comes from a
table of double-doubles (mpmath at import).  Then π/2 − · when |y| > |x| and π − · when
x < 0, in double-double, one rounding at the end, and the sign of y.

exp (x), for the particle filter's weights (:mod:`symmon.filters.particle._kernel`): x = k ln 2 + r
with k = round(x / ln 2) and r a double-double (Cody and Waite's split of ln 2, k ln2_hi
exact), exp r = 1 + r + r² (1/2! + … + r¹¹/13!) with 1 + r_h summed exactly, and 2^k from
the bits of the rounding constant: within 0.64 ulp (measured against long double on 10⁶
arguments), for x in [−708, 709] (``sm_exp_ordinary``; the caller takes libm's exp beyond).

hypot (x, y): h = √(x² + y²), then one Newton step h + (x² + y² − h²)/(2h) with the
residual computed exactly (two-product by fma, two-sum).
"""

from __future__ import annotations

import casadi as ca
import mpmath

from .csource import c_defines, c_file

__all__ = ["VECMATH_C", "VECTOR_OPS", "PARAMETER_OPS", "vector_rows", "split_parameters", "ORDINARY_EXP", "EXP_LOW", "EXP_HIGH"]

#: Arguments with |a| in [2^-ORDINARY_EXP, 2^ORDINARY_EXP] are ordinary: no product of the
#: double-double steps overflows or underflows.  Others go to libm (CasADi's C).
ORDINARY_EXP = 500
#: ``sm_exp(x)`` is for x in [−EXP_LOW, EXP_HIGH] (``sm_exp_ordinary``): the result and the
#: scale 2^k are normal doubles (exp(−708) ≈ 3.3e−308 > 2^−1022, k ≤ 1023); others to libm.
EXP_LOW, EXP_HIGH = 708.0, 709.0


def _dd(x: mpmath.mpf) -> tuple[float, float]:
    hi = float(x)
    return hi, float(x - hi)


def _tables() -> tuple[list[tuple[float, float]], tuple[float, float], tuple[float, float]]:
    with mpmath.workprec(256):
        table = [_dd(mpmath.atan(mpmath.mpf(k) / 8)) for k in range(9)]
        return table, _dd(mpmath.pi / 2), _dd(mpmath.pi)


def _constants() -> dict[str, float]:
    """The numbers of ``vecmath.c``, its ``SM_`` macros: the table of atan(k/8) for k = 0 ... 8
    and π/2, π as double-doubles, the Taylor coefficients of atan (−1/3, 1/5, ..., −1/15) and of
    exp (1/2!, ..., 1/13!), Cody and Waite's split of ln 2, and the ranges of the ordinary
    arguments."""
    table, (p2h, p2l), (pih, pil) = _tables()
    with mpmath.workprec(256):
        ln2 = mpmath.log(2)
        ln2_hi = float(mpmath.floor(ln2 * 2**32) / 2**32)  # 32 bits: k ln2_hi exact for |k| < 2^21
        ln2_lo = float(ln2 - ln2_hi)
        log2e = float(1 / ln2)
    out = {"SM_SMALL": 2.0 ** -ORDINARY_EXP, "SM_BIG": 2.0 ** ORDINARY_EXP}
    out.update({f"SM_ATAN_HI{k}": hi for k, (hi, _) in enumerate(table)})
    out.update({f"SM_ATAN_LO{k}": lo for k, (_, lo) in enumerate(table)})
    out.update({f"SM_ATAN_C{2 * j + 1}": (-1) ** j / (2 * j + 1) for j in range(1, 8)})
    out.update(SM_PI2_HI=p2h, SM_PI2_LO=p2l, SM_PI_HI=pih, SM_PI_LO=pil, SM_EXP_MIN=-EXP_LOW,
               SM_EXP_MAX=EXP_HIGH, SM_LOG2E=log2e, SM_LN2_HI=ln2_hi, SM_LN2_LO=ln2_lo)
    out.update({f"SM_EXP_C{j}": float(1 / mpmath.factorial(j)) for j in range(2, 14)})
    return out


#: The C of ``sm_atan2``, ``sm_exp`` and ``sm_hypot`` (``vecmath.c`` after its ``SM_`` macros;
#: see the module docstring).
VECMATH_C = c_defines(**_constants()) + c_file(__package__, "vecmath.c")

#: CasADi SX operations the vector loop writes out, as C of their operands (strings).
VECTOR_OPS = {
    ca.OP_ASSIGN: "{0}", ca.OP_ADD: "({0}+{1})", ca.OP_SUB: "({0}-{1})", ca.OP_MUL: "({0}*{1})",
    ca.OP_DIV: "({0}/{1})", ca.OP_NEG: "(-{0})", ca.OP_SQ: "({0}*{0})", ca.OP_TWICE: "(2.*{0})",
    ca.OP_INV: "(1./{0})", ca.OP_SQRT: "sqrt({0})", ca.OP_FABS: "fabs({0})", ca.OP_FLOOR: "floor({0})",
    ca.OP_CEIL: "ceil({0})", ca.OP_LT: "({0}<{1})", ca.OP_LE: "({0}<={1})", ca.OP_EQ: "({0}=={1})",
    ca.OP_NE: "({0}!={1})", ca.OP_NOT: "(!{0})", ca.OP_AND: "({0}&&{1})", ca.OP_OR: "({0}||{1})",
    ca.OP_IF_ELSE_ZERO: "({0}?{1}:0)", ca.OP_COPYSIGN: "copysign({0},{1})",
    ca.OP_ATAN2: "sm_atan2({0},{1})", ca.OP_HYPOT: "sm_hypot({0},{1})",
}
#: Operations of libm that the vector loop evaluates once per call where their arguments depend
#: on the parameters and constants only (:func:`vector_rows`), as CasADi's C writes them.
PARAMETER_OPS = {
    ca.OP_SIN: "sin({0})", ca.OP_COS: "cos({0})", ca.OP_TAN: "tan({0})", ca.OP_ASIN: "asin({0})",
    ca.OP_ACOS: "acos({0})", ca.OP_ATAN: "atan({0})", ca.OP_SINH: "sinh({0})", ca.OP_COSH: "cosh({0})",
    ca.OP_TANH: "tanh({0})", ca.OP_ASINH: "asinh({0})", ca.OP_ACOSH: "acosh({0})", ca.OP_ATANH: "atanh({0})",
    ca.OP_EXP: "exp({0})", ca.OP_LOG: "log({0})", ca.OP_ERF: "erf({0})", ca.OP_POW: "pow({0},{1})",
    ca.OP_CONSTPOW: "pow({0},{1})", ca.OP_FMOD: "fmod({0},{1})",
}
#: Operations whose arguments must be ordinary (:data:`ORDINARY_EXP`) for the vector result.
_CHECKED = (ca.OP_ATAN2, ca.OP_HYPOT)


def _literal(v: float) -> str:
    if v != v:
        return "NAN"
    if v in (float("inf"), float("-inf")):
        return "INFINITY" if v > 0 else "(-INFINITY)"
    return f"({v.hex()})"


def vector_rows(f: ca.Function, name: str, n_in: int, ld: int) -> str | None:
    """C of ``int {name}(const double* z, const double* p, double* out, long long n,
    unsigned char* odd)``: for each of n ≤ ld rows, output k of f(z[i*n_in:], p) in
    ``out[k*ld + i]`` (a block by columns, so that the stores are contiguous), and
    ``odd[i]`` = 1 where an argument of atan2 or hypot is not ordinary (the row's numbers
    are then to be recomputed by CasADi's C); returns the number of such rows.

    ``f`` is an SX function of two dense inputs (a row, parameters shared by every row) and
    one dense output.  The instructions that depend on the parameters and constants only
    (a ``cos(1.2 k)`` of a per-step parameter k) are evaluated once per call, before the
    loop, by the same C operations (:data:`VECTOR_OPS`, or libm's function for those of
    :data:`PARAMETER_OPS`, as CasADi's C calls it): the same numbers as per row.  Returns
    None when an instruction that depends on the row has an operation outside
    :data:`VECTOR_OPS`.
    """
    if not f.is_a("SXFunction") or f.n_in() != 2 or f.n_out() != 1:
        return None
    pre, body, used = [], [], set()
    at: dict[int, str] = {}  # work variable -> the C name of the value it holds now
    for k in range(f.n_instructions()):
        op, ins, outs = f.instruction_id(k), f.instruction_input(k), f.instruction_output(k)
        if op == ca.OP_OUTPUT:
            body.append(f"out[{outs[1]}*{ld}+i] = {at[ins[0]]};")
            continue
        if op == ca.OP_CONST:
            code, row = _literal(float(f.instruction_constant(k))), False
        elif op == ca.OP_INPUT:
            row = ins[0] == 0
            code = f"z[i*{n_in}+{ins[1]}]" if row else f"p[{ins[1]}]"
        else:
            args = [at[j] for j in ins]
            row = any(a.startswith("v") for a in args)  # else a function of the parameters only
            form = VECTOR_OPS.get(op) if row else VECTOR_OPS.get(op, PARAMETER_OPS.get(op))
            if form is None:
                return None
            if op in _CHECKED:  # at this point: work variables are reused later
                (body if row else pre).append(f"ok{'' if row else '0'} &= sm_ordinary({args[0]}) & sm_ordinary({args[1]});")
            code = form.format(*args)
        if row:
            body.append(f"v{outs[0]} = {code};")
            at[outs[0]] = f"v{outs[0]}"
            used.add(outs[0])
        else:  # once per call, before the loop
            pre.append(f"const double h{k} = {code};")
            at[outs[0]] = f"h{k}"
    decl = f"double {', '.join(f'v{j}' for j in sorted(used))};" if used else ""
    lines = "\n    ".join(body)
    hoisted = "\n  ".join(pre)
    return f"""
static int {name}(const double* restrict z, const double* restrict p, double* restrict out,
    long long n, unsigned char* restrict odd) {{
  long long i;
  int bad = 0, ok0 = 1;
  {hoisted}
  for (i = 0; i < n; ++i) {{
    {decl}
    int ok = ok0;
    {lines}
    odd[i] = !ok;
    bad += odd[i];
  }}
  return bad;
}}
"""


#: The operations :func:`split_parameters` takes out of the rows: libm's functions.
_SPLIT_OPS = frozenset(PARAMETER_OPS) | {ca.OP_ATAN2, ca.OP_HYPOT}


def split_parameters(f: ca.Function, n_row: int) -> tuple[ca.Function, ca.Function] | None:
    """f(z) with z = [w; p] split into ``pre`` and ``row``: ``pre(p)`` = q, the values of the
    functions of :data:`PARAMETER_OPS` (libm's ``cos``, ``exp``, ...) whose arguments depend on
    p (and constants) only, and ``row(w, p, q)`` = f([w; p]), with those values read from q.

    For a batch of rows w that share p (the points of a point rule), q is computed once for
    the batch instead of once per row; every operation is the same, in the same order, so
    the numbers are f's, bit for bit.  ``f``: an SX function of one dense input (w its first
    ``n_row`` entries) and dense outputs.  None when f has no such function (nothing to
    gain) or is not an SX function.
    """
    if not f.is_a("SXFunction") or f.n_in() != 1:
        return None
    n_p = f.nnz_in(0) - n_row
    w, p = ca.SX.sym("w", n_row), ca.SX.sym("p", n_p)
    row_val: dict[int, ca.SX] = {}
    pre_val: dict[int, ca.SX | None] = {}  # the value as an expression of p, for a function of p only
    outs: list[list[ca.SX]] = [[ca.SX(0)] * f.nnz_out(i) for i in range(f.n_out())]
    q_exprs: list[ca.SX] = []
    q_syms: list[ca.SX] = []
    for k in range(f.n_instructions()):
        op, ins, res = f.instruction_id(k), f.instruction_input(k), f.instruction_output(k)
        if op == ca.OP_OUTPUT:
            outs[res[0]][res[1]] = row_val[ins[0]]
            continue
        if op == ca.OP_CONST:
            v = ca.SX(float(f.instruction_constant(k)))
            row_val[res[0]], pre_val[res[0]] = v, v
            continue
        if op == ca.OP_INPUT:
            j = ins[1]
            row_val[res[0]] = w[j] if j < n_row else p[j - n_row]
            pre_val[res[0]] = None if j < n_row else p[j - n_row]
            continue
        args = [row_val[j] for j in ins]
        pre = [pre_val[j] for j in ins]
        fixed = all(a is not None for a in pre)
        make = (lambda a: ca.SX.unary(op, *a)) if len(ins) == 1 else (lambda a: ca.SX.binary(op, *a))
        if fixed and op in _SPLIT_OPS:  # once per batch: read from q
            q = ca.SX.sym(f"q{len(q_syms)}")
            q_exprs.append(make(pre))
            q_syms.append(q)
            row_val[res[0]], pre_val[res[0]] = q, q_exprs[-1]
        else:
            row_val[res[0]] = make(args)
            pre_val[res[0]] = make(pre) if fixed else None
    if not q_syms:
        return None
    name = f.name()
    pre_f = ca.Function(f"{name}_pre", [p], [ca.vertcat(*q_exprs)], {"cse": True})
    qs = ca.vertcat(*q_syms)
    row_f = ca.Function(f"{name}_row", [w, p, qs], [ca.vertcat(*o) for o in outs], {"cse": True})
    return pre_f, row_f
