"""The expression language of model files: a whitelist parser to sympy.

:func:`parse_expression` parses the text into a Python
syntax tree and builds sympy objects node by node from a small whitelist; text from a file
is never executed or handed to sympy's string parser. Accepted:

- names: the declared input and noise symbols, the ``[params]`` constants, and the
  constants ``pi`` and ``e`` (also spelled ``E``, as sympy prints it);
- int and float literals (integers up to 1e15 in absolute value);
- binary ``+ - * / **``, unary ``-`` and ``+``, parentheses;
- calls with positional arguments of the functions in :data:`FUNCTIONS`:

  ==========================================================  =========
  function                                                    arguments
  ==========================================================  =========
  sqrt, exp, log, sin, cos, tan, asin, acos, atan              1
  sinh, cosh, tanh, asinh, acosh, atanh                        1
  abs / Abs, sign                                              1
  atan2 (atan2(y, x), the angle of the point (x, y))           2
  hypot (hypot(a, b) = sqrt(a**2 + b**2))                      2
  min / Min, max / Max                                         2 or more
  ==========================================================  =========

Everything else is refused with a :class:`ModelFileError` giving the source, the line, the
column and the reason: attributes, subscripts, lambdas, comprehensions, strings, bytes,
f-strings, dunder names, keyword and starred arguments, comparisons, boolean operators,
conditional expressions, assignment expressions, unknown names and functions, wrong
arities, exponents above 64 in absolute value or containing a power themselves, numbers
that would grow past 100 digits, expressions longer than 2000 characters or nested more
than 50 levels deep, and results that are complex or not finite, including constants
that are complex without showing it (``acos(2)``, ``(-8)**(1/3)``) or that overflow a
double (``exp(710)``).

The TOML schema that holds these expressions is in :mod:`symmon.files.modelfile`.
"""

# Security note: this module does not use eval, exec, compile, sympify or parse_expr;
# the only parser applied to file text is ast.parse, and its tree is walked by hand.

from __future__ import annotations

import ast
import math
import re
import warnings
from dataclasses import dataclass
from typing import Callable, Mapping

import sympy as sp

from ..errors import ArgumentTypeError, ModelFileError

__all__ = [
    "ModelFileError",
    "parse_expression",
    "FUNCTIONS",
    "CONSTANTS",
    "MAX_EXPRESSION_LENGTH",
    "MAX_DEPTH",
    "MAX_EXPONENT",
    "MAX_INTEGER_LITERAL",
    "MAX_RESULT_DIGITS",
]

#: Longest expression text accepted, in characters (checked before parsing).
MAX_EXPRESSION_LENGTH = 2000
#: Deepest nesting accepted: brackets in the text, and levels of the syntax tree
#: (a chain ``a + b - c + ...`` or ``a * b / c ...`` counts as one level).
MAX_DEPTH = 50
#: Largest absolute value of a numeric exponent.
MAX_EXPONENT = 64
#: Largest absolute value of an integer literal (and of an integer parameter).
MAX_INTEGER_LITERAL = 10**15
#: Largest number of decimal digits of an exact number produced while building.
MAX_RESULT_DIGITS = 100


# --------------------------------------------------------------------------------------
# The whitelist
# --------------------------------------------------------------------------------------


def _hypot(a: sp.Expr, b: sp.Expr) -> sp.Expr:
    return sp.sqrt(a**2 + b**2)


@dataclass(frozen=True)
class _Function:
    build: Callable[..., sp.Expr]
    min_args: int
    max_args: int | None  # None: any number from min_args on

    def arity(self) -> str:
        if self.max_args is None:
            return f"{self.min_args} or more arguments"
        n = self.min_args
        return f"{n} argument" + ("" if n == 1 else "s")


