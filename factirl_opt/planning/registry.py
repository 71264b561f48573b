"""The planner registry: planners by name, as the objectives and the step solvers are registered.

``planner=`` takes a name everywhere (:func:`available_planners`); ``"auto"`` resolves to
``"dense"`` up to :data:`AUTO_DENSE_MAX_STATES` states and to ``"sparse-lu"`` above (docs/maths.md
§4). :func:`get_planner` returns the planner of that name bound to an MDP, one per MDP and name
(kept by :mod:`factirl_opt.planning.cache` for the MDP's lifetime).
"""

from __future__ import annotations

from typing import Any

from .._validation import check_mdp
from ..exceptions import ValidationError
from .base import Planner
from .cache import cached_planner
from .dense import DensePlanner
from .sparse_lu import SparseLUPlanner

__all__ = ["register_planner", "unregister_planner", "available_planners", "get_planner", "resolve_planner", "AUTO_DENSE_MAX_STATES"]

#: ``planner="auto"`` uses the dense planner up to this many states (the measured crossover, 12x12)
AUTO_DENSE_MAX_STATES = 144

_REGISTRY: dict[str, type[Planner]] = {}


def register_planner(name: str, cls: type[Planner], overwrite: bool = False) -> None:
    """Register a :class:`~factirl_opt.planning.base.Planner` subclass under ``name``.

    ``cls(mdp)`` must build the planner bound to ``mdp``. ``"auto"`` is reserved.
    """
    if not isinstance(name, str) or not name or name == "auto":
        raise ValidationError(f"planner name must be a non-empty string other than 'auto'; got {name!r}")
    if not (isinstance(cls, type) and issubclass(cls, Planner)):
        raise ValidationError(f"planner {name!r} must be a Planner subclass; got {cls!r}")
    if name in _REGISTRY and not overwrite:
        raise ValidationError(f"a planner named {name!r} is already registered (pass overwrite=True to replace it)")
    _REGISTRY[name] = cls


def unregister_planner(name: str) -> None:
    """Remove the planner registered as ``name`` (planners already bound to MDPs stay usable)."""
    if not isinstance(name, str) or name not in _REGISTRY:
        raise ValidationError(f"unknown planner {name!r}; available: {', '.join(available_planners())}")
    del _REGISTRY[name]


def available_planners() -> list[str]:
    """Names accepted by ``planner=``: ``"auto"`` first, then every registered planner."""
    return ["auto", *_REGISTRY]


def resolve_planner(name: Any, n_states: int) -> str:
    """The registered name ``name`` stands for on a model of ``n_states`` states (``"auto"``
    resolved); an unknown name raises :class:`ValidationError` listing the known ones."""
    if not isinstance(name, str) or name not in available_planners():
        raise ValidationError(f"unknown planner {name!r}; available: {', '.join(available_planners())}")
    if name == "auto":
        return "dense" if n_states <= AUTO_DENSE_MAX_STATES else "sparse-lu"
    return name


def get_planner(mdp: Any, planner: str | Planner = "auto") -> Planner:
    """The planner named ``planner`` bound to ``mdp`` (one per MDP and name), or a Planner as is.

    Parameters
    ----------
    mdp : TabularMDP
    planner : str or Planner, default="auto"
        A name of :func:`available_planners`, or a planner already bound to ``mdp``.
    """
    if isinstance(planner, Planner):
        if planner.mdp is not mdp:
            raise ValidationError("this planner is bound to another MDP")
        return planner
    check_mdp(mdp)
    name = resolve_planner(planner, mdp.n_states)
    return cached_planner(mdp, name, _REGISTRY[name])


register_planner("dense", DensePlanner)
register_planner("sparse-lu", SparseLUPlanner)
