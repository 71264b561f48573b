"""What the learners share around a fit: the objective and solvers they build, and how a fit ends.

One home for each piece the flat and the factorial learners both use:

- :func:`make_objective`: the one place where demonstrations are parsed into the empirical
  statistics of eq. (5) and bound to a registered objective (docs/maths.md §5-6);
- :func:`resolve_step_solver`: a step solver by name or instance, refused before any work when
  it cannot apply to the objective (:func:`check_solver_applies`);
- :func:`first_step_stall`: the rule that calls a fit "stalled" when its first iteration left
  the total loss unchanged, and :func:`warn_if_stalled`, its warning;
- :func:`features_digest`: a SHA-256 of the base features a model was fitted with, checked
  before the features are used again (``FactIRL.transfer``);
- :func:`one_environment` and :func:`environments_setup`: tasks in several environments (a
  sequence of MDPs, or one feature matrix per task), bound to one
  :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective` and their
  :class:`~factirl_opt.tasks.features.TaskFeatures` (docs/maths.md §7-8).
"""

from __future__ import annotations

import dataclasses
import hashlib
import warnings
from collections.abc import Sequence
from typing import Any, Callable, TypeVar

import numpy as np

import solvers

from .._threads import blas_limited
from .._validation import check_beta, check_features
from ..tasks.demonstrations import empirical_statistics
from ..exceptions import ConvergenceWarning, MaxIterWarning, ValidationError, translate_solver_errors
from ..mdp.tabular import TabularMDP
from ..objectives import Objective, get_objective
from ..objectives.environments import MultiEnvironmentObjective, multi_environment_objective
from ..mdp.environments import check_environments
from ..planning.cache import isolated_planning
from ..tasks.features import StateBroadcast, TaskFeatures

__all__ = [
    "make_objective",
    "check_solver_applies",
    "resolve_step_solver",
    "first_step_stall",
    "same_loss",
    "held_by_constraint",
    "warn_if_stalled",
    "warn_if_max_iter",
    "features_digest",
    "check_features_digest",
    "REWARDS",
    "reward_features",
    "reward_dimension",
    "per_task_features",
    "one_environment",
    "Environments",
    "environments_setup",
    "environment_signatures",
    "learner_entry",
]

F = TypeVar("F", bound=Callable[..., Any])


def learner_entry(fn: F) -> F:
    """Decorator of the learners' entry points (``fit``, ``transfer``, ``fit_factorial``,
    ``transfer_coefficients``): BLAS threads limited (:func:`factirl_opt._threads.blas_limited`)
    and planning caches of the call's own (:func:`factirl_opt.planning.cache.isolated_planning`:
    the result does not depend on what the thread planned before)."""
    return isolated_planning(blas_limited(fn))


#: what a learner's reward depends on: ``"state-action"`` R(s, a), or ``"state"`` r(s) broadcast over actions
REWARDS = ("state-action", "state")

#: a first step that moves the total loss by at most this many units of ``eps |loss|`` changed nothing
STALL_ULPS = 4


def reward_features(mdp: Any, features: Any = None, reward: str = "state-action",
                    min_columns: int = 1) -> np.ndarray | StateBroadcast | None:
    """What a learner's rewards are linear in: ``R_i = Phi theta_i`` (docs/maths.md §7).

    Parameters
    ----------
    mdp : TabularMDP
    features : array_like, shape (S*A, p) or (S, p), optional
    reward : {"state-action", "state"}
        ``"state"``: one reward per state, repeated over the actions (p = S), at the cost of
        tabular rewards; only without ``features``.
    min_columns : int
        Smallest accepted number of features.

    Returns
    -------
    None, StateBroadcast or ndarray of shape (S*A, p)
        None for tabular rewards (p = S*A); ``kron(I_S, 1_A)`` unformed for ``reward="state"``;
        else the validated features (state features repeated over the actions).
    """
    if not isinstance(reward, str) or reward not in REWARDS:
        raise ValidationError(f"reward must be one of {', '.join(map(repr, REWARDS))}; got {reward!r}")
    if reward == "state":
        if features is not None:
            raise ValidationError(
                f"reward='state' learns one free reward per state and takes no features (got features of shape "
                f"{np.shape(features)}); for rewards of the states on features pass state features (S, p) with "
                "reward='state-action'")
        return StateBroadcast(mdp.n_states, mdp.n_actions)
    if features is None:
        return None
    return check_features(features, mdp.n_params, mdp.n_states, min_columns=min_columns)