_UNARY = {
    "sqrt": sp.sqrt, "exp": sp.exp, "log": sp.log,
    "sin": sp.sin, "cos": sp.cos, "tan": sp.tan,
    "asin": sp.asin, "acos": sp.acos, "atan": sp.atan,
    "sinh": sp.sinh, "cosh": sp.cosh, "tanh": sp.tanh,
    "asinh": sp.asinh, "acosh": sp.acosh, "atanh": sp.atanh,
    "abs": sp.Abs, "Abs": sp.Abs, "sign": sp.sign,
}

#: The functions an expression may call: name -> (sympy builder, min and max arity).
FUNCTIONS: Mapping[str, _Function] = {
    **{name: _Function(fn, 1, 1) for name, fn in _UNARY.items()},
    "atan2": _Function(sp.atan2, 2, 2),
    "hypot": _Function(_hypot, 2, 2),
    "min": _Function(sp.Min, 2, None), "Min": _Function(sp.Min, 2, None),
    "max": _Function(sp.Max, 2, None), "Max": _Function(sp.Max, 2, None),
}

#: Named constants; ``E`` is how sympy prints Euler's number, so dumped files read back.
CONSTANTS: Mapping[str, sp.Expr] = {"pi": sp.pi, "e": sp.E, "E": sp.E}

#: Names a model file may not declare: they would shadow a function or a constant.
_RESERVED = frozenset(FUNCTIONS) | frozenset(CONSTANTS)

# Reasons for the syntax the parser refuses, by syntax-tree node type.
_REFUSED_NODES: dict[type, str] = {
    ast.Attribute: "attribute access is not allowed",
    ast.Subscript: "subscripts are not allowed",
    ast.Slice: "slices are not allowed",
    ast.Lambda: "lambda functions are not allowed",
    ast.ListComp: "comprehensions are not allowed",
    ast.SetComp: "comprehensions are not allowed",
    ast.DictComp: "comprehensions are not allowed",
    ast.GeneratorExp: "comprehensions are not allowed",
    ast.JoinedStr: "f-strings are not allowed",
    ast.FormattedValue: "f-strings are not allowed",
    ast.Compare: "comparisons are not allowed",
    ast.BoolOp: "boolean operators (and, or) are not allowed",
    ast.IfExp: "conditional expressions (x if c else y) are not allowed",
    ast.NamedExpr: "assignment expressions (:=) are not allowed",
    ast.Starred: "starred arguments are not allowed",
    ast.List: "lists are not allowed",
    ast.Tuple: "tuples are not allowed",
    ast.Set: "sets are not allowed",
    ast.Dict: "dicts are not allowed",
    ast.Await: "await is not allowed",
}

_BINOP_NAMES: dict[type, str] = {
    ast.FloorDiv: "//", ast.Mod: "%", ast.MatMult: "@", ast.LShift: "<<",
    ast.RShift: ">>", ast.BitOr: "|", ast.BitXor: "^", ast.BitAnd: "&",
}

_NEWLINE = r"\r\n|\r|\n"  # Python's line ends, as the tokenizer sees them


# --------------------------------------------------------------------------------------
# The parser
# --------------------------------------------------------------------------------------


class _Refused(Exception):
    """Internal: a refusal at a position (line and 0-based byte offset of the expression)."""

    def __init__(self, reason: str, lineno: int = 1, col: int = 0, *, char_col: bool = False):
        super().__init__(reason)
        self.reason = reason
        self.lineno = lineno
        self.col = col
        self.char_col = char_col  # True when col already counts characters


