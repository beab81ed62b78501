"""Propagation of Gaussians through a model: :func:`propagate` (one Gaussian of u, and v),
:func:`propagate_many` (K of them), their single-point result :class:`JointMoments`, and
:func:`quadrature_error` (docs/architecture.md, "Data flow of propagate")."""

from .accuracy import quadrature_error as quadrature_error
from .front import check_transform as check_transform
from .front import input_batch as input_batch
from .front import joint_input as joint_input
from .front import propagate as propagate
from .front import propagate_many as propagate_many
from .front import propagate_mixture as propagate_mixture
from .joint import JointMoments as JointMoments

__all__ = ["propagate", "propagate_many", "JointMoments", "quadrature_error", "joint_input", "input_batch",
           "check_transform", "propagate_mixture"]
