"""The importance-sampled posterior of transferred tasks: the prior's draws weighted by the demonstrations (docs/maths.md §10a).

A new task transferred with the dictionary ``D`` fixed has ``k`` coefficients ``h`` and rewards
``R(h) = Phi D h``. Its posterior given its demonstrations ``tau`` is

    p(h | tau) ∝ N(h; m, P^-1) prod_{(s, a) in tau} pi_h(a | s),

with ``(m, P^-1)`` the Gaussian of the training tasks' coefficients (the Laplace posterior's prior,
:func:`~factirl_opt.learners.transfer.coefficient_prior`) and ``pi_h`` the policy the model's
objective models for the rewards ``R(h)`` at its ``beta`` (the Boltzmann policy of ``Q*`` for policy
matching, eq. 7; the soft-optimal policy for MCE). :class:`~factirl_opt.learners.posterior.LaplacePosterior`
approximates it by a Gaussian at its mode, with the likelihood of the objective's own loss. Here it is
represented without either approximation, by self-normalised importance sampling from the prior:
``n`` draws ``h_j ~ N(m, P^-1)``, planned once for every task of an MDP (the draws do not depend on the
task), each task weighting them by its demonstrations' likelihood,
``w_ij ∝ exp(sum_(s, a) c_i(s, a) log pi_{h_j}(a | s))`` with ``c_i`` the task's (state, action) counts.

A greedy demonstration constrains the direction of ``h`` more than a Gaussian at the mode says (the
set of rewards whose policy takes the demonstrated actions is a cone), and this is what ranks new
tasks by their regret (``results/transfer-prediction/README.md``, §1b). The price is planning: ``n``
reward vectors per MDP, against the Laplace posterior's few Newton steps per task.

The regret of acting greedily on a task's transferred reward ``R_i`` under draw ``j`` is exact and
linear in ``h_j`` once the draw's optimal value is known:
``mean_s V*_{R(h_j)}(s) - sum_l h_jl mean_s V^{pi_i}_{R(e_l)}(s)``, the units of
:func:`factirl_opt.deviation`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import as_rng, check_array, check_int, check_real
from ..exceptions import NotFittedError, ValidationError
from ..planning import plan
from ..planning.engine import greedy_values
from .posterior import has_prior
from .transfer import coefficient_prior
from .transfer_likelihood import tasks_problem

__all__ = ["ParticlePosterior", "importance_posterior", "particle_weights", "PARTICLE_CHUNK"]

#: the prior's draws planned per batch (bounds the memory of one batch's values, policies and factors)
PARTICLE_CHUNK = 1000


@dataclasses.dataclass(eq=False)
class ParticlePosterior:
    """One transferred task's posterior as weighted draws of its coefficients (:func:`importance_posterior`).

    Parameters
    ----------
    coefficients : ndarray, shape (n, k)
        The prior's draws ``h_j`` (shared by the tasks of one call).
    weights : ndarray, shape (n,)
        Their normalised importance weights (nonnegative, summing to 1).
    regrets : ndarray, shape (n,)
        The regret of acting greedily on ``acted_rewards`` under each draw's rewards.
    unit_rewards : ndarray, shape (k, S, A)
        The rewards of each primitive on the task's MDP, ``R(h) = sum_l h_l unit_rewards[l]``.
    acted_rewards : ndarray, shape (S, A)
        The reward whose greedy policy the regrets score (the task's transferred reward).
    mdp : TabularMDP
    """

    coefficients: NDArray[np.float64]
    weights: NDArray[np.float64]
    regrets: NDArray[np.float64]
    unit_rewards: NDArray[np.float64]
    acted_rewards: NDArray[np.float64]
    mdp: Any

    @property
    def n_particles(self) -> int:
        return int(self.weights.shape[0])

    @property
    def effective_sample_size(self) -> float:
        """``1 / sum_j w_j^2``: how many equally weighted draws the weighted ones are worth (1 to n)."""
        return float(1.0 / np.sum(self.weights ** 2))

    def rewards(self, h: ArrayLike) -> NDArray[np.float64]:
        """Rewards (m, S, A) of coefficients ``h`` (m, k)."""
        return np.tensordot(np.atleast_2d(np.asarray(h, dtype=np.float64)), self.unit_rewards, axes=1)

    def mean_rewards(self) -> NDArray[np.float64]:
        """The rewards (S, A) of the posterior mean of ``h``."""
        return self.rewards(self.weights @ self.coefficients)[0]

    def expected_regret(self) -> float:
        """The posterior expected regret of acting on ``acted_rewards``: ``sum_j w_j regret_j``."""
        return float(self.weights @ self.regrets)

    def regret_quantile(self, q: float) -> float:
        """The ``q`` quantile of the regret under the weighted draws (the smallest regret whose weight
        below or at it reaches ``q``); ``q = 0.9`` is the 90% upper bound."""
        q = check_real(q, "q", 0.0, 1.0, what="a probability")
        order = np.argsort(self.regrets, kind="stable")
        cum = np.cumsum(self.weights[order])
        return float(self.regrets[order][min(int(np.searchsorted(cum, q * cum[-1])), len(order) - 1)])

    def _resample(self, n: int, rng: Any) -> NDArray[np.intp]:
        n = check_int(n, "n", minimum=1)
        return as_rng(rng).choice(self.n_particles, size=n, p=self.weights)

    def sample_rewards(self, n: int, rng: Any = None) -> NDArray[np.float64]:
        """``n`` rewards (n, S, A) resampled from the weighted draws."""
        return self.rewards(self.coefficients[self._resample(n, rng)])

    def sample_regrets(self, n: int, rng: Any = None) -> NDArray[np.float64]:
        """The regrets (n,) of the draws :meth:`sample_rewards` returns for the same ``rng``."""
        return self.regrets[self._resample(n, rng)]


def particle_weights(log_likelihoods: ArrayLike) -> NDArray[np.float64]:
    """Self-normalised importance weights (n_tasks, n) from log-likelihoods (n_tasks, n) of the prior's draws.

    Raises
    ------
    ValidationError
        A non-finite log-likelihood.
    """
    L = check_array(log_likelihoods, "log_likelihoods", ndim=2)
    W = np.exp(L - L.max(axis=1, keepdims=True))
    return W / W.sum(axis=1, keepdims=True)


def _groups(problem):
    """Task indices per (MDP, features) pair, and that pair's planner, objective class and beta."""
    out: dict = {}
    for sub, tasks, _ in problem.groups():
        for t in tasks:
            t = int(t)
            key = (id(problem.mdps[t]), id(problem.features[t]))
            out.setdefault(key, (sub, []))[1].append(t)
    return list(out.values())


def _acted_policy_values(planner, unit, acted):
    """``mean_s V^{pi}_{R(e_l)}(s)`` (k,) of the greedy policy ``pi`` of ``acted`` (S, A) for each primitive."""
    pols = np.repeat(plan(planner, acted[None]).policy, unit.shape[0], axis=0)
    return greedy_values(planner, unit, pols)[0].mean(axis=1)


def importance_posterior(model: Any, n_particles: int = 10_000, rng: Any = None, *,
                         acted_rewards: ArrayLike | None = None) -> list[ParticlePosterior]:
    """The importance-sampled posterior of each task of a :class:`~factirl_opt.FactIRL`'s last transfer.

    Draws ``n_particles`` coefficient vectors from the prior the Laplace posterior uses (the Gaussian
    of the training tasks' coefficients), plans each one's rewards once per MDP of the transferred
    tasks, and weights them per task by the likelihood of the task's demonstrations under the policy
    the model's objective models (module docstring; docs/maths.md §10a). The draws come from ``rng``
    alone: a task's posterior does not depend on which other tasks were transferred with it.

    Parameters
    ----------
    model : FactIRL
        Fitted, with a coefficient prior (2 or more training tasks, not the flat model), without a
        residual (``residual_penalty_`` infinite), and transferred (``model.transfer``).
    n_particles : int, default=10000
        Draws of the prior. The cost is planning them: ``n_particles`` reward vectors per MDP of the
        transferred tasks, once, whatever the number of tasks on it.
    rng : numpy.random.Generator or int or None
    acted_rewards : array_like, shape (n_tasks, S, A) or list of n_tasks (S_i, A), optional
        The rewards whose greedy policies the regrets score; default: the transfer's own
        (``model.transfer_rewards_``).

    Returns
    -------
    list of ParticlePosterior
        One per transferred task, in the transfer's order.

    Raises
    ------
    NotFittedError
        The model is not fitted, or has transferred no tasks since its fit (a loaded model keeps its
        posterior but not its transfer's demonstrations).
    ValidationError
        The model has no coefficient prior or has a residual, or ``acted_rewards`` has the wrong shape.
    """
    state = vars(model).get("_transfer")
    if getattr(model, "dictionary_", None) is None or state is None or state.tasks is None:
        raise NotFittedError("importance_posterior scores the tasks of the model's last transfer: fit the model and call "
                             "transfer first (a loaded model keeps no transferred demonstrations)")
    if not has_prior(model):
        raise ValidationError("importance_posterior draws from the training coefficients' prior: the model needs 2 or more "
                              "training tasks and a shared dictionary (not the flat model, residual_penalty_=0)")
    n = check_int(n_particles, "n_particles", minimum=1)
    problem = tasks_problem(model, state.tasks, state.dictionary)
    if problem.residual:
        raise ValidationError(f"importance_posterior samples the k coefficients only; this model has a residual "
                              f"(residual_penalty_={problem.residual_penalty!r}): use transfer_posterior_, or fit with "
                              "residual_penalty=numpy.inf")
    acted = list(model.transfer_rewards_ if acted_rewards is None else acted_rewards)  # type: ignore[arg-type]
    if len(acted) != problem.n_tasks:
        raise ValidationError(f"acted_rewards must hold one reward per transferred task ({problem.n_tasks}); got {len(acted)}")
    m, P = coefficient_prior(model.coefficients_)
    L = np.linalg.cholesky(np.linalg.inv(P))
    H = m + as_rng(rng).standard_normal((n, m.shape[0])) @ L.T
    out: list = [None] * problem.n_tasks
    for sub, tasks in _groups(problem):
        mdp = problem.mdps[tasks[0]]
        S, A = mdp.n_states, mdp.n_actions
        unit = problem.basis(tasks[0]).T.reshape(-1, S, A)  # (k, S, A)
        counts = np.stack([_counts(problem, t) for t in tasks])  # (g, S*A)
        acted_g = [_acted(acted[t], t, S, A) for t in tasks]
        loglik = np.empty((len(tasks), n))
        best = np.empty(n)
        for lo in range(0, n, PARTICLE_CHUNK):
            R = np.tensordot(H[lo:lo + PARTICLE_CHUNK], unit, axes=1)
            log_pi, V = type(sub).log_policy_and_values(sub.planner, R, sub.beta)
            loglik[:, lo:lo + PARTICLE_CHUNK] = counts @ log_pi.reshape(len(R), -1).T
            best[lo:lo + PARTICLE_CHUNK] = V.mean(axis=1)
        weights = particle_weights(loglik)
        for g, t in enumerate(tasks):
            c = _acted_policy_values(sub.planner, unit, acted_g[g])
            out[t] = ParticlePosterior(H, weights[g], np.maximum(best - H @ c, 0.0), unit, acted_g[g], mdp)
    return out


def _acted(R, task, S, A):
    R = check_array(R, f"acted_rewards[{task}]")
    if R.shape != (S, A):
        raise ValidationError(f"acted_rewards[{task}] must have the shape (S, A) = ({S}, {A}) of the task's MDP; got {R.shape}")
    return R


def _counts(problem, task):
    """The task's demonstrated (state, action) counts (S*A,): ``N mu(s) pi_hat(a|s)``."""
    _, mu, pi_hat = problem.statistics(task)
    return (problem.n_pairs[task] * np.asarray(mu)[:, None] * np.asarray(pi_hat)).ravel()
