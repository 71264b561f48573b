"""Time fitting the paper-scale training set: flat (GradIRL) for all tasks, then factorial.

Paper-scale defaults (section 4, DESIGN section 2): 10x10 grid, 100 tasks whose rewards mix
k = 5 random primitives (``factirl_opt.ground_truth``: D ~ N(0, 1), H ~ N(0, 1)), 10
demonstrations of 10 steps per task, beta = 5. The flat learner fits every task (batched);
the factorial learner (``init="pca"``) starts from the PCA of those flat rewards (passed as
``flat_rewards``, so the flat fit is not repeated). Both learners use their default
hyperparameters unless overridden.

Prints times, Q* evaluation counts and the mean train deviation from the optimal score
(eq. 13) of both learners. ``--quick`` is a tiny configuration for tests.
"""

import time

import numpy as np

from ..demonstrations import sample_demonstrations
from ..evaluation import deviation
from ..factirl import FactIRL
from ..synthetic import random_coefficients, random_dictionary, task_rewards
from ..gradirl import GradIRL
from ..mdp import GridWorld
from .._threads import limit_blas_threads

__all__ = ["add_arguments", "run"]

QUICK = {"size": 4, "n_tasks": 6, "n_demos": 3, "length": 5, "max_iter": 5, "flat_max_iter": 10}


def add_arguments(parser):
    parser.add_argument("--size", type=int, default=10, help="grid side (default 10)")
    parser.add_argument("--n-tasks", type=int, default=100, help="training tasks (default 100)")
    parser.add_argument("--n-demos", type=int, default=10, help="demonstrations per task (default 10)")
    parser.add_argument("--length", type=int, default=10, help="steps per demonstration (default 10)")
    parser.add_argument("-k", "--n-primitives", type=int, default=5, help="primitives, true and learnt (default 5)")
    parser.add_argument("--beta", type=float, default=5.0)
    parser.add_argument("--flat-max-iter", type=int, default=100, help="GradIRL iterations (default 100)")
    parser.add_argument("--max-iter", type=int, default=100, help="FactIRL outer iterations (default 100)")
    parser.add_argument("--inner-steps", type=int, default=5, help="FactIRL steps per sub-problem (default 5)")
    parser.add_argument("--tol", type=float, default=1e-5, help="relative-decrease stopping tolerance (both)")
    parser.add_argument("--h-solver", default="armijo", help="FactIRL H-step solver (default armijo)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--blas-threads", type=int, default=1, help="OpenBLAS threads (0: leave as is; default 1)")
    parser.add_argument("--quick", action="store_true", help=f"tiny configuration for tests: {QUICK}")


def run(args):
    if args.quick:
        for key, value in QUICK.items():
            setattr(args, key, value)
    with limit_blas_threads(args.blas_threads) as threads:
        rng = np.random.default_rng(args.seed)
        k = args.n_primitives

        t0 = time.perf_counter()
        mdp = GridWorld(size=args.size)
        D = random_dictionary(mdp.n_params, k, rng)
        H = random_coefficients(args.n_tasks, k, rng=rng)
        R = task_rewards(D, H, mdp.n_states, mdp.n_actions)
        demos = sample_demonstrations(mdp, R, args.n_demos, args.length, rng)
        t_data = time.perf_counter() - t0

        t0 = time.perf_counter()
        flat = GradIRL(beta=args.beta, max_iter=args.flat_max_iter, tol=args.tol).fit(mdp, demos)
        t_flat = time.perf_counter() - t0

        t0 = time.perf_counter()
        fact = FactIRL(
            n_primitives=k,
            beta=args.beta,
            init="pca",
            max_iter=args.max_iter,
            inner_steps=args.inner_steps,
            tol=args.tol,
            h_solver=args.h_solver,
            rng=np.random.default_rng(args.seed + 1),
        ).fit(mdp, demos, flat_rewards=flat.rewards_)
        t_fact = time.perf_counter() - t0

        dev_flat = float(np.mean(deviation(mdp, R, flat.rewards_)))
        dev_fact = float(np.mean(deviation(mdp, R, fact.rewards_)))
    total = t_flat + t_fact
    return {
        "benchmark": "fit",
        "total_s": total,
        "flat": {
            "time_s": t_flat,
            "n_evaluations": flat.n_evaluations_,
            "n_iter": int(flat.n_iter_),
            "status": flat.status_,
            "final_loss": float(flat.loss_.sum()),
            "mean_train_deviation": dev_flat,
        },
        "factorial": {
            "time_s": t_fact,
            "n_evaluations": fact.n_evaluations_,
            "n_iter": int(fact.n_iter_),
            "final_loss": float(fact.loss_.sum()),
            "mean_train_deviation": dev_fact,
        },
        "deviation_ratio_factorial_over_flat": dev_fact / dev_flat if dev_flat > 0 else float("nan"),
        "data_time_s": t_data,
        "settings": {
            "size": args.size,
            "n_tasks": args.n_tasks,
            "n_demos": args.n_demos,
            "length": args.length,
            "n_primitives": k,
            "beta": args.beta,
            "flat_max_iter": args.flat_max_iter,
            "max_iter": args.max_iter,
            "inner_steps": args.inner_steps,
            "tol": args.tol,
            "h_solver": args.h_solver,
            "seed": args.seed,
            "quick": bool(args.quick),
            "blas_threads": threads,
        },
    }
