"""GradIRL, the flat learner (Neu & Szepesvari 2007; paper section 3.1)."""

import warnings
from typing import ClassVar

import numpy as np

import solvers

from ._progress import fit_progress
from ._threads import blas_limited
from ._validation import check_beta, check_features, check_int, check_mdp, check_tol
from .demonstrations import empirical_statistics
from .exceptions import ConvergenceWarning, ValidationError, translate_solver_errors
from .objectives import get_objective
from .problems import weights_problem
from .synthetic import task_rewards

__all__ = ["GradIRL", "make_objective", "warn_if_stalled", "check_solver_applies"]


def make_objective(mdp, demos_per_task, beta, objective="policy-matching", planner="auto"):
    """The named objective bound to the empirical statistics of ``demos_per_task``."""
    mu, pi_hat = empirical_statistics(mdp, demos_per_task)
    return get_objective(objective)(mdp, mu, pi_hat, check_beta(beta), planner=planner)


def _least_squares_only(solver):
    return solver.needs_jacobian or solver.needs_linearization


def check_solver_applies(solver, objective, what):
    """Refuse, before any work, a least-squares solver on an objective without residuals.

    The Gauss-Newton solvers (``gn-qp-*``, ``gn-cg``) need residuals (policy matching has them);
    a likelihood such as ``"mce"`` does not. The message lists the solvers that apply.
    """
    if _least_squares_only(solver) and not get_objective(objective).least_squares:
        usable = [name for name in solvers.available_solvers() if not _least_squares_only(solvers.get_solver(name))]
        raise ValidationError(
            f"{what} {solver.name!r} is a Gauss-Newton solver: it needs a least-squares objective (residuals), and the "
            f"{objective!r} objective has none; use a gradient solver: {', '.join(usable)}"
        )
    return solver


def warn_if_stalled(status, iterations, what):
    """A :class:`ConvergenceWarning` when a fit stalled before its second step."""
    if status == "stalled" and iterations <= 1:
        warnings.warn(
            f"{what} stalled at its first step: no step decreased the loss. The rewards are probably far "
            "from the scale where the Boltzmann policy is informative (check the scale of the features or of "
            "the initialisation, and beta)",
            ConvergenceWarning,
            stacklevel=3,
        )


class GradIRL:
    """Flat learner: one reward per task whose Boltzmann policy on Q* matches the expert's.

    Minimises eq. (5) (or another registered objective) for every task, batched over the task
    axis, by gradient descent with Armijo step-size adaptation (or any registered step solver),
    from zero weights.

    Parameters
    ----------
    beta : float, default=5.0
        Boltzmann inverse temperature (eq. 7).
    features : array_like, shape (S*A, p) or (S, p), optional
        Linear reward features ``R = F w`` (state features are repeated over actions); None
        learns tabular rewards (``theta = R``, d = S*A).
    max_iter : int, default=100
        Maximum descent iterations.
    tol : float, default=1e-5
        Stop when the relative decrease of the total loss over an iteration is below tol.
    solver : str or solvers.StepSolver, default="armijo"
        Step solver (see ``solvers.available_solvers()``).
    solver_options : dict, optional
        Options for a solver given by name.
    objective : str, default="policy-matching"
        Per-task loss (see ``factirl_opt.available_objectives()``).
    planner : str, default="auto"
        Planning engine (see ``factirl_opt.available_planners()``).
    verbose : bool, default=False
        Show a progress bar (iterations, loss) on stderr.
    callback : callable, optional
        Called as ``callback(iteration, total_loss)`` after each iteration.

    Attributes
    ----------
    weights_ : ndarray, shape (n, p)
        Learnt parameters (tabular theta, p = S*A, or feature weights).
    rewards_ : ndarray, shape (n, S, A)
    loss_ : ndarray, shape (n,)
        Final loss of each task.
    loss_history_ : list of float
        Total loss (sum over tasks) before the first step and after each iteration.
    n_evaluations_ : int
        Batched planning evaluations used.
    n_iter_ : int
    status_ : str
        ``"converged"``, ``"max_iter"`` or ``"stalled"`` (a :class:`ConvergenceWarning` is
        issued when it stalls at its first step).
    mdp_signature_ : dict
        The signature of the MDP it was fitted on.
    """

    #: The learnt attributes and their kinds, from which ``save_model`` derives what to store and
    #: ``load_model`` what to check (factirl_opt.persistence.learnt): a tuple names the axes of a
    #: finite float array (same name, same length; S, A of the MDP, p parameters), a string a kind.
    learnt_attributes: ClassVar[dict[str, tuple[str, ...] | str]] = {
        "weights_": ("n", "p"), "rewards_": ("n", "S", "A"), "loss_": ("n",), "loss_history_": "history",
        "n_evaluations_": "count", "n_iter_": "count", "status_": "text", "stop_reason_": "text",
        "mdp_signature_": "mdp-signature", "features_sha256_": "features-digest",
    }

    def __init__(self, beta=5.0, features=None, max_iter=100, tol=1e-5, solver="armijo", solver_options=None,
                 objective="policy-matching", planner="auto", verbose=False, callback=None):
        self.beta = beta
        self.features = features
        self.max_iter = max_iter
        self.tol = tol
        self.solver = solver
        self.solver_options = solver_options
        self.objective = objective
        self.planner = planner
        self.verbose = verbose
        self.callback = callback

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
        max_iter = check_int(self.max_iter, "max_iter", minimum=0)
        tol = check_tol(self.tol)
        F = None if self.features is None else check_features(self.features, mdp.n_params, mdp.n_states)
        objective = make_objective(mdp, demos_per_task, self.beta, self.objective, self.planner)
        problem = weights_problem(objective, F)
        with translate_solver_errors(), fit_progress(self.callback, self.verbose, max_iter, "GradIRL") as report:
            solver = check_solver_applies(solvers.resolve_solver(self.solver, self.solver_options), self.objective, "solver")
            res = solver.run(problem, np.zeros((problem.n_rows, problem.n_params)), max_iter, tol=tol, callback=report)
        S, A = mdp.n_states, mdp.n_actions
        self.weights_ = res.coefficients
        self.rewards_ = res.coefficients.reshape(-1, S, A) if F is None else task_rewards(F, res.coefficients, S, A)
        self.loss_ = res.loss
        self.loss_history_ = res.loss_history
        self.n_evaluations_ = int(objective.n_evaluations)
        self.n_iter_ = res.iterations
        self.status_ = res.status
        self.mdp_signature_ = mdp.signature()
        warn_if_stalled(res.status, res.iterations, "GradIRL.fit")
        return self

    def __repr__(self):
        features = "None" if self.features is None else np.shape(self.features)
        return f"GradIRL(beta={self.beta}, features={features}, max_iter={self.max_iter}, objective={self.objective!r})"
