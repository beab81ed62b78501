"""Measures of nonlinearity (Straka & Havlík 2024; Liu & Li 2015): the formula (25)–(29)
(:mod:`.formula`), the weights (:mod:`.weights`), Σ_c = Cov_v E[g | v] (:mod:`.conditional`),
the front end :func:`nonlinearity` and :func:`compare` (:mod:`.mon`), the sweeps
(:mod:`.sweep`) and the choice of a transform (:func:`advise`, :mod:`.advice`)."""

from . import sweep as sweep
from . import weights as weights
from .advice import Advice as Advice
from .advice import advise as advise
from .formula import MonParts as MonParts
from .formula import NonlinearityMeasure as NonlinearityMeasure
from .formula import mon_from_moments as mon_from_moments
from .mon import compare as compare
from .mon import nonlinearity as nonlinearity
from .sweep import SweepResult as SweepResult
from .sweep import sweep_alpha as sweep_alpha
from .sweep import sweep_states as sweep_states

__all__ = ["nonlinearity", "compare", "MonParts", "NonlinearityMeasure", "mon_from_moments", "advise", "Advice",
           "SweepResult", "sweep_alpha", "sweep_states", "sweep", "weights"]
