"""Changes of units: the affine map (18) as sympy, the parts of the changed model.

A change of units is the affine map (18) of Straka & Havlík (2024)::

    u = S_u ū + o_u,    y = S_y ȳ + o_y,    v = S_v v̄,              (18a–c)

where the barred quantities are expressed in the *new* units and the plain ones in the
*old* units.  The same physical relation in the new units is (20), (35a) (with the
erratum S_v⁻¹, o_v → S_y⁻¹, o_y: erratum 1 of docs/reference/errata.md)::

    ḡ(ū, v̄) = S_y⁻¹ (g(S_u ū + o_u, S_v v̄) − o_y).

Direction convention, used everywhere in this module: **S maps new-unit numbers to
old-unit numbers**.  Column k of S is the old-unit value of one new unit of component k.
Converting a position from m (old) to km (new) gives S = 1000, because 1 km = 1000 m;
converting a bearing from rad to deg gives S = π/180.

This module validates scale matrices and offsets and substitutes them into the outputs
(:func:`changed_parts`, :func:`changed_model`); it knows no Model class, so that
:meth:`Model.change_units <symmon.Model.change_units>` can build on it.  The public
functions (:func:`~symmon.core.rescale.change_units`, ``changed_relation``,
``change_gaussian``) are in :mod:`symmon.core.rescale`, published by :mod:`symmon.units`.

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV, eqs. (18)–(21), (34)–(43).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import sympy as sp

from ..errors import ModelError, ShapeError, SingularMatrixError, SymmonError


class ModelParts(Protocol):
    """What a change of units reads from a model (a :class:`~symmon.Model` is one; this module
    is below :mod:`symmon.core.model`, which builds on it, and does not import it)."""

    inputs: tuple
    noise: tuple
    outputs: tuple
    n_v: int
    angle_inputs: frozenset
    angle_outputs: frozenset

__all__ = [
    "scale_matrix", "offset_vector", "sympify_entry", "inverse", "Relation", "changed_parts",
    "changed_model", "unchanged",
]

#: Relative tolerance of the numeric positive-definiteness and affinity checks.
_PD_RTOL = 1e-12

# --------------------------------------------------------------------------------------
# Validation of scale matrices and offsets
# --------------------------------------------------------------------------------------
def sympify_entry(x: Any, name: str) -> sp.Expr:
    if isinstance(x, str):
        raise ShapeError(f"{name}: entries must be numbers or sympy expressions, not strings ({x!r})")
    if isinstance(x, (float, np.floating)):
        if not np.isfinite(x):
            raise ShapeError(f"{name} contains NaN or inf")
        return sp.Float(float(x))
    if isinstance(x, (np.integer,)):
        return sp.Integer(int(x))
    try:
        e = sp.sympify(x, strict=True)
    except sp.SympifyError as exc:
        raise ShapeError(f"{name}: entry {x!r} is not a number or sympy expression") from exc
    if e.has(sp.nan, sp.zoo, sp.oo, -sp.oo):
        raise ShapeError(f"{name} contains NaN or inf")
    return e


def scale_matrix(S: Any, n: int, name: str) -> sp.Matrix:
    """``S`` as an n×n sympy Matrix: None → I, a scalar → s·I, a vector → diag, a matrix as is.

    Raises
    ------
    ShapeError
        Wrong shape or non-numeric entries.
    SingularMatrixError
        det S is (provably) zero.
    SymmonError
        A numeric S whose symmetric part is not positive definite, or a diagonal entry
        that is provably not positive (a scale must keep the orientation of each axis).
    """
    if S is None:
        return sp.eye(n)
    if isinstance(S, sp.MatrixBase):
        M = sp.Matrix(S)
    else:
        arr = np.asarray(S, dtype=object)
        if arr.ndim == 0:
            M = sympify_entry(arr.item(), name) * sp.eye(n)
        elif arr.ndim == 1:
            if arr.shape[0] != n:
                raise ShapeError(f"{name} must have {n} diagonal entries, got {arr.shape[0]}")
            M = sp.diag(*[sympify_entry(x, name) for x in arr])
        elif arr.ndim == 2:
            M = sp.Matrix(arr.shape[0], arr.shape[1], [sympify_entry(x, name) for x in arr.ravel()])
        else:
            raise ShapeError(f"{name} must be a scalar, a vector or a matrix, got shape {arr.shape}")
    if M.shape != (n, n):
        raise ShapeError(f"{name} must be {n}x{n}, got {M.rows}x{M.cols}")
    M = M.applyfunc(lambda e: sympify_entry(e, name))
    for i in range(n):
        if M[i, i].is_positive is False:  # only what is provably false (sympy.stats style)
            raise SymmonError(f"{name}[{i},{i}] = {M[i, i]} is not positive: a scale matrix is positive definite (18)")
    if not M.free_symbols:
        A = np.array(M.evalf(), dtype=float)
        # Tested with the diagonal scaled to 1 (the diagonal is positive, checked above): a
        # scale of 1e-6 beside one of 1e6 (µm and km) is no less definite than two of 1.
        r = 1.0 / np.sqrt(np.diag(A))
        B = r[:, None] * A * r[None, :]
        sym = 0.5 * (B + B.T)
        if np.linalg.matrix_rank(B) < n:
            raise SingularMatrixError(f"{name} is singular: a change of units must be invertible (18)")
        if np.linalg.eigvalsh(sym)[0] <= _PD_RTOL:
            raise SymmonError(
                f"{name} is not positive definite (smallest eigenvalue of the symmetric part of "
                f"diag^-1/2 {name} diag^-1/2: {np.linalg.eigvalsh(sym)[0]:.3g}); (18) requires positive "
                "definite scale matrices"
            )
        if M.det() == 0:
            raise SingularMatrixError(f"{name} is singular: a change of units must be invertible (18)")
    else:
        d = sp.cancel(M.det())
        if d == 0:
            raise SingularMatrixError(f"{name} is singular (det = 0 identically): a change of units must be invertible (18)")
    return M


def offset_vector(o: Any, n: int, name: str) -> sp.Matrix:
    """``o`` as an n×1 sympy Matrix (None → 0; a scalar is accepted for n = 1)."""
    if o is None:
        return sp.zeros(n, 1)
    if isinstance(o, sp.MatrixBase):
        items = list(o)
        if min(o.shape) > 1:
            raise ShapeError(f"{name} must be a vector, got a {o.rows}x{o.cols} matrix")
    else:
        arr = np.asarray(o, dtype=object)
        if arr.ndim == 0:
            arr = arr.reshape(1)
        if arr.ndim != 1:
            raise ShapeError(f"{name} must be a vector, got shape {arr.shape}")
        items = list(arr)
    if len(items) != n:
        raise ShapeError(f"{name} must have length {n}, got {len(items)}")
    return sp.Matrix([sympify_entry(x, name) for x in items])


def inverse(M: sp.Matrix) -> sp.Matrix:
    # Diagonal scales (the usual case) are inverted entrywise: no symbolic LU noise.
    if M.is_diagonal():
        return sp.diag(*[1 / M[i, i] for i in range(M.rows)])
    return M.inv().applyfunc(sp.cancel)


def _bar_symbol(s: sp.Symbol, taken: set[str], suffix: str) -> sp.Symbol:
    name = s.name + suffix
    while name in taken:
        name += suffix or "_"
    taken.add(name)
    return sp.Symbol(name, **s.assumptions0)


# --------------------------------------------------------------------------------------
# Change of units of a model and of a Gaussian
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Relation:
    """ḡ as plain sympy objects (a Model rejects symbols other than its inputs and noise)."""

    inputs: tuple
    noise: tuple
    outputs: tuple
    name: str


def changed_parts(model: ModelParts, Su, ou, Sy, oy, Sv, suffix: str) -> tuple[list, list, sp.Matrix]:
    taken = {s.name for s in model.inputs + model.noise} if suffix else set()
    if suffix:
        u_new = [_bar_symbol(s, taken, suffix) for s in model.inputs]
        v_new = [_bar_symbol(s, taken, suffix) for s in model.noise]
    else:
        u_new, v_new = list(model.inputs), list(model.noise)
    repl = dict(zip(model.inputs, Su * sp.Matrix(u_new) + ou))
    if model.n_v:
        repl.update(zip(model.noise, Sv * sp.Matrix(v_new)))
    g = sp.Matrix([e.xreplace(repl) for e in model.outputs])  # simultaneous replacement
    return u_new, v_new, inverse(Sy) * (g - oy)


def changed_model(model: ModelParts, Su, ou, Sy, oy, Sv, suffix: str) -> tuple[list, list, list, list]:
    """The parts of the model in new units (20): new inputs, outputs ḡ, new noise, and the
    angle declarations kept (those of components whose units are unchanged); numeric scales only."""
    params = set().union(*(M.free_symbols for M in (Su, ou, Sy, oy, Sv)))
    if params:
        raise ModelError(
            f"symbolic scales or offsets {sorted(map(str, params))} cannot go into a Model, which "
            "accepts only input and noise symbols: use symmon.units.changed_relation for the "
            "symbolic ḡ, or numbers here"
        )
    u_new, v_new, g_bar = changed_parts(model, Su, ou, Sy, oy, Sv, suffix)
    angles: list = []
    for i in sorted(model.angle_outputs):
        if unchanged(Sy, oy, i):
            angles.append(i)
    for i in sorted(model.angle_inputs):
        if unchanged(Su, ou, i):
            angles.append(u_new[i])
    return u_new, list(g_bar), v_new, angles




def unchanged(S: sp.Matrix, o: sp.Matrix, i: int) -> bool:
    row = [S[i, j] for j in range(S.cols)]
    return all(sp.simplify(x - (1 if j == i else 0)) == 0 for j, x in enumerate(row)) and o[i] == 0
