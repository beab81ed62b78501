"""The named models of the papers, each with its input distribution.

- :func:`polar`: the motivation example (14)–(16) of Straka & Havlík (2024), with the
  bearing unit as a parameter.
- :func:`bot`, :func:`gmti`, :func:`rdcos`: the tracking problems (45)–(47) with the
  state (44) scaled by α.
- :func:`radar_h`, :func:`radar_hinv`: the radar sensor of Gustafsson & Hendeby's
  lecture, its inverse for the direct approach.
- :func:`coordinated_turn`: the coordinated turn with a turn-rate state (Bar-Shalom, Li &
  Kirubarajan 2001, §11.7.2, (11.7.2-4)), the manoeuvring mode of an IMM.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from ..errors import SymmonError, plain_repr
from .gaussian import Gaussian
from .model import Model

__all__ = ["Problem", "polar", "bot", "gmti", "rdcos", "radar_h", "radar_hinv", "coordinated_turn", "BEARING_UNITS",
           "GMTI_SENSOR", "TURN_SERIES"]

#: Size of common bearing units, in radians.
BEARING_UNITS = {"rad": 1.0, "deg": np.pi / 180, "mrad": 1e-3, "grad": np.pi / 200}

#: The GMTI sensor position s = [s_x, s_y, s_z] in metres (Sec. V).
GMTI_SENSOR = (1e3, 1e3, 1e3)

#: The mean of the state (44): [x, y, ẋ, ẏ] in [m, m, m/s, m/s].
STATE_MEAN = (500.0, 500.0, 5.0, 8.7)
STATE_COV = (1e3, 1e3, 1.0, 1.0)


@dataclass(frozen=True)
class Problem:
    """A model with its input (and noise) distribution and the units of its outputs."""

    model: Model
    u: Gaussian
    v: Gaussian | None = None
    output_units: tuple[str, ...] = field(default_factory=tuple)


def _check_alpha(alpha: float) -> float:
    a = float(alpha)
    if not np.isfinite(a) or a <= 0:
        raise SymmonError(f"alpha must be positive and finite, got {plain_repr(alpha)}")
    return a


def _unit_size(unit: str | float, table: dict[str, float], what: str) -> tuple[float, str]:
    if isinstance(unit, str):
        if unit not in table:
            raise SymmonError(f"unknown {what} unit {unit!r}; known: {sorted(table)} or a number")
        return table[unit], unit
    s = float(unit)
    if not np.isfinite(s) or s <= 0:
        raise SymmonError(f"{what} unit size must be positive, got {unit!r}")
    return s, f"{s:g} rad"


def polar(alpha: float = 1.0, bearing_unit: str | float = "rad") -> Problem:
    """Cartesian to polar, (14)–(16): u = [x, y] ~ N([1, 10], α diag(1, 100)) in km.

    Parameters
    ----------
    alpha : float
        The covariance scale of (14).
    bearing_unit : str or float
        ``"rad"`` (16), ``"deg"`` (15), or the size of the unit in radians.
    """
    a = _check_alpha(alpha)
    size, label = _unit_size(bearing_unit, BEARING_UNITS, "bearing")
    x, y = sp.symbols("x y", real=True)
    scale = sp.Integer(1) if size == 1.0 else (sp.pi / 180 if label == "deg" else sp.Float(size))
    model = Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x) / scale], name=f"polar_{label}")
    return Problem(model, Gaussian([1.0, 10.0], a * np.diag([1.0, 100.0])), None, ("km", label))


def _state(alpha: float) -> tuple[tuple[sp.Symbol, ...], Gaussian]:
    a = _check_alpha(alpha)
    syms = sp.symbols("x y vx vy", real=True)
    return syms, Gaussian(STATE_MEAN, a * np.diag(STATE_COV))


def bot(alpha: float = 1.0) -> Problem:
    """Bearing-only tracking (45): z = atan2(x, y) (the paper's argument order), rad."""
    (x, y, vx, vy), u = _state(alpha)
    return Problem(Model([x, y, vx, vy], [sp.atan2(x, y)], name="bot"), u, None, ("rad",))


#: GMTI output unit sets of Sec. V: SI, or [km, deg, km/h].
GMTI_UNITS = {"si": (1.0, 1.0, 1.0), "km-deg-kmh": (1e3, np.pi / 180, 1 / 3.6)}
RDCOS_UNITS = {"m": 1.0, "km": 1e3}


def gmti(alpha: float = 1.0, units: str = "si") -> Problem:
    """Ground moving target indicator (46): range, bearing, range rate from s = (1e3, 1e3, 1e3).

    Parameters
    ----------
    units : {"si", "km-deg-kmh"}
        [m, rad, m/s] or [km, deg, km/h] for the outputs.
    """
    if units not in GMTI_UNITS:
        raise SymmonError(f"unknown GMTI units {units!r}; use one of {sorted(GMTI_UNITS)}")
    (x, y, vx, vy), u = _state(alpha)
    sx, sy, sz = (sp.Float(c) for c in GMTI_SENSOR)
    r = sp.sqrt((x - sx) ** 2 + (y - sy) ** 2 + sz**2)
    b = sp.atan2(x - sx, y - sy)
    rr = ((x - sx) * vx + (y - sy) * vy) / r
    if units == "si":
        outs, labels = [r, b, rr], ("m", "rad", "m/s")
    else:
        outs, labels = [r / 1000, b * 180 / sp.pi, rr * sp.Rational(36, 10)], ("km", "deg", "km/h")
    return Problem(Model([x, y, vx, vy], outs, name=f"gmti_{units}"), u, None, labels)


def rdcos(alpha: float = 1.0, units: str = "m") -> Problem:
    """Range and direction cosine (47): [√(x² + y²), x/√(x² + y²)], range in m or km."""
    if units not in RDCOS_UNITS:
        raise SymmonError(f"unknown RDCOS units {units!r}; use one of {sorted(RDCOS_UNITS)}")
    (x, y, vx, vy), u = _state(alpha)
    r = sp.sqrt(x**2 + y**2)
    outs = [r if units == "m" else r / 1000, x / r]
    return Problem(Model([x, y, vx, vy], outs, name=f"rdcos_{units}"), u, None, (units, "-"))


def radar_h(p=(0.0, 0.0), noise: bool = True) -> Model:
    """The lecture's radar: r = ‖x − p‖ + e_r, φ = atan2(x₂ − p₂, x₁ − p₁) + e_φ.

    This is the form of the lecture's SigSys code (``hypot`` and ``atan2(x2 − p2, x1 − p1)``).
    """
    x1, x2 = sp.symbols("x1 x2", real=True)
    p1, p2 = (sp.Float(float(c)) for c in p)
    r = sp.sqrt((x1 - p1) ** 2 + (x2 - p2) ** 2)
    phi = sp.atan2(x2 - p2, x1 - p1)
    if not noise:
        return Model([x1, x2], [r, phi], name="radar_h", angles=[1])
    er, ep = sp.symbols("e_r e_phi", real=True)
    return Model([x1, x2], [r + er, phi + ep], noise=[er, ep], name="radar_h", angles=[1])


def radar_hinv(p=(0.0, 0.0)) -> Model:
    """The inverse x = p + [r cos φ, r sin φ] for the direct approach (u = y − e)."""
    r, phi = sp.symbols("r phi", real=True)
    p1, p2 = (sp.Float(float(c)) for c in p)
    return Model([r, phi], [p1 + r * sp.cos(phi), p2 + r * sp.sin(phi)], name="radar_hinv")


#: Below this ``|ωT|`` the coordinated turn uses the Taylor series of its two ratios (to (ωT)⁴:
#: an error below (ωT)⁶/5040 ≈ 2e-16 relative): sin(ωT)/ω and (1 − cos ωT)/ω are 0/0 at ω = 0,
#: and their derivatives lose about eps/(ωT)² to cancellation just above it (2e-12).
TURN_SERIES = 1e-2


def coordinated_turn(T: float = 1.0) -> Model:
    """The coordinated turn with unknown turn rate, state [x, y, ẋ, ẏ, ω] (Bar-Shalom, Li &
    Kirubarajan 2001, §11.7.2, (11.7.2-4)): one step of T at the constant turn rate ω,

        x⁺ = x + (sin ωT / ω) ẋ − ((1 − cos ωT) / ω) ẏ,   ẋ⁺ = cos ωT ẋ − sin ωT ẏ,
        y⁺ = y + ((1 − cos ωT) / ω) ẋ + (sin ωT / ω) ẏ,   ẏ⁺ = sin ωT ẋ + cos ωT ẏ,   ω⁺ = ω.

    At ω = 0 it is the constant-velocity step; for ``|ωT|`` < :data:`TURN_SERIES` the two ratios
    are their Taylor series (a Piecewise), so that f and its derivatives are finite and
    accurate there, and 1 − cos ωT is computed as 2 sin²(ωT/2) (no cancellation).

    Parameters
    ----------
    T : float
        The time step (> 0).

    Examples
    --------
    >>> import numpy as np
    >>> from symmon.compile import compiled
    >>> g = compiled(coordinated_turn(1.0))
    >>> np.round(g.eval_g(np.array([[0.0, 0.0, 1.0, 0.0, np.pi / 2]]))[0], 6).tolist()  # a quarter turn
    [0.63662, 0.63662, 0.0, 1.0, 1.570796]
    """
    T = float(T)
    if not (np.isfinite(T) and T > 0):
        raise SymmonError(f"T must be a positive time step, got {T!r}")
    x, y, vx, vy, w = sp.symbols("x y vx vy omega", real=True)
    a = w * T
    small = sp.Abs(a) < TURN_SERIES
    # sin(ωT)/ω = T (1 − a²/6 + a⁴/120 − …), (1 − cos ωT)/ω = T a (1/2 − a²/24 + a⁴/720 − …)
    s = sp.Piecewise((T * (1 - a**2 / 6 + a**4 / 120), small), (sp.sin(a) / w, True))
    c = sp.Piecewise((T * a * (sp.Rational(1, 2) - a**2 / 24 + a**4 / 720), small), (2 * sp.sin(a / 2)**2 / w, True))
    return Model([x, y, vx, vy, w], [x + s * vx - c * vy, y + c * vx + s * vy, sp.cos(a) * vx - sp.sin(a) * vy,
                                     sp.sin(a) * vx + sp.cos(a) * vy, w], name=f"coordinated_turn_T{T:g}")