class _Builder:
    """Build a sympy expression from a syntax tree, refusing anything off the whitelist."""

    def __init__(self, names: Mapping[str, sp.Expr], functions: Mapping[str, _Function] = FUNCTIONS) -> None:
        self.names = names
        self.functions = functions
        self.checked: set[sp.Basic] = set()  # results of _checked, finite and real

    # -- entry -------------------------------------------------------------------------
    def build(self, node: ast.AST, depth: int) -> sp.Expr:
        if depth > MAX_DEPTH:
            raise self._at(node, f"expression nested too deeply (more than {MAX_DEPTH} levels)")
        if isinstance(node, ast.Constant):
            return self._constant(node)
        if isinstance(node, ast.Name):
            return self._name(node)
        if isinstance(node, ast.UnaryOp):
            return self._unary(node, depth)
        if isinstance(node, ast.BinOp):
            return self._binop(node, depth)
        if isinstance(node, ast.Call):
            return self._call(node, depth)
        reason = _REFUSED_NODES.get(type(node), f"Python syntax '{type(node).__name__}' is not allowed")
        raise self._at(node, reason)

    @staticmethod
    def _at(node: ast.AST, reason: str) -> _Refused:
        return _Refused(reason, getattr(node, "lineno", 1), getattr(node, "col_offset", 0))

    # -- leaves --------------------------------------------------------------------------
    def _constant(self, node: ast.Constant) -> sp.Expr:
        v = node.value
        if isinstance(v, bool) or v is None or v is Ellipsis:
            raise self._at(node, f"the constant {v!r} is not allowed; only numbers are")
        if isinstance(v, (str, bytes)):
            kind = "string" if isinstance(v, str) else "bytes"
            raise self._at(node, f"{kind} literals are not allowed")
        if isinstance(v, int):
            if abs(v) > MAX_INTEGER_LITERAL:
                raise self._at(node, f"integer literal too large (more than {MAX_INTEGER_LITERAL:.0e} in absolute value)")
            return sp.Integer(v)
        if isinstance(v, float):
            if not math.isfinite(v):
                raise self._at(node, "float literal is not finite")
            return sp.Float(v)
        raise self._at(node, f"{type(v).__name__} literals are not allowed")

    def _name(self, node: ast.Name) -> sp.Expr:
        name = node.id
        if name.startswith("__"):
            raise self._at(node, f"dunder names such as {name!r} are not allowed")
        if name in self.names:
            return self.names[name]
        if name in CONSTANTS:
            return CONSTANTS[name]
        if name in self.functions:
            raise self._at(node, f"the function {name!r} must be called, e.g. {name}(x)")
        known = sorted(set(self.names) | set(CONSTANTS))
        raise self._at(node, f"unknown name {name!r}; known names: {', '.join(known)}")

    # -- operators -----------------------------------------------------------------------
    def _unary(self, node: ast.UnaryOp, depth: int) -> sp.Expr:
        if isinstance(node.op, ast.USub):
            return self._checked(node, sp.Mul(sp.Integer(-1), self.build(node.operand, depth + 1)))
        if isinstance(node.op, ast.UAdd):
            return self.build(node.operand, depth + 1)
        op = "not" if isinstance(node.op, ast.Not) else "~"
        raise self._at(node, f"the operator {op!r} is not allowed")

    def _binop(self, node: ast.BinOp, depth: int) -> sp.Expr:
        if isinstance(node.op, (ast.Add, ast.Sub)):
            # A long sum is a left-leaning chain; walk it iteratively and build one Add.
            terms = self._chain(node, (ast.Add, ast.Sub), ast.Sub, depth)
            return self._checked(node, sp.Add(*[sp.Mul(sp.Integer(-1), t) if neg else t for t, neg in terms]))
        if isinstance(node.op, (ast.Mult, ast.Div)):
            factors = self._chain(node, (ast.Mult, ast.Div), ast.Div, depth)
            return self._checked(
                node, sp.Mul(*[sp.Pow(f, sp.Integer(-1)) if inv else f for f, inv in factors])
            )
        if isinstance(node.op, ast.Pow):
            return self._pow(node, depth)
        op = _BINOP_NAMES.get(type(node.op), type(node.op).__name__)
        raise self._at(node, f"the operator {op!r} is not allowed")

    def _chain(self, node: ast.BinOp, ops: tuple, inverse: type, depth: int) -> list[tuple[sp.Expr, bool]]:
        """The operands of a left-leaning chain of ``ops``, each with True if inverted."""
        spine: list[tuple[ast.AST, bool]] = []
        cur: ast.AST = node
        while isinstance(cur, ast.BinOp) and isinstance(cur.op, ops):
            spine.append((cur.right, isinstance(cur.op, inverse)))
            cur = cur.left
        lead: list[tuple[sp.Expr, bool]] = []
        if inverse is ast.Div and isinstance(cur, ast.UnaryOp) and isinstance(cur.op, ast.USub):
            # Python reads "-(a - b)*c" as (-(a - b))*c, and sympy would distribute that -1
            # into the sum. sympy prints the product -1*(a - b)*c that way, so keep the -1
            # as a factor of the whole product (the same value): printed text reads back as is.
            lead = [(sp.Integer(-1), False)]
            cur = cur.operand
            depth += 1
        spine.append((cur, False))
        spine.reverse()  # source order, so the first refusal is the leftmost one
        return lead + [(self.build(sub, depth + 1), flag) for sub, flag in spine]

    def _pow(self, node: ast.BinOp, depth: int) -> sp.Expr:
        exp_node = node.right
        literal = _literal_number(exp_node)
        if literal is not None and abs(literal) > MAX_EXPONENT:
            raise self._at(exp_node, f"exponent {literal!r} too large (limit {MAX_EXPONENT} in absolute value)")
        for sub in ast.walk(exp_node):
            if isinstance(sub, ast.BinOp) and isinstance(sub.op, ast.Pow):
                raise self._at(sub, "power towers are not allowed: an exponent may not contain '**' (use exp())")
        base = self.build(node.left, depth + 1)
        expo = self.build(exp_node, depth + 1)
        if expo.is_Number and abs(expo) > MAX_EXPONENT:
            raise self._at(exp_node, f"exponent {expo} too large (limit {MAX_EXPONENT} in absolute value)")
        if base.is_Rational and expo.is_Number:
            # A numeric power is computed exactly by sympy: bound its size first.
            p, q = base.as_numer_denom()
            digits = abs(float(expo)) * max(_digits(p), _digits(q))
            if digits > MAX_RESULT_DIGITS:
                raise self._at(node, f"numeric power too large (about {digits:.0f} digits; limit {MAX_RESULT_DIGITS})")
        return self._checked(node, sp.Pow(base, expo))

    # -- calls ---------------------------------------------------------------------------
    def _call(self, node: ast.Call, depth: int) -> sp.Expr:
        func = node.func
        if not isinstance(func, ast.Name):
            reason = _REFUSED_NODES.get(type(func), "only the listed functions may be called, by name")
            raise self._at(func, reason)
        name = func.id
        if name.startswith("__"):
            raise self._at(func, f"dunder names such as {name!r} are not allowed")
        if name not in self.functions:
            raise self._at(func, f"unknown function {name!r}; allowed functions: {', '.join(sorted(self.functions))}")
        if node.keywords:
            raise self._at(node.keywords[0], f"keyword arguments are not allowed (in a call of {name})")
        for arg in node.args:
            if isinstance(arg, ast.Starred):
                raise self._at(arg, f"starred arguments are not allowed (in a call of {name})")
        spec = self.functions[name]
        n = len(node.args)
        if n < spec.min_args or (spec.max_args is not None and n > spec.max_args):
            raise self._at(node, f"wrong number of arguments: {name} takes {spec.arity()}, got {n}")
        args = [self.build(a, depth + 1) for a in node.args]
        try:
            result = spec.build(*args)
        except (ValueError, TypeError) as exc:  # e.g. max of a complex constant: "not comparable"
            raise self._at(node, f"{name}: {exc}") from None
        return self._checked(node, result)

    # -- results -------------------------------------------------------------------------
    def _checked(self, node: ast.AST, expr: sp.Expr) -> sp.Expr:
        # Subtrees already checked are skipped: a deep expression is walked about once, not
        # once per level (sympy may still rebuild a node, which is then walked again).
        walk = sp.preorder_traversal(expr)
        for atom in walk:
            if atom in self.checked:
                walk.skip()
                continue
            if atom in (sp.zoo, sp.nan, sp.oo, sp.S.NegativeInfinity):
                raise self._at(node, f"the expression is not finite ({expr})")
            if atom == sp.I:
                raise self._at(node, f"the expression is complex ({expr})")
            if isinstance(atom, sp.Rational) and max(_digits(atom.p), _digits(atom.q)) > MAX_RESULT_DIGITS:
                # Exact big numbers make sympy's simplifications (roots, logs) slow.
                raise self._at(node, f"number too large (more than {MAX_RESULT_DIGITS} digits)")
            if isinstance(atom, sp.Float) and not math.isfinite(float(atom)):
                # sympy evaluates functions of floats itself, e.g. cosh(cosh(64.0)) = 1e(1e27).
                raise self._at(node, f"the number {str(sp.Float(atom, 4))} is not finite in double precision")
        if not expr.free_symbols and not expr.is_Number:
            # A constant such as acos(2) or (-8)**(1/3) is complex without containing I.
            value = expr.evalf(15)
            if not (value.is_Number and math.isfinite(float(value))):
                raise self._at(node, f"the constant {expr} is not a finite real number in double precision ({str(value)})")
        self.checked.add(expr)
        return expr


