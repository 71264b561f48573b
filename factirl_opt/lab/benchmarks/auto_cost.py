"""The cost of ``FactIRL(n_primitives="auto", residual_penalty="auto")`` relative to one fixed fit, side by side.

On a preset's grid world (default ``tiny``: 5x5, 8 training tasks x 5 demonstrations, its
budgets; ground truth of :func:`factirl_opt.lab.experiments.worlds.make_ground_truth` for each
seed), one process fits, in turn and ``--repeats`` times: the fixed learner (the preset's
FactIRL, k of the preset, ``residual_penalty=inf``, its own flat start), and the ``auto``
learner with each validation ``--searches`` (:data:`factirl_opt.learners.adaptive.SEARCHES`;
the flat start, the validation and the final fit). Prints per seed the median CPU time
(``time.process_time``: this process only, so other load on the machine counts less) of
each, their ratio, the ratio of the batched linear-solve calls (machine independent; counted
by a :class:`~factirl_opt.planning.CountingPlanner`), the candidate fits made, and the chosen
``(k, lambda)`` with its validation score, and the same pair's test deviation after transfer
from one demonstration.

``--quick`` is a tiny configuration for tests (options given explicitly keep their value).
"""

import statistics
import time
import warnings

import numpy as np

from ...parallel import limit_blas_threads
from ...evaluation import deviation
from ...exceptions import ConvergenceWarning
from ...learners import adaptive
from ...learners.factirl import FLAT_SOLVER, FLAT_TOL, FactIRL
from ...learners.solver_settings import SolverSettings
from ...planning import CountingPlanner, get_planner
from ..arguments import integer
from ..experiments.learner_solvers import factorial_options
from ..experiments.presets import PRESETS
from ..experiments.worlds import make_ground_truth
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run", "fit_auto"]

GRID_PRESETS = sorted(name for name, p in PRESETS.items() if p.world == "grid")
DEFAULTS = {"preset": "tiny", "seeds": [0, 1], "repeats": 5, "searches": list(adaptive.SEARCHES), "blas_threads": 1}
QUICK = {"seeds": [0], "repeats": 1}


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--preset", choices=GRID_PRESETS, help="the grid preset whose world, sizes and budgets are used")
    opt("--seeds", type=integer(0), nargs="+", metavar="SEED", help="seeds of the ground truth (one problem each)")
    opt("--repeats", type=integer(1), help="fits of each learner per seed (the median is reported)")
    opt("--searches", choices=adaptive.SEARCHES, nargs="+", metavar="NAME",
        help=f"validation searches of the auto learner, of {', '.join(adaptive.SEARCHES)}")
    opt("--blas-threads", type=integer(0), help="OpenBLAS threads (0: leave as is)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny configuration for tests; options given explicitly keep their value")


def fit_auto(learner, mdp, demos, search):
    """What ``FactIRL.fit`` does for ``"auto"`` values, with the validation ``search``: the flat
    start of every task, the choice of ``(k, lambda)``, the final fit; returns the fitted model and its table."""
    flat = adaptive.flat_start_rewards(learner, mdp, demos, FLAT_SOLVER, FLAT_TOL)
    k, lam, table = adaptive.choose_sharing(learner, mdp, demos, flat, search=search)
    model = adaptive.fixed_learner(learner, k, lam)
    model.fit(mdp, demos, flat_rewards=flat)
    return model, table


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
    preset = PRESETS[s["preset"]]
    kw = factorial_options(preset, SolverSettings())
    out = {"settings": {k: v for k, v in s.items() if k != "quick"}, "seeds": {}}
    with limit_blas_threads(s["blas_threads"]), warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        for seed in s["seeds"]:
            gt = make_ground_truth(preset, preset.default_tasks, preset.default_demos, seed)
            times = {"fixed": []} | {name: [] for name in s["searches"]}
            calls, chosen = {}, {}
            for _ in range(s["repeats"]):
                planner = CountingPlanner(get_planner(gt.mdp))
                fixed = FactIRL(rng=seed, **{**kw, "planner": planner})
                _, t = _timed(lambda: fixed.fit(gt.mdp, gt.train_demos))
                times["fixed"].append(t)
                calls["fixed"] = _calls(planner)
                for name in s["searches"]:
                    planner = CountingPlanner(get_planner(gt.mdp))
                    auto = FactIRL(rng=seed, **{**kw, "planner": planner, "n_primitives": "auto", "residual_penalty": "auto"})
                    (model, table), t = _timed(lambda: fit_auto(auto, gt.mdp, gt.train_demos, name))
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
                "time_ratio": {name: median[name] / median["fixed"] for name in s["searches"]},
                "calls_ratio": {name: calls[name] / calls["fixed"] for name in s["searches"]},
                "chosen": chosen,
                "fixed_test_deviation": float(np.mean(deviation(gt.mdp, gt.test_rewards, fixed.transfer_rewards_))),
            }
    return out
