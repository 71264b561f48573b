"""Held-out scores of the sharing search: how a transferred reward explains a task's other demonstrations.

``score="likelihood"`` (the default): the negative log-likelihood per step under the learner's
policy model with the transferred reward (policy matching: the Boltzmann policy of its Q*, eq. 7;
MCE: the soft-optimal policy), the policy's inverse temperature profiled out per task
(:func:`held_out_nll`: a reward's scale is not what transfer is judged on); ``"fixed-beta"``
keeps the learner's ``beta``; ``"objective"`` scores by the learner's objective, which for policy
matching is the squared policy difference; ``"occupancy"`` compares where the transferred reward's
optimal policy goes with where the expert went (:func:`held_out_occupancy_gap`); ``"deviation"``
is the transferred reward's deviation (the benchmark's measure, :func:`factirl_opt.deviation`)
under a reference reward of the task: the flat learner's reward of its scoring demonstrations,
fitted once per search (:func:`held_out_deviation`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize_scalar
from scipy.special import log_softmax

from ..._validation import check_rewards
from ...evaluation import deviation
from ...exceptions import ValidationError
from ...planning import get_planner, optimal_q
from ...tasks.demonstrations import empirical_statistics
from ...tasks.task_set import TaskSet
from ...tasks.trajectories import parse_demonstrations
from ..em import log_policies
from ..fitting import task_objective

__all__ = ["N_TRANSFER_DEMOS", "SCORES", "REFERENCE_SCORES", "DEFAULT_SCORE", "needs_reference", "held_out_nll",
           "held_out_occupancy_gap", "held_out_deviation"]

#: demonstrations a held-out task is transferred from (the one-demonstration use)
N_TRANSFER_DEMOS = 1
#: held-out scores of :func:`search_sharing`: the negative log-likelihood under the learner's
#: policy model with its inverse temperature fitted per task (:func:`held_out_nll`), the same
#: with the learner's ``beta``, the learner's own objective, or the distance between the
#: occupancies of the transferred reward's optimal policy and of the demonstrations
#: (:func:`held_out_occupancy_gap`), or the transferred reward's deviation under a reference reward
#: of the task (:func:`held_out_deviation`)
SCORES = ("likelihood", "fixed-beta", "objective", "occupancy", "deviation")
#: the scores that judge a transfer against a reference reward of each held-out task, which the
#: search fits once (:func:`~factirl_opt.learners.selection.search.reference_rewards`)
REFERENCE_SCORES = ("deviation",)
#: the score ``FactIRL.fit`` uses
DEFAULT_SCORE = "likelihood"


def needs_reference(score: str) -> bool:
    """Whether the held-out ``score`` (a name of :data:`SCORES`) judges a transfer against a
    reference reward of each held-out task (:data:`REFERENCE_SCORES`)."""
    return score in REFERENCE_SCORES


def _one_reward(mdp: Any, rewards: ArrayLike) -> np.ndarray:
    """One task's reward, validated (finite, shape (S, A) or (S,)), as (S, A)."""
    R, single = check_rewards(mdp, rewards, "rewards")
    if not single:
        raise ValidationError(f"rewards must be one task's reward, of shape (S, A) = ({mdp.n_states}, {mdp.n_actions}) "
                              f"or (S,) = ({mdp.n_states},); got {np.shape(rewards)}")
    return R[0]


def held_out_nll(mdp: Any, demos: Any, rewards: ArrayLike, model: Any, temper: bool = True) -> float:
    """Negative log-likelihood per step of demonstrations under the policy a learner models for a reward.

    The policy is the one the learner's objective models (:func:`~factirl_opt.learners.em.log_policies`;
    policy matching: the Boltzmann policy of the optimal Q*, eq. 7; MCE: the soft-optimal policy),
    ``log pi(a|s)``. With ``temper`` its logits are rescaled by the ``c >= 0`` that fits the
    demonstrations best, ``min_c -sum_(s,a) mu(s) pi_hat(a|s) log softmax_a(c log pi(.|s))``
    (convex in c; ``c = 0`` is the uniform policy, so the score is at most ``log |A|``). For policy
    matching this is exactly the likelihood of the Boltzmann policy with the inverse temperature
    ``c * beta`` (Q* is positively homogeneous in the reward), i.e. the likelihood of the best
    rescaled reward: transfer is judged on the reward's direction, which the policy it induces
    depends on, and not on its scale, which one demonstration does not fix.

    Parameters
    ----------
    mdp : TabularMDP
    demos : array of int, shape (n_demos, horizon, 2)
        (state, action) pairs.
    rewards : array, shape (S, A)
    model : FactIRL or GradIRL
        Its ``beta``, ``objective`` and ``planner``.
    temper : bool, default True

    Returns
    -------
    float

    Raises
    ------
    ValidationError
        ``rewards`` not finite, or not one task's reward of the MDP's shape.
    """
    R = _one_reward(mdp, rewards)
    mu, pi_hat = empirical_statistics(mdp, [demos])
    return _statistics_nll(mdp, mu[0], pi_hat[0], R, model, temper)


