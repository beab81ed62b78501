"""Discretisation of an SDE dx = a(x, t) dt + L(x, t) dβ, E[dβ dβᵀ] = Q_c dt, into a Model.

The result is a :class:`~symmon.core.model.Model` x_{k+1} = f(x_k, w; dt) with the step dt a
parameter (so irregular steps are per-step parameter values, as for any model) and noise
symbols w ~ N(0, I) entering through a factor of the step's noise covariance: every filter,
``simulate``, ``propagate`` and ``nonlinearity`` take it with Q = I.

A time-varying SDE (a time symbol t in a or L, :attr:`SDE.is_time_invariant` false) gives
f(x_k, w; t, dt), the start time t of the step a parameter too (before dt), named after
the SDE's time symbol; sub-step j of N starts at t + j dt/N.  ``"exact"`` refuses it (a
time-varying linear SDE has no single e^{A dt}); the other methods take the time as
follows.  The methods:

- ``"exact"``: a linear time-invariant SDE, a = A x + b, L constant.  F = e^{A dt},
  c = ∫₀^dt e^{A s} ds b and Q(dt) = ∫₀^dt e^{A s} L Q_c Lᵀ e^{Aᵀ s} ds (Van Loan 1978), in
  closed form by sympy (nilpotent and diagonalisable A: white-noise acceleration, Singer,
  Ornstein–Uhlenbeck, the coordinated turn with a known rate); f = F x + c + G w with
  G Gᵀ = Q(dt) the Cholesky factor.  When sympy cannot give a closed form within
  :data:`CLOSED_FORM_SECONDS` (eigenvalues that are roots of a quintic, say) it raises
  :class:`~symmon.errors.DiscretizationError`: a numeric Q(dt) at one step is
  :func:`van_loan_numeric`, but a model needs Q as an expression of dt, so use
  ``"local_linear"`` or ``"taylor1.5"`` with ``substeps`` instead.
- ``"local_linear"`` (Ozaki 1992; Jimenez & Biscay 2002) for additive noise: on each
  sub-step h, x + h φ₁(J h) a(x) with J = ∂a/∂x at the sub-step's start and the noise of
  covariance ∫₀^h e^{J s} L Q_c Lᵀ e^{Jᵀ s} ds.  For a linear time-invariant drift it is
  ``"exact"``; otherwise φ₁ and the integral are their Taylor series in J h to
  :data:`SERIES_TERMS` terms (a local error O(h^{SERIES_TERMS+1}) while ‖J h‖ < 1, far
  below the scheme's own: take ``substeps`` so that ‖J h‖ stays small).  With time, the
  drift is linearised in t as well, a + J (x − x_n) + (∂a/∂t) s, whose flow adds
  h² φ₂(J h) ∂a/∂t, φ₂(z) = Σ_k z^k/(k+2)! (Jimenez & Biscay 2002, the non-autonomous
  local linearisation); L Q_c Lᵀ is taken at the sub-step's mid-time t + h/2 (the midpoint
  rule of ∫₀^h e^{J s} L Q_c Lᵀ(t + h − s) e^{Jᵀ s} ds: a local error O(h³) in the
  covariance, where the start time would leave O(h²)).
- ``"taylor1.5"``: the strong order-1.5 Itô–Taylor scheme for additive noise (Kloeden &
  Platen 1992, §10.4, the scheme (10.4.1) for additive noise, ΔZ by (10.4.3)):
  x + a h + b ΔW + (∂a/∂x) b ΔZ + ½ L⁰a h² + L⁰b (ΔW h − ΔZ) with b = L S (S Sᵀ = Q_c),
  L⁰ = ∂/∂t + Σ_k a_k ∂/∂x_k + ½ Σ_kl (b bᵀ)_kl ∂²/∂x_k∂x_l (so L⁰b = ∂b/∂t, zero for a
  time-invariant L), ΔW = √h ξ₁ and the iterated integral ΔZ = ½ h^{3/2} (ξ₁ + ξ₂/√3);
  its noise symbols are ξ₁ and ξ₂ of every sub-step.
- ``"euler"``: Euler–Maruyama, x + a h + L(x) S √h ξ (strong order 1 for additive noise,
  1/2 otherwise), a and L at the sub-step's start time.
- ``"rk4"``: the classical Runge–Kutta step for the mean (its stages at t, t + h/2 and
  t + h) and, for the noise, the covariance of the flow linearised at the sub-step's start
  (the series of ``"local_linear"``) with L(x) evaluated there (at the mid-time t + h/2, as
  ``"local_linear"``, for a time-varying L).

``substeps=N`` divides each step into N sub-steps of h = dt/N, each with its own noise
symbols (n_w grows N-fold: the model is the composition of the sub-steps, nonlinear between
them).  The composition is an expression DAG: each sub-step's expression refers to the
previous sub-step's state (one shared node per state), built with sympy's evaluation off,
so that it has as many distinct nodes as the sub-steps' operations, linear in N.  Evaluated,
sympy would distribute numbers over the sums and ask the assumptions of sin(·) of the whole
previous state, rebuilding the tree: its size grew geometrically (sin x − x³/2 by
``"taylor1.5"`` had no model within minutes at 8 sub-steps).  Every consumer walks the
outputs as a DAG (:mod:`symmon.core.dag`), and the compiled CasADi function evaluates the
sub-steps in sequence, each once.  :func:`symmon.measures.mon.choose_substeps` chooses their
number by the sub-step's measure of nonlinearity (as :func:`symmon.advise_filter` does for an
SDE).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg
import sympy as sp

from ..errors import DiscretizationError, ModelError
from ..timelimit import OutOfTime, deadline
from . import dag
from .model import Model

# The SDE (:class:`symmon.core.sde.SDE`) is read through its public attributes: sde.py
# imports this module, so this one does not import it back.

__all__ = ["METHODS", "SERIES_TERMS", "CLOSED_FORM_SECONDS", "default_dt", "discretize", "exact_transition",
           "expm_closed_form", "van_loan", "van_loan_numeric", "factor", "compose"]

#: The discretisation methods, by name.
METHODS = ("exact", "local_linear", "taylor1.5", "euler", "rk4")
#: Terms of the Taylor series of e^{J h} (φ₁ and the covariance integral) for a nonlinear drift.
SERIES_TERMS = 6
#: Seconds that sympy may spend on the closed forms of one exact discretisation.
CLOSED_FORM_SECONDS = 60.0


def default_dt() -> sp.Symbol:
    """The default step symbol, ``Symbol("dt", positive=True)``."""
    return sp.Symbol("dt", positive=True)


#: Operations above which a closed form is not passed to ``sympy.simplify`` (minutes on a
#: 3 x 3 matrix with complex eigenvalues): only the complex exponentials are made real.
SIMPLIFY_OPS = 80


def _clean(e: sp.Expr) -> sp.Expr:
    if e.has(sp.I):
        e = sp.expand_complex(e)
        if e.has(sp.I):
            e = e.rewrite(sp.cos)
    return sp.simplify(e) if sp.count_ops(e) <= SIMPLIFY_OPS else e


def _closed(M: sp.Matrix, what: str) -> sp.Matrix:
    bad = [e for e in M if e.has(sp.Integral) or e.has(sp.I) or e.has(sp.RootOf)
           or e.has(sp.zoo) or e.has(sp.nan)]
    if bad:
        raise DiscretizationError(
            f"{what} has no closed form sympy can give: {dag.bounded_str(bad[0])}; discretize with "
            "'local_linear' or 'taylor1.5' (and substeps=) instead")
    return M


def _rational(M: sp.Matrix) -> sp.Matrix:
    """Floats as the rationals they print as: sympy's exponential of a matrix needs exact
    eigenvalues."""
    return M.applyfunc(lambda e: sp.nsimplify(e, rational=True) if e.has(sp.Float) else e)


def expm_closed_form(A: sp.Matrix, t: sp.Symbol) -> sp.Matrix:
    """e^{A t} in closed form (sympy's Jordan form), simplified to real functions.

    Raises
    ------
    DiscretizationError
        If the result is not closed (an unevaluated root or integral, complex numbers left).
    """
    E = (_rational(A) * t).exp().applyfunc(_clean)
    return _closed(E, "the matrix exponential e^{A dt}")


def van_loan(A: sp.Matrix, B: sp.Matrix, dt: sp.Expr, b: sp.Matrix | None = None
             ) -> tuple[sp.Matrix, sp.Matrix, sp.Matrix]:
    """F = e^{A dt}, c = ∫₀^dt e^{A s} ds b and Q = ∫₀^dt e^{A s} B e^{Aᵀ s} ds in closed form.

    Parameters
    ----------
    A, B : sympy.Matrix
        The drift matrix (n, n) and the diffusion L Q_c Lᵀ (n, n).
    dt : sympy.Expr
        The step.
    b : sympy.Matrix, optional
        The constant part of the drift (n, 1).

    Raises
    ------
    DiscretizationError
        If sympy cannot give a closed form within :data:`CLOSED_FORM_SECONDS`.

    Examples
    --------
    >>> import sympy as sp
    >>> dt = sp.Symbol("dt", positive=True)
    >>> van_loan(sp.Matrix([[0, 1], [0, 0]]), sp.Matrix([[0, 0], [0, 1]]), dt)[2]
    Matrix([
    [dt**3/3, dt**2/2],
    [dt**2/2,      dt]])
    """
    s = sp.Dummy("s", positive=True)
    n = A.shape[0]
    try:
        with deadline(CLOSED_FORM_SECONDS):
            E = expm_closed_form(A, s)
            F = E.subs(s, dt)
            B = _rational(B)
            integrand = E * B * E.T
            Q = sp.zeros(n, n)
            for i in range(n):
                for j in range(i, n):
                    val = _clean(sp.integrate(sp.expand(integrand[i, j]), (s, 0, dt), conds="none"))
                    Q[i, j] = Q[j, i] = val
            c = sp.zeros(n, 1)
            if b is not None and any(e != 0 for e in b):
                Eb = E * _rational(b)
                c = Eb.applyfunc(lambda e: _clean(sp.integrate(sp.expand(e), (s, 0, dt), conds="none")))
    except OutOfTime:
        raise DiscretizationError(
            f"sympy found no closed form of e^(A dt) and Van Loan's integral within {CLOSED_FORM_SECONDS:g} s; "
            "discretize with 'local_linear' or 'taylor1.5' (and substeps=) instead") from None
    return _closed(F, "e^{A dt}"), _closed(c, "the drift's constant part"), _closed(Q, "Van Loan's integral Q(dt)")


def van_loan_numeric(A, B, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """F = e^{A dt} and Q(dt) numerically, from one matrix exponential of Van Loan's block matrix.

    exp([[-A, B], [0, Aᵀ]] dt) = [[·, F⁻¹ Q], [0, Fᵀ]] (Van Loan 1978, Theorem 1).

    Examples
    --------
    >>> F, Q = van_loan_numeric([[0, 1], [0, 0]], [[0, 0], [0, 1]], 2.0)
    >>> np.round(Q, 12).tolist()
    [[2.666666666667, 2.0], [2.0, 2.0]]
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = B
    M[n:, n:] = A.T
    E = scipy.linalg.expm(M * dt)
    F = E[n:, n:].T
    Q = F @ E[:n, n:]
    return F, (Q + Q.T) / 2


def exact_transition(sde: Any, dt: sp.Expr) -> tuple[sp.Matrix, sp.Matrix, sp.Matrix]:
    """(F, c, Q) of the exact discretisation x_{k+1} = F x_k + c + e, e ~ N(0, Q), of a linear
    SDE (cached on the SDE per step symbol).

    Raises
    ------
    DiscretizationError
        If the SDE is not linear, is time-varying, or sympy finds no closed form.
    """
    sde.check_time_invariant("the exact transition (e^(A dt), Van Loan's Q(dt))")
    cache = sde.__dict__.setdefault("_exact_cache", {})
    if dt not in cache:
        A, b = sde.linear_parts
        B = sde.diffusion * sde.spectral_density * sde.diffusion.T
        cache[dt] = van_loan(A, B, dt, b)
    return cache[dt]


def factor(Q: sp.Matrix, simplify: bool = True) -> sp.Matrix:
    """G with G Gᵀ = Q: the Cholesky factor of a symbolic covariance, without the columns of
    pivots that are identically zero (so a singular Q of rank r gets r columns when its zero
    pivots are exact zeros).

    Raises
    ------
    DiscretizationError
        If a pivot is zero but the rest of its column is not (a Q that is not positive
        semi-definite, or whose singularity sympy cannot see).
    """
    n = Q.shape[0]
    def simp(e: sp.Expr) -> sp.Expr:
        return sp.simplify(e) if simplify and sp.count_ops(e) <= SIMPLIFY_OPS else e

    cols: list[list[sp.Expr]] = []
    for j in range(n):
        d = simp(Q[j, j] - sum((c[j] ** 2 for c in cols), sp.Integer(0)))
        rest = [simp(Q[i, j] - sum((c[i] * c[j] for c in cols), sp.Integer(0))) for i in range(j + 1, n)]
        if d == 0:
            if any(r != 0 for r in rest):
                raise DiscretizationError(
                    f"the noise covariance has a zero pivot at row {j} but a nonzero entry below it: "
                    "not positive semi-definite, or singular in a way sympy cannot see")
            continue
        r = sp.sqrt(d)
        cols.append([sp.Integer(0)] * j + [r] + [simp(e / r) for e in rest])
    if not cols:
        return sp.zeros(n, 0)
    return sp.Matrix(cols).T


def _series_phi1(J: sp.Matrix, v: sp.Matrix, h: sp.Expr) -> sp.Matrix:
    """h φ₁(J h) v = Σ_k h^{k+1} J^k v / (k+1)!, SERIES_TERMS terms (matrix-vector products only)."""
    term = v * h
    out = term
    for k in range(1, SERIES_TERMS):
        term = J * term * h / (k + 1)
        out = out + term
    return out


def _series_phi2(J: sp.Matrix, v: sp.Matrix, h: sp.Expr) -> sp.Matrix:
    """h² φ₂(J h) v = ∫₀^h e^{J (h − s)} s ds v = Σ_k h^{k+2} J^k v / (k+2)!, SERIES_TERMS terms."""
    term = v * h ** 2 / 2
    out = term
    for k in range(1, SERIES_TERMS):
        term = J * term * h / (k + 2)
        out = out + term
    return out


def _series_cov(J: sp.Matrix, B: sp.Matrix, h: sp.Expr) -> sp.Matrix:
    """∫₀^h e^{J s} B e^{Jᵀ s} ds = Σ_k C_k h^{k+1}/(k+1)!, C₀ = B, C_k = J C_{k-1} + C_{k-1} Jᵀ."""
    C = B
    out = B * h
    for k in range(1, SERIES_TERMS):
        C = J * C + C * J.T
        out = out + C * h ** (k + 1) / sp.factorial(k + 1)
    return out


def _noise_symbols(count: int, substeps: int, taken: set[str]) -> list[list[sp.Symbol]]:
    prefix = "w"
    while any(name.startswith(prefix) for name in taken):
        prefix += "_"
    if substeps == 1:
        return [[sp.Symbol(f"{prefix}{i}", real=True) for i in range(count)]]
    return [[sp.Symbol(f"{prefix}{s}_{i}", real=True) for i in range(count)] for s in range(substeps)]


def _step(sde: Any, method: str, h: sp.Expr) -> tuple[sp.Matrix, int]:
    """One sub-step's map of the states (and the time symbol, the sub-step's start) and r
    template noise symbols ``_w0 …`` (Dummies)."""
    x = sp.Matrix(sde.states)
    a = sde.drift
    L = sde.diffusion
    t = None if sde.is_time_invariant else sde.time
    S = factor(sde.spectral_density)
    r = S.shape[1]
    if method in ("taylor1.5", "local_linear") and not sde.additive:
        raise DiscretizationError(
            f"{method!r} needs additive noise (a diffusion L free of the states); {sde.name!r} has "
            "L(x): use 'euler' or 'rk4'")
    J = sde.jacobian
    if method == "euler":
        w = sp.Matrix([sp.Dummy(f"w{i}") for i in range(r)])
        return x + a * h + L * S * w * sp.sqrt(h), list(w)
    if method == "taylor1.5":
        xi1 = sp.Matrix([sp.Dummy(f"w{i}") for i in range(r)])
        xi2 = sp.Matrix([sp.Dummy(f"z{i}") for i in range(r)])
        b = L * S
        B = b * b.T
        xs = list(sde.states)
        L0a = J * a + sp.Matrix([sp.Rational(1, 2) * sum(
            (B[k, l] * sp.diff(a[i], xs[k], xs[l]) for k in range(sde.n) for l in range(sde.n) if B[k, l] != 0),
            sp.Integer(0)) for i in range(sde.n)])
        dW = xi1 * sp.sqrt(h)
        dZ = (xi1 + xi2 / sp.sqrt(3)) * h ** sp.Rational(3, 2) / 2
        step = x + a * h + b * dW + J * b * dZ
        if t is not None:  # L⁰ has ∂/∂t: ∂a/∂t in L⁰a, and L⁰b = ∂b/∂t (b free of x)
            L0a = L0a + a.diff(t)
            step = step + b.diff(t) * (dW * h - dZ)
        return step + L0a * h ** 2 / 2, list(xi1) + list(xi2)
    B = L * sde.spectral_density * L.T
    if method == "local_linear":
        mean = x + _series_phi1(J, a, h)
        if t is not None:  # the drift linearised in t too: + h² φ₂(J h) ∂a/∂t
            mean = mean + _series_phi2(J, a.diff(t), h)
    else:  # rk4
        def at(point, dt_stage):
            sub = dict(zip(sde.states, point))
            if t is not None:
                sub[t] = t + dt_stage
            return a.xreplace(sub)
        k1 = a
        k2 = at(x + k1 * h / 2, h / 2)
        k3 = at(x + k2 * h / 2, h / 2)
        k4 = at(x + k3 * h, h)
        mean = x + (k1 + 2 * k2 + 2 * k3 + k4) * h / 6
    if t is not None:  # L Q_c Lᵀ at the mid-time: the midpoint rule of ∫ e^{J s} B(t + h − s) e^{Jᵀ s} ds
        B = B.xreplace({t: t + h / 2})
    G = factor(_series_cov(J, B, h), simplify=False)
    w = sp.Matrix([sp.Dummy(f"w{i}") for i in range(G.shape[1])])
    return mean + G * w, list(w)


def compose(template: sp.Matrix | list, states: list, template_noise: list, noise: list[list[sp.Symbol]],
            time: sp.Symbol | None = None, h: sp.Expr | None = None) -> list[sp.Expr]:
    """The sub-step map ``template`` (of the states and the template noise symbols) applied
    once per list of ``noise`` symbols, each application to the previous one's result.

    With ``time`` (the symbol of a sub-step's start time in ``template``) and the sub-step
    ``h``, application j starts at time + j h.

    One sub-step alone is substituted with sympy's evaluation (a readable expression); more
    are composed with the evaluation off, so that each application refers to the previous
    state as one shared node: an expression DAG of as many distinct nodes as the
    applications' operations (linear in their number), walked once per node by every
    consumer (:mod:`symmon.core.dag`) and compiled to CasADi as the sub-steps in sequence.

    Examples
    --------
    >>> import sympy as sp
    >>> from symmon.core import dag
    >>> x, w = sp.symbols("x w", real=True)
    >>> ws = [[sp.Symbol(f"w{i}", real=True)] for i in range(64)]
    >>> out = compose([x + sp.sin(x) / 10 + w], [x], [w], ws)
    >>> dag.measure(out)[0] < 64 * 8       # distinct nodes: linear in the sub-steps
    True
    """
    cur = list(states)
    if len(noise) == 1:
        sub = dict(zip(states, cur))
        sub.update(zip(template_noise, noise[0]))
        return [e.xreplace(sub) for e in template]
    starts = [time + j * h for j in range(len(noise))] if time is not None else None
    with sp.evaluate(False):
        for j, ws in enumerate(noise):
            sub = dict(zip(states, cur))
            sub.update(zip(template_noise, ws))
            if starts is not None:
                sub[time] = starts[j]
            cur = [e.xreplace(sub) for e in template]
    return cur


def discretize(sde: Any, method: str = "exact", dt: sp.Expr | None = None, substeps: int = 1) -> Model:
    """The transition of ``sde`` over a step dt: a Model f(x, w; dt), w ~ N(0, I), or
    f(x, w; t, dt) for a time-varying SDE, t the start time of the step.

    Parameters
    ----------
    sde : SDE
    method : {"exact", "local_linear", "taylor1.5", "euler", "rk4"}
        See the module notes.
    dt : sympy.Symbol or positive number, optional
        The step: a symbol (default ``Symbol("dt", positive=True)``) becomes the model's last
        parameter, after the SDE's own; a number gives a model of that fixed step.
    substeps : int, default 1
        Sub-steps of dt/substeps, each with its own noise symbols (not for ``"exact"``,
        and not used by ``"local_linear"`` on a linear drift, which is exact).

    Returns
    -------
    Model
        Inputs: the states; outputs: the states after dt; noise: w, whose covariance is the
        identity (pass ``Q = np.eye(f.n_v)`` to the filters and ``simulate``); params: the
        SDE's, then its time symbol if it is time-varying (the step's start time), then dt;
        angles: the SDE's angle states, as inputs and outputs.

    Raises
    ------
    ModelError
        For an unknown method, a bad ``substeps`` or ``dt``, or a dt whose name is a state's,
        a parameter's or the time symbol's.
    DiscretizationError
        For a method that does not apply (``"exact"`` on a nonlinear or a time-varying SDE,
        an order-1.5 or local-linear scheme with a state-dependent diffusion) or a closed
        form that sympy cannot give.

    Examples
    --------
    >>> import sympy as sp
    >>> from symmon.core.sde import SDE
    >>> p, v = sp.symbols("p v", real=True)
    >>> f = discretize(SDE([p, v], [v, 0], [0, 1]), "exact")
    >>> f.outputs[0]
    sqrt(3)*dt**(3/2)*w0/3 + dt*v + p
    """
    if method not in METHODS:
        raise ModelError(f"method must be one of {list(METHODS)}, got {method!r}")
    if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise ModelError(f"substeps must be a positive integer, got {substeps!r}")
    substeps = int(substeps)
    if method == "exact" and substeps != 1:
        raise ModelError("substeps does not apply to the 'exact' method (it is exact for any dt)")
    if dt is None:
        dt = default_dt()
    varying = not sde.is_time_invariant
    params = list(sde.params) + ([sde.time] if varying else [])
    taken = {str(s) for s in (*sde.states, *sde.params)} | ({str(sde.time)} if sde.time is not None else set())
    if isinstance(dt, sp.Symbol):
        if str(dt) in taken:
            raise ModelError(f"dt: the step symbol {dt} has the name of a state or parameter (or the time symbol) "
                             f"of {sde.name!r}")
        params.append(dt)
    else:
        try:
            dt = sp.sympify(dt, strict=True)
        except sp.SympifyError:
            raise ModelError(f"dt must be a sympy Symbol or a positive number, got {dt!r}") from None
        if not (dt.is_number and dt.is_positive):
            raise ModelError(f"dt must be a sympy Symbol or a positive number, got {dt!r}")
    taken |= {str(dt)}
    angles = sorted(sde.angles) + [sde.states[i] for i in sorted(sde.angles)]
    x = sp.Matrix(sde.states)
    if method == "exact":
        sde.check_time_invariant("the 'exact' discretisation")
    if method == "local_linear" and sde.is_linear and not varying:
        try:
            return discretize(sde, "exact", dt)
        except DiscretizationError:
            pass  # no closed form: the series below
    if method == "exact":
        F, c, Q = exact_transition(sde, dt)
        G = factor(Q)
        (w,) = _noise_symbols(G.shape[1], 1, taken)
        out = F * x + c + G * sp.Matrix(w)
        return Model(sde.states, list(out), w or None, sde.name, angles, params)
    h = dt / substeps
    template, tw = _step(sde, method, h)
    noise = _noise_symbols(len(tw), substeps, taken)
    cur = compose(template, sde.states, tw, noise, sde.time if varying else None, h)
    flat = [s for ws in noise for s in ws]
    return Model(sde.states, cur, flat or None, sde.name, angles, params)
