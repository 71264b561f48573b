"""Unlabeled against labelled demonstrations, on the paper's grid or on Objectworld, as the number of tasks grows.

For each number of tasks n (default 4, 10, 20) and each seed, n tasks are drawn in the chosen
world (``--world``), the task labels are dropped, and three learners fit the same
demonstrations:

- ``labelled``: :class:`factirl_opt.FactIRL` given the task labels (the reference);
- ``em_flat``: :class:`factirl_opt.MultiIntentIRL` with ``n_primitives=None`` (each intention
  its own reward; Babes-Vroman's EM), K = n intentions;
- ``em_shared``: :class:`factirl_opt.MultiIntentIRL` with ``n_primitives=k`` (a dictionary shared
  by the intentions, the paper's model).

Two more learners, chosen by ``--learners``, bound what the shared EM could reach by fixing the
dictionary it learns: EM over K intentions whose rewards are ``Phi_fixed h_c`` with the k
columns of ``Phi_fixed`` given as features (k coefficients per intention, nothing shared to
learn):

- ``em_true_dictionary``: the true primitives (the grid's dictionary; Objectworld's colour
  primitives);
- ``em_labelled_dictionary``: the dictionary of the ``labelled`` learner (``Phi D`` on the
  world's features), learnt with the task labels.

And one tells whether the likelihood itself points at the tasks: ``em_shared_true_start``, the
shared EM started from the true labels instead of its default start (compare its
``best_log_likelihood`` and ARI with ``em_shared``'s).

Worlds (:data:`WORLDS`):

``"grid"`` (the paper's)
    ``GridWorld(size)``; tasks drawn from a random dictionary of k primitives
    (:func:`factirl_opt.synthetic_tasks`, ``rng=seed``), ``n_demos`` demonstrations of
    ``length`` steps per task; tabular rewards (no base features). Test tasks: ``n_test`` new
    tasks of the true dictionary (``rng=seed + 10000``).
``"objectworld"`` (ELIRL's multi-task Objectworld on one map)
    The world of the ``objectworld`` experiments (:func:`factirl_opt.lab.experiments.worlds.objectworld`)
    with the ``objectworld-quick`` preset's colours (c1 = k inner, 2 outer), object density
    (0.05), determinism (0.7) and gamma (0.9) at side ``size``: one map, tasks by ELIRL's rule
    (2-4 inner colours each, reward ``sum_c w_c 1[distance to colour c < 3]``), the greedy
    expert's demonstrations. Every learner's rewards live on Levine's discrete features of the
    map (S, (N-1)(c1+c2)) (``features=``; docs/maths.md §7). Test tasks: ``n_test`` new tasks
    on the same map. The seed's streams are the world's, so for one seed the map and the test
    tasks are the same at every n, and the tasks of a smaller n are the first of a larger one.

``--objective`` sets every learner's objective (policy matching by default; with ``"mce"`` the
EM's M-step raises its own likelihood, docs/maths.md §6); the oracle always uses the Boltzmann
policy.

Scores per learner: the adjusted Rand index of its labels against the true tasks (1 for the
labelled learner), the mean train deviation (eq. 13, docs/maths.md §9) of the recovered rewards
with intentions matched to true tasks by the Hungarian algorithm on the deviation matrix
(:func:`factirl_opt.match_intentions`), and, for the learners with a dictionary, the mean
deviation of one-demonstration transfer (:meth:`factirl_opt.FactIRL.transfer`, docs/maths.md §8)
to the test tasks, one demonstration of ``length`` steps each. Each row also gives
``oracle_ari``, the adjusted Rand index of :func:`oracle_labels` (every episode assigned to the
true task under whose Boltzmann policy it is most likely): how far the demonstrations can be
told apart at all.

``--size``, ``--n-demos`` and ``--length`` default to the world's values (:data:`WORLD_DEFAULTS`;
with ``--quick``, :data:`WORLD_QUICK`). ``--quick`` is a tiny configuration for tests (options
given explicitly keep their value).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from typing import Any, Callable

import numpy as np
from scipy.special import logsumexp

from ...validation import check_int
from ...evaluation import deviation
from ...exceptions import ValidationError
from ..arguments import integer, real
from ..experiments.presets import get_preset
from ..experiments.worlds import objectworld
from ...learners.start import IntentionStart
from ...learners.factirl import FactIRL
from ...mdp.tabular import GridWorld, TabularMDP
from ...objectives import available_objectives, get_objective
from ...planning import optimal_q
from ...learners.multi_intent import MultiIntentIRL, adjusted_rand_index, match_intentions
from ...datasets.synthetic import synthetic_tasks
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run", "settings", "matched_deviation", "oracle_labels", "Draw", "draw_grid", "draw_objectworld", "LEARNERS", "EM_LEARNERS", "WORLDS",
           "WORLD_DEFAULTS", "WORLD_QUICK"]

DEFAULTS = {"n_tasks": [4, 10, 20], "seeds": [0], "world": "grid", "n_primitives": 5,
            "learners": ["labelled", "em_flat", "em_shared"],
            "beta": 5.0, "objective": "policy-matching", "em_max_iter": 20, "m_step_max_iter": 20, "n_test": 5}
QUICK = {"n_tasks": [2], "n_primitives": 2, "em_max_iter": 2, "m_step_max_iter": 3, "n_test": 1}
#: world -> defaults of the options whose value depends on the world
WORLD_DEFAULTS = {"grid": {"size": 10, "n_demos": 10, "length": 10},
                  "objectworld": {"size": 16, "n_demos": 10, "length": 16}}
#: world -> the same under ``--quick``
WORLD_QUICK = {"grid": {"size": 4, "n_demos": 3, "length": 5},
               "objectworld": {"size": 5, "n_demos": 3, "length": 5}}
#: the Objectworld experiments' preset whose colours, density, dynamics and planner the world takes
OBJECTWORLD_PRESET = "objectworld-quick"
#: EM learner -> (learns a shared dictionary, dictionary held fixed as its features or None, starts from the true labels)
EM_LEARNERS = {"em_flat": (False, None, False), "em_shared": (True, None, False),
               "em_true_dictionary": (False, "true", False), "em_labelled_dictionary": (False, "labelled", False),
               "em_shared_true_start": (True, None, True)}
#: every learner ``--learners`` can name; the first three are the default line-up
LEARNERS = ("labelled", *EM_LEARNERS)


@dataclasses.dataclass
class Draw:
    """One draw of a world's tasks: what the learners see and are scored against.

    Attributes
    ----------
    mdp : TabularMDP
    features : ndarray, shape (S, p), or None
        The base features every learner's rewards live on; None for tabular rewards.
    rewards : ndarray, shape (n, S, A)
        True rewards of the n training tasks.
    demos : list of n int arrays, each (n_demos, length, 2)
    test_rewards : ndarray, shape (n_test, S, A)
        True rewards of the transfer tasks.
    test_demos : list of n_test int arrays, each (1, length, 2)
    dictionary : ndarray, shape (S*A, k) or (S, k)
        The true primitive rewards (the tasks' rewards are combinations of its columns).
    """

    mdp: TabularMDP
    features: np.ndarray | None
    rewards: np.ndarray
    demos: list
    test_rewards: np.ndarray
    test_demos: list
    dictionary: np.ndarray


def draw_grid(s: dict, n: int, seed: int) -> Draw:
    """n tasks of a random dictionary of ``s["n_primitives"]`` primitives on ``GridWorld(s["size"])``."""
    mdp = GridWorld(s["size"])
    tasks = synthetic_tasks(mdp, n, s["n_demos"], s["length"], n_primitives=s["n_primitives"], rng=seed)
    test = synthetic_tasks(mdp, s["n_test"], 1, s["length"], dictionary=tasks.dictionary, rng=seed + 10_000)
    return Draw(mdp, None, np.asarray(tasks.rewards), tasks.demos, np.asarray(test.rewards), test.demos,
                np.asarray(tasks.dictionary))


def draw_objectworld(s: dict, n: int, seed: int) -> Draw:
    """n tasks on one Objectworld map of side ``s["size"]`` with ``s["n_primitives"]`` inner colours."""
    preset = dataclasses.replace(get_preset(OBJECTWORLD_PRESET), name="unlabeled-objectworld", grid_size=s["size"],
                                 n_primitives=s["n_primitives"], demo_length=s["length"], n_test_tasks=s["n_test"],
                                 beta=s["beta"])
    gt = objectworld(preset, n, s["n_demos"], seed)
    return Draw(gt.mdp, gt.features, gt.train_rewards, gt.train_demos, gt.test_rewards, gt.test_demos, gt.dictionary)


#: world name -> ``(settings, n_tasks, seed) -> Draw``
WORLDS: dict[str, Callable[[dict, int, int], Draw]] = {"grid": draw_grid, "objectworld": draw_objectworld}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_option(parser, "--n-tasks", type=integer(1), nargs="+", defaults=DEFAULTS, quick=QUICK, help="numbers of tasks")
    add_option(parser, "--seeds", type=integer(0), nargs="+", defaults=DEFAULTS, help="task and demonstration seeds")
    add_option(parser, "--world", choices=sorted(WORLDS), defaults=DEFAULTS, help="the paper's grid or one Objectworld map")
    add_option(parser, "--learners", nargs="+", choices=LEARNERS, defaults=DEFAULTS,
               help="learners to run (em_true_dictionary, em_labelled_dictionary: EM with that dictionary fixed; "
                    "em_shared_true_start: the shared EM started from the true labels)")
    for flag, what in (("--size", "grid side"), ("--n-demos", "demonstrations per task"),
                       ("--length", "steps per demonstration")):
        dest = flag[2:].replace("-", "_")
        shown = "; ".join(f"{w} {WORLD_DEFAULTS[w][dest]} (--quick: {WORLD_QUICK[w][dest]})" for w in WORLDS)
        parser.add_argument(flag, type=integer(2 if flag == "--size" else 1), default=None, help=f"{what} (default: {shown})")
    add_option(parser, "--n-primitives", type=integer(1), defaults=DEFAULTS, quick=QUICK,
               help="k of the true and learnt dictionaries (Objectworld: also its inner colours)")
    add_option(parser, "--beta", type=real(0, low_open=True), defaults=DEFAULTS)
    add_option(parser, "--objective", choices=[name for name in available_objectives() if get_objective(name).models_policy()], defaults=DEFAULTS,
               help="every learner's objective (MCE: EM's M-step raises its likelihood)")
    add_option(parser, "--em-max-iter", type=integer(0), defaults=DEFAULTS, quick=QUICK, help="EM iterations")
    add_option(parser, "--m-step-max-iter", type=integer(0), defaults=DEFAULTS, quick=QUICK, help="iterations per M-step")
    add_option(parser, "--n-test", type=integer(1), defaults=DEFAULTS, quick=QUICK, help="new tasks of one-demo transfer")
    parser.add_argument("--quick", action="store_true", help="tiny configuration for tests")


def settings(args: argparse.Namespace) -> dict:
    """The run's settings: explicit options > ``--quick`` values > defaults (the world's where they depend on it).

    Raises
    ------
    ValidationError
        On an unknown world or a count below 1 (sizes below 2).
    """
    s = resolve_settings(args, DEFAULTS, QUICK)
    if s["world"] not in WORLDS:
        raise ValidationError(f"world must be one of {', '.join(map(repr, WORLDS))}; got {s['world']!r}")
    world_values = (WORLD_QUICK if s["quick"] else WORLD_DEFAULTS)[s["world"]]
    for key, value in world_values.items():
        if s.get(key) is None:
            s[key] = value
    for key in ("n_demos", "length", "n_primitives", "em_max_iter", "m_step_max_iter", "n_test"):
        s[key] = check_int(s[key], key, minimum=1)
    s["size"] = check_int(s["size"], "size", minimum=2)
    s["n_tasks"] = [check_int(n, "n_tasks", minimum=1) for n in s["n_tasks"]]
    s["quick"] = bool(s["quick"])
    s["learners"] = list(dict.fromkeys(s["learners"]))  # each once, in the order given
    return s


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


def oracle_labels(mdp: TabularMDP, rewards: np.ndarray, episodes: list, beta: float) -> np.ndarray:
    """Each episode's most likely true task: how well the episodes can be told apart when the rewards are known.

    The upper bound of an E-step at the true rewards (its labels with uniform mixture weights):
    an EM with learnt rewards can get further from the truth, and an EM kept near the true
    partition can score above it.

    The log-likelihood of episode j under task i is ``sum_t log pi_i(a_t | s_t)`` with ``pi_i``
    the Boltzmann policy (eq. 7, inverse temperature ``beta``) of ``Q*`` of the true reward
    ``rewards[i]`` (docs/maths.md §2); each episode goes to the task of highest log-likelihood
    (first on ties).

    Parameters
    ----------
    mdp : TabularMDP
    rewards : ndarray, shape (n, S, A)
        True rewards of the n tasks.
    episodes : list of int arrays, each (L, 2)
        ``(state, action)`` rows.
    beta : float

    Returns
    -------
    labels : ndarray of int, shape (n_episodes,)
    """
    Q, _ = optimal_q(mdp, rewards)
    z = beta * np.asarray(Q)
    log_pi = z - logsumexp(z, axis=-1, keepdims=True)  # (n, S, A)
    loglik = np.array([log_pi[:, ep[:, 0], ep[:, 1]].sum(axis=1) for ep in episodes])  # (n_episodes, n)
    return np.argmax(loglik, axis=1)


def _transfer(draw: Draw, model: FactIRL) -> float:
    """Mean deviation of one-demo transfer to the draw's test tasks."""
    model.transfer(draw.mdp, draw.test_demos)
    return float(np.mean(deviation(draw.mdp, draw.test_rewards, model.transfer_rewards_)))


