"""Policies for new tasks: generalised policy improvement (GPI) over successor features against planning each task.

Per world (:data:`WORLDS`, each a preset of the harness with a few changes) and seed, one process:

1. learns a dictionary on the world's training tasks (``FactIRL``, policy matching, the preset's
   solvers and budgets; ``fit_cpu_s``);
2. draws ``--n-new`` new tasks from the world's true task distribution (the grid: the preset's
   coefficients on the true primitives; Objectworld: ELIRL's rule, ``multitask_rewards``; with a
   map per task, new task ``i`` on training map ``i mod n_train``). Their *learnt* coefficients
   ``h`` are the least-squares projection of the true reward on the learnt primitive rewards
   ``Phi D`` of the task's map (the best reward the dictionary's span holds, in place of a
   transfer from demonstrations): the new tasks lie in the learnt dictionary's span;
3. measures CPU time (``time.process_time``), side by side, the planner's caches emptied before
   each: the library (``library_cpu_s``: ``FactIRL.gpi_policies`` on one task per map, which plans
   the library's policies and computes their successor features once), then the policies of
   every new task by GPI (``gpi_cpu_s``), by GPI and one exact improvement step (``gpi1_cpu_s``),
   and by planning each task's learnt reward exactly (``plan_cpu_s``: ``optimal_q``, ``--plan-chunk``
   tasks at a time; the rewards are built before the clock starts);
4. scores the three policies exactly: the value loss ``mean_s (V*(s) - V^pi(s))`` (the units of
   ``fo.deviation``) under the learnt reward (against the planned policy, optimal there) and under
   the true reward (against the true optimum), averaged over the new tasks; and checks GPI's
   theorem on every task (the GPI policy's value under the learnt reward, uniform start, against
   the best library policy's from ``gpi_report_``).

The acceptance ratios are reported as ``cpu_gpi_over_plan``, ``true_loss_gpi_over_plan`` and
``true_loss_gpi1_over_plan``. ``--library`` chooses the library's parts (default ``FactIRL.gpi_policies``'s: primitives,
negatives, tasks; add ``other-tasks`` on a map per task to carry every training task to every map).
``--quick``: the tiny worlds and 20 new tasks, for tests.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from ...datasets.objectworld import make_objectworld, multitask_rewards, state_action_rewards
from ...datasets.synthetic import random_coefficients
from ...learners.factirl import FactIRL
from ...learners.gpi import DEFAULT_PARTS, LIBRARY_PARTS
from ...parallel import limit_blas_threads
from ...planning import clear_caches, optimal_q, policy_evaluation
from ...tasks.task_set import reward_basis
from ..arguments import integer
from ..experiments.learner_solvers import factorial_options
from ..experiments.presets import PRESETS
from ..experiments.worlds import make_ground_truth
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run", "WORLDS", "DEFAULTS", "QUICK", "world_run"]

#: world name -> (preset, training tasks, demonstrations per task, changes to the preset)
WORLDS: dict[str, tuple[str, int, int, dict[str, Any]]] = {
    "grid": ("fast", 100, 10, {}),
    "objectworld-per-task": ("objectworld-per-task", 20, 32, {}),
    "objectworld-100": ("objectworld", 20, 16, {"grid_size": 100, "fact_max_iter": 10, "flat_max_iter": 20}),
    # the same map and tasks, fitted with the objectworld preset's own budgets (a closer learnt reward)
    "objectworld-100-full-fit": ("objectworld", 20, 16, {"grid_size": 100}),
    "grid-tiny": ("tiny", 8, 5, {}),
    "objectworld-per-task-tiny": ("objectworld-per-task-quick", 4, 8, {"fact_max_iter": 3, "flat_max_iter": 5}),
    "objectworld-tiny": ("objectworld-tiny", 6, 4, {}),
}
DEFAULTS = {"worlds": ["grid", "objectworld-per-task", "objectworld-100"], "seeds": [0], "n_new": 1000,
            "plan_chunk": 50, "library": list(DEFAULT_PARTS), "blas_threads": 1}
QUICK = {"worlds": ["grid-tiny", "objectworld-per-task-tiny", "objectworld-tiny"], "n_new": 20, "plan_chunk": 8}

#: the first word of the new tasks' seeds, apart from the ground truth's streams
_NEW_TASKS_STREAM = 0x677069


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--worlds", nargs="+", choices=list(WORLDS), help="worlds to run")
    opt("--seeds", type=integer(0), nargs="+", metavar="SEED", help="seeds of the ground truth")
    opt("--n-new", type=integer(1), help="new tasks per world")
    opt("--plan-chunk", type=integer(1), help="new tasks planned (and scored) at once")
    opt("--library", nargs="+", choices=LIBRARY_PARTS, help="the GPI library's parts")
    opt("--blas-threads", type=integer(1), help="BLAS threads")
    parser.add_argument("--quick", action="store_true", help="the tiny worlds and 20 new tasks, for tests")


@dataclasses.dataclass
class _Problem:
    """A world's fitted model and new tasks, map by map (``maps``: per map, the new tasks on it)."""

    model: Any
    mdps: list  # per map
    features: list  # per map (None: the model's own)
    maps: list  # per map: indices of the new tasks on it
    phi: list  # per map: the learnt primitive rewards (k, S, A)
    H: np.ndarray  # (n_new, k) learnt coefficients
    true_rewards: Any  # (map index, task indices) -> (r, S, A)
    fit_cpu_s: float
    n_train: int