def make_objective(mdp: Any, demos_per_task: Any, beta: float, objective: str = "policy-matching",
                   planner: str = "auto") -> Objective:
    """The named objective bound to the empirical statistics of ``demos_per_task``.

    Parameters
    ----------
    mdp : TabularMDP
    demos_per_task : list of n task demonstrations
        Parsed here, once (:func:`factirl_opt.empirical_statistics`).
    beta : float
        Boltzmann inverse temperature (eq. 7).
    objective : str or Objective subclass
        See ``factirl_opt.available_objectives()``.
    planner : str

    Returns
    -------
    Objective
        Over the n tasks (``objective.n_tasks``).
    """
    mu, pi_hat = empirical_statistics(mdp, demos_per_task)
    return get_objective(objective)(mdp, mu, pi_hat, check_beta(beta), planner=planner)


def least_squares_only(solver: solvers.StepSolver) -> bool:
    """Whether ``solver`` needs residuals (a Gauss-Newton solver)."""
    return bool(solver.needs_jacobian or solver.needs_linearization)


def check_solver_applies(solver: solvers.StepSolver, objective: Any, what: str) -> solvers.StepSolver:
    """Refuse, before any work, a least-squares solver on an objective without residuals.

    The Gauss-Newton solvers (``gn-qp-*``, ``gn-cg``) need residuals (policy matching has them);
    a likelihood such as ``"mce"`` does not. The message lists the solvers that apply.
    """
    if least_squares_only(solver) and not get_objective(objective).least_squares:
        usable = [name for name in solvers.available_solvers() if not least_squares_only(solvers.get_solver(name))]
        raise ValidationError(
            f"{what} {solver.name!r} is a Gauss-Newton solver: it needs a least-squares objective (residuals), and the "
            f"{objective!r} objective has none; use a gradient solver: {', '.join(usable)}"
        )
    return solver


def resolve_step_solver(solver: str | solvers.StepSolver, options: dict | None, objective: Any,
                        what: str) -> solvers.StepSolver:
    """The step solver ``solver`` (a name with ``options``, or an instance), checked against the objective.

    Solver errors are raised as the library's exceptions (:func:`translate_solver_errors`).
    """
    with translate_solver_errors():
        return check_solver_applies(solvers.resolve_solver(solver, options), objective, what)


def first_step_stall(history: list, iterations: int, held: bool = False) -> tuple[str, str] | None:
    """``("stalled", reason)`` when the first iteration of a fit left its total loss unchanged
    (up to rounding, :func:`same_loss`).

    Shared by the learners' fits: a first step that changed nothing (no block moved, or every
    accepted step had a zero effect, as with a tiny beta or saturated policies) will not
    change anything later, and it is not convergence, unless the start is held by the
    solver's constraint or penalty (``held``, :func:`held_by_constraint`).

    Parameters
    ----------
    history : list of float
        Total loss at the start and after each iteration.
    iterations : int
        Iterations done.
    held : bool
        The start is optimal for the constrained or penalised problem while the gradient is
        not zero (e.g. ``h = 0`` under a large L1 penalty): the fit has converged.
    """
    if iterations == 1 and len(history) >= 2 and not held and same_loss(history[0], history[1]):
        return "stalled", f"stalled: the first iteration changed nothing (total loss {history[0]:.6g} before and after)"
    return None


def same_loss(before: float, after: float) -> bool:
    """Whether two total losses differ by rounding only: equal, or within ``4 eps |before|``.

    A first step that moves the loss by a few units in the last place (e.g. MCE at a tiny
    beta, where every reward change is rounded away) changed nothing.
    """
    return bool(before == after or abs(after - before) <= STALL_ULPS * np.finfo(float).eps * abs(before))


