"""The datasets layer: worlds and tasks to learn from.

- :mod:`~factirl_opt.datasets.synthetic`: the paper's synthetic tasks (random dictionaries and
  coefficients, demonstrations of their rewards).
- :mod:`~factirl_opt.datasets.objectworld`: Objectworld (Levine et al. 2011), its multi-task
  version (ELIRL) and families of maps (:mod:`~factirl_opt.datasets.objectworld.maps`).
"""

from .synthetic import SyntheticTasks, random_coefficients, random_dictionary, synthetic_tasks

__all__ = ["SyntheticTasks", "random_coefficients", "random_dictionary", "synthetic_tasks"]