def _preset(name):
    base, _, _, changes = WORLDS[name]
    return dataclasses.replace(PRESETS[base], name=f"gpi-{name}", n_test_tasks=1, **changes)


def _project(phi, R):
    """Least-squares coefficients (r, k) of rewards R (r, S, A) on the primitive rewards phi (k, S, A)."""
    k = phi.shape[0]
    return np.linalg.lstsq(phi.reshape(k, -1).T, R.reshape(R.shape[0], -1).T, rcond=None)[0].T


def problem(name, n_new, seed):
    """Fit the world's model and draw its new tasks (see the module docstring)."""
    preset = _preset(name)
    _, n_train, n_demos, _ = WORLDS[name]
    gt = make_ground_truth(preset, n_train, n_demos, seed)
    per_task = "train" in gt.task_maps
    train_mdps = gt.mdps("train")
    train_feats = list(gt.task_maps["train"].features) if per_task else gt.features
    t = time.process_time()
    model = FactIRL(rng=seed, features=train_feats,
                    **factorial_options(preset, preset.solvers, "policy-matching", features=train_feats is not None))
    model.fit(train_mdps, gt.train_demos)
    fit_cpu = time.process_time() - t
    rng = np.random.default_rng([_NEW_TASKS_STREAM, seed])
    D = model.dictionary_
    k = D.shape[1]
    if per_task:
        maps = gt.task_maps["train"]
        H_true = multitask_rewards(maps.worlds[0], n_new, rng=rng)[1]
        owner = np.arange(n_new) % n_train
        mdps, feats = [maps.mdps[j] for j in range(n_train)], [maps.features[j] for j in range(n_train)]
        tasks = [np.flatnonzero(owner == j) for j in range(n_train)]

        def true_rewards(j, rows):
            return state_action_rewards(H_true[rows] @ maps.primitives[j].T, maps.mdps[j].n_actions)
    elif preset.world == "objectworld":
        world = make_objectworld(preset.grid_size, preset.n_primitives, preset.n_outer_colours, determinism=preset.p_success,
                                 gamma=preset.gamma, objects=gt.map_extras["objects"])
        R_state = multitask_rewards(world, n_new, rng=rng)[0]
        mdps, feats, tasks = [gt.mdp], [None], [np.arange(n_new)]

        def true_rewards(j, rows):
            return state_action_rewards(R_state[rows], gt.mdp.n_actions)
    else:
        H_true = random_coefficients(n_new, gt.dictionary.shape[1], kind=preset.coefficient_kind, rng=rng)
        mdps, feats, tasks = [gt.mdp], [None], [np.arange(n_new)]
        S, A = gt.mdp.n_states, gt.mdp.n_actions

        def true_rewards(j, rows):
            return (H_true[rows] @ gt.dictionary.T).reshape(len(rows), S, A)
    phi, H = [], np.empty((n_new, k))
    for j, (m, f) in enumerate(zip(mdps, feats)):
        basis = reward_basis(m, model.features if f is None else f, model.reward, k)
        phi.append(np.asarray(basis.factorial_rewards(D, np.eye(k))).reshape(k, m.n_states, m.n_actions))
        H[tasks[j]] = _project(phi[j], true_rewards(j, tasks[j]))
    return _Problem(model, mdps, feats, tasks, phi, H, true_rewards, fit_cpu, n_train)


def _per_task(p, values):
    """Per-map arrays (in ``p.maps`` order) to the new tasks' list of ``mdp``/``features`` arguments."""
    n = p.H.shape[0]
    out = [None] * n
    for j, rows in enumerate(p.maps):
        for i in rows:
            out[i] = values[j]
    return out


def _timed(fn):
    t = time.process_time()
    out = fn()
    return time.process_time() - t, out


def _clear(p):
    for m in {id(m): m for m in p.mdps}.values():
        clear_caches(m)


