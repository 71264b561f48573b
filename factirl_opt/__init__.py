"""factirl-opt: multi-task inverse reinforcement learning (Mangin & Oudeyer 2014).

The data path: MDP + demonstrations -> empirical statistics -> eq. (5) loss and its adjoint
gradient -> a registered step solver -> learnt rewards -> eq. (13) score.

The package is cut into layers, each a subpackage; imports point down only (a test checks it):

====================  =========================================================================
``exceptions`` ...    the base: exceptions, interruption, validation, BLAS threads, atomic files
``mdp``               tabular MDPs, successor lists, models estimated from logs, per-task environments
``planning``          the engine that solves Bellman systems (the only one)
``parallel``          task shards served by processes or a Dask cluster
``tasks``             demonstrations, trajectories, reward features
``objectives``        rewards -> loss and dJ/dR (policy matching, MCE), and the step problems
``evaluation``        scores of learnt rewards (eq. 13)
``learners``          GradIRL, FactIRL, MultiIntentIRL and their fitting schemes
``adapters``          Gymnasium, MiniGrid/BabyAI, Minari
``datasets``          synthetic tasks, Objectworld and its maps, BabyAI tasks
``persistence``       saving and loading models and demonstrations
``lab``               the experiment harness and command line, above the library (not imported here)
====================  =========================================================================

The top level holds the core; worlds, adapters and the other exceptions are in namespaces:
``fo.objectworld``, ``fo.minigrid``, ``fo.adapters``, ``fo.datasets``, ``fo.exceptions``,
``fo.mdp``, ``fo.tasks``, ``fo.objectives``. Their former top-level names still work for one
release, with a :class:`FutureWarning` (once per name); so do the former module paths
(``factirl_opt.gradirl`` and the like).

Internal modules (not public API; any module of the package may import their names):
``_validation`` (every boundary check), ``_threads`` (BLAS thread limits), ``_progress``
(progress bars and callbacks of long fits), ``_deprecation`` (the aliases above).
"""

from . import exceptions
from ._deprecation import install_module_aliases, moved_attribute
from .datasets.synthetic import SyntheticTasks, random_coefficients, random_dictionary, synthetic_tasks
from .evaluation import deviation, optimal_score, score, soft_deviation
from .exceptions import FactIRLError
from .learners import (
    Execution,
    FactIRL,
    IntentionStart,
    PosteriorSettings,
    DictionaryConstraint,
    Start,
    GradIRL,
    MultiIntentIRL,
    PAPER_SETTINGS,
    SharingSearch,
    SolverSettings,
    adjusted_rand_index,
    fit_factorial,
    match_intentions,
    pca_dictionary,
    transfer_coefficients,
)
from .mdp import GridWorld, TabularMDP, estimate_mdp
from .objectives import available_objectives, mce_loss, policy_matching_loss
from .persistence import load_demonstrations, load_model, save_demonstrations, save_model
from .planning import available_planners, boltzmann_policy, optimal_q, policy_evaluation, value_iteration
from .tasks import demonstrations_from_trajectories, empirical_statistics, feature_rewards, sample_demonstrations, task_rewards

from ._version import __version__

__all__ = [
    # models
    "TabularMDP",
    "GridWorld",
    "estimate_mdp",
    # planning
    "optimal_q",
    "available_planners",
    "policy_evaluation",
    "value_iteration",
    "boltzmann_policy",
    # demonstrations and rewards
    "sample_demonstrations",
    "empirical_statistics",
    "demonstrations_from_trajectories",
    "task_rewards",
    "feature_rewards",
    "random_dictionary",
    "random_coefficients",
    "synthetic_tasks",
    "SyntheticTasks",
    # objectives
    "policy_matching_loss",
    "mce_loss",
    "available_objectives",
    # estimators
    "GradIRL",
    "FactIRL",
    "PAPER_SETTINGS",
    "MultiIntentIRL",
    "SolverSettings",
    "Execution",
    "Start",
    "PosteriorSettings",
    "DictionaryConstraint",
    "IntentionStart",
    "SharingSearch",
    "pca_dictionary",
    "fit_factorial",
    "transfer_coefficients",
    # scores
    "score",
    "optimal_score",
    "deviation",
    "soft_deviation",
    "adjusted_rand_index",
    "match_intentions",
    # persistence
    "save_model",
    "load_model",
    "save_demonstrations",
    "load_demonstrations",
    # the base exception
    "FactIRLError",
]

#: namespaces reachable as attributes of the package, loaded on first access
_NAMESPACES = {
    "objectworld": "factirl_opt.datasets.objectworld",
    "minigrid": "factirl_opt.adapters.minigrid",
    "adapters": "factirl_opt.adapters",
    "datasets": "factirl_opt.datasets",
    "validation": "factirl_opt.validation",
}

