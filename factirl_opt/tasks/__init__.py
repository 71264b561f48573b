"""The tasks layer: demonstrations, trajectories and reward features, one home for "tasks on environments".

- :mod:`~factirl_opt.tasks.trajectories`: demonstrations as given (arrays, episodes of any
  length, trajectories from other libraries) parsed into per-task (state, action) steps.
- :mod:`~factirl_opt.tasks.demonstrations`: an expert's demonstrations sampled on one MDP or
  one per task, and their empirical statistics (``mu_hat``, ``pi_hat``).
- :mod:`~factirl_opt.tasks.features`: the reward models ``R_i = Phi_i w_i`` (tabular, state,
  shared or per-task features) and the products the learners need;
- :mod:`~factirl_opt.tasks.basis`: :class:`RewardBasis`, the one type every kind of features
  is seen through below the estimators (a new kind plugs in as a subclass, given as
  ``features=``);
- :mod:`~factirl_opt.tasks.task_set`: the tasks of a fit, validated once, and their row subsets.
"""

from .demonstrations import empirical_statistics, sample_demonstrations
from .basis import RewardBasis, SharedBasis, StateBasis, TabularBasis, TaskBasis
from .features import StateBroadcast, TaskFeatures, feature_rewards, task_rewards
from .trajectories import demonstrations_from_trajectories

__all__ = [
    "sample_demonstrations",
    "empirical_statistics",
    "demonstrations_from_trajectories",
    "TaskFeatures",
    "StateBroadcast",
    "feature_rewards",
    "task_rewards",
    "RewardBasis",
    "TabularBasis",
    "StateBasis",
    "SharedBasis",
    "TaskBasis",
]