def held_by_constraint(solver: solvers.StepSolver, result: solvers.SolverResult) -> bool:
    """Whether a run ended at a point its constraint or penalty holds: a zero optimality measure
    (projected gradient or minimum-norm subgradient) with a nonzero gradient."""
    if not result.gradient_norm == 0.0:
        return False
    grad = solver.gradient(result.state)
    return grad is not None and bool(np.any(np.asarray(grad) != 0))


def warn_if_stalled(status: str, iterations: int, what: str) -> None:
    """A :class:`ConvergenceWarning` when a fit stalled before its second step."""
    if status == "stalled" and iterations <= 1:
        warnings.warn(
            f"{what} stalled at its first step: no step decreased the loss. The rewards are probably far "
            "from the scale where the Boltzmann policy is informative (check the scale of the features or of "
            "the initialisation, and beta)",
            ConvergenceWarning,
            stacklevel=3,
        )


def warn_if_max_iter(result: solvers.SolverResult, what: str, max_iter: int) -> None:
    """A :class:`MaxIterWarning` (a :class:`ConvergenceWarning`) naming the tasks of a separable fit
    that stopped at ``max_iter`` (``max_iter > 0``) before their own stopping rule held
    (:mod:`solvers.separable`)."""
    if result.status != "max_iter" or result.row_status is None or max_iter <= 0:
        return
    late = np.flatnonzero(np.asarray(result.row_status) == "max_iter")
    if late.size == 0:
        return
    shown = ", ".join(str(int(i)) for i in late[:20]) + (", ..." if late.size > 20 else "")
    warnings.warn(
        f"{what} stopped at max_iter={max_iter} before its tolerance for {late.size} of {len(result.row_status)} "
        f"task(s): [{shown}]; their rewards are not converged (increase max_iter)",
        MaxIterWarning,
        stacklevel=3,
    )


def features_digest(features: np.ndarray | None) -> str | None:
    """SHA-256 (hex) of validated base features (S*A, p) as float64, shape included; None without.

    Two feature matrices have the same digest exactly when they have the same shape and the
    same values bit for bit.
    """
    if features is None:
        return None
    F = np.ascontiguousarray(features, dtype=np.float64)
    h = hashlib.sha256(repr(F.shape).encode())
    h.update(F.tobytes())
    return h.hexdigest()


def check_features_digest(expected: str | None, features: Any, what: str) -> None:
    """Refuse features other than those a model was fitted with (digest ``expected``).

    Raises
    ------
    ValidationError
        When the digest of ``features`` differs from ``expected`` (other values of the same
        shape, features where the fit had none, or none where it had some).
    """
    actual = features_digest(features)
    if actual == expected:
        return
    if expected is None:
        raise ValidationError(f"{what} was fitted without features, but features of shape {np.shape(features)} are set now")
    if actual is None:
        raise ValidationError(f"{what} was fitted with features (sha256 {expected[:12]}...), but features=None now")
    raise ValidationError(
        f"{what} was fitted with other features than the ones set now (shape {np.shape(features)}, sha256 "
        f"{actual[:12]}... instead of {expected[:12]}...): the dictionary only means something on the features it was "
        "learnt with; restore those features or fit again"
    )


def reward_dimension(mdp: Any, features: Any) -> int:
    """p, the number of reward parameters per task: ``S*A`` (tabular), or the features' columns."""
    if isinstance(features, TaskFeatures):
        return features.n_features
    return mdp.n_params if features is None else features.shape[1]


def per_task_features(features: Any) -> bool:
    """Whether ``features`` is one matrix per task (a sequence of 2-d arrays, or a 3-d array)."""
    if isinstance(features, np.ndarray):
        return features.ndim == 3
    return (isinstance(features, Sequence) and not isinstance(features, (str, bytes)) and len(features) > 0
            and np.ndim(features[0]) == 2)


def _n_tasks(demos_per_task: Any) -> int | None:
    try:
        return len(demos_per_task)
    except TypeError:
        return None


