"""Standalone C of a nonlinear Kalman filter: predict and update, for embedded targets.

:func:`export_filter_c` (and :meth:`symmon.NonlinearKalmanFilter.export_c`) writes
``NAME.c`` and ``NAME.h``: C99 with no dynamic allocation, no global mutable state and no
I/O, that includes only ``<math.h>`` and ``<string.h>``.  Its interface::

    #define NAME_NX n        /* states */
    #define NAME_NY n_y      /* measurements */
    int NAME_predict(double *x, double *P);
    int NAME_update(double *x, double *P, const double *y, double *loglik);

Both work in place on the state x (NX) and its covariance P (NX × NX, symmetric, row-major
and column-major alike); ``NAME_update`` adds log N(ν; 0, S) of the innovation ν to
``*loglik``.  They return ``NAME_OK`` (0), or an error code and leave x, P and ``*loglik``
unchanged: ``NAME_ERR_STATE`` (x or P not finite on entry), ``NAME_ERR_MEASUREMENT`` (a component
of y infinite), ``NAME_ERR_S`` (the innovation covariance S is not positive definite) or
``NAME_ERR_P`` (the new P is not positive definite, or the new x is not finite).  A NaN
component of y is a missing measurement, as in ``kf.filter``: the update runs on the measured
components (the filter step's mask), and a y of NaN only leaves x and P as predicted.  With model
parameters (``Model(params=...)``) the function whose model uses them takes ``const double
*p`` after the state (``NAME_NP`` values, f's then h's), and a non-finite one returns
``NAME_ERR_PARAM``.

The step is the filter's own (:mod:`symmon.filters.gaussian.step`): the same CasADi graphs of the
time update and of the measurement update (Lemma 7.1 of Gustafsson & Hendeby), with Q and
R fixed at export, angle states and angle measurements wrapped as in the filter, and the
filter's choice of graph: straight-line SX for small filters (below ``MX_FROM`` variables
and ``MAX_SX_POINTS`` points: the fastest C, a few tens of KB), else MX, whose products with
P, Cholesky factors, map over the points and gain solve are matrix nodes around small SX
functions of f, h and their derivatives' nonzeros, so the C has loops and grows with the
nonzeros, not with n³ (docs/export.md).
Positive definiteness is tested by the pivots of a Cholesky factor of S and of the new P.
The interface's C, the prototypes, the work-size macros and the example program are templates
beside this module (``export_filter.c.in``, ``export_api.h.in``, ``export_work.h.in``,
``export_example.c.in``): :func:`~symmon.compile.csource.choose` keeps the parameter argument
where a model has parameters, and :func:`~symmon.compile.csource.fill` puts in the prefix (a
checked C identifier) and the sizes; user text reaches the files only through
:func:`~symmon.compile.cnames.comment_text`.

Also written: ``NAME_example.c``, a program that reads x0, P0 and per step the parameter
values and a measurement from stdin and prints the estimates, and ``NAME_README.md``
(interface, sizes, build, the model it came from, the symmon version and the model's hash).
A file of these names that symmon's export did not write (it carries :data:`STAMP`) is not
replaced.

A square-root filter (``square_root=True``) exports its square-root step
(:mod:`symmon.filters.gaussian._sqrtstep`): ``NAME_predict(x, S)`` and ``NAME_update(x, S, y,
&loglik)`` (NaN components of y missing, as in the standard export) carry the lower Cholesky factor S of P (P = S Sᵀ, row-major) in place of P, √Q
and √R are fixed, and definiteness is a positive diagonal of the factors.

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import casadi as ca
import numpy as np

from ...codegen.export import HEADER_CLOSING, c_prefix, generate_sources, work_sizes
from ...compile.cnames import c_identifier, comment_text
from ...compile.csource import c_file, choose, fill
from ...errors import ArgumentTypeError, OutputPathError, SymmonError
from ...io import atomic_write_text, check_output_set
from ...version import __version__
from ._sqrtstep import noise_factor, sqrt_predict_graph, sqrt_update_graph
from .step import predict_graph, select_params, step_kind, update_graph
from ..inputs import FilterSpec
from .strategy import RuleStrategy

__all__ = ["export_filter_c", "filter_functions", "ERROR_CODES", "STAMP"]

#: The mark in the head of every file the export writes: a file without it is not replaced.
STAMP = "written by symmon's NonlinearKalmanFilter.export_c"

#: The return codes of the exported functions, by suffix (``NAME_OK``, ``NAME_ERR_STATE``, …).
ERROR_CODES = {
    "OK": (0, "success"),
    "ERR_STATE": (1, "x or P is not finite on entry"),
    "ERR_MEASUREMENT": (2, "a measurement is infinite (NaN marks a missing one)"),
    "ERR_S": (3, "the innovation covariance S is not positive definite"),
    "ERR_P": (4, "the new P is not positive definite, or the new x is not finite"),
    "ERR_EVAL": (5, "the generated evaluation failed (not expected)"),
    "ERR_PARAM": (6, "a parameter value is not finite"),
}


def _transform(kf: FilterSpec):
    if not isinstance(kf.strategy, RuleStrategy):
        raise SymmonError(
            f"export_c needs a filter with one transform for every step; {kf.method} chooses one per "
            "step: export each candidate filter (e.g. the EKF and the UKF) and switch between them in C"
        )
    return kf.strategy.transform


def _family(kf: FilterSpec) -> str:
    """ekf, ekf2, ukf, ckf, ghkf, …: the filter's label without its settings."""
    return re.sub(r"[^a-z0-9]+", "", kf.method.split("(")[0].lower()) or "kf"