#: former top-level names -> (module that holds them now, the namespace to use)
_MOVED_NAMES = {
    **{name: ("factirl_opt.datasets.objectworld", "fo.objectworld") for name in (
        "ObjectWorld", "make_objectworld", "objectworld_transitions", "objectworld_distances", "objectworld_features",
        "levine_reward", "multitask_primitives", "multitask_rewards", "state_action_rewards", "plot_objectworld",
        "ObjectWorldMaps", "objectworld_maps", "fresh_maps", "block_cells")},
    **{name: ("factirl_opt.adapters.minigrid", "fo.minigrid") for name in (
        "from_minigrid", "MiniGridModel", "minigrid_feature_names", "parse_goto_mission", "bot_demonstration",
        "BotDemonstration", "run_policy", "PolicyRun")},
    **{name: ("factirl_opt.adapters", "fo.adapters") for name in (
        "from_gymnasium", "gymnasium_rewards", "read_minari", "LoggedEpisodes")},
    **{name: ("factirl_opt.exceptions", "fo.exceptions") for name in (
        "ConvergenceWarning", "InterruptedFitWarning", "FitInterrupted", "ValidationError", "NotFittedError",
        "SolverError", "UnknownSolverError", "PersistenceError", "MissingDependencyError",
        "MissingSolverBackendError", "SolverOptionError", "WorkersLost")},
    **{name: ("factirl_opt.mdp", "fo.mdp") for name in (
        "from_successors", "to_successors", "transition_log_likelihood", "transition_counts", "as_transitions",
        "sample_transitions")},
    **{name: ("factirl_opt.objectives", "fo.objectives") for name in (
        "policy_matching_grad_reference", "residual_jacobian")},
    **{name: ("factirl_opt.objectives.environments", "fo.objectives.environments") for name in (
        "MultiEnvironmentObjective", "multi_environment_objective")},
    "TaskFeatures": ("factirl_opt.tasks", "fo.tasks"),
}

#: former top-level names that were renamed too -> their name now (resolved directly, not through the
#: namespace's own deprecated alias: one warning, naming the current name)
_RENAMED_NAMES = {"MissingSolverBackendError": "MissingSolverDependencyError"}

#: former module paths -> where the module is now
_MOVED_MODULES = {
    "successors": "mdp.successors", "model_estimation": "mdp.estimation",
    "task_environments": "mdp.environments", "task_features": "tasks.features", "demonstrations": "tasks.demonstrations",
    "trajectories": "tasks.trajectories", "problems": "objectives.problems", "solver_settings": "learners.solver_settings",
    "fitting": "learners.fitting", "gradirl": "learners.gradirl", "factirl": "learners.factirl",
    "factorial": "learners.factorial", "transfer": "learners.transfer", "dictionary": "learners.dictionary",
    "em": "learners.em", "intention_count": "learners.intention_count", "multi_intent": "learners.multi_intent",
    "multi_intent_fit": "learners.multi_intent_fit", "gym_adapter": "adapters.gymnasium",
    "minari_adapter": "adapters.minari", "minigrid": "adapters.minigrid", "synthetic": "datasets.synthetic",
    "objectworld": "datasets.objectworld", "objectworld_maps": "datasets.objectworld.maps",
    "experiments": "lab.experiments", "benchmarks": "lab.benchmarks", "cli": "lab.cli", "bench": "lab.bench",
    "learners.adaptive": "learners.selection.search", "learners.evidence": "learners.selection.evidence",
}

#: names a former module path held that now live in another module (former path -> name -> module
#: now), as they were at the move; names removed since are not here (tests/test_deprecation.py lists them)
_MOVED_MODULE_NAMES = {
    "successors": {name: "mdp.tabular" for name in ("from_successors", "to_successors")},
    "gradirl": {"weights_rewards": "tasks.features"},
    "factorial": {"factorial_rewards": "tasks.features"},
    "problems": {name: "tasks.features" for name in (
        "FEATURE_SCALE_LIMIT", "linear_rewards", "dense_features", "StateBroadcast")},
    "task_environments": {"feature_rewards": "tasks.features"},
    "fitting": {name: "tasks.task_set" for name in (
        "REWARDS", "reward_features", "reward_dimension", "per_task_features", "one_environment",
        "environment_signatures")},
    "experiments.babyai": {
        **{name: "datasets.babyai" for name in (
            "N_STREAMS", "SEED_RANGE", "SPLITS", "mission_rewards", "random_success_probability")},
        **{name: "lab.experiments.worlds" for name in ("babyai_world", "babyai_large_world")}},
    "learners.adaptive": {
        **{name: "learners.selection.results" for name in (
            "CV_RESULTS_KEYS", "ROW_KEYS", "check_cv_results", "cv_results", "plot_validation", "rows_cv_results",
            "validation_rows")},
        **{name: "learners.selection.scores" for name in ("held_out_nll", "held_out_occupancy_gap")},
        **{name: "learners.selection.folds" for name in ("task_mdp", "task_subset", "take_tasks")},
        **{name: "learners.selection.rules" for name in ("choose_row", "DEFAULT_RULE")},
        "sharing_candidates": "learners.selection.routes"},
}
install_module_aliases(__name__, _MOVED_MODULES, _MOVED_MODULE_NAMES)


def __getattr__(name: str) -> object:
    if name in _NAMESPACES:
        import importlib

        module = importlib.import_module(_NAMESPACES[name])
        globals()[name] = module
        return module
    if name in _MOVED_NAMES:
        return moved_attribute(name, *_MOVED_NAMES[name], _RENAMED_NAMES.get(name))
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_NAMESPACES) | set(_MOVED_NAMES))
