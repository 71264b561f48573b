"""Unlabeled against labelled demonstrations on the paper's grid, as the number of tasks grows.

For each number of tasks n (default 4, 10, 20) and each seed, tasks are drawn from a random
dictionary of k primitives on ``GridWorld(size)`` (:func:`factirl_opt.synthetic_tasks`, n
demonstrations per task), the task labels are dropped, and three learners fit the same
demonstrations:

- ``labelled``: :class:`factirl_opt.FactIRL` given the task labels (the reference);
- ``em_flat``: :class:`factirl_opt.MultiIntentIRL` with ``n_primitives=None`` (each intention
  its own reward; Babes-Vroman's EM), K = n intentions;
- ``em_shared``: :class:`factirl_opt.MultiIntentIRL` with ``n_primitives=k`` (a dictionary shared
  by the intentions, the paper's model).

Scores per learner: the adjusted Rand index of its labels against the true tasks (1 for the
labelled learner), the mean train deviation (eq. 13, docs/maths.md §9) of the recovered rewards
with intentions matched to true tasks by the Hungarian algorithm on the deviation matrix
(:func:`factirl_opt.match_intentions`), and, for the learners with a dictionary, the mean
deviation of one-demonstration transfer (:meth:`factirl_opt.FactIRL.transfer`) to
``--n-test`` new tasks drawn from the true dictionary.

``--quick`` is a tiny configuration for tests (options given explicitly keep their value).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from ..evaluation import deviation
from ..factirl import FactIRL
from ..mdp import GridWorld
from ..multi_intent import MultiIntentIRL, adjusted_rand_index, match_intentions
from ..synthetic import synthetic_tasks
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run", "matched_deviation", "LEARNERS"]

DEFAULTS = {"n_tasks": [4, 10, 20], "seeds": [0], "size": 10, "n_demos": 10, "length": 10, "n_primitives": 5,
            "beta": 5.0, "em_max_iter": 20, "m_step_max_iter": 20, "n_test": 5}
QUICK = {"n_tasks": [2], "size": 4, "n_demos": 3, "length": 5, "n_primitives": 2, "em_max_iter": 2,
         "m_step_max_iter": 3, "n_test": 1}
LEARNERS = ("labelled", "em_flat", "em_shared")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_option(parser, "--n-tasks", type=int, nargs="+", defaults=DEFAULTS, quick=QUICK, help="numbers of tasks")
    add_option(parser, "--seeds", type=int, nargs="+", defaults=DEFAULTS, help="task and demonstration seeds")
    add_option(parser, "--size", type=int, defaults=DEFAULTS, quick=QUICK, help="grid side")
    add_option(parser, "--n-demos", type=int, defaults=DEFAULTS, quick=QUICK, help="demonstrations per task")
    add_option(parser, "--length", type=int, defaults=DEFAULTS, quick=QUICK, help="steps per demonstration")
    add_option(parser, "--n-primitives", type=int, defaults=DEFAULTS, quick=QUICK)
    add_option(parser, "--beta", type=float, defaults=DEFAULTS)
    add_option(parser, "--em-max-iter", type=int, defaults=DEFAULTS, quick=QUICK, help="EM iterations")
    add_option(parser, "--m-step-max-iter", type=int, defaults=DEFAULTS, quick=QUICK, help="iterations per M-step")
    add_option(parser, "--n-test", type=int, defaults=DEFAULTS, quick=QUICK, help="new tasks of one-demo transfer")
    parser.add_argument("--quick", action="store_true", help="tiny configuration for tests")


def matched_deviation(mdp: Any, true_rewards: np.ndarray, learnt_rewards: np.ndarray) -> float:
    """Mean deviation (eq. 13) of true tasks (n, S, A) from learnt intentions (K, S, A), matched one to one.

    The (n, K) matrix of deviations of each true task from each intention's reward is matched by
    the Hungarian algorithm (:func:`factirl_opt.match_intentions`), and the matched deviations
    averaged over the tasks.
    """
    n, K = len(true_rewards), len(learnt_rewards)
    cost = np.array([[deviation(mdp, true_rewards[i], learnt_rewards[c]) for c in range(K)]
                     for i in range(n)])
    match = match_intentions(cost)
    return float(cost[np.arange(n), match].mean())


def _transfer(mdp, model, dictionary, s, seed):
    """Mean deviation of one-demo transfer to ``n_test`` new tasks of the true dictionary."""
    test = synthetic_tasks(mdp, s["n_test"], 1, s["length"], dictionary=dictionary, rng=seed + 10_000)
    model.transfer(mdp, test.demos)
    return float(np.mean(deviation(mdp, test.rewards, model.transfer_rewards_)))


def _one(mdp, n, seed, s):
    """The three learners on one draw of n tasks: ARI, matched train deviation, transfer, seconds."""
    k = s["n_primitives"]
    tasks = synthetic_tasks(mdp, n, s["n_demos"], s["length"], n_primitives=k, rng=seed)
    episodes = [ep for demos in tasks.demos for ep in demos]
    truth = np.repeat(np.arange(n), s["n_demos"])
    out: dict[str, Any] = {}
    t0 = time.perf_counter()
    lab = FactIRL(n_primitives=k, beta=s["beta"], rng=seed).fit(mdp, tasks.demos)
    out["labelled"] = {"ari": 1.0, "train_deviation": float(np.mean(deviation(mdp, tasks.rewards, lab.rewards_))),
                       "transfer_deviation": _transfer(mdp, lab, tasks.dictionary, s, seed),
                       "seconds": time.perf_counter() - t0}
    for name, kk in (("em_flat", None), ("em_shared", k)):
        t0 = time.perf_counter()
        em = MultiIntentIRL(n, n_primitives=kk, beta=s["beta"], max_iter=s["em_max_iter"],
                            m_step_max_iter=s["m_step_max_iter"], rng=seed).fit(mdp, episodes)
        out[name] = {"ari": adjusted_rand_index(truth, em.labels_),
                     "train_deviation": matched_deviation(mdp, tasks.rewards, em.rewards_),
                     "transfer_deviation": (None if kk is None else _transfer(mdp, em.to_factirl(), tasks.dictionary, s, seed)),
                     "best_log_likelihood": em.best_log_likelihood_, "n_iter": em.n_iter_,
                     "seconds": time.perf_counter() - t0}
    return out


def run(args: argparse.Namespace) -> dict:
    s = resolve_settings(args, DEFAULTS, QUICK)
    mdp = GridWorld(s["size"])
    rows = [{"n_tasks": n, "seed": seed, "learners": _one(mdp, n, seed, s)} for n in s["n_tasks"] for seed in s["seeds"]]
    return {"benchmark": "unlabeled", "rows": rows,
            "settings": {**{k: v for k, v in s.items() if k != "quick"}, "quick": bool(s["quick"])}}


if __name__ == "__main__":  # pragma: no cover
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    print(run(parser.parse_args()))
