"""The registry of transform names and presets: what ``--transform`` accepts and what
``compare`` lists.

A preset is a short name, a one-line summary and a factory that builds the transform
from the options a front end can set (samples, seed, order, groups); each factory takes
the options it needs and ignores the others.  Every rule, built-in or new, declares its
presets in its class (``presets = {name: (summary, factory)}``) and
:meth:`Transform.__init_subclass__ <symmon.Transform.__init_subclass__>` registers them
here when the class is created (docs/architecture.md).  The names are listed in the order
the rules' modules are imported by :mod:`symmon.transforms`.

Examples
--------
>>> from symmon.transforms.registry import make, names
>>> names()[:5]
('tt1', 'tt2', 'ut1', 'ut2', 'ct')
>>> make("gh", order=3)
GaussHermite(order=3, sparse=None, error_estimate=False)
"""

from __future__ import annotations

from dataclasses import dataclass
import re
from typing import Any, Callable

from ..errors import SymmonError

#: A preset's factory: the keyword options of :func:`make` → a ``Transform``.  Annotated
#: without the class: :mod:`symmon.transforms.base` registers its rules here when they are
#: created, so this module is below it and does not import it.
Factory = Callable[..., Any]

__all__ = ["Preset", "make", "resolve", "names", "presets", "compare_set", "COMPARE", "DEFAULT",
           "default_transform"]


@dataclass(frozen=True)
class Preset:
    """A named transform: ``factory(**options)`` builds it (see :func:`make`)."""

    name: str
    summary: str
    factory: Factory


_PRESETS: dict[str, Preset] = {}


def _register(name: str, summary: str, factory: Factory) -> Preset:
    """Add a preset (called by :meth:`Transform.__init_subclass__` only: rules declare
    ``presets``) under ``name`` (lower case, no spaces), listed after those before it.

    ``factory`` is called with the keyword options of :func:`make`, so it must accept
    ``**options`` and take from them only what it needs.

    Raises
    ------
    SymmonError
        If the name is taken or not a lower-case word.
    """
    if not (isinstance(name, str) and name and name == name.lower() and name.isidentifier()):
        raise SymmonError(f"a transform name must be a lower-case word, got {name!r}")
    if name in _PRESETS:
        raise SymmonError(f"the transform name {name!r} is already registered ({_PRESETS[name].summary})")
    preset = Preset(name, summary, factory)
    _PRESETS[name] = preset
    return preset


def names() -> tuple[str, ...]:
    """The registered names, in registration order (the order ``compare`` lists them)."""
    return tuple(_PRESETS)


def presets() -> tuple[Preset, ...]:
    """The registered presets, in registration order."""
    return tuple(_PRESETS.values())


def make(name: str, *, samples: int = 10**6, seed: int = 0, order: int = 5, groups: int = 16) -> Any:
    """The transform registered as ``name``, built with the options it uses.

    Parameters
    ----------
    name : str
        One of :func:`names`.
    samples, seed, groups : int
        Monte Carlo sample count, seed and number of independent groups.
    order : int
        Gauss–Hermite order per dimension.

    Where Monte Carlo runs is not an option of the transform: pass an
    :class:`~symmon.transforms.executor.Executor` to :func:`symmon.propagate`.

    Raises
    ------
    SymmonError
        For an unknown name.
    """
    if name not in _PRESETS:
        raise SymmonError(f"unknown transform {name!r}; use one of {names()} (or gh<order>, e.g. 'gh5')")
    return _PRESETS[name].factory(samples=samples, seed=seed, order=order, groups=groups)


def resolve(transform: Any) -> Any:
    """A transform given by its short name, as on the command line, or as itself.

    A registered name (:func:`names`: ``"tt1"``, ``"ut1"``, ``"gh"``, ``"mc"``, ...) is built
    with :func:`make`'s defaults; ``"gh<order>"`` (``"gh5"``) is Gauss–Hermite of that order.
    Anything that is not a string is returned as it is, for the caller to check.

    Raises
    ------
    SymmonError
        For an unknown name.

    Examples
    --------
    >>> resolve("ut1"), resolve("gh3")
    (UT.ut1(), GaussHermite(order=3, sparse=None, error_estimate=False))
    """
    if not isinstance(transform, str):
        return transform
    name = transform.strip().lower()
    order = re.fullmatch(r"gh(\d{1,3})", name)
    if order:
        return make("gh", order=int(order.group(1)))
    return make(name)


#: The names :func:`symmon.compare` uses by default, with ``samples=10**5``.
COMPARE = ("tt1", "tt2", "ut1", "ct", "gh", "mc")


#: The default transform of :func:`symmon.propagate`, :func:`symmon.propagate_many`,
#: :func:`symmon.nonlinearity` and the sweeps.  TT2: in the accuracy-per-cost table of
#: benchmarks/RESULTS.md it agrees with 10⁷-sample Monte Carlo to 1e-3 on every Figure 2
#: problem up to α = 1 at one batched evaluation, where the UT rules miss already at
#: α = 0.1; Gauss–Hermite does as well but its n^order nodes do not scale with n, while
#: TT2's cost grows with the nonzeros of the Hessians (docs/guide/transforms.md).
DEFAULT = "tt2"


def default_transform() -> Any:
    """The transform used when none is given (:data:`DEFAULT`)."""
    return make(DEFAULT)


def compare_set() -> list[Any]:
    """The transforms :func:`symmon.compare` uses by default (:data:`COMPARE`)."""
    return [make(n, samples=10**5) for n in COMPARE]