def _fixed_dictionary(draw: Draw, which: str, labelled: FactIRL | None) -> np.ndarray:
    """The ``"true"`` or ``"labelled"`` dictionary's columns, taken as features: (S*A, k) or (S, k)."""
    if which == "true":
        return np.asarray(draw.dictionary)
    assert labelled is not None  # fitted by _one whenever this learner is asked for
    D = labelled.dictionary_
    return D if draw.features is None else np.asarray(draw.features) @ D


def _one(draw: Draw, seed: int, s: dict) -> dict[str, Any]:
    """The chosen learners on one draw of n tasks: ARI, matched train deviation, transfer, seconds."""
    k, n, mdp, features = s["n_primitives"], len(draw.demos), draw.mdp, draw.features
    episodes = [ep for demos in draw.demos for ep in demos]
    truth = np.repeat(np.arange(n), [len(demos) for demos in draw.demos])
    out: dict[str, Any] = {}
    lab = None
    if {"labelled", "em_labelled_dictionary"} & set(s["learners"]):
        t0 = time.perf_counter()
        lab = FactIRL(n_primitives=k, beta=s["beta"], features=features, objective=s["objective"],
                      rng=seed).fit(mdp, draw.demos)
        seconds = time.perf_counter() - t0
        if "labelled" in s["learners"]:
            out["labelled"] = {"ari": 1.0, "train_deviation": float(np.mean(deviation(mdp, draw.rewards, lab.rewards_))),
                               "transfer_deviation": _transfer(draw, lab), "seconds": seconds}
    for name in s["learners"]:
        if name == "labelled":
            continue
        t0 = time.perf_counter()
        shared, fixed, true_start = EM_LEARNERS[name]
        kk = k if shared else None
        em = MultiIntentIRL(n, n_primitives=kk, beta=s["beta"], objective=s["objective"], max_iter=s["em_max_iter"],
                            m_step_max_iter=s["m_step_max_iter"],
                            features=features if fixed is None else _fixed_dictionary(draw, fixed, lab),
                            start=IntentionStart(init=truth if true_start else "agreement"), rng=seed).fit(mdp, episodes)
        out[name] = {"ari": adjusted_rand_index(truth, em.labels_),
                     "train_deviation": matched_deviation(mdp, draw.rewards, em.rewards_),
                     "transfer_deviation": None if kk is None else _transfer(draw, em.to_factirl()),
                     "best_log_likelihood": em.best_log_likelihood_, "n_iter": em.n_iter_,
                     "seconds": time.perf_counter() - t0}
    return out


def run(args: argparse.Namespace) -> dict:
    s = settings(args)
    draw = WORLDS[s["world"]]
    rows = []
    for n in s["n_tasks"]:
        for seed in s["seeds"]:
            d = draw(s, n, seed)
            truth = np.repeat(np.arange(n), [len(demos) for demos in d.demos])
            oracle = oracle_labels(d.mdp, d.rewards, [ep for demos in d.demos for ep in demos], s["beta"])
            rows.append({"n_tasks": n, "seed": seed, "oracle_ari": adjusted_rand_index(truth, oracle),
                         "learners": _one(d, seed, s)})
    return {"benchmark": "unlabeled", "rows": rows, "settings": s}


if __name__ == "__main__":  # pragma: no cover
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    print(run(parser.parse_args()))