def _literal_number(node: ast.AST) -> int | float | None:
    """The value of a literal number, possibly signed, or None."""
    sign = 1
    while isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        sign = -sign if isinstance(node.op, ast.USub) else sign
        node = node.operand
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        return sign * node.value
    return None


def _digits(n: int | sp.Integer) -> float:
    """Number of decimal digits of an integer, from its bit length (no conversion to text)."""
    return max(int(abs(n)).bit_length(), 1) * math.log10(2)


def _nesting_error(text: str) -> _Refused | None:
    """Refuse bracket nesting deeper than MAX_DEPTH before the parser sees it."""
    depth = 0
    line, col = 1, 0
    i = 0
    while i < len(text):
        ch = text[i]
        if ch in "([{":
            depth += 1
            if depth > MAX_DEPTH:
                return _Refused(
                    f"expression nested too deeply (more than {MAX_DEPTH} levels of brackets)",
                    line, col, char_col=True,
                )
        elif ch in ")]}":
            depth -= 1
        if ch == "\r" and text[i + 1 : i + 2] == "\n":
            i += 1
        if ch in "\r\n":
            line, col = line + 1, 0
        else:
            col += 1
        i += 1
    return None


def _char_position(text: str, index: int) -> tuple[int, int]:
    """Line (1-based) and 0-based character column of ``text[index]``."""
    before = re.split(_NEWLINE, text[:index])
    return len(before), len(before[-1])


