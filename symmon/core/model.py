"""Symbolic models y = g(u, v) and the detection of their noise structure.

The structure follows Straka & Havlík (2024), eqs. (1), (3), (4):

- ``"none"``: no noise symbols (noise-free); g = f(u), with an empty π and γ.
- ``"additive"``: g = f(u) + B v with a constant matrix B (B = I in (4)).
- ``"multiplicative"``: g = f(u) + π(u) γ(v) (3).
- ``"general"``: anything else (1).

The split is read off the expression tree (sums, products, integer powers by the multinomial
theorem over the u- and v-groups, exp of sums), never by expanding powers of the u-part, so
(a + … + h + v)⁶⁴ is split into 65 terms in a fraction of a second.
"""

from __future__ import annotations

from functools import cached_property
from typing import Iterable, Sequence

import numpy as np
import sympy as sp
from sympy.ntheory.multinomial import multinomial_coefficients

from ..errors import ModelError, plain_repr
from . import dag
from .affine import changed_model, offset_vector, scale_matrix
from .symbols import as_symbols
from .tracing import trace

__all__ = ["Model"]


def _as_exprs(items) -> tuple[sp.Expr, ...]:
    if isinstance(items, sp.MatrixBase):
        items = list(items)
    elif isinstance(items, sp.Basic):
        items = [items]
    out = []
    for e in items:
        if isinstance(e, str):
            raise ModelError(
                "outputs must be sympy expressions, not strings (use symmon.files.modelfile to parse text safely)"
            )
        try:
            e = sp.sympify(e, strict=True)  # numbers and sympy objects only, never text
        except sp.SympifyError as exc:
            raise ModelError(f"output {e!r} is not a sympy expression") from exc
        out.append(e)
    if not out:
        raise ModelError("a model needs at least one output")
    return tuple(out)


#: Largest number of terms f + Σ π_k γ_k that the structure detection builds for one output.
MAX_SEPARABLE_TERMS = 2000


class _TooLarge(Exception):
    """The separable form exists (or may) but has more than MAX_SEPARABLE_TERMS terms."""


def _short(e: sp.Expr, n: int = 60) -> str:
    text = dag.bounded_str(e)
    return text if len(text) <= n else text[: n - 3] + "..."


Groups = dict  # {γ(v) normalised: π(u)}, with γ = 1 for the part f(u)


def _add_to(out: Groups, v_part: sp.Expr, u_part: sp.Expr) -> None:
    # Normalise the sign and the number of γ so that γ and −2γ are one column.
    coeff, v_core = v_part.as_coeff_Mul()
    out[v_core] = out.get(v_core, sp.Integer(0)) + coeff * u_part


def _times(a: Groups, b: Groups) -> Groups:
    if len(a) * len(b) > MAX_SEPARABLE_TERMS:
        raise _TooLarge(MAX_SEPARABLE_TERMS)
    out: Groups = {}
    for va, ua in a.items():
        for vb, ub in b.items():
            _add_to(out, va * vb, ua * ub)
    return out


