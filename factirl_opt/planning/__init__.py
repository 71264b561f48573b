"""The planning engine: the one place that solves Bellman systems (docs/maths.md §2-§4).

Planners (``planner=`` by name everywhere; :func:`available_planners`,
:func:`register_planner`, :func:`unregister_planner`):

``"dense"``
    Batched dense LU (``numpy.linalg.solve`` on (n, S, S) systems, built in chunks of tasks
    that fit in 256 MiB), Howard's policy iteration from the immediate-reward greedy policy.
    Best for small S; refuses sparse models whose dense copy would not fit
    (:mod:`~factirl_opt.planning.dense`).
``"sparse-lu"``
    One sparse LU (SuperLU) per policy with diagonal pivots in a fixed fill-reducing order,
    reused for the policy's values, the transposed (adjoint) solve and the Jacobian's
    right-hand sides, cached between calls (per thread), and updated by a verified low-rank
    correction for a policy that differs in a few states; Bellman backups are one sparse x
    dense product for all tasks; policy iteration is modified by value-iteration sweeps
    between exact evaluations (:mod:`~factirl_opt.planning.sparse_lu`,
    :mod:`~factirl_opt.planning.lowrank`, :mod:`~factirl_opt.planning.cache`).
``"auto"`` (default)
    ``"dense"`` up to :data:`AUTO_DENSE_MAX_STATES` states, ``"sparse-lu"`` above: the
    crossover measured on GridWorld with 100 tasks (``python -m factirl_opt.lab.bench scale``), so
    the paper's 10x10 grid keeps the dense arithmetic.

Memory. A planning budget (an objective's ``planner_options={"max_bytes": ...}``, or the
:func:`planning_budget` context manager) makes objectives plan, solve and release their tasks
chunk by chunk instead of keeping every task's factorisations (:mod:`~factirl_opt.planning.budget`).

Modules: :mod:`~factirl_opt.planning.engine` (policy iteration, policy values, adjoint and
tangent), :mod:`~factirl_opt.planning.successor_features` (successor features of fixed policies
and generalised policy improvement), :mod:`~factirl_opt.planning.base` (the planner interface),
:mod:`~factirl_opt.planning.registry`, one module per planner, the low-rank updates, the caches
(owner and lifetime documented there) and the glibc allocator tuning
(:mod:`~factirl_opt.planning.allocator`, process-wide).

Threads, pickling, mutation. Models are immutable, so a cached planner never goes stale; the
planners of an MDP live in a lock-protected weak mapping owned by
:mod:`~factirl_opt.planning.cache` (not on the MDP, which pickles without them), and the sparse
planner keeps its factorisations per thread, so concurrent calls give exactly the results of
sequential ones.
"""

from .base import Planner, PolicySystem
from .budget import get_planning_budget, planning_budget
from .counting import CountingPlanner
from .cache import CACHE_GROUPS_PER_TASK, FACTOR_CACHE_BYTES, FactorCache, clear_caches
from .dense import DENSE_CHUNK_BYTES, DensePlanner
from .engine import PlanResult, adjoint, boltzmann_policy, optimal_q, plan, policy_evaluation, tangent, value_iteration
from .lowrank import RESIDUAL_TOL, UPDATE_MAX_RANK, UpdatedFactor
from .registry import (
    AUTO_DENSE_MAX_STATES,
    available_planners,
    get_planner,
    register_planner,
    resolve_planner,
    unregister_planner,
)
from .sparse_lu import SparseLUPlanner, TaskFactor
from .successor_features import successor_features

__all__ = [
    "CountingPlanner",
    "available_planners",
    "get_planner",
    "register_planner",
    "unregister_planner",
    "resolve_planner",
    "clear_caches",
    "planning_budget",
    "get_planning_budget",
    "optimal_q",
    "policy_evaluation",
    "boltzmann_policy",
    "value_iteration",
    "PlanResult",
    "plan",
    "adjoint",
    "tangent",
    "successor_features",
    "Planner",
    "PolicySystem",
    "DensePlanner",
    "SparseLUPlanner",
    "TaskFactor",
    "UpdatedFactor",
    "FactorCache",
    "AUTO_DENSE_MAX_STATES",
    "DENSE_CHUNK_BYTES",
    "FACTOR_CACHE_BYTES",
    "CACHE_GROUPS_PER_TASK",
    "UPDATE_MAX_RANK",
    "RESIDUAL_TOL",
]
