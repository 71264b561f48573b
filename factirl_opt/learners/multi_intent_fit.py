"""The EM loop of :class:`factirl_opt.learners.multi_intent.MultiIntentIRL`: its M-steps and its start.

- :class:`WeightedObjective`: an objective over K intentions whose per-intention loss is scaled
  by a weight (the intention's share of the demonstrated steps), so that the M-step's total
  loss is EM's expected complete-data negative log-likelihood per step (with MCE;
  docs/maths.md §6);
- :func:`flat_m_step` (each intention its own reward; GradIRL's step problem) and
  :func:`factorial_m_step` (``R_c = Phi D h_c``; FactIRL's alternating scheme, docs/maths.md
  §8), both warm-started from the previous parameters and never ending above their start;
- :func:`run_em`: one EM run from a start, keeping the point of highest log-likelihood.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

import solvers

from .._validation import check_beta, check_int, check_tol
from .dictionary import pca_dictionary, shrink_coefficients
from .em import agreement_clustering, e_step, episode_counts, kmeans, log_policies, weighted_statistics
from ..exceptions import ValidationError, translate_solver_errors
from .factorial import GTOL, run_factorial
from ..tasks.basis import WEIGHT_NAMES, RewardBasis
from .fitting import resolve_step_solver, statistics_objective
from ..tasks.task_set import TaskSet
from ..interruption import run_keeping_best
from ..objectives import available_objectives, get_objective
from ..objectives.contract import TaskObjective
from ..objectives.sharding import Execution
from ..planning import get_planner
from ..objectives.problems import weights_problem
from .solver_settings import estimator_solvers

__all__ = ["WeightedObjective", "EMSettings", "EMRun", "flat_m_step", "factorial_m_step", "run_em",
           "start_responsibilities", "best_of_runs", "episode_subset", "episode_log_likelihoods"]

WHAT = "MultiIntentIRL.fit"


class WeightedObjective(TaskObjective):
    """An objective whose task (intention) c has loss ``w_c J_c``: what the step problems need.

    Residuals and Jacobian products are scaled by ``sqrt(w_c)``, so least-squares solvers
    see the same weighted loss ``w_c ||r_c||^2``.

    Parameters
    ----------
    objective : Objective
        Bound to the K intentions' weighted statistics.
    weights : ndarray, shape (K,)
        Nonnegative.
    """

    def __init__(self, objective: Any, weights: NDArray[np.float64]) -> None:
        self.objective = objective
        self.weights = np.asarray(weights, dtype=np.float64)
        self.mdp, self.n_tasks = objective.mdp, objective.n_tasks
        self.least_squares, self.name = objective.least_squares, objective.name

    @property
    def n_evaluations(self) -> int:
        return self.objective.n_evaluations

    def _w(self, rows, ndim):
        w = self.weights[np.arange(self.n_tasks) if rows is None else np.asarray(rows)]
        return w.reshape(-1, *([1] * (ndim - 1)))

    def loss_and_grad(self, rewards: NDArray[np.float64], rows: Any = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Weighted loss (r,) and gradient (r, S, A) of intentions ``rows`` (all by default)."""
        loss, grad = self.objective.loss_and_grad(rewards, rows)
        return loss * self._w(rows, 1), grad * self._w(rows, 3)

    def residual_jacobian(self, rewards: NDArray[np.float64], rows: Any, features: Any) -> tuple:
        """Weighted loss, residuals (scaled by ``sqrt(w)``) and their Jacobian."""
        loss, res, jac = self.objective.residual_jacobian(rewards, rows, features)
        return loss * self._w(rows, 1), res * np.sqrt(self._w(rows, 2)), jac * np.sqrt(self._w(rows, 3))

    def linearize(self, rewards: NDArray[np.float64], rows: Any = None) -> solvers.Linearization:
        """The objective's linearisation with residuals and products scaled by ``sqrt(w)``."""
        lin = self.objective.linearize(rewards, rows)
        w = self._w(rows, 1)
        sq = np.sqrt(w)

        def jvp(dR):
            out = lin.jvp(dR)
            return out * sq.reshape(-1, *([1] * (out.ndim - 1)))

        def vjp(U):
            return lin.vjp(U * sq[:, None])

        return solvers.Linearization(lin.loss * w, lin.residual * sq[:, None], jvp, vjp)

    def reset(self) -> None:
        self.objective.reset()

    def reward_limit(self) -> float:
        return float(self.objective.reward_limit())


