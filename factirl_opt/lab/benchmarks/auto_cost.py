"""The cost of ``FactIRL(n_primitives="auto", residual_penalty="auto")`` relative to one fixed fit, side by side.

On a preset's grid world (default ``tiny``: 5x5, 8 training tasks x 5 demonstrations, its
budgets; ground truth of :func:`factirl_opt.lab.experiments.worlds.make_ground_truth` for each
seed), or with ``--readme`` on the README's own grid (the paper's 10x10 grid, 30 tasks x 10
demonstrations of 10 steps from a 5-primitive dictionary, ``FactIRL``'s defaults, ``n_primitives=5``
against ``"auto"``; 10 new tasks transferred from one demonstration), one process fits, in turn
and ``--repeats`` times: the fixed learner (k of the preset or 5, ``residual_penalty=inf``, its
own flat start), and the ``auto`` learner with each search route ``--routes``
(:data:`factirl_opt.learners.selection.ROUTES`, with the choice rule ``--rule``, by default each route's own; the flat start,
the search and the final fit). Prints per seed the median CPU time (``time.process_time``:
this process only, so other load on the machine counts less) of each, their ratio, the ratio
of the batched linear-solve calls (machine independent; counted by a
:class:`~factirl_opt.planning.CountingPlanner`), the candidate fits made, and the chosen
``(k, lambda)`` with its validation score, and the same pair's test deviation after transfer
from one demonstration.

``--quick`` is a tiny configuration for tests (options given explicitly keep their value).
``--searches`` is the former name of ``--routes``.
"""

import statistics
import time
import warnings
from types import SimpleNamespace

import numpy as np

from ...parallel import limit_blas_threads
from ...datasets.synthetic import random_coefficients, random_dictionary
from ...evaluation import deviation
from ...exceptions import ConvergenceWarning
from ...learners.factirl import FactIRL
from ...learners.fitting import learner_tasks
from ...learners.selection import DEFAULT_ROUTE, ROUTES, RULES, SharingSearch, fixed_learner
from ...learners.selection.search import own_flat_start_rewards
from ...learners.solver_settings import SolverSettings
from ...mdp import GridWorld
from ...objectives.sharding import Execution
from ...planning import CountingPlanner, get_planner
from ...tasks.features import task_rewards
from ...tasks.demonstrations import sample_demonstrations
from ..arguments import integer
from ..experiments.learner_solvers import factorial_options
from ..experiments.presets import PRESETS
from ..experiments.worlds import make_ground_truth
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run", "fit_auto", "readme_grid"]

GRID_PRESETS = sorted(name for name, p in PRESETS.items() if p.world == "grid")
DEFAULTS = {"preset": "tiny", "seeds": [0, 1], "repeats": 5, "routes": [DEFAULT_ROUTE, "race", "pca"],
            "rule": None, "blas_threads": 1}
QUICK = {"seeds": [0], "repeats": 1}


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--preset", choices=GRID_PRESETS, help="the grid preset whose world, sizes and budgets are used")
    opt("--seeds", type=integer(0), nargs="+", metavar="SEED", help="seeds of the ground truth (one problem each)")
    opt("--repeats", type=integer(1), help="fits of each learner per seed (the median is reported)")
    opt("--routes", "--searches", dest="routes", choices=list(ROUTES), nargs="+", metavar="NAME",
        help=f"search routes of the auto learner, of {', '.join(ROUTES)}")
    opt("--rule", choices=RULES, help="the choice rule of the auto learner (default: each route's own)")
    opt("--blas-threads", type=integer(0), help="OpenBLAS threads (0: leave as is)")
    parser.add_argument("--readme", action="store_true",
                        help="the README's grid (30 tasks x 10 demonstrations, FactIRL's defaults, k = 5) instead of a preset's")
    parser.add_argument("--quick", action="store_true",
                        help="tiny configuration for tests; options given explicitly keep their value")


def fit_auto(learner, mdp, demos, route=DEFAULT_ROUTE, rule=None):
    """What ``FactIRL.fit`` does for ``"auto"`` values, with the search ``route`` and ``rule`` (None:
    the route's own, :func:`~factirl_opt.learners.selection.route_rule`): the
    flat start of every task, the choice of ``(k, lambda)``, the final fit; returns the fitted model
    and its table (the rows of :func:`~factirl_opt.learners.selection.results.validation_rows`)."""
    learner = learner.set_params(sharing_search=SharingSearch(route=route, rule=rule))
    tasks = learner_tasks(learner, mdp, demos)
    flat = own_flat_start_rewards(learner, tasks)
    found = learner.sharing_search.search(learner, tasks, flat)
    model = fixed_learner(learner, found.n_primitives, found.residual_penalty)
    model.fit(mdp, demos, flat_rewards=flat)
    return model, found.rows


