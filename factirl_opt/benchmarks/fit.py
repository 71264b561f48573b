"""Time fitting the paper-scale training set: flat (GradIRL) for all tasks, then factorial.

Paper-scale defaults (section 4, DESIGN section 2): 10x10 grid, 100 tasks whose rewards mix
k = 5 random primitives (:func:`factirl_opt.synthetic_tasks`: D ~ N(0, 1), H ~ N(0, 1)), 10
demonstrations of 10 steps per task, beta = 5. The flat learner fits every task (batched);
the factorial learner (``init="pca"``) starts from the PCA of those flat rewards (passed as
``flat_rewards``, so the flat fit is not repeated). Both learners use their default
hyperparameters unless overridden.

Prints times, Q* evaluation counts and the mean train deviation from the optimal score
(eq. 13) of both learners. ``--quick`` is a tiny configuration for tests (options given
explicitly keep their value).
"""

import time

import numpy as np

from .._threads import limit_blas_threads
from ..evaluation import deviation
from ..factirl import FactIRL
from ..gradirl import GradIRL
from ..mdp import GridWorld
from ..synthetic import synthetic_tasks
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run"]

DEFAULTS = {"size": 10, "n_tasks": 100, "n_demos": 10, "length": 10, "n_primitives": 5, "beta": 5.0,
            "flat_max_iter": 100, "max_iter": 100, "inner_steps": 5, "tol": 1e-5, "h_solver": "armijo", "seed": 0,
            "blas_threads": 1}
#: a few seconds' setting in which the factorial learner still clearly beats the flat one (k = 2 primitives
#: shared by 16 tasks: measured deviation ratio 0.1-0.4 over seeds 0-5)
QUICK = {"size": 4, "n_tasks": 16, "n_demos": 5, "length": 6, "n_primitives": 2, "max_iter": 15, "flat_max_iter": 20}


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--size", type=int, help="grid side")
    opt("--n-tasks", type=int, help="training tasks")
    opt("--n-demos", type=int, help="demonstrations per task")
    opt("--length", type=int, help="steps per demonstration")
    opt("-k", "--n-primitives", type=int, help="primitives, true and learnt")
    opt("--beta", type=float, help="Boltzmann inverse temperature")
    opt("--flat-max-iter", type=int, help="GradIRL iterations")
    opt("--max-iter", type=int, help="FactIRL outer iterations")
    opt("--inner-steps", type=int, help="FactIRL steps per sub-problem")
    opt("--tol", type=float, help="relative-decrease stopping tolerance (both learners)")
    opt("--h-solver", help="FactIRL H-step solver")
    opt("--seed", type=int, help="seed of the synthetic tasks")
    opt("--blas-threads", type=int, help="OpenBLAS threads (0: leave as is)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny configuration for tests; options given explicitly keep their value")


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _fit_both(s):
    """Generate the tasks, fit flat then factorial; returns the measurements of both."""
    k = s["n_primitives"]
    mdp = GridWorld(size=s["size"])
    tasks, t_data = _timed(lambda: synthetic_tasks(mdp, s["n_tasks"], s["n_demos"], s["length"], n_primitives=k,
                                                   rng=np.random.default_rng(s["seed"])))
    flat, t_flat = _timed(lambda: GradIRL(beta=s["beta"], max_iter=s["flat_max_iter"], tol=s["tol"]).fit(mdp, tasks.demos))
    fact = FactIRL(n_primitives=k, beta=s["beta"], init="pca", max_iter=s["max_iter"], inner_steps=s["inner_steps"],
                   tol=s["tol"], h_solver=s["h_solver"], rng=np.random.default_rng(s["seed"] + 1))
    _, t_fact = _timed(lambda: fact.fit(mdp, tasks.demos, flat_rewards=flat.rewards_))
    flat_entry = {
        "time_s": t_flat, "n_evaluations": flat.n_evaluations_, "n_iter": int(flat.n_iter_), "status": flat.status_,
        "final_loss": float(flat.loss_.sum()),
        "mean_train_deviation": float(np.mean(deviation(mdp, tasks.rewards, flat.rewards_))),
    }
    fact_entry = {
        "time_s": t_fact, "n_evaluations": fact.n_evaluations_, "n_iter": int(fact.n_iter_),
        "final_loss": float(fact.loss_.sum()),
        "mean_train_deviation": float(np.mean(deviation(mdp, tasks.rewards, fact.rewards_))),
    }
    return flat_entry, fact_entry, t_data


def run(args):
    s = resolve_settings(args, DEFAULTS, QUICK)
    with limit_blas_threads(s["blas_threads"]) as threads:
        flat, fact, t_data = _fit_both(s)
    dev_flat, dev_fact = flat["mean_train_deviation"], fact["mean_train_deviation"]
    settings = {key: s[key] for key in DEFAULTS}
    settings.update(quick=bool(s["quick"]), blas_threads=threads)
    return {
        "benchmark": "fit",
        "total_s": flat["time_s"] + fact["time_s"],
        "flat": flat,
        "factorial": fact,
        "deviation_ratio_factorial_over_flat": dev_fact / dev_flat if dev_flat > 0 else float("nan"),
        "data_time_s": t_data,
        "settings": settings,
    }
