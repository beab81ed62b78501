"""Estimation with nonlinear transformations (Gustafsson & Hendeby 2012): the direct approach
with fusion, the indirect approach with conditioning, and one predict / update step
(:mod:`.nlt`); the closed-form MMSE estimators of distances (:mod:`.mmse`).  The Kalman
filters are in :mod:`symmon.filters`."""

from . import mmse as mmse
from .nlt import DirectResult as DirectResult
from .nlt import IndirectResult as IndirectResult
from .nlt import direct as direct
from .nlt import fuse as fuse
from .nlt import indirect as indirect
from .nlt import predict as predict
from .nlt import update as update

__all__ = ["fuse", "DirectResult", "IndirectResult", "direct", "indirect", "predict", "update", "mmse"]