@dataclasses.dataclass
class EMSettings:
    """Validated settings of an EM fit (built from the estimator by :meth:`build`)."""

    n_intentions: int
    n_primitives: int | None
    objective: Any
    beta: float
    planner: Any  # the Planner of the fit's MDP (E-steps)
    basis: RewardBasis  # the intentions' rewards R_c = Phi w_c (the task set's basis)
    solver: solvers.StepSolver
    max_iter: int
    tol: float
    m_max_iter: int
    m_tol: float
    inner_steps: int
    d_solver: solvers.StepSolver | None = None  # the D-step's; None: ``solver``
    execution: Execution = Execution()  # shards and planner (name) of each M-step's objective

    @classmethod
    def build(cls, est: Any, tasks: TaskSet, K: int) -> EMSettings:
        """Validate the hyper-parameters of ``est`` (a MultiIntentIRL) for its task set (one MDP) and K intentions."""
        objective = get_objective(est.objective)
        if not objective.models_policy():
            with_policy = [name for name in available_objectives() if get_objective(name).models_policy()]
            raise ValidationError(f"objective must be one of {', '.join(map(repr, with_policy))} (its policy scores "
                                  f"the episodes in the E-step); got {est.objective!r}")
        mdp, p = tasks.mdp, tasks.n_params
        k = None
        if est.n_primitives is not None:
            k = check_int(est.n_primitives, "n_primitives", minimum=1)
            if k > p:
                raise ValidationError(f"n_primitives={k} exceeds the reward dimension p={p}")
        solver, options, d_solver, d_options = estimator_solvers(est)
        if d_solver is None and d_options is not None:
            raise ValidationError("d_solver_options given without d_solver")
        return cls(K, k, objective, check_beta(est.beta), get_planner(mdp, est._group("execution").planner),
                   tasks.basis, resolve_step_solver(solver, options, objective.name, "solver"),
                   check_int(est.max_iter, "max_iter", minimum=1), check_tol(est.tol),
                   check_int(est.m_step_max_iter, "m_step_max_iter", minimum=0), check_tol(est.m_step_tol, "m_step_tol"),
                   check_int(est.inner_steps, "inner_steps", minimum=1),
                   None if d_solver is None else resolve_step_solver(d_solver, d_options, objective.name, "d_solver"),
                   est._group("execution"))


@dataclasses.dataclass
class EMRun:
    """One EM run: the kept (highest log-likelihood) point and the history."""

    rewards: NDArray[np.float64]
    params: Any
    responsibilities: NDArray[np.float64]
    mixture_weights: NDArray[np.float64]
    history: list
    best_log_likelihood: float
    converged: bool


