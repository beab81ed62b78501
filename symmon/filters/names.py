"""The Gaussian filters that are one rule, by their filter names: ``"ekf"`` is TT1, ``"ukf"`` is
``UT.ut1()``, ``"ckf"`` the cubature rule, ``"ghkf"`` Gauss–Hermite of order 3, ``"ekf2"`` TT2.

A filter is named in Python where it takes a rule (``NonlinearKalmanFilter(f, h, Q, R, "ukf")``,
the Gaussian-sum filter's component filter): :func:`filter_rule` accepts these names next to
the rule names of :mod:`symmon.transforms.registry` (``"tt1"``, ``"ut1"``, ...), so ``"ekf"`` and
``"tt1"`` are one filter.  The whole filters, with their settings, are registered in
:mod:`symmon.filters.registry`, which reads this table for the rule filters.
"""

from __future__ import annotations

from typing import Any

from ..errors import SymmonError
from ..transforms.registry import names as rule_names
from ..transforms.registry import resolve

__all__ = ["RULE_FILTERS", "filter_rule"]

#: Filter name → the registered rule name it runs (``"gh3"``: Gauss–Hermite of order 3).
RULE_FILTERS: dict[str, str] = {"ekf": "tt1", "ekf2": "tt2", "ukf": "ut1", "ckf": "ct", "ghkf": "gh3"}


def filter_rule(transform: Any) -> Any:
    """The rule of a Gaussian filter given by a filter name (:data:`RULE_FILTERS`) or a rule
    name (``"tt1"``, ``"gh5"``, ...); anything that is not a string is returned as it is.

    Raises
    ------
    SymmonError
        For a name that is neither, listing both kinds.

    Examples
    --------
    >>> filter_rule("ekf"), filter_rule("tt1"), filter_rule("ukf")
    (TT1(), TT1(), UT.ut1())
    """
    if not isinstance(transform, str):
        return transform
    name = transform.strip().lower()
    if name in RULE_FILTERS:
        return resolve(RULE_FILTERS[name])
    if name == "iekf":
        raise SymmonError("'iekf' is the EKF iterated: NonlinearKalmanFilter(f, h, Q, R, 'ekf', iterations=5)")
    try:
        return resolve(name)
    except SymmonError:
        raise SymmonError(f"unknown filter or rule {transform!r}; filters: {', '.join(RULE_FILTERS)}; "
                          f"rules: {', '.join(rule_names())} (or gh<order>, e.g. 'gh5')") from None
