"""How the ``symmon`` command prints and writes its results: JSON, tables and figures.

Every number printed is checked first (:func:`_finite`): a NaN or inf is an error naming
the quantity, never a printed result.  JSON is strict (NaN and inf are null), tables use one
number format (:func:`_num`) and label each quantity with the unit the model file's
``[units]`` table gives it.  The commands themselves are in :mod:`symmon.cli.commands`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import SymmonError
from ..units.proof import show_point


# --------------------------------------------------------------------------- JSON and checks
def _jsonable(a: Any) -> Any:
    """Arrays and floats as JSON values; NaN and inf become null (strict JSON has neither)."""
    if a is None:
        return None
    if isinstance(a, (list, tuple)):
        return [_jsonable(x) for x in a]
    arr = np.asarray(a)
    if arr.ndim == 0:
        x = arr.item()
        if isinstance(x, float) and not math.isfinite(x):
            return None
        return x
    return [_jsonable(x) for x in arr]


def _finite(name: str, value: Any) -> Any:
    """``value``, after checking that every number in it is finite (None passes).

    A NaN or inf is an error, never a printed result: the command exits 1 naming the quantity.
    """
    if value is not None and not np.all(np.isfinite(np.asarray(value, dtype=float))):
        raise SymmonError(f"{name} is not finite (it contains NaN or inf); no result is printed")
    return value


def _bytes_text(n: int) -> str:
    """A size in bytes, in B, KiB, MiB or GiB with three significant digits."""
    if n < 1024:
        return f"{n} B"
    for unit in ("KiB", "MiB", "GiB"):
        n /= 1024
        if n < 1024 or unit == "GiB":
            return f"{n:.3g} {unit}"
    raise AssertionError("unreachable")


def _print_json(obj: dict) -> None:
    print(json.dumps(obj, indent=2, allow_nan=False))


def _measure_json(res) -> dict:
    return {"value": res.value, "squared": res.squared, "J_Ab": res.J_Ab, "J_n": res.J_n,
            "stderr": _jsonable(res.stderr), "weight": res.weight_name, "structure": res.structure,
            "transform": repr(res.transform), "notes": list(res.notes)}


def _finite_measure(res, where: str):
    """The MoN result ``res``, after checking that its numbers are finite."""
    for name, value in (("the MoN", res.value), ("the squared MoN", res.squared), ("J_Ab", res.J_Ab),
                        ("J_n", res.J_n), ("the standard error of the MoN", res.stderr)):
        _finite(name + where, value)
    return res


# --------------------------------------------------------------------------- units
#: Widest expression printed in an output table; longer ones are cut with "…" (``--json`` has them whole).
EXPR_WIDTH = 60


def _units_of(spec) -> dict[str, Any]:
    """The file's ``[units]`` by role: a unit (or None) per output, input and noise symbol."""
    m, units = spec.model, spec.units
    return {"outputs": [units.get(f"outputs[{i}]") for i in range(m.n_y)],
            "inputs": {str(s): units.get(str(s)) for s in m.inputs},
            "noise": {str(s): units.get(str(s)) for s in m.noise}}


def _label(name: str, unit: str | None) -> str:
    return f"{name} [{unit}]" if unit else name


def _short(text: str, width: int = EXPR_WIDTH) -> str:
    return text if len(text) <= width else text[:width - 1] + "…"


def _num(x: float) -> str:
    """One number format for every table: 6 significant digits, exponent only when needed."""
    return f"{x:.6g}"


def _grid(title: str, rows: Sequence[str], cols: Sequence[str], values: np.ndarray) -> list[str]:
    """A labelled matrix: a header of column labels, then one labelled line per row."""
    first = max(len(r) for r in rows)
    cells = [[_num(v) for v in row] for row in np.atleast_2d(values)]
    widths = [max(len(c), *(len(r[j]) for r in cells)) for j, c in enumerate(cols)]
    lines = [title, " " * first + "".join(f"  {c:>{w}}" for c, w in zip(cols, widths))]
    lines += [f"{r:<{first}}" + "".join(f"  {c:>{w}}" for c, w in zip(cells_r, widths))
              for r, cells_r in zip(rows, cells)]
    return lines


