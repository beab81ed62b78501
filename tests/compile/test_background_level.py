"""The optimisation level of a background build (symmon.compile.ccache.background_level).

C above HUGE_BYTES is built at -O0 when one function holds most of it (gcc's time grows faster
than the code within a function: minutes at -O2 for a 735 KB straight-line function), and at
-O3 when it is many functions of at most SPLIT_FUNCTION_BYTES (gcc's time about linear over
them: the 674 KB Hessian library of the fit at n = 30, functions of at most 94 KB, builds in
about 20 s at -O3 and evaluates 3.8 times faster than at -O0; docs/compile.md).
"""

from __future__ import annotations

import casadi as ca

from symmon.compile.ccache import (HUGE_BYTES, OPT_HUGE, OPT_SYNC, SPLIT_BYTES, SPLIT_FUNCTION_BYTES,
                                   background_level, largest_function_bytes)
from symmon.compile.compiled import generated_c


def straight_line(n: int, name: str) -> ca.Function:
    """One SX function of n inputs with n² outputs sin(x_i + x_j) x_j: straight-line C."""
    x = ca.SX.sym("x", n)
    return ca.Function(name, [x], [ca.vertcat(*[ca.sin(x[i] + x[j]) * x[j] for i in range(n) for j in range(n)])])


def test_one_large_function_is_built_at_o0():
    code = generated_c(straight_line(90, "big"))
    assert len(code) > HUGE_BYTES
    assert largest_function_bytes(code) > 0.9 * len(code)  # nearly all of it one function
    assert background_level(code) == OPT_HUGE


def test_many_small_functions_are_built_at_o3():
    fs = [straight_line(30, f"part{i}") for i in range(12)]
    code = generated_c(*fs)
    one = len(generated_c(fs[0]))
    assert HUGE_BYTES < len(code) <= SPLIT_BYTES
    assert largest_function_bytes(code) <= min(one, SPLIT_FUNCTION_BYTES)
    assert background_level(code) == OPT_SYNC
    assert background_level(code[:HUGE_BYTES // 2]) == OPT_SYNC  # small C: -O3 as before


def test_too_much_split_code_is_still_built_at_o0():
    block = "static int f(void) {\n  return 0;\n}\n"
    many = block * (SPLIT_BYTES // len(block) + 1)
    assert largest_function_bytes(many) < 100
    assert background_level(many) == OPT_HUGE
    # Without a closing brace in the first column the whole file counts as one function.
    assert largest_function_bytes("x" * 1000) == 1000
