"""What the learners share around a fit: the objective and solvers they build, and how a fit ends.

One home for each piece the flat and the factorial learners both use:

- :func:`make_objective`: the one place where demonstrations are parsed into the empirical
  statistics of eq. (5) and bound to a registered objective (docs/maths.md §5-6);
- :func:`resolve_step_solver`: a step solver by name or instance, refused before any work when
  it cannot apply to the objective (:func:`check_solver_applies`);
- :func:`first_step_stall`: the rule that calls a fit "stalled" when its first iteration left
  the total loss unchanged, and :func:`warn_if_stalled`, its warning;
- :func:`features_digest`: a SHA-256 of the base features a model was fitted with, checked
  before the features are used again (``FactIRL.transfer``).
"""

from __future__ import annotations

import hashlib
import warnings
from typing import Any

import numpy as np

import solvers

from ._validation import check_beta, check_features
from .demonstrations import empirical_statistics
from .exceptions import ConvergenceWarning, ValidationError, translate_solver_errors
from .objectives import Objective, get_objective
from .problems import StateBroadcast

__all__ = [
    "make_objective",
    "check_solver_applies",
    "resolve_step_solver",
    "first_step_stall",
    "held_by_constraint",
    "warn_if_stalled",
    "features_digest",
    "check_features_digest",
    "REWARDS",
    "reward_features",
]

#: what a learner's reward depends on: ``"state-action"`` R(s, a), or ``"state"`` r(s) broadcast over actions
REWARDS = ("state-action", "state")


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
    """``("stalled", reason)`` when the first iteration of a fit left its total loss unchanged.

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
    if iterations == 1 and len(history) >= 2 and history[1] == history[0] and not held:
        return "stalled", f"stalled: the first iteration changed nothing (total loss {history[0]:.6g} before and after)"
    return None


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