def _moments_text(spec, m) -> list[str]:
    """E y with its standard deviation and unit per output, then Cov y and Cov(y, u), labelled."""
    units = _units_of(spec)
    ys = [f"y[{i}]" for i in range(spec.model.n_y)]
    sd = np.sqrt(np.clip(np.diag(m.cov), 0.0, None))
    se = None if m.stderr is None else np.asarray(m.stderr["mean"], dtype=float)
    head = ["output", "E y", "sd", *(["MC s.e."] if se is not None else []), "unit", "expression"]
    rows = [[y, _num(m.mean[i]), _num(sd[i]), *([_num(se[i])] if se is not None else []),
             units["outputs"][i] or "-", _short(str(e))] for i, (y, e) in enumerate(zip(ys, spec.model.outputs))]
    widths = [max(len(r[j]) for r in [head, *rows]) for j in range(len(head))]
    lines = ["  ".join(f"{c:<{w}}" if j in (0, len(head) - 2, len(head) - 1) else f"{c:>{w}}"
                       for j, (c, w) in enumerate(zip(r, widths))).rstrip() for r in [head, *rows]]
    ylab = [_label(y, u) for y, u in zip(ys, units["outputs"])]
    ulab = [_label(k, u) for k, u in units["inputs"].items()]
    lines += _grid("Cov y (entry i, j in the unit of y[i] times that of y[j]):", ylab, ylab, m.cov)
    lines += _grid("Cov(y, u) (entry i, j in the unit of y[i] times that of u[j]):", ylab, ulab, m.cross_cov)
    if not any(units["outputs"]) and not any(units["inputs"].values()):
        lines.append("(the file has no [units] table: the numbers are in the model's own units)")
    return lines


def _mon_unit(spec, weight: str) -> str:
    """What the MoN is measured in: nothing, except for the raw Liu–Li MoN (6) (W = I)."""
    if weight != "liu-li-raw":
        return "unitless"
    units = [u or "?" for u in _units_of(spec)["outputs"]]
    if len(set(units)) == 1 and units[0] != "?":
        return units[0]  # √tr of a covariance of outputs that share one unit
    return "mixed units of y: " + ", ".join(units)


# --------------------------------------------------------------------------- proofs
def _refutation_text(proof, out: str | None) -> str:
    """A failed proof in a few lines: the counterexample (where the two sides differ, and by
    how much) instead of the whole difference, which ``--out`` writes."""
    import sympy as sp

    lines = [f"{proof.statement} with weight {proof.weight!r} ({proof.transform}): fails [{proof.seconds:.2f} s]"]
    cex = proof.counterexample or {}
    if "lhs" in cex:
        lhs, rhs = float(cex["lhs"]), float(cex["rhs"])
        rel = f" ({100 * abs(lhs - rhs) / abs(lhs):.2g} % of M²)" if lhs else ""
        lines.append(f"  counterexample: M² = {_num(lhs)} in the old units and {_num(rhs)} in the new units, "
                     f"a difference of {_num(lhs - rhs)}{rel}")
        lines.append(f"  at {show_point(cex)}")
    elif "difference" in cex:
        lines.append(f"  counterexample: M²(g, u) − M²(ḡ, ū) = {_num(float(cex['difference']))} at a rational point")
    size = sp.count_ops(proof.difference)
    where = f"written to {out}" if out else "--out FILE writes it"
    lines.append(f"  M²(g, u) − M²(ḡ, ū) is a nonzero expression of {size} operations ({where})")
    if proof.lemmas:
        lines.append("  by the lemmas: " + ", ".join(proof.lemmas))
    if proof.assumptions:
        lines.append("  assuming: " + "; ".join(proof.assumptions))
    return "\n".join(lines)


def _proof_report(proof) -> str:
    """Everything a proof found, whole: the verdict, M² on both sides, their difference and
    the counterexample point with every value."""
    lines = [str(proof), "", f"M²(g, u) = {proof.lhs}", "", f"M²(ḡ, ū) = {proof.rhs}", "",
             f"M²(g, u) − M²(ḡ, ū) = {proof.difference}"]
    if proof.counterexample:
        lines += ["", "counterexample:"] + [f"  {k} = {v}" for k, v in proof.counterexample.items()]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- filter banks
