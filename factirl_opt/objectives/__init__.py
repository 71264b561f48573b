"""Objectives: registered per-task losses over rewards (docs/maths.md §5 and §6).

An objective maps (MDP, empirical statistics, beta) to a batched loss per task and ``dJ/dR``;
the learners take one by name (``objective=``), and the step solvers and the factorial scheme
never know which one runs.

``"policy-matching"`` (default)
    The paper's eq. (5): squared distance between the Boltzmann policy on ``Q*`` and the
    demonstrated policy (:class:`PolicyMatchingObjective`; least squares, so the Gauss-Newton
    solvers apply).
``"mce"``
    Maximum causal entropy (Ziebart et al. 2010), infinite horizon, discounted: the negative
    log-likelihood of the demonstrated pairs under the soft-optimal policy of the soft Bellman
    equation (:class:`MCEObjective`, :func:`mce_loss`; not least squares: gradient solvers only).

Every kind of objective a fit runs on (these, the multi-environment, sharded and weighted ones)
implements one contract, :class:`TaskObjective` (:mod:`factirl_opt.objectives.contract`).
"""

from ..exceptions import ValidationError
from ._base import Objective
from .contract import TaskObjective
from .mce import MCEObjective, mce_loss, soft_values
from .policy_matching import (
    PolicyMatchingObjective,
    dq_dtheta,
    jacobian_mode,
    policy_matching_grad_reference,
    policy_matching_loss,
    residual_jacobian,
)

__all__ = [
    "Objective",
    "TaskObjective",
    "PolicyMatchingObjective",
    "policy_matching_loss",
    "policy_matching_grad_reference",
    "residual_jacobian",
    "jacobian_mode",
    "dq_dtheta",
    "MCEObjective",
    "mce_loss",
    "soft_values",
    "register_objective",
    "available_objectives",
    "get_objective",
]

_REGISTRY: dict[str, type] = {}


def register_objective(name, cls, overwrite=False):
    """Register an :class:`Objective` subclass under ``name``."""
    if not isinstance(name, str) or not name:
        raise ValidationError(f"objective name must be a non-empty string; got {name!r}")
    if not (isinstance(cls, type) and issubclass(cls, Objective)):
        raise ValidationError(f"objective {name!r} must be an Objective subclass; got {cls!r}")
    if name in _REGISTRY and not overwrite:
        raise ValidationError(f"an objective named {name!r} is already registered (pass overwrite=True to replace it)")
    _REGISTRY[name] = cls


def available_objectives():
    """Registered objective names (sorted)."""
    return sorted(_REGISTRY)


def get_objective(name):
    """The :class:`Objective` subclass registered as ``name`` (a subclass is returned as is)."""
    if isinstance(name, type) and issubclass(name, Objective):
        return name
    if not isinstance(name, str) or name not in _REGISTRY:
        raise ValidationError(f"unknown objective {name!r}; available: {', '.join(available_objectives())}")
    return _REGISTRY[name]


register_objective("policy-matching", PolicyMatchingObjective)
register_objective("mce", MCEObjective)
