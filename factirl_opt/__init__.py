"""factirl-opt: multi-task inverse reinforcement learning (Mangin & Oudeyer 2014).

The data path: MDP + demonstrations -> empirical statistics -> eq. (5) loss and its adjoint
gradient -> a registered step solver -> learnt rewards -> eq. (13) score.

Internal modules (not public API; any module of the package may import their names):
``_validation`` (every boundary check), ``_threads`` (BLAS thread limits), ``_progress``
(progress bars and callbacks of long fits).
"""

from .demonstrations import empirical_statistics, sample_demonstrations
from .evaluation import deviation, optimal_score, score, soft_deviation
from .exceptions import (
    ConvergenceWarning,
    FactIRLError,
    MissingDependencyError,
    MissingSolverBackendError,
    NotFittedError,
    PersistenceError,
    SolverError,
    SolverOptionError,
    UnknownSolverError,
    ValidationError,
    WorkersLost,
)
from .factirl import FactIRL, fit_factorial, pca_dictionary, transfer_coefficients
from .gradirl import GradIRL
from .interruption import FitInterrupted, InterruptedFitWarning
from .gym_adapter import from_gymnasium, gymnasium_rewards
from .mdp import GridWorld, TabularMDP
from .minari_adapter import LoggedEpisodes, read_minari
from .model_estimation import as_transitions, estimate_mdp, sample_transitions, transition_counts, transition_log_likelihood
from .multi_intent import MultiIntentIRL, adjusted_rand_index, match_intentions
from .objectives import (
    available_objectives,
    mce_loss,
    policy_matching_grad_reference,
    policy_matching_loss,
    residual_jacobian,
)
from .persistence import load_demonstrations, load_model, save_demonstrations, save_model
from .solver_settings import SolverSettings
from .planning import available_planners, boltzmann_policy, optimal_q, policy_evaluation, value_iteration
from .objectworld import (
    ObjectWorld,
    levine_reward,
    make_objectworld,
    multitask_primitives,
    multitask_rewards,
    objectworld_distances,
    objectworld_features,
    objectworld_transitions,
    plot_objectworld,
    state_action_rewards,
)
from .objectworld_maps import ObjectWorldMaps, block_cells, fresh_maps, objectworld_maps
from .objectives.environments import MultiEnvironmentObjective, multi_environment_objective
from .successors import from_successors, to_successors
from .synthetic import SyntheticTasks, random_coefficients, random_dictionary, synthetic_tasks, task_rewards
from .task_environments import feature_rewards
from .task_features import TaskFeatures
from .trajectories import demonstrations_from_trajectories

__version__ = "0.1.0"

#: Public names of the optional BabyAI/MiniGrid adapter, loaded on first access (PEP 562) so
#: that ``import factirl_opt`` does not import minigrid; loading :mod:`factirl_opt.minigrid`
#: imports minigrid when it is installed, which registers its environments with gymnasium.
_MINIGRID_NAMES = (
    "from_minigrid", "MiniGridModel", "minigrid_feature_names", "parse_goto_mission",
    "bot_demonstration", "BotDemonstration", "run_policy", "PolicyRun",
)


def __getattr__(name):
    if name in _MINIGRID_NAMES:
        import importlib

        value = getattr(importlib.import_module(".minigrid", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_MINIGRID_NAMES))

__all__ = [
    "TabularMDP",
    "GridWorld",
    "optimal_q",
    "available_planners",
    "policy_evaluation",
    "value_iteration",
    "boltzmann_policy",
    "sample_demonstrations",
    "empirical_statistics",
    "demonstrations_from_trajectories",
    "policy_matching_loss",
    "mce_loss",
    "available_objectives",
    "policy_matching_grad_reference",
    "residual_jacobian",
    "GradIRL",
    "FactIRL",
    "SolverSettings",
    "pca_dictionary",
    "fit_factorial",
    "transfer_coefficients",
    "score",
    "optimal_score",
    "deviation",
    "soft_deviation",
    "feature_rewards",
    "random_dictionary",
    "random_coefficients",
    "task_rewards",
    "synthetic_tasks",
    "SyntheticTasks",
    "from_gymnasium",
    "gymnasium_rewards",
    "estimate_mdp",
    "MultiIntentIRL",
    "adjusted_rand_index",
    "match_intentions",
    "transition_log_likelihood",
    "transition_counts",
    "as_transitions",
    "sample_transitions",
    "read_minari",
    "LoggedEpisodes",
    *_MINIGRID_NAMES,
    "save_model",
    "load_model",
    "save_demonstrations",
    "load_demonstrations",
    "ObjectWorld",
    "make_objectworld",
    "objectworld_transitions",
    "objectworld_distances",
    "objectworld_features",
    "levine_reward",
    "multitask_primitives",
    "multitask_rewards",
    "state_action_rewards",
    "plot_objectworld",
    "ObjectWorldMaps",
    "objectworld_maps",
    "fresh_maps",
    "block_cells",
    "MultiEnvironmentObjective",
    "multi_environment_objective",
    "from_successors",
    "to_successors",
    "TaskFeatures",
    "FactIRLError",
    "ConvergenceWarning",
    "InterruptedFitWarning",
    "FitInterrupted",
    "ValidationError",
    "NotFittedError",
    "SolverError",
    "UnknownSolverError",
    "PersistenceError",
    "MissingDependencyError",
    "MissingSolverBackendError",
    "SolverOptionError",
    "WorkersLost",
]