def filter_functions(kf: FilterSpec, name: str) -> dict[str, ca.Function]:
    """The CasADi functions :func:`export_filter_c` writes C for.

    Returns
    -------
    dict
        ``"predict"``: (x, P) ↦ (x⁻, P⁻, P⁻ positive definite); ``"update"``: (x⁻, P⁻, y, mask) ↦
        (x⁺, P⁺, log N(ν; 0, S), S positive definite, P⁺ positive definite), on the components
        of y whose mask is 1 (the filter step's :func:`~symmon.filters.gaussian.step.update_graph`).  Q
        and R are the filter's, fixed.  "Positive definite" is 1 when every pivot of the matrix's Cholesky
        factor is > 0, else 0.
    """
    transform = _transform(kf)
    f, h = kf.f_model, kf.h_model
    n, n_y = f.n_u, h.n_y
    # The filter step's own choice (symmon.filters.gaussian.step.step_kind): straight-line SX for small
    # filters (the fastest C, and short), MX with loops from MX_FROM variables on.
    kind, chol = step_kind(f, h, transform)
    x, P, y, mask = kind.sym("x", n), kind.sym("P", n, n), kind.sym("y", n_y), kind.sym("mask", n_y)
    names = kf.params
    p = kind.sym("p", len(names))
    if kf.square_root:
        return _sqrt_functions(kf, transform, name, x, P, y, mask, p)
    Q, R = ca.DM(np.asarray(kf.Q, dtype=float)), ca.DM(np.asarray(kf.R, dtype=float))
    x_pred, P_pred = predict_graph(f, transform, kf.angle_states, x, P, Q, chol, select_params(f, names, p))

    def pivot(A):
        # 1 when every pivot of chol(A) is > 0, else 0: a comparison is false for NaN (a
        # negative pivot), where fmin would skip the NaN.
        return ca.mmin(ca.diag(chol(A)) > 0)

    opts = {"cse": True}
    # A function takes p when its model has parameters: (x, P, p) and (x, P, p, y).
    pf, ph = ([p], ["p"]) if f.n_p else ([], []), ([p], ["p"]) if h.n_p else ([], [])
    predict = ca.Function(f"{name}_predict_step", [x, P, *pf[0]],
                          [ca.densify(x_pred), ca.densify(P_pred), pivot(P_pred)],
                          ["x", "P", *pf[1]], ["x_pred", "P_pred", "pd_P"], opts)
    x_new, P_new, _, S, loglik, _ = update_graph(h, transform, kf.angle_states, x, P, y, R, chol, mask,
                                                 select_params(h, names, p), kf.iterations)
    update = ca.Function(f"{name}_update_step", [x, P, *ph[0], y, mask],
                         [ca.densify(x_new), ca.densify(P_new), loglik, pivot(S), pivot(P_new)],
                         ["x", "P", *ph[1], "y", "mask"], ["x_new", "P_new", "loglik", "pd_S", "pd_P"], opts)
    return {"predict": predict, "update": update}