def readme_grid(seed=0):
    """The README's ten-line problem: the paper's 10x10 grid, 30 training tasks x 10 demonstrations of
    10 steps from a 5-primitive dictionary, 10 new tasks with one demonstration each (seeds 0-4 in
    the README; ``seed`` shifts them all)."""
    mdp = GridWorld(size=10, p_success=0.7, gamma=0.9)
    D = random_dictionary(mdp.n_params, 5, rng=seed)
    R = task_rewards(D, random_coefficients(30, 5, rng=seed + 1), mdp.n_states, mdp.n_actions)
    demos = sample_demonstrations(mdp, R, n_demos=10, length=10, rng=seed + 2)
    R_new = task_rewards(D, random_coefficients(10, 5, rng=seed + 3), mdp.n_states, mdp.n_actions)
    test = sample_demonstrations(mdp, R_new, 1, 10, rng=seed + 4)
    return SimpleNamespace(mdp=mdp, train_demos=demos, test_demos=test, test_rewards=R_new)


def _calls(planner):
    """Batched linear-solve calls (forward and transposed) of a counting planner: the planning work
    in calls, which is what costs at the small sizes where the tasks of a batch are cheap."""
    return int(planner.n_forward_calls + planner.n_transpose_calls)


def _timed(fn):
    t0 = time.process_time()
    out = fn()
    return out, time.process_time() - t0


def run(args):
    s = resolve_settings(args, DEFAULTS, QUICK)
    if s["readme"]:
        kw = {"n_primitives": 5, "execution": Execution()}  # FactIRL's defaults
    else:
        preset = PRESETS[s["preset"]]
        kw = factorial_options(preset, SolverSettings())
    out = {"settings": {k: v for k, v in s.items() if k != "quick"}, "seeds": {}}
    with limit_blas_threads(s["blas_threads"]), warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        for seed in s["seeds"]:
            gt = readme_grid(seed) if s["readme"] else make_ground_truth(preset, preset.default_tasks,
                                                                         preset.default_demos, seed)
            times = {"fixed": []} | {name: [] for name in s["routes"]}
            calls, chosen = {}, {}
            for _ in range(s["repeats"]):
                planner = CountingPlanner(get_planner(gt.mdp))
                fixed = FactIRL(rng=seed, **{**kw, "execution": kw["execution"].set_params(planner=planner)})
                _, t = _timed(lambda: fixed.fit(gt.mdp, gt.train_demos))
                times["fixed"].append(t)
                calls["fixed"] = _calls(planner)
                for name in s["routes"]:
                    planner = CountingPlanner(get_planner(gt.mdp))
                    auto = FactIRL(rng=seed, **{**kw, "execution": kw["execution"].set_params(planner=planner),
                                                "n_primitives": "auto", "residual_penalty": "auto"})
                    (model, table), t = _timed(lambda: fit_auto(auto, gt.mdp, gt.train_demos, name, s["rule"]))
                    times[name].append(t)
                    calls[name] = _calls(planner)
                    model.transfer(gt.mdp, gt.test_demos)
                    best = next(r for r in table if r["chosen"])
                    chosen[name] = {"n_primitives": model.n_primitives_, "residual_penalty": model.residual_penalty_,
                                    "score": best["score"], "candidates": len(table),
                                    "candidate_fits": int(sum(len(r["fold_scores"]) for r in table)),
                                    "test_deviation": float(np.mean(deviation(gt.mdp, gt.test_rewards, model.transfer_rewards_)))}
            fixed.transfer(gt.mdp, gt.test_demos)
            median = {name: statistics.median(v) for name, v in times.items()}
            out["seeds"][str(seed)] = {
                "cpu_time_s": median, "cpu_times_s": times, "planner_calls": calls,
                "time_ratio": {name: median[name] / median["fixed"] for name in s["routes"]},
                "calls_ratio": {name: calls[name] / calls["fixed"] for name in s["routes"]},
                "chosen": chosen,
                "fixed_test_deviation": float(np.mean(deviation(gt.mdp, gt.test_rewards, fixed.transfer_rewards_))),
            }
    return out
