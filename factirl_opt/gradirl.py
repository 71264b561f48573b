"""GradIRL, the flat learner (Neu & Szepesvari 2007; paper section 3.1)."""

import numpy as np

import solvers

from ._threads import blas_limited
from ._validation import check_beta, check_features, check_int, check_mdp, check_tol
from .demonstrations import empirical_statistics
from .objective import PolicyMatchingObjective
from .problems import weights_problem

__all__ = ["GradIRL"]


class GradIRL:
    """Flat learner: one reward per task whose Boltzmann policy on Q* matches the expert's.

    Minimises eq. (5) for every task (batched over the task axis) by gradient descent with
    Armijo step-size adaptation (or any registered step solver), from zero weights.

    Parameters
    ----------
    beta : float, default=5.0
        Boltzmann inverse temperature (eq. 7).
    features : array_like, shape (S*A, k), optional
        Linear reward features ``R = F w``; None learns tabular rewards (``theta = R``, d = S*A).
    max_iter : int, default=100
        Maximum descent iterations.
    tol : float, default=1e-5
        Stop when the relative decrease of the total loss over an iteration is below tol.
    solver : str or solvers.StepSolver, default="armijo"
        Step solver (see ``solvers.available_solvers()``).
    solver_options : dict, optional
        Options for a solver given by name.

    Attributes
    ----------
    weights_ : ndarray, shape (n, p)
        Learnt parameters (tabular theta, p = S*A, or feature weights, p = k).
    rewards_ : ndarray, shape (n, S, A)
    loss_ : ndarray, shape (n,)
        Final loss of each task.
    loss_history_ : list of float
        Total loss (sum over tasks) before the first step and after each iteration.
    n_evaluations_ : int
        Batched Q* evaluations used.
    n_iter_ : int
    status_ : str
    """

    def __init__(self, beta=5.0, features=None, max_iter=100, tol=1e-5, solver="armijo", solver_options=None):
        self.beta = beta
        self.features = features
        self.max_iter = max_iter
        self.tol = tol
        self.solver = solver
        self.solver_options = solver_options

    @blas_limited
    def fit(self, mdp, demos_per_task):
        """Learn one reward per task.

        Parameters
        ----------
        mdp : TabularMDP
        demos_per_task : list of n task demonstrations
            Each an int array (m, L, 2) or a list of (L_j, 2) episodes.

        Returns
        -------
        self
        """
        check_mdp(mdp)
        beta = check_beta(self.beta)
        check_int(self.max_iter, "max_iter", minimum=0)
        check_tol(self.tol)
        F = None if self.features is None else check_features(self.features, mdp.n_params, mdp.n_states)
        solver = solvers.resolve_solver(self.solver, **(self.solver_options or {}))
        mu, pi_hat = empirical_statistics(mdp, demos_per_task)
        objective = PolicyMatchingObjective(mdp, mu, pi_hat, beta)
        problem = weights_problem(objective, F)
        x0 = np.zeros((problem.n_rows, problem.n_params))
        res = solver.run(problem, x0, int(self.max_iter), tol=self.tol)
        S, A = mdp.n_states, mdp.n_actions
        self.weights_ = res.coefficients
        self.rewards_ = (res.coefficients if F is None else res.coefficients @ F.T).reshape(-1, S, A)
        self.loss_ = res.loss
        self.loss_history_ = res.loss_history
        self.n_evaluations_ = int(objective.n_evaluations)
        self.n_iter_ = res.iterations
        self.status_ = res.status
        return self

    def __repr__(self):
        return f"GradIRL(beta={self.beta}, features={'None' if self.features is None else np.shape(self.features)}, max_iter={self.max_iter})"