def _statistics_nll(mdp: Any, mu: Any, pi_hat: Any, R: np.ndarray, model: Any, temper: bool) -> float:
    """:func:`held_out_nll` of a task's statistics ``mu`` (S,), ``pi_hat`` (S, A) and its reward ``R`` (S, A)."""
    weights = mu[:, None] * pi_hat
    log_pi = log_policies(get_planner(mdp, model._group("execution").planner), R[None], model.beta, model.objective)[0]
    if not temper:
        return float(-np.sum(weights * log_pi))
    seen = weights.sum(axis=1) > 0
    weights, log_pi = weights[seen], log_pi[seen]
    log_pi = log_pi - log_pi.max(axis=1, keepdims=True)  # finite, and the same policy

    def nll(log_c: float) -> float:
        return float(-np.sum(weights * log_softmax(np.exp(log_c) * log_pi, axis=1)))

    best = minimize_scalar(nll, bounds=(-12.0, 12.0), method="bounded", options={"xatol": 1e-6})
    return min(best.fun, float(np.log(log_pi.shape[1]) * weights.sum()))


def held_out_occupancy_gap(mdp: Any, demos: Any, rewards: ArrayLike, planner: str = "auto") -> float:
    """Where the reward's optimal policy goes against where the demonstrations went.

    The total variation ``sum_(s,a) |rho_pi(s, a) - rho_hat(s, a)|`` between two discounted
    state-action occupancies over the demonstrations' horizon: ``rho_hat`` of the
    demonstrations themselves (``sum_t gamma^t 1[(s_t, a_t) = (s, a)]``, averaged over the
    episodes), and ``rho_pi`` of the optimal (greedy) policy of ``rewards`` started from each
    episode's first state and run for as many steps as the episode has (``d_(t+1) = P^T (d_t *
    pi)``, through the model), averaged over the episodes. It bounds the difference of values for
    any reward ``r``: ``|V_hat(r) - V_pi(r)| <= max|r| * gap``. Unlike a likelihood it does not
    reward a model for imitating how the expert moves between equally good actions, only for
    going where the expert goes (BabyAI: the bot's tie-breaking, shared by every mission,
    improves the held-out likelihood of a shared model whose transferred rewards reach the target
    less often; ``results/which-learner/README.md``).

    Parameters
    ----------
    mdp : TabularMDP
    demos : array of int, shape (n_demos, horizon, 2), or list of (L_j, 2) episodes
    rewards : array, shape (S, A)
    planner : str, default="auto"

    Returns
    -------
    float
        In ``[0, 2 (1 - gamma^L) / (1 - gamma)]``, L the longest episode; 0 when the
        demonstrations follow the greedy policy through a deterministic model.

    Raises
    ------
    ValidationError
        ``rewards`` not finite, or not one task's reward of the MDP's shape.
    """
    R = _one_reward(mdp, rewards)
    return _occupancy_gap(mdp, parse_demonstrations([demos], mdp.n_states, mdp.n_actions)[0].episodes(), R, planner)


def _occupancy_gap(mdp: Any, episodes: list, R: np.ndarray, planner: str) -> float:
    """:func:`held_out_occupancy_gap` of parsed episodes (each (L_j, 2)) and a validated reward ``R`` (S, A)."""
    S, A, gamma = mdp.n_states, mdp.n_actions, mdp.gamma
    _, greedy = optimal_q(mdp, R[None], planner=planner)
    pi = np.zeros((S, A))
    pi[np.arange(S), np.asarray(greedy).reshape(S)] = 1.0
    P = mdp.csr()
    expert, learnt = np.zeros((S, A)), np.zeros((S, A))
    for e in episodes:  # each episode's start, for its own length
        np.add.at(expert, (e[:, 0], e[:, 1]), gamma ** np.arange(len(e)))
        d = np.zeros(S)
        d[e[0, 0]] = 1.0
        for t in range(len(e)):
            x = d[:, None] * pi
            learnt += gamma ** t * x
            d = P.T @ x.reshape(-1)
    learnt /= len(episodes)
    expert /= len(episodes)
    return float(np.abs(learnt - expert).sum())


