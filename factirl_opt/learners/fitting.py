"""What the learners share around a fit: the objective and solvers they build, and how a fit ends.

One home for each piece the flat and the factorial learners both use:

- :func:`learner_tasks`: the task set a public ``fit`` builds once (what runs below takes it, or rows of it);
- :func:`make_objective`: demonstrations parsed into the statistics of eq. (5), bound to an objective (§5-6);
- :func:`resolve_step_solver`: a step solver by name or instance, refused before any work when
  it cannot apply to the objective (:func:`check_solver_applies`);
- :func:`first_step_stall`: the rule that calls a fit "stalled" when its first iteration left
  the total loss unchanged, and :func:`warn_if_stalled`, its warning;
- :func:`features_digest`: a SHA-256 of the base features a model was fitted with, checked
  before the features are used again (``FactIRL.transfer``);
- :func:`task_objective`: the objective of a :class:`~factirl_opt.tasks.task_set.TaskSet`'s statistics (one
  MDP, or a :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective` over
  several; docs/maths.md §7-8).
"""

from __future__ import annotations

import warnings
from typing import Any, Callable, TypeVar

import numpy as np

import solvers

from .._threads import blas_limited
from .._validation import check_beta
from ..tasks.demonstrations import empirical_statistics
from ..exceptions import ConvergenceWarning, MaxIterWarning, ValidationError, translate_solver_errors
from ..objectives import Objective, get_objective
from ..objectives.environments import MultiEnvironmentObjective
from ..planning.cache import isolated_planning
from ..tasks.task_set import TaskSet, features_digest, refuse_features_digest, task_set

__all__ = [
    "make_objective",
    "statistics_objective",
    "check_solver_applies",
    "resolve_step_solver",
    "first_step_stall",
    "same_loss",
    "held_by_constraint",
    "warn_if_stalled",
    "warn_if_max_iter",
    "check_features_digest",
    "task_objective",
    "learner_tasks",
    "learner_entry",
    "GTOL",
]

F = TypeVar("F", bound=Callable[..., Any])


def learner_entry(fn: F) -> F:
    """Decorator of the learners' entry points (``fit``, ``transfer``, ``fit_factorial``,
    ``transfer_coefficients``, ``transfer_posterior_``, ``request_starts``): BLAS threads limited
    (:func:`factirl_opt._threads.blas_limited`) and planning caches of the call's own (:func:`factirl_opt.planning.cache.isolated_planning`:
    the result does not depend on what the thread planned before)."""
    return isolated_planning(blas_limited(fn))


#: a first step that moves the total loss by at most this many units of ``eps |loss|`` changed nothing
STALL_ULPS = 4

#: default ``gtol`` of the learners' fits and transfers: a run (in a separable run, a task) stops when
#: its gradient norm is at most ``GTOL`` times its value at the start (:func:`solvers.gradient_converged`).
#: The rule that stops a task whose demonstrations are matched exactly, where the loss falls toward 0
#: as the rewards grow without bound and the relative decrease of its loss never becomes small
#: (docs/maths.md §5).
GTOL = 1e-4


def make_objective(mdp: Any, demos_per_task: Any, beta: float,
                   objective: str | type[Objective] = "policy-matching", planner: str = "auto") -> Objective:
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
    return statistics_objective(mdp, mu, pi_hat, beta, objective, planner)


def statistics_objective(mdp: Any, mu_hat: Any, pi_hat: Any, beta: float, objective: Any = "policy-matching",
                         planner: Any = "auto") -> Objective:
    """The named objective bound to given statistics of tasks on one MDP (eq. 5).

    :func:`make_objective` binds those of demonstrations; the EM M-step binds the intentions'
    weighted statistics (:func:`factirl_opt.learners.em.weighted_statistics`).

    Parameters
    ----------
    mdp : TabularMDP
    mu_hat : ndarray, shape (n, S)
    pi_hat : ndarray, shape (n, S, A)
    beta : float
    objective : str or Objective subclass
    planner : str
    """
    return get_objective(objective)(mdp, mu_hat, pi_hat, check_beta(beta), planner=planner)


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


def check_features_digest(expected: str | None, features: Any, what: str) -> None:
    """Refuse features other than those a model was fitted with (digest ``expected``).

    Raises
    ------
    ValidationError
        When the digest of ``features`` differs from ``expected`` (other values of the same
        shape, features where the fit had none, or none where it had some).
    """
    actual = features_digest(features)
    if actual != expected:
        refuse_features_digest(expected, actual, np.shape(features), what)


def learner_tasks(learner: Any, mdp: Any, demos_per_task: Any, parsed: Any = None) -> TaskSet:
    """The task set a public ``fit`` builds once: :func:`~factirl_opt.tasks.task_set.task_set` with its ``features``, ``reward``."""
    return task_set(mdp, demos_per_task, learner.features, learner.reward, parsed=parsed)


def task_objective(tasks: TaskSet, beta: float, objective: Any = "policy-matching",
                   planner: Any = "auto") -> Objective | MultiEnvironmentObjective:
    """The named objective bound to the empirical statistics of a task set's demonstrations
    (``tasks.mu_hat``, ``tasks.pi_hat``, of the demonstrations it parsed once).

    One environment: :func:`statistics_objective` on its MDP. Several: a
    :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective` (one objective per
    distinct MDP, docs/maths.md §7), whose errors name the task.

    Parameters
    ----------
    tasks : TaskSet
        From :func:`~factirl_opt.tasks.task_set.task_set`.
    beta, objective, planner
        As in :func:`make_objective`.
    """
    if tasks.mdp is not None:
        return statistics_objective(tasks.mdp, tasks.mu_hat, tasks.pi_hat, beta, objective, planner)
    return MultiEnvironmentObjective(tasks.mdps or [], tasks.mu_hat, tasks.pi_hat, beta, objective, planner)