def parse_expression(
    text: str,
    symbols: Mapping[str, sp.Expr],
    *,
    source: str = "<expr>",
    line_offset: int = 0,
    col_offset: int = 0,
    functions: Mapping[str, tuple[Callable[..., sp.Expr], int, int | None]] | None = None,
) -> sp.Expr:
    """Parse an expression text into sympy through a whitelist, never executing it.

    Parameters
    ----------
    text : str
        The expression, e.g. ``"sqrt(x**2 + y**2)"``. It may span lines.
    symbols : mapping of str to sympy.Expr
        The names the expression may use: symbols, and constants (sympy numbers) that
        stand for their value. They shadow the built-in constants ``pi``, ``e`` and ``E``.
    source : str, default "<expr>"
        Where the text comes from, for error messages (a file name and key).
    line_offset : int, default 0
        Added to the line numbers in error messages (the line of the text in its file,
        minus one).
    col_offset : int, default 0
        Added to the column numbers of the first line in error messages.
    functions : mapping, optional
        More functions a caller's language allows: name -> (builder of sympy arguments,
        least and most arguments, ``None`` for any number), e.g. the derivation files'
        ``Phi``, ``erf`` and ``expect`` (:mod:`symmon.files.derivationfile`). They may not
        replace a function of :data:`FUNCTIONS`.

    Returns
    -------
    sympy.Expr

    Raises
    ------
    ModelFileError
        For anything outside the whitelist of the module docstring; the message is
        ``"<source>, line L, column C: <reason>"`` with 1-based line and column.
    TypeError
        If ``text`` is not a string or ``symbols`` maps to something that is not sympy.

    Examples
    --------
    >>> import sympy as sp
    >>> x, y = sp.symbols("x y", real=True)
    >>> parse_expression("hypot(x, y) + atan2(y, x)", {"x": x, "y": y})
    sqrt(x**2 + y**2) + atan2(y, x)
    >>> parse_expression("x.__class__", {"x": x})
    Traceback (most recent call last):
        ...
    symmon.errors.ModelFileError: <expr>, line 1, column 1: attribute access is not allowed
    """
    if not isinstance(text, str):
        raise ArgumentTypeError(f"text must be a str, got {type(text).__name__}")
    names: dict[str, sp.Expr] = {}
    for key, value in symbols.items():
        if not isinstance(key, str) or not isinstance(value, sp.Basic):
            raise ArgumentTypeError(f"symbols must map names (str) to sympy objects, got {key!r}: {value!r}")
        names[key] = value
    table: Mapping[str, _Function] = FUNCTIONS
    if functions:
        clash = sorted(set(functions) & set(FUNCTIONS))
        if clash:
            raise ArgumentTypeError(f"functions may not replace the built-in functions {clash}")
        table = {**FUNCTIONS, **{k: _Function(*spec) for k, spec in functions.items()}}
    try:
        return _parse(text, names, table)
    except _Refused as r:
        if r.char_col:
            col = r.col
        else:
            lines = re.split(_NEWLINE, text)
            line_text = lines[r.lineno - 1] if 0 < r.lineno <= len(lines) else ""
            # ast columns count UTF-8 bytes; report characters.
            col = len(line_text.encode("utf-8")[: r.col].decode("utf-8", errors="ignore"))
        line = r.lineno + line_offset
        column = col + 1 + (col_offset if r.lineno == 1 else 0)
        raise ModelFileError(
            f"{source}, line {line}, column {column}: {r.reason}",
            source=source, line=line, column=column, reason=r.reason,
        ) from None