def one_environment(mdp: Any, demos_per_task: Any, features: Any) -> Any:
    """The MDP of a fit whose tasks all share one MDP object and one feature matrix (or none), else None.

    That fit runs the one-MDP code path, so ``fit([mdp] * n, ...)`` with the same object is
    ``fit(mdp, ...)`` bit for bit. Anything that is neither a TabularMDP nor a sequence is
    returned as is, for the one-MDP path to refuse.
    """
    if per_task_features(features):
        return None
    if isinstance(mdp, TabularMDP) or not isinstance(mdp, Sequence) or isinstance(mdp, (str, bytes)):
        return mdp
    mdps = check_environments(mdp, _n_tasks(demos_per_task))
    return mdps[0] if all(m is mdps[0] for m in mdps) else None


@dataclasses.dataclass
class Environments:
    """What a fit over tasks in several environments is built on.

    Attributes
    ----------
    mdps : list of n TabularMDP
    features : TaskFeatures
        ``Phi_i`` of every task (one shared matrix is referenced n times, never copied).
    digest : str or None
        :func:`features_digest` of one shared feature matrix; None for per-task features.
    """

    mdps: list
    features: TaskFeatures
    digest: str | None


def _task_features(mdps: list, features: Any, reward: str, min_columns: int) -> tuple[TaskFeatures, str | None]:
    if reward != "state-action":
        raise ValidationError(f"reward={reward!r} learns one free reward per state of one MDP; tasks in several "
                              "environments need features (pass state features (S_i, p) per task instead)")
    if features is None:
        raise ValidationError(
            "tasks in several environments need features (one shared (S*A, p) matrix, or one (S_i*A, p) or (S_i, p) "
            "matrix per task): tabular rewards are defined on one MDP")
    S = [m.n_states for m in mdps]
    if per_task_features(features):
        tf = TaskFeatures(list(features), S, mdps[0].n_actions)
        digest = None
    else:
        F = check_features(features, mdps[0].n_params, mdps[0].n_states, min_columns=min_columns)
        bad = [i for i, s in enumerate(S) if s != S[0]]
        if bad:
            raise ValidationError(f"one shared feature matrix ({np.shape(features)}) cannot fit every environment: task 0 "
                                  f"has S = {S[0]} states, task {bad[0]} has {S[bad[0]]}; give one feature matrix per task")
        tf, digest = TaskFeatures([F] * len(mdps), S, mdps[0].n_actions), features_digest(F)
    if tf.n_features < min_columns:
        raise ValidationError(f"features must have p >= {min_columns} columns; got p = {tf.n_features}")
    return tf, digest


def environments_setup(mdp: Any, demos_per_task: Any, features: Any, reward: str, beta: float,
                       objective: Any = "policy-matching", planner: Any = "auto",
                       min_columns: int = 1) -> tuple[MultiEnvironmentObjective, Environments]:
    """The objective and the features of a fit over tasks in several environments.

    Parameters
    ----------
    mdp : TabularMDP or sequence of n TabularMDP
        One per task (tasks given the same object are planned as one batch).
    demos_per_task : list of n task demonstrations
        Each on its own task's MDP.
    features : array_like or sequence of n array_like
        One (S*A, p) or (S, p) matrix shared by every task (equal-sized environments), or one
        (S_i*A, p) or (S_i, p) matrix per task, with the same p.
    reward : str
        Must be ``"state-action"``.
    beta, objective, planner
        As in :func:`make_objective`.
    min_columns : int
        Smallest accepted p.

    Raises
    ------
    ValidationError
        For a wrong count of MDPs, features or demonstrations, numbers of actions that differ,
        features with another p or that do not fit their task's MDP, no features, or a state
        out of range of its task's MDP (each naming the task).
    """
    n = _n_tasks(demos_per_task)
    if n is None:
        raise ValidationError(f"demos_per_task must be a list with one entry per task; got {type(demos_per_task).__name__}")
    mdps = check_environments(mdp, n)
    tf, digest = _task_features(mdps, features, reward, min_columns)
    obj = multi_environment_objective(mdps, demos_per_task, beta, objective, planner)
    return obj, Environments(mdps, tf, digest)


def environment_signatures(mdps: Sequence[TabularMDP]) -> list[dict]:
    """One :meth:`TabularMDP.signature` per task (computed once per distinct MDP object)."""
    seen: dict[int, dict] = {}
    for m in mdps:
        if id(m) not in seen:
            seen[id(m)] = m.signature()
    return [dict(seen[id(m)]) for m in mdps]