def _sqrt_functions(kf: FilterSpec, transform, name: str, x, U, y, mask, p) -> dict[str, ca.Function]:
    """:func:`filter_functions` of a square-root filter: (x, S) ↦ (x⁻, S⁻, S⁻ nonsingular) and
    (x⁻, S⁻, y, mask) ↦ (x⁺, S⁺, log N(ν; 0, S), S_y nonsingular, S⁺ nonsingular), with S the lower
    Cholesky factor of P stored row-major (so the graph reads its column-major argument U as
    S = Uᵀ and writes Sᵀ); √Q and √R fixed (:mod:`symmon.filters.gaussian._sqrtstep`)."""
    f, h, names = kf.f_model, kf.h_model, kf.params
    Qs, Rs = (ca.DM(noise_factor(np.asarray(C, dtype=float))) for C in (kf.Q, kf.R))
    S = U.T

    def nonsingular(L):
        # 1 when every diagonal entry of the factor is > 0 (false for NaN), else 0.
        return ca.mmin(ca.diag(L) > 0)

    opts = {"cse": True}
    pf, ph = ([p], ["p"]) if f.n_p else ([], []), ([p], ["p"]) if h.n_p else ([], [])
    x_pred, S_pred = sqrt_predict_graph(f, transform, kf.angle_states, x, S, Qs, select_params(f, names, p))
    predict = ca.Function(f"{name}_predict_step", [x, U, *pf[0]],
                          [ca.densify(x_pred), ca.densify(S_pred.T), nonsingular(S_pred)],
                          ["x", "S", *pf[1]], ["x_pred", "S_pred", "pd_P"], opts)
    x_new, S_new, _, Sy, loglik, _ = sqrt_update_graph(h, transform, kf.angle_states, x, S, y, Rs, mask,
                                                       select_params(h, names, p), kf.iterations)
    update = ca.Function(f"{name}_update_step", [x, U, *ph[0], y, mask],
                         [ca.densify(x_new), ca.densify(S_new.T), loglik, nonsingular(Sy), nonsingular(S_new)],
                         ["x", "S", *ph[1], "y", "mask"], ["x_new", "S_new", "loglik", "pd_S", "pd_P"], opts)
    return {"predict": predict, "update": update}


def _work_macros(P: str, fname: str, key: str, f: ca.Function, extra_reals: int) -> list[str]:
    """The work-array sizes of one function and the stack they take (``export_work.h.in``)."""
    s = work_sizes(f)
    return fill(c_file(__package__, "export_work.h.in"), K=f"{P}_{key}", FNAME=fname, ARG=s["arg"],
                RES=s["res"], IW=s["iw"], W=s["w"] + extra_reals).splitlines()


def _template(name: str, P: str, kf) -> str:
    """The template ``name`` of this package filled for the prefix ``P`` and the filter: its
    optional parts chosen by whether f and h have parameters (FP, HP), the filter has any
    (NP), and its form (SQRT, or FULL: the covariance itself); the placeholders the prefix,
    its upper case P_, the covariance's name COV (S or P) and the update's argument of y,
    Y_AT (after p where h has parameters).  Only the flags and placeholders the template
    has are passed (:func:`choose` and :func:`fill` refuse others)."""
    fp, hp = bool(kf.f_model.n_p), bool(kf.h_model.n_p)
    text = c_file(__package__, name)
    flags = dict(FP=fp, HP=hp, NP=bool(kf.params), SQRT=bool(kf.square_root), FULL=not kf.square_root)
    values = dict(P=P, P_=P.upper(), COV="S" if kf.square_root else "P", Y_AT=3 if hp else 2)
    text = choose(text, **{k: v for k, v in flags.items() if f"@?{k}:" in text})
    return fill(text, **{k: v for k, v in values.items() if f"@{k}@" in text})


def _signatures(P: str, kf) -> tuple[str, str]:
    """The C prototypes of the two functions (``export_api.h.in``)."""
    predict, update = _template("export_api.h.in", P, kf).splitlines()
    return predict, update


def _model_hash(kf: FilterSpec, transform) -> str:
    """sha256 of what the C computes: f, h, Q, R, the transform, its iterations (the IEKF's
    Gauss–Newton steps) and the angles."""
    f, h = kf.f_model, kf.h_model
    key = repr((f.key, h.key, transform, kf.iterations,
                sorted(kf.angle_states), sorted(h.angle_outputs),
                np.asarray(kf.Q).tolist(), np.asarray(kf.R).tolist()) + (("square_root",) if kf.square_root else ()))
    return hashlib.sha256(key.encode()).hexdigest()


