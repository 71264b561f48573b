"""Tasks in many environments: a FactIRL fit with a map per task against the same fit on one map.

ELIRL's Objectworld protocol puts every task on its own map (:func:`factirl_opt.datasets.objectworld.maps`,
default 100 tasks on 32x32 maps, 5 inner and 2 outer colours, discrete features with a bias
column, 32 demonstrations of 16 steps per task). Two routes fit the same tasks, with the same
demonstrations, solvers and iteration budget, side by side in one run:

- ``per_task_maps``: ``FactIRL(features=[Phi_1, ..., Phi_n]).fit(maps.mdps, demos)``, each task
  on its own map's features (the maps share their dynamics, so the MDP is one object and all
  tasks are planned as one batch; the features differ);
- ``one_map``: ``FactIRL(features=Phi_1).fit(mdp, demos)``, every task on the first map's
  features (today's one-MDP path).

The demonstrations are drawn on each task's own map (greedy expert); both routes see the same
state-action pairs (the dynamics are the same on every map). The budget is fixed: PCA start
from ``--flat-max-iter`` flat iterations, ``pca_shrink=False``, ``--max-iter`` outer iterations
of ``--inner-steps`` steps, ``tol = gtol = 0``. Each route runs in a fresh (spawned) process,
which draws the maps and the demonstrations itself (same seed) and then times the fit;
``peak_rss_mb`` is that process's peak resident memory (``ru_maxrss``), ``rss_before_fit_mb``
its resident memory just before the fit. ``ratio`` is per-task-maps wall time over one-map
wall time (the acceptance bound is 1.5), ``ratio_cpu`` the same for the processes' CPU times
(``time.process_time``, steadier on a shared machine: BLAS runs on ``--blas-threads`` threads),
``ratio_per_evaluation`` the wall-time ratio per batched planning evaluation.

``--quick`` is a tiny configuration for tests (options given explicitly keep their value).
"""

import argparse
import multiprocessing
import os
import resource
import time

import numpy as np

from ...parallel import limit_blas_threads
from ...tasks.demonstrations import sample_demonstrations
from ...learners.solver_settings import SolverSettings
from ...learners.start import Start
from ...learners.factirl import FactIRL
from ...datasets.objectworld.maps import objectworld_maps
from ..arguments import integer, real, solver_name
from ...objectives import available_objectives
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run"]

DEFAULTS = {"n_tasks": 100, "size": 32, "n_demos": 32, "length": 16, "n_primitives": 5, "beta": 5.0,
            "flat_max_iter": 10, "max_iter": 3, "inner_steps": 5, "h_solver": "armijo", "d_solver": "armijo",
            "objective": "policy-matching", "seed": 0, "blas_threads": 1}
QUICK = {"n_tasks": 6, "size": 8, "n_demos": 4, "length": 6, "n_primitives": 2, "flat_max_iter": 3, "max_iter": 2}
ROUTES = ("per_task_maps", "one_map")


def add_arguments(parser):
    add_option(parser, "--n-tasks", type=integer(1), defaults=DEFAULTS, quick=QUICK, help="tasks, one map each")
    add_option(parser, "--size", type=integer(2), defaults=DEFAULTS, quick=QUICK, help="map side")
    add_option(parser, "--n-demos", type=integer(1), defaults=DEFAULTS, quick=QUICK, help="demonstrations per task")
    add_option(parser, "--length", type=integer(1), defaults=DEFAULTS, quick=QUICK, help="steps per demonstration")
    add_option(parser, "--n-primitives", type=integer(1), defaults=DEFAULTS, quick=QUICK)
    add_option(parser, "--beta", type=real(0, low_open=True), defaults=DEFAULTS)
    add_option(parser, "--flat-max-iter", type=integer(0), defaults=DEFAULTS, quick=QUICK, help="flat iterations of the PCA start")
    add_option(parser, "--max-iter", type=integer(0), defaults=DEFAULTS, quick=QUICK, help="outer iterations")
    add_option(parser, "--inner-steps", type=integer(1), defaults=DEFAULTS)
    add_option(parser, "--h-solver", type=solver_name, defaults=DEFAULTS)
    add_option(parser, "--d-solver", type=solver_name, defaults=DEFAULTS)
    add_option(parser, "--objective", choices=available_objectives(), defaults=DEFAULTS)
    add_option(parser, "--seed", type=integer(0), defaults=DEFAULTS)
    add_option(parser, "--blas-threads", type=integer(0), defaults=DEFAULTS)
    parser.add_argument("--in-process", action="store_true", help="run both routes here (peak memory: the run's so far)")
    parser.add_argument("--quick", action="store_true", help="tiny configuration for tests")


def _rss_mb():
    """Current resident memory (MB) from /proc, or NaN where it cannot be read."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return float("nan")


def _route(name, s):
    """Draw the maps and demonstrations (seeded) and time one route's fit."""
    with limit_blas_threads(s["blas_threads"]):
        maps = objectworld_maps(s["n_tasks"], size=s["size"], bias=True, rng=s["seed"])
        mdp, A = maps.mdps[0], maps.mdps[0].n_actions
        R = np.repeat(np.asarray(maps.rewards)[:, :, None], A, axis=2)
        demos = [sample_demonstrations(m, R[i:i + 1], s["n_demos"], s["length"], rng=s["seed"] + 1 + i)[0]
                 for i, m in enumerate(maps.mdps)]
        features = list(maps.features) if name == "per_task_maps" else maps.features[0]
        model = FactIRL(n_primitives=s["n_primitives"], beta=s["beta"], features=features,
                        start=Start(pca_shrink=False, flat_max_iter=s["flat_max_iter"]), max_iter=s["max_iter"],
                        inner_steps=s["inner_steps"], tol=0.0, gtol=0.0,
                        solver=SolverSettings(s["h_solver"], d_solver=s["d_solver"]), objective=s["objective"])
        rss = _rss_mb()
        t0, c0 = time.perf_counter(), time.process_time()
        model.fit(maps.mdps if name == "per_task_maps" else mdp, demos)
        seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"fit_s": seconds, "fit_cpu_s": cpu, "n_evaluations": int(model.n_evaluations_), "n_iter": int(model.n_iter_),
            "final_loss": float(model.loss_history_[-1]), "status": model.status_,
            "rss_before_fit_mb": rss, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def run(args):
    s = resolve_settings(args, DEFAULTS, QUICK)
    load_before = os.getloadavg()
    results = {}
    ctx = multiprocessing.get_context("spawn")
    for name in ROUTES:
        if s["in_process"]:
            results[name] = _route(name, s)
            continue
        with ctx.Pool(1) as pool:  # a fresh process per route: its own peak memory
            results[name] = pool.apply(_route, (name, s))
    return {
        "benchmark": "environments",
        "routes": results,
        "ratio": results["per_task_maps"]["fit_s"] / results["one_map"]["fit_s"],
        "ratio_cpu": results["per_task_maps"]["fit_cpu_s"] / results["one_map"]["fit_cpu_s"],
        "ratio_per_evaluation": (results["per_task_maps"]["fit_s"] / results["per_task_maps"]["n_evaluations"])
                                / (results["one_map"]["fit_s"] / results["one_map"]["n_evaluations"]),
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "settings": {**{k: v for k, v in s.items() if k != "quick"}, "quick": bool(s["quick"]),
                     "memory": "ru_maxrss of the process that ran the route"
                               + (" (this process: the peak so far)" if s["in_process"] else " (a fresh process per route)")},
    }


if __name__ == "__main__":  # pragma: no cover
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    print(run(parser.parse_args()))