def held_out_deviation(mdp: Any, reference: ArrayLike, rewards: ArrayLike, planner: str = "auto") -> float:
    """The deviation of a transferred reward under a reference reward of the task, in units of the reference's range.

    ``deviation(mdp, R_ref / (max R_ref - min R_ref), rewards)`` (:func:`factirl_opt.deviation`,
    the which-learner benchmark's measure of a transfer with the true reward in place of
    ``R_ref``): how much value, mean over the states, acting greedily on ``rewards`` loses
    against the optimal policy of the reference. In the sharing search the reference of a
    held-out task is the flat learner's reward of its scoring demonstrations (those the transfer
    did not see; :func:`~factirl_opt.learners.selection.search.reference_rewards`): one fit per
    task for every candidate, so the candidates are compared on the same stand-in for the true
    reward, and in the benchmark's units rather than the likelihood's. The range makes the score
    invariant to the reference's scale and offset (the flat learner's scale follows how
    deterministic the demonstrations look), so every held-out task weighs alike; a constant
    reference (every policy optimal) scores 0.

    Parameters
    ----------
    mdp : TabularMDP
    reference : array, shape (S, A) or (S,)
        The task's reference reward.
    rewards : array, shape (S, A) or (S,)
        The transferred reward.
    planner : str, default="auto"

    Returns
    -------
    float
        In ``[0, 1 / (1 - gamma)]``.

    Raises
    ------
    ValidationError
        ``reference`` or ``rewards`` not finite, or not one task's reward of the MDP's shape.
    """
    return _reference_deviation(mdp, _one_reward(mdp, reference), _one_reward(mdp, rewards), planner)


def _reference_deviation(mdp: Any, ref: np.ndarray, R: np.ndarray, planner: str) -> float:
    """:func:`held_out_deviation` of validated rewards ``ref`` and ``R`` (S, A)."""
    spread = float(ref.max() - ref.min())
    if spread == 0.0:
        return 0.0
    return float(deviation(mdp, ref / spread, R, planner=planner))


def _score(model: Any, tasks: TaskSet, idx: Sequence[int] | np.ndarray, t: int,
           score: str = DEFAULT_SCORE, transfer_max_iter: int | None = None, reference: Any = None) -> np.ndarray:
    """Held-out score of tasks ``idx`` of ``tasks``: transfer from their first t demonstrations, then, on the
    others, :func:`held_out_nll` (``score="likelihood"``: tempered; ``"fixed-beta"``: not), the
    learner's objective (``"objective"``), :func:`held_out_occupancy_gap` (``"occupancy"``) or
    :func:`held_out_deviation` under ``reference`` (``"deviation"``: the reference rewards of the
    tasks ``idx``, in that order); one value per task."""
    if needs_reference(score) and (reference is None or len(reference) != len(idx)):
        raise ValidationError(f"score={score!r} needs a reference reward per held-out task ({len(idx)}); got "
                              f"{'none' if reference is None else len(reference)}")
    held = tasks.subset(idx)
    model._transfer_tasks(held.episodes(0, t), max_iter=transfer_max_iter)
    rewards = model.transfer_rewards_
    rest = held.episodes(t)
    out = np.empty(len(idx))
    for j in range(len(idx)):
        one = held.mdp if held.mdps is None else held.mdps[j]
        R = _one_reward(one, rewards[j])
        if score == "occupancy":
            out[j] = _occupancy_gap(one, rest.demonstrations[j].episodes(), R, model._group("execution").planner)
        elif score == "deviation":
            out[j] = _reference_deviation(one, _one_reward(one, reference[j]), R, model._group("execution").planner)
        elif score == "objective":
            obj = task_objective(rest.subset([j]), model.beta, model.objective, model._group("execution").planner)
            out[j] = obj.loss_and_grad(np.asarray(rewards[j])[None])[0][0]
        else:
            out[j] = _statistics_nll(one, rest.mu_hat[j], rest.pi_hat[j], R, model, temper=score == "likelihood")
    return out