def _settings(kf: FilterSpec, transform) -> str:
    """The rule's settings with the dimension-dependent defaults resolved (the UT's κ = 3 − n)
    for the dimensions the two updates integrate over; both when they differ."""
    d_f, d_h = kf.dimensions
    if transform.settings(d_f) == transform.settings(d_h):
        return transform.settings(d_f)
    return f"time update {transform.settings(d_f)}; measurement update {transform.settings(d_h)}"


def _label(kf: FilterSpec, transform) -> str:
    """The filter's name for the files' titles: ``kf.method``, with the settings resolved
    where a default depends on the dimension (``UKF(alpha = 1.0, beta = 0.0, kappa = -5.0)``
    rather than ``kappa=None``), so that a title never contradicts the settings below it."""
    d_f, d_h = kf.dimensions
    if all(transform.settings(d) == repr(transform) for d in (d_f, d_h)):
        return kf.method
    return f"{kf.method.split('(')[0]}({_settings(kf, transform)})"


def _owned(path: Path) -> bool:
    """Whether ``path`` is missing, or a file the export wrote (:data:`STAMP` in its head)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            return STAMP in fh.read(4096)
    except FileNotFoundError:
        return True


def _header(kf, P: str, fs: dict[str, ca.Function], transform, digest: str) -> str:
    f, h = kf.f_model, kf.h_model
    n, n_y = f.n_u, h.n_y
    P_ = P.upper()
    states = ", ".join(comment_text(str(s)) for s in f.inputs)
    ys = ", ".join(comment_text(str(e)) for e in h.outputs)
    lines = [
        f"{P}: the {comment_text(_label(kf, transform))} filter exported by symmon {__version__}",
        f"({STAMP}).",
        "",
        f"  dynamics f: {comment_text(f.name)};  measurement h: {comment_text(h.name)}",
        f"  state x = [{states}]   (NX = {n})",
        f"  measurement y = [{ys}]   (NY = {n_y})",
        f"  noise: {'general, w in f' if f.n_v else 'additive Q'}; {'general, e in h' if h.n_v else 'additive R'};"
        " Q and R fixed at export",
    ]
    if kf.params:
        lines.append(f"  parameters p = [{', '.join(comment_text(str(q)) for q in kf.params)}]   (NP = {len(kf.params)}),"
                     " an argument of the functions whose model uses them")
    if kf.angle_states:
        lines.append(f"  angle states (wrapped to (-pi, pi]): {sorted(kf.angle_states)} (0-based)")
    if h.angle_outputs:
        lines.append(f"  angle measurements (wrapped innovation): {sorted(h.angle_outputs)} (0-based)")
    if kf.square_root:
        cov_lines = [
            _signatures(P, kf)[0],
            "    The time update, in place: x <- E f(x), S <- the lower Cholesky factor of Cov f (+ Q).",
            _signatures(P, kf)[1],
            "    The measurement update, in place, with y[NY]; adds log N(innovation; 0, S_y S_y^T) to *loglik.",
            "    A NaN component of y is missing: the update uses the others; y all NaN leaves x, S.",
            "",
            "x has NX entries; S is NX x NX, the lower triangular Cholesky factor of the covariance",
            "(P = S S^T), row-major: the square-root form, whose P stays positive definite where",
            "P - K S K^T loses it to rounding.  Both return 0 (OK), or an error code below and then",
            "leave x, S and *loglik unchanged.  C99, reentrant: no allocation, no global mutable state,",
            "no I/O; the work",
        ]
    else:
        cov_lines = [
            _signatures(P, kf)[0],
            "    The time update, in place: x <- E f(x), P <- Cov f (+ Q).",
            _signatures(P, kf)[1],
            "    The measurement update, in place, with y[NY]; adds log N(innovation; 0, S) to *loglik.",
            "    A NaN component of y is missing: the update uses the others; y all NaN leaves x, P.",
            "",
            "x has NX entries, P NX x NX (symmetric: row- and column-major alike; written exactly",
            "symmetric).  Both return 0 (OK), or an error code below and then leave x, P and *loglik",
            "unchanged.  C99, reentrant: no allocation, no global mutable state, no I/O; the work",
        ]
    lines += [
        f"  transform: {comment_text(_settings(kf, transform))}" + (f", {kf.iterations} iterations" if kf.iterations > 1 else ""),
        f"  model hash (sha256 of f, h, Q, R, the transform, its iterations and the angles): {digest}",
        "",
        *cov_lines,
        "memory is on the stack, of the sizes *_STACK_BYTES below.  Build: cc -std=c99 -O2 -c "
        f"{P}.c (link with -lm).",
    ]
    body = "/*\n" + "\n".join((" * " + ln).rstrip() for ln in lines) + "\n */\n"
    macros = [f"#define {P_}_NX {n}", f"#define {P_}_NY {n_y}"]
    if kf.params:
        macros.append(f"#define {P_}_NP {len(kf.params)}")
    macros.append("")
    for key, (code, what) in ERROR_CODES.items():
        macros.append(f"#define {P_}_{key} {code}  /* {what} */")
    macros.append("")
    macros += _work_macros(P_, f"{P}_predict", "PREDICT", fs["predict"], n + n * n)
    macros += _work_macros(P_, f"{P}_update", "UPDATE", fs["update"], n + n * n + 2 * n_y)  # + y and its mask
    return body, "\n".join(macros)


def export_filter_c(kf: FilterSpec, directory: str | Path, name: str | None = None) -> list[Path]:
    """Write the filter as standalone C: ``NAME.c``, ``NAME.h``, ``NAME_example.c``, ``NAME_README.md``.

    Parameters
    ----------
    kf : NonlinearKalmanFilter
        A filter with one transform (EKF, second-order EKF, UKF, CKF, Gauss–Hermite), additive
        or general noise, angle states and measurements; Q and R are fixed in the C.
    directory : str or Path
        Output directory (created if missing); the files are written atomically.
    name : str, optional
        The C prefix and file name: a C identifier (ASCII letter first, then letters, digits and
        single underscores, at most 63 characters); default: the measurement model's name and
        the filter family, e.g. ``range_bearing_ukf``.

    Returns
    -------
    list of Path
        The four files written.

    Raises
    ------
    SymmonError
        For an adaptive filter (no single step to export), or a ``name`` that is not such an
        identifier.
    OutputPathError
        If ``directory`` exists and is not a directory, or one of the four files in it
        cannot be written (read-only, not a regular file) or exists without
        :data:`STAMP` (a file the export did not write, e.g. a user's README): checked
        before anything is generated or written.

    Notes
    -----
    The exported step computes what :meth:`NonlinearKalmanFilter.filter` computes (the same
    graphs; tests/filters/test_export.py checks x, P and the log-likelihood against it to 1e-9
    relative on a target passing behind the sensor).  See docs/export.md.
    """
    # Checked by what the export reads (FilterSpec), not by class: filters.nonlinear imports this module.
    if not all(hasattr(kf, a) for a in ("f_model", "h_model", "Q", "R", "strategy", "angle_states")):
        raise ArgumentTypeError(f"kf must be a symmon.NonlinearKalmanFilter, got {type(kf).__name__}")
    transform = _transform(kf)
    default = f"{c_identifier(kf.h_model.name, hashed=False)}_{_family(kf)}"
    P = c_prefix(default if name is None else name, from_model=name is None)
    files = (f"{P}.c", f"{P}.h", f"{P}_example.c", f"{P}_README.md")
    outdir = check_output_set(directory, files)
    foreign = [outdir / f for f in files if not _owned(outdir / f)]
    if foreign:
        raise OutputPathError(
            f"export_c would replace {', '.join(str(p) for p in foreign)}, which symmon's export did not write "
            f"(no {STAMP!r} in its head): move it away, or export to another directory or name=")
    fs = filter_functions(kf, P)
    outdir.mkdir(parents=True, exist_ok=True)
    c_src, head, tail = generate_sources(fs.values(), P)
    digest = _model_hash(kf, transform)
    comment, macros = _header(kf, P, fs, transform, digest)
    guard = f"{P.upper()}_SYMMON_FILTER_H"
    protos = "\n".join(_signatures(P, kf)) + "\n"
    h_src = (comment + f"#ifndef {guard}\n#define {guard}\n\n" + macros + "\n\n" + head
             + "/* The filter interface (symmon). */\n" + protos + HEADER_CLOSING + tail + f"#endif /* {guard} */\n")
    c_src = (f"/* {P}.c: the {comment_text(_label(kf, transform))} filter ({STAMP}, symmon {__version__}). */\n"
             + c_src.rstrip("\n") + "\n\n#include <string.h>\n#include \"" + P + ".h\"\n\n"
             + _template("export_filter.c.in", P, kf))
    example = _template("export_example.c.in", P, kf)
    readme = _readme(kf, P, fs, transform, digest)
    return [atomic_write_text(outdir / f"{P}.c", c_src), atomic_write_text(outdir / f"{P}.h", h_src),
            atomic_write_text(outdir / f"{P}_example.c", example), atomic_write_text(outdir / f"{P}_README.md", readme)]


def _readme(kf, P: str, fs: dict[str, ca.Function], transform, digest: str) -> str:
    f, h = kf.f_model, kf.h_model
    n, n_y = f.n_u, h.n_y
    sizes = {k: work_sizes(fn) for k, fn in fs.items()}
    # Doubles and long longs of 8 bytes, pointers of 8 (a 64-bit target).
    extra = {"predict": n + n * n, "update": n + n * n + 2 * n_y}  # the new state (and y with its mask)
    stack = {k: 8 * (s["w"] + extra[k]) + 8 * s["iw"] + 8 * (s["arg"] + s["res"]) for k, s in sizes.items()}
    # Plain text of user names: Markdown code spans, with backticks replaced.
    def code(text: str) -> str:
        return "`" + comment_text(str(text)).replace("`", "'") + "`"

    return "\n".join([
        f"# {P}: an exported {comment_text(_label(kf, transform))} filter",
        "",
        f"Generated by symmon {__version__} ({STAMP}; it replaces only files that carry this mark).",
        "",
        f"- dynamics f: {code(f.name)}; measurement h: {code(h.name)}",
        f"- state ({n}): " + ", ".join(code(s) for s in f.inputs),
        f"- measurement ({n_y}): " + ", ".join(code(e) for e in h.outputs),
        f"- transform: {code(_settings(kf, transform))}" + (f", {kf.iterations} iterations" if kf.iterations > 1 else ""),
        f"- model hash (sha256 of f, h, Q, R, the transform, its iterations and the angles): `{digest}`",
        "",
        "## Interface (see the comment at the top of the header)",
        "",
        "```c",
        _signatures(P, kf)[0] + "  /* in place */",
        _signatures(P, kf)[1] + "  /* in place */",
        "```",
        "",
        f"x has {P.upper()}_NX = {n} entries, "
        + (f"S is {n} x {n} (the lower Cholesky factor of P = S S^T, row-major)" if kf.square_root
           else f"P is {n} x {n} (symmetric)")
        + f", y has {P.upper()}_NY = {n_y}"
        + (f", p has {P.upper()}_NP = {len(kf.params)}: " + ", ".join(code(q) for q in kf.params) if kf.params else "")
        + ".",
        "Return codes: " + "; ".join(f"{code(P.upper() + '_' + k)} = {c} ({what})"
                                      for k, (c, what) in ERROR_CODES.items()) + ".",
        "On an error x, P and *loglik are left unchanged. A NaN component of y is a missing measurement:",
        "the update uses the measured ones (as `kf.filter` does), and a y of NaN leaves x and P as predicted.",
        "",
        "## Memory",
        "",
        "No allocation and no global mutable state; each call takes its work memory on the stack:",
        f"about {stack['predict']} bytes for predict and {stack['update']} for update on a 64-bit target "
        f"(the macros {P.upper()}_PREDICT_STACK_BYTES and {P.upper()}_UPDATE_STACK_BYTES give it for yours).",
        "",
        "## Build and check",
        "",
        "```sh",
        f"cc -std=c99 -O2 -Wall -Wextra -pedantic -c {P}.c",
        f"cc -std=c99 -O2 {P}.c {P}_example.c -lm -o {P}_example",
        f"./{P}_example < measurements.txt",
        "```",
        "",
        f"`{P}_example` reads x0 ({n} numbers), "
        + (f"S0 ({n * n}, the lower Cholesky factor of P0, row-major)" if kf.square_root else f"P0 ({n * n}, row-major)")
        + " and then per step" + (f" the {len(kf.params)} parameter values and" if kf.params else "") + " one measurement of",
        f"{n_y} numbers (`nan` for a missing one) from stdin, and prints per step `k code x P loglik`.",
        "Run it on a recorded sequence and compare with `kf.filter` in symmon (docs/export.md).",
        "",
    ])