def flat_m_step(objective: WeightedObjective, settings: EMSettings, W0: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per-intention weights (K, p) from ``W0`` by the step solver; a row never ends above its start."""
    problem = weights_problem(objective, settings.basis)
    start = problem.loss_and_grad(W0, np.arange(problem.n_rows))[0]
    with translate_solver_errors():
        res = run_keeping_best(settings.solver, problem, W0, settings.m_max_iter, WHAT, tol=settings.m_tol)
    keep = np.asarray(res.loss) <= start
    return np.where(keep[:, None], res.coefficients, W0)


def factorial_m_step(objective: WeightedObjective, settings: EMSettings, params: Any,
                     rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(D, H)`` by the alternating scheme from ``params``; the first one from the PCA of a flat fit.

    The first start is FactIRL's: the uncentred PCA of flat rewards fitted to the same weighted
    statistics, its coefficients halved while the loss decreases (:mod:`factirl_opt.learners.dictionary`).
    """
    basis, k = settings.basis, settings.n_primitives
    assert k is not None  # the caller's branch; never user input
    if params is None:
        W = flat_m_step(objective, settings, np.zeros((objective.n_tasks, basis.n_params)))
        D, H = basis.start_dictionary(basis.start_points(W), k, rng, pca_dictionary)
        H = shrink_coefficients(lambda Hs: objective.loss_and_grad(basis.factorial_rewards(D, Hs))[0], H)[0]
    else:
        D, H = params
    d_solver = settings.solver if settings.d_solver is None else settings.d_solver
    fit = run_factorial(objective, D, H, settings.solver, d_solver, base_features=basis,
                        max_iter=settings.m_max_iter, inner_steps=settings.inner_steps, tol=settings.m_tol, gtol=GTOL)
    return fit.dictionary, fit.coefficients


def start_responsibilities(counts: Any, lengths: NDArray[np.int64], K: int, init: str,
                           rng: np.random.Generator, n_actions: int) -> NDArray[np.float64]:
    """Starting responsibilities (n, K): the episodes' agreements, k-means of their frequencies, or random.

    ``"agreement"``: hard labels of :func:`factirl_opt.learners.em.agreement_clustering`.
    ``"frequencies"``: each episode is described by its normalised state-action counts next to
    its action frequencies (which episodes of one intention share even where they visit
    different states); k-means++ and Lloyd (:func:`factirl_opt.learners.em.kmeans`) give hard labels.
    ``"random"``: rows drawn from a flat Dirichlet.
    """
    n = len(lengths)
    if init == "random":
        return rng.dirichlet(np.ones(K), size=n)
    if init == "agreement":
        return np.eye(K)[agreement_clustering(counts, counts.shape[1] // n_actions, n_actions, K, rng)]
    freq = np.asarray(counts.todense()) / lengths[:, None]
    actions = freq.reshape(n, -1, n_actions).sum(axis=1)
    return np.eye(K)[kmeans(np.hstack([freq, actions]), K, rng)]


def _m_step(mdp, counts, resp, settings, params, rng):
    """Parameters and rewards (K, S, A) fitted to the responsibilities, and the mixture weights."""
    mu, pi, steps = weighted_statistics(counts, resp, mdp.n_states, mdp.n_actions)
    base = statistics_objective(mdp, mu, pi, settings.beta, settings.objective, settings.execution.planner)
    basis = settings.basis
    with settings.execution.shards(base) as base:
        obj = WeightedObjective(base, steps / steps.sum())
        if settings.n_primitives is None:
            W = flat_m_step(obj, settings, np.zeros((settings.n_intentions, basis.n_params)) if params is None else params)
            return W, basis.rewards(W, names=WEIGHT_NAMES), resp.mean(axis=0)
        D, H = factorial_m_step(obj, settings, params, rng)
    return (D, H), basis.factorial_rewards(D, H), resp.mean(axis=0)


def run_em(mdp: Any, steps: NDArray[np.int64], lengths: NDArray[np.int64], settings: EMSettings, init: str,
           given: NDArray[np.float64] | None, rng: np.random.Generator, callback: Callable | None = None) -> EMRun:
    """One EM run: alternate M-steps and E-steps, keep the point of highest log-likelihood.

    Each iteration fits the parameters to the current responsibilities (warm-started from the
    previous ones) with the mixture weights their means, then recomputes the log-likelihood
    and the responsibilities (:func:`factirl_opt.learners.em.e_step`). Stops after ``max_iter``
    iterations or when the log-likelihood changes by at most ``tol * max(1, |previous|)``.
    """
    counts = episode_counts(steps, lengths, mdp.n_states, mdp.n_actions)
    resp = given if given is not None else start_responsibilities(counts, lengths, settings.n_intentions, init, rng,
                                                                  mdp.n_actions)
    params: Any = None
    history: list[float] = []
    best: tuple | None = None
    converged = False
    for it in range(1, settings.max_iter + 1):
        params, R, mix = _m_step(mdp, counts, resp, settings, params, rng)
        _, resp, ll = e_step(counts, log_policies(settings.planner, R, settings.beta, settings.objective), mix)
        history.append(ll)
        if best is None or ll > best[0]:
            best = (ll, R, params, resp, mix)
        if callback is not None:
            callback(it, ll)
        if it > 1 and abs(ll - history[-2]) <= settings.tol * max(1.0, abs(history[-2])):
            converged = True
            break
    assert best is not None  # max_iter >= 1
    ll, R, params, resp, mix = best
    return EMRun(R, params, resp, mix, history, ll, converged)


def best_of_runs(mdp: Any, steps: NDArray[np.int64], lengths: NDArray[np.int64], settings: EMSettings, init: str,
                 given: NDArray[np.float64] | None, rng: np.random.Generator, n_init: int,
                 callback: Callable | None = None) -> EMRun:
    """The run of highest best log-likelihood among ``n_init`` runs of :func:`run_em`."""
    best = None
    for _ in range(n_init):
        run = run_em(mdp, steps, lengths, settings, init, given, rng, callback)
        if best is None or run.best_log_likelihood > best.best_log_likelihood:
            best = run
    assert best is not None  # n_init >= 1, validated by the caller
    return best


def episode_subset(steps: NDArray[np.int64], lengths: NDArray[np.int64],
                   indices: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Concatenated steps (N', 2) and lengths (m,) of the episodes ``indices`` (m,), in that order."""
    ends = np.cumsum(lengths)
    starts = ends - lengths
    rows = np.concatenate([np.arange(starts[j], ends[j]) for j in indices]) if len(indices) else np.zeros(0, np.int64)
    return steps[rows.astype(np.int64)], lengths[indices]


def episode_log_likelihoods(mdp: Any, steps: NDArray[np.int64], lengths: NDArray[np.int64], settings: EMSettings,
                            run: EMRun) -> NDArray[np.float64]:
    """Mixture log-likelihood (m,) ``log sum_c w_c prod_t pi_c(a_t | s_t)`` of each episode under a fitted run.

    The episodes are given as concatenated steps (N, 2) and lengths (m,); the per-intention
    terms are those of :func:`factirl_opt.learners.em.e_step`.
    """
    counts = episode_counts(steps, lengths, mdp.n_states, mdp.n_actions)
    log_pi = log_policies(settings.planner, run.rewards, settings.beta, settings.objective)
    L = e_step(counts, log_pi, run.mixture_weights)[0]
    with np.errstate(divide="ignore"):
        return logsumexp(L + np.log(run.mixture_weights)[None, :], axis=1)
