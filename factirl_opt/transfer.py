"""Transfer: the coefficients of new tasks with a learnt dictionary fixed (paper section 4.2).

With ``D`` fixed, each new task's reward is ``R_i = Phi D h_i`` and only ``h_i`` (k numbers)
is fitted: a row-separable problem over the coefficients, the H-step of the factorial scheme
run to convergence from ``h = 0`` (docs/maths.md §8). :func:`transfer_coefficients` validates
and builds the objective; :func:`run_transfer` runs on pieces already built (``FactIRL.transfer``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

import solvers

from ._progress import fit_progress
from ._threads import blas_limited
from ._validation import check_features, check_int, check_mdp, check_tol
from .exceptions import translate_solver_errors
from .fitting import first_step_stall, held_by_constraint, make_objective, resolve_step_solver, reward_features
from .interruption import INTERRUPTED, FitInterrupted, run_keeping_best
from .problems import linear_rewards, weights_problem

__all__ = ["transfer_coefficients", "run_transfer", "TransferFit"]


@dataclasses.dataclass
class TransferFit:
    """Result of :func:`transfer_coefficients`.

    Attributes
    ----------
    coefficients : ndarray, shape (n_new, k)
    rewards : ndarray, shape (n_new, S, A)
    loss : ndarray, shape (n_new,)
        Per-task objective, without a solver's penalty.
    loss_history : list of float
        Total objective (with the penalty) at the start and after each step.
    n_iter, n_evaluations : int
    status : str
        ``"converged"``, ``"max_iter"``, ``"stalled"`` or ``"interrupted"`` (a KeyboardInterrupt:
        each task's best coefficients seen until then; loss NaN for a task never evaluated).
    reason : str
        Why the run stopped, with the values that met the rule.
    """

    coefficients: np.ndarray
    rewards: np.ndarray
    loss: np.ndarray
    loss_history: list
    n_iter: int
    n_evaluations: int
    status: str
    reason: str = ""


@blas_limited
def transfer_coefficients(mdp: Any, demos_per_task: Any, dictionary: ArrayLike, *, beta: float = 5.0,
                          base_features: ArrayLike | None = None, h_solver: Any = "armijo",
                          h_solver_options: dict | None = None, max_iter: int = 100, tol: float = 1e-5,
                          objective: Any = "policy-matching", planner: str = "auto", callback: Callable | None = None,
                          verbose: bool = False, reward: str = "state-action") -> TransferFit:
    """Coefficients of new tasks with the dictionary fixed (section 4.2).

    Starts from ``h = 0`` (projected onto the solver's feasible set) and runs the H-solver for
    up to ``max_iter`` steps. Parameters as in :func:`factirl_opt.fit_factorial`;
    ``dictionary`` is (p, k).

    Returns
    -------
    TransferFit

    Raises
    ------
    FitInterrupted
        A KeyboardInterrupt during the run; its ``result`` is the :class:`TransferFit` of each
        task's best coefficients seen (status ``"interrupted"``).
    """
    check_mdp(mdp)
    Phi = reward_features(mdp, base_features, reward)
    D = check_features(dictionary, mdp.n_params if Phi is None else Phi.shape[1], name="dictionary")
    max_iter, tol = check_int(max_iter, "max_iter", minimum=0), check_tol(tol)
    obj = make_objective(mdp, demos_per_task, beta, objective, planner)
    solver = resolve_step_solver(h_solver, h_solver_options, objective, "h_solver")
    return run_transfer(obj, D, solver, base_features=Phi, max_iter=max_iter, tol=tol, callback=callback, verbose=verbose)


def run_transfer(objective: Any, dictionary: NDArray[np.float64], solver: solvers.StepSolver, *,
                 base_features: Any = None, max_iter: int = 100, tol: float = 1e-5, callback: Callable | None = None,
                 verbose: bool = False) -> TransferFit:
    """:func:`transfer_coefficients` on pieces already built and validated.

    Parameters
    ----------
    objective : Objective
        Bound to the new tasks' statistics.
    dictionary : ndarray, shape (p, k)
    solver : solvers.StepSolver
        Resolved and checked.
    base_features : ndarray, shape (S*A, p), or StateBroadcast, optional
    max_iter, tol, callback, verbose
        As in :func:`transfer_coefficients`.

    Returns
    -------
    TransferFit
    """
    mdp = objective.mdp
    F = dictionary if base_features is None else base_features @ dictionary
    names = ("dictionary" if base_features is None else "features @ dictionary", "coefficients")
    problem = weights_problem(objective, F, names)
    ev0 = objective.n_evaluations
    x0 = solver.project(np.zeros((problem.n_rows, problem.n_params)))
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "transfer") as report:
        try:
            res = run_keeping_best(solver, problem, x0, max_iter, "transfer", callback=report, tol=tol)
        except FitInterrupted as exc:
            raise FitInterrupted(_transfer_fit(mdp, F, solver, exc.result, objective.n_evaluations - ev0, names),
                                 "transfer") from exc.__cause__
    return _transfer_fit(mdp, F, solver, res, objective.n_evaluations - ev0, names)


def _transfer_fit(mdp, F, solver, res, n_evaluations, names):
    rewards = linear_rewards(F, res.coefficients, mdp.n_states, mdp.n_actions, names)
    loss = res.loss - solver.penalty(res.coefficients)
    status, reason = res.status, res.reason
    if status != INTERRUPTED:
        status, reason = first_step_stall(res.loss_history, res.iterations, held_by_constraint(solver, res)) or (status, reason)
    return TransferFit(res.coefficients, rewards, loss, res.loss_history, res.iterations, int(n_evaluations), status,
                       reason)
