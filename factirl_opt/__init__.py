"""factirl-opt: multi-task inverse reinforcement learning (Mangin & Oudeyer 2014).

The data path: MDP + demonstrations -> empirical statistics -> eq. (5) loss and its adjoint
gradient -> a registered step solver -> learnt rewards -> eq. (13) score.
"""

from .demonstrations import empirical_statistics, sample_demonstrations
from .evaluation import deviation, optimal_score, score
from .exceptions import (
    FactIRLError,
    MissingDependencyError,
    NotFittedError,
    PersistenceError,
    SolverError,
    UnknownSolverError,
    ValidationError,
)
from .factirl import FactIRL, pca_dictionary
from .gradirl import GradIRL
from .gym_adapter import from_gymnasium, gymnasium_rewards
from .mdp import GridWorld, TabularMDP
from .objective import policy_matching_grad_reference, policy_matching_loss, residual_jacobian
from .persistence import load_demonstrations, load_model, save_demonstrations, save_model
from .planning import boltzmann_policy, optimal_q, policy_evaluation, value_iteration
from .synthetic import SyntheticTasks, random_coefficients, random_dictionary, synthetic_tasks, task_rewards

__version__ = "0.1.0"

__all__ = [
    "TabularMDP",
    "GridWorld",
    "optimal_q",
    "policy_evaluation",
    "value_iteration",
    "boltzmann_policy",
    "sample_demonstrations",
    "empirical_statistics",
    "policy_matching_loss",
    "policy_matching_grad_reference",
    "residual_jacobian",
    "GradIRL",
    "FactIRL",
    "pca_dictionary",
    "score",
    "optimal_score",
    "deviation",
    "random_dictionary",
    "random_coefficients",
    "task_rewards",
    "synthetic_tasks",
    "SyntheticTasks",
    "from_gymnasium",
    "gymnasium_rewards",
    "save_model",
    "load_model",
    "save_demonstrations",
    "load_demonstrations",
    "FactIRLError",
    "ValidationError",
    "NotFittedError",
    "SolverError",
    "UnknownSolverError",
    "PersistenceError",
    "MissingDependencyError",
]