def _bank_json(r) -> dict:
    if r.result is None:
        return {"name": r.name, "error": r.error}
    out = {"name": r.name, "method": r.result.method,
           "anees": _jsonable(r.anees.value), "anis": None if r.anis is None else _jsonable(r.anis.value),
           "anees_bounds": [r.anees.lower, r.anees.upper],
           "anis_bounds": None if r.anis is None else [r.anis.lower, r.anis.upper],
           "rmse": _jsonable(r.rmse), "log_likelihood": _jsonable(r.result.log_likelihood)}
    if r.result.choices is not None:
        names, counts = np.unique(r.result.choices, return_counts=True)
        out["choices"] = {str(k): int(v) for k, v in zip(names, counts)}
    if r.smoothed is not None:
        out["smoothed"] = {"anees": _jsonable(r.smoothed_anees.value), "rmse": _jsonable(r.smoothed_rmse)}
    return out


def _filter_plot(spec, rows, states: list[str], path: str) -> Path:
    """NEES, NIS (log scale, with the χ² intervals) and RMSE per step, one line per filter,
    in the package's figure style (:mod:`symmon.reproduce.common`): each filter one colour,
    marker and line style in every panel, the legends right of the axes, no title."""
    from matplotlib.lines import Line2D

    from ..reproduce.common import (figure_style, filter_style, label_panels, legend_outside, plain_log_ticks,
                                    pyplot, save_plot)

    # One RMSE panel per unit: a norm over components is only meaningful in one unit.
    # Without [units], one panel over all the states, as the scenario declares no units.
    by_unit: dict[str | None, list[int]] = {}
    for i, s in enumerate(states):
        by_unit.setdefault(spec.unit(s), []).append(i)
    groups = list(by_unit.items()) if spec.units else [(None, list(range(len(states))))]
    plt = pyplot()
    with figure_style():
        fig, axes = plt.subplots(2 + len(groups), 1, figsize=(8, 5 + 2.5 * len(groups)), sharex=True,
                                 layout="constrained")
        try:
            k = np.arange(1, spec.steps + 1)
            for r in rows:
                if r.result is None:
                    continue
                st = filter_style(r.name, len(k))
                axes[0].semilogy(k, r.anees.value, label=r.name, **st)
                if r.anis is not None:  # a Gaussian-sum filter has none
                    axes[1].semilogy(k, r.anis.value, **st)
                for ax, (_, idx) in zip(axes[2:], groups):
                    ax.semilogy(k, np.sqrt(np.sum(r.rmse[:, idx] ** 2, axis=1)), **st)
                    if r.smoothed is not None:  # the smoother thin, in its filter's colour, no markers
                        ax.semilogy(k, np.sqrt(np.sum(r.smoothed_rmse[:, idx] ** 2, axis=1)), ls=(0, (1, 1)),
                                    color=st["color"], lw=0.8, zorder=st["zorder"])
            ok = [r for r in rows if r.result is not None and r.anis is not None]
            if ok:
                for ax, t, what in ((axes[0], ok[0].anees, "NEES"), (axes[1], ok[0].anis, "NIS")):
                    ax.axhspan(t.lower, t.upper, color="0.85", label=f"{t.confidence:.0%} interval")
                    ax.set_ylabel(f"average {what}")
            for ax, (unit, idx) in zip(axes[2:], groups):
                unit_text = f" [{unit}]" if unit else ("" if spec.units else " (no units declared)")
                ax.set_ylabel(f"RMSE of ({', '.join(states[i] for i in idx)}){unit_text}\n(norm over components)")
            axes[-1].set_xlabel("step k")
            # The filters' legend once, beside the first panel (their looks are the same in
            # every panel); the NIS panel's legend has its interval, the RMSE panels' the smoother.
            legend_outside(axes[0])
            if ok:
                legend_outside(axes[1], handles=[axes[1].patches[0]])
            if any(r.smoothed is not None for r in rows):
                legend_outside(axes[2], handles=[Line2D([], [], color="0.35", lw=1.2, label="filter"),
                                                 Line2D([], [], color="0.35", lw=0.8, ls=(0, (1, 1)),
                                                        label="its RTS smoother")])
            for ax in axes:
                if ax.get_yscale() == "log":
                    plain_log_ticks(ax)
            label_panels(axes)
            return save_plot(fig, path)
        finally:
            plt.close(fig)