def world_run(name, s, seed):
    """One world's row of the benchmark (see the module docstring)."""
    p = problem(name, s["n_new"], seed)
    model, n = p.model, p.H.shape[0]
    mdp_args = _per_task(p, p.mdps)
    feat_args = None if p.features[0] is None else _per_task(p, p.features)
    library = tuple(s["library"])
    # the library: built once, on one task per map
    firsts = [int(rows[0]) for rows in p.maps]
    _clear(p)
    library_cpu, _ = _timed(lambda: model.gpi_policies([mdp_args[i] for i in firsts], p.H[firsts],
                                                       features=None if feat_args is None else [feat_args[i] for i in firsts],
                                                       library=library, evaluate=False))
    values = model.gpi_report_.library_values
    L = [len(v) for v in values] if isinstance(values, list) else [values.shape[1]]
    _clear(p)
    gpi_cpu, pol_gpi = _timed(lambda: model.gpi_policies(mdp_args, p.H, features=feat_args, library=library, evaluate=False))
    report = model.gpi_report_
    _clear(p)
    gpi1_cpu, pol_gpi1 = _timed(lambda: model.gpi_policies(mdp_args, p.H, features=feat_args, library=library,
                                                           improvement_steps=1, evaluate=False))
    pol_plan = np.empty_like(pol_gpi)
    plan_cpu = 0.0
    _clear(p)
    for j, rows in enumerate(p.maps):
        for lo in range(0, len(rows), s["plan_chunk"]):
            r = rows[lo:lo + s["plan_chunk"]]
            R = (p.H[r] @ p.phi[j].reshape(p.phi[j].shape[0], -1)).reshape(len(r), *p.phi[j].shape[1:])
            t = time.process_time()
            pol_plan[r] = optimal_q(p.mdps[j], R, planner=model._group("execution").planner)[1]
            plan_cpu += time.process_time() - t
    # exact values of the three policies under the learnt and the true rewards
    names = ("plan", "gpi", "gpi1")
    policies = dict(zip(names, (pol_plan, pol_gpi, pol_gpi1)))
    learnt = {key: np.empty(n) for key in names}
    true = {key: np.empty(n) for key in names}
    optimal_true = np.empty(n)
    for j, rows in enumerate(p.maps):
        m = p.mdps[j]
        for lo in range(0, len(rows), s["plan_chunk"]):
            r = rows[lo:lo + s["plan_chunk"]]
            R = (p.H[r] @ p.phi[j].reshape(p.phi[j].shape[0], -1)).reshape(len(r), *p.phi[j].shape[1:])
            Rt = p.true_rewards(j, r)
            Q_true = optimal_q(m, Rt, planner=model._group("execution").planner)[0]
            optimal_true[r] = Q_true.max(axis=2).mean(axis=1)
            for key in names:
                learnt[key][r] = policy_evaluation(m, R, policies[key][r], planner=model._group("execution").planner).mean(axis=1)
                true[key][r] = policy_evaluation(m, Rt, policies[key][r], planner=model._group("execution").planner).mean(axis=1)
            clear_caches(m)
    learnt_loss = {key: float(np.mean(learnt["plan"] - learnt[key])) for key in names}
    true_loss = {key: float(np.mean(optimal_true - true[key])) for key in names}
    slack = 1e-9 * np.maximum(1.0, np.abs(report.best_library_value))
    violations = int(np.count_nonzero(learnt["gpi"] < report.best_library_value - slack))
    best_library_loss = float(np.mean(learnt["plan"] - report.best_library_value))
    return {
        "n_states": int(p.mdps[0].n_states), "n_actions": int(p.mdps[0].n_actions), "n_maps": len(p.mdps),
        "n_train": p.n_train, "n_new": n, "k": int(p.H.shape[1]), "library": list(library), "library_size": L,
        "fit_cpu_s": p.fit_cpu_s, "fit_status": model.status_,
        "library_cpu_s": library_cpu, "gpi_cpu_s": gpi_cpu, "gpi1_cpu_s": gpi1_cpu, "plan_cpu_s": plan_cpu,
        "cpu_gpi_over_plan": gpi_cpu / plan_cpu, "cpu_gpi1_over_plan": gpi1_cpu / plan_cpu,
        "cpu_library_over_plan": library_cpu / plan_cpu,
        "learnt_loss": learnt_loss, "best_library_learnt_loss": best_library_loss, "true_loss": true_loss,
        "true_loss_gpi_over_plan": true_loss["gpi"] / true_loss["plan"] if true_loss["plan"] > 0 else None,
        "true_loss_gpi1_over_plan": true_loss["gpi1"] / true_loss["plan"] if true_loss["plan"] > 0 else None,
        "gpi_equals_plan": float(np.mean(np.all(pol_gpi == pol_plan, axis=1))),
        "gpi1_equals_plan": float(np.mean(np.all(pol_gpi1 == pol_plan, axis=1))),
        "theorem_violations": violations,
    }


def run(args):
    s = resolve_settings(args, DEFAULTS, QUICK)
    result: dict[str, Any] = {"settings": {k: v for k, v in s.items() if k != "quick"}, "worlds": {}}
    with limit_blas_threads(s["blas_threads"]):
        for name in s["worlds"]:
            result["worlds"][name] = {str(seed): world_run(name, s, seed) for seed in s["seeds"]}
    return result