def _separate(e: sp.Expr, uset: set, vset: set) -> Groups | sp.Expr:
    """e = Σ_k π_k(u) γ_k(v) read off e's own tree, without expanding powers of u-only parts.

    Sums and products are split term by term; a positive integer power of a separable sum is
    multiplied out in γ only (π stays a power of the u-part: (a + … + h + v)⁶⁴ gives 65
    terms, not the C(71, 7) of a full multinomial expansion); exp and constant bases with a sum
    in the exponent split into products; a power of a single product splits where sympy's
    ``expand_power_base`` says it is valid. Returns the groups {γ: π}, or the subexpression
    that mixes u and v (a mixed function argument or an inverse of a mixed sum).

    Raises
    ------
    _TooLarge
        The form would have more than MAX_SEPARABLE_TERMS terms.
    """
    syms = e.free_symbols
    if not syms & vset:
        return {sp.Integer(1): e}
    if not syms & uset:
        out: Groups = {}
        _add_to(out, e, sp.Integer(1))
        return out
    if e.is_Add or e.is_Mul:
        parts = [_separate(a, uset, vset) for a in e.args]
        for p in parts:
            if isinstance(p, sp.Basic):
                return p
        acc: Groups = parts[0]
        for p in parts[1:]:
            if e.is_Add:
                for v_core, u_part in p.items():
                    acc[v_core] = acc.get(v_core, sp.Integer(0)) + u_part
                if len(acc) > MAX_SEPARABLE_TERMS:
                    raise _TooLarge(MAX_SEPARABLE_TERMS)
            else:
                acc = _times(acc, p)
        return acc
    if isinstance(e, sp.exp) or (e.is_Pow and not e.base.free_symbols and e.exp.is_Add):
        # exp(a(u) + b(v)) = exp(a) exp(b); c^(a + b) = c^a c^b.
        base, expo = (sp.E, e.args[0]) if isinstance(e, sp.exp) else e.args
        u_terms, v_terms = [], []
        for t in sp.Add.make_args(expo):
            if t.free_symbols & uset and t.free_symbols & vset:
                return e
            (v_terms if t.free_symbols & vset else u_terms).append(t)
        return {sp.Pow(base, sp.Add(*v_terms)): sp.Pow(base, sp.Add(*u_terms))}
    if e.is_Pow:
        base, n = e.args
        inner = _separate(base, uset, vset)
        if isinstance(inner, sp.Basic):
            return inner if inner != base else e
        if n.is_Integer and n > 0:
            m = len(inner)
            if m > 1 and sp.binomial(int(n) + m - 1, m - 1) > MAX_SEPARABLE_TERMS:
                raise _TooLarge(MAX_SEPARABLE_TERMS)
            # The multinomial theorem over the m groups: (Σ π_j γ_j)ⁿ = Σ_k c_k Π π_j^k_j Π γ_j^k_j.
            gam, pis = list(inner), list(inner.values())
            out = {}
            for k, c in multinomial_coefficients(m, int(n)).items():
                _add_to(out, sp.Mul(*[g**kj for g, kj in zip(gam, k)]), c * sp.Mul(*[p**kj for p, kj in zip(pis, k)]))
            return out
        split = sp.expand_power_base(e, deep=False)
        if split != e and split.is_Mul:
            return _separate(split, uset, vset)
        return e
    return e