def _parse(text: str, names: Mapping[str, sp.Expr], functions: Mapping[str, _Function] = FUNCTIONS) -> sp.Expr:
    if len(text) > MAX_EXPRESSION_LENGTH:
        line, col = _char_position(text, MAX_EXPRESSION_LENGTH)
        raise _Refused(
            f"expression too long ({len(text)} characters; the limit is {MAX_EXPRESSION_LENGTH})",
            line, col, char_col=True,
        )
    nesting = _nesting_error(text)
    if nesting is not None:
        raise nesting
    try:
        with warnings.catch_warnings():
            # Invalid escapes in (refused) strings warn while parsing; the refusal says enough.
            warnings.simplefilter("ignore")
            tree = ast.parse(text, mode="eval")
    except SyntaxError as exc:
        line = exc.lineno or 1
        col = (exc.offset or 1) - 1
        raise _Refused(f"invalid syntax: {exc.msg}", line, max(col, 0), char_col=True) from None
    except (RecursionError, MemoryError):
        raise _Refused("expression too complex to parse (nested too deeply)", 1, 0, char_col=True) from None
    except ValueError as exc:  # e.g. null bytes on some Python versions
        raise _Refused(f"invalid syntax: {exc}", 1, 0, char_col=True) from None
    try:
        return _Builder(names, functions).build(tree.body, 1)
    except RecursionError:
        raise _Refused("expression too complex (nested too deeply)", 1, 0, char_col=True) from None
