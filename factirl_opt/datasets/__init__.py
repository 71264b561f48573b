"""The datasets layer: worlds and tasks to learn from.

- :mod:`~factirl_opt.datasets.synthetic`: the paper's synthetic tasks (random dictionaries and
  coefficients, demonstrations of their rewards).
- :mod:`~factirl_opt.datasets.objectworld`: Objectworld (Levine et al. 2011), its multi-task
  version (ELIRL) and families of maps (:mod:`~factirl_opt.datasets.objectworld.maps`).
- :mod:`~factirl_opt.datasets.babyai`: BabyAI GoTo layouts as tasks, with the BabyAI bot's
  demonstrations (extra ``.[minigrid]``; loaded on first access, as it imports minigrid).
"""

from .synthetic import SyntheticTasks, random_coefficients, random_dictionary, synthetic_tasks

__all__ = ["SyntheticTasks", "random_coefficients", "random_dictionary", "synthetic_tasks", "babyai_tasks", "BabyAITasks"]

_BABYAI_NAMES = ("babyai_tasks", "BabyAITasks")


def __getattr__(name: str) -> object:
    if name in _BABYAI_NAMES:
        from . import babyai

        return getattr(babyai, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