class Model:
    """A nonlinear transformation y = g(u, v) declared with sympy.

    Parameters
    ----------
    inputs : sequence of sympy.Symbol
        The random inputs u (the state).
    outputs : sequence of sympy.Expr
        The components of g.
    noise : sequence of sympy.Symbol, optional
        The noise symbols v, independent of u and zero mean.
    name : str, optional
    angles : iterable of sympy.Symbol or int, optional
        Output indices (or input symbols) that are angles; see :mod:`symmon.core.angles`.
    params : sequence of sympy.Symbol, optional
        Parameters: symbols that are neither random inputs nor noise (a sensor bias, a
        time step dt, a control input, a noise intensity).  Their values are given where the
        model is evaluated, ``params={"b": 0.5}``: the filters take them as inputs of their
        compiled steps (a value per step or per run, no recompile; and ``fit`` estimates
        them), the other evaluators substitute them (:meth:`with_params`).

    Raises
    ------
    ModelError
        On duplicate symbols, symbols declared twice (as inputs, noise or parameters), or
        outputs that use symbols that are declared as none of them.

    Examples
    --------
    >>> import sympy as sp
    >>> x, y = sp.symbols("x y")
    >>> Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)]).structure
    'none'
    """

    def __init__(
        self,
        inputs: Sequence[sp.Symbol],
        outputs: Sequence[sp.Expr] | sp.Expr,
        noise: Sequence[sp.Symbol] | None = None,
        name: str | None = None,
        angles: Iterable | None = None,
        params: Sequence[sp.Symbol] | None = None,
    ) -> None:
        u = as_symbols(inputs, "inputs")
        v = as_symbols(noise, "noise")
        p = as_symbols(params, "params")
        if not u:
            raise ModelError("a model needs at least one input symbol")
        for group, what in ((u, "inputs"), (v, "noise"), (p, "params")):
            dup = {s for s in group if group.count(s) > 1}
            if dup:
                raise ModelError(f"duplicate symbols in {what}: {sorted(map(str, dup))}")
        for (a, an), (b, bn) in (((u, "inputs"), (v, "noise")), ((u, "inputs"), (p, "params")),
                                 ((v, "noise"), (p, "params"))):
            both = set(a) & set(b)
            if both:
                raise ModelError(f"symbols declared both as {an} and {bn}: {sorted(map(str, both))}")
        g = _as_exprs(outputs)
        known = set(u) | set(v) | set(p)
        for i, e in enumerate(g):
            # dag.free_symbols: sympy's walks the tree, 2^100 nodes for a traced 100-step loop.
            unknown = dag.free_symbols(e) - known
            if unknown:
                raise ModelError(
                    f"output {i} ({dag.bounded_str(e)}) uses unknown symbols {sorted(map(str, unknown))}; "
                    f"declared inputs {[str(s) for s in u]}, noise {[str(s) for s in v]}"
                    + (f", params {[str(s) for s in p]}" if p else "; declare parameters with params=[...]")
                    + _namesakes(unknown, known)
                )
        self._u = u
        self._v = v
        self._p = p
        self._g = g
        self._name = name
        self._angles = self._resolve_angles(angles)

    @classmethod
    def from_function(cls, fn, inputs, noise=None, angles=None, name: str | None = None,
                      args=()) -> "Model":
        """Trace a NumPy-style Python function into a Model.

        The function is called once on symbolic inputs (see :mod:`symmon.core.tracing`):
        the operations and functions listed in the Notes become the same sympy expressions
        a declaration would hold.

        Parameters
        ----------
        fn : callable
            ``fn(x, *args)``, or ``fn(x, v, *args)`` when ``noise`` is given; FilterPy's
            ``hx(x)`` and ``fx(x, dt)`` (with ``args=(dt,)``) work as written.
        inputs, noise : sequence of str or sympy.Symbol
            Names of the components of ``x`` and of the noise ``v``: one name for each
            entry the function reads.
        angles, name
            As for :class:`Model`.
        args : sequence
            Further numeric arguments of ``fn``.

        Raises
        ------
        UnsupportedFunctionError
            Naming an operation that cannot be traced by its qualified name (``np.fmod``,
            ``np.sort``, ``scipy.special.gamma``; ``float(x[0])``, ``math.sqrt``, a Python
            ``if`` on a traced comparison) and saying what to write instead.
        ModelError
            If ``fn`` reads an entry past the names (``x[2]`` with two names in
            ``inputs``), saying how many names to give, or cannot be called as
            ``fn(x, *args)`` / ``fn(x, v, *args)``.

        Notes
        -----
        A traced function may use (:data:`symmon.core.tracing.SUPPORTED`, each tested
        against NumPy):

        - the operators ``+ - * / **``, unary ``-``, ``abs()``, ``@``, indexing (also
          negative), slicing, iteration and unpacking of ``x``, the comparisons
          ``< <= > >= == !=`` and ``&``, ``|``, ``^``, ``~`` of comparisons;
        - arithmetic: ``np.add``, ``np.subtract``, ``np.multiply``, ``np.divide``,
          ``np.true_divide``, ``np.power``, ``np.pow``, ``np.float_power``,
          ``np.negative``, ``np.positive``, ``np.reciprocal``, ``np.square``, ``np.sqrt``,
          ``np.cbrt``, ``np.conjugate`` (``np.conj``: a traced value is real);
        - exponentials and logarithms: ``np.exp``, ``np.expm1``, ``np.log``, ``np.log1p``,
          ``np.log2``, ``np.log10``, and ``scipy.special.erf``, ``scipy.special.erfc``;
        - trigonometry: ``np.sin``, ``np.cos``, ``np.tan``, ``np.arcsin`` (``np.asin``),
          ``np.arccos`` (``np.acos``), ``np.arctan`` (``np.atan``), ``np.arctan2``
          (``np.atan2``), ``np.hypot``, ``np.deg2rad`` (``np.radians``), ``np.rad2deg``
          (``np.degrees``), ``np.sinh``, ``np.cosh``, ``np.tanh``, ``np.arcsinh``
          (``np.asinh``), ``np.arccosh`` (``np.acosh``), ``np.arctanh`` (``np.atanh``);
        - branches on values: ``np.where(cond, a, b)`` (a sympy Piecewise),
          ``np.maximum``, ``np.minimum``, ``np.clip``, ``np.max``, ``np.min`` (NaN where
          an argument is NaN, as in NumPy), ``np.fmax``, ``np.fmin`` (Max, Min: a NaN
          dropped), ``np.abs`` (``np.absolute``), ``np.sign``,
          ``np.floor``, ``np.ceil``, the comparisons ``np.greater``, ``np.greater_equal``,
          ``np.less``, ``np.less_equal``, ``np.equal``, ``np.not_equal`` and
          ``np.logical_and``, ``np.logical_or``, ``np.logical_xor``, ``np.logical_not``;
        - arrays: ``np.array``, ``np.asarray``, ``np.concatenate``, ``np.hstack``,
          ``np.vstack``, ``np.stack``, ``np.dot``, ``np.matmul``, ``np.inner``,
          ``np.outer``, ``np.linalg.norm``, ``np.sum``, ``np.prod``, ``np.mean``,
          ``np.var``, ``np.std``, ``np.cumsum``.

        (``np.pow``, ``np.asin`` and the other short names exist from NumPy 2.)  A
        comparison is a symbolic condition, not a Python bool: write a branch as
        ``np.where(cond, a, b)``.  Comparisons and the functions that compare work on traced
        scalars and on the arrays computed from ``x``; on an array built with
        ``np.array([...])`` NumPy compares the entries itself, so apply them to the entries.

        Examples
        --------
        >>> import numpy as np
        >>> def hx(x):
        ...     return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])
        >>> Model.from_function(hx, inputs=["x", "y"], angles=[1]).outputs
        (sqrt(x**2 + y**2), atan2(y, x))
        >>> Model.from_function(lambda x: np.where(x[0] > 0, x[0], 0.0), inputs=["x"]).outputs
        (Piecewise((x, x > 0), (0, True)),)
        """
        u, v, g = trace(fn, inputs, noise, args)
        label = name if name is not None else getattr(fn, "__name__", None)
        return cls(u, g, v, label, angles)

    def _resolve_angles(self, angles) -> tuple[frozenset[int], frozenset[int]]:
        out_idx: set[int] = set()
        in_idx: set[int] = set()
        if angles is None:
            angles = ()
        elif isinstance(angles, (int, np.integer, sp.Symbol)):
            angles = (angles,)  # a single declaration, e.g. angles=1
        for a in angles:
            if isinstance(a, (int, np.integer)) and not isinstance(a, (bool, np.bool_)):
                a = int(a)  # numpy indices too; bool is an int but never an index
                if not 0 <= a < len(self._g):
                    raise ModelError(f"angle output index {a} out of range for {len(self._g)} outputs")
                out_idx.add(a)
            elif isinstance(a, sp.Symbol) and a in self._u:
                in_idx.add(self._u.index(a))
            else:
                raise ModelError(
                    f"angles must be output indices or input symbols, got {plain_repr(a)}"
                )
        return frozenset(out_idx), frozenset(in_idx)

    # --- basic properties -------------------------------------------------
    @property
    def inputs(self) -> tuple[sp.Symbol, ...]:
        """The input symbols u."""
        return self._u

    @property
    def noise(self) -> tuple[sp.Symbol, ...]:
        """The noise symbols v (possibly empty)."""
        return self._v

    @property
    def params(self) -> tuple[sp.Symbol, ...]:
        """The parameter symbols (possibly empty): neither random inputs nor noise."""
        return self._p

    @property
    def n_p(self) -> int:
        return len(self._p)

    def with_params(self, values: dict | None) -> "Model":
        """The model with its parameters replaced by values: a model without parameters.

        Parameters
        ----------
        values : dict
            A finite real value for each parameter, keyed by name (``"b"``) or symbol.

        Raises
        ------
        ModelError
            For a missing, unknown or non-finite value.

        Examples
        --------
        >>> import sympy as sp
        >>> x, b = sp.symbols("x b")
        >>> Model([x], [x + b], params=[b]).with_params({"b": 2.0}).outputs
        (x + 2.0,)
        """
        if not self._p:
            if values:
                raise ModelError(f"model {self.name!r} declares no parameters, got params {sorted(map(str, values))}")
            return self
        vals = check_param_values(self._p, values, self.name)
        mapping = {s: sp.Float(vals[str(s)]) for s in self._p}
        # A large DAG (a traced loop, composed sub-steps) is rebuilt node by node: xreplace
        # would rebuild it as a tree.
        g = [e.xreplace(mapping) for e in self._g] if dag.is_small(self._g) else dag.substitute(self._g, mapping)
        return Model(self._u, g, self._v, self._name, self._angle_args())

    @property
    def outputs(self) -> tuple[sp.Expr, ...]:
        """The output expressions g."""
        return self._g

    @property
    def name(self) -> str:
        return self._name or "model"

    @property
    def n_u(self) -> int:
        return len(self._u)

    @property
    def n_v(self) -> int:
        return len(self._v)

    @property
    def n_y(self) -> int:
        return len(self._g)

    @property
    def angle_outputs(self) -> frozenset[int]:
        """Indices of the outputs that are angles."""
        return self._angles[0]

    @property
    def angle_inputs(self) -> frozenset[int]:
        """Indices of the inputs that are angles."""
        return self._angles[1]

    def with_angles(self, angles: Iterable) -> "Model":
        """The same model with angle declarations replaced by ``angles``."""
        return Model(self._u, self._g, self._v, self._name, angles, self._p)

    # --- noise structure --------------------------------------------------
    @cached_property
    def _split(self) -> tuple[str, sp.Matrix | None, sp.Matrix | None, sp.Matrix | None, str]:
        if not self._v:
            return "none", sp.Matrix(self._g), sp.zeros(self.n_y, 0), sp.zeros(0, 1), "no noise symbols"
        vset = set(self._v)
        uset = set(self._u)
        if not dag.is_small(self._g):
            return self._split_large(uset, vset)
        # Constant Jacobian in v means g = f(u) + B v (cheap: no expansion).
        Jv = sp.Matrix(self._g).jacobian(sp.Matrix(self._v))
        if all(not (e.free_symbols & (vset | uset)) for e in Jv):
            f = sp.Matrix(self._g).subs({s: 0 for s in self._v})
            return "additive", f, Jv, sp.Matrix(self._v), "the Jacobian in v is constant"
        gammas: dict[sp.Expr, int] = {}
        rows: list[dict[int, sp.Expr]] = []
        f_parts: list[sp.Expr] = []
        for e in self._g:
            try:
                groups = _separate(e, uset, vset)
            except _TooLarge as exc:
                return "general", None, None, None, (
                    f"a separable form f(u) + π(u)γ(v) of {_short(e)} would have more than {exc.args[0]} "
                    "terms: treated as general noise, whose formulas hold for every g"
                )
            if isinstance(groups, sp.Basic):
                return "general", None, None, None, (
                    f"no separable form f(u) + π(u)γ(v) found: {_short(groups)} mixes u and v "
                    "(general noise, whose formulas hold for every g)"
                )
            f_parts.append(groups.pop(sp.Integer(1), sp.Integer(0)))
            row: dict[int, sp.Expr] = {}
            for v_core, u_part in groups.items():
                if u_part == 0:  # terms that cancelled, e.g. (x + v)² − v²
                    continue
                k = gammas.setdefault(v_core, len(gammas))
                row[k] = u_part
            rows.append(row)
        pi = sp.Matrix(self.n_y, len(gammas), lambda i, k: rows[i].get(k, sp.Integer(0)))
        return "multiplicative", sp.Matrix(f_parts), pi, sp.Matrix(list(gammas)), (
            f"g = f(u) + π(u)γ(v) with {len(gammas)} components of γ, read off term by term without expanding")

    def _split_large(self, uset: set, vset: set):
        """The structure of outputs too large for sympy's recursive walks (a traced loop):
        additive when each output is a sum of terms free of v and of terms c·v_j with a
        number c (read off the top-level sum, each term's symbols found by a DAG walk),
        general otherwise (whose formulas hold for every g)."""
        f_parts, rows = [], []
        for e in self._g:
            f_terms, row = [], [sp.Integer(0)] * self.n_v
            terms = sp.Add.make_args(e)
            for t in terms:
                syms = dag.free_symbols(t)
                if not syms & vset:
                    f_terms.append(t)
                    continue
                c, rest = t.as_coeff_Mul()
                if rest in vset and not syms & uset:
                    row[self._v.index(rest)] += c
                    continue
                return "general", None, None, None, (
                    f"the outputs are too large for sympy's symbolic walks (more than {dag.MAX_TREE} nodes as "
                    f"a tree or {dag.MAX_DEPTH} levels deep) and not a sum f(u) + B v: treated as general "
                    "noise, whose formulas hold for every g")
            f_parts.append(e if len(f_terms) == len(terms) else sp.Add(*f_terms))
            rows.append(row)
        return "additive", sp.Matrix(f_parts), sp.Matrix(rows), sp.Matrix(self._v), (
            "g = f(u) + B v, read off the sum of each output (the outputs are too large for sympy's "
            "symbolic walks)")

    @property
    def structure(self) -> str:
        """``"none"`` (noise-free), ``"additive"``, ``"multiplicative"`` or ``"general"``, found symbolically.

        ``"multiplicative"`` is exact: f + π γ equals g identically (it is built from g's own
        terms). ``"general"`` means that no separable form was found, or that it would be too
        large (:attr:`structure_note` says which); the general-noise formulas hold for every g,
        so this costs speed, never correctness.
        """
        return self._split[0]

    @property
    def structure_note(self) -> str:
        """How :attr:`structure` was decided, e.g. which factor mixes u and v."""
        return self._split[4]

    def _require(self, what: str):
        if self.structure == "general":
            raise ModelError(f"{what} is not defined for a model with general (non-separable) noise")

    @property
    def f(self) -> sp.Matrix:
        """f(u) of g = f(u) + π(u)γ(v) (the whole g for a noise-free model)."""
        self._require("f")
        return self._split[1]

    @property
    def pi(self) -> sp.Matrix:
        """π(u), shape (n_y, n_γ); a constant matrix B for additive noise."""
        self._require("pi")
        return self._split[2]

    @property
    def gamma(self) -> sp.Matrix:
        """γ(v), shape (n_γ, 1). It need not be zero mean: the measures recentre it."""
        self._require("gamma")
        return self._split[3]

    # --- transformations of the model --------------------------------------
    def noise_free(self) -> "Model":
        """The model with every noise symbol set to zero (keeps inputs and angles)."""
        g = [e.subs({s: 0 for s in self._v}) for e in self._g]
        return Model(self._u, g, None, self._name, self._angle_args(), self._p)

    def _angle_args(self) -> list:
        return sorted(self.angle_outputs) + [self._u[i] for i in sorted(self.angle_inputs)]

    def subs(self, values: dict) -> "Model":
        """Substitute parameter values (not inputs or noise) into the outputs."""
        return Model(self._u, [e.subs(values) for e in self._g], self._v, self._name, self._angle_args())

    def change_units(self, S_u=None, o_u=None, S_y=None, o_y=None, S_v=None, *, suffix: str = "_bar") -> "Model":
        """The same relation in new units: ḡ(ū, v̄) = S_y⁻¹(g(S_u ū + o_u, S_v v̄) − o_y) (18), (20).

        See :func:`symmon.units.change_units` for the arguments and conventions (S maps
        new-unit numbers to old-unit numbers).
        """
        Su = scale_matrix(S_u, self.n_u, "S_u")
        ou = offset_vector(o_u, self.n_u, "o_u")
        Sy = scale_matrix(S_y, self.n_y, "S_y")
        oy = offset_vector(o_y, self.n_y, "o_y")
        Sv = scale_matrix(S_v, self.n_v, "S_v") if self.n_v else sp.zeros(0, 0)
        if self.n_v == 0 and S_v is not None:
            raise ModelError("S_v was given but the model declares no noise symbols")
        u_new, g_bar, v_new, angles = changed_model(self, Su, ou, Sy, oy, Sv, suffix)
        return Model(u_new, g_bar, v_new or None, self._name, angles or None)

    # --- display -----------------------------------------------------------
    def __repr__(self) -> str:
        parts = [f"inputs={[str(s) for s in self._u]}"]
        if self._v:
            parts.append(f"noise={[str(s) for s in self._v]}")
        if self._p:
            parts.append(f"params={[str(s) for s in self._p]}")
        parts.append(f"outputs={[dag.bounded_str(e) for e in self._g]}")
        return f"Model({self.name!r}, " + ", ".join(parts) + f", structure={self.structure!r})"

    def _repr_latex_(self) -> str:
        args = ", ".join(sp.latex(s) for s in self._u + self._v)
        body = r" \\ ".join(sp.latex(e) if dag.is_small([e]) else r"\text{" + dag.bounded_str(e).strip("<>") + "}"
                             for e in self._g)
        return (
            r"$g(" + args + r") = \begin{bmatrix}" + body + r"\end{bmatrix}"
            + r"\quad\text{(" + (f"{self.structure} noise" if self._v else "noise-free") + r")}$"
        )

    def __eq__(self, other: object) -> bool:
        # By the structural hash: sympy's == walks two equal expressions built apart as
        # trees, exponential for two traces of one loop.
        if not isinstance(other, Model):
            return NotImplemented
        return self is other or self.key == other.key

    def __hash__(self) -> int:
        return int(self.key[:16], 16)

    @cached_property
    def key(self) -> str:
        """A structural hash of the model (:func:`symmon.core.dag.digest`): its inputs, noise,
        parameters, outputs in order and angle declarations.

        Equal models have equal keys in every process; the cost is linear in the distinct
        nodes of the outputs, however large their tree (a traced loop).
        """
        def ints(ix):
            return sp.Tuple(*sorted(ix))
        return dag.digest([sp.Tuple(*self._u), sp.Tuple(*self._v), sp.Tuple(*self._p), sp.Tuple(*self._g),
                           ints(self.angle_outputs), ints(self.angle_inputs)])


def _namesakes(unknown: set, known: set) -> str:
    """The unknown symbols that share a name with a declared one, told apart by their sympy
    assumptions (``Symbol('px')`` and ``Symbol('px', real=True)`` are two symbols)."""
    by_name = {s.name: s for s in known}
    pairs = sorted(((s, by_name[s.name]) for s in unknown if getattr(s, "name", None) in by_name),
                   key=lambda pair: pair[0].name)
    if not pairs:
        return ""
    told = "; ".join(f"the output's {sp.srepr(a)} is not the declared {sp.srepr(b)}" for a, b in pairs)
    return (f". Same names, other assumptions: {told}. sympy treats a name with other assumptions as "
            "another symbol: create each symbol once (sp.symbols(..., real=True)) and use it in the "
            "outputs and the declarations")


def check_param_values(params: Sequence[sp.Symbol], values: dict | None, name: str = "model") -> dict[str, float]:
    """``values`` as {parameter name: finite float}, one for each of ``params``.

    Raises
    ------
    ModelError
        For a missing, unknown or non-finite value, or one that is not a real scalar.
    """
    if values is None:
        values = {}
    if not isinstance(values, dict):
        raise ModelError(f"params must be a dict of parameter values, got {type(values).__name__}")
    names = [str(s) for s in params]
    given = {str(k): v for k, v in values.items()}
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise ModelError(f"{name!r} has no parameters {unknown}; its parameters are {names}")
    missing = [n for n in names if n not in given]
    if missing:
        raise ModelError(f"{name!r} needs values of its parameters {missing} (params={{...}})")
    out = {}
    for n in names:
        try:
            val = float(given[n])
        except (TypeError, ValueError):
            raise ModelError(f"parameter {n!r} must be a real number, got {given[n]!r}") from None
        if not np.isfinite(val):
            raise ModelError(f"parameter {n!r} must be finite, got {val}")
        out[n] = val
    return out


def with_param_values(model, params: dict | None):
    """``model`` with its parameters substituted when ``params`` is given (:meth:`Model.with_params`);
    unchanged otherwise (a model with parameters then asks for their values where it is
    compiled).  The ``params=`` of :func:`symmon.propagate` and the measures: the model is
    compiled once per distinct set of values (the filters take them as inputs instead)."""
    if params is None or not isinstance(model, Model):
        return model
    return model.with_params(params)
